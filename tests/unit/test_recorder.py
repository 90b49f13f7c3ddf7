"""Recorder: trajectory.npz contract, events.jsonl, run.rrd contents, buffering, crash safety."""

from __future__ import annotations

import json
import logging
import os
import socket
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pytest

from splitspec_core.model.rows import REPORTED
from splitspec_orchestrator.records.recorder import Recorder, RecordingError
from tests.rrd_readback import read_rrd, read_rrd_state, read_rrd_vectors, rrd_entities, verify_rrd

os.environ.setdefault("RERUN_ANALYTICS", "0")

IDS = (1, 2, 5)
M, N, T = 3, 4, 20
GRAPHS = ("ring", "complete")
SWITCH_TAU = 8  # ring -> complete
LOST_ID, LOST_TAU, LOST_NOTICED = 5, 12, 14  # agent 5 lost from tau 12, noticed after row 14
RESENT_TAU = 10
DT = 0.1

RING = [(1, 2), (2, 5), (5, 1)]
COMPLETE = [(j, i) for j in IDS for i in IDS if i != j]


def synthetic(seed: int = 0):
    """Truth, reported estimates (with garbage where dead) and the expected stored arrays."""
    rng = np.random.default_rng(seed)
    x = rng.normal(size=(T, N))
    xhat = x[:, None, :] + rng.normal(size=(T, M, N)) * 0.8 ** np.arange(T)[:, None, None]
    alive = np.ones((T, M), dtype=bool)
    alive[LOST_TAU:, IDS.index(LOST_ID)] = False
    graph = np.where(np.arange(T) < SWITCH_TAU, 0, 1)
    xhat_resent = xhat[RESENT_TAU] + 0.5  # the row re-sent for RESENT_TAU replaces the first one
    expected_xhat = xhat.copy()
    expected_xhat[RESENT_TAU] = xhat_resent
    expected_xhat[~alive] = np.nan
    return x, xhat, xhat_resent, alive, graph, expected_xhat


def record(out: Path, *, time_mode: str, close: bool = True, flush_seconds: float = 1.0, **kw) -> Recorder:
    x, xhat, xhat_resent, alive, graph, _ = synthetic()
    rec = Recorder(out, agent_ids=IDS, n=N, steps=T - 1, time_mode=time_mode, dt=DT, graph_names=GRAPHS,
                   run_id="test-run", scenario_name="synthetic", flush_seconds=flush_seconds, **kw)
    t_of = (lambda tau: float(tau)) if time_mode == "discrete" else (lambda tau: tau * DT)
    rec.event("start", 0.0, agents=list(IDS), seed=np.int64(7))
    rec.topology(0, "ring", IDS, RING)
    lost_col = IDS.index(LOST_ID)
    for tau in range(T):
        if tau == SWITCH_TAU:
            rec.topology(tau, "complete", IDS if tau < LOST_TAU else (1, 2), COMPLETE)
            rec.event("switch", t_of(tau), graph="complete")
        # The orchestrator has not noticed the loss yet: rows LOST_TAU..LOST_NOTICED report it alive.
        reported_alive = alive[tau].copy()
        if LOST_TAU <= tau <= LOST_NOTICED:
            reported_alive[lost_col] = True
        rec.row(tau, x[tau], xhat[tau], reported_alive, int(graph[tau]))
        if tau == RESENT_TAU:
            rec.row(tau, x[tau], xhat_resent, reported_alive, int(graph[tau]))
        if tau == LOST_NOTICED:
            rec.mark_lost(LOST_TAU, LOST_ID)
            rec.topology(LOST_TAU, "complete", (1, 2), COMPLETE)
            rec.event("agent_lost", t_of(LOST_TAU), agent=LOST_ID)
    rec.event("message_rejected", t_of(3), reason="stale")
    if close:
        rec.close()
    return rec


# flush_seconds 0: every call flushes, so the re-sent row and mark_lost hit rows already in Rerun
# (Clear path); NEVER: rows stay buffered until mark_lost (rows 0..14) and close (rows 15..19).
NEVER = 3600.0


