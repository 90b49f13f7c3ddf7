"""Design time for growing networks (issue: design engine).

Random jointly observable systems (n = 10, every agent sees part of the
state) on random strongly connected graphs (a ring plus 2m random arcs),
discrete (spectral q) and continuous (g_bound + exact g_min), place gains.
Prints a table; no timing assertions anywhere (the machine is shared).

    .venv/bin/python benchmarks/bench_design.py [--sizes 5 20 50 100] [--repeat 1]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from splitspec_core.designer import design
from splitspec_core.generate import random_strongly_connected_arcs, random_system
from splitspec_core.scenario_model import parse_scenario


def scenario(m: int, n: int, time_mode: str, seed: int) -> dict:
    rng = np.random.default_rng(seed)
    A, Cs = random_system(rng, m, n, time=time_mode)
    arcs = random_strongly_connected_arcs(rng, m, extra=2 * m)
    d = {"rate": 0.9, "gains": "place", "q_method": "spectral"} if time_mode == "discrete" else \
        {"rate": 0.5, "gains": "place", "g": "auto"}
    return {
        "name": f"bench-{m}", "time": time_mode,
        "system": {"A": A.tolist(), "C": {i + 1: C.tolist() for i, C in enumerate(Cs)}},
        "graphs": {"g": {"arcs": [[j + 1, i + 1] for j, i in arcs]}},
        "design": d,
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", type=int, nargs="+", default=[5, 20, 50, 100])
    ap.add_argument("--n", type=int, default=10)
    ap.add_argument("--repeat", type=int, default=1)
    args = ap.parse_args()
    print(f"{'m':>5} {'n':>3} {'time':>10} {'nbar':>6} {'result':>22} {'seconds':>9}")
    for m in args.sizes:
        for mode in ("discrete", "continuous"):
            sc = parse_scenario(scenario(m, args.n, mode, seed=m))
            best = np.inf
            for _ in range(args.repeat):
                t0 = time.perf_counter()
                des = design(sc)
                best = min(best, time.perf_counter() - t0)
            nbar = des.cases[0].nbar
            res = f"q = {des.q}" if mode == "discrete" else f"g = {des.g:.4g} (min {max(des.g_mins.values()):.3g})"
            print(f"{m:>5} {args.n:>3} {mode:>10} {nbar:>6} {res:>22} {best:>9.3f}", flush=True)


if __name__ == "__main__":
    main()
