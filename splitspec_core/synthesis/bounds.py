"""The centralised part of the design: the gain ``g`` (continuous) and ``q`` (discrete).

Everything here acts on the unobservable-space coordinates of the paper:

* ``V = blockdiag(V_1..V_m)`` (never formed: we use the Gram matrix
  ``G = [V_i' V_j]`` and ``V'(M (x) I_n)V = expand(M) o G``),
* ``Atil = blockdiag(A_1..A_m)``, ``A_i = V_i'(A + K_i C_i)V_i`` (eq. QA2),
* ``B = V' Sbar V`` (discrete, eq. split_discrete_ench: ``A_V = Atil B^q``),
* continuous ``A_V(g) = Atil - g V'(I - Sbar)V = Atil - g (I - B)``
  (eq. split_continuous_split),
* ``H = blockdiag(pi_i I_{n_i})`` with the Perron vector ``pi`` of ``S``
  (eq. H); the discrete weight ``R = V'(Pi (x) I)V`` equals ``H``.

A :class:`Case` is one (agent set, graph) pair the design must cover: each
graph of the scenario, and with ``design.resilience: 1`` each graph
restricted to the survivors of every single agent loss.

Why one module: every certificate (eq. g, the dwell and arbitrary-switching bounds, the four q
methods) is built on the same ``Case`` and compared side by side in the design report.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

from ..errors import DesignError
from ..model.graphs import Graph, is_doubly_stochastic, perron_vector
from . import spectral
from .spectral import certifies, spectral_radius  # also bounds.spectral_radius, as before

__all__ = [
    "Case",
    "make_case",
    "g_bound",
    "abscissa",
    "g_min",
    "dwell_constants",
    "g_dwell_bound",
    "sampled_decay",
    "g_arbitrary_bound",
    "QResult",
    "q_spectral",
    "q_weighted",
    "q_two_norm",
    "q_mixed",
    "choose_q",
    "mixed_norm",
    "spectral_radius",
    "error_radius",
 "nice_ceil"]


# --------------------------------------------------------------------------
# cases
# --------------------------------------------------------------------------


@dataclass(frozen=True)
class Case:
    """One agent set and graph, in unobservable-space coordinates.

    Attributes
    ----------
    label : str
        e.g. ``a`` or ``a without agent 3``.
    graph : Graph
    sizes : tuple of int
        ``n_i = dim V_i`` per agent of ``graph.ids``.
    A_blocks : tuple of (n_i, n_i) arrays
        The blocks ``A_i`` of ``Atil``.
    V_blocks : tuple of (n, n_i) arrays
        The ``V_i``.
    Atil : (nbar, nbar) array
        ``blockdiag(A_i)``; formed on first use (a large design's spectral q never forms it:
        :mod:`splitspec_core.synthesis.spectral` applies it block by block).
    B : (nbar, nbar) array
        ``V' Sbar V``; formed on first use, like ``Atil``.
    Vcat : (n, nbar) array
        ``[V_1 .. V_m]`` (the Gram matrix ``G = Vcat' Vcat`` has the blocks ``V_i' V_j``).
    h : (nbar,) array
        Diagonal of ``H`` (``pi_i`` repeated ``n_i`` times); computed on first use.
    VLV : (nbar, nbar) array
        ``V'(L (x) I)V`` with ``L = 2 Pi - Pi S - S' Pi`` (eq. split_continuous_lyap); computed on first use.
    """

    label: str
    graph: Graph
    sizes: tuple
    A_blocks: tuple = field(repr=False, compare=False)
    V_blocks: tuple = field(repr=False, compare=False)
    # q -> rho(Atil B^q), filled by error_radius: the q search, the certified bound and the report's
    # error radius ask for the same numbers; q -> how it was computed (spectral.Radius)
    _radius: dict = field(default_factory=dict, init=False, repr=False, compare=False)
    _how: dict = field(default_factory=dict, init=False, repr=False, compare=False)

    @cached_property
    def nbar(self) -> int:
        """``nbar = sum n_i`` (int), the size of the unobservable-space coordinates."""
        return int(sum(self.sizes))

    @cached_property
    def Vcat(self) -> np.ndarray:
        """``[V_1 .. V_m]``, an (n, nbar) array (n x 0 when every agent observes everything)."""
        return np.hstack(self.V_blocks) if self.nbar else np.zeros((self.V_blocks[0].shape[0], 0))

    @cached_property
    def Atil(self) -> np.ndarray:
        """``Atil = blockdiag(A_i)``, an (nbar, nbar) array (eq. QA2), formed on first use."""
        return _block_diag(self.A_blocks, self.sizes)

    @cached_property
    def B(self) -> np.ndarray:
        """``B = V' Sbar V``, an (nbar, nbar) array (eq. split_discrete_ench), formed on first use."""
        G = self.Vcat.T @ self.Vcat  # blocks V_i' V_j
        return _expand(self.graph.S, self.sizes) * G  # V' (S (x) I) V

    # h and VLV only serve g, its dwell bound and the weighted q: computed on first use (a discrete
    # design with spectral q never needs the Perron vector of the m + 1 cases of a resilient design)
    @cached_property
    def _pi(self) -> np.ndarray:
        return perron_vector(self.graph.S)

    @cached_property
    def h(self) -> np.ndarray:
        """The diagonal of ``H``, an (nbar,) array: the Perron vector's ``pi_i`` repeated ``n_i`` times (eq. H)."""
        return np.repeat(self._pi, self.sizes)

    @cached_property
    def VLV(self) -> np.ndarray:
        """``V'(L (x) I)V`` with ``L = 2 Pi - Pi S - S' Pi``, an (nbar, nbar) symmetric array (eq. split_continuous_lyap)."""
        S, Pi = self.graph.S, np.diag(self._pi)
        L = 2 * Pi - Pi @ S - S.T @ Pi  # eq. (split_continuous_lyap)
        return _expand(L, self.sizes) * (self.Vcat.T @ self.Vcat)


