"""Local gains ``K_i = Q_i^-1 Kbar_i`` (paper, proof of prop. error; sign: ``A + K_i C_i``).

Each agent designs ``Kbar_i`` for its observable pair ``(Cbar_i, Abar_i)`` so
that ``Abar_i + Kbar_i Cbar_i`` decays faster than the rate ``lam``:

* continuous: every pole has real part ``< -lam``;
* discrete: every pole has modulus ``< lam``.

Only the slow modes move
------------------------
A mode of the observable part that already decays faster than the gain's own target (real part below
``-(1 + margin) lam``, or modulus below ``lam / (1 + margin)``) is kept where it is: the gain acts on the
quotient by the invariant subspace of those modes only.  In the dual (state feedback) form: with ``U_1``
an orthonormal basis of the ``Abar_i'``-invariant subspace of the fast eigenvalues and ``U_2`` its
complement, ``F = F_2 U_2'`` leaves ``U_1`` invariant with its eigenvalues, and places those of
``T_22 - U_2' Ct' F_2`` (``T_22 = U_2' Abar_i' U_2``): a problem of the size of the slow part.  On a stiff
model (power systems: exciter and filter modes at -20 to -80, electromechanical modes near -0.5) this is
the difference between moving 13 poles and moving 32, and between a gain of 1e5 and 1e9; moving a fast
mode to a slower target only costs gain.  Nothing changes for a model whose modes are all slow (the
paper's oscillators): every mode moves, as before.

Methods and their documented margin (``design.margin``, default 0.5)
---------------------------------------------------------------------
``place``
    Distinct real poles for the r modes that move.  Continuous: ``-(1 + margin) lam (1 + k/4)``,
    ``k = 0..r-1``.  Discrete: ``alpha (r - k) / r`` with
    ``alpha = lam / (1 + margin)``.  Placed on the dual pair
    ``(T_22, U_2' Ct')``: Ackermann's formula for one effective output (the
    gain is unique; checked, else the fallback), ``scipy.signal.place_poles``
    (method YT) otherwise.
``riccati``
    Steady-state Kalman gain of the slow part, shifted so the rate is
    guaranteed: continuous CARE for ``(T_22 + alpha I, U_2' Ct')`` with
    ``alpha = (1 + margin) lam`` (all poles left of ``-alpha``); discrete DARE
    for ``(T_22 / alpha, U_2' Ct' / alpha)`` with ``alpha = lam / (1 + margin)``
    (all poles inside radius ``alpha``).  Weights: process ``W`` and
    measurement ``R`` (identity multiples; from the scenario's noise levels
    when they are set, else 1).
``kalman``
    The ``riccati`` method's shifted Riccati equation with the agent's own noise as weights: the process noise
    covariance on its slow observable part and its measurement noise covariance ``R_i`` in the outputs' row-space
    coordinates (:func:`kalman_gain`).
``explicit``
    The user's ``K_i`` (``Kbar_i = Q_i K_i``), checked against the rate.
"""

from __future__ import annotations

import numpy as np

from ..errors import AssumptionError, DesignError
from ..scenarios import gain_methods
from .gain_registry import LOCAL_METHODS, GainRequest, LocalGain, local_method, meets_rate, poles_text, regularise
from .gain_target import beyond_target
from .modal import invariant_subspace
from .observability import Decomposition
from .subspaces import complement

__all__ = ["LocalGain", "GainRequest", "LOCAL_METHODS", "local_method", "target_poles", "place_gain", "riccati_gain",
           "shifted_riccati", "kalman_gain", "explicit_gain", "meets_rate", "design_gain", "poles_text"]


def target_poles(r: int, time: str, rate: float, margin: float) -> np.ndarray:
    """The ``place`` method's poles (see the module docstring): distinct, real, beyond the rate by the margin.

    Parameters
    ----------
    r : int
        How many poles (the slow modes that move).
    time : str
        ``continuous`` or ``discrete``.
    rate : float
        ``lam``.
    margin : float
        ``design.margin``.

    Returns
    -------
    (r,) array
        Continuous: ``-(1 + margin) lam (1 + k/4)``; discrete: ``alpha (r - k) / r`` with
        ``alpha = lam / (1 + margin)``; ``k = 0 .. r-1``.

    Examples
    --------
    >>> target_poles(3, "discrete", 0.5, 0.5).round(4).tolist()
    [0.3333, 0.2222, 0.1111]
    >>> target_poles(2, "continuous", 1.0, 0.5).tolist()
    [-1.5, -1.875]
    """
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


