"""The orchestrator's rules, without I/O: identity, admission, losses, retries, restarts, faults between rounds.

:class:`RoundMachine` is to the orchestrator what :class:`splitspec_agents.agent.AgentNode`
is to an agent: events in (method calls with already-decoded values and the
current monotonic time ``now``), actions out (a list of small dataclasses the
Zenoh shell in :mod:`splitspec_orchestrator.driver` executes: publish a tick, record a
row, log an event, signal or spawn a process, query statuses, stop).  It
opens no socket and reads no clock, so every rule is unit-tested case by case
(``tests/unit/test_rounds.py``).

This module holds the rules of a round and :class:`Phase`, where a run is.  The actions are in
:mod:`.actions`; the claims and the state the rules keep are small I/O-free collaborators the
machine holds: the claims and the process table (:mod:`.claims`), liveness (:mod:`.liveness`:
spawned, restarted, frozen and to-be-lost processes, silent sensors, the orchestrator's own clock),
the rejection counts (:mod:`.rejections`), the agents' network (:mod:`.topology`, with the
survivors' verdict) and what the round in flight has collected (:mod:`.collected`).

The rules
---------
*Identity.*  Every plant or agent process claims its identity with a
``hello`` (role, id, pid, host, a random nonce).  A claim is granted when
nobody holds the identity (never claimed, or the holder's token went away,
or the holder was declared lost, or it never showed a token within
``wait`` seconds); the same nonce asking again gets the same answer.  A
second claimant of a held identity is refused with the holder's pid and
host (``duplicate_refused``); the holder keeps running and the registry keeps
pointing at it.  Liveliness tokens carry the nonce: only the token of the
granted claim counts, so an impostor's token can neither keep an agent
"alive" nor hide its death.

*Start-up.*  The run starts when the plant and every agent hold a granted
claim and show their token; it fails with one line after ``wait`` seconds,
or at once when a process the orchestrator spawned exits (with its status).

*Rounds.*  Event time ``tau``, attempt ``a``: tick; collect ``truth(tau)``
(from the plant, same attempt) and ``xhat`` of every alive agent for ``tau``
(admissions) and ``tau + 1``; record; next.  Only messages of the round in
flight count (older or newer are ``stale``/``future``), so buffers hold at
most two event times.  A loss during a round re-runs it without the agent
(``a + 1``): "lost from event time tau on".  When a round exceeds
``round_timeout``: agents that do not answer a status query are frozen and
lost; if all answer, the round is re-run once, then the late ones are lost.

*Frozen processes.*  A round that has had no news for :data:`PROBE_SECONDS`
queries every process's status (answered from a Zenoh thread, so a busy
process answers and a frozen one cannot): an agent that does not answer
within :data:`PROBE_ANSWER_SECONDS` is lost as frozen, a silent plant stops
the run; if all answer, nobody is blamed and the round waits on.  So a frozen
agent is lost about 1.1 s after it froze, while links keep a long lease (a loaded machine,
or the orchestrator's own freeze, never closes a link); a killed process
closes its sockets and is lost at once through its liveliness token.

*Time.*  A gap of more than :data:`~.liveness.STALL_SECONDS` between two calls means
the orchestrator itself was frozen or starved: every deadline moves by the
gap (``orchestrator_stalled``), so nobody is blamed for the orchestrator's
own pause.  The time inside a spawn of its own processes is not such a gap
(:meth:`RoundMachine.on_spawned`): at m = 100 the m + 1 spawns take seconds
on a busy machine, and a warning about them would be a false alarm.

*Between rounds* (at the step the simulator applies them): pending losses,
then the scenario's faults in order (kill, freeze, restart, drop/restore an
arc), then agents that came back by hand (a rejoin with a new incarnation).

*Rejections* are counted per (process, reason) and logged as one summary
event per second, never one line per message.

Why one module: the rules of a round act on one another (a loss during a retry during a restart,
a freeze of the orchestrator itself), so they stay in one class; what they keep and what they say
is in the collaborators above, and this module is that class and its docstring of the rules.
"""

from __future__ import annotations

import math
import os
from enum import Enum

