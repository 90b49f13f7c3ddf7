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

Rank decisions: what an agent "sees" (``design.rank_tol``)
----------------------------------------------------------
The observable space is built as the block Krylov space
``span{C_i', A'C_i', A'^2 C_i', ...}`` with orthogonalisation at every step
(never forming the ill-conditioned powers ``A^k``).  Every direction found
carries a *graded margin*: its singular value when the staircase is run on
the scaled matrices ``C_i / ||C_i||_2`` and ``(A - aI) / ||A - aI||_2``
(``a = trace(A) / n``) with each new block weighted by the margins of the
block it came from.  The margin of a direction is thus the singular value of
the (scaled) observability matrix along it: how far the pair is from one in
which that direction is unobservable.  A model perturbed by ``delta``
(relative; a model rounded to d decimals has ``delta ~ 10^-d``) moves every
margin by about ``delta``, so a direction whose margin is of the order of the
model's accuracy cannot be told from an unobservable one, and seeing it alone
would take a gain of order ``1 / margin``.  Without the grading (each block
normalised on its own, as before) a perturbation of a direction reached
through weak earlier ones looks large: a model rounded to 6 decimals then
showed margins up to 3e-3 where it has none.

A direction counts as seen by agent i when its graded margin is at least
``design.rank_tol``, default :data:`DEFAULT_RANK_TOL` = 1e-3 ("auto"): a model
known to about 4 significant digits.  Below it the direction goes to ``V_i``
and consensus recovers it from the neighbours, which is safe as long as the
network still jointly observes it with a margin above the same threshold
(joint observability is decided by margins alone on the stacked pair
``(C, A)``).  One exception keeps each agent's split honest: a weak
direction reached in a full step from the directions it came from (its
margin over theirs, its *step*, at least :data:`SPLIT_STEP` = 0.05) is still
counted, because leaving it out would leave ``V_i`` that far from invariant
(a long chain of moderate steps, e.g. 8 states seen through one output, has
small graded margins without a single small step).  What rounding adds
enters with a small step (its size over the margin of what it leaks from),
so it is left out.  Measured with ``benchmarks/bench_rounded.py --splits 400``
(random structured systems, n = 4..10, m = 3..8, continuous and discrete):
their entries rounded to 6 decimals give the exact system's split in 400 of
400, rounded to 4 decimals in 399 of 400; the exact systems' own splits
change in 3 of 400 (weak directions left to consensus, split residual at
most 0.037), and none becomes only weakly jointly observable.  The staircase
explores chain by chain, and a weak direction kept early can take the place of
a subspace a strong chain reaches later; what it leaves is checked against the
scaled observability matrix itself, and what that sees with a margin at least
the threshold is counted and explored from (before this check, 5 of the 400
exact splits changed, one agent of two sensors 5e-8 apart missed a direction it
sees with margin 0.1).  A perturbation
within ten times of the threshold can pass for a full step of a weak chain
(its size over the margin of the parent it leaks from): over 1000 random
systems, continuous and discrete (10,098 agents), a relative perturbation of
1e-4 changed 19 agents' splits and rounding to 4 decimals 8; 1e-5 and 5
decimals and below changed none.  Such an agent then sees a direction with a
margin of about the perturbation, and the design's conditioning warning names
it and ``design.rank_tol``.  A threshold on
margins is invariant to scaling ``A`` or ``C_i`` and to shifting ``A`` by a
multiple of the identity.  Margins below :data:`ROUND_OFF` (1e-12) are
round-off whatever ``rank_tol`` says; a direction known only as well as its
parents' basis (nearly dependent rows of ``C_i``) must also stand well above
the leak of that inexact basis.

When a direction with a margin above round-off is left out (``Decomposition.weak``),
``V_i`` is only nearly A-invariant and ``C_i V_i`` only nearly zero: the
split of the error dynamics (prop. error) then holds up to ``split_residual``,
and the designer checks the rate on the full error matrix as well.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np

from .gain_target import GainTarget
from .modal import Spectrum, rescale
from .subspaces import complement as _complement
from .subspaces import difference, intersection
from .modal import spectrum as modal_spectrum

__all__ = ["DEFAULT_RANK_TOL", "ROUND_OFF", "SPLIT_STEP", "Staircase", "Decomposition", "threshold_of",
           "observability_staircase", "decompose", "unobservable_directions"]


#: ``design.rank_tol: auto``: the smallest graded margin of a direction an agent counts as seen
DEFAULT_RANK_TOL = 1e-3
#: graded margins below this are round-off, whatever ``design.rank_tol`` says
ROUND_OFF = 1e-12
#: a direction below the threshold is still counted when its step from the directions it came from is at least
#: this: leaving it out would break the split by as much (``split_residual``)
SPLIT_STEP = 0.05


@dataclass(frozen=True)
class Staircase:
    """The observability staircase of ``(C, A)`` with its graded margins (see the module docstring).

    Attributes
    ----------
    W : (n, r) array
        Orthonormal basis of the observable space as decided: ``W'W = I``.
    margins : (r,) array
        Graded margin of each column of ``W`` (in the order found).
    weak : float
        The largest graded margin left out above :data:`ROUND_OFF` (0.0 if none): a direction
        observable in exact arithmetic but not counted.
    weak_direction : (n,) array or None
        That direction (unit norm).
    threshold : float
        The threshold applied (``rank_tol``, or :data:`DEFAULT_RANK_TOL`).
    """

    W: np.ndarray
    margins: np.ndarray
    weak: float
    weak_direction: np.ndarray | None
    threshold: float

    @property
    def margin(self) -> float | None:
        """The smallest graded margin counted (None when nothing is observable)."""
        return float(self.margins.min()) if self.margins.size else None


def threshold_of(rank_tol: float | None) -> float:
    """The margin threshold for ``design.rank_tol`` (None: auto).

    Parameters
    ----------
    rank_tol : float or None
        ``design.rank_tol``.

    Returns
    -------
    float
        :data:`DEFAULT_RANK_TOL` for None, else ``rank_tol`` but at least :data:`ROUND_OFF`.
    """
    return DEFAULT_RANK_TOL if rank_tol is None else max(float(rank_tol), ROUND_OFF)


def observability_staircase(A: np.ndarray, C: np.ndarray, *, rank_tol: float | None = None,
                            keep_full_steps: bool = True, c_scale: float | None = None,
                            a_scale: float | None = None, move: float = 0.0) -> Staircase:
    """Observable space of ``(C, A)`` by the graded staircase (see the module docstring).

    Parameters
    ----------
    A : (n, n) array
        State matrix (a cluster's ``A_k`` when called per cluster).
    C : (p, n) array
        Output rows.
    rank_tol : float, optional
        ``design.rank_tol`` (None: :data:`DEFAULT_RANK_TOL`).
    keep_full_steps : bool, default True
        Count a weak direction reached in a full step (:data:`SPLIT_STEP`), which an
        agent's split needs; the joint decision has no split to keep and counts margins alone.
    c_scale : float, optional
        Measure ``C`` against this norm instead of its own (a cluster's restriction ``C X_k`` against
        the whole ``|C|``: a mode the sensors see weakly must not look strong because it is alone in its cluster).
    a_scale : float, optional
        The norm of the whole matrix a cluster's ``A`` was cut from.  The cluster's own spread
        ``|A - aI|`` sets the scale of its images; a spread below :data:`ROUND_OFF` of ``a_scale`` is round-off (a
        repeated eigenvalue: five integrators of a power-system model came out ``1e-17`` apart) and has no images,
        and images are known only to ``eps a_scale / spread`` of their weight (a round-off spread scaled up is not a
        margin).
    move : float, default 0.0
        How far the local gain must move the cluster's modes
        (:class:`splitspec_core.model.gain_target.GainTarget`): the images are measured against the larger of the spread
        and that distance.  A direction the staircase reaches
        in ``j`` steps then has a margin of about the distance over the gain that moves it (the gain grows like
        ``move^j / |C (A - aI)^j v|``): three governor modes ``5e-4`` apart that the gain must move by ``0.16`` are
        not seen by a sensor of one of them, however clean their spread looks against itself.

    Returns
    -------
    Staircase
        The observable space ``W`` (n, r) with its graded margins and the largest margin left out.

    Examples
    --------
    >>> import numpy as np
    >>> st = observability_staircase(np.array([[0.0, 1.0], [-1.0, 0.0]]), np.array([[1.0, 0.0]]))
    >>> st.W.shape, round(st.margin, 3)
    ((2, 2), 1.0)
    """
    step = SPLIT_STEP if keep_full_steps else math.inf
    n = A.shape[0]
    threshold = threshold_of(rank_tol)
    normC = np.linalg.norm(C, 2) if C.size else 0.0
    if c_scale is not None:
        if normC <= ROUND_OFF * c_scale:  # nothing but round-off of the restriction
            normC = 0.0
        else:
            normC = c_scale
    if normC == 0.0:
        return Staircase(np.zeros((n, 0)), np.zeros(0), 0.0, None, threshold)
    # the Krylov space of A' is that of (A - aI)': a shift changes no direction, only the scale
    scale = float(np.linalg.norm(A - (np.trace(A) / n) * np.eye(n), 2))
    if a_scale is not None and scale <= ROUND_OFF * a_scale:
        scale = 0.0
    if scale > 0.0:
        scale = max(scale, move)
    weak, weak_dir = 0.0, None

    eps = np.finfo(float).eps
    # the images' round-off, relative to their weight (0 for a matrix measured against itself)
    blur = 16.0 * eps * a_scale / scale if a_scale is not None and scale > 0 else 0.0

    def split(U, s, ratio, floor):
        """Keep what is above the floor and either strong (margin >= threshold) or a full step from its parents."""
        nonlocal weak, weak_dir
        real = s > max(ROUND_OFF, floor)
        keep = real & ((s >= threshold) | (ratio >= step))
        left = np.flatnonzero(real & ~keep)
        if left.size and s[left[0]] > weak:  # s is sorted: the first one left out is the largest
            weak, weak_dir = float(s[left[0]]), U[:, left[0]].copy()
        return keep

    U, s, _ = np.linalg.svd(C.T / normC, full_matrices=False)
    keep = split(U, s, s, 0.0)  # C's own directions: their step is their margin
    new, mu = U[:, keep], s[keep]
    W, margins = new, [mu]
    # a kept direction of margin mu is itself known only to ~eps / mu (nearly dependent rows of C_i: two
    # sensors of one quantity), and projecting the next block's strong columns (weight up to max mu) against
    # that inexact basis leaks ~noise * max mu out of the span found so far: a direction counts only well
    # above that leak (for well-determined directions it is ~1e-13, far below any threshold)
    noise = eps / mu.min() if mu.size else 0.0
    # the shifted, scaled A as a matrix, for _missed's observability matrix; the staircase below keeps forming its
    # images as (A' X - a X) / scale, the order of operations its rank decisions were measured with
    S = (A - (np.trace(A) / n) * np.eye(n)) / scale if scale > 0 else None
    while True:
        while W.shape[1] < n and new.shape[1] > 0 and scale > 0:
            # the next block: images of the last one under A' (shifted and scaled), each weighted by its margin,
            # orthogonalised against what is known (classical Gram-Schmidt, twice)
            X = (A.T @ (new * mu) - (np.trace(A) / n) * (new * mu)) / scale
            for _ in range(2):
                X = X - W @ (W.T @ X)
            U, s, Vt = np.linalg.svd(X, full_matrices=False)
            leak = noise * float(mu.max())
            parents = np.linalg.norm(Vt * mu[None, :], axis=1)  # the weight of the directions each one came from
            ratio = s / np.maximum(parents, 1e-300)  # its step from them
            keep = split(U, s, ratio, max(10.0 * leak, blur * float(mu.max())))
            new, mu = U[:, keep], s[keep]
            if mu.size:
                # a new direction inherits the error of those it came from, divided by its step from them (a weak
                # chain is as well determined as its own steps are)
                noise = max(noise, float(np.max((noise + eps) / ratio[keep])))
            W = np.hstack([W, new])
            margins.append(mu)
        new, mu = _missed(C / normC, S, W, threshold, max(ROUND_OFF, 10.0 * noise, blur))
        if not mu.size:
            break
        W = np.hstack([W, new])  # and their images, in the loop above
        margins.append(mu)
    return Staircase(W, np.concatenate(margins), weak, weak_dir, threshold)


@dataclass(frozen=True)
class Decomposition:
    """Observability decomposition of ``(C_i, A)``.

    Attributes
    ----------
    V : (n, n_i) array
        Orthonormal basis of the unobservable space: ``V'V = I``, ``C_i V = 0``, ``A V = V A_i``
        (exactly when nothing observable was left out, else up to ``split_residual``).
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
    margin : float or None
        The smallest graded margin of a direction counted as seen (``observability_margin``).
    weak : float
        The largest graded margin of a direction left out (0.0: none above round-off).
    split_residual : float
        ``max(||Q A V||_2 / ||A - aI||_2, ||C_i V||_2 / ||C_i||_2)`` in balanced coordinates: how far ``V`` is
        from an exact unobservable space (round-off when ``weak`` is 0).
    unobserved : int
        The dimension of the directions no agent sees, taken out of ``V`` (:meth:`without`); 0: none.
    weak_direction : (n,) array or None
        The direction of ``weak`` (unit, the user's coordinates); None when nothing was left out.
    """

    V: np.ndarray
    Q: np.ndarray
    Abar: np.ndarray
    Cbar: np.ndarray
    P: np.ndarray
    A_un: np.ndarray
    margin: float | None = None
    weak: float = 0.0
    split_residual: float = 0.0
    unobserved: int = 0
    weak_direction: np.ndarray | None = field(default=None, repr=False, compare=False)

    @property
    def n_unobservable(self) -> int:
        """int: ``n_i``, the dimension of the unobservable space (columns of ``V``)."""
        return self.V.shape[1]

    def without(self, W: np.ndarray, A: np.ndarray) -> "Decomposition":
        """The estimator's decomposition when the directions ``W`` (orthonormal, in ``span V``) go unobserved by
        every agent: ``V`` becomes ``V ⊖ W`` (:mod:`splitspec_core.model.detectability`); ``Q``, ``Abar``, ``Cbar`` and
        the margins are the agent's own, unchanged.

        Parameters
        ----------
        W : (n, w) array
            Orthonormal basis of the jointly unobserved directions.
        A : (n, n) array_like
            State matrix, in the decomposition's coordinates (for ``A_un``).

        Returns
        -------
        Decomposition
            ``self`` when ``W`` is empty; else with ``V``, ``P``, ``A_un`` of ``V ⊖ W`` and ``unobserved = w``.
        """
        if W.shape[1] == 0:
            return self
        V = difference(self.V, W)
        return replace(self, V=V, P=V @ V.T, A_un=V.T @ np.asarray(A) @ V, unobserved=int(W.shape[1]))

    @property
    def n_observable(self) -> int:
        """int: ``n - n_i``, the dimension of the observable space (rows of ``Q``)."""
        return self.Q.shape[0]


def _missed(Cs: np.ndarray, S: np.ndarray | None, W: np.ndarray, threshold: float, floor: float) -> tuple:
    """Directions outside ``span W`` that the scaled observability matrix ``[Cs; Cs S; ...; Cs S^(n-1)]`` sees with a
    margin of at least ``threshold`` (and above ``floor``): ``(directions, margins)``.

    The staircase explores the Krylov space chain by chain, and a weak direction kept early can take the place of a
    subspace a strong chain reaches later: two sensors of one quantity (rows 5e-8 apart) kept x1 - x3 with margin
    4e-8 at the first step, so the strong chain's image there was projected out and the direction it reveals two
    steps on was left to the weak chain's tiny margin, and out.  What is left is checked against its margin as the
    module defines it (the singular values of that matrix on it); the staircase then goes on from what this finds.
    """
    n = W.shape[0]
    if S is None or W.shape[1] >= n:
        return np.zeros((n, 0)), np.zeros(0)
    V = _complement(W)
    R, blocks = Cs, []
    for _ in range(n):
        blocks.append(R @ V)
        R = R @ S
    _, s, Vt = np.linalg.svd(np.vstack(blocks), full_matrices=False)
    seen = (s >= threshold) & (s > floor)
    return V @ Vt[seen].T, s[seen]


def split_residual_of(A: np.ndarray, C: np.ndarray, Q: np.ndarray, V: np.ndarray) -> float:
    """How far ``V`` is from an exact unobservable space of ``(C, A)`` (``Decomposition.split_residual``).

    Parameters
    ----------
    A : (n, n) array
        State matrix (balanced coordinates, as the decisions use).
    C : (p, n) array
        Output rows, or any matrix with their 2-norm on every subspace (a triangular factor).
    Q : (n - k, n) array
        Orthonormal rows with kernel ``span V``.
    V : (n, k) array
        Orthonormal basis of the candidate unobservable space.

    Returns
    -------
    float
        ``max(||Q A V||_2 / ||A - aI||_2, ||C V||_2 / ||C||_2)``, ``a = trace(A) / n``; 0.0 when ``V`` or ``Q``
        is empty (a zero norm leaves its term 0).
    """
    if not V.shape[1] or not Q.shape[0]:
        return 0.0
    n = A.shape[0]
    scale = float(np.linalg.norm(A - (np.trace(A) / n) * np.eye(n), 2))
    normC = float(np.linalg.norm(C, 2))
    inv = float(np.linalg.norm(Q @ A @ V, 2)) / scale if scale > 0 else 0.0
    out = float(np.linalg.norm(C @ V, 2)) / normC if normC > 0 else 0.0
    return max(inv, out)


@dataclass(frozen=True)
class _Decided:
    """Agent i's decisions in balanced coordinates: ``Vb`` (its unobservable space), the margins counted, the
    largest margin left out and that direction (balanced coordinates)."""

    Vb: np.ndarray
    margins: np.ndarray
    weak: float
    weak_direction: np.ndarray | None


def _decide(sp: Spectrum, C: np.ndarray, rank_tol: float | None, keep_full_steps: bool = True,
            free: GainTarget | None = None) -> _Decided:
    """The unobservable space of ``(C, A)`` cluster by cluster (:mod:`splitspec_core.model.modal`): each cluster's restricted
    pair ``(C_b X_k, A_k)`` by the graded staircase, ``C_b`` measured against its whole norm.  A cluster whose
    eigenvalues all satisfy ``free`` (they decay faster than the local gain's target, so the gain leaves them where
    they are: :mod:`splitspec_core.model.gains`) is decided at round-off: seeing it costs no gain, and counting what the
    sensors see of it, however little, keeps ``C_i V_i = 0`` (leaving it to consensus would couple the split by that
    much, times the gain).  Its margins are not the agent's (``margins`` holds those of the other clusters).  The
    other clusters' images are measured against the larger of their spread and the distance ``free.shift`` the gain
    moves them (:func:`observability_staircase`, ``move``)."""
    Cb = C * sp.d[None, :]
    normC = float(np.linalg.norm(Cb, 2)) if Cb.size else 0.0
    normA = float(np.linalg.norm(sp.A_b, 1))
    parts, margins, weak, weak_dir = [], [], 0.0, None
    for cl in sp.clusters:
        if normC == 0.0:
            parts.append(cl.X)
            continue
        alone = free is not None and bool(np.all(free(cl.eigs)))
        move = 0.0 if free is None or alone else float(np.max(free.shift(cl.eigs)))
        st = observability_staircase(cl.A, Cb @ cl.X, rank_tol=ROUND_OFF if alone else rank_tol,
                                     keep_full_steps=keep_full_steps, c_scale=normC, a_scale=normA, move=move)
        parts.append(cl.X @ _complement(st.W))
        if not alone:
            margins.append(st.margins)
        if st.weak > weak:
            weak, weak_dir = st.weak, cl.X @ st.weak_direction
    n = sp.A_b.shape[0]
    V = np.hstack(parts) if parts else np.zeros((n, 0))
    if V.shape[1]:
        V, _ = np.linalg.qr(V)  # the clusters' parts are independent (disjoint spectra), not orthogonal
    return _Decided(V, np.concatenate(margins) if margins else np.zeros(0), weak, weak_dir)


def decompose(A: np.ndarray, C: np.ndarray, *, rank_tol: float | None = None,
              spectrum: Spectrum | None = None, free: GainTarget | None = None,
              scale: np.ndarray | None = None) -> Decomposition:
    """Observability decomposition of ``(C, A)``, decided cluster by cluster in balanced coordinates.

    The margins, ``weak`` and ``split_residual`` are measured in the balanced coordinates (unit-free);
    ``weak_direction`` is in the user's.

    Parameters
    ----------
    A : (n, n) array_like
        State matrix.
    C : (s_i, n) array_like
        Agent i's output rows ``C_i``.
    rank_tol : float, optional
        ``design.rank_tol`` (None: auto, :data:`DEFAULT_RANK_TOL`).
    spectrum : Spectrum, optional
        The skeleton of ``A`` (:func:`splitspec_core.model.modal.spectrum`, all agents' rows stacked for the
        decoupled states); computed from ``(A, C)`` when not given.
    free : GainTarget, optional
        The local gain's target (:func:`splitspec_core.model.gain_target.beyond_target`): clusters already past it
        are decided at round-off, the others' dynamics are measured against the distance the gain moves them
        (:func:`_decide`).
    scale : (n,) array, optional
        The coordinates the decomposition is written in, ``x = diag(scale) x_w`` (None: the user's own; the
        design's ``design.coordinates``): ``V`` and ``Q`` are orthonormal there, ``Abar``, ``Cbar``, ``P``,
        ``A_un`` are of ``D^-1 A D`` and ``C D``.

    Returns
    -------
    Decomposition
        ``V_i``, ``Q_i``, ``Abar_i``, ``Cbar_i``, ``P_i = V_i V_i'``, ``A_i = V_i' A V_i`` (eq. QA2) and the margins.

    Examples
    --------
    >>> import numpy as np
    >>> dec = decompose(np.diag([-1.0, -2.0]), np.array([[1.0, 0.0]]))
    >>> dec.n_unobservable, np.abs(dec.V).round(12).ravel().tolist()
    (1, [0.0, 1.0])
    """
    A = np.asarray(A, dtype=float)
    C = np.asarray(C, dtype=float)
    sp = spectrum if spectrum is not None else modal_spectrum(A, C)
    dec = _decide(sp, C, rank_tol, free=free)
    if scale is not None:
        A, C = A * scale[None, :] / scale[:, None], C * scale[None, :]
    V = rescale(dec.Vb, sp.d, scale)
    Q = _complement(V).T
    residual = split_residual_of(sp.A_b, C * sp.d[None, :], _complement(dec.Vb).T, dec.Vb)
    weak_dir = None
    if dec.weak_direction is not None:
        weak_dir = sp.d * dec.weak_direction
        weak_dir = weak_dir / np.linalg.norm(weak_dir)
    return Decomposition(
        V=V, Q=Q, Abar=Q @ A @ Q.T, Cbar=C @ Q.T, P=V @ V.T, A_un=V.T @ A @ V,
        margin=float(dec.margins.min()) if dec.margins.size else None, weak=dec.weak, split_residual=residual,
        weak_direction=weak_dir,
    )


def unobservable_directions(A: np.ndarray, Cs, *, rank_tol: float | None = None) -> np.ndarray:
    """Orthonormal basis of what no agent sees: ``V_1 ∩ ... ∩ V_m``, each ``V_i`` decided as :func:`decompose` does
    (in one skeleton of ``A`` balanced with every agent's rows; :mod:`splitspec_core.model.detectability`).

    Parameters
    ----------
    A : (n, n) array_like
        State matrix.
    Cs : iterable of (s_i, n) array_like
        Every agent's ``C_i``.
    rank_tol : float, optional
        ``design.rank_tol`` (None: auto).

    Returns
    -------
    (n, w) array
        ``W`` in the user's coordinates; the identity when ``Cs`` is empty.
    """
    A = np.asarray(A, dtype=float)
    Cs = [np.asarray(C, dtype=float) for C in Cs]
    n = A.shape[0]
    if not Cs:
        return np.eye(n)
    sp = modal_spectrum(A, np.vstack(Cs))
    return sp.to_user(intersection([_decide(sp, C, rank_tol).Vb for C in Cs], n, tol=threshold_of(rank_tol)))
