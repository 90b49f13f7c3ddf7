"""The user's own measurements: files read back exactly, estimates equal to the simulation's, what is known
without truth, and bad files refused in one line before anything runs."""

import csv
import json

import numpy as np
import pytest

from splitspec_core.synthesis.designer import design
from splitspec_core.errors import ScenarioError
from splitspec_core.scenarios.generate import random_strongly_connected_arcs, random_system
from splitspec_core.scenarios.measurements import load_measurements, write_measurements
from splitspec_core.studies.no_truth import disagreement, kalman_reference, no_truth_arrays
from splitspec_core.scenarios.load import load_scenario, parse_scenario
from splitspec_core.simulation.simulator import simulate
from tests.conftest import EXAMPLES
from tests.integration.runtime_helpers import run


def hidden_scenario(seed: int, time: str = "discrete"):
    """A random system the code has never seen: 5 agents, n = 6, noisy, on a random strongly connected graph."""
    rng = np.random.default_rng(seed)
    A, Cs = random_system(rng, 5, 6, time=time)
    arcs = random_strongly_connected_arcs(rng, 5, extra=4)
    d = {"rate": 0.8, "gains": "place"} if time == "discrete" else {"rate": 0.5, "gains": "place", "g": "auto"}
    return parse_scenario({
        "name": f"hidden{seed}", "time": time,
        "system": {"A": A.tolist(), "C": {i + 1: C.tolist() for i, C in enumerate(Cs)},
                   "process_noise": 0.02, "measurement_noise": 0.05},
        "graphs": {"a": {"arcs": [[j + 1, i + 1] for j, i in arcs]}},
        "design": d, "run": {"steps": 80 if time == "discrete" else 1500, "seed": seed,
                             **({"dt": 0.01} if time == "continuous" else {})}})


def sizes_of(sc):
    return [np.shape(C)[0] for C in sc.system.Cs]


@pytest.mark.parametrize("time", ["discrete", "continuous"])
@pytest.mark.parametrize("ext", ["npz", "csv"])
def test_measurements_of_a_simulation_reproduce_its_estimates(tmp_path, time, ext):
    sc = hidden_scenario(11, time)
    des = design(sc)
    tr = simulate(des, keep_y=True)
    path = tmp_path / f"m.{ext}"
    write_measurements(path, t=tr.t, y=tr.y, agent_ids=sc.agent_ids, sizes=sizes_of(sc), x=tr.x)
    meas = load_measurements(path, sc)
    # exact: the CSV holds repr() of each float64 (17 digits), which reads back to the same bits
    assert np.array_equal(meas.y, tr.y) and np.array_equal(meas.x, tr.x) and meas.steps == len(tr.t) - 1
    again = simulate(des, measurements=meas)
    # exact: the same y through the same operations in the same order as the simulated plant's run
    assert np.array_equal(again.xhat, tr.xhat, equal_nan=True) and np.array_equal(again.x, tr.x)
    # without the truth: the same estimates, x unknown (NaN), and what can be known instead
    path2 = tmp_path / f"notruth.{ext}"
    write_measurements(path2, t=tr.t, y=tr.y, agent_ids=sc.agent_ids, sizes=sizes_of(sc))
    blind = simulate(des, measurements=load_measurements(path2, sc))
    assert np.array_equal(blind.xhat, tr.xhat, equal_nan=True) and np.isnan(blind.x).all() and not blind.has_truth
    ref = no_truth_arrays(blind, sc)
    assert ref["residual"].shape == (len(tr.t), sc.m) and ref["kf"].shape == (len(tr.t), sc.n)
    # the estimates agree with one another and with the centralized filter far better at the end than at start
    assert ref["disagreement"][-10:].max() < 0.2 * ref["disagreement"][0]
    assert np.nanmax(ref["kf_distance"][-10:]) < 0.2 * np.nanmax(ref["kf_distance"][0])


