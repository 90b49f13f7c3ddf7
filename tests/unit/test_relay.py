"""The relay kind (``design.consensus: relay``, issue 44): each agent the Kalman predictor of the samples it holds.

The oracles here share no code with the product: the textbook augmented-state Riccati equation for the protocol's
limit, and the error recursion written out from the design's gains for the simulator's noise-free steps."""

from __future__ import annotations

import dataclasses
import json
import math

import numpy as np
import pytest
import scipy.linalg as sla

import splitspec_core as ss
from splitspec_orchestrator import cli
from splitspec_core.errors import DesignError, ScenarioError
from splitspec_core.simulation.simulator import simulate
from splitspec_core.synthesis.designer import design
from splitspec_core.synthesis.exchange_limit import hop_distances, information_delays, scenario_limit
from splitspec_core.synthesis.relay import design_relay, scenario_relay, survivors_radius
from splitspec_core.synthesis.report import design_json, design_text
from splitspec_core.synthesis.verdict import rate_certificate
from tests.conftest import EXAMPLES


def ring(q=1, **keys):
    sc = ss.load_scenario(EXAMPLES / "ring10_noise.yaml")
    d = dict(consensus="relay", gains="optimal", q=q, resilience=0, K=None)
    d.update(keys)
    return dataclasses.replace(sc, design=dataclasses.replace(sc.design, **d))


def small_system(seed=0, n=4, m=4):
    rng = np.random.default_rng(seed)
    F = rng.normal(size=(n, n))
    F *= 1.05 / max(abs(np.linalg.eigvals(F)))  # one mode unstable: the sensors must work
    Cs = [rng.normal(size=(1, n)) for _ in range(m)]
    Q = np.diag(rng.uniform(0.1, 1.0, n))
    Rs = [np.array([[rng.uniform(0.1, 1.0)]]) for _ in range(m)]
    arcs = [(i, (i + 1) % m) for i in range(m)] + [((i + 1) % m, i) for i in range(m)]
    return F, Cs, Q, Rs, hop_distances(m, arcs)


def augmented_limit(F, Cs, Q, Rs, delays_i):
    """Agent i's steady prediction covariance of x(tau + 1), from the textbook augmented state
    (x(tau), .., x(tau - D)) and one DARE: the oracle of the relay kind at alpha = 1."""
    n, D = F.shape[0], int(max(delays_i))
    N = n * (D + 1)
    Fa = np.zeros((N, N))
    Fa[:n, :n] = F
    for d in range(1, D + 1):
        Fa[d * n:(d + 1) * n, (d - 1) * n:d * n] = np.eye(n)
    rows = []
    for C, d in zip(Cs, delays_i):
        row = np.zeros((C.shape[0], N))
        row[:, d * n:(d + 1) * n] = C
        rows.append(row)
    Ca = np.vstack(rows)
    Ra = sla.block_diag(*Rs)
    Qa = np.zeros((N, N))
    Qa[:n, :n] = Q
    Qa += 1e-12 * np.eye(N)  # the delayed copies carry no noise of their own
    P = sla.solve_discrete_are(Fa.T, Ca.T, Qa, Ra)
    return P[:n, :n]


@pytest.mark.parametrize("q", [1, 2])
def test_each_agent_is_the_kalman_predictor_of_what_the_protocol_delivers(q):
    """At alpha = 1 agent i's covariance is the augmented-state DARE's: the protocol's limit, met exactly."""
    F, Cs, Q, Rs, dist = small_system()
    des = design_relay(F, Cs, Q, Rs, dist, q)
    delays = information_delays(dist, q)
    assert des.alpha == 1.0 and des.D == int(delays.max())
    for i in range(len(Cs)):
        want = augmented_limit(F, Cs, Q, Rs, delays[i])
        assert np.allclose(des.agent_P[i], want, rtol=1e-6, atol=1e-8), i
    assert des.ratio == pytest.approx(des.limit, rel=1e-7)


def test_a_rate_faster_than_the_kalman_predictor_is_certified_by_the_shifted_base():
    F, Cs, Q, Rs, dist = small_system(seed=2)
    free = design_relay(F, Cs, Q, Rs, dist, 1)
    lam = 0.8 * free.radius
    des = design_relay(F, Cs, Q, Rs, dist, 1, lam)
    C = np.vstack(Cs)
    assert des.alpha < 1.0 and des.certified
    assert des.radius == pytest.approx(max(abs(np.linalg.eigvals(F - des.L @ C))), rel=1e-12) and des.radius < lam
    assert des.ratio > free.ratio  # speed costs accuracy
    assert math.isfinite(des.transient_constant)


