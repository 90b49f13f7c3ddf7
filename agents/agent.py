"""One agent: fetches its part of the design, then runs the two-rate protocol round after round.

The protocol logic lives in :class:`AgentNode` (no sockets: messages in,
messages out), the Zenoh shell in :func:`main`.  The math is exactly the
per-agent step functions of :mod:`splitspec_core.model.steps`, so a run equals
``splitspec simulate`` to round-off.

Round ``(tau, attempt)`` (discrete):  z_i(0) = x_i(tau); for k = 1..q wait
for every neighbour's z_j(k-1) of the same (tau, attempt), then
z_i(k) = consensus_subround(...) (published on ``z/<i>`` for k < q); then wait
for y_i(tau) and publish x_i(tau+1) on ``xhat/<i>``, which the orchestrator
records and the neighbours keep as the next round's z_i(0): z_i(0) itself is
published only in a round the tick marks ``fresh`` (someone starts with a fresh
estimate: the first round, a rejoin) and in a re-run (attempt > 0).  Otherwise
the tick's ``prev_attempt`` names the attempt of round tau-1 whose estimates
are this round's z_j(0), so a neighbour never uses an estimate of an aborted
attempt.  The new estimate is committed when the tick of tau+1 arrives; a tick
of the same tau with a higher attempt (a round re-run after a loss) discards it.
Continuous time: one exchange per step (z = x_i(k)), then the sampled-data
step (and the adaptive gain update, eq. adaptive).

Plausibility (every message is also MAC-checked with the run's key, see
:mod:`splitspec_core.runtime.wire`): a tick must be newer than the last one and at
most one event time ahead of it; ``y`` and ``z`` at most one event time
ahead of the last tick (``z`` also at most two attempts ahead).  Buffers are
bounded: ``y`` for at most two event times, ``z`` for at most ``ZBUF_ROUNDS * q *
(in-neighbours)`` messages; anything beyond is dropped and counted (``future``, ``stale``...).

The whole-state design (``config["gain"]`` with ``consensus: whole``, :mod:`splitspec_core.synthesis.whole_state`)
runs the other order: once ``y_i(tau)`` is in, the update ``z_i(0) = F_i x_i(tau) - K_i y_i(tau)`` (sent), then q
sub-rounds ``z_i(k) = sum_j w_ij z_j(k - 1)`` and ``x_i(tau + 1) = z_i(q)``; in continuous time on the sampled model.

Why one module: the protocol's state machine (:class:`AgentNode`) and the few lines of its Zenoh shell are one
process; what a message does to a round is read in one place.
"""

from __future__ import annotations

import argparse
import logging
import time
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np

from splitspec_core.model import steps as st
from splitspec_core.model.impairment import Impairment, sub_round
from splitspec_core.model.local_design import central_part, directions_of, scenario_agent
from splitspec_core.scenarios.load import parse_scenario_text
from splitspec_core.model.plant import initial_estimate, output_rows
from splitspec_core.model.rows import report
from splitspec_core.model.screening import FLATLINE, UNTESTED
from splitspec_core.runtime.ticks import Fence, TickNetwork
from splitspec_core.runtime.wire import Keys, WireError, decode, encode

from .measure import YBuffer

log = logging.getLogger("splitspec.agent")


class Watch(NamedTuple):
    """The sensor watch of an agent's estimate (:mod:`splitspec_core.model.screening`), committed with it."""

    #: the sensor is suspect: the agent takes its neighbours' whole estimate and no measurement
    suspect: bool = False
    #: failed tests in a row (clean ones while suspect)
    run: int = 0
    #: measurements seen since this incarnation started or another agent rejoined (its warm-up)
    seen: int = 0
    #: the last measurement given (the flat-line test's)
    last: np.ndarray | None = None


class Candidate(NamedTuple):
    """A round's result, computed, not yet committed: ``x_i(tau)`` and what goes with it."""

    tau: int
    x: np.ndarray
    g: float
    watch: Watch


class BadData(NamedTuple):
    """``design.bad_data`` as the agent is sent it (:func:`splitspec_core.synthesis.bad_data.agent_config`)."""

    S_inv: np.ndarray
    threshold: float
    suspect_after: int
    warmup: int
    flatline: bool


class RelayState(NamedTuple):
    """The relay kind's state beside the estimate (:class:`RelayPart`), committed with it."""

    base: np.ndarray
    t_base: int
    held: dict
    sent: set
    bus: dict


@dataclass(eq=False)
class Round:
    """The round in flight of an agent (``AgentNode.round``): its network row, where its exchanges stand, what it
    measured and what it reports.  Made by ``AgentNode.on_tick``, filled as messages arrive."""

    tau: int
    attempt: int
    nbs: list
    ws: list
    graph: int
    groups: object
    z: np.ndarray  # z_i(k): the state this agent sends (the relay kind: the samples of its exchange)
    P: np.ndarray  # the projection of its consensus sub-rounds (I: a suspect sensor)
    z0: tuple | None  # the (tau, attempt) of the x_j(tau) that are the neighbours' z_j(0); None: sent as z messages
    open: float | None  # when the sub-round in flight opened (deadlines only)
    k: int = 0  # the exchanges done
    stat: float = UNTESTED  # the bad-data test's statistic
    set_aside: bool = False  # the measurement failed the test (or its sensor is suspect)
    lost: list = field(default_factory=list)  # the neighbours' messages that did not count: (k, j, cause)
    used: int = 0  # the neighbours' messages that counted
    wake: float | None = None  # when on_timer is wanted
    realized: tuple | None = None  # continuous time: the neighbours' states of the step
    updated: bool = False  # the kinds that update first: y_i(tau) is in and z_i(0) sent
    y: np.ndarray | None = None  # y_i(tau) (None: none)
    watch: Watch | None = None  # the watch after this round's test
    held: dict | None = None  # the relay kind: the samples held, their keys sent, the known inputs of the walk
    sent: set | None = None
    bus: dict | None = None

