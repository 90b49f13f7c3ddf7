"""`--secure`: Zenoh user/password authentication and access control on the orchestrator's router."""

import pytest
import yaml

from splitspec_core.runtime.bus import BusError, open_session
from splitspec_core.runtime.security import read_credentials
from splitspec_core.runtime.wire import Keys
from tests.conftest import EXAMPLES
from tests.integration.runtime_helpers import (all_pids, assert_all_gone, compare_with_simulate, events, free_port,
                                               run, scenario_file)
from tests.integration.test_malformed import rogue_during_hand_started_run

pytestmark = pytest.mark.slow


def test_secure_deployment_by_hand_refuses_and_confines(tmp_path):
    scen = scenario_file(tmp_path, "paper_discrete", run={"steps": 200, "pace": 25})
    creds = tmp_path / "creds"
    r = run("credentials", scen, "--out", creds)
    assert r.returncode == 0, r.stderr
    assert (creds / "users.txt").stat().st_mode & 0o077 == 0 and (creds / "agent-1.cred").stat().st_mode & 0o077 == 0
    out = tmp_path / "out"
    rid = "secure-test"
    keys = Keys(rid)
    # a compromised agent 1 (its real credentials) forging other processes' messages
    forged = {keys.z(2), keys.y, keys.xhat(2), keys.truth, keys.tick}
    with rogue_during_hand_started_run(tmp_path, scen, out, rid, creds=creds, only=forged,
                                       credentials=read_credentials(creds / "agent-1.cred")) as (endpoint, procs, sent):
        # no credentials, a wrong password, an unknown user: refused at connection time
        for user, password in ((None, None), ("agent-1", "wrong"), ("mallory", "x")):
            with pytest.raises(BusError, match="cannot open a Zenoh client session"):
                open_session("client", connect=[endpoint], user=user, password=password, connect_timeout_ms=1000)
        assert procs[0].poll() is None  # refused while the run was going on
    assert sum(sent.values()) > 100  # the compromised session did connect and publish
    # the router dropped every forged message: no process ever saw one (without --secure they arrive and are
    # rejected by validation, see test_malformed), and the estimates are the simulator's
    assert not [e for e in events(out) if e["event"] == "message_rejected"]
    started = next(e for e in events(out) if e["event"] == "orchestrator_started")
    assert started["secure"] is True
    compare_with_simulate(out, scen, tmp_path)


def test_run_secure_equals_simulate_and_cleans_up(tmp_path):
    import os

    from splitspec_orchestrator.registry import runtime_dir

    rid = "sec" + os.urandom(4).hex()
    raw = yaml.safe_load((EXAMPLES / "ring10_faults.yaml").read_text())
    scen = tmp_path / "f.yaml"
    scen.write_text(yaml.safe_dump(raw))
    out = tmp_path / "out"
    r = run("run", scen, "--out", out, "--secure", "--run-id", rid)
    assert r.returncode == 0, r.stderr
    compare_with_simulate(out, scen, tmp_path)  # restarted agents got their credentials too
    assert [e["id"] for e in events(out) if e["event"] == "agent_rejoined"] == [3, 5]
    assert not list(runtime_dir().glob(f"creds-{rid}-*"))  # the run's credentials are deleted
    assert_all_gone(all_pids(out))


def test_secure_bad_input(tmp_path):
    scen = EXAMPLES / "paper_discrete.yaml"
    r = run("orchestrator", scen, "--listen", "tcp/127.0.0.1:1", "--out", tmp_path / "o", "--secure", tmp_path / "nope")
    assert r.returncode == 2 and "cannot read" in r.stderr and "splitspec credentials" in r.stderr
    # with --connect, --secure DIR is the run's own router's credentials (a run with a standby): the same one line
    r = run("orchestrator", scen, "--connect", "tcp/127.0.0.1:1", "--out", tmp_path / "o", "--secure", tmp_path)
    assert r.returncode == 2 and "users.txt" in r.stderr and "splitspec credentials" in r.stderr
    assert r.stderr.count("\n") == 2, r.stderr  # the run id's line, then the one error line
    r = run("agent", "--id", 1, "--connect", "tcp/127.0.0.1:1", "--run-id", "x",
            "--credentials", tmp_path / "none.cred")
    assert r.returncode == 2 and "cannot read credentials file" in r.stderr
    bad = tmp_path / "bad.cred"
    bad.write_text("no-colon\n")
    r = run("plant", "--connect", "tcp/127.0.0.1:1", "--run-id", "x", "--credentials", bad)
    assert r.returncode == 2 and "expected one line 'user:password'" in r.stderr
    # credentials for another scenario (agents 1..3) do not cover ring10's agents
    creds = tmp_path / "c"
    assert run("credentials", scen, "--out", creds).returncode == 0
    r = run("orchestrator", EXAMPLES / "ring10.yaml", "--listen", f"tcp/127.0.0.1:{free_port()}", "--out",
            tmp_path / "o2", "--secure", creds, "--wait", 2)
    assert r.returncode != 0 and "no credentials for agent-4" in r.stderr and "Traceback" not in r.stderr
    for res in (r,):
        assert res.stderr.count("splitspec: error") == 1
