"""Orthonormal bases of subspaces: complement, intersection, difference (numpy only: agent processes use them).

The intersection of all but one of m subspaces, for each of the m (what the survivors of a single agent loss leave
unobserved), comes from triangular factors shared between the m cases (:func:`triangular_without_each`): O(m)
small factorizations in all, where m separate intersections would stack m - 1 complements each, O(m^2).
"""

from __future__ import annotations

import numpy as np

__all__ = ["complement", "intersection", "intersections_without_each", "triangular_without_each", "difference",
           "INTERSECT_TOL"]

#: a direction lies in every subspace of an intersection when their stacked complements leave less than this of it
#: (round-off; the observability decisions pass their own threshold: a subspace decided with weak directions left
#: out is only known to about that much)
INTERSECT_TOL = 1e-8


def complement(W: np.ndarray) -> np.ndarray:
    """Orthonormal basis of the orthogonal complement of ``span W``.

    Parameters
    ----------
    W : (n, r) array
        Orthonormal columns (r may be 0).

    Returns
    -------
    (n, n - r) array
        Orthonormal basis of ``(span W)^⊥`` (the identity when ``r = 0``).

    Examples
    --------
    >>> import numpy as np
    >>> Q = complement(np.array([[1.0], [0.0], [0.0]]))
    >>> Q.shape, np.round(np.abs(Q[0]), 12).tolist()
    ((3, 2), [0.0, 0.0])
    """
    n, r = W.shape
    if r == 0:
        return np.eye(n)
    # numpy's QR (LAPACK dgeqrf + dorgqr, as scipy.linalg.qr): an agent process then needs no scipy
    Qfull, _ = np.linalg.qr(W, mode="complete")
    return Qfull[:, r:]


def intersection(Vs, n: int, *, tol: float = INTERSECT_TOL) -> np.ndarray:
    """Orthonormal basis of ``span V_1 ∩ ... ∩ span V_m`` (each ``V_i`` orthonormal, n rows; none: everything): the
    right singular vectors of the stacked orthogonal complements ``[Q_1; ...; Q_m]`` whose singular value is at most
    ``tol`` (the directions within that angle of every ``V_i``).

    Parameters
    ----------
    Vs : iterable of (n, r_i) arrays
        The subspaces' orthonormal bases.
    n : int
        State dimension.
    tol : float, default INTERSECT_TOL
        Largest singular value that counts as zero.

    Returns
    -------
    (n, w) array
        Orthonormal basis of the intersection (w may be 0).

    Examples
    --------
    >>> import numpy as np
    >>> I = np.eye(3)
    >>> W = intersection([I[:, :2], I[:, 1:]], 3)
    >>> np.round(np.abs(W), 12).ravel().tolist()
    [0.0, 1.0, 0.0]
    """
    Vs = list(Vs)
    if not Vs:
        return np.eye(n)
    return _near_null(np.vstack([complement(V).T for V in Vs]), n, tol)


def intersections_without_each(Vs, n: int, *, tol: float = INTERSECT_TOL) -> list:
    """``[intersection(Vs without V_k) for k]``, to round-off, in O(m) factorizations: the singular values and right
    singular vectors of the stacked complements without ``Q_k`` are those of its triangular factor
    (:func:`triangular_without_each`), ``n`` columns at most ``n`` rows, so the same test ``s <= tol`` decides.
    The bases may differ from :func:`intersection`'s by a rotation within the subspace.

    Parameters
    ----------
    Vs : sequence of (n, r_i) arrays
        The m subspaces' orthonormal bases.
    n : int
        State dimension.
    tol : float, default INTERSECT_TOL
        As for :func:`intersection`.

    Returns
    -------
    list of (n, w_k) arrays
        One basis per left-out ``k``, in the order of ``Vs``.
    """
    return [_near_null(R, n, tol) for R in triangular_without_each([complement(V).T for V in Vs], n)]


def triangular_without_each(blocks, n: int) -> list:
    """``[R_k for k]``: a triangular factor of the blocks (each with ``n`` columns) stacked without block ``k``, so
    ``R_k' R_k = sum_{j != k} B_j' B_j`` and ``R_k`` has the singular values, right singular vectors and 2-norm of
    that stack (``[B_j]_{j != k} = U R_k``, ``U`` with orthonormal columns), to round-off.

    From prefix and suffix factors: ``F_k`` of ``B_1 .. B_k`` and ``G_k`` of ``B_k .. B_m``, each one QR of at most
    ``n`` rows more than the last; then ``R_k`` is the factor of ``[F_{k-1}; G_{k+1}]`` (at most ``2n`` rows).  QR is
    backward stable, so ``R_k`` is the exact factor of a stack within ``eps`` of the blocks' norm of the true one:
    its small singular values are as accurate as an SVD of the whole stack would give.  3m factorizations in all.

    Parameters
    ----------
    blocks : sequence of array_like
        The m blocks ``B_j``, each reshaped to ``n`` columns.
    n : int
        Number of columns.

    Returns
    -------
    list of (r_k, n) arrays
        ``R_k`` for each k, ``r_k <= n`` rows (0 when the other blocks have none).
    """
    blocks = [np.asarray(B, dtype=float).reshape(-1, n) for B in blocks]
    empty = np.zeros((0, n))

    def grow(F: np.ndarray, B: np.ndarray) -> np.ndarray:
        if B.shape[0] == 0:
            return F
        return np.linalg.qr(np.vstack([F, B]), mode="r")

    pre, suf = [empty], [empty]
    for B in blocks:
        pre.append(grow(pre[-1], B))
    for B in reversed(blocks):
        suf.append(grow(suf[-1], B))
    suf.reverse()  # suf[k]: the factor of blocks k .. m-1 (suf[m]: none)
    m = len(blocks)
    return [grow(pre[k], suf[k + 1]) for k in range(m)]


def _near_null(Q: np.ndarray, n: int, tol: float) -> np.ndarray:
    """The right singular vectors of ``Q`` (``n`` columns) whose singular value is at most ``tol`` (those past its
    rows: singular value 0); every direction when ``Q`` has no rows."""
    if Q.shape[0] == 0:
        return np.eye(n)
    _, s, Vt = np.linalg.svd(Q, full_matrices=True)
    s = np.concatenate([s, np.zeros(n - len(s))])
    return Vt[s <= tol].T.copy()


def difference(V: np.ndarray, W: np.ndarray) -> np.ndarray:
    """Orthonormal basis of ``span V ⊖ span W``, the part of ``span V`` orthogonal to ``span W`` (``W ⊆ span V``, both
    orthonormal).

    Parameters
    ----------
    V : (n, v) array
        Orthonormal basis of the larger subspace.
    W : (n, w) array
        Orthonormal basis of a subspace of ``span V``.

    Returns
    -------
    (n, v - w) array
        ``V`` itself when either is empty.
    """
    if W.shape[1] == 0 or V.shape[1] == 0:
        return V
    R = V - W @ (W.T @ V)
    U, _, _ = np.linalg.svd(R, full_matrices=False)
    keep = V.shape[1] - W.shape[1]
    return U[:, :keep].copy() if keep > 0 else np.zeros((V.shape[0], 0))
