"""A plant or agent started by hand that cannot join says why in one line and exits within seconds.

Real processes, real Zenoh: a secure `splitspec run` (the default), then hand-started processes without
credentials, with a wrong password, with the run's credentials but an unknown run id, against an endpoint
nobody listens on; a process waiting on a router that hosts no run, which then stops; and processes
started before their orchestrator on a plain router, which must still wait for it (compose.yaml).
"""

import os
import signal
import subprocess
import time

import pytest

from splitspec_orchestrator.registry import runtime_dir
from tests.integration.runtime_helpers import (ENV, ROOT, all_pids, assert_all_gone, cli, compare_with_simulate,
                                               dump, endless, events, free_port, pid_alive, replay, run,
                                               scenario_file, start, stop_run, wait_for_event, wait_for_listener)

pytestmark = pytest.mark.slow

BAR = 5.0  # seconds: the bar for a hand-started process that cannot join, after its own start-up


def cold_start() -> float:
    """Seconds a `splitspec agent --help` takes from its start to its exit, now: the start-up (the interpreter, the
    imports) a hand-started process spends before it can try anything; on a starved machine it is seconds."""
    t0 = time.monotonic()
    subprocess.run(cli("agent", "--help"), cwd=ROOT, env=ENV, capture_output=True, timeout=120, check=True)
    return time.monotonic() - t0


def hand_started(*args) -> tuple:
    """``splitspec ARGS`` by hand: ``(exit status, stderr, seconds to exit less its start-up)`` (:func:`cold_start`
    measured just before); the process is gone after."""
    startup = cold_start()
    t0 = time.monotonic()
    p = subprocess.Popen(cli(*args), cwd=ROOT, env=ENV, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                         start_new_session=True)
    try:
        _, err = p.communicate(timeout=60)
    finally:
        if p.poll() is None:
            p.kill()
            p.communicate()
    took = time.monotonic() - t0 - startup
    assert not pid_alive(p.pid)
    return p.returncode, err, took


def one_error_line(err: str) -> str:
    """The only line on stderr, a ``splitspec: error: ...`` (no traceback, no log lines around it)."""
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("splitspec: error: "), err
    return lines[0]


@pytest.mark.long
def test_hand_started_process_that_cannot_join_exits_at_once_with_the_reason(tmp_path):
    # until stopped, once every case was tried (a run of 400 steps at pace 25 once ended first on a starved machine)
    scen = endless(tmp_path, "paper_discrete", 25)
    out = tmp_path / "out"
    rid = "hand" + os.urandom(4).hex()
    log = tmp_path / "run.log"
    p = start("run", scen, "--out", out, "--run-id", rid, log=log)  # secure: the default
    try:
        wait_for_event(out, "run_started", timeout=90)
        endpoint = next(e["endpoint"] for e in events(out) if e["event"] == "orchestrator_started")
        (creds,) = runtime_dir().glob(f"creds-{rid}-*")
        wrong = tmp_path / "wrong.cred"
        wrong.write_text("agent-3:not-the-password\n")
        nobody = f"tcp/127.0.0.1:{free_port()}"
        cases = {
            "no credentials": (["agent", "--id", 3, "--connect", endpoint, "--run-id", rid],
                               ["refused agent 3, which has no credentials", "--credentials FILE",
                                "splitspec credentials"]),
            "plant, no credentials": (["plant", "--connect", endpoint, "--run-id", rid],
                                      ["refused the plant, which has no credentials"]),
            "wrong password": (["agent", "--id", 3, "--connect", endpoint, "--run-id", rid, "--credentials", wrong],
                               ["refused user 'agent-3'", "wrong password", "splitspec credentials"]),
            "unknown run id": (["agent", "--id", 3, "--connect", endpoint, "--run-id", "rdeadbeef",
                                "--credentials", creds / "agent-3.cred"],
                               [f"no run 'rdeadbeef' on {endpoint}: this router hosts run '{rid}'", "--run-id"]),
            "unreachable": (["agent", "--id", 3, "--connect", nobody, "--run-id", rid],
                            [f"cannot reach a Zenoh router at {nobody}", "connection refused"]),
        }
        for case, (args, expected) in cases.items():
            code, err, took = hand_started(*args)
            line = one_error_line(err)
            assert code == 1, (case, code, err)
            assert all(text in line for text in expected), (case, line)
            assert took < BAR, (case, took, line)
        assert p.poll() is None, "the run ended before every case was tried"
        stop_run(p, log)
    finally:
        if p.poll() is None:
            p.send_signal(signal.SIGINT)
            p.wait(timeout=30)
    # the run was not disturbed: nothing rejected, the simulator's trajectory, nothing left
    assert not [e for e in events(out) if e["event"] == "message_rejected"]
    replay(out, tmp_path)
    assert_all_gone(all_pids(out))


