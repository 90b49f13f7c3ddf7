"""Pure parts of fault handling: verdicts at a loss, replay of recorded events, the run registry."""

import dataclasses
import json

import numpy as np
import pytest
import yaml

from splitspec_core.synthesis.designer import design
from splitspec_core.synthesis.survivors import certify_network
from splitspec_core.errors import ScenarioError
from splitspec_core.model.network import NetworkState, active_arcs, consensus_rows, make_plan
from splitspec_core.scenarios.replay import faults_from_events, load_events, with_recorded_faults
from splitspec_core.scenarios.load import load_scenario
from splitspec_core.simulation.simulator import simulate
from tests.conftest import EXAMPLES


@pytest.fixture(scope="module")
def paper():
    return design(load_scenario(EXAMPLES / "paper_discrete.yaml"))


@pytest.fixture(scope="module")
def ring():
    return design(load_scenario(EXAMPLES / "ring10.yaml"))


def test_verdict_non_redundant_loss(paper):
    v = certify_network(paper, [1, 2])  # agent 3 alone sees the second oscillator
    assert v["jointly_observable"] is False and v["ok"] is False and v["rate_certified"] is False
    assert v["unobservable_direction"]
    v = certify_network(paper, [2, 3])  # agent 2 sees the first oscillator: still fine
    assert v["ok"] and v["rate_certified"] and v["certificate"].startswith("q = 6")


def full_error_radius(des, alive) -> float:
    """rho of the survivors' one-event-time error map F (I - P + P (S (x) I))^q, from the full matrices."""
    sc = des.scenario
    rows = consensus_rows(sc, 0, alive)
    pos = {a: k for k, a in enumerate(alive)}
    n, m = sc.n, len(alive)
    ad = {a.id: a for a in des.agents}
    W = np.zeros((m * n, m * n))
    F = np.zeros((m * n, m * n))
    for i in alive:
        r = slice(pos[i] * n, pos[i] * n + n)
        P = ad[i].P
        W[r, r] += np.eye(n) - P
        for j, w in zip(*rows[i]):
            W[r, pos[j] * n:pos[j] * n + n] += w * P
        C = sc.system.Cs[sc.agent_ids.index(i)]
        F[r, r] = sc.system.A + ad[i].K @ C
    return float(np.max(np.abs(np.linalg.eigvals(F @ np.linalg.matrix_power(W, des.q)))))


def test_verdict_matches_the_full_error_map(ring, paper):
    """A certified verdict at a loss means the survivors' full mn x mn error map contracts at the rate."""
    for des in (ring, paper):
        sc = des.scenario
        for lost in sc.agent_ids:
            alive = [a for a in sc.agent_ids if a != lost]
            v = certify_network(des, alive)
            if v["jointly_observable"]:
                # the full mn x mn map against the split one: radii agree to round-off only (another matrix,
                # another eigenvalue problem), so a radius within 1e-9 of the rate decides nothing here
                rho = full_error_radius(des, alive)
                if abs(rho - sc.design.rate) > 1e-9:
                    assert v["rate_certified"] == (rho < sc.design.rate), (lost, rho, v)
    # ring10 is designed with resilience: 1, so every single loss stays certified
    assert all(certify_network(ring, [a for a in ring.scenario.agent_ids if a != x])["ok"]
               for x in ring.scenario.agent_ids)


def test_verdict_after_link_failures(ring):
    sc = ring.scenario
    # cutting the ring on both sides of agent 2 (uniform weights: one direction each) isolates it
    v = certify_network(ring, sc.agent_ids, {(1, 2), (3, 2)})
    assert v["strongly_connected"] == {"ring": False} and v["unreachable"]["ring"][1] == 2 and not v["ok"]
    v = certify_network(ring, sc.agent_ids, {(1, 6)})
    assert v["ok"]


