"""The orchestrator's process shell: Zenoh, the recorder, child processes; the rules are in :mod:`.rounds`.

``splitspec orchestrator SCENARIO --listen ENDPOINT --out DIR [--run-id ID]``

This module only moves things between the world and
:class:`splitspec_orchestrator.rounds.machine.RoundMachine`: it decodes messages (MAC, schema,
shapes) and hands their values to the machine, and executes the machine's
actions (:mod:`.rounds.actions`: publish a tick, record, log, signal, spawn, query statuses, stop).
What it does, through the machine:

* opens Zenoh as a router on ENDPOINT (no external router needed), or as a
  client of an external router with ``--connect``;
* answers ``config`` queries with the scenario and the centralised part of
  the design (g or q); each query carries a ``hello`` (role, id, pid, host),
  logged as ``process_started``;
* waits until the plant and every agent hold their liveliness token, then
  runs event times ``0..steps``: tick (active graph restricted to the alive
  agents, with the weights), collect ``truth(tau)`` and every alive agent's
  ``xhat(tau+1)``, record, next tick.  An agent whose token disappears (or
  that misses the round timeout) is lost from that event time on and the
  round in flight is re-run without it (a higher ``attempt``);
* executes the scenario's faults between rounds, at the step the simulator
  applies them (:func:`splitspec_core.model.network.fault_step`): ``kill`` sends
  SIGKILL and ``freeze`` SIGSTOP to the agent's process (or, for a process on
  another host, asks it to do so to itself), both lost from that event time;
  ``restart`` spawns a new agent process and admits it with a fresh estimate
  once its token appears; ``drop_arc``/``restore_arc`` change the links;
* admits at the next event time any agent that (re)appears by hand after a
  loss (``splitspec agent --id I --connect ...``), with a new incarnation;
* after every change of the network, logs the resilience verdict
  (:func:`splitspec_core.synthesis.survivors.certify_network`): still strongly connected,
  jointly observable, and is the rate still certified by the designed g or q;
* records ``trajectory.npz``, ``events.jsonl``, ``run.rrd`` and a copy of the
  scenario (``scenario.yaml``), so that ``splitspec simulate scenario.yaml
  --faults-from events.jsonl`` replays the run.

Why one module: it is the one place that touches the orchestrator's Zenoh session; every
function decodes one kind of message or executes one kind of action, none holds a rule.
"""

from __future__ import annotations

import argparse
import logging
import math
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from splitspec_core.synthesis.design_cache import cached_design as design
from splitspec_core.synthesis.whole_state import agent_gain as central_gain
from splitspec_core.synthesis.bad_data import agent_config, bad_data
from splitspec_core.model.screening import Watch
from splitspec_core.errors import SplitspecError
from splitspec_core.model.network import given_measurements
from splitspec_core.model.rows import REPORTED, run_columns
from splitspec_core.scenarios.faults import PLANT
from splitspec_core.scenarios.load import load_scenario, read_scenario_text, resolved_scenario_text
from splitspec_core.runtime.cli import EVENTS_LOGGER
from splitspec_core.runtime.node import settle_heap
from splitspec_core.runtime.ticks import TickEncoder
from splitspec_core.runtime.wire import Keys, WireError, decode, encode, new_run_key

from .rounds import actions as A
from .rounds.machine import RoundMachine
from .rounds.tally import RunTally
from .records.outdir import OutputDirError, check_output_dir
from .records.events import event_text

log = logging.getLogger("splitspec.orchestrator")
told = logging.getLogger(EVENTS_LOGGER)  # the run's events: `splitspec run`'s terminal shows them (--log-level events)

EXIT_OK, EXIT_FAILED, EXIT_INTERRUPTED = 0, 1, 130
POLL_SECONDS = 0.5  # the event loop wakes at least this often (timers, child processes, stall detection)
#: children are polled (one waitpid each) at most this often: the loop turns once per message or two, and m + 1
#: waitpids per turn were m (m + 1) per round (6% of the orchestrator at m = 100); their liveliness tokens
#: still report a death at once
CHILD_POLL_SECONDS = 0.05
#: a child's token goes when its sockets close, a moment before its exit can be reaped: how long the loop waits for
#: the exit status of a child whose token went, so its loss says how it ended (``killed by SIGKILL``)
EXIT_GRACE_SECONDS = 0.5


class RunFailed(SplitspecError, RuntimeError):
    """The run cannot go on (plant lost, participants missing, ...)."""


class Superseded(RunFailed):
    """A standby took the run over while this orchestrator was cut off (a higher epoch holds the records)."""


EXIT_SUPERSEDED = 4  #: an orchestrator that found its run taken over by a standby (it wrote nothing more)


class Progress:
    """One status line on a terminal: event time, max error (without truth: the consensus disagreement,
    :func:`~splitspec_orchestrator.viewer.reference_view.progress_text`), alive agents, rounds per second."""

    def __init__(self, steps: int | None, m: int):
        self.enabled = sys.stderr.isatty()
        self.steps, self.m = steps, m
        self.t0 = self.last = time.monotonic()

    def update(self, tau: int, max_err: float, alive: int, *, force: bool = False, xhat=None,
               alive_mask=None) -> None:
        if not self.enabled:
            return
        now = time.monotonic()
        if now - self.last < 0.25 and not force:
            return
        from .viewer.reference_view import progress_text

        figure = f"max error {max_err:9.3e}" if xhat is None else progress_text(max_err, xhat, alive_mask)
        self.last = now
        rps = tau / max(now - self.t0, 1e-9)
        total = "" if self.steps is None else f"/{self.steps}"
        sys.stderr.write(f"\revent {tau:>6}{total}  {figure}  alive {alive}/{self.m}  "
                         f"{rps:7.1f} rounds/s ")
        if force:
            sys.stderr.write("\n")
        sys.stderr.flush()


