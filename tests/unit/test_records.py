"""Records that never contradict each other: growth, write failures on real tmpfs mounts, --out checks, recovery."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pytest

from splitspec_orchestrator.cli import main
from splitspec_orchestrator.records.outdir import RESERVE_FILE, OutputDirError, check_output_dir
from splitspec_orchestrator.records.recorder import Recorder, RecordsWriteError
from splitspec_orchestrator.records.recover import recover
from splitspec_core.errors import SplitspecError
from tests.rrd_readback import read_rrd, read_rrd_logs, verify_rrd

os.environ.setdefault("RERUN_ANALYTICS", "0")

IDS = (1, 2, 5)
M, N = 3, 4
GRAPHS = ("ring", "complete")
ROOT = os.name == "posix" and os.geteuid() == 0


def recorder(out: Path, *, steps: int = 50, flush_seconds: float = 0.0, **kw) -> Recorder:
    return Recorder(out, agent_ids=IDS, n=N, steps=steps, time_mode="discrete", dt=1.0, graph_names=GRAPHS,
                    run_id="records", scenario_name="records", flush_seconds=flush_seconds, **kw)


def put_row(rec: Recorder, tau: int) -> None:
    rng = np.random.default_rng(tau)
    rec.row(tau, rng.normal(size=N), rng.normal(size=(M, N)), np.ones(M, dtype=bool), 0)


def events_of(out: Path) -> list[dict]:
    return [json.loads(line) for line in (out / "events.jsonl").read_text().splitlines()]


def npz_rows(out: Path) -> int:
    with np.load(out / "trajectory.npz") as f:
        return int(f["t"].shape[0])


def rrd_taus(out: Path) -> list[int]:
    return [tau for tau, _ in read_rrd(out / "run.rrd").get("errors/max", [])]


def assert_records_agree(out: Path, K: int) -> None:
    """trajectory.npz holds K rows, run.rrd verifies and holds event times 0..K-1, events.jsonl ends saying K."""
    assert npz_rows(out) == K
    ok, msg = verify_rrd(out / "run.rrd")
    assert ok, msg
    assert rrd_taus(out) == list(range(K))
    for entity, series in read_rrd(out / "run.rrd").items():
        assert all(tau < K for tau, _ in series), entity
    assert events_of(out)[-1]["rows"] == K


def _mount(path: Path, size: str, *opts: str) -> None:
    subprocess.run(["mount", "-t", "tmpfs", "-o", ",".join([f"size={size}", *opts]), "tmpfs", str(path)],
                   check=True, capture_output=True)


def _remount(path: Path, mode: str) -> None:
    subprocess.run(["mount", "-o", f"remount,{mode}", str(path)], check=True, capture_output=True)


@pytest.fixture
def tmpfs(tmp_path):
    """``tmpfs(size, ro=False)``: a fresh tmpfs mounted under tmp_path (unmounted at teardown)."""
    if not ROOT:
        pytest.skip("mounting a tmpfs needs root")
    mounted: list[Path] = []

    def mount(size: str = "2m", *, ro: bool = False) -> Path:
        mnt = tmp_path / f"mnt{len(mounted)}"
        mnt.mkdir()
        _mount(mnt, size, *(["ro"] if ro else []))
        mounted.append(mnt)
        return mnt

    try:
        yield mount
    finally:
        for mnt in reversed(mounted):
            subprocess.run(["umount", str(mnt)], capture_output=True)
            if os.path.ismount(mnt):
                subprocess.run(["umount", "-l", str(mnt)], capture_output=True)


# ---------------------------------------------------------------------- growth


def test_huge_steps_hint_allocates_little(tmp_path):
    rec = recorder(tmp_path, steps=10**9, flush_seconds=3600.0)
    try:
        S = rec._s  # the recorder's RowStore
        arrays = [S.t, S.x, S.xhat, S.alive, S.graph, S.tau, S.wall, S.shown, S.shown_max, S.g, S.round, S.env_c, S.env_t0]
        assert all(a.shape[0] <= 1024 for a in arrays)
        assert sum(a.nbytes for a in arrays) < 1 << 20
        cap = S.t.shape[0]
        for tau in range(cap + 1):  # one row more than the capacity: storage doubles
            put_row(rec, tau)
        assert S.t.shape[0] == 2 * cap and S.xhat.shape == (2 * cap, M, N)
    finally:
        rec.close()
    assert npz_rows(tmp_path) == cap + 1


def test_background_thread_grows_the_row_storage_ahead_of_the_caller(tmp_path):
    """Fresh memory is slow to touch: the background thread doubles the storage once it is 3/4 full, so the
    round loop's row() does not pay for it (it still can, when rows outrun the flush period)."""
    rec = recorder(tmp_path, steps=10, flush_seconds=0.05)
    try:
        cap = rec._s.capacity
        for tau in range(cap * 3 // 4 + 1):
            put_row(rec, tau)
        deadline = time.monotonic() + 10.0
        while rec._s.capacity == cap and time.monotonic() < deadline:
            time.sleep(0.02)
        assert rec._s.capacity == 2 * cap
        for tau in range(cap * 3 // 4 + 1, cap + 1):
            put_row(rec, tau)
        assert rec._s.capacity == 2 * cap  # no growth in row()
    finally:
        rec.close()
    assert npz_rows(tmp_path) == cap + 1 and rrd_taus(tmp_path) == list(range(cap + 1))


# ---------------------------------------------------------------------- write failures


def test_enospc_mid_recording_keeps_every_row_recorded(tmpfs):
    """Rows whose data exceed a 2 MiB tmpfs: RecordsWriteError, then close(finished=False) keeps them all."""
    out = tmpfs("2m") / "run"
    rec = recorder(out)
    rec.event("run_started", 0.0)
    assert (out / RESERVE_FILE).exists()
    with pytest.raises(RecordsWriteError) as info:
        for tau in range(100_000):
            put_row(rec, tau)
            if tau % 10 == 0:
                rec.event("tick", float(tau), note="x" * 200)
    err = info.value
    assert isinstance(err, SplitspecError) and isinstance(err, RuntimeError)
    assert err.strerror == "No space left on device"
    assert err.path.parent == out and err.path.name in ("run.rrd", "trajectory.npz", "events.jsonl")
    assert str(err) == f"cannot write {err.path}: No space left on device"
    assert "\n" not in str(err)
    assert err.tau is not None and 0 < err.tau < 100_000
    rows = rec.rows_recorded
    with pytest.raises(RecordsWriteError):  # the recording has stopped
        put_row(rec, rows)
    with pytest.raises(RecordsWriteError):
        rec.flush()
    rec.close(finished=False)  # does not raise
    rec.close(finished=False)
    assert rec.rows_kept == rows  # records up to the failing row kept (the reserve made room)
    assert_records_agree(out, rows)
    last = events_of(out)[-1]
    assert last["event"] == "recording_closed" and last["finished"] is False
    assert "No space left on device" in last["error"]
    assert not (out / RESERVE_FILE).exists()
    assert not [p.name for p in out.iterdir() if p.name.startswith(".")]  # no temporary file left


def free_bytes(p):
    st = os.statvfs(p)
    return st.f_bavail * st.f_frsize


@pytest.mark.parametrize("left", [0.0, 0.05, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.8, 1.0, 1.3])
def test_close_on_a_disk_fuller_than_the_reserve(tmpfs, left):
    """No reserve left and only ``left`` x (rrd + npz size) free at close: the rrd rewrite and the trajectory cut
    compete for the room (CI once kept a 371-row trajectory beside a 334-row rrd); the three records still agree."""
    mnt = tmpfs("8m")
    out = mnt / "run"
    rec = recorder(out, reserve_bytes=0, steps=400, flush_seconds=3600.0)
    rec.event("run_started", 0.0)
    for tau in range(300):
        put_row(rec, tau)
    rec.flush()
    with open(mnt / "filler", "wb") as f:
        try:
            f.write(b"\0" * free_bytes(mnt))
        except OSError:
            pass
    with pytest.raises(RecordsWriteError):
        for tau in range(300, 100_000):
            put_row(rec, tau)
            if tau % 20 == 0:
                rec.flush()
    size = (out / "run.rrd").stat().st_size + (out / "trajectory.npz").stat().st_size
    os.truncate(mnt / "filler", max(0, (mnt / "filler").stat().st_size - int(left * size)))
    rec.close(finished=False)
    K = rec.rows_kept
    assert 0 < K <= rec.rows_recorded
    assert_records_agree(out, K)


def test_read_only_from_the_start_is_one_line(tmpfs):
    mnt = tmpfs("1m", ro=True)
    with pytest.raises(RecordsWriteError) as info:
        recorder(mnt)
    assert str(info.value) == f"cannot write {mnt / 'events.jsonl'}: Read-only file system"
    assert info.value.strerror == "Read-only file system"


@pytest.mark.filterwarnings("ignore:RRD file has no footer")
def test_remounted_read_only_mid_run(tmpfs):
    """EROFS mid-run: the records on disk are those of the last flush and agree; recover finishes run.rrd."""
    mnt = tmpfs("8m")
    out = mnt / "run"
    rec = recorder(out, flush_seconds=3600.0)
    rec.event("run_started", 0.0)
    for tau in range(30):
        put_row(rec, tau)
    rec.flush()
    for tau in range(30, 40):  # buffered, never written
        put_row(rec, tau)
    _remount(mnt, "ro")  # possible: the recorder keeps no file open between calls
    try:
        with pytest.raises(RecordsWriteError) as info:
            rec.flush()
        assert str(info.value) == f"cannot write {out / 'run.rrd'}: Read-only file system"
        assert info.value.tau == 39
        rec.close(finished=False)  # does not raise
        assert rec.rows_kept == 30
        assert npz_rows(out) == 30
        assert rrd_taus(out) == list(range(30))  # footer-less, but holds exactly the kept rows
        assert events_of(out)[-1]["event"] == "run_started"  # recording_closed could not be written
    finally:
        _remount(mnt, "rw")
    result = recover(out)
    assert result["rows"] == 30 and result["rrd"] == "rewritten" and result["rrd_verified"]
    assert_records_agree(out, 30)
    assert events_of(out)[-1]["event"] == "records_recovered"


def test_normal_close_keeps_all_rows_and_verifies(tmp_path):
    rec = recorder(tmp_path, flush_seconds=3600.0)
    for tau in range(12):
        put_row(rec, tau)
    rec.close()
    assert rec.rows_kept == rec.rows_recorded == 12
    assert_records_agree(tmp_path, 12)
    assert events_of(tmp_path)[-1] == {**events_of(tmp_path)[-1], "event": "recording_closed", "finished": True}
    assert not (tmp_path / RESERVE_FILE).exists()
    assert recover(tmp_path)["changed"] is False  # records that agree are left alone


# ---------------------------------------------------------------------- --out checks


def test_check_output_dir_empty():
    with pytest.raises(OutputDirError, match=r"^--out must name a directory$"):
        check_output_dir("")


def test_check_output_dir_file(tmp_path):
    f = tmp_path / "file"
    f.write_text("x")
    with pytest.raises(OutputDirError) as info:
        check_output_dir(f)
    assert str(info.value) == f"cannot write to output directory {f}: Not a directory"
    assert isinstance(info.value, ValueError) and isinstance(info.value, SplitspecError)


def test_check_output_dir_creates_and_probes(tmp_path):
    out = check_output_dir(tmp_path / "a" / "b")
    assert out.is_dir() and list(out.iterdir()) == []


def test_check_output_dir_read_only(tmpfs, capsys):
    mnt = tmpfs("1m", ro=True)
    for target in (mnt, mnt / "sub"):
        with pytest.raises(OutputDirError) as info:
            check_output_dir(target)
        assert str(info.value) == f"cannot write to output directory {target}: Read-only file system"
    # The CLI: one line, exit 2, before any process starts.
    scenario = Path(__file__).parents[2] / "examples" / "paper_discrete.yaml"
    assert main(["run", str(scenario), "--out", str(mnt / "run")]) == 2
    captured = capsys.readouterr()
    assert captured.err.splitlines() == [
        f"splitspec: error: cannot write to output directory {mnt / 'run'}: Read-only file system"]


def test_check_output_dir_full(tmpfs):
    mnt = tmpfs("64k")
    fd = os.open(mnt / "filler", os.O_WRONLY | os.O_CREAT)
    try:
        while os.write(fd, b"\0" * 4096):
            pass
    except OSError:  # No space left on device: the mount is full
        pass
    finally:
        os.close(fd)
    with pytest.raises(OutputDirError, match=r"^cannot write to output directory .*: No space left on device$"):
        check_output_dir(mnt)


# ---------------------------------------------------------------------- recovery after SIGKILL


_KILLED_WRITER = textwrap.dedent("""
    import os, signal, sys, time
    import numpy as np
    sys.path.insert(0, {tests!r})
    from test_records import recorder, put_row
    from pathlib import Path
    rec = recorder(Path({out!r}), flush_seconds=0.05)
    rec.event("run_started", 0.0)
    rec.topology(0, "ring", (1, 2, 5), [(1, 2), (2, 5), (5, 1)])
    for tau in range(400):
        put_row(rec, tau)
        if tau == 40:
            rec.event("graph_switched", 40.0, graph="complete")
            rec.topology(40, "complete", (1, 2, 5), [(1, 2), (2, 1)])
        if tau % 25 == 0:
            rec.flush()
        time.sleep(0.001)
    with open(Path({out!r}) / "events.jsonl", "a") as f:
        f.write('{{"event": "torn')  # a line the kill cut short
    os.kill(os.getpid(), signal.SIGKILL)
""")


@pytest.mark.filterwarnings("ignore:RRD file has no footer")
def test_recover_after_sigkill(tmp_path):
    out = tmp_path / "run"
    script = _KILLED_WRITER.format(tests=str(Path(__file__).parent), out=str(out))
    proc = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120,
                          env={**os.environ, "RERUN_ANALYTICS": "0"})
    assert proc.returncode == -signal.SIGKILL, proc.stdout + proc.stderr
    ok, _ = verify_rrd(out / "run.rrd")
    assert not ok  # before: no footer
    from splitspec_core.simulation.trajectory_chunks import read_chunks

    K0 = npz_rows(out)
    K = len(read_chunks(out)["tau"])  # the chunks, appended at every flush: at least trajectory.npz's rows
    assert K >= K0 > 0
    taus = rrd_taus(out)
    assert taus[:K] == list(range(K)) and len(taus) >= K  # run.rrd is never behind the chunks
    assert len(taus) - K <= 400 - K  # and at most the unflushed rows ahead

    result = recover(out)
    assert result["rows"] == K and result["rrd"] == "rewritten" and result["rrd_verified"]
    assert result["events_torn_line_dropped"] and result["changed"]
    assert result["message"] == (f"recovered {out}: {K} event times kept in trajectory.npz, events.jsonl and "
                                 f"run.rrd (run.rrd rewritten, verified, torn last line of events.jsonl dropped)")
    assert_records_agree(out, K)
    events = events_of(out)
    assert events[-1]["event"] == "records_recovered" and events[-1]["rows"] == K
    assert not (out / RESERVE_FILE).exists()
    logs = read_rrd_logs(out / "run.rrd")
    assert [tau for tau, _, _ in logs["topology"]] == ([0, 40] if K >= 40 else [0])
    assert all(tau <= K for tau, _, _ in logs["events"])

    before = {name: (out / name).read_bytes() for name in ("trajectory.npz", "events.jsonl", "run.rrd")}
    again = recover(out)  # idempotent
    assert again["rows"] == K and again["changed"] is False and again["rrd"] == "kept"
    assert {name: (out / name).read_bytes() for name in before} == before


@pytest.mark.filterwarnings("ignore:RRD file has no footer")
@pytest.mark.parametrize("steps", [400, None])
def test_recover_makes_the_trajectory_a_run_of_steps_was_killed_before_writing(tmp_path, steps):
    """make test, 2026-11-30, on a busy machine: the orchestrator of a run of run.steps SIGKILLed once the chunks held
    10 rows, before its first rewrite of trajectory.npz; the recovery left none.  It now makes it from the chunks,
    for a run of run.steps (run_started names its steps), and never for a run until stopped (steps: null)."""
    from splitspec_core.simulation.trajectory_chunks import read_chunks

    out = tmp_path / "run"
    script = _KILLED_WRITER.format(tests=str(Path(__file__).parent), out=str(out))
    proc = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120,
                          env={**os.environ, "RERUN_ANALYTICS": "0"})
    assert proc.returncode == -signal.SIGKILL, proc.stdout + proc.stderr
    (out / "trajectory.npz").unlink()  # as if killed before its first rewrite
    lines = (out / "events.jsonl").read_text().splitlines(keepends=True)
    k = next(i for i, line in enumerate(lines) if '"run_started"' in line)
    lines[k] = json.dumps({**json.loads(lines[k]), "steps": steps}) + "\n"
    (out / "events.jsonl").write_text("".join(lines))
    K = len(read_chunks(out)["tau"])
    result = recover(out)
    assert result["rows"] == K and result["rrd_verified"]
    if steps is None:
        assert not (out / "trajectory.npz").exists()
        assert "kept in chunks/, events.jsonl and run.rrd" in result["message"]
    else:
        assert npz_rows(out) == K and "kept in trajectory.npz, events.jsonl and run.rrd" in result["message"]
        assert_records_agree(out, K)


