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
  spectral radius of a matrix within that backward error of ours; our own radius is within about ``TOL`` of it
  when the largest eigenvalue is simple, but a k-fold defective one moves like ``TOL^(1/k)``, so the accuracy
  claimed (:class:`Radius` ``tol``) is ``100 TOL`` when no other Ritz value coincides with the largest (within
  ``CLUSTER``), ``CLUSTER`` when some do, and the radius is computed densely when all of them do (the
  multiplicity may be larger);
* when it does not converge, when all the Ritz values it was asked for coincide (a multiple eigenvalue of
  unknown multiplicity), or when its ``rho`` is within ``max(DECIDE, its accuracy)`` (relative) of the rate
  it is compared with, the radius is computed again densely (every eigenvalue: the exact path, whatever the
  size);
* every value records how it was computed (:class:`Radius`), and the design reports the methods and
  tolerances used (``splitspec design --json``: ``q_eigenvalues``).

``method`` everywhere: ``dense`` (always form and decompose), ``iterative`` (always ARPACK first, with the
fallbacks above), ``auto`` (iterative above ``DENSE_MAX`` unknowns, where it is faster; the default).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["DENSE_MAX", "DECIDE", "TOL", "Radius", "radius", "summary", "use_iterative"]

DENSE_MAX = 300  # nbar above which "auto" goes matrix-free (dense eigvals of 300 x 300: ~30 ms)
TOL = 1e-12  # ARPACK's relative tolerance on the Ritz values
# An iterative radius within max(DECIDE, its accuracy) (relative) of the rate is computed again densely.
DECIDE = 1e-4
CLUSTER = 1e-2  # Ritz values within this (relative, in the complex plane) of the largest: maybe one eigenvalue
# (a k-fold defective eigenvalue perturbed by TOL spreads its Ritz values over about TOL^(1/k): 1e-3 for k = 4)
METHODS = ("auto", "dense", "iterative")


@dataclass(frozen=True)
class Radius:
    """A spectral radius and how it was computed: ``dense``, ``iterative`` (ARPACK; ``tol`` its expected relative
    accuracy: ``100 TOL`` for a simple largest eigenvalue, ``CLUSTER`` when other Ritz values coincide with it) or
    ``dense (fallback: ...)`` when the iterative computation did not settle it (``tol`` 0: round-off only)."""

    value: float
    method: str
    tol: float


def use_iterative(nbar: int, method: str = "auto") -> bool:
    if method not in METHODS:
        raise ValueError(f"eigenvalue method must be one of {METHODS}, got {method!r}")
    return method == "iterative" or (method == "auto" and nbar > DENSE_MAX)


def _padded(blocks, sizes, shape) -> np.ndarray:
    out = np.zeros((len(blocks), *shape))
    for k, blk in enumerate(blocks):
        blk = np.asarray(blk, dtype=float)
        out[k, :blk.shape[0], :blk.shape[1]] = blk
    return out


def _sparse_factors(case):
    """``(Atil, B)`` as CSR matrices: Atil block diagonal, B with the block ``S_ij V_i' V_j`` per arc (and i = j).

    Vectorised over the blocks: every ``V_i`` and ``A_i`` zero-padded to the largest ``n_i``, the blocks of all
    arcs in one batched product, the padding masked out."""
    import scipy.sparse as sp

    sizes = np.asarray(case.sizes, dtype=int)
    edges = np.concatenate([[0], np.cumsum(sizes)])
    N, s = int(edges[-1]), int(sizes.max())
    n = case.V_blocks[0].shape[0]
    a, b = np.meshgrid(np.arange(s), np.arange(s), indexing="ij")

    def csr(blocks, I, J):
        keep = (a[None] < sizes[I, None, None]) & (b[None] < sizes[J, None, None])
        rows = np.broadcast_to(edges[I, None, None] + a[None], keep.shape)[keep]
        cols = np.broadcast_to(edges[J, None, None] + b[None], keep.shape)[keep]
        return sp.csr_matrix((blocks[keep], (rows, cols)), shape=(N, N))

    ids = np.arange(len(sizes))
    Atil = csr(_padded(case.A_blocks, sizes, (s, s)), ids, ids)
    S = np.asarray(case.graph.S)
    I, J = np.nonzero(S)
    V = _padded(case.V_blocks, sizes, (n, s))
    blocks = S[I, J][:, None, None] * np.einsum("pka,pkb->pab", V[I], V[J])  # S_ij V_i' V_j: V' (S (x) I) V
    return Atil, csr(blocks, I, J)


