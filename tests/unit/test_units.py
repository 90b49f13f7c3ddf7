"""Rank decisions and margins that mean the same whatever the units (splitspec_core/model/modal.py).

A change of state units is a diagonal similarity: ``x_new = D^-1 x`` gives ``A_new = D^-1 A D`` and
``C_new = C D``.  The decisions are made in balanced coordinates, so they must not move: each agent's
unobservable space is the same subspace (``D^-1 V_i``), what no agent sees too, and every margin
changes only by the balancing's tolerance.  The models: the paper's example, and a power system's
linearised model (examples/models/kundur_full.npz: 52 states, eigenvalues from -49.5 to 0, |A| = 1e3)
with each generator's PMU, and with its exciter and governor outputs too.
"""

from __future__ import annotations

import numpy as np
import pytest
import scipy.linalg as sla

from splitspec_core.model import modal
from splitspec_core.model.observability import decompose, unobservable_directions
from tests.conftest import EXAMPLES, ROOT

#: the largest ratio of a margin in new units to the same margin in the old ones (measured: 1.013 at worst over
#: these models and 10 random unit changes each, 1e-3 .. 1e3; the balancing stops at 1e-6 per sweep, but some
#: states of these models have no balanced point and drift slowly, which the margins feel a little)
MARGIN_FACTOR = 1.05


def paper():
    A = np.array([[0, 1, 0, 0], [-1, 0, 0, 0], [0, 0, 0, 1], [0, 0, -2, 0.0]])
    return A, [np.eye(4)[[0]], np.eye(4)[[1]], np.eye(4)[[2]]]


def power(which: str):
    d = np.load(ROOT / "examples" / "models" / "kundur_full.npz", allow_pickle=False)
    return d["A"], [d[f"C_{which}_{k}"] for k in range(1, len(d["generators"]) + 1)]


MODELS = {"paper": paper, "kundur-pmu": lambda: power("pmu"), "kundur-more": lambda: power("more")}


def decisions(A, Cs):
    sp = modal.spectrum(A, np.vstack(Cs))
    return [decompose(A, C, spectrum=sp) for C in Cs]


def projector(V):
    return V @ V.T


def same_subspace(V, W, tol=1e-6) -> bool:
    return V.shape == W.shape and np.linalg.norm(projector(V) - projector(W), 2) <= tol


def in_units(V, D):
    """The subspace spanned by ``V`` written in the new units ``x_new = D^-1 x`` (orthonormal)."""
    return np.linalg.qr(V / D[:, None])[0] if V.shape[1] else V


@pytest.mark.parametrize("model", list(MODELS))
def test_decisions_and_margins_do_not_depend_on_the_units(model):
    A, Cs = MODELS[model]()
    base = decisions(A, Cs)
    W = unobservable_directions(A, Cs)
    rng = np.random.default_rng(7)
    for _ in range(6):
        D = 10.0 ** rng.uniform(-3, 3, size=A.shape[0])
        A2, Cs2 = A * D[None, :] / D[:, None], [C * D[None, :] for C in Cs]
        new = decisions(A2, Cs2)
        for b, c in zip(base, new):
            assert b.n_unobservable == c.n_unobservable
            # the same subspace: to round-off when it is an exact unobservable space, else to what it is known to
            # (a weak direction left out: the split residual; measured: a tenth of it at most)
            assert same_subspace(in_units(b.V, D), c.V, tol=1e-6 + b.split_residual)
            if b.margin is not None:
                assert 1 / MARGIN_FACTOR <= c.margin / b.margin <= MARGIN_FACTOR, (b.margin, c.margin)
            assert (b.weak == 0) == (c.weak == 0)
            if b.weak:
                assert 1 / MARGIN_FACTOR <= c.weak / b.weak <= MARGIN_FACTOR, (b.weak, c.weak)
        assert same_subspace(in_units(W, D), unobservable_directions(A2, Cs2))


@pytest.mark.parametrize("model", list(MODELS))
def test_balancing_first_changes_nothing(model):
    """The model balanced beforehand by scipy's ``matrix_balance`` (LAPACK dgebal: powers of 2, a loose stop, so
    another diagonal similarity): the same decisions, margins within the same factor."""
    A, Cs = MODELS[model]()
    Ab, (s, _) = sla.matrix_balance(A, permute=False, separate=True)
    base, new = decisions(A, Cs), decisions(Ab, [C * s[None, :] for C in Cs])
    for b, c in zip(base, new):
        assert b.n_unobservable == c.n_unobservable and same_subspace(in_units(b.V, s), c.V, tol=1e-6 + b.split_residual)
        if b.margin is not None:
            assert 1 / MARGIN_FACTOR <= c.margin / b.margin <= MARGIN_FACTOR


def test_balancing_finds_the_same_point_from_any_units():
    """Where the balanced point exists (an irreducible A), balancing ``D^-1 A D`` recovers ``D`` up to a common factor."""
    A = np.random.default_rng(3).normal(size=(6, 6))
    D = 10.0 ** np.random.default_rng(4).uniform(-3, 3, size=6)
    d1, d2 = modal.balance(A), modal.balance(A * D[None, :] / D[:, None])
    ratio = d2 * D / d1
    assert np.allclose(ratio / ratio[0], 1.0, rtol=1e-4)
    B = A * d1[None, :] / d1[:, None]
    off = B - np.diag(np.diag(B))
    assert np.allclose(np.linalg.norm(off, axis=0), np.linalg.norm(off, axis=1), rtol=1e-4)  # balanced


def test_a_stiff_model_is_decided_per_time_scale():
    """The power model with PMUs and exciter/governor outputs: the whole-model staircase of the stacked outputs gave
    "only weakly jointly observable ... margin of only 8.5e-11" (the issue's report); per cluster, what no agent sees
    is exactly the four lead-lag states whose pole cancels a zero (eigenvalue -1, PBH value 1e-13), and every other
    eigenvalue's PBH value on the balanced model is far from zero."""
    A, Cs = power("more")
    W = unobservable_directions(A, Cs)
    names = list(np.load(ROOT / "examples" / "models" / "kundur_full.npz")["states"])
    carried = sorted(names[k] for k in np.flatnonzero(np.sum(W ** 2, axis=1) > 1e-6))
    assert W.shape[1] == 4 and carried == [f"LL_x_EXDC2_{g}" for g in range(1, 5)], carried
    assert np.allclose(np.linalg.eigvals(W.T @ A @ W), -1.0, atol=1e-9)
    # the PBH test per eigenvalue on the balanced model: ~0 for the four, and for every other eigenvalue at least
    # the smallest margin an agent counts as seen (relative to |C_b| and to the eigenvalue's own scale)
    sp = modal.spectrum(A, np.vstack(Cs))
    Cb = np.vstack(Cs) * sp.d[None, :]
    Cb = Cb / np.linalg.norm(Cb, 2)
    n = A.shape[0]
    pbh = []
    for lam in np.linalg.eigvals(sp.A_b):
        scale = max(abs(lam), 1.0)
        pbh.append((lam, np.linalg.svd(np.vstack([(sp.A_b - lam * np.eye(n)) / scale, Cb]), compute_uv=False)[-1]))
    tiny = [lam for lam, v in pbh if v < 1e-9]
    assert len(tiny) == 4 and np.allclose(tiny, -1.0, atol=1e-6)
    counted = min(d.margin for d in decisions(A, Cs) if d.margin is not None)
    assert min(v for lam, v in pbh if abs(lam + 1.0) > 1e-6) >= 1e-6 * counted
