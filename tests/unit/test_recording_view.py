"""What a researcher sees in run.rrd: the incremental envelope, log errors, marks, loss clears, topology positions."""

from __future__ import annotations

import math

import numpy as np
import pytest
import yaml

from splitspec_orchestrator.viewer.blueprint import circle_positions, node_positions
from splitspec_orchestrator.records.events import event_text
from splitspec_orchestrator.records.recorder import Recorder, RecordingError
from splitspec_core.simulation.metrics import envelope, envelope_restarts
from splitspec_core.errors import ScenarioError
from splitspec_core.scenarios.load import parse_scenario
from tests.integration.runtime_helpers import EXAMPLES
from tests.rrd_readback import read_rrd, read_rrd_clears, read_rrd_nodes, read_rrd_state

IDS = (1, 2, 5)
M, N, T = 3, 2, 30
DT = 0.05
LAM = {"discrete": 0.8, "continuous": 2.0}
NEVER = 3600.0


def rows(seed: int = 3):
    """Errors decaying at a rate, agent 2 dead on [8, 14) then rejoining, a graph switch at 20."""
    rng = np.random.default_rng(seed)
    x = rng.normal(size=(T, N))
    xhat = x[:, None, :] + rng.normal(size=(T, M, N)) * (0.9 ** np.arange(T))[:, None, None]
    alive = np.ones((T, M), dtype=bool)
    alive[8:14, 1] = False
    graph = np.where(np.arange(T) < 20, 0, 1)
    g = 1.0 + np.cumsum(rng.uniform(size=(T, M)), axis=0)
    return x, xhat, alive, graph, g


def record(out, time_mode: str, *, flush_seconds: float, envelope_rate, positions=None,
           flush_before_row_20: str | None = None) -> None:
    x, xhat, alive, graph, g = rows()
    rec = Recorder(out, agent_ids=IDS, n=N, steps=T - 1, time_mode=time_mode, dt=DT, graph_names=("a", "b"),
                   run_id="view", scenario_name="view", flush_seconds=flush_seconds, envelope_rate=envelope_rate,
                   columns=("g",) if time_mode == "continuous" else (), positions=positions)
    t_of = (lambda tau: float(tau)) if time_mode == "discrete" else (lambda tau: tau * DT)
    rec.topology(0, "a", IDS, [(1, 2), (2, 5), (5, 1)])
    for tau in range(T):
        if tau == 8:
            rec.mark_lost(8, 2)
            rec.event("agent_lost", t_of(8), id=2, tau=8, reason="killed by the scenario (SIGKILL to pid 1)")
            rec.topology(8, "a", (1, 5), [(1, 2), (2, 5), (5, 1)])
        if tau == 14:
            rec.event("agent_rejoined", t_of(14), id=2, tau=14, incarnation=1)
        if tau == 20:
            rec.event("graph_switched", t_of(20), graph="b", previous="a")
            if flush_before_row_20:  # a flush between the switch and its row (background or flush())
                rec._flush() if flush_before_row_20 == "background" else rec.flush()
        rec.row(tau, x[tau], xhat[tau], alive[tau], int(graph[tau]), g=g[tau], wall_ms=1.5, attempts=1,
                rejected=tau % 2)
    rec.close()


@pytest.mark.parametrize("time_mode", ["discrete", "continuous"])
@pytest.mark.parametrize("flush_seconds", [0.0, NEVER])
def test_incremental_envelope_equals_the_batch_one(tmp_path, time_mode, flush_seconds):
    """Row by row, the live envelope is analysis.envelope(fit=False) restarted at rejoins and switches."""
    record(tmp_path, time_mode, flush_seconds=flush_seconds, envelope_rate=LAM[time_mode])
    x, xhat, alive, graph, _ = rows()
    t = np.arange(T) * (1.0 if time_mode == "discrete" else DT)
    err = np.where(alive, np.linalg.norm(xhat - x[:, None, :], axis=2), np.nan)
    err_max = np.nanmax(err, axis=1)
    restarts = envelope_restarts(alive, graph)
    assert restarts.tolist() == [0, 14, 20]
    want = envelope(t, err_max, restarts, time=time_mode, rate=LAM[time_mode], fit=False)
    series = read_rrd(tmp_path / "run.rrd")
    got = dict(series["errors_log10/envelope"])
    assert sorted(got) == list(range(T))
    np.testing.assert_allclose([got[k] for k in range(T)], np.log10(want), rtol=0, atol=1e-9)
    # decays at the designed rate between restarts, starts at the max error at each restart
    for k0 in restarts:
        assert got[int(k0)] == pytest.approx(math.log10(err_max[k0]), abs=1e-12)
    # log10 errors are log10 of the linear ones, dead rows absent
    for i, a in enumerate(IDS):
        lin, lg = dict(series[f"errors/agent_{a}"]), dict(series[f"errors_log10/agent_{a}"])
        assert sorted(lg) == sorted(lin) == [k for k in range(T) if alive[k, i]]
        np.testing.assert_allclose([lg[k] for k in lg], np.log10([lin[k] for k in lg]), rtol=0, atol=1e-12)
    lmax = dict(series["errors_log10/max"])
    np.testing.assert_allclose([lmax[k] for k in range(T)], np.log10(err_max), rtol=0, atol=1e-9)
    # round diagnostics
    assert [v for _, v in series["rounds/rejected"]] == [k % 2 for k in range(T)]
    assert {v for _, v in series["rounds/attempts"]} == {1.0}


