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
from dataclasses import dataclass

import numpy as np

from .errors import AssumptionError

__all__ = ["DEFAULT_RANK_TOL", "ROUND_OFF", "SPLIT_STEP", "Staircase", "Decomposition", "JointObservability", "threshold_of",
           "observability_staircase", "observable_basis", "decompose", "unobservable_directions",
           "joint_observability", "check_joint_observability"]


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
    """The margin threshold for ``design.rank_tol`` (None: auto)."""
    return DEFAULT_RANK_TOL if rank_tol is None else max(float(rank_tol), ROUND_OFF)


def observability_staircase(A: np.ndarray, C: np.ndarray, *, rank_tol: float | None = None,
                            keep_full_steps: bool = True) -> Staircase:
    """Observable space of ``(C, A)`` by the graded staircase (see the module docstring).

    ``keep_full_steps``: count a weak direction reached in a full step (:data:`SPLIT_STEP`), which an
    agent's split needs; the joint decision has no split to keep and counts margins alone.
    """
    step = SPLIT_STEP if keep_full_steps else math.inf
    n = A.shape[0]
    threshold = threshold_of(rank_tol)
    normC = np.linalg.norm(C, 2) if C.size else 0.0
    if normC == 0.0:
        return Staircase(np.zeros((n, 0)), np.zeros(0), 0.0, None, threshold)
    # the Krylov space of A' is that of (A - aI)': a shift changes no direction, only the scale
    scale = float(np.linalg.norm(A - (np.trace(A) / n) * np.eye(n), 2))
    weak, weak_dir = 0.0, None

    eps = np.finfo(float).eps

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
            keep = split(U, s, ratio, 10.0 * leak)
            new, mu = U[:, keep], s[keep]
            if mu.size:
                # a new direction inherits the error of those it came from, divided by its step from them (a weak
                # chain is as well determined as its own steps are)
                noise = max(noise, float(np.max((noise + eps) / ratio[keep])))
            W = np.hstack([W, new])
            margins.append(mu)
        new, mu = _missed(C / normC, S, W, threshold, max(ROUND_OFF, 10.0 * noise))
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
        ``max(||Q A V||_2 / ||A - aI||_2, ||C_i V||_2 / ||C_i||_2)``: how far ``V`` is from an exact
        unobservable space (round-off when ``weak`` is 0).
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

    @property
    def n_unobservable(self) -> int:
        return self.V.shape[1]

    @property
    def n_observable(self) -> int:
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


def observable_basis(A: np.ndarray, C: np.ndarray, *, rank_tol: float | None = None) -> np.ndarray:
    """Orthonormal basis (columns) of the observable space of ``(C, A)`` as decided by the graded staircase.

    Returns
    -------
    W : (n, r) array
        ``W'W = I``; ``span W`` is the span of the directions whose graded margin is at least the threshold.
    """
    return observability_staircase(A, C, rank_tol=rank_tol).W


def _complement(W: np.ndarray) -> np.ndarray:
    """Orthonormal basis of the orthogonal complement of ``span W``."""
    n, r = W.shape
    if r == 0:
        return np.eye(n)
    # numpy's QR (LAPACK dgeqrf + dorgqr, as scipy.linalg.qr): an agent process then needs no scipy
    Qfull, _ = np.linalg.qr(W, mode="complete")
    return Qfull[:, r:]


def _split_residual(A: np.ndarray, C: np.ndarray, Q: np.ndarray, V: np.ndarray) -> float:
    if not V.shape[1] or not Q.shape[0]:
        return 0.0
    n = A.shape[0]
    scale = float(np.linalg.norm(A - (np.trace(A) / n) * np.eye(n), 2))
    normC = float(np.linalg.norm(C, 2))
    inv = float(np.linalg.norm(Q @ A @ V, 2)) / scale if scale > 0 else 0.0
    out = float(np.linalg.norm(C @ V, 2)) / normC if normC > 0 else 0.0
    return max(inv, out)


