"""Estimation quality under noise: exact steady-state covariance, tuning, and `splitspec compare`."""

import dataclasses
import json

import numpy as np
import pytest
import yaml

from splitspec_core.simulation.metrics import steady_rms
from splitspec_core.studies.comparison import compare, settle_time, sweep
from splitspec_core.synthesis.designer import design
from splitspec_core.errors import DesignError
from splitspec_core.synthesis.error_matrix import error_dynamics
from splitspec_core.synthesis.error_matrix import predicted_rms
from splitspec_core.synthesis.noise_tuning import tune
from splitspec_core.scenarios.load import load_scenario
from splitspec_core.simulation.simulator import simulate
from tests.conftest import EXAMPLES
from tests.integration.runtime_helpers import run
from tests.unit.test_certificates import sampled_error_map
from tests.unit.test_resilience_runtime import full_error_radius


def _refuse(constant):
    """``json.loads(..., parse_constant=_refuse)``: strict JSON, no NaN or Infinity."""
    raise ValueError(f"not JSON: {constant}")


def test_error_map_is_the_estimators():
    """M of the covariance recursion is the noise-free error map built independently from the full matrices."""
    des = design(load_scenario(EXAMPLES / "paper_discrete.yaml"))
    M, _ = error_dynamics(des)
    assert np.max(np.abs(np.linalg.eigvals(M))) == pytest.approx(full_error_radius(des, [1, 2, 3]), rel=1e-9)


