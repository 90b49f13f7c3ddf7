"""The whole-state design: every agent averages its neighbours' whole estimates, its gain chosen for the noise.

The paper's split gives each agent, to estimate *by itself*, every direction it sees at all, however weakly, and
takes from its neighbours only what it does not see (``P_i`` the projection on its unobservable space).  On a
coupled physical system every sensor sees almost everything, weakly: the local gains are huge and each sensor's
noise is amplified.  Here the consensus subspace is the whole state (``P_i = I``), and the gains come from the noise.

The estimator
-------------
The paper's two-rate estimator (eqs. split-discrete-est1 .. p3) with ``P_i = I``, each agent's estimate its
*averaged state* (eq. split-discrete-p3): per event time ``tau`` it updates with its own measurement, then averages
``q`` times with its neighbours (:mod:`splitspec_core.model.steps`)::

    z_i(0) = (A + K_i C_i) x_i(tau) - K_i y_i(tau) [+ B u(tau)]
    z_i(k) = sum_j w_ij z_j(k - 1),        k = 1 .. q
    x_i(tau + 1) = z_i(q)

In continuous time it runs on the sampled model, one event time per ``run.dt`` (``q`` exchanges per step; no g):
``z_i(0) = E x_i + D [K_i (C_i x_i - y_i) + B u]``, ``E = exp(A dt)``, ``D = int_0^dt exp(A s) ds``.

The error ``e_i = x_i - x`` (``F_i = A + K_i C_i``, or ``E + D K_i C_i``; ``W = S^q (x) I_n``)::

    e(tau + 1) = W blkdiag(F_i) e(tau) - W blkdiag(K_i) w(tau) - 1 (x) v(tau)

``W blkdiag(F_i)`` has the eigenvalues of the paper's ``blkdiag(F_i) W`` (eq. split-discrete-error with ``P = I``;
``AB`` and ``BA`` share their spectrum): the same certificate of the rate.  What changes is what an agent reports:
the average of its neighbours' updated estimates, which carries every sensor's information, instead of its own
innovation amplified.

The gains
---------
With ``pi`` the stationary weights of consensus (``pi' S = pi'``, ``sum pi = 1``; ``1/m`` for doubly stochastic
weights), when every estimate agrees the weighted average follows ``sum_i pi_i (F_i xbar - K_i y_i)``.  With
``K_i = -L_i / pi_i`` (``L = [L_1 .. L_m]`` a centralized predictor gain, its columns per agent) that is the
centralized predictor ``xbar+ = (F - L C) xbar + L y``: consensus spreads it, ``q`` sets how closely.  ``L`` is the
Kalman predictor of the per-step model (:func:`~splitspec_core.model.plant.sampled_model`: the scenario's real noise
levels) when it decays faster than the rate with a small margin; else the Riccati design of ``F`` shifted by the
largest ``alpha`` whose filter does (:func:`~splitspec_core.synthesis.kalman.shifted_predictor`): among this family,
the smallest centralized error at the rate.  Several margins are tried; ``q`` is the smallest the certificate takes,
raised while the predicted steady RMS (the Lyapunov equation of the full error system) still falls by more than
:data:`Q_GAIN` per exchange (at most :data:`Q_EXTRA` more); the candidate with the smallest predicted RMS wins
(``design.gains: optimal``).  ``design.gains: riccati`` takes the centralized Riccati design shifted by the rate
itself (no search); ``explicit`` the user's ``K_i``.

What certifies it
-----------------
Every case held constant (each graph the switching uses, and with ``design.resilience: 1`` each single agent loss,
the gains kept): the spectral radius of the full error matrix ``< lam`` per event time (``m n <=``
:data:`~splitspec_core.synthesis.error_matrix.MAX_RATE_DIM`); switching, or ``m n`` beyond that, the mixing bound
or the dwell-time bound (:mod:`.mixing`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import scipy.linalg as sla

from ..errors import DesignError
from ..model import steps as st
from ..model.graphs import perron_vector
from ..model.plant import output_rows, sampled_model
from ..scenarios import gain_methods
from ..scenarios.specs import Scenario
from .error_matrix import MAX_NOISE_DIM, MAX_RATE_DIM, step_blocks, whole_matrix, whole_noise
from .mixing import certify, mixing_bound, same_agents
from .bounds import smallest
from ..model.observability import unobservable_directions
from .kalman import kalman_predictor, per_step_rate, shifted_predictor, spectral_radius
from .spectral import certifies

__all__ = ["WholeState", "Q_GAIN", "Q_EXTRA", "Q_CAP", "SEARCH_DIM", "MARGINS", "case_radius", "radius_at", "design_whole",
           "whole_gains", "agent_gain"]

#: q is raised while one more exchange lowers the predicted steady RMS by more than this fraction
Q_GAIN = 0.01
#: ... by at most this many exchanges past the smallest certified q
Q_EXTRA = 8
#: the largest q the automatic search tries (design.q_max lowers it)
Q_CAP = 512
#: the smallest q is looked for among every q up to this (above it by doubling and bisection)
SCAN = 16
#: bisection steps of the shift alpha of the centralized filter (:func:`_alpha_for`)
ALPHA_STEPS = 12
#: up to this m n every candidate centralized filter is designed and the smallest predicted RMS kept; above it the
#: first (the smallest centralized error) that certifies
SEARCH_DIM = 400
#: the centralized filter's margins tried when the Kalman filter is too slow for the rate: its radius at most
#: ``lam^(1 + margin)`` per step (the distributed estimator approaches it as q grows)
MARGINS = (0.03, 0.1, 0.3)


@dataclass(frozen=True)
class WholeState:
    """What the whole-state design chose, and its references (the report's and ``--json``'s ``whole_state``).

    Attributes
    ----------
    alpha : float
        The shift of the centralized Riccati design (1: the Kalman predictor itself).
    L : (n, p) array
        The centralized predictor gain per step; agent i's ``K_i`` is ``-L_i / pi_i`` (``D^-1`` of it in continuous
        time).
    pi : (m,) array
        The stationary weights of consensus on the scenario's first graph.
    lam_step : float
        The rate per event time (``lam``, or ``exp(-lam dt)``; the envelope's when directions no agent sees limit it).
    central_radius, central_rms : float
        ``rho(F - L C)`` and the centralized predictor's steady RMS with this ``L``.
    kf_radius, kf_rms : float
        The Kalman predictor's.
    reference_rms : float or None
        The rate-certified centralized reference: the Riccati design shifted by the rate (None: it has no solution).
    q_certified : int
        The smallest q the certificate takes.
    tried : tuple
        ``(margin, alpha, q, radius, predicted RMS or None)`` of each candidate.
    method : str
        ``optimal``, ``riccati`` or ``explicit``.
    """

    alpha: float
    L: np.ndarray = field(repr=False)
    pi: np.ndarray = field(repr=False)
    lam_step: float
    central_radius: float
    central_rms: float
    kf_radius: float | None
    kf_rms: float | None
    reference_rms: float | None
    q_certified: int
    tried: tuple = ()
    method: str = "optimal"
    predicted: np.ndarray | None = field(default=None, repr=False)  # every agent's predicted RMS at q, first graph


def case_radius(sc: Scenario, Fs_by_id: dict, case, q: int) -> float:
    """The spectral radius of the full error matrix of ``case`` (its graph and agents held constant) at ``q``.

    Parameters
    ----------
    sc : Scenario
        The scenario (not read; kept for the callers' uniform signature).
    Fs_by_id : dict
        ``{agent id: F_i}``, every agent's error map per event time (``A + K_i C_i``, or ``E + D K_i C_i``).
    case : bounds.Case
        A graph held constant with its agents (``case.graph.ids``, ``case.graph.S``).
    q : int
        Consensus exchanges per event time.

    Returns
    -------
    float
        ``rho((S^q (x) I_n) blkdiag(F_i))``, per event time; the rate is certified for the case when it is below
        ``lam`` (per step).
    """
    return spectral_radius(whole_matrix([Fs_by_id[i] for i in case.graph.ids], case.graph.S, q))


class _Radii(dict):
    """Every agent's ``F_i`` (agent id -> matrix) and the case radii computed with them, each once (a dense
    eigenvalue problem of size m n: a second at 1700)."""

    def __init__(self, by_id: dict):
        super().__init__(by_id)
        self.cache: dict = {}
        self.rms: dict = {}  # q -> every agent's predicted steady RMS (first graph)

    def of(self, sc: Scenario, case, q: int) -> float:
        key = (case.label, int(q))
        if key not in self.cache:
            self.cache[key] = case_radius(sc, self, case, q)
        return self.cache[key]


def _predicted(sc: Scenario, Fs, Kss, S, q: int, Qn, R, per_agent: dict | None = None) -> float | None:
    """The RMS over agents of the predicted steady RMS errors (None: not computed, or unstable); ``per_agent``: where
    to keep each agent's, by q (the design's own figures: :func:`~splitspec_core.synthesis.error_matrix.predicted_rms`
    is seeded with them, a Lyapunov equation of size m n is seconds at 1700)."""
    m, n = len(Fs), sc.n
    if m * n > MAX_NOISE_DIM:
        return None
    M = whole_matrix(Fs, S, q)
    if spectral_radius(M) >= 1.0:
        return None
    Sigma = sla.solve_discrete_lyapunov(M, whole_noise(Kss, S, q, R, Qn))
    tr = np.maximum([np.trace(Sigma[i * n:(i + 1) * n, i * n:(i + 1) * n]) for i in range(m)], 0.0)
    if per_agent is not None:
        per_agent[int(q)] = np.sqrt(tr)
    return float(np.sqrt(np.mean(tr)))


def whole_gains(sc: Scenario, L: np.ndarray, pi: np.ndarray) -> list:
    """Every agent's ``K_i`` (the user's coordinates, the scenario's time) from the centralized per-step gain ``L``:
    ``K_s,i = -L_i / pi_i``; continuous time ``K_i = D^-1 K_s,i`` (the step applies ``D K_i``).

    Parameters
    ----------
    sc : Scenario
        The scenario (its ``C_i`` split ``L``'s columns per agent; its ``time``, ``A`` and ``run.dt``).
    L : (n, p) array
        The centralized predictor gain per step, ``p = sum s_i`` (``xbar+ = (F - L C) xbar + L y``).
    pi : (m,) array
        The stationary weights of consensus, in agent order.

    Returns
    -------
    list of arrays
        ``[K_1, ..., K_m]``, each (n, s_i), in agent order.
    """
    rows = output_rows(sc.system.Cs)
    Kss = [-L[:, r] / pi[k] for k, r in enumerate(rows)]
    if sc.time == "discrete":
        return Kss
    _, D, _ = st.sampled_data_matrices(np.asarray(sc.system.A, dtype=float), sc.run.dt)
    return [np.linalg.solve(D, K_s) for K_s in Kss]


def _alpha_for(F, C, Q, R, target: float, kf) -> tuple:
    """The largest ``alpha`` in ``[target, 1]`` whose shifted predictor's radius is at most ``target`` (bisection;
    ``alpha = target`` always is: ``rho < alpha``); its predictor.  ``kf``: the Kalman predictor (None: none)."""
    if kf is not None and kf.radius <= target:
        return 1.0, kf
    lo, hi = target, 1.0
    best = shifted_predictor(F, C, Q, R, lo)
    for _ in range(ALPHA_STEPS):  # on log(1 - alpha): alpha's distance to 1 within a few per cent
        mid = 1.0 - math.sqrt((1.0 - lo) * (1.0 - hi)) if hi < 1.0 else 1.0 - 0.5 * (1.0 - lo)
        try:
            p = shifted_predictor(F, C, Q, R, mid)
        except DesignError:
            hi = mid
            continue
        if p.radius <= target:
            lo, best = mid, p
        else:
            hi = mid
    return lo, best


def design_whole(sc: Scenario, cases, *, rate: float, dwell: float | None, warnings: list) -> tuple:
    """The whole-state design of ``sc`` over ``cases`` (the graphs held constant the certificate covers, the first
    one the scenario's first used graph) at ``rate`` (``lam``, or the envelope's when directions no agent sees limit
    it; ``dwell``: the switching's average dwell time, scenario units, for the dwell-time bound):
    ``(Ks, q, WholeState, radii, certificate)``.

    ``Ks``: every agent's ``K_i`` in the user's coordinates; ``radii``: the full error matrix's spectral radius per
    case at ``q`` (empty above :data:`MAX_RATE_DIM`); ``certificate``: ``(method, bound, certified, switching)``.

    Parameters
    ----------
    sc : Scenario
        The scenario (its ``design.gains`` picks the family: ``explicit`` the user's ``K_i``, ``riccati`` and
        ``kalman`` the Riccati design shifted by the rate, ``optimal`` the search of the module docstring; its
        ``design.q``, ``design.q_max``).
    cases : sequence of bounds.Case
        The graphs (and agent sets) held constant the certificate covers; the first one's stationary weights ``pi``
        split the centralized gain, and the predicted noise is computed on it.
    rate : float
        ``lam`` in the scenario's units (discrete: per event time; continuous: per second, taken per ``run.dt``
        step as ``exp(-lam dt)``).
    dwell : float or None
        The switching's average dwell time in scenario units, for the dwell-time bound (None: none).
    warnings : list
        The design's warnings; the certificate's are appended to it.

    Returns
    -------
    tuple
        ``(Ks, q, info, radii, certificate)``: ``Ks`` a list of (n, s_i) arrays in agent order, ``q`` an int,
        ``info`` a :class:`WholeState`, ``radii`` a dict ``{case label: float}``, ``certificate`` a tuple
        ``(method str, bound float, certified bool, switching bool)``.

    Raises
    ------
    DesignError
        Nothing in the family meets the rate within ``q <=`` :data:`Q_CAP` (the message says what limits it).

    Examples
    --------
    Two agents, each seeing one state, with noise (``design.gains: optimal``): the Kalman predictor meets the rate
    (``alpha = 1``), and one exchange per event time certifies it:

    >>> import splitspec_core as ss
    >>> from splitspec_core.synthesis.prelude import Prelude
    >>> sc = ss.scenario(A=[[0.9, 0.2], [0, 0.8]], C={1: [[1, 0]], 2: [[0, 1]]}, graphs={"a": [(1, 2), (2, 1)]},
    ...                  rate=0.5, process_noise=0.1, measurement_noise=0.1, consensus="whole")
    >>> Ks, q, info, radii, certificate = design_whole(sc, Prelude.of(sc).cases, rate=0.5, dwell=None, warnings=[])
    >>> [K.round(4).ravel().tolist() for K in Ks], q, info.alpha, info.pi.round(6).tolist()
    ([[-1.0906, -0.0282], [-0.2626, -0.9235]], 1, 1.0, [0.5, 0.5])
    >>> round(radii["a"], 4), certificate[0], certificate[2]
    (0.3478, 'full error matrix', True)
    """
    d = sc.design
    F, Qn, R = sampled_model(sc)
    Cs = [np.asarray(C, dtype=float) for C in sc.system.Cs]
    C = np.vstack(Cs)
    lam = per_step_rate(sc, rate)
    first = cases[0].graph
    pi = perron_vector(first.S) if first.ids == sc.agent_ids else np.full(sc.m, 1.0 / sc.m)
    try:
        kf = kalman_predictor(F, C, Qn, R)
    except DesignError:
        kf = None
    try:
        ref = shifted_predictor(F, C, Qn, R, lam)
    except DesignError:
        ref = None
    q_given = None if d.q == "auto" else int(d.q)
    q_cap = min(d.q_max, Q_CAP)
    candidates = []
    whole = gain_methods.method(d.gains).whole  # given, shifted or search (scenarios/gain_methods.py)
    if whole == "given":
        candidates.append((None, None, None, [np.asarray(K, dtype=float) for K in d.K]))
    elif whole == "shifted":
        if ref is None:
            raise DesignError(_no_centralized(lam, F, Cs))
        candidates.append((None, lam, ref, whole_gains(sc, ref.L, pi)))
    else:
        seen = set()
        for margin in MARGINS:
            try:
                alpha, p = _alpha_for(F, C, Qn, R, lam ** (1.0 + margin), kf)
            except DesignError:
                continue
            if alpha in seen:
                continue
            seen.add(alpha)
            candidates.append((margin, alpha, p, whole_gains(sc, p.L, pi)))
        if not candidates:
            raise DesignError(_no_centralized(lam, F, Cs))
    # the smallest centralized error first; above SEARCH_DIM the first candidate that certifies is kept (each one
    # costs eigenvalue and Lyapunov problems of size m n: seconds each at 1700)
    candidates.sort(key=lambda c: math.inf if c[2] is None else c[2].rms)
    tried, best = [], None
    for margin, alpha, p, Ks in candidates:
        if best is not None and sc.m * sc.n > SEARCH_DIM:
            break
        Fs, Kss = step_blocks(sc.system.A, Ks, Cs, dt=sc.run.dt if sc.time == "continuous" else None)
        by_id = _Radii(dict(zip(sc.agent_ids, Fs)))
        q_cert = _smallest_q(sc, by_id, cases, lam, q_cap) if q_given is None else q_given
        if q_cert is None:
            tried.append((margin, alpha, None, None, None))
            continue
        q, rms = _noise_q(sc, Fs, Kss, first.S, q_cert, Qn, R, q_cap, by_id.rms,
                          lambda q: _certifies(sc, by_id, cases, lam, q)) if q_given is None else \
            (q_given, _predicted(sc, Fs, Kss, first.S, q_given, Qn, R, by_id.rms))
        radius = radius_at(sc, by_id, cases, q)
        tried.append((margin, alpha, q, radius, rms))
        key = (math.inf if rms is None else rms, q)
        if best is None or _better(key, best[0]):
            best = (key, margin, alpha, p, Ks, q, q_cert, by_id)
    if best is None:
        raise DesignError(_why_not(sc, candidates, cases, lam, q_cap, Cs))
    _, margin, alpha, p, Ks, q, q_cert, by_id = best
    radii, cert = certify(sc, by_id, cases, q, lam, dwell, warnings)
    Lp = p.L if p is not None else np.zeros((sc.n, C.shape[0]))
    info = WholeState(alpha=alpha if alpha is not None else float("nan"), L=Lp, pi=pi, lam_step=lam,
                      central_radius=p.radius if p is not None else float("nan"),
                      central_rms=p.rms if p is not None else float("nan"),
                      kf_radius=None if kf is None else kf.radius, kf_rms=None if kf is None else kf.rms,
                      reference_rms=None if ref is None else ref.rms, q_certified=q_cert, tried=tuple(tried),
                      method=d.gains, predicted=by_id.rms.get(int(q)))
    return Ks, q, info, radii, cert


def _why_not(sc: Scenario, candidates, cases, lam: float, q_cap: int, Cs) -> str:
    """Why no candidate certifies: as q grows a case's map tends to its agents' average ``sum_i pi_i F_i`` (``pi`` its
    graph's stationary weights); a case where that decays no faster than the rate is one no q helps (an agent loss
    the kept gains do not survive), else the consensus needs more than ``q_cap`` exchanges."""
    _, _, _, Ks = candidates[0]
    Fs, _ = step_blocks(sc.system.A, Ks, Cs, dt=sc.run.dt if sc.time == "continuous" else None)
    by_id = dict(zip(sc.agent_ids, Fs))
    per = "per event time" if sc.time == "discrete" else "per step"
    for c in cases:
        pi_c = perron_vector(c.graph.S)
        limit = spectral_radius(sum(w * by_id[i] for w, i in zip(pi_c, c.graph.ids)))
        if limit >= lam:
            return (f"no whole-state design meets rate {lam:.6g} {per} on {c.label}: with the gains kept, its agents' "
                    f"average decays at only {limit:.6g} {per}, whatever q (the split keeps each agent's own gain)")
    return (f"no whole-state design meets rate {lam:.6g} {per} with q <= {q_cap}: the consensus cannot keep up with "
            "the gains (a slower design.rate, or a graph that mixes faster)")


def _better(key: tuple, other: tuple) -> bool:
    """A candidate's ``(rms, q)`` beats another's: a smaller RMS by more than 2 %, or as good within 2 % and fewer
    exchanges."""
    (r, q), (r0, q0) = key, other
    if math.isinf(r) or math.isinf(r0):
        return (r, q) < (r0, q0)
    if r < r0 * 0.98:
        return True
    return r <= r0 * 1.02 and q < q0


def radius_at(sc: Scenario, by_id: dict, cases, q: int) -> dict:
    """Every case's full error matrix's spectral radius at ``q`` (:func:`case_radius`, each computed once).

    Parameters
    ----------
    sc : Scenario
        The scenario (its size ``m n``).
    by_id : dict
        ``{agent id: F_i}`` with the cache of computed radii (``of(sc, case, q)``; the designer's ``_Radii``).
    cases : sequence of bounds.Case
        The cases the design covers.
    q : int
        Consensus exchanges per event time.

    Returns
    -------
    dict
        ``{case label: radius (float)}``; empty when ``m n`` exceeds :data:`MAX_RATE_DIM` (too large for the dense
        eigenvalue problem).
    """
    if sc.m * sc.n > MAX_RATE_DIM:
        return {}
    return {c.label: by_id.of(sc, c, q) for c in cases}


def _certifies(sc: Scenario, by_id, cases, lam: float, q: int) -> bool:
    """Every case's full error matrix at ``q`` has radius below ``lam`` (above :data:`MAX_RATE_DIM`: the mixing bound
    of each agent set's graphs)."""
    if sc.m * sc.n > MAX_RATE_DIM:
        groups = same_agents(cases)
        return all(certifies(mixing_bound([by_id[i] for i in ids], Ss, q, lam), lam) for ids, Ss in groups.items())
    return all(certifies(by_id.of(sc, c, q), lam) for c in cases)


def _smallest_q(sc: Scenario, by_id: dict, cases, lam: float, q_cap: int) -> int | None:
    """The smallest q whose full error matrices (each case held constant) all have radius below ``lam`` (doubling,
    then bisection); above :data:`MAX_RATE_DIM` the mixing bound's; None when none up to ``q_cap`` does."""
    try:  # every q up to a few (the radius need not be monotone in q), then doubling and bisection
        return smallest(lambda q: _certifies(sc, by_id, cases, lam, q), q_cap, what="q",
                        scan=SCAN if sc.m * sc.n <= SEARCH_DIM else 4)
    except DesignError:
        return None


def _noise_q(sc: Scenario, Fs, Kss, S, q0: int, Qn, R, q_cap: int, per_agent: dict, ok=None) -> tuple:
    """From the smallest certified ``q0``: raised while more exchanges lower the predicted RMS by more than
    :data:`Q_GAIN` each (at most :data:`Q_EXTRA` more; above :data:`SEARCH_DIM` two at a time, once);
    ``(q, rms)`` (``rms`` None when not computed).  The radius is not monotone in q (a q between two certified ones
    can miss the rate: the disagreement's modes rotate), so a q that ``ok`` does not certify is stepped over."""
    rms = _predicted(sc, Fs, Kss, S, q0, Qn, R, per_agent)
    q, cand = q0, q0
    step, extra = (1, Q_EXTRA) if sc.m * sc.n <= SEARCH_DIM else (2, 2)
    while rms is not None and cand + step <= min(q0 + extra, q_cap):
        cand += step
        if ok is not None and not ok(cand):
            continue  # not certified at this q: the next one may be
        nxt = _predicted(sc, Fs, Kss, S, cand, Qn, R, per_agent)
        if nxt is None or nxt > rms * (1.0 - (cand - q) * Q_GAIN):
            break
        q, rms = cand, nxt
    return q, rms


def _no_centralized(lam: float, F: np.ndarray, Cs) -> str:
    """Why no centralized Riccati design meets ``lam`` per event time, as computed: the slowest mode no agent sees
    (``F`` on :func:`~splitspec_core.model.observability.unobservable_directions`), or, when every such mode is
    faster, the seen modes too weakly observable for the shifted Riccati equation."""
    V = unobservable_directions(F, Cs)
    slowest = float(np.max(np.abs(np.linalg.eigvals(V.T @ F @ V)))) if V.shape[1] else None
    head = f"no centralized Riccati design meets {lam:.6g} per event time: "
    if slowest is not None and slowest >= lam:
        return head + f"a mode no agent sees decays with radius {slowest:.6g} per event time, slower than that"
    unseen = ("" if slowest is None else
              f" (the modes no agent sees decay faster, radius {slowest:.6g})")
    return head + ("the shifted Riccati equation has no stabilising solution: a mode the sensors see is too weakly "
                   f"observable to move that far{unseen}")



def agent_gain(des, agent_id: int) -> dict | None:
    """What agent ``agent_id``'s process is sent when the design chose its gain centrally (the whole-state design, or
    ``design.gains: optimal`` whatever consensus it chose), else None (the agent computes its own part of the
    design, :func:`splitspec_core.model.local_design.scenario_agent`): ``{"K": K_i, "consensus": ..., "P": P_i}``
    in the user's coordinates, exactly the floats the simulator holds (``Design.agents``).

    Parameters
    ----------
    des : Design
        The design (:func:`splitspec_core.synthesis.designer.design`).
    agent_id : int
        One of its agents.

    Returns
    -------
    dict or None
        ``{"K": nested list (n x s_i), "consensus": "whole" or "split"}``, with ``"P"`` (n x n nested list) for the
        split; the fusion kind's :func:`~splitspec_core.synthesis.fusion_kind.agent_fusion`; None when the agent
        designs its own gain (a local method with the split).

    Examples
    --------
    >>> import splitspec_core as ss
    >>> from splitspec_core.synthesis.designer import design
    >>> sc = ss.scenario(A=[[0.9, 0.2], [0, 0.8]], C={1: [[1, 0]], 2: [[0, 1]]}, graphs={"a": [(1, 2), (2, 1)]},
    ...                  rate=0.5, process_noise=0.1, measurement_noise=0.1, consensus="whole")
    >>> sent = agent_gain(design(sc), 1)
    >>> sent["consensus"], np.round(sent["K"], 4).tolist()
    ('whole', [[-1.0906], [-0.0282]])
    >>> agent_gain(design(ss.load_scenario("examples/paper_discrete.yaml")), 1) is None
    True
    """
    if des.consensus == "fusion":  # its gains per graph and its weights per neighbour (fusion_kind.py)
        from .fusion_kind import agent_fusion

        return agent_fusion(des, agent_id)
    if des.consensus == "relay":  # its walk's gains by lag (relay.py)
        from .relay import agent_relay

        return agent_relay(des, agent_id)
    if des.consensus != "whole" and gain_methods.method(des.scenario.design.gains).local:
        return None
    a = next(a for a in des.agents if a.id == agent_id)
    out = {"K": np.asarray(a.K, dtype=float).tolist(), "consensus": des.consensus}
    if des.consensus != "whole":
        out["P"] = np.asarray(a.P, dtype=float).tolist()
    return out