def test_the_centralized_kalman_filter_is_the_better_reference():
    """On a noisy hidden system with its truth: the centralized KF's steady error is below every agent's (it sees
    every measurement at once), and the residual of agent i is y_i - C_i x_i recomputed here."""
    sc = hidden_scenario(5)
    des = design(sc)
    tr = simulate(des, keep_y=True, steps=400)
    ref = no_truth_arrays(tr, sc)
    tail = slice(200, None)
    kf_rms = np.sqrt(np.mean(np.linalg.norm(ref["kf"][tail] - tr.x[tail], axis=1) ** 2))
    agent_rms = np.sqrt(np.mean(tr.errors()[tail] ** 2, axis=0))
    assert kf_rms < agent_rms.min(), (kf_rms, agent_rms)
    C2 = np.asarray(sc.system.Cs[1])
    r = slice(sizes_of(sc)[0], sizes_of(sc)[0] + C2.shape[0])
    assert ref["residual"][37, 1] == pytest.approx(np.linalg.norm(tr.y[37, r] - C2 @ tr.xhat[37, 1]), rel=1e-12)
    # disagreement: the largest pairwise distance, by brute force
    X = tr.xhat[37]
    brute = max(np.linalg.norm(a - b) for a in X for b in X)
    assert disagreement(tr.xhat[37:38])[0] == pytest.approx(brute, rel=1e-12)


def test_a_missing_measurement_means_prediction_only(tmp_path):
    """Agent 2 has no measurement at rows 10..19 (empty CSV cells): its update there is A z_i(q), recomputed here
    through the per-agent step functions (the loop estimator), the batch simulator agreeing to round-off."""
    sc = hidden_scenario(3)
    des = design(sc)
    tr = simulate(des, keep_y=True)
    missing = np.zeros((len(tr.t), sc.m), dtype=bool)
    missing[10:20, 1] = True
    path = tmp_path / "gap.csv"
    write_measurements(path, t=tr.t, y=tr.y, agent_ids=sc.agent_ids, sizes=sizes_of(sc), missing=missing)
    text = path.read_text().splitlines()
    assert text[11].split(",")[1 + sizes_of(sc)[0]] == ""  # the empty cells are in the file
    meas = load_measurements(path, sc)
    assert np.array_equal(meas.missing, missing)
    batch = simulate(des, measurements=meas)
    loop = simulate(des, measurements=meas, estimator="loop")
    scale = np.nanmax(np.abs(loop.xhat))
    assert np.nanmax(np.abs(batch.xhat - loop.xhat)) <= 1e-12 * scale  # batched vs per-agent: round-off
    assert not np.allclose(batch.xhat[20:, 1], tr.xhat[20:, 1])  # the gap changed agent 2's estimates
    # exact: before the gap the simulator's step runs the same operations on the same y (a missing row only
    # changes the rows of the agents without a measurement, from their step on)
    assert np.array_equal(batch.xhat[:11], tr.xhat[:11], equal_nan=True)
    # and an NPZ says the same with missing_<id>
    npz = tmp_path / "gap.npz"
    write_measurements(npz, t=tr.t, y=tr.y, agent_ids=sc.agent_ids, sizes=sizes_of(sc), missing=missing)
    # exact: the same bits of y and the same missing rows as the CSV, through the same simulator
    assert np.array_equal(simulate(des, measurements=load_measurements(npz, sc)).xhat, batch.xhat, equal_nan=True)
    # the centralized filter leaves those rows out too
    kf_gap = kalman_reference(sc, meas.y, missing)
    kf_all = kalman_reference(sc, tr.y, np.zeros_like(missing))
    # exact before the gap: the filter's steps are the same operations until a row is left out
    assert np.array_equal(kf_gap[:11], kf_all[:11]) and not np.allclose(kf_gap[11:21], kf_all[11:21])


def write_csv(path, header, rows):
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(header)
        w.writerows(rows)


@pytest.fixture
def paper():
    return load_scenario(EXAMPLES / "paper_discrete.yaml")  # agents 1, 2, 3 with one output each; n = 4


def good_rows(T=5):
    return [[k, 0.1 * k, 0.2, 0.3] for k in range(T)]


