"""simulate's measured rate: fitted after the last fault's effect and its certified transient, or not at all (and
why), never across a kill, a rejoin or a lying sensor (issue 46, finding 6)."""

import json

import numpy as np
import pytest
import yaml

from splitspec_orchestrator import cli
from splitspec_core.scenarios.faults import make_fault
from splitspec_core.simulation.metrics import fault_effects, faults_in_force, fit_decay, transient_steps


def building(faults: list, *, bad_data=None) -> dict:
    """A model of one's own (not in examples/): four rooms in a row, each with a wall mass, one thermometer per
    room, the third 20x noisier; one minute per event time."""
    Ac = np.zeros((8, 8))

    def link(i, j, k, ci, cj):  # heat flow k (T_j - T_i) between masses of capacities ci, cj
        Ac[i, i] -= k / ci
        Ac[i, j] += k / ci
        Ac[j, j] -= k / cj
        Ac[j, i] += k / cj

    for r in range(4):
        link(r, 4 + r, 0.05, 1.0, 5.0)  # room r and its wall
        Ac[4 + r, 4 + r] -= 0.002  # the wall to the outside
    for r in range(3):
        link(r, r + 1, 0.02, 1.0, 1.0)  # neighbouring rooms
    A = np.round(np.eye(8) + Ac, 6)
    design = {"rate": 0.9, "bad_data": bad_data if bad_data is not None else "off"}
    return {"name": "building", "time": "discrete",
            "system": {"A": A.tolist(), "C": {i + 1: [[float(j == i) for j in range(8)]] for i in range(4)},
                       "x0": [3.0, 1.0, -2.0, 0.5, 1.0, 0.0, -1.0, 2.0], "process_noise": 0.01,
                       "measurement_noise": {1: 0.05, 2: 0.05, 3: 1.0, 4: 0.05}},
            "graphs": {"ring": {"undirected": [[1, 2], [2, 3], [3, 4], [4, 1]]}},
            "design": design, "faults": faults, "run": {"steps": 300, "seed": 1}}


def simulate(tmp_path, capsys, raw: dict) -> tuple:
    path = tmp_path / "building.yaml"
    path.write_text(yaml.safe_dump(raw))
    out = tmp_path / "out"
    assert cli.main(["simulate", str(path), "--out", str(out), "--no-plots"]) == 0
    return capsys.readouterr().out, json.loads((out / "summary.json").read_text())


def test_a_lie_and_a_kill_are_not_fitted_across(tmp_path, capsys):
    """The newcomer's run: a lie on the noisy thermometer from 100 to 162, agent 4 killed at 180 and restarted at
    200.  Before: the fit over the run's second half spanned the restart (measured 1.02: "does NOT meet")."""
    raw = building([{"at": 100, "corrupt": 3, "bias": 5.0, "for": 62}, {"at": 180, "kill": 4},
                    {"at": 200, "restart": 4}], bad_data={"false_alarm": 1e-5, "suspect_after": 3})
    text, s = simulate(tmp_path, capsys, raw)
    assert "does NOT meet" not in text
    assert s["measured_meets_design"] is True and 0 < s["measured_rate"] <= 0.9 * (1 + 1e-3)
    assert s["measured_after_fault"] == 200.0  # the restart: the last fault's effect
    assert s["measured_from"] >= 200.0 + transient_steps(9.0, 0.9)  # past its transient (c is 9.2 here)
    assert "after the last fault's effect at tau = 200" in text


def test_a_restart_near_the_end_says_why_no_rate_is_measured(tmp_path, capsys):
    raw = building([{"at": 150, "kill": 4}, {"at": 296, "restart": 4}])
    text, s = simulate(tmp_path, capsys, raw)
    assert s["measured_rate"] is None and s["measured_meets_design"] is None
    assert "does NOT meet" not in text and "meets the design" not in text
    line, = [ln for ln in text.splitlines() if "measured rate" in ln]
    assert "not measured" in line and "after the last fault's effect (tau = 296)" in line and "6 needed" in line


def test_a_lie_to_the_end_of_the_run_is_the_fault_not_the_design(tmp_path, capsys):
    raw = building([{"at": 100, "corrupt": 2, "bias": 5.0}])
    text, s = simulate(tmp_path, capsys, raw)
    assert s["measured_rate"] is None and "does NOT meet" not in text
    assert "agent 2's measurements corrupted (bias 5.0) from tau = 100 to the end of the run" in s["measured_note"]


def test_fault_effects_count_losses_rejoins_faults_and_sensors_but_not_an_orchestrator_kill():
    alive = np.ones((10, 2), dtype=bool)
    alive[3:6, 1] = False  # lost at 3, back at 6
    faults = [make_fault("kill", 3, agent=2), make_fault("restart", 6, agent=2),
              make_fault("corrupt", 4.5, agent=1, bias=1.0), make_fault("kill_orchestrator", 8)]
    got = fault_effects(np.arange(10.0), alive, faults=faults, sensors=[(7.0, 1, "sensor_suspect", 9.0, 4.0)])
    assert got.tolist() == [3, 5, 6, 7]  # the corrupt at ceil(4.5) = 5; no 8


@pytest.mark.parametrize("faults, lasting", [
    ([("corrupt", 1, {"agent": 2, "bias": 1.0}), ("repair", 5, {"agent": 2})], []),
    ([("corrupt", 1, {"agent": 2, "bias": 1.0}), ("repair", 5, {"agent": 1})], ["corrupt"]),  # another sensor
    ([("partition", 1, {"groups": ((1,), (2,))}), ("heal", 4, {})], []),
    ([("drop_arc", 1, {"arc": (1, 2)})], ["drop_arc"]),
    ([("kill", 1, {"agent": 2})], []),  # a loss: the survivors' decay is the design's (resilience)
])
def test_faults_in_force_at_the_end(faults, lasting):
    fs = [make_fault(action, at, **fields) for action, at, fields in faults]
    assert [f.action for f in faults_in_force(fs)] == lasting


def test_fit_decay_after_a_disturbance_fits_the_stretch_after_it():
    t = np.arange(60.0)
    err = np.where(t < 40, 0.8 ** t, 5 * 0.6 ** (t - 40))  # a fresh estimate at 40, then 0.6 per step
    assert fit_decay(t, err, time="discrete", after=40) == pytest.approx(0.6, rel=1e-9)
    assert fit_decay(t, err, time="discrete", after=40, skip=15) is None  # 5 samples left, 6 needed
    assert fit_decay(t, err, time="discrete") > 0.6 * 1.05  # across it: the fault's measure, not the design's


@pytest.mark.parametrize("steps", [1300, 3000])
def test_round_off_within_the_certified_transient_is_not_a_run_too_short(tmp_path, capsys, steps):
    """Issue 46's walk (a motor and its load, agent 3 back at 800): the noise-free error reached round-off near
    tau = 1000, inside the certified transient after the rejoin (294 steps, c = 376 against a decay much faster
    than the rate): the note said `0 steps ..., 6 needed: a longer run (--steps) measures it`, which no run does."""
    from tests.unit.test_bad_data import MOTOR

    raw = yaml.safe_load(MOTOR)
    raw["run"]["steps"] = steps
    text, s = simulate(tmp_path, capsys, raw)
    assert s["measured_rate"] is None and s["measured_after_fault"] == 800.0
    note = s["measured_note"]
    assert "longer run" not in note and "6 needed" not in note, note
    assert "at round-off from tau = " in note and "(tau = 800, 294 steps)" in note and "however long the run" in note
    at = int(note.split("round-off from tau = ")[1].split(",")[0])
    assert 800 < at <= 800 + 294
