"""Helpers for multi-process tests: start splitspec processes, read their records, check nothing is left."""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import yaml

from splitspec_core.model.rows import REPORTED, present

ROOT = Path(__file__).resolve().parents[2]
EXAMPLES = ROOT / "examples"
ENV = {**os.environ, "RERUN_ANALYTICS": "0", "PYTHONUNBUFFERED": "1"}


def scenario_file(tmp_path: Path, example: str, **changes) -> Path:
    """A copy of an example with some sections changed (e.g. ``run={"steps": 60, "pace": 25}``)."""
    raw = yaml.safe_load((EXAMPLES / f"{example}.yaml").read_text())
    for section, values in changes.items():
        raw.setdefault(section, {}).update(values)
    path = tmp_path / f"{example}.yaml"
    path.write_text(yaml.safe_dump(raw))
    return path


def endless(tmp_path: Path, example: str, pace: float, *, faults: bool = False) -> Path:
    """A copy of an example paced at ``pace``, without run.steps (and without its faults unless ``faults``): it runs
    until stopped.  A test that waits for something (a kill, a rejoin, a late process) runs until it has seen it and
    then stops the run (:func:`stopped`): a run of run.steps at a pace ends on the wall clock, and on a starved
    machine before a cold-started process (`splitspec kill`, a hand-started agent) has done its part."""
    raw = yaml.safe_load((EXAMPLES / f"{example}.yaml").read_text())
    raw["run"] = {"pace": pace, "seed": (raw.get("run") or {}).get("seed", 0)}
    if not faults:
        raw.pop("faults", None)
    path = tmp_path / f"{example}_endless.yaml"
    path.write_text(yaml.safe_dump(raw))
    return path


def stop_run(p: subprocess.Popen, log: Path, timeout: float = 120.0) -> None:
    """Stop a run until stopped as Ctrl-C does (the terminal signals the whole process group); it must end with
    exit 0 (its records written, its processes stopped)."""
    os.killpg(p.pid, signal.SIGINT)
    try:
        code = p.wait(timeout=timeout)
    finally:
        if p.poll() is None:
            os.killpg(p.pid, signal.SIGKILL)
    assert code == 0, dump(log)


def recorded(out: Path) -> dict:
    """A run's rows as ``trajectory.npz``'s arrays (``t``, ``x``, ``xhat``, ``alive``, ``agent_ids``, ...): that
    file's, or a run until stopped's chunks."""
    from splitspec_core.simulation.trajectory_chunks import read_chunks

    if (out / "trajectory.npz").exists():
        with np.load(out / "trajectory.npz") as z:
            return {k: z[k] for k in z.files}
    rows = read_chunks(out)
    assert rows is not None, f"{out} has neither trajectory.npz nor chunks"
    return rows


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def wait_for_listener(endpoint: str, timeout: float = 60.0) -> None:
    """Until something accepts TCP connections at ``tcp/HOST:PORT`` (a router is up): hand-started processes give
    the router only a short budget (``splitspec_core.runtime.node.CONNECT_BUDGET``) to be reachable."""
    host, _, port = endpoint.removeprefix("tcp/").rpartition(":")
    deadline = time.monotonic() + timeout
    while True:
        try:
            with socket.create_connection((host, int(port)), timeout=1.0):
                return
        except OSError:
            if time.monotonic() > deadline:
                raise AssertionError(f"nothing listens at {endpoint} after {timeout} s") from None
            time.sleep(0.05)


def cli(*args) -> list:
    return [sys.executable, "-m", "splitspec_orchestrator", *map(str, args)]


def start(*args, log: Path, env_extra: dict | None = None, **kw) -> subprocess.Popen:
    """Start ``splitspec ARGS`` in its own process group, output to ``log``."""
    f = open(log, "wb")
    return subprocess.Popen(cli(*args), cwd=ROOT, env={**ENV, **(env_extra or {})}, stdout=f,
                            stderr=subprocess.STDOUT, start_new_session=True, **kw)


def run(*args, timeout=180, **kw) -> subprocess.CompletedProcess:
    return subprocess.run(cli(*args), cwd=ROOT, env=ENV, capture_output=True, text=True, timeout=timeout, **kw)