def test_no_envelope_without_a_certified_rate(tmp_path):
    """The adaptive gain has no designed rate: no envelope entity at all; gains are logged, NaN where dead."""
    record(tmp_path, "continuous", flush_seconds=0.0, envelope_rate=None)
    series = read_rrd(tmp_path / "run.rrd")
    assert "errors_log10/envelope" not in series
    _, _, alive, _, g = rows()
    got = dict(series["gains/agent_2"])
    assert sorted(got) == [k for k in range(T) if alive[k, 1]]
    assert got[3] == pytest.approx(g[3, 1])
    with np.load(tmp_path / "trajectory.npz") as f:
        np.testing.assert_array_equal(np.isnan(f["g"]), ~alive)
        np.testing.assert_array_equal(f["g"][alive], g[alive])  # exact: stored copies of the gains given


def test_loss_clears_every_series_and_marks_the_axis(tmp_path):
    record(tmp_path, "continuous", flush_seconds=NEVER, envelope_rate=LAM["continuous"])
    clears = read_rrd_clears(tmp_path / "run.rrd")
    agent2 = {"errors/agent_2", "errors_log10/agent_2", "gains/agent_2"}
    assert {e for e, taus in clears.items() if 8 in taus} == agent2
    # its state estimates (in the shared per-component batches) are NaN while it is dead: no line there
    _, _, alive, _, _ = rows()
    state = read_rrd_state(tmp_path / "run.rrd")
    for k in (1, 2):
        assert sorted(dict(state[f"state/{k}/agent_2"])) == [tau for tau in range(T) if alive[tau, 1]]
    series = read_rrd(tmp_path / "run.rrd")
    assert [tau for tau, _ in series["marks/lost"]] == [8]
    assert [tau for tau, _ in series["marks/rejoined"]] == [14]
    assert [tau for tau, _ in series["marks/graph_switch"]] == [20]
    # at the height of the log10 max error of that row (visible next to the curves)
    lmax = dict(series["errors_log10/max"])
    assert series["marks/graph_switch"][0][1] == pytest.approx(lmax[20], abs=1e-12)


@pytest.mark.parametrize("flush", ["background", "flush()"])
def test_a_mark_waits_for_its_own_row(tmp_path, flush):
    """A flush (the background one, or a caller's flush()) between a graph switch (logged with the tick) and
    that event time's row: the mark still stands at the height of its own row (CI once saw the previous row's
    height)."""
    record(tmp_path, "discrete", flush_seconds=NEVER, envelope_rate=LAM["discrete"], flush_before_row_20=flush)
    series = read_rrd(tmp_path / "run.rrd")
    lmax = dict(series["errors_log10/max"])
    assert [tau for tau, _ in series["marks/graph_switch"]] == [20]
    assert series["marks/graph_switch"][0][1] == pytest.approx(lmax[20], abs=1e-12)
    assert lmax[20] != pytest.approx(lmax[19], abs=1e-6)  # the two heights differ: the test can tell them apart


def test_a_mark_still_waiting_for_its_row_is_written_at_exit(tmp_path):
    """The interpreter's exit flush (a run that never called close) writes a mark whose row never came."""
    from splitspec_orchestrator.records.flusher import _flush_open_recorders

    x, xhat, alive, graph, g = rows()
    rec = Recorder(tmp_path, agent_ids=IDS, n=N, steps=T - 1, time_mode="discrete", dt=DT, graph_names=("a", "b"),
                   run_id="exit", scenario_name="exit", flush_seconds=NEVER, envelope_rate=LAM["discrete"])
    rec.topology(0, "a", IDS, [(1, 2), (2, 5), (5, 1)])
    for tau in range(5):
        rec.row(tau, x[tau], xhat[tau], alive[tau], 0)
    rec.event("graph_switched", 5.0, graph="b", previous="a")  # its row 5 never comes
    _flush_open_recorders()
    series = read_rrd(tmp_path / "run.rrd")
    assert [tau for tau, _ in series["marks/graph_switch"]] == [5]


def test_event_texts_are_short_complete_sentences():
    assert event_text("agent_lost", {"id": 3, "reason": "killed by the scenario (SIGKILL to pid 9)"}) == \
        "agent 3 lost: killed by the scenario (SIGKILL to pid 9)"
    assert event_text("agent_rejoined", {"id": 3, "incarnation": 1}) == "agent 3 rejoined (incarnation 1)"
    assert event_text("graph_switched", {"graph": "b", "previous": "a"}) == "graph a -> b"
    assert event_text("arc_dropped", {"arc": [1, 6], "tau": 15}) == "arc 1 -> 6 dropped"
    assert event_text("something_new", {"k": 1}) == "something_new k=1"


