"""Bad data in a recorded stream, on real processes (issue 37, item 4): `splitspec simulate --write-measurements`,
the file's rows of agent 3 biased by 20 signal standard deviations, and `splitspec run --measurements` on it equal to
`splitspec simulate --measurements` (y_rejected, y_statistic and the sensor_suspect / sensor_restored events
included).  The file's first rows are empty for every agent (a stream that starts late): the agent processes count
their warm-up in measurements as the simulator does."""

from __future__ import annotations

import uuid

import numpy as np
import pytest
import yaml

import splitspec_core as ss
from splitspec_core.model.screening import UNTESTED, sensor_events
from splitspec_core.scenarios.measurements import load_measurements, write_measurements
from splitspec_core.simulation.simulator import Trajectory
from splitspec_core.synthesis.bad_data import bad_data
from tests.conftest import EXAMPLES
from tests.integration.runtime_helpers import compare_with_simulate, events, run

pytestmark = pytest.mark.slow

LATE, T0, FOR, STEPS = 40, 100, 60, 200  # every agent's first 40 rows empty; agent 3's rows 100..159 biased


def test_a_run_on_a_recorded_stream_that_lies_equals_simulate(tmp_path):
    raw = yaml.safe_load((EXAMPLES / "ring10_noise.yaml").read_text())
    raw["design"]["bad_data"] = {"false_alarm": 1e-5, "suspect_after": 3}
    raw["run"] = {"steps": STEPS, "seed": 2}
    scen = tmp_path / "ring10_bad.yaml"
    scen.write_text(yaml.safe_dump(raw))
    full = tmp_path / "full.npz"
    r = run("simulate", scen, "--out", tmp_path / "sim0", "--no-plots", "--write-measurements", full)
    assert r.returncode == 0, r.stderr
    sc = ss.load_scenario(scen)
    meas = load_measurements(full, sc)
    y, missing = meas.y.copy(), meas.missing.copy()
    sigma = float(y[LATE:, 2].std())  # agent 3's signal (x5, an oscillator of amplitude ~3)
    y[T0:T0 + FOR, 2] += 20 * sigma
    missing[:LATE] = True
    lying = tmp_path / "lying.csv"
    write_measurements(lying, t=meas.t, y=y, agent_ids=sc.agent_ids, sizes=[1] * 10, x=meas.x, missing=missing)
    out = tmp_path / "out"
    r = run("run", scen, "--out", out, "--measurements", lying, "--run-id", "b" + uuid.uuid4().hex[:10])
    assert r.returncode == 0, r.stdout + r.stderr
    compare_with_simulate(out, scen, tmp_path, 1e-9, "--measurements", lying)  # xhat, y, every reported column
    ran, sim = np.load(out / "trajectory.npz"), np.load(tmp_path / "sim" / "trajectory.npz")
    assert (ran["y_rejected"] == sim["y_rejected"]).all()
    np.testing.assert_allclose(ran["y_statistic"], sim["y_statistic"], rtol=1e-9, atol=1e-9)
    warm = bad_data(ss.design(sc).detail).warmup
    assert (ran["y_statistic"][:LATE + warm] == UNTESTED).all() and (ran["y_statistic"][LATE + warm:-1] >= 0).all()
    rejected = ran["y_rejected"]
    first = int(np.flatnonzero(rejected[T0:, 2])[0])
    assert first <= 5 and rejected[T0 + 5:T0 + FOR, 2].all()
    assert not np.delete(rejected, 2, axis=1).any() and not rejected[:T0, 2].any() and not rejected[T0 + FOR + 3:, 2].any()
    # the other agents' mean error over the bad rows within 2x their steady RMS before them (the file has the truth)
    err = np.linalg.norm(ran["xhat"] - ran["x"][:, None, :], axis=2)
    rms = np.sqrt((err[LATE + warm:T0] ** 2).mean(axis=0))
    ratio = err[T0:T0 + FOR].mean(axis=0) / rms
    assert np.all(np.delete(ratio, 2) <= 2.0), ratio
    # events.jsonl: what the agents decided, as the simulation's records imply
    expected = sensor_events(Trajectory.load(tmp_path / "sim" / "trajectory.npz"), bad_data(ss.design(sc).detail))
    ev = [e for e in events(out) if e["event"] in ("sensor_suspect", "sensor_restored")]
    assert [(e["t"], e["agent"], e["event"]) for e in ev] == [e[:3] for e in expected]
    assert [(e["agent"], e["event"]) for e in ev] == [(3, "sensor_suspect"), (3, "sensor_restored")]
    assert T0 <= ev[0]["t"] <= T0 + 5 and T0 + FOR <= ev[1]["t"] <= T0 + FOR + 5
