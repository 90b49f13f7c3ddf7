"""The fusion kind: each exchange fuses the neighbours' estimates with matrix weights chosen for the noise.

The estimator
-------------
The paper's two-rate protocol (eqs. split-discrete-est1 .. p3: measure, ``q`` exchanges, predict) with the
consensus step's scalar weights and projection ``P_i`` replaced by matrix weights, one set per sub-round
(:mod:`splitspec_core.model.steps`: :func:`~splitspec_core.model.steps.local_update`,
:func:`~splitspec_core.model.steps.matrix_fusion`, :func:`~splitspec_core.model.steps.prediction_update`)::

    z_i(0) = x_i(tau) + L_i (y_i(tau) - C_i x_i(tau))          (no measurement: z_i(0) = x_i(tau))
    z_i(k) = sum_{j in N_i} W_ij(k) z_j(k - 1),  sum_j W_ij(k) = I,   k = 1 .. q
    x_i(tau + 1) = F z_i(q) [+ B u(tau)]

Each exchange sends one estimate: ``n`` numbers per agent, ``q n`` per event time, as the paper's protocol does.
``sum_j W_ij(k) = I`` keeps exact estimates exact, so the error ``e_i = x_i - x`` obeys (``w`` the process noise,
``v_i`` agent i's measurement noise)::

    e(tau + 1) = M e(tau) + (I (x) F) W(q) .. W(1) blkdiag(L_i) v(tau) - 1 (x) w(tau)
    M = (I (x) F) W(q) .. W(1) blkdiag(I - L_i C_i)

``W(k)`` the block matrix of the ``W_ij(k)`` (block ``ij`` zero unless i hears j).  Its steady covariance ``X``
solves ``X = M X M' + (I (x) F) W L R L' W' (I (x) F)' + 1 1' (x) Q``.

The gains (where the accuracy comes from)
-----------------------------------------
Every gain is the best for its agent given what the others do, at the steady state: with ``X`` the joint covariance of
the predicted errors, ``L_i`` is agent i's Kalman update (``X_ii C_i' (C_i X_ii C_i' + R_i)^-1``), and after it each
``W_i(k)`` is the best linear unbiased fusion of the estimates agent i hears, given their joint covariance
``Sigma`` (the blocks of ``N_i``): ``W_i = (J' Sigma^-1 J)^-1 J' Sigma^-1``, ``J = [I; ..; I]``.  The correlations
between neighbours' errors (the common process noise, the information they already share) are in ``Sigma``, so
nothing is counted twice.  This is the steady-state distributed Kalman filter of Rego et al. (there: fuse the
neighbours' predictions, then measure) moved inside the two-rate protocol (measure, then fuse ``q`` times), which lets
a sensor's sample of ``tau`` reach agents up to ``q`` hops away before the prediction of ``tau + 1``: the protocol's
limit (:mod:`.exchange_limit`) is what this can approach.  ``Sigma`` is regularised by ``REG`` on the diagonal of
its correlation matrix (neighbours' estimates grow nearly identical as ``q`` grows: the weights stay bounded; states
in any units).

The iteration: ``FIXED`` plain event times of the covariance recursion from independent errors, then policy
iteration (the gains of ``X`` frozen, their steady ``X`` by Smith doubling, again) until the trace settles; the
gains of the smallest trace seen are kept (each evaluated exactly, so any of them is a valid estimator).  Greedy
gains are not a policy improvement: the gains of an exact steady covariance are sometimes not stabilising (with
``REG`` 1e-9, every policy step on the IEEE 39-bus model at q = 3); then the step is damped (``DAMP``: part of the way
from the last stabilising gains), and where that fails too more plain event times run before the next try.

What certifies it
-----------------
The rate: the spectral radius of the full error matrix ``M`` (every agent's whole error, ``m n`` unknowns) below
``lam`` per event time.  When the noise's gains are slower than the rate, the gains are designed for ``F / alpha``
(every error decays ``alpha`` faster in that design's model): the largest ``alpha`` in ``(0, 1]`` whose design
certifies, by continuation and regula falsi (:func:`design_fusion`).  The accuracy: ``X``, the Lyapunov solution of
the frozen design, with its residual; the envelope: :meth:`FusionDesign.transient_constant`.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
import scipy.linalg as sla
import scipy.sparse.linalg as spla

from ..errors import DesignError
from ..scenarios.specs import Scenario
from .kalman import kalman_predictor, regularise
from .spectral import certifies

__all__ = ["FusionDesign", "REG", "FIXED", "design_fusion", "fusion_gains", "error_map", "steady_covariance",
           "scenario_fusion", "neighbour_positions"]

log = logging.getLogger(__name__)

#: Tikhonov regularisation of a neighbourhood's covariance, added to the diagonal of its correlation matrix (1e-9
#: made the greedy gains of an exact steady covariance unstable at every policy step of the IEEE 39-bus model at q = 3,
#: the weights of nearly equal estimates unbounded: 841 s; 1e-6: stable after the first, 96 s, the same 1.205x)
REG = 1e-6
#: the most the regularisation grows to where round-off leaves a neighbourhood's correlations indefinite
REG_MAX = 1e-3
#: plain event times of the covariance recursion before policy iteration
FIXED = 20
#: policy iterations at most
OUTER = 60
#: the trace of ``X`` settled: no fall by more than this fraction in ``STALL`` policy iterations
TOL = 1e-7
STALL = 2
#: damped policy steps, tried in turn where the greedy gains do not stabilise: the fraction of the step taken
DAMP = (0.5, 0.25, 0.125)
#: search steps of the shift alpha (regula falsi, bisection where a failed design has no radius)
ALPHA_STEPS = 6
#: a continuation step keeps the last stable gains' radius on F / alpha at most this (closer to 1 its covariance
#: grows without bound and its next gains do not stabilise: the IEEE 39-bus model at 0.9999)
CONTINUE = 0.999
#: the shift's search gives up after two steps in a row that closed less than this fraction of the gap between the
#: smallest radius so far and the rate
STALLED = 0.1
#: the shift's search stops once the radius is within this fraction below the rate
SETTLE = 2e-3
#: plain event times before policy iteration when warm-started from another shift's covariance
WARM_FIXED = 3
#: above this many unknowns (m n) the radius is ARPACK's, checked densely near the rate
DENSE_RADIUS = 600
#: an iterative radius within this fraction of the rate is computed again densely
DECIDE = 1e-2


@dataclass(frozen=True)
class FusionDesign:
    """A fusion design: the gains, what they certify and what they are predicted to give.

    Attributes
    ----------
    q : int
        Exchanges per event time.
    neighbours : tuple of tuple of int
        ``N_i`` per agent (0-based positions, itself first).
    Ls : tuple of (n, s_i) arrays
        The local update gains ``L_i``.
    weights : tuple of tuple of (n, |N_i| n) arrays
        ``weights[k][i] = [W_ij(k+1) for j in N_i]`` side by side.
    F : (n, n) array
        The per-step model.
    alpha : float
        The shift the gains were designed with (1: none).
    radius : float
        ``rho(M)``: every eigenvalue up to ``DENSE_RADIUS`` unknowns, else ARPACK's largest (dense again within
        ``DECIDE`` of the rate).
    covariance : (m n, m n) array
        ``X``, the steady covariance of the predicted errors.
    residual : float
        ``|X - M X M' - N|_max / |X|_max`` of the Lyapunov equation.
    iterations : int
        Policy iterations of the last design.
    kf_rms : float
        The centralized Kalman predictor's RMS per state.
    Cs : tuple of (s_i, n) arrays
        The output matrices the gains were designed for.
    """

    q: int
    neighbours: tuple
    Ls: tuple
    weights: tuple
    F: np.ndarray
    alpha: float
    radius: float
    covariance: np.ndarray
    residual: float
    iterations: int
    kf_rms: float
    Cs: tuple = ()

    @property
    def m(self) -> int:
        """Number of agents."""
        return len(self.neighbours)

    @property
    def n(self) -> int:
        """Number of states."""
        return self.F.shape[0]

    @property
    def agent_rms(self) -> np.ndarray:
        """``sqrt(trace X_ii / n)`` per agent: its predicted steady RMS per state."""
        d = np.diag(self.covariance).reshape(self.m, self.n)
        return np.sqrt(np.maximum(d.sum(axis=1), 0.0) / self.n)

    @property
    def rms(self) -> float:
        """``sqrt(trace X / (m n))``: the network's predicted steady RMS per state."""
        return float(np.sqrt(max(np.trace(self.covariance), 0.0) / (self.m * self.n)))

    @property
    def ratio(self) -> float:
        """``rms / kf_rms``: the predicted ratio to the centralized Kalman predictor."""
        return self.rms / self.kf_rms

    @property
    def M(self) -> np.ndarray:
        """The error map ``M = (I (x) F) W(q) .. W(1) blkdiag(I - L_i C_i)`` (:func:`error_map`)."""
        return error_map(self.F, self.Cs, self.Ls, self.weights, self.neighbours)[0]

    def transient_constant(self, rate: float) -> float:
        """``c`` with ``|e(tau)| <= c rate^tau |e(0)|`` for every ``tau`` without noise (the stacked error, 2-norm).

        From the Lyapunov function of ``M / rate``: ``P = (M / rate)' P (M / rate) + I`` exists when
        ``radius < rate``, ``e' P e`` does not grow along ``M / rate``, so ``c = sqrt(cond P)``.

        Parameters
        ----------
        rate : float
            ``lam`` per event time, above :attr:`radius`.

        Returns
        -------
        float
            ``c >= 1`` (``inf`` when ``radius >= rate``: no such constant).
        """
        if not self.radius < rate:
            return float("inf")
        Ms = self.M / rate
        P = sla.solve_discrete_lyapunov(Ms.T, np.eye(Ms.shape[0]))
        w = np.linalg.eigvalsh(0.5 * (P + P.T))
        return float(np.sqrt(w[-1] / w[0])) if w[0] > 0 else float("inf")

    @property
    def numbers_per_event(self) -> int:
        """What each agent sends per event time: ``q`` estimates of ``n`` numbers."""
        return self.q * self.n


