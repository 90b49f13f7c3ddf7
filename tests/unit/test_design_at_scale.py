"""Design at scale (issue "Speed at scale", items 6-7): the resilient ring, warm-started q, sparse block norms."""

from __future__ import annotations

import json

import numpy as np
import pytest
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st

import splitspec_core as ss
from splitspec_core.synthesis import bounds, spectral
from splitspec_core.synthesis.designer import design
from splitspec_core.errors import DesignError
from splitspec_core.scenarios.generate import random_system, ring_arcs, ring_scenario, ring_system
from splitspec_core.model.graphs import is_strongly_connected
from splitspec_core.model.observability import unobservable_directions
from splitspec_core.scenarios.load import load_scenario, parse_scenario
from splitspec_orchestrator import cli
from tests.numerics import assert_close


# --------------------------------------------------------------------------
# the ring of the benchmark
# --------------------------------------------------------------------------


@pytest.mark.parametrize("m, n", [(4, 4), (10, 10), (12, 5)])
def test_ring_is_redundant(m, n):
    """Any m - 1 agents still jointly observe (C, A) and still form a strongly connected graph."""
    A, Cs = ring_system(np.random.default_rng(m), m, n)
    arcs = ring_arcs(m)
    assert unobservable_directions(A, Cs).shape[1] == 0
    for lost in range(m):
        alive = [i for i in range(m) if i != lost]
        assert unobservable_directions(A, [Cs[i] for i in alive]).shape[1] == 0
        pos = {a: k for k, a in enumerate(alive)}
        assert is_strongly_connected(m - 1, [(pos[j], pos[i]) for j, i in arcs if j in pos and i in pos])


def test_ring_needs_two_observers_per_block():
    with pytest.raises(ValueError, match="m >= 2"):
        ring_system(np.random.default_rng(0), 5, 6)


def test_ring_resilient_design():
    des = design(parse_scenario(ring_scenario(8, 4, resilience=1)))
    assert des.redundantly_jointly_observable and des.redundantly_strongly_connected
    assert len(des.cases) == 1 + 8 and des.q_result.certified


def test_random_system_unchanged_by_the_refactor():
    """random_system draws exactly what it drew before the oscillator blocks became a helper."""
    A, Cs = random_system(np.random.default_rng(3), 4, 5)
    assert A.shape == (5, 5) and len(Cs) == 4
    # the values drawn at the time (to 1e-12: the QR of the random basis may differ in its last bits on another BLAS)
    assert A[0, 0] == pytest.approx(0.818775539384253, rel=1e-12)
    assert sum(c.sum() for c in Cs) == pytest.approx(1.2393351448471717, rel=1e-12)


# --------------------------------------------------------------------------
# the other q methods: on request only (splitspec design --all-methods)
# --------------------------------------------------------------------------


@pytest.fixture
def resilient_ring(tmp_path):
    path = tmp_path / "ring.yaml"
    path.write_text(yaml.safe_dump(ring_scenario(8, 4, resilience=1), sort_keys=False))
    return path


def test_design_computes_other_methods_only_when_asked(resilient_ring, monkeypatch):
    from splitspec_core.synthesis import bounds

    asked = []
    real = bounds.choose_q
    monkeypatch.setattr(bounds, "choose_q", lambda method, cases, *a, **kw: asked.append(method) or
                        real(method, cases, *a, **kw))
    sc = load_scenario(resilient_ring)
    des = design(sc)
    assert asked == ["spectral"] and list(des.q_methods) == ["spectral"]  # loss cases included: nothing else
    asked.clear()
    des = ss.design(sc, all_q_methods=True).detail
    assert sorted(asked) == sorted(des.q_methods) == ["mixed", "spectral", "two-norm", "weighted"]


@pytest.mark.parametrize("as_json", [False, True])
def test_cli_all_methods_flag(resilient_ring, capsys, as_json):
    fmt = ["--json"] if as_json else []
    assert cli.main(["design", str(resilient_ring), *fmt]) == 0
    plain = capsys.readouterr().out
    assert cli.main(["design", str(resilient_ring), *fmt, "--all-methods"]) == 0
    full = capsys.readouterr().out
    if as_json:
        assert list(json.loads(plain)["q_methods"]) == ["spectral"]
        assert sorted(json.loads(full)["q_methods"]) == ["mixed", "spectral", "two-norm", "weighted"]
        assert json.loads(full)["q"] == json.loads(plain)["q"]
    else:
        assert "other methods:" not in plain
        assert "other methods:" in full and "    mixed: q = " in full
        lines = full.splitlines()
        start = lines.index("  other methods:")
        assert [ln for ln in lines[start + 1:] if ln.startswith("    ")] == lines[start + 1:start + 4]
        assert lines[:start] + lines[start + 4:] == plain.splitlines()  # the report otherwise unchanged


