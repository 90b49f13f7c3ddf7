"""The single-loss analysis at scale (splitspec_core/synthesis/resilience.py, model/detectability.py, model/subspaces.py).

What the survivors of each single agent loss leave unobserved (``W_S``, the intersection of their ``V_i``) comes
from triangular factors shared between the m losses: O(m) factorizations in all, where one intersection per
loss stacked m - 1 complements each (O(m^2) QR factorizations: 161,000 at m = 400, 21 of the plain design's 24 s).
The count is checked here (never a time: speed lives in benchmarks/bench_design.py), and the result against the
intersection of each survivor set computed alone.
"""

from __future__ import annotations

import numpy as np

from splitspec_core.model.subspaces import intersection, intersections_without_each, triangular_without_each


def projector(W: np.ndarray) -> np.ndarray:
    """``W W'``: the orthogonal projection on span W, whatever basis of it W is."""
    return W @ W.T


# --------------------------------------------------------------------------
# the shared factors give each survivor set's intersection
# --------------------------------------------------------------------------


def test_triangular_without_each_has_the_stacks_gram_matrix():
    """``R_k' R_k = sum_{j != k} B_j' B_j`` to round-off (1e-12 of its norm: sums of a few dozen products of
    order one), blocks of 0 to 4 rows, n = 5."""
    rng = np.random.default_rng(1)
    n = 5
    blocks = [rng.standard_normal((int(rng.integers(0, 5)), n)) for _ in range(9)]
    for k, R in enumerate(triangular_without_each(blocks, n)):
        rest = np.vstack([B for j, B in enumerate(blocks) if j != k])
        G = rest.T @ rest
        assert R.shape[0] <= n and np.allclose(R, np.triu(R))
        assert np.max(np.abs(R.T @ R - G)) <= 1e-12 * np.max(np.abs(G))


def test_triangular_without_each_of_one_block_and_of_empty_blocks():
    n = 3
    (R,) = triangular_without_each([np.ones((2, n))], n)
    assert R.shape == (0, n)
    Rs = triangular_without_each([np.zeros((0, n)), np.eye(n), np.zeros((0, n))], n)
    assert Rs[1].shape == (0, n)
    assert np.allclose(np.abs(Rs[0]), np.eye(n)) and np.allclose(np.abs(Rs[2]), np.eye(n))


def test_intersections_without_each_are_each_survivor_sets_intersection():
    """Subspaces sharing a common part, each agent with a private direction of its own and a random rest: without
    agent k the intersection gains k's private direction.  The same subspace as :func:`intersection` of the
    survivors (projectors to 1e-12: orthonormal bases of n = 8 from SVDs of order-one matrices)."""
    rng = np.random.default_rng(7)
    n, m = 8, 6
    common = np.linalg.qr(rng.standard_normal((n, 2)))[0]
    Vs = []
    for k in range(m):
        private = rng.standard_normal((n, 1)) if k % 2 == 0 else np.zeros((n, 0))
        Vs.append(np.linalg.qr(np.hstack([common, private, rng.standard_normal((n, k % 3))]))[0])
    each = intersections_without_each(Vs, n)
    for k in range(m):
        alone = intersection([V for j, V in enumerate(Vs) if j != k], n)
        assert each[k].shape == alone.shape
        assert np.max(np.abs(projector(each[k]) - projector(alone))) <= 1e-12
    assert intersections_without_each([np.eye(n)[:, :3]], n)[0].shape == (n, n)  # no survivor: everything
