"""Spectral radii of the error map without dense eigendecompositions (large networks).

The spectral q (eq. split_discrete_rho) needs ``rho(Atil B^q)`` of every case: ``Atil = blockdiag(A_i)``,
``B = V' Sbar V`` (eq. split_discrete_ench), of size ``nbar = sum n_i``.  Formed densely that is an
``nbar x nbar`` matrix and an O(nbar^3) eigendecomposition per case and q: minutes for a resilient design of
100 agents, out of reach for 1000.  Both factors are sparse: ``Atil`` is block diagonal, and ``B`` has the
block ``S_ij V_i' V_j`` only where agent i hears agent j (``S_ij != 0``).  So ``x -> Atil B^q x`` costs q sparse
products, and ARPACK (implicitly restarted Arnoldi, :func:`scipy.sparse.linalg.eigs`) finds the eigenvalues of
largest modulus from a few dozen of them.

A certificate never says more than what was computed:

* ARPACK stops when the Ritz values' residuals are below ``TOL`` relative to them; its answer ``rho`` is the
  spectral radius of a matrix within that backward error of ours.  How far that is from our own radius depends
  on the eigenvalue's condition: the accuracy claimed (:class:`Radius` ``tol``) is ten times the first-order
  error, condition x residual, with the condition ``|x| |y| / |y' x|`` from the left eigenvector ``y`` (ARPACK
  again, on the transpose), and at least ``100 TOL``.  A defective (multiple) eigenvalue, which moves like
  ``TOL^(1/k)``, has ``y' x`` near 0: a huge condition, a large claimed error;
* when it does not converge (or fails: an ARPACK error), or when its ``rho`` is within ``max(DECIDE, its accuracy)``
  of the rate it is compared with, the radius is computed again densely (every eigenvalue: the exact path, whatever the
  size);
* every value records how it was computed (:class:`Radius`), and the design reports the methods and
  tolerances used (``splitspec design --json``: ``q_eigenvalues``).

Every certificate decides by one rule, :func:`certifies` (and every report phrases it by :func:`comparison`): a bound
certifies the rate only when it is *below* it, by the relative margin :data:`CERTIFY_MARGIN`.  A bound equal to
the rate certifies nothing (a Jordan block at the rate grows like ``k lam^k``; its transient constant is infinite),
and a bound an ulp below it is equal to it up to the round-off of the eigenvalue (or norm) that computed it: a
double eigenvalue moves like the square root of the round-off, ``1e-8`` relative, and the error map of another
computation path (:mod:`.conditioning`'s full error matrix) lands on the other side of the rate.

``method`` everywhere: ``dense`` (always form and decompose), ``iterative`` (always ARPACK first, with the
fallbacks above), ``auto`` (iterative above ``DENSE_MAX`` unknowns, where it is faster; the default).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..model.graphs import positions_in

__all__ = ["CERTIFY_MARGIN", "certifies", "comparison", "DENSE_MAX", "DECIDE", "TOL", "Radius", "radius", "radii", "spectral_radius", "summary", "use_iterative"]

DENSE_MAX = 300  # nbar above which "auto" goes matrix-free (dense eigvals of 300 x 300: ~30 ms)
TOL = 1e-8  # ARPACK's relative tolerance on the Ritz values
# An iterative radius within max(DECIDE, its accuracy) (relative) of the rate is computed again densely: 1 %, more
# than the gap between the largest eigenvalues of these crowded spectra (0.1 % measured), should ARPACK settle on
# the second largest with a small residual.
DECIDE = 1e-2
NCV = 40  # ARPACK's Krylov basis size (at least): the top of these spectra is crowded (moduli 0.5 % apart)
METHODS = ("auto", "dense", "iterative")
#: The relative margin of the one rule (:func:`certifies`): 100 times the round-off of a defective (double)
#: eigenvalue's modulus (``sqrt(eps) ~ 1.5e-8``), a rate slower by a millionth of itself: nothing a design needs
CERTIFY_MARGIN = 1e-6


def certifies(bound: float, limit: float) -> bool:
    """The one rule of every certificate: ``bound < limit - CERTIFY_MARGIN |limit|`` (strict, with a margin).

    ``bound`` is what must be below ``limit``: a spectral radius or norm per event time against the rate ``lam``
    (discrete), a spectral abscissa against ``-lam`` (continuous), a decay rate ``-d`` against ``-lam``.  Equal, or
    within :data:`CERTIFY_MARGIN` (relative) of it, certifies nothing (module docstring).

    Parameters
    ----------
    bound : float
        The certified quantity.
    limit : float
        What it must be below.

    Returns
    -------
    bool
        True when ``bound`` is below ``limit`` by the margin (False for NaN).

    Examples
    --------
    >>> certifies(0.4736, 0.5), certifies(0.5, 0.5), certifies(0.5 * (1 - 1e-9), 0.5), certifies(-2.1, -2.0)
    (True, False, False, True)
    """
    return bool(bound < limit - CERTIFY_MARGIN * abs(limit))


def comparison(bound: float, limit: float, *, limit_text: str | None = None, digits: int = 4) -> str:
    """The one rule (:func:`certifies`) as a report prints it: ``bound < limit`` when it certifies, ``bound >= limit``
    when it is not below, and for a bound below but within the margin, both with 10 digits and the reason.

    Parameters
    ----------
    bound : float
        The certified quantity.
    limit : float
        What it must be below.
    limit_text : str, optional
        How ``limit`` is named (e.g. ``rate 0.5``); default its value.
    digits : int
        Significant digits of ``bound``.

    Returns
    -------
    str
        A clause, e.g. ``0.4736 < rate 0.5``.

    Examples
    --------
    >>> comparison(0.4736, 0.5, limit_text="rate 0.5"), comparison(0.52, 0.5), comparison(0.94996, 0.95)
    ('0.4736 < rate 0.5', '0.52 >= 0.5', '0.94996 < 0.95')
    >>> print(comparison(0.2999999999, 0.3, limit_text="rate 0.3"))
    0.2999999999 is not below rate 0.3 by the certificate's margin (1e-06 relative)
    """
    named = f"{limit:g}" if limit_text is None else limit_text
    while digits < 10 and bound != limit and f"{bound:.{digits}g}" == f"{limit:.{digits}g}":
        digits += 1  # never "0.95 < rate 0.95": as many digits as tell them apart
    if certifies(bound, limit):
        return f"{bound:.{digits}g} < {named}"
    if bound >= limit or not bound == bound:
        return f"{bound:.{digits}g} >= {named}"
    return f"{bound:.10g} is not below {named} by the certificate's margin ({CERTIFY_MARGIN:g} relative)"


@dataclass(frozen=True)
class Radius:
    """A spectral radius and how it was computed: ``dense``, ``iterative`` (ARPACK; ``tol`` its claimed relative
    accuracy: ten times condition x residual, at least ``100 TOL``) or
    ``dense (fallback: ...)`` when the iterative computation did not settle it (``tol`` 0: round-off only)."""

    value: float
    method: str
    tol: float


def use_iterative(nbar: int, method: str = "auto") -> bool:
    """Whether ``method`` takes the iterative (ARPACK) path for a case of ``nbar`` unknowns.

    Parameters
    ----------
    nbar : int
        The case's size, ``sum n_i``.
    method : {"auto", "dense", "iterative"}
        ``auto``: iterative above :data:`DENSE_MAX`.

    Returns
    -------
    bool
        True: ARPACK first (with the dense fallbacks); False: dense.

    Raises
    ------
    ValueError
        An unknown ``method``.

    Examples
    --------
    >>> use_iterative(10), use_iterative(400), use_iterative(10, "iterative"), use_iterative(400, "dense")
    (False, True, True, False)
    """
    if method not in METHODS:
        raise ValueError(f"eigenvalue method must be one of {METHODS}, got {method!r}")
    return method == "iterative" or (method == "auto" and nbar > DENSE_MAX)


def _padded(blocks, shape) -> np.ndarray:
    """The blocks stacked into one ``(len, *shape)`` array, each zero-padded to ``shape`` (one ``np.stack`` when
    they all have that shape already)."""
    if {np.shape(b) for b in blocks} == {shape}:
        return np.stack(blocks).astype(float, copy=False)
    out = np.zeros((len(blocks), *shape))
    for k, blk in enumerate(blocks):
        blk = np.asarray(blk, dtype=float)
        out[k, :blk.shape[0], :blk.shape[1]] = blk
    return out


def _sparse_factors(case):
    """``(Atil B, B)`` as sparse matrices: ``B`` with the block ``S_ij V_i' V_j`` per arc (and i = j), ``Atil B``
    with ``A_i S_ij V_i' V_j`` (as sparse as ``B``: ``Atil`` is block diagonal).

    Vectorised over the blocks: every ``V_i`` and ``A_i`` zero-padded to the largest ``n_i``, the blocks of all
    arcs in one batched product.  Every ``n_i`` equal (the common case: agents with the same kind of sensor): block
    sparse rows (BSR) of those blocks, whose products run ~1.5x faster than CSR's; otherwise CSR with the padding
    masked out."""
    import scipy.sparse as sp

    sizes = np.asarray(case.sizes, dtype=int)
    N, s, m = int(sizes.sum()), int(sizes.max()), len(sizes)
    n = case.V_blocks[0].shape[0]
    I, J, w = case.graph.entries
    order = np.lexsort((J, I))  # row by row, columns ascending: the block rows of B
    I, J, w = I[order], J[order], w[order]
    V = _padded(case.V_blocks, (n, s))
    Bb = w[:, None, None] * np.matmul(V[I].transpose(0, 2, 1), V[J])  # S_ij V_i' V_j: V' (S (x) I) V
    ABb = np.matmul(_padded(case.A_blocks, (s, s))[I], Bb)  # A_i S_ij V_i' V_j: Atil V' (S (x) I) V
    if np.all(sizes == s):
        indptr = np.concatenate([[0], np.cumsum(np.bincount(I, minlength=m))])
        return tuple(sp.bsr_matrix((blocks, J, indptr), shape=(N, N)) for blocks in (ABb, Bb))
    edges = np.concatenate([[0], np.cumsum(sizes)])
    a, b = np.meshgrid(np.arange(s), np.arange(s), indexing="ij")
    keep = (a[None] < sizes[I, None, None]) & (b[None] < sizes[J, None, None])
    rows = np.broadcast_to(edges[I, None, None] + a[None], keep.shape)[keep]
    cols = np.broadcast_to(edges[J, None, None] + b[None], keep.shape)[keep]
    return tuple(sp.csr_matrix((blocks[keep], (rows, cols)), shape=(N, N)) for blocks in (ABb, Bb))


def spectral_radius(M: np.ndarray) -> float:
    """The largest eigenvalue modulus of a formed matrix: every eigenvalue (``eigvals``).

    Parameters
    ----------
    M : (k, k) array
        The matrix.

    Returns
    -------
    float
        ``max |eig(M)|``; 0 for an empty matrix.
    """
    return float(np.max(np.abs(np.linalg.eigvals(M)))) if M.size else 0.0


def _dense(case, q: int) -> float:
    """``rho(Atil B^q)`` of the formed matrix (eq. split_discrete_ench), as the dense path of
    :func:`splitspec_core.synthesis.bounds.error_radius` computes it (``matrix_power``, then :func:`spectral_radius`)."""
    return spectral_radius(case.Atil @ np.linalg.matrix_power(case.B, q))


def _warm_start(case, warm, N: int):
    """Start vectors for ``case`` from the eigenvectors of another case at the same q (``warm``: its agent ids,
    block sizes and vectors), block by block for the agents both have: a loss case of a resilient design is the
    network with one agent less, and its dominant eigenvectors are close to the full network's.  A fixed random
    vector otherwise (the same answer every run)."""
    fixed = np.random.default_rng(0).standard_normal(N)
    if warm is None:
        return fixed, fixed
    ids, sizes, x, w = warm
    sizes = np.asarray(sizes, dtype=int)
    k, found = positions_in(ids, case.graph.ids)
    own = np.asarray(case.sizes, dtype=int)
    if not (np.all(found) and np.all(sizes[k] == own)):
        return fixed, fixed
    starts = np.concatenate([[0], np.cumsum(sizes)])[k]  # where each agent's block is in warm's vectors
    edges = np.concatenate([[0], np.cumsum(own)])
    pick = np.arange(N) - np.repeat(edges[:-1] - starts, own)
    out = []
    for v in (x, w):
        v = (v.real + v.imag)[pick]
        norm = np.linalg.norm(v)
        # mixed with the fixed random vector: every direction keeps a component, so an eigenvector of this case
        # that the other case's misses (one localised at the lost agent, say) is still found
        out.append(v / norm + 0.5 * fixed / np.linalg.norm(fixed) if norm > 0 else fixed)
    return out[0], out[1]


def radius(case, q: int, *, rate: float | None = None, warm=None, vectors: dict | None = None) -> Radius:
    """``rho(Atil B^q)`` of ``case`` by ARPACK on the operator ``x -> Atil B^q x``, densely when ARPACK does not
    converge or (with ``rate``) lands within ``max(DECIDE, its accuracy)`` of it (see the module docstring).
    ``warm``: start from another case's eigenvectors (:func:`_warm_start`); ``vectors``: a dict that receives this
    case's, ``{q: (ids, sizes, right, left)}``, for the next.

    Parameters
    ----------
    case : bounds.Case
        One agent set and graph (``nbar <= 3``: dense at once).
    q : int
        Consensus exchanges per event time (at least 1).
    rate : float, optional
        The rate the radius will be compared with; None: no comparison, no fallback for closeness.
    warm : tuple, optional
        ``(ids, sizes, right, left)`` of another case at this q.
    vectors : dict, optional
        Receives ``vectors[q] = (ids, sizes, right, left)`` of this case.

    Returns
    -------
    Radius
        The value, ``iterative`` with its claimed relative accuracy, or ``dense``/``dense (fallback: why)`` with 0.

    Examples
    --------
    >>> from splitspec_core.model.graphs import build_graph
    >>> from splitspec_core.synthesis.bounds import make_case
    >>> ids = tuple(range(1, 7))
    >>> ring = build_graph("ring", ids, [(i, i % 6 + 1) for i in ids] + [(i % 6 + 1, i) for i in ids])
    >>> Vs = [np.array([[np.cos(t)], [np.sin(t)]]) for t in np.linspace(0, 2.5, 6)]
    >>> case = make_case("ring", ring, Vs, [np.array([[1.1]])] * 6)
    >>> r = radius(case, 3)
    >>> r.method, round(r.value, 6), round(spectral_radius(case.Atil @ np.linalg.matrix_power(case.B, 3)), 6)
    ('iterative', 0.65473, 0.65473)
    >>> radius(case, 3, rate=0.65).method  # doctest: +ELLIPSIS
    "dense (fallback: ARPACK's 0.65473... within 0.01 of the rate)"
    """
    from scipy.sparse.linalg import ArpackError, ArpackNoConvergence, LinearOperator, eigs

    N = case.nbar
    if N <= 3:  # ARPACK needs k < N - 1
        return Radius(_dense(case, q), "dense", 0.0)
    # built for this call and dropped after it: the m + 1 cases of a resilient design of 1000 agents would hold
    # 2.5 GB of them (a case is evaluated at one q but for the few a q search visits again)
    AB, B = _sparse_factors(case)  # Atil B formed (as sparse as B): one product less per application

    def apply(x):
        for _ in range(q - 1):
            x = B @ x
        return AB @ x

    ABt, Bt = AB.T, B.T

    def apply_t(y):  # (Atil B^q)' y = (B')^(q-1) (Atil B)' y: for the left eigenvector
        y = ABt @ y
        for _ in range(q - 1):
            y = Bt @ y
        return y

    k = min(3, N - 2)  # a complex pair and the next: with k = 1 ARPACK settled on the second largest of a crowded
    # spectrum (0.7357 for 0.7365, m = 600 resilient; the condition check caught it)
    v0, w0 = _warm_start(case, warm, N)
    kw = dict(k=k, which="LM", tol=TOL, ncv=min(N, max(2 * k + 1, NCV)), maxiter=max(1000, 10 * N))
    try:
        vals, X = eigs(LinearOperator((N, N), matvec=apply, dtype=float), v0=v0, **kw)
        left, W = eigs(LinearOperator((N, N), matvec=apply_t, dtype=float), v0=w0, **kw)
    except ArpackNoConvergence:
        return Radius(_dense(case, q), "dense (fallback: ARPACK did not converge)", 0.0)
    except ArpackError as exc:  # e.g. error 1 of dneupd (the Schur form could not be reordered: a drawn case of 8
        # agents on one state, 6 of them blind), raised where the iteration itself converged
        return Radius(_dense(case, q), f"dense (fallback: {str(exc).split(':')[0]})", 0.0)
    top = int(np.argmax(np.abs(vals)))
    theta, x = vals[top], X[:, top]
    rho = float(abs(theta))
    # the accuracy claimed: the first-order error of a simple eigenvalue, condition x residual (Wilkinson): the
    # residual |(Atil B^q) x - theta x| of the Ritz pair, the condition |x| |y| / |y' x| from the left eigenvector
    # y (ARPACK on the transpose).  A defective (multiple) eigenvalue has y' x ~ 0: a huge condition, so a large
    # claimed error, which sends any decision near the rate to the dense path.  x 10 and at least 100 TOL: a
    # margin for what first order leaves out (tests/property/test_design_properties.py checks the claim).
    # the left Ritz vector of theta: ARPACK may have returned the conjugate of the pair (the matrix is real, so the
    # eigenvector of conj(theta) is the conjugate of theta's)
    both = np.concatenate([left, np.conj(left)])
    pick = int(np.argmin(np.abs(both - theta)))
    w = W[:, pick] if pick < len(left) else np.conj(W[:, pick - len(left)])
    if vectors is not None:
        vectors[q] = (case.graph.ids, case.sizes, x, w)
    resid = float(np.linalg.norm(apply(x.real) + 1j * apply(x.imag) - theta * x) / np.linalg.norm(x))
    overlap = abs(np.dot(w, x))  # w' x with w an eigenvector of the transpose (y = conj(w))
    cond = np.inf if overlap == 0 else float(np.linalg.norm(w) * np.linalg.norm(x) / overlap)
    tol = min(1.0, max(100 * TOL, 10 * cond * resid / max(rho, 1e-300)))
    margin = max(DECIDE, tol)
    if rate is not None and abs(rho - rate) <= margin * max(rho, rate):
        return Radius(_dense(case, q), f"dense (fallback: ARPACK's {rho:.10g} within {margin:.3g} of the rate)", 0.0)
    return Radius(rho, "iterative", tol)


def _radius_of(state, k: int) -> Radius:
    cases, q, rate, warm = state
    return radius(cases[k], q, rate=rate, warm=warm)


def radii(cases, q: int, *, rate: float | None = None, warm=None, workers: int | None = None) -> list:
    """:func:`radius` of every case at ``q`` (all started from ``warm``), on ``workers`` processes
    (:func:`splitspec_core.parallel.fork_map`; ``None``: every core this process may use): the loss cases of a
    resilient design are independent.  The values of the serial loop, in the order of ``cases``.

    Parameters
    ----------
    cases : iterable of bounds.Case
        The cases.
    q : int
        Consensus exchanges per event time.
    rate : float, optional
        As in :func:`radius`.
    warm : tuple, optional
        Every case's start (:func:`radius`).
    workers : int, optional
        Processes (None: every core this process may use).

    Returns
    -------
    list of Radius
        One per case, in order.
    """
    from ..parallel import fork_map

    return fork_map(_radius_of, (tuple(cases), q, rate, warm), range(len(cases)), workers=workers)


def summary(hows) -> dict:
    """What a set of :class:`Radius` used: ``{"methods": {method: count}, "tolerance": the largest tol, "decide":
    DECIDE}`` (tolerance and decide 0: every radius dense).

    Parameters
    ----------
    hows : iterable of Radius or None
        How each radius was computed (None skipped).

    Returns
    -------
    dict
        Every ``dense (fallback: ...)`` counted as ``dense (fallback)``.

    Examples
    --------
    >>> summary([Radius(0.5, "dense", 0.0), Radius(0.4, "iterative", 1e-6), None])
    {'methods': {'dense': 1, 'iterative': 1}, 'tolerance': 1e-06, 'decide': 0.01}
    """
    methods: dict = {}
    tol = 0.0
    for h in hows:
        if h is None:
            continue
        key = "dense (fallback)" if h.method.startswith("dense (fallback") else h.method
        methods[key] = methods.get(key, 0) + 1
        tol = max(tol, h.tol)
    return {"methods": methods, "tolerance": tol, "decide": DECIDE if tol else 0.0}
