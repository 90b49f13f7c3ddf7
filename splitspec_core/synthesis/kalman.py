"""The centralized Kalman predictor and its rate-shifted variant: the references and the whole-state design's start.

The per-step model (:func:`splitspec_core.model.plant.sampled_model`):

``x(k+1) = F x(k) + v(k)``, ``E[v v'] = Q``;  ``y(k) = C x(k) + w(k)``, ``E[w w'] = R``.

* :func:`kalman_predictor`: the steady-state one-step predictor ``xhat(k+1) = F xhat(k) + L (y(k) - C xhat(k))``
  seeing every measurement, the bound no distributed estimator beats at steady state
  (:mod:`splitspec_core.studies.baselines` runs it);
* :func:`shifted_predictor`: the Riccati design of ``F`` shifted by ``alpha`` (the predictor of ``F / alpha``,
  ``C / alpha``): ``rho(F - L C) < alpha``, so its error decays at least as fast as ``alpha^k``; ``alpha = 1`` is the
  Kalman predictor.  At ``alpha`` the rate asked it is the rate-shifted reference (:data:`SHIFTED_NAME`): certified
  at the rate, but not the best estimator that is (the minimum-variance filter under a decay-rate constraint is an
  LMI this tool does not solve), so a distributed estimator can beat it; the whole-state design (:mod:`.whole_state`)
  searches ``alpha`` for the smallest error;
* :func:`steady_covariance`: the steady error covariance of any fixed predictor gain (a Lyapunov equation).

Noise-free measurements (``R = 0``) or a zero process noise make the Riccati equations degenerate; both are
regularised with a tiny multiple of the identity (:data:`REGULARISATION`, see :func:`regularise`).
"""

from __future__ import annotations

from dataclasses import dataclass

import hashlib
import math

import numpy as np
import scipy.linalg as sla

from ..errors import DesignError
from ..model.gain_registry import REGULARISATION, regularise  # noqa: F401 - the same rule as the local gains
from ..model.plant import sampled_model
from ..scenarios.specs import Scenario
from .spectral import certifies

#: The rate-shifted reference (:func:`references`), named once for every line, table, figure and doc that shows it:
#: the Kalman filter of the model shifted by the rate (the Riccati design for ``A / rate``, per step).  Certified at the
#: rate, it is not the optimum among the centralized estimators that are, so no line calls it the best (a distributed
#: design beating it is no paradox).
SHIFTED_NAME = "the centralized Kalman filter designed for A/rate"
#: what it is, said beside :data:`SHIFTED_NAME` in the report
SHIFTED_NOTE = "a rate-shifted Riccati design, not the optimum under the rate"
#: its short label in figures and tables
SHIFTED_LABEL = "centralized KF for A/rate (rate-shifted)"

__all__ = ["SHIFTED_NAME", "SHIFTED_NOTE", "SHIFTED_LABEL", "REGULARISATION", "regularise", "KalmanPredictor",
           "kalman_predictor", "shifted_predictor",
           "steady_covariance", "spectral_radius", "per_step_rate", "references"]


@dataclass(frozen=True)
class KalmanPredictor:
    """Steady-state one-step predictor ``xhat(k+1) = F xhat(k) + L (y(k) - C xhat(k))``.

    Attributes
    ----------
    L : (n, p) array
        Predictor gain ``F P C' (C P C' + R)^-1`` (the Kalman predictor; the shifted one's for
        :func:`shifted_predictor`).
    P : (n, n) array
        Steady-state prediction-error covariance ``E[(x(k) - xhat(k))(x(k) - xhat(k))']`` of the model's noise.
    radius : float
        ``rho(F - L C)``: the predictor's error decays as ``radius^k``.
    """

    L: np.ndarray
    P: np.ndarray
    radius: float = float("nan")

    @property
    def rms(self) -> float:
        """Its steady-state RMS error, ``sqrt(trace P)``."""
        return float(np.sqrt(max(np.trace(self.P), 0.0)))


def spectral_radius(M: np.ndarray) -> float:
    """``max |eig(M)|`` (0 for an empty matrix).

    Parameters
    ----------
    M : (k, k) array_like
        A square matrix.

    Returns
    -------
    float
        The spectral radius.
    """
    return float(np.max(np.abs(np.linalg.eigvals(M)), initial=0.0)) if np.size(M) else 0.0


def _detectable(F: np.ndarray, C: np.ndarray, tol: float = 1e-9, *, radius: float = 1.0) -> bool:
    """PBH test: ``[lam I - F; C]`` has full column rank for every eigenvalue ``|lam| >= radius``."""
    n = F.shape[0]
    for lam in np.linalg.eigvals(F):
        if abs(lam) < radius * (1.0 - tol):
            continue
        M = np.vstack([lam * np.eye(n) - F, C.astype(complex)])
        s = np.linalg.svd(M, compute_uv=False)
        if s[-1] <= tol * max(1.0, s[0]):
            return False
    return True


#: Kalman predictors kept by their model's content (a design's steps ask for the same one several times: the relay
#: kind, its limit, the references; 0.7 s each at n = 170), at most this many
KEPT = 8
_kept: dict = {}


