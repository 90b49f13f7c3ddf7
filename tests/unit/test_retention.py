"""run.keep and run.record_every without processes: the keys, a recorder until stopped that removes its oldest
closed segments, what load_run and view say is left, the disk rate splitspec pace prints.  With processes:
tests/integration/test_until_stopped.py (retention while running, then load and replay)."""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import pytest

import splitspec_core as ss
from splitspec_core.errors import ScenarioError
from splitspec_core.runs import kept_span, nothing_removed, read_events
from splitspec_core.scenarios.specs import RunSpec
from splitspec_core.simulation.trajectory_chunks import chunk_segments, read_chunks
from splitspec_orchestrator.commands.pace import DiskRate
from splitspec_orchestrator.records.files import Continuous
from splitspec_orchestrator.records.recorder import Recorder
from splitspec_orchestrator.records.retention import records_bytes
from splitspec_orchestrator.view import retention_line
from splitspec_orchestrator.viewer.rrd_file import rrd_segments

os.environ.setdefault("RERUN_ANALYTICS", "0")

IDS, M, N = (1, 2, 5), 3, 4
SEGMENT = 60_000  # chunk segments of some 25 rows here (a flush per row, zstd)


def _scenario(**run):
    return ss.scenario(A=np.diag([0.9, 1.1]), C={1: [[1.0, 0.0]], 2: [[0.0, 1.0]]}, graphs={"g": [(1, 2), (2, 1)]},
                       rate=0.95, time="discrete", **run)


def test_run_keep_and_record_every_are_read_and_checked():
    sc = _scenario(pace=50, keep={"hours": 6, "gigabytes": 2.5})
    assert (sc.run.keep_hours, sc.run.keep_gigabytes, sc.run.recorded_every) == (6.0, 2.5, 5)
    assert _scenario(pace=50, record_every=1).run.recorded_every == 1
    assert _scenario(pace=50, steps=100).run.recorded_every == 1  # a run of run.steps: every event time
    assert _scenario(pace=8).run.recorded_every == 1  # slow enough to record whole
    assert RunSpec(pace=200.0, until_stopped=True).recorded_every == 20
    bad = [({"pace": 50, "steps": 10, "keep": {"hours": 1}}, "run.keep is for a run that goes on until stopped"),
           ({"pace": 50, "keep": {"days": 1}}, "unknown key run.keep.days"),
           ({"pace": 50, "keep": {}}, "run.keep needs hours or gigabytes"),
           ({"pace": 50, "keep": {"hours": 0}}, r"run.keep.hours must be > 0, got 0"),
           ({"pace": 50, "keep": {"gigabytes": -1}}, r"run.keep.gigabytes must be > 0"),
           ({"pace": 50, "keep": 3}, "run.keep must be a map"),
           ({"pace": 50, "record_every": 0}, r"run.record_every must be >= 1, got 0")]
    for run, message in bad:
        with pytest.raises(ScenarioError, match=message):
            _scenario(**run)


def test_run_keep_segment_mb_sets_the_segment_sizes_and_the_variables_override_it(monkeypatch):
    """Issue 46, finding 10: segments closed at 64 and 256 MiB whatever the scenario said, so a short run's run.keep
    removed nothing; run.keep.segment_mb sets both (SPLITSPEC_CHUNK_MB / SPLITSPEC_RRD_ROLL_MB still override)."""
    monkeypatch.delenv("SPLITSPEC_CHUNK_MB", raising=False)
    monkeypatch.delenv("SPLITSPEC_RRD_ROLL_MB", raising=False)
    sc = _scenario(pace=50, keep={"hours": 1, "segment_mb": 0.5})
    assert sc.run.keep_segment_mb == 0.5
    cont = Continuous.from_env(sc.run)
    assert (cont.chunk_bytes, cont.rrd_bytes) == (1 << 19, 1 << 19)
    assert (Continuous.from_env(_scenario(pace=50, keep={"hours": 1}).run).chunk_bytes,
            Continuous.from_env(_scenario(pace=50, keep={"hours": 1}).run).rrd_bytes) == (64 << 20, 256 << 20)
    monkeypatch.setenv("SPLITSPEC_CHUNK_MB", "2")
    assert Continuous.from_env(sc.run).chunk_bytes == 2 << 20 and Continuous.from_env(sc.run).rrd_bytes == 1 << 19
    for keep, message in [({"hours": 1, "segment_mb": 0.01}, r"run.keep.segment_mb must be >= 0.0625 \(64 KiB\)"),
                          ({"segment_mb": 1}, "run.keep.segment_mb needs hours or gigabytes")]:
        with pytest.raises(ScenarioError, match=message):
            _scenario(pace=50, keep=keep)


