"""The orchestrator and the ``splitspec`` command (installed as ``splitspec_orchestrator``).

The orchestrator process enforces synchronous rounds, topology switches and faults, and records the run; it
is also the Zenoh router of a local run.  It starts the plant and the agents as child processes and never
imports them (``tests/unit/test_architecture.py``).

- the command: :mod:`.cli` (parser, error boundary) and :mod:`.commands` (``design``, ``simulate``, ``run``, ...);
  :mod:`.launcher` (``splitspec run``), :mod:`.view` (``splitspec view``), :mod:`.recover`, :mod:`.registry`;
- the orchestrator: :mod:`.rounds` (its rules, no I/O: admission, losses, retries, faults) and :mod:`.driver`
  (its process shell: Zenoh, child processes, the recorder);
- the records: :mod:`.recorder` (buffering, the flush thread, consistency, close) with :mod:`.rowstore`,
  :mod:`.record_files` (``trajectory.npz``, ``run.rrd``), :mod:`.measured_records` (runs on measurements
  and live sensors), :mod:`.eventlog` (``events.jsonl``), :mod:`.outdir`; the Rerun side :mod:`.rerun_sink`,
  :mod:`.rrdfile`, :mod:`.blueprint` (entity paths, default layout), :mod:`.topology_view`, :mod:`.reference_view`;
  :mod:`.plots` (PNG figures).
"""
