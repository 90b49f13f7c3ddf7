"""The process runtime: what the agent, plant and orchestrator processes need and the math never does.

- :mod:`.wire`: the message codec (binary round messages, msgpack for the rest, MAC trailers, key names built in one place).
- :mod:`.bus`: the Zenoh session, bounded inboxes and liveliness.
- :mod:`.node`: the process shell of a plant or agent, ``NodeShell`` (session, identity claim, configuration,
  publishing, the loop).
- :mod:`.security`: the per-process Zenoh users, passwords and access-control policy of a secure run.
- :mod:`.cli`: the command-line conventions every process shares (one-line errors, typed options).

Imports flow one way: ``splitspec_agents``, ``splitspec_plant``, ``splitspec_orchestrator`` ->
``splitspec_core.runtime`` -> ``splitspec_core``.  No module of ``splitspec_core`` outside this
subpackage imports it (the table of docs/explanation/architecture.md, checked by
``tests/unit/test_architecture.py``), so design and simulate run where Zenoh and msgpack are not installed.
"""