def neighbour_positions(m: int, arcs) -> tuple:
    """``N_i`` per agent: 0-based positions of the agents i hears, itself first, then ascending.

    Parameters
    ----------
    m : int
        Number of agents.
    arcs : iterable of (int, int)
        Arcs ``(j, i)`` between 0-based positions.

    Returns
    -------
    tuple of tuple of int

    Examples
    --------
    >>> neighbour_positions(3, [(0, 1), (2, 1), (1, 0)])
    ((0, 1), (1, 0, 2), (2,))
    """
    nb = [set() for _ in range(m)]
    for j, i in arcs:
        if j != i:
            nb[i].add(int(j))
    return tuple((i,) + tuple(sorted(s)) for i, s in enumerate(nb))


def _rows(nb, n):
    return np.concatenate([np.arange(j * n, (j + 1) * n) for j in nb])


def _block_diag_sandwich(X: np.ndarray, T: np.ndarray) -> np.ndarray:
    """``blkdiag(T_i) X blkdiag(T_i)'`` for ``T`` of shape (m, n, n), by batched block products."""
    m, n = T.shape[0], T.shape[1]
    B = X.reshape(m, n, m, n).transpose(0, 2, 1, 3)
    B = T[:, None] @ B @ T[None].swapaxes(-1, -2)
    return B.transpose(0, 2, 1, 3).reshape(m * n, m * n)