def events(out: Path) -> list:
    """The run's events so far: every whole line of its events.jsonl (a line the orchestrator is still writing, with
    no newline yet, is left for the next read: read while running, the file can end mid-line)."""
    p = out / "events.jsonl"
    if not p.exists():
        return []
    text = p.read_text()
    whole = text if text.endswith("\n") else text[:text.rfind("\n") + 1]
    return [json.loads(line) for line in whole.splitlines() if line.strip()]


def wait_for_event(out: Path, name: str, timeout: float = 60.0, **where) -> dict:
    """First ``name`` event (with the given field values, e.g. ``id=3``) in ``events.jsonl``."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        for e in events(out):
            if e["event"] == name and all(e.get(k) == v for k, v in where.items()):
                return e
        time.sleep(0.05)
    raise AssertionError(f"no {name} event in {out}/events.jsonl within {timeout} s: {events(out)}")


def wait_for_rows(out: Path, rows: int, timeout: float = 60.0) -> None:
    """Until the records hold at least ``rows`` event times: ``trajectory.npz`` (written incrementally), or for a
    run until stopped its chunks (the last segment's last event time)."""
    from splitspec_core.simulation.trajectory_chunks import chunk_segments, segment_last_tau

    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        try:
            with np.load(out / "trajectory.npz") as f:
                if f["t"].shape[0] >= rows:
                    return
        except (OSError, ValueError, KeyError):
            pass  # not written yet
        try:
            segments = chunk_segments(out)
            last = segment_last_tau(segments[-1][1]) if segments else None
            if last is not None and last + 1 >= rows:
                return
        except (OSError, ValueError):
            pass
        time.sleep(0.05)
    raise AssertionError(f"fewer than {rows} rows in {out} (trajectory.npz or chunks) after {timeout} s")


def pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    # a zombie is dead for our purposes
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().split(")")[-1].split()[0] != "Z"
    except (FileNotFoundError, ProcessLookupError):  # gone between the two looks (reading its stat: ESRCH)
        return False


def started_pids(out: Path) -> dict:
    """``{(role, id): pid}`` from ``process_started`` events, plus the orchestrator and the agent fork server."""
    pids = {}
    for e in events(out):
        if e["event"] == "process_started":
            pids[(e["role"], e["id"])] = e["pid"]
        elif e["event"] == "orchestrator_started":
            pids[("orchestrator", 0)] = e["pid"]
        elif e["event"] == "fork_server_started":
            pids[("fork_server", 0)] = e["pid"]
    return pids


def assert_all_gone(pids, timeout: float = 10.0) -> None:
    deadline = time.monotonic() + timeout
    left = list(pids)
    while left and time.monotonic() < deadline:
        left = [p for p in left if pid_alive(p)]
        time.sleep(0.05)
    for p in left:  # do not leak into later tests, but fail
        try:
            os.kill(p, signal.SIGKILL)
        except ProcessLookupError:
            pass
    assert not left, f"processes still running: {left}"


def all_pids(out: Path) -> list:
    """Every pid of the run: the orchestrator, the agent fork server and every process_started (restarted agents
    included)."""
    return [e["pid"] for e in events(out) if e["event"] in ("process_started", "orchestrator_started",
                                                             "fork_server_started")]


def compare_trajectories(a_path: Path, b_path: Path, tol: float = 1e-9, *, last_ends: bool = True) -> float:
    """Assert two trajectory.npz files agree to ``tol`` (relative to the largest value); return the max diff.

    ``last_ends=False``: ``a``'s last row did not end its run (a run until stopped went on past it, exchanging its
    messages) while ``b``'s did (``simulate``'s last row is followed by no exchange): the agents' reported columns are
    compared without that row (``messages_used`` there is a count in ``a``, none in ``b``)."""
    a, b = np.load(a_path), np.load(b_path)
    # exact: flags, indices, ids, and times k * dt (one correctly rounded product in both the recorder and the
    # simulator); the estimates below, computed in other processes along other paths, only to ``tol``
    for k in ("t", "alive", "graph", "agent_ids", "lost", "lost_cause"):
        if k in a.files or k in b.files:  # lost: the same consensus messages did not count (integer rows)
            assert np.array_equal(a[k], b[k]), k
    # x: NaN where nobody knows the truth (a measurements file without it), in both
    assert np.allclose(a["x"], b["x"], rtol=0, atol=tol * max(1.0, np.nanmax(np.abs(b["x"]), initial=0.0)),
                       equal_nan=True)
    for k in ("y", "y_missing", "u"):  # the measurements and known inputs the estimators were given: exact
        if k in a.files or k in b.files:
            assert np.array_equal(a[k], b[k], equal_nan=k == "u"), k
    for k in ("residual", "disagreement", "kf", "kf_distance"):  # computed from the estimates: to ``tol``
        if k in a.files or k in b.files:
            assert np.allclose(a[k], b[k], rtol=0, atol=tol * max(1.0, float(np.nanmax(np.abs(b[k])))),
                               equal_nan=True), k
    assert np.array_equal(np.isnan(a["xhat"]), np.isnan(b["xhat"]))
    diff = float(np.nanmax(np.abs(a["xhat"] - b["xhat"]))) if np.isfinite(b["xhat"]).any() else 0.0
    assert diff <= tol * max(1.0, float(np.nanmax(np.abs(b["xhat"])))), diff
    # every column the agents report (the row schema: g (T, m), NaN where dead and in discrete time, else the
    # adaptive g_i or the fixed g; ...): the fill at the same places in both, the values to ``tol`` (integers: exact)
    for c in REPORTED:
        ga, gb = (a[c.name], b[c.name]) if last_ends else (a[c.name][:-1], b[c.name][:-1])
        assert ga.shape == gb.shape == a["alive"][:len(ga)].shape, (c.name, ga.shape, gb.shape)
        has = present(c, gb)
        assert np.array_equal(present(c, ga), has), f"{c.name} has no value at different places"
        if ga.dtype.kind != "f":
            assert np.array_equal(ga, gb), f"{c.name} differs"
        elif has.any():
            gdiff = float(np.max(np.abs(ga[has] - gb[has])))
            assert gdiff <= tol * max(1.0, float(np.max(np.abs(gb[has])))), f"{c.name} differs by {gdiff}"
    return diff


def assert_chunks_hold_the_trajectory(out: Path) -> None:
    """A run of run.steps keeps its rows twice: ``trajectory.npz`` and the append-only chunks; they must agree
    exactly (both hold the values the recorder was given, copied, never computed along another path)."""
    from splitspec_core.simulation.trajectory_chunks import read_chunks

    rows = read_chunks(out)
    assert rows is not None, f"{out} has no chunks/"
    with np.load(out / "trajectory.npz") as z:
        for k in ("t", "x", "xhat", "alive", "graph", *(c.name for c in REPORTED), "lost", "lost_cause", "agent_ids",
                  "y", "y_missing", "u"):
            if k in z.files:
                assert np.array_equal(z[k], rows[k], equal_nan=z[k].dtype.kind == "f"), k


def compare_with_simulate(out: Path, scenario: Path, tmp: Path, tol: float = 1e-9, *extra) -> float:
    """``splitspec simulate SCENARIO [EXTRA]`` must give the run's trajectory (and its chunks hold it too)."""
    sim = tmp / "sim"
    r = run("simulate", scenario, "--out", sim, "--no-plots", *extra)
    assert r.returncode == 0, r.stderr
    assert_chunks_hold_the_trajectory(out)
    return compare_trajectories(out / "trajectory.npz", sim / "trajectory.npz", tol)


def replay(out: Path, tmp: Path, tol: float = 1e-9) -> float:
    """The run's own scenario copy replayed with the faults recorded in its events.jsonl; a run until stopped's
    with the faults and the length of its records (``--faults-from OUT``), against its chunks."""
    if (out / "trajectory.npz").exists():
        return compare_with_simulate(out, out / "scenario.yaml", tmp, tol, "--faults-from", out / "events.jsonl")
    import splitspec_core as ss

    sim = tmp / "sim"
    r = run("simulate", out / "scenario.yaml", "--out", sim, "--no-plots", "--faults-from", out)
    assert r.returncode == 0, r.stderr
    ss.load_run(out).trajectory.save(tmp / "recorded.npz")
    return compare_trajectories(tmp / "recorded.npz", sim / "trajectory.npz", tol, last_ends=False)


def dump(*logs: Path) -> str:
    return "\n".join(f"--- {p.name}\n{p.read_text(errors='replace')[-4000:]}" for p in logs if p.exists())
