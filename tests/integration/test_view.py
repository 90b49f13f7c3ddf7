"""`splitspec view OUT` without a display: the web viewer on loopback, stopped by Ctrl-C with nothing left."""

from __future__ import annotations

import re
import signal
import subprocess
import time
import urllib.parse
import urllib.request
from pathlib import Path

import pytest

from tests.integration.runtime_helpers import ENV, EXAMPLES, ROOT, assert_all_gone, cli, dump, free_port, run

pytestmark = pytest.mark.slow

NO_DISPLAY = {k: v for k, v in ENV.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}


@pytest.fixture(scope="module")
def recorded(tmp_path_factory) -> Path:
    """A real run's output directory (the paper's discrete example, about 7 s)."""
    out = tmp_path_factory.mktemp("view") / "run"
    r = run("run", EXAMPLES / "paper_discrete.yaml", "--out", out)
    assert r.returncode == 0, r.stderr[-4000:]
    assert (out / "run.rrd").is_file()
    return out


def start_view(*args, log: Path) -> subprocess.Popen:
    f = open(log, "wb")
    return subprocess.Popen(cli("view", *args), cwd=ROOT, env=NO_DISPLAY, stdout=f, stderr=subprocess.STDOUT,
                            start_new_session=True)


def wait_for_url(proc: subprocess.Popen, log: Path, timeout: float = 60.0) -> str:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        m = re.search(r"open (http://\S+)", log.read_text(errors="replace"))
        if m:
            return m.group(1)
        assert proc.poll() is None, f"view exited with {proc.returncode}\n{dump(log)}"
        time.sleep(0.1)
    raise AssertionError(f"no URL printed within {timeout} s\n{dump(log)}")


def children(pid: int) -> list:
    """Every descendant pid of ``pid`` (from /proc)."""
    out = subprocess.run(["ps", "-e", "-o", "pid=,ppid="], capture_output=True, text=True).stdout.split()
    parent = dict(zip(map(int, out[::2]), map(int, out[1::2])))
    found, frontier = [], [pid]
    while frontier:
        p = frontier.pop()
        kids = [c for c, pp in parent.items() if pp == p]
        found += kids
        frontier += kids
    return found


def test_view_serves_the_web_viewer_and_stops_on_sigint(recorded, tmp_path):
    port = free_port()
    log = tmp_path / "view.log"
    proc = start_view(recorded, "--port", port, log=log)
    try:
        url = wait_for_url(proc, log)
        viewer = children(proc.pid)
        assert viewer, f"no viewer process\n{dump(log)}"
        lines = [line for line in log.read_text().splitlines() if line.strip()]
        assert len(lines) == 1 and "ssh -L" in lines[0], dump(log)
        parts = urllib.parse.urlsplit(url)
        assert parts.hostname == "127.0.0.1" and parts.port == port
        proxy = urllib.parse.parse_qs(parts.query)["url"][0]
        assert re.fullmatch(r"rerun\+http://127\.0\.0\.1:\d+/proxy", proxy), proxy
        with urllib.request.urlopen(url, timeout=10) as resp:
            assert resp.status == 200
            page = resp.read().decode()
        assert "re_viewer.js" in page and "the_canvas_id" in page
        with urllib.request.urlopen(f"http://127.0.0.1:{port}/re_viewer_bg.wasm", timeout=10) as resp:
            assert resp.status == 200 and resp.headers["Content-Type"] == "application/wasm"
        proc.send_signal(signal.SIGINT)
        assert proc.wait(timeout=15) == 0, dump(log)
        assert_all_gone(viewer)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()


def test_view_dies_with_its_viewer_when_killed(recorded, tmp_path):
    """SIGKILL leaves no handler to run: the viewer still goes (PR_SET_PDEATHSIG)."""
    log = tmp_path / "view.log"
    proc = start_view(recorded, log=log)
    try:
        wait_for_url(proc, log)
        viewer = children(proc.pid)
        assert viewer
        proc.kill()
        proc.wait()
        assert_all_gone(viewer)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()


@pytest.mark.parametrize("case", ["missing", "file", "no_recording", "bad_port"])
def test_view_bad_input_is_one_line_and_exit_2(recorded, tmp_path, case):
    empty = tmp_path / "empty"
    empty.mkdir()
    args = {"missing": [tmp_path / "nope"], "file": [recorded / "run.rrd"], "no_recording": [empty],
            "bad_port": [recorded, "--port", "70000"]}[case]
    r = subprocess.run(cli("view", *args), cwd=ROOT, env=NO_DISPLAY, capture_output=True, text=True, timeout=60)
    assert r.returncode == 2, r.stderr
    assert r.stdout == ""
    lines = r.stderr.splitlines()
    assert len(lines) == 1 and lines[0].startswith("splitspec: error: "), r.stderr
