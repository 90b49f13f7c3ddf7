"""Designs of rounded models (issue "Honest designs on imperfect models"): exact against 6 and 4 decimals.

Random structured systems (:func:`splitspec_core.scenarios.generate.random_system`: oscillator blocks in a
random orthogonal basis, each agent one output seeing some blocks, so most agents have a 2- or
4-dimensional unobservable space), continuous and discrete, 4 to 7 agents, two random strongly
connected graphs (discrete: random switching between them, as ``tests/unit/test_simulate.py`` draws them;
continuous: the first graph held constant).  Each system
is designed three times with default settings: exact, and with every entry of ``A`` and ``C``
rounded to 6 and to 4 decimals (as a model copied from a paper or a data sheet).  For each:

* ``n_i same``: every agent's ``dim V_i`` equals the exact design's;
* ``|K| x``: the largest ``||K_i||_2`` over the exact design's;
* ``peak x``: the noise-free simulation's largest error (all agents, all times) over the exact one's,
  from the same initial state and estimates;
* ``rate``: the measured decay (``analysis.fit_decay``) against the designed rate (discrete: lower is
  faster, continuous: higher is faster);
* ``certified``, ``c`` (the transient constant), and the number of warning lines.

``--rank-tol 1e-9`` designs with that threshold instead of the default (close to the former
default: a rounded model's weak directions then count as seen).

``--splits N`` counts, over N random systems (n = 4..10, m = 3..8, continuous and discrete, the
population of :mod:`splitspec_core.model.observability`'s docstring), the rank decisions alone: how many exact
systems' splits the default rule changes (against the round-off floor), how many rounded models (6 and 4
decimals) get the exact system's split, and how many exact systems become only weakly jointly observable.

    .venv/bin/python benchmarks/bench_rounded.py [--systems 7] [--rank-tol auto]
    .venv/bin/python benchmarks/bench_rounded.py --splits 400
"""

from __future__ import annotations

import argparse
import math

import numpy as np

from splitspec_core.simulation.metrics import fit_decay
from splitspec_core.synthesis.conditioning import conditioning
from splitspec_core.synthesis.designer import design
from splitspec_core.scenarios.generate import random_strongly_connected_arcs, random_system
from splitspec_core.synthesis.verdict import rate_certificate
from splitspec_core.scenarios.load import parse_scenario
from splitspec_core.simulation.simulator import simulate

from _common import loadavg


def raw_system(seed: int, time: str) -> dict:
    rng = np.random.default_rng(seed)
    m = int(rng.integers(4, 8))
    n = int(rng.choice([6, 8]))
    A, Cs = random_system(rng, m, n, time=time)
    arcs_a = random_strongly_connected_arcs(rng, m, extra=m)
    arcs_b = random_strongly_connected_arcs(rng, m, extra=2)
    d = {"rate": 0.8, "gains": "place", "q": "auto"} if time == "discrete" else {"rate": 0.5, "gains": "place",
                                                                                  "g": "auto"}
    return {
        "name": f"rounded{seed}", "time": time,
        "system": {"A": A.tolist(), "C": {i + 1: C.tolist() for i, C in enumerate(Cs)}},
        "graphs": {"a": {"arcs": [[j + 1, i + 1] for j, i in arcs_a]},
                   "b": {"arcs": [[j + 1, i + 1] for j, i in arcs_b]}},
        # discrete: random switching (spectral q per graph held constant); continuous: graph a alone (the g
        # of a dwell-time certificate is large enough to need a far smaller run.dt than the 0.002 used here)
        **({"switching": {"random": {"graphs": ["a", "b"], "dwell": 3}}} if time == "discrete" else {}),
        "design": d,
        "run": {"steps": 300 if time == "discrete" else 15000, "seed": seed,
                **({"dt": 0.002} if time == "continuous" else {})},
    }


def rounded(raw: dict, decimals: int | None, rank_tol) -> dict:
    out = {**raw, "system": dict(raw["system"]), "design": dict(raw["design"])}
    if decimals is not None:
        out["system"]["A"] = np.round(np.array(raw["system"]["A"]), decimals).tolist()
        out["system"]["C"] = {i: np.round(np.array(C), decimals).tolist() for i, C in raw["system"]["C"].items()}
    if rank_tol != "auto":
        out["design"]["rank_tol"] = float(rank_tol)
    return out


