"""The loss sweep (issue "Networks that misbehave"): ring10, 5 levels x 20 seeds x 200 event times in under 30 s.

    .venv/bin/python benchmarks/bench_loss_sweep.py [--repeat 3] [--seeds 20] [--steps 200]

Times the whole command a user types, in a fresh process each time (interpreter start, imports, design,
the lossless reference and the five levels, the JSON and the PNG):

    splitspec compare SCENARIO --sweep-loss 0 0.05 0.1 0.2 0.4 --seeds 20 --steps 200 --out DIR

on ``examples/ring10_lossy.yaml`` (noise-free: one simulation per seed and level) and
``examples/ring10_noise.yaml`` (noisy: a noise-free one for the rate and a noisy one for the RMS), the two
interleaved, ``--repeat`` times each; medians, with the 1-minute load after each run.  Beside them, one
simulation of ring10 (200 event times, q = 6) on a perfect network and under loss 0.1, interleaved in this
process (the per-simulation cost of drawing losses and applying realized weights, as a ratio).
"""

from __future__ import annotations

import argparse
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from _common import loadavg

ROOT = Path(__file__).resolve().parents[1]
LEVELS = ["0", "0.05", "0.1", "0.2", "0.4"]


def sweep_seconds(scenario: Path, seeds: int, steps: int) -> float:
    with tempfile.TemporaryDirectory() as out:
        t0 = time.perf_counter()
        subprocess.run([sys.executable, "-m", "splitspec_orchestrator", "compare", str(scenario), "--out", out,
                        "--seeds", str(seeds), "--steps", str(steps), "--sweep-loss", *LEVELS],
                       check=True, stdout=subprocess.DEVNULL, cwd=ROOT)
        dt = time.perf_counter() - t0
        assert (Path(out) / "loss_sweep.json").is_file() and (Path(out) / "loss_sweep.png").is_file()
    return dt


def per_simulation(steps: int, repeat: int) -> tuple:
    import dataclasses

    import splitspec_core as ss
    from splitspec_core.synthesis.designer import design
    from splitspec_core.scenarios.specs import NetworkSpec
    from splitspec_core.simulation.simulator import simulate

    sc = ss.load_scenario(ROOT / "examples" / "ring10_lossy.yaml")
    des = design(sc)
    perfect = dataclasses.replace(des, scenario=dataclasses.replace(sc, network=NetworkSpec()))
    lossy = dataclasses.replace(des, scenario=dataclasses.replace(sc, network=NetworkSpec(loss=0.1)))
    a, b = [], []
    for k in range(repeat):
        for d, acc in ((perfect, a), (lossy, b)):
            t0 = time.perf_counter()
            simulate(d, seed=k, steps=steps, noise=False)
            acc.append(time.perf_counter() - t0)
    return statistics.median(a), statistics.median(b)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--seeds", type=int, default=20)
    ap.add_argument("--steps", type=int, default=200)
    args = ap.parse_args()
    print(f"load before: {loadavg()}")
    scen = {"ring10_lossy (noise-free)": ROOT / "examples" / "ring10_lossy.yaml",
            "ring10_noise (noisy)": ROOT / "examples" / "ring10_noise.yaml"}
    times: dict = {k: [] for k in scen}
    for r in range(args.repeat):
        for name, path in scen.items():
            dt = sweep_seconds(path, args.seeds, args.steps)
            times[name].append(dt)
            print(f"  run {r + 1} {name}: {dt:.2f} s  (load {loadavg(1)})", flush=True)
    print(f"\nsplitspec compare --sweep-loss {' '.join(LEVELS)} --seeds {args.seeds} --steps {args.steps}"
          " (+ the lossless reference)")
    print(f"  {'scenario':<28} {'median s':>9} {'min s':>7} {'max s':>7}  target")
    for name, ts in times.items():
        print(f"  {name:<28} {statistics.median(ts):9.2f} {min(ts):7.2f} {max(ts):7.2f}  < 30 s: "
              f"{'yes' if statistics.median(ts) < 30 else 'NO'}")
    plain, lossy = per_simulation(args.steps, max(5, 2 * args.repeat))
    print(f"\none simulation, ring10, {args.steps} event times, q = 6: perfect network {1000 * plain:.1f} ms, "
          f"loss 0.1 {1000 * lossy:.1f} ms (x{lossy / plain:.2f})   load {loadavg()}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