HOST = socket.gethostname()


def local_endpoint(endpoint: str) -> str:
    """An endpoint a process on this machine can connect to (``0.0.0.0`` / ``[::]`` -> loopback)."""
    return endpoint.replace("/0.0.0.0:", "/127.0.0.1:").replace("/[::]:", "/[::1]:")


def _is_splitspec_process(pid: int) -> bool:
    """A live (not zombie) splitspec process of this user: the guard against pid reuse before signalling."""
    from .registry import is_own_splitspec_process

    return is_own_splitspec_process(int(pid))


def _columns_and_watch(des) -> tuple:
    """The reported row columns a run of ``des`` records, and the agents' sensor watch
    (:class:`splitspec_core.model.screening.Watch`) when the design tests their measurements (``design.bad_data``:
    the agents' test, :func:`~splitspec_core.synthesis.bad_data.agent_config`, rides on their config), else None."""
    bd = bad_data(des)
    columns = run_columns(has_g=not des.two_rate, bad_data=bd is not None)
    return columns, None if bd is None else Watch(bd, des.scenario.agent_ids)


def _sensor_events(rec, watch: Watch | None, sc, a) -> None:
    """The ``sensor_suspect`` / ``sensor_restored`` events of the round of ``a.tau`` (a ``Record``), from the agents'
    reported ``y_statistic`` replayed through their watch (:class:`splitspec_core.model.screening.Watch`)."""
    if watch is None:
        return
    t = a.tau * sc.run.dt if sc.time == "continuous" else float(a.tau)
    for _, agent, event, d, threshold in watch.row(a.tau, a.alive, a.columns["y_statistic"]):
        fields = {"agent": int(agent), "statistic": float(d), "threshold": float(threshold)}
        rec.event(event, t, **fields)
        told.log(logging.WARNING if event == "sensor_suspect" else logging.INFO, "event time %d: %s", a.tau,
                 event_text(event, fields))  # set aside: a warning; taken back: news


def _used(msg: dict) -> dict:
    """What an ``xhat`` says its round used: the consensus messages it did not count (``lost``), the measurement
    (``y``) and the live known inputs (``u``)."""
    return {"lost": msg["lost"], "y": msg["y"], "u": msg["u"]}


def _live_records(rec, sc, a) -> None:
    """Live sensors: the ``y_i`` the agents used in the round of ``a.tau`` (a ``Record``) and, with live known
    inputs, the ``u`` they took, to the recorder before the row; an ``inputs_differ`` event when agents took
    different ones (the records' ``u`` is the first agent's: the others' rows do not replay exactly)."""
    if not sc.sources:
        return
    rec.live_y(a.tau, a.y)
    if sc.input_source is None:
        return
    recorded, others = rec.live_u(a.tau, a.u)
    if not others:
        return
    t = a.tau * sc.run.dt if sc.time == "continuous" else float(a.tau)
    fields = {"tau": int(a.tau), "recorded": int(recorded), "agents": [int(i) for i in others]}
    rec.event("inputs_differ", t, level="WARN", **fields)
    told.warning("event time %d: %s", a.tau, event_text("inputs_differ", fields))


def _check_sensor_faults(sc) -> None:
    """A scenario's sensor faults are applied by the plant process: live sensors (``sources:``) have none."""
    sensor_faults = sorted({f.action for f in sc.faults if f.runtime == PLANT})
    if sc.sources and sensor_faults:
        raise SplitspecError(f"this scenario's {', '.join(sensor_faults)} faults are applied by the plant process, "
                             "and its live sensors (sources:) publish without one: drop them, or corrupt a "
                             "recorded log with simulate --measurements")


