"""Orthonormal bases of subspaces: complement, intersection, difference (numpy only: agent processes use them)."""

from __future__ import annotations

import numpy as np

__all__ = ["complement", "intersection", "difference", "INTERSECT_TOL"]

#: a direction lies in every subspace of an intersection when their stacked complements leave less than this of it
#: (round-off; the observability decisions pass their own threshold: a subspace decided with weak directions left
#: out is only known to about that much)
INTERSECT_TOL = 1e-8


def complement(W: np.ndarray) -> np.ndarray:
    """Orthonormal basis of the orthogonal complement of ``span W``."""
    n, r = W.shape
    if r == 0:
        return np.eye(n)
    # numpy's QR (LAPACK dgeqrf + dorgqr, as scipy.linalg.qr): an agent process then needs no scipy
    Qfull, _ = np.linalg.qr(W, mode="complete")
    return Qfull[:, r:]


def intersection(Vs, n: int, *, tol: float = INTERSECT_TOL) -> np.ndarray:
    """Orthonormal basis of ``span V_1 ∩ ... ∩ span V_m`` (each ``V_i`` orthonormal, n rows; none: everything): the
    right singular vectors of the stacked orthogonal complements ``[Q_1; ...; Q_m]`` whose singular value is at most
    ``tol`` (the directions within that angle of every ``V_i``)."""
    Vs = list(Vs)
    if not Vs:
        return np.eye(n)
    Q = np.vstack([complement(V).T for V in Vs])
    if Q.shape[0] == 0:
        return np.eye(n)
    _, s, Vt = np.linalg.svd(Q, full_matrices=True)
    s = np.concatenate([s, np.zeros(n - len(s))])
    return Vt[s <= tol].T.copy()


def difference(V: np.ndarray, W: np.ndarray) -> np.ndarray:
    """Orthonormal basis of ``span V ⊖ span W``, the part of ``span V`` orthogonal to ``span W`` (``W ⊆ span V``, both
    orthonormal)."""
    if W.shape[1] == 0 or V.shape[1] == 0:
        return V
    R = V - W @ (W.T @ V)
    U, _, _ = np.linalg.svd(R, full_matrices=False)
    keep = V.shape[1] - W.shape[1]
    return U[:, :keep].copy() if keep > 0 else np.zeros((V.shape[0], 0))
