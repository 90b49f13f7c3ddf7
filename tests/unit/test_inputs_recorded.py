"""Every run records the known inputs u its estimators used (issue 38 item 3): ``trajectory.npz``'s ``u``, the chunks'
``u`` column (only with ``system.B``), read back by ``read_chunks``, ``Trajectory`` and ``ss.load_run``; with live
inputs the u the agents report, and the centralized Kalman filter runs on it."""

import os

import numpy as np
import pytest
import yaml

import splitspec_core as ss
from splitspec_core.model.plant import input_of
from splitspec_core.model.rows import report
from splitspec_core.scenarios.load import load_scenario
from splitspec_core.scenarios.measurements import load_measurements, write_measurements
from splitspec_core.simulation.simulator import Trajectory
from splitspec_core.simulation.trajectory_chunks import ChunkWriter, read_chunks
from splitspec_core.studies.no_truth import held_inputs, kalman_reference
from splitspec_orchestrator.records.recorder import Recorder
from splitspec_orchestrator.rounds.collected import Collected

os.environ.setdefault("RERUN_ANALYTICS", "0")

SYSTEM = {"A": [[0.9, 0.3], [-0.3, 0.9]], "B": [[0.0, 1.0], [1.0, 0.0]],
          "C": {1: [[1.0, 0.0]], 2: [[0.0, 1.0]], 3: [[1.0, 1.0]]}}


def scenario(tmp_path, *, live: bool, u=None):
    system = dict(SYSTEM, **({"u": u} if u is not None else {}))
    data = {"name": "inputs", "time": "discrete", "system": system,
            "graphs": {"a": {"undirected": [[1, 2], [2, 3]]}}, "design": {"rate": 0.5},
            "run": {"steps": 5, "seed": 1, **({"pace": 10} if live else {})}}
    if live:
        data["sources"] = {1: "s/1", 2: "s/2", 3: "s/3", "inputs": "s/u"}
    path = tmp_path / "scenario.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return load_scenario(path)


def rows(L, m=2, n=2):
    return dict(tau=np.arange(L), t=np.arange(L, dtype=float), x=np.zeros((L, n)), xhat=np.ones((L, m, n)),
                alive=np.ones((L, m), dtype=bool), graph=np.zeros(L, dtype=int), wall=np.zeros(L, dtype=int),
                round=np.zeros((L, 5)), lost=[[]] * L)


def test_the_chunks_u_column_round_trips_and_is_absent_without_inputs(tmp_path):
    u = np.array([[1.0, -2.0], [0.5, 1e300], [np.nan, np.nan]])
    (tmp_path / "with").mkdir()
    (tmp_path / "without").mkdir()
    w = ChunkWriter(tmp_path / "with", agent_ids=[1, 2], states=("a", "b"), n=2, inputs=2)
    w.append({**rows(2), "u": u[:2]})
    w.append({**rows(3), "tau": np.array([2, 3, 4]), "t": np.array([2.0, 3, 4]), "u": np.vstack([u[2:], u[:2]])})
    back = read_chunks(tmp_path / "with")
    assert back["u"].shape == (5, 2) and np.array_equal(back["u"], np.vstack([u, u[:2]]), equal_nan=True)
    assert np.array_equal(read_chunks(tmp_path / "with", start=1.0, end=2.0)["u"], u[1:3], equal_nan=True)
    traj = Trajectory.from_arrays(back)
    assert np.array_equal(traj.u, back["u"], equal_nan=True)
    ChunkWriter(tmp_path / "without", agent_ids=[1, 2], states=("a", "b"), n=2).append(rows(2))
    without = read_chunks(tmp_path / "without")
    assert "u" not in without and Trajectory.from_arrays(without).u is None


def test_the_trajectory_file_round_trips_u_and_a_window_keeps_its_rows(tmp_path):
    u = np.arange(8.0).reshape(4, 2)
    tr = Trajectory(t=np.arange(4.0), x=np.zeros((4, 2)), xhat=np.zeros((4, 1, 2)), alive=np.ones((4, 1), bool),
                    graph=np.zeros(4, dtype=int), agent_ids=np.array([1]), u=u)
    tr.save(tmp_path / "t.npz")
    back = Trajectory.load(tmp_path / "t.npz")
    assert np.array_equal(back.u, u)
    assert np.array_equal(back.window(1.0, 2.0).u, u[1:3])
    tr0 = Trajectory(t=np.arange(2.0), x=np.zeros((2, 2)), xhat=np.zeros((2, 1, 2)), alive=np.ones((2, 1), bool),
                     graph=np.zeros(2, dtype=int), agent_ids=np.array([1]))
    tr0.save(tmp_path / "none.npz")
    with np.load(tmp_path / "none.npz") as z:
        assert "u" not in z.files


