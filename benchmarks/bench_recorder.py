"""The recorder's cost to the orchestrator's round loop: the recorder before and after, side by side.

Feeds a :class:`Recorder` what the orchestrator feeds it (``driver.py``): one ``row`` per event time
(truth, every agent's estimate, alive set, graph index, round diagnostics) for a ring of m agents
with n = 6 states, the topology at the start and at every graph switch, a ``message_rejected``
event every so often, one agent lost (``mark_lost`` + ``agent_lost`` + topology) and rejoining.
Each (recorder, m) runs in a fresh process, twice:

1. paced at ``--rate`` rows per second (a round loop that waits for its agents between rows, as a
   real run does: 80 events/s at m = 8 in ``bench_runtime.py``): the wall time of each
   ``Recorder.row`` call seen by the caller (median, p99, max, mean), of the ``event`` /
   ``topology`` / ``mark_lost`` calls, and the process CPU time per row while rows come in (every
   thread: the background flusher and Rerun's encoder included; the feeding loop's own CPU
   subtracted; not the recorder's start and close), then the wall time of ``close``;
2. unpaced: rows per second through ``row`` (loop only) and including ``close`` (everything on disk).

"before" is the recorder of a git revision (default: where this branch left ``main``), loaded
from ``git archive`` into a temporary package; "after" is the working tree's.  Both write
``trajectory.npz``, ``events.jsonl`` and ``run.rrd`` to a temporary directory with the default
``flush_seconds`` = 1 s.  The machine is shared: compare the two columns, not absolute times;
``/proc/loadavg`` is printed before and after.

    .venv/bin/python benchmarks/bench_recorder.py [--rows 1000] [--rate 100] [--burst 20000]
        [--ms 8 16 32] [--before REV | --no-before]        (about 3 minutes on 2 cores)
"""

from __future__ import annotations

import argparse
import importlib
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from _common import loadavg

ROOT = Path(__file__).resolve().parents[1]
ENV = {**os.environ, "RERUN_ANALYTICS": "0"}
N = 6


def before_package(rev: str, into: Path) -> str:
    """Extract ``orchestrator/`` of ``rev`` as package ``splitspec_orchestrator_before`` under ``into``."""
    archive = subprocess.run(["git", "-C", str(ROOT), "archive", rev, "orchestrator"], capture_output=True,
                             check=True).stdout
    subprocess.run(["tar", "-x", "-C", str(into)], input=archive, check=True)
    (into / "orchestrator").rename(into / "splitspec_orchestrator_before")
    return "splitspec_orchestrator_before"


# ---------------------------------------------------------------------- worker (one process per run)