#: z messages buffered for at most this many (event time, attempt) rounds per sub-round and neighbour
ZBUF_ROUNDS = 6


#: folded fusion weights an agent keeps (FusionPart)
FOLDED = 64


class FusionPart:
    """The fusion kind's part of an agent (:mod:`splitspec_core.synthesis.fusion_kind`), from its configuration's
    ``gain`` (:func:`~splitspec_core.synthesis.fusion_kind.agent_fusion`): the per-step model ``F``, ``L_i`` and
    ``{j: W_ij(k)}`` per graph, the known input's map per step (``D`` on the sampled model).  Its three steps are
    the simulator's (``kinds.Fusion``) for this agent: ``z_i(0) = x_i + L_i (y_i - C_i x_i)``; per sub-round
    ``z_i(k) = sum_j W_ij(k) z_j(k - 1)`` over the neighbours whose estimates count, the others' weights folded into
    its own; ``x_i(tau + 1) = F z_i(q) [+ B u]``."""

    def __init__(self, gain: dict, sc, C: np.ndarray):
        n, s = C.shape[1], C.shape[0]
        self.C = C
        self.F = np.asarray(gain["F"], dtype=float).reshape(n, n)
        self.L = [np.asarray(gain["L"][name], dtype=float).reshape(n, s) for name in sc.graph_names]
        self.W = [[{int(j): np.asarray(W, dtype=float).reshape(n, n) for j, W in per_k.items()}
                   for per_k in gain["weights"][name]] for name in sc.graph_names]
        self.G = None if sc.time == "discrete" else st.sampled_data_matrices(np.asarray(sc.system.A), sc.run.dt)[1]
        # fold_weights is pure: its result kept per (graph, sub-round, neighbours that count), at most FOLDED of them
        # (building the (n, 3n) matrix each sub-round was a quarter of the agent's Python time at n = 170)
        self._folded: dict = {}

    def update(self, x: np.ndarray, y, graph: int) -> np.ndarray:
        """``z_i(0)`` from ``x_i(tau)`` and ``y_i(tau)`` (None: none) on the graph of index ``graph``."""
        return st.local_update(x, self.L[graph], self.C, y)

    def fuse(self, states: list, me: int, nbs: list, graph: int, k: int) -> np.ndarray:
        """``z_i(k + 1)`` from the states of ``nbs`` (``me`` among them), the others' weights folded into its own."""
        key = (graph, k, tuple(nbs))
        W = self._folded.get(key)
        if W is None:
            if len(self._folded) >= FOLDED:
                self._folded.clear()
            W = self._folded[key] = st.fold_weights(self.W[graph][k], me, nbs)
        return st.matrix_fusion(states, W)

    def predict(self, z: np.ndarray, bu) -> np.ndarray:
        """``x_i(tau + 1) = F z_i(q) [+ B u(tau)]`` (``bu``: the known input's ``B u``, None without)."""
        return st.prediction_update(z, self.F, st.step_input(self.G, bu))


