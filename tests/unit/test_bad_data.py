"""design.bad_data (issue 37, "Sensors that lie"): each agent's test of its measurement, the suspect sensor's
fallback, the records, on ring10_noise with a biased sensor.

Sampling tolerances: the statistic's mean and its false-alarm rate at level 0.01 are checked by batch means (the
innovations of a non-optimal filter are correlated, so the per-step count would overstate the sample): 20 batches,
within 4 standard errors of their mean.
"""

from __future__ import annotations

import numpy as np
import pytest
import yaml
from scipy.stats import chi2

from tests.conftest import EXAMPLES
from splitspec_core.errors import ScenarioError
from splitspec_core.model import steps as st
from splitspec_core.model.screening import UNTESTED, sensor_events
from splitspec_core.scenarios.load import parse_scenario_text
from splitspec_core.simulation.simulator import simulate
from splitspec_core.synthesis.bad_data import bad_data, fallback_radius, report_lines
from splitspec_core.synthesis.designer import design

ON = {"false_alarm": 1e-5, "suspect_after": 3}
AT, FOR = 200, 60  # the bias: from event time 200, for 60


def ring10_noise(*, bad=ON, faults=None, steps=400, seed=1, **design_keys):
    raw = yaml.safe_load((EXAMPLES / "ring10_noise.yaml").read_text())
    if bad is not None:
        raw["design"]["bad_data"] = bad
    raw["design"].update(design_keys)
    if faults:
        raw["faults"] = faults
    raw["run"] = {"steps": steps, "seed": seed}
    return parse_scenario_text(yaml.safe_dump(raw), source="ring10_noise")


def batch_means(values: np.ndarray, batches: int = 20) -> tuple:
    """(mean, standard error) of ``values`` by the means of ``batches`` consecutive batches."""
    means = np.array([b.mean() for b in np.array_split(values, batches)])
    return float(means.mean()), float(means.std(ddof=1) / np.sqrt(batches))


# ------------------------------------------------------------------------------------------------ the scenario key


def test_bad_data_is_parsed_with_its_defaults():
    assert ring10_noise(bad="off").design.bad_data is None
    assert ring10_noise(bad={}).design.bad_data == (1e-5, 3)
    assert ring10_noise(bad={"false_alarm": 1e-3, "suspect_after": 5}).design.bad_data == (1e-3, 5)


def bad_data_as_written(text: str):
    """ring10_noise with ``design.bad_data`` written ``text`` in the file (YAML reads ``off``/``no`` as false)."""
    raw = yaml.safe_load((EXAMPLES / "ring10_noise.yaml").read_text())
    raw["run"] = {"steps": 100}
    body = yaml.safe_dump(raw).replace("design:\n", f"design:\n  bad_data: {text}\n", 1)
    return parse_scenario_text(body, source="ring10_noise").design


@pytest.mark.parametrize("text", ["off", "Off", "no", "false", '"off"'])
def test_bad_data_off_as_the_docs_write_it_turns_the_test_off(text):
    """Issue 46, finding 1: ``design.bad_data: off`` (a boolean to YAML) was refused as "must be a mapping"."""
    d = bad_data_as_written(text)
    assert d.bad_data is None and not d.bad_data_default


@pytest.mark.parametrize("text", ["on", "true", "yes", '"on"'])
def test_bad_data_on_is_the_test_with_its_declared_defaults(text):
    d = bad_data_as_written(text)
    assert d.bad_data == (1e-5, 3) and not d.bad_data_default


def test_bad_data_is_on_by_default_when_the_scenario_states_measurement_noise():
    """Issue 46, finding 2: absent, the test is on under stated measurement noise, and the report says so first."""
    d = ring10_noise(bad=None).design
    assert d.bad_data == (1e-5, 3) and d.bad_data_default
    lines = report_lines(design(ring10_noise(bad=None)))
    assert lines[0] == ("bad-data test: on (default: the scenario states measurement noise; design.bad_data: off "
                        "turns it off)")
    assert lines[1].startswith("bad data: each agent tests")
    raw = yaml.safe_load((EXAMPLES / "ring10.yaml").read_text())  # noise-free: nothing to calibrate, off
    quiet = parse_scenario_text(yaml.safe_dump(raw), source="ring10").design
    assert quiet.bad_data is None and not quiet.bad_data_default


