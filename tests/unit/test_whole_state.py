"""The whole-state design (splitspec_core/synthesis/whole_state.py): gains, certificate, noise, the estimator that
runs it, the agent that runs it, and the choice between it and the paper's split."""

import dataclasses
import math

import numpy as np
import pytest
import scipy.linalg as sla

import splitspec_core as ss
from splitspec_agents.agent import AgentNode
from splitspec_core.errors import DesignError, ScenarioError
from splitspec_core.model import steps as st
from splitspec_core.runtime.wire import encode, new_run_key
from splitspec_core.simulation.montecarlo import simulate_seeds
from splitspec_core.simulation.simulator import simulate
from splitspec_core.synthesis.designer import design, highest_rate
from splitspec_core.synthesis.error_matrix import block_diagonal, full_error_matrix, predicted_rms, whole_matrix
from splitspec_core.synthesis.kalman import kalman_predictor, shifted_predictor, spectral_radius
from splitspec_core.synthesis.report import design_json, design_text
from splitspec_core.synthesis.survivors import certify_network
from splitspec_core.synthesis.verdict import rate_certificate
from splitspec_core.synthesis.mixing import mixing_bound
from splitspec_core.synthesis.whole_state import _no_centralized, agent_gain
from tests.conftest import EXAMPLES

OSC = [[0.955336, 0.29552], [-0.29552, 0.955336]]  # a lightly rotating oscillator, radius 1


def two_agents(**design_keys):
    """One oscillator seen by two agents (each its own coordinate), process and measurement noise."""
    return ss.scenario(name="two", time="discrete", A=OSC, C={1: [[1, 0]], 2: [[0, 1]]}, process_noise=0.1,
                       measurement_noise=0.2, graphs={"g": [(1, 2), (2, 1)]}, steps=40, seed=3,
                       **{"rate": 0.8, **design_keys})


def ring(**design_keys):
    sc = ss.load_scenario(EXAMPLES / "ring10_noise.yaml")
    keys = {"gains": "optimal", "consensus": "whole", "resilience": 0, "K": None, **design_keys}
    return dataclasses.replace(sc, design=dataclasses.replace(sc.design, **keys))


def continuous(**design_keys):
    return ss.scenario(name="cont", time="continuous", A=[[0, 1, 0, 0], [-1, 0, 0, 0], [0, 0, 0, 1], [0, 0, -2, 0]],
                       C={1: [[1, 0, 0, 0]], 2: [[0, 1, 0, 0]], 3: [[0, 0, 1, 0]]}, process_noise=0.25,
                       measurement_noise=0.05, graphs={"a": [(1, 2), (2, 1), (2, 3), (3, 2), (1, 3)]},
                       dt=0.01, steps=200, seed=7, **{"rate": 1.0, **design_keys})


# ------------------------------------------------------------------------------------------------- the gains


def test_the_gains_are_the_kalman_predictors_columns_over_the_consensus_weights():
    """K_i = -L_i / pi_i with L the Kalman predictor of the plant's per-step model: with every estimate agreeing, the
    weighted average of the agents' updates is the centralized predictor (module docstring)."""
    sc = two_agents(gains="optimal", consensus="whole")
    des = design(sc)
    F, C = np.array(OSC), np.array([[1.0, 0.0], [0.0, 1.0]])
    kf = kalman_predictor(F, C, 0.01 * np.eye(2), 0.04 * np.eye(2))
    assert des.consensus == "whole" and des.whole.alpha == 1.0  # the Kalman filter already beats the rate
    pi = des.whole.pi
    np.testing.assert_allclose(pi, [0.5, 0.5], rtol=1e-12)  # two agents hearing each other: uniform weights
    for k, a in enumerate(des.agents):
        np.testing.assert_allclose(a.K, -kf.L[:, [k]] / pi[k], rtol=1e-10)
        np.testing.assert_array_equal(a.P, np.eye(2))
    # the averaged update of agreeing estimates is the centralized one: sum_i pi_i (F_i x - K_i y_i)
    x, y = np.array([0.3, -1.2]), np.array([0.5, 0.7])
    avg = sum(pi[k] * (st.measurement_update(x, F + a.K @ C[[k]], a.K, y[[k]])) for k, a in enumerate(des.agents))
    np.testing.assert_allclose(avg, (F - kf.L @ C) @ x + kf.L @ y, rtol=1e-12, atol=1e-14)