def _slow_part(dec: Decomposition, time: str, rate: float, margin: float) -> np.ndarray:
    """``U_2``: orthonormal basis of the complement of the ``Abar_i'``-invariant subspace of the modes that already
    decay faster than the gain's target (module docstring, "Only the slow modes move")."""
    return complement(invariant_subspace(dec.Abar.T, beyond_target(time, rate, margin)))


def _slow_gain(dec: Decomposition, time: str, rate: float, margin: float, method: str, solve) -> LocalGain:
    """What ``place`` and ``riccati`` share: the gain on the slow part (module docstring, "Only the slow modes move").

    ``solve(T22, B2)`` is the method's own step: ``F2`` for the dual slow part ``(T22, B2)``
    (``T22 = U2' Abar' U2``, ``B2 = U2' Ct'``); then ``F = F2 U2'`` leaves the fast modes where they are.
    """
    r = dec.n_observable
    s = dec.Cbar.shape[0]
    if r == 0:
        return _lift(dec, np.zeros((0, s)), method)
    T, Ct = _output_basis(dec.Cbar)
    U2 = _slow_part(dec, time, rate, margin)
    if U2.shape[1] == 0:  # every observable mode already beats the target: no gain at all
        return _lift(dec, np.zeros((r, s)), method)
    F2 = solve(U2.T @ dec.Abar.T @ U2, U2.T @ Ct.T)
    Kt = -(F2 @ U2.T).T  # (r, rank): eig(Abar + Kt Ct) = fast modes + the method's poles
    # Kbar Cbar = Kt Ct with Cbar = T Ct  =>  Kbar = Kt pinv(T)
    Kbar = Kt @ np.linalg.pinv(T)
    return _lift(dec, Kbar, method)


@local_method("place")
def place_gain(dec: Decomposition, request: GainRequest) -> LocalGain:
    """Pole placement on the slow modes of the observable part (poles from :func:`target_poles`).

    One effective output: Ackermann's formula (the gain is unique); several: ``scipy.signal.place_poles``
    (method YT), imported only then because importing ``scipy.signal`` costs over a second of
    start-up in every agent process.

    Parameters
    ----------
    dec : Decomposition
        The agent's observability decomposition.
    request : GainRequest
        ``time``, ``rate``, ``margin``.

    Returns
    -------
    LocalGain
        ``Abar_i + Kbar_i Cbar_i`` with the slow modes at :func:`target_poles`, the fast ones where they were.
    """
    time, rate, margin = request.time, request.rate, request.margin

    def solve(T22: np.ndarray, B2: np.ndarray) -> np.ndarray:
        poles = target_poles(T22.shape[0], time, rate, margin)
        # the outputs' combinations that reach the slow part: fewer than the outputs when some output sees only fast
        # modes (B2 = Br Vr', Br of full column rank); the placement runs on Br, and F2 = Vr F_r
        Ub, sb, Vbt = np.linalg.svd(B2, full_matrices=False)
        r_b = int(np.sum(sb > 1e-12 * (sb[0] if sb.size else 0.0)))
        Br, Vr = Ub[:, :r_b] * sb[:r_b], Vbt[:r_b].T
        # dual problem on the slow part: eig(T22 - Br F_r) = poles
        Fr = _ackermann(T22, Br, poles) if r_b == 1 else None
        if Fr is None:
            import warnings

            from scipy.signal import place_poles

            try:
                # YT's "Convergence was not reached" is a UserWarning on stderr, not an error: the poles it reaches
                # are checked against the rate below (a failure is one line naming the agent), so it is not shown
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore", UserWarning)
                    Fr = place_poles(T22, Br, poles, method="YT").gain_matrix
            except ValueError as exc:
                raise DesignError(f"pole placement failed: {exc}") from None
        return Vr @ Fr

    return _slow_gain(dec, time, rate, margin, request.method, solve)