def clear_taus(path: Path) -> dict[str, set[int]]:
    """entity -> event times at which a Clear was logged."""
    from rerun.chunk import RrdReader

    out: dict[str, set[int]] = {}
    for chunk in RrdReader(path).stream():
        batch = chunk.to_record_batch()
        if chunk.is_static or "Clear:is_recursive" not in batch.schema.names:
            continue
        out.setdefault(chunk.entity_path.lstrip("/"), set()).update(batch.column("event").to_pylist())
    return out


@pytest.fixture(scope="module", params=[("discrete", NEVER), ("continuous", 0.0), ("discrete", 0.0),
                                        ("continuous", NEVER)], ids=lambda p: f"{p[0]}-flush{p[1]:g}")
def recorded(request, tmp_path_factory):
    mode, flush_seconds = request.param
    out = tmp_path_factory.mktemp(f"run_{mode}")
    rec = record(out, time_mode=mode, flush_seconds=flush_seconds)
    assert rec.rows_recorded == T
    return out, mode, flush_seconds


def test_trajectory_contract(recorded):
    out, mode, _ = recorded
    x, _, _, alive, graph, expected_xhat = synthetic()
    with np.load(out / "trajectory.npz") as f:
        assert set(f.files) == {"t", "x", "xhat", "alive", "graph", "agent_ids", *(c.name for c in REPORTED), "lost",
                                "lost_cause", "states"}  # every column the agents report (the row schema)
        assert f["states"].tolist() == [f"x{k + 1}" for k in range(N)]  # no names given: x1 .. xn
        assert f["lost"].shape == (0, 4) and f["lost"].dtype == np.int64  # rows given without losses: none
        assert f["g"].shape == f["alive"].shape and np.isnan(f["g"]).all()  # no gains given
        t, xs, xh, al, gr, ids = (f[k] for k in ("t", "x", "xhat", "alive", "graph", "agent_ids"))
    assert t.shape == (T,) and xs.shape == (T, N) and xh.shape == (T, M, N)
    assert al.shape == (T, M) and al.dtype == bool and gr.shape == (T,) and ids.shape == (M,)
    np.testing.assert_array_equal(ids, IDS)
    np.testing.assert_allclose(t, np.arange(T) * (1.0 if mode == "discrete" else DT), rtol=0, atol=1e-12)
    # exact: the recorder stores copies of the rows it was given (float64 in, float64 out)
    np.testing.assert_array_equal(xs, x)
    np.testing.assert_array_equal(al, alive)
    np.testing.assert_array_equal(gr, graph)
    # NaN exactly where dead, the re-sent row replaced the first one, garbage of dead agents not stored
    np.testing.assert_array_equal(np.isnan(xh).all(axis=2), ~alive)
    assert not np.isnan(xh[alive]).any()
    np.testing.assert_array_equal(xh, expected_xhat)


def test_events_jsonl(recorded):
    out, _, _ = recorded
    lines = (out / "events.jsonl").read_text().splitlines()
    events = [json.loads(line) for line in lines]
    assert all("event" in e and "t" in e and "wall" in e for e in events)
    names = [e["event"] for e in events]
    assert names[0] == "start" and names[-1] == "recording_closed"
    assert {"switch", "agent_lost", "message_rejected"} <= set(names)
    assert events[0]["seed"] == 7 and events[0]["agents"] == list(IDS)
    assert events[-1]["finished"] is True and events[-1]["rows"] == T


def test_rrd_verifies(recorded):
    out, _, _ = recorded
    ok, output = verify_rrd(out / "run.rrd")
    assert ok, output


