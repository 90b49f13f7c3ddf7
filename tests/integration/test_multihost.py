"""Several hosts on one machine (Linux network namespaces): the process CLI across a real (virtual) network.

Every process runs in its own namespace with its own address on a private subnet and reaches the others only
through a bridge; the run must still equal `simulate`. Also run: the same with an external router host, and a
run with a `network.deadline` over links that really delay, jitter and lose frames (netem, or its user-space
emulator where the kernel has no netem: `tests/integration/netns.py`): messages really arrive late, the run
records them and its replay equals it.
"""

import os
import shutil
import subprocess
import sys
import time

import numpy as np
import pytest

from tests.integration import netns
from tests.integration.runtime_helpers import (ENV, ROOT, cli, compare_with_simulate, dump, events, replay,
                                               scenario_file, wait_for_event)

pytestmark = [pytest.mark.slow,
              pytest.mark.skipif(netns.available() is not None, reason=f"{netns.available()}")]

AGENTS = (1, 2, 3)


def start_on(lab, host, args, log):
    return subprocess.Popen(lab.exec(host, cli(*args)), cwd=ROOT, env=ENV, stdout=open(log, "wb"),
                            stderr=subprocess.STDOUT)


def wait_for_router(lab, host, endpoint, timeout: float = 60.0) -> None:
    """Until ``endpoint`` accepts TCP connections from ``host``'s namespace: processes started by hand give the
    router a short budget (``splitspec_core.runtime.node.CONNECT_BUDGET``) to be reachable."""
    addr, port = endpoint.removeprefix("tcp/").rsplit(":", 1)
    code = ("import socket, sys, time\n"
            f"deadline = time.monotonic() + {timeout}\n"
            "while True:\n"
            "    try:\n"
            f"        socket.create_connection(({addr!r}, {port}), 1).close()\n"
            "        break\n"
            "    except OSError:\n"
            "        if time.monotonic() > deadline:\n"
            "            sys.exit(1)\n"
            "        time.sleep(0.05)\n")
    r = subprocess.run(lab.exec(host, [sys.executable, "-c", code]), timeout=timeout + 30)
    assert r.returncode == 0, f"nothing listens at {endpoint} (seen from {host}) after {timeout} s"


def start_clients(lab, procs: dict, logs: dict, endpoint: str, rid: str, out) -> None:
    """The plant and every agent, each on its own host, once the router answers: they need nothing but the
    endpoint and the run id; returns when the run has started."""
    wait_for_router(lab, "plant", endpoint)
    procs["plant"] = start_on(lab, "plant", ["plant", "--connect", endpoint, "--run-id", rid], logs["plant"])
    for i in AGENTS:
        procs[f"a{i}"] = start_on(lab, f"a{i}", ["agent", "--id", i, "--connect", endpoint, "--run-id", rid],
                                  logs[f"a{i}"])
    wait_for_event(out, "run_started", timeout=90)


def stop_all(procs: dict) -> None:
    """Terminate the lab's processes still running and give them 5 s to go (the lab then removes their hosts)."""
    for p in procs.values():
        if p.poll() is None:
            p.terminate()
    deadline = time.monotonic() + 5
    while any(p.poll() is None for p in procs.values()) and time.monotonic() < deadline:
        time.sleep(0.05)


def net_namespace(pid: int) -> str:
    return os.readlink(f"/proc/{pid}/ns/net")