def kalman_predictor(F: np.ndarray, C: np.ndarray, Q: np.ndarray, R: np.ndarray) -> KalmanPredictor:
    """Steady-state one-step predictor of ``x+ = F x + v``, ``y = C x + w`` (``cov v = Q``, ``cov w = R``).

    ``P`` is the stabilising solution of the DARE
    ``P = F P F' - F P C' (C P C' + R)^-1 C P F' + Q`` (solved by
    ``scipy.linalg.solve_discrete_are(F', C', Q, R)``) and
    ``L = F P C' (C P C' + R)^-1``.

    A singular ``R`` (noise-free measurements) or a singular ``Q`` (e.g. no
    process noise) is regularised first with :func:`regularise`: ``1e-9
    max(1, |.|_2) I`` is added, so the predictor is the limit of small noise.

    Parameters
    ----------
    F : (n, n) array
        The per-step transition matrix.
    C : (p, n) array
        The stacked output matrix (a 1-D array is one row).
    Q, R : (n, n) array, (p, p) array
        Covariances of the process noise ``v`` and the measurement noise ``w`` (singular allowed: regularised).

    Returns
    -------
    KalmanPredictor
        ``L``, ``P`` (of the regularised noise) and ``radius = rho(F - L C) < 1``.

    Raises
    ------
    DesignError
        If ``(C, F)`` is not detectable or the solver fails.

    Examples
    --------
    >>> import numpy as np
    >>> kp = kalman_predictor(np.array([[0.9]]), np.array([[1.0]]), np.array([[1.0]]), np.array([[1.0]]))
    >>> round(float(kp.L[0, 0]), 4), round(kp.rms, 4)
    (0.5377, 1.2182)
    """
    F = np.asarray(F, dtype=float)
    C = np.atleast_2d(np.asarray(C, dtype=float))
    arrays = [np.ascontiguousarray(a, dtype=float) for a in (F, C, np.atleast_2d(Q), np.atleast_2d(R))]
    key = hashlib.sha1(b"".join(repr(a.shape).encode() + a.tobytes() for a in arrays)).hexdigest()
    if key in _kept:
        return _kept[key]
    out = _kalman_predictor(F, C, Q, R)
    for a in (out.L, out.P):
        a.setflags(write=False)  # shared by every caller of the same model
    if len(_kept) >= KEPT:
        _kept.pop(next(iter(_kept)))
    _kept[key] = out
    return out


def _kalman_predictor(F: np.ndarray, C: np.ndarray, Q: np.ndarray, R: np.ndarray) -> KalmanPredictor:
    if not _detectable(F, C):
        raise DesignError("kalman_predictor: (C, F) is not detectable: an unstable mode of F is unobserved")
    Qr, Rr = regularise(Q), regularise(R)
    try:
        P = sla.solve_discrete_are(F.T, C.T, Qr, Rr)
    except (np.linalg.LinAlgError, ValueError) as exc:
        raise DesignError(f"kalman_predictor: the Riccati solver failed ({exc})".replace("\n", " ")) from None
    P = 0.5 * (P + P.T)
    S = C @ P @ C.T + Rr
    L = np.linalg.solve(S, C @ P @ F.T).T  # F P C' S^-1 (S symmetric)
    radius = spectral_radius(F - L @ C)
    if not np.all(np.isfinite(P)) or radius >= 1.0:
        raise DesignError("kalman_predictor: no stabilising Riccati solution (F - L C is not Schur)")
    return KalmanPredictor(L=L, P=P, radius=radius)


