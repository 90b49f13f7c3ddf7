"""The rules of a run's rounds, I/O-free: what the orchestrator does on each message and each timeout.

``machine.py`` the :class:`RoundMachine` (the two-rate round of q exchanges per event time, admissions,
losses, retries, restarts, the faults between rounds) and its :class:`Phase`; it returns actions
(``actions.py``) for its shell (``splitspec_orchestrator.driver``) to carry out, and keeps its state in
small collaborators: ``claims.py`` (the claim identity and the process table), ``liveness.py`` (spawned,
frozen and restarted processes, silent sensors, the orchestrator's own freezes), ``rejections.py``
(rejected messages, summarised), ``topology.py`` (the agents' network and the survivors' verdict) and
``collected.py`` (the round in flight's truth and estimates), ``pace.py`` (each event time's lateness against
``run.pace``, the warning when the run falls behind); ``tally.py`` counts what the run did for the shell (its
end event and closing line); ``follower.py`` is a standby orchestrator's view of the run it follows (the rounds
its active one commits, the network, the process table) and hands it to a new machine at a takeover.  Nothing
here opens a socket, a file or a process; each module imports only ``actions.py`` of its neighbours, but
``machine.py`` which imports them all and ``follower.py`` which imports the machine and ``collected.py``.
"""