def test_the_default_test_is_off_where_the_design_cannot_calibrate_it_and_the_report_says_why():
    """Measurement noise on some outputs only, or a kind without the test: off by default, one line saying why
    (given explicitly, the first is refused: test_bad_data_needs_measurement_noise)."""
    raw = yaml.safe_load((EXAMPLES / "ring10_noise.yaml").read_text())
    raw["system"]["measurement_noise"] = {1: 0.0, **{k: 0.1 for k in range(2, 11)}}
    raw["run"] = {"steps": 100}
    des = design(parse_scenario_text(yaml.safe_dump(raw), source="some"))
    assert bad_data(des) is None
    assert report_lines(des) == ["bad-data test: off (system.measurement_noise is 0 on some output: the test is "
                                 "calibrated against it; on by default when the scenario states measurement noise)"]
    des = design(ring10_noise(bad=None, consensus="fusion", gains="optimal", resilience=0))
    assert bad_data(des) is None and des.consensus == "fusion"
    assert report_lines(des)[0].startswith("bad-data test: off (design.consensus: fusion has no bad-data test")


@pytest.mark.parametrize("bad, words", [
    ({"false_alarm": 0.7}, "design.bad_data.false_alarm must be in (0, 0.5), got 0.7"),
    ({"suspect_after": 0}, "design.bad_data.suspect_after must be >= 1"),
    ({"false_alarms": 1e-3}, "unknown key design.bad_data.false_alarms"),
    ("sometimes", "design.bad_data must be off, on or a map {false_alarm, suspect_after}, got the string"),
    (3, "design.bad_data must be off, on or a map {false_alarm, suspect_after}, got int 3"),
])
def test_bad_data_refuses_bad_values_in_one_line(bad, words):
    with pytest.raises(ScenarioError) as e:
        ring10_noise(bad=bad)
    assert words in str(e.value) and "\n" not in str(e.value)


def test_bad_data_needs_measurement_noise():
    raw = yaml.safe_load((EXAMPLES / "ring10.yaml").read_text())  # noise-free
    raw["design"]["bad_data"] = ON
    with pytest.raises(ScenarioError, match="design.bad_data needs system.measurement_noise above 0"):
        parse_scenario_text(yaml.safe_dump(raw), source="ring10")


# ------------------------------------------------------------------------------------------------ the pure steps


def test_sensor_watch_suspects_after_k_failures_in_a_row_and_restores_after_k_clean_tests():
    state, events = (False, 0), []
    tests = [True, True, False, True, True, True, False, None, False, True, False, False, False, True]
    for failed in tests:
        suspect, run, event = st.sensor_watch(*state, failed, 3)
        state = (suspect, run)
        events.append(event)
    assert events.index("sensor_suspect") == 5  # the third failure in a row (a clean test at 2 broke the first run)
    # suspect from 6: clean at 6 and 8 (7 has no measurement: no change), a failure at 9 starts over: 10, 11, 12
    assert events.index("sensor_restored") == 12
    assert [e for e in events if e] == ["sensor_suspect", "sensor_restored"]


def test_innovation_test_is_the_quadratic_form_against_the_threshold():
    rng = np.random.default_rng(3)
    C, z, y = rng.normal(size=(2, 4)), rng.normal(size=4), rng.normal(size=2)
    L = rng.normal(size=(2, 2))
    S = L @ L.T + np.eye(2)
    r = y - C @ z
    expected = float(r @ np.linalg.solve(S, r))
    d, failed = st.innovation_test(y, C, z, np.linalg.inv(S), expected + 1e-9)
    assert d == pytest.approx(expected, rel=1e-12) and not failed
    assert st.innovation_test(y, C, z, np.linalg.inv(S), expected - 1e-9)[1]


# ------------------------------------------------------------------------------------------------ the design


