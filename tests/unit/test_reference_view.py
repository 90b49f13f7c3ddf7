"""What a run on measurements records: ReferenceRows (pure), the reference tab of the default blueprint, and a
Recorder fed by a y source without the truth, read back from its run.rrd."""

from __future__ import annotations

import numpy as np
import pytest

from splitspec_core.scenarios.measurements import Measurements
from splitspec_core.studies.no_truth import disagreement, residuals
from splitspec_orchestrator.viewer import blueprint as bp
from splitspec_orchestrator.records.recorder import Recorder, RecordingError
from splitspec_orchestrator.viewer.reference_view import ReferenceRows, file_rows, known_parts, progress_text
from tests.rrd_readback import read_rrd, read_rrd_clears, rrd_entities, verify_rrd
from tests.unit.test_measurements import hidden_scenario

# two agents, n = 2: agent 1 sees x1, agent 2 sees x1 + x2 and x2
CS = [np.array([[1.0, 0.0]]), np.array([[1.0, 1.0], [0.0, 1.0]])]


def test_residuals_and_disagreement_by_hand():
    y = {0: (np.array([1.0, 3.0, 2.0]), np.array([False, False])),
         1: (np.array([0.0, 3.0, 2.0]), np.array([True, False]))}
    rows = ReferenceRows(CS, y.get)  # event time 2: no measurement known
    xhat = np.array([[[1.0, 0.0], [1.0, 2.0]],          # agent 1 explains y_1; agent 2: |(3, 2) - (3, 2)| = 0
                     [[0.0, 0.0], [4.0, 3.0]],          # agent 1 missing; agent 2: |(3, 2) - (7, 3)| = sqrt(17)
                     [[np.nan, np.nan], [0.0, 0.0]]])   # agent 1 dead, no y at all
    b = rows.batch([0, 1, 2], [0.0, 1.0, 2.0], [0, 0, 0], xhat)
    np.testing.assert_array_equal(b.residual, [[0.0, 0.0], [np.nan, np.sqrt(17.0)], [np.nan, np.nan]])
    np.testing.assert_array_equal(b.disagreement, [2.0, 5.0, 0.0])  # |(0,2)|, |(4,3)|, one agent alive
    # the same as the functions that write trajectory.npz (exact: those functions, on this one whole batch)
    Y, missing = rows.measurements([0, 1, 2])
    assert missing.tolist() == [[False, False], [True, False], [True, True]]
    np.testing.assert_array_equal(b.residual, residuals(xhat, Y, missing, CS))
    np.testing.assert_array_equal(b.disagreement, disagreement(xhat))


def test_a_clear_wherever_a_value_is_unknown():
    rows = ReferenceRows(CS, lambda tau: (np.array([1.0, 3.0, 2.0]), np.array([tau == 1, False])))
    xhat = np.array([[[1.0, 0.0], [1.0, 2.0]], [[1.0, 0.0], [1.0, 2.0]], [[np.nan, np.nan], [np.nan, np.nan]]])
    parts = {path: (v, known) for path, v, known in rows.batch([0, 1, 2], [0, 1, 2], [0, 0, 0], xhat).parts([1, 2])}
    assert set(parts) == {"residual/agent_1", "residual_log10/agent_1", "residual/agent_2",
                          "residual_log10/agent_2", "disagreement", "disagreement_log10"}
    # agent 1: 0 (known; its log10 is not), missing (Clear), dead (Clear)
    assert parts["residual/agent_1"][1].tolist() == [True, False, False]
    assert parts["residual_log10/agent_1"][1].tolist() == [False, False, False]
    assert parts["disagreement"][1].tolist() == [True, True, False]  # none alive at event time 2
    np.testing.assert_array_equal(parts["disagreement_log10"][0][:2], np.log10([2.0, 2.0]))
    path, v, known = known_parts("a", "a_log10", np.array([1e-3, np.inf]))[1]
    assert path == "a_log10" and known.tolist() == [True, False] and v[0] == pytest.approx(-3.0, abs=1e-15)


def test_file_rows_and_a_row_of_the_wrong_shape():
    meas = Measurements("m.npz", t=np.arange(3.0), y=np.arange(9.0).reshape(3, 3),
                        missing=np.array([[False, False], [False, True], [False, False]]), x=None, sha256="")
    y_row = file_rows(meas)
    assert y_row(3) is None and y_row(-1) is None
    y, miss = y_row(1)
    assert y.tolist() == [3.0, 4.0, 5.0] and miss.tolist() == [False, True]
    with pytest.raises(ValueError, match=r"event time 0 has y \(2,\).*expected \(3,\)"):
        ReferenceRows(CS, lambda tau: (np.zeros(2), np.zeros(2, bool))).measurements([0])