@pytest.mark.parametrize("example,steps", [("ring10_noise", 4000), ("paper_continuous", 30000)])
def test_predicted_rms_matches_a_long_simulation(example, steps):
    """The Lyapunov solution is what the simulated RMS converges to (one long realisation per agent)."""
    des = design(load_scenario(EXAMPLES / f"{example}.yaml"))
    pred = predicted_rms(des)
    tr = simulate(des, seed=11, steps=steps, progress=False)
    e = tr.errors()[steps // 10:]
    sim = np.sqrt(np.mean(e ** 2, axis=0))
    # errors are correlated in time (ring10: ~5 steps, paper_continuous: ~0.6 s = 60 steps): >= 450 independent
    # samples per agent put the RMS within a few percent
    np.testing.assert_allclose(sim, pred, rtol=0.08)
    assert np.sqrt(np.mean(sim ** 2)) == pytest.approx(np.sqrt(np.mean(pred ** 2)), rel=0.05)


def test_tune_is_certified_and_no_worse_than_the_design():
    sc = load_scenario(EXAMPLES / "paper_discrete_noise.yaml")
    res = tune(sc)
    assert res.design.q_result.certified
    assert res.rms <= res.baseline_rms + 1e-12
    # it is the best certified candidate, and it beats place measurably on this example
    certified = [c["rms"] for c in res.candidates if c["certified"]]
    assert res.rms == pytest.approx(min(certified))
    place = min(c["rms"] for c in res.candidates if c["gains"] == "place" and c["certified"])
    assert res.rms < 0.95 * place
    # the tuned scenario designs to the same thing from scratch
    assert np.sqrt(np.mean(predicted_rms(design(res.scenario)) ** 2)) == pytest.approx(res.rms)
    with pytest.raises(DesignError, match="needs system.process_noise"):
        tune(load_scenario(EXAMPLES / "paper_discrete.yaml"))


def test_compare_on_the_paper_example():
    sc = load_scenario(EXAMPLES / "paper_discrete_noise.yaml")
    res = compare(sc, seeds=range(3), steps=60)
    est = res.estimators
    assert set(est) == {"split (scenario)", "split place", "split riccati", "split tuned", "centralized KF", "KCF"}
    kf = est["centralized KF"]
    # measured (3 seeds x 58 steps) against the DARE's steady RMS; each split's ratio against the ratio of the two
    # exact predictions (Lyapunov / DARE): independent computations, within sampling error (15 %)
    assert kf.rms_mean == pytest.approx(kf.predicted_rms, rel=0.15)
    for name in ("split place", "split riccati", "split tuned"):
        assert est[name].ratio_to_centralized == pytest.approx(est[name].predicted_rms / kf.predicted_rms, rel=0.15)
    central = est["centralized KF"].rms_mean
    for name, r in est.items():
        assert r.rms_mean >= 0.95 * central, name  # nobody beats the centralized Kalman filter
    for name in ("split place", "split riccati", "split tuned"):
        assert est[name].messages_per_event == 3 * est[name].q
        assert est[name].predicted_rms == pytest.approx(est[name].rms_mean, rel=0.3)
    assert est["centralized KF"].messages_per_event == 3
    assert res.t.shape == (61,)


def test_sweep_marks_certified_values():
    sc = load_scenario(EXAMPLES / "paper_discrete_noise.yaml")
    sw = sweep(sc, seed=0, steps=40, values=[1, 3, 6, 8])
    rows = {r["value"]: r for r in sw["rows"]}
    assert not rows[3]["certified"] and rows[6]["certified"] and rows[8]["certified"]
    assert rows[1]["predicted_rms"] == float("inf") or rows[1]["predicted_rms"] > rows[6]["predicted_rms"]
    assert rows[6]["measured_rate"] <= sc.design.rate


def _sampled_error_radius(des) -> float:
    """Spectral radius of the full sampled-data error map (:func:`tests.unit.test_certificates.sampled_error_map`)."""
    return float(np.max(np.abs(np.linalg.eigvals(sampled_error_map(des)))))


def test_sweep_never_certifies_an_unstable_sampled_data_form():
    """A g certified for the ODE (eq. g) whose sampled-data form with run.dt is unstable is not certified."""
    sc = load_scenario(EXAMPLES / "paper_continuous.yaml")
    sc = dataclasses.replace(sc, run=dataclasses.replace(sc.run, dt=0.05))
    g0 = design(sc).g
    values = [g0, 2 * g0, 4 * g0]
    sw = sweep(sc, seed=0, steps=400, values=values)
    unstable_but_ode_certified = 0
    for row in sw["rows"]:
        des = design(dataclasses.replace(sc, design=dataclasses.replace(sc.design, g=row["value"])))
        rho = _sampled_error_radius(des)
        meets = rho <= np.exp(-sc.design.rate * sc.run.dt)  # the sampled-data form decays at the rate
        assert row["certified"] == (des.g_certified_by is not None and meets), (row, rho)
        if des.g_certified_by is not None and rho >= 1:
            unstable_but_ode_certified += 1
            assert not row["certified"] and "UNSTABLE" in row["certificate"] and "run.dt = 0.05" in row["certificate"]
            assert row["measured_rate"] < 0 and row["predicted_rms"] == float("inf")  # the error does grow
        if row["certified"]:
            assert row["measured_rate"] >= sc.design.rate
    assert unstable_but_ode_certified  # the sweep reached the contradiction the certificate must catch
    assert sw["rows"][0]["certified"]  # the designed g is still certified at this dt


def test_discrete_sweep_certifies_only_contracting_error_maps():
    """Discrete time runs exactly A_V = Atil B^q (eq. split_discrete_ench): a certified q contracts at the rate."""
    sc = load_scenario(EXAMPLES / "paper_discrete_noise.yaml")
    q0 = design(sc).q
    sw = sweep(sc, seed=0, steps=40, values=list(range(1, q0 + 3)))
    assert [r["certified"] for r in sw["rows"]].count(True) == 3  # q0, q0 + 1, q0 + 2
    for row in sw["rows"]:
        des = design(dataclasses.replace(sc, design=dataclasses.replace(sc.design, q=row["value"])))
        rho = full_error_radius(des, sc.agent_ids)
        assert row["certified"] == (rho < sc.design.rate), (row, rho)  # q_method spectral is exact here
        assert row["certificate"].startswith(f"q = {row['value']}: spectral bound")


def test_settle_time_and_steady_rms():
    t = np.arange(10.0)
    err = np.array([1, 0.5, 1e-2, 1e-4, 2e-3, 1e-4, 1e-5, 1e-6, 1e-7, 1e-8])
    assert settle_time(t, err) == 5.0  # after the bump at 4
    assert settle_time(t, np.ones(10)) is None
    assert steady_rms(np.array([[9.0, 9.0], [9.0, 9.0], [3.0, 4.0], [3.0, 4.0]])) == pytest.approx(np.sqrt(12.5))


def test_compare_and_tune_cli(tmp_path):
    out = tmp_path / "c"
    r = run("compare", EXAMPLES / "paper_discrete_noise.yaml", "--out", out, "--seeds", 2, "--steps", 40, "--sweep")
    assert r.returncode == 0, r.stderr
    data = json.loads((out / "compare.json").read_text(), parse_constant=_refuse)
    rows = data["estimators"]
    for name, row in rows.items():  # each ratio: the row's steady RMS over the KF's, as the file gives them
        assert row["ratio_to_centralized"] == pytest.approx(row["rms_mean"] / rows["centralized KF"]["rms_mean"],
                                                            rel=1e-12), name
    for f in ("compare_errors.png", "compare_ratios.png", "sweep.png", "sweep.json"):
        assert (out / f).stat().st_size > 1000
    assert "centralized KF" in r.stdout and "tuned design" in r.stdout
    tuned = tmp_path / "tuned.yaml"
    r = run("design", EXAMPLES / "paper_discrete_noise.yaml", "--tune", "rms", "--write", tuned)
    assert r.returncode == 0, r.stderr
    raw = yaml.safe_load(tuned.read_text())
    assert raw["design"]["gains"] in ("place", "riccati") and "K" not in raw["design"]
    sc = load_scenario(tuned)
    assert design(sc).q == raw["design"]["q"]
    # bad input: one line, exit 2
    r = run("compare", EXAMPLES / "paper_discrete.yaml", "--out", tmp_path / "x")
    assert r.returncode == 2 and "compare needs noise" in r.stderr and r.stderr.count("\n") == 1
    r = run("design", EXAMPLES / "paper_discrete.yaml", "--write", tmp_path / "y.yaml")
    assert r.returncode == 2 and "--write needs --tune" in r.stderr


def test_adaptive_gain_has_no_steady_state():
    sc = load_scenario(EXAMPLES / "paper_continuous.yaml")
    sc = dataclasses.replace(sc, design=dataclasses.replace(sc.design, g="adaptive", g0=1.0))
    with pytest.raises(DesignError, match="adaptive"):
        predicted_rms(design(sc))


def test_a_kalman_filter_whose_certified_transient_outlasts_the_run_is_measured_from_its_clean_run(monkeypatch):
    """The Kalman filter's envelope is a bound: on the IEEE 39-bus model (170 states) its transient constant put the
    end of its transient past a 120 s run, and every ratio of compare came out None.  Here the constant is made
    that large on a small example: the KF's steady RMS is then read after its noise-free run has settled, the note
    says so, and the ratios exist."""
    from splitspec_core.studies import transients

    sc = load_scenario(EXAMPLES / "ring10_noise.yaml")
    honest = compare(sc, seeds=range(2), steps=300)
    huge = type("Constant", (), {"constant": 1e200})()
    monkeypatch.setattr(transients, "transient_constant", lambda A, r: huge)
    res = compare(sc, seeds=range(2), steps=300)
    kf = res.estimators["centralized KF"]
    assert kf.steady_from is not None and "noise-free run" in kf.note
    assert honest.estimators["centralized KF"].note is None  # certified there: no fallback
    # issue 46 (4): no tuned candidate beats ring10's own place design (q = 6): kept, no duplicate row
    assert honest.tuned["kept"] and "split tuned" not in honest.estimators
    own = next(iter(res.estimators))  # the scenario's own design comes first
    # its ratio is its steady RMS over the KF's, both measured, each from its own start
    assert res.estimators[own].ratio_to_centralized == pytest.approx(res.estimators[own].rms_mean / kf.rms_mean,
                                                                     rel=1e-12)
    # measured from its own settling, the KF's figure is the honest run's to sampling error
    assert kf.rms_mean == pytest.approx(honest.estimators["centralized KF"].rms_mean, rel=0.1)


@pytest.mark.long
def test_a_split_whose_gains_miss_the_rate_is_a_failed_row_not_a_failed_compare():
    """IEEE 14-bus at 0.5 /s: place's local poles miss the rate (an AssumptionError), riccati has no solution; the
    whole-state design is certified.  compare returns it and the baselines, and says why each split failed."""
    sc = load_scenario(EXAMPLES / "ieee14_pmu.yaml")
    sc = dataclasses.replace(sc, design=dataclasses.replace(sc.design, rate=0.5))
    res = compare(sc, seeds=[0], steps=300)
    assert "optimal (whole state)" in res.estimators and "centralized KF" in res.estimators
    assert "split place" in res.failed and "do not meet rate 0.5" in res.failed["split place"]
    assert "split place" not in res.estimators
    assert res.estimators["optimal (whole state)"].certified_rate


# --------------------------------------------------------------------------
# issue 46: a model of the newcomer's own (not from examples/)
# --------------------------------------------------------------------------


def building(path, *, steps=300):
    """Issue 46's model: four rooms in a ring, each with a wall mass (8 states, sampled every minute), four agents
    reading their room's thermometer, agent 4's 20x noisier; the default design (optimal, whole state) beats every
    split on it by far.  Written to ``path``; returns it."""
    A = np.zeros((8, 8))
    for i in range(4):
        A[i, i], A[i, 4 + i] = -0.22, 0.1  # room i: losses, its wall
        A[i, (i + 1) % 4] = A[i, (i - 1) % 4] = 0.05  # its two neighbouring rooms
        A[4 + i, i], A[4 + i, 4 + i] = 0.01, -0.015  # wall i: its room, losses
    data = {"name": "building4", "time": "discrete",
            "system": {"sample": 1.0, "A": A.tolist(), "C": {i + 1: [np.eye(8)[i].tolist()] for i in range(4)},
                       "process_noise": 0.02, "measurement_noise": {1: 0.1, 2: 0.1, 3: 0.1, 4: 2.0}},
            "graphs": {"ring": {"undirected": [[1, 2], [2, 3], [3, 4], [4, 1]]}},
            "design": {"rate": 0.9}, "run": {"steps": steps, "seed": 1}}
    path.write_text(yaml.safe_dump(data))
    return path


def _significant_digits(number_text: str) -> int:
    mantissa = number_text.lower().split("e")[0].lstrip("+-").replace(".", "").lstrip("0")
    return len(mantissa)


def _all_weights(raw: dict) -> list:
    return [v for v in (raw["design"].get("riccati") or {}).values()]


def test_tune_never_writes_a_design_predicted_worse_than_the_scenarios_own(tmp_path):
    """Issue 46 (4): on the building the best certified split was predicted 72.9 against the default design's 1.02,
    and --tune wrote it, saying nothing.  It keeps the scenario's own design, says so in one line, and the file it
    writes designs to the scenario's own predicted RMS (recomputed here from the file)."""
    src = building(tmp_path / "building.yaml")
    own = design(load_scenario(src))
    own_rms = float(np.sqrt(np.mean(predicted_rms(own) ** 2)))
    res = tune(load_scenario(src))
    assert res.kept and res.design.consensus == own.consensus
    assert res.rms == pytest.approx(own_rms, rel=1e-9)
    assert res.best is not None and res.best["rms"] > 10 * own_rms  # what it turned down: certified, far worse
    target = tmp_path / "tuned.yaml"
    r = run("design", src, "--tune", "rms", "--write", target)
    assert r.returncode == 0, r.stderr
    kept = [line for line in r.stdout.splitlines() if "kept the scenario's own design" in line]
    assert len(kept) == 1 and f"{res.best['rms']:.4g}" in kept[0], r.stdout
    written = design(load_scenario(target))
    written_rms = float(np.sqrt(np.mean(predicted_rms(written) ** 2)))
    assert written_rms <= own_rms * (1 + 1e-9)
    assert written.consensus == own.consensus and written.q == own.q


def test_tune_writes_rounded_numbers_whose_certificate_it_checked(tmp_path):
    """Issue 46 (4): the weights printed as 1.2625000000000002e-05.  The numbers --tune prints and writes have at
    most 6 significant digits, and the written file designs (from scratch) to the certified design and predicted RMS
    it printed."""
    target = tmp_path / "tuned.yaml"
    r = run("design", EXAMPLES / "paper_discrete_noise.yaml", "--tune", "rms", "--write", target)
    assert r.returncode == 0, r.stderr
    raw = yaml.safe_load(target.read_text())
    assert raw["design"]["gains"] == "riccati"  # weighted: the weights are written
    text = target.read_text()
    for key in ("process_weight", "measurement_weight"):
        line = next(ln for ln in text.splitlines() if ln.strip().startswith(f"{key}:"))
        assert _significant_digits(line.split(":", 1)[1].strip()) <= 6, line
        assert f"{key} {raw['design']['riccati'][key]:.6g}" in r.stdout, r.stdout
    des = design(load_scenario(target))
    from splitspec_core.synthesis.verdict import rate_certificate

    assert rate_certificate(des).certified
    printed = float(r.stdout.split("predicted steady-state RMS error ")[1].split()[0])
    assert float(np.sqrt(np.mean(predicted_rms(des) ** 2))) == pytest.approx(printed, rel=1e-3)  # printed to 4 digits


def test_compare_runs_long_enough_for_every_certified_transient(tmp_path):
    """Issue 46 (5): with the building's own 300 steps the centralized KF (radius 0.99 per step, certified transient
    557 steps) had no steady figure and every ratio was missing.  Without --steps compare now runs at least twice the
    longest certified transient, says so, and every row has a ratio; each ratio agrees with the exact (Lyapunov /
    DARE) prediction of the same two rows to sampling error."""
    sc = load_scenario(building(tmp_path / "building.yaml"))
    res = compare(sc, seeds=range(3))
    kf = res.estimators["centralized KF"]
    assert kf.steady_from is not None and res.steps >= 2 * kf.steady_from > sc.run.steps
    assert res.steps_note is not None and "centralized KF" in res.steps_note and str(res.steps) in res.steps_note
    # the KF's own figure: measured over the window, against the DARE's steady RMS (independent computations)
    assert kf.rms_mean == pytest.approx(kf.predicted_rms, rel=0.15)
    for name, r in res.estimators.items():
        assert r.ratio_to_centralized is not None and r.ratio_note is None, (name, r.ratio_note)
        assert r.steady_from is not None and r.steady_from < res.steps
        if r.predicted_rms is not None:  # measured ratio vs the exact one, 3 seeds x >= 600 steps: within 15 %
            assert r.ratio_to_centralized == pytest.approx(r.predicted_rms / kf.predicted_rms, rel=0.15), name
    # the chart: every ratio a bar, on a log scale (the splits are ~400x the KF, the KCF ~1x)
    from splitspec_orchestrator.plots import ratio_bars

    bars, missing, log = ratio_bars(res)
    assert set(bars) == set(res.estimators) and not missing and log
    # forced short, the steps are the user's: no note
    assert compare(sc, seeds=[0], steps=120).steps_note is None


def test_compare_json_is_strict_and_every_missing_ratio_says_why(tmp_path):
    """Issue 46 (5): forced to 300 steps, compare.json held a bare NaN, every ratio was '-' with no reason and the
    chart drew 0.00 bars.  Now: strict JSON (null, never NaN), a reason per row without a ratio, no bar for it."""
    src = building(tmp_path / "building.yaml")
    out = tmp_path / "c"
    r = run("compare", src, "--out", out, "--seeds", 2, "--steps", 300)
    assert r.returncode == 0, r.stderr
    data = json.loads((out / "compare.json").read_text(), parse_constant=_refuse)
    rows = data["estimators"]
    assert data["steps"] == 300 and "steps_note" not in data
    assert rows["centralized KF"]["rms_mean"] is None and "557 steps" in rows["centralized KF"]["note"]
    for name, row in rows.items():
        assert row["ratio_to_centralized"] is None, name
        assert row["ratio_note"] and "centralized KF" in row["ratio_note"] or "no steady figure" in row["ratio_note"]
    assert r.stdout.count("ratio n/a: ") == 2  # one line per reason: the KF's own, and every other row's
    assert "0.00" not in r.stdout
    assert (out / "compare_ratios.png").stat().st_size > 1000
    from splitspec_orchestrator.plots import ratio_bars
    from splitspec_core.studies.comparison import CompareResult, EstimatorResult

    res = CompareResult(**{**{k: data[k] for k in ("scenario", "time", "steps", "rate", "exchanges", "kcf_eps")},
                           "seeds": tuple(data["seeds"]), "process_noise": 0.02, "measurement_noise": 0.1,
                           "estimators": {n: EstimatorResult(**{("settle_time" if k == "settle_time_1e-3" else k): v
                                                                for k, v in row.items()}) for n, row in rows.items()},
                           "tuned": None, "t": np.arange(301.0), "curves": {}})
    bars, missing, log = ratio_bars(res)
    assert not bars and set(missing) == set(rows) and all(v.startswith("n/a: ") for v in missing.values())


def test_tune_writes_a_matrix_a_row_per_line_under_a_header_that_reads(tmp_path):
    """Issue 46's walk (a motor, 5 states): the file --tune --write wrote had one number per line (its 5 x 5 A took
    30 lines) under `# motor its own design kept by ...`.  Each row of a matrix is one line, the file reads back to
    the same scenario, and the header says what the file is."""
    target = tmp_path / "tuned.yaml"
    r = run("design", EXAMPLES / "paper_discrete_noise.yaml", "--tune", "rms", "--write", target)
    assert r.returncode == 0, r.stderr
    text = target.read_text()
    source = yaml.safe_load((EXAMPLES / "paper_discrete_noise.yaml").read_text())
    A = source["system"]["A"]
    lines = text.splitlines()
    at = lines.index("  A:")
    assert [yaml.safe_load(ln.strip()[2:]) for ln in lines[at + 1:at + 1 + len(A)]] == A, text
    assert yaml.safe_load(text)["system"]["A"] == A
    name = source["name"]
    assert lines[0] in (f"# {name}: tuned for noise (`splitspec design --tune rms`)",
                        f"# {name}: its own design, kept: no candidate predicted better (`splitspec design --tune rms`)"
                        ), lines[0]
