"""What certifies the whole-state design's rate beyond one graph held constant (:mod:`.whole_state`).

* **the mixing bound** (:func:`mixing_bound`): for doubly stochastic weights the error's average ``ebar`` and
  disagreement ``delta`` obey, in the norm of a Lyapunov function ``X`` of ``Fbar = mean F_i`` and the two-norm,
  ``[|ebar+|_X, |delta+|] <= G [|ebar|_X, |delta|]`` with ``G = [[a, b], [s c, s d]]``, ``a = |Fbar|_X``,
  ``b = |[F_1 .. F_m]|_{2->X} / m``, ``c = |[F_i - Fbar]_i|_{X->2}``, ``d = max |F_i|_2``,
  ``s = max |S^q - 11'/m|_2`` over the graphs: every sequence of them decays at ``rho(G)``.  Derivation: with
  ``u = blkdiag(F_i) e`` (the update), ``ubar = Fbar ebar + (1/m) sum_i F_i delta_i`` and
  ``u - 1 (x) ubar = [F_i - Fbar]_i ebar + (I - J) blkdiag(F_i) delta``; averaging (``S^q (x) I``, doubly
  stochastic) keeps ``ubar`` and shrinks the disagreement by ``s``.  Arbitrary switching, any size: only
  ``n x n`` and ``m x m`` matrices are formed.  It is the two-norm argument of the paper's Appendix B with the
  average in place of the split;
* **the dwell-time bound** (:func:`dwell_bound`): switching with an average dwell ``tau_D`` among graphs held
  constant each with ``|M^k| <= c r^k``: ``r c^(1 / tau_D) <= lam``;
* :func:`certify`: which of them (or the full error matrices held constant) certifies a design's q.
"""

from __future__ import annotations

import math

import numpy as np
import scipy.linalg as sla

from .conditioning import transient_constant
from .error_matrix import MAX_RATE_DIM, whole_matrix
from ..model.graphs import is_doubly_stochastic
from .kalman import spectral_radius
from .spectral import certifies
from ..scenarios.specs import Scenario

__all__ = ["mixing_bound", "dwell_bound", "same_agents", "certify"]


def mixing_bound(Fs, Ss, q: int, lam: float) -> float:
    """The decay rate the mixing bound certifies for the whole-state error under arbitrary switching among the doubly
    stochastic ``Ss`` (module docstring); ``inf`` when the average's own map ``Fbar`` does not decay faster than
    ``lam`` or a weight matrix is not doubly stochastic.

    Parameters
    ----------
    Fs : sequence of (n, n) arrays
        Every agent's error map ``F_i`` of one event time (update only).
    Ss : iterable of (m, m) arrays
        The consensus weight matrices switched among (a sequence: read twice).
    q : int
        Averaging rounds per event time.
    lam : float
        The rate per event time asked.

    Returns
    -------
    float
        ``rho(G)``, the best over a few Lyapunov functions of ``Fbar``; certified when below ``lam``.

    Examples
    --------
    >>> Fs, S = [np.array([[0.5]]), np.array([[0.3]])], np.full((2, 2), 0.5)
    >>> round(mixing_bound(Fs, [S], 1, 0.6), 3), mixing_bound(Fs, [np.array([[1.0, 0.0], [1.0, 0.0]])], 1, 0.6)
    (0.4, inf)
    """
    if not all(is_doubly_stochastic(np.asarray(S)) for S in Ss):
        return math.inf
    m, n = len(Fs), Fs[0].shape[0]
    Fbar = sum(Fs) / m
    r = spectral_radius(Fbar)
    if r >= lam:
        return math.inf
    J = np.full((m, m), 1.0 / m)
    s = max(float(np.linalg.norm(np.linalg.matrix_power(np.asarray(S, dtype=float), int(q)) - J, 2)) for S in Ss)
    d = max(float(np.linalg.norm(F, 2)) for F in Fs)
    Fcat = np.hstack(Fs)
    Dcat = np.vstack([F - Fbar for F in Fs])
    best = math.inf
    for t in (0.25, 0.5, 0.75, 0.9):  # the Lyapunov function of Fbar / rr, rr between its radius and lam
        rr = r + t * (lam - r)
        try:
            X = sla.solve_discrete_lyapunov((Fbar / rr).T, np.eye(n))  # Fbar' X Fbar <= rr^2 X
            Xh = np.linalg.cholesky(0.5 * (X + X.T)).T  # |v|_X = |Xh v|
        except (np.linalg.LinAlgError, ValueError):
            continue
        Xi = np.linalg.inv(Xh)
        a = float(np.linalg.norm(Xh @ Fbar @ Xi, 2))
        b = float(np.linalg.norm(Xh @ Fcat, 2)) / m
        c = float(np.linalg.norm(Dcat @ Xi, 2))
        G = np.array([[a, b], [s * c, s * d]])
        best = min(best, spectral_radius(G))
    return best