def _expand(M: np.ndarray, sizes) -> np.ndarray:
    """Repeat entry ``M_ij`` into an ``n_i x n_j`` block."""
    sizes = np.asarray(sizes)
    return np.repeat(np.repeat(M, sizes, axis=0), sizes, axis=1)


def _block_diag(blocks, sizes) -> np.ndarray:
    """``blockdiag(blocks)`` (the blocks ``n_i x n_i``): the values ``scipy.linalg.block_diag`` gives, at a
    fraction of its per-block overhead (it dominated building the m + 1 cases of a resilient design)."""
    edges = np.concatenate([[0], np.cumsum(sizes, dtype=int)])
    out = np.zeros((edges[-1], edges[-1]))
    for k, blk in enumerate(blocks):
        out[edges[k]:edges[k + 1], edges[k]:edges[k + 1]] = blk
    return out


def make_case(label: str, graph: Graph, Vs, A_uns) -> Case:
    """Build a :class:`Case` from per-agent ``V_i`` and ``A_i`` (in ``graph.ids`` order); the matrices on first use.

    Parameters
    ----------
    label : str
        The case's name in messages and the report (``a``, ``a without agent 3``).
    graph : Graph
        The agents (``graph.ids``) and their stochastic matrix ``S``.
    Vs : sequence of (n, n_i) arrays
        Orthonormal bases ``V_i`` of the agents' unobservable spaces, one per agent of ``graph.ids``.
    A_uns : sequence of (n_i, n_i) arrays
        The blocks ``A_i = V_i'(A + K_i C_i)V_i`` (eq. QA2), in the same order.

    Returns
    -------
    Case
        With ``sizes = (n_i)``; ``Atil``, ``B``, ``h``, ``VLV`` are formed when first asked for.

    Examples
    --------
    >>> import numpy as np
    >>> from splitspec_core.model.graphs import build_graph
    >>> g = build_graph("a", (1, 2), [(1, 2), (2, 1)])
    >>> case = make_case("a", g, [np.array([[0.], [1.]]), np.array([[0.6], [0.8]])],
    ...                  [np.array([[1.1]]), np.array([[1.2]])])
    >>> case.nbar, np.round(case.B, 3).tolist()
    (2, [[0.5, 0.4], [0.4, 0.5]])
    >>> r = q_spectral([case], 0.5)
    >>> r.q, round(r.bound, 3), r.certified
    (8, 0.495, True)
    """
    return Case(label=label, graph=graph, sizes=tuple(V.shape[1] for V in Vs), A_blocks=tuple(A_uns),
                V_blocks=tuple(Vs))


# --------------------------------------------------------------------------
# continuous time: g
# --------------------------------------------------------------------------


def g_bound(case: Case, rate: float) -> float:
    """Sufficient g for a constant graph, eq. (g).

    ``g >= lam_max(H(lam I + Atil) + (lam I + Atil)'H) / lam_min(V'(L (x) I)V)``;
    returns 0 when the numerator is negative (any g works).

    Parameters
    ----------
    case : Case
        One agent set and graph (constant).
    rate : float
        The decay rate ``lam`` > 0 (errors within ``c exp(-lam t)``).

    Returns
    -------
    float
        The sufficient g (>= 0); 0 when every agent observes everything (``nbar = 0``).

    Raises
    ------
    DesignError
        ``V'(L (x) I)V`` is not positive definite (graph not strongly connected or system not jointly observable).
    """
    if case.nbar == 0:
        return 0.0
    M = rate * np.eye(case.nbar) + case.Atil
    HM = case.h[:, None] * M
    num = float(np.linalg.eigvalsh(HM + HM.T)[-1])
    den = float(np.linalg.eigvalsh(case.VLV)[0])
    if den <= 0:
        raise DesignError(f"{case.label}: V'(L (x) I)V is not positive definite (lambda_min = {den:.3g}); "
                          "is the graph strongly connected and the system jointly observable?")
    return max(num, 0.0) / den