def _fuse(X: np.ndarray, Wk, nbs, n: int) -> np.ndarray:
    """``W X W'`` with ``W`` the block-sparse fusion of one sub-round (one product per agent and side)."""
    Y = np.vstack([Wi @ X[_rows(nb, n)] for Wi, nb in zip(Wk, nbs)])
    Z = np.vstack([Wi @ Y.T[_rows(nb, n)] for Wi, nb in zip(Wk, nbs)])
    return 0.5 * (Z + Z.T)


def _blue(Sigma: np.ndarray, k: int, n: int) -> np.ndarray:
    """``(J' S^-1 J)^-1 J' S^-1`` for ``S`` the regularised ``Sigma`` (``D (Sigma / d d' + REG I) D``, ``D = diag(d)``, ``d``
    the standard deviations): the best linear unbiased fusion of ``k``
    estimates of one ``n``-vector with joint error covariance ``Sigma``.  Where round-off leaves the regularised
    correlations indefinite, the regularisation grows tenfold until they factor (a Cholesky factorisation each: an
    eigendecomposition instead cost 36 % of the IEEE 39-bus design at q = 3), up to ``REG_MAX``; beyond, the
    pseudo-inverse of their positive part."""
    S = 0.5 * (Sigma + Sigma.T)
    d = np.sqrt(np.maximum(np.diag(S), np.finfo(float).tiny))
    C = S / np.outer(d, d)  # the correlations: the regularisation is the same for every state's units
    J = np.tile(np.eye(n), (k, 1)) / d[:, None]
    diag = np.diag_indices_from(C)
    reg = REG
    while reg <= REG_MAX:
        Cr = C.copy()
        Cr[diag] += reg
        try:
            G = sla.cho_solve(sla.cho_factor(Cr), J) / d[:, None]  # S^-1 J, S = D C D
            break
        except np.linalg.LinAlgError:
            reg *= 10.0
    else:
        w, U = np.linalg.eigh(C)
        keep = w > REG * w.max()
        G = ((U[:, keep] / w[keep]) @ (U[:, keep].T @ J)) / d[:, None]
    J = np.tile(np.eye(n), (k, 1))
    return np.linalg.solve(J.T @ G, G.T)