import numpy as np

from splitspec_core.model.impairment import CAUSES
from splitspec_core.model.network import make_plan
from splitspec_core.scenarios.faults import ORCHESTRATOR, RESTART, SIGNAL

from .actions import (Control, Event, Finished, KillSelf, Log, QueryStatus, Record, RegistryUpdate, ReplyConfig,
                      ReplyRefused, Signal, Spawn, Stop, Tick)
from .claims import ClaimTable, describe_status
from .collected import Collected
from .liveness import PROBE_ANSWER_SECONDS, PROBE_SECONDS, Liveness
from .pace import PaceWatch
from .rejections import Rejections
from .topology import TopologyState

# the actions test_rounds.py checks are importable from here too (it reads R.<name>); the rest are in .actions
__all__ = ["RoundMachine", "Phase", "Tick", "Record", "Event", "Log", "Signal", "Control", "Spawn", "QueryStatus",
           "ReplyConfig", "ReplyRefused", "RegistryUpdate", "Stop", "Finished"]


class Phase(str, Enum):
    """Where a run is (``RoundMachine.phase``).  A ``str`` Enum: each value is the plain string the phase was
    before, so whoever reads ``phase`` from outside (``m.phase == "restarting"``) reads what it read before;
    in text, write ``phase.value`` (formatting the member gives ``Phase.ROUND``)."""

    WAITING = "waiting"  # for the participants' claims and tokens
    BETWEEN = "between"  # between two rounds: pending losses, the faults due, admissions
    RESTARTING = "restarting"  # for the token of an agent the scenario restarts
    PACING = "pacing"  # run.pace: for the wall-clock time of the next round
    ROUND = "round"  # a round in flight
    STATUS = "status"  # a status query in flight (answered by on_status)
    DONE = "done"


#: the plan's length of a run that goes on until stopped (``run.until_stopped``): never reached
ENDLESS = 1 << 62


# ---------------------------------------------------------------------- the machine


