"""The limit of the two-rate protocol: what no estimator within ``q`` exchanges per event time can beat.

In the paper's two-rate protocol (eqs. split-discrete-est1 .. p3) an agent measures at event time ``tau``, exchanges
``q`` times with its neighbours, and predicts ``x(tau + 1)``.  What agent j measured at ``tau`` can travel ``q`` hops
before that prediction, ``2 q`` before the next, and so on: a sensor ``d`` hops away (along the arcs, towards i)
reaches agent i's estimate of ``x(tau + 1)`` with its samples up to ``tau - delta_ij``,

    ``delta_ij = max(0, ceil(d_ij / q) - 1)``          (``d_ii = 0``: its own sensor, no delay)

event times late.  Whatever the messages carry and however they are combined, agent i's estimate of ``x(tau + 1)`` is
a function of those samples, so its error covariance is at least that of the centralized Kalman *predictor* fed the
same delayed samples (the best linear estimator; the best of all under Gaussian noise).  The limit of the network is
the RMS of those covariances over the agents, beside the Kalman predictor's own (every sample up to ``tau``).

How it is computed (exactly, without the augmented state)
---------------------------------------------------------
The textbook route augments the state with ``D = max delta`` delayed copies and solves one DARE of size
``n (D + 1)`` per agent (400 states per agent on Rego's ring at ``q = 1``: a minute for the 20 agents).  The
information agent i holds at ``tau`` is nested: every sensor up to ``tau - D``, then at ``tau - D + 1 .. tau`` the
sensors whose delay is at most ``D - 1 .. 0``.  The estimate of ``x(tau - D + 1)`` from every sensor up to
``tau - D`` is the Kalman predictor's (its steady covariance ``P``, one DARE of size ``n``); each later event time
adds the sensors already arrived by it, a Riccati step each (white noise: nothing else correlates):

    ``P <- F (P - P C_t' (C_t P C_t' + R_t)^-1 C_t P) F' + Q``,   ``C_t`` the rows of sensors with ``delta <= t``,

for ``t = D - 1, ..., 0``: ``D`` steps of size ``n``, the same covariance as the augmented DARE (a test computes
both).  The limit is the predictor's, as the protocol's estimate is: ``x_i(tau + 1)`` given data up to ``tau``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg as sla
from scipy.sparse.csgraph import shortest_path

from ..errors import AssumptionError, DesignError, SplitspecError
from ..model.graphs import arc_positions
from ..model.plant import output_rows, sampled_model
from ..scenarios.specs import Scenario
from .design_data import cached_analysis
from .kalman import kalman_predictor, regularise

__all__ = ["ProtocolLimit", "Exchanges", "network_model", "hop_distances", "information_delays", "delayed_predictor_covariance",
           "protocol_limit", "scenario_limit", "design_exchanges"]


#: the design report states the limit for networks up to this many agents (each agent's limit is a Riccati step per
#: event time of delay: a ring of m agents at q = 1 costs about m^2 / 2 of them)
LIMIT_AGENTS = 200
#: ... and up to this m n, the noise's prediction's (error_matrix.MAX_NOISE_DIM, not imported: error_matrix reaches this
#: module through the fusion kind)
LIMIT_DIM = 2000


@dataclass(frozen=True)
class ProtocolLimit:
    """The protocol's limit at ``q`` exchanges per event time, and the Kalman predictor beside it.

    Attributes
    ----------
    q : int
        Exchanges per event time.
    delays : (m, m) int array
        ``delta_ij``: event times agent i hears sensor j late (row i, column j; 0-based agent positions).
    agent_rms : (m,) array
        ``sqrt(trace P_i / n)``: agent i's limit, RMS per state.
    rms : float
        ``sqrt(mean_i trace P_i / n)``: the network's limit, RMS per state over every agent.
    kf_rms : float
        The centralized Kalman predictor's, ``sqrt(trace P / n)``.
    """

    q: int
    delays: np.ndarray
    agent_rms: np.ndarray
    rms: float
    kf_rms: float

    @property
    def ratio(self) -> float:
        """``rms / kf_rms``: the limit relative to the Kalman predictor (1 when every sensor arrives in time)."""
        return self.rms / self.kf_rms


def hop_distances(m: int, arcs) -> np.ndarray:
    """``d[i, j]``: the fewest arcs from agent j to agent i (how far j's information travels to reach i).

    Parameters
    ----------
    m : int
        Number of agents.
    arcs : iterable of (int, int)
        Arcs ``(j, i)`` between 0-based positions (i hears j).

    Returns
    -------
    (m, m) float array
        Hop counts (``d[i, i] = 0``; ``inf`` where j cannot reach i).

    Examples
    --------
    >>> hop_distances(3, [(0, 1), (1, 2)])
    array([[ 0., inf, inf],
           [ 1.,  0., inf],
           [ 2.,  1.,  0.]])
    """
    adj = np.zeros((m, m))
    for j, i in arcs:
        adj[i, j] = 1.0  # an edge i -> j in the reversed graph: row i reaches the agents it hears
    return shortest_path(adj, method="D", directed=True, unweighted=True)


def information_delays(dist: np.ndarray, q: int) -> np.ndarray:
    """``delta_ij = max(0, ceil(d_ij / q) - 1)``: how many event times late agent i can know sensor j's samples.

    Parameters
    ----------
    dist : (m, m) array
        Hop distances (:func:`hop_distances`), all finite.
    q : int
        Exchanges per event time, at least 1.

    Returns
    -------
    (m, m) int array

    Examples
    --------
    >>> information_delays(np.array([[0.0, 1.0, 2.0, 3.0]]), 2)
    array([[0, 0, 0, 1]])
    """
    if q < 1:
        raise DesignError(f"the protocol needs at least one exchange per event time, got q = {q}")
    if not np.all(np.isfinite(dist)):
        raise AssumptionError("the graph is not strongly connected: some sensor never reaches some agent")
    return np.maximum(0, np.ceil(np.asarray(dist) / q).astype(int) - 1)


def delayed_predictor_covariance(F: np.ndarray, Cs, Q: np.ndarray, Rs, delays, P: np.ndarray) -> np.ndarray:
    """The steady covariance of the Kalman predictor of ``x(tau + 1)`` fed sensor j's samples ``delays[j]`` late.

    Parameters
    ----------
    F : (n, n) array
        The per-step model, ``x(tau + 1) = F x(tau) + w``.
    Cs : sequence of (s_j, n) arrays
        The sensors' output matrices.
    Q : (n, n) array
        ``E[w w']``.
    Rs : sequence of (s_j, s_j) arrays
        The sensors' noise covariances.
    delays : sequence of int
        ``delta_j`` per sensor (event times).
    P : (n, n) array
        The Kalman predictor's steady covariance with every sensor (no delay).

    Returns
    -------
    (n, n) array
        The covariance (module docstring: ``max delta`` Riccati steps from ``P``).

    Examples
    --------
    A random walk seen by one sensor one event time late: the error of a two-step prediction.

    >>> F, C, Q, R = np.eye(1), np.eye(1), np.eye(1), np.eye(1)
    >>> P = kalman_predictor(F, C, Q, R).P
    >>> round(float(delayed_predictor_covariance(F, [C], Q, [R], [1], P)[0, 0] - P[0, 0]), 12)
    1.0
    """
    delays = [int(d) for d in delays]
    P = np.array(P, dtype=float)
    n = P.shape[0]
    rows = sum(int(np.shape(C)[0]) for C in Cs)
    info = None
    if rows > 4 * n:  # many sensors: the update in information form, n x n per event time whatever their number
        info = [C.T @ np.linalg.solve(R, C) for C, R in zip(Cs, Rs)]
    for t in range(max(delays, default=0) - 1, -1, -1):
        held = [j for j, d in enumerate(delays) if d <= t]  # fewer as t nears tau: the farther ones not yet in
        if held and info is not None:
            held_info = sum((info[j] for j in held), np.zeros((n, n)))
            # (P^-1 + sum C_j' R_j^-1 C_j)^-1 = P - P (I + H P)^-1 H P, H the information of the sensors arrived
            P = P - P @ np.linalg.solve(np.eye(n) + held_info @ P, held_info @ P)
        elif held:
            C = np.vstack([Cs[j] for j in held])
            R = sla.block_diag(*[Rs[j] for j in held])
            PC = P @ C.T
            # the measurement update of the sensors arrived by t (Joseph-free: P stays symmetric below)
            P = P - PC @ np.linalg.solve(C @ PC + R, PC.T)
        P = F @ P @ F.T + Q
        P = 0.5 * (P + P.T)
    return P


def protocol_limit(F: np.ndarray, Cs, Q: np.ndarray, Rs, dist: np.ndarray, q: int) -> ProtocolLimit:
    """The two-rate protocol's limit at ``q`` exchanges per event time (module docstring).

    Parameters
    ----------
    F : (n, n) array
        The per-step model.
    Cs : sequence of (s_i, n) arrays
        Each agent's output matrix, in agent order.
    Q : (n, n) array
        The process noise covariance per step.
    Rs : sequence of (s_i, s_i) arrays
        Each agent's measurement noise covariance.
    dist : (m, m) array
        Hop distances (:func:`hop_distances`).
    q : int
        Exchanges per event time.

    Returns
    -------
    ProtocolLimit

    Raises
    ------
    DesignError
        If the stacked sensors are not detectable with the noise (no Kalman predictor).

    Examples
    --------
    Two agents each seeing one coordinate of a random walk, one hop apart: with one exchange each agent has the
    other's sample in time, so the limit is the Kalman predictor itself.

    >>> I = np.eye(2)
    >>> lim = protocol_limit(I, [I[[0]], I[[1]]], I, [np.eye(1)] * 2, hop_distances(2, [(0, 1), (1, 0)]), 1)
    >>> round(lim.ratio, 12)
    1.0
    """
    F = np.asarray(F, dtype=float)
    n = F.shape[0]
    C = np.vstack(Cs)
    R = sla.block_diag(*Rs)
    P = kalman_predictor(F, C, Q, R).P  # a DesignError when the stacked sensors are not detectable
    Q, Rs = regularise(Q), [regularise(Ri) for Ri in Rs]  # as the predictor's: singular noise is its small limit
    delays = information_delays(dist, q)
    per = np.array([np.trace(delayed_predictor_covariance(F, Cs, Q, Rs, row, P)) for row in delays])
    return ProtocolLimit(q=int(q), delays=delays, agent_rms=np.sqrt(np.maximum(per, 0.0) / n),
                         rms=float(np.sqrt(max(per.mean(), 0.0) / n)), kf_rms=float(np.sqrt(max(np.trace(P), 0.0) / n)))


def network_model(sc: Scenario, graph: int = 0) -> tuple:
    """``(F, Q, R, Cs, Rs, arcs)``: a scenario's per-step model and noise, its agents' outputs and one graph's arcs.

    Parameters
    ----------
    sc : Scenario
        Discrete, or continuous on its model sampled with ``run.dt``
        (:func:`~splitspec_core.model.plant.sampled_model`).
    graph : int, default 0
        The graph's index, in the scenario's order.

    Returns
    -------
    tuple
        ``F`` (n, n), ``Q`` (n, n), ``R`` (p, p) stacked, ``Cs`` and ``Rs`` per agent (agent order), ``arcs`` a list of
        ``(j, i)`` 0-based positions (i hears j).
    """
    F, Q, R = sampled_model(sc)
    Cs = [np.asarray(C, dtype=float) for C in sc.system.Cs]
    Rs = [R[r, r] for r in output_rows(Cs)]
    j, i = arc_positions(sc.agent_ids, sc.graphs[graph].arcs)
    return F, Q, R, Cs, Rs, list(zip(j.tolist(), i.tolist()))


def scenario_limit(sc: Scenario, q: int, *, graph: int = 0) -> ProtocolLimit:
    """:func:`protocol_limit` of a scenario on one of its graphs (its per-step model and noise).

    Parameters
    ----------
    sc : Scenario
        The scenario (discrete, or continuous on its sampled model with ``run.dt``).
    q : int
        Exchanges per event time.
    graph : int, default 0
        The graph's index, in the scenario's order.

    Returns
    -------
    ProtocolLimit
    """
    F, Q, _, Cs, Rs, arcs = network_model(sc, graph)
    return protocol_limit(F, Cs, Q, Rs, hop_distances(sc.m, arcs), q)

@dataclass(frozen=True)
class Exchanges:
    """What each agent of a design sends, and the protocol's limit at that many exchanges (``splitspec design``).

    Attributes
    ----------
    per : str
        ``event time`` (discrete) or ``run.dt`` (continuous: one event time per step).
    messages : int or None
        Messages each agent sends per event time (``q``; 1 for the continuous sampled-data form with ``g``); None
        when the design has no ``q``.
    numbers : int or None
        Numbers each agent sends per event time: ``messages n`` (each message one estimate); the relay kind's: at
        most ``p``, every sensor's sample once.
    limit : ProtocolLimit or None
        The limit at ``messages`` exchanges, on ``graph``; None without noise, above the noise analysis's size or
        above :data:`LIMIT_AGENTS` agents.
    graph : str or None
        The graph the limit is computed on (the first the switching uses).
    relayed : bool
        The messages carry samples (the relay kind), not estimates.
    """

    per: str
    messages: int | None
    numbers: int | None
    limit: ProtocolLimit | None
    graph: str | None
    relayed: bool = False

    def text(self) -> str:
        """The report's line.

        Returns
        -------
        str
            ``exchanges: ...``, with the limit where it was computed.
        """
        if self.messages is None:
            return ""
        if self.relayed:
            out = (f"exchanges: each agent sends {self.messages} message{'s' if self.messages != 1 else ''} per "
                   f"{self.per} carrying at most {self.numbers} numbers in all (every sensor's sample once, each with "
                   "its sensor and event time)")
        else:
            out = (f"exchanges: each agent sends {self.messages} message{'s' if self.messages != 1 else ''} of "
                   f"{self.numbers // self.messages} numbers per {self.per} ({self.numbers} numbers)")
        if self.limit is not None:
            out += (f"; the protocol's limit at q = {self.messages}: {self.limit.ratio:.4g}x the centralized Kalman "
                    f"filter's RMS (graph {self.graph}: each sensor ceil(d / q) - 1 event times late; no estimator "
                    f"within {self.messages} exchange{'s' if self.messages != 1 else ''} does better)")
        return out


@cached_analysis
def design_exchanges(des) -> Exchanges:
    """:class:`Exchanges` of a design: its ``q`` (or one exchange per step), and the limit under noise.

    Parameters
    ----------
    des : Design
        The design.

    Returns
    -------
    Exchanges

    Examples
    --------
    >>> import splitspec_core as ss
    >>> from splitspec_core.synthesis.designer import design
    >>> des = design(ss.scenario(A=[[0, 1, 0, 0], [-1, 0, 0, 0], [0, 0, 0, 1], [0, 0, -2, 0]],
    ...                          C={1: [[1, 0, 0, 0]], 2: [[0, 1, 0, 0]], 3: [[0, 0, 1, 0]]},
    ...                          graphs={"a": [(1, 2), (2, 1), (2, 3), (3, 2), (1, 3)]}, rate=0.5, gains="place"))
    >>> ex = design_exchanges(des)
    >>> ex.messages, ex.numbers, ex.limit is None
    (6, 24, True)
    """
    sc = des.scenario
    per = "event time" if sc.time == "discrete" else "run.dt"
    if sc.time == "continuous" and des.consensus not in ("whole", "fusion", "relay"):
        q = 1  # the sampled-data form: one exchange per step
    else:
        q = None if des.q is None else int(des.q)
    if q is None or q < 1:
        return Exchanges(per=per, messages=None, numbers=None, limit=None, graph=None)
    limit, graph = None, None
    if sc.system.has_noise and sc.m * sc.n <= LIMIT_DIM and sc.m <= LIMIT_AGENTS:
        graph = sc.switching.graph_names(sc.graph_names)[0]
        try:
            limit = scenario_limit(sc, q, graph=sc.graph_names.index(graph))
        except SplitspecError:  # no Kalman predictor (the stacked sensors not detectable with the noise): no limit
            limit, graph = None, None
    if des.consensus == "relay":  # every sample once: p numbers, whatever q (synthesis/relay.py)
        p = sum(int(np.shape(C)[0]) for C in sc.system.Cs)
        return Exchanges(per=per, messages=q, numbers=p, limit=limit, graph=graph, relayed=True)
    return Exchanges(per=per, messages=q, numbers=q * sc.n, limit=limit, graph=graph)