class AgentNode:
    """Protocol state of agent ``agent_id``; ``on_*`` methods return ``[(key, payload), ...]`` to publish."""

    def __init__(self, agent_id: int, config: dict, run_id: str):
        self.id = agent_id
        self.run_id = run_id
        self.keys = Keys(run_id)
        sc = parse_scenario_text(config["scenario"], source="config")
        if agent_id not in sc.agent_ids:
            raise ValueError(f"agent {agent_id} is not in the scenario (agents: {', '.join(map(str, sc.agent_ids))})")
        self.sc = sc
        self.seed = int(config["seed"])
        self.mac_key = config.get("key")
        self.extra_counts = None  # callable -> {reason: count} of drops outside the node (the inbox)
        self.index = sc.agent_ids.index(agent_id)
        d = sc.design
        self.A = np.array(sc.system.A)
        self.C = np.asarray(sc.system.Cs[self.index])
        self.n, self.s = sc.n, self.C.shape[0]
        gain = config.get("gain")
        # the fusion kind (synthesis/fusion_kind.py): L_i and W_ij(k) per graph, the per-step model; P_i = I
        self.fusion = FusionPart(gain, sc, self.C) if gain is not None and gain.get("consensus") == "fusion" else None
        # the relay kind (synthesis/relay.py): the samples passed on, the walk's gains by lag
        self.relay = RelayPart(gain, sc, self.index) if gain is not None and gain.get("consensus") == "relay" else None
        if self.fusion is not None or self.relay is not None:
            self.K, self.P, self.V, self.whole = np.zeros((self.n, self.s)), np.eye(self.n), np.zeros((self.n, 0)), False
        elif gain is not None:  # a gain the design chose centrally (design.gains: optimal, or design.consensus: whole)
            self.K, self.P, self.V = central_part(gain, self.n, self.s)
            self.whole = gain["consensus"] == "whole"
        else:
            # the local part of the design: V_i, P_i, K_i from (A, C_i, lam) (minus W, what no agent sees, if sent)
            local = scenario_agent(sc, agent_id, unobserved=directions_of(config.get("unobserved"), sc.n))
            self.K, self.P, self.V = local.K, local.P, local.V_adaptive
            self.whole = False
        # continuous: the paper's sampled-data form with g; the whole-state design runs q exchanges per run.dt
        self.continuous = sc.time == "continuous" and not self.whole and self.fusion is None and self.relay is None
        self.G = None
        if self.fusion is not None or self.relay is not None:
            self.exchanges, self.adaptive, self.g0 = int(config["q"]), False, 0.0
        elif self.whole:  # update, then average q times, on the per-step model (steps.step_matrices)
            dt = sc.run.dt if sc.time == "continuous" else None
            self.A, self.F, self.K, self.G = st.step_matrices(self.A, self.K, self.C, dt=dt)
            self.exchanges = int(config["q"])
            self.adaptive = False
            self.g0 = 0.0
        elif self.continuous:
            self.E, self.D, _ = st.sampled_data_matrices(self.A, sc.run.dt)
            self.dt = sc.run.dt
            self.adaptive = config["g_mode"] == "adaptive"
            self.g0 = float(d.g0) if self.adaptive else float(config["g"])
            self.exchanges = 1
        else:
            self.F = self.A + self.K @ self.C
            self.exchanges = int(config["q"])
            self.adaptive = False
            self.g0 = 0.0
        # potential in-neighbours over every graph (subscriptions)
        self.in_neighbours = sorted({j for g in sc.graphs for j, i in g.arcs if i == agent_id})
        self.zbuf_limit = ZBUF_ROUNDS * self.exchanges * max(1, len(self.in_neighbours))
        self.tick_tag = None  # (tau, attempt) of the last accepted tick
        self.fence = Fence()  # the highest orchestrator epoch seen (the shell's, shared with its control messages)
        self.net = TickNetwork(agent_id, sc.agent_ids)  # the network of the last tick that carried one
        self.x = None  # committed x_i(tau)
        self.g = self.g0
        self.tau = None  # tau of the committed estimate
        self.incarnation = None
        self.round = None  # dict of the round in flight
        self.candidate: Candidate | None = None  # computed, not yet committed
        self.zbuf: dict = {}  # (tau, attempt, k) -> {j: z_j}
        self.xbuf: dict = {}  # (tau, attempt of round tau - 1) -> {j: x_j(tau)}: the next round's z_j(0)
        rows = output_rows(sc.system.Cs)
        self.ys = YBuffer(agent_id, rows[self.index], rows[-1].stop, B=sc.system.B)  # y_i(tau) or none; B u(tau)
        self.sampler = self.input_sampler = None  # live sensor and live inputs (sources:, agents/sensor.py)
        self.record_y = bool(config.get("record_y", False))  # report the y_i used (measurements, live sensors)
        self.rejected: dict = {}
        # design.bad_data (splitspec_core.synthesis.bad_data): the design's S_i^-1, threshold, k and warm-up; the watch
        # (suspect, run, measurements seen by this incarnation: its warm-up) of x_i(tau)
        bd = config.get("bad_data")
        self.bad = None if bd is None else BadData(np.asarray(bd["S_inv"], dtype=float).reshape(self.s, self.s),
                                                   float(bd["threshold"]), int(bd["suspect_after"]), int(bd["warmup"]),
                                                   bool(bd.get("flatline", False)))
        # suspect, failures (or clean tests) in a row, measurements seen (the warm-up), the last measurement given
        self.watch = Watch()
        self.watched = None  # every agent's incarnation at the last round taken part in: a higher one is a rejoin
        # a misbehaving network (splitspec_core.model.impairment): the same draws as the simulator's, a deadline per
        # sub-round, messages held for their delay; the clock is only read when a deadline or a delay is set
        net = sc.network
        self.imp = Impairment(net, self.seed) if net.impaired else None
        self.deadline = net.deadline
        self.delayed = net.delayed
        self.undrawn = not (net.lossy or net.delayed)  # no loss, no delay: at most a deadline (_neighbour_states)
        self.clock = time.monotonic
        self.arrived: dict = {}  # ("z" | "x", buffer tag) -> {agent: when its message arrived} (delays only)

    # ------------------------------------------------------------------ helpers

    def reject(self, reason: str) -> None:
        self.rejected[reason] = self.rejected.get(reason, 0) + 1

    def counts(self) -> dict:
        """Running totals of rejected messages per reason (the node's and the inbox's)."""
        out = dict(self.rejected)
        for reason, c in (self.extra_counts() if self.extra_counts else {}).items():
            out[reason] = out.get(reason, 0) + c
        return out

    def _xhat(self, tau: int, attempt: int, x: np.ndarray, columns: dict, lost=(), y=(), u=None) -> tuple:
        """The ``xhat`` message of ``x_i(tau)`` with the row columns this agent reports (``columns``:
        :func:`splitspec_core.model.rows.report`); ``y`` and ``u``: the measurement and the live known inputs
        its round used (reported when the run records them, ``record_y``; ``u`` only with live inputs)."""
        used = ([] if not self.record_y else None if y is None else [float(v) for v in y])
        took = [] if u is None or not self.record_y else [float(v) for v in u]
        return (self.keys.xhat(self.id), encode("xhat", self.run_id, mac_key=self.mac_key, tau=tau, attempt=attempt,
                                                  agent=self.id, incarnation=int(self.incarnation), x=x, **columns,
                                                  rejected=self.counts(), lost=[v for t in lost for v in t], y=used,
                                                  u=took))

    def next_wakeup(self) -> float | None:
        """When the round in flight wants :meth:`on_timer` (a sub-round's deadline, a held message's release)."""
        return self.round.wake if self.round is not None else None

    def on_timer(self) -> list:
        """The clock reached :meth:`next_wakeup`: go on with what has arrived."""
        return self._advance()

    def _z(self, k: int, z: np.ndarray) -> tuple:
        r = self.round
        return (self.keys.z(self.id), encode("z", self.run_id, mac_key=self.mac_key, tau=r.tau,
                                               attempt=r.attempt, k=k, agent=self.id, z=z))

    def _relayed(self, k: int, samples: dict) -> tuple:
        """The relay kind's exchange ``k``: the samples' values side by side, ``[sensor, t, ...]`` which they are."""
        r, vals = self.round, list(samples.values())
        return (self.keys.z(self.id), encode("r", self.run_id, mac_key=self.mac_key, tau=r.tau, attempt=r.attempt,
                                               k=k, agent=self.id, z=np.concatenate(vals) if vals else np.zeros(0),
                                               samples=[int(v) for key in samples for v in key]))

    # ------------------------------------------------------------------ inputs

    def on_tick(self, payload: bytes) -> list:
        try:
            t = decode(payload, self.run_id, "tick", mac_key=self.mac_key)
        except WireError as e:
            self.reject(e.reason)
            return []
        if not self.fence.admit(t):  # a superseded orchestrator's (a standby took over): never obeyed
            self.reject("fenced")
            return []
        tau, attempt = t["tau"], t["attempt"]
        out = []
        if self.tick_tag is not None:
            if (tau, attempt) <= self.tick_tag:
                self.reject("stale")
                return []
            if tau > self.tick_tag[0] + 1:
                self.reject("future")
                return []
        self.tick_tag = (tau, attempt)
        # the network rides only on the ticks where it changed (runtime.ticks); one this agent never got: no part
        known = self.net.update(t) or self.reject("unknown_topology")
        me = self.net.row if known else None
        if self.candidate is not None:
            if self.candidate.tau == tau and me is not None:  # commit x_i(tau) (and the watch after round tau - 1)
                self.x, self.g, self.watch = self.candidate.x, self.candidate.g, self.candidate.watch
                self.tau = tau
                if self.relay is not None:  # and the relay kind's state after round tau - 1
                    self.relay.commit(tau)
            self.candidate = None
        if me is None:  # not taking part (lost, or not admitted yet)
            self.round = None
            if known and self.x is not None and not self.net.alive:
                self.x = None  # we were declared lost: a rejoin starts afresh
            return []
        inc, incs = self.net.incarnation, self.net.incarnations
        if self.whole and self.watched is not None and any(v > self.watched.get(j, 0) for j, v in incs.items()):
            # another agent rejoined with a fresh estimate, averaged into this one's: a sensor not suspect warms up
            # afresh (Screen.rejoined; the split's consensus leaves what this agent measures alone)
            self.watch = self.watch if self.watch.suspect else self.watch._replace(seen=0)
        self.watched = dict(incs)
        if self.x is None or inc != self.incarnation or self.tau != tau:
            # admission (start or rejoin): a fresh estimate of this incarnation, reported first
            self.incarnation = int(inc)
            self.x = initial_estimate(self.n, self.seed, self.index, self.incarnation)
            if self.relay is not None:
                self.relay.start(self.x, tau)
            self.g = self.g0
            self.tau = tau
            self.watch = Watch()  # a fresh sensor watch and warm-up (model/screening.py: Screen.reset)
            out.append(self._xhat(tau, attempt, self.x, report(g=self.g)))
        # drop buffers of older rounds
        self.zbuf = {k: v for k, v in self.zbuf.items() if (k[0], k[1]) >= (tau, attempt)}
        self.xbuf = {k: v for k, v in self.xbuf.items() if k[0] >= tau}
        self.ys.prune(tau)
        if self.sampler is not None and not t["final"]:  # a live sensor: y_i(tau) is its value now (sensor.py)
            self.ys.put_sample(tau, self.sampler.take(),  # and the live known inputs' u(tau), if any
                               None if self.input_sampler is None else self.input_sampler.take())
        if self.arrived:
            self.arrived = {k: v for k, v in self.arrived.items() if k[1][0] >= tau}
        if t["final"]:
            self.round = None
            return out
        nbs, ws = me
        # z_j(0): sent as such in a fresh or re-run round, else the x_j(tau) of round (tau - 1, prev_attempt)
        explicit = bool(t["fresh"]) or attempt > 0
        # a suspect sensor: this round takes the neighbours' whole estimate (P_i = I) and no measurement
        update_first = self.whole or self.fusion is not None or self.relay is not None  # z_i(0) once y_i(tau) is in
        self.round = Round(tau=tau, attempt=attempt, nbs=nbs, ws=ws, graph=int(t["graph"]), groups=self.net.groups,
                           z=self.x.copy(), P=np.eye(self.n) if self.watch.suspect else self.P,
                           z0=None if explicit or update_first else (tau, int(t["prev_attempt"])),
                           open=self.clock() if self.deadline is not None else None)
        if explicit and not update_first:
            out.append(self._z(0, self.round.z))
        return out + self._advance()

    def _from_neighbour(self, msg_type: str, field: str, key: str, payload: bytes) -> dict | None:
        """A neighbour's z or x message, decoded, from the agent its key names, with an n-vector; else counted."""
        try:
            m = decode(payload, self.run_id, msg_type, mac_key=self.mac_key)
        except WireError as e:
            self.reject(e.reason)
            return None
        if str(m["agent"]) != Keys.last(key):
            self.reject("wrong_sender")
            return None
        if msg_type == "r":  # the relay kind's samples: they fit their values and their event time's window
            m[field] = self.relay.parse(m, self.sc.m)
            if m[field] is None:
                self.reject("bad_field")
            return m if m[field] is not None else None
        if m[field].shape != (self.n,):
            self.reject("bad_shape")
            return None
        return m

    def _store(self, buf: dict, tag: tuple, agent: int, value: np.ndarray) -> list:
        """Buffer a neighbour's vector under ``tag`` (one per agent and tag, at most ``zbuf_limit`` in ``buf``)."""
        slot = buf.get(tag)
        if slot is not None and agent in slot:
            self.reject("duplicate")
            return []
        if sum(len(v) for v in buf.values()) >= self.zbuf_limit:
            self.reject("buffer_full")
            return []
        buf.setdefault(tag, {})[agent] = value
        if self.delayed:
            self.arrived.setdefault(("x" if buf is self.xbuf else "z", tag), {})[agent] = self.clock()
        return self._advance()

    def on_z(self, key: str, payload: bytes) -> list:
        m = self._from_neighbour("r" if self.relay is not None else "z", "z", key, payload)
        if m is None:
            return []
        r = self.round
        tag = (m["tau"], m["attempt"])
        # before the first tick nothing is stale: a neighbour may have started the first round already
        stale = self.tau is not None and tag < ((self.tau, -1) if r is None else (r.tau, r.attempt))
        if stale or not 0 <= m["k"] < self.exchanges:
            self.reject("stale" if stale else "bad_k")
            return []
        # the next legitimate round is at most one event time ahead of the last tick (a neighbour may
        # have seen the next tick first), and at most two attempts ahead within the same event time
        if self.tick_tag is not None:
            t_tau, t_att = self.tick_tag
            if m["tau"] > t_tau + 1 or (m["tau"] == t_tau and m["attempt"] > t_att + 2):
                self.reject("future")
                return []
        return self._store(self.zbuf, (m["tau"], m["attempt"], m["k"]), m["agent"], m["z"])

    def on_y(self, payload: bytes) -> list:
        try:
            m = decode(payload, self.run_id, "y", mac_key=self.mac_key)
        except WireError as e:
            self.reject(e.reason)
            return []
        kept = self.ys.put_message(m, last_tau=self.tau, tick_tau=self.tick_tag[0] if self.tick_tag else None,
                                   reject=self.reject)
        return self._advance() if kept else []

    def on_x(self, key: str, payload: bytes) -> list:
        """A neighbour's new estimate x_j(tau) (its report to the orchestrator): the next round's z_j(0)."""
        m = self._from_neighbour("xhat", "x", key, payload)
        if m is None:
            return []
        if self.tick_tag is not None:
            t_tau, t_att = self.tick_tag
            # x_j(tau + 1) of the round in flight, x_j(tau) (an admission report), or x_j(tau + 2): when round
            # tau + 1 needs nothing new from this agent (continuous time, q = 1: z(0) is x(tau + 1), already
            # sent; or live sensors: no plant to wait for), a neighbour can finish it before this agent has read
            # tick tau + 1; the orchestrator cannot tick tau + 2 before this agent's x(tau + 2), so nothing honest
            # is further ahead.  At most two attempts ahead.
            if m["tau"] < t_tau or m["tau"] > t_tau + 2:
                self.reject("stale" if m["tau"] < t_tau else "future")
                return []
            if m["attempt"] > t_att + 2:
                self.reject("future")
                return []
        return self._store(self.xbuf, (m["tau"], m["attempt"]), m["agent"], m["x"])

    # ------------------------------------------------------------------ the round

    def _neighbour_states(self, k: int):
        """``(nbs, ws, states)`` of the sub-round using the neighbours' ``z_j(k)``, or None while it waits.

        Every neighbour's message counts unless a partition in force cuts it, it is drawn lost, or (with a
        deadline) it has not arrived, and been held for its delay, by the deadline: the sub-round then goes on
        with what it has (:func:`~splitspec_core.model.impairment.realized_row`) and records what did not count.
        """
        r = self.round
        if k == 0 and r.z0 is not None:  # eq. split-discrete-p1: z_j(0) = x_j(tau), sent as x_j's report
            kind, tag = "x", r.z0
        else:
            kind, tag = "z", (r.tau, r.attempt, k)
        slot = (self.xbuf if kind == "x" else self.zbuf).get(tag, {})
        if self.undrawn and not r.groups:  # sub_round's decisions without it: only a deadline can drop a message
            if all(j in slot for j in r.nbs if j != self.id):  # every message on time: the whole row
                r.wake = None
                r.used += sum(1 for j in r.nbs if j != self.id)  # the neighbours' messages it counts
                return r.nbs, r.ws, [r.z if j == self.id else slot[j] for j in r.nbs]
            if self.deadline is None or self.clock() < r.open + self.deadline:  # wait (for all, or till then)
                r.wake = None if self.deadline is None else r.open + self.deadline
                return None
            # past the deadline: sub_round records the missing messages as late
        now = self.clock() if (self.delayed or self.deadline is not None) else 0.0
        arrived = self.arrived.get((kind, tag), {}) if self.delayed else None
        got = sub_round(self.imp, self.sc.design.weights, tau=r.tau, k=k + 1, me=self.id, nbs=r.nbs,
                        ws=r.ws, have=slot, groups=r.groups, now=now, opened=r.open or 0.0, arrived=arrived)
        if got[0] == "wait":
            r.wake = got[1]
            return None
        _, nbs, ws, lost = got
        r.wake = None
        r.lost += lost
        r.used += sum(1 for j in nbs if j != self.id)  # the neighbours' messages it counts
        return nbs, ws, [r.z if j == self.id else slot[j] for j in nbs]

    def _opened(self) -> None:
        """The next sub-round opens now (its deadline counts from here)."""
        if self.deadline is not None:
            self.round.open = self.clock()

    def _advance(self) -> list:
        r = self.round
        out = []
        if r is None:
            return out
        if self.whole:
            return self._advance_whole(r)
        if self.fusion is not None:
            return self._advance_fusion(r)
        if self.relay is not None:
            return relay_round(self, r)
        if self.continuous:
            if r.realized is None:
                got = self._neighbour_states(0)
                if got is None:
                    return out
                r.realized = got
            _, ws, states = r.realized
            if not self.ys.ready(r.tau):
                return out
            y = self.ys.get(r.tau)  # None: no measurement, the step without its innovation
            bu = self.ys.bu(r.tau)  # the known input's B u(tau) (None: no inputs)
            x_next = st.sampled_step(self.x, self.E, self.D, self.K, self.C, screen_round(self, self.x, y), r.P, self.g,
                                     states, ws, bu)
            g_next = self.g
            if self.adaptive:
                g_next = st.adaptive_gain_step(self.g, st.adaptive_gain_rate(self.V, self.x, states, ws), self.dt)
            return self._finish(x_next, g_next, y)
        while r.k < self.exchanges:
            got = self._neighbour_states(r.k)
            if got is None:
                return out
            _, ws, states = got
            # eq. split-discrete-p2 (over the neighbours whose message counts: impairment.realized_row)
            r.z = st.consensus_subround(r.z, r.P, states, ws)
            r.k += 1
            self._opened()
            if r.k < self.exchanges:
                out.append(self._z(r.k, r.z))
        if not self.ys.ready(r.tau):
            return out
        y = self.ys.get(r.tau)
        # eq. split-discrete-est1, or the prediction without a measurement (none, or set aside by the test)
        bu = self.ys.bu(r.tau)
        used = screen_round(self, r.z, y)
        x_next = st.prediction_update(r.z, self.A, bu) if used is None else \
            st.measurement_update(r.z, self.F, self.K, used, bu)
        return out + self._finish(x_next, 0.0, y)

    def _advance_whole(self, r: dict) -> list:
        """The whole-state design's round (synthesis/whole_state.py): once ``y_i(tau)`` is in, the update
        ``z_i(0) = F_i x_i(tau) - K_i y_i(tau) [+ B u]`` (its prediction without a measurement), sent; then q sub-rounds
        ``z_i(k) = sum_j w_ij z_j(k - 1)``; ``x_i(tau + 1) = z_i(q)``."""

        def update(y):
            bu = st.step_input(self.G, self.ys.bu(r.tau))
            used = screen_round(self, self.x, y)
            return st.prediction_update(self.x, self.A, bu) if used is None else \
                st.measurement_update(self.x, self.F, self.K, used, bu)

        # eq. split-discrete-p2 with P_i = I
        return self._update_then_exchange(r, update, lambda got, k: st.weighted_average(got[2], got[1]), lambda z: z)

    def _advance_fusion(self, r: dict) -> list:
        """The fusion kind's round (:class:`FusionPart`), as the simulator's ``kinds.Fusion`` runs it for this agent."""
        part, g = self.fusion, r.graph

        def update(y):
            r.watch = self.watch
            return part.update(self.x, y, g)

        return self._update_then_exchange(r, update, lambda got, k: part.fuse(got[2], self.id, got[0], g, k),
                                          lambda z: part.predict(z, self.ys.bu(r.tau)))

    def _update_then_exchange(self, r: dict, update, combine, finish) -> list:
        """The round of the kinds that update first (the whole state, fusion): once ``y_i(tau)`` is in,
        ``z_i(0) = update(y_i)`` (sent); per sub-round ``z_i(k) = combine((nbs, ws, states), k - 1)`` over the
        neighbours whose estimates count; ``x_i(tau + 1) = finish(z_i(q))``."""
        out = []
        if not r.updated:
            if not self.ys.ready(r.tau):
                return out
            r.y, r.updated = self.ys.get(r.tau), True
            r.z = update(r.y)
            self._opened()
            out.append(self._z(0, r.z))
        while r.k < self.exchanges:
            got = self._neighbour_states(r.k)
            if got is None:
                return out
            r.z = combine(got, r.k)
            r.k += 1
            self._opened()
            if r.k < self.exchanges:
                out.append(self._z(r.k, r.z))
        return out + self._finish(finish(r.z), 0.0, r.y)

    def _finish(self, x_next: np.ndarray, g_next: float, y) -> list:
        r = self.round
        self.candidate = Candidate(r.tau + 1, x_next, g_next, r.watch if r.watch is not None else self.watch)
        self.round = None
        # the row columns of x_i(tau + 1): g_i(tau + 1) and what round tau measured (splitspec_core.model.rows)
        columns = report(g=g_next, messages_used=r.used, y_rejected=r.set_aside, y_statistic=r.stat)
        # the live known inputs the round added (B u(tau), measure.YBuffer.bu): recorded beside y (trajectory u)
        u = self.ys.ubuf.get(r.tau) if self.input_sampler is not None else None
        return [self._xhat(r.tau + 1, r.attempt, x_next, columns, r.lost, y, u)]


