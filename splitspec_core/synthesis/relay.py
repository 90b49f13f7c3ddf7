"""The relay kind: the agents pass the sensors' samples on, and each runs the Kalman predictor of what it holds.

The estimator
-------------
Inside the paper's two-rate protocol (eqs. split-discrete-est1 .. p3: measure, ``q`` exchanges, predict), each
exchange carries *samples*, not estimates: agent i sends the samples ``y_j(t)`` it has not sent before, its own
``y_i(tau)`` first.  A sensor ``d_ij`` hops away then reaches agent i ``delta_ij = max(0, ceil(d_ij / q) - 1)`` event
times late (:func:`~.exchange_limit.information_delays`), the fewest the protocol allows, so with ``D = max delta``
every agent holds every sensor's samples up to ``tau - D`` and, at ``t = tau - D + 1 .. tau``, those of the sensors
with ``delta_ij <= tau - t``.  Agent i keeps one estimate ``b_i`` of ``x(tau - D)`` (the *base*) and, each event
time, walks it forward over the samples it holds (:func:`~splitspec_core.model.steps.relay_step`, predictor form)::

    b_i <- F b_i + L (y(tau - D) - C b_i)                          every sensor, the base's gain L
    e   <- F e + L_il (y_H(tau - l) - C_H e),  l = D - 1, .., 0     from e = b_i; H = {j: delta_ij <= l}
    x_i(tau + 1) = e          [+ the known input's B u(t) at each step]

``L`` is the centralized Kalman predictor's gain (shifted by the rate when that is too slow, below) and ``L_il`` the
Kalman gains of the walk given the base's steady covariance; so at ``alpha = 1`` each agent's estimate is exactly the
protocol's limit (:mod:`.exchange_limit`: the Kalman predictor fed each sensor ``delta_ij`` late), whatever
``q``.  A sample that did not arrive (an agent lost, a message lost) is left out of its step: the columns of the
samples held are applied.  An agent that starts (or starts again) at ``tau_0`` takes its initial estimate as the
base at ``tau_0`` and walks from there; its base moves on once it is ``D`` event times behind.

What each agent sends: every sample once (its own, and each it relays), so about ``p`` numbers per event time
(``p`` the outputs of all the sensors) whatever ``q``, in ``q`` messages; the fusion kind sends ``q n``.  Where the
sensors are few and the state large (a power system's PMUs), that is the cheaper message by far.

What certifies it
-----------------
The agents' errors do not couple: the base's error obeys ``e_b(t + 1) = M e_b(t) + noise``, ``M = F - L C``, the same
map for every agent, and agent i's estimate is the walk's fixed map ``G_i`` of it.  The rate: ``rho(M)`` below
``lam`` per event time.  The envelope (noise-free, from the initial errors): ``||e_i(tau)|| <= c_i lam^tau
||e_i(0)||`` with ``c_i`` the larger of the walk's start (the first ``D`` event times, exactly) and
``||G_i|| c_M lam^-D``, ``c_M`` the transient constant of ``M`` (:func:`.conditioning.transient_constant`): ``n x n``
maps only, whatever ``m``.  The accuracy: the base's steady covariance (a Lyapunov equation of size ``n``), walked
through each agent's ``D`` steps (Joseph form): exact for the gains used.

When the Kalman predictor is slower than the rate, ``L`` is the Riccati predictor of ``F / alpha``
(:func:`~.kalman.shifted_predictor`), ``alpha`` the largest in ``[lam, 1]`` whose gain certifies, by bisection
(:data:`ALPHA_STEPS`); the walk's gains stay the Kalman gains of the base's true covariance.

The graph must be fixed: the walk's gains are those of one graph's delays.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import scipy.linalg as sla

from ..errors import DesignError
from ..model.plant import output_rows
from ..scenarios.specs import Scenario
from .exchange_limit import hop_distances, information_delays, network_model, protocol_limit
from .kalman import kalman_predictor, per_step_rate, regularise, shifted_predictor, spectral_radius, steady_covariance
from .spectral import certifies

__all__ = ["RelayDesign", "ALPHA_STEPS", "AUTO_GAP", "design_relay", "scenario_relay", "relay_gains", "walk_maps",
           "relay_transient", "relay_q", "agent_relay", "survivors_radius", "gain_table", "LAG_MAX", "AUTO_LAG",
           "relay_design", "refusal_text"]

#: Riccati equations (of size n) the search of the shift alpha in [lam, 1] solves at most (regula falsi, Illinois)
ALPHA_STEPS = 10
#: ... stopping once the bracket is narrower than this fraction of 1 - lam
ALPHA_TOL = 1e-3
#: ... aiming at a radius this fraction of 1 - lam below the rate (a radius a hair below it certifies with a transient
#: constant without bound: the platoon's 0.69999991 against 0.7 gave 2e5, 0.699982 gave 56)
ALPHA_MARGIN = 5e-3
#: ``design.lag: auto``: the most extra event times the base is kept behind
LAG_MAX = 20
#: ``design.lag: auto``: one more event time behind (one more step of the walk per agent and event time) is taken
#: while it lowers the predicted RMS by at least this fraction (the IEEE 39-bus model at q = 3: 0.1 % a step, none
#: taken; the platoon at q = 3: 5 % for the first, 15 taken)
AUTO_LAG = 2e-3
#: ``design.q: auto``: the smallest q whose protocol limit is within this fraction of the Kalman predictor (as the
#: fusion kind's; more exchanges send no more numbers here, only more messages)
AUTO_GAP = 0.01


@dataclass(frozen=True)
class RelayDesign:
    """A relay design: the gains, what they certify and what they are predicted to give.

    Attributes
    ----------
    q : int
        Exchanges per event time.
    delays : (m, m) int array
        ``delta_ij``: event times agent i holds sensor j's samples late.
    F : (n, n) array
        The per-step model.
    L : (n, p) array
        The base's gain on every sensor's rows (stacked in agent order).
    walk : tuple of tuple of (rows, L_il)
        ``walk[i][l]`` for ``l = 0 .. D - 1``: the stacked rows agent i holds at lag ``l`` (int array) and their gain
        (n, len(rows)).
    alpha : float
        The shift the base's gain is designed for (1: the Kalman predictor).
    radius : float
        ``rho(F - L C)``.
    lam_step : float
        The rate per event time.
    agent_P : tuple of (n, n) array
        Each agent's predicted steady error covariance.
    kf_P_trace : float
        The centralized Kalman predictor's ``trace P``.
    limit : float
        The protocol's limit at ``q`` over the Kalman predictor's RMS.
    transient : tuple of float
        ``c_i`` per agent (module docstring); ``inf`` when not certified.
    lag : int
        Event times the base is kept behind beyond the longest delay (``design.lag``).
    """

    q: int
    delays: np.ndarray = field(repr=False)
    F: np.ndarray = field(repr=False)
    L: np.ndarray = field(repr=False)
    walk: tuple = field(repr=False)
    alpha: float
    radius: float
    lam_step: float
    agent_P: tuple = field(repr=False)
    kf_P_trace: float
    limit: float
    transient: tuple = ()
    lag: int = 0

    @property
    def D(self) -> int:
        """Event times the base is behind: the longest delay and :attr:`lag` more."""
        return (int(self.delays.max()) if self.delays.size else 0) + int(self.lag)

    @property
    def certified(self) -> bool:
        """``rho(F - L C)`` below the rate per event time (the one rule, :func:`.spectral.certifies`)."""
        return certifies(self.radius, self.lam_step)

    @property
    def agent_rms(self) -> np.ndarray:
        """Each agent's predicted steady RMS error, ``sqrt(trace P_i)``."""
        return np.sqrt(np.maximum([np.trace(P) for P in self.agent_P], 0.0))

    @property
    def ratio(self) -> float:
        """The predicted RMS over the agents relative to the centralized Kalman predictor's."""
        return float(np.sqrt(np.mean(self.agent_rms ** 2) / self.kf_P_trace))

    @property
    def kf_rms(self) -> float:
        """The centralized Kalman predictor's RMS of the error vector (``sqrt(trace P)``)."""
        return float(math.sqrt(self.kf_P_trace))

    @property
    def transient_constant(self) -> float:
        """``max_i c_i``: the envelope's constant over the stacked errors (module docstring)."""
        return max(self.transient, default=1.0)


