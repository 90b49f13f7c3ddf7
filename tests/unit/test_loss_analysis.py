"""The single-loss analysis at scale (synthesis/resilience.py, model/detectability.py, model/subspaces.py).

What the survivors of each single agent loss leave unobserved (``W_S``, the intersection of their ``V_i``) comes
from triangular factors shared between the m losses: O(m) factorizations in all, where one intersection per
loss rescaled and complemented m - 1 subspaces each (2m(m - 1) QR factorizations: 322,000 at m = 400, 11.1 s of
the plain design's 11.8 s).
The count is checked here (never a time: speed lives in benchmarks/bench_design.py), and the result against the
intersection of each survivor set computed alone.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from splitspec_core.model.detectability import still_text
from splitspec_core.model.subspaces import intersection, intersections_without_each, triangular_without_each
from splitspec_core.scenarios.generate import ring_scenario
from splitspec_core.scenarios.load import load_scenario, parse_scenario
from splitspec_core.synthesis import prelude
from splitspec_core.synthesis.designer import design
from tests.conftest import EXAMPLES


def projector(W: np.ndarray) -> np.ndarray:
    """``W W'``: the orthogonal projection on span W, whatever basis of it W is."""
    return W @ W.T


# --------------------------------------------------------------------------
# how the work grows with m
# --------------------------------------------------------------------------


def factorizations_of_the_loss_analysis(monkeypatch, m: int) -> int:
    """QR and SVD factorizations (numpy.linalg: every subspace operation of the core) run inside the design's
    single-agent loss analysis of the benchmark's ring with chords (n = 6, one output per agent), m agents."""
    inside, count = [False], [0]

    def counted(fn):
        def wrapper(*args, **kwargs):
            count[0] += inside[0]
            return fn(*args, **kwargs)
        return wrapper

    for name in ("qr", "svd"):
        monkeypatch.setattr(np.linalg, name, counted(getattr(np.linalg, name)))
    real = prelude.analyse_agent_losses

    def analysed(*args, **kwargs):
        inside[0] = True
        try:
            return real(*args, **kwargs)
        finally:
            inside[0] = False

    monkeypatch.setattr(prelude, "analyse_agent_losses", analysed)
    des = design(parse_scenario(ring_scenario(m, 6, rate=0.9, chords=True), source="<test>"))
    assert len(des.agent_losses) == m and all(rep.ok for rep in des.agent_losses.values())
    return count[0]


def test_the_loss_analysis_factorizations_grow_linearly_in_m(monkeypatch):
    """Doubling m at most doubles the factorizations (2.2x: what a constant overhead may add); on the code that
    intersected m - 1 subspaces per loss it was 4x (2m^2 QR factorizations)."""
    counts = {m: factorizations_of_the_loss_analysis(monkeypatch, m) for m in (25, 50, 100)}
    for m in (25, 50):
        assert counts[2 * m] <= 2.2 * counts[m], counts
    assert counts[100] <= 10 * 100, counts  # a few per agent: rescale, complement, prefix, suffix, the SVD


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


def three_agents(d: float) -> dict:
    """An oscillator seen by agents 1 and 2; a mode m (m+ = d m) seen by agent 3 only (test_detectability.py)."""
    return {"name": "lose-3", "time": "discrete",
            "system": {"A": [[math.cos(0.7), math.sin(0.7), 0], [-math.sin(0.7), math.cos(0.7), 0], [0, 0, d]],
                       "C": {1: [[1, 0, 0]], 2: [[0, 1, 0]], 3: [[1, 0, 1]]}, "states": ["p", "v", "m"]},
            "graphs": {"ring": {"undirected": [[1, 2], [2, 3], [3, 1]]}},
            "design": {"rate": 0.5, "gains": "place"}}


def private_modes(m: int) -> dict:
    """Every agent sees one of an oscillator's coordinates and a stable mode of its own: each loss leaves that
    mode unobserved (``W_S`` of dimension 1, a different one per loss)."""
    rng = np.random.default_rng(m)
    n = m + 2
    A = np.zeros((n, n))
    A[:2, :2] = [[math.cos(0.5), math.sin(0.5)], [-math.sin(0.5), math.cos(0.5)]]
    C = {}
    for k in range(m):
        A[2 + k, 2 + k] = rng.uniform(0.1, 0.8)
        A[2 + k, 0] = rng.uniform(-0.3, 0.3)
        row = np.zeros(n)
        row[k % 2], row[2 + k] = 1.0, 1.0 + 0.1 * k
        C[k + 1] = [row.tolist()]
    return {"name": f"private{m}", "time": "discrete", "system": {"A": A.tolist(), "C": C},
            "graphs": {"ring": {"undirected": [[k + 1, (k + 1) % m + 1] for k in range(m)]}},
            "design": {"rate": 0.9, "gains": "place"}}


SCENARIOS = {
    "three agents, d = 0.3": lambda: parse_scenario(three_agents(0.3)),
    "three agents, d = 0.9": lambda: parse_scenario(three_agents(0.9)),
    "private modes, m = 7": lambda: parse_scenario(private_modes(7)),
    "ring with chords, m = 30": lambda: parse_scenario(ring_scenario(30, 6, rate=0.9, chords=True)),
    "platoon (approximate split, modes at 1)": lambda: load_scenario(EXAMPLES / "platoon.yaml"),
}


@pytest.mark.parametrize("name", list(SCENARIOS))
def test_each_loss_leaves_what_its_survivors_leave_computed_alone(name):
    """The design's loss reports against :meth:`Design.unobserved_of` of each survivor set (one intersection of the
    m - 1 subspaces, as before): the same W_S (projectors to 1e-12), residual (to 1e-12: a ratio of 2-norms of
    order-one matrices, round-off itself in most cases), verdicts and texts, and the spectrum on W_S to 1e-6 of
    |A| (the platoon's double mode at 1 is defective: round-off moves such an eigenvalue by about its square root,
    1e-8, whichever basis of W_S carries it).  (The IEEE 14-bus example, 10 s to design, agrees as well: projectors
    to 9e-12 in balanced coordinates, as far as the old path's W_S is from the design's own W there, 2.4e-12
    in the user's: the accuracy of a subspace decided against weakly seen directions.)"""
    des = design(SCENARIOS[name]())
    rate = des.scenario.design.rate
    for lost, rep in des.agent_losses.items():
        got = rep.unobserved
        alone = des.unobserved_of([a for a in des.scenario.agent_ids if a != lost])
        assert got.dim == alone.dim
        assert np.max(np.abs(projector(got.W) - projector(alone.W)), initial=0.0) <= 1e-12
        assert np.max(np.abs(projector(got.W_working) - projector(alone.W_working)), initial=0.0) <= 1e-12
        assert abs(got.residual - alone.residual) <= 1e-12
        assert np.allclose(np.sort_complex(got.eigs), np.sort_complex(alone.eigs), rtol=0, atol=1e-6 * got.scale)
        assert (got.decays, got.limits(rate)) == (alone.decays, alone.limits(rate))
        assert got.summary(rate) == alone.summary(rate)
        assert rep.unobservable_direction == (None if alone.decays else still_text(alone))