def decompose(A: np.ndarray, C: np.ndarray, *, rank_tol: float | None = None) -> Decomposition:
    """Observability decomposition of ``(C, A)``; see the module docstring."""
    st = observability_staircase(A, C, rank_tol=rank_tol)
    W = st.W
    V = _complement(W)
    Q = W.T.copy()
    return Decomposition(
        V=V, Q=Q, Abar=Q @ A @ Q.T, Cbar=C @ Q.T, P=V @ V.T, A_un=V.T @ A @ V,
        margin=st.margin, weak=st.weak, split_residual=_split_residual(A, C, Q, V),
    )


def unobservable_directions(A: np.ndarray, Cs, *, rank_tol: float | None = None) -> np.ndarray:
    """Orthonormal basis of the jointly unobservable space of ``(C, A)`` (as :func:`joint_observability` decides)."""
    st = observability_staircase(A, np.vstack(list(Cs)), rank_tol=rank_tol, keep_full_steps=False)
    return _complement(st.W)


def _direction_text(v: np.ndarray) -> str:
    v = v / v[np.argmax(np.abs(v))]
    v = np.where(np.abs(v) < 5e-4, 0.0, v)
    return "[" + " ".join(f"{x:.3g}" for x in v) + "]"


@dataclass(frozen=True)
class JointObservability:
    """Joint observability of ``(C, A)`` as decided (the stacked pair, the same rule as each agent's).

    ``margin``: the smallest graded margin counted; ``weak``: the largest left out (0.0 if none);
    ``direction``: a direction nobody sees (text), or None.
    """

    observable: bool
    margin: float | None
    weak: float
    direction: str | None
    threshold: float


def joint_observability(A: np.ndarray, Cs, *, rank_tol: float | None = None) -> JointObservability:
    """Joint observability of the stacked pair, by margins alone (no split to keep: see :func:`observability_staircase`).

    When it is not observable as decided, ``weak`` is the margin the threshold would have to go below for it to
    be (the weakest direction of the staircase run down to round-off), 0.0 if not even then, and ``direction``
    the part of that direction nobody sees at the threshold.
    """
    C = np.vstack(list(Cs))
    st = observability_staircase(A, C, rank_tol=rank_tol, keep_full_steps=False)
    n = A.shape[0]
    if st.W.shape[1] == n:
        return JointObservability(True, st.margin, st.weak, None, st.threshold)
    full = observability_staircase(A, C, rank_tol=ROUND_OFF, keep_full_steps=False)
    if full.W.shape[1] == n:
        weakest = int(np.argmin(full.margins))
        weak, v = float(full.margins[weakest]), full.W[:, weakest]
        v = v - st.W @ (st.W.T @ v)
        if np.linalg.norm(v) < 1e-6:  # that one is seen: name any direction nobody sees
            v = _complement(st.W)[:, 0]
    else:
        weak, v = 0.0, _complement(full.W)[:, 0]
    return JointObservability(False, st.margin, weak, _direction_text(v / np.linalg.norm(v)), st.threshold)


def check_joint_observability(A: np.ndarray, Cs, *, rank_tol: float | None = None,
                              who: str = "every agent") -> JointObservability:
    """Raise :class:`AssumptionError` naming the direction if ``(C, A)`` is not jointly observable as decided.

    A direction left out with a margin above round-off is named with that margin ("only weakly
    observable"), with the threshold that left it out and how to override it.
    """
    jo = joint_observability(A, Cs, rank_tol=rank_tol)
    if jo.observable:
        return jo
    if jo.weak > 0.0:
        source = "design.rank_tol: auto" if rank_tol is None else f"design.rank_tol: {rank_tol:g}"
        raise AssumptionError(
            f"(C, A) is only weakly jointly observable: direction {jo.direction} is seen by {who} with a margin "
            f"of only {jo.weak:.2g} (< {jo.threshold:g}, {source}); a model accurate to better than that can "
            f"set design.rank_tol below {jo.weak:.2g} (gains then grow like 1 / margin)")
    raise AssumptionError(
        f"(C, A) is not jointly observable: direction {jo.direction} is unobservable to {who}")
