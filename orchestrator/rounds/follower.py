"""What a standby orchestrator knows of the run it follows: the rounds, the network, the processes.

A standby (``run.standby: true``, ``splitspec standby``) hears what the active orchestrator hears and says
(the ticks, the plant's truth, the agents' estimates, the active one's ``state``) and keeps, I/O-free:

* the round in flight: the last tick (event time, attempt, graph, whether it is fresh or final), the network it
  announced (who is alive, their incarnations, a partition in force) and what the round has collected so far
  (:class:`~.collected.Collected`, the machine's own buffers);
* the rounds the active one committed: a round ``tau`` is committed when the tick of ``tau + 1`` names its
  attempt (``prev_attempt``, exactly the agents' rule); its row is assembled as the machine assembles it
  (:meth:`Collected.take`) and kept among the last :data:`KEEP_ROWS`, so that rows the dead orchestrator had
  committed but not yet written (it flushes about once a second) are recorded by its successor;
* the active one's ``state``: its epoch, the process table (pid, host, nonce of every granted process), the
  origin of the pace on the wall clock, and how many rows its records hold on disk.

:meth:`Follower.view` hands all of it to :func:`adopt` at a takeover; the round in
flight goes on where it was (its messages were collected here while it ran), so the estimates are those of an
uninterrupted run.  A follower is :attr:`~Follower.ready` once it has seen a tick with the network and a state saying
that the records on disk reach the first round it followed (the active one resends the network in its next tick
when a standby's token appears, and its state about once a second): then nothing the dead one committed is lost.
A standby that is not ready when the active one dies still takes over, and says which rows are missing.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field

import numpy as np

from .actions import Record, Stop
from .collected import Collected
from .machine import Phase

__all__ = ["Follower", "FollowedRound", "KEEP_ROWS", "adopt"]

#: committed rows a follower keeps (at 50 event times per second: 40 s, far more than a flush interval)
KEEP_ROWS = 2048
#: committed rounds a follower waits for while their messages come in (a truth or an estimate may come after the
#: next tick: the router forwards each sender's messages on its own thread)
OWED_ROUNDS = 4


@dataclass
class FollowedRound:
    """The round in flight as the last tick announced it, and the network in force."""

    tau: int
    attempt: int
    prev_attempt: int
    graph: int
    fresh: bool
    final: bool
    topology: int  # the tick's count of network changes (a takeover's ticks count on from it)
    alive: tuple | None = None  # None: the follower did not know the network at its tick (it cannot record it)
    incarnation: dict = field(default_factory=dict)  # agent id -> incarnation
    partition: tuple = ()


class Follower:
    """A standby's view of the run (``sc``: the scenario; ``keep``: committed rows kept, default
    :data:`KEEP_ROWS`)."""

    def __init__(self, sc, *, keep: int = KEEP_ROWS):
        self.sc = sc
        self.index = {a: k for k, a in enumerate(sc.agent_ids)}
        self.plantless = bool(getattr(sc, "sources", None))
        self.round: FollowedRound | None = None
        self.network = None  # (alive, incarnation, partition) of the last tick that carried it
        self.rows: deque = deque(maxlen=int(keep))  # Record of each committed round, oldest first
        self.owed: list = []  # rounds committed (by the next tick) whose messages have not all come yet
        self.truths: dict = {}  # (tau, attempt) -> x(tau): the messages of the last event times, by tag
        self.xhats: dict = {}  # (tau, attempt) -> {agent id: (incarnation, x, columns, lost, y, u)}
        self.epoch = 0  # the active orchestrator's (its state, its ticks)
        self.procs: dict | None = None  # "plant" / agent id -> {"pid", "host", "nonce"}
        self.t_run_wall: float | None = None  # wall-clock time of event time 0 of the pace (None: not started)
        self.pid: int | None = None  # the active orchestrator's pid and host (its state)
        self.host = ""
        self.first: int | None = None  # the first round it followed with its network (it can record it)
        self.kept = 0  # the rows the active one's records hold on disk (its last state)

    @property
    def ready(self) -> bool:
        """It can take over with nothing lost: it has seen the network of a tick and the active one's state, and the
        records on disk reach the first round it followed (every later one it holds)."""
        return (self.round is not None and self.network is not None and self.procs is not None
                and self.first is not None and self.kept >= self.first)

    def on_state(self, msg: dict) -> None:
        """The active orchestrator's ``state`` (decoded): epoch, process table, pace origin, pid and host."""
        if int(msg["epoch"]) < self.epoch:
            return  # a superseded orchestrator's
        self.epoch = int(msg["epoch"])
        self.procs = {("plant" if k == "plant" else int(k)): dict(v) for k, v in msg["procs"].items()}
        self.t_run_wall = msg["t_run_wall"]
        self.kept = max(self.kept, int(msg["kept"]))
        self.pid, self.host = msg.get("pid"), str(msg.get("host", ""))

    def on_tick(self, t: dict) -> None:
        """A tick (decoded): the previous round is committed when the tick names its attempt (recorded once its
        messages are all in: they may come after the tick); takes the network when the tick carries one."""
        epoch = int(t.get("epoch", 0))
        if epoch < self.epoch:
            return
        self.epoch = epoch
        if "rows" in t:
            self.network = (tuple(sorted(int(a) for a in t["alive"])),
                            {int(k): int(v) for k, v in t["incarnation"].items()},
                            tuple(tuple(int(a) for a in g) for g in t["partition"]))
        prev = self.round
        tau = int(t["tau"])
        if prev is not None and tau == prev.tau + 1 and int(t["prev_attempt"]) == prev.attempt and prev.alive is not None:
            self.owed.append(prev)
        alive, inc, part = self.network if self.network is not None else (None, {}, ())
        self.round = FollowedRound(tau, int(t["attempt"]), int(t["prev_attempt"]), int(t["graph"]), bool(t["fresh"]),
                                   bool(t["final"]), int(t["topology"]), alive, inc, part)
        if alive is not None and self.first is None:
            self.first = tau
        self._settle()

    def on_truth(self, tau: int, attempt: int, x: np.ndarray) -> None:
        """The plant's truth (decoded)."""
        self.truths[(int(tau), int(attempt))] = x
        self._settle()

    def on_xhat(self, aid: int, tau: int, attempt: int, incarnation: int, x: np.ndarray, columns: dict,
                lost=(), y=(), u=()) -> None:
        """An agent's estimate (decoded): ``x_i(tau)`` of the round ``attempt`` (an admission estimate, or the result
        of round ``tau - 1``)."""
        if aid in self.index:
            self.xhats.setdefault((int(tau), int(attempt)), {})[aid] = (int(incarnation), x, columns, lost, y, u)
            self._settle()

    def collect(self, r: FollowedRound) -> Collected:
        """What round ``r`` has collected, as the machine collects it (:class:`~.collected.Collected`): its truth,
        each agent's ``x_i(tau)`` (the previous round's result of its committed attempt, or an admission estimate
        of this round) and ``x_i(tau + 1)`` of its attempt, from the agent's incarnation in force."""
        c = Collected(self.index, self.sc.m, self.sc.n, plantless=self.plantless)
        if (r.tau, r.attempt) in self.truths:
            c.put_truth(r.tau, r.attempt, self.truths[(r.tau, r.attempt)], at=(r.tau, r.attempt), in_flight=True)
        for (tau, attempt), by in self.xhats.items():
            if tau == r.tau and attempt == r.prev_attempt:  # the previous round's results, as it collected them
                at = (r.tau - 1, attempt)
            elif (tau == r.tau and attempt <= r.attempt) or (tau == r.tau + 1 and attempt == r.attempt):
                at = (r.tau, r.attempt)  # an admission estimate (a re-run crossed keeps it), this round's results
            else:
                continue
            for aid, (inc, x, columns, lost, y, u) in by.items():
                if inc == r.incarnation.get(aid, 0):
                    c.put_xhat(aid, tau, attempt, x, columns, at=at, in_flight=True, same_incarnation=True, lost=lost,
                               y=y, u=u)
        return c

    @property
    def collected(self) -> Collected:
        """What the round in flight has collected (a takeover hands it to the new machine)."""
        return self.collect(self.round)

    def _settle(self) -> None:
        """Record the owed rounds whose messages are all in (oldest first); forget what is older than they need."""
        while self.owed:
            r = self.owed[0]
            c = self.collect(r)
            if not c.done(r.tau, r.alive, r.final):
                if len(self.owed) <= OWED_ROUNDS:
                    break  # the rest may still come
                self.owed.pop(0)  # never whole (it came before this standby followed): the active one records it
                continue
            self.owed.pop(0)
            row = c.take(r.tau, r.alive)
            alive = sorted(r.alive)
            self.rows.append(Record(r.tau, row.x, row.xhat, row.alive, r.graph, row.columns, attempts=r.attempt + 1,
                                    lost=row.lost, y=tuple((a, row.used.get(a)) for a in alive),
                                    u=tuple((a, row.inputs[a]) for a in alive if row.inputs.get(a) is not None)))
        oldest = (self.owed[0].tau if self.owed else self.round.tau if self.round is not None else 0) - 1
        for buf in (self.truths, self.xhats):
            for tag in [tag for tag in buf if tag[0] < oldest]:
                del buf[tag]

    def rows_from(self, first: int) -> list:
        """The committed rows of event times ``first`` and later (what the records on disk do not hold)."""
        return [r for r in self.rows if r.tau >= first]