def relay_gains(F: np.ndarray, Cs, Rs, Q: np.ndarray, delays: np.ndarray, L: np.ndarray, P_base: np.ndarray,
                lag: int = 0) -> tuple:
    """The walk's gains of every agent and its predicted steady covariance.

    Parameters
    ----------
    F : (n, n) array
        The per-step model.
    Cs, Rs : sequences of (s_j, n), (s_j, s_j) arrays
        The sensors' output matrices and noise covariances, in agent order.
    Q : (n, n) array
        The process noise covariance per step.
    delays : (m, m) int array
        ``delta_ij``.
    L : (n, p) array
        The base's gain.
    P_base : (n, n) array
        The base's steady covariance under ``L``.
    lag : int, default 0
        Event times the base is behind beyond the longest delay (every sensor held there).

    Returns
    -------
    tuple
        ``(walk, agent_P)`` as :class:`RelayDesign` holds them.
    """
    rows = output_rows(Cs)
    m, D = delays.shape[0], (int(delays.max()) if delays.size else 0) + int(lag)
    walk, agent_P = [], []
    for i in range(m):
        P, steps = np.array(P_base, dtype=float), [None] * D
        for lag in range(D - 1, -1, -1):  # the walk from tau - D + 1 to tau, the farther sensors not yet in
            held = [j for j in range(m) if delays[i, j] <= lag]
            r = np.concatenate([np.arange(rows[j].start, rows[j].stop) for j in held]).astype(np.int64) \
                if held else np.zeros(0, dtype=np.int64)
            C = np.vstack([Cs[j] for j in held]) if held else np.zeros((0, F.shape[0]))
            R = sla.block_diag(*[Rs[j] for j in held]) if held else np.zeros((0, 0))
            PC = P @ C.T
            # the predictor-form Kalman gain of the walk's step given its prior covariance P
            Lw = np.linalg.solve(C @ PC + R, (F @ PC).T).T if len(r) else np.zeros((F.shape[0], 0))
            steps[lag] = (r, Lw)
            Fc = F - Lw @ C
            P = Fc @ P @ Fc.T + Lw @ R @ Lw.T + Q  # Joseph form: exact for the gain used
            P = 0.5 * (P + P.T)
        walk.append(tuple(steps))
        agent_P.append(P)
    return tuple(walk), tuple(agent_P)


