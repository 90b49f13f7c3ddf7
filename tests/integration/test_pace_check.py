"""`splitspec pace`: a short real run (the processes of `splitspec run`) decides whether a pace is feasible.

The two runtime tests run ring10 for real, against a pace no machine keeps (exit 1, NOT feasible) and a modest
one (exit 0, feasible); the others check the measure on rows of known wall times, the rule's margin, and the
one-line refusals, without starting any process.
"""

from __future__ import annotations

import numpy as np
import pytest
import yaml

from splitspec_core.simulation.trajectory_chunks import ChunkWriter
from splitspec_core.scenarios.sections import parse_scenario
from splitspec_orchestrator.commands.pace import (MARGIN, PROBE_STEPS, WARMUP_ROWS, PaceMeasurement, measure,
                                                  probe_mapping, record_sizes, verdict)
from tests.conftest import EXAMPLES
from tests.integration.runtime_helpers import all_pids, assert_all_gone, events, run, scenario_file

PREFIX = "splitspec: error: "
SECONDS = "1.5"  # of rounds per measuring run (start-up not counted): two runs stay well under 30 s


def assert_one_line_error(r, *fragments) -> None:
    assert "Traceback" not in r.stderr, r.stderr
    assert r.returncode == 2, (r.returncode, r.stderr)
    lines = r.stderr.splitlines()
    assert len(lines) == 1 and lines[0].startswith(PREFIX), r.stderr
    assert r.stdout == "", r.stdout
    for f in fragments:
        assert f in lines[0], (f, lines[0])


@pytest.mark.parametrize("value", ["0", "-1", "nan"])
def test_bad_seconds_is_one_line_exit_2(tmp_path, value):
    r = run("pace", scenario_file(tmp_path, "ring10"), f"--seconds={value}", timeout=60)
    assert_one_line_error(r, "--seconds must be a number in (0, 3600]")


def test_out_holding_records_is_refused_before_any_process(tmp_path):
    """The measure reads the records it finds in --out: a directory with an earlier run's is refused."""
    out = tmp_path / "out"
    out.mkdir()
    (out / "events.jsonl").write_text('{"event": "run_started", "t": 0.0, "wall": 1.0}\n')
    r = run("pace", scenario_file(tmp_path, "ring10"), "--pace", "5", "--out", out, timeout=60)
    assert_one_line_error(r, f"--out {out} already holds a run's records (events.jsonl)")
    assert sorted(p.name for p in out.iterdir()) == ["events.jsonl"]


def _rows(out, walls_ms) -> None:
    """Chunks of a 2-agent, 1-state run whose row tau arrived at ``walls_ms[tau]`` ms."""
    T = len(walls_ms)
    w = ChunkWriter(out, agent_ids=(1, 2), states=("x1",), n=1)
    w.append({"tau": np.arange(T), "t": np.arange(T, dtype=float), "x": np.zeros((T, 1)),
              "xhat": np.zeros((T, 2, 1)), "alive": np.ones((T, 2), bool), "graph": np.zeros(T, np.int64),
              "g": np.full((T, 2), np.nan), "wall": (np.asarray(walls_ms) * 1e6).astype(np.int64),
              "round": np.zeros((T, 5)), "lost": [np.zeros(0, np.int64)] * T})


def test_a_flush_while_the_records_are_read_is_no_sample(tmp_path, monkeypatch):
    """CI once printed ``disk: about 0 GB per hour``: the measuring run's first flush landed between reading its
    rows (none yet) and their size, so the window from the middle grew by rows and by no byte.  A sample whose bytes
    changed while its rows were read is no sample; one that did not has its rows and its bytes from one state."""
    import splitspec_core.simulation.trajectory_chunks as chunks

    _rows(tmp_path, [0.0, 10.0, 20.0])
    real = chunks.read_chunks
    assert record_sizes(tmp_path)[:2] == (3, sum(p.stat().st_size for _, p in chunks.chunk_segments(tmp_path)))

    def read_then_flush(out, **kw):  # a flush landing while the rows are read: bytes appended to the segment
        rows = real(out, **kw)
        seg = chunks.chunk_segments(out)[-1][1]
        with open(seg, "ab") as f:
            f.write(b"\0" * 64)
        return rows

    monkeypatch.setattr(chunks, "read_chunks", read_then_flush)
    assert record_sizes(tmp_path) is None


def test_measure_uses_the_rows_wall_times_after_the_warm_up(tmp_path):
    # a slow start-up row, then rounds of 10 ms with every fifth one 30 ms
    steps = [500.0] * WARMUP_ROWS + [30.0 if k % 5 == 4 else 10.0 for k in range(100)]
    _rows(tmp_path, np.concatenate([[0.0], np.cumsum(steps)]) + 1e6)
    meas = measure(tmp_path)
    kept = np.array(steps[6:])  # 103 intervals: the warm-up left out is max(3, ceil(5 % of 103)) = 6
    assert meas.event_times == kept.size == 97
    assert meas.mean_ms == pytest.approx(kept.mean(), abs=1e-9)
    assert meas.p90_ms == pytest.approx(np.percentile(kept, 90), abs=1e-9)
    assert meas.median_ms == pytest.approx(10.0)
    assert 10.0 < meas.p90_ms <= 30.0  # the slow rounds count: the mean alone would hide them