@pytest.mark.parametrize("name,header,rows,msg", [
    ("nan.csv", ["t", "y1.1", "y2.1", "y3.1"], [[0, 1, 2, 3], [1, "nan", 2, 3]], "line 3, column y1.1: nan is not finite"),
    ("inf.csv", ["t", "y1.1", "y2.1", "y3.1"], [[0, 1, 2, 3], [1, 1, "inf", 3]], "column y2.1: inf is not finite"),
    ("t.csv", ["t", "y1.1", "y2.1", "y3.1"], [[0, 1, 2, 3], [2, 1, 2, 3], [1, 1, 2, 3]],
     "t is not strictly increasing: row 3 has t = 1 after 2"),
    ("agent.csv", ["t", "y1.1", "y2.1"], good_rows(), "header has no column y3.1"),
    ("unknown.csv", ["t", "y1.1", "y2.1", "y3.1", "y7.1"], [[0, 1, 2, 3, 4]] * 2, "'y7.1' is not t, y<id>.<row>"),
    ("row.csv", ["t", "y1.1", "y2.1", "y3.1", "y1.2"], [[0, 1, 2, 3, 4]] * 2, "'y1.2' is not t"),
    ("word.csv", ["t", "y1.1", "y2.1", "y3.1"], [[0, 1, 2, 3], [1, "one", 2, 3]], "'one' is not a number"),
    ("short.csv", ["t", "y1.1", "y2.1", "y3.1"], [[0, 1, 2, 3], [1, 2, 3]], "line 3 has 3 cells; the header has 4"),
    ("someX.csv", ["t", "y1.1", "y2.1", "y3.1", "x.1"], [[0, 1, 2, 3, 4]] * 2, "some x columns but not x.2"),
    ("one.csv", ["t", "y1.1", "y2.1", "y3.1"], [[0, 1, 2, 3]], "has 1 row(s); at least 2"),
])
def test_bad_csv_files_are_refused_in_one_line(tmp_path, paper, name, header, rows, msg):
    path = tmp_path / name
    write_csv(path, header, rows)
    with pytest.raises(ScenarioError, match=None) as err:
        load_measurements(path, paper)
    assert msg in str(err.value) and str(path) in str(err.value) and "\n" not in str(err.value)


@pytest.mark.parametrize("arrays,msg", [
    ({"t": np.arange(4.0), "y_1": np.zeros((4, 1)), "y_2": np.zeros((4, 1))}, "has no y_3"),
    ({"t": np.arange(4.0), "y_1": np.zeros((4, 1)), "y_2": np.zeros((4, 1)), "y_3": np.zeros((3, 1))},
     "y_3 has shape (3, 1); agent 3 has 1 output(s) and t has 4 rows: expected (4, 1)"),
    ({"t": np.arange(4.0), "y_1": np.zeros(4), "y_2": np.zeros(4), "y_3": np.full(4, np.nan)}, "y_3[0] is nan"),
    ({"t": np.arange(4.0), "y_1": np.zeros(4), "y_2": np.zeros(4), "y_3": np.zeros(4), "x": np.zeros((4, 3))},
     "x has shape (4, 3); expected (4, 4)"),
    ({"t": np.arange(4.0), "y_1": np.zeros(4), "y_2": np.zeros(4), "y_3": np.zeros(4), "y_9": np.zeros(4)},
     "has y_9, which names no agent"),
    ({"y_1": np.zeros(4)}, "has no array t"),
    ({"t": np.array(["a", "b"]), "y_1": np.zeros(2), "y_2": np.zeros(2), "y_3": np.zeros(2)}, "t holds <U1 values"),
])
def test_bad_npz_files_are_refused_in_one_line(tmp_path, paper, arrays, msg):
    path = tmp_path / "bad.npz"
    np.savez(path, **arrays)
    with pytest.raises(ScenarioError) as err:
        load_measurements(path, paper)
    assert msg in str(err.value) and "\n" not in str(err.value)


def test_nan_where_a_measurement_is_marked_missing_is_accepted(tmp_path, paper):
    path = tmp_path / "gaps.npz"
    y3 = np.ones(4)
    y3[2] = np.nan  # a logger's "no value", marked missing: not a bad value
    np.savez(path, t=np.arange(4.0), y_1=np.zeros(4), y_2=np.zeros(4), y_3=y3,
             missing_3=np.array([False, False, True, False]))
    m = load_measurements(path, paper)
    assert m.missing[:, 2].tolist() == [False, False, True, False] and np.isfinite(m.y).all()


def test_a_small_npz_that_expands_beyond_the_bound_is_refused_before_inflating(tmp_path, paper, monkeypatch):
    import splitspec_core.scenarios.measurements as meas

    monkeypatch.setattr(meas, "MAX_FILE_BYTES", 1 << 16)  # the bound scaled down: 4 x 64 KiB expanded
    path = tmp_path / "bomb.npz"
    np.savez_compressed(path, t=np.arange(40000.0), y_1=np.zeros(40000), y_2=np.zeros(40000), y_3=np.zeros(40000))
    assert path.stat().st_size < 1 << 16  # zeros compress: the file itself passes the size check
    with pytest.raises(ScenarioError, match="expands to 1 MiB; at most 0 MiB"):
        load_measurements(path, paper)


