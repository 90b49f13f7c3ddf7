"""Local gains ``K_i = Q_i^-1 Kbar_i`` (paper, proof of prop. error; sign: ``A + K_i C_i``).

Each agent designs ``Kbar_i`` for its observable pair ``(Cbar_i, Abar_i)`` so
that ``Abar_i + Kbar_i Cbar_i`` decays faster than the rate ``lam``:

* continuous: every pole has real part ``< -lam``;
* discrete: every pole has modulus ``< lam``.

Methods and their documented margin (``design.margin``, default 0.5)
---------------------------------------------------------------------
``place``
    Distinct real poles.  Continuous: ``-(1 + margin) lam (1 + k/4)``,
    ``k = 0..r-1``.  Discrete: ``alpha (r - k) / r`` with
    ``alpha = lam / (1 + margin)``.  Placed on the dual pair
    ``(Abar_i', Cbar_i')``: Ackermann's formula for one effective output (the
    gain is unique; checked, else the fallback), ``scipy.signal.place_poles``
    (method YT) otherwise.
``riccati``
    Steady-state Kalman gain of the observable part, shifted so the rate is
    guaranteed: continuous CARE for ``(Abar_i + alpha I, Cbar_i)`` with
    ``alpha = (1 + margin) lam`` (all poles left of ``-alpha``); discrete DARE
    for ``(Abar_i / alpha, Cbar_i / alpha)`` with ``alpha = lam / (1 + margin)``
    (all poles inside radius ``alpha``).  Weights: process ``W`` and
    measurement ``R`` (identity multiples; from the scenario's noise levels
    when they are set, else 1).
``explicit``
    The user's ``K_i`` (``Kbar_i = Q_i K_i``), checked against the rate.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .errors import AssumptionError, DesignError
from .observability import Decomposition

__all__ = ["LocalGain", "target_poles", "place_gain", "riccati_gain", "explicit_gain", "meets_rate", "design_gain"]


@dataclass(frozen=True)
class LocalGain:
    """A local gain with its diagnostics.

    Attributes
    ----------
    K : (n, s_i) array
        ``K_i``; ``A + K_i C_i`` leaves the unobservable space invariant.
    Kbar : (r_i, s_i) array
        ``Kbar_i = Q_i K_i``.
    poles : (r_i,) complex array
        Spectrum of ``Abar_i + Kbar_i Cbar_i`` (the part the gain assigns).
    method : str
        ``place``, ``riccati`` or ``explicit``.
    """

    K: np.ndarray
    Kbar: np.ndarray
    poles: np.ndarray
    method: str


def meets_rate(poles: np.ndarray, time: str, rate: float) -> bool:
    """Whether every pole decays strictly faster than the rate."""
    poles = np.asarray(poles)
    if poles.size == 0:
        return True
    if time == "continuous":
        return bool(np.max(poles.real) < -rate)
    return bool(np.max(np.abs(poles)) < rate)


def target_poles(r: int, time: str, rate: float, margin: float) -> np.ndarray:
    """The ``place`` method's poles (see the module docstring)."""
    k = np.arange(r)
    if time == "continuous":
        return -(1.0 + margin) * rate * (1.0 + k / 4.0)
    alpha = rate / (1.0 + margin)
    return alpha * (r - k) / r


def _output_basis(Cbar: np.ndarray):
    """Row-space basis of ``Cbar``: ``Cbar = T Ct`` with ``Ct`` orthonormal rows of full rank."""
    U, s, Wt = np.linalg.svd(Cbar, full_matrices=False)
    rank = int(np.sum(s > 1e-12 * (s[0] if s.size else 0.0)))
    return U[:, :rank] * s[:rank], Wt[:rank]


def _lift(dec: Decomposition, Kbar: np.ndarray, method: str) -> LocalGain:
    # K_i = Q_i^-1 Kbar_i with Q_i^-1 = Q_i' (orthonormal rows)
    K = dec.Q.T @ Kbar
    poles = np.linalg.eigvals(dec.Abar + Kbar @ dec.Cbar) if dec.n_observable else np.zeros(0, complex)
    return LocalGain(K=K, Kbar=Kbar, poles=poles, method=method)


def _ackermann(A: np.ndarray, b: np.ndarray, poles: np.ndarray) -> np.ndarray | None:
    """Single-input pole placement: ``f`` (1, r) with ``eig(A - b f) = poles`` (Ackermann's formula).

    The single-input gain is unique, so this is the gain any method finds; returns ``None`` when
    the controllability matrix is too ill-conditioned for the result to be trusted (the caller then
    uses ``scipy.signal.place_poles``).
    """
    r = A.shape[0]
    W = np.empty((r, r))
    col = b[:, 0]
    for k in range(r):
        W[:, k] = col
        col = A @ col
    coeffs = np.real(np.poly(poles))  # phi(s) = s^r + c1 s^(r-1) + ... + cr
    phi = np.zeros_like(A)
    for c in coeffs:  # Horner: phi(A)
        phi = phi @ A + c * np.eye(r)
    try:
        if np.linalg.cond(W) > 1e8:
            return None
        e = np.zeros(r)
        e[-1] = 1.0
        f = np.linalg.solve(W.T, e) @ phi
    except np.linalg.LinAlgError:
        return None
    got = np.sort_complex(np.linalg.eigvals(A - np.outer(b[:, 0], f)))
    if np.max(np.abs(got - np.sort_complex(poles.astype(complex)))) > 1e-9 * (1.0 + np.max(np.abs(poles))):
        return None
    return f[None, :]


