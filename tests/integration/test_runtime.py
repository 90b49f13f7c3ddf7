"""`splitspec run`: real OS processes over real Zenoh sessions on loopback, compared with `simulate`."""

import json
import os
import signal
import subprocess
from pathlib import Path

import numpy as np
import pytest
import yaml

from splitspec_core.model.network import fault_step
from splitspec_orchestrator.records.recover import recover
from tests.conftest import EXAMPLES, ROOT
from tests.integration.runtime_helpers import (ENV, assert_all_gone, cli, compare_with_simulate, events, run,
                                               scenario_file, started_pids, wait_for_event, wait_for_rows)
from tests.rrd_readback import read_rrd, read_rrd_state, verify_rrd

pytestmark = pytest.mark.slow


@pytest.mark.parametrize("example,changes", [
    ("paper_discrete", {}),
    ("paper_discrete_switching", {}),  # random switching + process noise
    ("paper_continuous", {"run": {"steps": 150}}),  # sampled-data, process noise
    ("paper_continuous_switching", {"run": {"steps": 150}, "system": {"measurement_noise": 0.05}}),
    ("paper_continuous", {"run": {"steps": 150}, "design": {"g": "adaptive", "g0": 1.0}}),
    ("paper_discrete_filter", {}),  # a state no agent sees: P_i on V_i minus W, W sent in the config
    ("paper_continuous_filter", {}),
    # noise per state, per agent and per output: the plant process draws what the simulator draws
    ("paper_discrete_switching", {"system": {"process_noise": [0.1, 0.05, 0.0, 0.2],
                                             "measurement_noise": {1: 0.05, 2: [0.1], 3: 0.0}}}),
    # design.gains: kalman: each agent process designs its gain from the scenario's noise as the designer does
    ("paper_discrete_switching", {"design": {"gains": "kalman", "K": None},
                                  "system": {"process_noise": [0.1, 0.05, 0.0, 0.2], "measurement_noise": 0.05}}),
    ("paper_continuous", {"run": {"steps": 150},
                          "system": {"process_noise": [[0.3, 0.1, 0, 0], [0.1, 0.2, 0, 0], [0, 0, 0.25, 0],
                                                       [0, 0, 0, 0]],  # an intensity matrix, singular
                                     "measurement_noise": {1: 0.05, 2: [0.02], 3: 0.1}}}),
])
def test_run_equals_simulate(tmp_path, example, changes):
    scen = scenario_file(tmp_path, example, **changes)
    out = tmp_path / "out"
    r = run("run", scen, "--out", out)
    assert r.returncode == 0, r.stdout + r.stderr
    assert "run.rrd" in r.stdout and "splitspec view" in r.stdout  # tells the user how to open the recording
    compare_with_simulate(out, scen, tmp_path)
    # every agent ran in its own process
    pids = started_pids(out)
    sc = yaml.safe_load(scen.read_text())
    agents = sorted(int(i) for i in sc["system"]["C"])
    assert sorted(i for role, i in pids if role == "agent") == agents
    assert ("plant", 0) in pids and ("orchestrator", 0) in pids
    assert len(set(pids.values())) == len(pids) == len(agents) + 3  # and the agent fork server
    assert_all_gone(pids.values())
    ev = events(out)
    names = [e["event"] for e in ev]
    steps = sc["run"]["steps"] if "steps" in sc.get("run", {}) else None
    assert names[-2:] == ["run_finished", "recording_closed"] and names.count("run_finished") == 1, names
    finished, closed = ev[-2:]
    assert finished["reason"] == "steps" and (steps is None or finished["rounds"] == steps), finished
    assert closed["finished"] is True and closed["rows"] == finished["rounds"] + 1, closed  # event times 0..steps
    assert "agent_lost" not in names and "run_interrupted" not in names
    ok, msg = verify_rrd(out / "run.rrd")
    assert ok, msg
    traj = np.load(out / "trajectory.npz")
    scalars = read_rrd(out / "run.rrd")
    T = traj["t"].shape[0]
    for k, aid in enumerate(traj["agent_ids"]):
        got = dict(scalars[f"errors/agent_{aid}"])
        assert sorted(got) == list(range(T))
        expect = np.linalg.norm(traj["xhat"][:, k] - traj["x"], axis=1)
        assert np.allclose([got[t] for t in range(T)], expect, rtol=1e-9, atol=1e-12)
    assert len(scalars["errors/max"]) == T
    # the states' names (system.states) name the recording's state entities and trajectory.npz's states
    names = sc["system"].get("states") or [f"x{k + 1}" for k in range(traj["x"].shape[1])]
    assert traj["states"].tolist() == names
    labels = names if "states" in sc["system"] else [str(k + 1) for k in range(len(names))]
    state = read_rrd_state(out / "run.rrd")
    assert {f"state/{s}/truth" for s in labels} | {f"state/{s}/agent_{a}" for s in labels for a in agents} \
        <= set(state), sorted(state)


