"""Runtime speed: events per second of `splitspec run` beside the raw Zenoh one-way latency.

Measured side by side in one invocation (the machine is shared; compare ratios, not absolute times):

1. raw latency: a Zenoh router and two client processes on loopback play ping-pong with 100-byte
   messages through the router (the same topology as a run); one-way latency = median RTT / 2;
2. `splitspec run` (real processes, unpaced) of the paper's discrete example (m = 3, q = 6) and of
   an undirected ring of m = 8 agents; rounds per second from the run's `run_finished` event;
3. the ratio of the time per event to the protocol floor (q + 2) x one-way latency: one hop for the
   tick, q consensus exchanges, one hop for the estimates.

    .venv/bin/python benchmarks/bench_runtime.py [--steps 400] [--repeat 2]
"""

from __future__ import annotations

import argparse
import json
import os
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import yaml

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
ENV = {**os.environ, "RERUN_ANALYTICS": "0"}

PING = r'''
import sys, time, queue
from splitspec_core.runtime.bus import open_session
role, ep, n = sys.argv[1], sys.argv[2], int(sys.argv[3])
if role == "router":
    s = open_session("router", listen=[ep])
    sys.stdin.read()  # until the parent closes stdin
    s.close(); sys.exit()
s = open_session("client", connect=[ep])
q = queue.SimpleQueue()
mine, other = ("ping", "pong") if role == "a" else ("pong", "ping")
sub = s.declare_subscriber(f"bench/{other}", lambda smp: q.put(smp.payload.to_bytes()))
pub = s.declare_publisher(f"bench/{mine}")
time.sleep(1.0)
if role == "a":
    ts = []
    for _ in range(n):
        t0 = time.perf_counter(); pub.put(b"x" * 100); q.get(timeout=10); ts.append(time.perf_counter() - t0)
    print(sorted(ts)[n // 2])
else:
    for _ in range(n):
        q.get(timeout=30); pub.put(b"y" * 100)
s.close()
'''


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def one_way_latency(n: int = 1000) -> float:
    ep = f"tcp/127.0.0.1:{free_port()}"
    router = subprocess.Popen([sys.executable, "-c", PING, "router", ep, "0"], cwd=ROOT, env=ENV,
                              stdin=subprocess.PIPE)
    try:
        time.sleep(1.0)
        b = subprocess.Popen([sys.executable, "-c", PING, "b", ep, str(n)], cwd=ROOT, env=ENV)
        time.sleep(0.3)
        out = subprocess.run([sys.executable, "-c", PING, "a", ep, str(n)], cwd=ROOT, env=ENV, capture_output=True,
                             text=True, timeout=120)
        b.wait(timeout=30)
        return float(out.stdout.strip()) / 2
    finally:
        router.stdin.close()
        router.wait(timeout=10)


def ring_scenario(m: int, steps: int) -> dict:
    from splitspec_core.generate import random_system

    A, Cs = random_system(np.random.default_rng(8), m, 6, time="discrete")
    return {"name": f"ring{m}", "time": "discrete",
            "system": {"A": A.tolist(), "C": {i + 1: C.tolist() for i, C in enumerate(Cs)}},
            "graphs": {"ring": {"undirected": [[i, i % m + 1] for i in range(1, m + 1)]}},
            "design": {"rate": 0.9, "gains": "place", "q_method": "spectral"},
            "run": {"steps": steps, "seed": 1}}


def run_rate(scenario: Path, out: Path) -> tuple:
    r = subprocess.run([sys.executable, "-m", "splitspec_orchestrator", "run", str(scenario), "--out", str(out)],
                       cwd=ROOT, env=ENV, capture_output=True, text=True, timeout=600)
    if r.returncode != 0:
        raise RuntimeError(r.stderr[-2000:])
    ev = [json.loads(x) for x in (out / "events.jsonl").read_text().splitlines()]
    fin = next(e for e in ev if e["event"] == "run_finished")
    q = next(e for e in ev if e["event"] == "orchestrator_started")["q"]
    return fin["rounds_per_second"], q


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--steps", type=int, default=400)
    ap.add_argument("--repeat", type=int, default=2)
    args = ap.parse_args()
    tmp = Path(tempfile.mkdtemp(prefix="bench_runtime_"))
    paper = yaml.safe_load((ROOT / "examples/paper_discrete.yaml").read_text())
    paper["run"]["steps"] = args.steps
    scenarios = {"paper m=3": paper, "ring m=8": ring_scenario(8, args.steps)}
    lat = [one_way_latency() for _ in range(args.repeat)]
    one_way = min(lat)
    print(f"# {os.cpu_count()} cpus; raw Zenoh one-way latency through the router (median RTT/2, best of "
          f"{args.repeat}): {one_way * 1e6:.0f} us  (all: {', '.join(f'{x * 1e6:.0f}' for x in lat)})")
    print(f"{'scenario':>10} {'m':>3} {'q':>3} {'steps':>6} {'events/s':>9} {'ms/event':>9} {'floor ms':>9} "
          f"{'ratio':>6}")
    for name, sc in scenarios.items():
        path = tmp / f"{name.split()[0]}.yaml"
        path.write_text(yaml.safe_dump(sc))
        best, q = 0.0, None
        for k in range(args.repeat):
            rps, q = run_rate(path, tmp / f"{name.split()[0]}_{k}")
            best = max(best, rps)
        m = len(sc["system"]["C"])
        per = 1.0 / best
        floor = (q + 2) * one_way
        print(f"{name:>10} {m:>3} {q:>3} {args.steps:>6} {best:>9.1f} {per * 1e3:>9.2f} {floor * 1e3:>9.3f} "
              f"{per / floor:>6.1f}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