def test_the_shifted_predictor_meets_its_shift_and_alpha_one_is_the_kalman_filter():
    F, C = np.array(OSC) * 1.05, np.array([[1.0, 0.0]])
    Q, R = 0.01 * np.eye(2), np.array([[0.04]])
    kf = kalman_predictor(F, C, Q, R)
    for alpha in (0.9, 0.5, 0.2):
        p = shifted_predictor(F, C, Q, R, alpha)
        assert p.radius < alpha and p.rms >= kf.rms * (1 - 1e-12)  # faster, never less noisy than the Kalman filter
        # P is the true steady covariance of that gain: P = (F - L C) P (F - L C)' + Q + L R L'
        Ac = F - p.L @ C
        np.testing.assert_allclose(p.P, Ac @ p.P @ Ac.T + Q + p.L @ R @ p.L.T, rtol=1e-9, atol=1e-14)
    np.testing.assert_array_equal(shifted_predictor(F, C, Q, R, 1.0).L, kf.L)


def test_the_whole_state_error_matrix_has_the_papers_spectrum():
    """W^q blkdiag(F_i) (update, then average) and blkdiag(F_i) W^q (eq. split-discrete-error with P_i = I) share
    their eigenvalues: the certificate of the rate is the paper's."""
    des = design(ring())
    sc = des.scenario
    S, q = des.graphs[0].S, des.q
    M = full_error_matrix(sc.system.A, sc.system.Cs, des.Ks, des.Ps, S, time="discrete", q=q, consensus="whole")
    paper = full_error_matrix(sc.system.A, sc.system.Cs, des.Ks, [np.eye(sc.n)] * sc.m, S, time="discrete", q=q)
    ours, theirs = np.sort_complex(np.linalg.eigvals(M)), np.sort_complex(np.linalg.eigvals(paper))
    np.testing.assert_allclose(np.abs(ours), np.abs(theirs), atol=1e-9)
    assert spectral_radius(M) < sc.design.rate and rate_certificate(des).certified


def test_q_is_the_smallest_certified_then_raised_only_while_the_noise_falls():
    des = design(ring())
    sc = des.scenario
    w = des.whole
    Fs = [sc.system.A + K @ C for K, C in zip(des.Ks, sc.system.Cs)]
    S = des.graphs[0].S
    assert spectral_radius(whole_matrix(Fs, S, w.q_certified)) < sc.design.rate
    assert spectral_radius(whole_matrix(Fs, S, w.q_certified - 1)) >= sc.design.rate
    rms = {q: float(np.sqrt(np.mean(predicted_rms(design(ring(q=q))) ** 2))) for q in (des.q, des.q + 1)}
    assert des.q >= w.q_certified and rms[des.q + 1] > rms[des.q] * (1 - 0.01)  # one more exchange: < 1 % better


# ---------------------------------------------------------------------------------------------- noise, measured


@pytest.mark.long
@pytest.mark.parametrize("make", [two_agents, continuous], ids=["discrete", "continuous"])
def test_the_predicted_steady_rms_is_what_a_monte_carlo_measures(make):
    des = design(make(gains="optimal", consensus="whole"))
    pred = predicted_rms(des)
    runs = simulate_seeds(des, range(300), steps=400)
    tail = runs.sq_error[:, 200:] / runs.alive_count[:, 200:]  # mean square error over agents, per step
    per_seed = tail.mean(axis=1)
    mean, se = per_seed.mean(), per_seed.std(ddof=1) / math.sqrt(len(per_seed))
    assert abs(mean - np.mean(pred ** 2)) < 4 * se + 1e-12, (mean, np.mean(pred ** 2), se)


