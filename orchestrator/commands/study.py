"""The study commands: ``splitspec design``, ``simulate`` and ``compare`` (offline, one process).

Each calls the public API (:mod:`splitspec_core.api`) and writes what it returns: the report,
``trajectory.npz`` / ``summary.json`` / plots, ``compare.json`` / plots.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import sys
from pathlib import Path

import numpy as np

import splitspec_core as ss
from splitspec_core.runtime.cli import MAX_SEED, UsageError
from splitspec_core.scenarios.noise import noise_text

from . import out_dir


MAX_KCF_EPS = 1e12  # as splitspec_core.scenarios.specs.MAX_MAGNITUDE


def _seed_range(first: int, count: int, what: str) -> None:
    """Seeds first .. first + count - 1 must all be valid seeds."""
    if first + count - 1 > MAX_SEED:
        raise UsageError(f"{what}: the last seed {first + count - 1} exceeds 2**63 - 1 = {MAX_SEED}")


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
    from splitspec_core.synthesis.noise_tuning import tune
    from splitspec_core.scenarios.load import dump_yaml, load_yaml, read_scenario_text

    res = tune(sc)
    d = res.design
    cd = res.scenario.design
    what = ("q", d.q) if sc.time == "discrete" else ("g", d.g)
    weighted = gain_methods.method(cd.gains).weighted  # its Riccati weights travel with it (design.riccati)
    weights = None if not weighted else {"process_weight": float(cd.process_weight),
                                         "measurement_weight": float(cd.measurement_weight)}
    summary = {"gains": cd.gains, what[0]: what[1], "riccati": weights, "predicted_rms": res.rms,
               "baseline_predicted_rms": res.baseline_rms, "candidates": res.candidates}
    if args.json:
        json.dump(summary, sys.stdout, indent=None if args.compact else 2)
        sys.stdout.write("\n")
    else:
        print(f"tuned for noise (process {noise_text(sc.system.process_noise)}, measurement "
              f"{noise_text(sc.system.measurement_noise)}): "
              f"gains {cd.gains}" + (f" {weights}" if weights else "") + f", {what[0]} = {what[1]:g}")
        print(f"  predicted steady-state RMS error {res.rms:.4g} (the scenario's design: {res.baseline_rms:.4g}, "
              f"{len(res.candidates)} candidates, all with the rate certified unless marked)")
    if args.write:
        raw = load_yaml(read_scenario_text(args.scenario), source=str(args.scenario))
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
        try:
            Path(args.write).write_text(f"# {sc.name} tuned for noise by `splitspec design --tune rms`\n"
                                        + dump_yaml(raw), encoding="utf-8")
        except OSError as exc:
            raise UsageError(f"cannot write {args.write}: {exc.strerror}") from None
        print(f"wrote {args.write}") if not args.json else None
    return 0


def cmd_compare(args: argparse.Namespace) -> int:
    from splitspec_core.studies.comparison import certificate_lines, sweep, sweep_line
    from splitspec_core.simulation.simulator import check_trajectory_memory

    sc = ss.load_scenario(args.scenario)
    seed0 = sc.run.seed if args.seed is None else args.seed
    _seed_range(seed0, args.seeds, "--seeds")
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
             "  steady RMS: from the end of each estimator's certified transient (steady from) to the end of the run",
             f"  {'estimator':<22} {'steady RMS':>11} {'+-':>9} {'/ central':>9} {'predicted':>10} "
             f"{'steady from':>11} {'settle 1e-3':>11} {'msgs/event':>10}"]
    for name, r in result.estimators.items():
        pred = "-" if r.predicted_rms is None else f"{r.predicted_rms:.4g}"
        st = "never" if r.settle_time is None else f"{r.settle_time:g}"
        if r.steady_from is None:
            lines.append(f"  {name:<22} {'-':>11} {'':>9} {'-':>9} {pred:>10} {'not settled':>11} {st:>11} "
                         f"{r.messages_per_event:>10}")
            continue
        ratio = "-" if r.ratio_to_centralized is None else f"{r.ratio_to_centralized:.3f}"
        lines.append(f"  {name:<22} {r.rms_mean:11.4g} {r.rms_std:9.2g} {ratio:>9} "
                     f"{pred:>10} {r.steady_from:11g} {st:>11} {r.messages_per_event:>10}")
    lines += [f"  {name}: {r.note}" for name, r in result.estimators.items() if r.note]
    lines += [f"  faults: {result.note}"] if result.note else []
    lines += [f"  {name}: not designed: {why}" for name, why in result.failed.items()]
    lines += certificate_lines(result)
    if result.tuned is not None:
        tnd = result.tuned
        what = f"q = {tnd['q']}" if tnd["q"] is not None else f"g = {tnd['g']:g}"
        w = "" if tnd["gains"] == "place" else (f" (process_weight {tnd['process_weight']:.3g}, measurement_weight "
                                                f"{tnd['measurement_weight']:.3g})")
        lines.append(f"  tuned design: gains {tnd['gains']}{w}, {what}: predicted RMS {tnd['predicted_rms']:.4g} "
                     f"vs {tnd['baseline_predicted_rms']:.4g} for the split design it started from")
    plots = []
    if not args.no_plots:
        from .. import plots as P

        P.plot_compare(result, out / "compare_errors.png", out / "compare_ratios.png")
        plots = ["compare_errors.png", "compare_ratios.png"]
    if args.sweep:
        sw = sweep(sc, seed=seed0, steps=args.steps)
        (out / "sweep.json").write_text(json.dumps(sw, indent=2) + "\n")
        if not args.no_plots:
            from .. import plots as P

            P.plot_sweep(sw, out / "sweep.png")
            plots.append("sweep.png")
        lines.append(sweep_line(sw))
    res = {**result.to_json(), "plots": plots}
    (out / "compare.json").write_text(json.dumps(res, indent=2) + "\n")
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
    (out / "rate_sweep.json").write_text(json.dumps(res, indent=2) + "\n")
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


def _simulate_summary_text(summary: dict, *, time: str, out) -> str:
    rate_word = "exp(-lam t)" if time == "continuous" else "lam^tau"
    meas = summary["measured_rate"]
    if summary.get("rate_note"):  # the adaptive gain: no rate to meet
        lines = [f"simulated {summary['steps']} steps; adaptive gain: {summary['rate_note']}"]
        if meas is not None:
            lines.append(f"  measured rate (noise-free, tail fit) {meas:.4g} ({rate_word}), for information")
    else:
        lines = [f"simulated {summary['steps']} steps; designed rate {summary['designed_rate']:g} ({rate_word})"
                 + ("" if summary.get("certified_rate", True) else
                    f", NOT certified by the design ({summary.get('certificate')})")]
        if meas is not None:
            verdict = "meets" if summary["measured_meets_design"] else "does NOT meet"
            lines.append(f"  measured rate (noise-free, tail fit) {meas:.4g}: {verdict} the design")
        if summary.get("envelope_pieces") and len(summary["envelope_pieces"]) > 1:
            lines.append(f"  envelope restarted {len(summary['envelope_pieces']) - 1} times (rejoins, switches)")
    lines.append(f"  alive at the end: {', '.join(map(str, summary['alive_at_end'])) or 'none'}")
    lines.append("  agent   final error   max error")
    for aid, a in summary["agents"].items():
        fe = "dead" if a["final_error"] is None else f"{a['final_error']:.3e}"
        me = "-" if a["max_error"] is None else f"{a['max_error']:.3e}"
        lines.append(f"  {aid:>5}   {fe:>11}   {me:>9}")
    if "monte_carlo" in summary:
        mc = summary["monte_carlo"]
        lines.append(f"  monte carlo over {mc['seeds']} seeds: steady-state RMS error {mc['steady_rms_mean']:.4g} "
                     f"+- {mc['steady_rms_std']:.3g}, final {mc['final_rms_mean']:.4g} +- {mc['final_rms_std']:.3g}")
    lines.append(f"wrote {out}/trajectory.npz, summary.json" + ("" if summary.get("plots") is None else
                                                               ", " + ", ".join(summary["plots"])))
    return "\n".join(lines)


def _chunked_run(out, sc, lost):
    """A run whose rows are in its chunks only (it went on until stopped): the consensus messages that did not
    count (``lost``, when ``trajectory.npz`` gave none) and its last event time (the steps to replay; None for a
    run of ``run.steps``)."""
    from splitspec_core.simulation.trajectory_chunks import has_chunks, read_chunks

    if (out / "trajectory.npz").is_file() or not has_chunks(out):
        return lost, None
    rows = read_chunks(out)
    if lost is None and len(rows["lost"]):
        lost = (rows["lost"], rows["lost_cause"])
    return lost, (int(rows["tau"][-1]) if sc.run.until_stopped and len(rows["tau"]) else None)


def cmd_simulate(args: argparse.Namespace) -> int:
    from splitspec_core.simulation.metrics import event_marks, sensor_events, summarize
    from splitspec_core.synthesis.verdict import rate_certificate
    from splitspec_core.simulation.simulator import check_trajectory_memory

    sc = ss.load_scenario(args.scenario)
    if sc.sources and not args.measurements:
        raise UsageError("this scenario's measurements come from live sensors (sources:), which simulate does not "
                         "have: give --measurements FILE (a sensor's recorded log) or use `splitspec run`")
    lost = None
    if args.faults_from:
        from splitspec_core.scenarios.replay import recorded_run, with_recorded_faults

        events, lost = recorded_run(args.faults_from)
        sc = with_recorded_faults(sc, events)
        lost, steps = _chunked_run(events.parent, sc, lost)
        if args.steps is None and steps is not None:
            args.steps = steps  # a run until stopped: replay as many event times as it recorded
        if lost is None and sc.network.impaired:
            lost = (np.zeros((0, 4), dtype=np.int64), None)  # the run lost nothing: replay that, draw nothing
    if args.measurements or args.write_measurements:
        if args.exact:
            raise UsageError("--exact integrates the noise-free ODE; --measurements and --write-measurements belong "
                             "to the sampled-data estimator: drop one")
        if args.monte_carlo:
            raise UsageError("--monte-carlo draws new noise per seed; --measurements and --write-measurements fix "
                             "one realisation: drop one")
    meas = None
    if args.measurements:
        from splitspec_core.scenarios.measurements import load_measurements

        meas = load_measurements(args.measurements, sc, steps=args.steps)
    if args.exact and sc.time != "continuous":
        raise UsageError("--exact integrates the continuous-time ODE; this scenario is discrete")
    if args.exact and sc.design.g == "adaptive":
        from splitspec_core.simulation.simulator import EXACT_NEEDS_FIXED_G

        raise UsageError(f"--exact: {EXACT_NEEDS_FIXED_G}, or drop --exact")
    seed = sc.run.seed if args.seed is None else args.seed
    if args.monte_carlo:
        _seed_range(seed, args.monte_carlo, "--monte-carlo")
    # --monte-carlo keeps no trajectory per seed (ss.simulate(seeds=...): per-step errors only), so one is the peak
    check_trajectory_memory(sc, meas.steps if meas is not None else args.steps,
                            key="--steps" if args.steps is not None else "run.steps")
    d = ss.design(sc)
    out = out_dir(args.out)
    traj = ss.simulate(d, seed=seed, steps=args.steps, exact=args.exact, progress=None, lost=lost, measurements=meas,
                       keep_y=bool(args.write_measurements))
    if meas is not None:
        return _simulate_measured(args, sc, d, traj, meas, out)
    noisy = sc.system.has_noise
    clean = ss.simulate(d, seed=seed, steps=args.steps, noise=False, lost=lost) if noisy and not args.exact else traj
    if args.write_measurements:
        from splitspec_core.scenarios.measurements import write_measurements

        write_measurements(args.write_measurements, t=traj.t, y=traj.y, agent_ids=sc.agent_ids,
                           sizes=[np.shape(C)[0] for C in sc.system.Cs], x=traj.x, u=traj.u)
        traj = dataclasses.replace(traj, y=None, y_missing=None)  # the file holds them; trajectory.npz as always
    traj.save(out / "trajectory.npz")
    adaptive = d.g_mode == "adaptive"
    # the certificate of what ran: --exact integrates the ODE itself, else the sampled-data form
    cert = rate_certificate(d.detail, sampled=not args.exact)
    # the envelope's rate: the design's, or slower when directions no agent sees limit it; none when some of them do
    # not decay (design.undetectable: exclude: the certificate is of the error modulo them)
    envelope_rate = None if d.detail.excluded else d.detail.envelope_rate
    summary = summarize(traj, time=sc.time, rate=envelope_rate, noise_free=clean, adaptive=adaptive,
                        certified_rate=cert.certified)
    summary.update({"certificate": cert.text, "scenario": sc.name, "seed": seed, "time": sc.time,
                    "g": d.g, "q": d.q, "estimator": "exact ODE" if args.exact else "discrete two-rate" if
                    d.detail.two_rate else "sampled-data"})
    mc = None
    if args.monte_carlo:
        # the seeds as one batch (or one after another where a seed changes more than the noise: MonteCarloRuns)
        mc = ss.simulate(d, seeds=range(seed, seed + args.monte_carlo), steps=args.steps).stats()
        summary["monte_carlo"] = {k: v for k, v in mc.items() if not hasattr(v, "shape")}
    if not args.no_plots:
        from .. import plots

        title = f"{sc.name}: {'g = %g' % d.g if d.g is not None else 'q = %d' % d.q if d.q else 'adaptive g'}"
        marks = event_marks(traj.t, traj.alive, traj.graph, agent_ids=traj.agent_ids, faults=sc.faults,
                            graph_names=sc.graph_names, dt=sc.run.dt if sc.time == "continuous" else 1.0,
                            sensors=sensor_events(traj, d.detail))  # design.bad_data: sensors set aside, taken back
        plots.plot_errors(traj, out / "errors.png", time=sc.time, rate=envelope_rate, title=title,
                          marks=marks, noise_free=clean, adaptive=adaptive)
        plots.plot_states(traj, out / "states.png", time=sc.time, title=title, marks=marks, shown=sc.shown_states)
        summary["plots"] = ["errors.png", "states.png"]
        if mc is not None:
            # faults strike every seed at the same step; a random switching signal may differ per seed
            plots.plot_monte_carlo(traj.t, mc, out / "monte_carlo.png", time=sc.time, title=title,
                                   marks=[mk for mk in marks if mk.kind != "switch"])
            summary["plots"].append("monte_carlo.png")
    (out / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
    print(_simulate_summary_text(summary, time=sc.time, out=out))
    if args.write_measurements:
        print(f"wrote {args.write_measurements} (the measurements and the truth; splitspec simulate --measurements "
              "reads it back)")
    return 0


def _simulate_measured(args: argparse.Namespace, sc, d, traj, meas, out) -> int:
    """``simulate --measurements``: the estimates from the user's measurements, judged by what can be known."""
    from splitspec_core.simulation.metrics import event_marks, summarize
    from splitspec_core.studies.no_truth import no_truth_arrays

    ref = no_truth_arrays(traj, sc, meas.u)
    traj.save(out / "trajectory.npz", extra=ref)
    summary = {"scenario": sc.name, "time": sc.time, "q": d.q, "g": d.g, "measurements": meas.path,
               "sha256": meas.sha256, "truth": meas.has_truth, "steps": int(traj.t.size - 1),
               "missing": int(meas.missing[:traj.t.size - 1].sum())}
    if meas.has_truth:
        summary.update(summarize(traj, time=sc.time, rate=sc.design.rate, adaptive=d.g_mode == "adaptive"))
    summary["reference"] = _reference_summary(traj, ref)
    plots = []
    if not args.no_plots:
        from .. import plots as P

        title = f"{sc.name}: {'g = %g' % d.g if d.g is not None else 'q = %d' % d.q if d.q else 'adaptive g'}" \
                f", measurements {Path(meas.path).name}"
        marks = event_marks(traj.t, traj.alive, traj.graph, agent_ids=traj.agent_ids, faults=sc.faults,
                            graph_names=sc.graph_names, dt=sc.run.dt if sc.time == "continuous" else 1.0)
        P.plot_reference(traj, ref, out / "reference.png", time=sc.time, title=title, marks=marks)
        plots.append("reference.png")
        if meas.has_truth:
            P.plot_errors(traj, out / "errors.png", time=sc.time, rate=sc.design.rate, title=title, marks=marks,
                          adaptive=d.g_mode == "adaptive")
            plots.append("errors.png")
        P.plot_states(traj, out / "states.png", time=sc.time, title=title, marks=marks,
                      reference=None if meas.has_truth else ref["kf"], shown=sc.shown_states)
        plots.append("states.png")
    summary["plots"] = plots
    (out / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
    r = summary["reference"]
    lines = [f"estimated {summary['steps']} steps from {meas.path} ({'with' if meas.has_truth else 'no'} truth"
             + (f", {summary['missing']} measurements missing: predicted only" if summary["missing"] else "") + ")",
             f"  at the end: consensus disagreement {_g(r['final_disagreement'])}, largest residual "
             f"{_g(r['final_residual_max'])}, largest distance to the centralized Kalman filter "
             f"{_g(r['final_kf_distance_max'])}"]
    if meas.has_truth:
        lines.append("  final error (truth in the file): max "
                     + _g(max((a["final_error"] for a in summary["agents"].values() if a["final_error"] is not None),
                              default=None)))
    lines.append(f"wrote {out}/trajectory.npz, summary.json" + "".join(f", {p}" for p in plots))
    print("\n".join(lines))
    return 0


def _g(x) -> str:
    return "-" if x is None else f"{x:.3g}"


def _reference_summary(traj, ref: dict) -> dict:
    """Final and largest residual, disagreement and distance to the centralized KF (what is known without truth)."""
    def last(a):
        a = np.asarray(a)
        finite = a[np.isfinite(a)]
        return float(finite.max()) if finite.size else None

    per_agent = {}
    for k, aid in enumerate(traj.agent_ids.tolist()):
        per_agent[str(aid)] = {"final_residual": last(ref["residual"][-1:, k]),
                               "final_kf_distance": last(ref["kf_distance"][-1:, k]),
                               "max_kf_distance": last(ref["kf_distance"][:, k])}
    return {"final_disagreement": last(ref["disagreement"][-1:]), "max_disagreement": last(ref["disagreement"]),
            "final_residual_max": last(ref["residual"][-1]), "final_kf_distance_max": last(ref["kf_distance"][-1]),
            "agents": per_agent}