def test_switching_is_logged(tmp_path):
    out = tmp_path / "out"
    r = run("run", EXAMPLES / "paper_discrete_switching.yaml", "--out", out)
    assert r.returncode == 0, r.stderr
    traj = np.load(out / "trajectory.npz")
    switches = [e for e in events(out) if e["event"] == "graph_switched"]
    changes = int(np.sum(traj["graph"][1:] != traj["graph"][:-1]))
    assert changes > 0 and len(switches) == changes
    for e in switches:
        assert traj["graph"][int(e["t"])] == ["a", "b"].index(e["graph"])


def start_paced_run(tmp_path, min_rows: int = 10):
    """Start `splitspec run` on a slow (paced) scenario; return once rows are on disk."""
    scen = scenario_file(tmp_path, "paper_discrete", run={"steps": 400, "pace": 20})
    out = tmp_path / "out"
    p = subprocess.Popen(cli("run", scen, "--out", out), cwd=ROOT, env=ENV, stdout=subprocess.PIPE,
                         stderr=subprocess.STDOUT, start_new_session=True)
    try:
        wait_for_event(out, "run_started", timeout=60)
        wait_for_rows(out, min_rows, timeout=60)
    except BaseException:
        p.kill()
        raise
    return p, out, started_pids(out)


def test_agents_are_forks_of_the_fork_server(tmp_path):
    """A local run starts its agents as forks of one agent fork server (splitspec_agents.forkserver): each a
    process of its own, named after its agent, the server's child; the plant is a process of its own."""
    p, out, pids = start_paced_run(tmp_path)
    try:
        assert [e["event"] for e in events(out)][:2] == ["orchestrator_started", "fork_server_started"]
        server = pids[("fork_server", 0)]
        with open(f"/proc/{server}/cmdline", "rb") as f:
            assert b"splitspec_agents.forkserver" in f.read()
        agents = {ident: pid for (role, ident), pid in pids.items() if role == "agent"}
        assert sorted(agents) == [1, 2, 3] and len(set(agents.values())) == 3
        for ident, pid in agents.items():
            with open(f"/proc/{pid}/stat") as f:
                assert int(f.read().rsplit(")", 1)[1].split()[1]) == server
            with open(f"/proc/{pid}/comm") as f:
                assert f.read().strip() == f"agent {ident}"
            # Zenoh's transmission and application tasks on the reception threads (runtime.node.NODE_ZENOH_RUNTIME):
            # no thread of their own
            tasks = Path(f"/proc/{pid}/task")
            threads = {(tasks / t / "comm").read_text().strip() for t in os.listdir(tasks)}
            assert any(t.startswith("rx-") for t in threads), threads
            assert not any(t.startswith(("tx-", "app-")) for t in threads), threads
        with open(f"/proc/{pids[('plant', 0)]}/stat") as f:  # the plant: the orchestrator's own child
            assert int(f.read().rsplit(")", 1)[1].split()[1]) == pids[("orchestrator", 0)]
    finally:
        p.send_signal(signal.SIGINT)
        p.wait(timeout=30)
    assert_all_gone(pids.values())