def test_rrd_values_match_trajectory(recorded):
    out, mode, _ = recorded
    series = read_rrd(out / "run.rrd")
    with np.load(out / "trajectory.npz") as f:
        x, xhat, alive = f["x"], f["xhat"], f["alive"]
    err = np.linalg.norm(xhat - x[:, None, :], axis=2)  # NaN where dead
    for i, a in enumerate(IDS):
        got = dict(series[f"errors/agent_{a}"])
        alive_taus = [tau for tau in range(T) if alive[tau, i]]
        assert sorted(got) == alive_taus, f"agent {a}: values at {sorted(got)}"  # none where dead
        for tau in alive_taus:
            assert got[tau] == pytest.approx(err[tau, i], abs=1e-9, rel=0)
    got_max = dict(series["errors/max"])
    assert sorted(got_max) == list(range(T))
    for tau in range(T):
        assert got_max[tau] == pytest.approx(np.nanmax(err[tau]), abs=1e-9, rel=0)
    state = read_rrd_state(out / "run.rrd")
    for k in range(N):
        truth = dict(state[f"state/{k + 1}/truth"])
        np.testing.assert_allclose([truth[tau] for tau in range(T)], x[:, k], rtol=0, atol=1e-12)
        for i, a in enumerate(IDS):
            est = dict(state[f"state/{k + 1}/agent_{a}"])
            assert sorted(est) == [tau for tau in range(T) if alive[tau, i]]
            # exact: the estimates themselves, logged as float64 and read back
            np.testing.assert_array_equal([est[tau] for tau in sorted(est)], xhat[sorted(est), i, k])


def test_state_is_one_batch_per_component(recorded):
    """state/<k>/agents: one entity per component holding m values per event time (NaN where dead)."""
    out, _, _ = recorded
    ents = rrd_entities(out / "run.rrd")
    assert {e for e in ents if e.startswith("state/")} == \
        {f"state/{k}/{who}" for k in range(1, N + 1) for who in ("truth", "agents")}
    vectors = read_rrd_vectors(out / "run.rrd")
    with np.load(out / "trajectory.npz") as f:
        xhat = f["xhat"]
    for k in range(N):
        rows = vectors[f"state/{k + 1}/agents"]
        assert [tau for tau, _ in rows] == list(range(T))
        # exact (NaN where dead): the rows of trajectory.npz, logged as float64 and read back
        np.testing.assert_array_equal(np.array([v for _, v in rows]), xhat[:, :, k])


def test_rrd_topology_and_event_levels(recorded):
    from rerun.chunk import RrdReader

    out, _, _ = recorded
    levels, nodes_labels = {}, []
    for chunk in RrdReader(out / "run.rrd").stream():
        batch = chunk.to_record_batch()
        if chunk.entity_path == "/events" and "TextLog:text" in batch.schema.names:
            for text, level in zip(batch.column("TextLog:text").to_pylist(),
                                   batch.column("TextLog:level").to_pylist()):
                levels[text[0]] = level[0]
        if chunk.entity_path == "/topology" and "GraphNodes:labels" in batch.schema.names:
            nodes_labels += batch.column("GraphNodes:labels").to_pylist()
    # one short sentence per event (orchestrator.eventlog.event_text); unknown events: "<event> k=v ..."
    assert levels[f"agent {LOST_ID} lost"] == "WARN" and levels["1 message(s) rejected (stale)"] == "WARN"
    assert levels["start agents=[1, 2, 5] seed=7"] == "INFO" and levels["switch graph=complete"] == "INFO"
    assert ["agent 1", "agent 2", f"agent {LOST_ID} (lost)"] in nodes_labels


def test_clear_only_for_values_already_sent(recorded):
    """mark_lost on buffered rows drops the values; on rows already in Rerun it logs Clear.

    Either way every series of the lost agent alone gets a Clear at the loss itself (a break in its
    line); in the shared state batches its values are NaN from the loss on, re-sent rows included.
    """
    out, _, flush_seconds = recorded
    clears = clear_taus(out / "run.rrd")
    series = {f"errors/agent_{LOST_ID}", f"errors_log10/agent_{LOST_ID}"}
    assert set(clears) == series
    lost_col = IDS.index(LOST_ID)
    for k in range(N):
        rows = dict(read_rrd_vectors(out / "run.rrd")[f"state/{k + 1}/agents"])
        assert all(np.isnan(rows[tau][lost_col]) == (tau >= LOST_TAU) for tau in range(T))
    if flush_seconds == NEVER:  # rows 12..14 were still buffered when agent 5 was marked lost
        assert all(clears[s] == {LOST_TAU} for s in series)
    else:
        lost = set(range(LOST_TAU, LOST_NOTICED + 1))
        assert all(clears[s] == lost for s in series)


