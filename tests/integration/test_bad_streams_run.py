"""Bad data in a recorded stream, on real processes (issue 37, item 4): `splitspec simulate --write-measurements`,
the file's rows of agent 3 biased by 20 signal standard deviations, and `splitspec run --measurements` on it equal to
`splitspec simulate --measurements` (y_rejected, y_statistic and the sensor_suspect / sensor_restored events
included).  The file's first rows are empty for every agent (a stream that starts late): the agent processes count
their warm-up in measurements as the simulator does."""

from __future__ import annotations

import signal
import time
import uuid
from pathlib import Path

import numpy as np
import pytest
import yaml

import splitspec_core as ss
from splitspec_core.model.screening import UNTESTED, sensor_events
from splitspec_core.scenarios.measurements import load_measurements, write_measurements
from splitspec_core.simulation.simulator import Trajectory
from splitspec_core.synthesis.bad_data import bad_data
from tests.conftest import EXAMPLES
from tests.integration.runtime_helpers import compare_with_simulate, events, run, wait_for_rows

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
    assert not np.delete(rejected, 2, axis=1).any()
    assert not rejected[:T0, 2].any() and not rejected[T0 + FOR + 3:, 2].any()  # k = 3 clean tests restore it
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


# ------------------------------------------------------------------------------------------------ live sensors

RATE, BIAS = 40, 1.0  # samples 4x faster than the event times (pace 10)
SAMPLES_PER_EVENT = 4  # RATE / run.pace
OFF_TIME_AFTER = 10  # event times an estimate may fail its test after taking a sample off time
LIVE_LATE = 70  # the sensors start after the run's 70th event time, past the warm-up's 66
LIE_FROM, LIE_SAMPLES = 4 * 85, 4 * 20  # agent 1's sensor lies ~8.5 s after it starts, for ~2 s (~20 event times)
LIVE_AFTER = 4 * 25  # samples published after the lie before the run is stopped (25 event times: the restore's)


def _lines(path: Path) -> int:
    """Lines written to ``path`` so far (0 before it exists)."""
    try:
        with open(path, "rb") as f:
            return sum(1 for _ in f)
    except OSError:
        return 0


def used_samples(record, traj, agent: int) -> np.ndarray:
    """Per event time, the publisher's sample (row of its log) whose ``y_i`` agent ``agent`` used; -1 where none.
    Found by exact equality (JSON carries ``repr`` of the floats, the log too)."""
    rows = np.genfromtxt(record, delimiter=",", names=True)
    ys = np.column_stack([rows[f"y{agent}{r}"] for r in (1, 2)])
    where = {tuple(v): k for k, v in enumerate(ys) if np.isfinite(v).all()}
    cols = slice(2 * (agent - 1), 2 * agent)
    return np.array([-1 if traj["y_missing"][tau, agent - 1] else where[tuple(traj["y"][tau, cols])]
                     for tau in range(len(traj["y"]))])


