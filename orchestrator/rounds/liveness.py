"""Liveness: what the orchestrator knows of its processes' lives, of the live sensors, and of its own.

:class:`Liveness` keeps the processes this orchestrator spawned (until their token shows), the agent the
scenario restarts, the frozen processes (killed at the end), the agents found dead or frozen whose loss is
still to be applied, the live sensors that went silent, and the orchestrator's own clock (a gap of more
than :data:`STALL_SECONDS` between two calls is its own freeze); it signals, spawns and reports them.
When to probe (:data:`PROBE_SECONDS`, :data:`PROBE_ANSWER_SECONDS`) and when a loss is applied are
:class:`~splitspec_orchestrator.rounds.machine.RoundMachine`'s rules.  I/O-free: the times are the
machine's ``now``, and a signal or a spawn is an action for the shell.
"""

from __future__ import annotations

import signal

from splitspec_core.scenarios.faults import Kill

from .actions import Control, Event, Log, Signal, Spawn

__all__ = ["Liveness", "STALL_SECONDS", "PROBE_SECONDS", "PROBE_ANSWER_SECONDS"]

STALL_SECONDS = 2.5  #: a gap between calls longer than this is the orchestrator's own freeze
PROBE_SECONDS = 0.3  #: a round with no news for this long: ask every process whether it is alive
PROBE_ANSWER_SECONDS = 0.8  #: ... and give it this long to answer (a busy process answers in milliseconds)