def test_cli_all_methods_with_tune_is_refused(resilient_ring, capsys):
    assert cli.main(["design", str(resilient_ring), "--tune", "rms", "--all-methods"]) == 2
    assert "--all-methods" in capsys.readouterr().err


# --------------------------------------------------------------------------
# mixed norm over the non-zero blocks only
# --------------------------------------------------------------------------


def dense_mixed_norm(M, rows, cols):
    """Eq. (split_mmn) block by block over all blocks, zero ones included (the former implementation)."""
    r_edges, c_edges = np.concatenate([[0], np.cumsum(rows)]), np.concatenate([[0], np.cumsum(cols)])
    best = 0.0
    for i in range(len(rows)):
        if rows[i] == 0:
            continue
        row_sum = 0.0
        for j in range(len(cols)):
            if cols[j] == 0:
                continue
            row_sum += np.linalg.norm(M[r_edges[i]:r_edges[i + 1], c_edges[j]:c_edges[j + 1]], 2)
        best = max(best, row_sum)
    return best


@pytest.mark.parametrize("seed", range(40))
def test_mixed_norm_sparse_equals_dense(seed):
    rng = np.random.default_rng(seed)
    m = int(rng.integers(1, 12))
    rows = rng.integers(0, 4, size=m)  # empty blocks (n_i = 0) too
    cols = rows if seed % 2 else rng.integers(0, 4, size=int(rng.integers(1, 12)))
    M = rng.normal(size=(rows.sum(), cols.sum()))
    keep = rng.random((len(rows), len(cols))) < rng.uniform(0, 1)  # a random block pattern, often sparse
    M *= np.repeat(np.repeat(keep, rows, axis=0), cols, axis=1)
    ref = dense_mixed_norm(M, rows, cols)
    assert bounds.mixed_norm(M, rows, cols) == pytest.approx(ref, rel=1e-12, abs=0)


def test_mixed_norm_on_a_resilient_rings_cases():
    """Atil (block diagonal) and B = V' Sbar V (arcs and diagonal) of every case, and a dense B^p."""
    des = design(parse_scenario(ring_scenario(12, 6, resilience=1)))
    for case in des.cases:
        for M in (case.Atil, case.B, np.linalg.matrix_power(case.B, 30)):
            assert bounds.mixed_norm(M, case.sizes) == pytest.approx(dense_mixed_norm(M, case.sizes, case.sizes),
                                                                     rel=1e-12, abs=0)


# --------------------------------------------------------------------------
# the q search warm-started over the cases, powers of B sharing their squares
# --------------------------------------------------------------------------


@pytest.mark.parametrize("size", [1, 3, 8])
def test_powers_are_matrix_power_bit_for_bit(size):
    rng = np.random.default_rng(size)
    B = rng.normal(size=(size, size)) / size
    powers = bounds._Powers(B)
    for k in [*rng.permutation(70), 64, 1, 0, 129, 3, 2]:  # any order: the squares are shared
        # exact by construction: _Powers makes the very matmul calls of matrix_power, on equal operands, in
        # the same order (the squares B, B^2, B^4, ... from the lowest bit of k up); only where they are kept
        # differs.  That is _Powers' contract, and what lets the warm-started q equal the one from scratch.
        assert np.array_equal(powers(int(k)), np.linalg.matrix_power(B, int(k))), k


@settings(max_examples=300, deadline=None)
@given(st.lists(st.lists(st.booleans(), min_size=1, max_size=150), min_size=1, max_size=6),
       st.integers(1, 150))
def test_warm_started_max_equals_searches_from_scratch(tables, q_max):
    """Any predicates, monotone in k or not, with and without an answer below q_max: same q, same error."""
    def preds():
        return [lambda k, t=t: t[(k - 1) % len(t)] for t in tables]

    def outcome(f):
        try:
            return f()
        except DesignError as exc:
            return str(exc)

    whats = [f"case {i}" for i in range(len(tables))]
    scratch = outcome(lambda: max(bounds.smallest(p, q_max, what=w) for p, w in zip(preds(), whats)))
    assert outcome(lambda: bounds._smallest_max(preds(), q_max, whats=whats)) == scratch


