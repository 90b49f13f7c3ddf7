"""The size of a design's errors: transient constant, margins, gain sizes, the full error matrix, noise."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import yaml

from splitspec_core.synthesis.conditioning import conditioning, transient_constant
from splitspec_core.synthesis.error_matrix import full_error_matrix, predicted_rms
from splitspec_core.synthesis.designer import design
from splitspec_core.scenarios.load import load_scenario, parse_scenario
from splitspec_core.simulation.simulator import simulate
from splitspec_orchestrator import cli
from tests.conftest import EXAMPLES


# --------------------------------------------------------------------------
# the transient constant, by hand
# --------------------------------------------------------------------------


def test_transient_constant_worked_by_hand():
    # M = [[0, 10], [0, 0]]: ||M^0|| = 1, ||M|| = 10, M^2 = 0; at r = 0.5 the supremum is 10 / 0.5 = 20, at k = 1
    t = transient_constant(np.array([[0.0, 10.0], [0.0, 0.0]]), 0.5)
    assert t.constant == pytest.approx(20.0, rel=1e-12) and t.step == 1 and t.method == "exact"
    assert t.agent_index == 0  # the first row carries the peak
    # a normal contraction never exceeds its initial size: c = 1
    assert transient_constant(np.diag([0.3, -0.2]), 0.5).constant == 1.0
    # not decaying at the rate: infinite, and said so
    t = transient_constant(np.diag([0.6, 0.1]), 0.5)
    assert math.isinf(t.constant) and "not below" in t.method


def test_transient_constant_falls_back_to_a_lyapunov_bound():
    """Too much work for the exact peak: the Lyapunov bound, never below the exact constant."""
    rng = np.random.default_rng(1)
    # upper triangular: eigenvalues on the diagonal (radius 0.49 < 0.5), far from normal above it
    M = np.diag([0.49, 0.48, 0.3, 0.2, -0.4, 0.1]) + np.triu(rng.normal(size=(6, 6)), 1) * 0.5
    exact = transient_constant(M, 0.5)
    capped = transient_constant(M, 0.5, max_work=2 * 6 ** 3 * 3)  # three steps only
    assert exact.method == "exact" and capped.method.startswith("Lyapunov bound")
    assert capped.constant >= exact.constant * (1 - 1e-9)


@pytest.mark.parametrize("example", ["paper_discrete", "paper_continuous"])
def test_the_constant_bounds_the_simulated_errors(example):
    """||e(k)|| <= c r^k ||e(0)|| along a noise-free simulation on the constant graph, and c is nearly attained."""
    des = design(load_scenario(EXAMPLES / f"{example}.yaml"))
    c = conditioning(des).transient_constant
    assert 1.0 <= c < 1e3
    sc = des.scenario
    r = sc.design.rate if sc.time == "discrete" else math.exp(-sc.design.rate * sc.run.dt)
    worst = 0.0
    for seed in range(20):
        tr = simulate(des, seed=seed, noise=False, steps=200)
        e = np.linalg.norm((tr.xhat - tr.x[:, None, :]).reshape(len(tr.t), -1), axis=1)
        ratio = e / (e[0] * r ** np.arange(len(e)))
        # only while the bound is above round-off (the discrete plant grows like 2^(k/2): its round-off too)
        live = c * e[0] * r ** np.arange(len(e)) > 1e-9 * np.maximum(1.0, np.linalg.norm(tr.x, axis=1))
        assert live[:20].all()
        assert ratio[live].max() <= c * (1 + 1e-9), (seed, ratio[live].max(), c)
        worst = max(worst, ratio[live].max())
    assert worst >= 0.1 * c  # random initial errors get within a factor 10 of the worst case


def test_full_error_matrix_is_eq_split_discrete_error():
    """M = blkdiag(A + K_i C_i) (I - P (I - S (x) I))^q, from the pieces by hand for the paper's example."""
    des = design(load_scenario(EXAMPLES / "paper_discrete.yaml"))
    sc = des.scenario
    A = np.asarray(sc.system.A)
    S = des.graphs[0].S
    M = full_error_matrix(A, sc.system.Cs, des.Ks, des.Ps, S, time="discrete", q=des.q)
    n, m = 4, 3
    big_P = np.zeros((m * n, m * n))
    big_F = np.zeros((m * n, m * n))
    for i in range(m):
        big_P[i * n:(i + 1) * n, i * n:(i + 1) * n] = des.Ps[i]
        big_F[i * n:(i + 1) * n, i * n:(i + 1) * n] = A + des.Ks[i] @ sc.system.Cs[i]
    W = np.eye(m * n) - big_P @ (np.eye(m * n) - np.kron(S, np.eye(n)))
    # the same products in another grouping: 1e-12 of their size
    ref = big_F @ np.linalg.matrix_power(W, des.q)
    assert np.max(np.abs(M - ref)) <= 1e-12 * np.max(np.abs(ref))
    # its spectral radius is the split certificate's (prop. errordis: the spectrum is that of the blocks)
    rho = np.max(np.abs(np.linalg.eigvals(M)))
    assert rho == pytest.approx(max(des.q_result.bound, max(abs(p) for a in des.agents for p in a.gain.poles)),
                                rel=1e-9)


# --------------------------------------------------------------------------
# margins and gain sizes in the report
# --------------------------------------------------------------------------