def fusion_gains(X: np.ndarray, Fa: np.ndarray, Cs, Rs, nbs, q: int) -> tuple:
    """The gains that are best for each agent given the predicted errors' joint covariance ``X`` (module docstring).

    Parameters
    ----------
    X : (m n, m n) array
        The joint covariance of ``e(tau)``.
    Fa : (n, n) array
        The design's model (``F / alpha``).
    Cs, Rs : sequences of arrays
        Output matrices and measurement noise covariances per agent.
    nbs : tuple of tuple of int
        ``N_i`` (:func:`neighbour_positions`).
    q : int
        Exchanges per event time.

    Returns
    -------
    tuple
        ``(Ls, weights, X_next)``: the gains, and the covariance after one event time with them (before the process
        noise is added: ``(I (x) Fa) W .. (L-updated X) .. W' (I (x) Fa)'``).
    """
    m, n = len(Cs), Fa.shape[0]
    Ls, T = [], np.empty((m, n, n))
    noise = np.zeros_like(X)
    for i, (C, R) in enumerate(zip(Cs, Rs)):
        Xi = X[i * n:(i + 1) * n, i * n:(i + 1) * n]
        L = np.linalg.solve(C @ Xi @ C.T + R, C @ Xi).T  # X_ii C' (C X_ii C' + R)^-1
        Ls.append(L)
        T[i] = np.eye(n) - L @ C
        noise[i * n:(i + 1) * n, i * n:(i + 1) * n] = L @ R @ L.T
    X = _block_diag_sandwich(X, T) + noise
    weights = []
    for _ in range(q):
        Wk = tuple(_blue(X[np.ix_(_rows(nb, n), _rows(nb, n))], len(nb), n) for nb in nbs)
        weights.append(Wk)
        X = _fuse(X, Wk, nbs, n)
    X = _block_diag_sandwich(X, np.broadcast_to(Fa, (m, n, n)))
    return tuple(Ls), tuple(weights), X