def test_a_run_that_removed_nothing_says_why_and_what_its_records_take(tmp_path):
    """Issue 46, finding 10: on_disk was None when nothing was removed; the run's plan (said at its start, the
    driver's records_retention event) and the records on disk now say why nothing went."""
    out = tmp_path / "run"
    rec = _until_stopped(out, Continuous(window_rows=16, chunk_bytes=1 << 30, rrd_bytes=1 << 30, keep_hours=1.0))
    assert rec.retention_plan["chunk_mb"] == 1024 and rec.retention_plan["hours"] == 1.0
    assert rec.retention_plan["text"].startswith("run.keep: a row chunk segment closes past 1024 MiB, a recording "
                                                 "segment past 1024 MiB")
    rec.event("records_retention", 0.0, **rec.retention_plan)  # as the driver does once the recorder is made
    _feed_from(rec, 0, 40)
    rec.close()
    line = nothing_removed(out, read_events(out / "events.jsonl"))
    assert line.startswith("run.keep removed nothing: no segment had closed (a row chunk segment closes past 1024 "
                           "MiB, a recording segment past 1024 MiB: set run.keep.segment_mb for a short run)")
    size = records_bytes(out)
    assert size > 0 and line.endswith(f"; the records take {size / 1e6:.1f} MB")
    assert retention_line(out) == line
    assert _until_stopped(tmp_path / "plain", Continuous(window_rows=16)).retention_plan is None  # no run.keep


def _until_stopped(out: Path, cont: Continuous) -> Recorder:
    return Recorder(out, agent_ids=IDS, n=N, steps=50, time_mode="discrete", dt=1.0, graph_names=("g",),
                    run_id="keep", scenario_name="keep", flush_seconds=0.0, continuous=cont)


@pytest.mark.long
def test_a_recorder_until_stopped_keeps_its_records_under_run_keep_gigabytes(tmp_path):
    # the same 400 rows without run.keep first: how much run.rrd (one segment, never removed) and the chunks take
    # (chunk segments of half the usual size, some 12 rows each: as many segments as twice the rows would fill)
    seg, rows_n = SEGMENT // 2, 400
    whole = tmp_path / "whole"
    rec = _until_stopped(whole, Continuous(window_rows=16, chunk_bytes=seg, rrd_bytes=1 << 30))
    _feed_from(rec, 0, rows_n)
    # as written while running (the close compacts it)
    rrd, chunks = (whole / "run.rrd").stat().st_size, sum(p.stat().st_size for _, p in chunk_segments(whole))
    rec.close()
    room = 5 * seg  # about five chunk segments beside run.rrd (the run writes about thirty)
    out = tmp_path / "run"
    rec = _until_stopped(out, Continuous(window_rows=16, chunk_bytes=seg, rrd_bytes=1 << 30,
                                         keep_bytes=rrd + room))
    rec._w.retention.every = 0.0  # sweep at every flush (a run's: every 5 s)
    _feed_from(rec, 0, rows_n)
    # the rule after the last sweep: within the limit, but for the chunk segment being written (never removed) and
    # what the removal events added to run.rrd (about 1.3 kB each: a flush sends each log as a chunk of its own)
    assert records_bytes(out) <= rrd + room + seg + 60 * 1300, (records_bytes(out), rrd + room)
    rec.close()
    removed = [json.loads(line) for line in (out / "events.jsonl").read_text().splitlines()
               if '"records_removed"' in line]
    assert removed and {e["kind"] for e in removed} == {"chunks"} and {e["reason"] for e in removed} == {"gigabytes"}
    for e in removed:  # each removal names what went
        assert not (out / e["file"]).exists() and e["bytes"] > 0 and e["first_tau"] <= e["last_tau"]
    kept = sum(p.stat().st_size for _, p in chunk_segments(out))
    # bounded: the room left beside run.rrd plus the segment being written (and run.rrd's own spread), a fraction of
    # what the run wrote
    assert kept < chunks / 2, (kept, chunks)  # a fraction of what the run wrote
    rows = read_chunks(out)
    cut = max(e["last_tau"] for e in removed) + 1
    # what is left: every row from the first no removal took to the last, values as recorded
    assert rows["tau"].tolist() == list(range(cut, rows_n))
    assert rows_n - 10 > cut > 0
    rng = np.random.default_rng(rows_n - 10)
    assert np.array_equal(rows["x"][rows_n - 10 - cut], rng.normal(size=N))  # exact: the values given, copied
    span = kept_span(ss.runs.read_events(out / "events.jsonl"))
    assert span["chunks_from"] == cut and span["recording_from"] is None and span["removed"] == len(removed)
    assert span["text"].startswith(f"run.keep removed {len(removed)} segments (") and str(cut) in span["text"]
    assert retention_line(out).startswith(span["text"])