def walk_maps(F: np.ndarray, C: np.ndarray, walk_i: tuple) -> tuple:
    """Agent i's noise-free error maps: ``G_i`` (the walk from the base, lags ``D - 1 .. 0``) and ``W_tau`` for the
    first ``D`` event times after a start (lags ``tau .. 0`` from the initial estimate).

    Parameters
    ----------
    F : (n, n) array
        The per-step model.
    C : (p, n) array
        Every sensor's rows, stacked.
    walk_i : tuple of (rows, L_il)
        Agent i's walk (:class:`RelayDesign`).

    Returns
    -------
    tuple
        ``(G_i, [W_0, .., W_{D-1}])``.
    """
    n = F.shape[0]

    def step(lag):
        r, Lw = walk_i[lag]
        return F - Lw @ C[r]

    D = len(walk_i)
    starts, W = [], np.eye(n)
    for tau in range(D):  # W_tau = step(0) .. step(tau): the walk from lag tau down, the last step applied first
        W = W @ step(tau)
        starts.append(W)
    return (starts[-1] if starts else np.eye(n)), starts


def gain_table(r: RelayDesign, i: int) -> list:
    """Agent ``i``'s gains by lag, each on every stacked row: ``[G_0, .., G_D]``, ``G_D`` the base's, zero columns
    for the rows not held at that lag (:func:`splitspec_core.model.steps.relay_walk`).

    Parameters
    ----------
    r : RelayDesign
        The design.
    i : int
        The agent's position.

    Returns
    -------
    list of (n, p) ndarray
    """
    n, p = r.L.shape
    out = []
    for rows, Lw in r.walk[i]:
        G = np.zeros((n, p))
        G[:, rows] = Lw
        out.append(G)
    return out + [np.asarray(r.L)]


