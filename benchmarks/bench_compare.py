"""`splitspec compare`'s baselines over many seeds: one batch against the per-seed loop.

    .venv/bin/python benchmarks/bench_compare.py [--seeds 200] [--loop-seeds 20] [--repeat 2] [--steps 200]
                                                 [--m 10 100]

The cases: ``examples/ring10_noise.yaml`` (m = 10, n = 8, the example users start from) and, for
every other ``--m``, a ring with one random chord per agent (``generate.ring_scenario``, n = 6, rate 0.9, one
output each) with process noise 0.05 and measurement noise 0.1; the KCF gets as many exchanges as the
case's design has q.

What is timed (wall clock and CPU time of this process) is the baselines' share of ``compare``:

* ``batched``: ``baselines.baseline_seeds`` on ``--seeds`` seeds (what ``compare`` runs now: the centralized
  Kalman predictor and the KCF of every seed at once, the KCF's gains computed once per chunk of seeds);
* ``looped``: ``baselines.baseline_trajectories`` once per seed (what ``compare`` ran before), on only
  ``--loop-seeds`` seeds, extrapolated per seed to ``--seeds`` (seeds cost alike).

The two alternate (looped, batched, looped, batched ...) ``--repeat`` times in this one invocation, each row
with the 1-minute load average read just before it; then the median per seed and their ratio.  The squared
errors of the seeds both ran are compared (to the largest of them, round-off expected; see
``tests/unit/test_baselines.py``); the script exits 1 if they differ by more than 1e-9.  Finally one whole
``compare`` (every estimator, ``--seeds`` seeds) is timed for information.  No timing assertions.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np
import scipy

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
from _common import loadavg  # noqa: E402

from splitspec_core.studies.baselines import baseline_seeds, baseline_trajectories  # noqa: E402
from splitspec_core.studies.comparison import compare  # noqa: E402
from splitspec_core.synthesis.designer import design  # noqa: E402
from splitspec_core.scenarios.generate import ring_scenario  # noqa: E402
from splitspec_core.scenarios.load import load_scenario, parse_scenario  # noqa: E402

TOL = 1e-9


def case(m: int):
    """``(label, scenario, exchanges)``."""
    if m == 10:
        sc = load_scenario(HERE.parent / "examples" / "ring10_noise.yaml")
        label = "ring10_noise"
    else:
        data = ring_scenario(m, 6, rate=0.9, chords=True)
        data["system"].update(process_noise=0.05, measurement_noise=0.1)
        sc = parse_scenario(data)
        label = f"ring+chords {m}"
    return label, sc, int(design(sc).q)


def looped(sc, seeds, exchanges: int, steps: int) -> dict:
    """The per-seed loop, reduced to ``baseline_seeds``'s squared errors."""
    out = {"centralized": [], "kcf": []}
    for s in seeds:
        r = baseline_trajectories(sc, s, exchanges=exchanges, steps=steps)
        out["centralized"].append(np.sum((r["centralized"] - r["x"]) ** 2, axis=1))
        out["kcf"].append(np.sum((r["kcf"] - r["x"][:, None, :]) ** 2, axis=(1, 2)))
    return {k: np.stack(v) for k, v in out.items()}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=200, help="seeds of the batched run")
    ap.add_argument("--loop-seeds", type=int, default=20, help="seeds of the looped run (extrapolated per seed)")
    ap.add_argument("--repeat", type=int, default=2)
    ap.add_argument("--steps", type=int, default=200)
    ap.add_argument("--m", type=int, nargs="+", default=[10, 100], help="10: ring10_noise; others: rings with chords")
    args = ap.parse_args()
    if min(args.seeds, args.loop_seeds, args.repeat, args.steps, *args.m) < 1:
        ap.error("every option must be positive")
    t_start = time.perf_counter()
    print(f"# numpy {np.__version__}, scipy {scipy.__version__}, {os.cpu_count()} cpus, "
          f"OPENBLAS_NUM_THREADS={os.environ.get('OPENBLAS_NUM_THREADS', 'unset')}; {args.steps} steps; "
          f"batched {args.seeds} seeds, looped {args.loop_seeds} (extrapolated), alternating, {args.repeat} each")
    worst = 0.0
    summary = []
    for m in args.m:
        label, sc, q = case(m)
        print(f"\n## {label}: m = {sc.m}, n = {sc.n}, KCF exchanges = {q}")
        print(f"{'run':>4} {'path':>8} {'seeds':>6} {'wall s':>8} {'cpu s':>8} {'ms/seed':>8} {'load 1m':>8}")
        per: dict = {"looped": [], "batched": []}
        res: dict = {}
        for r in range(args.repeat):
            for path, n in (("looped", args.loop_seeds), ("batched", args.seeds)):
                load = loadavg(1)
                w0, c0 = time.perf_counter(), time.process_time()
                if path == "looped":
                    res[path] = looped(sc, range(n), q, args.steps)
                else:
                    res[path] = baseline_seeds(sc, range(n), exchanges=q, steps=args.steps)
                wall, cpu = time.perf_counter() - w0, time.process_time() - c0
                per[path].append(wall / n)
                print(f"{r + 1:>4} {path:>8} {n:>6} {wall:>8.2f} {cpu:>8.2f} {1e3 * wall / n:>8.2f} {load:>8}",
                      flush=True)
        k = min(args.loop_seeds, args.seeds)
        for key in ("centralized", "kcf"):
            a, b = res["batched"][key].sq_error[:k], res["looped"][key]
            worst = max(worst, float(np.max(np.abs(a - b)) / np.max(np.abs(b))))
        ml, mb = float(np.median(per["looped"])), float(np.median(per["batched"]))
        load = loadavg(1)
        w0 = time.perf_counter()
        compare(sc, seeds=range(args.seeds), steps=args.steps)
        whole = time.perf_counter() - w0
        line = (f"{label}: per seed looped {1e3 * ml:.2f} ms, batched {1e3 * mb:.2f} ms: {ml / mb:.1f}x; "
                f"{args.seeds} seeds of the baselines {mb * args.seeds:.2f} s (looped {ml * args.seeds:.1f} s "
                f"extrapolated); whole compare of {args.seeds} seeds {whole:.1f} s (load {load})")
        print(line)
        summary.append(line)
    print("\n" + "\n".join(summary))
    print(f"batched vs looped: max |squared error difference| / max squared error = {worst:.1e} (limit {TOL:g}); "
          f"load average now {loadavg()}")
    print(f"# total wall time {time.perf_counter() - t_start:.1f} s")
    return 0 if worst <= TOL else 1


if __name__ == "__main__":
    sys.exit(main())