def test_recover_cli(tmp_path, capsys):
    rec = recorder(tmp_path / "run", flush_seconds=3600.0)
    for tau in range(5):
        put_row(rec, tau)
    rec.close()
    assert main(["recover", str(tmp_path / "run")]) == 0
    out = capsys.readouterr().out.strip().splitlines()
    assert out == [f"recovered {tmp_path / 'run'}: 5 event times kept in trajectory.npz, events.jsonl and "
                   "run.rrd (nothing to change)"]
    assert main(["recover", str(tmp_path / "nothing")]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"splitspec: error: {tmp_path / 'nothing'} is not a directory"]


def test_background_flush_failure_is_raised_by_the_next_call(tmpfs):
    """The background flusher hits ENOSPC: stored, raised by the next call; close keeps every row."""
    mnt = tmpfs("2m")
    out = mnt / "run"
    rec = recorder(out, flush_seconds=0.2)
    for tau in range(20):
        put_row(rec, tau)
    rec.flush()
    fd = os.open(mnt / "filler", os.O_WRONLY | os.O_CREAT)  # fill what the reserve left
    try:
        while os.write(fd, b"\0" * 4096):
            pass
    except OSError:
        pass
    finally:
        os.close(fd)
    for tau in range(20, 60):  # buffered: the background flusher writes them
        put_row(rec, tau)
    deadline = time.monotonic() + 10.0
    while rec._failure is None and time.monotonic() < deadline:
        time.sleep(0.05)
    with pytest.raises(RecordsWriteError, match="No space left on device") as info:
        rec.event("later", 60.0)
    assert info.value.tau == 59
    rec.close(finished=False)
    assert rec.rows_kept == 60
    assert_records_agree(out, 60)


def test_normal_exit_without_close_leaves_a_verifiable_rrd(tmp_path):
    script = textwrap.dedent(f"""
        import sys
        sys.path.insert(0, {str(Path(__file__).parent)!r})
        from test_records import recorder, put_row
        from pathlib import Path
        rec = recorder(Path({str(tmp_path)!r}), flush_seconds=3600.0)
        for tau in range(7):
            put_row(rec, tau)
    """)
    proc = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=60,
                          env={**os.environ, "RERUN_ANALYTICS": "0"})
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert npz_rows(tmp_path) == 7
    ok, msg = verify_rrd(tmp_path / "run.rrd")
    assert ok, msg
    assert rrd_taus(tmp_path) == list(range(7))
    assert not (tmp_path / RESERVE_FILE).exists()