def relay_transient(F: np.ndarray, C: np.ndarray, L: np.ndarray, walk: tuple, lam: float) -> tuple:
    """``c_i`` per agent: ``||e_i(tau)|| <= c_i lam^tau ||e_i(0)||`` without noise (module docstring).

    Parameters
    ----------
    F, C, L : arrays
        The per-step model, every sensor's rows stacked, the base's gain.
    walk : tuple
        The walks (:class:`RelayDesign`).
    lam : float
        The rate per event time.

    Returns
    -------
    tuple of float
        ``inf`` for every agent when ``rho(F - L C) >= lam``.
    """
    from .conditioning import transient_constant

    cM = transient_constant(F - L @ C, lam).constant
    out = []
    for walk_i in walk:
        G, starts = walk_maps(F, C, walk_i)
        D = len(walk_i)
        c = max([1.0] + [float(np.linalg.norm(W, 2)) / lam ** (t + 1) for t, W in enumerate(starts)])
        tail = float(np.linalg.norm(G, 2)) * cM / lam ** D if math.isfinite(cM) else math.inf
        out.append(max(c, tail))
    return tuple(out)


def design_relay(F: np.ndarray, Cs, Q: np.ndarray, Rs, dist: np.ndarray, q: int, lam: float | None = None,
                 lag="auto") -> RelayDesign:
    """The relay design at ``q`` exchanges per event time (module docstring).

    Parameters
    ----------
    F : (n, n) array
        The per-step model.
    Cs, Rs : sequences of arrays
        Each agent's output matrix and measurement noise covariance, in agent order.
    Q : (n, n) array
        The process noise covariance per step.
    dist : (m, m) array
        Hop distances (:func:`~.exchange_limit.hop_distances`).
    q : int
        Exchanges per event time.
    lam : float or None
        The rate per event time to certify; None: the Kalman predictor's gain as it is.
    lag : int or "auto", default "auto"
        Event times the base stays behind beyond the longest delay; ``auto``: none when the base is the Kalman
        predictor (the walk would add nothing), else one more while it lowers the predicted RMS by :data:`AUTO_LAG`,
        up to :data:`LAG_MAX` (more never hurts the accuracy: the walk's information contains the later base's; it
        costs a step of the walk per agent and event time).

    Returns
    -------
    RelayDesign
        Not certified when no shift in ``[lam, 1]`` certifies (the Kalman predictor's gain kept).

    Raises
    ------
    DesignError
        The stacked sensors are not detectable with the noise (no Kalman predictor).

    Examples
    --------
    Two agents each seeing one coordinate of a random walk, three hops apart at one exchange: each holds the other's
    samples two event times late, as the protocol's limit says.

    >>> I = np.eye(2)
    >>> d = np.array([[0.0, 3.0], [3.0, 0.0]])
    >>> des = design_relay(I, [I[[0]], I[[1]]], I, [np.eye(1)] * 2, d, 1, lam=0.9)
    >>> des.D, des.certified, round(des.ratio, 6) == round(des.limit, 6)
    (2, True, True)
    """
    F = np.asarray(F, dtype=float)
    C = np.vstack(Cs)
    R = sla.block_diag(*Rs)
    kf = kalman_predictor(F, C, Q, R)  # a DesignError when the stacked sensors are not detectable with the noise
    Qr, Rsr = regularise(Q), [regularise(Ri) for Ri in Rs]
    delays = information_delays(dist, q)
    base, alpha = kf, 1.0
    if lam is not None and not certifies(kf.radius, lam):  # the one rule (spectral.certifies)
        base, alpha = _shift(F, C, Q, R, lam, kf)
    P_base = kf.P if base is kf else steady_covariance(F, C, base.L, Q, R)
    if lag == "auto":
        lag = 0 if alpha == 1.0 else _auto_lag(F, Cs, Rsr, Qr, delays, base.L, P_base)
    walk, agent_P = relay_gains(F, Cs, Rsr, Qr, delays, base.L, P_base, int(lag))
    radius = float(base.radius)
    lam_step = float(lam) if lam is not None else 1.0
    transient = relay_transient(F, C, base.L, walk, lam_step) if radius < lam_step else (math.inf,) * len(Cs)
    limit = protocol_limit(F, Cs, Q, Rs, dist, q).ratio
    return RelayDesign(q=int(q), delays=delays, F=F, L=base.L, walk=walk, alpha=float(alpha), radius=radius,
                       lam_step=lam_step, agent_P=agent_P, kf_P_trace=float(np.trace(kf.P)), limit=float(limit),
                       transient=transient, lag=int(lag))


