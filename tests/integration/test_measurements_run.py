"""`splitspec run --measurements FILE`: the plant process plays the user's file, and the run equals
`splitspec simulate --measurements FILE` to round-off, with the truth or without it (then the records hold
residuals, disagreement and the distance to the centralized Kalman filter)."""

import numpy as np
import pytest
import yaml

from splitspec_core.scenarios.measurements import load_measurements, write_measurements
from splitspec_core.scenarios.load import load_scenario
from tests.integration.runtime_helpers import all_pids, assert_all_gone, compare_with_simulate, events, run

pytestmark = pytest.mark.slow


def hidden(tmp_path, seed: int = 4):
    """A random noisy system written as a scenario file (5 agents, n = 6)."""
    from tests.unit.test_measurements import hidden_scenario

    sc = hidden_scenario(seed)
    raw = {"name": sc.name, "time": "discrete",
           "system": {"A": np.asarray(sc.system.A).tolist(), "C": {i: np.asarray(C).tolist()
                                                                   for i, C in zip(sc.agent_ids, sc.system.Cs)},
                      "process_noise": 0.02, "measurement_noise": 0.05},
           "graphs": {"a": {"arcs": [list(a) for a in sc.graphs[0].arcs]}},
           "design": {"rate": 0.8, "gains": "place"}, "run": {"steps": 30, "seed": seed}}
    path = tmp_path / "hidden.yaml"
    path.write_text(yaml.safe_dump(raw))
    return path, load_scenario(path)


def test_a_run_on_recorded_measurements_equals_simulate(tmp_path):
    scen, sc = hidden(tmp_path)
    sim = tmp_path / "sim0"
    meas = tmp_path / "m.npz"
    r = run("simulate", scen, "--out", sim, "--no-plots", "--write-measurements", meas, "--steps", 35)
    assert r.returncode == 0, r.stderr
    out = tmp_path / "out"
    r = run("run", scen, "--out", out, "--measurements", meas)
    assert r.returncode == 0, r.stdout + r.stderr
    # the file decides the steps (35, not run.steps 30); the run equals its simulation on the same file
    compare_with_simulate(out, scen, tmp_path, 1e-9, "--measurements", meas)
    with np.load(out / "trajectory.npz") as f, np.load(sim / "trajectory.npz") as g:
        assert f["xhat"].shape[0] == 36
        # and the estimates of the original simulation (its plant drew these very measurements)
        assert np.nanmax(np.abs(f["xhat"] - g["xhat"])) <= 1e-9 * np.nanmax(np.abs(g["xhat"]))
        assert np.array_equal(f["x"], g["x"])  # the truth the file carries, passed through unchanged
    assert_all_gone(all_pids(out))


def test_a_run_without_truth_and_with_gaps(tmp_path):
    """CSV without x; agent 2 has no measurement at event times 5..9: it predicts there, in the run as in simulate."""
    scen, sc = hidden(tmp_path, seed=6)
    sim = tmp_path / "sim0"
    r = run("simulate", scen, "--out", sim, "--no-plots", "--write-measurements", tmp_path / "full.npz")
    assert r.returncode == 0, r.stderr
    full = load_measurements(tmp_path / "full.npz", sc)
    missing = full.missing.copy()
    missing[5:10, 1] = True
    csv = tmp_path / "blind.csv"
    write_measurements(csv, t=full.t, y=full.y, agent_ids=sc.agent_ids, sizes=[np.shape(C)[0] for C in sc.system.Cs],
                       missing=missing)
    out = tmp_path / "out"
    r = run("run", scen, "--out", out, "--measurements", csv)
    assert r.returncode == 0, r.stdout + r.stderr
    assert "consensus disagreement" in r.stdout and "(the file has no truth)" in r.stdout
    compare_with_simulate(out, scen, tmp_path, 1e-9, "--measurements", csv)
    with np.load(out / "trajectory.npz") as f:
        assert np.isnan(f["x"]).all() and np.array_equal(f["y_missing"], missing)
        assert np.isnan(f["residual"][5:10, 1]).all() and np.isfinite(f["residual"][:5, 1]).all()
        assert f["disagreement"][-1] < 0.5 * f["disagreement"][0]
        assert f["kf"].shape == (31, sc.n) and np.isfinite(f["kf_distance"]).all()
    assert not any(e["event"] == "agent_lost" for e in events(out))  # a missing measurement is not a fault


def test_sensor_faults_on_a_file_run_equal_simulate_and_record_what_was_given(tmp_path):
    """A file with a gap, and sensors lying on it (stuck across the gap, noisy and biased): the plant process
    corrupts the file's rows as simulate does, and both record the same y, what the estimators were given (not
    the file's), the gap left as it is."""
    scen, sc = hidden(tmp_path, seed=6)
    r = run("simulate", scen, "--out", tmp_path / "sim0", "--no-plots", "--write-measurements", tmp_path / "full.npz")
    assert r.returncode == 0, r.stderr
    full = load_measurements(tmp_path / "full.npz", sc)
    missing = full.missing.copy()
    missing[5:10, 1] = True
    meas = tmp_path / "gap.npz"
    write_measurements(meas, t=full.t, y=full.y, agent_ids=sc.agent_ids, sizes=[np.shape(C)[0] for C in sc.system.Cs],
                       missing=missing, x=full.x)
    raw = yaml.safe_load(scen.read_text())
    raw["faults"] = [{"at": 8, "corrupt": sc.agent_ids[1], "for": 10, "stuck": True},
                     {"at": 4, "corrupt": sc.agent_ids[3], "noise": 0.2, "bias": 0.1}]
    lying = tmp_path / "lying.yaml"
    lying.write_text(yaml.safe_dump(raw))
    out = tmp_path / "out"
    r = run("run", lying, "--out", out, "--measurements", meas)
    assert r.returncode == 0, r.stdout + r.stderr
    compare_with_simulate(out, lying, tmp_path, 1e-9, "--measurements", meas)  # y and y_missing: exact
    with np.load(out / "trajectory.npz") as f:
        y, given = load_measurements(meas, sc).y, f["y"]
        rows = np.cumsum([0] + [np.shape(C)[0] for C in sc.system.Cs])
        a2, a4 = slice(rows[1], rows[2]), slice(rows[3], rows[4])
        np.testing.assert_array_equal(given[5:10, a2], y[5:10, a2])  # the gap, as the file has it
        np.testing.assert_array_equal(given[10:18, a2], np.repeat(y[4:5, a2], 8, axis=0))  # held: y(4), before the gap
        assert not np.allclose(given[4:, a4], y[4:, a4] + 0.1) and np.array_equal(given[:4], y[:4])
        np.testing.assert_array_equal(given[18:, a2], y[18:, a2])  # repaired


def test_a_bad_measurements_file_starts_nothing(tmp_path):
    scen, _ = hidden(tmp_path)
    bad = tmp_path / "bad.csv"
    bad.write_text("t,y1.1\n0,1\n1,2\n")
    out = tmp_path / "out"
    r = run("run", scen, "--out", out, "--measurements", bad)
    assert r.returncode == 2 and r.stderr.count("\n") == 1 and "header has no column y2.1" in r.stderr, r.stderr
    assert not out.exists()