def test_resent_rows_buffered_and_sent(tmp_path):
    """A re-sent row replaces a sent row (values re-sent, Clear where an agent went) or a buffered one."""
    rec = Recorder(tmp_path, agent_ids=IDS, n=N, steps=4, time_mode="discrete", dt=1.0, graph_names=GRAPHS,
                   run_id="resend", scenario_name="resend", flush_seconds=NEVER)
    rng = np.random.default_rng(1)
    x, xhat = rng.normal(size=(4, N)), rng.normal(size=(4, M, N))
    everyone = np.ones(M, dtype=bool)
    for tau in range(3):
        rec.row(tau, x[tau], xhat[tau], everyone, 0)
    rec.flush()  # rows 0..2 in Rerun
    rec.row(3, x[3], xhat[3], everyone, 0)  # buffered
    without_2, without_1 = np.array([True, False, True]), np.array([False, True, True])
    xhat[1] += 1.0
    rec.row(1, x[1], xhat[1], without_2, 0)  # sent row: new values, Clear for agent 2
    xhat[3] -= 1.0
    rec.row(3, x[3], xhat[3], without_1, 0)  # buffered row: agent 1 never sent
    rec.close()

    series = read_rrd(tmp_path / "run.rrd")
    state = read_rrd_state(tmp_path / "run.rrd")
    alive = np.array([everyone, without_2, everyone, without_1])
    err = np.linalg.norm(xhat - x[:, None, :], axis=2)
    for i, a in enumerate(IDS):
        got = dict(series[f"errors/agent_{a}"])
        assert sorted(got) == [tau for tau in range(4) if alive[tau, i]]
        for tau, value in got.items():
            assert value == pytest.approx(err[tau, i], abs=1e-9, rel=0)
            assert dict(state[f"state/1/agent_{a}"])[tau] == xhat[tau, i, 0]  # exact: logged and read back
    assert [v for _, v in series["errors/max"]] == pytest.approx(
        [err[tau, alive[tau]].max() for tau in range(4)], abs=1e-9, rel=0)
    assert clear_taus(tmp_path / "run.rrd") == {"errors/agent_2": {1}, "errors_log10/agent_2": {1}}
    for k in range(N):  # the re-sent row 1 retracts agent 2's state with NaN; agent 1 never sent for row 3
        assert sorted(dict(state[f"state/{k + 1}/agent_2"])) == [0, 2, 3]
        assert sorted(dict(state[f"state/{k + 1}/agent_1"])) == [0, 1, 2]
    with np.load(tmp_path / "trajectory.npz") as f:
        np.testing.assert_array_equal(f["alive"], alive)
        np.testing.assert_array_equal(np.isnan(f["xhat"]).all(axis=2), ~alive)


@pytest.mark.filterwarnings("ignore:RRD file has no footer")
def test_background_flush_when_rows_stop(tmp_path):
    """With no recorder call for flush_seconds, buffered rows still reach trajectory.npz and run.rrd."""
    rec = Recorder(tmp_path, agent_ids=IDS, n=N, steps=10, time_mode="discrete", dt=1.0, graph_names=GRAPHS,
                   run_id="idle", scenario_name="idle", flush_seconds=0.2)
    try:
        rec.event("start", 0.0)
        for tau in range(3):
            rec.row(tau, np.zeros(N), np.ones((M, N)), np.ones(M, dtype=bool), 0)
        deadline = time.monotonic() + 10.0
        series: dict = {}
        while time.monotonic() < deadline:
            time.sleep(0.1)
            if (tmp_path / "trajectory.npz").exists() and (tmp_path / "run.rrd").exists():
                series = read_rrd(tmp_path / "run.rrd")
                if len(series.get("errors/max", [])) == 3:
                    break
        with np.load(tmp_path / "trajectory.npz") as f:
            assert f["t"].shape == (3,)
        assert [tau for tau, _ in series["errors/max"]] == [0, 1, 2]
    finally:
        rec.close()
    assert rec._watcher is not None
    rec._watcher.join(timeout=5.0)
    assert not rec._watcher.is_alive()  # close() stops the background flusher