def test_held_inputs_hold_the_last_finite_row_and_zero_before_the_first():
    u = np.array([[np.nan, np.nan], [1.0, 2.0], [np.nan, np.nan], [np.nan, 5.0], [3.0, 4.0]])
    assert np.array_equal(held_inputs(u), [[0, 0], [1, 2], [1, 2], [1, 2], [3, 4]])
    assert np.isnan(u[0]).all()  # the argument is not changed


def test_simulate_records_the_signal_and_a_file_s_u(tmp_path):
    sc = scenario(tmp_path, live=False, u={"steps": [[0, [1.0, 0.0]], [3, [-2.0, 0.5]]]})
    d = ss.design(sc)
    tr = ss.simulate(d, steps=5)
    assert np.array_equal(tr.u, [input_of(sc, k) for k in range(6)])
    assert tr.u[0].tolist() == [1.0, 0.0] and tr.u[5].tolist() == [-2.0, 0.5]
    # a file's u replaces the signal: the trajectory holds the file's rows
    fu = np.column_stack([np.linspace(-1, 1, 6), np.arange(6.0)])
    log = tmp_path / "m.npz"
    write_measurements(log, t=np.arange(6.0), y=np.ones((6, 3)), agent_ids=sc.agent_ids, sizes=[1, 1, 1], u=fu)
    assert np.array_equal(ss.simulate(d, measurements=load_measurements(log, sc)).u, fu)


def record_zeros(out, sc, rows: int) -> None:
    """A recorder of ``sc`` given its inputs and ``rows`` rows of zeros, closed."""
    rec = Recorder(out, agent_ids=sc.agent_ids, n=sc.n, steps=rows - 1, time_mode="discrete", dt=1.0,
                   graph_names=sc.graph_names, run_id="zeros", scenario_name=sc.name, flush_seconds=1e9)
    rec.set_inputs(sc)
    for tau in range(rows):
        rec.row(tau, np.zeros(sc.n), np.zeros((3, sc.n)), np.ones(3, dtype=bool), 0)
    rec.close()


def test_a_run_with_a_signal_records_u_in_the_npz_and_the_chunks(tmp_path):
    sc = scenario(tmp_path, live=False, u={"sine": [{"amplitude": [1.0, 0.5], "period": 4}]})
    record_zeros(tmp_path / "out", sc, 6)
    expected = np.array([input_of(sc, k) for k in range(6)])
    with np.load(tmp_path / "out" / "trajectory.npz") as z:
        assert np.array_equal(z["u"], expected)  # the same function as the plant process's, the same u
        assert "kf" not in z.files  # not a run on measurements
    assert np.array_equal(read_chunks(tmp_path / "out")["u"], expected)


def test_a_recorder_without_inputs_writes_no_u(tmp_path):
    scenario(tmp_path, live=False)
    data = yaml.safe_load((tmp_path / "scenario.yaml").read_text())
    del data["system"]["B"]
    (tmp_path / "plain.yaml").write_text(yaml.safe_dump(data))
    plain = load_scenario(tmp_path / "plain.yaml")
    assert plain.system.B is None
    record_zeros(tmp_path / "out", plain, 3)
    with np.load(tmp_path / "out" / "trajectory.npz") as z:
        assert "u" not in z.files
    assert "u" not in read_chunks(tmp_path / "out")


def test_live_inputs_the_agents_took_are_recorded_and_the_kf_runs_on_them(tmp_path):
    sc = scenario(tmp_path, live=True)
    out = tmp_path / "out"
    rec = Recorder(out, agent_ids=sc.agent_ids, n=sc.n, steps=5, time_mode="discrete", dt=1.0,
                   graph_names=sc.graph_names, run_id="live", scenario_name=sc.name, flush_seconds=1e9)
    rec.set_live_sources(sc)
    rng = np.random.default_rng(4)
    xhat = rng.normal(size=(6, 3, sc.n))
    taken = []
    for tau in range(6):
        rec.live_y(tau, [(a, [float(tau + a)]) for a in (1, 2, 3)] if tau < 5 else [])
        if tau == 1:  # agents 3 and 1 took different values: agent 1's (first in the scenario's order) is recorded
            used = [(3, [9.0, 9.0]), (1, [0.5, -1.0]), (2, [0.5, -1.0])]
        elif tau == 2:  # none reported one (none alive): NaN
            used = []
        elif tau == 5:  # the last event time has no round
            used = []
        else:
            used = [(a, [float(tau), -float(tau)]) for a in (1, 2, 3)]
        taken.append(rec.live_u(tau, used))
        rec.row(tau, np.full(sc.n, np.nan), xhat[tau], np.ones(3, dtype=bool), 0)
        if tau == 3:
            rec.flush()  # a flush in between: the chunks get rows 0..3 now, the rest at the close
    rec.close()
    assert taken[1] == (1, [3]) and taken[0] == (1, []) and taken[2] == (None, [])
    with np.load(out / "trajectory.npz") as z:
        u, y, miss, kf = z["u"], z["y"], z["y_missing"], z["kf"]
    expected = np.array([[0.0, -0.0], [0.5, -1.0], [np.nan, np.nan], [3.0, -3.0], [4.0, -4.0], [np.nan, np.nan]])
    assert np.array_equal(u, expected, equal_nan=True)
    assert np.array_equal(read_chunks(out)["u"], u, equal_nan=True)
    # the filter: on the recorded u, NaN rows held (row 2 holds row 1's); the same function and input, so exact
    assert np.isfinite(kf).all()
    assert np.array_equal(kf, kalman_reference(sc, y, miss, held_inputs(u)))
    assert not np.array_equal(kf, kalman_reference(sc, y, miss, np.zeros_like(u)))  # u moved it
    (out / "scenario.yaml").write_text((tmp_path / "scenario.yaml").read_text())  # as splitspec run writes it
    assert np.array_equal(ss.load_run(out).trajectory.u, u, equal_nan=True)