class Orchestrator:
    """The shell around :class:`~splitspec_orchestrator.rounds.machine.RoundMachine`.  ``run()`` returns the process exit code."""

    def __init__(self, scenario_path: str | None, *, out: Path, run_id: str, listen: str | None, connect: str | None,
                 wait: float | None = None, round_timeout: float = 10.0, viewer: str | None = None,
                 security=None, spawn_local: bool = False, measurements: str | None = None,
                 scenario_text: str | None = None, epoch: int = 1, standby: bool | None = None):
        if scenario_text is not None:  # a standby's: the run's scenario as its orchestrator sent it
            from splitspec_core.scenarios.load import parse_scenario_text

            self.scenario_text = scenario_text
            self.sc = parse_scenario_text(scenario_text, source="the run's scenario")
        else:
            # the processes (and scenario.yaml in the records) get the scenario with system.file's arrays written in
            self.scenario_text = resolved_scenario_text(Path(scenario_path), read_scenario_text(scenario_path))
            self.sc = load_scenario(scenario_path)
        self.epoch = int(epoch)  # 1, and one more at each takeover (fencing: every tick and control carries it)
        #: a standby follows (or may follow) this run: the processes it starts outlive it, its state is published
        self.standby = bool(self.sc.run.standby if standby is None else standby)
        self.des = design(self.sc)
        self.columns, self.watch = _columns_and_watch(self.des)  # the row columns it records; bad data's watch
        self.meas, self.measurements_path = None, measurements
        if measurements is not None and self.sc.sources:
            raise SplitspecError("--measurements replaces the plant, and this scenario has live sensors (sources:) "
                                 "and no plant: drop one (simulate --measurements plays a file for such a scenario)")
        _check_sensor_faults(self.sc)
        if measurements is not None:  # the plant plays the user's file; the file decides the steps
            import dataclasses

            from splitspec_core.scenarios.measurements import load_measurements

            self.meas = load_measurements(measurements, self.sc)
            self.sc = dataclasses.replace(self.sc, run=dataclasses.replace(self.sc.run, steps=self.meas.steps))
        self.keys = Keys(run_id)
        self.out = out
        self.listen, self.connect = listen, connect
        from splitspec_core.runtime.cli import default_wait

        self.wait = default_wait(self.sc.m) if wait is None else wait
        self.round_timeout = round_timeout
        self.viewer = viewer
        self.security = security  # splitspec_core.runtime.security.Credentials or None
        self.spawn_local = spawn_local
        self.key = new_run_key()
        self.ticks = TickEncoder(self.keys.run_id, mac_key=self.key, epoch=self.epoch)  # the network when it changed
        self.takeover = None  # a standby's: (its follower's view, what it knew at the loss); see run()
        from .takeover import StandbyLink

        self.link = StandbyLink(self)  # its side of its standbys: their hellos and tokens, its state for them
        self.stop_requested = False
        self.stop_signal: str | None = None  # the signal that asked a run until stopped to stop
        self.children: dict = {}  # pid -> Popen (or forks.ForkedProcess) of the processes this orchestrator started
        self.forks = None  # the agent fork server of a local run (forks.ForkServer), started with the run

    # ------------------------------------------------------------------ set-up

    def _open(self) -> None:
        from splitspec_core.runtime.bus import Inbox, lease_ms_for, open_session

        if getattr(self, "session", None) is not None:  # a standby's, already following the run
            self._declare()
            return
        kw: dict = {"lease_ms": lease_ms_for("orchestrator")}
        if self.security is not None:  # authentication + access control on the embedded router
            sensors = self.sc.sensor_keys  # the agents' sensors and the live inputs' publisher (sensor-inputs)
            kw["extra"] = self.security.router_extra(self.keys.run_id, self.sc.agent_ids, sensors)
        if self.connect:
            if self.security is not None:  # a run's own router (a run with a standby): its orchestrator user
                from splitspec_core.runtime.security import read_credentials

                kw.pop("extra", None)
                kw["user"], kw["password"] = read_credentials(self.security.credentials_file("orchestrator"))
            self.session = open_session("client", connect=[self.connect], **kw)
        else:
            self.session = open_session("router", listen=[self.listen], **kw)
        self.inbox = Inbox(self.session)
        self.inbox.mac_key = self.key
        self.inbox.watch_liveliness(self.keys.alive_all, "alive")
        self.inbox.subscribe(self.keys.truth, "truth")
        self.inbox.subscribe(f"{self.keys.prefix}/xhat/*", "xhat")
        self._declare()

    def _declare(self) -> None:
        """The active orchestrator's part of the session: the config queryable, its publishers and its token
        (its epoch is the token's id)."""
        import zenoh

        self.inbox.serve_deferred(self.keys.config, "hello")
        block = zenoh.CongestionControl.BLOCK
        self.pub_tick = self.session.declare_publisher(self.keys.tick, congestion_control=block)
        self.pub_control = self.session.declare_publisher(self.keys.control, congestion_control=block)
        self.pub_state = self.session.declare_publisher(self.keys.state, congestion_control=block)
        self.token = self.session.liveliness().declare_token(self.keys.alive("orchestrator", self.epoch))

    # ------------------------------------------------------------------ inputs -> machine

    def _handle(self, item, now: float) -> list:
        """One inbox item -> the machine's actions."""
        m = self.machine
        channel, key, payload = item
        if channel == "alive":
            member = self.keys.parse_member(key)
            if member is not None and member[0] == "standby":
                return self.link.token(member[2], payload == "put", ready=member[1] == 1)
            if member is None or member[0] not in ("plant", "agent"):
                return []
            if payload != "put" and self.standby and self.link.held_by_another():
                raise Superseded(self.superseded)  # cut off: the tokens went with the link, not the processes
            role, ident, nonce = member
            gone = [] if payload == "put" else self._exit_status(role, ident, nonce)
            return gone + m.on_token(role, ident, nonce, payload == "put", now)
        if channel == "hello":
            query = payload
            raw = query.payload.to_bytes() if query.payload is not None else b""
            try:
                h = decode(raw, self.keys.run_id, "hello")
            except WireError as e:
                m.reject("orchestrator", e.reason)
                query.drop()  # no answer: not a hello of this run
                return []
            if h["role"] == "standby":
                _reply(query, self.link.hello(h))
                return []
            return m.on_hello(query, h, now)
        if channel == "truth":
            try:
                msg = decode(payload, self.keys.run_id, "truth", mac_key=self.key)
                if msg["x"].shape == (0,) and self.meas is not None and self.meas.x is None:
                    msg["x"] = np.full(self.sc.n, np.nan)  # measurements without truth: x unknown
                if msg["x"].shape != (self.sc.n,):
                    raise WireError("bad_shape", "truth")
            except WireError as e:
                m.reject("orchestrator", e.reason)
                return []
            return m.on_truth(msg["tau"], msg["attempt"], msg["x"], msg["rejected"], now)
        if channel == "xhat":
            try:
                msg = decode(payload, self.keys.run_id, "xhat", mac_key=self.key)
                if str(msg["agent"]) != Keys.last(key):
                    raise WireError("wrong_sender", key)
                if msg["x"].shape != (self.sc.n,):
                    raise WireError("bad_shape", "xhat")
            except WireError as e:
                m.reject("orchestrator", e.reason)
                return []
            return m.on_xhat(msg["agent"], msg["tau"], msg["attempt"], msg["incarnation"], msg["x"],
                             {c.name: msg[c.name] for c in REPORTED}, msg["rejected"], now, **_used(msg))
        if channel == "signal":
            self.stop_requested = True
        return []  # a standby's own channels (tick, state, control) after its takeover: nothing to do

    def _exit_status(self, role: str, ident: int, nonce: str | None) -> list:
        """The token of a granted process went: if this orchestrator started it, its exit status first (waited for
        up to :data:`EXIT_GRACE_SECONDS`), so it is lost as ``the process exited (killed by SIGKILL)``; a process it
        did not start (another host, by hand), or one still running, is known by its liveliness alone."""
        c = self.machine.claims.get((role, 0 if role == "plant" else int(ident)))
        p = None if c is None or c.nonce != nonce or c.released else self.children.get(c.pid)
        if p is None:
            return []
        try:
            status = p.wait(timeout=EXIT_GRACE_SECONDS)
        except subprocess.TimeoutExpired:
            return []  # still running: its token went with its link
        del self.children[c.pid]
        return self.machine.on_child_exit(c.pid, status, time.monotonic())

    def _poll_processes(self, now: float) -> list:
        """Children that exited; granted processes on this host that vanished before showing a token."""
        out = []
        if now >= self._next_child_poll:  # a waitpid per child: at most every CHILD_POLL_SECONDS, not per message
            self._next_child_poll = now + CHILD_POLL_SECONDS
            for pid, p in list(self.children.items()):
                if p.poll() is not None:
                    del self.children[pid]
                    out += self.machine.on_child_exit(pid, p.returncode, now)
        if not self.machine.started:
            from .registry import pid_running

            for (role, ident), c in list(self.machine.claims.items()):
                if (not c.present and not c.released and c.host == HOST and c.pid not in self.children
                        and not pid_running(c.pid)):
                    out += self.machine.on_pid_gone(role, ident, c.pid, now)
        dropped = self.inbox.take_dropped()  # what the callbacks refused (bad MAC, full inbox)
        for reason, total in dropped.items():
            prev = self._dropped_seen.get(reason, 0)
            if total > prev:
                self.machine.reject("orchestrator", reason, total - prev)
                self._dropped_seen[reason] = total
        return out

    # ------------------------------------------------------------------ actions

    def _execute(self, actions: list) -> None:
        for a in actions:
            kind = type(a)
            if kind is A.Tick:
                if self.takeover is not None:
                    from .takeover import took_over

                    took_over(self, a.tau)
                self.pub_tick.put(self.ticks.encode(
                    tau=a.tau, attempt=a.attempt, graph=a.graph, final=a.final, fresh=a.fresh,
                    prev_attempt=a.prev_attempt, alive=a.alive, rows=a.rows, incarnation=a.incarnation,
                    partition=a.partition))
            elif kind is A.Record:
                if a.tau < self.first_row:  # a standby's takeover: the dead orchestrator's records hold it
                    continue
                _live_records(self.rec, self.sc, a)  # before the row: a flush in between writes both
                columns = {k: v for k, v in a.columns.items() if k in self.columns}  # this run's (rows.run_columns)
                self.rec.row(a.tau, a.x, a.xhat, a.alive, a.graph, **columns, attempts=a.attempts,
                             rejected=a.rejected, wall_ms=(time.monotonic() - a.started) * 1e3, lost=a.lost,
                             late_ms=a.late * 1e3 if math.isfinite(a.late) else None)
                self.tally.record(a)
                _sensor_events(self.rec, self.watch, self.sc, a)  # what the agents decided in the round of a.tau
                self.progress.update(a.tau, a.max_error, int(a.alive.sum()), force=a.tau == self.machine.plan.steps,
                                     xhat=a.xhat, alive_mask=a.alive)
            elif kind is A.Event:
                self.tally.event(a)
                self.rec.event(a.name, a.t, level=a.level, **a.fields)
            elif kind is A.Log:
                told.log(logging.WARNING if a.level == "warning" else logging.INFO, "%s", a.message)
            elif kind is A.Topology:
                self.rec.topology(a.tau, a.graph_name, list(a.alive), list(a.arcs), partition=a.partition)
            elif kind is A.MarkLost:
                self.rec.mark_lost(a.tau, a.agent)
            elif kind is A.ReplyConfig:
                _reply(a.ref, _config(self, a))
            elif kind is A.ReplyRefused:
                _reply(a.ref, encode("refused", self.keys.run_id, reason=a.reason, holder_pid=a.holder_pid,
                                     holder_host=a.holder_host))
            elif kind is A.RegistryUpdate:
                self.registry.data["agents"] = {str(k): v for k, v in self.machine.procs.items() if k != "plant"}
                if "plant" in self.machine.procs:
                    self.registry.data["plant"] = self.machine.procs["plant"]
                self.registry.update()
                self.link.next_state = 0.0  # a standby learns the new process table at once
            elif kind is A.Signal:
                if _is_splitspec_process(a.pid):
                    try:
                        os.kill(a.pid, a.sig)
                    except ProcessLookupError:
                        pass
            elif kind is A.Control:
                self.pub_control.put(encode("control", self.keys.run_id, mac_key=self.key, cmd=a.cmd,
                                            epoch=self.epoch))
            elif kind is A.Spawn:
                began = time.monotonic()
                p = _spawn(self, a.role, a.ident)
                self._execute(self.machine.on_spawned(a.role, a.ident, p.pid, time.monotonic(), began=began))
            elif kind is A.QueryStatus:
                agents, plant = _answering(self, a.timeout)
                if self.standby and not agents and not plant:  # nobody answers: this one is cut off, not they
                    self.superseded = (f"this orchestrator (epoch {self.epoch}) hears none of the run's processes: "
                                       "it is cut off and a standby takes the run over; it stands down and writes "
                                       "nothing more")
                    raise Superseded(self.superseded)
                self._execute(self.machine.on_status(agents, time.monotonic(), plant=plant))
            elif kind is A.Stop:
                if self.stop_requested:  # Ctrl-C reached the whole process group: a process lost now is its doing
                    return
                raise RunFailed(a.message)
            elif kind is A.Finished:
                self.finished = True
            elif kind is A.KillSelf:  # the scenario's `kill: orchestrator` (events.jsonl has its line already)
                log.warning("event time %d: the scenario kills this orchestrator (pid %d)", a.tau, os.getpid())
                os.kill(os.getpid(), signal.SIGKILL)

    # ------------------------------------------------------------------ run

    def run(self) -> int:
        from .records.recorder import RecordsWriteError
        from .registry import RunRegistry

        sc = self.sc
        self.finished = False
        self.superseded = ""  # a standby took over while this one was cut off: it writes nothing more
        self._dropped_seen: dict = {}
        self._next_child_poll = 0.0
        taking_over = self.takeover is not None  # (take_over clears it at the first tick)
        self.rec = _open_records(self, taking_over)
        self.registry = RunRegistry(self.keys.run_id, {"endpoint": self.connect or self.listen,
                                                       "out": str(self.out.resolve()), "host": HOST})
        now = time.monotonic()
        self.machine = m = RoundMachine(sc, self.des, host=HOST, wait=self.wait, round_timeout=self.round_timeout,
                                        spawned=self.spawn_local, now=now)
        m.epoch = self.epoch
        self.progress = Progress(None if sc.run.until_stopped else m.plan.steps, sc.m)
        self.tally = RunTally()
        code = EXIT_OK
        t_run = None
        write_error = None
        t_start = time.monotonic()
        try:
            self.registry.update()
            if self.spawn_local and not self.standby and sys.platform.startswith("linux"):  # the agents are its
                _start_forks(self)  # forks (it relies on PR_SET_PDEATHSIG); it imports numpy, Zenoh meanwhile
            self._open()
            if taking_over:
                from .takeover import take_over

                take_over(self, time.monotonic())
                t_run = m.t_run  # the pace's origin (the first orchestrator's first round): the run's seconds count from it
            else:
                self.rec.event("orchestrator_started", 0.0, pid=os.getpid(), endpoint=self.connect or self.listen,
                               run_id=self.keys.run_id, scenario=sc.name, q=self.des.q, g=self.des.g,
                               secure=self.security is not None, epoch=self.epoch, host=HOST)
            if self.forks is not None:
                self.rec.event("fork_server_started", 0.0, pid=self.forks.proc.pid)
            if sc.sources and not taking_over:  # once the router listens: a sensor that connects finds it
                self._announce_sensors()
            if self.security is None and not taking_over:
                self.rec.event("insecure_run", 0.0, level="WARN",
                               note="no authentication or access control on the router (--insecure, or no "
                                    "--secure DIR); messages are still signed with the run's key")
            if not taking_over:
                self._execute(m.start(time.monotonic()))
            while not self.finished:
                if self.stop_requested:
                    if sc.run.until_stopped:  # the way such a run ends: as finished
                        break
                    raise KeyboardInterrupt
                now = time.monotonic()
                item = self.inbox.get(timeout=max(0.0, min(POLL_SECONDS, m.next_deadline() - now)))
                now = time.monotonic()
                if item is not None and not self.stop_requested:  # stopped while waiting: what woke it is no loss
                    self._execute(self._handle(item, now))
                    # drain what is already queued before looking at timers and children (a stop asked for first)
                    while not (self.finished or self.stop_requested) and (item := self.inbox.get(0)) is not None:
                        self._execute(self._handle(item, time.monotonic()))
                if self.stop_requested:
                    continue  # the processes a Ctrl-C also reached are not lost: the run stops
                now = time.monotonic()
                self._execute(self._poll_processes(now) + m.on_timer(now))
                if t_run is None and m.started:
                    t_run = time.monotonic()
                if self.standby and now >= self.link.next_state:
                    self.link.publish_state(now)
                    if self.link.held_by_another():
                        raise Superseded(self.superseded)
            secs = time.monotonic() - (t_run or t_start)
            self._execute(m.finish_summaries(time.monotonic()))
            last = self.tally.last.tau if self.tally.last is not None else 0
            rounds = m.plan.steps if not sc.run.until_stopped else last
            reason = "steps" if not sc.run.until_stopped else f"stopped ({self.stop_signal or 'signal'})"
            self.rec.event("run_finished", m.t(rounds), rounds=rounds, reason=reason,
                           **_summary(self.tally, m, secs), rejected_messages=m.rejected_total, alive=sorted(m.alive),
                           stalled_seconds=round(m.stalled_seconds, 3))
            log.info("run finished: %d event times in %.2f s (%.1f rounds/s), %d messages rejected",
                     rounds, secs, rounds / max(secs, 1e-9), m.rejected_total)
        except KeyboardInterrupt:
            code = EXIT_INTERRUPTED
            self._safe_event("run_interrupted", m.t(), **_summary(self.tally, m, time.monotonic() - (t_run or t_start)))
            log.warning("interrupted at event time %d; records written so far are kept", m.tau)
        except Superseded as exc:
            code = EXIT_SUPERSEDED
            print(f"splitspec: error: {exc}", file=sys.stderr)
        except RunFailed as exc:
            code = EXIT_FAILED
            if self.link.held_by_another():  # cut off, and a standby took over: nothing is written
                print(f"splitspec: error: {exc}; but {self.superseded}", file=sys.stderr)
                code = EXIT_SUPERSEDED
            else:
                self._safe_event("run_failed", m.t(), reason=str(exc),
                                 **_summary(self.tally, m, time.monotonic() - (t_run or t_start)))
                print(f"splitspec: error: {exc}", file=sys.stderr)
        except RecordsWriteError as exc:  # the records cannot be kept: stop at once, say what is left
            code = EXIT_FAILED
            write_error = exc
        finally:
            try:
                if not self.superseded:
                    self._execute(m.finish_summaries(time.monotonic()))
            except Exception:  # noqa: BLE001 - the records may be what failed
                pass
            try:
                self._shutdown()
            finally:
                if self.superseded:
                    self.rec.abandon()
                else:
                    self.rec.close(finished=code == EXIT_OK)
                    self.registry.remove()
                if self.finisher is not None:  # the dead orchestrator's run.rrd segment, finished beside the run
                    from .viewer.rrd_file import wait_finished

                    wait_finished([self.finisher])
                if self.left_segments is not None and not self.superseded:  # a dead one's rolled segments too
                    from .takeover import finish_left_segments

                    finish_left_segments(self.out, self.left_segments)
        if write_error is not None:
            kept = self.rec.rows_kept
            at = write_error.tau if getattr(write_error, "tau", None) is not None else m.tau
            print(f"splitspec: error: {write_error}; stopping at event time {at}, records up to event time "
                  f"{kept - 1} kept in {self.out}", file=sys.stderr)
        log.info("wall time %.2f s", time.monotonic() - t_start)
        return code

    def _announce_sensors(self) -> None:
        """Where the user's sensors publish, and with which credentials (logged and in events.jsonl)."""
        endpoint = self.connect or local_endpoint(self.listen)
        keys = {str(a): self.keys.sensor(key) for a, key in self.sc.sensor_keys.items()}
        creds = None if self.security is None else str(self.security.dir)
        self.rec.event("sensors", 0.0, endpoint=endpoint, run_id=self.keys.run_id, keys=keys, credentials=creds)
        log.warning("live sensors: publish y_i on %s at %s%s", ", ".join(keys.values()), endpoint,
                    "" if creds is None else f" with --credentials {creds}/sensor-<id>.cred"
                    + (" (u: sensor-inputs.cred)" if self.sc.input_source is not None else ""))

    def _safe_event(self, name: str, t: float, **fields) -> None:
        try:
            self.rec.event(name, t, **fields)
        except Exception as exc:  # noqa: BLE001 - e.g. the disk is full: the one-line message says so
            log.debug("could not record %s: %s", name, exc)

    def _shutdown(self) -> None:
        session = getattr(self, "session", None)
        machine = getattr(self, "machine", None)
        try:
            if session is not None and not self.superseded:
                self.pub_control.put(encode("control", self.keys.run_id, mac_key=self.key, cmd="stop",
                                            epoch=self.epoch))
            for pid in (machine.stopped if machine else ()):  # frozen processes cannot obey a stop
                if _is_splitspec_process(pid):
                    try:
                        os.kill(pid, signal.SIGKILL)
                    except ProcessLookupError:
                        pass
            if session is not None:
                # give the others a moment to leave on their own (their tokens disappear)
                deadline = time.monotonic() + 3.0
                while not self.superseded and time.monotonic() < deadline and any(
                        c.present and not c.released for c in machine.claims.values()):
                    item = self.inbox.get(timeout=0.1)
                    if item is not None and item[0] == "alive":
                        self._handle(item, time.monotonic())  # only the claims matter now, not the actions
                self.token.undeclare()
        except Exception as exc:  # noqa: BLE001 - shutting down: report and go on
            log.warning("shutdown: %s", exc)
        finally:
            from .launcher import stop_all

            stop_all(list(self.children.values()), grace=3.0)
            if self.forks is not None:
                self.forks.close(grace=3.0)
            if session is not None:
                self.inbox.close()
                try:
                    session.close()
                except Exception as exc:  # noqa: BLE001 - e.g. a link to a frozen process cannot close cleanly
                    log.warning("shutdown: closing the Zenoh session: %s", str(exc).split(" at ")[0])


