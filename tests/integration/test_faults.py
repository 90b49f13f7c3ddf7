"""Faults on real processes: kills, hangs, restarts, rejoins by hand, plant death, chaos; replay in simulate."""

import os
import time
import signal
import uuid
from contextlib import contextmanager

import numpy as np
import pytest
import yaml

from tests.conftest import EXAMPLES
from tests.integration.runtime_helpers import (all_pids, assert_all_gone, compare_with_simulate, dump, endless,
                                               events, recorded, replay, run, start, started_pids, stop_run,
                                               wait_for_event, scenario_file, wait_for_rows)
from tests.rrd_readback import read_rrd, read_rrd_logs, verify_rrd

pytestmark = pytest.mark.slow


def run_id() -> str:
    return "t" + uuid.uuid4().hex[:10]


@contextmanager
def running(tmp_path, scen, rid, *extra, env_extra=None):
    """`splitspec run` in the background: yields (process, out dir, log); its group is killed if the body fails."""
    out = tmp_path / "out"
    log = tmp_path / "run.log"
    p = start("run", scen, "--out", out, "--run-id", rid, *extra, log=log, env_extra=env_extra)
    try:
        yield p, out, log
    except BaseException:
        os.killpg(p.pid, signal.SIGKILL)
        raise


def finish(p, log, timeout=120):
    try:
        p.wait(timeout=timeout)
    finally:
        if p.poll() is None:
            os.killpg(p.pid, signal.SIGKILL)
    return p.returncode, log.read_text(errors="replace")


def lost_events(out, aid=None):
    return [e for e in events(out) if e["event"] == "agent_lost" and (aid is None or e["id"] == aid)]


def agent_errors(out):
    traj = recorded(out)
    return traj, np.linalg.norm(traj["xhat"] - traj["x"][:, None, :], axis=2)


def test_scenario_faults_execute_for_real_and_equal_simulate(tmp_path):
    """kill / drop_arc / freeze / restart / restore_arc from the scenario: real signals, real respawns."""
    scen = EXAMPLES / "ring10_faults.yaml"
    out = tmp_path / "out"
    r = run("run", scen, "--out", out, "--run-id", run_id())
    assert r.returncode == 0, r.stdout + r.stderr
    compare_with_simulate(out, scen, tmp_path)
    ev = events(out)
    lost = {e["id"]: e for e in ev if e["event"] == "agent_lost"}
    assert lost[3]["tau"] == 10 and "SIGKILL" in lost[3]["reason"]
    assert lost[5]["tau"] == 20 and "SIGSTOP" in lost[5]["reason"]
    back = {e["id"]: e for e in ev if e["event"] == "agent_rejoined"}
    assert (back[3]["tau"], back[3]["incarnation"]) == (30, 1) and (back[5]["tau"], back[5]["incarnation"]) == (35, 1)
    assert [e["arc"] for e in ev if e["event"] == "arc_dropped"] == [[1, 6]]
    # a restart is a new OS process
    pids3 = [e["pid"] for e in ev if e["event"] == "process_started" and e["role"] == "agent" and e["id"] == 3]
    assert len(pids3) == 2 and pids3[0] != pids3[1]
    assert_all_gone(all_pids(out))  # the frozen process included
    # every change has a verdict; ring10 is designed with resilience: 1, so single losses stay certified
    verdicts = [e for e in ev if e["event"] == "resilience_verdict"]
    assert len(verdicts) == 6 and all(v["rate_certified"] for v in verdicts if len(v["alive"]) == 9)
    # the recording shows the death and the rejoin: no error for agent 3 while it is dead
    ok, msg = verify_rrd(out / "run.rrd")
    assert ok, msg
    err3 = dict(read_rrd(out / "run.rrd")["errors/agent_3"])
    assert sorted(err3) == list(range(10)) + list(range(30, 61))
    logs = read_rrd_logs(out / "run.rrd")
    assert any(tau == 10 and level == "WARN" and text.startswith("agent 3 lost: killed by the scenario") for tau, level, text in logs["events"])
    assert any(tau == 30 and text == "agent 3 rejoined (incarnation 1)" for tau, _, text in logs["events"])
    topo = {tau: (labels, edges) for tau, labels, edges in logs["topology"]}
    assert "agent 3 (lost)" in topo[10][0] and all(3 not in e for e in topo[10][1])
    assert (1, 6) not in topo[15][1] and (1, 6) in topo[40][1]
    assert "agent 3 (lost)" not in topo[30][0] and "agent 5 (lost)" not in topo[35][0]