def _shift(F, C, Q, R, lam: float, kf) -> tuple:
    """``(predictor, alpha)``: the largest ``alpha`` in ``[lam, 1]`` whose shifted gain certifies ``lam`` (the error
    grows as it falls), by regula falsi (Illinois) on ``radius(alpha) - lam`` from ``[lam, 1]`` (at ``lam`` the
    radius is below it by construction, at 1 it is the Kalman predictor's, not below); ``(kf, 1.0)`` when not even
    the most shifted gain certifies."""
    aim = lam - ALPHA_MARGIN * (1.0 - lam)
    try:
        lo_p = shifted_predictor(F, C, Q, R, aim, covariance=False)
    except DesignError:
        return kf, 1.0
    if not lo_p.radius < aim:
        return kf, 1.0
    lo, hi, g_lo, g_hi, side = aim, 1.0, lo_p.radius - aim, kf.radius - aim, 0
    lam = aim
    found, alpha = lo_p, lam
    for _ in range(ALPHA_STEPS - 1):
        if hi - lo < ALPHA_TOL * (1.0 - lam):
            break
        a = (lo * g_hi - hi * g_lo) / (g_hi - g_lo) if g_hi > g_lo else 0.5 * (lo + hi)
        a = min(max(a, lo + 0.01 * (hi - lo)), hi - 0.01 * (hi - lo))  # inside the bracket
        try:
            p = shifted_predictor(F, C, Q, R, a, covariance=False)
            g = p.radius - lam
        except DesignError:
            p, g = None, math.inf
        if p is not None and g < 0:
            found, alpha, lo, g_lo = p, a, a, g
            g_hi, side = (0.5 * g_hi if side == -1 else g_hi), -1  # Illinois: the stale end's value halved
        else:
            hi, g_hi = a, (g if math.isfinite(g) else 2 * max(g_hi, 1e-12))
            g_lo, side = (0.5 * g_lo if side == 1 else g_lo), 1
    return found, float(alpha)