def test_near_the_centralized_kalman_filter_where_the_split_is_not():
    sc = ss.load_scenario(EXAMPLES / "ring10_noise.yaml")
    sc = dataclasses.replace(sc, design=dataclasses.replace(sc.design, resilience=0, gains="optimal", K=None))
    des = design(sc)
    split = design(dataclasses.replace(sc, design=dataclasses.replace(sc.design, consensus="split")))
    kf = des.whole.kf_rms
    ours = float(np.sqrt(np.mean(predicted_rms(des) ** 2)))
    theirs = float(np.sqrt(np.mean(predicted_rms(split) ** 2)))
    assert des.consensus == "whole" and "auto chose the whole state" in des.chosen
    assert ours < 1.1 * kf < theirs  # measured: 1.02x against 1.6x


# ------------------------------------------------------------------------------------------- the estimator


@pytest.mark.parametrize("make", [two_agents, continuous], ids=["discrete", "continuous"])
def test_batch_and_loop_estimators_agree_through_a_kill_and_a_restart(make):
    sc = make(gains="optimal", consensus="whole", faults=[{"at": 5 if make is two_agents else 0.05, "kill": 2},
                                                          {"at": 9 if make is two_agents else 0.09, "restart": 2}])
    des = design(sc)
    a = simulate(des, estimator="batch")
    b = simulate(des, estimator="loop")
    np.testing.assert_array_equal(a.alive, b.alive)
    assert not a.alive[7, 1] and a.alive[-1].all()
    # the same step functions, summed in another order (sparse products against loops): round-off only
    np.testing.assert_allclose(a.xhat, b.xhat, rtol=1e-11, atol=1e-12)


def test_continuous_time_runs_q_exchanges_per_step_on_the_sampled_model():
    des = design(continuous(gains="optimal", consensus="whole", q=2))
    sc = des.scenario
    assert des.g is None and des.q == 2 and des.two_rate
    tr = simulate(des, steps=1, noise=False)
    E, D, _ = st.sampled_data_matrices(np.asarray(sc.system.A), sc.run.dt)
    x = tr.x[0]
    Z = np.stack([E @ tr.xhat[0, i] + D @ (des.Ks[i] @ (sc.system.Cs[i] @ tr.xhat[0, i] - sc.system.Cs[i] @ x))
                  for i in range(sc.m)])
    S = des.graphs[0].S
    expected = S @ (S @ Z)  # two exchanges: z <- S z
    np.testing.assert_allclose(tr.xhat[1], expected, rtol=1e-12, atol=1e-12)


# ------------------------------------------------------------------------------------------- the agent process

KEY = new_run_key()


def test_the_agent_process_runs_the_loop_estimators_round():
    """An AgentNode fed its neighbour's messages computes the loop estimator's x_i(1) from the gain the design sent."""
    sc = two_agents(gains="optimal", consensus="whole")
    des = design(sc)
    text = ("name: two\ntime: discrete\nsystem:\n  A: [[0.955336, 0.29552], [-0.29552, 0.955336]]\n"
            "  C: {1: [[1, 0]], 2: [[0, 1]]}\n  process_noise: 0.1\n  measurement_noise: 0.2\n"
            "graphs:\n  g: {arcs: [[1, 2], [2, 1]]}\ndesign: {rate: 0.8, gains: optimal, consensus: whole}\n"
            "run: {steps: 40, seed: 3}\n")
    cfg = {"scenario": text, "seed": 3, "g": None, "q": des.q, "g_mode": None, "key": KEY, "gain": agent_gain(des, 1)}
    node = AgentNode(1, cfg, "r")
    rows = {"1": [[1, 2], [0.5, 0.5]]}
    out = node.on_tick(encode("tick", "r", mac_key=KEY, tau=0, attempt=0, graph=0, final=False, alive=[1, 2],
                              rows=rows, incarnation={"1": 0}, fresh=True, prev_attempt=0, topology=1, partition=[]))
    assert [k for k, _ in out] == ["splitspec/r/xhat/1"]  # admission; z(0) waits for y_1(0)
    x1 = node.x.copy()
    y = np.array([0.4, -0.3])
    out = node.on_y(encode("y", "r", mac_key=KEY, tau=0, attempt=0, y=y))
    assert [k for k, _ in out] == ["splitspec/r/z/1"]  # the updated estimate, z_1(0)
    z2 = np.array([0.25, 0.5])
    for k in range(des.q):
        out = node.on_z("splitspec/r/z/2", encode("z", "r", mac_key=KEY, tau=0, attempt=0, k=k, agent=2, z=z2))
    assert out[-1][0] == "splitspec/r/xhat/1" and node.candidate.tau == 1
    F1 = np.array(OSC) + des.Ks[0] @ np.array([[1.0, 0.0]])
    z = st.measurement_update(x1, F1, des.Ks[0], y[:1])
    for _ in range(des.q):  # the neighbour's z stays z2 in this round (its messages say so)
        z = st.weighted_average([z, z2], [0.5, 0.5])
    np.testing.assert_array_equal(node.candidate.x, z)  # the same functions on the same floats, in the same order