def test_threshold_is_the_chi_square_quantile_and_S_is_the_steady_state_innovation_covariance():
    des = design(ring10_noise())
    bd = bad_data(des)
    for t, C, R in zip(bd.tests, des.scenario.system.Cs, des.scenario.system.measurement_covariances):
        assert t.threshold == pytest.approx(chi2.ppf(1 - 1e-5, np.shape(C)[0]), rel=1e-9)
        assert np.all(np.linalg.eigvalsh(t.S - R) >= -1e-12)  # C Sigma C' >= 0 on top of R
        np.testing.assert_allclose(t.S_inv @ t.S, np.eye(len(t.S)), atol=1e-12)
    assert bd.warmup == int(np.ceil(np.log(1e3) / -np.log(0.8)))


def test_the_statistic_is_chi_square_on_clean_data():
    """mean d_i = s_i = 1 (S_i right), and d_i > chi2.ppf(0.99) at rate 0.01 (the threshold's calibration)."""
    des = design(ring10_noise(steps=4000))
    tr = simulate(des)
    warm = bad_data(des).warmup
    d = tr.columns["y_statistic"][warm:-1]
    assert np.all(d >= 0)  # every alive agent tested every event time after its warm-up
    assert np.all(tr.columns["y_statistic"][:warm] == UNTESTED)
    mean, se = batch_means(d.mean(axis=1))
    assert abs(mean - 1.0) < 4 * se, (mean, se)
    rate, se = batch_means((d > chi2.ppf(0.99, 1)).mean(axis=1))
    assert abs(rate - 0.01) < 4 * se + 1e-3, (rate, se)


def test_empirical_innovation_covariance_matches_S():
    """r_i = y_i - C_i x_i(tau) from a long noisy run (the split's C_i z_i(q) = C_i x_i(tau)), per agent."""
    des = design(ring10_noise(steps=4000))
    tr = simulate(des, keep_y=True)
    warm = bad_data(des).warmup
    for k, (t, C) in enumerate(zip(bad_data(des).tests, des.scenario.system.Cs)):
        r = tr.y[warm:-1, k] - tr.xhat[warm:-1, k] @ np.asarray(C)[0]
        var, se = batch_means(r ** 2)
        assert abs(var - t.S[0, 0]) < 4 * se, (t.agent, var, t.S[0, 0], se)


def test_every_sensor_of_ring10_noise_can_be_lost_and_the_report_says_so():
    des = design(ring10_noise())  # given explicitly: no line saying it is the default
    lines = report_lines(des)
    assert lines[0].startswith("bad data: each agent tests") and "threshold 19.51 for s_i = 1" in lines[0]
    for f, line in zip(bad_data(des).fallbacks, lines[1:]):
        rho = fallback_radius(des, f.agent, 0)
        assert f.certified and rho < 0.8 and line == f.text
        assert line == f"agent {f.agent}'s sensor can be lost: radius {rho:.4g} meets rate 0.8 (graph ring)"


def test_a_sensor_that_alone_sees_an_oscillator_cannot_be_lost():
    """The paper's example: agent 3 alone sees x3, x4 (an undamped oscillator): its loss is not survivable."""
    raw = yaml.safe_load((EXAMPLES / "paper_discrete.yaml").read_text())
    raw["system"]["measurement_noise"] = 0.1
    raw["system"]["process_noise"] = 0.05
    raw["design"]["bad_data"] = ON
    des = design(parse_scenario_text(yaml.safe_dump(raw), source="paper"))
    f3 = bad_data(des).fallbacks[2]
    assert not f3.certified and not f3.stable
    assert f3.text.startswith("agent 3's sensor cannot be lost: the others leave 2 directions unobserved")
    assert bad_data(des).fallbacks[0].stable  # agent 2 still sees the first oscillator


# ------------------------------------------------------------------------------------------------ a sensor that lies


@pytest.fixture(scope="module")
def clean_rms():
    tr = simulate(design(ring10_noise(bad="off", steps=AT + FOR)))
    return np.sqrt((tr.errors()[100:AT] ** 2).mean(axis=0)), float(tr.x[:, 4].std())