def _auto_lag(F, Cs, Rs, Q, delays, L, P_base) -> int:
    """``design.lag: auto`` (:func:`design_relay`): one more extra event time while it lowers the predicted RMS by
    :data:`AUTO_LAG`, at most :data:`LAG_MAX`.  The extra steps hold every sensor, the same for every agent: the
    base's covariance walked through them once (the walk's Kalman step), each agent's delays after each."""
    C = np.vstack(Cs)
    R = sla.block_diag(*Rs)
    P, rms = np.array(P_base, dtype=float), []
    for lag in range(LAG_MAX + 1):
        _, agent_P = relay_gains(F, Cs, Rs, Q, delays, L, P, 0)
        rms.append(math.sqrt(max(float(np.mean([np.trace(Pi) for Pi in agent_P])), 0.0)))
        if lag and rms[-1] > (1 - AUTO_LAG) * rms[-2]:  # this step did not pay: the one before it is the lag
            return lag - 1
        PC = P @ C.T
        Lw = np.linalg.solve(C @ PC + R, (F @ PC).T).T
        Fc = F - Lw @ C
        P = Fc @ P @ Fc.T + Lw @ R @ Lw.T + Q
        P = 0.5 * (P + P.T)
    return LAG_MAX


def relay_q(sc: Scenario) -> int:
    """The relay design's ``q``: ``design.q``, or for ``auto`` the smallest whose protocol limit is within
    :data:`AUTO_GAP` of the Kalman predictor (at most the graph's diameter: every sample in within the event time).

    Parameters
    ----------
    sc : Scenario
        One graph.

    Returns
    -------
    int
    """
    if sc.design.q != "auto":
        return int(sc.design.q)
    F, Q, _, Cs, Rs, arcs = network_model(sc, 0)
    dist = hop_distances(sc.m, arcs)
    diameter = max(1, int(dist[np.isfinite(dist)].max()))
    return next((k for k in range(1, diameter) if protocol_limit(F, Cs, Q, Rs, dist, k).ratio <= 1 + AUTO_GAP),
                diameter)


def scenario_relay(sc: Scenario, q: int, rate: float | None) -> RelayDesign:
    """:func:`design_relay` of a scenario on its graph (its per-step model and noise).

    Parameters
    ----------
    sc : Scenario
        One graph, measurement noise on every output.
    q : int
        Exchanges per event time.
    rate : float or None
        ``lam`` in the scenario's units; None: unshifted.

    Returns
    -------
    RelayDesign

    Raises
    ------
    DesignError
        More than one graph (the walk's gains are one graph's), or no Kalman predictor.
    """
    if len(sc.graph_names) > 1:
        raise DesignError(f"design.consensus: relay needs one fixed graph (the scenario has {len(sc.graph_names)}: "
                          "the walk's gains are one graph's delays): design.consensus: fusion switches graphs")
    F, Q, _, Cs, Rs, arcs = network_model(sc, 0)
    lam = None if rate is None else per_step_rate(sc, rate)
    return design_relay(F, Cs, Q, Rs, hop_distances(sc.m, arcs), q, lam, sc.design.lag)


def agent_relay(des, agent_id: int) -> dict:
    """What agent ``agent_id``'s process is sent: the per-step model, the stacked outputs, its gains by lag and
    every sensor's rows, the floats the simulator holds.

    Parameters
    ----------
    des : Design
        A relay design.
    agent_id : int

    Returns
    -------
    dict
        ``{"consensus": "relay", "F", "C", "gains": [G_0, .., G_D], "rows": [[first, stop] per sensor]}`` (nested
        lists).
    """
    sc = des.scenario
    k = des.whole
    i = sc.agent_ids.index(agent_id)
    return {"consensus": "relay", "F": np.asarray(k.F).tolist(),
            "C": np.vstack([np.asarray(C, dtype=float) for C in sc.system.Cs]).tolist(),
            "gains": [G.tolist() for G in gain_table(k, i)],
            "rows": [[r.start, r.stop] for r in output_rows(sc.system.Cs)]}