class RelayPart:
    """The relay kind's part of an agent (:mod:`splitspec_core.synthesis.relay`), from its configuration's ``gain``
    (:func:`~splitspec_core.synthesis.relay.agent_relay`): the per-step model ``F``, the stacked ``C``, its gains by
    lag, every sensor's rows.  Its state (the base, its event time, the samples held and sent, the known inputs'
    ``B u(t)`` of the walk) is committed with the estimate; a round works on copies.  Its steps are the simulator's
    (``kinds.Relay``) for this agent: its own sample held, per exchange ``relay_forward`` (sent) and the counted
    neighbours' samples held, then ``relay_walk`` and ``relay_prune``."""

    def __init__(self, gain: dict, sc, index: int):
        self.F = np.asarray(gain["F"], dtype=float)
        self.C = np.asarray(gain["C"], dtype=float).reshape(-1, sc.n)
        self.table = [np.asarray(G, dtype=float).reshape(sc.n, -1) for G in gain["gains"]]
        self.D = len(self.table) - 1
        self.rows = [np.arange(a, b, dtype=np.int64) for a, b in gain["rows"]]
        self.index = index
        self.G = None if sc.time == "discrete" else st.sampled_data_matrices(np.asarray(sc.system.A), sc.run.dt)[1]
        self.state: RelayState | None = None
        self.candidate: tuple | None = None  # (tau + 1, the RelayState after the round)

    def start(self, x: np.ndarray, tau: int) -> None:
        """A start or a restart at ``tau``: the estimate is the base, nothing held."""
        self.state, self.candidate = RelayState(np.array(x, dtype=float), int(tau), {}, set(), {}), None

    def commit(self, tau: int) -> None:
        """The round's state becomes the agent's, with its estimate of ``tau``."""
        if self.candidate is not None and self.candidate[0] == tau:
            self.state = self.candidate[1]
        self.candidate = None

    def open(self, r: dict, y, bu) -> None:
        """The round's copies, its own sample ``y_i(tau)`` held (None: none), ``B u(tau)`` kept."""
        r.held, r.sent, r.bus = dict(self.state.held), set(self.state.sent), dict(self.state.bus)
        if y is not None:
            r.held[(self.index, r.tau)] = np.array(y, dtype=float)
        bu = st.step_input(self.G, bu)
        if bu is not None:
            r.bus[r.tau] = bu

    def forward(self, r: dict) -> dict:
        """What this exchange sends: the samples held and not sent (now sent)."""
        out = st.relay_forward(r.held, r.sent)
        r.sent |= set(out)
        return out

    def parse(self, m: dict, m_agents: int) -> dict | None:
        """An ``r`` message's samples ``{(sensor, t): y_j(t)}``, or None when they do not fit its values or its
        event time's window."""
        keys, vals, at, out = m["samples"], m["z"], 0, {}
        for j, t in zip(keys[::2], keys[1::2]):
            if not 0 <= j < m_agents or not m["tau"] - self.D <= t <= m["tau"] or (j, t) in out:
                return None
            size = len(self.rows[j])
            out[(j, t)], at = vals[at:at + size], at + size
        return out if at == len(vals) else None

    def walk(self, r: dict) -> np.ndarray:
        """``x_i(tau + 1)`` by the walk; the state after it kept as the candidate."""
        tau = r.tau
        base, t_base = self.state.base, self.state.t_base
        samples = st.relay_samples(r.held, self.rows, t_base, tau)
        base, t_base, x = st.relay_walk(base, t_base, tau, self.table, self.F, self.C, samples, r.bus or None)
        cut = tau - self.D + 1  # no walk starts before: the older samples are no longer held or sent
        bus = {t: v for t, v in r.bus.items() if t >= cut}
        self.candidate = (tau + 1, RelayState(base, t_base, st.relay_prune(r.held, cut),
                                              {h for h in r.sent if h[1] >= cut}, bus))
        return x