def abscissa(case: Case, g: float) -> float:
    """Spectral abscissa of ``A_V(g) = Atil - g (I - B)`` (eq. split_continuous_split).

    Parameters
    ----------
    case : Case
        One agent set and graph.
    g : float
        The consensus gain.

    Returns
    -------
    float
        ``max Re eig(A_V(g))``; ``-inf`` when ``nbar = 0``.  The error decays at rate ``lam`` when it is below
        ``-lam`` (:func:`~splitspec_core.synthesis.spectral.certifies`).
    """
    if case.nbar == 0:
        return -math.inf
    AV = case.Atil - g * (np.eye(case.nbar) - case.B)
    return float(np.max(np.linalg.eigvals(AV).real))


def g_min(case: Case, rate: float, *, g_hi: float | None = None, rtol: float = 1e-6) -> float:
    """Smallest g with ``abscissa(A_V(g))`` below ``-lam`` by the one rule (:func:`.spectral.certifies`; bisection on
    the spectrum).

    The abscissa is decreasing in g for large g (Prop. split_continuous_stable);
    the bisection starts from the sufficient ``g_hi`` (eq. g by default) and
    assumes a single crossing below it.  Returns 0 if g = 0 already works.

    Parameters
    ----------
    case : Case
        One agent set and graph (constant).
    rate : float
        The decay rate ``lam``.
    g_hi : float, optional
        A g known to work, the bisection's upper end (default :func:`g_bound`; doubled until it works).
    rtol : float
        Relative width of the final bracket.

    Returns
    -------
    float
        The upper end of the final bracket: a g that meets the rate, within ``rtol`` of the smallest.

    Raises
    ------
    DesignError
        No g up to 1e12 meets the rate.
    """
    if certifies(abscissa(case, 0.0), -rate):
        return 0.0
    hi = g_bound(case, rate) if g_hi is None else g_hi
    hi = max(hi, 1e-9)
    while not certifies(abscissa(case, hi), -rate):  # eq. (g) is sufficient, so this ends
        hi *= 2.0
        if hi > 1e12:
            raise DesignError(f"{case.label}: no g up to 1e12 meets rate {rate:g}")
    lo = 0.0
    while hi - lo > rtol * hi:
        mid = 0.5 * (lo + hi)
        if certifies(abscissa(case, mid), -rate):
            hi = mid
        else:
            lo = mid
    return hi


def sampled_decay(case: Case, g: float, Et: np.ndarray, Dt: np.ndarray, dt: float) -> float:
    """Decay rate of the sampled-data estimator's unobservable part (see :mod:`splitspec_core.model.steps`).

    With ``E = exp(A dt)``, ``D = int exp(A s) ds`` (both leave each ``V_i``
    invariant), the error on ``V`` obeys ``w+ = (Et - g Dt (I - B)) w`` with
    ``Et = blockdiag(V_i' E V_i)``, ``Dt = blockdiag(V_i' D V_i)``.  Returns
    ``-ln(rho) / dt``; a negative value means the sampled-data estimator is unstable.

    Parameters
    ----------
    case : Case
        One agent set and graph.
    g : float
        The consensus gain.
    Et, Dt : (nbar, nbar) array
        ``blockdiag(V_i' E V_i)`` and ``blockdiag(V_i' D V_i)``.
    dt : float
        The sampling period.

    Returns
    -------
    float
        The decay rate per unit time, ``-ln(rho) / dt``; ``inf`` when ``nbar = 0`` or ``rho = 0``.
    """
    if case.nbar == 0:
        return math.inf
    rho = spectral_radius(Et - g * Dt @ (np.eye(case.nbar) - case.B))
    return -math.log(rho) / dt if rho > 0 else math.inf


def dwell_constants(cases) -> tuple:
    """``(c, lam_star)`` with ``||exp(-V'(I - Sbar)V t)||_2 <= c exp(-lam_star t)`` for every case.

    From the Lyapunov equation (split_continuous_lyap) with ``H``:
    ``c = max sqrt(max h / min h)``, ``lam_star = min lam_min(V'(L (x) I)V) / (2 max h)``.

    Parameters
    ----------
    cases : iterable of Case
        The graphs switched among.

    Returns
    -------
    tuple of (float, float)
        ``(c, lam_star)``; ``(1.0, inf)`` when no case has an unobservable part.
    """
    c, lam_star = 1.0, math.inf
    for case in cases:
        if case.nbar == 0:
            continue
        c = max(c, math.sqrt(case.h.max() / case.h.min()))
        lam_star = min(lam_star, float(np.linalg.eigvalsh(case.VLV)[0]) / (2 * case.h.max()))
    return c, lam_star


def g_dwell_bound(cases, rate: float, dwell: float) -> float:
    """Sufficient g for switching with average dwell time ``dwell``, eq. (split_continuous_g).

    ``g >= (ln c + (lam + ||Atil||_2 c) tau_D) / (lam_star tau_D)``.

    Parameters
    ----------
    cases : sequence of Case
        The graphs switched among (iterated twice: not a generator).
    rate : float
        The decay rate ``lam``.
    dwell : float
        The average dwell time ``tau_D`` (time units).

    Returns
    -------
    float
        The sufficient g; 0 when no case has an unobservable part.
    """
    c, lam_star = dwell_constants(cases)
    if not math.isfinite(lam_star):
        return 0.0
    norm_a = max(np.linalg.norm(case.Atil, 2) if case.nbar else 0.0 for case in cases)
    return (math.log(c) + (rate + norm_a * c) * dwell) / (lam_star * dwell)