def feed(Recorder, out: Path, m: int, rows: int, rate: float | None, seed: int = 0) -> dict:
    """Feed one run's worth of recorder calls; the caller-side wall time of each call."""
    rng = np.random.default_rng(seed)
    ids = tuple(range(1, m + 1))
    ring = [(ids[(k + 1) % m], ids[k]) for k in range(m)] + [(ids[k], ids[(k + 1) % m]) for k in range(m)]
    ring2 = ring + [(ids[k], ids[(k + m // 2) % m]) for k in range(m)]
    x = rng.normal(size=(rows, N)).cumsum(axis=0) * 0.1
    noise = rng.normal(size=(rows, m, N)) * (0.97 ** np.arange(rows))[:, None, None]
    lost, lost_at, noticed, rejoin = 3, rows // 3, rows // 3 + 2, rows // 2
    alive = np.ones((rows, m), dtype=bool)
    alive[lost_at:rejoin, ids.index(lost)] = False
    import rerun  # noqa: F401  (imported by the recorder; not part of its cost per row)

    rec = Recorder(out, agent_ids=ids, n=N, steps=rows, time_mode="discrete", dt=1.0,
                   graph_names=("ring", "ring2"), run_id=f"bench-{m}", scenario_name=f"bench ring m={m}",
                   envelope_rate=0.9, gains=False)
    t_row: list[int] = []
    t_other: dict[str, list[int]] = {"event": [], "topology": [], "mark_lost": []}
    clock = time.perf_counter_ns

    def timed(kind, fn, *args, **kw):
        t = clock()
        fn(*args, **kw)
        t_other[kind].append(clock() - t)

    timed("event", rec.event, "run_started", 0.0, agents=list(ids), steps=rows)
    timed("topology", rec.topology, 0, "ring", ids, ring)
    graph = 0
    period = None if not rate else 1.0 / rate
    next_at = time.perf_counter()
    feed_cpu = 0.0
    cpu0, wall0 = time.process_time(), time.perf_counter()
    for tau in range(rows):
        if period:
            next_at += period
            delay = next_at - time.perf_counter()
            if delay > 0:
                time.sleep(delay)
        f0 = time.process_time()
        if tau and tau % 200 == 0:  # a graph switch every 200 event times
            graph = 1 - graph
            timed("topology", rec.topology, tau, ("ring", "ring2")[graph],
                  [a for a, ok in zip(ids, alive[tau]) if ok], (ring, ring2)[graph])
            timed("event", rec.event, "graph_switched", float(tau), graph=("ring", "ring2")[graph],
                  previous=("ring", "ring2")[1 - graph])
        if tau % 50 == 25:
            timed("event", rec.event, "message_rejected", float(tau), by="agent 1", reason="stale", count=1)
        reported = alive[tau].copy()
        if lost_at <= tau <= noticed:
            reported[ids.index(lost)] = True  # not noticed yet
        xhat = x[tau][None, :] + noise[tau]
        wall_ms = float(rng.uniform(5, 15))
        feed_cpu += time.process_time() - f0
        t = clock()
        rec.row(tau, x[tau], xhat, reported, graph, wall_ms=wall_ms, attempts=1, rejected=0)
        t_row.append(clock() - t)
        if tau == noticed:
            timed("mark_lost", rec.mark_lost, lost_at, lost)
            timed("event", rec.event, "agent_lost", float(lost_at), id=lost, tau=lost_at, reason="bench")
            timed("topology", rec.topology, lost_at, ("ring", "ring2")[graph],
                  [a for a in ids if a != lost], (ring, ring2)[graph])
        if tau == rejoin:
            timed("event", rec.event, "agent_rejoined", float(tau), id=lost, tau=tau, incarnation=1)
    loop_wall = time.perf_counter() - wall0
    cpu = time.process_time() - cpu0 - feed_cpu  # every thread's, during the loop
    t = time.perf_counter()
    rec.close()
    close_s = time.perf_counter() - t
    with np.load(out / "trajectory.npz") as f:
        assert f["t"].shape[0] == rows
    return {"row_ns": t_row, "other_ns": t_other, "loop_s": loop_wall, "close_s": close_s, "cpu_s": cpu,
            "rrd_bytes": (out / "run.rrd").stat().st_size}


def worker(args) -> None:
    if args.worker == "after":
        sys.path.insert(0, str(ROOT))
        pkg = "splitspec_orchestrator"
    else:
        tmp = Path(tempfile.mkdtemp(prefix="bench-rec-pkg."))
        pkg = before_package(args.worker, tmp)
        sys.path.insert(0, str(tmp))
    try:  # the recorder's module: records/recorder.py since the layout by role, recorder.py before
        Recorder = importlib.import_module(f"{pkg}.records.recorder").Recorder
    except ModuleNotFoundError:
        Recorder = importlib.import_module(f"{pkg}.recorder").Recorder
    with tempfile.TemporaryDirectory(prefix="bench-rec.") as d:
        paced = feed(Recorder, Path(d) / "paced", args.m, args.rows, args.rate)
        burst = feed(Recorder, Path(d) / "burst", args.m, args.burst, None, seed=1)
    def stats(ns):
        us = np.asarray(ns) / 1e3
        return {"median_us": float(np.median(us)), "p99_us": float(np.percentile(us, 99)),
                "max_us": float(us.max()), "mean_us": float(us.mean())}

    other = {k: (float(np.max(v)) / 1e3 if v else None) for k, v in paced["other_ns"].items()}
    print(json.dumps({
        "paced": {**stats(paced["row_ns"]), "other_max_us": other, "close_s": paced["close_s"],
                  "cpu_ms_per_row": paced["cpu_s"] / args.rows * 1e3},
        "burst": {**stats(burst["row_ns"]), "rows_per_s": args.burst / burst["loop_s"],
                  "total_rows_per_s": args.burst / (burst["loop_s"] + burst["close_s"]),
                  "close_s": burst["close_s"], "rrd_kb": burst["rrd_bytes"] / 1024},
    }))


# ---------------------------------------------------------------------- driver


def run_one(variant: str, m: int, args) -> dict:
    cmd = [sys.executable, __file__, "--worker", variant, "--m", str(m), "--rows", str(args.rows),
           "--rate", str(args.rate), "--burst", str(args.burst)]
    p = subprocess.run(cmd, capture_output=True, text=True, env=ENV, timeout=1800)
    if p.returncode != 0:
        raise SystemExit(f"{variant} m={m} failed:\n{p.stdout}\n{p.stderr}")
    return json.loads(p.stdout.strip().splitlines()[-1])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--rows", type=int, default=1000, help="rows of the paced run")
    ap.add_argument("--rate", type=float, default=100.0, help="rows per second of the paced run")
    ap.add_argument("--burst", type=int, default=20000, help="rows of the unpaced run")
    ap.add_argument("--ms", type=int, nargs="+", default=[8, 16, 32])
    ap.add_argument("--before", default=None, help="git revision of the 'before' recorder "
                    "(default: git merge-base HEAD main)")
    ap.add_argument("--no-before", action="store_true", help="measure the working tree only")
    ap.add_argument("--worker", help=argparse.SUPPRESS)
    ap.add_argument("--m", type=int, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.worker:
        worker(args)
        return
    variants = ["after"]
    if not args.no_before:
        rev = args.before
        if rev is None:
            p = subprocess.run(["git", "-C", str(ROOT), "merge-base", "HEAD", "main"], capture_output=True, text=True)
            rev = p.stdout.strip() if p.returncode == 0 else None
        if rev:
            variants = [rev, "after"]
        else:
            print("no git revision for 'before' (not a git checkout?): measuring the working tree only")
    names = {v: ("after" if v == "after" else f"before ({v[:10]})") for v in variants}
    print(f"loadavg before: {loadavg()}")
    print(f"n = {N}, flush_seconds = 1 (the default); every (recorder, m) in its own process\n")
    results = {(m, v): run_one(v, m, args) for m in args.ms for v in variants}

    def table(title, head, line):
        print(title)
        print(head)
        print("|---" * (head.count("|") - 1) + "|")
        for m in args.ms:
            for v in variants:
                print(line(m, names[v], results[(m, v)]))
        print()

    table(f"Paced: {args.rows} rows at {args.rate:g} rows/s (the caller's wall time per call; CPU of every "
          f"thread per row while rows come in)",
          "| m | recorder | row median | row p99 | row max | row mean | event / topology / mark_lost max "
          "| CPU per row | close |",
          lambda m, name, r: (lambda p: (
              f"| {m} | {name} | {p['median_us']:.0f} us | {p['p99_us']:.0f} us | {p['max_us'] / 1e3:.2f} ms | "
              f"{p['mean_us']:.0f} us | {p['other_max_us']['event'] / 1e3:.2f} / "
              f"{p['other_max_us']['topology'] / 1e3:.2f} / {p['other_max_us']['mark_lost'] / 1e3:.2f} ms | "
              f"{p['cpu_ms_per_row']:.2f} ms | {p['close_s']:.2f} s |"))(r["paced"]))
    table(f"Unpaced: {args.burst} rows as fast as the caller can",
          "| m | recorder | row median | row p99 | row max | rows/s (loop) | rows/s (with close) | close "
          "| run.rrd |",
          lambda m, name, r: (lambda b: (
              f"| {m} | {name} | {b['median_us']:.0f} us | {b['p99_us']:.0f} us | {b['max_us'] / 1e3:.1f} ms | "
              f"{b['rows_per_s']:,.0f} | {b['total_rows_per_s']:,.0f} | {b['close_s']:.2f} s | "
              f"{b['rrd_kb'] / 1024:.1f} MB |"))(r["burst"]))
    print(f"loadavg after: {loadavg()}")


if __name__ == "__main__":
    main()