def _factors(case):
    cached = case.__dict__.get("_sparse")
    if cached is None:
        cached = case.__dict__["_sparse"] = _sparse_factors(case)  # the frozen Case's cache, like cached_property
    return cached


def _dense(case, q: int) -> float:
    """Every eigenvalue of the formed ``Atil B^q`` (eq. split_discrete_ench): the operations of the dense path of
    :func:`splitspec_core.bounds.error_radius` (``matrix_power``, ``eigvals``), so the same value."""
    M = case.Atil @ np.linalg.matrix_power(case.B, q)
    return float(np.max(np.abs(np.linalg.eigvals(M)))) if M.size else 0.0


def radius(case, q: int, *, rate: float | None = None) -> Radius:
    """``rho(Atil B^q)`` of ``case`` by ARPACK on the operator ``x -> Atil B^q x``, densely when ARPACK does not
    converge or (with ``rate``) lands within ``DECIDE`` of it (see the module docstring)."""
    from scipy.sparse.linalg import ArpackNoConvergence, LinearOperator, eigs

    N = case.nbar
    if N <= 3:  # ARPACK needs k < N - 1
        return Radius(_dense(case, q), "dense", 0.0)
    Atil, B = _factors(case)

    def apply(x):
        for _ in range(q):
            x = B @ x
        return Atil @ x

    op = LinearOperator((N, N), matvec=apply, dtype=float)
    k = min(6, N - 2)  # a few: complex pairs and near-ties of the largest modulus converge together
    v0 = np.random.default_rng(0).standard_normal(N)  # a fixed start: the same answer every run
    try:
        vals = eigs(op, k=k, which="LM", tol=TOL, v0=v0, ncv=min(N, max(2 * k + 1, 20)), maxiter=max(1000, 10 * N),
                    return_eigenvectors=False)
    except ArpackNoConvergence:
        return Radius(_dense(case, q), "dense (fallback: ARPACK did not converge)", 0.0)
    vals = vals[np.argsort(-np.abs(vals))]
    rho = float(abs(vals[0]))
    # Ritz values this close to the largest may be one multiple eigenvalue: k of them, accurate to about
    # TOL^(1/k); as many as were asked for, and its multiplicity (so the accuracy) is unknown: dense
    cluster = int(np.sum(np.abs(vals - vals[0]) <= CLUSTER * rho))
    if cluster >= k:
        return Radius(_dense(case, q), f"dense (fallback: {cluster} of ARPACK's largest eigenvalues coincide)", 0.0)
    # the accuracy claimed: 100 TOL for a simple largest eigenvalue; when other Ritz values coincide with it, it
    # may be a multiple defective eigenvalue, whose Ritz values ARPACK need not all find (a drawn 4-fold one gave
    # 2, off by 5e-4): accurate to the width of the cluster only.  tests/property/test_design_properties.py
    # checks the claim against dense.
    tol = 100 * TOL if cluster == 1 else CLUSTER
    margin = max(DECIDE, tol)
    if rate is not None and abs(rho - rate) <= margin * max(rho, rate):
        return Radius(_dense(case, q), f"dense (fallback: ARPACK's {rho:.10g} within {margin:g} of the rate)", 0.0)
    return Radius(rho, "iterative", tol)


def summary(hows) -> dict:
    """What a set of :class:`Radius` used: ``{"methods": {method: count}, "tolerance": the largest tol, "decide":
    DECIDE}`` (tolerance 0: every radius dense)."""
    methods: dict = {}
    tol = 0.0
    for h in hows:
        if h is None:
            continue
        key = "dense (fallback)" if h.method.startswith("dense (fallback") else h.method
        methods[key] = methods.get(key, 0) + 1
        tol = max(tol, h.tol)
    return {"methods": methods, "tolerance": tol, "decide": DECIDE if tol else 0.0}
