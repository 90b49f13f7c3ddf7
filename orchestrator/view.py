"""``splitspec view OUT``: open a saved run's recording ``OUT/run.rrd``.

With a display (``DISPLAY`` or ``WAYLAND_DISPLAY`` set) this is the native
Rerun viewer, ``rerun OUT/run.rrd``, in the foreground. Without one (an ssh
session, a container) the bundled ``rerun`` serves its web viewer on loopback:
an HTTP port for the viewer's page (wasm and js) and a gRPC port from which the
page streams the recording, both free ports unless given. One line says which
URL to open, and how to reach it from another machine over ssh; the viewer is
served until Ctrl-C (or SIGTERM), then stopped with its whole process group,
and it dies with this process if that is killed (``PR_SET_PDEATHSIG``).
"""

from __future__ import annotations

import logging
import os
import signal
import socket
import subprocess
import sys
import tempfile
import time
import urllib.error
import urllib.parse
import urllib.request
from dataclasses import dataclass
from pathlib import Path

from splitspec_core.errors import ScenarioError, SplitspecError
from splitspec_core.runtime.cli import sigterm_at_parent_death

from .launcher import free_port

log = logging.getLogger("splitspec.view")

RECORDING_NAME = "run.rrd"
LOOPBACK = "127.0.0.1"
START_TIMEOUT = 30.0  # seconds for the web viewer to answer on both ports
STOP_TIMEOUT = 5.0  # seconds between SIGTERM and SIGKILL when stopping it


class ViewError(SplitspecError, RuntimeError):
    """The viewer could not be started (not bad input: exit status 1)."""


@dataclass(frozen=True)
class WebViewer:
    """Where a served web viewer is: the page's port, the recording's gRPC port, the URL to open."""

    web_port: int
    grpc_port: int
    url: str
    pid: int


def has_display(env: dict | None = None) -> bool:
    """True if a native window can be opened: ``DISPLAY`` or ``WAYLAND_DISPLAY`` is set and not empty."""
    env = os.environ if env is None else env
    return bool(env.get("DISPLAY") or env.get("WAYLAND_DISPLAY"))


def recording_path(out) -> Path:
    """``OUT/run.rrd`` of a run's output directory, or :class:`ScenarioError` (bad input) saying what is wrong."""
    out = Path(out)
    if not out.exists():
        raise ScenarioError(f"{out} does not exist (give the --out directory of a run)")
    if not out.is_dir():
        raise ScenarioError(f"{out} is not a directory (give the --out directory of a run, not a file)")
    rrd = out / RECORDING_NAME
    from .viewer.rrd_file import rrd_segments

    if not rrd.is_file() and not rrd_segments(rrd):  # run.keep may have removed run.rrd, not its later segments
        raise ScenarioError(f"no {RECORDING_NAME} in {out} (write one with: splitspec run SCENARIO --out {out})")
    return rrd


def retention_line(out) -> str | None:
    """What ``run.keep`` removed and which span of the recording is still on disk (one line); when it removed
    nothing, why; None without ``run.keep``."""
    from splitspec_core.runs import kept_span, nothing_removed, read_events

    events = Path(out) / "events.jsonl"
    span = kept_span(read_events(events)) if events.is_file() else None
    if span is None:
        return nothing_removed(out, read_events(events)) if events.is_file() else None
    segs = [Path(p).name for p in _segments(Path(out) / RECORDING_NAME)]
    return (f"{span['text']}; the recording on disk: {', '.join(segs[:1] + (['...'] if len(segs) > 2 else []) + segs[-1:] if len(segs) > 1 else segs)}"
            + (f" (from event time {span['recording_from']})" if span.get("recording_from") is not None else ""))


def _segments(rrd: Path) -> list[str]:
    """``run.rrd`` and the segments it rolled into (``run-0001.rrd`` ..., a long run until stopped): opened together,
    one recording."""
    from .viewer.rrd_file import rrd_segments

    return [str(p) for p in rrd_segments(rrd)] or [str(rrd)]


def rerun_executable() -> str:
    """The ``rerun`` binary bundled with rerun-sdk (package ``rerun_cli``), else ``rerun`` on PATH.

    The binary itself, not the ``rerun`` console script: that script runs the binary as its own child, so
    signalling the script would leave the viewer running.
    """
    import importlib.util
    import shutil

    spec = importlib.util.find_spec("rerun_cli")
    if spec is not None and spec.origin:
        binary = Path(spec.origin).parent / "rerun"
        if binary.is_file() and os.access(binary, os.X_OK):
            return str(binary)
    found = shutil.which("rerun")
    if found is None:
        raise ViewError("the rerun viewer (from rerun-sdk) is not installed: neither rerun_cli nor rerun on PATH")
    return found


def viewer_url(web_port: int, grpc_port: int, *, host: str = LOOPBACK) -> str:
    """The page to open: the web viewer at ``web_port``, reading the recording from the gRPC proxy at ``grpc_port``."""
    proxy = f"rerun+http://{host}:{grpc_port}/proxy"
    return f"http://{host}:{web_port}/?url={urllib.parse.quote(proxy, safe='')}"


def web_viewer_command(rrd: Path, *, web_port: int, grpc_port: int) -> list:
    """``rerun --web-viewer`` serving ``rrd`` (and its rolled segments) on loopback only, at the two given ports."""
    return [rerun_executable(), "--web-viewer", "--bind", LOOPBACK, "--web-viewer-port", str(web_port),
            "--port", str(grpc_port), *_segments(rrd)]


def _answers_http(url: str) -> bool:
    try:
        with urllib.request.urlopen(url, timeout=1.0) as resp:
            return resp.status == 200
    except (urllib.error.URLError, OSError):
        return False


