"""What a gain design method is: the request it takes, the gain it returns, and the registry of the local methods.

Every local method (:mod:`splitspec_core.model.gains`) is one function ``fn(dec, request) -> LocalGain``
registered with ``@local_method("word")`` under a word of ``design.gains`` declared in
:mod:`splitspec_core.scenarios.gain_methods`; :func:`splitspec_core.model.gains.design_gain` dispatches through
:data:`LOCAL_METHODS` and checks the result against the rate (:func:`meets_rate`).  A method that weighs the
scenario's noise makes a singular covariance definite with :func:`regularise`, the same rule as the centralized
filters (:mod:`splitspec_core.synthesis.kalman`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import DesignError
from ..scenarios import gain_methods

__all__ = ["LocalGain", "GainRequest", "LOCAL_METHODS", "local_method", "meets_rate", "poles_text", "POLES_SHOWN",
           "REGULARISATION", "regularise"]

#: relative size of the identity added to a singular covariance (see :func:`regularise`)
REGULARISATION = 1e-9


def regularise(M: np.ndarray) -> np.ndarray:
    """A symmetric PSD matrix made positive definite if it is (numerically) singular.

    If the smallest eigenvalue of ``M`` is at most ``1e-12 |M|_2`` (singular to round-off, relative to ``M`` itself),
    returns ``M + REGULARISATION max(1, |M|_2) I`` (``REGULARISATION = 1e-9``);
    otherwise ``M`` unchanged.  Used for noise-free measurements (``R = 0``) and
    zero (or rank-deficient) process noise, where the Riccati equation has no
    stabilising solution or its solver needs ``R`` invertible.  Small noise that is stated is not singular: a motor's
    angles with process noise std ``1e-6`` per step (variance ``1e-12``, beside ``2.5e-3`` on its speeds) were taken
    as singular against ``1e-12 max(1, |M|_2)`` and given ``1e-9``, 1000 times their noise, so the centralized Kalman
    filter's predicted RMS was that of another model (0.2142, the true one's 0.2125) and a distributed design was
    reported at 0.992x of it (issue 46's walk).

    Parameters
    ----------
    M : (k, k) array_like
        A symmetric PSD matrix (symmetrised first).

    Returns
    -------
    (k, k) array
        ``(M + M') / 2``, with the identity term added when it is singular.

    Examples
    --------
    >>> regularise(np.zeros((2, 2))).tolist()
    [[1e-09, 0.0], [0.0, 1e-09]]
    """
    M = 0.5 * (np.asarray(M, dtype=float) + np.asarray(M, dtype=float).T)
    if M.size == 0:
        return M
    norm = float(np.linalg.norm(M, 2))
    if np.linalg.eigvalsh(M)[0] <= 1e-12 * norm:
        return M + REGULARISATION * max(1.0, norm) * np.eye(M.shape[0])
    return M


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
        The word of ``design.gains`` that made it (:mod:`splitspec_core.scenarios.gain_methods`).
    """

    K: np.ndarray
    Kbar: np.ndarray
    poles: np.ndarray
    method: str


@dataclass(frozen=True)
class GainRequest:
    """What one agent's gain design is asked: every method's function takes ``(dec, request)``.

    Built once from the scenario (:func:`splitspec_core.model.local_design.gain_request`), alike in the designer and
    in every agent process.

    Attributes
    ----------
    method : str
        The word of ``design.gains`` (:mod:`splitspec_core.scenarios.gain_methods`).
    time : str
        ``continuous`` or ``discrete``.
    rate : float
        ``lam``: continuous, every pole's real part ``< -lam``; discrete, every modulus ``< lam``.
    margin : float
        ``design.margin``: how far beyond the rate a margin-using method aims.
    K : (n, s_i) array or None
        The user's ``K_i`` in the working coordinates (``explicit``).
    process_weight, measurement_weight : float
        The identity multiples of the Riccati weights (``design.riccati``, else the noise levels squared, else 1).
    process_covariance : (n, n) array or None
        The process noise's covariance per step (continuous: intensity) in the working coordinates.
    measurement_covariance : (s_i, s_i) array or None
        ``R_i``, the agent's measurement noise covariance.
    label : str
        How a message names the agent (``agent 3``, or ``design.K.3`` for the user's gain).
    """

    method: str
    time: str
    rate: float
    margin: float = 0.5
    K: np.ndarray | None = None
    process_weight: float = 1.0
    measurement_weight: float = 1.0
    process_covariance: np.ndarray | None = None
    measurement_covariance: np.ndarray | None = None
    label: str = "agent"


#: ``{word: function (dec, request) -> LocalGain}``: the local gain methods (``@local_method``)
LOCAL_METHODS: dict = {}


def local_method(name: str):
    """Register ``fn(dec, request) -> LocalGain`` as the local gain method ``name``, a word declared in
    :mod:`splitspec_core.scenarios.gain_methods` with ``local`` set (else the import fails, naming it).

    Parameters
    ----------
    name : str
        The word of ``design.gains``.

    Returns
    -------
    callable
        The decorator; it returns the function unchanged.
    """
    declared = gain_methods.METHODS.get(name)
    if declared is None or not declared.local:
        raise DesignError(f"gain method {name!r} is not declared as a local method in scenarios/gain_methods.py")

    def register(fn):
        LOCAL_METHODS[name] = fn
        return fn

    return register


def meets_rate(poles: np.ndarray, time: str, rate: float) -> bool:
    """Whether every pole decays strictly faster than the rate.

    Parameters
    ----------
    poles : array_like
        The poles (complex), e.g. of ``Abar_i + Kbar_i Cbar_i``.
    time : str
        ``continuous`` or ``discrete``.
    rate : float
        ``lam``.

    Returns
    -------
    bool
        Continuous: every real part ``< -lam``; discrete: every modulus ``< lam``; True for no poles.

    Examples
    --------
    >>> meets_rate([0.2, 0.3j], "discrete", 0.5), meets_rate([-1.0, -0.4], "continuous", 0.5)
    (True, False)
    """
    poles = np.asarray(poles)
    if poles.size == 0:
        return True
    if time == "continuous":
        return bool(np.max(poles.real) < -rate)
    return bool(np.max(np.abs(poles)) < rate)



#: poles a message or report line lists at most, the slowest first
POLES_SHOWN = 6


def poles_text(poles, time: str, *, limit: int = POLES_SHOWN) -> str:
    """``[-0.3, -0.45, -0.6]``; more than ``limit``: the slowest ``limit`` and how many more, down to the fastest.

    Parameters
    ----------
    poles : array_like
        The poles (complex; a real one printed without its zero imaginary part).
    time : str
        ``continuous`` (the slowest: the largest real part) or ``discrete`` (the largest modulus).
    limit : int
        How many poles are listed at most (default :data:`POLES_SHOWN`).

    Returns
    -------
    str
        The poles to 4 significant digits: all of them in the given order, or the slowest ``limit``, how many more,
        and the fastest.

    Examples
    --------
    >>> poles_text([-0.3, -0.45 + 0.1j], "continuous")
    '[-0.3, -0.45+0.1j]'
    >>> poles_text(-np.arange(1.0, 9.0), "continuous", limit=3)
    '[-1, -2, -3, ... 5 more, the fastest -8]'
    """
    poles = np.asarray(poles)
    if poles.size <= limit:
        return "[" + ", ".join(_pole_text(p) for p in poles) + "]"
    speed = -poles.real if time == "continuous" else -np.abs(poles)  # the slowest first
    order = np.argsort(speed, kind="stable")
    shown = ", ".join(_pole_text(p) for p in poles[order[:limit]])
    return f"[{shown}, ... {poles.size - limit} more, the fastest {_pole_text(poles[order[-1]])}]"


def _pole_text(p: complex) -> str:
    if abs(p.imag) < 1e-12:
        return f"{p.real:.4g}"
    return f"{p.real:.4g}{p.imag:+.4g}j"