@pytest.mark.parametrize("what", ["noise", "signal"])
def test_a_sensor_biased_20_sd_is_flagged_and_set_aside(clean_rms, what):
    """Agent 3 biased 20 standard deviations for 60 event times: of its measurement noise (0.1), or of its signal
    (x5's std over the run, about 2.4): flagged within 5 event times, errors within 2x (others) and 3x (agent 3)
    their clean steady RMS; without the test they are many times that."""
    rms, signal = clean_rms
    bias = 20 * (0.1 if what == "noise" else signal)
    faults = [{"at": AT, "corrupt": 3, "for": FOR, "bias": bias}]
    des = design(ring10_noise(faults=faults, steps=AT + FOR + 20))
    tr = simulate(des)
    rejected = tr.columns["y_rejected"][:, 2]
    first = AT + int(np.argmax(rejected[AT:]))
    events = sensor_events(tr, bad_data(des))
    (suspect,) = [e for e in events if e[2] == "sensor_suspect"]
    assert first - AT <= 5 and suspect[0] - AT <= 5 and suspect[1] == 3, events
    assert rejected[AT:AT + FOR].all()
    ratio = tr.errors()[AT:AT + FOR].mean(axis=0) / rms
    assert np.all(np.delete(ratio, 2) <= 2.0) and ratio[2] <= 3.0, ratio
    (restored,) = [e for e in events if e[2] == "sensor_restored"]
    assert AT + FOR <= restored[0] <= AT + FOR + 5  # taken back after k clean tests
    blind = simulate(design(ring10_noise(bad="off", faults=faults, steps=AT + FOR + 20)))
    assert (blind.errors()[AT:AT + FOR].mean(axis=0) / rms).max() > 5 * ratio.max()


def test_a_lie_is_caught_by_the_default_test(clean_rms):
    """Issue 46, finding 2: no design.bad_data key, measurement noise stated: the biased sensor is flagged and the
    other agents stay within 2x their clean steady RMS (without a test they were many times it)."""
    rms, _ = clean_rms
    faults = [{"at": AT, "corrupt": 3, "for": FOR, "bias": 2.0}]
    des = design(ring10_noise(bad=None, faults=faults, steps=AT + FOR + 20))
    tr = simulate(des)
    assert [e[1:3] for e in sensor_events(tr, bad_data(des))][:1] == [(3, "sensor_suspect")]
    ratio = tr.errors()[AT:AT + FOR].mean(axis=0) / rms
    assert np.all(np.delete(ratio, 2) <= 2.0), ratio


def test_clean_data_rejects_at_most_2_per_10000_agent_event_times():
    tr = simulate(design(ring10_noise(steps=1000, seed=4)))
    tested = tr.columns["y_statistic"] >= 0
    assert tested.sum() >= 9000
    assert tr.columns["y_rejected"].sum() <= 2 * tested.sum() / 10_000


@pytest.mark.parametrize("consensus", ["split", "whole"])
def test_batch_and_agent_loop_estimators_agree_with_a_suspect_sensor(consensus):
    """The vectorised estimator's fallback (P_i = I on S itself) and the agents' step functions: the same run."""
    faults = [{"at": 40, "corrupt": 3, "for": 20, "bias": 2.0}, {"at": 45, "kill": 5, "for": 8}]
    gains = {"consensus": "whole", "gains": "kalman", "resilience": 0} if consensus == "whole" else {}
    des = design(ring10_noise(faults=faults, steps=90, **gains))
    a, b = simulate(des, estimator="batch"), simulate(des, estimator="loop")
    np.testing.assert_allclose(a.xhat, b.xhat, rtol=0, atol=1e-9)
    assert (a.columns["y_rejected"] == b.columns["y_rejected"]).all() and a.columns["y_rejected"][40:60, 2].all()
    np.testing.assert_allclose(a.columns["y_statistic"], b.columns["y_statistic"], rtol=1e-6, atol=1e-9)
    assert not a.columns["y_rejected"][:, 4][45:53].any()  # agent 5 dead: the fill


def test_the_consensus_sub_rounds_leave_what_each_agent_sees_alone():
    """C_i P_i = 0 (P_i projects on agent i's unobservable space), so C_i z_i(q) = C_i x_i(tau): the innovation the
    split design's update forms is the one the test's S_i predicts."""
    des = design(ring10_noise())
    for C, P in zip(des.scenario.system.Cs, des.Ps):
        assert np.abs(np.asarray(C) @ P).max() < 1e-12