def test_rule_is_the_p90_against_90_percent_of_a_period():
    meas = PaceMeasurement(mean_ms=5.0, event_times=100, p90_ms=9.0, median_ms=5.0)
    edge = MARGIN * 1000.0 / 9.0  # p90 exactly 90 % of a period: not feasible (strictly below is)
    ok, line = verdict(meas, edge * 0.999, about="m = 3")
    assert ok and line.startswith(f"pace {edge * 0.999:g}: feasible on this machine: 5 ms per event time")
    assert line.endswith("; m = 3")
    ok, line = verdict(meas, edge)
    assert not ok and "NOT feasible" in line and "capacity about 200 event times per second;" in line
    ok, line = verdict(meas, 250.0)  # capacity 200 < 250
    assert not ok and "capacity about 200 event times per second < 250" in line and "highest pace" in line
    ok, line = verdict(PaceMeasurement(mean_ms=5.0, event_times=100), 150.0)  # no p90: the mean is judged
    assert ok and "75 % used by the mean" in line
    ok, line = verdict(meas, None)
    assert ok and line.startswith("capacity on this machine:") and "about 100" in line  # 0.9 * 1000 / 9


def until_stopped_with_keep(tmp_path, example: str = "ring10_faults"):
    """``example`` paced at 2, until stopped (no run.steps), with run.keep: what a deployment looks like (a pace
    slow enough that a starved machine, two other deployments beside it, still keeps it)."""
    raw = yaml.safe_load((EXAMPLES / f"{example}.yaml").read_text())
    raw["run"] = {"pace": 2, "seed": 1, "keep": {"hours": 1, "gigabytes": 2}}
    path = tmp_path / f"{example}.yaml"
    path.write_text(yaml.safe_dump(raw))
    return path


def test_the_measuring_run_of_a_scenario_with_run_keep_is_valid(tmp_path):
    """Issue 46, finding 3: pace refused a paced scenario with run.keep (the copy has run.steps, and run.keep is
    for a run until stopped); the copy leaves run.keep out."""
    data, _ = probe_mapping(until_stopped_with_keep(tmp_path))
    assert "keep" not in data["run"] and data["run"]["steps"] == PROBE_STEPS
    sc = parse_scenario(data)
    assert sc.run.keep_hours is None and not sc.run.until_stopped


@pytest.mark.slow
def test_a_pace_no_machine_keeps_is_not_feasible(tmp_path):
    r = run("pace", scenario_file(tmp_path, "ring10"), "--pace", "100000", "--seconds", SECONDS, timeout=120)
    assert "Traceback" not in r.stderr, r.stderr
    assert r.returncode == 1, r.stdout + r.stderr
    lines = r.stdout.splitlines()
    assert len(lines) == 1, r.stdout  # no disk figure for a pace that cannot be kept
    assert lines[0].startswith("pace 100000: NOT feasible on this machine: "), lines[0]
    assert lines[0].endswith("m = 10, n = 8, q = 6"), lines[0]


@pytest.mark.slow
def test_a_modest_pace_is_feasible_faults_removed(tmp_path):
    """ring10_faults at pace 2 (500 ms a period) until stopped with run.keep: feasible; the measuring run had no
    fault, no pace, no run.keep, and left no process behind; the disk line says what run.keep keeps."""
    scen = until_stopped_with_keep(tmp_path)  # --pace defaults to run.pace
    out = tmp_path / "out"
    r = run("pace", scen, "--seconds", SECONDS, "--out", out, timeout=120)
    assert "Traceback" not in r.stderr, r.stderr
    assert r.returncode == 0, r.stdout + r.stderr
    lines = r.stdout.splitlines()
    assert len(lines) == 2 and lines[0].startswith("pace 2: feasible on this machine: "), r.stdout
    ms = float(lines[0].split(": ")[2].split(" ms per event time")[0])
    assert 0 < ms < MARGIN * 500, lines[0]
    # the records' growth, measured: bytes of chunks and recording per hour at the pace, the state panels every one
    assert lines[1].startswith("disk: about ") and " GB per hour at pace 2 (" in lines[1], lines[1]
    assert float(lines[1].split("disk: about ")[1].split(" GB")[0]) > 0 and "every 1 event time;" in lines[1]
    assert "; run.keep.hours 1: about " in lines[1] and "; run.keep.gigabytes 2: reached after about " in lines[1]
    copy = yaml.safe_load((out / "scenario.yaml").read_text())
    assert copy["run"]["record_every"] == 1 and "keep" not in copy["run"]
    assert copy["faults"] == [] and "pace" not in copy["run"] and copy["run"]["steps"] == PROBE_STEPS
    names = {e["event"] for e in events(out)}
    assert "run_started" in names and not names & {"agent_lost", "arc_dropped", "agent_restarting"}, names
    assert_all_gone(all_pids(out))