def test_corrupt_sensor_and_kill_for_real_equal_simulate_and_replay(tmp_path):
    """corrupt (applied by the plant process) and a kill with for:, on real processes: run == simulate, the
    replay of the recorded events too, events and timeline marks for the sensor fault."""
    raw = yaml.safe_load((EXAMPLES / "ring10.yaml").read_text())
    raw["system"]["measurement_noise"] = 0.01  # the plant's draws go into the corrupted measurement too
    raw["run"] = {**raw.get("run", {}), "steps": 40}
    raw["faults"] = [{"at": 8, "corrupt": 2, "for": 6, "bias": 0.5, "scale": 1.2}, {"at": 11, "kill": 7, "for": 9}]
    scen = tmp_path / "corrupt.yaml"
    scen.write_text(yaml.safe_dump(raw))
    out = tmp_path / "out"
    r = run("run", scen, "--out", out, "--run-id", run_id())
    assert r.returncode == 0, r.stdout + r.stderr
    compare_with_simulate(out, scen, tmp_path)
    replay(out, tmp_path / "replay")
    ev = events(out)
    (bad,) = [e for e in ev if e["event"] == "sensor_corrupted"]
    (fixed,) = [e for e in ev if e["event"] == "sensor_repaired"]
    assert (bad["id"], bad["tau"], bad["bias"], bad["scale"], fixed["id"], fixed["tau"]) == (2, 8, 0.5, 1.2, 2, 14)
    # the terminal tells each fault and its end, not the fault alone
    told = [ln.split(" splitspec.events ", 1)[1] for ln in r.stderr.splitlines() if " splitspec.events " in ln]
    assert "WARNING event time 8: agent 2's measurements corrupted (scale 1.2, bias 0.5) by the scenario" in told
    assert "INFO event time 14: agent 2's sensor repaired" in told
    assert "WARNING agent 7 lost from event time 11: killed by the scenario (SIGKILL to pid " in "\n".join(told)
    assert any(t.startswith("INFO agent 7 rejoins at event time 20 with a fresh estimate") for t in told), told
    traj, err = agent_errors(out)
    k = list(traj["agent_ids"]).index(2)
    import splitspec_core as ss

    clean = ss.simulate(ss.load_scenario(scen), faults=raw["faults"][1:]).errors()  # the kill alone
    assert err[14, k] > 10 * clean[14, k]  # given 1.2 y + 0.5 from event time 8 to 13, its estimate goes astray
    np.testing.assert_allclose(err[:9], clean[:9], rtol=1e-9, atol=1e-12)  # y(8) is used from event time 9 on
    logs = read_rrd_logs(out / "run.rrd")
    assert any(tau == 8 and text == "agent 2's measurements corrupted (scale 1.2, bias 0.5)"
               for tau, _, text in logs["events"])
    assert [tau for tau, _ in read_rrd(out / "run.rrd")["marks/sensor"]] == [8, 14]


