"""The paper's Section 5 numbers, reproduced by the design engine (NOTES.md)."""

import numpy as np
import pytest

from splitspec_core.synthesis import bounds
from splitspec_core.synthesis.designer import design
from splitspec_core.scenarios.load import load_scenario


@pytest.fixture(scope="module")
def disc(request):
    from tests.conftest import EXAMPLES
    return design(load_scenario(EXAMPLES / "paper_discrete.yaml"), compare_q_methods=True)


@pytest.fixture(scope="module")
def cont():
    from tests.conftest import EXAMPLES
    return design(load_scenario(EXAMPLES / "paper_continuous.yaml"))


def test_explicit_gains_put_poles_where_the_paper_says(disc, cont):
    for a in cont.agents:
        assert np.allclose(np.sort(a.gain.poles.real), [-3, -2]) and np.allclose(a.gain.poles.imag, 0)
    for a in disc.agents:
        assert np.allclose(np.sort(np.abs(a.gain.poles)), [0.2, 0.3], atol=1e-2)


def test_unobservable_spaces_match_the_paper(disc):
    # V_1 = V_2 = span(e3, e4), V_3 = span(e1, e2)
    P12 = np.diag([0, 0, 1, 1.0])
    P3 = np.diag([1, 1, 0, 0.0])
    for a, P in zip(disc.agents, (P12, P12, P3)):
        assert np.allclose(a.P, P, atol=1e-12)


def test_continuous_eq_g_bound_and_g10(cont):
    # eq. (g) on graph (a) with rate 1: about 9.47, so g = 10 works
    assert cont.g_bounds["a"] == pytest.approx(9.4688, abs=1e-3)
    assert cont.g == 10
    assert cont.g_certified_by == "eq:g"
    assert cont.g_bounds["a"] <= 10
    # the exact smallest g is lower than the bound
    assert cont.g_mins["a"] < cont.g_bounds["a"]
    # error spectrum at g = 10 lies left of -1
    case = cont.cases[0]
    assert bounds.abscissa(case, 10.0) < -1.0


def test_continuous_graph_b_needs_larger_bound():
    from tests.conftest import EXAMPLES
    des = design(load_scenario(EXAMPLES / "paper_continuous_switching.yaml"))
    assert des.g_bounds["b"] == pytest.approx(11.78, abs=1e-2)


def test_discrete_spectral_q_is_6(disc):
    case = disc.cases[0]
    rho = lambda q: bounds.spectral_radius(case.Atil @ np.linalg.matrix_power(case.B, q))  # noqa: E731
    assert rho(5) == pytest.approx(0.568, abs=1e-3)
    assert rho(6) == pytest.approx(0.474, abs=1e-3)
    assert rho(5) > 0.5 > rho(6)
    assert disc.q == 6
    assert disc.q_result.method == "spectral"
    assert disc.q_result.bound == pytest.approx(rho(6))
    assert disc.q_result.certified


def test_discrete_mixed_norm_matches_paper_comment(disc):
    # the paper's (commented) worked example: p = 4, then q = 3p = 12
    mixed = disc.q_methods["mixed"]
    assert (mixed.p, mixed.pbar, mixed.q) == (4, 3, 12)
    assert mixed.certified


def test_full_error_matrix_at_q6_meets_rate(disc):
    sc = disc.scenario
    A = sc.system.A
    m, n = sc.m, sc.n
    Abar = np.zeros((m * n, m * n))
    P = np.zeros_like(Abar)
    for k, (a, C) in enumerate(zip(disc.agents, sc.system.Cs)):
        Abar[k * n:(k + 1) * n, k * n:(k + 1) * n] = A + a.K @ C
        P[k * n:(k + 1) * n, k * n:(k + 1) * n] = a.P
    S = disc.graphs[0].S
    E = Abar @ np.linalg.matrix_power(np.eye(m * n) - P @ (np.eye(m * n) - np.kron(S, np.eye(n))), 6)
    rho = np.max(np.abs(np.linalg.eigvals(E)))
    assert rho < 0.5
    assert rho == pytest.approx(0.4736, abs=1e-3)
