"""Bad data in a recorded stream (issue 37, item 4): a measurements file whose rows of one agent lie is tested as the
simulated plant's corrupted sensor is (``design.bad_data``), and a stream that starts late is not taken for a liar.

Every file here is ring10_noise's own simulated measurements and truth (``simulate(..., keep_y=True)`` written with
:func:`~splitspec_core.scenarios.measurements.write_measurements`), edited as an array: agent 3's rows biased by 20
standard deviations of its clean signal for 60 event times, or every agent's first rows left empty.
"""

from __future__ import annotations

import numpy as np
import pytest
import yaml

import splitspec_core as ss
from tests.conftest import EXAMPLES
from splitspec_core.model import steps as st
from splitspec_core.model.screening import UNTESTED, sensor_events
from splitspec_core.scenarios.load import parse_scenario_text
from splitspec_core.scenarios.measurements import load_measurements, write_measurements
from splitspec_core.synthesis.bad_data import bad_data as _bad_data

ON = {"false_alarm": 1e-5, "suspect_after": 3}
STEPS = 1100  # 10 agents: 10,000 agent-event times after the first 100
SETTLED = 100  # the clean steady RMS and the false alarms are counted from here
T0, FOR = 400, 60  # the file's bad rows: agent 3 (position 2), event times 400..459
AGENT = 2


def ring10_noise(*, steps: int = STEPS, faults=None):
    raw = yaml.safe_load((EXAMPLES / "ring10_noise.yaml").read_text())
    raw["design"]["bad_data"] = ON
    raw["run"] = {"steps": steps, "seed": 1}
    if faults:
        raw["faults"] = faults
    return parse_scenario_text(yaml.safe_dump(raw), source="ring10_noise")


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    """``(design, clean file, its Measurements, the bias, the corrupted file)``."""
    des = ss.design(ring10_noise())
    tr = ss.simulate(des, keep_y=True)
    sc = des.scenario
    sizes = [np.shape(C)[0] for C in sc.system.Cs]
    work = tmp_path_factory.mktemp("streams")
    clean = work / "clean.npz"
    write_measurements(clean, t=tr.t, y=tr.y, agent_ids=sc.agent_ids, sizes=sizes, x=tr.x)
    meas = load_measurements(clean, sc)
    bias = 20 * float(meas.y[SETTLED:, AGENT].std())  # 20 standard deviations of agent 3's clean signal (~2.4)
    y = meas.y.copy()
    y[T0:T0 + FOR, AGENT] += bias  # bad data in the recorded stream: the array edited, no fault in the scenario
    bad = work / "bad.csv"
    write_measurements(bad, t=meas.t, y=y, agent_ids=sc.agent_ids, sizes=sizes, x=meas.x)
    return des, clean, meas, bias, bad


def steady_rms(tr) -> np.ndarray:
    return np.sqrt((tr.errors()[SETTLED:] ** 2).mean(axis=0))


def test_a_clean_file_replays_its_simulation_and_rejects_at_most_2_per_10000(recorded):
    des, clean, meas, _, _ = recorded
    tr = ss.simulate(des, measurements=clean)
    assert np.array_equal(tr.xhat, ss.simulate(des).xhat)  # the file is the plant's measurements, exactly
    tested = tr.columns["y_statistic"][SETTLED:-1] != UNTESTED
    assert tested.sum() == 10_000  # every agent tested at every event time after the warm-up
    assert tr.columns["y_rejected"][SETTLED:-1].sum() <= 2
    assert sensor_events(tr, _bad_data(des.detail)) == []