def adopt(m, view: Follower, present: set, now: float, *, t_run: float | None = None) -> list:
    """A standby takes over: the round machine ``m`` (:class:`~.machine.RoundMachine`, new) goes on with the run its
    follower ``view`` followed: the round in flight where it was (its messages were collected there), with the
    network, the incarnations and the process table in force; the machine's actions.

    ``present``: ``(role, id, nonce)`` of the tokens up now (a granted process whose token is gone is lost at
    once; the plant's stops the run); ``t_run``: the pace's origin on this process's clock.  The faults of the
    round in flight's event time were applied before its tick: none is left to apply; the network faults of the
    event times up to it are replayed into the network.
    """
    from splitspec_core.scenarios.faults import RESTART, SIGNAL

    r = view.round
    m.started = True
    m.live.last_now = now
    m.t_run = now if t_run is None else t_run
    m.tau, m.attempt, m.prev_attempt = r.tau, r.attempt, r.prev_attempt
    m.fresh_tau = r.tau if r.fresh else None
    m.faults_left = []
    replay = [f for tau in sorted(m.plan.faults) if tau <= r.tau for f in m.plan.faults[tau]
              if f.runtime not in (SIGNAL, RESTART)]
    m.topology.adopt(r.alive, r.incarnation, replay, graph=r.graph)
    m.identity.adopt(view.procs, present, now)
    m.collected = view.collected
    m.phase = Phase.ROUND
    m.round_started = m.quiet_since = now
    m.deadline = now + m.round_timeout
    for a in sorted(m.alive):
        c = m.identity.get("agent", a)
        if c is None or not c.present:
            m.pending_loss[a] = "liveliness lost (the process died or froze)"
    plant = m.identity.get("plant", 0)
    if not m.plantless and (plant is None or not plant.present):
        m.phase = Phase.DONE
        return [Stop(1, f"the plant (pid {m.identity.pid('plant')}) has no liveliness token at the takeover of event "
                        f"time {m.tau}; stopping")]
    return m.on_timer(now)