def test_ctrl_c_leaves_nothing_behind(tmp_path):
    p, out, pids = start_paced_run(tmp_path)
    try:
        p.send_signal(signal.SIGINT)  # what Ctrl-C does to the launcher
        p.wait(timeout=30)
    finally:
        if p.poll() is None:
            p.kill()
    assert p.returncode != 0
    assert_all_gone(pids.values())
    names = [e["event"] for e in events(out)]
    assert "run_interrupted" in names
    traj = np.load(out / "trajectory.npz")  # records so far are readable
    assert 10 <= traj["t"].shape[0] < 401


@pytest.mark.filterwarnings("ignore:RRD file has no footer")  # expected: the writer was SIGKILLed
def test_orchestrator_crash_leaves_nothing_behind(tmp_path):
    p, out, pids = start_paced_run(tmp_path)
    try:
        os.kill(pids[("orchestrator", 0)], signal.SIGKILL)
        p.wait(timeout=30)
    finally:
        if p.poll() is None:
            p.kill()
    # `splitspec run` says what happened in one line, with its own exit status, and recovered the records
    text = p.stdout.read().decode(errors="replace")
    assert p.returncode == 3, text
    (line,) = [ln for ln in text.splitlines() if ln.startswith("splitspec: error:")]
    assert line.startswith(f"splitspec: error: the orchestrator (pid {pids[('orchestrator', 0)]}) was lost (SIGKILL)")
    assert "records recovered" in line and "Traceback" not in text
    assert_all_gone(pids.values(), timeout=10)
    traj = np.load(out / "trajectory.npz")  # written incrementally: readable after the crash
    assert traj["t"].shape[0] >= 10
    T = traj["t"].shape[0]
    # the launcher ran `splitspec recover`: the three records agree on the T event times and run.rrd verifies;
    # recovering again changes nothing
    assert [tau for tau, _ in read_rrd(out / "run.rrd")["errors/max"]] == list(range(T))
    assert json.loads((out / "events.jsonl").read_text().splitlines()[-1])["event"] == "records_recovered"
    result = recover(out)
    assert result["rows"] == T and result["rrd"] == "kept" and result["rrd_verified"], result
    assert [tau for tau, _ in read_rrd(out / "run.rrd")["errors/max"]] == list(range(T))
    assert json.loads((out / "events.jsonl").read_text().splitlines()[-1])["rows"] == T


def test_run_equals_simulate_in_balanced_coordinates(tmp_path):
    """The paper's discrete example with the filter nobody sees, in units from 1e-3 to 1e3 (x_new = D^-1 x): the
    design works in balanced coordinates (design.coordinates: auto), so every agent runs P_i = D P_b D^-1 and
    K_i = D K_b, and W goes to the agents in those coordinates; the run is simulate's, to round-off, and the design's
    q and certificate are the unscaled example's."""
    import splitspec_core as ss

    raw = yaml.safe_load((EXAMPLES / "paper_discrete_filter.yaml").read_text())
    D = np.array([1e-3, 30.0, 1e3, 0.02, 5.0])
    A, K = np.array(raw["system"]["A"], dtype=float), raw["design"]["K"]
    raw["system"]["A"] = (A * D[None, :] / D[:, None]).tolist()
    raw["system"]["C"] = {i: (np.array(C, dtype=float) * D[None, :]).tolist() for i, C in raw["system"]["C"].items()}
    raw["design"]["K"] = {i: (np.array(k, dtype=float) / D[:, None]).tolist() for i, k in K.items()}
    scen = tmp_path / "units.yaml"
    scen.write_text(yaml.safe_dump(raw))
    des = ss.design(ss.load_scenario(scen))
    plain = ss.design(ss.load_scenario(EXAMPLES / "paper_discrete_filter.yaml"))
    assert des.detail.scale is not None and plain.detail.scale is None
    assert des.q == plain.q and des.checks.rate_certified and des.detail.unobserved.dim == 1
    a = des.detail.agents[0]
    assert np.allclose(a.P @ a.P, a.P) and np.allclose(a.P, a.scale[:, None] * a.dec.P / a.scale[None, :])
    out = tmp_path / "out"
    r = run("run", scen, "--out", out)
    assert r.returncode == 0, r.stdout + r.stderr
    compare_with_simulate(out, scen, tmp_path)