def _open_records(orch, taking_over: bool):
    """The run's :class:`~splitspec_orchestrator.records.recorder.Recorder` in ``orch.out``: a new run's (the folder
    checked, ``scenario.yaml`` written), or, ``taking_over``, the dead orchestrator's records resumed
    (:func:`~splitspec_orchestrator.takeover.resume_records`; ``orch.first_row`` the rows they hold, its finisher
    waited for at the end); in a run with a standby, held by ``orch``'s epoch (fencing on disk)."""
    from .records.files import Continuous
    from .records.recorder import Recorder

    from .takeover import hold_records, records_holder, resume_records

    sc, resume = orch.sc, None
    orch.first_row, orch.finisher, orch.left_segments = 0, None, None
    if not taking_over:
        check_output_dir(orch.out)
        try:
            (orch.out / "scenario.yaml").write_text(orch.scenario_text, encoding="utf-8")
        except OSError as exc:
            raise OutputDirError(f"cannot write {orch.out / 'scenario.yaml'}: {exc.strerror}") from None
    if orch.standby:  # first: a superseded orchestrator finds a higher epoch there and writes nothing more
        hold_records(orch.out, orch.epoch)
    torn = None
    if taking_over:  # the dead orchestrator's records, made to agree, go on
        orch.first_row, segment, torn = resume_records(orch.out)
        resume = (orch.first_row, segment)
    des = orch.des
    rec = Recorder(orch.out, agent_ids=sc.agent_ids, n=sc.n, steps=sc.run.steps, time_mode=sc.time,
                   dt=sc.run.dt if sc.time == "continuous" else 1.0, graph_names=sc.graph_names,
                   run_id=orch.keys.run_id, scenario_name=sc.name, viewer=orch.viewer,
                   envelope_rate=None if des.g_mode == "adaptive" or des.excluded else float(des.envelope_rate),
                   columns=orch.columns, positions=sc.positions, record_every=sc.run.recorded_every,
                   states=sc.state_names if sc.states_named else None, shown=sc.shown_states,
                   continuous=Continuous.from_env(sc.run) if sc.run.until_stopped else None, resume=resume)
    if rec.retention_plan is not None and not taking_over:  # run.keep: what it will do, said at the start (once)
        told.info("%s", rec.retention_plan["text"])  # on splitspec run's terminal, as the removals (recorder.py)
        rec.event("records_retention", 0.0, **rec.retention_plan)
    rec.set_inputs(sc)  # the signal's u; a file's u, or the live u, replace it (set_measurements, ...)
    if orch.meas is not None:
        rec.set_measurements(sc, given_measurements(sc, orch.meas, int(sc.run.seed)))  # the sensor faults
    if sc.sources:
        rec.set_live_sources(sc)
    if orch.standby:
        rec.fence_with(lambda: (records_holder(orch.out) or {}).get("epoch", 0) > orch.epoch)
    if torn is not None:  # the dead one's recording segment, finished beside the run (waited for at the end)
        orch.finisher = rec.finish_beside(torn)
    if taking_over:  # at the end, every segment left without its footer is finished (takeover.finish_left_segments)
        orch.left_segments = rec.layout_args()
    else:  # set up (imports, design, records): never visited by a collection again (takeover.took_over, a standby's)
        settle_heap()
    return rec