def oracle_errors(des, C, e0, steps):
    """Noise-free errors of one agent written out: the walk from the initial error for the first D event times,
    then the base's map F - L C and the walk's maps, from the design's gains alone."""
    F, L = des.F, des.L

    def walk_map(i, lag):
        rows, Lw = des.walk[i][lag]
        return F - Lw @ C[rows]

    out = {}
    for i, e in e0.items():
        D = des.D
        errs = [e]
        base = e
        for tau in range(steps):
            if tau >= D:  # the base's own step, then the walk from lag D - 1
                base = (F - L @ C) @ base
                x = base
                for lag in range(D - 1, -1, -1):
                    x = walk_map(i, lag) @ x
            else:  # the base holds the initial estimate; the walk from lag tau
                x = base
                for lag in range(tau, -1, -1):
                    x = walk_map(i, lag) @ x
            errs.append(x)
        out[i] = np.array(errs)
    return out


def test_the_simulator_is_the_error_recursion_written_out_and_the_envelope_holds():
    sc = ring(q=1)
    des = design(sc)
    steps = 40
    tr = simulate(des, steps=steps + 1, noise=False)
    C = np.vstack([np.asarray(Ci, dtype=float) for Ci in sc.system.Cs])
    e = tr.xhat - tr.x[:, None, :]
    want = oracle_errors(des.whole, C, {i: e[0, i] for i in range(sc.m)}, steps)
    lam, c = des.whole.lam_step, des.whole.transient_constant
    for i in range(sc.m):
        # the same recursion, summed in another order: round-off apart
        assert np.allclose(e[:steps + 1, i], want[i], rtol=1e-9, atol=1e-9 * np.abs(e[0, i]).max()), i
        norms = np.linalg.norm(e[:, i], axis=1)
        assert np.all(norms <= c * lam ** np.arange(len(norms)) * norms[0] * (1 + 1e-9)), i


def test_the_measured_steady_error_is_the_predicted_one():
    sc = ring(q=2)
    des = design(sc)
    tr = simulate(des, steps=4000, seed=11)
    e = tr.xhat[200:] - tr.x[200:, None, :]
    measured = float(np.sqrt(np.mean(np.sum(e ** 2, axis=2))))
    predicted = float(np.sqrt(np.mean(des.whole.agent_rms ** 2)))
    # 3800 correlated steps x 10 agents: a few percent of sampling error
    assert measured == pytest.approx(predicted, rel=0.05)


def test_the_design_report_and_json_say_what_it_sends_and_what_certifies_it():
    sc = ring(q=2)
    des = design(sc)
    assert des.consensus == "relay" and des.q == 2 and des.two_rate
    cert = rate_certificate(des)
    assert cert.certified and cert.by == "base error map" and "relay" in cert.text
    j = json.loads(json.dumps(design_json(des)))
    p = sum(np.shape(C)[0] for C in sc.system.Cs)
    assert j["relay"]["q"] == 2 and j["relay"]["certified"] and j["consensus"] == "relay"
    assert j["relay"]["limit"] == pytest.approx(scenario_limit(sc, 2).ratio, rel=1e-12)
    assert j["relay"]["ratio_to_kalman"] == pytest.approx(j["relay"]["limit"], rel=1e-6)  # alpha = 1: the limit
    assert j["exchanges"]["messages"] == 2 and j["exchanges"]["numbers"] == p
    assert j["predicted_rms"]["ratio_to_kalman"] == pytest.approx(des.whole.ratio, rel=1e-9)
    text = design_text(des)
    assert "consensus on the sensors' samples, passed on (relay)" in text
    assert f"carrying at most {p} numbers in all" in text
    assert "rate certified: q = 2: spectral radius of the base's error map" in text


def test_the_kinds_steps_run_batched_or_looped_with_a_kill_and_a_restart():
    faults = ss.load_scenario(EXAMPLES / "ring10_faults.yaml").faults
    sc = dataclasses.replace(ring(q=1), faults=faults)
    des = design(sc)
    a = simulate(des, steps=80, estimator="batch")
    b = simulate(des, steps=80, estimator="loop")
    assert not a.alive.all()
    assert np.array_equal(a.xhat, b.xhat, equal_nan=True)  # the same code in the same order: exactly
    err = np.linalg.norm(a.xhat[-1] - a.x[-1], axis=1)
    assert np.all(np.isfinite(err)) and err.max() < 10 * np.sqrt(des.whole.kf_P_trace)


def test_the_survivors_verdict_leaves_the_lost_sensors_out():
    sc = ring(q=1)
    des = design(sc)
    arcs = {sc.graph_names[0]: list(sc.graphs[0].arcs)}
    every = survivors_radius(des, tuple(sc.agent_ids), arcs)
    assert every == pytest.approx(des.whole.radius, rel=1e-9)
    without = survivors_radius(des, tuple(sc.agent_ids[1:]), arcs)
    assert without != pytest.approx(every)


