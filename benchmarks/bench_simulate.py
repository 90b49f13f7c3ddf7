"""Batch simulator vs a dense mn x mn reference (issue: simulator performance).

    .venv/bin/python benchmarks/bench_simulate.py [--sizes 10 50 200] [--repeat R] [--steps 500]
                                                  [--arc-m M] [--extras 0 2 4 16]

Quick check: ``--sizes 10 50`` (the arc table then runs at m = 50).

Scenarios: random jointly observable discrete-time systems (n = 10, every
agent sees part of the state, ``random_system``) on random strongly connected
graphs (a random ring plus ``extra`` random arcs, ``random_strongly_connected_arcs``),
built as in ``bench_design.py``; design ``rate 0.9, gains place, q_method
spectral, q = 10`` given explicitly (the script prints whether the spectral
certificate holds for q = 10); process and measurement noise 0.01; 500 steps;
constant graph, no faults.

What is measured (wall clock, ``time.perf_counter``, best of ``--repeat``;
design time is excluded and only shown for information):

* ``batch``: ``simulate(des, estimator="batch")`` end to end - plant and noise
  draws, recording, per step ``q`` sparse sub-rounds ``W @ Z`` plus batched
  ``P_i`` products, and the batched measurement update;
* ``dense``: the textbook stacked form of eqs. (split-discrete-est1..p3):
  precompute ``M = I - P (I - kron(S, I_n))``, ``Abar = blockdiag(A + K_i C_i)``,
  ``Kbig = blockdiag(K_i)`` (``S = D^-1 Adj'`` built here from the arcs, uniform
  weights), then per step ``q`` dense mat-vecs ``z <- M z`` and
  ``x <- Abar z - Kbig y``.  It uses the same :class:`Plant` (same noise
  streams) and the same ``initial_estimate`` draws, so both trajectories must
  agree to rounding; the max abs difference of the estimates is printed and
  a mismatch (relative > 1e-8) makes the script exit with status 1.
  ``dense s`` includes the precompute (shown separately as ``setup s``).

The second table holds m fixed and grows the graph (ring + extra*m random
arcs, nested graphs from one random stream, same system): batch cost should
grow with the number of arcs (``nnz(B) = arcs + m``), not with ``(mn)^2``.
``est ms/step`` times ``BatchEstimator.step`` alone (fixed rows and
measurements, no plant, no recording) and ``B@w us`` one sparse sub-round
product; at these sizes the per-step cost is mostly fixed per-call overhead
(q einsum calls over (m, n, n)), so it grows far slower than the arc count.
The default extras are 0, 2, 4, 16 (the 2m graph is table 1's, its design is
reused); ``--extras 0 2 4 16 64`` adds a denser graph, but its *design* then
takes minutes at m = 200 (the arc-loss analysis is quadratic in the arcs).

Default run: about 3 minutes on 2 shared cores, mostly the designs
(m = 200: 15-25 s each) and the dense reference at m = 200 (~40 s).

No timing assertions anywhere (the machine is shared).
"""

from __future__ import annotations

import argparse
import os
import sys
import time

import numpy as np
import scipy
import scipy.linalg as sla

from splitspec_core.synthesis.designer import design
from splitspec_core.simulation.kinds import spmv as _spmv
from splitspec_core.scenarios.generate import random_strongly_connected_arcs, random_system
from splitspec_core.model.network import consensus_rows
from splitspec_core.scenarios.load import parse_scenario
from splitspec_core.model.plant import Plant, initial_estimate
from splitspec_core.simulation.simulator import BatchEstimator, simulate

N = 10
Q = 10
RATE = 0.9
SEED = 1  # run seed: initial state, initial estimates, noise
REL_TOL = 1e-8


def scenario(m: int, n: int, extra: int, steps: int, seed: int) -> dict:
    """Same construction as bench_design.scenario (discrete), with explicit q and noise.

    The system and the ring come first from ``default_rng(seed)``, so for a
    fixed seed every ``extra`` gives the same system and nested graphs.
    """
    rng = np.random.default_rng(seed)
    A, Cs = random_system(rng, m, n, time="discrete")
    arcs = random_strongly_connected_arcs(rng, m, extra=extra)
    return {
        "name": f"bench-sim-{m}-{extra}", "time": "discrete",
        "system": {"A": A.tolist(), "C": {i + 1: C.tolist() for i, C in enumerate(Cs)},
                   "process_noise": 0.01, "measurement_noise": 0.01},
        "graphs": {"g": {"arcs": [[j + 1, i + 1] for j, i in arcs]}},
        "design": {"rate": RATE, "gains": "place", "q_method": "spectral", "q": Q},
        "run": {"steps": steps, "seed": SEED},
    }


