"""`splitspec run` on a misbehaving network: real processes lose, cut and wait for messages as `simulate` says.

Injected losses and partitions are drawn from the scenario seed (splitspec_core.model.impairment), so a run and its
simulation lose the same messages; a deadline with delayed messages makes some arrive too late for real, and the
replay of what the run recorded (`simulate --faults-from RUN`) gives the run's trajectory.
"""

import numpy as np
import pytest

from tests.integration.runtime_helpers import (all_pids, assert_all_gone, compare_trajectories, compare_with_simulate,
                                               events, replay, run, scenario_file)

pytestmark = pytest.mark.slow


def lost_of(path) -> tuple:
    with np.load(path) as f:
        return f["lost"].copy(), f["lost_cause"].copy()


def test_a_lossy_ring_loses_what_simulate_loses(tmp_path):
    """ring10, every consensus message lost with probability 0.1: the same lost rows, the same trajectory."""
    scen = scenario_file(tmp_path, "ring10", network={"loss": 0.1}, run={"steps": 40})
    out = tmp_path / "out"
    r = run("run", scen, "--out", out)
    assert r.returncode == 0, r.stdout + r.stderr
    sim = tmp_path / "sim"
    compare_with_simulate(out, scen, tmp_path)
    lost, cause = lost_of(out / "trajectory.npz")
    s_lost, s_cause = lost_of(sim / "trajectory.npz")
    # 40 event times x q sub-rounds x 24 arcs x 0.1: several hundred, every one drawn lost (cause 0)
    assert len(lost) > 300 and set(cause.tolist()) == {0}
    assert np.array_equal(lost, s_lost) and np.array_equal(cause, s_cause)  # exact: the same integer draws
    summaries = [e for e in events(out) if e["event"] == "messages_lost"]
    assert sum(e["count"] for e in summaries) == len(lost)
    assert len({e["tau"] for e in summaries}) == len(summaries)  # one line per event time, not per message
    assert_all_gone(all_pids(out))


def test_each_agent_counts_the_messages_it_used_as_simulate_does(tmp_path):
    """A per-agent row column (messages_used: the neighbours' consensus messages agent i counted in round tau)
    through the row schema alone: computed by every agent process and by the simulator, equal; in trajectory.npz,
    in the chunks and in run.rrd; on a lossy ring it is q times the in-degree less what did not count."""
    from splitspec_core.api import design, load_scenario
    from splitspec_core.simulation.trajectory_chunks import read_chunks
    from tests.rrd_readback import read_rrd, verify_rrd

    scen = scenario_file(tmp_path, "ring10", network={"loss": 0.1}, run={"steps": 30})
    out = tmp_path / "out"
    r = run("run", scen, "--out", out)
    assert r.returncode == 0, r.stdout + r.stderr
    compare_with_simulate(out, scen, tmp_path)  # every reported column too: run == simulate
    with np.load(out / "trajectory.npz") as f, np.load(tmp_path / "sim" / "trajectory.npz") as s:
        used, ids, lost, alive = f["messages_used"], f["agent_ids"].tolist(), f["lost"], f["alive"]
        assert np.array_equal(used, s["messages_used"])  # exact: integer counts of the same draws
    sc = load_scenario(scen)
    q = int(design(sc).q)
    indegree = np.array([sum(1 for j, i in sc.graphs[0].arcs if i == a and j != a) for a in ids])
    missed = np.zeros_like(used)
    for tau, _k, _j, i in lost.tolist():
        missed[tau, ids.index(i)] += 1
    assert alive.all() and missed.sum() > 50  # nobody dies here; the losses do show in the counts
    np.testing.assert_array_equal(used[:-1], q * indegree[None, :] - missed[:-1])  # exact: integer counts
    assert (used[-1] == -1).all()  # the last row has no round: the column's fill
    np.testing.assert_array_equal(read_chunks(out)["messages_used"], used)  # the chunks hold the same rows
    ok, msg = verify_rrd(out / "run.rrd")
    assert ok, msg
    series = read_rrd(out / "run.rrd")
    for k, a in enumerate(ids):  # one series per agent, every row with a round, the values of the npz
        got = series[f"messages_used/agent_{a}"]
        assert [tau for tau, _ in got] == list(range(len(used) - 1))
        np.testing.assert_array_equal([v for _, v in got], used[:-1, k])


def test_a_partition_splits_and_heals_in_a_run(tmp_path):
    """ring10_partition: the cut side stops converging while cut; both reconverge after the heal; = simulate."""
    out = tmp_path / "out"
    scen = scenario_file(tmp_path, "ring10_partition")
    r = run("run", scen, "--out", out)
    assert r.returncode == 0, r.stdout + r.stderr
    compare_with_simulate(out, scen, tmp_path)
    names = [(e["event"], e.get("tau")) for e in events(out)]
    assert ("partition", 5) in names and ("healed", 35) in names
    with np.load(out / "trajectory.npz") as f:
        e = np.linalg.norm(f["xhat"] - f["x"][:, None, :], axis=2)
        ids = f["agent_ids"].tolist()
        cause = f["lost_cause"]
    side_a = [ids.index(a) for a in (1, 2, 3, 9, 10)]
    assert e[34, side_a].min() > 1e-2 and np.nanmax(e[-1]) < 1e-6 * np.nanmax(e[34])
    assert set(cause.tolist()) == {2}


def test_late_messages_are_recorded_and_replayed(tmp_path):
    """A deadline shorter than the delays: many messages really arrive late; the run records them and the replay of
    its records equals it (what a simulation cannot know: how late each one really was)."""
    scen = scenario_file(tmp_path, "ring10", network={"delay": {"mean": 0.002, "jitter": 0.001}, "deadline": 0.0025},
                         run={"steps": 30})
    out = tmp_path / "out"
    r = run("run", scen, "--out", out)
    assert r.returncode == 0, r.stdout + r.stderr
    lost, cause = lost_of(out / "trajectory.npz")
    # delays uniform in 1..3 ms against a 2.5 ms deadline: about a quarter late by the draw alone, more for real
    assert (cause == 1).sum() > 0.1 * 30 * 6 * 24, np.bincount(cause)
    # the run says so on the terminal, with the replay command
    counts = np.bincount(cause, minlength=3)
    assert f"network: {len(lost)} consensus messages did not count ({counts[1]} late)" in r.stdout \
        or f"({counts[0]} loss, {counts[1]} late)" in r.stdout, r.stdout
    assert f"--faults-from {out}" in r.stdout
    diff = replay(out, tmp_path)
    assert diff <= 1e-9
    rep, rep_cause = lost_of(tmp_path / "sim" / "trajectory.npz")
    assert np.array_equal(rep, lost) and np.array_equal(rep_cause, cause)
    # and without the record, the simulation (which can only emulate lateness) is a different trajectory
    emulated = tmp_path / "emulated"
    assert run("simulate", scen, "--out", emulated, "--no-plots").returncode == 0
    with pytest.raises(AssertionError):
        compare_trajectories(out / "trajectory.npz", emulated / "trajectory.npz")
