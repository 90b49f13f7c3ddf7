"""design.bad_data on real processes (issue 37): a corrupted sensor and a killed agent, run == simulate to round-off,
``y_rejected`` the same, the ``sensor_suspect`` / ``sensor_restored`` events in events.jsonl and their marks in
run.rrd."""

from __future__ import annotations

import uuid

import numpy as np
import pytest
import yaml

import splitspec_core as ss
from splitspec_core.simulation.metrics import sensor_events
from splitspec_core.simulation.simulator import Trajectory
from tests.conftest import EXAMPLES
from tests.integration.runtime_helpers import compare_with_simulate, events, run
from tests.rrd_readback import read_rrd

pytestmark = pytest.mark.slow


@pytest.mark.parametrize("consensus", ["split", "whole"])
def test_corrupted_sensor_and_killed_agent_for_real_equal_simulate(tmp_path, consensus):
    raw = yaml.safe_load((EXAMPLES / "ring10_noise.yaml").read_text())
    raw["design"]["bad_data"] = {"false_alarm": 1e-5, "suspect_after": 3}
    if consensus == "whole":  # update, then average: the agents' other round (agents/agent.py, _advance_whole)
        raw["design"].update(consensus="whole", gains="kalman", resilience=0)
    raw["faults"] = [{"at": 40, "corrupt": 3, "for": 15, "bias": 2.0}, {"at": 45, "kill": 5, "for": 8}]
    raw["run"] = {"steps": 80, "seed": 1}
    scen = tmp_path / "bad_data.yaml"
    scen.write_text(yaml.safe_dump(raw))
    out = tmp_path / "out"
    r = run("run", scen, "--out", out, "--run-id", "t" + uuid.uuid4().hex[:10])
    assert r.returncode == 0, r.stdout + r.stderr
    compare_with_simulate(out, scen, tmp_path)  # xhat, alive, graph and every reported column, y_rejected included
    ran = np.load(out / "trajectory.npz")
    sim = np.load(tmp_path / "sim" / "trajectory.npz")
    assert ran["y_rejected"].dtype == bool and (ran["y_rejected"] == sim["y_rejected"]).all()
    k = list(ran["agent_ids"]).index(3)
    assert ran["y_rejected"][40:55, k].all()
    if consensus == "split":  # nobody else's innovation moves: it depends on the agent's own observable error only
        assert ran["y_rejected"].sum() == ran["y_rejected"][:, k].sum()
    np.testing.assert_allclose(ran["y_statistic"], sim["y_statistic"], rtol=1e-9, atol=1e-9)
    des = ss.design(ss.load_scenario(scen)).detail
    expected = sensor_events(Trajectory.load(tmp_path / "sim" / "trajectory.npz"), des)
    ev = [e for e in events(out) if e["event"] in ("sensor_suspect", "sensor_restored")]
    assert [(e["t"], e["agent"], e["event"]) for e in ev] == [e[:3] for e in expected]
    np.testing.assert_allclose([e["statistic"] for e in ev], [e[3] for e in expected], rtol=1e-9)
    suspect, restored = [e for e in ev if e["agent"] == 3]
    assert (suspect["event"], restored["event"]) == ("sensor_suspect", "sensor_restored")
    assert 40 <= suspect["t"] <= 45 and 55 <= restored["t"] <= 60
    assert suspect["statistic"] > suspect["threshold"] > restored["statistic"]
    rrd = read_rrd(out / "run.rrd")
    assert [tau for tau, _ in rrd["marks/suspect"]] == [int(e["t"]) for e in ev if e["event"] == "sensor_suspect"]
    assert [tau for tau, _ in rrd["marks/restored"]] == [int(e["t"]) for e in ev if e["event"] == "sensor_restored"]


def test_a_rejoin_for_real_leaves_the_other_sensors_trusted_as_simulate_does(tmp_path):
    """Issue 46's walk (a motor and its load, the current sensor's agent killed at 700 and restarted at 800): each
    agent process starts its warm-up afresh on the tick that carries the rejoiner's higher incarnation, as the
    simulator's Screen.rejoined does; before, the two angle sensors became suspect at 803 and were never restored
    (the run ended 3.68 off)."""
    from tests.unit.test_bad_data import MOTOR

    scen = tmp_path / "motor.yaml"
    scen.write_text(MOTOR)
    out = tmp_path / "out"
    r = run("run", scen, "--out", out, "--run-id", "t" + uuid.uuid4().hex[:10])
    assert r.returncode == 0, r.stdout + r.stderr
    compare_with_simulate(out, scen, tmp_path)  # xhat, alive and every reported column, y_statistic included
    ran = np.load(out / "trajectory.npz")
    assert not ran["y_rejected"].any()
    assert (ran["y_statistic"][800:1142] == -1).all() and (ran["y_statistic"][1142:-1] >= 0).all()
    assert [e for e in events(out) if e["event"] in ("sensor_suspect", "sensor_restored")] == []
    assert [e["event"] for e in events(out) if e["event"] in ("agent_lost", "agent_rejoined")] == [
        "agent_lost", "agent_rejoined"]


def test_a_stuck_sensor_for_real_is_caught_by_its_repeats_as_simulate_does(tmp_path):
    """The plant process holds agent 3's measurement (corrupt ... stuck): each agent process's repeat test fails it
    from the first repeat, as the simulator's does; the records and the events agree with simulate."""
    from splitspec_core.model.screening import FLATLINE

    raw = yaml.safe_load((EXAMPLES / "ring10_noise.yaml").read_text())
    raw["design"]["bad_data"] = {"false_alarm": 1e-5, "suspect_after": 3}
    raw["faults"] = [{"at": 40, "corrupt": 3, "for": 15, "stuck": True}, {"at": 45, "kill": 5, "for": 8}]
    raw["run"] = {"steps": 70, "seed": 2}
    scen = tmp_path / "stuck.yaml"
    scen.write_text(yaml.safe_dump(raw))
    out = tmp_path / "out"
    r = run("run", scen, "--out", out, "--run-id", "t" + uuid.uuid4().hex[:10])
    assert r.returncode == 0, r.stdout + r.stderr
    compare_with_simulate(out, scen, tmp_path)
    ran = np.load(out / "trajectory.npz")
    k = list(ran["agent_ids"]).index(3)
    assert (ran["y_statistic"][40:55, k] == FLATLINE).all() and (ran["y_statistic"][:40] != FLATLINE).all()
    ev = [(e["t"], e["agent"], e["event"]) for e in events(out) if e["event"].startswith("sensor_")
          and e["event"] != "sensor_corrupted" and e["event"] != "sensor_repaired"]
    assert ev == [(42.0, 3, "sensor_suspect"), (57.0, 3, "sensor_restored")]
    rrd = read_rrd(out / "run.rrd")
    assert [tau for tau, _ in rrd["marks/suspect"]] == [42]