@pytest.mark.filterwarnings("ignore:RRD file has no footer")
def test_crash_leaves_readable_trajectory(tmp_path):
    """A process killed without close() still leaves every row in trajectory.npz (flush_seconds=0)."""
    script = textwrap.dedent(f"""
        import os, sys
        sys.path.insert(0, {str(Path(__file__).parent)!r})
        from test_recorder import record
        from pathlib import Path
        record(Path({str(tmp_path)!r}), time_mode="continuous", close=False, flush_seconds=0.0)
        os._exit(3)  # no close(), no atexit, no Rerun shutdown
    """)
    proc = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=60,
                          env={**os.environ, "RERUN_ANALYTICS": "0"})
    assert proc.returncode == 3, proc.stdout + proc.stderr
    x, _, _, alive, _, expected_xhat = synthetic()
    assert not list(tmp_path.glob(".trajectory.*"))  # no temporary file left behind
    with np.load(tmp_path / "trajectory.npz") as f:  # exact: stored copies of the rows given
        assert f["t"].shape == (T,)
        np.testing.assert_array_equal(f["x"], x)
        np.testing.assert_array_equal(f["xhat"], expected_xhat)
        np.testing.assert_array_equal(f["alive"], alive)
    events = [json.loads(line) for line in (tmp_path / "events.jsonl").read_text().splitlines()]
    assert events[-1]["event"] == "message_rejected"
    # run.rrd (no footer after a kill) is readable; rows flushed just before the kill may not have reached it
    got = [tau for tau, _ in read_rrd(tmp_path / "run.rrd").get("errors/max", [])]
    assert got == list(range(len(got)))


def flushed_on_disk(out: str, rows: int, *, deadline: float) -> bool:
    """Until ``rows`` rows are on disk (the recorder's background flush, and the Rerun file sink behind it, write
    them in their own threads): in ``trajectory.npz`` and in ``run.rrd``, the loss's Clear too; False at
    ``deadline``."""
    import warnings

    while time.monotonic() < deadline:
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")  # "RRD file has no footer": it is being written
                with np.load(Path(out) / "trajectory.npz") as f:
                    npz = f["t"].shape[0]
                rrd = len(read_rrd(Path(out) / "run.rrd").get("errors/max", []))
                cleared = bool(clear_taus(Path(out) / "run.rrd"))
        except (OSError, RuntimeError, ValueError, KeyError, EOFError):  # not there yet, or cut mid-write: again
            npz = rrd = 0
            cleared = False
        if npz >= rows and rrd >= rows and cleared:
            return True
        time.sleep(0.02)
    return False