def g_arbitrary_bound(cases, rate: float) -> float | None:
    """Sufficient g for arbitrary switching among doubly stochastic graphs (Theorem thm:arb).

    ``g >= lam_max((lam I + Atil) + (lam I + Atil)') / min lam_min(V'((2I - S - S') (x) I)V)``.
    Returns ``None`` if some ``S`` is not doubly stochastic.

    Parameters
    ----------
    cases : iterable of Case
        The graphs switched among.
    rate : float
        The decay rate ``lam``.

    Returns
    -------
    float or None
        The sufficient g (>= 0), the worst over the cases; None when the theorem does not apply.

    Raises
    ------
    DesignError
        ``2I - B - B'`` is not positive definite for some case.
    """
    worst = 0.0
    for case in cases:
        if not is_doubly_stochastic(case.graph.S):
            return None
        if case.nbar == 0:
            continue
        M = rate * np.eye(case.nbar) + case.Atil
        num = float(np.linalg.eigvalsh(M + M.T)[-1])
        # V'((2I - S - S') (x) I)V = 2 I - B - B'
        den = float(np.linalg.eigvalsh(2 * np.eye(case.nbar) - case.B - case.B.T)[0])
        if den <= 0:
            raise DesignError(f"{case.label}: 2I - B - B' is not positive definite")
        worst = max(worst, max(num, 0.0) / den)
    return worst


# --------------------------------------------------------------------------
# discrete time: q
# --------------------------------------------------------------------------


@dataclass(frozen=True)
class QResult:
    """A consensus count q with the bound it certifies.

    Attributes
    ----------
    q : int
    method : str
        ``spectral``, ``weighted``, ``two-norm`` or ``mixed``.
    bound : float
        The certified quantity at this q (below the rate by :func:`.spectral.certifies` when ``certified``):
        spectral radius of ``Atil B^q`` (spectral), ``||Atil||_R ||B||_R^q``
        (weighted, eq. rnorm), ``max |Atil B^q|_2`` (two-norm),
        ``||Atil|| ||B^p||^pbar`` (mixed, eq. rajit2/rajit3).
    certified : bool
        Whether ``bound`` certifies the rate (:func:`.spectral.certifies`: strictly below it, by its margin).
    switching : bool
        Whether the certificate holds under arbitrary switching among the
        cases (two-norm and mixed), or per constant graph only.
    p, pbar : int or None
        The factors ``q = p * pbar`` of the two-norm and mixed methods.
    """

    q: int
    method: str
    bound: float
    certified: bool
    switching: bool
    p: int | None = None
    pbar: int | None = None
    eig: dict | None = None  # spectral q: how the radii were computed (spectral.summary: method, tolerance)


_SCAN = 64  # smallest scans k = 1.._SCAN one by one, then doubles and bisects


def smallest(pred, q_max: int, *, what: str, scan: int = _SCAN) -> int:
    """Smallest k in [1, q_max] with pred(k): linear scan to ``scan`` (every k: a predicate need not be monotone
    there), then doubling and bisection.

    Parameters
    ----------
    pred : callable
        ``pred(k) -> bool``; assumed monotone (false, then true) beyond ``scan``.
    q_max : int
        The largest k tried.
    what : str
        What k is, for the error message (``q (spectral, a)``).
    scan : int
        How many k are tried one by one first.

    Returns
    -------
    int
        The smallest k found.

    Examples
    --------
    >>> smallest(lambda k: k * k >= 5000, 1000, what="k")
    71

    Raises
    ------
    DesignError
        No k up to ``q_max`` (one line naming ``what``).
    """
    for k in range(1, min(scan, q_max) + 1):
        if pred(k):
            return k
    lo, hi = scan, 2 * scan
    while True:
        if hi >= q_max:
            hi = q_max
            if not pred(hi):
                raise DesignError(f"no {what} up to design.q_max = {q_max} works; raise design.q_max")
            break
        if pred(hi):
            break
        lo, hi = hi, hi * 2
    while hi - lo > 1:
        mid = (lo + hi) // 2
        if pred(mid):
            hi = mid
        else:
            lo = mid
    return hi


def _smallest_max(preds, q_max: int, *, whats) -> int:
    """``max(smallest(pred) for pred in preds)``, the same number, warm-started from the cases already searched.

    Once q is the max over the cases searched so far, a case with ``pred(q)`` true and ``q <= 64``
    (inside the linear scan of :func:`smallest`) has its own smallest k at most q, so it cannot
    raise the max: one evaluation instead of a search.  Only a case with ``pred(q)`` false is
    searched from scratch (its evaluations memoised by the caller), exactly as before, so the
    result and any error are those of the searches from scratch, also for a predicate that is
    not monotone in k.  With ``design.resilience: 1`` the loss cases mostly need the q of the
    cases before them, and then cost one evaluation each.
    """
    q = None
    for pred, what in zip(preds, whats):
        if q is not None and q <= min(_SCAN, q_max) and pred(q):
            continue
        k = smallest(pred, q_max, what=what)
        q = k if q is None else max(q, k)
    return q