def _child_env() -> dict:
    """The environment of the processes an orchestrator starts (they know it started them)."""
    from splitspec_core.runtime.bus import CHILD_ENV

    return {**os.environ, CHILD_ENV: "1"}


def _start_forks(orch) -> None:
    """Start ``orch``'s agent fork server (:mod:`splitspec_orchestrator.forks`); agents start as new processes if
    it cannot."""
    from .forks import ForkServer

    try:
        orch.forks = ForkServer(env=_child_env(), run_id=orch.keys.run_id)
    except OSError as exc:
        log.warning("cannot start the agent fork server (%s); starting agents as new processes", exc)
    else:
        orch.children[orch.forks.proc.pid] = orch.forks.proc


def _spawn(orch, role: str, ident: int):
    """Start ``orch``'s plant or agent ``ident`` (a fork of its fork server when it has one): the process, held
    among ``orch.children``."""
    from .launcher import node_command, spawn

    endpoint = orch.connect or local_endpoint(orch.listen)
    args = ["--log-level", "warning"] + (["--id", ident] if role == "agent" else [])
    args += ["--connect", endpoint, "--run-id", orch.keys.run_id, "--wait", orch.wait]
    if orch.security is not None:
        user = "plant" if role == "plant" else f"agent-{ident}"
        args += ["--credentials", orch.security.credentials_file(user)]
    if role == "plant" and orch.measurements_path is not None:
        args += ["--measurements", orch.measurements_path]
    p = None
    if orch.standby:  # they outlive this orchestrator (a standby takes over): not its forks, no parent death
        p = spawn(node_command(role, *args), env=_child_env(), parent_death=False)
    elif role == "agent" and orch.forks is not None:  # a fork of the agent fork server: no interpreter start
        from .forks import ForkServerError

        try:
            p = orch.forks.spawn(args)
        except ForkServerError as exc:
            log.warning("%s; starting agents as new processes", exc)
            orch.forks = None
    if p is None:
        p = spawn(node_command(role, *args), env=_child_env())
    orch.children[p.pid] = p
    return p