@pytest.mark.filterwarnings("ignore:RRD file has no footer")
def test_crash_keeps_rows_up_to_last_flush(tmp_path):
    """Killed after rows were buffered: both files hold exactly the rows up to the last flush (mark_lost)."""
    script = textwrap.dedent(f"""
        import os, sys, time
        sys.path.insert(0, {str(Path(__file__).parent)!r})
        from test_recorder import record, NEVER, LOST_NOTICED, flushed_on_disk
        from pathlib import Path
        rec = record(Path({str(tmp_path)!r}), time_mode="discrete", close=False, flush_seconds=NEVER)
        # the rows mark_lost flushed reach both files from the recorder's and the Rerun sink's own threads
        flushed_on_disk({str(tmp_path)!r}, LOST_NOTICED + 1, deadline=time.monotonic() + 60)
        os._exit(3)  # no close(), no atexit, no Rerun shutdown
    """)
    proc = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=60,
                          env={**os.environ, "RERUN_ANALYTICS": "0"})
    assert proc.returncode == 3, proc.stdout + proc.stderr
    x, _, _, alive, _, expected_xhat = synthetic()
    flushed = LOST_NOTICED + 1  # mark_lost flushed rows 0..14; rows 15..19 were still buffered
    with np.load(tmp_path / "trajectory.npz") as f:  # exact: stored copies of the rows given
        assert f["t"].shape == (flushed,)
        np.testing.assert_array_equal(f["xhat"], expected_xhat[:flushed])
        np.testing.assert_array_equal(f["alive"], alive[:flushed])
    series = read_rrd(tmp_path / "run.rrd")
    assert [tau for tau, _ in series["errors/max"]] == list(range(flushed))
    assert [tau for tau, _ in series[f"errors/agent_{LOST_ID}"]] == list(range(LOST_TAU))
    # only the loss's own Clears (rows 12..14 were buffered when the loss was marked)
    assert set(map(frozenset, clear_taus(tmp_path / "run.rrd").values())) == {frozenset({LOST_TAU})}


@pytest.mark.filterwarnings("ignore:RRD file has no footer")
@pytest.mark.parametrize("keep", [True, False], ids=["exit", "dropped"])
def test_exit_without_close_flushes_buffered_rows(tmp_path, keep):
    """Without close(), buffered rows still reach both files at a normal exit or when the recorder is dropped."""
    script = textwrap.dedent(f"""
        import sys
        sys.path.insert(0, {str(Path(__file__).parent)!r})
        from test_recorder import record, NEVER
        from pathlib import Path
        {"rec = " if keep else ""}record(Path({str(tmp_path)!r}), time_mode="discrete", close=False,
                                           flush_seconds=NEVER)
    """)
    proc = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=60,
                          env={**os.environ, "RERUN_ANALYTICS": "0"})
    assert proc.returncode == 0, proc.stdout + proc.stderr
    with np.load(tmp_path / "trajectory.npz") as f:
        assert f["t"].shape == (T,)
    assert [tau for tau, _ in read_rrd(tmp_path / "run.rrd")["errors/max"]] == list(range(T))


def test_failing_rerun_send_is_a_warning(tmp_path, caplog):
    rec = Recorder(tmp_path, agent_ids=IDS, n=N, steps=3, time_mode="discrete", dt=1.0, graph_names=GRAPHS,
                   run_id="fail", scenario_name="fail", flush_seconds=NEVER)

    def broken(*args, **kwargs):
        raise RuntimeError("sink gone")

    rec._rec.rec.send_columns = broken  # the RerunSink's recording stream
    with caplog.at_level(logging.WARNING, logger="orchestrator"):
        for tau in range(3):
            rec.row(tau, np.zeros(N), np.ones((M, N)), np.ones(M, dtype=bool), 0)
        rec.event("start", 0.0)
        rec.close()
    assert "Rerun row log failed" in caplog.text and "sink gone" in caplog.text
    with np.load(tmp_path / "trajectory.npz") as f:
        assert f["t"].shape == (3,)


def test_unreachable_viewer_falls_back_to_file(tmp_path, caplog):
    with socket.socket() as s:  # a free port nobody listens on
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    with caplog.at_level(logging.WARNING, logger="orchestrator"):
        record(tmp_path, time_mode="discrete", viewer=f"rerun+http://127.0.0.1:{port}/proxy")
    assert "not reachable" in caplog.text
    assert len(read_rrd(tmp_path / "run.rrd")["errors/max"]) == T


