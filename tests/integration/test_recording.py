"""`splitspec run examples/ring10_faults.yaml` read back from run.rrd: what the default recording shows."""

from __future__ import annotations

import numpy as np
import pytest

from tests.conftest import EXAMPLES
from tests.integration.runtime_helpers import compare_with_simulate, events, run, scenario_file
from tests.rrd_readback import (read_blueprint, read_rrd, read_rrd_clears, read_rrd_logs, read_rrd_nodes,
                                read_rrd_state, rrd_entities, verify_rrd)

pytestmark = pytest.mark.slow

IDS = list(range(1, 11))
N = 8


@pytest.fixture(scope="module")
def ring10(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("ring10")
    out = tmp / "out"
    r = run("run", EXAMPLES / "ring10_faults.yaml", "--out", out, timeout=300)
    assert r.returncode == 0, r.stdout + r.stderr
    return out, tmp


def test_entities_and_blueprint(ring10):
    out, _ = ring10
    rrd = out / "run.rrd"
    ok, msg = verify_rrd(rrd)
    assert ok, msg
    ents = rrd_entities(rrd)
    want = {"errors/max", "errors_log10/max", "errors_log10/envelope", "topology", "topology/graph", "events",
            "rounds/wall_ms", "rounds/attempts", "rounds/rejected", "marks/lost", "marks/rejoined", "marks/fault"}
    want |= {f"errors/agent_{a}" for a in IDS} | {f"errors_log10/agent_{a}" for a in IDS}
    want |= {f"state/{k}/truth" for k in range(1, N + 1)} | {f"state/{k}/agents" for k in range(1, N + 1)}
    assert want <= ents, sorted(want - ents)
    # one batch entity per state component, not one entity per agent and component
    assert {e for e in ents if e.startswith("state/")} == {e for e in want if e.startswith("state/")}
    assert not any(e.startswith("gains/") for e in ents)  # discrete time: no g
    series = read_rrd(rrd)
    # rounds: every event time has its diagnostics
    assert len(series["rounds/wall_ms"]) == 61 and all(v >= 0 for _, v in series["rounds/wall_ms"])
    assert all(v >= 1 for _, v in series["rounds/attempts"])
    # the blueprint travels in the file: log errors first, per-component state views, topology, event log
    bp = read_blueprint(rrd)
    views = {name: (cls, origin) for cls, name, origin in bp["views"]}
    assert views["log10 |x_i - x|, designed envelope, marks"] == ("TimeSeries", "/")
    assert views["communication graph"] == ("Graph", "topology")
    assert views["events"] == ("TextLog", "events")
    assert {views[f"x{k}: truth and estimates"][1] for k in range(1, N + 1)} == {f"state/{k}" for k in
                                                                                   range(1, N + 1)}
    assert {"series", "states", "rounds"} <= set(bp["containers"])


def test_log_errors_equal_the_trajectory(ring10):
    out, _ = ring10
    series = read_rrd(out / "run.rrd")
    with np.load(out / "trajectory.npz") as f:
        err = np.linalg.norm(f["xhat"] - f["x"][:, None, :], axis=2)
        alive = f["alive"]
    for i, a in enumerate(IDS):
        got = dict(series[f"errors_log10/agent_{a}"])
        assert sorted(got) == [k for k in range(err.shape[0]) if alive[k, i]]
        np.testing.assert_allclose([got[k] for k in sorted(got)], np.log10(err[sorted(got), i]), rtol=0, atol=1e-9)
    lmax = dict(series["errors_log10/max"])
    np.testing.assert_allclose([lmax[k] for k in range(err.shape[0])], np.log10(np.nanmax(err, axis=1)),
                               rtol=0, atol=1e-9)
    env = dict(series["errors_log10/envelope"])
    assert sorted(env) == list(range(err.shape[0]))
    assert env[30] == pytest.approx(lmax[30], abs=1e-12)  # restarts at the rejoin of agent 3, at the max error


def test_every_loss_clears_the_agents_series_and_is_marked(ring10):
    out, _ = ring10
    rrd = out / "run.rrd"
    clears = read_rrd_clears(rrd)
    lost = [e for e in events(out) if e["event"] == "agent_lost"]
    assert [(e["id"], e["tau"]) for e in lost] == [(3, 10), (5, 20)]
    state = read_rrd_state(rrd)
    for e in lost:
        a, tau = e["id"], e["tau"]
        for path in [f"errors/agent_{a}", f"errors_log10/agent_{a}"]:
            assert tau in clears.get(path, []), (path, clears.get(path))
        for k in range(1, N + 1):  # no estimate drawn at the loss: NaN in the state batch, beside recorded ones
            assert tau not in dict(state[f"state/{k}/agent_{a}"])
            assert tau in dict(state[f"state/{k}/truth"]) and tau in dict(state[f"state/{k}/agent_1"])
    series = read_rrd(rrd)
    assert [tau for tau, _ in series["marks/lost"]] == [10, 20]
    assert [tau for tau, _ in series["marks/rejoined"]] == [30, 35]
    assert [tau for tau, _ in series["marks/fault"]] == [15, 40]  # arc 1 -> 6 dropped and restored
    texts = [text for _, _, text in read_rrd_logs(rrd)["events"]]
    assert any(t.startswith("agent 3 lost: killed by the scenario (SIGKILL") for t in texts)
    assert "agent 3 rejoined (incarnation 1)" in texts and "arc 1 -> 6 dropped" in texts


def test_topology_positions_greys_and_dropped_arc(ring10):
    out, _ = ring10
    rrd = out / "run.rrd"
    nodes = read_rrd_nodes(rrd)
    first = nodes[0][2]
    assert len(set(first)) == 10 and all(p == first_p for (_, _, ps, _) in nodes for p, first_p in zip(ps, first))
    by_tau = {tau: labels for tau, _, _, labels in nodes}
    assert "agent 3 (lost)" in by_tau[10] and "agent 5 (lost)" in by_tau[20]
    topo = {tau: edges for tau, _, edges in read_rrd_logs(rrd)["topology"]}
    assert not any(3 in e for e in topo[10])  # a lost agent's arcs are gone
    assert (1, 6) not in topo[15] and (1, 6) in topo[40]  # the dropped arc is absent until restored
    assert read_rrd_nodes(rrd, "topology/graph")[0][3] == ["graph: ring"]


def test_g_and_trajectory_equal_simulate(ring10):
    out, tmp = ring10
    with np.load(out / "trajectory.npz") as f:
        assert f["g"].shape == f["alive"].shape and np.isnan(f["g"]).all()  # discrete time: no g
    compare_with_simulate(out, EXAMPLES / "ring10_faults.yaml", tmp)


def test_adaptive_gain_run_logs_gains_and_no_envelope(tmp_path):
    """Continuous time, adaptive g (no certified rate): gains/agent_<i> equal trajectory.npz's g, no envelope."""
    scen = scenario_file(tmp_path, "paper_continuous", run={"steps": 60}, design={"g": "adaptive", "g0": 1.0})
    out = tmp_path / "out"
    r = run("run", scen, "--out", out, timeout=300)
    assert r.returncode == 0, r.stdout + r.stderr
    rrd = out / "run.rrd"
    ents = rrd_entities(rrd)
    assert "errors_log10/envelope" not in ents and "errors_log10/max" in ents
    series = read_rrd(rrd)
    with np.load(out / "trajectory.npz") as f:
        g, ids = f["g"], f["agent_ids"].tolist()
    assert np.isfinite(g).all()  # nobody dies here: every agent has its g_i(t)
    for i, a in enumerate(ids):
        got = series[f"gains/agent_{a}"]
        assert [tau for tau, _ in got] == list(range(g.shape[0]))
        np.testing.assert_allclose([v for _, v in got], g[:, i], rtol=0, atol=1e-12)
    assert np.all(np.diff(g, axis=0) >= 0)  # eq. (adaptive): g_i never decreases
    compare_with_simulate(out, scen, tmp_path)
    bp = read_blueprint(rrd)
    assert ("TimeSeries", "adaptive gains g_i", "gains") in bp["views"]