def error_map(F: np.ndarray, Cs, Ls, weights, nbs) -> tuple:
    """``(M, P)``: the error recursion ``e+ = M e + P blkdiag(L_i) v - 1 (x) w`` of the frozen gains.

    Parameters
    ----------
    F : (n, n) array
        The per-step model.
    Cs : sequence of (s_i, n) arrays
    Ls : sequence of (n, s_i) arrays
    weights : tuple of tuple of (n, |N_i| n) arrays
    nbs : tuple of tuple of int

    Returns
    -------
    tuple of two (m n, m n) arrays
        ``(M, P)``: ``M = (I (x) F) W(q) .. W(1) blkdiag(I - L_i C_i)`` and ``P = (I (x) F) W(q) .. W(1)``, which
        carries the measurement noise: the noise covariance per event time is
        ``P blkdiag(L_i R_i L_i') P' + 1 1' (x) Q``.
    """
    m, n = len(Cs), F.shape[0]
    # block by block: W(k) has a block only where i hears j, so P's blocks are those of the agents within k hops
    # (forming the dense m n x m n products cost three 1700^3 multiplications per design step on the IEEE 39-bus)
    P = {(i, i): np.eye(n) for i in range(m)}
    for Wk in weights:
        nxt: dict = {}
        for i, (Wi, nb) in enumerate(zip(Wk, nbs)):
            for a, j in enumerate(nb):
                Wij = Wi[:, a * n:(a + 1) * n]
                for (r, c), B in P.items():
                    if r == j:
                        nxt[(i, c)] = nxt[(i, c)] + Wij @ B if (i, c) in nxt else Wij @ B
        P = nxt
    T = [np.eye(n) - L @ C for L, C in zip(Ls, Cs)]
    Pd = np.zeros((m * n, m * n))
    Md = np.zeros((m * n, m * n))
    for (i, j), B in P.items():
        FB = F @ B
        Pd[i * n:(i + 1) * n, j * n:(j + 1) * n] = FB
        Md[i * n:(i + 1) * n, j * n:(j + 1) * n] = FB @ T[j]
    return Md, Pd


def steady_covariance(M: np.ndarray, N: np.ndarray, *, doublings: int = 60) -> np.ndarray:
    """``X = sum_k M^k N M'^k`` by Smith doubling (``X <- X + A X A'``, ``A <- A^2``).

    Parameters
    ----------
    M : (d, d) array
        A Schur-stable map.
    N : (d, d) array
        Symmetric positive semi-definite.
    doublings : int, default 60
        At most this many doublings.

    Returns
    -------
    (d, d) array

    Raises
    ------
    DesignError
        If ``M^(2^k)`` does not fall below round-off within ``doublings`` (``M`` not Schur-stable).

    Examples
    --------
    >>> steady_covariance(np.array([[0.5]]), np.array([[3.0]]))
    array([[4.]])
    """
    X, A = np.array(N, dtype=float), np.array(M, dtype=float)
    with np.errstate(over="ignore", invalid="ignore"):
        for _ in range(doublings):
            if not np.abs(A).max() < 1e60:  # M^(2^k) growing (or overflowed): unstable
                break
            step = A @ X @ A.T
            if not np.isfinite(step).all():
                break
            X = X + step
            X = 0.5 * (X + X.T)
            if np.abs(step).max() <= 1e-17 * np.abs(X).max():
                return X
            A = A @ A
    raise DesignError("the fusion design's error map is not stable: no steady covariance")


def _blend(old: tuple, new: tuple, beta: float) -> tuple:
    """``(1 - beta) old + beta new`` of two gain sets ``(Ls, weights)``: every ``sum_j W_ij(k) = I`` is kept."""
    Ls = tuple((1.0 - beta) * a + beta * b for a, b in zip(old[0], new[0]))
    weights = tuple(tuple((1.0 - beta) * a + beta * b for a, b in zip(ko, kn)) for ko, kn in zip(old[1], new[1]))
    return Ls, weights