def evaluate(raw: dict) -> dict:
    sc = parse_scenario(raw)
    try:
        des = design(sc)
    except Exception as exc:  # noqa: BLE001 - a refusal is a result here
        return {"error": str(exc)}
    tr = simulate(des, noise=False)
    e = tr.errors()
    err = np.nanmax(e, axis=1)
    rate = fit_decay(tr.t, err, time=sc.time, scale=np.linalg.norm(tr.x, axis=1))
    cond = conditioning(des)
    return {
        "n_i": [a.dec.n_unobservable for a in des.agents],
        "K": max(c.gain_norm for c in cond.agents),
        "peak": float(np.nanmax(err)),
        "rate": rate,
        "certified": rate_certificate(des).certified,
        "c": cond.transient_constant,
        "warnings": len(des.warnings) + len(cond.warnings),
    }


def splits(count: int) -> None:
    from splitspec_core.model.observability import ROUND_OFF, decompose, unobservable_directions

    changed = weak_joint = 0
    same = {6: 0, 4: 0}
    largest_residual = 0.0
    for seed in range(count):
        rng = np.random.default_rng(seed)
        time = "discrete" if seed % 2 else "continuous"
        m, n = int(rng.integers(3, 9)), int(rng.choice([4, 5, 6, 7, 8, 10]))
        A, Cs = random_system(rng, m, n, time=time)
        floor = [decompose(A, C, rank_tol=ROUND_OFF).n_unobservable for C in Cs]
        decs = [decompose(A, C) for C in Cs]
        auto = [d.n_unobservable for d in decs]
        largest_residual = max([largest_residual] + [d.split_residual for d in decs])
        changed += auto != floor
        weak_joint += unobservable_directions(A, Cs).shape[1] > 0
        for dec in same:
            same[dec] += [decompose(np.round(A, dec), np.round(C, dec)).n_unobservable for C in Cs] == auto
    print(f"# rank decisions over {count} random systems (rank_tol auto): exact splits changed {changed}/{count} "
          f"(largest split residual {largest_residual:.2g}), with directions no agent sees {weak_joint}/{count}, "
          f"rounded to 6 decimals: the exact split {same[6]}/{count}, to 4 decimals {same[4]}/{count}; "
          f"load {loadavg()}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--systems", type=int, default=7, help="systems per time mode (default 7)")
    ap.add_argument("--rank-tol", default="auto", help="design.rank_tol for every design (default auto)")
    ap.add_argument("--splits", type=int, default=0, help="count rank decisions over this many systems instead")
    args = ap.parse_args()
    if args.splits:
        splits(args.splits)
        return
    print(f"# design of rounded models, rank_tol {args.rank_tol}; load {loadavg()}")
    print(f"{'system':>14} {'dec':>4} {'n_i same':>8} {'|K|':>9} {'|K| x':>8} {'peak':>9} {'peak x':>8} "
          f"{'rate':>7} {'design':>6} {'cert':>5} {'c':>8} {'warn':>4}")
    summary = {6: [], 4: []}
    for time in ("discrete", "continuous"):
        for k in range(args.systems):
            seed = 100 + k
            raw = raw_system(seed, time)
            ex = evaluate(rounded(raw, None, args.rank_tol))
            for dec in (None, 6, 4):
                res = ex if dec is None else evaluate(rounded(raw, dec, args.rank_tol))
                name = f"{time[:4]} {seed}"
                if "error" in res:
                    print(f"{name:>14} {dec or '-':>4} refused: {res['error']}")
                    continue
                same = res["n_i"] == ex["n_i"]
                kx, px = res["K"] / ex["K"], res["peak"] / ex["peak"]
                rate = "-" if res["rate"] is None else f"{res['rate']:.3f}"
                c = "inf" if res["c"] is not None and math.isinf(res["c"]) else \
                    ("-" if res["c"] is None else f"{res['c']:.3g}")
                print(f"{name:>14} {dec or '-':>4} {'yes' if same else 'NO':>8} {res['K']:>9.3g} {kx:>7.2f}x "
                      f"{res['peak']:>9.3g} {px:>7.2f}x {rate:>7} {raw['design']['rate']:>6} "
                      f"{'yes' if res['certified'] else 'NO':>5} {c:>8} {res['warnings']:>4}")
                if dec is not None:
                    meets = res["rate"] is not None and (res["rate"] <= raw["design"]["rate"] if time == "discrete"
                                                         else res["rate"] >= raw["design"]["rate"])
                    summary[dec].append((same, kx, px, meets))
    for dec, rows in summary.items():
        if rows:
            print(f"# {dec} decimals: same n_i {sum(r[0] for r in rows)}/{len(rows)}, |K| within 10x "
                  f"{sum(r[1] <= 10 for r in rows)}/{len(rows)} (max {max(r[1] for r in rows):.3g}x), peak within 10x "
                  f"{sum(r[2] <= 10 for r in rows)}/{len(rows)} (max {max(r[2] for r in rows):.3g}x), measured rate "
                  f"meets the design {sum(r[3] for r in rows)}/{len(rows)}")
    print(f"# load {loadavg()}")


if __name__ == "__main__":
    main()
