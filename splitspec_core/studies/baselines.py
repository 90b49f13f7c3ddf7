"""Baselines for the split-spectrum estimator: the centralized Kalman predictor and the KCF.

Both are one-step *predictors*, like the project's estimator: at event time k
an estimate of ``x(k)`` made before ``y(k)`` is available, ``y(k)`` arrives and
the estimate of ``x(k+1)`` is produced.  The model is the one the plant
(:class:`splitspec_core.simulation.simulator.Plant`) actually follows, per step:

``x(k+1) = F x(k) + v(k)``, ``E[v v'] = Q``;  ``y(k) = C x(k) + w(k)``, ``E[w w'] = R``

with ``F = A`` (discrete) or ``exp(A dt)`` (continuous, sampled), ``Q`` the
exact per-step process covariance and ``R`` the outputs' noise covariance, diagonal (``sigma_m^2 I`` for one
std, else each output's variance; :func:`sampled_model`).

* :func:`kalman_predictor` / :func:`run_predictor` - the steady-state
  centralized predictor seeing every measurement, the bound no distributed
  estimator can beat at steady state;
* :class:`KalmanConsensusFilter` - R. Olfati-Saber, "Kalman-Consensus Filter:
  Optimality, stability, and performance", IEEE CDC 2009, Algorithm 1, with a
  multi-exchange extension so it can use as many exchanges per event time as
  the split-spectrum estimator;
* :func:`baseline_trajectories` - both on the same noise realisations,
  initial state and initial estimates as :func:`splitspec_core.simulation.simulator.simulate`;
* :func:`baseline_seeds` - both over many seeds as one batched computation
  (:class:`SeedBatchKCF`): the KCF's gains do not depend on the measurements, so
  every seed shares them.

Noise-free measurements (``R = 0``) or a zero process noise make the Riccati
equations degenerate; both are regularised with a tiny multiple of the
identity (:data:`REGULARISATION`, see :func:`regularise`).

Why one module: the centralized predictor and the KCF share the sampled model, the noise
realisations and the trajectory loop that makes them comparable line by line.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping, Sequence

import numpy as np
import scipy.linalg as sla

from ..synthesis.kalman import REGULARISATION, KalmanPredictor, kalman_predictor, regularise  # noqa: F401
from ..simulation.montecarlo import CHUNK, MonteCarloRuns
from ..model.network import NetworkState, consensus_rows, make_plan, sensor_schedule
from ..scenarios.specs import Scenario
from ..model.plant import (Plant, advanced, initial_estimate, input_sequence, measured,  # noqa: F401
                          output_rows, sampled_model, seed_draws)  # sampled_model: also from here
from ..simulation.simulator import check_trajectory_memory

__all__ = [
    "REGULARISATION",
    "regularise",
    "sampled_model",
    "KalmanPredictor",
    "kalman_predictor",
    "run_predictor",
    "default_eps",
    "KalmanConsensusFilter",
    "SeedBatchKCF",
    "baseline_trajectories",
    "baseline_seeds",
]

# --------------------------------------------------------------------------
# centralized steady-state Kalman predictor (synthesis.kalman) and its run
# --------------------------------------------------------------------------


def run_predictor(F: np.ndarray, C: np.ndarray, L: np.ndarray, ys: np.ndarray, x0: np.ndarray,
                  gus: np.ndarray | None = None) -> np.ndarray:
    """Run ``xhat(k+1) = F xhat(k) + L (y(k) - C xhat(k)) [+ G u(k)]`` from ``xhat(0) = x0`` (``gus``: the known
    inputs' ``G u(k)`` per step, :func:`~splitspec_core.model.plant.input_sequence`).

    Parameters
    ----------
    F : (n, n) array
        The per-step transition matrix.
    C : (p, n) array
        The stacked output matrix.
    L : (n, p) array
        The predictor gain (:func:`kalman_predictor`).
    ys : (T - 1, p) array
        Stacked measurements ``y(0), ..., y(T - 2)``.
    x0 : (n,) array
        The initial prediction ``xhat(0)``.
    gus : (T - 1, n) array, optional
        ``G u(k)`` per step; None: no known inputs.

    Returns
    -------
    (T, n) array
        The predictions ``xhat(0), ..., xhat(T - 1)``.

    Examples
    --------
    >>> run_predictor(np.array([[0.9]]), np.eye(1), np.array([[0.5]]), np.ones((2, 1)), np.zeros(1)).ravel().tolist()
    [0.0, 0.5, 0.7]
    """
    F, C, L = (np.asarray(a, dtype=float) for a in (F, C, L))
    ys = np.asarray(ys, dtype=float).reshape(len(ys), -1)
    out = np.zeros((ys.shape[0] + 1, F.shape[0]))
    out[0] = x0
    A = F - L @ C
    for k, y in enumerate(ys):
        out[k + 1] = A @ out[k] + L @ y
        if gus is not None:
            out[k + 1] += gus[k]
    return out


# --------------------------------------------------------------------------
# Kalman-consensus filter
# --------------------------------------------------------------------------


def _neighbour_lists(neighbours, m: int) -> list:
    if isinstance(neighbours, Mapping):
        lists = [list(neighbours.get(i, ())) for i in range(m)]
    else:
        lists = [list(nb) for nb in neighbours]
    if len(lists) != m:
        raise ValueError(f"neighbours: expected {m} agents, got {len(lists)}")
    for i, nb in enumerate(lists):
        if i in nb or any(not 0 <= j < m for j in nb) or len(set(nb)) != len(nb):
            raise ValueError(f"neighbours[{i}]: expected distinct agent indices in 0..{m - 1} other than {i}")
    return [[int(j) for j in nb] for nb in lists]


def default_eps(neighbours) -> float:
    """``1 / (1 + max in-degree)``, the default consensus gain of :class:`KalmanConsensusFilter`.

    With ``gamma_i = eps / (1 + |M_i|_F)`` the consensus step size satisfies
    ``gamma_i |M_i|_2 < eps``, so ``gamma_i |M_i|_2 d_i < d_i / (1 + d_max) < 1``:
    in the scalar (or commuting) case the consensus update
    ``x_i + gamma_i M_i sum_j (x_j - x_i)`` is then a convex combination of the
    neighbours' estimates with weight at least ``1 / (1 + d_max)`` on itself,
    the usual step size bound of a Laplacian iteration.  It never amplifies
    disagreement, so repeated exchanges stay stable.

    Parameters
    ----------
    neighbours : dict or list
        Agent index -> in-neighbour indices (or a list of them, by agent index).

    Returns
    -------
    float
        ``eps`` in ``(0, 1]``; 1 without any neighbour.

    Examples
    --------
    >>> default_eps({0: [1], 1: [0, 2], 2: [1]})
    0.3333333333333333
    """
    lists = neighbours.values() if isinstance(neighbours, Mapping) else neighbours
    return 1.0 / (1.0 + max((len(nb) for nb in lists), default=0))


class KalmanConsensusFilter:
    """Olfati-Saber's discrete-time Kalman-consensus filter (CDC 2009, Algorithm 1), one-step predictor form.

    Each agent i keeps a prior ``xbar_i`` (its prediction of ``x(k)``) and
    ``P_i``.  Per event time, with ``J_i = {i} U N_i`` (``N_i`` the in-neighbours):

    * ``u_i = sum_{j in J_i} C_j' R_j^-1 y_j``, ``U_i = sum_{j in J_i} C_j' R_j^-1 C_j``
      (the first exchange carries ``u_j, U_j, xbar_j``);
    * ``M_i = (P_i^-1 + U_i)^-1``;
    * ``xhat_i = xbar_i + M_i (u_i - U_i xbar_i) + gamma_i M_i sum_{j in N_i} (xbar_j - xbar_i)``,
      ``gamma_i = eps / (1 + |M_i|_F)``;
    * multi-step extension (``exchanges = q > 1``): each further exchange carries
      ``xhat_j`` and applies, simultaneously for all i,
      ``xhat_i <- xhat_i + gamma_i M_i sum_{j in N_i} (xhat_j - xhat_i)``;
      ``exchanges = 1`` is exactly Algorithm 1;
    * ``P_i <- F M_i F' + Q``, ``xbar_i <- F xhat_i``.

    Numerically the fusion is evaluated in the algebraically identical
    innovation form (matrix inversion lemma): with ``C_J``, ``R_J`` stacked
    over ``J_i``, ``K = P_i C_J' (C_J P_i C_J' + R_J)^-1``,
    ``M_i (u_i - U_i xbar_i) = K (y_J - C_J xbar_i)`` and
    ``M_i = (I - K C_J) P_i (I - K C_J)' + K R_J K'`` (Joseph form), which stays
    well conditioned for the tiny regularised ``R_j`` of noise-free
    measurements, where ``u_i - U_i xbar_i`` would cancel large numbers.

    Parameters
    ----------
    F : (n, n) array
    Cs : list of (s_i, n) arrays
    Q : (n, n) array
        Process covariance per step (regularised if singular, :func:`regularise`).
    Rs : list of (s_i, s_i) arrays
        Measurement covariances (regularised if singular, e.g. ``R_i = 0``).
    neighbours : dict or list
        Agent index -> in-neighbour indices (agent itself excluded).
    eps : float, optional
        Consensus gain; default :func:`default_eps` = ``1 / (1 + max in-degree)``.
    exchanges : int
        Exchanges per event time (``>= 1``).
    P0 : (n, n) array, optional
        Initial ``P_i`` of every agent; default the identity.

    Attributes
    ----------
    P : (m, n, n) array
        Current ``P_i`` (changed by :meth:`step`, reset to ``P0`` by :meth:`reset`).
    """

    def __init__(self, F: np.ndarray, Cs: Sequence[np.ndarray], Q: np.ndarray, Rs: Sequence[np.ndarray],
                 neighbours, *, eps: float | None = None, exchanges: int = 1, P0: np.ndarray | None = None):
        self.F = np.asarray(F, dtype=float)
        n = self.F.shape[0]
        self.Cs = [np.atleast_2d(np.asarray(C, dtype=float)) for C in Cs]
        self.m = len(self.Cs)
        if len(Rs) != self.m:
            raise ValueError(f"Rs: expected {self.m} matrices, got {len(Rs)}")
        self.Rs = [regularise(np.atleast_2d(np.asarray(R, dtype=float))) for R in Rs]
        self.Q = regularise(Q)
        self.neighbours = _neighbour_lists(neighbours, self.m)
        self.eps = default_eps(self.neighbours) if eps is None else float(eps)
        if int(exchanges) < 1:
            raise ValueError(f"exchanges: expected an integer >= 1, got {exchanges}")
        self.exchanges = int(exchanges)
        self.P0 = np.eye(n) if P0 is None else np.array(P0, dtype=float)
        # stacked output matrix and noise covariance over each inclusive neighbourhood J_i
        self._J = [[i] + nb for i, nb in enumerate(self.neighbours)]
        self._CJ = [np.vstack([self.Cs[j] for j in J]) for J in self._J]
        self._RJ = [sla.block_diag(*[self.Rs[j] for j in J]) for J in self._J]
        self.reset()

    def reset(self) -> None:
        """Every ``P_i`` back to ``P0``."""
        self.P = np.stack([self.P0.copy() for _ in range(self.m)])

    def step(self, xbar: np.ndarray, ys: Sequence[np.ndarray]) -> np.ndarray:
        """One event time: priors ``xbar`` (m, n) and measurements ``[y_1, ..., y_m]`` -> next priors (m, n).

        Updates :attr:`P`.

        Parameters
        ----------
        xbar : (m, n) array
            Every agent's prior ``xbar_i(k)``.
        ys : sequence of (s_i,) arrays
            Every agent's measurement ``y_i(k)``, by agent index.

        Returns
        -------
        (m, n) array
            The priors ``xbar_i(k + 1) = F xhat_i(k)``.
        """
        xbar = np.asarray(xbar, dtype=float)
        n = self.F.shape[0]
        I = np.eye(n)
        Ms, gammas = [], []
        xhat = np.zeros_like(xbar)
        for i, J in enumerate(self._J):
            P, CJ, RJ = self.P[i], self._CJ[i], self._RJ[i]
            yJ = np.concatenate([np.asarray(ys[j], dtype=float).ravel() for j in J])
            S = CJ @ P @ CJ.T + RJ
            K = np.linalg.solve(S, CJ @ P).T  # P C_J' S^-1
            IKC = I - K @ CJ
            M = IKC @ P @ IKC.T + K @ RJ @ K.T  # = (P^-1 + U_i)^-1
            M = 0.5 * (M + M.T)
            gamma = self.eps / (1.0 + np.linalg.norm(M, "fro"))
            disagreement = sum((xbar[j] - xbar[i] for j in self.neighbours[i]), np.zeros(n))
            xhat[i] = xbar[i] + K @ (yJ - CJ @ xbar[i]) + gamma * (M @ disagreement)
            Ms.append(M)
            gammas.append(gamma)
        for _ in range(self.exchanges - 1):  # multi-step extension: consensus on the estimates
            prev = xhat.copy()
            for i, nb in enumerate(self.neighbours):
                disagreement = sum((prev[j] - prev[i] for j in nb), np.zeros(n))
                xhat[i] = prev[i] + gammas[i] * (Ms[i] @ disagreement)
        for i, M in enumerate(Ms):
            Pn = self.F @ M @ self.F.T + self.Q
            self.P[i] = 0.5 * (Pn + Pn.T)
        return xhat @ self.F.T

    def run(self, ys: np.ndarray, X0: np.ndarray, rows: Sequence[slice], gus: np.ndarray | None = None) -> np.ndarray:
        """Priors of every agent over a run, starting from :meth:`reset`.

        Parameters
        ----------
        ys : (T - 1, p) array
            Stacked measurements ``y(0), ..., y(T - 2)``.
        X0 : (m, n) array
            Initial priors ``xbar_i(0)``.
        rows : sequence of slice
            Each agent's rows in a stacked ``y`` (:func:`splitspec_core.model.plant.output_rows`).
        gus : (T - 1, n) array, optional
            ``G u(k)`` per step, added to every agent's prediction; None: no known inputs.

        Returns
        -------
        (T, m, n) array
            ``xbar_i(k)``, the predictions of ``x(k)`` comparable with the
            project's ``x_i(k)``.

        Examples
        --------
        >>> kcf = KalmanConsensusFilter(np.array([[0.9]]), [np.eye(1), np.eye(1)], np.eye(1),
        ...                             [np.eye(1), np.eye(1)], {0: [1], 1: [0]})
        >>> X = kcf.run(np.ones((3, 2)), np.zeros((2, 1)), [slice(0, 1), slice(1, 2)])
        >>> X.shape, np.round(X[:, 0, 0], 3).tolist()
        ((4, 2, 1), [0.0, 0.6, 0.798, 0.849])
        """
        ys = np.asarray(ys, dtype=float).reshape(len(ys), -1)
        X = np.array(X0, dtype=float)
        self.reset()
        out = np.zeros((ys.shape[0] + 1,) + X.shape)
        out[0] = X
        for k, y in enumerate(ys):
            X = self.step(X, [y[r] for r in rows])
            if gus is not None:  # every agent's prediction adds the known input, as the plant does
                X = X + gus[k]
            out[k + 1] = X
        return out


#: the KCF's covariances have converged when one step changes them by at most this much of their size
CONVERGED = 1e-15


class SeedBatchKCF:
    """:class:`KalmanConsensusFilter` on many seeds at once: priors ``X`` (m, n, N), seeds on the trailing axis.

    ``P_i``, ``K_i``, ``M_i`` and ``gamma_i`` follow from ``P0`` alone (the Riccati-like recursion
    ``P_i <- F M_i F' + Q`` never sees a measurement), so every seed has the same ones.  They are computed once
    per event time for all agents together: every neighbourhood ``J_i`` padded to the largest, with zero rows
    of ``C_J`` and an identity block of ``R_J`` (``S`` is then ``diag(S_i, I)``, so ``K`` has zero columns
    there and ``M`` is unchanged).  The estimates of every seed are then batched products: the innovation
    ``K_i (y_J - C_J xbar_i)`` over a padded gather of ``y``, the consensus term ``gamma_i M_i sum_{j in N_i}
    (x_j - x_i)`` with one sparse adjacency product.  Per seed the numbers are :meth:`KalmanConsensusFilter.run`'s
    to round-off (other summation orders: the padded solve, ``(gamma_i M_i) d`` for ``gamma_i (M_i d)``,
    the adjacency product for the neighbour sum), not bit for bit.  Once the covariances repeat themselves to
    round-off (:data:`CONVERGED`) the gains are kept and the Riccati-like recursion stops: a long run costs the
    estimates' products only.
    """

    def __init__(self, kcf: KalmanConsensusFilter):
        import scipy.sparse as sp

        self.F, self.Q, self.exchanges, self.eps = kcf.F, kcf.Q, kcf.exchanges, kcf.eps
        m, n = kcf.m, kcf.F.shape[0]
        self.m, self.n, self.P0 = m, n, kcf.P0
        smax = max(CJ.shape[0] for CJ in kcf._CJ)
        self.CJ = np.zeros((m, smax, n))
        self.RJ = np.tile(np.eye(smax), (m, 1, 1))
        rows = output_rows(kcf.Cs)  # each agent's rows in the stacked y
        p = rows[-1].stop
        self.gather = np.full((m, smax), p)  # row p: the zero row appended to y
        for i, (J, CJ, RJ) in enumerate(zip(kcf._J, kcf._CJ, kcf._RJ)):
            s = CJ.shape[0]
            self.CJ[i, :s], self.RJ[i, :s, :s] = CJ, RJ
            self.gather[i, :s] = np.concatenate([np.arange(rows[j].start, rows[j].stop) for j in J])
        ri = [i for i, nb in enumerate(kcf.neighbours) for _ in nb]
        ci = [j for nb in kcf.neighbours for j in nb]
        self.adj = sp.csr_matrix((np.ones(len(ri)), (ri, ci)), shape=(m, m))
        self.deg = np.array([len(nb) for nb in kcf.neighbours], dtype=float)[:, None, None]
        self.reset()

    def reset(self) -> None:
        """Every ``P_i`` back to ``P0``."""
        self.P = np.tile(self.P0, (self.m, 1, 1))
        self.fixed = None  # (K, gamma M) once P has converged to round-off: every later step has the same

    def _disagreement(self, X: np.ndarray) -> np.ndarray:
        """``sum_{j in N_i} (x_j - x_i)`` of every agent and seed, (m, n, N)."""
        m, n, N = X.shape
        return (self.adj @ X.reshape(m, n * N)).reshape(m, n, N) - self.deg * X

    def step(self, X: np.ndarray, y: np.ndarray) -> np.ndarray:
        """One event time of every seed: priors (m, n, N) and stacked measurements (sum s_i, N) -> next priors.

        Updates :attr:`P` (the same for every seed).  The equations of :meth:`KalmanConsensusFilter.step`.

        Parameters
        ----------
        X : (m, n, N) array
            Every agent's prior of every seed.
        y : (sum s_i, N) array
            The stacked measurements of every seed.

        Returns
        -------
        (m, n, N) array
            The next priors.
        """
        P, CJ, RJ = self.P, self.CJ, self.RJ
        if self.fixed is None:
            CJt = CJ.transpose(0, 2, 1)
            S = CJ @ P @ CJt + RJ
            K = np.linalg.solve(S, CJ @ P).transpose(0, 2, 1)  # P C_J' S^-1, zero columns on the padding
            IKC = np.eye(self.n) - K @ CJ
            M = IKC @ P @ IKC.transpose(0, 2, 1) + K @ RJ @ K.transpose(0, 2, 1)  # Joseph form: (P^-1 + U_i)^-1
            M = 0.5 * (M + M.transpose(0, 2, 1))
            gM = (self.eps / (1.0 + np.linalg.norm(M, "fro", axis=(1, 2))))[:, None, None] * M  # gamma_i M_i
            Pn = self.F @ M @ self.F.T + self.Q
            Pn = 0.5 * (Pn + Pn.transpose(0, 2, 1))
            # P_i never sees a measurement: once it repeats itself to round-off, so do K_i and gamma_i M_i, for good
            if np.max(np.abs(Pn - P)) <= CONVERGED * np.max(np.abs(Pn)):
                self.fixed = (K, gM)
            self.P = Pn
        else:
            K, gM = self.fixed
        yJ = np.concatenate([y, np.zeros((1, y.shape[1]))])[self.gather]  # (m, smax, N), zeros on the padding
        # xhat_i = xbar_i + K (y_J - C_J xbar_i) + gamma_i M_i sum_{j in N_i} (xbar_j - xbar_i)
        Xh = X + K @ (yJ - CJ @ X) + gM @ self._disagreement(X)
        for _ in range(self.exchanges - 1):  # multi-step extension: consensus on the estimates
            Xh = Xh + gM @ self._disagreement(Xh)
        return np.matmul(self.F, Xh)


# --------------------------------------------------------------------------
# both baselines on the simulator's realisations
# --------------------------------------------------------------------------


def baseline_trajectories(sc: Scenario, seed: int, *, exchanges: int, steps: int | None = None, noise: bool = True,
                          eps: float | None = None) -> dict:
    """The centralized predictor and the KCF on the realisations of :func:`simulate` (same scenario and seed).

    Same :class:`Plant` (initial state, process and measurement streams) and
    the same order of ``measure`` / ``advance`` as the simulator, so ``x``
    equals ``simulate(...).x``.  The KCF agents start from
    ``initial_estimate(n, seed, i)``, the centralized predictor from their mean.
    The network is the scenario's first graph (no switching, no network faults), the
    in-neighbours of agent i those of :func:`consensus_rows`; the scenario's sensor faults (``corrupt``) change
    the measurements both filters are given, as they change the simulator's (:func:`sensor_schedule`).  Both filters use
    the noisy model (:func:`sampled_model`) even with ``noise=False``, so their
    gains do not change.

    Parameters
    ----------
    sc : Scenario
        The scenario (its first graph).
    seed : int
        The simulator's seed: the same realisations as ``simulate(sc, seed=seed)``.
    exchanges : int
        KCF exchanges per event time.
    steps : int, optional
        Defaults to ``run.steps``.
    noise : bool
        False zeroes the plant's process and measurement noise.
    eps : float, optional
        KCF consensus gain (default :func:`default_eps`).

    Returns
    -------
    dict
        ``t`` (T,), ``x`` (T, n) true states, ``centralized`` (T, n) and
        ``kcf`` (T, m, n) predictions.

    Examples
    --------
    >>> import splitspec_core as ss
    >>> sc = ss.scenario(A=[[0.9, 0.2], [0, 0.8]], C={1: [[1, 0]], 2: [[0, 1]]}, graphs={"a": [(1, 2), (2, 1)]},
    ...                  rate=0.5, process_noise=0.1, measurement_noise=0.1)
    >>> b = baseline_trajectories(sc, 1, exchanges=2, steps=20)
    >>> {k: v.shape for k, v in b.items()}
    {'t': (21,), 'x': (21, 2), 'centralized': (21, 2), 'kcf': (21, 2, 2)}
    >>> bool(np.allclose(b["x"], ss.simulate(sc, seed=1, steps=20).x))
    True
    """
    check_trajectory_memory(sc, steps)
    steps = sc.run.steps if steps is None else int(steps)
    m, n, T = sc.m, sc.n, steps + 1
    plant = Plant(sc, seed, noise=noise)
    xs = np.zeros((T, n))
    ys = np.zeros((steps, plant.C.shape[0]))
    sensors, net = sensor_schedule(sc, steps), NetworkState(sc, seed)
    for k in range(T):
        xs[k] = plant.x
        if k == steps:
            break
        net.apply(sensors.get(k, ()))
        ys[k] = net.measured(plant.measure(), plant.rows)  # as the sensor faults in force give it
        plant.advance()
    F, C, Lc, kcf = _filters(sc, exchanges, eps)
    X0 = np.stack([initial_estimate(n, seed, i) for i in range(m)])
    gus = input_sequence(sc, steps)  # known inputs: the filters add G u(k) as the plant does
    central = run_predictor(F, C, Lc, ys, X0.mean(axis=0), gus)
    return {"t": _times(sc, seed, steps), "x": xs, "centralized": central,
            "kcf": kcf.run(ys, X0, plant.rows, gus)}


def baseline_seeds(sc: Scenario, seeds, *, exchanges: int, steps: int | None = None, noise: bool = True,
                   eps: float | None = None, chunk: int = CHUNK, gains: dict | None = None) -> dict:
    """Both baselines over many seeds as one batched computation: the errors of :func:`baseline_trajectories`.

    Per seed the realisations are :func:`baseline_trajectories`'s bit for bit (:func:`seed_draws`) and the
    estimates its estimates to round-off (:class:`SeedBatchKCF`; the centralized predictor as one ``(n, N)``
    product per step); the scenario's sensor faults change the measurements as in :func:`baseline_trajectories`.
    Known inputs (``system.B``) are left out of plant and filters alike: every filter adds the
    plant's own ``G u(k)``, so the errors do not depend on them.  Only squared errors are kept, ``2 N T`` floats;
    seeds run in chunks of ``chunk``, each holding its noise draws for the whole run.  ``gains``: more centralized
    predictors to run on the same realisations, ``{name: L}`` (``xhat+ = (F - L C) xhat + L y``; the rate-certified
    reference of :func:`splitspec_core.synthesis.kalman.references`).

    Parameters
    ----------
    sc : Scenario
        The scenario (its first graph).
    seeds : iterable of int
        The simulator's seeds.
    exchanges : int
        KCF exchanges per event time.
    steps : int, optional
        Defaults to ``run.steps``.
    noise : bool
        False zeroes the plant's process and measurement noise.
    eps : float, optional
        KCF consensus gain (default :func:`default_eps`).
    chunk : int
        Seeds per batch.
    gains : dict, optional
        ``{name: L}``, more centralized predictor gains (n, p).

    Returns
    -------
    dict
        ``{"centralized": runs, "kcf": runs}`` and one entry per name of ``gains``, each a
        :class:`~splitspec_core.simulation.montecarlo.MonteCarloRuns` (the split-spectrum estimator's Monte Carlo
        result, so the same statistics apply): ``sq_error`` (N, T) is ``|xhat(k) - x(k)|^2`` of a centralized
        predictor (one estimate: ``alive_count`` 1) and ``sum_i |xbar_i(k) - x(k)|^2`` over the m agents of the KCF
        (``alive_count`` m).
    """
    seeds = tuple(int(s) for s in seeds)
    steps = sc.run.steps if steps is None else int(steps)
    m, n, T = sc.m, sc.n, steps + 1
    F, C, Lc, kcf = _filters(sc, exchanges, eps)
    Ac, batch = F - Lc @ C, SeedBatchKCF(kcf)
    others = {name: (F - L @ C, np.asarray(L)) for name, L in (gains or {}).items()}  # more centralized predictors
    sq_c, sq_k = np.zeros((len(seeds), T)), np.zeros((len(seeds), T))
    sq_o = {name: np.zeros((len(seeds), T)) for name in others}
    sensors = sensor_schedule(sc, steps)
    for a in range(0, len(seeds), chunk):
        part = seeds[a:a + chunk]
        plant, x, v, w = seed_draws(sc, part, steps, noise=noise)
        net = NetworkState(sc, part)  # the sensor faults: each seed's own noise stream, as simulate draws it
        batch.reset()
        X = np.stack([np.stack([initial_estimate(n, s, i) for s in part], axis=1) for i in range(m)])  # (m, n, N)
        xc = X.mean(axis=0)  # the centralized predictor starts from the agents' mean
        xo = {name: xc.copy() for name in others}
        for k in range(T):
            sq_c[a:a + len(part), k] = np.sum((xc - x) ** 2, axis=0)
            sq_k[a:a + len(part), k] = np.sum((X - x[None]) ** 2, axis=(0, 1))
            for name, xe in xo.items():
                sq_o[name][a:a + len(part), k] = np.sum((xe - x) ** 2, axis=0)
            if k == steps:
                break
            net.apply(sensors.get(k, ()))
            y = net.measured(measured(plant.C, plant.sigma_m, x, w[k]), plant.rows)
            xc = Ac @ xc + Lc @ y  # run_predictor's step: xhat+ = (F - L C) xhat + L y
            for name, (A_o, L_o) in others.items():
                xo[name] = A_o @ xo[name] + L_o @ y
            X = batch.step(X, y)
            x = advanced(plant.F, plant.L, x, v[k])
    t = _times(sc, seeds[0], steps)
    return {name: MonteCarloRuns(seeds=seeds, t=t, sq_error=sq, alive_count=np.full(sq.shape, count), batched=True)
            for name, sq, count in (("centralized", sq_c, 1), ("kcf", sq_k, m), *((k, v, 1) for k, v in sq_o.items()))}


def _times(sc: Scenario, seed: int, steps: int) -> np.ndarray:
    """The simulator's event times (index, or time in continuous time) of a run of ``steps`` steps."""
    return make_plan(sc, seed, steps, sequence=False).times()


def _filters(sc: Scenario, exchanges: int, eps: float | None) -> tuple:
    """``(F, C, L, kcf)``: the sampled model, the stacked ``C``, the centralized predictor's gain ``L`` and the KCF on
    the scenario's first graph (in-neighbours of :func:`consensus_rows`), both with the noisy model
    (:func:`sampled_model`)."""
    F, Q, R = sampled_model(sc)
    Cs = [np.asarray(Ci) for Ci in sc.system.Cs]  # as Plant holds them
    C = np.vstack(Cs)
    pos = {a: k for k, a in enumerate(sc.agent_ids)}
    rows = consensus_rows(sc, 0, sc.agent_ids)
    neighbours = {pos[i]: [pos[j] for j in nbs if j != i] for i, (nbs, _) in rows.items()}
    Rs = sc.system.measurement_covariances  # each agent's own R_i (its outputs' variances)
    kcf = KalmanConsensusFilter(F, Cs, Q, Rs, neighbours, eps=eps, exchanges=exchanges)
    return F, C, kalman_predictor(F, C, Q, R).L, kcf