@pytest.mark.parametrize("external_router", [False, True], ids=["embedded-router", "external-router"])
def test_processes_on_separate_hosts_equal_simulate(tmp_path, external_router):
    # paced: slow enough to look at the processes while they run
    scen = scenario_file(tmp_path, "paper_discrete", run={"steps": 120, "pace": 40})
    out = tmp_path / "out"
    rid = "multihost"
    hosts = (["router"] if external_router else []) + ["orch", "plant"] + [f"a{i}" for i in AGENTS]
    logs = {h: tmp_path / f"{h}.log" for h in hosts}
    procs = {}
    with netns.NetnsLab(hosts) as lab:
        try:
            if external_router:
                endpoint = f"tcp/{lab.addr['router']}:7447"
                procs["router"] = start_on(lab, "router", ["router", "--listen", endpoint], logs["router"])
                orch_net = ["--connect", endpoint]
            else:
                endpoint = f"tcp/{lab.addr['orch']}:7447"
                orch_net = ["--listen", endpoint]
            procs["orch"] = start_on(lab, "orch", ["orchestrator", scen, *orch_net, "--out", out, "--run-id", rid],
                                     logs["orch"])
            start_clients(lab, procs, logs, endpoint, rid, out)
            # each process really is on its own host: distinct network namespaces, none of them ours
            spaces = {h: net_namespace(p.pid) for h, p in procs.items()}
            assert len(set(spaces.values())) == len(hosts) and net_namespace(os.getpid()) not in spaces.values()
            # and the loopback of one host is not the others': nothing listens on 7447 on the plant's loopback
            probe = subprocess.run(lab.exec("plant", [sys.executable, "-c",
                                                      "import socket; socket.create_connection(('127.0.0.1', 7447), 1)"]),
                                   capture_output=True)
            assert probe.returncode != 0
            assert procs["orch"].wait(timeout=120) == 0, dump(*logs.values())
            for h in ["plant"] + [f"a{i}" for i in AGENTS]:
                assert procs[h].wait(timeout=20) == 0, dump(logs[h])
        finally:
            stop_all(procs)
        names = set(netns.lab_namespaces(os.getpid()))
        assert names == {lab.ns(h) for h in hosts} | {lab.ns("hub")}
    # cleaned up: no namespace, no link, no process of the lab left
    assert netns.lab_namespaces(os.getpid()) == []
    assert all(p.poll() is not None for p in procs.values())
    hellos = {(e["role"], e["id"]) for e in events(out) if e["event"] == "process_started"}
    assert hellos == {("plant", 0)} | {("agent", i) for i in AGENTS}
    compare_with_simulate(out, scen, tmp_path)
    assert np.load(out / "trajectory.npz")["t"].shape[0] == 121


# The links of the agents' hosts: every frame held 4 +- 3 ms (uniform) each way, and lost with probability 1.5 %
# (TCP retransmits it: tens to hundreds of ms later).  A consensus message crosses two such links (agent -> router
# host -> agent): 2 to 14 ms, 8 on average, before any loaded CPU adds its own; a sub-round waits 6 ms at most.
LINK = {"delay": 0.004, "jitter": 0.003, "loss": 0.015}
DEADLINE = 0.006
NETEM_STEPS = 40
MESSAGES = NETEM_STEPS * 6 * 5  # consensus messages: event times x q sub-rounds (paper_discrete: q = 6) x arcs


def impaired_run(tmp_path, *, link: dict | None, network: dict | None, steps: int = NETEM_STEPS) -> dict:
    """``paper_discrete`` (with ``network``) across namespaces whose agents' links are impaired by ``link``
    (:meth:`netns.NetnsLab.impair`; None: plain links, no emulator in the way); the figures of the run (its output
    in ``out``).

    Delay and jitter from the start; loss only once every process is in (``run_started``): a lost SYN costs the
    kernel's 1 s retransmission, and a hand-started process gives the router 2.5 s (``node.CONNECT_BUDGET``).
    """
    changes = {"run": {"steps": steps}} | ({"network": network} if network is not None else {})
    scen = scenario_file(tmp_path, "paper_discrete", **changes)
    out = tmp_path / "out"
    rid = "netem"
    agents = [f"a{i}" for i in AGENTS]
    hosts = ["orch", "plant"] + agents
    logs = {h: tmp_path / f"{h}.log" for h in hosts}
    procs = {}
    t0 = time.monotonic()
    with netns.NetnsLab(hosts, impairable=agents if link is not None else ()) as lab:
        try:
            for h in lab.impairable:
                lab.impair(h, delay=link.get("delay", 0.0), jitter=link.get("jitter", 0.0))
            endpoint = f"tcp/{lab.addr['orch']}:7447"
            procs["orch"] = start_on(lab, "orch", ["orchestrator", scen, "--listen", endpoint, "--out", out,
                                                   "--run-id", rid], logs["orch"])
            start_clients(lab, procs, logs, endpoint, rid, out)
            for h in lab.impairable:
                lab.impair(h, **link)
            assert procs["orch"].wait(timeout=120) == 0, dump(*logs.values())
            for h in ["plant"] + agents:
                assert procs[h].wait(timeout=20) == 0, dump(logs[h])
            frames = lab.link_stats() if lab.impairable else {}
            backend = lab.impair_backend
        finally:
            stop_all(procs)
    assert netns.lab_namespaces(os.getpid()) == []
    with np.load(out / "trajectory.npz") as f:
        cause, alive = f["lost_cause"], f["alive"]
    finished = next(e for e in events(out) if e["event"] == "run_finished")
    return {"out": out, "backend": backend, "frames": frames, "late": int((cause == 1).sum()),
            "lost": int((cause == 0).sum()), "partition": int((cause == 2).sum()), "all_alive": bool(alive.all()),
            "seconds": finished["seconds"], "ms_per_event_time": 1000 * finished["seconds"] / steps,
            "wall": time.monotonic() - t0, "loadavg": open("/proc/loadavg").read().split()[:3]}


