"""Runtime speed: ms per event of `splitspec run` on rings against the CPU cost of a bare Zenoh delivery.

Measured side by side in one invocation (the machine is shared: compare ratios, quote the load average):

1. bare zenoh-python: a router and two client processes play ping-pong through the router with
   100-byte messages and default callbacks (what a plain zenoh-python program does); CPU seconds of
   the three processes (user + sys) per delivered message;
2. the protocol's floor: deliveries per event time x that CPU cost.  Deliveries per event on a ring
   (every agent hears d = 2 neighbours), m agents, q exchanges:
     old protocol (before issue 14)  3m + 2 + 2mq: tick m + 1, y m (m publishes), truth 1, z 2mq, xhat m;
     new protocol                    3m + 2 + 2mq: tick m + 1, y m (one publish), truth 1, z 2m(q - 1),
                                     xhat 3m (each x_i(tau + 1) goes to the orchestrator and the 2 neighbours,
                                     and is their z_i(0) of the next round);
   publishes per event: old 2m + 2 + mq, new 3 + mq (see docs/benchmarks/index.md, "Runtime: messages per round");
3. `splitspec run` (real processes, unpaced) of undirected rings, n = 6 (``--pressure N``: each ring also
   with N more processes that only write to their memory, row ``pres``, interleaved: the cache pressure of
   more processes without their messages): ms/event (from the run's
   ``run_finished`` event), the ratio to the old protocol's floor, ms/event per delivery of the old protocol
   (us/deliv) against the first ring of the invocation (x first) and against the bare CPU per delivery
   spread over the machine's cores (x floor: below 1, a delivery costs less wall time than a bare Zenoh
   message's CPU on one of them), the agents' CPU per agent and event time, the peak RSS per agent and of the
   orchestrator (sampled from /proc every 0.2 s), and start-up: spawn of the first process to the first
   round (``run_started``), and per process from its spawn to its liveliness token (``process_ready``).

With ``--baseline DIR`` (a checkout of an older commit with its own ``.venv``, e.g. made with
``git worktree add /tmp/base <commit> && make -C /tmp/base setup``) every ring also runs with that
checkout, interleaved (new, old, new, old...), and the table shows both.

With ``--deadline D`` every ring also runs with ``network: {deadline: D}`` and nothing else (no loss, no
delay): each sub-round waits at most D seconds for its neighbours, so the agent reads a monotonic clock
and runs a timer (``NodeShell.run(timer=...)``) even when every message is on time.  Row ``dl`` of the
table; the plain ring (no ``network:``: every sub-round waits for all its neighbours) is row ``new``,
interleaved (new, dl, new, dl...).  D must be long enough that nothing is late on loopback (0.5 s is):
every run's ``trajectory.npz`` ``lost`` is checked and its count shown (column ``lost``, all runs of the
row).  A second table gives, per ring, the ratio deadline / plain of the medians, the median of the ratios
of the interleaved pairs (each pair ran back to back, so a change of load between pairs cancels) and their
interquartile range, with the 1-minute load average read after each run (min-max; the run's own
processes count in it too).  ``--bare-messages 0`` skips the bare Zenoh measurement (the floors, which the
deadline comparison does not need).  With both ``--baseline`` and ``--deadline`` the baseline runs both
too (rows ``old`` and ``odl``; it must know ``network:``), so one invocation compares the deadline's cost
before and after a change, interleaved.

    .venv/bin/python benchmarks/bench_runtime.py [--sizes 3 8 16 32] [--q 3 6] [--steps 200] [--repeat 2]
        [--baseline DIR] [--deadline SECONDS] [--bare-messages N] [--pressure N]

    # the deadline policy without loss against wait-for-all (target: at most 1.1x ms/event)
    .venv/bin/python benchmarks/bench_runtime.py --sizes 8 16 32 --q 3 --steps 200 --repeat 9 --deadline 0.5 \
        --bare-messages 0
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import socket
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np
import yaml

from _common import loadavg

from splitspec_core.parallel import available_workers

ROOT = Path(__file__).resolve().parents[1]
ENV = {**os.environ, "RERUN_ANALYTICS": "0"}

PING = r'''
import sys, time, queue, json, zenoh
role, ep, n = sys.argv[1], sys.argv[2], int(sys.argv[3])
c = zenoh.Config()
c.insert_json5("mode", json.dumps("router" if role == "router" else "client"))
c.insert_json5("listen/endpoints" if role == "router" else "connect/endpoints", json.dumps([ep]))
c.insert_json5("scouting/multicast/enabled", "false")
s = zenoh.open(c)
if role == "router":
    sys.stdin.read()  # until the parent closes stdin
    s.close(); sys.exit()
q = queue.SimpleQueue()
mine, other = ("ping", "pong") if role == "a" else ("pong", "ping")
sub = s.declare_subscriber(f"bench/{other}", lambda smp: q.put(smp.payload.to_bytes()))
pub = s.declare_publisher(f"bench/{mine}")
time.sleep(1.0)
if role == "a":
    for _ in range(n):
        pub.put(b"x" * 100); q.get(timeout=10)
else:
    for _ in range(n):
        q.get(timeout=60); pub.put(b"y" * 100)
s.close()
'''


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _children_cpu() -> float:
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


def bare_cpu_per_delivery(n: int = 5000) -> float:
    """CPU seconds (router + both clients, user + sys) per delivered 100-byte message, ping-pong through a router.

    The fixed costs (interpreter start, session open, the 1 s settle) are removed by running n and n/5
    round trips and taking the difference."""
    def run(k: int) -> float:
        ep = f"tcp/127.0.0.1:{free_port()}"
        before = _children_cpu()
        router = subprocess.Popen([sys.executable, "-c", PING, "router", ep, "0"], env=ENV, stdin=subprocess.PIPE)
        time.sleep(0.5)
        b = subprocess.Popen([sys.executable, "-c", PING, "b", ep, str(k)], env=ENV)
        time.sleep(0.3)
        subprocess.run([sys.executable, "-c", PING, "a", ep, str(k)], env=ENV, check=True, timeout=300)
        b.wait(timeout=60)
        router.stdin.close()
        router.wait(timeout=30)
        return _children_cpu() - before

    small, big = max(1, n // 5), n
    cpu_small, cpu_big = run(small), run(big)
    return (cpu_big - cpu_small) / (2 * (big - small))  # two deliveries per round trip


def deliveries_old(m: int, q: int) -> int:
    return 3 * m + 2 + 2 * m * q


def deliveries_new(m: int, q: int) -> int:
    return (m + 1) + m + 1 + 2 * m * (q - 1) + 3 * m  # = 3m + 2 + 2mq on a ring


def runtime_ring(m: int, q: int, steps: int, *, deadline: float | None = None) -> dict:
    """The benchmark's ring (random_system, any m >= 3; generate.ring_scenario needs m >= 2 ceil(n / 2)).

    ``deadline``: the same ring with ``network: {deadline: D}`` (no loss, no delay)."""
    from splitspec_core.scenarios.generate import random_system

    A, Cs = random_system(np.random.default_rng(8), m, 6, time="discrete")
    sc = {"name": f"ring{m}-q{q}", "time": "discrete",
          "system": {"A": A.tolist(), "C": {i + 1: C.tolist() for i, C in enumerate(Cs)}},
          "graphs": {"ring": {"undirected": [[i, i % m + 1] for i in range(1, m + 1)]}},
          "design": {"rate": 0.999, "gains": "place", "q_method": "spectral", "q": q},
          "run": {"steps": steps, "seed": 1}}
    if deadline is not None:
        sc["network"] = {"deadline": deadline}
    return sc


class RssSampler:
    """Peak RSS and CPU per process of a run (its ``--run-id`` in the command line), sampled from /proc.

    A sample counts for the role the process's command line shows at that moment: a child the orchestrator
    has forked but not yet exec'd shows the orchestrator's command line and, for a moment, a copy of its
    memory (counted as an agent's, it made the agents' peak at m = 32 up to 6 MB higher than any agent's).
    The agents of a local run are forks of the agent fork server, whose command line they share (it names
    the run).  CPU (user + system) is taken at the first sample after the run's ``run_started`` event and at
    the last one before its ``run_finished``: :meth:`cpu_per_round` is the rounds' CPU, without start-up.
    """

    def __init__(self, run_id: str, events: Path):
        self.run_id, self.events, self.peak = run_id, events, {}
        self.cpu0: dict | None = None
        self.cpu1: dict = {}
        self.t0 = self.t1 = None
        self._stop = threading.Event()
        self._t = threading.Thread(target=self._loop, daemon=True)
        self._t.start()

    def _phase(self) -> str:
        try:
            text = self.events.read_text()
        except OSError:
            return "starting"
        return "finished" if "run_finished" in text else "running" if "run_started" in text else "starting"

    def _loop(self) -> None:
        needle = self.run_id.encode()
        tick = os.sysconf("SC_CLK_TCK")
        while not self._stop.is_set():
            phase = self._phase()
            cpu = {}
            for d in os.listdir("/proc"):
                if not d.isdigit():
                    continue
                try:
                    cmd = Path(f"/proc/{d}/cmdline").read_bytes()
                    if needle not in cmd:
                        continue
                    rss = next(int(line.split()[1]) for line in Path(f"/proc/{d}/status").read_text().splitlines()
                               if line.startswith("VmRSS:"))
                    stat = Path(f"/proc/{d}/stat").read_text().rsplit(")", 1)[1].split()
                except (OSError, StopIteration, ValueError, IndexError):
                    continue
                role = ("agent" if b"splitspec_agents" in cmd else "plant" if b"splitspec_plant" in cmd
                        else "orchestrator" if b"orchestrator" in cmd else "other")
                key = (int(d), role)
                self.peak[key] = max(self.peak.get(key, 0), rss)
                cpu[key] = (int(stat[11]) + int(stat[12])) / tick
            if phase == "running":
                if self.cpu0 is None:
                    self.cpu0, self.t0 = cpu, time.monotonic()
                self.cpu1, self.t1 = cpu, time.monotonic()
            time.sleep(0.2)

    def stop(self) -> dict:
        self._stop.set()
        self._t.join()
        out: dict = {}
        for (_pid, role), kb in self.peak.items():
            out.setdefault(role, []).append(kb / 1024)
        return out

    def cpu_per_round(self, role: str, rounds_per_second: float) -> float:
        """CPU seconds per round of all processes of ``role`` present at both samples (nan without two)."""
        if self.cpu0 is None or self.t1 is None or self.t1 <= self.t0:
            return float("nan")
        used = sum(c - self.cpu0[k] for k, c in self.cpu1.items() if k[1] == role and k in self.cpu0)
        return used / ((self.t1 - self.t0) * rounds_per_second)


PRESSURE = r'''
import sys, time
buf = bytearray(int(sys.argv[1]) * 1024)
end = time.monotonic() + float(sys.argv[2])
while time.monotonic() < end:
    buf[::64] = bytes(len(buf) // 64)  # one write per cache line
    time.sleep(0.005)
'''


def pressure(count: int, seconds: float = 3600.0) -> list:
    """``count`` processes that each write to every cache line of 512 KB every 5 ms: the cache pressure of that
    many more processes, without their messages (``--pressure``)."""
    return [subprocess.Popen([sys.executable, "-c", PRESSURE, "512", str(seconds)]) for _ in range(count)]


def run_ring(python: str, cwd: Path, scenario: Path, out: Path, run_id: str, wait: float, m: int = 1,
             pressure_count: int = 0) -> dict:
    sleepers = pressure(pressure_count)
    sampler = RssSampler(run_id, out / "events.jsonl")
    t0 = time.time()
    r = subprocess.run([python, "-m", "splitspec_orchestrator", "run", str(scenario), "--out", str(out),
                        "--run-id", run_id, "--wait", str(wait)], cwd=cwd, env=ENV, capture_output=True, text=True,
                       timeout=1800)
    rss = sampler.stop()
    for p in sleepers:
        p.kill()
        p.wait()
    if r.returncode != 0:
        raise RuntimeError(f"run failed ({r.returncode}): {r.stderr[-2000:]}")
    ev = [json.loads(x) for x in (out / "events.jsonl").read_text().splitlines()]
    fin = next(e for e in ev if e["event"] == "run_finished")
    started = next(e for e in ev if e["event"] == "run_started")
    ready = [e["startup_s"] for e in ev if e["event"] == "process_ready" and "startup_s" in e]
    load = loadavg(1)
    with np.load(out / "trajectory.npz") as traj:  # consensus messages that did not count (none on a perfect network)
        lost = len(traj["lost"]) if "lost" in traj.files else 0
    agent_us = sampler.cpu_per_round("agent", fin["rounds_per_second"]) * 1e6 / m
    return {"ms": 1e3 / fin["rounds_per_second"], "startup": started["wall"] - t0, "agent_us": agent_us,
            "ready_max": max(ready) if ready else None,
            "agent_mb": max(rss.get("agent", [0])), "orch_mb": max(rss.get("orchestrator", [0])),
            "lost": lost, "load": float("nan") if load == "n/a" else float(load)}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", type=int, nargs="+", default=[3, 8, 16, 32])
    ap.add_argument("--q", type=int, nargs="+", default=[3, 6])
    ap.add_argument("--steps", type=int, default=200)
    ap.add_argument("--repeat", type=int, default=2)
    ap.add_argument("--bare-messages", type=int, default=5000, help="0: skip the bare Zenoh measurement (no floors)")
    ap.add_argument("--baseline", type=Path, help="an older checkout with its own .venv, run interleaved")
    ap.add_argument("--pressure", type=int, default=0, metavar="N",
                    help="also run every ring (row 'pres', interleaved) with N more processes writing 512 KB each "
                         "every 5 ms: the cache pressure of more processes without their messages")
    ap.add_argument("--deadline", type=float, metavar="SECONDS",
                    help="also run every ring with network: {deadline: SECONDS} (no loss, no delay), interleaved")
    args = ap.parse_args()
    if args.baseline is not None and not (args.baseline / ".venv/bin/python").is_file():
        ap.error(f"--baseline {args.baseline}: no .venv/bin/python there (make -C {args.baseline} setup)")
    if min(args.sizes) < 3 or min(args.q) < 1:
        ap.error("--sizes must be rings of at least 3 agents and --q at least 1")
    if args.deadline is not None and not args.deadline > 0:
        ap.error(f"--deadline must be positive seconds, not {args.deadline:g}")
    if args.bare_messages < 0 or 0 < args.bare_messages < 5:
        ap.error("--bare-messages must be 0 (skip) or at least 5")
    tmp = Path(tempfile.mkdtemp(prefix="bench_runtime_"))
    print(f"# {os.cpu_count()} cpus; load average {loadavg()}", flush=True)
    if args.bare_messages:
        bare = [bare_cpu_per_delivery(args.bare_messages) for _ in range(args.repeat)]
        cpu = statistics.median(bare)
        print(f"# bare zenoh-python through a router: {cpu * 1e6:.0f} us CPU per delivery (median of "
              f"{', '.join(f'{b * 1e6:.0f}' for b in bare)})", flush=True)
    else:
        cpu = float("nan")
        print("# bare zenoh-python: skipped (--bare-messages 0): no floors", flush=True)
    # (name, python, checkout, deadline of the scenario)
    variants = [("new", sys.executable, ROOT, None)]
    if args.deadline is not None:
        variants.append(("dl", sys.executable, ROOT, args.deadline))
        print(f"# dl: network: {{deadline: {args.deadline:g}}}, no loss, no delay; new: no network: (wait for all)",
              flush=True)
    if args.pressure:
        variants.append(("pres", sys.executable, ROOT, None))
        print(f"# pres: the same code with {args.pressure} pressure processes during every run", flush=True)
    if args.baseline is not None:
        variants.append(("old", str(args.baseline / ".venv/bin/python"), args.baseline, None))
        if args.deadline is not None:
            variants.append(("odl", str(args.baseline / ".venv/bin/python"), args.baseline, args.deadline))
    cores = available_workers()  # the CPUs this process may run on
    print(f"# us/deliv: ms/event over the old protocol's deliveries (3m + 2 + 2mq); x first: against the first ring "
          f"of the same q and code; x floor: against the bare CPU per delivery over the {cores} cores; agent us: "
          f"CPU per agent and event time (user + system, the rounds only)")
    print(f"{'ring':>8} {'q':>2} {'code':>4} {'ms/event':>9} {'old floor':>9} {'new floor':>9} {'ratio':>6} "
          f"{'us/deliv':>8} {'x first':>7} {'x floor':>7} {'agent us':>8} "
          f"{'agent MB':>8} {'orch MB':>7} {'start s':>7} {'ready s':>7} {'lost':>4}  load")
    first: dict = {}  # (q, code) -> us per delivery of the first ring
    pairs = []  # (m, q, {name: [run results]}) for the deadline table
    for m in args.sizes:
        for q in args.q:
            paths = {}
            for name, _, _, deadline in variants:
                paths[name] = tmp / f"ring{m}-q{q}-{name}.yaml"
                paths[name].write_text(yaml.safe_dump(runtime_ring(m, q, args.steps, deadline=deadline)))
            res: dict = {name: [] for name, _, _, _ in variants}
            for k in range(args.repeat):
                for name, python, cwd, _ in variants:  # interleaved: new, dl, old, new, dl, old...
                    rid = f"bench-{m}-{q}-{name}-{k}-{os.getpid()}"
                    res[name].append(run_ring(python, cwd, paths[name], tmp / rid, rid, wait=max(60.0, 3.0 * m), m=m,
                                              pressure_count=args.pressure if name == "pres" else 0))
            floor_old = deliveries_old(m, q) * cpu * 1e3
            floor_new = deliveries_new(m, q) * cpu * 1e3
            load = loadavg(1)
            for name, _, _, _ in variants:
                rs = res[name]
                ms = statistics.median(r["ms"] for r in rs)
                ready = [r["ready_max"] for r in rs if r["ready_max"] is not None]
                per = ms * 1e3 / deliveries_old(m, q)
                base = first.setdefault((q, name), per)
                print(f"{m:>8} {q:>2} {name:>4} {ms:>9.2f} {floor_old:>9.2f} {floor_new:>9.2f} {ms / floor_old:>6.2f} "
                      f"{per:>8.1f} {per / base:>7.2f} {per / (cpu * 1e6 / cores):>7.2f} "
                      f"{statistics.median(r['agent_us'] for r in rs):>8.0f} "
                      f"{max(r['agent_mb'] for r in rs):>8.0f} {max(r['orch_mb'] for r in rs):>7.0f} "
                      f"{statistics.median(r['startup'] for r in rs):>7.1f} "
                      f"{(statistics.median(ready) if ready else float('nan')):>7.2f} "
                      f"{sum(r['lost'] for r in rs):>4}  {load}", flush=True)
            pairs.append((m, q, res))
    if args.deadline is not None:
        print(f"\n# deadline {args.deadline:g} s (no loss, no delay) against wait-for-all: ms/event, medians of "
              f"{args.repeat} interleaved pairs; pair ratio: median over the pairs of dl / new (run back to back)")
        print(f"{'ring':>8} {'q':>2} {'plain':>8} {'deadline':>8} {'ratio':>6} {'pair ratio':>10} {'pair IQR':>11} "
              f"{'lost':>4}  load (1 min, min-max over the runs)")
        checkouts = [("new", "dl")] + ([("old", "odl")] if args.baseline is not None else [])
        for m, q, res in pairs:
            for p_name, d_name in checkouts:
                plain, dl = res[p_name], res[d_name]
                a, b = statistics.median(r["ms"] for r in plain), statistics.median(r["ms"] for r in dl)
                prs = [d["ms"] / p["ms"] for p, d in zip(plain, dl)]
                q1, _, q3 = statistics.quantiles(prs, n=4) if len(prs) > 1 else (prs[0],) * 3
                loads = [r["load"] for r in plain + dl]
                print(f"{m:>8} {q:>2} {a:>8.2f} {b:>8.2f} {b / a:>5.3f}x {statistics.median(prs):>9.3f}x "
                      f"{q1:>5.3f}-{q3:>5.3f} {sum(r['lost'] for r in dl):>4}  "
                      f"{min(loads):.2f}-{max(loads):.2f}" + ("  (baseline)" if p_name == "old" else ""), flush=True)
        nlost = sum(r["lost"] for _, _, res in pairs for _, d_name in checkouts for r in res[d_name])
        print(f"# lost in the deadline runs' trajectory.npz: {nlost} message{'s' * (nlost != 1)}"
              + ("" if nlost == 0 else " (the deadline was too short for this machine: the figures are not "
                 "'without loss')"), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