def test_input_errors_name_the_problem(tmp_path):
    rec = Recorder(tmp_path, agent_ids=IDS, n=N, steps=3, time_mode="discrete", dt=1.0, graph_names=GRAPHS,
                   run_id="bad", scenario_name="bad")
    ok = np.ones(M, dtype=bool)
    with pytest.raises(RecordingError, match=r"xhat has shape \(2, 4\); expected \(3, 4\)"):
        rec.row(0, np.zeros(N), np.zeros((2, N)), ok, 0)
    with pytest.raises(RecordingError, match="graph index 2"):
        rec.row(0, np.zeros(N), np.zeros((M, N)), ok, 2)
    with pytest.raises(RecordingError, match="unknown graph 'star'"):
        rec.topology(0, "star", IDS, [])
    rec.row(1, np.zeros(N), np.zeros((M, N)), ok, 0)
    with pytest.raises(RecordingError, match="increasing tau"):
        rec.row(0, np.zeros(N), np.zeros((M, N)), ok, 0)
    with pytest.raises(RecordingError, match="agent 9"):
        rec.mark_lost(0, 9)
    rec.close(finished=False)
    assert json.loads((tmp_path / "events.jsonl").read_text().splitlines()[-1])["finished"] is False
    with pytest.raises(RecordingError, match="after close"):
        rec.row(2, np.zeros(N), np.zeros((M, N)), ok, 0)


def test_round_loop_calls_never_write_or_wait_for_a_flush(tmp_path, monkeypatch):
    """flush_seconds > 0: row/event/topology/mark_lost do no Rerun call, no run.rrd or trajectory.npz write
    and no fsync in the caller's thread, and return at once while a (slow) background flush is under way."""
    import threading

    import splitspec_core.simulation.trajectory_file as trajfile
    import splitspec_orchestrator.viewer.rrd_file as rrdfile

    main = threading.current_thread()
    calls: list[tuple[str, bool]] = []  # (what, in the caller's thread)
    real_fsync, real_append = os.fsync, rrdfile.RrdAppender.append
    monkeypatch.setattr(os, "fsync", lambda fd: (calls.append(("fsync", threading.current_thread() is main)),
                                                 real_fsync(fd))[1])
    monkeypatch.setattr(rrdfile.RrdAppender, "append", lambda self, piece: (
        calls.append(("run.rrd", threading.current_thread() is main)), real_append(self, piece))[1])
    real_write = trajfile.write_trajectory
    monkeypatch.setattr("splitspec_orchestrator.records.files.write_trajectory", lambda *a, **kw: (
        calls.append(("trajectory.npz", threading.current_thread() is main)), real_write(*a, **kw))[1])
    rec = Recorder(tmp_path, agent_ids=IDS, n=N, steps=T, time_mode="discrete", dt=1.0, graph_names=GRAPHS,
                   run_id="bg", scenario_name="bg", flush_seconds=0.05)
    calls.clear()  # the constructor writes run.rrd's header itself
    in_flush, release = threading.Event(), threading.Event()
    real_send = rec._rec.send_rows

    def slow_send(batch):
        calls.append(("rerun", threading.current_thread() is main))
        in_flush.set()
        # a flush held until the callers are done (a fixed sleep stood in for it, and a starved machine's stall
        # made a caller look as if it waited): a caller that waits for it waits the whole 30 s
        release.wait(30.0)
        real_send(batch)

    rec._rec.send_rows = slow_send
    x, xhat, _, alive, graph, _ = synthetic()
    rec.topology(0, "ring", IDS, RING)
    rec.event("start", 0.0)
    longest = 0.0
    for tau in range(T):
        t0 = time.perf_counter()
        rec.row(tau, x[tau], xhat[tau], alive[tau] | (tau >= LOST_TAU), int(graph[tau]))
        if tau == LOST_NOTICED:
            rec.mark_lost(LOST_TAU, LOST_ID)
            rec.event("agent_lost", float(LOST_TAU), id=LOST_ID)
            rec.topology(LOST_TAU, "complete", (1, 2), COMPLETE)
        longest = max(longest, time.perf_counter() - t0)
        if tau == 5:
            assert in_flush.wait(10.0)  # rows 0..5 are being flushed, slowly, from here on
    release.set()
    assert longest < 10.0, f"a recorder call waited {longest:.3f} s for the flush"
    deadline = time.monotonic() + 20.0
    while rec.rows_kept < T and time.monotonic() < deadline:  # the background thread writes them all
        time.sleep(0.05)
    assert rec.rows_kept == T
    assert calls and not any(in_main for _, in_main in calls), calls
    assert {what for what, _ in calls} >= {"rerun", "run.rrd", "trajectory.npz", "fsync"}
    rec.close()  # close writes in the caller's thread
    assert any(in_main for _, in_main in calls)
    with np.load(tmp_path / "trajectory.npz") as f:
        assert f["t"].shape == (T,)
    assert [tau for tau, _ in read_rrd(tmp_path / "run.rrd")["errors/max"]] == list(range(T))


