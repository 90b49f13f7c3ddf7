"""Designs of real models (issue "Real systems I"): power-system benchmarks, detectable, stiff, named states.

The models are ANDES's linearised small-signal models of public test cases (``examples/models/*.npz``, made
by ``examples/models/make_power_models.py``; the tool and its version are in each file's ``meta``): Kundur's
two-area system (4 generators, 52 states; and a variant with a power-system stabiliser, 61 states), the IEEE
14-bus system (5 generators, 62 states) and the IEEE 39-bus system (10 generators, 160 and 170 states).  One
agent per generator: ``pmu`` measures its rotor angle and speed, ``more`` adds one exciter and one governor state.  The
agents talk over a ring (both directions), continuous time, gains ``place``, ``g`` auto, ``run.dt`` 0.01, unless
the row says otherwise.  ``ieee39_damped`` is the 39-bus system with its stabilisers' degenerate input filters
given 1 and 2 ms lags (``make_power_models.py`` says why; ``ieee39_full``'s linearisation has six spurious
eigenvalues near +1 and integrators nobody sees).

For each model and rate it prints:

* ``n``, ``m``; ``W``: the dimension of what no agent sees and its decay rate (``-max Re`` of ``A`` on ``W``);
* ``design s``: the design's wall time, ``cond s``: the conditioning's (the transient constant);
* ``g``; ``cert``: the certified rate (the envelope's: ``min(rate, 0.9 x W's decay)``) or why none;
* ``c``: the transient constant (``exact`` or a ``Lyapunov`` upper bound) and ``c_lo``: the largest
  ``||M^k|| / r^k`` actually formed (a lower bound of the true constant);
* from ``--seeds`` noise-free simulations, each from a random initial state and random estimates (the seeds'
  own draws): ``peak``, the largest ``||e(t)|| / (||e(0)|| exp(-rate t))`` over all seeds and times (must be at
  most ``c``); ``rate``, the decay measured on the tail (``analysis.fit_decay``, the smallest over the seeds;
  must be at least the certified rate); ``under``, whether every seed's error stayed under the envelope.

Then, for every certified row (``--no-noise`` skips it), a second table under noise (process noise intensity
``1e-4`` on every state, measurement noise std ``1e-3``, a PMU's order, ``--noise-horizon`` seconds):

* ``rms split``: the steady RMS error of the split-spectrum estimator with ``riccati`` gains (the row's other keys
  kept), ``rms KF``: the centralized Kalman filter's on the same realisations (``ss.compare``, ``--noise-seeds``
  seeds; steady: the run's second half), and their ratio;
* ``ms/event``: the multi-process runtime (``ss.run``: an orchestrator, a plant and m agent processes over Zenoh
  on loopback) at the model's n, ``1000 / rounds_per_second`` of its ``run_finished`` over ``--run-steps``
  event times, noise on.

    .venv/bin/python benchmarks/bench_real.py [--seeds 3] [--horizon 120] [--only kundur_full] [--no-noise]
"""

from __future__ import annotations

import argparse
import math
import time
import warnings
from pathlib import Path

import numpy as np

import splitspec_core as ss
from splitspec_core.simulation.metrics import fit_decay
from splitspec_core.errors import SplitspecError
from splitspec_core.synthesis.conditioning import conditioning
from splitspec_core.synthesis.verdict import rate_certificate

from _common import loadavg

MODELS = Path(__file__).resolve().parent.parent / "examples" / "models"

# (model, measurements, rate, extra design keys)
CASES = [
    ("kundur_full", "pmu", 0.2, {}),
    ("kundur_full", "more", 0.2, {}),
    ("kundur_full", "more", 0.5, {}),
    ("kundur_ieeest", "pmu", 0.2, {}),
    ("kundur_ieeest", "pmu", 0.2, {"margin": 0.1}),
    ("ieee14_full", "pmu", 0.2, {}),
    ("ieee14_full", "more", 0.2, {}),
    ("ieee39_full", "pmu", 0.2, {}),
    ("ieee39_full", "pmu", 0.2, {"undetectable": "exclude", "gains": "riccati"}),
    ("ieee39_damped", "pmu", 0.2, {}),
    ("ieee39_damped", "pmu", 0.2, {"gains": "riccati", "margin": 0.1}),
]


