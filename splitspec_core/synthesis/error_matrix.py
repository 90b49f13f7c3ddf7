"""The full ``mn x mn`` error dynamics of a design: its matrices, their spectra and noise (matrices only: what a
design does with them is the designer's, :func:`splitspec_core.synthesis.approximate.check_full`).

The full error matrix of one step, for the agents of a case with consensus matrix ``S``:

discrete (eq. split-discrete-error)
    ``M = blkdiag(A + K_i C_i) W^q``,  ``W = I - P (I - Sbar)`` (the consensus sub-round), ``Sbar = S (x) I_n``;
continuous, sampled-data form (:mod:`splitspec_core.model.steps`)
    ``M = blkdiag(E + D K_i C_i) - g blkdiag(D P_i) (I - Sbar)``, ``E = exp(A dt)``, ``D = int_0^dt exp(A s) ds``;
    and the ODE's own matrix ``Abar - g P (I - Sbar)`` (eq. split_continuous_em).

With an exact observability split these have the spectrum of the split blocks (prop. error,
prop. errordis), which is what the certificates of :mod:`.bounds` use.  When a weakly observable
direction was left to consensus (:mod:`splitspec_core.model.observability`) the split holds only up to
``split_residual``: :func:`full_radius` gives these full matrices' decay for every case held constant, which
the designer checks the rate on (:func:`splitspec_core.synthesis.approximate.check_full`: it raises an automatic
q or g until they meet it, and says so).

Steady-state noise (:func:`predicted_rms`): with process noise ``v`` (covariance ``Q``) and measurement
noise ``w`` (``R``) the stacked error follows ``e(k+1) = M e(k) - blkdiag(K_i) w(k) - (1 (x) I) v(k)``
(discrete; the sampled-data analogue in continuous time), and its steady-state covariance solves the
discrete Lyapunov equation ``Sigma = M Sigma M' + N``; agent i's RMS error is ``sqrt(trace Sigma_ii)``
(what a long simulation's RMS converges to: tested).
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

from .design_data import cached_analysis

if TYPE_CHECKING:  # annotations only
    from .design_data import Design

__all__ = ["full_error_matrix", "ode_error_matrix", "modulo", "case_parts", "full_radius", "error_dynamics",
           "predicted_rms", "MAX_DIM", "MAX_RATE_DIM", "MAX_NOISE_DIM",
           "block_diagonal", "step_blocks", "whole_matrix", "whole_noise", "remember_predicted"]

#: the largest ``m n`` for which the full error matrices' powers and Lyapunov equations are formed (the transient
#: constant, the predicted noise)
MAX_DIM = 1000
#: the largest ``m n`` for which an approximate split's rate is checked on the full error matrices (their
#: eigenvalues only: a few seconds per graph at 2000)
MAX_RATE_DIM = 2000
#: the largest ``m n`` for which the steady-state noise is predicted (one discrete Lyapunov equation: about 8 s at
#: 1700 on one core)
MAX_NOISE_DIM = 2000


def block_diagonal(blocks) -> np.ndarray:
    """Block diagonal that keeps zero-width blocks (``V_i`` with ``n_i = 0``) as rows (numpy only: agent
    processes import this module and never scipy).

    Parameters
    ----------
    blocks : sequence of 2-D arrays
        The blocks, any shapes (zero rows or columns allowed).

    Returns
    -------
    (sum of rows, sum of columns) array
        The blocks on the diagonal, zeros elsewhere.
    """
    out = np.zeros((sum(b.shape[0] for b in blocks), sum(b.shape[1] for b in blocks)))
    r = c = 0
    for b in blocks:
        out[r:r + b.shape[0], c:c + b.shape[1]] = b
        r += b.shape[0]
        c += b.shape[1]
    return out


def step_blocks(A: np.ndarray, Ks, Cs, *, dt: float | None = None) -> tuple:
    """``(F_i, K_s,i)`` per agent of the whole-state estimator: one event time's error map and noise gain
    (:func:`splitspec_core.model.steps.step_matrices`: ``A + K_i C_i`` and ``K_i``, or ``E + D K_i C_i`` and ``D K_i``
    in continuous time, ``dt`` = ``run.dt``).

    Parameters
    ----------
    A : (n, n) array
        The system matrix.
    Ks, Cs : sequences of arrays
        Per agent, in one order: the gains ``K_i`` (n, s_i) and the output matrices ``C_i`` (s_i, n).
    dt : float, optional
        Continuous time: the sampling period (``run.dt``); None: discrete time.

    Returns
    -------
    tuple of (list, list)
        ``([F_i], [K_s,i])``: the (n, n) error maps and the (n, s_i) noise gains, one per agent.
    """
    from ..model.steps import sampled_data_matrices, step_matrices

    ED = None if dt is None else sampled_data_matrices(np.asarray(A, dtype=float), dt)[:2]
    out = [step_matrices(A, np.asarray(K, dtype=float), np.asarray(C, dtype=float), dt=dt, sampled=ED)[1:3]
           for K, C in zip(Ks, Cs)]
    return [F for F, _ in out], [K for _, K in out]


def whole_matrix(Fs, S: np.ndarray, q: int) -> np.ndarray:
    """``(S^q (x) I) blkdiag(F_i)``: the whole-state estimator's full error matrix of one event time
    (:mod:`splitspec_core.synthesis.whole_state`: update, then average q times).

    Parameters
    ----------
    Fs : sequence of (n, n) arrays
        Every agent's error map ``F_i`` (:func:`step_blocks`).
    S, q : (m, m) array, int
        The stochastic consensus matrix and the averaging rounds per event time.

    Returns
    -------
    (mn, mn) array
        ``(S^q (x) I_n) blkdiag(F_i)``.
    """
    n = Fs[0].shape[0]
    Sq = np.linalg.matrix_power(np.asarray(S, dtype=float), int(q))
    return np.kron(Sq, np.eye(n)) @ block_diagonal(Fs)


def whole_noise(Kss, S: np.ndarray, q: int, R: np.ndarray, Qn: np.ndarray) -> np.ndarray:
    """The covariance of the noise entering one event time of the whole-state estimator:
    ``W blkdiag(K_s,i) R blkdiag(K_s,i)' W' + 11' (x) Q``, ``W = S^q (x) I``.

    Parameters
    ----------
    Kss : sequence of (n, s_i) arrays
        Every agent's noise gain ``K_s,i`` (:func:`step_blocks`).
    S, q : (m, m) array, int
        The stochastic consensus matrix and the averaging rounds per event time.
    R : (sum s_i, sum s_i) array
        The stacked measurement noise covariance.
    Qn : (n, n) array
        The process noise covariance per event time.

    Returns
    -------
    (mn, mn) array
        The noise covariance, symmetrised.
    """
    m, n = len(Kss), Kss[0].shape[0]
    W = np.kron(np.linalg.matrix_power(np.asarray(S, dtype=float), int(q)), np.eye(n))
    G = W @ block_diagonal(Kss)
    one = np.kron(np.ones((m, 1)), np.eye(n))
    N = G @ R @ G.T + one @ Qn @ one.T
    return 0.5 * (N + N.T)


def full_error_matrix(A: np.ndarray, Cs, Ks, Ps, S: np.ndarray, *, time: str, q: int | None = None,
                      g: float | None = None, dt: float | None = None, consensus: str = "split") -> np.ndarray:
    """The full error matrix of one event time (discrete) or one sampled-data step (continuous); module docstring.
    ``consensus="whole"``: the whole-state estimator's (:func:`whole_matrix`; ``Ps`` unused, ``q`` exchanges per
    event time in both times).

    Parameters
    ----------
    A : (n, n) array
        The system matrix.
    Cs, Ks, Ps : sequences of arrays
        Per agent, in one order: ``C_i`` (s_i, n), ``K_i`` (n, s_i) and the projection ``P_i`` (n, n).
    S : (m, m) array
        The stochastic consensus matrix (``Sbar = S (x) I_n``).
    time : {"discrete", "continuous"}
        The scenario's time.
    q, g, dt : int, float, float, optional
        Consensus sub-rounds per event time (discrete, and the whole-state estimator), the consensus gain and the
        sampling period (continuous): each required where it applies.
    consensus : {"split", "whole"}
        The split estimator (the paper's) or the whole-state one.

    Returns
    -------
    (mn, mn) array
        ``M``: the stacked errors ``e(k+1) = M e(k)`` without noise.

    Examples
    --------
    >>> import numpy as np
    >>> A, S = np.array([[1.2]]), np.full((2, 2), 0.5)  # agent 1 sees x, agent 2 sees nothing
    >>> M = full_error_matrix(A, [np.eye(1), np.zeros((1, 1))], [-np.eye(1), np.zeros((1, 1))],
    ...                       [np.zeros((1, 1)), np.eye(1)], S, time="discrete", q=1)
    >>> np.round(M, 3).tolist(), np.round(np.sort(abs(np.linalg.eigvals(M))), 3).tolist()
    ([[0.2, 0.0], [0.6, 0.6]], [0.2, 0.6])
    """
    A = np.asarray(A, dtype=float)
    n, m = A.shape[0], len(Cs)
    if consensus == "whole":
        return whole_matrix(step_blocks(A, Ks, Cs, dt=dt if time == "continuous" else None)[0], S, int(q))
    SI = np.kron(S, np.eye(n))
    if time == "discrete":
        W = np.eye(m * n) - block_diagonal(Ps) @ (np.eye(m * n) - SI)  # eq. (split-discrete-p1..p3), one sub-round
        return block_diagonal([A + K @ C for K, C in zip(Ks, Cs)]) @ np.linalg.matrix_power(W, int(q))
    from ..scenarios.sampling import sampled_data_matrices

    E, D, _ = sampled_data_matrices(A, dt)
    return (block_diagonal([E + D @ K @ C for K, C in zip(Ks, Cs)])
            - g * block_diagonal([D @ P for P in Ps]) @ (np.eye(m * n) - SI))


def modulo(M: np.ndarray, W: np.ndarray, m: int) -> np.ndarray:
    """The error map ``M`` (every agent's error stacked) modulo the directions ``W`` (orthonormal, A-invariant, no agent
    sees them): ``(I_m (x) U_o') M (I_m (x) U_o)`` with ``U_o`` spanning ``W^⊥``.  ``M`` is block triangular in the
    coordinates ``(U_o' e_i, W' e_i)`` (:mod:`splitspec_core.model.detectability`), so this is the map of the quotient's
    errors, whatever ``W``'s part does.

    Parameters
    ----------
    M : (mn, mn) array
        The stacked error map (or a covariance, transformed the same way).
    W : (n, w) array
        Orthonormal basis of the unobserved directions.
    m : int
        The number of agents stacked in ``M``.

    Returns
    -------
    (m(n - w), m(n - w)) array
        The map on the quotient errors; ``M`` itself when ``w = 0``.
    """
    from ..model.subspaces import complement

    if W.shape[1] == 0:
        return M
    T = np.kron(np.eye(m), complement(W))
    return T.T @ M @ T


def ode_error_matrix(A: np.ndarray, Cs, Ks, Ps, S: np.ndarray, g: float) -> np.ndarray:
    """``Abar - g P (I - Sbar)`` (eq. split_continuous_em).

    Parameters
    ----------
    A : (n, n) array
        The system matrix.
    Cs, Ks, Ps : sequences of arrays
        Per agent: ``C_i``, ``K_i``, ``P_i``.
    S, g : (m, m) array, float
        The stochastic consensus matrix and the consensus gain.

    Returns
    -------
    (mn, mn) array
        The continuous-time error ODE's matrix, ``Abar = blkdiag(A + K_i C_i)``.
    """
    n, m = np.shape(A)[0], len(Cs)
    return (block_diagonal([np.asarray(A) + K @ C for K, C in zip(Ks, Cs)])
            - g * block_diagonal(Ps) @ (np.eye(m * n) - np.kron(S, np.eye(n))))


def case_parts(des: "Design", case) -> tuple:
    """``(Cs, Ks, Ps)`` of the agents of ``case``'s graph, in its order: what the full error matrices are made of.

    Parameters
    ----------
    des, case : Design, bounds.Case
        The design and one of its cases (its ``graph.ids`` choose the agents).

    Returns
    -------
    tuple of (list, list, list)
        The ``C_i`` (scenario's), ``K_i`` and ``P_i`` (design's) arrays.
    """
    sc = des.scenario
    ad = {a.id: a for a in des.agents}
    Cs = dict(zip(sc.agent_ids, sc.system.Cs))
    ids = case.graph.ids
    return ([np.asarray(Cs[i]) for i in ids], [ad[i].K for i in ids], [ad[i].P for i in ids])


def full_radius(des: "Design", cases, *, q: int | None = None, g: float | None = None) -> dict:
    """Per case: the full error matrix's decay, in the certificate's terms.

    Discrete: the spectral radius of ``M`` (must be below ``lam``).  Continuous: ``{"ode": spectral
    abscissa of Abar - g P (I - Sbar)`` (must be at most ``-lam``), ``"sampled": -log rho(M) / dt`` (the decay
    rate of the sampled-data form, at least ``lam``)}.

    Parameters
    ----------
    des : Design
        The design (with ``design.undetectable: exclude`` the matrices are taken modulo ``W``).
    cases : iterable of bounds.Case
        The cases to check.
    q, g : int, float, optional
        The q to check (discrete time, the whole-state estimator) or the g (continuous split estimator): required
        where it applies (not ``des.q`` or ``des.g`` by default).

    Returns
    -------
    dict
        ``{case label: radius}`` (discrete, whole-state) or ``{case label: {"ode": ..., "sampled": ...}}``.

    """
    sc = des.scenario
    A = np.asarray(sc.system.A)
    out = {}

    def mod(M, k):  # design.undetectable: exclude: what the certificate covers is the error modulo W
        return modulo(M, des.unobserved.W, k) if des.excluded else M

    for case in cases:
        Cs, Ks, Ps = case_parts(des, case)
        if des.consensus == "whole":  # one event time (continuous: one run.dt) of the whole-state estimator
            M = mod(full_error_matrix(A, Cs, Ks, Ps, case.graph.S, time=sc.time, q=q, dt=sc.run.dt,
                                      consensus="whole"), len(Cs))
            out[case.label] = float(np.max(np.abs(np.linalg.eigvals(M))))
        elif sc.time == "discrete":
            M = mod(full_error_matrix(A, Cs, Ks, Ps, case.graph.S, time="discrete", q=q), len(Cs))
            out[case.label] = float(np.max(np.abs(np.linalg.eigvals(M))))
        else:
            ode = float(np.max(np.linalg.eigvals(mod(ode_error_matrix(A, Cs, Ks, Ps, case.graph.S, g),
                                                     len(Cs))).real))
            M = mod(full_error_matrix(A, Cs, Ks, Ps, case.graph.S, time="continuous", g=g, dt=sc.run.dt), len(Cs))
            rho = float(np.max(np.abs(np.linalg.eigvals(M))))
            out[case.label] = {"ode": ode, "sampled": -math.log(rho) / sc.run.dt if rho > 0 else math.inf}
    return out


def error_dynamics(des: "Design", graph_index: int = 0) -> tuple:
    """``(M, N)``: the full error matrix of the scenario's graph ``graph_index`` held constant, every agent,
    and the covariance of the noise entering per step (module docstring).

    Parameters
    ----------
    des, graph_index : Design, int
        The design (the scenario's noise, ``des.q`` or ``des.g``) and which of the scenario's graphs.

    Returns
    -------
    tuple of ((mn, mn) array, (mn, mn) array)
        ``(M, N)``; ``e(k+1) = M e(k) + noise`` with covariance ``N``.

    Raises
    ------
    DesignError
        The adaptive gain (continuous, no fixed g).
    """
    from ..model.plant import sampled_model
    from ..errors import DesignError
    from ..model.network import consensus_rows

    sc = des.scenario
    m, n = sc.m, sc.n
    if des.consensus == "relay":  # no map of the estimates alone: the base and the samples held are state too
        raise DesignError("the relay kind's error is not a map of the agents' estimates alone (each agent's base "
                          "and the samples it holds are state too): its prediction is the design's (synthesis/relay.py)")
    if des.consensus == "fusion":  # its own error map and noise (synthesis/fusion_kind.py)
        from .fusion_kind import fusion_matrix, fusion_noise

        return fusion_matrix(des, graph_index), fusion_noise(des, graph_index)
    _, Qn, R = sampled_model(sc)
    rows = consensus_rows(sc, graph_index, sc.agent_ids)
    pos = {a: k for k, a in enumerate(sc.agent_ids)}
    S = np.zeros((m, m))
    for i, (nbs, ws) in rows.items():
        for j, w in zip(nbs, ws):
            S[pos[i], pos[j]] = w
    Ks = [np.asarray(K) for K in des.Ks]
    Cs = [np.asarray(C) for C in sc.system.Cs]
    Ps = [np.asarray(P) for P in des.Ps]
    if des.consensus == "whole":
        Fs, Kss = step_blocks(sc.system.A, Ks, Cs, dt=sc.run.dt if sc.time == "continuous" else None)
        return whole_matrix(Fs, S, des.q), whole_noise(Kss, S, des.q, R, Qn)
    if sc.time == "discrete":
        M = full_error_matrix(sc.system.A, Cs, Ks, Ps, S, time="discrete", q=des.q)
        G = block_diagonal(Ks)
    else:
        if des.g is None:
            raise DesignError("the adaptive gain has no steady-state error covariance (g changes with time)")
        from ..scenarios.sampling import sampled_data_matrices

        M = full_error_matrix(sc.system.A, Cs, Ks, Ps, S, time="continuous", g=des.g, dt=sc.run.dt)
        _, D, _ = sampled_data_matrices(np.asarray(sc.system.A), sc.run.dt)
        G = block_diagonal([D @ K for K in Ks])
    one = np.kron(np.ones((m, 1)), np.eye(n))
    N = G @ R @ G.T + one @ Qn @ one.T
    return M, 0.5 * (N + N.T)


def predicted_rms(des: "Design", graph_index: int = 0) -> np.ndarray:
    """Steady-state RMS error ``sqrt(trace Sigma_ii)`` of every agent (inf if the error map is unstable); computed
    once per design and graph (a Lyapunov equation of size ``m n``: seconds at 1700); DesignError for the adaptive
    gain (:func:`error_dynamics`).

    Parameters
    ----------
    des, graph_index : Design, int
        The design and which of the scenario's graphs, held constant.

    Returns
    -------
    (m,) array
        Per agent, in the scenario's order (a copy); with ``design.undetectable: exclude``, of the error modulo
        ``W``.
    """
    return _predicted_rms(des, graph_index=int(graph_index)).copy()


def remember_predicted(des: "Design", graph_index: int, values: np.ndarray) -> None:
    """Keep ``values`` as ``des``'s :func:`predicted_rms` on graph ``graph_index``: the design computed them already
    (:mod:`.whole_state`, while choosing q).

    Parameters
    ----------
    des, graph_index : Design, int
        The design and which of the scenario's graphs.
    values : (m,) array_like
        The RMS errors per agent.
    """
    _predicted_rms.remember(des, np.asarray(values, dtype=float), graph_index=int(graph_index))


@cached_analysis
def _predicted_rms(des: "Design", *, graph_index: int) -> np.ndarray:
    import scipy.linalg as sla

    sc = des.scenario
    M, N = error_dynamics(des, graph_index)
    if des.excluded:  # the error modulo the directions no agent sees, which do not decay (design.undetectable: exclude)
        M, N = modulo(M, des.unobserved.W, sc.m), modulo(N, des.unobserved.W, sc.m)
    if np.max(np.abs(np.linalg.eigvals(M))) >= 1.0:
        return np.full(sc.m, math.inf)
    Sigma = sla.solve_discrete_lyapunov(M, N)
    n = M.shape[0] // sc.m
    return np.sqrt(np.maximum([np.trace(Sigma[i * n:(i + 1) * n, i * n:(i + 1) * n]) for i in range(sc.m)], 0.0))