class _Powers:
    """``B^k`` by the very matmul calls of :func:`numpy.linalg.matrix_power`, in its order (so the same bits on one
    machine), the squares shared between k.

    ``matrix_power`` multiplies, from the lowest bit of k up, the squares ``B, B^2, B^4, ...``
    (with short cuts for k = 2 and 3); keeping the squares, each further k costs
    ``popcount(k) - 1`` products instead of about ``log2(k) + popcount(k) - 1``.
    """

    def __init__(self, B: np.ndarray):
        self._sq = [B]

    def _square(self, j: int) -> np.ndarray:
        while len(self._sq) <= j:
            self._sq.append(np.matmul(self._sq[-1], self._sq[-1]))
        return self._sq[j]

    def __call__(self, k: int) -> np.ndarray:
        if k < 1:
            return np.linalg.matrix_power(self._sq[0], k)
        if k == 1:
            return self._sq[0]
        if k == 2:
            return self._square(1)
        if k == 3:
            return np.matmul(self._square(1), self._sq[0])  # matrix_power's short cut: (B B) B
        result, j = None, 0
        while k:
            k, bit = divmod(k, 2)
            if bit:
                z = self._square(j)
                result = z if result is None else np.matmul(result, z)
            j += 1
        return result


def _power(B: np.ndarray, k: int) -> np.ndarray:
    return np.linalg.matrix_power(B, k)


def error_radius(case: Case, q: int, powers: _Powers | None = None, *, rate: float | None = None,
                 method: str = "auto", warm=None, vectors: dict | None = None) -> float:
    """``rho(Atil B^q)``, the error map's spectral radius over one event time (eq. split_discrete_rho).

    Memoised on the case: the q search, the certified bound and the design report's error
    radius ask for the same numbers.  ``powers`` (of ``case.B``) shares the squares between q.
    ``method``: ``dense`` (every eigenvalue of the formed matrix), ``iterative`` (matrix-free, the largest
    eigenvalues only: :func:`splitspec_core.synthesis.spectral.radius`, which falls back to ``dense`` when it does not
    converge or lands within its tolerance of ``rate``) or ``auto`` (iterative above
    :data:`splitspec_core.synthesis.spectral.DENSE_MAX` unknowns); how each value was computed is in ``case._how``.
    ``warm``: the iterative path starts from these eigenvectors of another case (``spectral._warm_start``);
    ``vectors`` receives this case's.

    Parameters
    ----------
    case : Case
        One agent set and graph.
    q : int
        Consensus exchanges per event time.
    powers : callable, optional
        ``powers(k) = B^k`` of ``case.B`` (the dense path), shared between q.
    rate : float, optional
        The decay rate ``lam``: the iterative path decides against it.
    method : {"auto", "dense", "iterative"}
        How the radius is computed.
    warm : optional
        Eigenvectors of another case at this q, the iterative path's start.
    vectors : dict, optional
        Filled with this case's eigenvectors (iterative path).

    Returns
    -------
    float
        ``rho(Atil B^q)``; 0 when ``nbar = 0``.  The error shrinks by ``rho`` per event time when it is below ``lam``.
    """
    if not case.nbar:
        return 0.0
    if q not in case._radius:
        if spectral.use_iterative(case.nbar, method):
            how = spectral.radius(case, q, rate=rate, warm=warm, vectors=vectors)
        else:
            # eq. (split_discrete_ench): A_V = Atil (V' Sbar V)^q
            rho = spectral_radius(case.Atil @ (powers(q) if powers is not None else _power(case.B, q)))
            how = spectral.Radius(rho, "dense", 0.0)
        _remember(case, q, how)
    return case._radius[q]


def _remember(case: Case, q: int, how) -> None:
    case._radius[q] = how.value
    case._how[q] = how


def _prefetch(cases, q: int, *, rate: float, method: str, warm, workers: int | None) -> None:
    """The iterative radii of ``cases`` at ``q`` not yet known, on every core at once
    (:func:`splitspec_core.synthesis.spectral.radii`), remembered as :func:`error_radius` would: the q search then finds
    them (the same values as computed one by one)."""
    todo = [c for c in cases if c.nbar and q not in c._radius and spectral.use_iterative(c.nbar, method)]
    for case, how in zip(todo, spectral.radii(todo, q, rate=rate, warm=warm, workers=workers)):
        _remember(case, q, how)