def test_stuck_and_noisy_sensors_for_real_equal_simulate_and_replay_exactly(tmp_path):
    """stuck and noise (the plant process draws the noise from the sensor_noise stream, as simulate does) on real
    processes: run == simulate to round-off, the replay of the recorded events is simulate exactly; the events
    carry the options and the timeline marks them."""
    raw = yaml.safe_load((EXAMPLES / "ring10.yaml").read_text())
    raw["system"]["measurement_noise"] = 0.01
    raw["run"] = {**raw.get("run", {}), "steps": 40}
    raw["faults"] = [{"at": 8, "corrupt": 2, "for": 6, "stuck": True}, {"at": 10, "corrupt": 5, "for": 15, "noise": 0.3},
                     {"at": 12, "corrupt": 9, "stuck": True, "noise": [0.2]}]
    scen = tmp_path / "lying.yaml"
    scen.write_text(yaml.safe_dump(raw))
    out = tmp_path / "out"
    r = run("run", scen, "--out", out, "--run-id", run_id())
    assert r.returncode == 0, r.stdout + r.stderr
    compare_with_simulate(out, scen, tmp_path)
    replay(out, tmp_path / "replay")
    sim, again = (np.load(d / "sim" / "trajectory.npz") for d in (tmp_path, tmp_path / "replay"))
    for name in ("x", "xhat", "alive"):  # the replay rebuilt the very faults: the same numbers, bit for bit
        np.testing.assert_array_equal(again[name], sim[name])
    bad = [(e["id"], e["tau"], e.get("stuck"), e.get("noise")) for e in events(out) if e["event"] == "sensor_corrupted"]
    assert bad == [(2, 8, True, None), (5, 10, None, 0.3), (9, 12, True, [0.2])]
    import splitspec_core as ss

    clean = ss.simulate(ss.load_scenario(scen), faults=[]).errors()
    traj, err = agent_errors(out)
    np.testing.assert_allclose(err[:9], clean[:9], rtol=1e-9, atol=1e-12)  # y(8) is used from event time 9 on
    for a, tau in ((2, 8), (5, 10), (9, 12)):  # each lying sensor's estimate goes astray
        k = list(traj["agent_ids"]).index(a)
        assert err[tau + 4, k] > 3 * clean[tau + 4, k], a
    logs = read_rrd_logs(out / "run.rrd")
    texts = {text for _, _, text in logs["events"]}
    assert {"agent 2's measurements corrupted (stuck)", "agent 5's measurements corrupted (noise 0.3)",
            "agent 9's measurements corrupted (stuck, noise [0.2])"} <= texts
    assert [tau for tau, _ in read_rrd(out / "run.rrd")["marks/sensor"]] == [8, 10, 12, 14, 25]


def test_outside_sigkill_of_a_redundant_agent(tmp_path):
    """kill -9 from outside the run: survivors converge, the row is NaN from the recorded time, replay agrees."""
    scen = scenario_file(tmp_path, "ring10", run={"steps": 120, "pace": 20})
    with running(tmp_path, scen, run_id()) as (p, out, log):
        wait_for_rows(out, 25, timeout=90)
        victim = started_pids(out)[("agent", 4)]
        os.kill(victim, signal.SIGKILL)
    code, text = finish(p, log)
    assert code == 0, text
    (lost,) = lost_events(out, 4)
    tau = lost["tau"]
    assert tau >= 25 and lost["reason"] == "the process exited (killed by SIGKILL)"  # its parent reaped it
    assert f"agent 4 lost from event time {tau}: the process exited (killed by SIGKILL)" in text  # the terminal
    traj, err = agent_errors(out)
    k = list(traj["agent_ids"]).index(4)
    assert traj["alive"][:tau, k].all() and not traj["alive"][tau:, k].any()
    assert np.isnan(traj["xhat"][tau:, k]).all() and np.isfinite(traj["xhat"][:tau, k]).all()
    survivors = np.delete(err[-1], k)
    assert np.all(survivors < 1e-9), survivors  # converged to round-off
    replay(out, tmp_path)
    assert_all_gone(all_pids(out))


def test_hang_then_kill_and_rejoin_by_hand(tmp_path):
    """SIGSTOP via `splitspec kill`, then SIGKILL of another agent and a hand-started replacement.  The run goes on
    until stopped, 100 event times after the rejoin: two cold-started `splitspec kill`s and a hand-started agent once
    outlasted a run of 240 steps at pace 20 on a starved machine."""
    rid = run_id()
    scen = endless(tmp_path, "ring10", 20)
    hand = None
    with running(tmp_path, scen, rid, "--insecure") as (p, out, log):  # a hand-started agent joins
        wait_for_rows(out, 20, timeout=90)
        r = run("kill", "--agent", 7, "--signal", "STOP", "--run-id", rid, timeout=30)
        assert r.returncode == 0 and "SIGSTOP" in r.stdout, r.stderr
        frozen = wait_for_event(out, "agent_lost", timeout=30, id=7)
        assert "frozen" in frozen["reason"]  # found by the orchestrator's status probe
        r = run("kill", "--agent", 2, "--run-id", rid, timeout=30)
        assert r.returncode == 0 and "SIGKILL" in r.stdout, r.stderr
        wait_for_event(out, "agent_lost", timeout=30, id=2)
        endpoint = next(e["endpoint"] for e in events(out) if e["event"] == "orchestrator_started")
        hand = start("agent", "--id", 2, "--connect", endpoint, "--run-id", rid, log=tmp_path / "hand.log")
        back = wait_for_event(out, "agent_rejoined", timeout=60, id=2)
        assert back["incarnation"] == 1 and back["pid"] == hand.pid
        wait_for_rows(out, back["tau"] + 100, timeout=60)  # ring10's rate 0.8: 0.8^100 ~ 2e-10
        stop_run(p, log)
    code, text = finish(p, log)
    assert code == 0, text + dump(tmp_path / "hand.log")
    hand.wait(timeout=15)  # told to stop with the others
    (l2,) = lost_events(out, 2)
    traj, err = agent_errors(out)
    k = list(traj["agent_ids"]).index(2)
    lo, hi = l2["tau"], back["tau"]
    assert lo < hi and np.isnan(traj["xhat"][lo:hi, k]).all() and traj["alive"][hi:, k].all()
    assert err[-1, k] < 1e-6 * err[hi, k]  # the fresh estimate converged again
    replay(out, tmp_path)
    assert_all_gone(all_pids(out))  # the frozen agent too