def textbook_S(sc) -> np.ndarray:
    """``S = D^-1 Adj'`` of the (only) graph, self-arcs included: row i averages i's in-neighbours."""
    m = sc.m
    pos = {a: k for k, a in enumerate(sc.agent_ids)}
    adj = np.eye(m)
    for j, i in sc.graphs[0].arcs:
        adj[pos[j], pos[i]] = 1.0
    at = adj.T
    return at / at.sum(axis=1, keepdims=True)


def dense_simulate(des, seed: int, steps: int) -> tuple:
    """The stacked dense recursion; returns ``(x (T, n), xhat (T, m, n), setup seconds)``."""
    t0 = time.perf_counter()
    sc = des.scenario
    assert sc.switching.kind == "constant" and not sc.faults and sc.design.weights == "uniform"
    m, n, q = sc.m, sc.n, int(des.q)
    A = np.asarray(sc.system.A)
    Cs = [np.asarray(C) for C in sc.system.Cs]
    Ks = [np.asarray(K) for K in des.Ks]
    S = textbook_S(sc)
    Pbig = sla.block_diag(*[np.asarray(P) for P in des.Ps])
    I = np.eye(m * n)
    M = I - Pbig @ (I - np.kron(S, np.eye(n)))
    Abar = sla.block_diag(*[A + K @ C for K, C in zip(Ks, Cs)])
    Kbig = sla.block_diag(*Ks)
    setup = time.perf_counter() - t0

    plant = Plant(des.scenario, seed, noise=True)
    z = np.concatenate([initial_estimate(n, seed, i) for i in range(m)])
    T = steps + 1
    xs = np.zeros((T, n))
    xh = np.zeros((T, m, n))
    for k in range(T):
        xs[k] = plant.x
        xh[k] = z.reshape(m, n)
        if k == steps:
            break
        y = plant.measure()
        for _ in range(q):
            z = M @ z
        z = Abar @ z - Kbig @ y
        plant.advance()
    return xs, xh, setup


def estimator_only(des, steps: int) -> tuple:
    """``(seconds for `steps` BatchEstimator.step calls, seconds per sparse W @ Z)``.

    Same rows (constant graph, all alive) and one fixed set of measurements,
    so only the estimator's own work is timed.
    """
    sc = des.scenario
    est = BatchEstimator(des)
    rows = consensus_rows(sc, 0, sc.agent_ids)
    ys = Plant(des.scenario, SEED, noise=True).measure()
    W = est.weights(rows)
    alive = np.ones(sc.m, dtype=bool)
    X = np.stack([initial_estimate(sc.n, SEED, i) for i in range(sc.m)])
    t0 = time.perf_counter()
    for _ in range(steps):
        X = est.step(X, ys, W, alive)
    t_est = time.perf_counter() - t0
    B, _ = W
    w = np.ones(B.shape[1])
    best = np.inf
    for _ in range(20):  # min over chunks: robust to a shared machine
        t0 = time.perf_counter()
        for _ in range(100):
            _spmv(B, w)
        best = min(best, (time.perf_counter() - t0) / 100)
    return t_est, best, B.nnz


def best_of(fn, repeat: int) -> tuple:
    """``(best seconds, result of the last call)``."""
    best, out = np.inf, None
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t0)
    return best, out


_designs: dict = {}