def test_continuous_time_batch_and_agent_loop_agree_and_agent_3_cannot_be_lost():
    """The sampled-data form (continuous split design, fixed g): a biased sensor set aside, the fallback's P_i = I in
    both estimators; the report's line for the sensor only agent 3 has."""
    raw = yaml.safe_load((EXAMPLES / "paper_continuous.yaml").read_text())
    raw["system"]["measurement_noise"] = 0.05
    raw["design"]["bad_data"] = ON
    raw["faults"] = [{"at": 8.0, "corrupt": 2, "for": 1.0, "bias": 5.0}]
    des = design(parse_scenario_text(yaml.safe_dump(raw), source="paper_continuous"))
    a, b = simulate(des), simulate(des, estimator="loop")
    np.testing.assert_allclose(a.xhat, b.xhat, rtol=0, atol=1e-9)
    assert (a.columns["y_rejected"] == b.columns["y_rejected"]).all()
    assert a.columns["y_rejected"][800:900, 1].mean() > 0.9 and not a.columns["y_rejected"][:800].any()
    lines = report_lines(des)
    assert "its first 691 measurements (steps of run.dt = 0.01) untested" in lines[0], lines[0]
    assert lines[3].startswith("agent 3's sensor cannot be lost: the others leave 2 directions unobserved")


def test_the_whole_state_fallback_in_continuous_time_is_held_to_the_per_step_rate():
    """The whole-state design runs on the sampled model: its fallback's radius per step is held to exp(-rate dt),
    not to the rate itself (each sensor's verdict follows from its radii against that number)."""
    import math

    raw = yaml.safe_load((EXAMPLES / "paper_continuous.yaml").read_text())
    raw["system"].update(measurement_noise=0.05, process_noise=0.05)
    raw["design"].update(bad_data=ON, consensus="whole", gains="optimal")
    for key in ("g", "K", "g0"):
        raw["design"].pop(key, None)
    des = design(parse_scenario_text(yaml.safe_dump(raw), source="paper_continuous"))
    assert des.consensus == "whole"
    target = math.exp(-des.rate * des.scenario.run.dt)
    bd = bad_data(des)
    for fb in bd.fallbacks:
        assert fb.certified == all(r <= target for r in fb.radius.values()), fb
        if fb.stable:
            assert f"exp(-rate dt) = {target:.5g}" in fb.text, fb.text
    assert any(fb.stable for fb in bd.fallbacks)


def test_the_sensor_events_read_as_sentences():
    """The Rerun log and the terminal say what happened, not the event's raw fields."""
    from splitspec_orchestrator.records.events import event_text

    assert event_text("sensor_suspect", {"agent": 3, "statistic": 192.93, "threshold": 19.51}) == \
        "agent 3's sensor suspect (statistic 192.9 over 19.51): it estimates from its neighbours alone"
    assert event_text("sensor_restored", {"agent": 3, "statistic": 0.4, "threshold": 19.51}) == \
        "agent 3's sensor restored (statistic 0.4 under 19.51)"


def test_a_stuck_sensor_is_caught_by_its_repeats_at_once():
    """A sensor holding its last value (corrupt ... stuck): the chi-square test alone lets it through while the
    signal has not moved far (the IEEE 14-bus PMU angles); the repeat test fails it at its first repeat, reported as
    y_statistic FLATLINE, and the replayed watch (the orchestrator's events) agrees with the simulator's."""
    from splitspec_core.model.screening import FLATLINE
    from splitspec_orchestrator.records.events import event_text

    des = design(ring10_noise(faults=[{"at": 200, "corrupt": 3, "stuck": True, "for": 60}], steps=300))
    tr = simulate(des)
    k = des.scenario.agent_ids.index(3)
    assert (tr.columns["y_statistic"][200:260, k] == FLATLINE).all()
    # set aside while stuck, and while suspect after it: 3 clean tests restore it (the third at 262)
    assert tr.columns["y_rejected"][200:262, k].all() and not tr.columns["y_rejected"][263:299, k].any()
    assert (tr.columns["y_statistic"][:200] != FLATLINE).all() and (tr.columns["y_statistic"][:, k != np.arange(10)]
                                                                   != FLATLINE).all()
    ev = sensor_events(tr, bad_data(des))
    assert [(e[0], e[1], e[2]) for e in ev] == [(202, 3, "sensor_suspect"), (262, 3, "sensor_restored")]
    assert "repeats exactly: stuck" in event_text("sensor_suspect", {"agent": 3, "statistic": ev[0][3],
                                                                     "threshold": ev[0][4]})
    assert "a measurement repeating the last one exactly fails" in report_lines(des)[0]