NOISY_DISCRETE = {
    "name": "ring-whole", "time": "discrete",
    "system": {"A": [[0.955336, 0.29552, 0, 0], [-0.29552, 0.955336, 0, 0], [0, 0, 0.877583, 0.479426],
                     [0, 0, -0.479426, 0.877583]],
               "C": {1: [[1, 0, 0, 0]], 2: [[0, 0, 1, 0]], 3: [[0, 1, 0, 0]], 4: [[0, 0, 0, 1]]},
               "process_noise": 0.05, "measurement_noise": {1: 0.1, 2: 0.2, 3: [0.05], 4: 0.1}},
    "graphs": {"ring": {"undirected": [[1, 2], [2, 3], [3, 4], [4, 1]]}},
    "design": {"rate": 0.8},
    "faults": [{"at": 12, "kill": 3}, {"at": 20, "restart": 3}],
    "run": {"steps": 40, "seed": 5},
}
NOISY_CONTINUOUS = {
    "name": "osc-whole", "time": "continuous",
    "system": {"A": [[0, 1, 0, 0], [-1, 0, 0, 0], [0, 0, 0, 1], [0, 0, -2, 0]],
               "C": {1: [[1, 0, 0, 0]], 2: [[0, 1, 0, 0]], 3: [[0, 0, 1, 0]]},
               "process_noise": 0.25, "measurement_noise": 0.05},
    "graphs": {"a": {"arcs": [[1, 2], [2, 1], [2, 3], [3, 2], [1, 3], [3, 1]]}},
    "design": {"rate": 1.0, "consensus": "whole", "q": 3},
    "faults": [{"at": 0.3, "kill": 2}, {"at": 0.6, "restart": 2}],
    "run": {"steps": 100, "dt": 0.01, "seed": 7},
}


@pytest.mark.parametrize("raw", [NOISY_DISCRETE, NOISY_CONTINUOUS], ids=["discrete", "continuous"])
def test_run_equals_simulate_for_the_noise_optimal_design(tmp_path, raw):
    """The default design under noise (design.gains: optimal: the whole-state consensus, every agent's gain sent with
    its configuration): real processes through a kill and a restart give simulate's trajectory, to round-off, and
    the replay of the run's records gives it again."""
    import splitspec_core as ss

    scen = tmp_path / f"{raw['name']}.yaml"
    scen.write_text(yaml.safe_dump(raw))
    des = ss.design(ss.load_scenario(scen))
    assert des.detail.consensus == "whole" and des.checks.rate_certified
    out = tmp_path / "out"
    r = run("run", scen, "--out", out)
    assert r.returncode == 0, r.stdout + r.stderr
    compare_with_simulate(out, scen, tmp_path)
    traj = np.load(out / "trajectory.npz")
    k = 3 if raw["time"] == "discrete" else 2
    alive = traj["alive"][:, k - 1]
    assert not alive.all() and alive[-1]  # killed, then back
    ev = events(out)
    kill, restart = (fault_step(f["at"], raw["run"].get("dt", 1.0) if raw["time"] == "continuous" else 1.0)
                     for f in raw["faults"])
    (lost,) = [e for e in ev if e["event"] == "agent_lost"]
    (back,) = [e for e in ev if e["event"] == "agent_rejoined"]
    assert (lost["id"], lost["tau"], back["id"], back["tau"], back["incarnation"]) == (k, kill, k, restart, 1)
    assert lost["reason"].startswith("killed by the scenario (SIGKILL to pid ")
    assert back["reason"] == "restarted by the scenario"
    assert np.flatnonzero(~alive).tolist() == list(range(kill, restart))  # the trajectory says the same
