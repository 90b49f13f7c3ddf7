"""Estimators that exchange little, run on given measurements: the fusion and relay kinds and Rego's steady-state DKF.

* :func:`run_fusion` walks the fusion kind (:mod:`splitspec_core.synthesis.fusion`) agent by agent through the pure
  steps of :mod:`splitspec_core.model.steps` (:func:`~splitspec_core.model.steps.local_update`,
  :func:`~splitspec_core.model.steps.matrix_fusion`, :func:`~splitspec_core.model.steps.prediction_update`), the same
  functions an agent process calls;
* :func:`run_relay` walks the relay kind (:mod:`splitspec_core.synthesis.relay`) the same way, every sample arriving
  as the graph's hops say (:func:`~splitspec_core.model.steps.relay_samples`,
  :func:`~splitspec_core.model.steps.relay_walk`);
* :class:`SteadyStateDKF` ports the baseline of the field at one exchange per step: F. C. Rego et al.'s steady-state
  distributed Kalman filter (the public MATLAB code ``Steady-State-Distributed-Kalman-Filter-MATLAB``, ``DTKF.m``).
  Each agent fuses its neighbours' *predictions* and its own measurement in information form and predicts:

  ``x_i(k+1) = F (Om_i + S_i)^-1 (sum_{j in N_i} Pa_ij x_j(k) + C_i' R_i^-1 y_i(k))``,
  ``Pa_i = J' Sigma_i^+`` (``Sigma_i`` the joint covariance of the neighbours' prediction errors), ``Om_i = Pa_i J``,
  ``S_i = C_i' R_i^-1 C_i``;

  its joint covariance iterated to the steady state (``T X T' + blkdiag(F G_i S_i G_i' F') + 1 1' (x) Q``, ``G_i`` the
  inverse above), then frozen.  It exchanges *before* measuring: a neighbour's sample of ``k`` reaches agent i one
  event time later than in the two-rate protocol's order (measure, exchange, predict);
* :func:`simulate_measurements` draws one realisation of ``x(k+1) = F x + w``, ``y = C x + v`` for all of them.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg as sla

from ..errors import DesignError
from ..model import steps as st
from ..model.plant import output_rows
from ..synthesis.fusion import FusionDesign, steady_covariance
from ..synthesis.kalman import regularise
from ..synthesis.relay import RelayDesign, gain_table

__all__ = ["run_fusion", "run_relay", "SteadyStateDKF", "simulate_measurements"]


def run_fusion(des: FusionDesign, Cs, ys: np.ndarray, X0: np.ndarray) -> np.ndarray:
    """The fusion kind on the measurements ``ys``: every agent's predictions, step by step.

    Parameters
    ----------
    des : FusionDesign
        The gains.
    Cs : sequence of (s_i, n) arrays
        The agents' output matrices (agent order).
    ys : (T - 1, p) array
        Stacked measurements ``y(0) .. y(T - 2)`` (NaN rows of an agent: no measurement).
    X0 : (m, n) array
        The initial estimates ``x_i(0)``.

    Returns
    -------
    (T, m, n) array
        ``x_i(tau)``.
    """
    rows = output_rows(Cs)
    m = des.m
    out = np.empty((len(ys) + 1, m, des.n))
    out[0] = X0
    for tau, y in enumerate(ys):
        z = []
        for i in range(m):
            y_i = y[rows[i]]
            z.append(st.local_update(out[tau, i], des.Ls[i], Cs[i], None if np.isnan(y_i).any() else y_i))
        for Wk in des.weights:  # q sub-rounds: each agent fuses what its neighbours held after the last one
            z = [st.matrix_fusion([z[j] for j in nb], Wk[i]) for i, nb in enumerate(des.neighbours)]
        out[tau + 1] = [st.prediction_update(z_i, des.F) for z_i in z]
    return out


def run_relay(des: RelayDesign, Cs, ys: np.ndarray, X0: np.ndarray) -> np.ndarray:
    """The relay kind on the measurements ``ys``: every agent's predictions, step by step, each sample of sensor j
    held by agent i ``delta_ij`` event times late (no message lost).

    Parameters
    ----------
    des : RelayDesign
        The gains.
    Cs : sequence of (s_i, n) arrays
        The agents' output matrices (agent order).
    ys : (T - 1, p) array
        Stacked measurements ``y(0) .. y(T - 2)``.
    X0 : (m, n) array
        The initial estimates ``x_i(0)`` (each agent's first base).

    Returns
    -------
    (T, m, n) array
        ``x_i(tau)``.
    """
    sensor_rows = [np.arange(r.start, r.stop) for r in output_rows(Cs)]
    C = np.vstack(Cs)
    m = len(Cs)
    tables = [gain_table(des, i) for i in range(m)]
    # the rows agent i holds at each lag, sensors in order (what steps.relay_samples gives for every sample in time)
    held = [[np.concatenate([sensor_rows[j] for j in range(m) if des.delays[i, j] <= lag])
             for lag in range(des.D + 1)] for i in range(m)]
    base, t_base = np.array(X0, dtype=float), [0] * m
    out = np.empty((len(ys) + 1,) + base.shape)
    out[0] = X0
    for tau in range(len(ys)):
        for i in range(m):
            samples = {t: (held[i][tau - t], ys[t, held[i][tau - t]]) for t in range(t_base[i], tau + 1)}
            base[i], t_base[i], out[tau + 1, i] = st.relay_walk(base[i], t_base[i], tau, tables[i], des.F, C, samples)
    return out



@dataclass(frozen=True)
class SteadyStateDKF:
    """Rego et al.'s steady-state distributed Kalman filter (module docstring), its gains frozen.

    Attributes
    ----------
    T : (m n, m n) array
        The error map: ``e(k+1) = T e(k) + ...``; its rows of agent i are ``F G_i Pa_i`` on ``N_i``.
    gains : tuple of (n, n) arrays
        ``F G_i``.
    fusion : tuple of (n, |N_i| n) arrays
        ``Pa_i``.
    info : tuple of (n, s_i) arrays
        ``C_i' R_i^-1``.
    neighbours : tuple of tuple of int
    covariance : (m n, m n) array
        The steady joint covariance of the frozen filter (a Lyapunov solution).
    radius : float
        ``rho(T)``.
    kf_rms : float
        The centralized Kalman predictor's RMS per state, for ratios.
    """

    T: np.ndarray
    gains: tuple
    fusion: tuple
    info: tuple
    neighbours: tuple
    covariance: np.ndarray
    radius: float
    kf_rms: float

    @property
    def rms(self) -> float:
        """The network's predicted steady RMS per state."""
        return float(np.sqrt(max(np.trace(self.covariance), 0.0) / self.covariance.shape[0]))

    @property
    def ratio(self) -> float:
        """``rms / kf_rms``."""
        return self.rms / self.kf_rms

    @classmethod
    def design(cls, F: np.ndarray, Cs, Q: np.ndarray, Rs, nbs, *, kf_rms: float = float("nan"),
               tol: float = 1e-8, max_iter: int = 5000) -> "SteadyStateDKF":
        """Iterate the joint covariance to the steady state (``DTKF.m``) and freeze the gains.

        Parameters
        ----------
        F : (n, n) array
        Cs, Rs : sequences of arrays
        Q : (n, n) array
        nbs : tuple of tuple of int
            ``N_i`` per agent, itself first.
        kf_rms : float, optional
            The Kalman predictor's RMS per state (ratios).
        tol : float, default 1e-8
            Change of the covariance (Frobenius norm, relative to it) that ends the iteration (``DTKF.m``: 1e-8,
            absolute).
        max_iter : int, default 5000

        Returns
        -------
        SteadyStateDKF

        Raises
        ------
        DesignError
            If the iteration does not settle or the frozen filter is unstable.
        """
        F = np.asarray(F, dtype=float)
        m, n = len(Cs), F.shape[0]
        Q = regularise(Q)
        Rinv = [np.linalg.inv(regularise(R)) for R in Rs]
        S = [C.T @ Ri @ C for C, Ri in zip(Cs, Rinv)]
        X = 1e6 * np.eye(m * n)  # DTKF.m starts from (1 / x0obs)^-2 I, x0obs = 1000
        QQ = np.kron(np.ones((m, m)), Q)
        for _ in range(max_iter):
            T, D, parts = cls._step(F, X, S, nbs, n)
            Xn = T @ X @ T.T + D + QQ
            Xn = 0.5 * (Xn + Xn.T)
            done = np.linalg.norm(Xn - X) <= tol * np.linalg.norm(Xn)  # DTKF.m's norm(P_s - P_old), made relative
            X = Xn
            if done:
                break
        else:
            raise DesignError(f"Rego's steady-state DKF did not settle in {max_iter} iterations")
        T, D, parts = cls._step(F, X, S, nbs, n)
        radius = float(np.max(np.abs(np.linalg.eigvals(T))))
        if radius >= 1.0:
            raise DesignError(f"Rego's steady-state DKF is unstable here (spectral radius {radius:.6g})")
        X = steady_covariance(T, D + QQ)
        gains, fusion = zip(*parts)
        return cls(T=T, gains=tuple(gains), fusion=tuple(fusion), info=tuple(C.T @ Ri for C, Ri in zip(Cs, Rinv)),
                   neighbours=tuple(nbs), covariance=X, radius=radius, kf_rms=kf_rms)

    @staticmethod
    def _step(F, X, S, nbs, n):
        m = len(nbs)
        T = np.zeros((m * n, m * n))
        D = np.zeros((m * n, m * n))
        parts = []
        for i, nb in enumerate(nbs):
            rows = np.concatenate([np.arange(j * n, (j + 1) * n) for j in nb])
            J = np.tile(np.eye(n), (len(nb), 1))
            Pa = J.T @ np.linalg.pinv(X[np.ix_(rows, rows)])  # DTKF.m: ones' pinv(eta P eta')
            AP = F @ np.linalg.inv(Pa @ J + S[i])
            D[i * n:(i + 1) * n, i * n:(i + 1) * n] = AP @ S[i] @ AP.T
            T[i * n:(i + 1) * n, rows] = AP @ Pa
            parts.append((AP, Pa))
        return T, D, parts

    def run(self, Cs, ys: np.ndarray, X0: np.ndarray) -> np.ndarray:
        """The filter on the measurements ``ys`` (as :func:`run_fusion`).

        Parameters
        ----------
        Cs : sequence of (s_i, n) arrays
        ys : (T - 1, p) array
        X0 : (m, n) array

        Returns
        -------
        (T, m, n) array
        """
        rows = output_rows(Cs)
        out = np.empty((len(ys) + 1,) + np.shape(X0))
        out[0] = X0
        for k, y in enumerate(ys):
            for i, nb in enumerate(self.neighbours):
                acc = self.fusion[i] @ np.concatenate([out[k, j] for j in nb]) + self.info[i] @ y[rows[i]]
                out[k + 1, i] = self.gains[i] @ acc
        return out


def simulate_measurements(F: np.ndarray, Cs, Q: np.ndarray, Rs, steps: int, rng: np.random.Generator,
                          x0: np.ndarray | None = None) -> tuple:
    """One realisation: ``x(k+1) = F x(k) + w(k)``, ``y(k) = C x(k) + v(k)``, Gaussian noise.

    Parameters
    ----------
    F : (n, n) array
    Cs, Rs : sequences of arrays
    Q : (n, n) array
    steps : int
        ``T``: states ``x(0) .. x(T - 1)``.
    rng : numpy.random.Generator
    x0 : (n,) array, optional
        Default zeros.

    Returns
    -------
    tuple
        ``(x, y)``: (T, n) states and (T - 1, p) stacked measurements.
    """
    n = F.shape[0]
    C = np.vstack(Cs)
    Lq = np.linalg.cholesky(regularise(Q))
    Lr = np.linalg.cholesky(sla.block_diag(*[regularise(R) for R in Rs]))
    x = np.zeros((steps, n))
    x[0] = 0.0 if x0 is None else x0
    w = rng.standard_normal((steps, n)) @ Lq.T
    v = rng.standard_normal((steps - 1, C.shape[0])) @ Lr.T
    for k in range(steps - 1):
        x[k + 1] = F @ x[k] + w[k]
    return x, x[:-1] @ C.T + v