def _evaluate(Fa, Cs, Rs, nbs, QQ, gains) -> np.ndarray:
    """The steady covariance of frozen gains in the design's model; DesignError when they do not stabilise it."""
    M, P = error_map(Fa, Cs, gains[0], gains[1], nbs)
    noise = P @ sla.block_diag(*[L @ R @ L.T for L, R in zip(gains[0], Rs)]) @ P.T + QQ
    return steady_covariance(M, noise)


def _design_at(F, Cs, Q, Rs, nbs, q, alpha, X0, fixed=FIXED):
    """Gains at one shift ``alpha``: ``fixed`` plain event times, then policy iteration; ``(Ls, weights, X,
    iterations)`` with ``X`` the steady covariance of the returned gains in the design's model (``F / alpha``).

    Where the greedy gains of a steady covariance do not stabilise the design's model, the step is damped: the
    gains ``(1 - beta) last + beta greedy`` for ``beta`` in ``DAMP`` (convex: each ``sum_j W_ij = I`` kept), the last
    stabilising ones at ``beta = 0``; where none stabilises either, ``FIXED`` more plain event times."""
    m, n = len(Cs), F.shape[0]
    Fa = F / alpha
    QQ = np.kron(np.ones((m, m)), Q) / alpha ** 2
    X = X0
    for _ in range(fixed):
        Ls, weights, Xn = fusion_gains(X, Fa, Cs, Rs, nbs, q)
        X = Xn + QQ
    best, stalled, last = None, 0, None
    for it in range(1, OUTER + 1):
        Ls, weights, _ = fusion_gains(X, Fa, Cs, Rs, nbs, q)
        found = None
        for beta in (1.0,) + (DAMP if last is not None else ()):
            gains = (Ls, weights) if beta == 1.0 else _blend(last, (Ls, weights), beta)
            try:
                found = gains, _evaluate(Fa, Cs, Rs, nbs, QQ, gains)
                break
            except DesignError:
                continue
        if found is None:  # not yet stabilising: more plain event times
            for _ in range(FIXED):
                Ls, weights, Xn = fusion_gains(X, Fa, Cs, Rs, nbs, q)
                X = Xn + QQ
            continue
        last, X = found
        tr = np.trace(X)
        # near the fixed point the gains move in directions the covariance hardly feels (neighbours' estimates
        # nearly equal): the trace wanders at 1e-5 of itself; the best frozen gains seen are kept
        if best is None or tr < best[0] * (1 - TOL):
            stalled = 0
        else:
            stalled += 1
        if best is None or tr < best[0]:
            best = (tr, last[0], last[1], it, X)
        if stalled >= STALL:
            break
    if best is None:
        raise DesignError(f"the fusion design at q = {q} found no stabilising gains in {OUTER} policy iterations")
    return best[1], best[2], best[4], best[3]


def _radius(M: np.ndarray, rate: float | None) -> float:
    """``rho(M)``: every eigenvalue up to ``DENSE_RADIUS`` unknowns; above, ARPACK's largest moduli (cheap products
    with a formed matrix), computed again densely when it fails or lands within ``DECIDE`` (relative) of the rate."""
    if M.shape[0] > DENSE_RADIUS:
        try:
            vals = spla.eigs(M, k=6, which="LM", ncv=min(M.shape[0] - 1, 40), tol=1e-10, return_eigenvectors=False)
            rho = float(np.max(np.abs(vals)))
            if rate is None or abs(rho - rate) > DECIDE * rate:
                return rho
        except (spla.ArpackNoConvergence, spla.ArpackError):
            pass
    return float(np.max(np.abs(np.linalg.eigvals(M))))