def shifted_riccati(T22: np.ndarray, B2: np.ndarray, W: np.ndarray, R: np.ndarray, *, time: str, rate: float,
                    margin: float) -> np.ndarray:
    """``F2`` of the dual slow part ``(T22, B2)``: the steady-state Kalman gain of process weight ``W`` and
    measurement weight ``R``, shifted so every pole of ``T22 - B2 F2`` beats the rate by ``margin``.

    Parameters
    ----------
    T22, B2 : arrays
        The dual slow part (:func:`_slow_gain`).
    W, R : arrays
        Symmetric positive semi-definite (``W``) and definite (``R``) weights.
    time, rate, margin : str, float, float
        The rate and its margin (module docstring).

    Returns
    -------
    (rank, k) array
        ``F2``; continuous: every pole's real part ``< -(1 + margin) lam``; discrete: every modulus
        ``< lam / (1 + margin)``.

    Raises
    ------
    DesignError
        The shifted Riccati equation has no stabilising solution (one line with the shift and the solver's reason).
    """
    import scipy.linalg as sla  # here only: an agent with pole placement imports no scipy

    k = T22.shape[0]
    try:
        if time == "continuous":
            alpha = (1.0 + margin) * rate
            # CARE of the dual slow part: X makes (T22 + alpha I) - B2 R^-1 B2' X stable
            X = sla.solve_continuous_are(T22 + alpha * np.eye(k), B2, W, R)
            return np.linalg.solve(R, B2.T @ X)
        alpha = rate / (1.0 + margin)
        a, b = T22 / alpha, B2 / alpha
        # DARE of the dual slow part: a - b G2 is Schur stable, G2 = (R + b'X b)^-1 b'X a
        X = sla.solve_discrete_are(a, b, W, R)
        return np.linalg.solve(R + b.T @ X @ b, b.T @ X @ a)
    except (np.linalg.LinAlgError, ValueError) as exc:
        shift = (f"left of -{(1.0 + margin) * rate:.4g}" if time == "continuous" else
                 f"inside radius {rate / (1.0 + margin):.4g}")
        why = str(exc).strip().rstrip(".") or type(exc).__name__
        raise DesignError(f"the Riccati design of its slow modes has no stabilising solution with every pole "
                          f"{shift} (rate {rate:g} with design.margin {margin:g}): a mode it counts as seen is "
                          f"too weakly observable to move that far (solver: {why})") from None


@local_method("riccati")
def riccati_gain(dec: Decomposition, request: GainRequest) -> LocalGain:
    """Shifted steady-state Kalman gain on the slow modes of the observable part, with identity-multiple weights
    (module docstring).

    Parameters
    ----------
    dec : Decomposition
        The agent's observability decomposition.
    request : GainRequest
        ``time``, ``rate``, ``margin``, ``process_weight``, ``measurement_weight``.

    Returns
    -------
    LocalGain
        Every assigned pole beyond the rate by the margin (:func:`shifted_riccati`).
    """

    def solve(T22: np.ndarray, B2: np.ndarray) -> np.ndarray:
        W = request.process_weight * np.eye(T22.shape[0])
        R = request.measurement_weight * np.eye(B2.shape[1])
        return shifted_riccati(T22, B2, W, R, time=request.time, rate=request.rate, margin=request.margin)

    return _slow_gain(dec, request.time, request.rate, request.margin, request.method, solve)


@local_method("kalman")
def kalman_gain(dec: Decomposition, request: GainRequest) -> LocalGain:
    """Shifted steady-state Kalman gain of the agent's own noise on the slow modes of its observable part.

    The weights are the noise the agent's error meets, in the coordinates of :func:`_slow_gain`: the process noise on
    the slow observable part, ``W = U_2' Q_i Q_v Q_i' U_2``, and the measurement noise of the outputs' row-space
    coordinates, ``R = T^+ R_i T^+'`` (``Cbar_i = T Ct``, so ``Ct xbar = T^+ (y_i - w_i)``); each made definite when
    singular (:func:`~splitspec_core.model.gain_registry.regularise`).  The shift is the ``riccati`` method's
    (:func:`shifted_riccati`), so the rate is met with the same margin; on isotropic noise and orthonormal output
    rows it is the ``riccati`` gain with the noise levels as weights.  Continuous time weighs the process noise's
    intensity against ``R_i``.

    Parameters
    ----------
    dec : Decomposition
        The agent's observability decomposition (working coordinates).
    request : GainRequest
        ``time``, ``rate``, ``margin``, ``process_covariance`` (working coordinates) and
        ``measurement_covariance`` (``R_i``).

    Returns
    -------
    LocalGain
        Every assigned pole beyond the rate by the margin.
    """
    if request.process_covariance is None or request.measurement_covariance is None:
        raise DesignError("kalman gains need the scenario's noise covariances")
    T, _ = _output_basis(dec.Cbar)
    Tp = np.linalg.pinv(T)
    # y_i = T (Ct xbar) + w_i: the noise of Ct xbar read from y_i is T^+ w_i
    R = regularise(Tp @ request.measurement_covariance @ Tp.T)
    # v on the observable part xbar = Q_i x: Q_i Q_v Q_i'
    Qbar = dec.Q @ request.process_covariance @ dec.Q.T

    def solve(T22: np.ndarray, B2: np.ndarray) -> np.ndarray:
        U2 = _slow_part(dec, request.time, request.rate, request.margin)  # the slow part _slow_gain solves on
        W = regularise(U2.T @ Qbar @ U2)
        return shifted_riccati(T22, B2, W, R, time=request.time, rate=request.rate, margin=request.margin)

    return _slow_gain(dec, request.time, request.rate, request.margin, request.method, solve)


