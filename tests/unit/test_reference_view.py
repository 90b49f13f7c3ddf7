"""What a run on measurements records: ReferenceRows (pure) and the reference tab of the default blueprint."""

from __future__ import annotations

import numpy as np
import pytest

from splitspec_core.measurements import Measurements
from splitspec_core.reference import disagreement, residuals
from splitspec_orchestrator import blueprint as bp
from splitspec_orchestrator.reference_view import ReferenceRows, file_rows, known_parts, progress_text

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
    # the same as the functions that write trajectory.npz
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


def tab_names(blueprint) -> list[str]:
    tabs = blueprint.root_container.contents[0]
    return [t.name for t in tabs.contents]


@pytest.mark.parametrize("time_mode", ["discrete", "continuous"])
def test_the_blueprint_of_a_run_on_measurements_opens_on_the_reference_tab(time_mode):
    gains = time_mode == "continuous"
    today = ["log10 |x_i - x|, designed envelope, marks", "|x_i - x| (linear)", "states"] + \
        (["adaptive gains g_i"] if gains else []) + ["rounds"]
    # no measurements: the layout of every run so far, unchanged
    assert tab_names(bp.default_blueprint(time_mode, n=3, gains=gains)) == today
    ref = [bp.REFERENCE_TAB, f"{bp.REFERENCE_TAB} (linear)"]
    # with the truth: the reference tabs first, then the errors as before
    blue = bp.default_blueprint(time_mode, n=3, gains=gains, reference=True)
    assert tab_names(blue) == ref + today and blue.root_container.contents[0].active_tab == 0
    # without the truth: no error tab at all
    assert tab_names(bp.default_blueprint(time_mode, n=3, gains=gains, reference=True, truth=False)) == \
        ref + today[2:]
    views = [v.name for v in blue.root_container.contents[0].contents[0].contents]
    assert views == ["log10 residuals |y_i - C_i x_i|", "log10 disagreement max_ij |x_i - x_j|",
                     "log10 distance to the centralized KF |x_i - x_KF| (after the run)"]
    for truth, states in ((True, 4), (False, 2)):  # a tab by name: after the reference tabs
        blue = bp.default_blueprint(time_mode, n=3, reference=True, truth=truth, active_tab="states")
        assert blue.root_container.contents[0].active_tab == states
