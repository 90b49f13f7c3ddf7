"""Recorder: trajectory.npz contract, events.jsonl, run.rrd contents, crash safety."""

from __future__ import annotations

import json
import logging
import os
import socket
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from orchestrator.recorder import Recorder, RecordingError, read_rrd, verify_rrd

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


@pytest.fixture(scope="module", params=["discrete", "continuous"])
def recorded(request, tmp_path_factory):
    out = tmp_path_factory.mktemp(f"run_{request.param}")
    rec = record(out, time_mode=request.param)
    assert rec.rows_recorded == T
    return out, request.param


def test_trajectory_contract(recorded):
    out, mode = recorded
    x, _, _, alive, graph, expected_xhat = synthetic()
    with np.load(out / "trajectory.npz") as f:
        assert set(f.files) == {"t", "x", "xhat", "alive", "graph", "agent_ids"}
        t, xs, xh, al, gr, ids = (f[k] for k in ("t", "x", "xhat", "alive", "graph", "agent_ids"))
    assert t.shape == (T,) and xs.shape == (T, N) and xh.shape == (T, M, N)
    assert al.shape == (T, M) and al.dtype == bool and gr.shape == (T,) and ids.shape == (M,)
    np.testing.assert_array_equal(ids, IDS)
    np.testing.assert_allclose(t, np.arange(T) * (1.0 if mode == "discrete" else DT), rtol=0, atol=1e-12)
    np.testing.assert_array_equal(xs, x)
    np.testing.assert_array_equal(al, alive)
    np.testing.assert_array_equal(gr, graph)
    # NaN exactly where dead, the re-sent row replaced the first one, garbage of dead agents not stored
    np.testing.assert_array_equal(np.isnan(xh).all(axis=2), ~alive)
    assert not np.isnan(xh[alive]).any()
    np.testing.assert_array_equal(xh, expected_xhat)


def test_events_jsonl(recorded):
    out, _ = recorded
    lines = (out / "events.jsonl").read_text().splitlines()
    events = [json.loads(line) for line in lines]
    assert all("event" in e and "t" in e and "wall" in e for e in events)
    names = [e["event"] for e in events]
    assert names[0] == "start" and names[-1] == "recording_closed"
    assert {"switch", "agent_lost", "message_rejected"} <= set(names)
    assert events[0]["seed"] == 7 and events[0]["agents"] == list(IDS)
    assert events[-1]["finished"] is True and events[-1]["rows"] == T


def test_rrd_verifies(recorded):
    out, _ = recorded
    ok, output = verify_rrd(out / "run.rrd")
    assert ok, output


def test_rrd_values_match_trajectory(recorded):
    out, mode = recorded
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
    for k in range(N):
        truth = dict(series[f"state/{k + 1}/truth"])
        np.testing.assert_allclose([truth[tau] for tau in range(T)], x[:, k], rtol=0, atol=1e-12)
        est = dict(series[f"state/{k + 1}/agent_{LOST_ID}"])
        assert sorted(est) == list(range(LOST_TAU))


def test_rrd_topology_and_event_levels(recorded):
    from rerun.chunk import RrdReader

    out, _ = recorded
    levels, nodes_labels = {}, []
    for chunk in RrdReader(out / "run.rrd").stream():
        batch = chunk.to_record_batch()
        if chunk.entity_path == "/events" and "TextLog:text" in batch.schema.names:
            for text, level in zip(batch.column("TextLog:text").to_pylist(),
                                   batch.column("TextLog:level").to_pylist()):
                levels[text[0].split()[0]] = level[0]
        if chunk.entity_path == "/topology" and "GraphNodes:labels" in batch.schema.names:
            nodes_labels += batch.column("GraphNodes:labels").to_pylist()
    assert levels["agent_lost"] == "WARN" and levels["message_rejected"] == "WARN"
    assert levels["start"] == "INFO" and levels["switch"] == "INFO"
    assert ["agent 1", "agent 2", f"agent {LOST_ID} (lost)"] in nodes_labels


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
    with np.load(tmp_path / "trajectory.npz") as f:
        assert f["t"].shape == (T,)
        np.testing.assert_array_equal(f["x"], x)
        np.testing.assert_array_equal(f["xhat"], expected_xhat)
        np.testing.assert_array_equal(f["alive"], alive)
    events = [json.loads(line) for line in (tmp_path / "events.jsonl").read_text().splitlines()]
    assert events[-1]["event"] == "message_rejected"


def test_unreachable_viewer_falls_back_to_file(tmp_path, caplog):
    with socket.socket() as s:  # a free port nobody listens on
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    with caplog.at_level(logging.WARNING, logger="orchestrator.recorder"):
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