def dwell_bound(Ms, lam: float, dwell_steps: float) -> float:
    """The rate certified under switching with average dwell ``dwell_steps`` event times among the constant-graph
    maps ``Ms``: ``min_r r c(r)^(1 / tau_D)``, ``c(r) = max sup_k |M^k|_2 / r^k`` (:func:`transient_constant`).

    Parameters
    ----------
    Ms : sequence of square arrays
        The full error maps of one event time, one per graph held constant.
    lam : float
        The rate per event time asked (``r`` is tried between the largest spectral radius and it).
    dwell_steps : float
        The average dwell ``tau_D`` in event times.

    Returns
    -------
    float
        The certified rate; ``inf`` when some map does not decay faster than ``lam``, ``dwell_steps`` is not
        positive, or no transient constant is finite.
    """
    rho = max(spectral_radius(M) for M in Ms)
    if rho >= lam or not dwell_steps or dwell_steps <= 0:
        return math.inf
    best = math.inf
    for t in (0.25, 0.5, 0.75):
        r = rho + t * (lam - rho)
        cs = [transient_constant(M, r).constant for M in Ms]
        if any(c is None or not math.isfinite(c) for c in cs):
            continue
        best = min(best, r * max(cs) ** (1.0 / dwell_steps))
    return best


def same_agents(cases) -> dict:
    """``{agent ids: [S of each case over exactly them]}``: the graphs the mixing bound takes together.

    Parameters
    ----------
    cases : iterable of bounds.Case
        The design's cases.

    Returns
    -------
    dict
        ``{tuple of agent ids: list of (m, m) arrays}``, in the cases' order.
    """
    out: dict = {}
    for c in cases:
        out.setdefault(tuple(c.graph.ids), []).append(c.graph.S)
    return out


def certify(sc: Scenario, by_id: dict, cases, q: int, lam: float, dwell: float | None, warnings: list) -> tuple:
    """``(radii, (method, bound, certified, switching))`` at ``q``: the full error matrices held constant, and for
    switching (or beyond :data:`MAX_RATE_DIM`) the mixing bound or the dwell-time bound.

    Parameters
    ----------
    sc : Scenario
        The scenario (its ``time``, ``run.dt``, size).
    by_id : dict
        ``{agent id: F_i}`` with a method ``of(sc, case, q)`` giving a case's full-matrix radius, computed once
        (the whole-state designer's ``_Radii``).
    cases : sequence of bounds.Case
        The cases the design covers.
    q : int
        Averaging rounds per event time.
    lam : float
        The rate per event time asked.
    dwell : float or None
        The average dwell time (scenario time units), or None.
    warnings : list of str
        Appended to when only the graphs held constant are certified under switching.

    Returns
    -------
    tuple
        ``(radii, (method, bound, certified, switching))``: ``{case label: radius}`` (empty above
        ``MAX_RATE_DIM``), the method that decided (``full error matrix``, ``mixing bound`` or ``dwell-time bound``),
        its bound, whether it meets ``lam``, and whether it holds under switching.
    """
    # each case held constant (by_id.of: the design's radii, each computed once), up to MAX_RATE_DIM
    radii = {c.label: by_id.of(sc, c, q) for c in cases} if sc.m * sc.n <= MAX_RATE_DIM else {}
    groups = same_agents(cases)
    switching = any(len(Ss) > 1 for Ss in groups.values())
    if radii and not switching:
        worst = max(radii.values())
        return radii, ("full error matrix", worst, certifies(worst, lam), False)
    mix = max(mixing_bound([by_id[i] for i in ids], Ss, q, lam) for ids, Ss in groups.items())
    if certifies(mix, lam):
        return radii, ("mixing bound", mix, True, True)
    if radii:
        worst = max(radii.values())
        steps = None if dwell is None else (dwell if sc.time == "discrete" else dwell / sc.run.dt)
        if steps:
            Ms = [whole_matrix([by_id[i] for i in c.graph.ids], c.graph.S, q) for c in cases]
            dw = dwell_bound(Ms, lam, steps)
            if certifies(dw, lam):
                return radii, ("dwell-time bound", dw, True, True)
        warnings.append("the whole-state design is certified for each graph held constant; no switching certificate "
                        "holds (the mixing bound needs doubly stochastic weights, design.weights: metropolis on "
                        "undirected graphs; the dwell-time bound a longer dwell)")
        return radii, ("full error matrix", worst, certifies(worst, lam), False)
    return radii, ("mixing bound", mix, False, True)