def q_spectral(cases, rate: float, *, q: int | None = None, q_max: int = 100_000, method: str = "auto",
               workers: int | None = None) -> QResult:
    """Smallest q with ``rho(Atil B^q) < lam`` for every case (constant graphs).

    The cases are searched in order, each warm-started from the q of the ones before
    (:func:`_smallest_max`): the q of a search from scratch per case.  ``method``: how the spectral radii are
    computed (:func:`error_radius`); the result says which methods were used (``QResult.eig``).  Once the first
    case's q is known, the iterative radii of the others at that q (the loss cases of a resilient design mostly
    need no more) are computed on ``workers`` processes at once (``None``: every core; :func:`_prefetch`).

    Parameters
    ----------
    cases : iterable of Case
        Every case the design covers (at least one).
    rate : float
        The decay rate ``lam`` per event time (0 < lam < 1).
    q : int, optional
        Check this q instead of searching for it.
    q_max : int
        The largest q searched (``design.q_max``).
    method : {"auto", "dense", "iterative"}
        How the spectral radii are computed.
    workers : int, optional
        Processes for the other cases' radii (None: every core).

    Returns
    -------
    QResult
        ``bound = max rho(Atil B^q)`` over the cases, ``certified`` when below ``rate``, ``switching=False``,
        ``eig`` how the radii were computed.

    Raises
    ------
    DesignError
        No q up to ``q_max`` meets the rate for some case.
    """
    cases = tuple(cases)
    warm: dict = {}  # q -> (ids, sizes, right and left eigenvectors) of the first case evaluated at q

    def radius(case, k, powers=None):
        # the first case evaluated at k keeps its eigenvectors in warm: the start of every later case at k
        return error_radius(case, k, powers, rate=rate, method=method, warm=warm.get(k),
                            vectors=warm if k not in warm else None)

    def pred(case):
        powers = None if spectral.use_iterative(case.nbar, method) else _Powers(case.B)  # lives for this case
        return lambda k: certifies(radius(case, k, powers), rate)

    def what(case):
        return f"q (spectral, {case.label})"

    if q is None and cases:
        first = smallest(pred(cases[0]), q_max, what=what(cases[0]))  # remembered: _smallest_max replays it
        _prefetch(cases[1:], first, rate=rate, method=method, warm=warm.get(first), workers=workers)
        q = _smallest_max((pred(c) for c in cases), q_max, whats=(what(c) for c in cases))
    elif q is not None:
        radius(cases[0], q)  # the warm start of the rest
        _prefetch(cases[1:], q, rate=rate, method=method, warm=warm.get(q), workers=workers)
    bound = max(radius(c, q) for c in cases)
    return QResult(q=q, method="spectral", bound=bound, certified=certifies(bound, rate), switching=False,
                   eig=spectral.summary(c._how.get(q) for c in cases if c.nbar))


def _weighted_norm(M: np.ndarray, h: np.ndarray) -> float:
    """``||M||_R`` = largest singular value of ``R^1/2 M R^-1/2``, ``R = diag(h)``."""
    if M.size == 0:
        return 0.0
    s = np.sqrt(h)
    return float(np.linalg.norm(s[:, None] * M / s[None, :], 2))


def q_weighted(cases, rate: float, *, q: int | None = None, q_max: int = 100_000) -> QResult:
    """q by the weighted two-norm, eq. (rnorm): ``||B||_R^q < lam / ||Atil||_R`` (constant graphs; strict, by the
    one rule :func:`.spectral.certifies`).

    Parameters
    ----------
    cases : iterable of Case
        Every case the design covers.
    rate : float
        The decay rate ``lam`` per event time.
    q : int, optional
        Check this q instead of computing it.
    q_max : int
        The largest q allowed.

    Returns
    -------
    QResult
        ``bound = max ||Atil||_R ||B||_R^q`` over the cases, ``certified`` when below ``rate`` (:func:`.spectral.certifies`), ``switching=False``.

    Raises
    ------
    DesignError
        ``||B||_R >= 1`` for some case (eq. ino fails), or the q needed exceeds ``q_max``.
    """
    per = []
    for case in cases:
        na = _weighted_norm(case.Atil, case.h)
        nb = _weighted_norm(case.B, case.h)
        if case.nbar and nb >= 1.0:
            raise DesignError(f"{case.label}: ||B||_R = {nb:.6g} is not below 1 (eq. ino)")
        per.append((na, nb))
    if q is None:
        q = 1
        for na, nb in per:
            if na > rate and nb > 0:
                q = max(q, math.ceil(math.log(rate / na) / math.log(nb) - 1e-12))
        # the -1e-12 spares a step when the ratio is an integer; round-off can then leave
        # ||Atil||_R ||B||_R^q an ulp above lam, so step up until eq. (rnorm) holds as evaluated (by the one rule)
        while not certifies(max(na * nb ** q for na, nb in per), rate) and q <= q_max:
            q += 1
        if q > q_max:
            raise DesignError(f"q (weighted) = {q} exceeds design.q_max = {q_max}")
    bound = max(na * nb ** q for na, nb in per)
    return QResult(q=q, method="weighted", bound=bound, certified=certifies(bound, rate), switching=False)