@pytest.mark.parametrize("weights, gone", [("metropolis", {(1, 2), (2, 1)}),  # a failed link: both directions
                                           ("uniform", {(1, 2)})])  # one arc of a directed view
def test_active_arcs_metropolis_drops_both_directions(tmp_path, weights, gone):
    raw = yaml.safe_load((EXAMPLES / "ring10.yaml").read_text())  # undirected: metropolis weights apply
    raw["design"]["weights"] = weights
    path = tmp_path / "ring10.yaml"
    path.write_text(yaml.safe_dump(raw))
    sc = load_scenario(path)
    assert sc.design.weights == weights
    arcs = active_arcs(sc, 0, {(1, 2)})
    assert set(sc.graphs[0].arcs) - set(arcs) == gone and len(arcs) == len(sc.graphs[0].arcs) - len(gone)


def test_network_state_lose_and_rejoin():
    sc = load_scenario(EXAMPLES / "paper_discrete.yaml")
    net = NetworkState(sc)
    assert net.lose(1) and not net.lose(1)
    assert net.alive_ids() == [1, 3]
    assert net.rejoin(1) == 1 and net.rejoin(1) is None and net.rejoin(1) is None
    assert net.lose(1) and net.rejoin(1) == 2


def test_replay_events_reproduce_scenario_faults():
    """Events a run would log for the scenario's faults give the same trajectory as the faults themselves."""
    sc = load_scenario(EXAMPLES / "ring10_faults.yaml")
    evs = []
    for f in sc.faults:
        name = {"kill": "agent_lost", "freeze": "agent_lost", "restart": "agent_rejoined",
                "drop_arc": "arc_dropped", "restore_arc": "arc_restored"}[f.action]
        e = {"event": name, "tau": int(f.at)}
        e.update({"id": f.agent} if hasattr(f, "agent") else {"arc": list(f.arc)})
        evs.append(e)
    evs.insert(0, {"event": "process_started", "role": "agent", "id": 1})  # ignored
    replayed = faults_from_events(evs, sc)
    assert [f.action for f in replayed] == ["kill", "drop_arc", "kill", "restart", "restart", "restore_arc"]
    a = simulate(design(sc))
    b = simulate(design(dataclasses.replace(sc, faults=replayed)))
    # exact: the replayed faults equal the scenario's, so the same simulation runs twice, step for step
    np.testing.assert_array_equal(a.alive, b.alive)
    np.testing.assert_array_equal(a.xhat, b.xhat)


def test_replay_continuous_time_uses_dt():
    sc = load_scenario(EXAMPLES / "paper_continuous.yaml")
    (f,) = faults_from_events([{"event": "agent_lost", "id": 2, "tau": 40}], sc)
    assert f.at == pytest.approx(40 * sc.run.dt)
    plan = make_plan(dataclasses.replace(sc, faults=(f,)), 0)
    assert list(plan.faults) == [40]


def test_load_events_errors(tmp_path):
    p = tmp_path / "events.jsonl"
    p.write_text('{"event": "a"}\n[1, 2]\n{"event": "b"}\n')
    with pytest.raises(ScenarioError, match=r"events.jsonl:2: not a splitspec event"):
        load_events(p)
    p.write_text('{"event": "a"}\n{"event": "agent_lo')  # torn last line of a crashed run
    assert load_events(p) == [{"event": "a"}]
    sc = load_scenario(EXAMPLES / "paper_discrete.yaml")
    with pytest.raises(ScenarioError, match="no valid 'tau'"):
        faults_from_events([{"event": "agent_lost", "id": 1}], sc)
    with pytest.raises(ScenarioError, match="bad 'arc'"):
        faults_from_events([{"event": "arc_dropped", "tau": 1, "arc": [1, 9]}], sc)
    p.write_text(json.dumps({"event": "orchestrator_started", "scenario": "other"}) + "\n")
    with pytest.raises(ScenarioError, match="records scenario 'other'"):
        with_recorded_faults(sc, p)