class RoundMachine:
    """The orchestrator's protocol state (see the module docstring).

    Parameters
    ----------
    sc, des : the scenario and its design
    host : this machine's host name (processes elsewhere are asked to signal themselves)
    wait : seconds to wait for the participants (and for a restarted agent)
    round_timeout : seconds before a round's silent agents are investigated
    spawned : the orchestrator starts the plant and the agents itself (``splitspec run``)
    now : the current monotonic time
    """

    def __init__(self, sc, des, *, host: str, wait: float, round_timeout: float, spawned: bool = False,
                 now: float = 0.0):
        self.sc, self.des = sc, des
        self.wait, self.round_timeout = float(wait), float(round_timeout)
        self.spawned = spawned
        #: live sensors (scenario sources:): no plant process, no truth (x recorded as NaN)
        self.plantless = bool(getattr(sc, "sources", None))
        self.dt = sc.run.dt if sc.time == "continuous" else 1.0
        # O(1) memory: steps may be huge, or endless (run.steps omitted: the run goes on until stopped)
        self.plan = make_plan(sc, sc.run.seed, ENDLESS if sc.run.until_stopped else None, sequence=False)
        self.identity = ClaimTable(sc.agent_ids, wait=self.wait, plantless=self.plantless)  # claims, process table
        self.live = Liveness(now, host=host)  # children, frozen processes, pending losses, sensors, the stall clock
        self.rejections = Rejections(now)
        self.topology = TopologyState(sc, des)  # alive, joinable, the network, the survivors' verdict
        self.index = self.topology.index  # agent id -> its row
        self.collected = Collected(self.index, sc.m, sc.n, plantless=self.plantless)  # truth and estimates
        self.fresh_tau: int | None = None  # the event time whose round starts a fresh estimate (admission)
        self.prev_attempt = 0  # the attempt that completed the previous round
        self.phase = Phase.WAITING
        self.started = False
        self.tau = 0
        self.attempt = 0
        self.retried = False
        self.deadline = now + self.wait
        self.quiet_since = now  # the round in flight's last news (a message of it, or its tick)
        self.probing = False  # the status query in flight is a probe (not the round timeout's)
        self.faults_left: list = []
        self.t_run = None
        self.round_started = math.nan  # `now` of the round in flight's first tick (for Record)
        self.round_late = math.nan  # how late it started against run.pace (seconds; NaN unpaced)
        self.last_in: int | None = None  # the agent whose estimate came last in the round in flight
        self.pace = PaceWatch.of(sc, des, cores=os.cpu_count())  # run.pace: each event time's lateness, or None
        self.epoch = 1  # the orchestrator's (the shell's): the k-th `kill: orchestrator` is epoch k's

    # the collaborators' state, where the shell and the tests read it
    claims = property(lambda self: self.identity.claims, doc="(role, ident) -> :class:`.claims.Claim`")
    procs = property(lambda self: self.identity.procs, doc='"plant" / agent id -> {"pid", "host"}')
    alive = property(lambda self: self.topology.alive, doc="ids of the agents in the network")
    joinable = property(lambda self: self.topology.joinable, doc="ids of agents back, to join at the next tau")
    stopped = property(lambda self: self.live.stopped, doc="pids of frozen (SIGSTOPped) processes on this host")
    pending_loss = property(lambda self: self.live.pending_loss, doc="agent id -> why it is to be lost")
    stalled_seconds = property(lambda self: self.live.stalled_seconds, doc="the orchestrator's own freezes")
    rejected_total = property(lambda self: self.rejections.total, doc="messages rejected so far")
    truth = property(lambda self: self.collected.truth, doc="tau -> x(tau) from the plant")
    est = property(lambda self: self.collected.est, doc="tau -> {agent id: x_i(tau)}")

    # ------------------------------------------------------------------ helpers

    def t(self, tau: int | None = None) -> float:
        return float(self.tau if tau is None else tau) * self.dt

    def incarnation(self, aid: int) -> int:
        return self.topology.incarnation(aid)

    def reject(self, by: str, reason: str, count: int = 1) -> None:
        """Count ``count`` rejected messages of process ``by`` (summarised once per second)."""
        self.rejections.add(by, reason, count)

    def remote_counts(self, who: str, counts: dict, incarnation: int = 0) -> None:
        """Another process's running totals of rejections (sent with its truth / xhat); a restarted agent (a
        higher incarnation) counts from 0 again, and the totals of an older incarnation are not taken."""
        self.rejections.remote(who, counts, incarnation)

    @property
    def _in_flight(self) -> bool:
        """A round is in flight (its messages count)."""
        return self.phase in (Phase.ROUND, Phase.STATUS)

    def next_deadline(self) -> float:
        """When :meth:`on_timer` wants to be called at the latest (the shell polls at least every 0.5 s)."""
        if self.phase is Phase.ROUND:
            return min(self.deadline, self.quiet_since + PROBE_SECONDS)
        return self.deadline

    # ------------------------------------------------------------------ time

    def on_clock(self, now: float) -> list:
        """Every call starts here: detects the orchestrator's own freezes (every deadline moves by the gap)."""
        gap, out = self.live.stall(now, self.tau, self.t())
        if gap:  # nobody is blamed for the orchestrator's own pause
            self.deadline += gap
            self.quiet_since += gap
            if self.t_run is not None:
                self.t_run += gap
            self.identity.shift(gap)
        return out + self.rejections.summaries(now, self.t())

    # ------------------------------------------------------------------ identity

    def on_hello(self, ref, h: dict, now: float) -> list:
        """A process claims an identity (``h``: role, id, pid, host, nonce); reply config or refuse."""
        return self.on_clock(now) + self.identity.hello(ref, h, now, started=self.started, t=self.t())

    def on_token(self, role: str, ident: int, nonce: str | None, present: bool, now: float) -> list:
        """A liveliness token appeared or disappeared (only the granted claim's token counts)."""
        out = self.on_clock(now)
        c = self.identity.token(role, ident, nonce, present)
        if c is None:
            return out  # an impostor's, a superseded process's or a lost agent's token: ignored
        if present:
            # start-up of a process this orchestrator spawned: spawn to ready
            out += self.live.ready(role, ident, c.pid, now, self.t())
            if role == "agent" and self.started and ident not in self.alive:
                self.joinable.add(ident)
                if self.live.restart is None or self.live.restart[0] != ident:  # a restart says it rejoins
                    out.append(Log("info", f"agent {ident} is back; it joins at the next event time"))
            return out + self._progress(now)
        if role == "plant":
            if self.started:
                return out + [self._stop_plant("liveliness lost (the process died or froze)")]
            return out + [Event("process_left", self.t(), {"role": "plant", "pid": c.pid}),
                          Log("warning", f"the plant (pid {c.pid} on {c.host}) left during start-up; waiting for "
                                         "another one")]
        return out + self._agent_gone(ident, "liveliness lost (the process died or froze)", now)

    def _agent_gone(self, ident: int, why: str, now: float) -> list:
        """Agent ``ident``'s process is gone: lost at the next look if it is in the run."""
        self.joinable.discard(ident)
        if ident in self.alive:
            self.pending_loss[ident] = why
            return self._progress(now)
        return []

    def _stop_plant(self, why: str) -> Stop:
        pid = self.identity.pid("plant")
        self.phase = Phase.DONE
        return Stop(1, f"the plant (pid {pid}) was lost at event time {self.tau}: {why}; stopping (records up to "
                       f"event time {self.tau - 1} are kept)")

    def on_spawned(self, role: str, ident: int, pid: int, now: float, *, began: float | None = None) -> list:
        """The shell started process ``pid`` for ``role``/``ident``; it began at ``began`` and returned at ``now``.
        The time inside the spawn (fork and exec, seconds when the machine is busy starting the other m processes)
        is the orchestrator's own work, not a freeze: the stall detector looks at the gap before ``began`` only."""
        out = self.on_clock(began) if began is not None else []
        self.live.spawned(role, ident, pid, now)  # and the pid of an agent the scenario restarts
        return out

    def on_child_exit(self, pid: int, status: int, now: float) -> list:
        """A process this orchestrator spawned exited (``status`` as ``Popen.returncode``)."""
        out = self.on_clock(now)
        role, ident = self.live.exited(pid)
        if role is None:
            return out
        how = describe_status(status)
        who = ClaimTable.who(role, ident)
        out.append(Event("process_exited", self.t(), {"role": role, "id": ident, "pid": pid, "status": status,
                                                      "how": how}))
        if not self.started:
            self.phase = Phase.DONE
            return out + [Stop(1, f"{who} (pid {pid}) exited during start-up ({how}); see its output above")]
        if role == "plant":
            return out + [self._stop_plant(f"the process exited ({how})")]
        if self.live.restart is not None and self.live.restart == (ident, pid) and ident not in self.alive:
            return out + self._restart_failed(f"the new process exited ({how})") + self._progress(now)
        if self.identity.exited("agent", ident, pid):
            return out + self._agent_gone(ident, f"the process exited ({how})", now)
        return out

    def on_pid_gone(self, role: str, ident: int, pid: int, now: float) -> list:
        """A granted process on this host (not a child) is no longer running, before its token showed."""
        return self.on_clock(now) + self.identity.gone(role, ident, pid, self.t())

    # ------------------------------------------------------------------ start-up

    def start(self, now: float) -> list:
        """Called once the shell is up: spawn the participants (``spawned``) and wait for them."""
        self.deadline = now + self.wait
        self.live.last_now = now
        if not self.spawned:
            return []
        return [Spawn("plant", 0)] * (not self.plantless) + [Spawn("agent", a) for a in self.sc.agent_ids]

    # ------------------------------------------------------------------ messages

    def on_truth(self, tau: int, attempt: int, x: np.ndarray, rejected: dict, now: float) -> list:
        out = self.on_clock(now)
        self.remote_counts("plant", rejected)
        why = self.collected.put_truth(tau, attempt, x, at=(self.tau, self.attempt), in_flight=self._in_flight)
        if why:  # only messages of the round in flight count
            self.reject("orchestrator", why)
            return out
        self.quiet_since = now
        return out + self._progress(now)

    def on_xhat(self, aid: int, tau: int, attempt: int, incarnation: int, x: np.ndarray, columns: dict,
                rejected: dict, now: float, lost=(), y=(), u=()) -> list:
        """An agent's estimate with the row columns it reports (``columns``: :func:`splitspec_core.model.rows.report`;
        ``lost``: flat ``[k, j, cause, ...]`` of the consensus messages it did not count)."""
        out = self.on_clock(now)
        self.remote_counts(f"agent {aid}", rejected, int(incarnation))
        if aid not in self.index:
            self.reject("orchestrator", "wrong_sender")
            return out
        why = self.collected.put_xhat(aid, tau, attempt, x, columns, at=(self.tau, self.attempt),
                                      in_flight=self._in_flight, same_incarnation=incarnation == self.incarnation(aid),
                                      lost=lost, y=y, u=u)
        if why:  # x_i(tau) of any attempt (an admission estimate that crosses a re-run), x_i(tau + 1) of this one
            self.reject("orchestrator", why)
            return out
        self.quiet_since = now
        if tau == self.tau + 1:
            self.last_in = aid
        return out + self._progress(now)

    # ------------------------------------------------------------------ timers and status

    def on_timer(self, now: float) -> list:
        return self.on_clock(now) + self._progress(now)

    def on_status(self, answered: set, now: float, *, plant: bool = True) -> list:
        """The answer to :class:`QueryStatus`: agents (ids) whose processes answered, and whether the plant did."""
        out = self.on_clock(now)
        if self.phase is not Phase.STATUS:
            return out
        probing, self.probing = self.probing, False
        frozen = sorted(a for a in self.alive if a not in answered)
        late = self.collected.late(self.tau, self.alive, self.tau == self.plan.steps)
        self.phase = Phase.ROUND
        if not plant and not self.plantless:
            return out + [self._stop_plant("it does not answer a status query (frozen)")]
        if frozen:  # lost as frozen (one on this host is killed at the end: it cannot obey the final stop)
            self.live.frozen(frozen, self.procs, probing=probing, round_timeout=self.round_timeout)
        elif probing:
            self.quiet_since = now  # everybody is alive, only slow: wait on (the round timeout still holds)
        elif not self.retried:
            self.retried = True
            out.append(Event("round_retried", self.t(), {"tau": self.tau, "attempt": self.attempt + 1, "late": late}))
            out.append(Log("warning", f"event time {self.tau}: no estimate from splitspec_agents {late} within "
                                      f"{self.round_timeout:g} s, but all answer; re-running the round once"))
            return out + self._rerun(now)
        else:
            for a in late:
                self.pending_loss[a] = f"round timeout ({self.round_timeout:g} s without its estimate)"
        return out + self._progress(now)

    # ------------------------------------------------------------------ losses and admissions

    def _lose(self, aid: int, why: str) -> list:
        out = self.topology.lose(aid, why, self.tau, self.t(), pid=self.identity.pid(aid))
        if out:  # a new process may claim the identity (a rejoin); this one never comes back
            self.identity.release("agent", aid)
        return out

    def _admit(self, aid: int, why: str) -> list:
        out = self.topology.rejoin(aid, why, self.tau, self.t(), pid=self.identity.pid(aid))
        if out:
            self.fresh_tau = self.tau  # its neighbours need its z(0): every agent sends z(0) in this round
        return out

    def _apply_pending_losses(self) -> tuple:
        out, lost = [], False
        for a, why in sorted(self.pending_loss.items()):
            if a in self.alive:
                out += self._lose(a, why)
                lost = True
        self.pending_loss.clear()
        return out, lost

    # ------------------------------------------------------------------ the run

    def _progress(self, now: float) -> list:
        """Advance as far as the state allows (the heart of the machine)."""
        out: list = []
        for _ in range(10_000):  # each pass makes progress or returns
            if self.phase is Phase.WAITING:
                if not self.identity.missing():  # every participant holds its claim and shows its token
                    out += self._begin(now)
                    continue
                if now >= self.deadline:
                    self.phase = Phase.DONE
                    return out + [Stop(1, f"waited {self.wait:g} s for {', '.join(self.identity.missing())} to "
                                          "connect")]
                return out
            if self.phase is Phase.BETWEEN:
                out += self._between(now)
                if self.phase is Phase.BETWEEN:
                    continue
                if self.phase is Phase.DONE:
                    return out
                continue
            if self.phase is Phase.RESTARTING:
                aid, pid = self.live.restart
                if aid in self.joinable:
                    self.live.restart = None
                    out += self._admit(aid, "restarted by the scenario")
                    self.phase = Phase.BETWEEN
                    continue
                if now >= self.deadline:
                    out += self._restart_failed(f"no liveliness token within {self.wait:g} s")
                    continue
                return out
            if self.phase is Phase.PACING:
                if now >= self.deadline:
                    out += self._start_round(now)
                    continue
                if self.pending_loss:
                    lost_out, _ = self._apply_pending_losses()
                    out += lost_out
                return out
            if self.phase is Phase.ROUND:
                if self.pending_loss:
                    lost_out, lost = self._apply_pending_losses()
                    out += lost_out
                    if lost:
                        out += self._rerun(now)
                        continue
                if self.collected.done(self.tau, self.alive, self.tau == self.plan.steps):
                    out += self._complete(now)
                    continue
                if now >= self.deadline:
                    if self.tau not in self.truth and not self.plantless:
                        self.phase = Phase.DONE
                        return out + [Stop(1, f"no truth from the plant for event time {self.tau} within "
                                              f"{self.round_timeout:g} s")]
                    self.phase = Phase.STATUS
                    return out + [QueryStatus()]
                if now >= self.quiet_since + PROBE_SECONDS:
                    self.phase, self.probing = Phase.STATUS, True
                    return out + [QueryStatus(PROBE_ANSWER_SECONDS)]
                return out
            return out  # status (waiting for on_status) or done
        raise RuntimeError("round machine made no progress")  # pragma: no cover - a bug, not an input

    def _begin(self, now: float) -> list:
        self.started = True
        self.fresh_tau = 0
        self.topology.begin()
        self.t_run = now
        self.tau = 0
        self.faults_left = list(self.plan.faults.get(0, ()))
        self.phase = Phase.BETWEEN
        steps = None if self.sc.run.until_stopped else self.plan.steps  # None: until stopped
        return [Event("run_started", 0.0, {"agents": list(self.sc.agent_ids), "steps": steps})]

    def _between(self, now: float) -> list:
        """Pending losses, then the faults due at tau (one at a time: a restart waits), then admissions."""
        out, _ = self._apply_pending_losses()
        t = self.t()
        while self.faults_left:
            f = self.faults_left.pop(0)
            if f.runtime == SIGNAL:  # kill, freeze: the agent's process is signalled, and lost
                if f.agent not in self.alive:
                    out.append(Event("fault_skipped", t, {"action": f.action, "id": f.agent,
                                                          "reason": "agent not alive"}))
                    continue
                how, acts = self.live.signal_agent(f.agent, type(f), self.procs.get(f.agent))
                out += acts
                out += self._lose(f.agent, f"{f.loss_word} by the scenario ({how})")
            elif f.runtime == ORCHESTRATOR:  # epoch k's kill; its successor, replaying the step, goes on
                if _kill_epoch(self.plan, f) == self.epoch:
                    return out + [Event(f.event, t, {"tau": self.tau, "epoch": self.epoch}), KillSelf(self.tau)]
            elif f.runtime == RESTART:
                if f.agent in self.alive:
                    out.append(Event("fault_skipped", t, {"action": f.action, "id": f.agent,
                                                          "reason": "agent is alive"}))
                    continue
                return out + self._begin_restart(f.agent, now)
            else:  # NETWORK (partition, heal, arcs: the simulator's own bookkeeping of the links) or PLANT (the
                out += self.topology.change(f, self.tau, t)  # plant applies it itself): recorded, as simulated
        for a in sorted(self.joinable - self.alive):
            out += self._admit(a, "started by hand")
        if self.sc.run.pace:
            self.phase = Phase.PACING
            self.deadline = self.t_run + self.tau / self.sc.run.pace
            return out
        return out + self._start_round(now)

    def _begin_restart(self, aid: int, now: float) -> list:
        c = self.identity.get("agent", aid)
        old_pid = c.pid if c is not None and not c.released and c.present else None  # it still holds its token
        self.identity.release("agent", aid)  # superseded: a new process claims the identity
        self.joinable.discard(aid)
        self.phase, self.deadline = Phase.RESTARTING, now + self.wait
        return self.live.restart_agent(aid, old_pid, self.procs.get(aid), self.tau, self.t())

    def _restart_failed(self, why: str) -> list:
        self.phase = Phase.BETWEEN
        return self.live.restart_failed(why, self.tau, self.t())

    def _start_round(self, now: float) -> list:
        self.phase = Phase.ROUND
        self.attempt = 0
        self.retried = False
        self.round_started = now
        if self.sc.run.pace:  # its time was t_run + tau / pace (the PACING deadline)
            self.round_late = max(0.0, now - (self.t_run + self.tau / self.sc.run.pace))
        return self._tick(now)

    def _rerun(self, now: float) -> list:
        self.collected.drop_next(self.tau)
        self.attempt += 1
        self.phase = Phase.ROUND
        return self._tick(now)

    def _tick(self, now: float) -> list:
        graph = self.plan.graph_at(self.tau)
        out = self.topology.announce(self.tau, self.t(), graph)
        self.deadline = now + self.round_timeout
        self.quiet_since = now
        out.append(Tick(self.tau, self.attempt, graph, self.tau == self.plan.steps, tuple(sorted(self.alive)),
                        self.topology.rows(graph), {a: self.incarnation(a) for a in self.sc.agent_ids},
                        fresh=self.fresh_tau == self.tau, prev_attempt=self.prev_attempt,
                        partition=self.topology.groups))
        return out

    def _complete(self, now: float) -> list:
        row = self.collected.take(self.tau, self.alive)
        lost, used = row.lost, row.used
        out = [Record(self.tau, row.x, row.xhat, row.alive, self.plan.graph_at(self.tau), row.columns,
                      attempts=self.attempt + 1, rejected=self.rejections.since_record(), started=self.round_started,
                      lost=lost, y=tuple((a, used.get(a)) for a in sorted(self.alive)), late=self.round_late,
                      u=tuple((a, row.inputs[a]) for a in sorted(self.alive) if row.inputs.get(a) is not None))]
        out += self.pace.observe(self.tau, self.round_late, self.round_started, now, self.last_in, self.t()) \
            if self.pace is not None else []
        if self.plantless and self.tau < self.plan.steps:  # the last tick takes no measurement
            out += self.live.sensor_events(self.alive, used, self.tau, self.t())
        if lost:  # one line per event time, never one per message
            by = {c: sum(1 for r in lost if r[4] == k) for k, c in enumerate(CAUSES)}
            out.append(Event("messages_lost", self.t(), {"tau": self.tau, "count": len(lost),
                                                         **{c: v for c, v in by.items() if v}}))
        if self.tau == self.plan.steps:
            self.phase = Phase.DONE
            return out + self.rejections.summaries(now, self.t(), force=True) + [Finished(self.plan.steps)]
        self.prev_attempt = self.attempt  # its estimates x_i(tau + 1) start the next round
        self.tau += 1
        self.faults_left = list(self.plan.faults.get(self.tau, ()))
        self.phase = Phase.BETWEEN
        return out

    def finish_summaries(self, now: float) -> list:
        """Rejections not yet summarised (at the end of a run, whatever ended it)."""
        return self.rejections.summaries(now, self.t(), force=True)

    @property
    def finished(self) -> bool:
        return self.phase is Phase.DONE


def _kill_epoch(plan, f) -> int:
    """The epoch a scenario's ``kill: orchestrator`` ``f`` kills: the k-th of the plan's is epoch k's (a standby that
    took over at that step replays it and goes on)."""
    kills = [g for tau in sorted(plan.faults) for g in plan.faults[tau] if g.runtime == ORCHESTRATOR]
    return next(k for k, g in enumerate(kills, 1) if g is f)
