"""The spectral skeleton of ``A``: balanced coordinates and the invariant subspaces of its eigenvalue clusters.

Why the observability decisions need it
---------------------------------------
The unobservable space of ``(C_i, A)`` is A-invariant, so it splits along the spectral subspaces of ``A``:
with ``X_k`` a basis of the invariant subspace of a cluster of eigenvalues (clusters with disjoint
spectra), ``V_i = (+)_k X_k V_ik`` where ``V_ik`` is the unobservable space of the restricted pair
``(C_i X_k, X_k' A X_k)``.  Deciding each cluster on its own keeps the rank decisions local to a time
scale: one Krylov staircase over the whole of a stiff model (eigenvalues from -80 to 0) chains slow
modes through the fast ones, and its graded margins shrink like the product of the steps (8.5e-11 on a
power-system model whose PBH test gives 2.5e-2).  Within a cluster the staircase of
:mod:`splitspec_core.model.observability` runs on the cluster's own scale: the larger of its spread and the
distance the local gain must move it (a spread of round-off, a repeated eigenvalue, has no dynamics to
see through; three modes 5e-4 apart that the gain must move by 0.16 are told apart only by a gain of
order 0.16 / 5e-4, and count as seen only if that is what the margin says).  For a simple eigenvalue the
margin is then ``|C_i x_k| / |C_i|`` with ``x_k`` its unit eigenvector: how much of a unit excursion of
that mode the agent's sensors see (the PBH test ``sigma_min([A - lam I; C])`` of that mode, without
the distance to the other eigenvalues that the PBH value also carries).

Units
-----
A margin measured in the user's coordinates depends on the units of the states (a state in mV instead
of V scales its column of ``C`` by 1000).  The decisions are made in *balanced* coordinates
``x_b = D^-1 x``: ``A_b = D^-1 A D``, ``C_b = C D`` with ``D`` diagonal, chosen so that every state's
row and column norms agree (Osborne's iteration run to convergence, rather than LAPACK's powers of 2,
whose stopping rule leaves a state up to 8 times off the balanced point; :func:`balance` says what it does
with the states that have no balanced point).  Balancing ``D_u^-1 A D_u`` gives the same
balanced matrix whatever the units, so the decisions do not depend on them and the margins change only
by the iteration's tolerance (``tests/unit/test_units.py`` measures it).  Only decisions are made there:
the subspaces are mapped back, and the estimator runs in the user's coordinates.

Clusters
--------
Eigenvalues closer than :data:`CLUSTER_REL` (20 %) of their modulus (or :data:`CLUSTER_ABS` of ``|A_b|``)
are one cluster, complex pairs always together: within a cluster the eigenvectors of nearly equal
eigenvalues are ill-determined but their span is not.  Each cluster's basis is the span of its
eigenvectors (numpy's ``eig``, orthonormalised); when these are nearly dependent (a Jordan block, or
close to one) or their span is not invariant to round-off, the basis comes from the ordered real Schur
form instead (LAPACK ``dtrsen`` through scipy, imported then only: agent processes stay numpy-only for
the usual diagonalisable models).
"""

from __future__ import annotations

from dataclasses import dataclass

import math

import numpy as np

__all__ = ["CLUSTER_REL", "CLUSTER_ABS", "Cluster", "Spectrum", "balance", "clusters", "invariant_subspace", "rescale",
           "spectrum"]

#: eigenvalues closer than this fraction of their modulus are one cluster
CLUSTER_REL = 0.2
#: ... or closer than this fraction of ``|A_b|_2`` (eigenvalues near 0)
CLUSTER_ABS = 1e-8
#: a cluster's eigenvectors count as independent when the smallest singular value of their unit columns is above this
INDEPENDENT = 1e-7
#: and their span as invariant when ``|A_b X - X X' A_b X| <= INVARIANT |A_b|``
INVARIANT = 1e-10
#: balancing stops when no state's scale moves by more than this (relative) in a sweep
BALANCE_TOL = 1e-6
#: ... or after this many sweeps (Osborne's iteration converges linearly; some models have no balanced point in a
#: few directions and drift along them slowly: a bound, not a target)
BALANCE_SWEEPS = 400
#: over-relaxation of each step (1: Osborne's; measured on the power-system models, 1.8 needs 3 to 7 times fewer sweeps)
BALANCE_OMEGA = 1.8