def get_design(m: int, extra: int, steps: int):
    """Design (cached per (m, extra)); returns ``(design, seconds, certified)``."""
    key = (m, extra, steps)
    if key not in _designs:
        sc = parse_scenario(scenario(m, N, extra, steps, seed=m))
        t0 = time.perf_counter()
        des = design(sc)
        secs = time.perf_counter() - t0
        if des.q != Q:
            raise RuntimeError(f"design chose q = {des.q}, expected the given {Q}")
        _designs[key] = (des, secs, bool(des.q_result.certified))
    return _designs[key]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", type=int, nargs="+", default=[10, 50, 200])
    ap.add_argument("--steps", type=int, default=500)
    ap.add_argument("--repeat", type=int, default=None,
                    help="best of R runs (default: batch 3; dense 3 for m <= 50, 1 above)")
    ap.add_argument("--arc-m", type=int, default=None,
                    help="m of the arc-scaling table (default: largest size; 0 skips it)")
    ap.add_argument("--extras", type=int, nargs="+", default=[0, 2, 4, 16],
                    help="extra random arcs per agent in the arc-scaling table (ring + extra*m)")
    args = ap.parse_args()
    steps = args.steps
    if steps < 1 or any(m < 1 for m in args.sizes) or (args.repeat is not None and args.repeat < 1):
        ap.error("--steps, --sizes and --repeat must be positive")

    def repeats(m: int) -> tuple:
        if args.repeat is not None:
            return args.repeat, args.repeat
        return 3, (3 if m <= 50 else 1)

    t_start = time.perf_counter()
    print(f"# numpy {np.__version__}, scipy {scipy.__version__}, "
          f"{os.cpu_count()} cpus; n = {N}, q = {Q} (given), rate {RATE}, {steps} steps, discrete, "
          f"noise 0.01; seconds, best of R; design time excluded (shown for information)")
    print()
    print("Table 1: batch simulate vs dense mn x mn reference (ring + 2m random arcs)")
    print(f"{'m':>4} {'n':>3} {'q':>3} {'steps':>5} {'arcs':>5} {'cert':>4} {'R':>3} {'design s':>8} "
          f"{'batch s':>8} {'ms/step':>8} {'setup s':>8} {'dense s':>8} {'speed-up':>8} "
          f"{'max|diff|':>9} {'rel':>8}")
    ok = True
    dense_at: dict = {}
    for m in args.sizes:
        des, dsecs, cert = get_design(m, 2 * m, steps)
        rb, rd = repeats(m)
        tb, traj = best_of(lambda: simulate(des, seed=SEED, steps=steps, estimator="batch"), rb)
        td, (xs, xh, setup) = best_of(lambda: dense_simulate(des, SEED, steps), rd)
        same_plant = np.array_equal(xs, traj.x)  # exact: both step the same Plant class with the same seed
        diff = float(np.max(np.abs(traj.xhat - xh)))
        rel = diff / float(np.max(np.abs(xh)))
        good = same_plant and bool(np.isfinite(rel)) and rel <= REL_TOL
        ok = ok and good
        dense_at[m] = td
        print(f"{m:>4} {N:>3} {Q:>3} {steps:>5} {len(des.graphs[0].arcs):>5} {'yes' if cert else 'NO':>4} "
              f"{f'{rb}/{rd}':>3} {dsecs:>8.2f} {tb:>8.3f} {1e3 * tb / steps:>8.3f} {setup:>8.3f} {td:>8.3f} "
              f"{td / tb:>7.1f}x {diff:>9.2e} {rel:>8.1e}", flush=True)
        if not same_plant:
            print(f"  !! m = {m}: plant trajectories differ (max {np.max(np.abs(xs - traj.x)):.3g})")
        if not good:
            print(f"  !! m = {m}: batch and dense estimates disagree (relative {rel:.3g} > {REL_TOL:g})")
    print("(R = batch/dense repeats; setup s = dense precompute of M, Abar, Kbig, included in dense s)")

    am = max(args.sizes) if args.arc_m is None else args.arc_m
    if am > 0:
        rb, _ = repeats(am)
        print()
        print(f"Table 2: batch cost vs number of arcs, m = {am}, n = {N}, q = {Q} (ring + extra*m random arcs, "
              f"same system, nested graphs), best of {rb}")
        print(f"{'extra':>6} {'arcs':>6} {'nnz(B)':>6} {'cert':>4} {'design s':>8} {'batch s':>8} {'ms/step':>8} "
              f"{'est ms/step':>11} {'B@w us':>7} {'nnz x':>6} {'est x':>6} {'B@w x':>6}")
        base = None
        for e in args.extras:
            des, dsecs, cert = get_design(am, e * am, steps)
            arcs = len(des.graphs[0].arcs)
            tb, _ = best_of(lambda: simulate(des, seed=SEED, steps=steps, estimator="batch"), rb)
            runs = [estimator_only(des, steps) for _ in range(rb)]
            nnz = runs[0][2]
            te = min(r[0] for r in runs) / steps
            tw = min(r[1] for r in runs)
            if base is None:
                base = (nnz, te, tw)
            print(f"{e:>5}m {arcs:>6} {nnz:>6} {'yes' if cert else 'NO':>4} {dsecs:>8.2f} {tb:>8.3f} "
                  f"{1e3 * tb / steps:>8.3f} {1e3 * te:>11.3f} {1e6 * tw:>7.1f} {nnz / base[0]:>5.1f}x "
                  f"{te / base[1]:>5.2f}x {tw / base[2]:>5.2f}x", flush=True)
        print("(est ms/step: BatchEstimator.step alone, fixed rows and measurements; B@w us: one sparse "
              "sub-round product)")
        if am in dense_at:
            print(f"(dense reference at m = {am}: {dense_at[am]:.3f} s = {1e3 * dense_at[am] / steps:.1f} ms/step "
                  f"for any arc count: {(am * N) ** 2:,} multiply-adds per sub-round)")
    print()
    print(f"# total wall time {time.perf_counter() - t_start:.1f} s; batch vs dense agreement: "
          f"{'OK' if ok else 'MISMATCH'}")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