def relay_round(node: "AgentNode", r: dict) -> list:
    """The relay kind's round of ``node`` (:class:`RelayPart`), as the simulator's ``kinds.Relay`` runs it for this
    agent: once ``y_i(tau)`` is in, exchange ``k`` sends what it holds and has not sent, then holds what the counted
    neighbours sent; after ``q`` exchanges the walk."""
    part, out = node.relay, []
    if r.held is None:
        if not node.ys.ready(r.tau):
            return out
        r.y = node.ys.get(r.tau)
        r.watch = node.watch
        part.open(r, r.y, node.ys.bu(r.tau))
        node._opened()
        r.z = part.forward(r)
        out.append(node._relayed(0, r.z))
    while r.k < node.exchanges:
        got = node._neighbour_states(r.k)
        if got is None:
            return out
        for j, samples in zip(got[0], got[2]):
            if j != node.id:
                r.held.update(samples)
        r.k += 1
        node._opened()
        if r.k < node.exchanges:
            r.z = part.forward(r)
            out.append(node._relayed(r.k, r.z))
    return out + node._finish(part.walk(r), 0.0, r.y)


def screen_round(node, z: np.ndarray, y):
    """Agent ``node``'s bad-data test of ``y_i(tau)`` against ``z`` (what the update applies K_i to): ``y`` if it is used,
    None if there is none or it is set aside (failed, or the sensor suspect); the round keeps ``d_i`` and the
    watch after it (committed with the estimate).  Exactly :class:`splitspec_core.model.screening.Screen`."""
    r = node.round
    r.watch = node.watch
    if node.bad is None:
        return y
    bad, watch = node.bad, node.watch
    seen, tested = st.warmup_step(watch.seen, y is not None, bad.warmup)
    last = watch.last
    y_i = None if y is None else np.array(y, dtype=float)
    r.watch = watch._replace(seen=seen, last=last if y_i is None else y_i)
    if not tested:
        r.stat = UNTESTED
        return y
    d, failed = st.innovation_test(y_i, node.C, z, bad.S_inv, bad.threshold)
    if bad.flatline and st.flatline(y_i, last):
        d, failed = FLATLINE, True
    r.stat = d
    suspect, run, _ = st.sensor_watch(watch.suspect, watch.run, failed, bad.suspect_after)
    r.watch = Watch(suspect, run, seen, y_i)
    if watch.suspect or failed:
        r.set_aside = True
        return None
    return y


