"""The agent fork server (splitspec_agents.forkserver) and the orchestrator's handle on it (splitspec_orchestrator.forks):
real processes.  A forked agent is a process of its own, a child of the server, named after its agent, whose exit
status reaches the orchestrator as a spawned process's would; closing the server ends the agents it forked."""

from __future__ import annotations

import os
import signal
import socket
import sys
import time

import pytest

from splitspec_core.runtime.bus import CHILD_ENV
from splitspec_orchestrator.forks import ForkServer
from splitspec_orchestrator.registry import pid_running

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="the fork server runs on Linux")


def closed_endpoint() -> str:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return f"tcp/127.0.0.1:{s.getsockname()[1]}"  # nothing listens once the socket is closed


def agent_args(ident: int, wait: float = 60) -> list:
    return ["--id", str(ident), "--connect", closed_endpoint(), "--run-id", "forks-test", "--wait", str(wait)]


@pytest.fixture
def server():
    env = {k: v for k, v in os.environ.items() if k != CHILD_ENV}
    srv = ForkServer(env=env, run_id="forks-test")
    yield srv
    srv.close(grace=5.0)


@pytest.fixture
def patient_server():
    """As the orchestrator starts it: its agents are the orchestrator's children (CHILD_ENV), which wait for
    their router patiently (here: for 60 s, with nothing listening)."""
    srv = ForkServer(env={**os.environ, CHILD_ENV: "1"}, run_id="forks-test")
    yield srv
    srv.close(grace=5.0)


def ppid_of(pid: int) -> int:
    with open(f"/proc/{pid}/stat") as f:
        return int(f.read().rsplit(")", 1)[1].split()[1])


def test_a_forked_agent_is_its_own_named_process_and_its_kill_is_reported(patient_server):
    p = patient_server.spawn(agent_args(7))
    assert p.pid != patient_server.proc.pid and ppid_of(p.pid) == patient_server.proc.pid
    deadline, comm = time.monotonic() + 10, None
    while comm != "agent 7" and time.monotonic() < deadline:  # the fork names itself as it starts
        with open(f"/proc/{p.pid}/comm") as f:
            comm = f.read().strip()
        time.sleep(0.02)
    assert comm == "agent 7"  # ps and top show which agent (the command line is the server's)
    assert p.poll() is None
    p.kill()
    assert p.wait(timeout=10) == -signal.SIGKILL  # Popen's convention, from the server that reaped it


def test_a_forked_agent_exits_with_its_own_status(server):
    """Started by hand (no CHILD_ENV), an agent with nothing at its endpoint gives up and exits 1; bad
    arguments exit 2: the agent's own command line, run in the fork, and its status reaches the handle."""
    p = server.spawn(agent_args(3, wait=5))
    assert p.wait(timeout=30) == 1
    bad = server.spawn(["--id", "three"])
    assert bad.wait(timeout=30) == 2


def test_closing_the_server_ends_the_agents_it_forked(patient_server):
    ps = [patient_server.spawn(agent_args(i)) for i in (1, 2)]
    assert all(p.poll() is None for p in ps)
    patient_server.close(grace=5.0)
    deadline = time.monotonic() + 10
    while any(pid_running(p.pid) for p in ps) and time.monotonic() < deadline:
        time.sleep(0.05)
    assert not any(pid_running(p.pid) for p in ps)
    assert all(p.poll() is not None for p in ps)  # and the handles say so


def test_a_malformed_request_stops_the_server_in_one_line(tmp_path):
    """Only the orchestrator writes to the server, but what is not ``{"argv": [...]}`` ends it with one line and
    status 2: no traceback, no fork (the orchestrator then starts its agents as new processes)."""
    import subprocess

    err = tmp_path / "stderr"
    req_r, req_w = os.pipe()
    rep_r, rep_w = os.pipe()
    with open(err, "wb") as f:
        p = subprocess.Popen([sys.executable, "-m", "splitspec_agents.forkserver", "--requests", str(req_r),
                              "--replies", str(rep_w)], pass_fds=(req_r, rep_w), stderr=f)
    os.close(req_r)
    os.close(rep_w)
    try:
        with os.fdopen(rep_r, "rb") as replies:
            assert b'"ready"' in replies.readline()  # imports done: now the request
            os.write(req_w, b'{"args": ["--id", "1"]}\n')
            assert p.wait(timeout=30) == 2
            assert replies.read() == b""  # no {"pid": ...}: nothing was forked
    finally:
        os.close(req_w)
        if p.poll() is None:
            p.kill()
    lines = err.read_text().splitlines()
    assert lines == ['splitspec_agents.forkserver: error: a request is not {"argv": [...]}; stopping'], lines


def test_a_server_started_on_bad_descriptors_says_so_in_one_line():
    import subprocess

    r = subprocess.run([sys.executable, "-m", "splitspec_agents.forkserver", "--requests", "999", "--replies", "998"],
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == 2
    assert r.stderr.splitlines() == ["splitspec_agents.forkserver: error: Bad file descriptor (--requests 999, "
                                     "--replies 998)"], r.stderr
