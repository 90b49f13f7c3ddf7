"""`splitspec run` without --run-id gets a unique id; `splitspec kill` without --run-id finds that run."""

import os
import re
import signal
import subprocess
import time

import pytest

from tests.integration.runtime_helpers import (ENV, ROOT, all_pids, assert_all_gone, cli, events, scenario_file,
                                               start, wait_for_event, wait_for_rows)

pytestmark = pytest.mark.slow


def test_run_without_run_id_then_kill_without_run_id(tmp_path):
    # a private registry: other users of this machine's account may have runs of their own
    env = {"SPLITSPEC_RUNTIME_DIR": str(tmp_path / "rt")}
    scen = scenario_file(tmp_path, "paper_discrete", run={"steps": 240, "pace": 20})
    out, log = tmp_path / "out", tmp_path / "run.log"
    p = start("run", scen, "--out", out, log=log, env_extra=env)
    try:
        deadline = time.monotonic() + 30
        while not (m := re.search(r"splitspec: run id (r[0-9a-f]{8}) \(splitspec kill --run-id \1 --agent I\)",
                                  log.read_text(errors="replace"))):
            assert time.monotonic() < deadline and p.poll() is None, log.read_text(errors="replace")
            time.sleep(0.05)
        rid = m.group(1)
        wait_for_rows(out, 10, timeout=90)
        assert next(e for e in events(out) if e["event"] == "orchestrator_started")["run_id"] == rid
        r = subprocess.run(cli("kill", "--agent", 2), cwd=ROOT, env={**ENV, **env}, capture_output=True, text=True,
                           timeout=30)
        assert r.returncode == 0 and "sent SIGKILL to agent 2" in r.stdout and f"of run '{rid}'" in r.stdout, r
        lost = wait_for_event(out, "agent_lost", timeout=30, id=2)
        assert lost["reason"] == "the process exited (killed by SIGKILL)"  # its parent reaped it: not "liveliness"
        p.wait(timeout=120)
    finally:
        if p.poll() is None:
            os.killpg(p.pid, signal.SIGKILL)
    assert p.returncode == 0, log.read_text(errors="replace")
    assert [e["id"] for e in events(out) if e["event"] == "agent_lost"] == [2]
    assert_all_gone(all_pids(out))
    assert list((tmp_path / "rt").glob("*.json")) == []  # the orchestrator removed its entry