@local_method("explicit")
def explicit_gain(dec: Decomposition, request: GainRequest) -> LocalGain:
    """The user's ``K_i``; ``Kbar_i = Q_i K_i`` (the part along ``V_i`` does not affect the split).

    Parameters
    ----------
    dec : Decomposition
        The agent's observability decomposition.
    request : GainRequest
        ``K`` (n x s_i, the working coordinates).

    Returns
    -------
    LocalGain
        ``K_i`` as given, with the poles it assigns to the observable part.

    Raises
    ------
    DesignError
        The request carries no ``K``.
    """
    if request.K is None:
        raise DesignError("explicit gains need K")
    K = np.asarray(request.K, dtype=float)
    g = _lift(dec, dec.Q @ K, request.method)
    return LocalGain(K=K, Kbar=g.Kbar, poles=g.poles, method=request.method)


def design_gain(dec: Decomposition, request: GainRequest) -> LocalGain:
    """Design one agent's gain with the method ``request.method`` names (:data:`LOCAL_METHODS`) and check that it
    meets the rate.

    Parameters
    ----------
    dec : Decomposition
        The agent's observability decomposition.
    request : GainRequest
        The method, the rate and what the method takes.

    Returns
    -------
    LocalGain
        The gain; every pole of ``Abar_i + Kbar_i Cbar_i`` meets the rate (:func:`meets_rate`).

    Raises
    ------
    DesignError
        The method is not a registered local method, or its numerical step failed (said of ``request.label``).
    AssumptionError
        If the resulting observable-part poles do not meet the rate.

    Examples
    --------
    Agent 1 of the paper's discrete example sees the first oscillator; ``place`` puts its poles at
    :func:`target_poles` (rate 0.5, margin 0.5):

    >>> from splitspec_core.model.observability import decompose
    >>> A = np.array([[0, 1, 0, 0], [-1, 0, 0, 0], [0, 0, 0, 1], [0, 0, -2, 0]], dtype=float)
    >>> dec = decompose(A, np.array([[1.0, 0, 0, 0]]))
    >>> gain = design_gain(dec, GainRequest(method="place", time="discrete", rate=0.5))
    >>> (gain.K.round(4) + 0.0).ravel().tolist()
    [0.5, 0.9444, 0.0, 0.0]
    >>> sorted(gain.poles.real.round(4).tolist())
    [0.1667, 0.3333]
    """
    method, time, rate, margin, label = request.method, request.time, request.rate, request.margin, request.label
    fn = LOCAL_METHODS.get(method)
    if fn is None:
        raise DesignError(f"{label}: unknown local gain method {method!r} (the local methods: "
                          f"{', '.join(LOCAL_METHODS)})")
    try:
        gain = fn(dec, request)
    except DesignError as exc:  # the numerical failure, said of this agent
        raise DesignError(f"{label}: {exc}") from None
    if not meets_rate(gain.poles, time, rate):
        need = f"real parts < {-rate:g}" if time == "continuous" else f"moduli < {rate:g}"
        hint = ""
        if gain_methods.METHODS[method].margin and dec.n_observable:
            # many slow modes moved by few outputs: the placement's conditioning grows fast with that ratio
            slow = int(np.sum(~beyond_target(time, rate, margin)(np.linalg.eigvals(dec.Abar))))
            edge = (f"slower than the target -{(1 + margin) * rate:.3g}" if time == "continuous" else
                    f"outside the target radius {rate / (1 + margin):.3g}")
            other = "design.gains: " + gain_methods.listed(tuple(m for m in gain_methods.names_where(margin=True)
                                                                 if m != method))
            hint = (f"; it moves {slow} slow modes ({edge}) with {dec.Cbar.shape[0]} outputs: "
                    f"a smaller design.margin (fewer modes to move), {other} or a slower design.rate "
                    "may reach it")
        raise AssumptionError(
            f"{label}: gain ({method}) puts the observable-part poles at {poles_text(gain.poles, time)}, "
            f"which do not meet rate {rate:g} (need {need}){hint}")
    return gain