def test_hand_started_agent_exits_when_the_router_goes_away_while_it_waits(tmp_path):
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    router = start("router", "--listen", endpoint, log=tmp_path / "router.log")
    agent_log = tmp_path / "agent.log"
    agent = None
    try:
        wait_for_listener(endpoint)
        agent = start("agent", "--id", 3, "--connect", endpoint, "--run-id", "rnotyet", log=agent_log)
        # it waits for an orchestrator that is not there yet, and says so
        deadline = time.monotonic() + 30
        while "waiting up to 60 s for the orchestrator of run 'rnotyet'" not in agent_log.read_text():
            assert agent.poll() is None and time.monotonic() < deadline, dump(agent_log)
            time.sleep(0.05)
        router.send_signal(signal.SIGINT)
        assert router.wait(timeout=30) == 0, dump(tmp_path / "router.log")
        t0 = time.monotonic()
        code = agent.wait(timeout=30)
        took = time.monotonic() - t0
    finally:
        for proc in (agent, router):
            if proc is not None and proc.poll() is None:
                proc.kill()
                proc.wait()
    text = agent_log.read_text()
    errors = [ln for ln in text.splitlines() if ln.startswith("splitspec: error")]
    assert code == 1 and len(errors) == 1 and "Traceback" not in text, text
    assert f"lost the Zenoh router at {endpoint} while agent 3 waited for the orchestrator of run 'rnotyet'" \
        in errors[0]
    assert took < BAR, took
    assert_all_gone([agent.pid, router.pid])


def test_processes_started_before_their_orchestrator_wait_for_it(tmp_path):
    """The compose.yaml order: a router hosting no run, the plant and agents, and only then the orchestrator."""
    scen = scenario_file(tmp_path, "paper_discrete", run={"steps": 40, "seed": 7})
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    rid = "early"
    out = tmp_path / "out"
    router = start("router", "--listen", endpoint, log=tmp_path / "router.log")
    logs = {name: tmp_path / f"{name}.log" for name in ("plant", "a1", "a2", "a3")}
    procs = {}
    try:
        wait_for_listener(endpoint)
        procs["plant"] = start("plant", "--connect", endpoint, "--run-id", rid, log=logs["plant"])
        for i in (1, 2, 3):
            procs[f"a{i}"] = start("agent", "--id", i, "--connect", endpoint, "--run-id", rid, log=logs[f"a{i}"])
        deadline = time.monotonic() + 30
        while not all("waiting up to" in logs[n].read_text() for n in procs):
            assert all(q.poll() is None for q in procs.values()) and time.monotonic() < deadline, dump(*logs.values())
            time.sleep(0.05)
        r = run("orchestrator", scen, "--connect", endpoint, "--run-id", rid, "--out", out, timeout=120)
        assert r.returncode == 0, r.stderr + dump(*logs.values())
        for name, q in procs.items():
            assert q.wait(timeout=30) == 0, dump(logs[name])
    finally:
        for q in [*procs.values(), router]:
            if q.poll() is None:
                q.send_signal(signal.SIGINT)
                q.wait(timeout=30)
    compare_with_simulate(out, scen, tmp_path)
    assert_all_gone([q.pid for q in procs.values()] + all_pids(out))


def test_a_standby_started_after_its_run_ended_says_so_and_exits(tmp_path):
    """`splitspec standby` for a run whose orchestrator is not up (the run ended, or never was): it asks for the
    run's configuration for --wait seconds, then exits 1 in one line, writes nothing and leaves no process behind (a
    standby once kept its interpreter alive on Zenoh's callback threads, and its launcher with it)."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    router = start("router", "--listen", endpoint, log=tmp_path / "router.log")
    log = tmp_path / "standby.log"
    standby = None
    try:
        wait_for_listener(endpoint)
        t0 = time.monotonic()
        standby = start("standby", "--run-id", "rgone", "--connect", endpoint, "--out", tmp_path / "out",
                        "--wait", 3, log=log)
        code = standby.wait(timeout=60)
        took = time.monotonic() - t0
    finally:
        for proc in (standby, router):
            if proc is not None and proc.poll() is None:
                proc.kill()
                proc.wait()
    text = log.read_text()
    errors = [ln for ln in text.splitlines() if ln.startswith("splitspec: error")]
    assert code == 1 and len(errors) == 1 and "Traceback" not in text, text
    assert f"no orchestrator of run 'rgone' answered on {endpoint} within 3 s" in errors[0], errors
    assert 3 <= took < 3 + 20, took
    assert not (tmp_path / "out" / "events.jsonl").exists()  # it wrote nothing
    assert_all_gone([standby.pid])