# -------------------------------------------------------------------------------------- certificates, verdicts


def test_the_mixing_bound_holds_under_arbitrary_switching():
    """Two doubly stochastic graphs switched at random: every product of the maps decays at least as fast as the
    mixing bound says."""
    A = np.array(OSC)
    Cs = [np.array([[1.0, 0.0]]), np.array([[0.0, 1.0]]), np.array([[1.0, 0.0]])]
    kf = kalman_predictor(A, np.vstack(Cs), 0.01 * np.eye(2), 0.04 * np.eye(3))
    Fs = [A - 3 * kf.L[:, [k]] @ C for k, C in enumerate(Cs)]
    S1 = np.array([[0.5, 0.5, 0], [0.5, 0, 0.5], [0, 0.5, 0.5]])
    S2 = np.array([[2 / 3, 0, 1 / 3], [0, 2 / 3, 1 / 3], [1 / 3, 1 / 3, 1 / 3]])
    q = 8
    bound = mixing_bound(Fs, [S1, S2], q, 0.99)
    assert bound < 0.99
    rng = np.random.default_rng(1)
    Ms = [whole_matrix(Fs, S, q) for S in (S1, S2)]
    P = np.eye(6)
    for t in range(1, 201):
        P = Ms[rng.integers(2)] @ P
    assert np.linalg.norm(P, 2) ** (1 / 200) <= bound * 1.05  # the constant of the comparison system aside
    # a row-stochastic graph that is not doubly stochastic gets no mixing bound
    assert mixing_bound(Fs, [np.array([[0.5, 0.5, 0], [1 / 3, 1 / 3, 1 / 3], [0, 0.5, 0.5]])], q, 0.99) == math.inf


def test_the_runtime_verdict_keeps_the_gains_and_judges_the_survivors():
    des = design(ring())
    whole = certify_network(des, des.scenario.agent_ids)
    assert whole["rate_certified"] and "whole-state consensus" in whole["certificate"]
    # agent 5 alone sees x2 well: without it the kept gains leave the survivors' average too slow (radius 0.83)
    lost5 = certify_network(des, [i for i in des.scenario.agent_ids if i != 5])
    assert lost5["rate_certified"] is False and ">=" in lost5["certificate"]
    lost1 = certify_network(des, [i for i in des.scenario.agent_ids if i != 1])
    assert lost1["rate_certified"] is True


def test_resilience_falls_back_to_the_split_and_says_why():
    sc = ss.load_scenario(EXAMPLES / "ring10_noise.yaml")  # resilience: 1
    sc = dataclasses.replace(sc, design=dataclasses.replace(sc.design, gains="optimal", K=None))
    des = design(sc)
    assert des.consensus == "split" and "the whole state failed" in des.chosen
    assert "without agent 5" in des.chosen  # what limits the whole state, named


def test_a_refusal_names_the_fastest_rate_its_keys_certify():
    sc = ss.load_scenario(EXAMPLES / "paper_discrete.yaml")  # explicit gains: observable-part poles 0.2 and 0.3
    sc = dataclasses.replace(sc, design=dataclasses.replace(sc.design, rate=0.25))
    with pytest.raises(ss.SplitspecError) as info:
        design(sc)
    assert "the fastest rate these design keys certify is about" in str(info.value)
    reach = highest_rate(sc)
    ok = design(dataclasses.replace(sc, design=dataclasses.replace(sc.design, rate=reach.rate)))
    assert rate_certificate(ok).certified
    with pytest.raises(ss.SplitspecError):
        design(dataclasses.replace(sc, design=dataclasses.replace(sc.design, rate=reach.refused)))



