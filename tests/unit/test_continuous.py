"""Continuous operation without processes: runs until stopped in the scenario, the append-only chunks (written,
torn, read whole or by window, recovered), a recorder that holds a window of rows and rolls run.rrd, the pace
watch's verdicts, the closing line.  The runs themselves: tests/integration/test_until_stopped.py."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest
import yaml

import splitspec_core as ss
from splitspec_core.runs import closing_line
from splitspec_core.simulation.simulator import Trajectory
from splitspec_core.simulation.trajectory_chunks import ChunkWriter, chunk_segments, read_chunks, whole_length
from splitspec_orchestrator.viewer.rrd_file import rrd_segments
from splitspec_orchestrator.records.files import Continuous
from splitspec_orchestrator.records.recorder import Recorder
from splitspec_orchestrator.records.recover import recover
from splitspec_orchestrator.rounds.pace import PaceWatch
from tests.rrd_readback import read_blueprint, read_rrd, read_rrd_graph, read_rrd_logs, verify_rrd

os.environ.setdefault("RERUN_ANALYTICS", "0")

IDS, M, N = (1, 2, 5), 3, 4
ROOT = Path(__file__).resolve().parents[2]


# ---------------------------------------------------------------------------------------------- the scenario


def _scenario(run: dict, **more):
    return ss.scenario(A=np.diag([0.9, 1.1]), C={1: [[1.0, 0.0]], 2: [[0.0, 1.0]]}, graphs={"g": [(1, 2), (2, 1)]},
                       rate=0.95, time="discrete", **run, **more)


def test_steps_omitted_from_a_paced_run_means_until_stopped():
    assert _scenario({"pace": 10}).run.until_stopped
    assert not _scenario({"pace": 10, "steps": 30}).run.until_stopped
    unpaced = _scenario({})
    assert not unpaced.run.until_stopped and unpaced.run.steps == 60  # as before: 60 steps


def test_an_unpaced_run_without_steps_says_it_runs_the_default_steps(tmp_path):
    from splitspec_orchestrator.commands.deploy import default_steps_line

    line = default_steps_line(_scenario({}))
    assert line == ("splitspec: run.steps not given: running the default 60 steps (61 event times); set run.steps, "
                    "or run.pace to run until stopped")
    assert default_steps_line(_scenario({}), measurements=True) == ""  # the file decides the steps
    for run in ({"steps": 60}, {"pace": 10}, {"pace": 10, "steps": 30}):
        assert default_steps_line(_scenario(run)) == "", run
    raw = yaml.safe_load((ROOT / "examples" / "paper_continuous.yaml").read_text())
    raw["run"].pop("steps")
    (tmp_path / "c.yaml").write_text(yaml.safe_dump(raw))
    sc = ss.load_scenario(tmp_path / "c.yaml")
    assert default_steps_line(sc) == (f"splitspec: run.steps not given: running the default 60 steps of run.dt "
                                      f"{sc.run.dt:g} s (61 event times); set run.steps, or run.pace to run until "
                                      "stopped")


# ---------------------------------------------------------------------------------------------- the chunks


def _cols(taus, *, seed=0, lost_every=3):
    rng = np.random.default_rng(seed)
    L = len(taus)
    return {"tau": np.asarray(taus), "t": np.asarray(taus, float), "x": rng.normal(size=(L, N)),
            "xhat": rng.normal(size=(L, M, N)), "alive": rng.random((L, M)) > 0.2, "graph": np.zeros(L, int),
            "g": np.full((L, M), np.nan), "wall": np.arange(L), "round": rng.normal(size=(L, 5)),
            "lost": [np.array([[0, 1, 2, 0], [1, 2, 1, 1]]) if t % lost_every == 0 else np.zeros((0, 4)) for t in taus]}


def test_chunks_read_back_whole_by_window_and_the_last_write_wins(tmp_path):
    w = ChunkWriter(tmp_path, agent_ids=IDS, states=("a", "b", "c", "d"), n=N, segment_bytes=4000)
    written = [_cols(range(k, k + 5), seed=k) for k in range(0, 60, 5)]
    for c in written:
        w.append(c)
    again = _cols([57], seed=99)  # a row written again (an agent declared lost after its flush)
    w.append(again)
    segs = chunk_segments(tmp_path)
    assert len(segs) > 3 and [f for f, _ in segs] == sorted({f for f, _ in segs})  # distinct names, in order
    rows = read_chunks(tmp_path)
    assert rows["tau"].tolist() == list(range(60))
    # exact: the very float64 values written are read back (no arithmetic in between)
    assert np.array_equal(rows["xhat"][57], again["xhat"][0]) and np.array_equal(rows["x"][3], written[0]["x"][3])
    assert np.array_equal(rows["alive"][:5], written[0]["alive"])
    assert rows["lost"].shape == (2 * 20, 4) and rows["lost"][:, 0].tolist() == sorted(rows["lost"][:, 0].tolist())
    assert rows["lost_cause"].tolist()[:2] == [0, 1]
    part = read_chunks(tmp_path, start=21, end=33)
    assert part["tau"].tolist() == list(range(21, 34))
    assert np.array_equal(part["xhat"], rows["xhat"][21:34])
    assert set(part["lost"][:, 0].tolist()) == {t for t in range(21, 34) if t % 3 == 0}


def test_a_window_sees_a_row_written_again_in_the_next_segment(tmp_path):
    w = ChunkWriter(tmp_path, agent_ids=IDS, states=("a", "b", "c", "d"), n=N, segment_bytes=4000)
    for k in range(0, 75, 5):
        w.append(_cols(range(k, k + 5), seed=k))
    again = _cols([71], seed=7)  # written again after the segment of 70.. began (a loss noticed late)
    w.append(again)
    assert w.path.name == f"rows-{70:012d}.arrows" or chunk_segments(tmp_path)[-2][0] <= 71
    part = read_chunks(tmp_path, start=60, end=71.5)
    assert part["tau"].tolist() == list(range(60, 72))
    assert np.array_equal(part["xhat"][-1], again["xhat"][0])  # the last write, not the first


def test_a_torn_batch_is_left_out_and_recover_cuts_it(tmp_path):
    (tmp_path / "events.jsonl").write_text('{"event": "run_started", "t": 0.0, "wall": 0.0}\n')
    w = ChunkWriter(tmp_path, agent_ids=IDS, states=("a", "b", "c", "d"), n=N)
    w.append(_cols(range(0, 10)))
    w.append(_cols(range(10, 20)))
    (_, path), = chunk_segments(tmp_path)
    whole = path.stat().st_size
    with open(path, "ab") as f:  # the start of a third batch: the kill came mid-write
        f.write(ChunkWriter(tmp_path / "x", agent_ids=IDS, states=("a", "b", "c", "d"), n=N)
                .batch(_cols(range(20, 30))).serialize().to_pybytes()[:500])
    assert whole_length(path) == whole
    assert read_chunks(tmp_path)["tau"].tolist() == list(range(20))
    res = recover(tmp_path)
    assert res["rows"] == 20 and path.stat().st_size == whole and res["rrd"] == "missing"
    assert '"records_recovered"' in (tmp_path / "events.jsonl").read_text()


# ---------------------------------------------------------------------------------------------- the recorder


def _recorder(out: Path, **kw) -> Recorder:
    return Recorder(out, agent_ids=IDS, n=N, steps=50, time_mode="discrete", dt=1.0, graph_names=("g",),
                    run_id="cont", scenario_name="cont", flush_seconds=0.0, **kw)


def _feed(rec: Recorder, T: int, *, lose_at: int | None = None) -> None:
    for tau in range(T):
        rng = np.random.default_rng(tau)
        alive = np.ones(M, dtype=bool)
        if lose_at is not None and tau >= lose_at:
            alive[1] = False
        rec.row(tau, rng.normal(size=N), rng.normal(size=(M, N)), alive, 0, wall_ms=1.0, attempts=1, rejected=0,
                lost=[(tau, 0, 1, 2, 0)] if tau % 7 == 0 else [], late_ms=float(tau % 3))
        if tau == lose_at:
            rec.mark_lost(tau, 2)


def test_a_recorder_until_stopped_holds_a_window_and_loses_no_row(tmp_path):
    cont = Continuous(window_rows=16, chunk_bytes=6000, rrd_bytes=1_500_000)  # a segment holds ~200 kB of statics
    rec = _recorder(tmp_path / "until", continuous=cont)
    _feed(rec, 160, lose_at=90)
    held = rec._s.rows
    rec.close()
    assert held <= 2 * 16 + 1  # the window, not the run
    out = tmp_path / "until"
    assert not (out / "trajectory.npz").exists() and len(chunk_segments(out)) > 2
    full = tmp_path / "full"  # the same rows into a recorder of a run of run.steps: trajectory.npz and chunks
    rec2 = _recorder(full)
    _feed(rec2, 160, lose_at=90)
    rec2.close()
    npz = Trajectory.load(full / "trajectory.npz")
    for rows in (read_chunks(out), read_chunks(full)):
        # exact: both hold the values the recorder was given, copied, never computed along another path
        assert np.array_equal(rows["t"], npz.t) and np.array_equal(rows["alive"], npz.alive)
        assert np.array_equal(rows["xhat"], npz.xhat, equal_nan=True) and np.array_equal(rows["x"], npz.x)
        assert np.array_equal(rows["lost"], npz.lost) and np.array_equal(rows["lost_cause"], npz.lost_cause)
        assert rows["round"][:, 4].tolist() == [float(t % 3) for t in range(160)]  # late_ms
    assert not npz.alive[90:, 1].any() and npz.alive[:90, 1].all()
    segs = rrd_segments(out / "run.rrd")
    assert len(segs) >= 2
    taus = []
    for p in segs:
        ok, msg = verify_rrd(p)
        assert ok, (p.name, msg)
        taus += [tau for tau, _ in read_rrd(p).get("errors/max", [])]
    assert sorted(set(taus)) == list(range(160))  # every row in one segment or another
    closed = [line for line in (out / "events.jsonl").read_text().splitlines() if "recording_closed" in line]
    assert "\"rows\": 160" in closed[0]


def test_every_rolled_segment_opens_alone_with_the_topology_in_force_and_the_layout(tmp_path):
    ring = [(1, 2), (2, 5), (5, 1), (2, 1)]
    rec = _recorder(tmp_path, continuous=Continuous(window_rows=16, chunk_bytes=6000, rrd_bytes=700_000))
    rec.topology(0, "g", IDS, ring)
    for tau in range(160):
        if tau == 90:
            rec.topology(90, "g", (1, 5), ring)  # agent 2 lost: logged once, in whichever segment holds tau 90
        rng = np.random.default_rng(tau)
        rec.row(tau, rng.normal(size=N), rng.normal(size=(M, N)), np.array([True, tau < 90, True]), 0, wall_ms=1.0,
                attempts=1, rejected=0, lost=[], late_ms=0.0)
    rec.close()
    segs = rrd_segments(tmp_path / "run.rrd")
    assert len(segs) >= 3
    last_row = -1
    for path in segs:
        ok, msg = verify_rrd(path)
        assert ok, (path.name, msg)
        # the layout, once (a rolled segment gets it merged in by `rerun rrd optimize`; run.rrd has its own)
        assert read_blueprint(path)["views"].count(("Graph", "communication graph", "topology")) == 1, path.name
        rows = [tau for tau, _ in read_rrd(path)["errors/max"]]
        first, topo = min(rows), [tau for tau, _, _ in read_rrd_logs(path)["topology"]]
        # the segment opens on its own time span: its topology starts where the segment before it ended
        assert min(topo) == max(last_row, 0) and min(topo) <= first
        for tau in (first, max(rows)):
            graph = read_rrd_graph(path, "topology", tau)
            lost = tau >= 90
            assert graph["node_ids"] == ["1", "2", "5"], (path.name, tau)
            assert graph["labels"] == ["agent 1", "agent 2 (lost)" if lost else "agent 2", "agent 5"]
            assert sorted(graph["edges"]) == ([(5, 1)] if lost else sorted(ring)), (path.name, tau)
            assert read_rrd_graph(path, "topology/graph", tau)["labels"] == ["graph: g"]
        last_row = max(rows)


def test_a_topology_logged_late_for_an_event_time_before_a_roll_shows_in_the_next_segment(tmp_path):
    ring = [(1, 2), (2, 5), (5, 1), (2, 1)]
    rec = _recorder(tmp_path, continuous=Continuous(window_rows=16, chunk_bytes=6000, rrd_bytes=700_000))
    rec.topology(0, "g", IDS, ring)
    tau = 0
    while not (tmp_path / "run-0001.rrd").exists():  # rows until run.rrd rolls (a flush per row)
        rng = np.random.default_rng(tau)
        rec.row(tau, rng.normal(size=N), rng.normal(size=(M, N)), np.ones(M, dtype=bool), 0, wall_ms=1.0,
                attempts=1, rejected=0, lost=[], late_ms=0.0)
        tau += 1
    rolled_at = tau - 1  # the newest row of run.rrd: run-0001.rrd starts with the topology there
    rec.topology(rolled_at - 3, "g", (1, 5), ring)  # agent 2 lost 3 event times before, noticed now
    rng = np.random.default_rng(tau)
    rec.row(tau, rng.normal(size=N), rng.normal(size=(M, N)), np.array([True, False, True]), 0, wall_ms=1.0,
            attempts=1, rejected=0, lost=[], late_ms=0.0)
    rec.close()
    seg = tmp_path / "run-0001.rrd"
    for at in (rolled_at, tau):  # the copy at the segment's start is the topology in force there, not the one before
        graph = read_rrd_graph(seg, "topology", at)
        assert graph["labels"] == ["agent 1", "agent 2 (lost)", "agent 5"] and graph["edges"] == [(5, 1)], at


def test_the_notebook_widget_gets_every_segment_of_a_rolled_recording(tmp_path):
    pytest.importorskip("rerun_notebook")  # in the dev extra: installed by make test
    from splitspec_orchestrator.viewer.notebook_view import notebook_viewer, recording_files

    rec = _recorder(tmp_path / "run", continuous=Continuous(window_rows=16, chunk_bytes=6000, rrd_bytes=700_000))
    _feed(rec, 120)
    rec.close()
    files = recording_files(tmp_path / "run")
    assert files == rrd_segments(tmp_path / "run" / "run.rrd") and len(files) >= 3 and files[0].name == "run.rrd"
    viewer = notebook_viewer(tmp_path / "run")
    # what the widget queued until a front end shows it (see tests/integration/test_api_run.py): every row
    sent = [bytes(b) for event, buffers in viewer._viewer._event_queue if event == {"type": "rrd"}
            for b in buffers or []]
    taus = set()
    for k, b in enumerate(sent):
        (tmp_path / f"sent{k}.rrd").write_bytes(b)
        try:
            taus |= {tau for tau, _ in read_rrd(tmp_path / f"sent{k}.rrd").get("errors/max", [])}
        except ValueError as exc:  # a message may carry only the stream's start, no data yet
            assert "No recording store" in str(exc)
    assert taus == set(range(120))


def test_the_notebook_widget_orders_the_segments_by_number_and_skips_deleted_ones(tmp_path):
    from splitspec_core.errors import ScenarioError
    from splitspec_orchestrator.viewer.notebook_view import recording_files

    with pytest.raises(ScenarioError, match="has no run.rrd"):
        recording_files(tmp_path)
    for name in ("run.rrd", "run-0002.rrd", "run-10000.rrd", "run-0010.rrd", "run-x.rrd", "other-0001.rrd"):
        (tmp_path / name).write_bytes(b"")
    assert [p.name for p in recording_files(tmp_path)] == ["run.rrd", "run-0002.rrd", "run-0010.rrd", "run-10000.rrd"]


# ---------------------------------------------------------------------------------------------- the pace watch


def _watch(**kw) -> PaceWatch:
    return PaceWatch(50.0, q=4, m=10, cores=2, **kw)


def test_a_kept_pace_says_nothing():
    w = _watch()
    out = []
    for tau in range(500):  # a few rounds late by a hiccup, none sustained
        late = 0.05 if tau % 40 == 0 else 0.0
        out += w.observe(tau, late, tau * 0.02, tau * 0.02 + 0.005, 3, float(tau))
    assert out == [] and w.summary()["pace_kept"] and w.summary()["late_event_times"] == 13


def test_a_pace_the_machine_cannot_keep_is_reported_once_with_its_limit():
    w = _watch()
    out, start = [], 0.0
    for tau in range(400):  # rounds of 30 ms at a pace of 50 (20 ms): ever later
        out += w.observe(tau, start - tau * 0.02, start, start + 0.03, 7 if tau % 2 else 3, float(tau))
        start += 0.03
    events = [a for a in out if type(a).__name__ == "Event"]
    assert len(events) == 1 and events[0].name == "pace_not_kept" and events[0].level == "WARN"
    f = events[0].fields
    assert abs(f["achieved_rate"] - 1 / 0.03) < 0.5 and f["limit"].startswith("the machine") and "agent" in f["limit"]
    s = w.summary()
    assert not s["pace_kept"] and s["late_event_times"] >= 390 and s["max_lateness_ms"] > 3000


def test_the_limit_names_the_deadline_or_the_orchestrator():
    w = _watch(deadline_s=0.004)  # q = 4 sub-rounds of 4 ms: 16 ms of a 20 ms period
    start, out = 0.0, []
    for tau in range(200):
        out += w.observe(tau, start - tau * 0.02, start, start + 0.025, None, float(tau))
        start += 0.025
    assert "network deadline" in out[0].fields["limit"]
    w, start, out = _watch(), 0.0, []
    for tau in range(200):  # quick rounds (2 ms) started 25 ms apart
        out += w.observe(tau, start - tau * 0.02, start, start + 0.002, None, float(tau))
        start += 0.025
    assert out[0].fields["limit"].startswith("the orchestrator")


# ---------------------------------------------------------------------------------------------- the closing line


def test_the_closing_line_says_what_happened():
    end = {"event": "run_finished", "reason": "stopped (SIGTERM)", "event_times": 1500, "seconds": 30.0,
           "rounds_per_second": 50.0, "pace": 50.0, "pace_kept": True, "late_event_times": 0,
           "max_lateness_ms": 3.0, "final_max_error": 1.25e-3, "agents_lost": 2, "agents_rejoined": 1,
           "messages_lost": 12}
    line = closing_line(end)
    assert line == ("run finished (stopped (SIGTERM)): 1500 event times in 30 s (50 per second, pace 50 kept); "
                    "largest error at the end 0.00125; agents lost 2, rejoined 1; consensus messages lost 12")
    slow = closing_line({**end, "event": "run_interrupted", "pace_kept": False, "late_event_times": 900,
                         "max_lateness_ms": 8100.0, "final_max_error": None, "final_disagreement": 0.5})
    assert slow.startswith("run interrupted: ") and "pace 50 NOT kept: 900 late, up to 8100 ms" in slow
    assert "consensus disagreement at the end 0.5 (no truth)" in slow


@pytest.mark.parametrize("bad", [{"steps": 0, "pace": 5}])
def test_bad_steps_still_one_line(bad):
    with pytest.raises(ss.ScenarioError, match="run.steps"):
        _scenario(bad)


def test_the_measurements_behind_a_window_are_forgotten_with_it():
    from splitspec_orchestrator.viewer.reference_view import ReferenceRows

    asked = []

    def y_row(tau):
        asked.append(tau)
        return np.full(2, float(tau)), np.zeros(2, dtype=bool)

    rows = ReferenceRows([np.eye(2)[[0]], np.eye(2)[[1]]], y_row)
    y, _ = rows.measurements(np.arange(100))
    rows.batch(np.arange(100), np.arange(100.0), np.zeros(100), np.ones((100, 2, 2)) * np.arange(2)[None, :, None])
    rows.forget_before(80)
    held = len(rows._y)
    y2, miss2 = rows.measurements(np.array([79, 80, 99]))
    assert miss2[0].all() and y2[0].tolist() == [0.0, 0.0]  # forgotten: unknown
    assert y2[1:].tolist() == y[[80, 99]].tolist() and not miss2[1:].any()  # kept, not asked again
    assert asked == list(range(100))
    assert rows.mark_y(99) == pytest.approx(np.log10(np.sqrt(2)))  # |x_1 - x_2| = sqrt 2 at every kept event time
    assert rows.mark_y(79) == 0.0  # forgotten
    for k in range(10):  # a long run: the arrays stay the size of the window, not of the run
        rows.forget_before(100 + 100 * k)
        rows.measurements(np.arange(100 + 100 * k, 200 + 100 * k))
    assert len(rows._y) <= max(held, 256)
