"""The orchestrator's rules, without I/O: identity, admission, losses, retries, restarts, faults between rounds.

:class:`RoundMachine` is to the orchestrator what :class:`splitspec_agents.agent.AgentNode`
is to an agent: events in (method calls with already-decoded values and the
current monotonic time ``now``), actions out (a list of small dataclasses the
Zenoh shell in :mod:`splitspec_orchestrator.driver` executes: publish a tick, record a
row, log an event, signal or spawn a process, query statuses, stop).  It
opens no socket and reads no clock, so every rule is unit-tested case by case
(``tests/unit/test_rounds.py``).

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

*Time.*  A gap of more than :data:`STALL_SECONDS` between two calls means
the orchestrator itself was frozen or starved: every deadline moves by the
gap (``orchestrator_stalled``), so nobody is blamed for the orchestrator's
own pause.  The time inside a spawn of its own processes is not such a gap
(:meth:`RoundMachine.on_spawned`): at m = 100 the m + 1 spawns take seconds
on a busy machine, and a warning about them would be a false alarm.

*Between rounds* (at the step the simulator applies them): pending losses,
then the scenario's faults in order (kill, hang, restart, drop/restore an
arc), then agents that came back by hand (a rejoin with a new incarnation).

*Rejections* are counted per (process, reason) and logged as one summary
event per second, never one line per message.

Why one module: the rules act on one state and on each other (a loss during a retry during
a restart, a freeze of the orchestrator itself); split, each part would need the whole state.
"""

from __future__ import annotations

import math
import signal
from dataclasses import dataclass, field

import numpy as np

from splitspec_core.synthesis.survivors import certify_network
from splitspec_core.model.impairment import CAUSES
from splitspec_core.model.network import NetworkState, make_plan

__all__ = ["RoundMachine", "Claim", "STALL_SECONDS", "SUMMARY_SECONDS",
           "Tick", "Record", "Topology", "MarkLost", "Event", "Log", "Signal", "Control", "Spawn", "QueryStatus",
           "ReplyConfig", "ReplyRefused", "RegistryUpdate", "Stop", "Finished"]

STALL_SECONDS = 2.5  #: a gap between calls longer than this is the orchestrator's own freeze
PROBE_SECONDS = 0.3  #: a round with no news for this long: ask every process whether it is alive
PROBE_ANSWER_SECONDS = 0.8  #: ... and give it this long to answer (a busy process answers in milliseconds)
SUMMARY_SECONDS = 1.0  #: rejected messages are summarised once per this many seconds


# ---------------------------------------------------------------------- actions


@dataclass(frozen=True)
class Tick:
    tau: int
    attempt: int
    graph: int
    final: bool
    alive: tuple
    rows: dict
    incarnation: dict
    fresh: bool = True  # someone starts this round with a fresh estimate: every agent sends its z_i(0)
    prev_attempt: int = 0  # the attempt of round tau - 1 whose estimates x_i(tau) are this round's z_i(0)
    partition: tuple = ()  # groups of agent ids of a partition in force (splitspec_core.model.impairment), or ()


@dataclass(frozen=True)
class Record:
    tau: int
    x: np.ndarray
    xhat: np.ndarray
    alive: np.ndarray
    graph: int
    gains: np.ndarray
    attempts: int = 1  # attempts of the round (1 = not re-run)
    rejected: int = 0  # messages rejected since the previous record
    started: float = math.nan  # `now` of the round's first tick (driver clock)
    lost: tuple = ()  # (tau, k, j, i, cause) of every consensus message of the round that did not count
    y: tuple = ()  # live sensors: (agent id, y_i(tau) used or None) of the agents alive

    @property
    def max_error(self) -> float:
        """``max_i |x_i - x|`` over the alive agents (NaN when none is alive)."""
        errs = np.linalg.norm(self.xhat - self.x, axis=1)
        return float(np.nanmax(errs)) if np.isfinite(errs).any() else math.nan  # none alive, or no truth


@dataclass(frozen=True)
class Topology:
    tau: int
    graph_name: str
    alive: tuple
    arcs: tuple
    partition: tuple = ()  # groups of agent ids of a partition in force, or ()


@dataclass(frozen=True)
class MarkLost:
    tau: int
    agent: int


@dataclass(frozen=True)
class Event:
    name: str
    t: float
    fields: dict = field(default_factory=dict)


@dataclass(frozen=True)
class Log:
    level: str  # "info" | "warning"
    message: str


@dataclass(frozen=True)
class Signal:
    """Send ``sig`` to a process on this host (the shell checks it is still a splitspec process)."""
    pid: int
    sig: int


@dataclass(frozen=True)
class Control:
    """Broadcast a control command (``stop``, ``kill agent/<i>``, ``hang agent/<i>``)."""
    cmd: str


@dataclass(frozen=True)
class Spawn:
    """Start a process on this host; the shell answers with :meth:`RoundMachine.on_spawned`."""
    role: str
    ident: int