def test_a_biased_recorded_stream_is_flagged_set_aside_and_restored(recorded):
    des, clean, meas, bias, bad = recorded
    tr = ss.simulate(des, measurements=bad)
    given = tr.y
    assert np.array_equal(given[T0:T0 + FOR, AGENT], meas.y[T0:T0 + FOR, AGENT] + bias)  # the file's rows, used as read
    rejected = tr.columns["y_rejected"]
    first = int(np.flatnonzero(rejected[T0:, AGENT])[0])
    assert first <= 5 and rejected[T0 + 5:T0 + FOR, AGENT].all(), rejected[T0 - 2:T0 + FOR + 6, AGENT].astype(int)
    k = _bad_data(des.detail).suspect_after
    # clean rows: the other agents' at every event time, agent 3's outside the bad rows and the k clean tests that
    # restore its sensor (set aside by design: it is still suspect)
    clean_rows = np.ones(rejected.shape, dtype=bool)
    clean_rows[:SETTLED] = clean_rows[-1] = False
    clean_rows[T0:T0 + FOR + k, AGENT] = False
    assert clean_rows.sum() >= 9_900 and rejected[clean_rows].sum() <= 2 * clean_rows.sum() / 10_000
    assert not rejected[T0 + FOR + k:, AGENT].any()
    events = sensor_events(tr, _bad_data(des.detail))
    assert [(e[1], e[2]) for e in events] == [(3, "sensor_suspect"), (3, "sensor_restored")], events
    assert T0 <= events[0][0] <= T0 + 5 and T0 + FOR <= events[1][0] <= T0 + FOR + k + 2, events
    # the other agents' mean error over the bad rows: within 2x their clean steady RMS (the file has the truth);
    # agent 3 itself within 3x
    rms = steady_rms(ss.simulate(des, measurements=clean))
    ratio = tr.errors()[T0:T0 + FOR].mean(axis=0) / rms
    assert np.all(np.delete(ratio, AGENT) <= 2.0) and ratio[AGENT] <= 3.0, ratio
    # the same lie told by the simulated plant (a corrupt fault on the clean run) is the same run: the same rows
    # set aside, the same estimates to the bit
    faulty = ss.simulate(ss.design(ring10_noise(faults=[{"at": T0, "corrupt": 3, "for": FOR, "bias": bias}])))
    assert np.array_equal(faulty.columns["y_rejected"], rejected)
    assert np.array_equal(faulty.xhat, tr.xhat)


@pytest.mark.parametrize("late, agents", [(100, "all"), (250, "all"), (150, "one")])
def test_a_stream_that_starts_late_is_not_taken_for_a_liar(recorded, tmp_path, late, agents):
    """Every agent's (or agent 3's) first ``late`` rows empty, well past the warm-up's 31 event times: a live sensor
    started after the run, a log that begins later.  The warm-up counts measurements (steps.warmup_step): the first
    31 are used untested, nothing is set aside, the estimates settle as on the full file.  (Counted in event times,
    every first test failed and, ``late`` 100, 1223 of the 3000 agent-event times after it were set aside, the
    errors never settling: 3.7 against 0.30.)"""
    des, clean, meas, _, _ = recorded
    sc = des.scenario
    missing = meas.missing.copy()
    missing[:late, slice(None) if agents == "all" else AGENT] = True
    path = tmp_path / "late.npz"
    write_measurements(path, t=meas.t, y=meas.y, agent_ids=sc.agent_ids, sizes=[np.shape(C)[0] for C in sc.system.Cs],
                       x=meas.x, missing=missing)
    tr = ss.simulate(des, measurements=path)
    warm = _bad_data(des.detail).warmup
    assert warm == 31
    stat = tr.columns["y_statistic"]
    late_agents = range(10) if agents == "all" else [AGENT]
    for i in late_agents:  # untested before its first measurement, then while its first 31 are used
        assert (stat[:late + warm, i] == UNTESTED).all() and (stat[late + warm:-1, i] >= 0).all()
    assert not tr.columns["y_rejected"][:-1].any()
    full = ss.simulate(des, measurements=clean)
    err, ref = tr.errors()[late + 200:].mean(axis=0), full.errors()[late + 200:].mean(axis=0)
    assert np.all(err <= 1.5 * ref), (err, ref)


def test_the_warm_up_counts_measurements_not_event_times():
    seen, tested = 0, []
    for measured in [False] * 5 + [True, False, True, True, False, True]:
        seen, t = st.warmup_step(seen, measured, 3)
        tested.append(t)
    assert seen == 3 and tested == [False] * 5 + [False, False, False, False, False, True]
    assert st.warmup_step(0, True, 0) == (0, True)  # no warm-up: the first measurement is tested