def test_unreadable_huge_and_misnamed_files(tmp_path, paper):
    garbage = tmp_path / "garbage.npz"
    garbage.write_bytes(b"\x00\x01 not a zip file" * 10)
    with pytest.raises(ScenarioError, match=r"is not an NPZ file \(a zip archive"):
        load_measurements(garbage, paper)
    broken = tmp_path / "broken.npz"
    broken.write_bytes(b"PK\x03\x04 a zip file cut short")
    with pytest.raises(ScenarioError, match="is not a readable NPZ file"):
        load_measurements(broken, paper)
    huge = tmp_path / "huge.csv"
    with open(huge, "wb") as f:  # a sparse file: 2 GiB on paper, no disk used
        f.truncate(2 << 30)
    with pytest.raises(ScenarioError, match="is 2048 MiB; at most 1024 MiB are read"):
        load_measurements(huge, paper)
    with pytest.raises(ScenarioError, match="must be an .npz or a .csv file"):
        load_measurements(tmp_path / "log.txt", paper)
    with pytest.raises(ScenarioError, match="cannot read it"):
        load_measurements(tmp_path / "absent.csv", paper)
    cont = load_scenario(EXAMPLES / "paper_continuous.yaml")  # run.dt 0.01
    path = tmp_path / "dt.csv"
    write_csv(path, ["t", "y1.1", "y2.1", "y3.1"], [[0.02 * k, 0, 0, 0] for k in range(4)])
    with pytest.raises(ScenarioError, match="rows 1 and 2 are 0.02 s apart; run.dt is 0.01"):
        load_measurements(path, cont)


def test_simulate_cli_with_measurements(tmp_path):
    scen = EXAMPLES / "paper_discrete_noise.yaml"
    sim, meas = tmp_path / "sim", tmp_path / "m.npz"
    r = run("simulate", scen, "--out", sim, "--write-measurements", meas, "--steps", 40)
    assert r.returncode == 0, r.stderr
    assert f"wrote {meas}" in r.stdout
    with np.load(meas) as f:
        assert sorted(f.files) == ["t", "x", "y_1", "y_2", "y_3"] and f["t"].shape == (41,)
    blind = tmp_path / "blind.npz"
    with np.load(meas) as f:
        np.savez(blind, **{k: f[k] for k in f.files if k != "x"})
    out = tmp_path / "out"
    r = run("simulate", scen, "--out", out, "--measurements", blind)
    assert r.returncode == 0, r.stderr
    assert "no truth" in r.stdout and "distance to the centralized Kalman filter" in r.stdout
    with np.load(out / "trajectory.npz") as f, np.load(sim / "trajectory.npz") as g:
        assert np.isnan(f["x"]).all() and np.array_equal(f["xhat"], g["xhat"], equal_nan=True)  # exact, as above
        assert {"residual", "disagreement", "kf", "kf_distance", "y", "y_missing"} <= set(f.files)
    summary = json.loads((out / "summary.json").read_text())
    assert summary["truth"] is False and "agents" not in summary and summary["reference"]["final_disagreement"] > 0
    assert sorted(summary["plots"]) == ["reference.png", "states.png"] and not (out / "errors.png").exists()
    # bad input: one line, exit 2, nothing written
    bad = tmp_path / "bad.csv"
    write_csv(bad, ["t", "y1.1", "y2.1"], good_rows())
    for args, msg in ((["--measurements", bad], "header has no column y3.1"),
                      (["--measurements", blind, "--monte-carlo", "3"], "--monte-carlo draws new noise"),
                      (["--measurements", blind, "--steps", "99"], "has 41 rows (40 steps); --steps 99 asks for more"),
                      (["--measurements", blind, "--write-measurements", tmp_path / "w.npz"], "not allowed with")):
        r = run("simulate", scen, "--out", tmp_path / "refused", *args)
        assert r.returncode == 2 and msg in r.stderr and r.stderr.count("\n") == 1, (args, r.stderr)
        assert not (tmp_path / "refused").exists()