def shifted_predictor(F: np.ndarray, C: np.ndarray, Q: np.ndarray, R: np.ndarray, alpha: float, *,
                      covariance: bool = True) -> KalmanPredictor:
    """The Riccati predictor of ``F`` shifted by ``alpha`` in ``(0, 1]``: ``rho(F - L C) < alpha``.

    ``X`` solves the DARE of ``(F / alpha, C / alpha)`` with weights ``Q``, ``R`` (regularised as in
    :func:`kalman_predictor`) and ``L = F X C' (C X C' + alpha^2 R)^-1``: the Kalman predictor of the model
    ``x+ = (F / alpha) x + v``, ``y = (C / alpha) x + w``, whose closed loop ``(F - L C) / alpha`` is Schur.
    ``P`` is the steady error covariance of this gain on the true model (:func:`steady_covariance`), not ``X``.
    ``alpha = 1`` is :func:`kalman_predictor` exactly.

    Parameters
    ----------
    F : (n, n) array
        The per-step transition matrix.
    C : (p, n) array
        The stacked output matrix (a 1-D array is one row).
    Q, R : (n, n) array, (p, p) array
        Covariances of the process noise ``v`` and the measurement noise ``w`` (singular allowed: regularised).
    alpha : float
        The shift in ``(0, 1]``: the rate per step the predictor's error must beat.
    covariance : bool, default True
        False: ``P`` is left out (None; a search that needs only the gain and its radius).

    Returns
    -------
    KalmanPredictor
        ``L``, ``P`` (:func:`steady_covariance` of ``L`` under ``Q``, ``R``) and ``radius = rho(F - L C) < alpha``.

    Examples
    --------
    >>> F, one = np.array([[0.9]]), np.eye(1)
    >>> kp = shifted_predictor(F, one, one, one, 0.3)
    >>> kp.radius < 0.3, round(kp.rms, 3) >= round(kalman_predictor(F, one, one, one).rms, 3)
    (True, True)

    Raises
    ------
    DesignError
        When no stabilising solution exists (a mode of ``F`` no output sees decays slower than ``alpha``).
    """
    if alpha == 1.0:
        return kalman_predictor(F, C, Q, R)
    F = np.asarray(F, dtype=float)
    C = np.atleast_2d(np.asarray(C, dtype=float))
    Qr, Rr = regularise(Q), regularise(R)  # no detectability test first: without it the solver fails, said below
    try:
        X = sla.solve_discrete_are(F.T / alpha, C.T / alpha, Qr, Rr)
    except (np.linalg.LinAlgError, ValueError) as exc:
        raise DesignError(f"the shifted Riccati equation (alpha = {alpha:.6g}) has no solution "
                          f"({exc})".replace("\n", " ")) from None
    X = 0.5 * (X + X.T)
    L = np.linalg.solve(C @ X @ C.T + alpha ** 2 * Rr, C @ X @ F.T).T
    radius = spectral_radius(F - L @ C)
    if not np.all(np.isfinite(L)) or radius >= alpha:
        raise DesignError(f"the shifted Riccati equation (alpha = {alpha:.6g}) has no stabilising solution")
    return KalmanPredictor(L=L, P=steady_covariance(F, C, L, Q, R) if covariance else None, radius=radius)


def steady_covariance(F: np.ndarray, C: np.ndarray, L: np.ndarray, Q: np.ndarray, R: np.ndarray) -> np.ndarray:
    """Steady error covariance ``P = (F - L C) P (F - L C)' + Q + L R L'`` of the predictor with gain ``L``.

    Parameters
    ----------
    F, C : (n, n) array, (p, n) array
        The per-step model.
    L : (n, p) array
        The predictor gain (``F - L C`` Schur, else the solution means nothing).
    Q, R : (n, n) array, (p, p) array
        The noise covariances (as given: not regularised).

    Returns
    -------
    (n, n) array
        ``P``, symmetrised.
    """
    Ac = np.asarray(F) - L @ np.asarray(C)
    P = sla.solve_discrete_lyapunov(Ac, Q + L @ R @ L.T)
    return 0.5 * (P + P.T)


def per_step_rate(sc: Scenario, rate: float) -> float:
    """The rate per event time: ``lam`` (discrete) or ``exp(-lam dt)`` (continuous, one event time per ``run.dt``).

    Parameters
    ----------
    sc : Scenario
        Its ``time`` and ``run.dt``.
    rate : float
        ``lam``, per event time (discrete) or per unit time (continuous).

    Returns
    -------
    float
        The factor the error must shrink by per event time.
    """
    return rate if sc.time == "discrete" else math.exp(-rate * sc.run.dt)


def references(sc: Scenario, rate: float) -> tuple:
    """``(kf, ref)``: the two references of an estimator of ``sc`` under noise, on the per-step model the plant follows
    (:func:`~splitspec_core.model.plant.sampled_model`): the Kalman predictor (the bound no estimator beats at steady
    state) and :data:`SHIFTED_NAME`, the Riccati design shifted by the rate per step, certified at ``rate`` but not
    the best estimator that is (or the Kalman predictor itself when it is faster); either None when it does not
    exist.

    Parameters
    ----------
    sc : Scenario
        The scenario (its system, noise, agents' outputs stacked).
    rate : float
        ``lam`` (:func:`per_step_rate` turns it into the rate per step).

    Returns
    -------
    tuple of (KalmanPredictor or None, KalmanPredictor or None)
        ``(kf, ref)``; ``ref is kf`` when ``kf.radius`` is already below the rate per step.

    Examples
    --------
    >>> import splitspec_core as ss
    >>> sc = ss.scenario(A=[[0.9, 0.2], [0, 0.8]], C={1: [[1, 0]], 2: [[0, 1]]}, graphs={"a": [(1, 2), (2, 1)]},
    ...                  rate=0.5, process_noise=0.1, measurement_noise=0.1)
    >>> kf, ref = references(sc, 0.5)
    >>> round(kf.rms, 3) <= round(ref.rms, 3), ref.radius < 0.5
    (True, True)
    """
    F, Q, R = sampled_model(sc)
    C = np.vstack([np.asarray(Ci, dtype=float) for Ci in sc.system.Cs])
    lam = per_step_rate(sc, rate)
    try:
        kf = kalman_predictor(F, C, Q, R)
    except DesignError:
        kf = None
    if kf is not None and certifies(kf.radius, lam):  # the one rule (spectral.certifies)
        return kf, kf
    try:
        ref = shifted_predictor(F, C, Q, R, lam)
    except DesignError:
        ref = None
    return kf, ref