# ---------------------------------------------------------------------- process shell


def build_parser(prog: str = "python -m splitspec_agents") -> argparse.ArgumentParser:
    """The agent process's options (also ``splitspec agent ...``, which hands its arguments here)."""
    from splitspec_core.runtime.cli import ArgumentParser, add_logging_options, add_node_options

    p = ArgumentParser(prog=prog, description="One agent process: fetches its part of the design, computes V_i, P_i, K_i "
                       "locally and runs the protocol.")
    p.add_argument("--id", required=True, type=int, help="agent id (as in the scenario's system.C)")
    add_node_options(p)
    add_logging_options(p)
    return p


def cli_main(argv: list | None = None, *, prog: str = "python -m splitspec_agents") -> int:
    """Parse ``argv`` and run the agent inside the shared error boundary; the exit status."""
    from splitspec_core.runtime.cli import node_cli

    return node_cli(build_parser, main, argv, prog)


def main(args: argparse.Namespace) -> int:
    """``splitspec agent --id I --connect ENDPOINT [--run-id ID] [--credentials FILE]``."""
    from splitspec_core.runtime.node import NodeShell

    keys = Keys(args.run_id)  # required on the command line
    shell = NodeShell(args.connect, keys, log=log, role="agent", ident=args.id, credentials=args.credentials,
                      wait=args.wait)
    try:
        node = AgentNode(args.id, shell.fetch_config(wait=args.wait), keys.run_id)
        node.extra_counts = shell.inbox.take_dropped
        node.fence = shell.fence
        handlers = {"tick": lambda key, p: node.on_tick(p), "z": node.on_z, "x": node.on_x,
                    "y": lambda key, p: node.on_y(p)}
        subscriptions = ([(keys.tick, "tick"), (keys.y, "y")] + [(keys.z(j), "z") for j in node.in_neighbours]
                         + ([] if node.whole else [(keys.xhat(j), "x") for j in node.in_neighbours]))
        if node.sc.sources:
            from .sensor import attach

            sensor_sub = attach(node, shell, keys)  # noqa: F841 - held: a dropped subscriber is undeclared
        timed = node.deadline is not None or node.delayed  # sub-rounds with a deadline, messages held for a delay
        return shell.run(lambda ch, key, p: handlers[ch](key, p), node.reject,
                         name=f"agent {args.id} (q = {node.exchanges})", subscriptions=subscriptions,
                         timer=(node.next_wakeup, node.on_timer) if timed else None)
    finally:
        shell.close()
