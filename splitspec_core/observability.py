"""Observability decomposition of each pair ``(C_i, A)`` (paper, proof of prop. error).

For agent i, ``V_i`` is an orthonormal basis of the unobservable space
``V_i = ker [C_i; C_i A; ...; C_i A^(n-1)]`` (the largest A-invariant
subspace in ``ker C_i``), ``P_i = V_i V_i'`` the orthogonal projection on it,
and ``Q_i`` a full-rank matrix whose kernel is ``V_i``.  We take ``Q_i`` with
orthonormal rows spanning the observable space, so its right inverse is
``Q_i^-1 = Q_i'`` and

* ``Abar_i = Q_i A Q_i'`` solves ``Q_i A = Abar_i Q_i``,
* ``Cbar_i = C_i Q_i'`` solves ``Cbar_i Q_i = C_i``,
* ``A_i = V_i' (A + K_i C_i) V_i = V_i' A V_i`` (eq. QA2, since ``C_i V_i = 0``).

Rank decisions (documented tolerance)
-------------------------------------
The observable space is built as the block Krylov space
``span{C_i', A'C_i', A'^2 C_i', ...}`` with orthogonalisation at every step
(never forming the ill-conditioned powers ``A^k``).  A direction counts when
its singular value exceeds ``rank_tol * ||C_i||_2`` (first block) or
``rank_tol * ||A||_2`` (later blocks, whose vectors have norm up to
``||A||_2``), so the decision is invariant to scaling ``A`` or ``C_i``.
``rank_tol`` defaults to 1e-9 (``design.rank_tol``).  A kept direction whose
relative singular value is ``sigma`` is itself only known to ``~eps / sigma``
(nearly dependent rows of ``C_i``, e.g. two sensors of one oscillator at almost
the same angle), and ``A'`` carries that error out of the span found so far.
So the error ``delta`` of the basis is tracked (``eps / sigma`` for the first
block, ``(delta + eps) / sigma`` for each later one) and later blocks count a
direction only above ``max(rank_tol, 10 delta) * ||A||_2``; for well
conditioned ``C_i`` this is ``rank_tol``.  Joint observability is decided the
same way on the stacked pair ``(C, A)``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .errors import AssumptionError

__all__ = ["Decomposition", "observable_basis", "decompose", "unobservable_directions", "check_joint_observability"]


@dataclass(frozen=True)
class Decomposition:
    """Observability decomposition of ``(C_i, A)``.

    Attributes
    ----------
    V : (n, n_i) array
        Orthonormal basis of the unobservable space: ``V'V = I``, ``C_i V = 0``, ``A V = V A_i``.
    Q : (n - n_i, n) array
        Orthonormal rows with kernel ``span V`` (so ``Q Q' = I``, ``Q V = 0``).
    Abar : (n - n_i, n - n_i) array
        ``Q A Q'``; ``(Cbar, Abar)`` is observable.
    Cbar : (s_i, n - n_i) array
        ``C_i Q'``.
    P : (n, n) array
        ``V V'``, the orthogonal projection on the unobservable space.
    A_un : (n_i, n_i) array
        ``V' A V``, the paper's ``A_i`` (eq. QA2).
    """

    V: np.ndarray
    Q: np.ndarray
    Abar: np.ndarray
    Cbar: np.ndarray
    P: np.ndarray
    A_un: np.ndarray

    @property
    def n_unobservable(self) -> int:
        return self.V.shape[1]

    @property
    def n_observable(self) -> int:
        return self.Q.shape[0]


def observable_basis(A: np.ndarray, C: np.ndarray, *, rank_tol: float = 1e-9) -> np.ndarray:
    """Orthonormal basis (columns) of the observable space of ``(C, A)``.

    Returns
    -------
    W : (n, r) array
        ``W'W = I``; ``span W = range [C; CA; ...]'``, ``r`` the observability index rank.
    """
    n = A.shape[0]
    normC = np.linalg.norm(C, 2) if C.size else 0.0
    if normC == 0.0:
        return np.zeros((n, 0))
    eps = np.finfo(float).eps
    U, s, _ = np.linalg.svd(C.T, full_matrices=False)
    r = int(np.sum(s > rank_tol * normC))
    W = U[:, :r]
    new = W
    noise = eps * normC / s[r - 1] if r else 0.0  # accuracy of the least determined kept direction
    normA = np.linalg.norm(A, 2)
    while W.shape[1] < n and new.shape[1] > 0 and normA > 0:
        X = A.T @ new
        for _ in range(2):  # classical Gram-Schmidt, twice for orthogonality
            X = X - W @ (W.T @ X)
        U, s, _ = np.linalg.svd(X, full_matrices=False)
        r = int(np.sum(s > max(rank_tol, 10.0 * noise) * normA))
        new = U[:, :r]
        if r:  # a new direction inherits the error of those it came from, divided by its own size
            noise = max(noise, (noise + eps) * normA / s[r - 1])
        W = np.hstack([W, new])
    return W


def _complement(W: np.ndarray) -> np.ndarray:
    """Orthonormal basis of the orthogonal complement of ``span W``."""
    n, r = W.shape
    if r == 0:
        return np.eye(n)
    # numpy's QR (LAPACK dgeqrf + dorgqr, as scipy.linalg.qr): an agent process then needs no scipy
    Qfull, _ = np.linalg.qr(W, mode="complete")
    return Qfull[:, r:]


def decompose(A: np.ndarray, C: np.ndarray, *, rank_tol: float = 1e-9) -> Decomposition:
    """Observability decomposition of ``(C, A)``; see the module docstring."""
    W = observable_basis(A, C, rank_tol=rank_tol)
    V = _complement(W)
    Q = W.T.copy()
    return Decomposition(
        V=V, Q=Q, Abar=Q @ A @ Q.T, Cbar=C @ Q.T, P=V @ V.T, A_un=V.T @ A @ V,
    )


def unobservable_directions(A: np.ndarray, Cs, *, rank_tol: float = 1e-9) -> np.ndarray:
    """Orthonormal basis of the jointly unobservable space ``cap_i V_i`` of ``(C, A)``."""
    C = np.vstack(list(Cs))
    return _complement(observable_basis(A, C, rank_tol=rank_tol))


def _direction_text(v: np.ndarray) -> str:
    v = v / v[np.argmax(np.abs(v))]
    v = np.where(np.abs(v) < 5e-4, 0.0, v)
    return "[" + " ".join(f"{x:.3g}" for x in v) + "]"


def check_joint_observability(A: np.ndarray, Cs, *, rank_tol: float = 1e-9, who: str = "every agent") -> None:
    """Raise :class:`AssumptionError` naming an unobservable direction if ``(C, A)`` is not observable."""
    D = unobservable_directions(A, Cs, rank_tol=rank_tol)
    if D.shape[1]:
        raise AssumptionError(
            f"(C, A) is not jointly observable: direction {_direction_text(D[:, 0])} is unobservable to {who}")