def _feed_from(rec: Recorder, start: int, count: int) -> None:
    for tau in range(start, start + count):
        rng = np.random.default_rng(tau)
        rec.row(tau, rng.normal(size=N), rng.normal(size=(M, N)), np.ones(M, dtype=bool), 0, wall_ms=1.0,
                attempts=1, rejected=0, lost=[], late_ms=0.0)


def test_nothing_removed_says_nothing():
    assert kept_span([{"event": "run_started"}]) is None


def test_the_disk_rate_line_states_per_hour_per_day_and_on_hand():
    d = DiskRate(chunk_bytes=3000.0, rrd_bytes=2000.0, rows=500, every=5)
    line = d.line(50.0, keep_hours=6.0)
    # 5000 bytes a row at 50 a second: 0.9 GB an hour, 21.6 a day, 5.4 on hand for 6 hours
    assert "about 0.9 GB per hour at pace 50" in line and "21.6 GB a day" in line and "about 5.4 GB on hand" in line
    assert "540 MB/h of row chunks" in line and "360 MB/h of Rerun recording" in line and "every 5 event times" in line
    assert "on hand" not in d.line(50.0)


def test_the_disk_rate_line_says_when_the_first_segments_close():
    """Issue 46 (10) and its walk: a run.keep that removes nothing for a while left the user guessing; with the
    segment sizes pace says when the first segment of each kind closes, before which nothing is removed."""
    d = DiskRate(chunk_bytes=3000.0, rrd_bytes=2000.0, rows=500, every=5)
    line = d.line(50.0, keep_hours=0.01, segments=(64 << 20, 1 << 20))
    # 64 MiB of rows at 150 kB/s: 447 s = 7.5 min; 1 MiB of recording at 100 kB/s: 10 s
    assert "a row chunk segment closes about every 7.5 min (64 MiB)" in line, line
    assert "and a recording segment closes about every 10 s (1 MiB) (run.keep.segment_mb)" in line, line
    assert "nothing is removed before one closes" in line and "plus the segment being written of each kind" in line
    assert "segment closes" not in d.line(50.0, segments=(64 << 20, 1 << 20))  # no run.keep: no such line


@pytest.mark.long
def test_run_keep_recording_hours_keeps_the_recording_longer_than_the_rows(tmp_path):
    sc = _scenario(pace=50, keep={"hours": 6, "recording_hours": 24})
    assert (sc.run.keep_hours, sc.run.keep_recording_hours) == (6.0, 24.0)
    with pytest.raises(ScenarioError, match="run.keep.recording_hours needs hours or gigabytes"):
        _scenario(pace=50, keep={"recording_hours": 24})
    out = tmp_path / "run"
    # the rows' segments go as soon as they close; the recording's (rolled every 150 kB) stay a thousand hours
    rec = _until_stopped(out, Continuous(window_rows=16, chunk_bytes=SEGMENT, rrd_bytes=150_000, keep_hours=1e-9,
                                         keep_recording_hours=1000.0))
    rec._w.retention.every = 0.0
    _feed_from(rec, 0, 200)
    rec.close()
    removed = [json.loads(line) for line in (out / "events.jsonl").read_text().splitlines()
               if '"records_removed"' in line]
    assert removed and {e["kind"] for e in removed} == {"chunks"} and {e["reason"] for e in removed} == {"hours"}
    assert len(chunk_segments(out)) == 1  # the one being written when the run ended
    assert len(rrd_segments(out / "run.rrd")) >= 3 and (out / "run.rrd").exists()  # every segment of the recording


def test_a_finished_recording_is_compacted_and_keeps_every_row(tmp_path):
    """A flush sends one small chunk per entity: 200 flushes of one row each would leave thousands; the close
    compacts them (rerun rrd optimize) and every row is still there, verifiable."""
    from rerun.chunk import RrdReader

    from splitspec_orchestrator.viewer.rrd_file import optimize_rrd, verify_rrd
    from tests.rrd_readback import read_rrd

    rec = _until_stopped(tmp_path / "run", Continuous(window_rows=16, chunk_bytes=1 << 30, rrd_bytes=1 << 30))
    _feed_from(rec, 0, 200)
    rec.close()
    path = tmp_path / "run" / "run.rrd"
    chunks = sum(1 for _ in RrdReader(path).stream())
    assert chunks < 200, chunks  # merged: without it, at least one per flush on errors/max alone
    assert verify_rrd(path)[0]
    assert [tau for tau, _ in read_rrd(path)["errors/max"]] == list(range(200))
    size = path.stat().st_size
    assert optimize_rrd(path) and path.stat().st_size <= size * 1.01  # compacting again changes nothing much
    (tmp_path / "bad.rrd").write_bytes(b"not a recording")
    assert not optimize_rrd(tmp_path / "bad.rrd") and (tmp_path / "bad.rrd").read_bytes() == b"not a recording"