def spectral_from_scratch(cases, rate, q_max=100_000):
    """q_spectral as it was: every case searched from scratch, every radius recomputed."""
    def rho(case, k):
        return bounds.spectral_radius(case.Atil @ np.linalg.matrix_power(case.B, k)) if case.nbar else 0.0

    q = max(bounds.smallest(lambda k, c=c: rho(c, k) < rate, q_max, what=c.label) for c in cases)
    return q, max(rho(c, q) for c in cases), {c.label: rho(c, q) for c in cases}


def two_norm_p_from_scratch(cases):
    live = [c for c in cases if c.nbar]
    return max([bounds.smallest(lambda k, c=c: np.linalg.norm(np.linalg.matrix_power(c.B, k), 2) < 1.0, 100_000,
                                 what=c.label) for c in live] or [1])


def random_resilient(seed: int, method: str = "spectral") -> dict:
    """The ring of ring_system plus random chords (still redundant), a random rate."""
    rng = np.random.default_rng(seed)
    n = int(rng.choice([4, 5, 6, 8]))
    m = int(rng.integers((n + 1) // 2 * 2, 13))
    raw = ring_scenario(m, n, resilience=1, seed=seed, rate=float(rng.uniform(0.05, 0.9)), q_method=method)
    chords = rng.integers(1, m + 1, size=(int(rng.integers(0, m)), 2))
    raw["graphs"]["ring"]["arcs"] += [[int(j), int(i)] for j, i in chords if j != i]
    return raw


@pytest.mark.parametrize("seed", range(12))
def test_warm_started_q_equals_the_search_from_scratch(seed):
    """Random redundant networks with every loss case: the same q, and the same bound and error radii.

    The radii come out of the same matrix products (``_Powers`` is ``matrix_power``, see above) and the same
    eigenvalue routine, so they agree exactly on one machine; compared to 1e-12 (relative) all the same,
    since the point here is the warm start, not the bits.  q, an integer, must be equal.  Under
    ``make test-iterative`` the design's radii are ARPACK's (splitspec_core.synthesis.spectral): within DECIDE of the dense
    ones, the margin under which a comparison with the rate is made again densely."""
    des = design(parse_scenario(random_resilient(seed)))
    assert len(des.cases) == 1 + des.scenario.m
    q, bound, radius = spectral_from_scratch(des.cases, des.rate)
    assert des.q == q
    rtol = spectral.DECIDE if des.q_result.eig["methods"].get("iterative") else 1e-12
    assert des.q_result.bound == pytest.approx(bound, rel=rtol, abs=0)
    assert list(des.error_radius) == list(radius)
    assert_close([des.error_radius[k] for k in radius], list(radius.values()), rtol=rtol, what="error radii")
    # the cases in another order (the loss cases first): the same q again, on fresh cases (no memo)
    fresh = design(parse_scenario(random_resilient(seed))).cases
    order = np.random.default_rng(seed).permutation(len(fresh))
    assert bounds.q_spectral([fresh[k] for k in order], des.rate).q == q
    assert bounds.q_two_norm(fresh, des.rate).p == two_norm_p_from_scratch(fresh)


def test_warm_start_does_not_hide_a_case_that_needs_more():
    """A loss case needing a larger q than the base graph still raises q (here 1 -> 2)."""
    des = design(parse_scenario(ring_scenario(10, 4, resilience=1)))
    base = des.cases[0]
    assert bounds.q_spectral([base], des.rate).q < des.q == spectral_from_scratch(des.cases, des.rate)[0]


# --------------------------------------------------------------------------
# building the m + 1 cases
# --------------------------------------------------------------------------


def test_case_parts_as_the_eager_formulas():
    """h and VLV (now computed on first use) and Atil (no longer scipy's block_diag): the same values.

    VLV takes the Gram matrix as ``Vcat.T @ Vcat`` (numpy hands ``X.T @ X`` to BLAS ``syrk``), the formula
    below as a product of two separate arrays (``gemm``): another summation order, which differs in the
    last bits on some kernels (SkylakeX here, Haswell on AMD EPYC).  The entries are inner products of
    n <= 8 unit-norm columns times weights below 1, so 1e-12 of the largest entry is ample round-off room.
    h and Atil only copy numbers into place: exact."""
    import scipy.linalg as sla

    from splitspec_core.model.graphs import perron_vector

    des = design(parse_scenario(random_resilient(3)))
    ad = {a.id: a for a in des.agents}
    for case in des.cases:
        Vs = [ad[i].V for i in case.graph.ids]
        G = np.hstack(Vs).T @ np.hstack(Vs)
        S = case.graph.S
        pi = perron_vector(S)
        Pi = np.diag(pi)
        assert np.array_equal(case.h, np.repeat(pi, case.sizes))  # the same perron_vector, repeated: exact
        assert_close(case.VLV, bounds._expand(2 * Pi - Pi @ S - S.T @ Pi, case.sizes) * G, rtol=1e-12, what="VLV")
        # copies of the same blocks into zeros: exact
        assert np.array_equal(case.Atil, sla.block_diag(*[ad[i].dec.A_un for i in case.graph.ids]))
    assert bounds._block_diag([np.ones((2, 2)), np.zeros((0, 0)), 2 * np.ones((1, 1))], (2, 0, 1)).tolist() == \
        [[1, 1, 0], [1, 1, 0], [0, 0, 2]]


def test_spectral_design_needs_no_perron_vector(monkeypatch):
    """A discrete design with spectral q never uses h or VLV: no Perron vector for the m + 1 cases."""
    from splitspec_core.model import graphs

    calls = []
    real = graphs.perron_vector
    monkeypatch.setattr(bounds, "perron_vector", lambda S: calls.append(1) or real(S))
    design(parse_scenario(ring_scenario(10, 4, resilience=1)))
    assert calls == []
    design(parse_scenario(ring_scenario(10, 4, resilience=1, q_method="weighted")))
    assert len(calls) == 11  # ||.||_R needs H: one Perron vector per case


@pytest.mark.parametrize("seed", range(4))
def test_a_graphs_entries_are_its_matrix_nonzeros(seed):
    """``Graph.entries`` (the spectral path's S, never formed) against the nonzeros of the formed ``S``: the same
    positions and, computed by the same division 1 / (in-neighbours + 1), the same values exactly."""
    from splitspec_core.scenarios.generate import chord_arcs
    from splitspec_core.model.graphs import build_graph

    rng = np.random.default_rng(seed)
    m = int(rng.integers(4, 40))
    ids = tuple(int(i) for i in rng.permutation(np.arange(1, 3 * m))[:m])
    arcs = [(ids[j], ids[i]) for j, i in chord_arcs(rng, m)]
    lazy, formed = build_graph("g", ids, arcs), build_graph("g", ids, arcs)
    formed.S  # noqa: B018 - formed first: its entries are read from S
    got = sorted(zip(*[a.tolist() for a in lazy.entries]))
    want = sorted(zip(*[a.tolist() for a in formed.entries]))
    assert "S" not in lazy.__dict__ and got == want


@pytest.mark.parametrize("seed", range(6))
def test_arc_positions_as_a_lookup_by_hand(seed):
    """The vectorised ``arc_positions`` (a sorted search) against a dictionary lookup arc by arc: the same
    positions in the same order, arcs with an end outside ``ids`` dropped; ``build_graph`` keeps the same arcs."""
    from splitspec_core.model.graphs import arc_positions, build_graph

    rng = np.random.default_rng(seed)
    m = int(rng.integers(1, 30))
    ids = tuple(int(i) for i in rng.permutation(np.arange(1, 3 * m + 1))[:m])  # not sorted, gaps between
    arcs = [tuple(int(a) for a in rng.integers(0, 3 * m + 2, size=2)) for _ in range(int(rng.integers(0, 4 * m)))]
    pos = {a: k for k, a in enumerate(ids)}
    want = [(pos[j], pos[i]) for j, i in arcs if j in pos and i in pos]
    got = list(zip(*[a.tolist() for a in arc_positions(ids, arcs)]))
    assert got == want
    kept = build_graph("g", ids, arcs, check=False).arcs
    assert kept == tuple((j, i) for j, i in arcs if j in pos and i in pos and j != i)


@pytest.mark.parametrize("uniform", [True, False], ids=["bsr", "csr"])
def test_sparse_factors_are_the_formed_matrices(uniform):
    """The matrix-free path's ``Atil B`` and ``B`` (block sparse rows when every ``n_i`` is equal, CSR with the
    padding masked out otherwise) against the formed ``Atil @ B`` and ``B``.  The blocks are the same inner
    products in another order (batched ``matmul`` against the Gram matrix's ``Vcat' Vcat``): 1e-12 of the
    largest entry."""
    if uniform:
        des = design(parse_scenario(ring_scenario(12, 6, resilience=1, rate=0.9, chords=True)))
    else:
        des = design(parse_scenario(random_resilient(1)))  # agents with n_i = 3 and 4
    for case in des.cases:
        assert (len(set(case.sizes)) == 1) == uniform
        AB, B = spectral._sparse_factors(case)
        assert AB.format == B.format == ("bsr" if uniform else "csr")
        assert_close(B.toarray(), case.B, rtol=1e-12, what="B")
        assert_close(AB.toarray(), case.Atil @ case.B, rtol=1e-12, what="Atil B")


DRAWN = {"name": "drawn", "time": "discrete",
         "system": {"A": [[-1.1]], "C": {i: [[-1.0 if i in (2, 8) else 0.0]] for i in range(1, 9)}},
         "graphs": {"g1": {"arcs": [[i, i % 8 + 1] for i in range(1, 9)]}},
         "design": {"rate": 0.375, "gains": "riccati", "margin": 0.5, "rank_tol": 1e-12, "q": 27}}


def _drawn(eigenvalues):
    return design(parse_scenario({**DRAWN, "design": {**DRAWN["design"], "eigenvalues": eigenvalues}}))


def test_the_drawn_case_arpack_failed_on_is_designed_densely():
    """A drawn case (8 agents on one unstable state, 6 of them blind: at q = 27 the radius is 8e-9) on which ARPACK
    raised error 1 of dneupd (the Schur form could not be reordered) under one OpenBLAS kernel and ended the design.
    Under most kernels the radius is so tiny that ARPACK's claimed accuracy is no accuracy at all (relative error 1),
    so within ``max(DECIDE, accuracy)`` of the rate: the iterative design ends on a dense radius (which fallback
    depends on the kernel) equal to the dense design's.  scipy 1.13's ARPACK (``make test-lowest``) claims a
    relative accuracy of 0.34 instead: then its radius stands, far below the rate within what it claims.  Either
    way the design decides as the dense one does."""
    dense, it = _drawn("dense"), _drawn("iterative")
    (how,) = [c._how[27] for c in it.cases]
    rate = DRAWN["design"]["rate"]
    assert it.q == dense.q == 27 and it.q_result.certified == dense.q_result.certified
    if how.method == "iterative":  # settled by ARPACK: its interval is decisively below the rate
        assert how.value * (1 + how.tol) < rate * (1 - spectral.DECIDE)
        assert it.error_radius["g1"] == pytest.approx(dense.error_radius["g1"], rel=how.tol)
        assert it.q_result.eig["methods"] == {"iterative": 1}
        return
    assert how.method.startswith("dense (fallback: ")
    # the same dense computation on the same matrix: the same number (compared to round-off all the same)
    assert it.error_radius["g1"] == pytest.approx(dense.error_radius["g1"], rel=1e-12)
    assert it.q_result.eig["methods"] == {"dense (fallback)": 1}


def test_an_arpack_error_falls_back_to_the_dense_radius(monkeypatch):
    """Any error ARPACK raises (here its own ``ArpackError(1)``, raised where ``eigs`` is called, as dneupd raised
    it on the drawn case above under one kernel: which kernel hits it is not something a test can rely on) makes the
    radius dense, and the method says which error; before, the design ended in the error."""
    import scipy.sparse.linalg as sla

    def failing(*args, **kwargs):
        raise sla.ArpackError(1, infodict={1: "the Schur form could not be reordered"})

    monkeypatch.setattr(sla, "eigs", failing)
    case = design(parse_scenario(ring_scenario(12, 6, rate=0.9))).cases[0]
    got = spectral.radius(case, 3)
    assert got.method == "dense (fallback: ARPACK error 1)"
    # the dense path itself, called directly: the same operations in the same order, so the same number
    assert got.value == spectral._dense(case, 3)