def test_one_graph_only_and_noise_on_every_output_each_refused_in_one_line(tmp_path, capsys):
    import yaml

    raw = yaml.safe_load((EXAMPLES / "ring10_noise.yaml").read_text())
    raw["design"] = {"rate": 0.8, "consensus": "relay", "q": 1}
    path = tmp_path / "s.yaml"
    path.write_text(yaml.safe_dump(raw))
    assert cli.main(["design", str(path)]) == 0
    raw["system"]["measurement_noise"] = 0.0
    path.write_text(yaml.safe_dump(raw))
    with pytest.raises(ScenarioError, match="relay chooses its gains for the noise"):
        ss.load_scenario(path)
    capsys.readouterr()
    assert cli.main(["design", str(path)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "design.consensus: relay chooses its gains for the noise" in err[0], err
    two = ss.scenario(A=[[0.9, 0.2], [0, 0.8]], C={1: [[1, 0]], 2: [[0, 1]]},
                      graphs={"a": [(1, 2), (2, 1)], "b": [(1, 2), (2, 1)]}, rate=0.5, process_noise=0.1,
                      measurement_noise=0.1, consensus="relay", q=1)
    with pytest.raises(DesignError, match="needs one fixed graph"):
        scenario_relay(two, 1, None)


def test_an_agent_holds_only_samples_that_fit_their_values_and_their_window():
    """The ``r`` message on the wire, and what an agent process makes of it (agents/agent.py's RelayPart)."""
    from splitspec_agents.agent import RelayPart
    from splitspec_core.runtime.wire import WireError, decode, encode
    from splitspec_core.synthesis.relay import agent_relay

    sc = ring(q=1)
    des = design(sc)
    part = RelayPart(agent_relay(des, sc.agent_ids[0]), sc, 0)
    assert part.D == des.whole.D == 3
    payload = encode("r", "run", tau=7, attempt=0, k=0, agent=2, z=np.array([0.5, -1.0]), samples=[1, 7, 2, 5])
    m = decode(payload, "run", "r")
    got = part.parse(m, sc.m)
    assert got is not None and list(got) == [(1, 7), (2, 5)] and got[(2, 5)].tolist() == [-1.0]
    assert part.parse(dict(m, samples=[1, 7, 2, 3]), sc.m) is None  # t = 3 is before tau - D = 4
    assert part.parse(dict(m, samples=[1, 7]), sc.m) is None  # a value left over
    assert part.parse(dict(m, samples=[1, 7, 10, 7]), sc.m) is None  # no sensor 10 among 10 agents
    assert part.parse(dict(m, samples=[1, 7, 1, 7]), sc.m) is None  # the same sample twice
    bad = encode("r", "run", tau=7, attempt=0, k=0, agent=2, z=np.array([0.5]), samples=[1])
    with pytest.raises(WireError, match="samples"):
        decode(bad, "run", "r")


def test_a_lagged_base_buys_back_the_accuracy_the_rate_s_shift_costs_and_stays_certified():
    """The platoon is slower than its rate: the shifted base alone is 1.25x the KF at q = 3 (D = 0); kept behind
    (design.lag: auto) its walk's Kalman steps bring it within 2 % of the protocol's limit, the certificate (the base's
    radius) unchanged and the envelope's constant larger; more lag never hurts."""
    base = ss.load_scenario(EXAMPLES / "platoon.yaml")

    def at(lag):
        return dataclasses.replace(base, design=dataclasses.replace(base.design, consensus="relay", q=3, lag=lag,
                                                                    gains="optimal", resilience=0, K=None))

    none, auto = design(at(0)).whole, design(at("auto")).whole
    assert none.alpha < 1.0 and none.lag == 0 and auto.lag > 0 and auto.D == auto.lag  # every sensor in time at q = 3
    assert none.radius == auto.radius < auto.lam_step  # the same base, certified
    assert auto.ratio < none.ratio and auto.ratio <= 1.02 * auto.limit
    ratios = [design(at(k)).whole.ratio for k in (0, 2, 5)]
    assert ratios == sorted(ratios, reverse=True)
    assert auto.transient_constant > none.transient_constant
    tr = simulate(design(at("auto")), steps=60, noise=False)  # the envelope of the lagged design holds
    e = np.linalg.norm(tr.xhat - tr.x[:, None, :], axis=2)
    bound = auto.transient_constant * auto.lam_step ** np.arange(e.shape[0])[:, None] * e[0]
    assert np.all(e <= bound * (1 + 1e-9))


def test_design_lag_is_the_relay_kind_s_alone(tmp_path):
    import yaml

    raw = yaml.safe_load((EXAMPLES / "ring10_noise.yaml").read_text())
    raw["design"] = {"rate": 0.8, "consensus": "whole", "q": 1, "lag": 3}
    path = tmp_path / "s.yaml"
    path.write_text(yaml.safe_dump(raw))
    with pytest.raises(ScenarioError, match="design.lag is the relay kind's"):
        ss.load_scenario(path)
    raw["design"]["consensus"] = "relay"
    path.write_text(yaml.safe_dump(raw))
    des = design(ss.load_scenario(path))
    assert des.whole.lag == 3 and des.whole.D == des.whole.delays.max() + 3