def test_collected_keeps_the_u_each_agent_reported_with_its_next_estimate():
    c = Collected({1: 0, 2: 1}, 2, 2, plantless=True)
    for a in (1, 2):
        assert c.put_xhat(a, 0, 0, np.zeros(2), report(), at=(0, 0), in_flight=True, same_incarnation=True) is None
    c.put_xhat(1, 1, 0, np.ones(2), report(), at=(0, 0), in_flight=True, same_incarnation=True, y=[1.0], u=[2.0, 3.0])
    c.put_xhat(2, 1, 0, np.ones(2), report(), at=(0, 0), in_flight=True, same_incarnation=True, y=[1.0], u=[])
    row = c.take(0, [1, 2])
    assert row.inputs == {1: [2.0, 3.0]}  # agent 2 reported none ([]: it records no live inputs)
    c.drop_next(1)
    assert c.est_u == {}


@pytest.mark.parametrize("live", [False, True])
def test_set_inputs_after_the_first_row_is_refused(tmp_path, live):
    from splitspec_orchestrator.records.checks import RecordingError

    sc = scenario(tmp_path, live=live)
    rec = Recorder(tmp_path / "out", agent_ids=sc.agent_ids, n=sc.n, steps=2, time_mode="discrete", dt=1.0,
                   graph_names=sc.graph_names, run_id="late", scenario_name=sc.name, flush_seconds=1e9)
    rec.row(0, np.zeros(sc.n), np.zeros((3, sc.n)), np.ones(3, dtype=bool), 0)
    with pytest.raises(RecordingError, match="set_inputs"):
        rec.set_inputs(sc)
    rec.close()


def test_a_run_until_stopped_keeps_every_u_in_its_chunks_while_holding_a_window(tmp_path):
    """Live inputs on a recorder that holds a window of rows (a run until stopped): the chunks get every row's u
    and the recorder's rows of u stay the size of the window."""
    from splitspec_orchestrator.records.files import Continuous

    sc = scenario(tmp_path, live=True)
    out = tmp_path / "until"
    rec = Recorder(out, agent_ids=sc.agent_ids, n=sc.n, steps=50, time_mode="discrete", dt=1.0,
                   graph_names=sc.graph_names, run_id="until", scenario_name=sc.name, flush_seconds=0.0,
                   continuous=Continuous(window_rows=16, chunk_bytes=6000, rrd_bytes=1_500_000))
    rec.set_live_sources(sc)
    T = 300
    for tau in range(T):
        rec.live_y(tau, [(a, [1.0]) for a in (1, 2, 3)])
        rec.live_u(tau, [(a, [float(tau), 0.5]) for a in (2, 1)])
        rec.row(tau, np.full(sc.n, np.nan), np.zeros((3, sc.n)), np.ones(3, dtype=bool), 0)
    held = len(rec._meas.inputs._known)
    rec.close()
    assert not (out / "trajectory.npz").exists()
    u = read_chunks(out)["u"]
    assert np.array_equal(u, np.column_stack([np.arange(float(T)), np.full(T, 0.5)]))
    assert held <= 256  # the window's rows (2 x 16 and the growth), not the run's 300


def test_input_rows_ask_once_per_known_event_time_and_forget_a_window():
    from splitspec_orchestrator.records.measured import InputRows

    asked = []

    def u_row(tau):
        asked.append(tau)
        return None if tau == 3 else [float(tau)]

    rows = InputRows(1, u_row)
    first = rows.rows(np.arange(5))
    assert np.isnan(first[3]).all() and first[[0, 1, 2, 4], 0].tolist() == [0.0, 1.0, 2.0, 4.0]
    rows.rows(np.arange(5))
    assert asked == [0, 1, 2, 3, 4, 3]  # a None is asked again (a live u may come later), a known row never
    rows.forget_before(2)
    again = rows.rows(np.array([1, 2, 4]))
    assert np.isnan(again[0]).all() and again[1:, 0].tolist() == [2.0, 4.0]
    with pytest.raises(ValueError, match="expected 1"):
        InputRows(1, lambda tau: [1.0, 2.0]).rows([0])
