"""The agent process (installed as ``splitspec_agents``): one OS process per agent, running the split-spectrum
protocol over Zenoh.

- :mod:`.agent`: ``AgentNode``, the I/O-free state machine of one agent (its part of the design, then the
  two-rate protocol round after round, with the core's step functions), inside the runtime's process shell;
- :mod:`.measure`: the agent's measurements ``y_i(tau)``, or that it has none (it then predicts only);
- :mod:`.sensor`: live sensors (scenario ``sources:``), the newest ``y_i`` from the user's own process;
- ``python -m splitspec_agents`` (:mod:`.__main__`), what ``splitspec agent`` runs.

It imports only ``splitspec_core`` and its ``runtime`` (docs/explanation/architecture.md).
"""
