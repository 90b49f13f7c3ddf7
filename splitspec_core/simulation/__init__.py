"""Trajectories: the reference simulator and what is measured on its output.

``simulator.py`` the batch simulator (the same pure steps as the agent processes: run == simulate),
``kinds.py`` the estimator kinds, one class each (their batch, per-agent and per-seed forms: a kind is added there),
``loop.py`` the one simulation loop it, the exact ODE and the Monte Carlo batch share,
``montecarlo.py`` many seeds of one design as one batch, ``trajectory_file.py`` the ``trajectory.npz``
contract, ``trajectory_chunks.py`` a run's rows as append-only Arrow chunks (the one module here that imports
``pyarrow``, when it reads or writes them), ``metrics.py`` what a trajectory shows (errors, decay fits, envelopes, steady RMS, summaries).
Imports ``scenarios``, ``model`` and ``synthesis``.
"""
