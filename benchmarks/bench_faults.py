"""Fault detection and recovery times of `splitspec run`, and the cost of `--secure`.

All from real runs on loopback (the machine is shared: compare within one invocation):

1. detection latency: a paced ring10 run; from outside, SIGKILL one agent and later SIGSTOP another;
   latency = wall time of the `agent_lost` event - wall time of the signal (a killed process closes
   its sockets; a frozen one is found by the orchestrator's status probe after 0.3 s without news
   of the round plus a 1 s status query);
2. restart latency: examples/ring10_faults.yaml; `agent_restarting` -> `agent_rejoined` (a new
   Python process: start-up, config fetch, local design, token);
3. secure vs plain: rounds per second of the unpaced paper example with `--insecure` and without it
   (the default: authentication + access control on the router), same invocation;
4. kill latency: from launching `splitspec kill --agent 1` (a subprocess, no --run-id) until the
   victim is reaped, N times, without a real run: a registry entry in a private
   SPLITSPEC_RUNTIME_DIR names a live dummy orchestrator and a dummy agent 1 (`python -c` sleepers
   whose argv contains 'splitspec', so kill's process-identity guard accepts them); with the
   start-up of `python -c pass` and /proc/loadavg for scale;
5. chaos (``--chaos``, or ``--only chaos``): every case of tests/chaos/cases.py once (the same functions
   the test suite runs, with their assertions), as a table ``case | outcome | wall | figures`` with
   /proc/loadavg after each: detection of SIGKILL / SIGSTOP, flood rate and RSS growth, stall survived,
   start-up and mid-run deaths, full disk, restart storm.  An outcome is ``ok``, ``KNOWN BUG`` (a product
   bug the suite reports as xfail; every other check of the case passed), ``FAIL`` or ``skipped``.

    .venv/bin/python benchmarks/bench_faults.py [--repeat 3] [--only kill|chaos] [--kill-runs 20] [--chaos]
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import yaml

from splitspec_orchestrator import registry

from _common import loadavg

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:  # tests.chaos.cases (the chaos primitives and cases)
    sys.path.insert(0, str(ROOT))
ENV = {**os.environ, "RERUN_ANALYTICS": "0"}
CLI = [sys.executable, "-m", "splitspec_orchestrator"]


def events(out: Path) -> list:
    p = out / "events.jsonl"
    return [json.loads(x) for x in p.read_text().splitlines() if x.strip()] if p.exists() else []


def wait_for(pred, timeout=90.0):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        v = pred()
        if v:
            return v
        time.sleep(0.01)
    raise TimeoutError


def detection(tmp: Path, k: int) -> dict:
    raw = yaml.safe_load((ROOT / "examples/ring10.yaml").read_text())
    raw["run"].update(steps=400, pace=40)
    scen = tmp / "ring.yaml"
    scen.write_text(yaml.safe_dump(raw))
    out = tmp / f"det{k}"
    p = subprocess.Popen([*CLI, "run", scen, "--out", out, "--run-id", f"bench{os.getpid()}"], cwd=ROOT, env=ENV,
                         stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        wait_for(lambda: any(e["event"] == "run_started" for e in events(out)))
        pids = {e["id"]: e["pid"] for e in events(out) if e["event"] == "process_started" and e["role"] == "agent"}
        res = {}
        for aid, sig, name in ((4, signal.SIGKILL, "SIGKILL"), (7, signal.SIGSTOP, "SIGSTOP")):
            time.sleep(1.0)
            t0 = time.time()
            os.kill(pids[aid], sig)
            lost = wait_for(lambda: next((e for e in events(out) if e["event"] == "agent_lost" and e["id"] == aid),
                                         None))
            res[name] = lost["wall"] - t0
        p.wait(timeout=120)
        return res
    finally:
        if p.poll() is None:
            p.kill()


def restart(tmp: Path) -> list:
    out = tmp / "restart"
    subprocess.run([*CLI, "run", ROOT / "examples/ring10_faults.yaml", "--out", out, "--run-id",
                    f"benchr{os.getpid()}"], cwd=ROOT, env=ENV, capture_output=True, check=True, timeout=300)
    ev = events(out)
    start = {e["id"]: e["wall"] for e in ev if e["event"] == "agent_restarting"}
    return [e["wall"] - start[e["id"]] for e in ev if e["event"] == "agent_rejoined"]


def rounds_per_second(tmp: Path, secure: bool, steps: int, k: int) -> float:
    raw = yaml.safe_load((ROOT / "examples/paper_discrete.yaml").read_text())
    raw["run"].update(steps=steps)
    scen = tmp / "paper.yaml"
    scen.write_text(yaml.safe_dump(raw))
    out = tmp / f"rps{int(secure)}-{k}"
    cmd = [*CLI, "run", scen, "--out", out, "--run-id", f"benchs{os.getpid()}"] + ([] if secure else ["--insecure"])
    subprocess.run(cmd, cwd=ROOT, env=ENV, capture_output=True, check=True, timeout=300)
    return next(e["rounds_per_second"] for e in events(out) if e["event"] == "run_finished")


SLEEPER = "import time; time.sleep(600)"


def kill_latency(tmp: Path, runs: int, cli: list, run_id: str = "rbench000") -> list:
    """Seconds from starting ``CLI kill --agent 1`` until the dummy agent 1 is reaped, ``runs`` times."""
    rt = tmp / "rt"
    rt.mkdir(mode=0o700, exist_ok=True)
    env = {**ENV, "SPLITSPEC_RUNTIME_DIR": str(rt)}
    orch = subprocess.Popen([sys.executable, "-c", SLEEPER, "splitspec-bench-orchestrator"])
    out = []
    try:
        for _ in range(runs):
            victim = subprocess.Popen([sys.executable, "-c", SLEEPER, "splitspec-bench-agent"])
            time.sleep(0.05)  # the entry is written after the process started, as the orchestrator does
            entry = {"run_id": run_id, "orchestrator": {"pid": orch.pid}, "out": str(tmp), "host": os.uname().nodename,
                     "started": time.time(), "written": registry.now_mark(), "agents": {"1": {"pid": victim.pid, "host": os.uname().nodename}}}
            (rt / f"{run_id}.{orch.pid}.json").write_text(json.dumps(entry))
            time.sleep(0.2)  # quiet
            t0 = time.perf_counter()
            k = subprocess.Popen([*cli, "kill", "--agent", "1"], cwd=ROOT, env=env, stdout=subprocess.DEVNULL,
                                 stderr=subprocess.PIPE)
            try:
                victim.wait(timeout=10)
            except subprocess.TimeoutExpired:
                victim.kill()
                victim.wait()
                raise RuntimeError(f"kill did not signal the victim: {k.communicate()[1]!r}") from None
            out.append(time.perf_counter() - t0)
            if k.wait() != 0:
                raise RuntimeError(f"kill failed: {k.stderr.read()!r}")
            k.stderr.close()
    finally:
        orch.kill()
        orch.wait()
    return out


def startup(cmd: list, runs: int) -> list:
    out = []
    for _ in range(runs):
        t0 = time.perf_counter()
        subprocess.run(cmd, check=True)
        out.append(time.perf_counter() - t0)
    return out


def report_kill(tmp: Path, runs: int) -> None:
    print(f"kill latency (launch -> victim reaped), {runs} runs each, load average before {loadavg()}:")
    script = Path(sys.executable).parent / "splitspec"
    for name, cmd in (("splitspec kill (console script)", [sys.executable, script]),
                      ("python -m splitspec_orchestrator kill", CLI)):
        v = kill_latency(tmp, runs, cmd)
        print(f"  {name:34s} median {1000 * np.median(v):6.1f} ms   max {1000 * max(v):6.1f} ms")
    v = startup([sys.executable, "-c", "pass"], runs)
    name = "python -c pass (start-up, scale)"
    print(f"  {name:34s} median {1000 * np.median(v):6.1f} ms   max {1000 * max(v):6.1f} ms")
    print(f"  load average after {loadavg()}")


def report_chaos(tmp: Path) -> None:
    """Every chaos case once, as a table (the cases assert; a failure is an outcome, not an abort)."""
    import traceback

    from tests.chaos.cases import CASES, MountUnavailable, can_mount

    needs_mount = {"full disk", "read-only --out"}
    print(f"chaos cases (tests/chaos/cases.py), load average before {loadavg()}:")
    rows = []
    for name, case in CASES.items():
        d = tmp / ("chaos-" + "".join(c if c.isalnum() else "-" for c in name))
        d.mkdir()
        t0 = time.monotonic()
        if name in needs_mount and not can_mount():
            outcome, figures = "skipped", "needs root (tmpfs)"
        else:
            try:
                f = case(d)
                outcome, figures = "ok", ", ".join(f"{k} {v}" for k, v in f.items())
            except MountUnavailable as exc:
                outcome, figures = "skipped", str(exc)
            except AssertionError as exc:
                outcome, figures = "FAIL", " ".join(str(exc).split())[:300]
            except Exception as exc:  # noqa: BLE001 - a broken case is reported, the table goes on
                outcome, figures = "ERROR", "".join(traceback.format_exception_only(exc)).strip()[:300]
        rows.append((name, outcome, time.monotonic() - t0, figures, loadavg()))
        print(f"  {name:26s} | {outcome:9s} | {rows[-1][2]:5.1f} s | load {rows[-1][4]} | {figures}", flush=True)
    total = sum(r[2] for r in rows)
    ok = sum(r[1] == "ok" for r in rows)
    print(f"  {ok}/{len(rows)} ok, {total:.0f} s in all, load average after {loadavg()}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--steps", type=int, default=400)
    ap.add_argument("--only", choices=["kill", "chaos"],
                    help="kill: only the kill-latency measurement (no real runs); chaos: only the chaos table")
    ap.add_argument("--chaos", action="store_true", help="also run every chaos case once (tests/chaos/cases.py)")
    ap.add_argument("--kill-runs", type=int, default=20)
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        if args.only == "chaos":
            report_chaos(tmp)
            return
        report_kill(tmp, args.kill_runs)
        if args.only == "kill":
            return
        det = {"SIGKILL": [], "SIGSTOP": []}
        for r in range(args.repeat):
            for k, v in detection(tmp, r).items():
                det[k].append(v)
        lease = os.environ.get("SPLITSPEC_LEASE_MS", "10000 (default)")
        print(f"detection latency, ring10, link lease {lease} ms (frozen: status probe), {args.repeat} runs:")
        for k, v in det.items():
            print(f"  {k:8s} median {1000 * np.median(v):7.1f} ms   max {1000 * max(v):7.1f} ms")
        rs = restart(tmp)
        print(f"restart by the scenario (spawn -> admitted), ring10_faults: {', '.join(f'{r:.2f} s' for r in rs)}")
        plain, secure = [], []
        for r in range(args.repeat):  # interleaved, so both see the same machine load
            plain.append(rounds_per_second(tmp, False, args.steps, r))
            secure.append(rounds_per_second(tmp, True, args.steps, r))
        p, s = float(np.median(plain)), float(np.median(secure))
        print(f"paper example, {args.steps} steps: --insecure {p:.1f} rounds/s, secure (default) {s:.1f} rounds/s "
              f"(secure / plain = {s / p:.2f})")
        if args.chaos:
            report_chaos(tmp)


if __name__ == "__main__":
    main()