def test_a_mark_stands_on_the_last_positive_disagreement():
    rows = ReferenceRows(CS, lambda tau: None)
    assert rows.mark_y(5) == 0.0  # nothing batched yet
    same = [[1.0, 1.0], [1.0, 1.0]]
    rows.batch([0, 1, 2, 200], [0] * 4, [0] * 4, np.array([[[0.0, 0.0], [0.0, 10.0]], [[0.0, 0.0], [0.0, 100.0]],
                                                           same, [[0.0, 0.0], [0.0, 1e-3]]]))
    assert rows.mark_y(0) == pytest.approx(1.0) and rows.mark_y(1) == pytest.approx(2.0)
    assert rows.mark_y(2) == pytest.approx(2.0)  # event time 2 agrees exactly: log10 0 is no height
    assert rows.mark_y(150) == pytest.approx(2.0) and rows.mark_y(10_000) == pytest.approx(-3.0)


def test_progress_shows_the_disagreement_without_truth():
    xhat = np.array([[0.0, 0.0], [3.0, 4.0], [np.nan, np.nan]])
    assert progress_text(1.5e-3, xhat) == "max error 1.500e-03"
    assert progress_text(float("nan"), xhat) == "disagreement 5.000e+00"
    assert progress_text(float("nan"), xhat, np.array([True, False, True])) == "disagreement 0.000e+00"


def tab_names(blueprint) -> list[str]:
    tabs = blueprint.root_container.contents[0]
    return [t.name for t in tabs.contents]


@pytest.mark.parametrize("time_mode", ["discrete", "continuous"])
def test_the_blueprint_of_a_run_on_measurements_opens_on_the_reference_tab(time_mode):
    columns = ("g",) if time_mode == "continuous" else ()  # the reported row columns shown (continuous: g)
    today = ["log10 |x_i - x|, designed envelope, marks", "|x_i - x| (linear)", "states"] + \
        ([bp.PER_AGENT_TAB] if columns else []) + ["rounds"]
    # no measurements: the layout of every run so far, unchanged
    assert tab_names(bp.default_blueprint(time_mode, n=3, columns=columns)) == today
    ref = [bp.REFERENCE_TAB, f"{bp.REFERENCE_TAB} (linear)"]
    # with the truth: the reference tabs first, then the errors as before
    blue = bp.default_blueprint(time_mode, n=3, columns=columns, reference=True)
    assert tab_names(blue) == ref + today and blue.root_container.contents[0].active_tab == 0
    # without the truth: no error tab at all
    assert tab_names(bp.default_blueprint(time_mode, n=3, columns=columns, reference=True, truth=False)) == \
        ref + today[2:]
    views = [v.name for v in blue.root_container.contents[0].contents[0].contents]
    assert views == ["log10 residuals |y_i - C_i x_i|", "log10 disagreement max_ij |x_i - x_j|",
                     "log10 distance to the centralized KF |x_i - x_KF| (after the run)"]
    for truth, states in ((True, 4), (False, 2)):  # a tab by name: after the reference tabs
        blue = bp.default_blueprint(time_mode, n=3, reference=True, truth=truth, active_tab="states")
        assert blue.root_container.contents[0].active_tab == states