def test_margins_and_gain_norms_of_the_paper_example(capsys):
    """C_i = e_i' on two oscillators: each agent's margin is 1, decided on its own oscillator's time scale (the
    oscillators are two clusters of A's spectrum, splitspec_core.model.modal): C_i X_k has norm 1 and the rotation
    (A_k - 0 I) / ||A_k|| takes it to the other direction of the pair with a full step."""
    path = EXAMPLES / "paper_discrete.yaml"
    assert cli.main(["design", str(path), "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    K = yaml.safe_load(path.read_text())["design"]["K"]
    for a in out["agents"]:
        assert a["observability_margin"] == pytest.approx(1.0, rel=1e-5)  # balanced to 1e-6 (modal.BALANCE_TOL)
        assert a["gain_norm"] == pytest.approx(np.linalg.norm(K[a["id"]]), rel=1e-12)
        assert a["weak_margin"] == 0.0 and a["split_residual"] < 1e-12
    assert out["split_exact"] is True and out["full_error_matrix"] == {}
    assert 1.0 <= out["transient_constant"] < 100 and out["transient"]["method"].endswith("exact")
    assert out["rank_tol"] == "auto" and out["predicted_rms"] is None  # no noise in this scenario
    assert cli.main(["design", str(path)]) == 0
    text = capsys.readouterr().out
    assert "margin 1, |K| 1.06" in text and f"c = {out['transient_constant']:.3g}" in text


def test_predicted_noise_is_in_the_design_and_matches_monte_carlo(capsys):
    """design --json's steady-state RMS is the Lyapunov solution, and a Monte Carlo of simulate agrees with it."""
    path = EXAMPLES / "ring10_noise.yaml"
    assert cli.main(["design", str(path), "--json"]) == 0
    out = json.loads(capsys.readouterr().out)["predicted_rms"]
    des = design(load_scenario(path))
    pred = predicted_rms(des)
    got = np.array([out["agents"][str(i)] for i in des.scenario.agent_ids])
    assert np.allclose(got, pred, rtol=1e-12) and out["all"] == pytest.approx(np.sqrt(np.mean(pred ** 2)), rel=1e-12)
    # 40 seeds x 400 steps after a 100-step transient, errors correlated over ~5 steps: ~3000 independent samples
    # per agent; the RMS over agents and samples is then within ~2% (4 standard deviations: 6%)
    sq = []
    for seed in range(40):
        tr = simulate(des, seed=seed, steps=500)
        sq.append(tr.errors()[100:] ** 2)
    measured = float(np.sqrt(np.mean(np.concatenate(sq))))
    assert measured == pytest.approx(out["all"], rel=0.06)


# --------------------------------------------------------------------------
# warnings name the agent and the knob
# --------------------------------------------------------------------------


def oscillators(time: str = "discrete"):
    """Two oscillators (discrete rotations or continuous), distinct frequencies."""
    if time == "discrete":
        r = lambda w: [[math.cos(w), math.sin(w)], [-math.sin(w), math.cos(w)]]  # noqa: E731
    else:
        r = lambda w: [[0.0, w], [-w, 0.0]]  # noqa: E731
    A = np.zeros((4, 4))
    A[:2, :2], A[2:, 2:] = r(0.7), r(1.3)
    return A


def two_agents(C1, C2, **design_keys) -> dict:
    return {"name": "weak", "time": "discrete",
            "system": {"A": oscillators().tolist(), "C": {1: [list(C1)], 2: [list(C2)]}},
            "graphs": {"g": {"undirected": [[1, 2]]}},
            "design": {"rate": 0.5, "gains": "place", **design_keys}}


def test_a_forced_tolerance_counts_a_weak_direction_and_warns():
    """Agent 1 sees the second oscillator through a 1e-6 coupling: auto leaves it to consensus; forcing
    rank_tol below it counts it, and the warnings say what it costs (margin, gain, transient)."""
    raw = two_agents([1, 0, 1e-6, 0], [0, 0, 1, 0])
    auto = design(parse_scenario(raw))
    assert [a.dec.n_unobservable for a in auto.agents] == [2, 2]
    # left out, and reported: the coupling against |C_1| in balanced coordinates (a power of 2 of the user's)
    assert 2.5e-7 <= auto.agents[0].dec.weak <= 4e-6
    assert not auto.split_exact and auto.full_radius  # the rate then checked on the full error matrix
    assert any("agent(s) 1 left a weakly observable direction" in w for w in auto.warnings)
    forced = design(parse_scenario(two_agents([1, 0, 1e-6, 0], [0, 0, 1, 0], rank_tol=1e-9)))
    assert forced.agents[0].dec.n_unobservable == 0
    cond = conditioning(forced)
    assert cond.agents[0].observability_margin < 1e-5
    assert cond.agents[0].gain_norm > 1e4 * cond.agents[1].gain_norm
    text = " ".join(cond.warnings)
    assert "agent 1 sees a direction with an observability margin of only" in text and "design.rank_tol" in text
    assert "agent 1: ||K_i C_i|| is" in text
    assert "errors can grow" in text
    # what to do about it: each knob designed on the scenario and measured (synthesis/advice.py), not a list of names
    from splitspec_core.synthesis.advice import advice

    tried = {t.knob: t for t in advice(forced)}
    assert any(k.startswith("design.rate") for k in tried) and any(k.startswith("design.rank_tol") for k in tried)
    rank = next(t for k, t in tried.items() if k.startswith("design.rank_tol"))
    assert rank.transient is not None and rank.transient < cond.transient_constant  # consensus takes the weak one
    # and the same through the public report
    assert all(w.count("\n") == 0 for w in cond.warnings)