class Liveness:
    """Processes, sensors and the orchestrator itself: who is known alive, dead or frozen, and since when."""

    def __init__(self, now: float = 0.0, *, host: str = ""):
        self.host = host  # this machine's host name (processes elsewhere are asked to signal themselves)
        self.children: dict = {}  # pid -> (role, ident) of processes this orchestrator spawned
        self.spawn_times: dict = {}  # pid -> when it was spawned, until its liveliness token appears
        self.stopped: set = set()  # pids of frozen (SIGSTOPped) processes on this host (killed at the end)
        self.pending_loss: dict = {}  # agent id -> why it is lost (applied in the round or between rounds)
        self.sensor_since: dict = {}  # agent id -> event time its live sensor went silent, or None: it is heard
        self.restart: tuple | None = None  # (agent id, spawned pid or None) of a restart by the scenario
        self.last_now = now
        self.stalled_seconds = 0.0

    # ------------------------------------------------------------------ the orchestrator's own clock

    def stall(self, now: float, tau: int, t: float) -> tuple:
        """``(gap, actions)``: the gap since the previous call if it is the orchestrator's own freeze (longer than
        :data:`STALL_SECONDS`, at event time ``tau``), else 0, and what to say about it."""
        gap = now - self.last_now
        self.last_now = now
        if not gap > STALL_SECONDS:
            return 0.0, []
        self.stalled_seconds += gap
        return gap, [Event("orchestrator_stalled", t, {"seconds": round(gap, 3), "tau": tau}),
                     Log("warning", f"the orchestrator was frozen or starved for {gap:.1f} s (event time {tau}); "
                                    "nobody is blamed for it, the run goes on")]

    # ------------------------------------------------------------------ processes

    def spawned(self, role: str, ident: int, pid: int, now: float) -> None:
        """The shell started ``pid`` for ``role``/``ident`` and returned at ``now`` (its own work, not a freeze)."""
        self.last_now = max(self.last_now, now)
        self.children[int(pid)] = (role, int(ident))
        self.spawn_times[int(pid)] = now
        if self.restart is not None and role == "agent" and self.restart[0] == ident:
            self.restart = (ident, int(pid))

    def ready(self, role: str, ident: int, pid: int, now: float, t: float) -> list:
        """The token of ``pid`` showed: for a process this orchestrator spawned, its start-up (spawn to ready)."""
        spawned_at = self.spawn_times.pop(pid, None)
        if spawned_at is None:
            return []
        return [Event("process_ready", t, {"role": role, "id": ident, "pid": pid,
                                           "startup_s": round(now - spawned_at, 3)})]

    def exited(self, pid: int) -> tuple:
        """``(role, ident)`` of the child ``pid`` that exited, or ``(None, None)``: not one of ours."""
        return self.children.pop(int(pid), (None, None))

    def signal_agent(self, aid: int, kind: type, info: dict | None) -> tuple:
        """Signal agent ``aid`` as the fault kind ``kind`` says (:attr:`~splitspec_core.scenarios.faults.Fault.signal`:
        a kill, a freeze), its granted process being ``info`` ({"pid", "host"} or None): ``(how, actions)``; a
        process frozen on this host is killed at the end."""
        sig = getattr(signal, kind.signal)
        if info and info["host"] == self.host:
            if kind.keeps_process:
                self.stopped.add(int(info["pid"]))
            return f"{signal.Signals(sig).name} to pid {info['pid']}", [Signal(int(info["pid"]), int(sig))]
        # another host (or unknown pid): the agent signals itself
        where = info["host"] if info else "an unknown host"
        return (f"asked agent {aid} on {where} to {kind.action} itself",
                [Control(f"{kind.action} agent/{aid}")])

    def restart_agent(self, aid: int, old_pid: int | None, info: dict | None, tau: int, t: float) -> list:
        """The scenario restarts agent ``aid`` at event time ``tau``: spawn a new process (``old_pid``: the old
        one, if it still holds its token; ``info``: its {"pid", "host"})."""
        out = []
        if old_pid is not None:
            # the old process still holds its token (frozen, or its death not yet seen): kill it; its claim is
            # superseded now, so its token can neither block nor be confused with the new one
            how, acts = self.signal_agent(aid, Kill, info)
            self.stopped.discard(old_pid)
            out += acts + [Log("info", f"restart of agent {aid}: killed the old process ({how})")]
        self.restart = (aid, None)
        return out + [Event("agent_restarting", t, {"id": aid, "tau": tau}), Spawn("agent", aid)]

    def restart_failed(self, why: str, tau: int, t: float) -> list:
        """The restarted agent showed no token in time, or its new process exited: the run goes on without it."""
        aid = self.restart[0]
        self.restart = None
        return [Event("restart_failed", t, {"id": aid, "tau": tau, "reason": why}),
                Log("warning", f"restart of agent {aid} at event time {tau} failed: {why}; the run goes on "
                               "without it")]

    def frozen(self, agents, procs: dict, *, probing: bool, round_timeout: float) -> None:
        """``agents`` did not answer a status query (after a probe, or at the round timeout): lost as frozen;
        one on this host cannot obey the final stop, so it is killed then (``procs``: the process table)."""
        why = (f"no news of the round for {PROBE_SECONDS:g} s and no answer to a status query within "
               f"{PROBE_ANSWER_SECONDS:g} s: frozen"
               if probing else f"round timeout ({round_timeout:g} s) and no answer to a status query: frozen")
        for a in agents:
            self.pending_loss[a] = why
            info = procs.get(a)
            if info and info["host"] == self.host:
                self.stopped.add(int(info["pid"]))  # cannot obey the final stop: killed then

    # ------------------------------------------------------------------ live sensors

    def sensor_events(self, alive, used: dict, tau: int, t: float) -> list:
        """A live sensor heard before that gave its agent no measurement (``sensor_lost``), and its return
        (``sensor_back``): one event per change, not per event time (the per-row truth is ``y_missing``)."""
        out = []
        for a in sorted(alive):
            heard = used.get(a) is not None
            if a not in self.sensor_since:  # nothing to say until the sensor is first heard
                if heard:
                    self.sensor_since[a] = None
                continue
            silent_since = self.sensor_since[a]
            if silent_since is None and not heard:
                self.sensor_since[a] = tau
                out.append(Event("sensor_lost", t, {"agent": a, "tau": tau}))
            elif silent_since is not None and heard:
                self.sensor_since[a] = None
                out.append(Event("sensor_back", t, {"agent": a, "tau": tau, "silent": tau - silent_since}))
        return out