def _frozen(F, Cs, Q, Rs, nbs, q, alpha, X0, kf_rms, rate=None, fixed=FIXED) -> tuple:
    """The design at ``alpha`` evaluated on the model itself: ``(FusionDesign, X)``, ``X`` the design iteration's
    covariance (a warm start for the next shift)."""
    Ls, weights, Xa, its = _design_at(F, Cs, Q, Rs, nbs, q, alpha, X0, fixed)
    M, P = error_map(F, Cs, Ls, weights, nbs)
    m = len(Cs)
    noise = P @ sla.block_diag(*[L @ R @ L.T for L, R in zip(Ls, Rs)]) @ P.T + np.kron(np.ones((m, m)), Q)
    radius = _radius(M, rate)
    if radius >= 1.0:
        raise DesignError(f"the fusion design at q = {q} is not stable (spectral radius {radius:.6g})")
    # unshifted, the iteration's covariance is already this one (the same M and noise); shifted, solved again
    X = Xa if alpha == 1.0 else steady_covariance(M, noise)
    residual = float(np.abs(X - M @ X @ M.T - noise).max() / np.abs(X).max())
    return FusionDesign(q=int(q), neighbours=tuple(nbs), Ls=tuple(Ls), weights=weights, F=F, alpha=float(alpha),
                        radius=radius, covariance=X, residual=residual, iterations=its, kf_rms=kf_rms,
                        Cs=tuple(Cs)), Xa


def design_fusion(F: np.ndarray, Cs, Q: np.ndarray, Rs, nbs, q: int, *, rate: float | None = None) -> FusionDesign:
    """The fusion design at ``q`` exchanges per event time (module docstring), certified at ``rate`` if given.

    Parameters
    ----------
    F : (n, n) array
        The per-step model.
    Cs, Rs : sequences of arrays
        Output matrices and measurement noise covariances per agent (in agent order).
    Q : (n, n) array
        The process noise covariance per step.
    nbs : tuple of tuple of int
        ``N_i`` per agent (:func:`neighbour_positions`).
    q : int
        Exchanges per event time, at least 1.
    rate : float or None, optional
        ``lam`` per event time: the design must have ``rho(M) < lam``.  None: only stability.

    Returns
    -------
    FusionDesign
        The gains; ``radius < rate`` (strict).

    Raises
    ------
    DesignError
        If no shift ``alpha`` gives a radius below the rate, or the stacked sensors are not detectable.

    Examples
    --------
    Two agents on a random walk, each seeing one coordinate, one exchange: the fused estimate is the Kalman
    predictor's (every sensor one hop away arrives in time).

    >>> I = np.eye(2)
    >>> d = design_fusion(I, [I[[0]], I[[1]]], I, [np.eye(1)] * 2, ((0, 1), (1, 0)), 1)
    >>> round(d.ratio, 6), d.numbers_per_event
    (1.0, 2)
    """
    # One BLAS thread: most products are small (a neighbourhood's covariance, one agent's rows), where OpenBLAS's
    # threads cost more than they give, and on a busy machine they collapse (Rego's ring at q = 1, load 4:
    # 21.6 s with two threads, 8.1 s with one); one thread also fixes the summation order (the same gains every run).
    from threadpoolctl import threadpool_limits

    with threadpool_limits(1):
        return _design_fusion(F, Cs, Q, Rs, nbs, q, rate=rate)