def test_a_recorder_on_a_y_source_without_truth(tmp_path):
    """Continuous time with gains: a live-like y source that knows no row at event times 3 and 4 and misses agent
    1's at 6; agent 5 lost at 8 once rows up to 10 were logged.  No error, no truth; gains, states, residuals."""
    sc = hidden_scenario(3, "continuous")
    ids, n, T = list(sc.agent_ids), sc.n, 14
    rng = np.random.default_rng(0)
    Y = rng.normal(size=(T, sum(np.shape(C)[0] for C in sc.system.Cs)))

    def y_row(tau):
        if tau in (3, 4):
            return None
        return Y[tau], np.array([tau == 6] + [False] * (len(ids) - 1))

    rec = Recorder(tmp_path, agent_ids=ids, n=n, steps=T - 1, time_mode="continuous", dt=sc.run.dt,
                   graph_names=("a",), run_id="ref", scenario_name="ref", flush_seconds=0, columns=("g",))
    rec.set_y_source(sc, y_row, truth=False)
    xhat = rng.normal(size=(T, len(ids), n))
    alive = np.ones(len(ids), bool)
    for tau in range(T):
        rec.row(tau, np.full(n, np.nan), xhat[tau], alive, 0, g=np.full(len(ids), 2.0 + tau))
        if tau == 10:
            rec.mark_lost(8, ids[-1])
            alive = alive.copy()
            alive[-1] = False
    rec.close()
    rrd = tmp_path / "run.rrd"
    ok, msg = verify_rrd(rrd)
    assert ok, msg
    ents = rrd_entities(rrd)
    assert not [e for e in ents if e.startswith("errors") or e.endswith("/truth")], sorted(ents)
    series, clears = read_rrd(rrd), read_rrd_clears(rrd)
    with np.load(tmp_path / "trajectory.npz") as f:
        res, dis, kf = f["residual"], f["disagreement"], f["kf"]
        assert f["y_missing"][3:5].all() and f["y_missing"][6, 0] and not f["y_missing"][7].any()
    dead = xhat.copy()
    dead[8:, -1] = np.nan
    np.testing.assert_allclose(dis, disagreement(dead), rtol=0, atol=0)
    assert [k for k, _ in series["disagreement"]] == list(range(T))
    np.testing.assert_allclose([v for _, v in series["disagreement"]], dis, rtol=1e-12, atol=0)
    got = dict(series[f"residual/agent_{ids[0]}"])
    assert sorted(got) == [k for k in range(T) if k not in (3, 4, 6)]
    np.testing.assert_allclose([got[k] for k in sorted(got)], res[sorted(got), 0], rtol=1e-12, atol=0)
    assert {3, 4, 6} <= set(clears[f"residual/agent_{ids[0]}"])
    assert set(range(8, T)) <= set(clears[f"residual/agent_{ids[-1]}"])
    assert sorted(dict(series[f"residual/agent_{ids[-1]}"])) == [k for k in range(8) if k not in (3, 4)]
    # gains are logged without the truth (they are known), the lost agent's up to its loss
    assert sorted(dict(series[f"gains/agent_{ids[-1]}"])) == list(range(8))
    assert dict(series[f"gains/agent_{ids[0]}"])[T - 1] == 2.0 + T - 1
    np.testing.assert_array_equal([v for _, v in series["state/1/kf"]], kf[:, 0])


@pytest.mark.filterwarnings("ignore:RRD file has no footer")
def test_a_killed_run_without_truth_is_recovered_with_its_layout(tmp_path):
    """The records of a run on measurements killed mid-run (copied before its close): ``splitspec recover``
    rebuilds the blueprint from the recording's properties, the reference views and no error view."""
    import shutil

    from splitspec_orchestrator.records.recover import recover
    from tests.rrd_readback import read_blueprint

    sc = hidden_scenario(3)
    ids, n = list(sc.agent_ids), sc.n
    Y = np.random.default_rng(1).normal(size=(6, sum(np.shape(C)[0] for C in sc.system.Cs)))
    rec = Recorder(tmp_path / "run", agent_ids=ids, n=n, steps=5, time_mode="discrete", dt=1.0, graph_names=("a",),
                   run_id="killed", scenario_name="killed", flush_seconds=0)
    rec.set_y_source(sc, lambda tau: (Y[tau], np.zeros(len(ids), bool)), truth=False)
    for tau in range(6):
        rec.row(tau, np.full(n, np.nan), np.full((len(ids), n), float(tau)), np.ones(len(ids), bool), 0)
    with pytest.raises(RecordingError, match=r"set_y_source\(\) after the first row"):
        rec.set_y_source(sc, lambda tau: None, truth=True)
    killed = tmp_path / "killed"
    shutil.copytree(tmp_path / "run", killed)  # what a SIGKILL now leaves: run.rrd without footer
    rec.close()
    assert recover(killed)["rrd"] == "rewritten"
    views = {name for _, name, _ in read_blueprint(killed / "run.rrd")["views"]}
    assert "log10 residuals |y_i - C_i x_i|" in views and not [v for v in views if "|x_i - x|" in v], views


def test_each_known_measurement_is_asked_once():
    """trajectory.npz asks for every row at every flush: y_row is asked again only where it knew nothing."""
    asked = []

    def y_row(tau):
        asked.append(tau)
        return None if tau == 2 else (np.full(3, float(tau)), np.array([False, tau == 1]))

    rows = ReferenceRows(CS, y_row)
    rows.measurements([0, 1, 2])
    Y, missing = rows.measurements(np.arange(100))  # past the first 64 rows kept
    assert asked == [0, 1, 2] + [2] + list(range(3, 100))
    assert Y[99].tolist() == [99.0] * 3 and Y[2].tolist() == [0.0] * 3 and missing[2].all()
    assert missing[1].tolist() == [False, True] and not missing[50].any()