def _accepts_tcp(port: int) -> bool:
    try:
        with socket.create_connection((LOOPBACK, port), timeout=0.5):
            return True
    except OSError:
        return False


def stop_viewer(proc: subprocess.Popen) -> None:
    """SIGTERM to the viewer's process group, SIGKILL after :data:`STOP_TIMEOUT`; reaps it."""
    for sig in (signal.SIGTERM, signal.SIGKILL):
        try:
            os.killpg(proc.pid, sig)
        except ProcessLookupError:
            break
        try:
            proc.wait(STOP_TIMEOUT)
            break
        except subprocess.TimeoutExpired:
            continue
    proc.wait()


def _tail(stream, limit: int = 2000) -> str:
    stream.seek(0)
    text = stream.read().decode("utf-8", "replace")
    return " | ".join(line.strip() for line in text[-limit:].splitlines() if line.strip())


def start_web_viewer(rrd: Path, *, port: int | None = None, grpc_port: int | None = None,
                     timeout: float = START_TIMEOUT, log_file=None) -> tuple[subprocess.Popen, WebViewer]:
    """Start ``rerun --web-viewer`` on ``rrd`` and wait until the page and the gRPC port answer.

    Returns the process (its own process group, dying with this one) and where it serves. Raises
    :class:`ViewError` with the viewer's last output if it exits or does not answer within ``timeout``.
    """
    web_port = port or free_port()
    grpc_port = grpc_port or free_port()
    if web_port == grpc_port:
        raise ScenarioError(f"--port and --grpc-port must differ, got {web_port} for both")
    log_file = log_file if log_file is not None else tempfile.TemporaryFile()
    env = {**os.environ, "RERUN_ANALYTICS": os.environ.get("RERUN_ANALYTICS", "0")}
    proc = subprocess.Popen(web_viewer_command(rrd, web_port=web_port, grpc_port=grpc_port), env=env,
                            stdin=subprocess.DEVNULL, stdout=log_file, stderr=subprocess.STDOUT,
                            start_new_session=True, preexec_fn=sigterm_at_parent_death)
    viewer = WebViewer(web_port, grpc_port, viewer_url(web_port, grpc_port), proc.pid)
    deadline = time.monotonic() + timeout
    page = f"http://{LOOPBACK}:{web_port}/"
    while not (_answers_http(page) and _accepts_tcp(grpc_port)):
        if proc.poll() is not None or time.monotonic() > deadline:
            what = (f"exited with status {proc.returncode}" if proc.poll() is not None
                    else f"did not answer on ports {web_port} and {grpc_port} within {timeout:g} s")
            stop_viewer(proc)
            raise ViewError(f"the Rerun web viewer {what}: {_tail(log_file) or 'no output'}")
        time.sleep(0.1)
    return proc, viewer


def serve(rrd: Path, *, port: int | None = None, grpc_port: int | None = None, stream=None) -> int:
    """Serve the web viewer on ``rrd`` until SIGINT or SIGTERM (or until it exits); 0 when stopped, 1 if it died."""
    stream = sys.stdout if stream is None else stream
    # a plain flag, not a threading.Event: the handler runs in this thread, and Event.set inside Event.wait's own
    # lock (a signal arriving there) deadlocked it (a test left `splitspec view` and its viewer running at a core)
    stop: list = []
    previous = {sig: signal.signal(sig, lambda *_: stop.append(True)) for sig in (signal.SIGINT, signal.SIGTERM)}
    try:
        proc, viewer = start_web_viewer(rrd, port=port, grpc_port=grpc_port)
        try:
            host = socket.gethostname()
            print(f"splitspec: serving {rrd} in the Rerun web viewer: open {viewer.url}  (from another machine: "
                  f"ssh -L {viewer.web_port}:{LOOPBACK}:{viewer.web_port} -L {viewer.grpc_port}:{LOOPBACK}:"
                  f"{viewer.grpc_port} {host}, then open the same URL there; Ctrl-C to stop)", file=stream, flush=True)
            while not stop:
                time.sleep(0.2)
                if proc.poll() is not None:
                    print(f"splitspec: error: the Rerun web viewer exited with status {proc.returncode}",
                          file=sys.stderr)
                    return 1
            return 0
        finally:
            stop_viewer(proc)
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)


def open_native(rrd: Path) -> int:
    """``rerun rrd`` in the foreground (Ctrl-C reaches it through the terminal); its exit status."""
    proc = subprocess.Popen([rerun_executable(), *_segments(rrd)], stdin=subprocess.DEVNULL,
                            preexec_fn=sigterm_at_parent_death)
    try:
        return proc.wait()
    except KeyboardInterrupt:  # the viewer got the same SIGINT from the terminal; make sure it is gone
        proc.terminate()
        try:
            return proc.wait(STOP_TIMEOUT)
        except subprocess.TimeoutExpired:
            proc.kill()
            return proc.wait()


def view(out, *, web: bool = False, port: int | None = None, grpc_port: int | None = None) -> int:
    """Open ``OUT/run.rrd``: the native viewer with a display (unless ``web``), else serve the web viewer."""
    rrd = recording_path(out)
    line = retention_line(out)
    if line:
        print(f"splitspec: {line}", file=sys.stderr)
    if has_display() and not web and port is None and grpc_port is None:
        code = open_native(rrd)
        if code not in (0, -signal.SIGINT, -signal.SIGTERM, 130):
            print(f"splitspec: error: the native Rerun viewer exited with status {code} (no usable display? "
                  f"splitspec view {out} --web serves the web viewer instead)", file=sys.stderr)
            return 1
        return 0
    return serve(rrd, port=port, grpc_port=grpc_port)