def test_plant_death_stops_the_run_cleanly(tmp_path):
    rid = run_id()
    scen = scenario_file(tmp_path, "paper_discrete", run={"steps": 400, "pace": 20})
    with running(tmp_path, scen, rid) as (p, out, log):
        wait_for_rows(out, 10, timeout=90)
        r = run("kill", "--plant", "--run-id", rid, timeout=30)
        assert r.returncode == 0, r.stderr
    code, text = finish(p, log)
    assert code == 1
    errors = [line for line in text.splitlines() if line.startswith("splitspec: error:")]
    assert len(errors) == 1 and "the plant (pid " in errors[0] and ") was lost at event time" in errors[0], text
    assert "Traceback" not in text
    assert [e["event"] for e in events(out)][-2:] == ["run_failed", "recording_closed"]
    traj = np.load(out / "trajectory.npz")
    assert 10 <= traj["t"].shape[0] < 401
    ok, msg = verify_rrd(out / "run.rrd")
    assert ok, msg
    assert_all_gone(all_pids(out))
    # the run is gone from the registry: `splitspec kill` says so in one line
    r = run("kill", "--agent", 1, "--run-id", rid, timeout=30)
    assert r.returncode == 2 and r.stderr.count("\n") == 1 and "no running run" in r.stderr


def test_non_redundant_loss_is_reported_and_the_run_goes_on(tmp_path):
    """Agent 3 is the only one that observes the second oscillator of the paper's example."""
    raw = yaml.safe_load((EXAMPLES / "paper_discrete.yaml").read_text())
    raw["faults"] = [{"at": 10, "kill": 3}]
    scen = tmp_path / "lose3.yaml"
    scen.write_text(yaml.safe_dump(raw))
    out = tmp_path / "out"
    r = run("run", scen, "--out", out, "--run-id", run_id())
    assert r.returncode == 0, r.stderr
    assert "do NOT jointly observe" in r.stderr  # on the terminal
    (v,) = [e for e in events(out) if e["event"] == "resilience_verdict"]
    assert v["after"] == "agent 3 lost" and v["ok"] is False and v["jointly_observable"] is False
    assert v["alive"] == [1, 2] and v["unobservable_direction"]
    logs = read_rrd_logs(out / "run.rrd")
    assert any(level == "WARN" and "NOT jointly observe" in text and tau == 10 for tau, level, text in logs["events"])
    compare_with_simulate(out, scen, tmp_path)
    traj = np.load(out / "trajectory.npz")
    assert traj["t"].shape[0] == 41  # the run went on to the end