def test_real_link_impairment_makes_messages_late_and_the_replay_equals_the_run(tmp_path):
    r = impaired_run(tmp_path, link=LINK, network={"deadline": DEADLINE})
    print(f"\n{r['backend']}: {r['late']} of {MESSAGES} consensus messages late, {NETEM_STEPS} event times in "
          f"{r['seconds']} s ({r['ms_per_event_time']:.0f} ms each), test {r['wall']:.1f} s, load {r['loadavg']}, "
          f"frames {r['frames']}")
    # the links really lost frames
    assert sum(r["frames"][h][way]["dropped"] for h in r["frames"] for way in ("up", "down")) > 0, r["frames"]
    # the network alone made messages late (nothing is drawn lost: the scenario has no network.loss) ...
    assert r["lost"] == r["partition"] == 0 and r["late"] >= MESSAGES // 10, r
    # ... and not all of them: the sub-rounds averaged over what had arrived
    assert r["late"] < MESSAGES and r["all_alive"], r
    # the replay (simulate with the run's recorded losses) gives the run's trajectory
    replay(r["out"], tmp_path)


ACCEPT_ONE = """
import socket, sys
s = socket.socket(); s.bind((sys.argv[1], 5000)); s.listen(1); print("listening", flush=True)
s.settimeout(10); c, _ = s.accept(); c.close()
"""
CONNECT = "import socket, sys; socket.create_connection((sys.argv[1], 5000), 5).close()"


def root_links() -> list:
    return sorted(line.split(":")[1].strip() for line in
                  subprocess.run(["ip", "-o", "link"], capture_output=True, text=True).stdout.splitlines())


def test_lab_is_removed_after_a_failure():
    hosts = ["x", "y"]
    links_before = root_links()
    with pytest.raises(RuntimeError, match="boom"):
        with netns.NetnsLab(hosts) as lab:
            sleeper = subprocess.Popen(lab.exec("x", ["sleep", "60"]))
            assert set(netns.lab_namespaces(os.getpid())) == {lab.ns("x"), lab.ns("y"), lab.ns("hub")}
            # the hosts reach each other over the bridge (TCP from x to a listener on y)
            server = subprocess.Popen(lab.exec("y", [sys.executable, "-c", ACCEPT_ONE, lab.addr["y"]]),
                                      stdout=subprocess.PIPE)
            assert server.stdout.readline().strip() == b"listening"
            client = subprocess.run(lab.exec("x", [sys.executable, "-c", CONNECT, lab.addr["y"]]), capture_output=True)
            assert client.returncode == 0 and server.wait(timeout=10) == 0, client.stderr
            raise RuntimeError("boom")
    assert netns.lab_namespaces(os.getpid()) == []
    assert root_links() == links_before  # the lab never touched this namespace's links
    sleeper.wait(timeout=10)  # killed with its namespace
    assert sleeper.returncode == -9


def root_qdiscs() -> str:
    return subprocess.run(["tc", "qdisc", "show"], capture_output=True, text=True).stdout if shutil.which("tc") else ""


SEND_UDP = ("import socket, sys; s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)\n"
            "for k in range(100): s.sendto(b'x', (sys.argv[1], 9))")
TIME_CONNECT = ("import socket, sys, time; t = time.monotonic()\n"
                "socket.create_connection((sys.argv[1], 5000), 5).close(); print(time.monotonic() - t)")


