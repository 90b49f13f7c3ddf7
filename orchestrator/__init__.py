"""The orchestrator and the ``splitspec`` command (installed as ``splitspec_orchestrator``).

The orchestrator process enforces synchronous rounds, topology switches and faults, and records the run; it
is also the Zenoh router of a local run (of a run with a standby, a client of the run's own router).  It starts the plant and the agents as child processes and never
imports them (``tests/unit/test_architecture.py``).

- the command: :mod:`.cli` (parser, error boundary) and :mod:`.commands` (``design``, ``simulate``, ``run``, ...);
  :mod:`.launcher` (``splitspec run``), :mod:`.view` (``splitspec view``), :mod:`.registry` (where running runs
  are found), :mod:`.forks` (the agents' fork server), :mod:`.plots` (PNG figures);
- the orchestrator: :mod:`.rounds` (its rules, no I/O: admission, losses, retries, faults) and :mod:`.driver`
  (its process shell: Zenoh, child processes, the recorder); :mod:`.standby` (``splitspec standby``: a second
  orchestrator that follows a run) and :mod:`.takeover` (how it takes the run over: the records resumed, the
  fencing on disk, the active one's side of its standbys);
- the records: :mod:`.records` (the recorder, its rows and flushes, ``trajectory.npz``, ``events.jsonl``, the
  output folder and ``splitspec recover``);
- the Rerun recording: :mod:`.viewer` (the sink, ``run.rrd`` itself, the default layout, the topology and
  no-truth panels, the notebook widget).

Each package's own docstring names its modules (``tests/unit/test_architecture.py`` checks that they exist).
"""
