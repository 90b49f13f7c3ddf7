"""Several hosts on one machine (Linux network namespaces): the process CLI across a real (virtual) network.

Every process runs in its own namespace with its own address on a private subnet and reaches the others only
through a bridge; the run must still equal `simulate`. Also run: the same with an external router host.
"""

import os
import subprocess
import sys
import time

import numpy as np
import pytest

from tests.integration import netns
from tests.integration.runtime_helpers import (ENV, ROOT, cli, compare_with_simulate, dump, events,
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
            wait_for_router(lab, "plant", endpoint)
            # the other hosts need nothing but the endpoint and the run id
            procs["plant"] = start_on(lab, "plant", ["plant", "--connect", endpoint, "--run-id", rid], logs["plant"])
            for i in AGENTS:
                procs[f"a{i}"] = start_on(lab, f"a{i}", ["agent", "--id", i, "--connect", endpoint, "--run-id", rid],
                                          logs[f"a{i}"])
            wait_for_event(out, "run_started", timeout=90)
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
            for p in procs.values():
                if p.poll() is None:
                    p.terminate()
            deadline = time.monotonic() + 5
            while any(p.poll() is None for p in procs.values()) and time.monotonic() < deadline:
                time.sleep(0.05)
        names = set(netns.lab_namespaces(os.getpid()))
        assert names == {lab.ns(h) for h in hosts} | {lab.ns("hub")}
    # cleaned up: no namespace, no link, no process of the lab left
    assert netns.lab_namespaces(os.getpid()) == []
    assert all(p.poll() is not None for p in procs.values())
    hellos = {(e["role"], e["id"]) for e in events(out) if e["event"] == "process_started"}
    assert hellos == {("plant", 0)} | {("agent", i) for i in AGENTS}
    compare_with_simulate(out, scen, tmp_path)
    assert np.load(out / "trajectory.npz")["t"].shape[0] == 121


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