@dataclass(frozen=True)
class Cluster:
    """One cluster of eigenvalues: ``X`` (n, p) orthonormal basis of its invariant subspace (balanced
    coordinates), ``A`` (p, p) ``= X' A_b X`` (``A_b X = X A`` to round-off), ``eigs`` its eigenvalues."""

    X: np.ndarray
    A: np.ndarray
    eigs: np.ndarray


@dataclass(frozen=True)
class Spectrum:
    """Balanced coordinates ``x_b = x / d`` and the clusters of ``A_b = D^-1 A D`` (module docstring)."""

    d: np.ndarray
    A_b: np.ndarray
    clusters: tuple

    def to_user(self, Xb: np.ndarray) -> np.ndarray:
        """An orthonormal basis, in the user's coordinates, of the subspace spanned by ``Xb`` (balanced).

        Parameters
        ----------
        Xb : (n, p) array
            Basis in balanced coordinates ``x_b = x / d``.

        Returns
        -------
        (n, p) array
        """
        return rescale(Xb, self.d, None)

    def to_balanced(self, X: np.ndarray) -> np.ndarray:
        """An orthonormal basis, in balanced coordinates, of the subspace spanned by ``X`` (user's).

        Parameters
        ----------
        X : (n, p) array
            Basis in the user's coordinates.

        Returns
        -------
        (n, p) array
        """
        return rescale(X, None, self.d)


def rescale(X: np.ndarray, frm: np.ndarray | None, to: np.ndarray | None) -> np.ndarray:
    """An orthonormal basis, in the coordinates ``x = diag(to) x_to``, of the subspace spanned by ``X`` given in the
    coordinates ``x = diag(frm) x_frm`` (None: the user's own, ``diag(1)``).

    Parameters
    ----------
    X : (n, p) array
        Basis in the ``frm`` coordinates (need not be orthonormal).
    frm, to : (n,) array or None
        Scalings of the coordinates mapped from and to.

    Returns
    -------
    (n, p) array
        Orthonormal (QR of ``diag(frm / to) X``); ``(n, 0)`` when ``p = 0``.
    """
    if X.shape[1] == 0:
        return np.zeros((X.shape[0], 0))
    f = np.ones(X.shape[0]) if frm is None else frm
    t = np.ones(X.shape[0]) if to is None else to
    Q, _ = np.linalg.qr((f / t)[:, None] * X)
    return Q


def balance(A: np.ndarray, C: np.ndarray | None = None, *, tol: float = BALANCE_TOL) -> np.ndarray:
    """Scaling ``d`` with ``D^-1 A D`` balanced (module docstring).

    Osborne's iteration in the 2-norm (over-relaxed by :data:`BALANCE_OMEGA`): state k is scaled so that its
    off-diagonal column and row of ``A`` have the same norm, sweep after sweep until no state moves by more than
    ``tol`` (relative) or :data:`BALANCE_SWEEPS` have passed.  Where the balanced point exists it is unique up to
    a common factor (which no decision sees), so ``D_u^-1 A D_u`` in any units balances to the same matrix.  The
    states it leaves undetermined get a rule that does not depend on their units either: a state with only a row
    or only a column (nothing depends on it, as a filter whose output nobody uses, or nothing drives it) is scaled
    so that that side has the median norm of the balanced states' rows; a state with neither (decoupled) so
    that its column of ``C`` (all agents' rows) has the median norm of the measured states' columns.  ``C`` is
    not balanced against ``A``: a measured state of an oscillator has no balanced point with its measurement
    counted in its column (it shrinks without end), and the measurement's weight is the decisions' business.

    Parameters
    ----------
    A : (n, n) array_like
        State matrix.
    C : (p, n) array_like, optional
        All agents' output rows stacked; used only to scale decoupled states.
    tol : float, default BALANCE_TOL
        Relative move below which the iteration stops.

    Returns
    -------
    (n,) float array
        ``d``, positive: ``A_b = D^-1 A D`` with ``D = diag(d)``.

    Examples
    --------
    >>> import numpy as np
    >>> d = balance(np.array([[0.0, 100.0], [1.0, 0.0]]))
    >>> float(np.round(d[1] / d[0], 6))
    0.1
    """
    A = np.asarray(A, dtype=float)
    n = A.shape[0]
    B = A * A
    np.fill_diagonal(B, 0.0)  # B_ik = a_ik^2 d_k^2 / d_i^2 as d changes
    d = np.ones(n)
    cols, rows = B.sum(axis=0), B.sum(axis=1)
    both = (cols > 0) & (rows > 0)
    for _ in range(BALANCE_SWEEPS):
        moved = 0.0
        for k in np.flatnonzero(both):
            f2 = (B[k, :].sum() / B[:, k].sum()) ** (0.5 * BALANCE_OMEGA)  # column k grows by f2, row k shrinks
            moved = max(moved, abs(f2 - 1.0))
            B[:, k] *= f2
            B[k, :] /= f2
            d[k] *= math.sqrt(f2)
        if moved <= tol:
            break
    target = float(np.median(np.sqrt(B.sum(axis=1)[both]))) if both.any() else 1.0
    for k in np.flatnonzero(~both & ((cols > 0) | (rows > 0))):
        r, c = math.sqrt(B[k, :].sum()), math.sqrt(B[:, k].sum())
        f = r / target if r > 0 else target / c  # row k shrinks by f, or column k grows by f
        B[:, k] *= f * f
        B[k, :] /= f * f
        d[k] *= f
    Ccols = np.zeros(n) if C is None or np.size(C) == 0 else np.linalg.norm(np.asarray(C, dtype=float), axis=0)
    alone = np.flatnonzero((cols == 0) & (rows == 0) & (Ccols > 0))
    coupled = (Ccols > 0) & ~((cols == 0) & (rows == 0))
    if alone.size and coupled.any():
        d[alone] = float(np.median(Ccols[coupled] * d[coupled])) / Ccols[alone]
    return d