#: the noise of the second table: process noise intensity on every state, measurement noise std (a PMU's order)
NOISE = (1e-4, 1e-3)


def scenario(model: str, which: str, rate: float, extra: dict, horizon: float, dt: float,
             noise: tuple = (0.0, 0.0)) -> ss.Scenario:
    d = np.load(MODELS / f"{model}.npz", allow_pickle=False)
    m = len(d["generators"])
    ring = [(k, k % m + 1) for k in range(1, m + 1)] + [(k % m + 1, k) for k in range(1, m + 1)]
    return ss.scenario(name=f"{model}-{which}", time="continuous", A=d["A"], states=[str(s) for s in d["states"]],
                       C={k: d[f"C_{which}_{k}"] for k in range(1, m + 1)}, graphs={"ring": ring},
                       dt=dt, steps=int(round(horizon / dt)), process_noise=noise[0], measurement_noise=noise[1],
                       **{"rate": rate, "gains": "place", **extra})


def noise_row(model: str, which: str, rate: float, extra: dict, args) -> None:
    """The split-spectrum estimator (riccati gains) against the centralized KF under noise, and the runtime."""
    import tempfile

    name = f"{model} {which} {rate:g}" + ("".join(f" {k}={v}" for k, v in extra.items() if k != "gains"))
    sc = scenario(model, which, rate, {**extra, "gains": "riccati"}, args.noise_horizon, args.dt, NOISE)
    t0 = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        try:
            res = ss.compare(sc, seeds=args.noise_seeds)
        except SplitspecError as exc:
            print(f"{name:<40} compare failed: {exc}")
            return
    t_cmp = time.perf_counter() - t0
    split, kf = res.estimators["split riccati"], res.estimators["centralized KF"]
    with tempfile.TemporaryDirectory(prefix="bench-real-") as tmp:
        run_sc = scenario(model, which, rate, {**extra, "gains": "riccati"}, args.run_steps * args.dt, args.dt, NOISE)
        rec = ss.run(run_sc, out=Path(tmp) / "run")
        fin = rec.named("run_finished")[-1]
    ms = 1e3 / fin["rounds_per_second"]
    cert = "yes" if split.certified_rate else "no"
    print(f"{name:<40} {sc.n:>4} {sc.m:>3} {split.rms_mean:>10.3g} {kf.rms_mean:>9.3g} "
          f"{split.rms_mean / kf.rms_mean:>7.3g} {cert:>5} {ms:>9.2f}   (compare {t_cmp:.0f} s, "
          f"{args.noise_seeds} seeds of {sc.run.steps} steps; run of {args.run_steps} event times)")



def measure(des, seeds: int) -> dict:
    """Noise-free runs from the seeds' random initial states and estimates, against the envelope."""
    sc = des.scenario
    rate = des.envelope_rate
    peak, rates, under = 0.0, [], True
    for seed in range(seeds):
        tr = ss.simulate(des, seed=seed, noise=False)
        e = tr.xhat - tr.x[:, None, :]
        if des.excluded:  # the certificate covers the error modulo W (design.undetectable: exclude)
            W = des.unobserved.W
            e = e - (e @ W) @ W.T
        e = np.linalg.norm(e.reshape(e.shape[0], -1), axis=1)
        ratio = e / (e[0] * np.exp(-rate * tr.t))
        peak = max(peak, float(np.max(ratio)))
        c = conditioning(des).transient_constant
        if c is not None:
            under &= bool(np.all(ratio <= c * (1 + 1e-8)))
        r = fit_decay(tr.t, e, time=sc.time, scale=np.linalg.norm(tr.x, axis=1))
        if r is not None:
            rates.append(r)
    return {"peak": peak, "rate": min(rates) if rates else None, "under": under}


def lower_bound(method: str) -> str:
    """The peak of the powers formed, from the transient method's text (the exact constant when it is exact)."""
    if "peak of the first" in method:
        return method.rsplit(": ", 1)[1].rstrip(")")
    return "="


