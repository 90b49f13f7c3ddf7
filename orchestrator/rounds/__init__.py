"""The rules of a run's rounds, I/O-free: what the orchestrator does on each message and each timeout.

``machine.py`` the :class:`RoundMachine` (claims, liveness, the two-rate round of q exchanges per event
time, topology switches, the survivors' verdict) which returns actions for its shell
(``splitspec_orchestrator.driver``) to carry out; nothing here opens a socket, a file or a process.
"""
