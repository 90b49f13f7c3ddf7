"""Monte Carlo as one batch (issue "Scale", item 4): 1000 seeds of the m = 200 simulate case.

    .venv/bin/python benchmarks/bench_monte_carlo.py [--seeds 1000] [--loop-seeds 16] [--repeat 2] [--steps 500]
                                                     [--m 200] [--chunk 32]

The case is ``bench_simulate.py``'s m = 200 row: a random jointly observable discrete-time system
(n = 10) on a random ring plus 2m random arcs, ``place`` gains, q = 10 given, noise 0.01, 500 steps,
constant graph, no faults (its design, 20-40 s, is excluded and shown for information).

What is timed (wall clock and CPU time of this process, ``time.perf_counter`` / ``process_time``):

* ``batched``: ``simulate_seeds(des, seeds)`` on ``--seeds`` seeds, the path of
  ``splitspec simulate --monte-carlo N`` and ``ss.simulate(..., seeds=...)``: every seed's draws, the
  batched estimator in chunks of ``--chunk`` seeds, the per-step squared errors (no trajectories kept);
* ``looped``: the same call with ``force_loop=True``, i.e. ``simulate(des, seed=s)`` once per seed (what
  ``--monte-carlo`` ran before), on only ``--loop-seeds`` seeds: its total for ``--seeds`` seeds is
  *extrapolated* from its time per seed (seeds cost alike: same matrices, same step count).

The two alternate (looped, batched, looped, batched, ...) ``--repeat`` times in this one invocation; the
table gives each run with the 1-minute load average read just before it, then the medians and the ratio
of the medians per seed.  The batched and looped squared errors of the seeds both ran are compared
(relative difference to the larger norm; round-off expected, see ``tests/unit/test_montecarlo.py``), and
the peak resident memory of the process is printed (``ru_maxrss``: the design and scipy included).

No timing assertions (the machine is shared); the script exits 1 only if batched and looped disagree
beyond 1e-9.
"""

from __future__ import annotations

import argparse
import os
import resource
import sys
import time
from pathlib import Path

import numpy as np
import scipy

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import loadavg  # noqa: E402
from bench_simulate import get_design  # noqa: E402

from splitspec_core.simulation.montecarlo import simulate_seeds  # noqa: E402

REL_TOL = 1e-9


def timed(fn) -> tuple:
    """``(wall s, cpu s, load average before, result)``."""
    load = loadavg(1)
    w0, c0 = time.perf_counter(), time.process_time()
    out = fn()
    return time.perf_counter() - w0, time.process_time() - c0, load, out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=1000, help="seeds of the batched run")
    ap.add_argument("--loop-seeds", type=int, default=16, help="seeds of the looped run (extrapolated per seed)")
    ap.add_argument("--repeat", type=int, default=2)
    ap.add_argument("--steps", type=int, default=500)
    ap.add_argument("--m", type=int, default=200)
    ap.add_argument("--chunk", type=int, default=32)
    args = ap.parse_args()
    if min(args.seeds, args.loop_seeds, args.repeat, args.steps, args.m, args.chunk) < 1:
        ap.error("every option must be positive")
    t_start = time.perf_counter()
    des, dsecs, cert = get_design(args.m, 2 * args.m, args.steps)
    sc = des.scenario
    print(f"# numpy {np.__version__}, scipy {scipy.__version__}, {os.cpu_count()} cpus; m = {sc.m}, n = {sc.n}, "
          f"q = {des.q}, {len(des.graphs[0].arcs)} arcs, {args.steps} steps, discrete, noise 0.01; design "
          f"{dsecs:.1f} s (excluded), rate certified: {'yes' if cert else 'NO'}")
    print(f"# batched: {args.seeds} seeds in chunks of {args.chunk}; looped: {args.loop_seeds} seeds, "
          f"extrapolated to {args.seeds} per seed; alternating, {args.repeat} each")
    print()
    print(f"{'run':>4} {'path':>8} {'seeds':>6} {'wall s':>8} {'cpu s':>8} {'ms/seed':>8} "
          f"{'for ' + str(args.seeds) + ' s':>10} {'load 1m':>8}")
    per_seed: dict = {"looped": [], "batched": []}
    loop_runs = batch_runs = None
    for r in range(args.repeat):
        for path, n_seeds in (("looped", args.loop_seeds), ("batched", args.seeds)):
            wall, cpu, load, runs = timed(lambda: simulate_seeds(des, range(1, n_seeds + 1), steps=args.steps,
                                                                 chunk=args.chunk, force_loop=path == "looped"))
            per_seed[path].append(wall / n_seeds)
            total = wall / n_seeds * args.seeds
            mark = "" if path == "batched" else " (extrapolated)"
            print(f"{r + 1:>4} {path:>8} {n_seeds:>6} {wall:>8.2f} {cpu:>8.2f} {1e3 * wall / n_seeds:>8.2f} "
                  f"{total:>10.1f} {load:>8}{mark}", flush=True)
            if path == "looped":
                loop_runs = runs
            else:
                batch_runs = runs
    ml, mb = float(np.median(per_seed["looped"])), float(np.median(per_seed["batched"]))
    k = min(args.loop_seeds, args.seeds)
    rel = float(np.max(np.abs(batch_runs.sq_error[:k] - loop_runs.sq_error[:k])) / np.max(np.abs(loop_runs.sq_error[:k])))
    stats_b, stats_l = batch_runs.stats(), loop_runs.stats()
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024  # KiB on Linux
    print()
    print(f"median per seed: looped {1e3 * ml:.1f} ms, batched {1e3 * mb:.1f} ms: batched {ml / mb:.1f}x faster; "
          f"{args.seeds} seeds: batched {mb * args.seeds:.1f} s (median of measured runs), looped "
          f"{ml * args.seeds:.1f} s (extrapolated); load average now {loadavg()}")
    print(f"batched vs looped, seeds 1..{k}: max |sq_error difference| / max sq_error = {rel:.1e}; steady-state RMS "
          f"mean over all {args.seeds} seeds {stats_b['steady_rms_mean']:.6g} (looped {args.loop_seeds}: "
          f"{stats_l['steady_rms_mean']:.6g})")
    print(f"peak resident memory of this process: {peak:.0f} MiB (design, scipy and {args.chunk}-seed chunks included)")
    print(f"# total wall time {time.perf_counter() - t_start:.1f} s")
    return 0 if rel <= REL_TOL else 1


if __name__ == "__main__":
    sys.exit(main())