def _config(orch, a) -> bytes:
    """The ``config`` that grants a plant's or agent's claim (``a``: the machine's ``ReplyConfig``): the scenario,
    the run's key and what the design decided centrally for it."""
    des = orch.des
    extra = {} if orch.meas is None else {
        "measurements": {"sha256": orch.meas.sha256, "steps": orch.meas.steps, "truth": orch.meas.has_truth},
        "record_y": True}
    if orch.sc.sources:  # live sensors: the agents report the y_i they sampled (recorded)
        extra["record_y"] = True
    un = des.unobserved
    gain = central_gain(des, a.ident) if a.role == "agent" else None
    if gain is not None:  # a gain the design chose centrally: K_i (and P_i) as the simulator holds them
        extra["gain"] = gain
    elif un is not None and un.dim:  # W, the directions no agent sees: P_i projects on V_i minus W
        extra["unobserved"] = un.W_working.tolist()  # in the design's working coordinates
    return encode("config", orch.keys.run_id, scenario=orch.scenario_text, seed=int(orch.sc.run.seed), g=des.g,
                  q=des.q, g_mode=des.g_mode, key=orch.key, epoch=orch.epoch, standby=orch.standby, **extra,
                  **agent_config(des, a))


def _answering(orch, timeout: float) -> tuple:
    """Agents whose granted process answers a status query within ``timeout`` (not frozen), and the plant.

    A process on this host that did not answer but is not stopped (``/proc``: not ``T``, ``t``, a zombie or gone)
    is starved, not frozen: on a loaded machine a process can miss 0.8 s.  It is asked once more before it is lost
    (a SIGSTOPped one is found at the first query, as before; one elsewhere is known by its answers alone)."""
    from .registry import process_state

    answered, plant = _status_answers(orch, timeout)
    expected = [(("agent", a), a) for a in orch.machine.alive] + [(("plant", 0), None)]
    starved = [c for who, aid in expected if (c := orch.machine.claims.get(who)) is not None and c.host == HOST
               and not (plant if aid is None else aid in answered)
               and process_state(c.pid) not in (None, "T", "t", "Z", "X")]
    if starved:
        again, plant_again = _status_answers(orch, timeout)
        answered |= again
        plant = plant or plant_again
    return answered, plant


