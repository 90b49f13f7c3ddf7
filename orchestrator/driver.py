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
* records ``trajectory.npz``, ``events.jsonl`` and ``run.rrd``.
"""

from __future__ import annotations

import argparse
import logging
import math
import os
import signal
import sys
import time
from pathlib import Path

import numpy as np

from splitspec_core.design import design
from splitspec_core.errors import SplitspecError
from splitspec_core.network import consensus_rows, make_plan
from splitspec_core.resilience import network_verdict
from splitspec_core.scenario import load_scenario
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


class Orchestrator:
    """Round driver.  ``run()`` returns the process exit code."""

    def __init__(self, scenario_path: str, *, out: Path, run_id: str, listen: str | None, connect: str | None,
                 wait: float = 60.0, round_timeout: float = 10.0, viewer: str | None = None):
        self.scenario_text = Path(scenario_path).read_text(encoding="utf-8")
        self.sc = load_scenario(scenario_path)
        self.des = design(self.sc)
        self.keys = Keys(run_id)
        self.out = out
        self.listen, self.connect = listen, connect
        self.wait, self.round_timeout = wait, round_timeout
        self.viewer = viewer
        self.stop_requested = False

    # ------------------------------------------------------------------ set-up

    def _config_reply(self, query) -> bytes:
        payload = query.payload.to_bytes() if query.payload is not None else b""
        self.inbox.put(("hello", "", payload))
        return encode("config", self.keys.run_id, scenario=self.scenario_text, seed=int(self.sc.run.seed),
                      g=self.des.g, q=self.des.q, g_mode=self.des.g_mode)

    def _open(self) -> None:
        from splitspec_core.bus import Inbox, open_session

        if self.connect:
            self.session = open_session("client", connect=[self.connect])
        else:
            self.session = open_session("router", listen=[self.listen])
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
                if payload == "put":
                    self.present.add(aid)
                else:
                    self.present.discard(aid)
                    if aid in self.alive:
                        self.pending_loss.add(aid)
            elif role == "plant":
                self.plant_present = payload == "put"
        elif channel == "hello":
            try:
                h = decode(payload, self.keys.run_id, "hello")
            except WireError as e:
                self._reject("orchestrator", e.reason, t_now)
                return
            self.rec.event("process_started", t_now, role=h["role"], id=h["id"], pid=h["pid"], host=h["host"])
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
            if m["incarnation"] != self.incarnation.get(aid) or m["attempt"] != self.attempt:
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

    # ------------------------------------------------------------------ run

    def _wait_for_participants(self) -> None:
        need = set(self.sc.agent_ids)
        deadline = time.monotonic() + self.wait
        ok = self._pump(deadline, lambda: self.plant_present and need <= self.present, 0.0)
        if self.stop_requested:
            return
        if not ok:
            missing = ([] if self.plant_present else ["plant"]) + [f"agent {i}" for i in sorted(need - self.present)]
            raise RunFailed(f"waited {self.wait:g} s for {', '.join(missing)} to connect on "
                            f"{self.connect or self.listen} (run id {self.keys.run_id})")

    def _tick(self, tau: int, rows: dict, graph: int, final: bool) -> None:
        self.pub_tick.put(encode(
            "tick", self.keys.run_id, tau=tau, attempt=self.attempt, graph=graph, final=final,
            alive=sorted(self.alive),
            rows={str(i): [list(nb), list(w)] for i, (nb, w) in rows.items()},
            incarnation={str(i): int(v) for i, v in self.incarnation.items()}))

    def _lose(self, aid: int, tau: int, why: str) -> None:
        self.alive.discard(aid)
        self.rec.mark_lost(tau, aid)
        self.rec.event("agent_lost", float(tau) * self.dt, id=aid, tau=tau, reason=why)
        v = network_verdict(self.sc.system.A, dict(zip(self.sc.agent_ids, self.sc.system.Cs)), self.alive,
                            {g.name: g.arcs for g in self.sc.graphs}, rank_tol=self.sc.design.rank_tol)
        self.rec.event("resilience_verdict", float(tau) * self.dt, alive=sorted(self.alive),
                       strongly_connected=v.strongly_connected, jointly_observable=v.jointly_observable,
                       unobservable_direction=v.unobservable_direction)
        if not v.ok:
            log.warning("after losing agent %d the network is %s", aid,
                        "not jointly observable" if not v.jointly_observable else "not strongly connected")

    def run(self) -> int:
        from .recorder import Recorder

        sc = self.sc
        self.dt = sc.run.dt if sc.time == "continuous" else 1.0
        self.out.mkdir(parents=True, exist_ok=True)
        self.rec = Recorder(self.out, agent_ids=sc.agent_ids, n=sc.n, steps=sc.run.steps, time_mode=sc.time,
                            dt=self.dt, graph_names=sc.graph_names, run_id=self.keys.run_id,
                            scenario_name=sc.name, viewer=self.viewer)
        self.index = {a: k for k, a in enumerate(sc.agent_ids)}
        self.present: set = set()
        self.plant_present = False
        self.started = False
        self.alive: set = set()
        self.pending_loss: set = set()
        self.incarnation = {a: 0 for a in sc.agent_ids}
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
            self._open()
            self.rec.event("orchestrator_started", 0.0, pid=os.getpid(), endpoint=self.connect or self.listen,
                           run_id=self.keys.run_id, scenario=sc.name, q=self.des.q, g=self.des.g)
            self._wait_for_participants()
            if self.stop_requested:
                raise KeyboardInterrupt
            self.alive = set(sc.agent_ids)
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
                        time.sleep(delay)
                self.attempt = 0
                while True:
                    rows = consensus_rows(sc, graph, self.alive)
                    if graph != last_graph:
                        name = sc.graph_names[graph]
                        if last_graph is not None:
                            self.rec.event("graph_switched", t, graph=name, previous=sc.graph_names[last_graph])
                        self.rec.topology(tau, name, sorted(self.alive), sc.graphs[graph].arcs)
                        last_graph = graph
                    self._tick(tau, rows, graph, final)
                    expect_next = set() if final else set(self.alive)

                    def done():
                        if tau not in self.truth:
                            return False
                        have_now = self.est.get(tau, {})
                        have_next = self.est.get(tau + 1, {})
                        return all(a in have_now for a in self.alive) and expect_next <= set(have_next)

                    ok = self._pump(time.monotonic() + self.round_timeout, done, t)
                    if self.stop_requested:
                        raise KeyboardInterrupt
                    if self.started and not self.plant_present:
                        raise RunFailed(f"the plant was lost at event time {tau}; stopping")
                    if not ok:
                        late = sorted(a for a in expect_next if a not in self.est.get(tau + 1, {}))
                        if tau not in self.truth:
                            raise RunFailed(f"no truth from the plant for event time {tau} within "
                                            f"{self.round_timeout:g} s")
                        for a in late or sorted(a for a in self.alive if a not in self.est.get(tau, {})):
                            self.pending_loss.add(a)
                    if self.pending_loss:
                        for a in sorted(self.pending_loss):
                            if a in self.alive:
                                self._lose(a, tau, "liveliness lost" if a not in self.present else "round timeout")
                        self.pending_loss.clear()
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
            self._shutdown()
            self.rec.close(finished=code == EXIT_OK)
        log.info("wall time %.2f s", time.monotonic() - t_start)
        return code

    def _shutdown(self) -> None:
        session = getattr(self, "session", None)
        if session is None:
            return
        try:
            self.pub_control.put(encode("control", self.keys.run_id, cmd="stop"))
            # give the others a moment to leave on their own (their tokens disappear)
            deadline = time.monotonic() + 3.0
            while (self.present or self.plant_present) and time.monotonic() < deadline:
                item = self.inbox.get(timeout=0.1)
                if item is not None and item[0] == "alive":
                    self._handle(item, 0.0)
            self.token.undeclare()
        except Exception as exc:  # noqa: BLE001 - shutting down: report and go on
            log.warning("shutdown: %s", exc)
        finally:
            self.inbox.close()
            session.close()


def main(args: argparse.Namespace) -> int:
    """``splitspec orchestrator SCENARIO --listen ENDPOINT --out DIR [--run-id ID] [--connect ENDPOINT]``."""
    if not args.listen and not args.connect:
        raise SplitspecError("give --listen ENDPOINT (embedded router) or --connect ENDPOINT (external router)")
    orch = Orchestrator(args.scenario, out=Path(args.out), run_id=args.run_id or DEFAULT_RUN_ID,
                        listen=args.listen, connect=args.connect, wait=args.wait,
                        round_timeout=args.round_timeout, viewer=args.viewer)

    def on_signal(*_):
        orch.stop_requested = True
        if hasattr(orch, "inbox"):
            orch.inbox.put(("signal", "", b""))

    signal.signal(signal.SIGINT, on_signal)
    signal.signal(signal.SIGTERM, on_signal)
    return orch.run()