def test_live_sensors_have_no_repeat_test():
    """A live sensor slower than the rounds gives its sample twice: the repeat test is off there, and says so."""
    raw = yaml.safe_load((EXAMPLES / "ring10_noise.yaml").read_text())
    raw["design"]["bad_data"] = ON
    raw["sources"] = {i: f"sensors/{i}" for i in range(1, 11)}
    raw["run"] = {**raw.get("run", {}), "pace": 10}
    des = design(parse_scenario_text(yaml.safe_dump(raw), source="live"))
    assert bad_data(des).flatline is False
    assert "no repeat test" in report_lines(des)[0]


MOTOR = """
name: motor
time: discrete
system:
  time_unit: ms
  sample: 1.0
  A: [[0, 0.001, 0, 0, 0], [-100, -0.05, 100, 0.05, 0.5], [0, 0, 0, 0.001, 0], [10, 0.005, -10, -0.006, 0],
      [0, -0.05, 0, 0, -1]]
  B: [[0], [0], [0], [0], [1]]
  u: {constant: [1.0], sine: [{amplitude: [2.0], period: 200}]}
  C: {1: [[1, 0, 0, 0, 0]], 2: [[0, 0, 1, 0, 0]], 3: [[0, 0, 0, 0, 1]]}
  process_noise: [1.0e-6, 0.05, 1.0e-6, 0.05, 0.01]
  measurement_noise: {1: 5.0e-4, 2: 5.0e-3, 3: 0.01}
graphs:
  bus: {undirected: [[1, 2], [2, 3]]}
design: {rate: 0.98}
run: {steps: 1300, seed: 1}
faults:
  - {at: 700, kill: 3, for: 100}
"""


def test_a_rejoin_does_not_make_the_other_agents_sensors_suspect():
    """Issue 46 (the walk on a motor driving a load through a flexible shaft): the current sensor's agent killed at
    700 and restarted at 800 rejoins with a fresh estimate (its angle 10 rad off: the motor has turned) that the
    whole-state consensus spreads in one event time; every neighbour's clean measurement failed its test, the two
    angle sensors became suspect, and, nobody else seeing the angle, were never restored (the error held at 2.6 rad
    to the end).  A rejoin starts every agent's warm-up afresh, as the run's start does: no sensor is suspect, and
    every agent is back within 2x its clean steady RMS."""
    des = design(parse_scenario_text(MOTOR, source="motor"))
    tr = simulate(des)
    assert sensor_events(tr, bad_data(des)) == []
    err = tr.errors()
    clean = np.sqrt((err[400:700] ** 2).mean(axis=0))
    back = np.sqrt((err[1200:] ** 2).mean(axis=0))
    assert np.all(back <= 2.0 * clean), (back, clean)
    assert not tr.columns["y_rejected"][800:].any()


def test_a_rejoin_leaves_the_split_designs_tests_running():
    """The split's consensus moves only what each agent does not see (C_i P_i = 0): a rejoin does not reach the
    others' innovations, so their tests go on through it (no warm-up: a lie starting then is caught at once), and
    nothing is flagged."""
    des = design(parse_scenario_text(MOTOR.replace("design: {rate: 0.98}",
                                                   "design: {rate: 0.98, consensus: split, gains: riccati}"),
                                     source="motor"))
    tr = simulate(des)
    stat = tr.columns["y_statistic"]
    assert (stat[800:810, :2] >= 0).all() and (stat[800:810, 2] == UNTESTED).all()  # agent 3 itself warms up
    assert sensor_events(tr, bad_data(des)) == [] and not tr.columns["y_rejected"].any()