def _status_answers(orch, timeout: float) -> tuple:
    """One status query: the agents whose granted process answered within ``timeout``, and whether the plant did."""
    from splitspec_core.runtime.bus import query_all

    answered, plant = set(), False
    for key, _payload in query_all(orch.session, orch.keys.status_all, timeout=min(timeout, orch.round_timeout)):
        member = orch.keys.parse_member(key, "status")
        if member and member[0] in ("agent", "plant"):
            c = orch.machine.claims.get(("agent", member[1]) if member[0] == "agent" else ("plant", 0))
            if c is not None and c.nonce == member[2]:
                if member[0] == "agent":
                    answered.add(member[1])
                else:
                    plant = True
    return answered, plant


def _reply(query, payload: bytes) -> None:
    """Answer a query (a claim's config or refusal) and let it go; a querier that gave up asks again."""
    try:
        query.reply(str(query.key_expr), payload)
    except Exception as exc:  # noqa: BLE001 - the querier may have given up; it asks again
        log.debug("reply failed: %s", exc)
    finally:
        query.drop()


def _summary(tally: RunTally, machine: RoundMachine, seconds: float) -> dict:
    """What the run did (:class:`~splitspec_orchestrator.rounds.tally.RunTally`): the end event's fields."""
    from .viewer.reference_view import row_disagreement

    return tally.fields(seconds=seconds, pace=machine.pace, disagreement=row_disagreement)