def q_two_norm(cases, rate: float, *, q: int | None = None, q_max: int = 100_000) -> QResult:
    """q = p * pbar by the standard two-norm over all cases (time-varying graphs).

    ``p``: smallest with ``|B^p|_2 < 1`` for every case; ``pbar``: smallest with
    ``|Atil (B^p)^pbar|_2 < lam`` for every case.  Certificate:
    ``max |Atil B^q|_2 < lam`` (:func:`.spectral.certifies`), which bounds every product of switching steps.

    Parameters
    ----------
    cases : iterable of Case
        The graphs switched among.
    rate : float
        The decay rate ``lam`` per event time.
    q : int, optional
        Check this q instead of computing it (then ``p`` and ``pbar`` are None).
    q_max : int
        The largest q allowed.

    Returns
    -------
    QResult
        ``bound = max |Atil B^q|_2``, ``certified`` when below ``rate`` (:func:`.spectral.certifies`), ``switching=True``, ``p`` and ``pbar``.

    Raises
    ------
    DesignError
        No p or pbar within ``q_max``.
    """
    live = [c for c in cases if c.nbar]

    def norm2(M):
        return float(np.linalg.norm(M, 2)) if M.size else 0.0

    if q is None:
        def p_pred(case):  # |B^k|_2 < 1, memoised while this case is evaluated
            powers, memo = _Powers(case.B), {}
            return lambda k: memo[k] if k in memo else memo.setdefault(k, norm2(powers(k)) < 1.0)

        # warm-started over the cases (_smallest_max): the p of a search from scratch per case
        p = _smallest_max((p_pred(c) for c in live), q_max,
                          whats=(f"p (two-norm, {c.label})" for c in live)) if live else 1
        Bp = [_power(c.B, p) for c in live]
        pbar = smallest(lambda k: all(certifies(norm2(c.Atil @ _power(b, k)), rate) for c, b in zip(live, Bp)),
                         max(1, q_max // p), what="pbar (two-norm)")
        q = p * pbar
    else:
        p = pbar = None
    bound = max([norm2(c.Atil @ _power(c.B, q)) for c in live] or [0.0])
    return QResult(q=q, method="two-norm", bound=bound, certified=certifies(bound, rate), switching=True, p=p, pbar=pbar)


def mixed_norm(M: np.ndarray, rows, cols=None) -> float:
    """Mixed matrix norm, eq. (split_mmn): ``|| <M> ||_inf`` with ``<M>_ij = ||M_ij||_2``.

    Only the non-zero blocks are factorised: ``Atil`` is block diagonal and ``B = V' Sbar V``
    has blocks only on the graph's arcs and the diagonal, so most of the ``m^2`` blocks are
    exactly zero (norm 0).  The others are stacked by shape into one batched SVD each (the
    same LAPACK call per block as ``np.linalg.norm(block, 2)``), and each row of blocks is
    summed left to right as before: the same number as the block-by-block loop.

    Parameters
    ----------
    M : 2-D array
        The matrix, partitioned into blocks ``M_ij``.
    rows : sequence of int
        The row sizes of the blocks (``n_i``; zeros allowed).
    cols : sequence of int, optional
        The column sizes (default ``rows``).

    Returns
    -------
    float
        ``max_i sum_j ||M_ij||_2`` (>= 0); 0 when every block is empty.

    Examples
    --------
    >>> import numpy as np
    >>> round(mixed_norm(np.diag([3., 4.]), [1, 1]), 3), round(mixed_norm(np.ones((2, 2)), [1, 1]), 3)
    (4.0, 2.0)
    """
    cols = rows if cols is None else cols
    rows, cols = np.asarray(rows, dtype=int), np.asarray(cols, dtype=int)
    r_edges = np.concatenate([[0], np.cumsum(rows)])
    c_edges = np.concatenate([[0], np.cumsum(cols)])
    ri, cj = np.flatnonzero(rows), np.flatnonzero(cols)  # empty blocks count for nothing
    if not len(ri) or not len(cj):
        return 0.0
    # which blocks hold a non-zero entry: reduce over each block's rows, then its columns
    nz = np.logical_or.reduceat(np.logical_or.reduceat(M != 0, r_edges[ri], axis=0), c_edges[cj], axis=1)
    norms = np.zeros((len(ri), len(cj)))  # <M>_ij over the non-empty blocks
    bi, bj = np.nonzero(nz)
    shapes = rows[ri[bi]] * (int(cols.max()) + 1) + cols[cj[bj]]
    for shape in np.unique(shapes):
        sel = np.flatnonzero(shapes == shape)
        blocks = np.stack([M[r_edges[ri[i]]:r_edges[ri[i] + 1], c_edges[cj[j]]:c_edges[cj[j] + 1]]
                           for i, j in zip(bi[sel], bj[sel])])
        norms[bi[sel], bj[sel]] = np.linalg.svd(blocks, compute_uv=False).max(axis=-1)  # ||M_ij||_2
    row_sums = np.zeros(len(ri))
    for j in range(len(cj)):  # left to right, as the block-by-block loop added them
        row_sums += norms[:, j]
    return max(0.0, float(row_sums.max()))


def q_mixed(cases, rate: float, *, q: int | None = None, q_max: int = 100_000) -> QResult:
    """q = p * pbar by the mixed matrix norm, eqs. (rajit), (rajit2), (rajit3).

    ``p >= (m - 1)^2`` makes ``||B^p|| < 1`` (checked numerically; doubled if not);
    ``pbar`` is the smallest with ``||Atil|| ||B^p||^pbar < lam`` for every case (:func:`.spectral.certifies`).

    Parameters
    ----------
    cases : iterable of Case
        The graphs switched among.
    rate : float
        The decay rate ``lam`` per event time.
    q : int, optional
        Check this q: the factorisation ``q = p * pbar`` with the smallest bound is reported.
    q_max : int
        The largest q allowed.

    Returns
    -------
    QResult
        ``bound = max ||Atil|| ||B^p||^pbar`` (mixed norms), ``certified`` when below ``rate`` (:func:`.spectral.certifies`), ``switching=True``,
        ``p`` and ``pbar``.

    Raises
    ------
    DesignError
        ``||B^p|| >= 1`` for every p up to ``q_max``, or the q needed exceeds ``q_max``.
    """
    live = [c for c in cases if c.nbar]
    if q is not None:
        # certificate for a given q: factor q = p * pbar with the best admissible p
        best = (math.inf, None, None)
        for p in range(1, q + 1):
            if q % p:
                continue
            val = max([mixed_norm(c.Atil, c.sizes) * mixed_norm(_power(c.B, p), c.sizes) ** (q // p)
                       for c in live] or [0.0])
            if val < best[0]:
                best = (val, p, q // p)
        bound, p, pbar = best
        return QResult(q=q, method="mixed", bound=bound, certified=certifies(bound, rate), switching=True, p=p, pbar=pbar)
    if not live:
        return QResult(q=1, method="mixed", bound=0.0, certified=True, switching=True, p=1, pbar=1)
    p = max(1, max((c.graph.m - 1) ** 2 for c in live))
    while True:
        nbs = [mixed_norm(_power(c.B, p), c.sizes) for c in live]
        if max(nbs) < 1.0:
            break
        p *= 2
        if p > q_max:
            raise DesignError(f"mixed norm: ||B^p|| >= 1 for p up to design.q_max = {q_max}")
    nas = [mixed_norm(c.Atil, c.sizes) for c in live]
    pbar = 1
    for na, nb in zip(nas, nbs):
        if na > rate and nb > 0:
            pbar = max(pbar, math.ceil(math.log(rate / na) / math.log(nb) - 1e-12))
    # as in q_weighted: step up until eq. (rajit3) holds as evaluated, not just up to round-off
    while not certifies(max(na * nb ** pbar for na, nb in zip(nas, nbs)), rate) and p * pbar <= q_max:
        pbar += 1
    q = p * pbar
    if q > q_max:
        raise DesignError(f"q (mixed) = {q} exceeds design.q_max = {q_max}")
    bound = max(na * nb ** pbar for na, nb in zip(nas, nbs))
    return QResult(q=q, method="mixed", bound=bound, certified=certifies(bound, rate), switching=True, p=p, pbar=pbar)


_Q_METHODS = {"spectral": q_spectral, "weighted": q_weighted, "two-norm": q_two_norm, "mixed": q_mixed}


def choose_q(method: str, cases, rate: float, *, q: int | None = None, q_max: int = 100_000,
             eig: str = "auto", workers: int | None = None) -> QResult:
    """Dispatch to the q method named by ``design.q_method``; ``q`` given means 'check this q'; ``eig``: how the
    spectral q computes its radii (:func:`error_radius`); ``workers``: its processes (:func:`q_spectral`).

    Parameters
    ----------
    method : {"spectral", "weighted", "two-norm", "mixed"}
        The q method.
    cases : iterable of Case
        Every case the design covers.
    rate : float
        The decay rate ``lam`` per event time.
    q : int, optional
        Check this q instead of searching.
    q_max : int
        The largest q allowed.
    eig : {"auto", "dense", "iterative"}
        The spectral method's eigenvalue path (ignored by the others).
    workers : int, optional
        The spectral method's processes.

    Returns
    -------
    QResult
        The method's result.

    Raises
    ------
    DesignError
        As the method raises it.
    """
    if method == "spectral":
        return q_spectral(cases, rate, q=q, q_max=q_max, method=eig, workers=workers)
    return _Q_METHODS[method](cases, rate, q=q, q_max=q_max)


def nice_ceil(x: float) -> float:
    """Round up to two significant digits (9.47 -> 9.5, 103.8 -> 110); the auto g.

    Parameters
    ----------
    x : float
        The value to round up.

    Returns
    -------
    float
        The smallest two-significant-digit number ``>= x`` (up to 1e-9 relative); 0 for ``x <= 0``.

    Examples
    --------
    >>> nice_ceil(9.47), nice_ceil(103.8)
    (9.5, 110.0)
    """
    if x <= 0:
        return 0.0
    e = 10.0 ** (math.floor(math.log10(x)) - 1)
    return round(math.ceil(x / e - 1e-9) * e, 12)
