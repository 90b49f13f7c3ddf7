"""The study commands: ``splitspec design`` and ``compare`` (offline, one process; ``simulate``: :mod:`.simulate`).

Each calls the public API (:mod:`splitspec_core.api`) and writes what it returns: the report,
``trajectory.npz`` / ``summary.json`` / plots, ``compare.json`` / plots.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path


import splitspec_core as ss
from splitspec_core.runtime.cli import UsageError
from splitspec_core.scenarios.noise import noise_text

from . import out_dir, seed_range


MAX_KCF_EPS = 1e12  # as splitspec_core.scenarios.specs.MAX_MAGNITUDE


def cmd_design(args: argparse.Namespace) -> int:
    sc = ss.load_scenario(args.scenario)
    if args.write and not args.tune:
        raise UsageError("--write needs --tune")
    if args.all_methods and args.tune:
        raise UsageError("--all-methods belongs to the design report; --tune reports no q methods")
    if args.tune:
        return _tune(args, sc)
    # the other q methods are for information only and cost more than the design itself at scale: on request
    d = ss.design(sc, all_q_methods=args.all_methods, workers=args.workers)
    if args.json:
        json.dump(d.to_json(), sys.stdout, indent=None if args.compact else 2)
        sys.stdout.write("\n")
    else:
        print(d.report())
    return 0


def _tune(args: argparse.Namespace, sc) -> int:
    from pathlib import Path

    from splitspec_core.scenarios import gain_methods
    from splitspec_core.synthesis.noise_tuning import tune, tune_lines
    from splitspec_core.scenarios.load import dump_yaml, load_yaml, read_scenario_text

    res = tune(sc)  # never a design predicted worse than the scenario's own (res.kept: the scenario's own)
    d = res.design
    cd = res.scenario.design
    what = ("q", d.q) if sc.time == "discrete" else ("g", d.g)
    weighted = gain_methods.method(cd.gains).weighted  # its Riccati weights travel with it (design.riccati)
    weights = None if not weighted or cd.process_weight is None else {
        "process_weight": float(cd.process_weight), "measurement_weight": float(cd.measurement_weight)}
    summary = {"gains": cd.gains, what[0]: what[1], "riccati": weights, "predicted_rms": res.rms,
               "baseline_predicted_rms": res.baseline_rms, "kept": res.kept, "candidates": res.candidates}
    if args.json:
        json.dump(summary, sys.stdout, indent=None if args.compact else 2)
        sys.stdout.write("\n")
    else:
        print(f"noise: process {noise_text(sc.system.process_noise)}, measurement "
              f"{noise_text(sc.system.measurement_noise)}")
        print("\n".join(tune_lines(res)))
    if args.write:
        raw = load_yaml(read_scenario_text(args.scenario), source=str(args.scenario))
        if not res.kept:  # kept: the scenario's own design section, as the user wrote it
            dd = raw.setdefault("design", {})
            dd["gains"] = cd.gains
            dd.pop("K", None)
            dd[what[0]] = what[1]
            if weights:
                dd["riccati"] = weights
            else:
                dd.pop("riccati", None)
        raw["name"] = f"{sc.name}-tuned"
        model = (raw.get("system") or {}).get("file") if isinstance(raw.get("system"), dict) else None
        if isinstance(model, str) and not Path(model).expanduser().is_absolute():  # still found from the new file
            target = Path(args.write).resolve().parent
            raw["system"]["file"] = os.path.relpath(Path(args.scenario).resolve().parent / model, target)
        how = ("its own design, kept: no candidate predicted better" if res.kept else "tuned for noise")
        try:
            Path(args.write).write_text(f"# {sc.name}: {how} (`splitspec design --tune rms`)\n"
                                        + dump_yaml(raw), encoding="utf-8")
        except OSError as exc:
            raise UsageError(f"cannot write {args.write}: {exc.strerror}") from None
        print(f"wrote {args.write}") if not args.json else None
    return 0


def cmd_compare(args: argparse.Namespace) -> int:
    from splitspec_core.studies.comparison import (certificate_lines, missing_ratio_lines, strict_json, sweep,
                                                   sweep_line)
    from splitspec_core.simulation.simulator import check_trajectory_memory

    sc = ss.load_scenario(args.scenario)
    seed0 = sc.run.seed if args.seed is None else args.seed
    seed_range(seed0, args.seeds, "--seeds")
    check_trajectory_memory(sc, args.steps, key="--steps" if args.steps is not None else "run.steps")
    if args.sweep_rate:
        if args.sweep or args.sweep_loss or args.sweep_deadline:
            raise UsageError("--sweep-rate is a study of its own: run it without --sweep, --sweep-loss or "
                             "--sweep-deadline")
        return _rate_sweep(args, sc, seed0)
    if args.sweep_loss or args.sweep_deadline:
        if args.sweep:
            raise UsageError("--sweep (q or g) and --sweep-loss/--sweep-deadline are separate studies: run one at a time")
        return _network_sweeps(args, sc, seed0)
    out = out_dir(args.out)
    result = ss.compare(sc, seeds=args.seeds, seed=seed0, steps=args.steps, kcf_eps=args.kcf_eps)
    lines = [f"{sc.name}: {len(result.seeds)} seeds x {result.steps} steps; process noise "
             f"{noise_text(sc.system.process_noise)}, measurement noise {noise_text(sc.system.measurement_noise)}",
             *([f"  steps: {result.steps_note}"] if result.steps_note else []),
             "  steady RMS: from the end of each estimator's certified transient (steady from) to the end of the run",
             f"  {'estimator':<22} {'steady RMS':>11} {'+-':>9} {'/ central':>9} {'predicted':>10} "
             f"{'steady from':>11} {'settle 1e-3':>11} {'msgs/event':>10}"]
    for name, r in result.estimators.items():
        pred = "-" if r.predicted_rms is None else f"{r.predicted_rms:.4g}"
        st = "never" if r.settle_time is None else f"{r.settle_time:g}"
        if r.steady_from is None:
            lines.append(f"  {name:<22} {'-':>11} {'':>9} {'n/a':>9} {pred:>10} {'not settled':>11} {st:>11} "
                         f"{r.messages_per_event:>10}")
            continue
        ratio = "n/a" if r.ratio_to_centralized is None else f"{r.ratio_to_centralized:.3f}"
        lines.append(f"  {name:<22} {r.rms_mean:11.4g} {r.rms_std:9.2g} {ratio:>9} "
                     f"{pred:>10} {r.steady_from:11g} {st:>11} {r.messages_per_event:>10}")
    lines += [f"  {name}: {r.note}" for name, r in result.estimators.items() if r.note and r.steady_from is not None]
    lines += missing_ratio_lines(result)
    lines += [f"  faults: {result.note}"] if result.note else []
    lines += [f"  {name}: not designed: {why}" for name, why in result.failed.items()]
    lines += certificate_lines(result)
    if result.tuned is not None:
        tnd = result.tuned
        what = f"q = {tnd['q']}" if tnd["q"] is not None else f"g = {tnd['g']:g}"
        w = "" if tnd["process_weight"] is None else (f" (process_weight {tnd['process_weight']:.3g}, measurement_weight "
                                                f"{tnd['measurement_weight']:.3g})")
        lines.append(f"  tuned design: no candidate predicted better than the split design it started from "
                     f"({tnd['baseline_predicted_rms']:.4g}): kept it" if tnd.get("kept") else
                     f"  tuned design: gains {tnd['gains']}{w}, {what}: predicted RMS {tnd['predicted_rms']:.4g} "
                     f"vs {tnd['baseline_predicted_rms']:.4g} for the split design it started from")
    plots = []
    if not args.no_plots:
        from .. import plots as P

        P.plot_compare(result, out / "compare_errors.png", out / "compare_ratios.png", unit=P.time_unit(sc.system))
        plots = ["compare_errors.png", "compare_ratios.png"]
    if args.sweep:
        sw = sweep(sc, seed=seed0, steps=args.steps)
        # strict JSON: an infinite predicted RMS is null, and the row's certificate says why (the error grows)
        (out / "sweep.json").write_text(json.dumps(strict_json(sw), indent=2, allow_nan=False) + "\n")
        if not args.no_plots:
            from .. import plots as P

            P.plot_sweep(sw, out / "sweep.png")
            plots.append("sweep.png")
        lines.append(sweep_line(sw))
    res = {**result.to_json(), "plots": plots}
    (out / "compare.json").write_text(json.dumps(res, indent=2, allow_nan=False) + "\n")  # strict: null + why
    lines.append(f"wrote {out}/compare.json" + "".join(f", {p}" for p in plots) +
                 (", sweep.json" if args.sweep else ""))
    print("\n".join(lines))
    return 0


def _rate_sweep(args: argparse.Namespace, sc, seed0: int) -> int:
    """``compare --sweep-rate``: the steady RMS of each estimator against the rate asked."""
    from splitspec_core.studies.rate_sweep import check_rates, rate_sweep, rate_sweep_table

    rates = check_rates(sc, args.sweep_rate)  # before any work: one line, exit 2
    out = out_dir(args.out)
    res = rate_sweep(sc, rates, seeds=range(seed0, seed0 + args.seeds), steps=args.steps)
    from splitspec_core.studies.comparison import strict_json

    (out / "rate_sweep.json").write_text(json.dumps(strict_json(res), indent=2, allow_nan=False) + "\n")
    if not args.no_plots:
        from ..plots import plot_rate_sweep

        plot_rate_sweep(res, out / "rate_sweep.png")
    wrote = f"wrote {out}/rate_sweep.json" + ("" if args.no_plots else ", rate_sweep.png")
    print("\n".join(rate_sweep_table(res) + [wrote]))
    return 0


def _network_sweeps(args: argparse.Namespace, sc, seed0: int) -> int:
    """``compare --sweep-loss / --sweep-deadline``: the design on a misbehaving network, level by level."""
    from splitspec_core.studies.sweeps import check_sweep, network_sweep, sweep_table

    sweeps = [(p, v) for p, v in (("loss", args.sweep_loss), ("deadline", args.sweep_deadline)) if v]
    for parameter, values in sweeps:  # before any work: one line, exit 2
        check_sweep(sc, parameter, values)
    out = out_dir(args.out)
    lines, written = [], []
    for parameter, values in sweeps:
        sw = network_sweep(sc, parameter, values, seeds=range(seed0, seed0 + args.seeds), steps=args.steps,
                           progress=None)
        (out / f"{parameter}_sweep.json").write_text(json.dumps(sw, indent=2) + "\n")
        written.append(f"{parameter}_sweep.json")
        if not args.no_plots:
            from .. import plots as P

            P.plot_network_sweep(sw, out / f"{parameter}_sweep.png")
            written.append(f"{parameter}_sweep.png")
        lines += sweep_table(sw)
    lines.append(f"wrote {out}/" + ", ".join(written))
    print("\n".join(lines))
    return 0