def _clusters_of(w: np.ndarray, scale: float, rel: float) -> list:
    """Indices of ``w`` grouped: conjugate pairs together, single linkage on ``|w_a - w_b| <= rel max|w| + abs``."""
    n = len(w)
    reps = np.where(w.imag < 0, np.conj(w), w)  # a pair is one point of the upper half plane
    parent = np.arange(n)

    def root(a):
        while parent[a] != a:
            parent[a] = parent[parent[a]]
            a = parent[a]
        return a

    tol_abs = CLUSTER_ABS * scale
    for a in range(n):
        near = np.abs(reps - reps[a]) <= rel * np.maximum(np.abs(reps), abs(reps[a])) + tol_abs
        for b in np.flatnonzero(near):
            ra, rb = root(a), root(int(b))
            if ra != rb:
                parent[max(ra, rb)] = min(ra, rb)
    groups: dict = {}
    for a in range(n):
        groups.setdefault(root(a), []).append(a)
    return [np.array(g) for g in groups.values()]


def _eigvec_basis(Ab: np.ndarray, X: np.ndarray, idx: np.ndarray, w: np.ndarray) -> np.ndarray | None:
    """The cluster's invariant subspace from its eigenvectors (real, orthonormal), or None when they are
    nearly dependent or their span is not invariant to round-off (then: the Schur form)."""
    cols = []
    for k in idx:
        if w[k].imag > 0:
            cols += [X[:, k].real, X[:, k].imag]
        elif w[k].imag == 0:
            cols.append(X[:, k].real)
    B = np.column_stack(cols)
    if B.shape[1] != len(idx):  # an eigenvalue of the pair's lower half without its upper half: numpy's order
        return None
    B = B / np.linalg.norm(B, axis=0)
    U, s, _ = np.linalg.svd(B, full_matrices=False)
    if s[-1] < INDEPENDENT:
        return None
    R = Ab @ U
    if np.linalg.norm(R - U @ (U.T @ R), 2) > INVARIANT * max(np.linalg.norm(Ab, 2), 1e-300):
        return None
    return U


def _schur_basis(T: np.ndarray, Z: np.ndarray, w_schur: np.ndarray, chosen: np.ndarray) -> np.ndarray:
    """The invariant subspace of the eigenvalues ``chosen`` (of ``w_schur``, the Schur form's diagonal) by
    reordering the real Schur form (LAPACK ``dtrsen``)."""
    from scipy.linalg.lapack import dtrsen

    _, Zs, _, _, p, _, _, info = dtrsen(chosen.astype(np.int32), T, Z, job="N")
    if info != 0:  # pragma: no cover - dtrsen fails only when two eigenvalues are too close to swap
        raise np.linalg.LinAlgError(f"reordering the Schur form failed (dtrsen info {info})")
    return Zs[:, :p]