def survivors_radius(des, alive: tuple, arcs: dict) -> float:
    """The spectral radius of the base's error map on the survivors: the gain kept, the rows left out of the sensors
    lost and of those whose samples no longer reach every survivor within ``D`` event times (the base's step skips
    them).

    Parameters
    ----------
    des : Design
        A relay design.
    alive : tuple of int
        The survivors' ids.
    arcs : dict
        ``{graph name: arcs (j, i) still up}`` (the relay's one graph).

    Returns
    -------
    float
    """
    sc = des.scenario
    k = des.whole
    pos = {a: j for j, a in enumerate(sc.agent_ids)}
    rows = output_rows(sc.system.Cs)
    C = np.vstack([np.asarray(Ci, dtype=float) for Ci in sc.system.Cs])
    worst = 0.0
    for up in arcs.values():
        dist = hop_distances(sc.m, [(pos[j], pos[i]) for j, i in up if j in alive and i in alive])
        live = [pos[a] for a in alive]
        with np.errstate(invalid="ignore"):
            late = np.ceil(dist / k.q) - 1
        kept = [j for j in live if all(np.isfinite(dist[i, j]) and late[i, j] <= k.D for i in live)]
        r = np.concatenate([np.arange(rows[j].start, rows[j].stop) for j in kept]).astype(np.int64) \
            if kept else np.zeros(0, dtype=np.int64)
        worst = max(worst, spectral_radius(k.F - k.L[:, r] @ C[r]))
    return worst


def relay_design(sc: Scenario, agents: tuple, rate: float, warnings: list, common: dict):
    """The relay kind as a design (``design.consensus: relay``, :func:`splitspec_core.synthesis.designer.design`):
    the gains of :func:`scenario_relay` at :func:`relay_q`, certified by the base's ``n x n`` error map, each agent's
    predicted RMS kept as the design's.

    Parameters
    ----------
    sc : Scenario
        One graph, measurement noise on every output.
    agents : tuple of AgentDesign
        The agents' placeholders (:func:`~splitspec_core.model.local_design.whole_placeholder`).
    rate : float
        ``lam`` in the scenario's units (the envelope's when directions no agent sees limit it).
    warnings : list
        The design's warnings; a rate not certified appends its line.
    common : dict
        The fields every design shares (scenario, graphs, cases, ...).

    Returns
    -------
    Design
    """
    from . import bounds
    from .design_data import Design
    from .error_matrix import remember_predicted
    from ..model.local_design import with_gain

    kind = scenario_relay(sc, relay_q(sc), rate)
    if not kind.certified:
        warnings.append(refusal_text(sc, kind))
    rows = output_rows(sc.system.Cs)
    # each agent's K_i in the predictor's form without neighbours (x+ = F x - L_i (C_i x - y_i)): the base's columns
    # of its own rows, for the reports; what runs is the walk (kinds.Relay)
    agents = tuple(with_gain(a, -kind.L[:, rows[k]], "relay") for k, a in enumerate(agents))
    radii = {sc.graph_names[0]: kind.radius}
    result = bounds.QResult(q=kind.q, method="base error map", bound=kind.radius, certified=kind.certified,
                            switching=False)
    des = Design(agents=agents, warnings=tuple(warnings), q=kind.q, q_result=result,
                 q_methods={"base error map": result}, error_radius=radii, full_radius=radii, consensus="relay",
                 whole=kind, **common)
    remember_predicted(des, 0, kind.agent_rms)
    return des


def refusal_text(sc: Scenario, kind: RelayDesign) -> str:
    """One line: the relay kind does not certify the rate, and the fastest rate it keeps (whatever ``q``: its
    certificate is the centralized predictor's).

    Parameters
    ----------
    sc : Scenario
    kind : RelayDesign
        Not certified.

    Returns
    -------
    str
    """
    r = kind.radius
    fastest = f"{r:.6g} per event time" if sc.time == "discrete" else \
        f"{-math.log(r) / sc.run.dt:.4g} {sc.system.per_time}" if 0 < r < 1 else "none: its error map is unstable"
    return (f"design.consensus: relay does NOT certify rate {sc.design.rate:g} at any q: its base is the centralized "
            f"predictor, whose most shifted gain keeps rate {fastest} (spectral radius {r:.6g}): lower design.rate")