def test_a_centralized_refusal_says_what_it_computed():
    """No centralized Riccati design at the rate: the slowest mode no agent sees when it is the reason (a third
    state nobody measures, decaying at 0.9 per step, against 0.85 per step; the designer itself designs such a
    scenario at its envelope's rate, so the message is read from the function), else the seen modes (as the IEEE 14-bus
    model at 30 /s says: its unseen modes decay at radius 0.368 per 20 ms, the Riccati equation fails all the same)."""
    F = np.array([[*OSC[0], 0], [*OSC[1], 0], [0, 0, 0.9]])
    why = _no_centralized(0.85, F, [np.array([[1.0, 0, 0]]), np.array([[0, 1.0, 0]])])
    assert "a mode no agent sees decays with radius 0.9 per event time" in why
    why = _no_centralized(0.95, F, [np.array([[1.0, 0, 0]]), np.array([[0, 1.0, 0]])])
    assert "too weakly observable" in why and "radius 0.9)" in why

# ------------------------------------------------------------------------------------------------ keys, reports


@pytest.mark.parametrize("keys, message", [
    # the words the whole state takes (scenarios/gain_methods.py: whole set), place not among them
    ({"gains": "place", "consensus": "whole"}, r"design.consensus: whole takes design.gains riccati, [a-z, ]*explicit "
                                               r"or optimal \(place sets the split's local poles\)"),
    ({"consensus": "both"}, "design.consensus must be one of auto, split, whole"),
])
def test_bad_consensus_keys_are_one_line(keys, message):
    with pytest.raises(ScenarioError, match=message):
        two_agents(**keys)


def test_noise_decides_the_default_gains_and_optimal_needs_noise():
    assert two_agents().design.gains == "optimal"
    quiet = dict(name="q", time="discrete", A=OSC, C={1: [[1, 0]], 2: [[0, 1]]}, graphs={"g": [(1, 2), (2, 1)]},
                 rate=0.8)
    assert ss.scenario(**quiet).design.gains == "place"
    with pytest.raises(ScenarioError, match="design.gains: optimal minimizes the error under noise"):
        ss.scenario(**quiet, gains="optimal")


def test_continuous_whole_takes_q_and_refuses_g():
    assert continuous(consensus="whole", q=3).design.q == 3
    with pytest.raises(ScenarioError, match="design.g is the split design's consensus gain"):
        continuous(consensus="whole", g=5)
    with pytest.raises(ScenarioError, match="design.q is for discrete time and the whole-state design"):
        continuous(gains="place", q=3)


def test_the_report_says_what_each_agent_corrects_and_takes_and_against_which_references():
    des = design(two_agents())
    text = design_text(des)
    assert "agent 1: s_i = 1, corrects locally x1, x2; takes every state from its neighbours" in text
    assert "x the centralized Kalman filter's" in text and "auto chose the whole state" in text
    js = design_json(des)
    assert js["consensus"] == "whole" and js["whole_state"]["alpha"] == 1.0
    assert js["predicted_rms"]["ratio_to_kalman"] == pytest.approx(js["predicted_rms"]["all"] / js["predicted_rms"]["kalman"])
    assert js["agents"][0]["P"] == np.eye(2).tolist()


def test_a_split_design_for_the_noise_sends_its_gain_too():
    """design.gains: optimal that chose the split still sends K_i and P_i: an agent cannot compute them from the
    scenario (its gains are the Riccati design the designer picked), so the simulator's floats travel."""
    sc = ss.load_scenario(EXAMPLES / "ring10_noise.yaml")
    des = design(dataclasses.replace(sc, design=dataclasses.replace(sc.design, gains="optimal", K=None)))
    g = agent_gain(des, 3)
    assert g["consensus"] == "split"
    np.testing.assert_array_equal(np.array(g["K"]), des.agents[2].K)
    np.testing.assert_array_equal(np.array(g["P"]), des.agents[2].P)
    assert agent_gain(design(sc), 3) is None  # gains: place: every agent computes its own


def test_block_diagonal_and_full_matrix_sizes():
    assert block_diagonal([np.ones((2, 2)), np.ones((1, 1))]).shape == (3, 3)
    assert sla.block_diag(np.ones((2, 2))).shape == (2, 2)
