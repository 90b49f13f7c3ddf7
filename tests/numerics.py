"""Comparing floats that were computed along different paths.

Two computations of the same quantity along different paths (lazy against eager, batched against
looped, ``syrk`` against ``gemm``, another OpenBLAS kernel or thread count) agree only to round-off: a
kernel's summation order changes the last bits, and which kernel runs depends on the CPU
(``OPENBLAS_CORETYPE``), the thread count and even the operands' memory layout.  Such results are
compared with :func:`assert_close`, with a tolerance stated where it is used and justified by the
magnitudes involved.  ``np.array_equal`` stays only where the very same operations run in the same
order by construction (a function called twice on equal inputs, a copy, a serialisation round
trip), and the test says so in a comment.

Tolerances used in the suite (``eps = 2.2e-16``):

* ``1e-12`` of the larger max-norm: one level of products or sums of a few hundred terms of
  order one (the error of a dot product of length ``k`` is below ``k eps`` of the norms' product);
* ``1e-9``: whole trajectories (hundreds of steps of a contracting recursion, each step adding
  round-off of its own; the runtime's ``compare_trajectories`` uses it too), eigenvalue-based
  quantities (spectral radii of non-normal matrices are sensitive to round-off in their entries).
"""

from __future__ import annotations

import numpy as np

__all__ = ["assert_close", "max_rel_diff"]


def max_rel_diff(actual, expected) -> float:
    """``max |actual - expected|`` over the larger of the two max-norms (NaN where either is NaN ignored;
    0 for two empty or all-NaN arrays); a norm below 1e-300 counts as 1e-300."""
    a, b = np.asarray(actual, dtype=float), np.asarray(expected, dtype=float)
    if a.shape != b.shape:
        raise AssertionError(f"shapes differ: {a.shape} against {b.shape}")
    both = np.isfinite(a) & np.isfinite(b)
    if not both.any():
        return 0.0
    scale = max(float(np.max(np.abs(a[both]))), float(np.max(np.abs(b[both]))), 1e-300)
    return float(np.max(np.abs(a[both] - b[both]))) / scale


def assert_close(actual, expected, *, rtol: float, what: str = "", equal_nan: bool = False) -> float:
    """Assert ``max |actual - expected| <= rtol * max(||actual||_max, ||expected||_max)``; return that ratio.

    ``equal_nan``: NaN (and infinities) must sit at the same places in both and are otherwise ignored;
    without it a NaN anywhere fails.
    """
    a, b = np.asarray(actual, dtype=float), np.asarray(expected, dtype=float)
    label = f"{what}: " if what else ""
    if a.shape != b.shape:
        raise AssertionError(f"{label}shapes differ: {a.shape} against {b.shape}")
    if equal_nan:
        if not np.array_equal(~np.isfinite(a), ~np.isfinite(b)):
            raise AssertionError(f"{label}non-finite entries at different places")
        if not np.array_equal(a[~np.isfinite(a)], b[~np.isfinite(b)], equal_nan=True):
            raise AssertionError(f"{label}different non-finite values")
    elif not (np.isfinite(a).all() and np.isfinite(b).all()):
        raise AssertionError(f"{label}non-finite entries")
    rel = max_rel_diff(a, b)
    if rel > rtol:
        raise AssertionError(f"{label}differs by {rel:.3g} of the larger norm (tolerance {rtol:g})")
    return rel