@pytest.mark.long
def test_a_live_sensor_that_lies_is_flagged_restored_and_replays(tmp_path):
    """examples/sensors/publisher.py started 7 s into a run until stopped, agent 1's sensor biased by 1.0 (100 noise
    stds) for 80 samples later on, the run stopped 100 samples after the lie: the late start is not taken for a lie
    (the warm-up counts measurements: counted in event times, every sensor was suspect from its first sample on, for
    good); the agent flags the lie within 5 event times of the first biased sample it used and takes the sensor back
    after the last one; the run reports the y it used, and simulate --measurements on that y is the same run
    (y_rejected, every estimate).  (A run of fixed length ended before the lie when the publisher took 10 s to start
    under a suite's load.)"""
    from tests.integration.test_sensors_run import SensorRun, chain

    on = {"false_alarm": 1e-5, "suspect_after": 3}
    r = SensorRun(tmp_path, None, "--insecure", bad_data=on)
    try:
        record = tmp_path / "rec.csv"
        wait_for_rows(r.out, LIVE_LATE, timeout=60)
        pub = r.publish("--record", record, "--rate", RATE, "--seed", 3, "--bias", BIAS, "--bias-agent", 1,
                        "--bias-from", LIE_FROM, "--bias-samples", LIE_SAMPLES, credentials=None)
        published = LIE_FROM + LIE_SAMPLES + LIVE_AFTER
        deadline = time.monotonic() + 120
        while pub.poll() is None and time.monotonic() < deadline and _lines(record) <= published:
            time.sleep(0.2)
        assert _lines(record) > published, f"the publisher wrote {_lines(record) - 1} samples in 120 s"
        r.proc.send_signal(signal.SIGINT)  # a run until stopped: exit 0, its records complete
        traj = r.finish()
    finally:
        r.kill()
    k = on["suspect_after"]
    sample = used_samples(record, traj, 1)
    lying = (sample >= LIE_FROM) & (sample < LIE_FROM + LIE_SAMPLES)
    taus = np.flatnonzero(lying)
    assert len(taus) >= 10, sample
    first, last = int(taus[0]), int(taus[-1])
    stat, rejected = traj["y_statistic"], traj["y_rejected"]
    assert stat[first, 0] >= 0, stat[:, 0]  # tested: the lie starts after agent 1's warm-up
    flagged = first + int(np.argmax(rejected[first:, 0]))
    assert rejected[first:, 0].any() and flagged - first <= 5, rejected[first - 3:last + 8, 0].astype(int)
    assert rejected[taus[taus >= first + 5], 0].all()  # set aside while it lies
    ev = [(e["t"], e["agent"], e["event"]) for e in events(r.out) if e["event"] in ("sensor_suspect",
                                                                                    "sensor_restored")]
    # the lie's: agent 1's first suspicion from the first lying sample on and the restore after it (more, before or
    # after, below: samples taken off time; one at 151-154 before a lie from 160 failed a suite at load 2)
    own = [e for e in ev if e[1] == 1]
    start = next((j for j, e in enumerate(own) if e[2] == "sensor_suspect" and e[0] >= first), None)
    assert start is not None, (first, ev)
    mine = own[start:start + 2]
    assert [e[2] for e in mine] == ["sensor_suspect", "sensor_restored"], ev
    assert first <= mine[0][0] <= first + 5 and last < mine[1][0] <= last + k + 5, (first, last, ev)
    # nothing else set aside but after a measurement taken off time: under load the agents sometimes take the sample
    # before the one due (one 25 ms step older: the publisher late, or the round early); it measures the plant
    # elsewhere, the test may fail it, and an estimate that took it fails the next few (measured at load 13: samples
    # 268 and 308 instead of 269 and 309, agents 1 and 3 set aside at 141 and 151-157; none in 3 runs on a quiet
    # machine); within OFF_TIME_AFTER event times of one, set-asides and suspicions are allowed (each restored); 2
    # others allowed
    outside = rejected.copy()
    outside[first:int(mine[1][0]) + 1, 0] = False  # set aside from the lie until its restore (suspect till then)
    off = np.zeros(len(sample), dtype=bool)
    for a in (1, 2, 3):
        used = used_samples(record, traj, a) if a != 1 else sample
        behind = SAMPLES_PER_EVENT * np.arange(len(used)) - used  # samples between the newest due and the one used
        off |= (used >= 0) & (behind != np.median(behind[used >= 0]))
    after_off = np.convolve(off, np.ones(OFF_TIME_AFTER + 1), mode="full")[:len(off)] > 0  # off at tau - w .. tau
    assert (outside & ~after_off[:, None]).sum() <= 2, (np.argwhere(outside & ~after_off[:, None]),
                                                          np.flatnonzero(off), ev)
    others = [e for e in ev if e not in mine]
    for t, a, what in others:  # each other suspicion came after a sample taken off time
        if what == "sensor_suspect":
            assert after_off[int(t)], (t, a, np.flatnonzero(off), ev)
    T = len(traj["y"])
    for a in (1, 2, 3):  # and each was restored, but one the stop cut off: k clean tests, after up to OFF_TIME_AFTER
        # failing ones, restore it (CI: agent 3 suspect at 213 of a run stopped there, after a sample off time)
        theirs = [e for e in others if e[1] == a]
        if theirs and theirs[-1][2] == "sensor_suspect" and theirs[-1][0] > T - 1 - k - OFF_TIME_AFTER:
            theirs = theirs[:-1]
        assert [e[2] for e in theirs] == ["sensor_suspect", "sensor_restored"] * (len(theirs) // 2), others
    assert (stat[:LIVE_LATE] == UNTESTED).all() and sample[LIVE_LATE - 1] == -1  # no sensor yet: nothing tested
    # the y the agents used, replayed by the simulator: the same decisions and estimates
    replay = tmp_path / "used.npz"
    write_measurements(replay, t=np.arange(float(T)), y=np.nan_to_num(traj["y"]), agent_ids=[1, 2, 3],
                       sizes=[2, 2, 2], missing=traj["y_missing"])
    scenario = chain(tmp_path, T, on, name="replay.yaml")  # the run's scenario with its length
    sim = run("simulate", scenario, "--out", tmp_path / "replay", "--no-plots", "--measurements", replay)
    assert sim.returncode == 0, sim.stderr
    with np.load(tmp_path / "replay" / "trajectory.npz") as f:
        # all but the last row: the stopped run's last event time tested the measurement it took (for an update the
        # stop cut off), and may have set it aside (CI: agent 3's, at the stop); a run of T event times takes none
        assert np.array_equal(f["y_rejected"][:-1], rejected[:-1])
        np.testing.assert_allclose(f["y_statistic"][:-1], stat[:-1], rtol=1e-9, atol=1e-9)
        np.testing.assert_allclose(f["xhat"], traj["xhat"], rtol=0, atol=1e-9 * np.abs(traj["xhat"]).max())
        expected = sensor_events(Trajectory.load(tmp_path / "replay" / "trajectory.npz"),
                                 bad_data(ss.design(ss.load_scenario(scenario)).detail))
    assert [e for e in ev if e[0] < T - 1] == [e[:3] for e in expected if e[0] < T - 1]  # (the last row: as above)
