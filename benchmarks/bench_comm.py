"""Accuracy per message: the ratio to the centralized Kalman predictor against the numbers each agent sends.

For each model and each q (exchanges per event time), side by side on the same noise realisations:

* the protocol's limit at q (:mod:`splitspec_core.synthesis.exchange_limit`: the Kalman predictor fed each sensor
  ceil(d / q) - 1 event times late), which no estimator within q exchanges beats;
* the rate-certified centralized reference (the Riccati design shifted by the rate,
  :func:`~splitspec_core.synthesis.kalman.references`): where the Kalman predictor is slower than the rate, the
  centralized accuracy a certified estimator can aim at in this family;
* the fusion kind (:mod:`splitspec_core.synthesis.fusion`), predicted (its Lyapunov covariance) and measured (mean
  and spread over ``--seeds`` runs), with its spectral radius against the scenario's rate per event time;
* the relay kind (:mod:`splitspec_core.synthesis.relay`: the sensors' samples passed on, each agent the Kalman
  predictor of what it holds), predicted and measured on the same realisations, certified by its base's radius;
* Rego's steady-state distributed Kalman filter (one estimate per step, :class:`SteadyStateDKF`), a baseline at q = 1;
* the Kalman-consensus filter (Olfati-Saber, :class:`KalmanConsensusFilter`) with q exchanges, measured;
* the product's other estimator kinds at the same q (``design.consensus: whole`` and, in discrete time, ``split``,
  ``design.q: q``) and its default design (``consensus: auto``, ``q: auto``), as ``splitspec design`` makes them:
  predicted (their Lyapunov covariance, :func:`~splitspec_core.synthesis.error_matrix.predicted_rms`, which
  ``tests/unit/test_step_oracle.py`` and the noise tests hold to the simulator) and certified or not at the rate
  (``--kinds``; none: leave them out).

Numbers sent: per agent per event time, ``q n`` for the fusion kind (one estimate per exchange), ``p`` for the relay
kind (every sensor's sample once, whatever q; each with its sensor and event time), ``n`` for Rego's,
``n + s_i`` then ``n`` per further exchange for the KCF (its first message carries the prior and the measurement; the
most any agent sends is counted).

    .venv/bin/python benchmarks/bench_comm.py                       # every model, q = 1 2 3
    .venv/bin/python benchmarks/bench_comm.py --models rego --q 1 2 3 --seeds 5
    .venv/bin/python benchmarks/bench_comm.py --models ieee39_pmu --q 3 --rego-iterations 0 --append
    .venv/bin/python benchmarks/bench_comm.py --relay-only          # the relay rows of every model, the rest kept

Writes benchmarks/results/bench_comm.json and docs/figures/bench_comm.png (``--no-write``: print only); the printed
table of the run quoted in docs/benchmarks/index.md is kept as benchmarks/results/bench_comm.txt.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import logging
import sys
import time
import warnings
from pathlib import Path

import numpy as np

import splitspec_core as ss
from splitspec_core.errors import SplitspecError
from splitspec_core.model.plant import output_rows
from splitspec_core.studies.baselines import KalmanConsensusFilter, run_predictor
from splitspec_core.studies.few_exchanges import SteadyStateDKF, run_fusion, run_relay, simulate_measurements
from splitspec_core.synthesis.fusion import design_fusion, neighbour_positions
from splitspec_core.synthesis.error_matrix import predicted_rms
from splitspec_core.synthesis.kalman import kalman_predictor, per_step_rate, references
from splitspec_core.synthesis.exchange_limit import design_exchanges, hop_distances, network_model, protocol_limit
from splitspec_core.synthesis.relay import design_relay
from splitspec_core.synthesis.verdict import rate_certificate

from _common import loadavg

ROOT = Path(__file__).resolve().parents[1]
EXAMPLES = ROOT / "examples"
RESULTS = ROOT / "benchmarks" / "results"
FIGURE = ROOT / "docs" / "figures" / "bench_comm.png"
sys.path.insert(0, str(ROOT / "benchmarks"))


def _ieee39():
    from bench_real import scenario  # the IEEE 39-bus PMU ring as bench_real and the issue build it

    # the noise's gains (design.gains' default under noise), as issue 44 measured the default design
    return scenario("ieee39_damped", "pmu", 0.2, {"gains": "optimal"}, 2.0, 0.02, (1e-4, 1e-3))


MODELS = {
    "rego": lambda: ss.load_scenario(EXAMPLES / "rego_ring.yaml"),
    "ring10_noise": lambda: ss.load_scenario(EXAMPLES / "ring10_noise.yaml"),
    "ieee14_pmu": lambda: ss.load_scenario(EXAMPLES / "ieee14_pmu.yaml"),
    "platoon": lambda: ss.load_scenario(EXAMPLES / "platoon.yaml"),
    "ieee39_pmu": _ieee39,
}


def _parts(sc):
    return network_model(sc, 0)


def best_shifted(F, C, Q, R, lam: float, kf) -> float | None:
    """The smallest RMS (over the Kalman predictor's) of the centralized Riccati designs shifted by ``alpha`` that
    certify ``lam`` (radius below it): bisection on ``alpha`` in ``[lam, 1]`` (the error grows as the shift does)."""
    from splitspec_core.synthesis.kalman import shifted_predictor, steady_covariance

    if kf.radius < lam:
        return 1.0
    lo, hi, best = lam, 1.0, None
    for _ in range(30):
        a = lo if best is None else 0.5 * (lo + hi)
        try:
            p = shifted_predictor(F, C, Q, R, a)
            ok = p.radius < lam
        except SplitspecError:
            ok = False
        if ok:
            best = float(np.sqrt(np.trace(steady_covariance(F, C, p.L, Q, R)) / np.trace(kf.P)))
            lo = a
        else:
            if best is None:
                return None
            hi = a
    return best


def product_kinds(sc, qs, kinds, kf_rms: float) -> list:
    """The product's designs of each kind at each q, and its default design: what ``splitspec design`` says of them
    (numbers sent, certified, predicted ratio to the Kalman predictor), one row each."""
    rows = []
    todo = [(k, q) for k in kinds if not (k == "split" and sc.time == "continuous") for q in qs]
    for kind, q in todo + ([("auto", "auto")] if kinds else []):
        s = dataclasses.replace(sc, design=dataclasses.replace(sc.design, consensus=kind, q=q))
        t0 = time.perf_counter()
        try:
            des = ss.design(s).detail
            pred = float(np.sqrt(np.mean(predicted_rms(des) ** 2)))
            cert = rate_certificate(des)
        except SplitspecError as exc:
            print(f"   {kind} q={q}: refused: {exc}", flush=True)
            rows.append({"estimator": kind, "q": q, "refused": str(exc)})
            continue
        t_des = time.perf_counter() - t0
        ex = design_exchanges(des)
        label = f"{des.consensus} q={des.q}" + (" (default)" if kind == "auto" else "")
        r = {"estimator": des.consensus, "q": int(des.q), "default": kind == "auto", "numbers": ex.numbers,
             "limit": None if ex.limit is None else ex.limit.ratio, "predicted": pred / kf_rms if np.isfinite(pred)
             else None, "certified": bool(cert.certified), "design_s": t_des}
        rows.append(r)
        shown = "unstable" if r["predicted"] is None else f"{r['predicted']:.4f}"
        print(f"   {label:<22}: sends {ex.numbers:5d}  predicted {shown}  "
              f"{'certified' if cert.certified else 'NOT certified'} at the rate  design {t_des:.1f} s", flush=True)
    return rows


def relay_rows(key: str, qs, seeds: int, steps: int | None) -> list:
    """The relay kind at each q: designed at the rate, predicted, measured on ``seeds`` realisations (its own, the
    Kalman predictor beside it on each), one row each."""
    sc = MODELS[key]()
    F, Q, R, Cs, Rs, arcs = _parts(sc)
    lam = per_step_rate(sc, sc.design.rate)
    dist = hop_distances(sc.m, arcs)
    p = sum(C.shape[0] for C in Cs)
    rows, runs, made = [], {}, {}
    for q in qs:
        t0 = time.perf_counter()
        des = design_relay(F, Cs, Q, Rs, dist, q, lam)
        made[q] = (des, time.perf_counter() - t0)
        runs[f"relay q={q}"] = (lambda d: lambda y, X0: run_relay(d, Cs, y, X0))(des)
    radius = max(d.radius for d, _ in made.values())
    settle = int(np.ceil(np.log(1e-6) / np.log(max(radius, 1e-3))))
    steps = steps or max(2000, 12 * settle)
    meas = _measured(F, Cs, Q, Rs, runs, seeds, steps, min(settle, steps // 3))
    for q, (des, t_des) in made.items():
        mm = meas[f"relay q={q}"]
        r = {"estimator": "relay", "q": q, "numbers": p, "limit": des.limit, "predicted": des.ratio, "measured": mm,
             "radius": des.radius, "alpha": des.alpha, "certified": des.certified, "design_s": t_des,
             "of_limit": des.ratio / des.limit - 1.0, "delay": des.D,
             "transient": des.transient_constant if np.isfinite(des.transient_constant) else None}
        rows.append(r)
        print(f"   relay q={q} : sends {p:5d}  limit {des.limit:.4f}  predicted {des.ratio:.4f} "
              f"({100 * r['of_limit']:+.2f} % of the limit)  measured {np.mean(mm):.4f} [{min(mm):.4f}, "
              f"{max(mm):.4f}]  radius {des.radius:.8g} {'<' if des.certified else '>='} {lam:.8g}  alpha "
              f"{des.alpha:.6g}  D {des.D}  design {t_des:.1f} s", flush=True)
    return rows


def _measured(F, Cs, Q, Rs, runs: dict, seeds: int, steps: int, burn: int) -> dict:
    """RMS ratio to the Kalman predictor run on the same realisation, per estimator, over the seeds."""
    C = np.vstack(Cs)
    kf = kalman_predictor(F, C, Q, np.vstack([np.hstack([R if a == b else np.zeros((R.shape[0], S.shape[0]))
                                                          for b, S in enumerate(Rs)]) for a, R in enumerate(Rs)]))
    m, n = len(Cs), F.shape[0]
    out = {name: [] for name in runs}
    for seed in range(seeds):
        x, y = simulate_measurements(F, Cs, Q, Rs, steps, np.random.default_rng(seed))
        e_kf = run_predictor(F, C, kf.L, y, np.zeros(n)) - x
        ref = np.sqrt(np.mean(e_kf[burn:] ** 2))
        for name, run in runs.items():
            e = run(y, np.zeros((m, n))) - x[:, None]
            out[name].append(float(np.sqrt(np.mean(e[burn:] ** 2)) / ref))
    return out


def bench_model(key: str, qs, seeds: int, steps: int | None, rego_iterations: int = 2000,
                kinds=("whole", "split")) -> dict:
    sc = MODELS[key]()
    F, Q, R, Cs, Rs, arcs = _parts(sc)
    m, n = sc.m, sc.n
    lam = per_step_rate(sc, sc.design.rate)
    nbs = neighbour_positions(m, arcs)
    dist = hop_distances(m, arcs)
    kf_ref, rate_ref = references(sc, sc.design.rate)
    certified_reference = None if rate_ref is None or kf_ref is None else rate_ref.rms / kf_ref.rms
    best_ref = best_shifted(F, np.vstack(Cs), Q, R, lam, kf_ref)
    row = {"model": key, "m": m, "n": n, "rate_per_event": lam, "diameter": int(dist.max()), "rows": [],
           "kf_radius": None if kf_ref is None else kf_ref.radius, "certified_reference": certified_reference,
           "best_shifted_reference": best_ref}
    print(f"== {key}: m = {m}, n = {n}, diameter {int(dist.max())}, rate {lam:.6g} per event time; the Kalman "
          f"predictor's radius {kf_ref.radius:.6g}; centralized and certified at the rate: the Riccati design shifted "
          f"by the rate {certified_reference:.4g}x the KF's RMS, the best shift of it {best_ref:.4g}x "
          f"(load {loadavg()})", flush=True)
    runs, designs = {}, {}
    for q in qs:
        t0 = time.perf_counter()
        lim = protocol_limit(F, Cs, Q, Rs, dist, q)
        t_lim = time.perf_counter() - t0
        t0 = time.perf_counter()
        try:
            des = design_fusion(F, Cs, Q, Rs, nbs, q, rate=lam)
            certified = True
        except SplitspecError as exc:
            print(f"   q = {q}: fusion not certified at the rate ({exc}); the unshifted design instead", flush=True)
            des = design_fusion(F, Cs, Q, Rs, nbs, q)
            certified = False
        t_des = time.perf_counter() - t0
        designs[q] = (des, lim, certified, t_des, t_lim)
        runs[f"fusion q={q}"] = (lambda d: lambda y, X0: run_fusion(d, Cs, y, X0))(des)
        kcf = KalmanConsensusFilter(F, Cs, Q, Rs, [list(nb[1:]) for nb in nbs], exchanges=q)
        runs[f"kcf q={q}"] = (lambda k: lambda y, X0: k.run(y, X0, output_rows(Cs)))(kcf)
    t0 = time.perf_counter()
    rego = None
    if rego_iterations > 0:
        try:
            rego = SteadyStateDKF.design(F, Cs, Q, Rs, nbs, kf_rms=designs[qs[0]][0].kf_rms, max_iter=rego_iterations)
            runs["rego"] = lambda y, X0: rego.run(Cs, y, X0)
        except SplitspecError as exc:
            print(f"   Rego's steady-state DKF: {exc}", flush=True)
    t_rego = time.perf_counter() - t0
    radius = max([d[0].radius for d in designs.values()] + ([rego.radius] if rego else []))
    settle = int(np.ceil(np.log(1e-6) / np.log(max(radius, 1e-3))))  # the initial error fallen a millionfold
    steps = steps or max(2000, 12 * settle)
    burn = min(settle, steps // 3)
    meas = _measured(F, Cs, Q, Rs, runs, seeds, steps, burn)
    for q, (des, lim, certified, t_des, t_lim) in designs.items():
        mm = meas[f"fusion q={q}"]
        r = {"estimator": "fusion", "q": q, "numbers": des.numbers_per_event, "limit": lim.ratio,
             "predicted": des.ratio, "measured": mm, "radius": des.radius, "alpha": des.alpha,
             "certified": certified and des.radius < lam, "design_s": t_des, "limit_s": t_lim,
             "of_limit": des.ratio / lim.ratio - 1.0}
        row["rows"].append(r)
        print(f"   fusion q={q}: sends {r['numbers']:5d}  limit {lim.ratio:.4f}  predicted {des.ratio:.4f} "
              f"({100 * r['of_limit']:+.2f} % of the limit)  measured {np.mean(mm):.4f} "
              f"[{min(mm):.4f}, {max(mm):.4f}]  radius {des.radius:.6g} {'<' if r['certified'] else '>='} {lam:.6g}"
              f"  alpha {des.alpha:.4g}  design {t_des:.1f} s", flush=True)
    for q in designs:
        mm = meas[f"kcf q={q}"]
        sends = n + max(C.shape[0] for C in Cs) + (q - 1) * n
        row["rows"].append({"estimator": "kcf", "q": q, "numbers": sends, "measured": mm})
        print(f"   KCF q={q}   : sends {sends:5d}  measured {np.mean(mm):.4f} [{min(mm):.4f}, {max(mm):.4f}]", flush=True)
    if rego is not None:
        mm = meas["rego"]
        lim1 = designs[min(designs)][1] if 1 in designs else protocol_limit(F, Cs, Q, Rs, dist, 1)
        row["rows"].append({"estimator": "rego", "q": 1, "numbers": n, "limit": lim1.ratio, "predicted": rego.ratio,
                            "measured": mm, "radius": rego.radius, "certified": rego.radius < lam,
                            "design_s": t_rego})
        print(f"   Rego SSDKF : sends {n:5d}  predicted {rego.ratio:.4f}  measured {np.mean(mm):.4f} "
              f"[{min(mm):.4f}, {max(mm):.4f}]  radius {rego.radius:.6g}  design {t_rego:.1f} s", flush=True)
    row["rows"] += relay_rows(key, qs, seeds, steps)
    row["rows"] += product_kinds(sc, qs, kinds, kf_ref.rms)
    row["steps"], row["burn"], row["seeds"] = steps, burn, seeds
    return row


def figure(rows: list, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import matplotlib.ticker

    fig, axes = plt.subplots(1, len(rows), figsize=(4.2 * len(rows), 3.8), squeeze=False)
    for ax, row in zip(axes[0], rows):
        fus = [r for r in row["rows"] if r["estimator"] == "fusion"]
        x = [r["numbers"] for r in fus]
        ax.plot(x, [r["limit"] for r in fus], "k--", marker="_", ms=14, label="protocol limit")
        ax.plot(x, [r["predicted"] for r in fus], "C0-o", label="fusion, predicted")
        ax.errorbar(x, [np.mean(r["measured"]) for r in fus],
                    yerr=[[np.mean(r["measured"]) - min(r["measured"]) for r in fus],
                          [max(r["measured"]) - np.mean(r["measured"]) for r in fus]],
                    fmt="C0x", capsize=3, label="fusion, measured")
        for r in fus:
            ax.annotate(f"q={r['q']}" + ("" if r.get("certified", True) else ", not certified"),
                        (r["numbers"], r["predicted"]), textcoords="offset points", xytext=(4, 6), fontsize=8)
        rel = [r for r in row["rows"] if r["estimator"] == "relay"]
        for r in rel:  # every q sends the same numbers: one marker per q, filled when certified at the rate
            ax.plot([r["numbers"]], [r["predicted"]], "C1o", mfc="C1" if r["certified"] else "none", ms=7,
                    label="relay, predicted (filled: certified)")
            ax.plot([r["numbers"]], [np.mean(r["measured"])], "C1x", label="relay, measured")
            ax.annotate(f"q={r['q']}", (r["numbers"], r["predicted"]), textcoords="offset points", xytext=(-22, -4),
                        fontsize=7, color="C1")
        kcf = [r for r in row["rows"] if r["estimator"] == "kcf" and np.isfinite(np.mean(r["measured"]))]
        if kcf:
            ax.plot([r["numbers"] for r in kcf], [np.mean(r["measured"]) for r in kcf], "C2^:",
                    label="KCF, measured")
        for kind, style in (("whole", "C4"), ("split", "C5")):  # filled: certified at the rate; hollow: not
            pts = [r for r in row["rows"] if r["estimator"] == kind and r.get("predicted")]
            for r in pts:
                ax.plot([r["numbers"]], [r["predicted"]], style + ("*" if r.get("default") else "D"),
                        mfc=style if r["certified"] else "none", ms=9 if r.get("default") else 6,
                        label=f"{kind}, predicted" + (" (the default design)" if r.get("default") else ""))
        for r in row["rows"]:
            if r["estimator"] == "rego":
                ax.plot([r["numbers"]], [r["predicted"]], "C3s", label="Rego SSDKF (exchange, then measure)")
        ax.axhline(1.0, color="0.6", lw=0.8)
        if row.get("best_shifted_reference") and row["best_shifted_reference"] > 1.0 + 1e-9:
            ax.axhline(row["best_shifted_reference"], color="C1", lw=0.8, ls=":",
                       label="centralized Riccati, best shift certified")
        ax.set_xscale("log")
        ax.set_yscale("log")  # the KCF's several-fold ratios beside the fusion kind's few percent
        for axis, (lo, hi) in ((ax.xaxis, ax.get_xlim()), (ax.yaxis, ax.get_ylim())):
            axis.set_major_formatter(matplotlib.ticker.FormatStrFormatter("%.3g"))
            axis.set_minor_formatter(matplotlib.ticker.FormatStrFormatter("%.3g"))
            if hi > 3 * lo:  # over a wide range every minor tick labelled runs into the next: 2 and 5 per decade
                axis.set_minor_locator(matplotlib.ticker.LogLocator(subs=(2.0, 5.0)))
        ax.set_title(f"{row['model']} (m={row['m']}, n={row['n']})", fontsize=10)
        ax.set_xlabel("numbers each agent sends per event time")
        ax.set_ylabel("RMS error / centralized KF's")
        handles, labels = ax.get_legend_handles_labels()
        seen = {}
        for h, lab in zip(handles, labels):
            seen.setdefault(lab, h)
        ax.legend(seen.values(), seen.keys(), fontsize=6)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)


def _relay_only(args) -> int:
    """``--relay-only``: the relay kind of ``args.models`` at ``args.q``, replacing its rows in the records."""
    record = RESULTS / "bench_comm.json"
    data = json.loads(record.read_text()) if record.exists() else {"models": []}
    for key in args.models:
        row = next((r for r in data["models"] if r["model"] == key), None)
        if row is None:
            print(f"   {key}: not in the records: run it first without --relay-only", flush=True)
            return 2
        print(f"== {key} (load {loadavg()})", flush=True)
        t0 = time.perf_counter()
        new = relay_rows(key, sorted(args.q), args.seeds, args.steps)
        row["rows"] = [r for r in row["rows"] if r["estimator"] != "relay"] + new
        print(f"   ({time.perf_counter() - t0:.0f} s, load {loadavg()})", flush=True)
    if not args.no_write:
        record.write_text(json.dumps(data, indent=1))
        figure(data["models"], FIGURE)
        print(f"wrote {record} and {FIGURE}")
    return 0


def _kinds_only(args) -> int:
    """``--kinds-only``: the product's kinds of ``args.models`` at ``args.q``, replacing those rows in the records."""
    record = RESULTS / "bench_comm.json"
    data = json.loads(record.read_text()) if record.exists() else {"models": []}
    for key in args.models:
        row = next((r for r in data["models"] if r["model"] == key), None)
        if row is None:
            print(f"   {key}: not in the records: run it first without --kinds-only", flush=True)
            return 2
        sc = MODELS[key]()
        kf_ref, _ = references(sc, sc.design.rate)
        print(f"== {key} (load {loadavg()})", flush=True)
        t0 = time.perf_counter()
        kinds = product_kinds(sc, sorted(args.q), args.kinds, kf_ref.rms)
        row["rows"] = [r for r in row["rows"] if r["estimator"] in ("fusion", "kcf", "rego", "relay")] + kinds
        print(f"   ({time.perf_counter() - t0:.0f} s, load {loadavg()})", flush=True)
    if not args.no_write:
        record.write_text(json.dumps(data, indent=1))
        figure(data["models"], FIGURE)
        print(f"wrote {record} and {FIGURE}")
    return 0


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--models", nargs="+", default=list(MODELS), choices=list(MODELS))
    p.add_argument("--q", nargs="+", type=int, default=[1, 2, 3])
    p.add_argument("--seeds", type=int, default=3)
    p.add_argument("--steps", type=int, default=None, help="event times per run (default: 12 settling times)")
    p.add_argument("--rego-iterations", type=int, default=2000,
                   help="the most covariance iterations of Rego's filter's design (0: leave it out)")
    p.add_argument("--kinds", nargs="*", default=["whole", "split"], choices=["whole", "split"],
                   help="the product's other kinds at each q, and its default design (none given: leave them out)")
    p.add_argument("--kinds-only", action="store_true",
                   help="only the product's kinds of these models, their rows replaced in the records (the rest kept)")
    p.add_argument("--relay-only", action="store_true",
                   help="only the relay kind of these models, its rows replaced in the records (the rest kept)")
    p.add_argument("--no-write", action="store_true")
    p.add_argument("--append", action="store_true",
                   help="keep the records' other models, replace only these (a large model's rows run alone)")
    p.add_argument("--quiet", action="store_true", help="no progress lines from the designs")
    p.add_argument("--figure-only", action="store_true", help="draw the figure again from the records, run nothing")
    args = p.parse_args(argv)
    if args.figure_only:
        figure(json.loads((RESULTS / "bench_comm.json").read_text())["models"], FIGURE)
        print(f"wrote {FIGURE}")
        return 0
    if not args.quiet:  # each shift the fusion design tries, as it goes (a large model's design takes minutes)
        logging.basicConfig(level=logging.WARNING, format="      %(message)s")
        logging.getLogger("splitspec_core.synthesis.fusion").setLevel(logging.INFO)
    print(f"bench_comm: load {loadavg()}", flush=True)
    if args.kinds_only:
        return _kinds_only(args)
    if args.relay_only:
        return _relay_only(args)
    rows = []
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for key in args.models:
            t0 = time.perf_counter()
            rows.append(bench_model(key, sorted(args.q), args.seeds, args.steps, args.rego_iterations, args.kinds))
            print(f"   ({time.perf_counter() - t0:.0f} s, load {loadavg()})", flush=True)
    if not args.no_write:
        RESULTS.mkdir(parents=True, exist_ok=True)
        record = RESULTS / "bench_comm.json"
        if args.append and record.exists():  # the other models' rows as recorded, each with its own load
            kept = [r for r in json.loads(record.read_text())["models"] if r["model"] not in args.models]
            rows = kept + rows
        record.write_text(json.dumps({"load": loadavg(), "models": rows}, indent=1))
        figure(rows, FIGURE)
        print(f"wrote {RESULTS / 'bench_comm.json'} and {FIGURE}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