# ---------------------------------------------------------------------- topology positions


def test_circle_positions_are_distinct_on_a_circle_first_on_top():
    pos = circle_positions((4, 7, 9, 12))
    assert list(pos) == [4, 7, 9, 12]
    assert pos[4] == pytest.approx((0.0, -100.0))  # screen y points down: the top
    assert all(math.hypot(*p) == pytest.approx(100.0) for p in pos.values())
    assert len({(round(x, 6), round(y, 6)) for x, y in pos.values()}) == 4


def test_given_positions_keep_their_shape():
    pos = node_positions((1, 2, 3), {1: (0.0, 0.0), 2: (2.0, 0.0), 3: (0.0, 1.0)})
    assert pos[2][0] - pos[1][0] == pytest.approx(100.0 * 2) and pos[1][1] - pos[3][1] == pytest.approx(100.0)
    assert node_positions((1, 2), None) == circle_positions((1, 2))


def test_recorded_topology_uses_the_positions(tmp_path):
    given = {1: (0.0, 0.0), 2: (1.0, 0.0), 5: (0.0, 1.0)}
    record(tmp_path, "discrete", flush_seconds=0.0, envelope_rate=0.8, positions=given)
    nodes = read_rrd_nodes(tmp_path / "run.rrd")
    want = node_positions(IDS, given)
    assert [tau for tau, *_ in nodes] == [0, 8]
    for _, ids, pos, labels in nodes:
        assert ids == ["1", "2", "5"]
        np.testing.assert_allclose(pos, [want[a] for a in IDS], atol=1e-4)
    assert nodes[1][3] == ["agent 1", "agent 2 (lost)", "agent 5"]
    (tau, ids, _, labels), *_ = read_rrd_nodes(tmp_path / "run.rrd", "topology/graph")
    assert labels == ["graph: a"]


def test_recorder_refuses_partial_positions(tmp_path):
    with pytest.raises(RecordingError, match="positions must give every agent"):
        Recorder(tmp_path, agent_ids=IDS, n=N, steps=3, time_mode="discrete", dt=1.0, graph_names=("a",),
                 run_id="p", scenario_name="p", positions={1: (0, 0)})


def test_scenario_positions():
    raw = yaml.safe_load((EXAMPLES / "ring10_faults.yaml").read_text())
    assert parse_scenario(raw).positions is None
    sc = parse_scenario({**raw, "positions": {i: [i, i * i] for i in range(1, 11)}})
    assert sc.positions[3] == (3.0, 9.0)
    for bad, msg in [({1: [0, 0]}, "positions has no \\[x, y\\] for agents 2, 3"),
                     ({i: [i] for i in range(1, 11)}, "positions.1 must be a pair"),
                     ({i: [0, 0] for i in range(1, 11)}, "positions.2 = \\[0, 0\\] is also agent 1's"),
                     ({**{i: [i, 0] for i in range(1, 11)}, 11: [0, 1]}, "names agent 11"),
                     ({i: ["a", 0] for i in range(1, 11)}, "positions.1\\[0\\] must be a number")]:
        with pytest.raises(ScenarioError, match=msg):
            parse_scenario({**raw, "positions": bad})


def test_mark_height_is_the_last_positive_max_error_and_cheap():
    """marks/<kind> sit at log10 of the max error of the last row at or before the mark with a positive finite
    one; errors that reached exactly 0 (or rows with nobody alive) are skipped without a row-by-row scan."""
    import time

    from splitspec_orchestrator.records.rowstore import RowStore

    m, n, rows = 4, 3, 20000
    S = RowStore(m, n, capacity=rows)
    rng = np.random.default_rng(0)
    for k in range(rows):
        S.append_slot(2 * k)  # event times 0, 2, 4, ...
    S.t[:rows] = np.arange(rows)
    S.x[:rows] = rng.normal(size=(rows, n))
    S.xhat[:rows] = S.x[:rows, None, :] + rng.normal(size=(rows, m, n))
    S.alive[:rows] = True
    S.xhat[100:] = S.x[100:, None, :]  # exactly 0 from row 100 on
    S.alive[50:100] = False  # nobody alive on rows 50..99
    want = math.log10(np.linalg.norm(S.xhat[49] - S.x[49], axis=1).max())
    t0 = time.perf_counter()
    assert S.mark_y(2 * (rows - 1)) == pytest.approx(want, abs=1e-12)
    assert time.perf_counter() - t0 < 0.5
    assert S.mark_y(7) == pytest.approx(math.log10(np.linalg.norm(S.xhat[3] - S.x[3], axis=1).max()), abs=1e-12)
    S.alive[:, 1:] = False
    S.xhat[:rows, 0] = np.nan  # the one alive agent reports NaN: no height anywhere
    assert S.mark_y(100) == 0.0