def _design_fusion(F, Cs, Q, Rs, nbs, q, *, rate):
    """:func:`design_fusion` under its BLAS thread limit."""
    if q < 1:
        raise DesignError(f"the fusion design needs at least one exchange per event time, got q = {q}")
    F = np.asarray(F, dtype=float)
    m, n = len(Cs), F.shape[0]
    Q = regularise(np.asarray(Q, dtype=float))
    Rs = [regularise(np.asarray(R, dtype=float)) for R in Rs]
    kf = kalman_predictor(F, np.vstack(Cs), Q, sla.block_diag(*Rs))
    kf_rms = float(np.sqrt(max(np.trace(kf.P), 0.0) / n))
    X0 = np.kron(np.eye(m), 10.0 * kf.P + np.eye(n) * np.trace(kf.P) / n)
    try:
        best, warm = _frozen(F, Cs, Q, Rs, nbs, q, 1.0, X0, kf_rms, rate)
    except (np.linalg.LinAlgError, ValueError) as exc:
        raise DesignError(f"the fusion design at q = {q} failed: {exc}") from None
    log.info("fusion q = %d: unshifted, radius %.6g, predicted %.4gx the KF", q, best.radius, best.ratio)
    if rate is None or certifies(best.radius, rate):
        return best

    def attempt(alpha, X):
        """The design at ``alpha`` warm-started from ``X``: ``(design, its covariance)``, or ``(None, None)``."""
        try:
            with np.errstate(all="ignore"):  # a shift too far blows the covariances up: that is a failure, below
                d, Xa = _frozen(F, Cs, Q, Rs, nbs, q, alpha, X, kf_rms, rate, fixed=WARM_FIXED)
        except (DesignError, np.linalg.LinAlgError, ValueError):  # ValueError: covariances overflowed
            return None, None
        log.info("fusion q = %d: alpha %.6g, radius %.6g %s rate %.6g, predicted %.4gx the KF", q, alpha, d.radius,
                 "<" if certifies(d.radius, rate) else "not <", rate, d.ratio)
        return d, Xa

    # The largest alpha that certifies (the gains closest to the noise's).  The radius of a design for F / alpha is
    # about alpha times the unshifted one's: aim just below the rate by that line, then regula falsi between the
    # certified and the failing shift (bisection where a failed design has no radius), done within SETTLE below the
    # rate.  Continuation: each design starts from the last stable one's covariance, whose gains stabilise F / alpha
    # only for alpha above their radius, so a step never goes below that (on the IEEE 39-bus model, started at
    # alpha = rate / radius directly, 25 policy iterations found no stabilising gains).
    warm_X, warm_radius = warm, best.radius
    ok, fail, fail_radius = None, 1.0, best.radius
    lowest, slow = best.radius, 0  # the smallest uncertified radius so far; steps in a row that hardly moved it
    for _ in range(ALPHA_STEPS + 8):
        if ok is None:
            a = 0.999 * rate * fail / fail_radius if fail_radius else 0.5 * (rate + fail)
        elif ok.radius >= rate * (1.0 - SETTLE):
            break
        elif fail_radius is not None and fail_radius > ok.radius:
            a = ok.alpha + (rate * (1.0 - 0.5 * SETTLE) - ok.radius) * (fail - ok.alpha) / (fail_radius - ok.radius)
            a = min(max(a, ok.alpha + 0.05 * (fail - ok.alpha)), fail - 0.05 * (fail - ok.alpha))
        else:
            a = 0.5 * (ok.alpha + fail)
        a = max(a, warm_radius / CONTINUE)
        if a >= fail:
            break
        d, X = attempt(a, warm_X)
        if d is None:
            fail, fail_radius = a, None
            continue
        warm_X, warm_radius = X, d.radius
        if certifies(d.radius, rate):  # the one rule (spectral.certifies)
            ok = d
        else:
            fail, fail_radius = a, d.radius
            if ok is None:
                slow = slow + 1 if lowest - d.radius < STALLED * (lowest - rate) else 0
                lowest = min(lowest, d.radius)
                if slow >= 2:  # the continuation's fixed point (the IEEE 39-bus model: 5 %, then 1.6 % of the gap)
                    break
    if ok is None:
        raise DesignError(f"the fusion design at q = {q} is not certified at rate {rate:.6g} per event time "
                          f"(spectral radius {best.radius:.6g} unshifted, {lowest:.6g} at the most shifted)")
    return ok


def scenario_fusion(sc: Scenario, q: int, *, graph: int = 0, rate: float | None = None) -> FusionDesign:
    """:func:`design_fusion` of a scenario on one of its graphs (its per-step model and noise).

    Parameters
    ----------
    sc : Scenario
    q : int
        Exchanges per event time.
    graph : int, default 0
        The graph's index, in the scenario's order.
    rate : float or None, optional
        ``lam`` per event time.

    Returns
    -------
    FusionDesign
    """
    from .exchange_limit import network_model

    F, Q, _, Cs, Rs, arcs = network_model(sc, graph)
    return design_fusion(F, Cs, Q, Rs, neighbour_positions(sc.m, arcs), q, rate=rate)