def place_gain(dec: Decomposition, *, time: str, rate: float, margin: float = 0.5) -> LocalGain:
    """Pole placement on the observable part (poles from :func:`target_poles`).

    One effective output: Ackermann's formula (the gain is unique); several: ``scipy.signal.place_poles``
    (method YT), imported only then because importing ``scipy.signal`` costs over a second of
    start-up in every agent process.
    """
    r = dec.n_observable
    s = dec.Cbar.shape[0]
    if r == 0:
        return _lift(dec, np.zeros((0, s)), "place")
    T, Ct = _output_basis(dec.Cbar)
    poles = target_poles(r, time, rate, margin)
    # dual problem: eig(Abar' - Ct' F) = poles  =>  eig(Abar + (-F') Ct) = poles
    F = _ackermann(dec.Abar.T, Ct.T, poles) if Ct.shape[0] == 1 else None
    if F is None:
        from scipy.signal import place_poles

        try:
            F = place_poles(dec.Abar.T, Ct.T, poles, method="YT").gain_matrix
        except ValueError as exc:
            raise DesignError(f"pole placement failed: {exc}") from None
    Kt = -F.T  # (r, rank)
    # Kbar Cbar = Kt Ct with Cbar = T Ct  =>  Kbar = Kt pinv(T)
    Kbar = Kt @ np.linalg.pinv(T)
    return _lift(dec, Kbar, "place")


def riccati_gain(
    dec: Decomposition, *, time: str, rate: float, margin: float = 0.5,
    process_weight: float = 1.0, measurement_weight: float = 1.0,
) -> LocalGain:
    """Shifted steady-state Kalman gain on the observable part (see the module docstring)."""
    import scipy.linalg as sla  # here only: an agent with pole placement imports no scipy

    r = dec.n_observable
    s = dec.Cbar.shape[0]
    if r == 0:
        return _lift(dec, np.zeros((0, s)), "riccati")
    T, Ct = _output_basis(dec.Cbar)
    W = process_weight * np.eye(r)
    R = measurement_weight * np.eye(Ct.shape[0])
    try:
        if time == "continuous":
            alpha = (1.0 + margin) * rate
            # CARE for the dual: X makes (Abar + alpha I) - X Ct' R^-1 Ct stable
            X = sla.solve_continuous_are((dec.Abar + alpha * np.eye(r)).T, Ct.T, W, R)
            Kt = -X @ Ct.T @ np.linalg.inv(R)
        else:
            alpha = rate / (1.0 + margin)
            F, H = dec.Abar / alpha, Ct / alpha
            # DARE for the dual: F - F X H' (R + H X H')^-1 H is Schur stable
            X = sla.solve_discrete_are(F.T, H.T, W, R)
            Kt = -F @ X @ H.T @ np.linalg.inv(R + H @ X @ H.T)
    except (np.linalg.LinAlgError, ValueError) as exc:
        raise DesignError(f"Riccati equation failed: {exc}") from None
    Kbar = Kt @ np.linalg.pinv(T)
    return _lift(dec, Kbar, "riccati")


def explicit_gain(dec: Decomposition, K: np.ndarray) -> LocalGain:
    """The user's ``K_i``; ``Kbar_i = Q_i K_i`` (the part along ``V_i`` does not affect the split)."""
    Kbar = dec.Q @ K
    g = _lift(dec, Kbar, "explicit")
    return LocalGain(K=np.array(K, dtype=float), Kbar=Kbar, poles=g.poles, method="explicit")


def design_gain(
    dec: Decomposition, *, method: str, time: str, rate: float, margin: float = 0.5,
    K: np.ndarray | None = None, process_weight: float = 1.0, measurement_weight: float = 1.0,
    label: str = "agent",
) -> LocalGain:
    """Design one agent's gain and check that it meets the rate.

    Raises
    ------
    AssumptionError
        If the resulting observable-part poles do not meet the rate.
    """
    if method == "place":
        gain = place_gain(dec, time=time, rate=rate, margin=margin)
    elif method == "riccati":
        gain = riccati_gain(dec, time=time, rate=rate, margin=margin,
                            process_weight=process_weight, measurement_weight=measurement_weight)
    elif method == "explicit":
        if K is None:
            raise DesignError(f"{label}: explicit gains need K")
        gain = explicit_gain(dec, K)
    else:
        raise DesignError(f"unknown gain method {method!r}")
    if not meets_rate(gain.poles, time, rate):
        need = f"real parts < {-rate:g}" if time == "continuous" else f"moduli < {rate:g}"
        shown = ", ".join(_pole_text(p) for p in gain.poles)
        raise AssumptionError(
            f"{label}: gain ({method}) puts the observable-part poles at [{shown}], "
            f"which do not meet rate {rate:g} (need {need})")
    return gain


def _pole_text(p: complex) -> str:
    if abs(p.imag) < 1e-12:
        return f"{p.real:.4g}"
    return f"{p.real:.4g}{p.imag:+.4g}j"