def main(args: argparse.Namespace) -> int:
    """``splitspec orchestrator SCENARIO --listen ENDPOINT --out DIR [--run-id ID] [--connect ENDPOINT]``."""
    # Rerun's Rust side logs a failed write to stderr; the one line the user gets is ours (RUST_LOG overrides)
    os.environ.setdefault("RUST_LOG", "off")
    if not args.listen and not args.connect:
        raise SplitspecError("give --listen ENDPOINT (embedded router) or --connect ENDPOINT (external router)")
    security = None
    if getattr(args, "secure_dir", None):
        from splitspec_core.runtime.security import Credentials

        security = Credentials.load(args.secure_dir)  # with --connect: the run's own router's credentials
    if args.listen and load_scenario(args.scenario).run.standby:
        raise SplitspecError("run.standby needs a router that outlives the orchestrator: start `splitspec router "
                             "--listen ENDPOINT` and give the orchestrator --connect ENDPOINT (splitspec run does)")
    orch = Orchestrator(args.scenario, out=Path(args.out), run_id=args.run_id,
                        listen=args.listen, connect=args.connect, wait=args.wait,
                        round_timeout=args.round_timeout, viewer=args.viewer, security=security,
                        spawn_local=getattr(args, "spawn_local", False),
                        measurements=getattr(args, "measurements", None))

    def on_signal(signum, _frame):
        orch.stop_requested = True
        orch.stop_signal = signal.Signals(signum).name
        if hasattr(orch, "inbox"):
            orch.inbox.put(("signal", "", b""))

    signal.signal(signal.SIGINT, on_signal)
    signal.signal(signal.SIGTERM, on_signal)
    return orch.run()