@pytest.mark.filterwarnings("ignore:RRD file has no footer")
def test_mark_lost_asks_for_a_flush_of_the_rows_so_far(tmp_path):
    """With a flush period that never comes, mark_lost still gets every row recorded before it written
    (by the background thread), and only those."""
    rec = Recorder(tmp_path, agent_ids=IDS, n=N, steps=T, time_mode="discrete", dt=1.0, graph_names=GRAPHS,
                   run_id="ml", scenario_name="ml", flush_seconds=NEVER)
    try:
        x, xhat, _, alive, graph, _ = synthetic()
        for tau in range(LOST_NOTICED + 1):
            rec.row(tau, x[tau], xhat[tau], np.ones(M, dtype=bool), int(graph[tau]))
        rec.mark_lost(LOST_TAU, LOST_ID)
        for tau in range(LOST_NOTICED + 1, T):  # recorded after the request: not in that flush
            rec.row(tau, x[tau], xhat[tau], alive[tau], int(graph[tau]))
        deadline = time.monotonic() + 10.0
        while rec.rows_kept < LOST_NOTICED + 1 and time.monotonic() < deadline:
            time.sleep(0.02)
        assert rec.rows_kept == LOST_NOTICED + 1
        with np.load(tmp_path / "trajectory.npz") as f:
            assert f["t"].shape == (LOST_NOTICED + 1,)
            assert np.isnan(f["xhat"][LOST_TAU:, IDS.index(LOST_ID)]).all()
        assert [tau for tau, _ in read_rrd(tmp_path / "run.rrd")["errors/max"]] == list(range(LOST_NOTICED + 1))
    finally:
        rec.close()
    assert rec.rows_kept == T


def test_slow_trajectory_rewrites_are_spaced_out(tmp_path, monkeypatch):
    """The background thread spends at most about a tenth of its time rewriting trajectory.npz (the whole
    file each time): a rewrite that takes 0.1 s is not repeated within 0.9 s, while run.rrd is appended at
    every flush; close() still writes every row."""
    import splitspec_core.simulation.trajectory_file as trajfile

    writes: list[float] = []
    real_write = trajfile.write_trajectory

    def slow_write(*args, **kwargs):
        writes.append(time.monotonic())
        time.sleep(0.1)
        real_write(*args, **kwargs)

    monkeypatch.setattr("splitspec_orchestrator.records.files.write_trajectory", slow_write)
    rec = Recorder(tmp_path, agent_ids=IDS, n=N, steps=200, time_mode="discrete", dt=1.0, graph_names=GRAPHS,
                   run_id="npz", scenario_name="npz", flush_seconds=0.05)
    appends = []
    real_append = rec._rec.rrd_file.append
    rec._rec.rrd_file.append = lambda piece: (appends.append(time.monotonic()), real_append(piece))[1]
    t0 = time.monotonic()
    tau = 0
    while time.monotonic() - t0 < 2.0:
        rec.row(tau, np.zeros(N), np.ones((M, N)), np.ones(M, dtype=bool), 0)
        tau += 1
        time.sleep(0.01)
    during = list(writes)
    rec.close()
    assert 1 <= len(during) <= 3, during
    assert all(b - a >= 0.9 for a, b in zip(during, during[1:])), during
    assert len(appends) >= 2 * len(during)  # run.rrd kept up meanwhile
    with np.load(tmp_path / "trajectory.npz") as f:
        assert f["t"].shape == (tau,)
    assert rec.rows_kept == tau