def test_impaired_link_delays_and_loses_frames_and_is_removed():
    hosts = ["x", "y"]
    links_before, qdiscs_before = root_links(), root_qdiscs()
    with pytest.raises(RuntimeError, match="boom"):
        with netns.NetnsLab(hosts, impairable=["x"]) as lab:
            assert lab.impair_backend in ("netem", "linkem")
            with pytest.raises(ValueError, match="not built impairable"):
                lab.impair("y", delay=0.01)
            lab.impair("x", delay=0.05, jitter=0.0)
            server = subprocess.Popen(lab.exec("y", [sys.executable, "-c", ACCEPT_ONE, lab.addr["y"]]),
                                      stdout=subprocess.PIPE)
            assert server.stdout.readline().strip() == b"listening"
            # a TCP handshake crosses x's link twice (SYN out, SYN-ACK back): at least 100 ms
            client = subprocess.run(lab.exec("x", [sys.executable, "-c", TIME_CONNECT, lab.addr["y"]]),
                                    capture_output=True, text=True)
            assert client.returncode == 0 and server.wait(timeout=10) == 0, client.stderr
            assert float(client.stdout) >= 0.1, client.stdout
            # a link that loses every other frame: of 100 datagrams from x, some never leave x's link
            lab.impair("x", loss=0.5)
            before = lab.link_stats()["x"]["up"]
            sent = subprocess.run(lab.exec("x", [sys.executable, "-c", SEND_UDP, lab.addr["y"]]), capture_output=True)
            assert sent.returncode == 0, sent.stderr
            after = lab.link_stats()["x"]["up"]
            assert after["frames"] - before["frames"] >= 100 and 10 <= after["dropped"] - before["dropped"] <= 90
            raise RuntimeError("boom")
    assert netns.lab_namespaces(os.getpid()) == []
    assert root_links() == links_before and root_qdiscs() == qdiscs_before  # nothing left outside the lab


def test_a_standby_on_another_host_takes_over_and_the_cut_off_orchestrator_stands_down(tmp_path):
    """run.standby across hosts: the router on its own host, the orchestrator on one, its standby on another.  The
    orchestrator's host is cut off (its link down: no FIN, the router sees it go only when the link's lease runs
    out, 1.5 s here); the standby takes over, the run goes on; the cut-off one, back on the network, holds no round
    and writes nothing (it stands down, exit 4); the records equal simulate, every event time once."""
    from splitspec_orchestrator.viewer.rrd_file import verify_rrd

    steps = 400
    scen = scenario_file(tmp_path, "paper_discrete", run={"steps": steps, "pace": 40, "standby": True})
    out = tmp_path / "out"
    rid = "standby-hosts"
    hosts = ["router", "orch1", "orch2", "plant"] + [f"a{i}" for i in AGENTS]
    logs = {h: tmp_path / f"{h}.log" for h in hosts}
    procs = {}
    env = {**ENV, "SPLITSPEC_LEASE_MS": "1500"}
    with netns.NetnsLab(hosts) as lab:
        def start(host, args):
            procs[host] = subprocess.Popen(lab.exec(host, cli(*args)), cwd=ROOT, env=env, stdout=open(logs[host], "wb"),
                                           stderr=subprocess.STDOUT)
        try:
            endpoint = f"tcp/{lab.addr['router']}:7447"
            start("router", ["router", "--listen", endpoint])
            wait_for_router(lab, "orch1", endpoint)
            start("orch1", ["orchestrator", scen, "--connect", endpoint, "--out", out, "--run-id", rid])
            start("orch2", ["standby", "--connect", endpoint, "--out", out, "--run-id", rid])
            start("plant", ["plant", "--connect", endpoint, "--run-id", rid])
            for i in AGENTS:
                start(f"a{i}", ["agent", "--id", i, "--connect", endpoint, "--run-id", rid])
            wait_for_event(out, "standby_ready", timeout=90)
            lab.cut("orch1")
            took = wait_for_event(out, "orchestrator_takeover", timeout=30)
            assert took["epoch"] == 2 and took["pid"] == procs["orch2"].pid
            lab.cut("orch1", off=False)  # back: it must not hold a round again
            assert procs["orch1"].wait(timeout=30) == 4, dump(logs["orch1"])
            assert "stands down and writes nothing more" in logs["orch1"].read_text(errors="replace")
            assert procs["orch2"].wait(timeout=120) == 0, dump(logs["orch2"])
            for h in ["plant"] + [f"a{i}" for i in AGENTS]:
                assert procs[h].wait(timeout=20) == 0, dump(logs[h])
        finally:
            stop_all(procs)
    ev = events(out)
    names = [e["event"] for e in ev]
    assert names.count("run_finished") == 1 and "run_failed" not in names and "rows_missing" not in names
    assert names.count("orchestrator_takeover") == 1
    assert not [e for e in ev if e["event"] in ("agent_lost", "agent_rejoined")]
    with np.load(out / "trajectory.npz") as z:
        assert np.array_equal(z["t"], np.arange(steps + 1))
    compare_with_simulate(out, scen, tmp_path)
    for seg in sorted(out.glob("run*.rrd")):
        ok, said = verify_rrd(seg)
        assert ok, (seg, said[-2000:])