def row(model: str, which: str, rate: float, extra: dict, args) -> bool:
    name = f"{model} {which} {rate:g}" + ("".join(f" {k}={v}" for k, v in extra.items()))
    t0 = time.perf_counter()
    try:
        sc = scenario(model, which, rate, extra, args.horizon, args.dt)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            des = ss.design(sc).detail
    except SplitspecError as exc:
        print(f"{name:<40} refused in {time.perf_counter() - t0:.1f} s: {exc}")
        return False
    t_design = time.perf_counter() - t0
    t0 = time.perf_counter()
    cond = conditioning(des)
    t_cond = time.perf_counter() - t0
    un = des.unobserved
    cert = rate_certificate(des)
    c = cond.transient_constant
    how = ("c exact" if cond.transient_method.endswith("exact") else
           "c a Lyapunov bound" if "Lyapunov" in cond.transient_method else
           f"transient {cond.transient_method.split(': ')[-1]}")
    w = f"{un.dim} @ {un.decay:.3g}" if un.dim else "0"
    g = f"{des.g:.3g}" if des.g is not None else "adaptive"
    head = (f"{name:<40} {sc.n:>4} {sc.m:>3} {w:>12} {t_design:>8.1f} {t_cond:>6.1f} {g:>8} "
            f"{(f'{cert.rate:.3g}' if cert.certified else 'no'):>6}")
    cs = "-" if c is None else f"{c:.3g}"
    lo = "-" if c is None else lower_bound(cond.transient_method)
    if not cert.certified:
        print(f"{head} {cs:>9} {lo:>9}   not certified: {cert.text}")
        return False
    t0 = time.perf_counter()
    got = measure(des, args.seeds)
    mrate = f"{got['rate']:.3g}" if got["rate"] is not None else "-"
    under = "n/a" if c is None else "yes" if got["under"] else "NO"
    print(f"{head} {cs:>9} {lo:>9} {got['peak']:>9.3g} {mrate:>7} {under:>5}   ({how}; {args.seeds} runs of "
          f"{sc.run.steps} steps in {time.perf_counter() - t0:.1f} s)")
    return True


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, default=3, help="noise-free runs per certified design (default 3)")
    ap.add_argument("--horizon", type=float, default=120.0, help="simulated seconds (default 120)")
    ap.add_argument("--dt", type=float, default=0.01, help="run.dt (default 0.01)")
    ap.add_argument("--only", default=None, help="only the models whose name contains this")
    ap.add_argument("--no-noise", action="store_true", help="skip the table under noise (compare and ss.run)")
    ap.add_argument("--noise-seeds", type=int, default=2, help="seeds of the table under noise (default 2)")
    ap.add_argument("--noise-horizon", type=float, default=30.0, help="its simulated seconds (default 30)")
    ap.add_argument("--run-steps", type=int, default=500, help="event times of its multi-process run (default 500)")
    args = ap.parse_args()
    print(f"# real models, ring graphs, continuous time, gains place, g auto, run.dt {args.dt:g}; "
          f"load {loadavg()}")
    print(f"{'model meas rate':<40} {'n':>4} {'m':>3} {'W dim@decay':>12} {'design s':>8} {'cond s':>6} {'g':>8} "
          f"{'cert':>6} {'c':>9} {'c_lo':>9} {'peak':>9} {'rate':>7} {'under':>5}")
    certified = []
    for model, which, rate, extra in CASES:
        if args.only and args.only not in model:
            continue
        if row(model, which, rate, extra, args):
            certified.append((model, which, rate, extra))
    print(f"# load {loadavg()}")
    if args.no_noise or not certified:
        return
    print(f"\n# under noise (process {NOISE[0]:g}, measurement {NOISE[1]:g}), gains riccati, "
          f"{args.noise_horizon:g} s at run.dt {args.dt:g}; load {loadavg()}")
    print(f"{'model meas rate':<40} {'n':>4} {'m':>3} {'rms split':>10} {'rms KF':>9} {'ratio':>7} {'cert':>5} "
          f"{'ms/event':>9}")
    for case in certified:
        noise_row(*case, args)
    print(f"# load {loadavg()}")


if __name__ == "__main__":
    main()