@dataclass(frozen=True)
class QueryStatus:
    """Query every process's status for ``timeout`` seconds; the shell answers with :meth:`RoundMachine.on_status`."""
    timeout: float = 1.0


@dataclass(frozen=True)
class ReplyConfig:
    ref: object


@dataclass(frozen=True)
class ReplyRefused:
    ref: object
    reason: str
    holder_pid: int
    holder_host: str


@dataclass(frozen=True)
class RegistryUpdate:
    """The process table changed (``RoundMachine.procs``)."""


@dataclass(frozen=True)
class Stop:
    """The run cannot go on: ``message`` is the one line for the user; ``code`` the exit status."""
    code: int
    message: str


@dataclass(frozen=True)
class Finished:
    rounds: int


# ---------------------------------------------------------------------- identity


@dataclass
class Claim:
    """A granted identity: the process (nonce, pid, host) that holds ``role``/``ident``."""
    nonce: str
    pid: int
    host: str
    since: float
    present: bool = False  # its liveliness token is up
    released: bool = False  # token gone, superseded by a restart, or the agent was declared lost

    def live(self, now: float, ttl: float) -> bool:
        return not self.released and (self.present or now - self.since < ttl)


def describe_status(status: int) -> str:
    """``Popen.returncode`` in words: ``exit status 1`` / ``killed by SIGKILL``."""
    if status is None:
        return "still running"
    if status < 0:
        try:
            return f"killed by {signal.Signals(-status).name}"
        except ValueError:
            return f"killed by signal {-status}"
    return f"exit status {status}"


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

    PHASES = ("waiting", "between", "restarting", "pacing", "round", "status", "done")

    def __init__(self, sc, des, *, host: str, wait: float, round_timeout: float, spawned: bool = False,
                 now: float = 0.0):
        self.sc, self.des = sc, des
        self.host, self.wait, self.round_timeout = host, float(wait), float(round_timeout)
        self.spawned = spawned
        #: live sensors (scenario sources:): no plant process, no truth (x recorded as NaN)
        self.plantless = bool(getattr(sc, "sources", None))
        self.dt = sc.run.dt if sc.time == "continuous" else 1.0
        self.index = {a: k for k, a in enumerate(sc.agent_ids)}
        self.plan = make_plan(sc, sc.run.seed, sequence=False)  # O(1) memory: steps may be huge
        self.net = NetworkState(sc)
        self.net.alive[:] = False
        self.alive: set = set()
        self.joinable: set = set()
        self.claims: dict = {}  # (role, ident) -> Claim
        self.procs: dict = {}  # "plant" / agent id -> {"pid", "host"} of the granted process
        self.children: dict = {}  # pid -> (role, ident) of processes this orchestrator spawned
        self.spawn_times: dict = {}  # pid -> when it was spawned, until its liveliness token appears
        self.fresh_tau: int | None = None  # the event time whose round starts a fresh estimate (admission)
        self.prev_attempt = 0  # the attempt that completed the previous round
        self.hung: set = set()  # pids of frozen processes on this host (killed at the end)
        self.pending_loss: dict = {}
        self.phase = "waiting"
        self.started = False
        self.tau = 0
        self.attempt = 0
        self.retried = False
        self.deadline = now + self.wait
        self.restart: tuple | None = None  # (agent id, spawned pid or None)
        self.quiet_since = now  # the round in flight's last news (a message of it, or its tick)
        self.probing = False  # the status query in flight is a probe (not the round timeout's)
        self.faults_left: list = []
        self.truth: dict = {}
        self.est: dict = {}
        self.est_g: dict = {}  # tau -> {agent id: g_i(tau)} from the xhat messages (for Record)
        self.est_y: dict = {}  # tau + 1 -> {agent id: y_i(tau) it used, or None} (live sensors)
        self.sensor_since: dict = {}  # agent id -> event time its live sensor went silent, or None: it is heard
        self.est_lost: dict = {}  # tau + 1 -> {agent id: [k, j, cause, ...]}: what the round of tau did not count
        g_start = float(sc.design.g0) if des.g_mode == "adaptive" else (float(des.g) if des.g is not None else 0.0)
        self.gains = np.full(sc.m, g_start)
        self.last_graph: int | None = None
        self.topology_dirty = True
        self.t_run = None
        self.last_now = now
        self.rejected_total = 0
        self.rejected_recorded = 0  # rejected_total at the last Record
        self.round_started = math.nan  # `now` of the round in flight's first tick (for Record)
        self._rej_pending: dict = {}
        self._rej_last = now
        self._remote: dict = {}
        self.stalled_seconds = 0.0
        self._rows_cache: tuple | None = None  # (NetworkState.key, rows) of the last tick

    # ------------------------------------------------------------------ helpers

    def t(self, tau: int | None = None) -> float:
        return float(self.tau if tau is None else tau) * self.dt

    def incarnation(self, aid: int) -> int:
        return int(self.net.incarnation[self.index[aid]])

    def _who(self, role: str, ident: int) -> str:
        return "the plant" if role == "plant" else f"agent {ident}"

    def _key(self, role: str, ident: int) -> tuple:
        return (role, 0 if role == "plant" else int(ident))

    def reject(self, by: str, reason: str, count: int = 1) -> None:
        """Count ``count`` rejected messages of process ``by`` (summarised once per second)."""
        if count > 0:
            self._rej_pending[(by, reason)] = self._rej_pending.get((by, reason), 0) + count
            self.rejected_total += count

    def remote_counts(self, who: str, counts: dict, incarnation: int = 0) -> None:
        """Another process's running totals of rejections (sent with its truth / xhat); a restarted agent (a
        higher incarnation) counts from 0 again, and the totals of an older incarnation are not taken."""
        inc, prev = self._remote.get(who, (incarnation, {}))
        if incarnation < inc:
            return
        if incarnation > inc:
            prev = {}
        self._remote[who] = (incarnation, prev)
        for reason, c in counts.items():
            if isinstance(c, int) and c > prev.get(reason, 0):
                self.reject(who, str(reason), c - prev.get(reason, 0))
                prev[reason] = c

    def _summaries(self, now: float, force: bool = False) -> list:
        if not self._rej_pending or (not force and now - self._rej_last < SUMMARY_SECONDS):
            return []
        out = [Event("message_rejected", self.t(), {"by": by, "reason": reason, "count": c,
                                                     "seconds": round(now - self._rej_last, 3)})
               for (by, reason), c in sorted(self._rej_pending.items())]
        self._rej_pending.clear()
        self._rej_last = now
        return out

    def next_deadline(self) -> float:
        """When :meth:`on_timer` wants to be called at the latest (the shell polls at least every 0.5 s)."""
        if self.phase == "round":
            return min(self.deadline, self.quiet_since + PROBE_SECONDS)
        return self.deadline

    # ------------------------------------------------------------------ time

    def on_clock(self, now: float) -> list:
        """Every call starts here: detects the orchestrator's own freezes (every deadline moves by the gap)."""
        out = []
        gap = now - self.last_now
        if gap > STALL_SECONDS:
            self.deadline += gap
            self.quiet_since += gap
            if self.t_run is not None:
                self.t_run += gap
            self.stalled_seconds += gap
            for c in self.claims.values():
                c.since += gap
            out.append(Event("orchestrator_stalled", self.t(), {"seconds": round(gap, 3), "tau": self.tau}))
            out.append(Log("warning", f"the orchestrator was frozen or starved for {gap:.1f} s (event time "
                                      f"{self.tau}); nobody is blamed for it, the run goes on"))
        self.last_now = now
        return out + self._summaries(now)

    # ------------------------------------------------------------------ identity

    def on_hello(self, ref, h: dict, now: float) -> list:
        """A process claims an identity (``h``: role, id, pid, host, nonce); reply config or refuse."""
        out = self.on_clock(now)
        role, ident = h["role"], int(h["id"])
        who = self._who(role, ident)
        if role not in ("plant", "agent") or (role == "agent" and ident not in self.index):
            reason = (f"{role} {ident} is not part of this run (agents: "
                      f"{', '.join(map(str, self.sc.agent_ids))})")
            return out + [ReplyRefused(ref, reason, 0, ""), Event("identity_refused", self.t(), {
                "role": role, "id": ident, "pid": h["pid"], "host": h["host"], "reason": reason})]
        key = self._key(role, ident)
        c = self.claims.get(key)
        if c is not None and c.nonce == h["nonce"]:
            return out + [ReplyConfig(ref)]  # the same process asking again
        if c is not None and c.live(now, self.wait):
            reason = f"{who} is held by pid {c.pid} on host {c.host}; refusing a second process for it"
            return out + [
                ReplyRefused(ref, reason, c.pid, c.host),
                Event("duplicate_refused", self.t(), {"role": role, "id": ident, "pid": h["pid"], "host": h["host"],
                                                      "holder_pid": c.pid, "holder_host": c.host}),
                Log("warning", f"refused a second process for {who} (pid {h['pid']} on {h['host']}): held by pid "
                               f"{c.pid} on {c.host}")]
        if role == "plant" and self.plantless:
            reason = "this run has live sensors (scenario sources:): it takes no plant"
            return out + [ReplyRefused(ref, reason, 0, ""), Event("identity_refused", self.t(), {
                "role": role, "id": ident, "pid": h["pid"], "host": h["host"], "reason": reason})]
        if role == "plant" and self.started:
            reason = "the run is under way: the plant must be present from event time 0"
            return out + [ReplyRefused(ref, reason, 0, ""), Event("identity_refused", self.t(), {
                "role": role, "id": ident, "pid": h["pid"], "host": h["host"], "reason": reason})]
        self.claims[key] = Claim(nonce=h["nonce"], pid=int(h["pid"]), host=str(h["host"]), since=now)
        self.procs["plant" if role == "plant" else ident] = {"pid": int(h["pid"]), "host": str(h["host"])}
        return out + [ReplyConfig(ref), RegistryUpdate(),
                      Event("process_started", self.t(), {"role": role, "id": ident, "pid": h["pid"],
                                                          "host": h["host"]})]

    def on_token(self, role: str, ident: int, nonce: str | None, present: bool, now: float) -> list:
        """A liveliness token appeared or disappeared (only the granted claim's token counts)."""
        out = self.on_clock(now)
        key = self._key(role, ident) if role in ("plant", "agent") else None
        c = self.claims.get(key) if key else None
        if c is None or c.nonce != nonce or (c.released and present):
            return out  # an impostor's, a superseded process's or a lost agent's token: ignored
        if present:
            c.present = True
            spawned_at = self.spawn_times.pop(c.pid, None)
            if spawned_at is not None:  # start-up of a process this orchestrator spawned: spawn to ready
                out.append(Event("process_ready", self.t(), {"role": role, "id": ident, "pid": c.pid,
                                                             "startup_s": round(now - spawned_at, 3)}))
            if role == "agent" and self.started and ident not in self.alive:
                self.joinable.add(ident)
                out.append(Log("info", f"agent {ident} is back; it joins at the next event time"))
            return out + self._progress(now)
        if c.released:
            return out
        c.present, c.released = False, True
        if role == "plant":
            if self.started:
                return out + [self._stop_plant("liveliness lost (the process died or froze)")]
            return out + [Event("process_left", self.t(), {"role": "plant", "pid": c.pid}),
                          Log("warning", f"the plant (pid {c.pid} on {c.host}) left during start-up; waiting for "
                                         "another one")]
        self.joinable.discard(ident)
        if ident in self.alive:
            self.pending_loss[ident] = "liveliness lost (the process died or froze)"
            return out + self._progress(now)
        return out

    def _stop_plant(self, why: str) -> Stop:
        pid = self.procs.get("plant", {}).get("pid")
        self.phase = "done"
        return Stop(1, f"the plant (pid {pid}) was lost at event time {self.tau}: {why}; stopping (records up to "
                       f"event time {self.tau - 1} are kept)")

    def on_spawned(self, role: str, ident: int, pid: int, now: float, *, began: float | None = None) -> list:
        """The shell started process ``pid`` for ``role``/``ident``; it began at ``began`` and returned at ``now``.

        The time inside the spawn (fork and exec, seconds when the machine is busy starting the other m
        processes) is the orchestrator's own work, not a freeze: the stall detector looks at the gap
        before ``began`` only, and starts counting again from ``now``.
        """
        out = self.on_clock(began) if began is not None else []
        self.last_now = max(self.last_now, now)
        self.children[int(pid)] = (role, int(ident))
        self.spawn_times[int(pid)] = now
        if self.restart is not None and role == "agent" and self.restart[0] == ident:
            self.restart = (ident, int(pid))
        return out

    def on_child_exit(self, pid: int, status: int, now: float) -> list:
        """A process this orchestrator spawned exited (``status`` as ``Popen.returncode``)."""
        out = self.on_clock(now)
        role, ident = self.children.pop(int(pid), (None, None))
        if role is None:
            return out
        how = describe_status(status)
        who = self._who(role, ident)
        out.append(Event("process_exited", self.t(), {"role": role, "id": ident, "pid": pid, "status": status,
                                                      "how": how}))
        if not self.started:
            self.phase = "done"
            return out + [Stop(1, f"{who} (pid {pid}) exited during start-up ({how}); see its output above")]
        if role == "plant":
            return out + [self._stop_plant(f"the process exited ({how})")]
        c = self.claims.get(("agent", ident))
        if self.restart is not None and self.restart == (ident, pid) and ident not in self.alive:
            return out + self._restart_failed(f"the new process exited ({how})") + self._progress(now)
        if c is not None and c.pid == pid and not c.released:
            c.present, c.released = False, True
            self.joinable.discard(ident)
            if ident in self.alive:
                self.pending_loss[ident] = f"the process exited ({how})"
                return out + self._progress(now)
        return out

    def on_pid_gone(self, role: str, ident: int, pid: int, now: float) -> list:
        """A granted process on this host (not a child) is no longer running, before its token showed."""
        out = self.on_clock(now)
        c = self.claims.get(self._key(role, ident))
        if c is None or c.pid != pid or c.released or c.present:
            return out
        c.released = True
        return out + [Event("process_left", self.t(), {"role": role, "id": ident, "pid": pid}),
                      Log("warning", f"{self._who(role, ident)} (pid {pid}) exited before it was ready; waiting "
                                     "for another one")]

    # ------------------------------------------------------------------ start-up

    def start(self, now: float) -> list:
        """Called once the shell is up: spawn the participants (``spawned``) and wait for them."""
        self.deadline = now + self.wait
        self.last_now = now
        if not self.spawned:
            return []
        return [Spawn("plant", 0)] * (not self.plantless) + [Spawn("agent", a) for a in self.sc.agent_ids]

    def _ready(self) -> bool:
        plant = self.claims.get(("plant", 0))
        return ((self.plantless or (plant is not None and plant.present and not plant.released))
                and all((c := self.claims.get(("agent", a))) is not None and c.present and not c.released
                        for a in self.sc.agent_ids))

    def _missing(self) -> list:
        out = []
        plant = [(("plant", 0), "plant")] * (not self.plantless)
        for key, who in plant + [(("agent", a), f"agent {a}") for a in self.sc.agent_ids]:
            c = self.claims.get(key)
            if c is None or not c.present or c.released:
                out.append(who)
        return out

    # ------------------------------------------------------------------ messages

    def on_truth(self, tau: int, attempt: int, x: np.ndarray, rejected: dict, now: float) -> list:
        out = self.on_clock(now)
        self.remote_counts("plant", rejected)
        if self.phase not in ("round", "status") or attempt != self.attempt or tau != self.tau:
            self.reject("orchestrator", "stale" if (tau, attempt) < (self.tau, self.attempt) else "future")
            return out
        self.truth[tau] = x
        self.quiet_since = now
        return out + self._progress(now)

    def on_xhat(self, aid: int, tau: int, attempt: int, incarnation: int, x: np.ndarray, g: float, rejected: dict,
                now: float, lost=(), y=()) -> list:
        """An agent's estimate (``lost``: flat ``[k, j, cause, ...]`` of the consensus messages it did not count)."""
        out = self.on_clock(now)
        self.remote_counts(f"agent {aid}", rejected, int(incarnation))
        if aid not in self.index:
            self.reject("orchestrator", "wrong_sender")
            return out
        # x_i(tau) does not depend on the attempt (a fresh estimate at admission, else the last round's result):
        # an admission estimate that crosses a re-run still counts; x_i(tau + 1) only from the round in flight
        current = attempt == self.attempt or (tau == self.tau and attempt < self.attempt)
        if (self.phase not in ("round", "status") or not current or incarnation != self.incarnation(aid)
                or tau not in (self.tau, self.tau + 1)):
            ahead = (tau, attempt) > (self.tau + 1, self.attempt)
            self.reject("orchestrator", "future" if ahead else "stale")
            return out
        self.est.setdefault(tau, {})[aid] = x
        self.est_g.setdefault(tau, {})[aid] = g  # g_i(tau), recorded with row tau
        if tau == self.tau + 1:
            self.est_lost.setdefault(tau, {})[aid] = list(lost)
            if self.plantless:
                self.est_y.setdefault(tau, {})[aid] = y
        self.quiet_since = now
        if tau == self.tau + 1:
            self.gains[self.index[aid]] = g
        return out + self._progress(now)

    # ------------------------------------------------------------------ timers and status

    def on_timer(self, now: float) -> list:
        out = self.on_clock(now)
        return out + self._progress(now)

    def on_status(self, answered: set, now: float, *, plant: bool = True) -> list:
        """The answer to :class:`QueryStatus`: agents (ids) whose processes answered, and whether the plant did."""
        out = self.on_clock(now)
        if self.phase != "status":
            return out
        probing, self.probing = self.probing, False
        frozen = sorted(a for a in self.alive if a not in answered)
        late = self._late()
        self.phase = "round"
        if not plant and not self.plantless:
            return out + [self._stop_plant("it does not answer a status query (frozen)")]
        if frozen:
            why = (f"no news of the round for {PROBE_SECONDS:g} s and no answer to a status query within "
                   f"{PROBE_ANSWER_SECONDS:g} s: frozen"
                   if probing else f"round timeout ({self.round_timeout:g} s) and no answer to a status query: frozen")
            for a in frozen:
                self.pending_loss[a] = why
                info = self.procs.get(a)
                if info and info["host"] == self.host:
                    self.hung.add(int(info["pid"]))  # cannot obey the final stop: killed then
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

    def _late(self) -> list:
        final = self.tau == self.plan.steps
        have_next = self.est.get(self.tau + 1, {})
        late = [] if final else sorted(a for a in self.alive if a not in have_next)
        return late or sorted(a for a in self.alive if a not in self.est.get(self.tau, {}))

    # ------------------------------------------------------------------ the network

    def _verdict(self, after: str) -> list:
        v = certify_network(self.des, self.alive, frozenset(self.net.dropped))
        survivors = ", ".join(map(str, v["alive"])) or "none"
        if not v["jointly_observable"]:
            msg = (f"agents {survivors} do NOT jointly observe the system (direction {v['unobservable_direction']} "
                   "is seen by none of them): their estimates cannot converge; the run goes on")
        elif not all(v["strongly_connected"].values()):
            bad = ", ".join(f"graph {g} (agent {j} cannot reach agent {i})" for g, (j, i) in v["unreachable"].items())
            msg = f"the network of agents {survivors} is NOT strongly connected: {bad}; the run goes on"
        elif v["rate_certified"] is False:
            msg = (f"agents {survivors} still jointly observe the system over a strongly connected network, but the "
                   f"designed rate is no longer certified ({v['certificate']}); design with `design.resilience: 1` "
                   "to cover single losses")
        else:
            msg = f"agents {survivors}: still strongly connected and jointly observable; {v['certificate']}"
        self.topology_dirty = True
        return [Event("resilience_verdict", self.t(), {"level": "INFO" if v["ok"] else "WARN",
                                                       "note": f"{after} at event time {self.tau}: {msg}",
                                                       "after": after, "tau": self.tau, **v}),
                Log("info" if v["ok"] else "warning", f"{after} at event time {self.tau}: {msg}")]

    def _lose(self, aid: int, why: str) -> list:
        if not self.net.lose(self.index[aid]):
            return []
        self.alive.discard(aid)
        self.joinable.discard(aid)
        c = self.claims.get(("agent", aid))
        if c is not None:
            c.released = True  # a new process may claim the identity (a rejoin); this one never comes back
        pid = self.procs.get(aid, {}).get("pid")
        return [MarkLost(self.tau, aid),
                Event("agent_lost", self.t(), {"id": aid, "tau": self.tau, "reason": why, "pid": pid}),
                Log("warning", f"agent {aid} lost from event time {self.tau}: {why}")
                ] + self._verdict(f"agent {aid} lost")

    def _admit(self, aid: int, why: str) -> list:
        inc = self.net.rejoin(self.index[aid])
        if inc is None:
            return []
        self.alive.add(aid)
        self.joinable.discard(aid)
        self.fresh_tau = self.tau  # its neighbours need its z(0): every agent sends z(0) in this round
        if self.des.g_mode == "adaptive":
            self.gains[self.index[aid]] = float(self.sc.design.g0)  # a fresh estimate starts from g0 again
        pid = self.procs.get(aid, {}).get("pid")
        return [Event("agent_rejoined", self.t(), {"id": aid, "tau": self.tau, "incarnation": inc, "reason": why,
                                                   "pid": pid}),
                Log("info", f"agent {aid} rejoins at event time {self.tau} with a fresh estimate (incarnation {inc}): "
                            f"{why}")] + self._verdict(f"agent {aid} rejoined")

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
            if self.phase == "waiting":
                if self._ready():
                    out += self._begin(now)
                    continue
                if now >= self.deadline:
                    self.phase = "done"
                    return out + [Stop(1, f"waited {self.wait:g} s for {', '.join(self._missing())} to connect")]
                return out
            if self.phase == "between":
                out += self._between(now)
                if self.phase == "between":
                    continue
                if self.phase == "done":
                    return out
                continue
            if self.phase == "restarting":
                aid, pid = self.restart
                if aid in self.joinable:
                    self.restart = None
                    out += self._admit(aid, "restarted by the scenario")
                    self.phase = "between"
                    continue
                if now >= self.deadline:
                    out += self._restart_failed(f"no liveliness token within {self.wait:g} s")
                    continue
                return out
            if self.phase == "pacing":
                if now >= self.deadline:
                    out += self._start_round(now)
                    continue
                if self.pending_loss:
                    lost_out, _ = self._apply_pending_losses()
                    out += lost_out
                return out
            if self.phase == "round":
                if self.pending_loss:
                    lost_out, lost = self._apply_pending_losses()
                    out += lost_out
                    if lost:
                        out += self._rerun(now)
                        continue
                if self._round_done():
                    out += self._complete(now)
                    continue
                if now >= self.deadline:
                    if self.tau not in self.truth and not self.plantless:
                        self.phase = "done"
                        return out + [Stop(1, f"no truth from the plant for event time {self.tau} within "
                                              f"{self.round_timeout:g} s")]
                    self.phase = "status"
                    return out + [QueryStatus()]
                if now >= self.quiet_since + PROBE_SECONDS:
                    self.phase, self.probing = "status", True
                    return out + [QueryStatus(PROBE_ANSWER_SECONDS)]
                return out
            return out  # status (waiting for on_status) or done
        raise RuntimeError("round machine made no progress")  # pragma: no cover - a bug, not an input

    def _begin(self, now: float) -> list:
        self.started = True
        self.fresh_tau = 0
        self.net.alive[:] = True
        self.alive = set(self.sc.agent_ids)
        self.joinable.clear()
        self.t_run = now
        self.tau = 0
        self.faults_left = list(self.plan.faults.get(0, ()))
        self.phase = "between"
        return [Event("run_started", 0.0, {"agents": list(self.sc.agent_ids), "steps": self.plan.steps})]

    def _between(self, now: float) -> list:
        """Pending losses, then the faults due at tau (one at a time: a restart waits), then admissions."""
        out, _ = self._apply_pending_losses()
        t = self.t()
        while self.faults_left:
            f = self.faults_left.pop(0)
            if f.action in ("kill", "hang"):
                if f.agent not in self.alive:
                    out.append(Event("fault_skipped", t, {"action": f.action, "id": f.agent,
                                                          "reason": "agent not alive"}))
                    continue
                how, acts = self._signal_agent(f.agent, f.action)
                out += acts
                out += self._lose(f.agent, f"{'killed' if f.action == 'kill' else 'hung'} by the scenario ({how})")
            elif f.action == "restart":
                if f.agent in self.alive:
                    out.append(Event("fault_skipped", t, {"action": "restart", "id": f.agent,
                                                          "reason": "agent is alive"}))
                    continue
                return out + self._begin_restart(f.agent, now)
            elif f.action in ("partition", "heal"):  # no consensus message crosses between the groups
                self.net.apply([f])
                if f.action == "partition":
                    groups = [list(g) for g in f.groups]
                    out.append(Event("partition", t, {"groups": groups, "tau": self.tau}))
                    out.append(Log("warning", f"event time {self.tau}: partition {groups}: no consensus message "
                                              "crosses between the groups until a heal"))
                else:
                    out.append(Event("healed", t, {"tau": self.tau}))
                    out.append(Log("info", f"event time {self.tau}: the partition is healed"))
                self.topology_dirty = True
            else:  # drop_arc / restore_arc: the simulator's own bookkeeping
                self.net.apply([f])
                arc = tuple(f.arc)
                dropped = f.action == "drop_arc"
                out.append(Event("arc_dropped" if dropped else "arc_restored", t, {"arc": list(arc), "tau": self.tau}))
                out += self._verdict(f"arc {arc[0]} -> {arc[1]} {'dropped' if dropped else 'restored'}")
        for a in sorted(self.joinable - self.alive):
            out += self._admit(a, "started by hand")
        if self.sc.run.pace:
            self.phase = "pacing"
            self.deadline = self.t_run + self.tau / self.sc.run.pace
            return out
        return out + self._start_round(now)

    def _signal_agent(self, aid: int, action: str) -> tuple:
        sig = signal.SIGKILL if action == "kill" else signal.SIGSTOP
        info = self.procs.get(aid)
        if info and info["host"] == self.host:
            if action == "hang":
                self.hung.add(int(info["pid"]))
            return f"{signal.Signals(sig).name} to pid {info['pid']}", [Signal(int(info["pid"]), int(sig))]
        # another host (or unknown pid): the agent signals itself
        where = info["host"] if info else "an unknown host"
        return f"asked agent {aid} on {where} to {action} itself", [Control(f"{action} agent/{aid}")]

    def _begin_restart(self, aid: int, now: float) -> list:
        out = []
        c = self.claims.get(("agent", aid))
        if c is not None and not c.released and c.present:
            # the old process still holds its token (hung, or its death not yet seen): kill it; its claim is
            # superseded now, so its token can neither block nor be confused with the new one
            how, acts = self._signal_agent(aid, "kill")
            self.hung.discard(c.pid)
            out += acts + [Log("info", f"restart of agent {aid}: killed the old process ({how})")]
        if c is not None:
            c.released = True
        self.joinable.discard(aid)
        self.restart = (aid, None)
        self.phase = "restarting"
        self.deadline = now + self.wait
        out.append(Event("agent_restarting", self.t(), {"id": aid, "tau": self.tau}))
        return out + [Spawn("agent", aid)]

    def _restart_failed(self, why: str) -> list:
        aid = self.restart[0]
        self.restart = None
        self.phase = "between"
        return [Event("restart_failed", self.t(), {"id": aid, "tau": self.tau, "reason": why}),
                Log("warning", f"restart of agent {aid} at event time {self.tau} failed: {why}; the run goes on "
                               "without it")]

    def _start_round(self, now: float) -> list:
        self.phase = "round"
        self.attempt = 0
        self.retried = False
        self.round_started = now
        return self._tick(now)

    def _rerun(self, now: float) -> list:
        self.est.pop(self.tau + 1, None)
        self.est_y.pop(self.tau + 1, None)
        self.est_lost.pop(self.tau + 1, None)
        self.attempt += 1
        self.phase = "round"
        return self._tick(now)

    def _tick(self, now: float) -> list:
        out = []
        graph = self.plan.graph_at(self.tau)
        if graph != self.last_graph or self.topology_dirty:
            name = self.sc.graph_names[graph]
            if self.last_graph is not None and graph != self.last_graph:
                out.append(Event("graph_switched", self.t(), {"graph": name,
                                                              "previous": self.sc.graph_names[self.last_graph]}))
            out.append(Topology(self.tau, name, tuple(sorted(self.alive)), tuple(self.net.arcs(self.sc, graph)),
                                partition=tuple(self.net.groups or ())))
            self.last_graph, self.topology_dirty = graph, False
        self.deadline = now + self.round_timeout
        self.quiet_since = now
        out.append(Tick(self.tau, self.attempt, graph, self.tau == self.plan.steps, tuple(sorted(self.alive)),
                        self._rows(graph), {a: self.incarnation(a) for a in self.sc.agent_ids},
                        fresh=self.fresh_tau == self.tau, prev_attempt=self.prev_attempt,
                        partition=self.net.groups or ()))
        return out

    def _rows(self, graph: int) -> dict:
        """The tick's consensus rows of the active network, computed again only when it changed (a graph
        switch, a loss, a rejoin, an arc): building S is O(m) and the network changes rarely."""
        key = self.net.key(graph)
        if self._rows_cache is None or self._rows_cache[0] != key:
            self._rows_cache = (key, self.net.rows(self.sc, graph))
        return self._rows_cache[1]

    def _round_done(self) -> bool:
        if self.tau not in self.truth and not self.plantless:
            return False
        have_now = self.est.get(self.tau, {})
        have_next = self.est.get(self.tau + 1, {})
        final = self.tau == self.plan.steps
        n = len(self.alive)
        if len(have_now) < n or (not final and len(have_next) < n):
            return False  # O(1) for all but the last estimates of a round (called on every one of the m)
        return all(a in have_now for a in self.alive) and (final or all(a in have_next for a in self.alive))

    def _complete(self, now: float) -> list:
        sc = self.sc
        xh = np.full((sc.m, sc.n), np.nan)
        mask = np.zeros(sc.m, dtype=bool)
        for a in self.alive:
            xh[self.index[a]] = self.est[self.tau][a]
            mask[self.index[a]] = True
        gains = np.full(sc.m, np.nan)
        for a, g in self.est_g.pop(self.tau, {}).items():
            if a in self.alive:
                gains[self.index[a]] = float(g)
        rejected, self.rejected_recorded = self.rejected_total - self.rejected_recorded, self.rejected_total
        lost = tuple((self.tau, t[0], t[1], a, t[2]) for a, flat in sorted(self.est_lost.pop(self.tau + 1, {}).items())
                     if a in self.alive for t in zip(flat[0::3], flat[1::3], flat[2::3]))
        x = self.truth[self.tau] if not self.plantless else np.full(sc.n, np.nan)  # live sensors: x unknown
        used = self.est_y.pop(self.tau + 1, {})
        out = [Record(self.tau, x, xh, mask, self.plan.graph_at(self.tau), gains, attempts=self.attempt + 1,
                      rejected=rejected, started=self.round_started, lost=lost,
                      y=tuple((a, used.get(a)) for a in sorted(self.alive)))]
        if self.plantless and self.tau < self.plan.steps:  # the last tick takes no measurement
            out += self._sensor_events(used)
        if lost:  # one line per event time, never one per message
            by = {c: sum(1 for r in lost if r[4] == k) for k, c in enumerate(CAUSES)}
            out.append(Event("messages_lost", self.t(), {"tau": self.tau, "count": len(lost),
                                                         **{c: v for c, v in by.items() if v}}))
        self.truth.pop(self.tau, None)
        self.est.pop(self.tau, None)
        if self.tau == self.plan.steps:
            self.phase = "done"
            return out + self._summaries(now, force=True) + [Finished(self.plan.steps)]
        self.prev_attempt = self.attempt  # its estimates x_i(tau + 1) start the next round
        self.tau += 1
        self.faults_left = list(self.plan.faults.get(self.tau, ()))
        self.phase = "between"
        return out

    def _sensor_events(self, used: dict) -> list:
        """A live sensor heard before that gave its agent no measurement (``sensor_lost``), and its return
        (``sensor_back``): one event per change, not per event time (the per-row truth is ``y_missing``)."""
        out = []
        for a in sorted(self.alive):
            heard = used.get(a) is not None
            if a not in self.sensor_since:  # nothing to say until the sensor is first heard
                if heard:
                    self.sensor_since[a] = None
                continue
            silent_since = self.sensor_since[a]
            if silent_since is None and not heard:
                self.sensor_since[a] = self.tau
                out.append(Event("sensor_lost", self.t(), {"agent": a, "tau": self.tau}))
            elif silent_since is not None and heard:
                self.sensor_since[a] = None
                out.append(Event("sensor_back", self.t(), {"agent": a, "tau": self.tau,
                                                           "silent": self.tau - silent_since}))
        return out

    def finish_summaries(self, now: float) -> list:
        """Rejections not yet summarised (at the end of a run, whatever ended it)."""
        return self._summaries(now, force=True)

    @property
    def finished(self) -> bool:
        return self.phase == "done"