@pytest.mark.parametrize("seed", [11, 12, 13])
def test_chaos_random_kills(tmp_path, seed):
    """Seeded random SIGKILLs at random moments of a paced run: every run completes and replays."""
    rng = np.random.default_rng(seed)
    # until stopped, 30 event times after the last loss (a run of 100 steps once ended before it on a starved
    # machine: the rows reach the disk a flush, about a second, after their round)
    scen = endless(tmp_path, "ring10", 30)
    victims = [int(v) for v in rng.choice(np.arange(1, 11), size=2, replace=False)]
    rows = sorted(int(r) for r in rng.integers(5, 50, size=2))
    with running(tmp_path, scen, run_id()) as (p, out, log):
        for victim, row in zip(victims, rows):
            wait_for_rows(out, row, timeout=90)
            os.kill(started_pids(out)[("agent", victim)], signal.SIGKILL)
        last = wait_for_event(out, "agent_lost", timeout=60, id=victims[-1])
        wait_for_event(out, "agent_lost", timeout=60, id=victims[0])
        wait_for_rows(out, last["tau"] + 30, timeout=60)
        stop_run(p, log)
    code, text = finish(p, log)
    assert code == 0, text
    assert sorted(e["id"] for e in lost_events(out)) == sorted(victims)
    assert events(out)[-2]["event"] == "run_finished"
    replay(out, tmp_path)
    assert_all_gone(all_pids(out))


def test_kill_cli_bad_input(tmp_path):
    r = run("kill", "--agent", 1, "--run-id", "no-such-run-" + uuid.uuid4().hex[:6])
    assert r.returncode == 2 and r.stderr.startswith("splitspec: error: no running run") and "Traceback" not in r.stderr
    r = run("kill", "--run-id", "x")
    assert r.returncode == 2 and "one of the arguments --agent --plant --orchestrator is required" in r.stderr
    r = run("kill", "--agent", 1, "--run-id", "a/b")
    assert r.returncode == 2 and "--run-id" in r.stderr


def test_replay_bad_events_file(tmp_path):
    bad = tmp_path / "events.jsonl"
    bad.write_text('{"event": "agent_lost", "id": 99, "tau": 3}\n')
    r = run("simulate", EXAMPLES / "paper_discrete.yaml", "--out", tmp_path / "o", "--faults-from", bad)
    assert r.returncode == 2 and "agent 99" in r.stderr and r.stderr.count("\n") == 1
    bad.write_text('not json\n{"event": "x"}\n')
    r = run("simulate", EXAMPLES / "paper_discrete.yaml", "--out", tmp_path / "o", "--faults-from", bad)
    assert r.returncode == 2 and f"{bad}:1" in r.stderr
    r = run("simulate", EXAMPLES / "paper_discrete.yaml", "--out", tmp_path / "o", "--faults-from", tmp_path / "none")
    assert r.returncode == 2 and "cannot read events file" in r.stderr


def test_status_probe_catches_a_frozen_agent_long_before_its_lease(tmp_path):
    """With a 20 s lease, the status probe (or the round timeout) notices a SIGSTOPped agent at once; the round is
    re-run without it."""
    rid = run_id()
    # until stopped, 100 event times after the loss (a run of 300 steps at pace 25 is 12 s of wall time, less on a
    # starved machine than a cold-started `splitspec kill` may take)
    scen = endless(tmp_path, "paper_discrete", 25)
    with running(tmp_path, scen, rid, "--round-timeout", "0.5", env_extra={"SPLITSPEC_LEASE_MS": "20000"}) \
            as (p, out, log):
        wait_for_rows(out, 10, timeout=90)
        before = time.time()
        r = run("kill", "--agent", 1, "--signal", "STOP", "--run-id", rid, timeout=30)
        stopped = time.time()  # the signal was sent by now (the command's start-up is not the probe's)
        assert r.returncode == 0, r.stderr
        lost = wait_for_event(out, "agent_lost", timeout=30, id=1)
        wait_for_rows(out, lost["tau"] + 100, timeout=60)
        stop_run(p, log)
    code, text = finish(p, log)
    assert code == 0, text
    assert lost_events(out, 1) == [lost]
    # found long before the 20 s lease: the probe's 0.3 + 0.8 s, with room for a starved machine
    assert lost["reason"].endswith("frozen") and before <= lost["wall"] and lost["wall"] - stopped < 5.0, lost
    # agents 2 and 3 still observe both oscillators: the survivors converge (to round-off relative to |x|,
    # which grows like 2^(tau/2) in the paper's example)
    traj, err = agent_errors(out)
    assert np.all(err[-1, 1:] < 1e-9 * np.linalg.norm(traj["x"][-1])) and np.isnan(traj["xhat"][lost["tau"]:, 0]).all()
    replay(out, tmp_path)
    assert_all_gone(all_pids(out))  # the frozen process too