def clusters(M: np.ndarray, *, rel: float = CLUSTER_REL) -> list:
    """``[Cluster]`` of ``M`` in its own coordinates: the clusters of its eigenvalues with an orthonormal basis of each
    one's invariant subspace (module docstring: eigenvectors, or the ordered Schur form when they are nearly
    dependent).

    Parameters
    ----------
    M : (n, n) array_like
        The matrix (``A_b`` for :func:`spectrum`).
    rel : float, default CLUSTER_REL
        Eigenvalues closer than this fraction of their modulus share a cluster.

    Returns
    -------
    list of Cluster
        Empty when ``n = 0``.
    """
    M = np.asarray(M, dtype=float)
    n = M.shape[0]
    if n == 0:
        return []
    w, X = np.linalg.eig(M)
    groups = _clusters_of(w, float(np.linalg.norm(M, 2)), rel)
    schur = None
    out = []
    for idx in groups:
        U = _eigvec_basis(M, X, idx, w)
        if U is None:
            if schur is None:
                import scipy.linalg as sla

                T, Z = sla.schur(M, output="real")
                schur = (T, Z, _schur_eigs(T))
            T, Z, ws = schur
            chosen = np.zeros(n, dtype=bool)
            for z in w[idx]:  # each eigenvalue of the cluster claims its nearest one on the Schur diagonal
                free = np.flatnonzero(~chosen)
                chosen[free[np.argmin(np.abs(ws[free] - z))]] = True
            U = _schur_basis(T, Z, ws, chosen)
        out.append(Cluster(X=U, A=U.T @ M @ U, eigs=w[idx]))
    return out


def invariant_subspace(M: np.ndarray, keep) -> np.ndarray:
    """Orthonormal basis of the invariant subspace of ``M`` for the clusters whose eigenvalues all satisfy ``keep``
    (a predicate on an array of eigenvalues, true where kept); a cluster straddling it is left out whole.

    Parameters
    ----------
    M : (n, n) array_like
        The matrix.
    keep : callable
        ``keep(eigs) -> bool array``.

    Returns
    -------
    (n, p) array
        ``(n, 0)`` when no cluster is kept.

    Examples
    --------
    >>> import numpy as np
    >>> U = invariant_subspace(np.diag([-1.0, 2.0]), lambda w: w.real < 0)
    >>> np.abs(U).round(12).tolist()
    [[1.0], [0.0]]
    """
    M = np.asarray(M, dtype=float)
    parts = [c.X for c in clusters(M) if np.all(keep(c.eigs))]
    if not parts:
        return np.zeros((M.shape[0], 0))
    U, _ = np.linalg.qr(np.hstack(parts))
    return U


def spectrum(A: np.ndarray, C: np.ndarray | None = None, *, rel: float = CLUSTER_REL) -> Spectrum:
    """The spectral skeleton of ``A`` (module docstring); ``C`` (all agents' rows stacked) enters the balancing.

    Parameters
    ----------
    A : (n, n) array_like
        State matrix.
    C : (p, n) array_like, optional
        All agents' output rows stacked (for :func:`balance`).
    rel : float, default CLUSTER_REL
        Cluster width (:func:`clusters`).

    Returns
    -------
    Spectrum
        ``d``, ``A_b = D^-1 A D`` and the clusters of ``A_b``.

    Examples
    --------
    >>> import numpy as np
    >>> sp = spectrum(np.array([[-1.0, 1.0], [0.0, -1.05]]))
    >>> len(sp.clusters), sp.clusters[0].X.shape
    (1, (2, 2))
    """
    A = np.asarray(A, dtype=float)
    d = balance(A, C)
    Ab = A / d[:, None] * d[None, :]
    return Spectrum(d=d, A_b=Ab, clusters=tuple(clusters(Ab, rel=rel)))


def _schur_eigs(T: np.ndarray) -> np.ndarray:
    """The eigenvalues on the diagonal of a real Schur form, in position (a 2x2 block gives its pair)."""
    n = T.shape[0]
    out = np.zeros(n, dtype=complex)
    k = 0
    while k < n:
        if k + 1 < n and T[k + 1, k] != 0.0:
            out[k:k + 2] = np.linalg.eigvals(T[k:k + 2, k:k + 2])
            k += 2
        else:
            out[k] = T[k, k]
            k += 1
    return out
