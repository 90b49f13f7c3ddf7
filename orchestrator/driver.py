"""The orchestrator: serves the design, drives synchronous rounds, switches topologies, records.

``splitspec orchestrator SCENARIO --listen ENDPOINT --out DIR [--run-id ID]``

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
  applies them (:func:`splitspec_core.network.fault_step`): ``kill`` sends
  SIGKILL and ``hang`` SIGSTOP to the agent's process (or, for a process on
  another host, asks it to do so to itself), both lost from that event time;
  ``restart`` spawns a new agent process and admits it with a fresh estimate
  once its token appears; ``drop_arc``/``restore_arc`` change the links;
* admits at the next event time any agent that (re)appears by hand after a
  loss (``splitspec agent --id I --connect ...``), with a new incarnation;
* after every change of the network, logs the resilience verdict
  (:func:`splitspec_core.design.certify_network`): still strongly connected,
  jointly observable, and is the rate still certified by the designed g or q;
* records ``trajectory.npz``, ``events.jsonl``, ``run.rrd`` and a copy of the
  scenario (``scenario.yaml``), so that ``splitspec simulate scenario.yaml
  --faults-from events.jsonl`` replays the run.
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

from splitspec_core.design import certify_network, design
from splitspec_core.errors import SplitspecError
from splitspec_core.network import NetworkState, make_plan
from splitspec_core.scenario import load_scenario, read_scenario_text
from splitspec_core.wire import DEFAULT_RUN_ID, Keys, WireError, decode, encode

log = logging.getLogger("splitspec.orchestrator")

EXIT_OK, EXIT_FAILED, EXIT_INTERRUPTED = 0, 1, 130


class RunFailed(SplitspecError, RuntimeError):
    """The run cannot go on (plant lost, participants missing, ...)."""


class Progress:
    """One status line on a terminal: event time, max error, alive agents, rounds per second."""

    def __init__(self, steps: int, m: int):
        self.enabled = sys.stderr.isatty()
        self.steps, self.m = steps, m
        self.t0 = self.last = time.monotonic()

    def update(self, tau: int, max_err: float, alive: int, *, force: bool = False) -> None:
        if not self.enabled:
            return
        now = time.monotonic()
        if now - self.last < 0.25 and not force:
            return
        self.last = now
        rps = tau / max(now - self.t0, 1e-9)
        sys.stderr.write(f"\revent {tau:>6}/{self.steps}  max error {max_err:9.3e}  alive {alive}/{self.m}  "
                         f"{rps:7.1f} rounds/s ")
        if force:
            sys.stderr.write("\n")
        sys.stderr.flush()


HOST = socket.gethostname()
_FAULT_SIGNAL = {"kill": signal.SIGKILL, "hang": signal.SIGSTOP}


def local_endpoint(endpoint: str) -> str:
    """An endpoint a process on this machine can connect to (``0.0.0.0`` / ``[::]`` -> loopback)."""
    return endpoint.replace("/0.0.0.0:", "/127.0.0.1:").replace("/[::]:", "/[::1]:")


def _is_splitspec_process(pid: int) -> bool:
    """A live (not zombie) splitspec process: the guard against pid reuse before signalling a pid from a hello."""
    try:
        with open(f"/proc/{pid}/cmdline", "rb") as f:
            cmd = f.read()
    except OSError:
        return False
    return b"orchestrator.cli" in cmd or b"splitspec" in cmd


class Orchestrator:
    """Round driver.  ``run()`` returns the process exit code."""

    def __init__(self, scenario_path: str, *, out: Path, run_id: str, listen: str | None, connect: str | None,
                 wait: float = 60.0, round_timeout: float = 10.0, viewer: str | None = None,
                 security=None):
        self.scenario_text = read_scenario_text(scenario_path)
        self.sc = load_scenario(scenario_path)
        self.des = design(self.sc)
        self.keys = Keys(run_id)
        self.out = out
        self.listen, self.connect = listen, connect
        self.wait, self.round_timeout = wait, round_timeout
        self.viewer = viewer
        self.security = security  # splitspec_core.security.Credentials or None
        self.stop_requested = False

    # ------------------------------------------------------------------ set-up

    def _config_reply(self, query) -> bytes:
        payload = query.payload.to_bytes() if query.payload is not None else b""
        self.inbox.put(("hello", "", payload))
        return encode("config", self.keys.run_id, scenario=self.scenario_text, seed=int(self.sc.run.seed),
                      g=self.des.g, q=self.des.q, g_mode=self.des.g_mode)

    def _open(self) -> None:
        from splitspec_core.bus import Inbox, open_session

        kw: dict = {}
        if self.security is not None:  # authentication + access control on the embedded router
            kw = {"extra": self.security.router_extra(self.keys.run_id, self.sc.agent_ids)}
        if self.connect:
            self.session = open_session("client", connect=[self.connect], **kw)
        else:
            self.session = open_session("router", listen=[self.listen], **kw)
        self.inbox = Inbox(self.session)
        self.inbox.watch_liveliness(self.keys.alive_all, "alive")
        self.inbox.subscribe(self.keys.truth, "truth")
        self.inbox.subscribe(f"{self.keys.prefix}/xhat/*", "xhat")
        self.inbox.serve(self.keys.config, self._config_reply)
        self.pub_tick = self.session.declare_publisher(self.keys.tick)
        self.pub_control = self.session.declare_publisher(self.keys.control)
        self.token = self.session.liveliness().declare_token(self.keys.alive("orchestrator"))

    # ------------------------------------------------------------------ message handling

    def _reject(self, source: str, reason: str, t: float, count: int = 1) -> None:
        self.rejected_total += count
        self.rec.event("message_rejected", t, by=source, reason=reason, count=count)

    def _count_remote(self, who: str, counts: dict, t_now: float) -> None:
        """Log what another process rejected since its last report (it sends running totals)."""
        prev = self.remote_rejected.setdefault(who, {})
        for reason, count in counts.items():
            if isinstance(count, int) and count > prev.get(reason, 0):
                self._reject(who, str(reason), t_now, count - prev.get(reason, 0))
                prev[reason] = count

    def _handle(self, item, t_now: float) -> None:
        """Process one inbox item (any phase)."""
        channel, key, payload = item
        if channel == "alive":
            parts = key.split("/")
            role, ident = (parts[-2], parts[-1]) if len(parts) >= 2 else ("?", "?")
            if role == "agent":
                try:
                    aid = int(ident)
                except ValueError:
                    return
                if aid not in self.index:
                    return
                if payload == "put":
                    self.tokens.add(aid)
                    if aid not in self.alive:
                        # a new process for this agent (started by hand or by a restart): admitted at the
                        # next event time; a lost agent whose old token lingers is never re-admitted
                        self.joinable.add(aid)
                        if self.started:
                            log.info("agent %d is back; it joins at the next event time", aid)
                else:
                    self.tokens.discard(aid)
                    self.joinable.discard(aid)
                    if aid in self.alive:
                        self.pending_loss[aid] = "liveliness lost (process died or froze)"
            elif role == "plant":
                self.plant_present = payload == "put"
        elif channel == "hello":
            try:
                h = decode(payload, self.keys.run_id, "hello")
            except WireError as e:
                self._reject("orchestrator", e.reason, t_now)
                return
            self.rec.event("process_started", t_now, role=h["role"], id=h["id"], pid=h["pid"], host=h["host"])
            info = {"pid": h["pid"], "host": h["host"]}
            if h["role"] == "agent":
                self.procs[h["id"]] = info  # the registry's view (json writes the ids as strings)
            elif h["role"] == "plant":
                self.registry.data["plant"] = info
            self.registry.update()
        elif channel == "truth":
            try:
                m = decode(payload, self.keys.run_id, "truth")
                if m["x"].shape != (self.sc.n,):
                    raise WireError("bad_shape", "truth")
            except WireError as e:
                self._reject("orchestrator", e.reason, t_now)
                return
            self.truth[m["tau"]] = m["x"]
            self._count_remote("plant", m["rejected"], t_now)
        elif channel == "xhat":
            try:
                m = decode(payload, self.keys.run_id, "xhat")
                if str(m["agent"]) != Keys.last(key) or m["agent"] not in self.index:
                    raise WireError("wrong_sender", key)
                if m["x"].shape != (self.sc.n,):
                    raise WireError("bad_shape", "xhat")
            except WireError as e:
                self._reject("orchestrator", e.reason, t_now)
                return
            aid = m["agent"]
            if m["incarnation"] != self.incarnation(aid) or m["attempt"] != self.attempt:
                self._reject("orchestrator", "stale", t_now)
                return
            self.est.setdefault(m["tau"], {})[aid] = m["x"]
            self.gains[aid] = m["g"]
            self._count_remote(f"agent {aid}", m["rejected"], t_now)
        elif channel == "signal":
            self.stop_requested = True

    def _pump(self, deadline: float, done, t_now: float) -> bool:
        """Handle messages until ``done()`` or the deadline; False on timeout."""
        while not done():
            if self.stop_requested or self.pending_loss or (not self.plant_present and self.started):
                return True
            left = deadline - time.monotonic()
            if left <= 0:
                return False
            item = self.inbox.get(timeout=min(left, 0.5))
            if item is not None:
                self._handle(item, t_now)
        return True

    def _check_stop(self, tau: int) -> None:
        if self.stop_requested:
            raise KeyboardInterrupt
        if self.started and not self.plant_present:
            raise RunFailed(f"the plant was lost at event time {tau}; stopping (records up to event time "
                            f"{tau - 1} are kept in {self.out})")

    # ------------------------------------------------------------------ the network

    def incarnation(self, aid: int) -> int:
        return int(self.net.incarnation[self.index[aid]])

    def _verdict(self, tau: int, after: str) -> None:
        """Log the resilience verdict of the current network (events.jsonl, Rerun, terminal)."""
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
        self.rec.event("resilience_verdict", float(tau) * self.dt, level="INFO" if v["ok"] else "WARN",
                       note=f"{after} at event time {tau}: {msg}", after=after, tau=tau, **v)
        log.log(logging.INFO if v["ok"] else logging.WARNING, "%s at event time %d: %s", after, tau, msg)
        self.topology_dirty = True

    def _lose(self, aid: int, tau: int, why: str) -> None:
        if not self.net.lose(self.index[aid]):
            return
        self.alive.discard(aid)
        self.joinable.discard(aid)
        self.rec.mark_lost(tau, aid)
        pid = self.procs.get(aid, {}).get("pid")
        self.rec.event("agent_lost", float(tau) * self.dt, id=aid, tau=tau, reason=why, pid=pid)
        log.warning("agent %d lost from event time %d: %s", aid, tau, why)
        self._verdict(tau, f"agent {aid} lost")

    def _admit(self, aid: int, tau: int, why: str) -> None:
        inc = self.net.rejoin(self.index[aid])
        if inc is None:
            return
        self.alive.add(aid)
        self.joinable.discard(aid)
        pid = self.procs.get(aid, {}).get("pid")
        self.rec.event("agent_rejoined", float(tau) * self.dt, id=aid, tau=tau, incarnation=inc, reason=why, pid=pid)
        log.info("agent %d rejoins at event time %d with a fresh estimate (incarnation %d): %s", aid, tau, inc, why)
        self._verdict(tau, f"agent {aid} rejoined")

    def _apply_pending_losses(self, tau: int) -> bool:
        lost = False
        for a, why in sorted(self.pending_loss.items()):
            if a in self.alive:
                self._lose(a, tau, why)
                lost = True
        self.pending_loss.clear()
        return lost

    def _unresponsive(self) -> list:
        """Alive agents that do not answer a status query within a second (frozen processes)."""
        from splitspec_core.bus import query_all

        answered = set()
        for key, payload in query_all(self.session, self.keys.status_all, timeout=min(1.0, self.round_timeout)):
            parts = key.split("/")
            if len(parts) >= 2 and parts[-2] == "agent":
                try:
                    if decode(payload, self.keys.run_id, "hello")["id"] == int(parts[-1]):
                        answered.add(int(parts[-1]))
                except (WireError, ValueError):
                    pass
        return sorted(a for a in self.alive if a not in answered)

    def _signal_agent(self, aid: int, action: str) -> str:
        """Send the fault's signal to agent ``aid``'s process; returns how it was delivered."""
        sig = _FAULT_SIGNAL[action]
        info = self.procs.get(aid)
        if info and info["host"] == HOST and _is_splitspec_process(int(info["pid"])):
            try:
                os.kill(int(info["pid"]), sig)
                if action == "hang":
                    self.hung.add(int(info["pid"]))
                return f"{signal.Signals(sig).name} to pid {info['pid']}"
            except ProcessLookupError:
                return f"pid {info['pid']} already gone"
        # another host (or unknown pid): the agent signals itself
        self.pub_control.put(encode("control", self.keys.run_id, cmd=f"{action} agent/{aid}"))
        return f"asked agent {aid} on {info['host'] if info else 'an unknown host'} to {action} itself"

    def _spawn_agent(self, aid: int) -> subprocess.Popen:
        from .launcher import cli_command, spawn

        endpoint = self.connect or local_endpoint(self.listen)
        args = ["--log-level", "warning", "agent", "--id", aid, "--connect", endpoint, "--run-id", self.keys.run_id,
                "--wait", self.wait]
        if self.security is not None:
            args += ["--credentials", self.security.credentials_file(f"agent-{aid}")]
        p = spawn(cli_command(*args))
        self.children.append(p)
        return p

    def _wait_between_rounds(self, seconds: float, done, tau: int) -> bool:
        """Handle messages (and losses) between rounds until ``done()``; False on timeout."""
        deadline = time.monotonic() + seconds
        while True:
            ok = self._pump(deadline, done, float(tau) * self.dt)
            self._check_stop(tau)
            if self.pending_loss:
                self._apply_pending_losses(tau)
                continue
            return ok

    def _restart(self, aid: int, tau: int) -> None:
        t = float(tau) * self.dt
        old = self.procs.get(aid)
        if aid in self.tokens:
            # the old process still holds its token (hung, or its death not yet seen): make sure it is
            # dead and wait until its token is gone, so the new token cannot be confused with it
            if old and old["host"] == HOST and _is_splitspec_process(int(old["pid"])):
                how = self._signal_agent(aid, "kill")
                self.hung.discard(int(old["pid"]))
                log.info("restart of agent %d: killed the old process (%s)", aid, how)
            self._wait_between_rounds(self.wait, lambda: aid not in self.tokens, tau)
        p = self._spawn_agent(aid)
        self.rec.event("agent_restarting", t, id=aid, tau=tau, pid=p.pid)
        if self._wait_between_rounds(self.wait, lambda: aid in self.joinable or p.poll() is not None, tau) \
                and aid in self.joinable:
            self._admit(aid, tau, "restarted by the scenario")
        else:
            why = (f"exited with status {p.returncode}" if p.poll() is not None else
                   f"no liveliness token within {self.wait:g} s")
            self.rec.event("restart_failed", t, id=aid, tau=tau, reason=why)
            log.warning("restart of agent %d at event time %d failed: %s; the run goes on without it", aid, tau, why)

    def _between_rounds(self, tau: int, faults) -> None:
        """Scenario faults due at ``tau`` (in scenario order), then agents that came back by hand."""
        t = float(tau) * self.dt
        while (item := self.inbox.get(timeout=0)) is not None:  # what arrived since the last round
            self._handle(item, t)
        self._check_stop(tau)
        self._apply_pending_losses(tau)
        for f in faults:
            if f.action in ("kill", "hang"):
                if f.agent not in self.alive:
                    self.rec.event("fault_skipped", t, action=f.action, id=f.agent, reason="agent not alive")
                    continue
                how = self._signal_agent(f.agent, f.action)
                self._lose(f.agent, tau, f"{'killed' if f.action == 'kill' else 'hung'} by the scenario ({how})")
            elif f.action == "restart":
                if f.agent in self.alive:
                    self.rec.event("fault_skipped", t, action="restart", id=f.agent, reason="agent is alive")
                    continue
                self._restart(f.agent, tau)
            else:  # drop_arc / restore_arc: the simulator's own bookkeeping
                self.net.apply([f])
                arc = tuple(f.arc)
                self.rec.event("arc_dropped" if f.action == "drop_arc" else "arc_restored", t, arc=list(arc), tau=tau)
                self._verdict(tau, f"arc {arc[0]} -> {arc[1]} {'dropped' if f.action == 'drop_arc' else 'restored'}")
        for a in sorted(self.joinable - self.alive):
            self._admit(a, tau, "started by hand")

    # ------------------------------------------------------------------ run

    def _wait_for_participants(self) -> None:
        need = set(self.sc.agent_ids)
        deadline = time.monotonic() + self.wait
        ok = self._pump(deadline, lambda: self.plant_present and need <= self.tokens, 0.0)
        if self.stop_requested:
            return
        if not ok:
            missing = ([] if self.plant_present else ["plant"]) + [f"agent {i}" for i in sorted(need - self.tokens)]
            raise RunFailed(f"waited {self.wait:g} s for {', '.join(missing)} to connect on "
                            f"{self.connect or self.listen} (run id {self.keys.run_id})")

    def _tick(self, tau: int, rows: dict, graph: int, final: bool) -> None:
        self.pub_tick.put(encode(
            "tick", self.keys.run_id, tau=tau, attempt=self.attempt, graph=graph, final=final,
            alive=sorted(self.alive),
            rows={str(i): [list(nb), list(w)] for i, (nb, w) in rows.items()},
            incarnation={str(i): self.incarnation(i) for i in self.sc.agent_ids}))

    def run(self) -> int:
        from .recorder import Recorder
        from .registry import RunRegistry

        sc = self.sc
        self.dt = sc.run.dt if sc.time == "continuous" else 1.0
        self.out.mkdir(parents=True, exist_ok=True)
        (self.out / "scenario.yaml").write_text(self.scenario_text, encoding="utf-8")
        self.rec = Recorder(self.out, agent_ids=sc.agent_ids, n=sc.n, steps=sc.run.steps, time_mode=sc.time,
                            dt=self.dt, graph_names=sc.graph_names, run_id=self.keys.run_id,
                            scenario_name=sc.name, viewer=self.viewer)
        self.registry = RunRegistry(self.keys.run_id, {"endpoint": self.connect or self.listen,
                                                       "out": str(self.out.resolve()), "host": HOST})
        self.index = {a: k for k, a in enumerate(sc.agent_ids)}
        self.net = NetworkState(sc)
        self.net.alive[:] = False
        self.alive: set = set()
        self.tokens: set = set()  # agents holding a liveliness token
        self.joinable: set = set()  # agents whose token appeared since they were last lost
        self.procs: dict = self.registry.data["agents"]  # agent id -> {"pid", "host"} of its latest process
        self.children: list = []  # agent processes this orchestrator spawned (restarts)
        self.hung: set = set()  # pids of frozen agents on this host (SIGSTOPped by a fault or found frozen)
        self.plant_present = False
        self.started = False
        self.pending_loss: dict = {}
        self.topology_dirty = True
        self.attempt = 0
        self.truth: dict = {}
        self.est: dict = {}
        self.gains: dict = {}
        self.remote_rejected: dict = {}
        self.rejected_total = 0
        code = EXIT_OK
        t_start = time.monotonic()
        tau = 0
        try:
            self.registry.update()
            self._open()
            self.rec.event("orchestrator_started", 0.0, pid=os.getpid(), endpoint=self.connect or self.listen,
                           run_id=self.keys.run_id, scenario=sc.name, q=self.des.q, g=self.des.g,
                           secure=self.security is not None)
            self._wait_for_participants()
            if self.stop_requested:
                raise KeyboardInterrupt
            self.net.alive[:] = True
            self.alive = set(sc.agent_ids)
            self.joinable.clear()
            self.started = True
            plan = make_plan(sc, sc.run.seed)
            progress = Progress(plan.steps, sc.m)
            self.rec.event("run_started", 0.0, agents=list(sc.agent_ids), steps=plan.steps)
            last_graph = None
            t_run = time.monotonic()
            for tau in range(plan.steps + 1):
                graph = int(plan.graph_seq[tau])
                final = tau == plan.steps
                t = float(tau) * self.dt
                if sc.run.pace:
                    delay = t_run + tau / sc.run.pace - time.monotonic()
                    if delay > 0:
                        self._wait_between_rounds(delay, lambda: False, tau)
                self.attempt = 0
                retried = False
                self._between_rounds(tau, plan.faults.get(tau, ()))
                while True:
                    rows = self.net.rows(sc, graph)
                    if graph != last_graph or self.topology_dirty:
                        name = sc.graph_names[graph]
                        if last_graph is not None and graph != last_graph:
                            self.rec.event("graph_switched", t, graph=name, previous=sc.graph_names[last_graph])
                        self.rec.topology(tau, name, sorted(self.alive), self.net.arcs(sc, graph))
                        last_graph, self.topology_dirty = graph, False
                    self._tick(tau, rows, graph, final)
                    expect_next = set() if final else set(self.alive)

                    def done():
                        if tau not in self.truth:
                            return False
                        have_now = self.est.get(tau, {})
                        have_next = self.est.get(tau + 1, {})
                        return all(a in have_now for a in self.alive) and expect_next <= set(have_next)

                    ok = self._pump(time.monotonic() + self.round_timeout, done, t)
                    self._check_stop(tau)
                    if not ok:
                        if tau not in self.truth:
                            raise RunFailed(f"no truth from the plant for event time {tau} within "
                                            f"{self.round_timeout:g} s")
                        late = sorted(a for a in expect_next if a not in self.est.get(tau + 1, {}))
                        late = late or sorted(a for a in self.alive if a not in self.est.get(tau, {}))
                        # agents waiting for a frozen neighbour are late too: blame only those that do not
                        # answer a status query (a frozen process cannot)
                        frozen = self._unresponsive()
                        if frozen:
                            for a in frozen:
                                self.pending_loss[a] = (f"round timeout ({self.round_timeout:g} s) and no answer "
                                                        "to a status query: frozen")
                                info = self.procs.get(a)
                                if info and info["host"] == HOST:
                                    self.hung.add(int(info["pid"]))  # cannot obey the final stop: killed then
                        elif not retried:
                            retried = True
                            self.rec.event("round_retried", t, tau=tau, attempt=self.attempt + 1, late=late)
                            log.warning("event time %d: no estimate from agents %s within %g s, but all answer; "
                                        "re-running the round once", tau, late, self.round_timeout)
                            self.est.pop(tau + 1, None)
                            self.attempt += 1
                            continue
                        else:
                            for a in late:
                                self.pending_loss[a] = f"round timeout ({self.round_timeout:g} s without its estimate)"
                    if self._apply_pending_losses(tau):
                        self.est.pop(tau + 1, None)
                        self.attempt += 1
                        continue  # re-run the round without the lost agents
                    break
                xh = np.full((sc.m, sc.n), np.nan)
                alive_mask = np.zeros(sc.m, dtype=bool)
                for a in self.alive:
                    xh[self.index[a]] = self.est[tau][a]
                    alive_mask[self.index[a]] = True
                self.rec.row(tau, self.truth[tau], xh, alive_mask, graph)
                errs = np.linalg.norm(xh - self.truth[tau], axis=1)
                progress.update(tau, float(np.nanmax(errs)) if alive_mask.any() else math.nan, len(self.alive),
                                force=final)
                self.truth.pop(tau - 1, None)
                self.est.pop(tau - 1, None)
            secs = time.monotonic() - t_run
            self.rec.event("run_finished", float(plan.steps) * self.dt, rounds=plan.steps, seconds=round(secs, 3),
                           rounds_per_second=round(plan.steps / max(secs, 1e-9), 2),
                           rejected_messages=self.rejected_total, alive=sorted(self.alive))
            log.info("run finished: %d event times in %.2f s (%.1f rounds/s), %d messages rejected",
                     plan.steps, secs, plan.steps / max(secs, 1e-9), self.rejected_total)
        except KeyboardInterrupt:
            code = EXIT_INTERRUPTED
            self.rec.event("run_interrupted", float(tau) * self.dt)
            log.warning("interrupted at event time %d; records written so far are kept", tau)
        except RunFailed as exc:
            code = EXIT_FAILED
            self.rec.event("run_failed", float(tau) * self.dt, reason=str(exc))
            print(f"splitspec: error: {exc}", file=sys.stderr)
        finally:
            try:
                self._shutdown()
            finally:
                self.rec.close(finished=code == EXIT_OK)
                self.registry.remove()
        log.info("wall time %.2f s", time.monotonic() - t_start)
        return code

    def _shutdown(self) -> None:
        session = getattr(self, "session", None)
        try:
            if session is not None:
                self.pub_control.put(encode("control", self.keys.run_id, cmd="stop"))
            for pid in getattr(self, "hung", ()):  # frozen processes (hang fault, or found frozen) cannot obey a stop
                if _is_splitspec_process(pid):
                    try:
                        os.kill(pid, signal.SIGKILL)
                    except ProcessLookupError:
                        pass
            if session is not None:
                # give the others a moment to leave on their own (their tokens disappear)
                deadline = time.monotonic() + 3.0
                while (self.tokens or self.plant_present) and time.monotonic() < deadline:
                    item = self.inbox.get(timeout=0.1)
                    if item is not None and item[0] == "alive":
                        self._handle(item, 0.0)
                self.token.undeclare()
        except Exception as exc:  # noqa: BLE001 - shutting down: report and go on
            log.warning("shutdown: %s", exc)
        finally:
            from .launcher import stop_all

            stop_all(getattr(self, "children", []), grace=3.0)
            if session is not None:
                self.inbox.close()
                try:
                    session.close()
                except Exception as exc:  # noqa: BLE001 - e.g. a link to a frozen process cannot close cleanly
                    log.warning("shutdown: closing the Zenoh session: %s", str(exc).split(" at ")[0])


def main(args: argparse.Namespace) -> int:
    """``splitspec orchestrator SCENARIO --listen ENDPOINT --out DIR [--run-id ID] [--connect ENDPOINT]``."""
    if not args.listen and not args.connect:
        raise SplitspecError("give --listen ENDPOINT (embedded router) or --connect ENDPOINT (external router)")
    security = None
    if getattr(args, "secure_dir", None):
        from splitspec_core.security import Credentials

        if args.connect:
            raise SplitspecError("--secure configures the orchestrator's embedded router: use it with --listen, "
                                 "not --connect")
        security = Credentials.load(args.secure_dir)
    orch = Orchestrator(args.scenario, out=Path(args.out), run_id=args.run_id or DEFAULT_RUN_ID,
                        listen=args.listen, connect=args.connect, wait=args.wait,
                        round_timeout=args.round_timeout, viewer=args.viewer, security=security)

    def on_signal(*_):
        orch.stop_requested = True
        if hasattr(orch, "inbox"):
            orch.inbox.put(("signal", "", b""))

    signal.signal(signal.SIGINT, on_signal)
    signal.signal(signal.SIGTERM, on_signal)
    return orch.run()
