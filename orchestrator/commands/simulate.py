"""``splitspec simulate`` (offline, one process): the public API's simulation, then ``trajectory.npz``,
``summary.json`` and the plots; a run's faults replayed (``--faults-from``), recorded measurements, the references
computed without the truth.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
from pathlib import Path

import numpy as np

import splitspec_core as ss
from splitspec_core.runtime.cli import UsageError

from . import out_dir, seed_range


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
            after, tau = summary.get("measured_after_fault"), "tau" if time == "discrete" else "t"
            fit = "tail fit" + ("" if after is None else f" from {tau} = {summary['measured_from']:g}, after the last "
                                f"fault's effect at {tau} = {after:g}")
            verdict = "meets" if summary["measured_meets_design"] else "does NOT meet"
            lines.append(f"  measured rate (noise-free, {fit}) {meas:.4g}: {verdict} the design")
        elif summary.get("measured_note"):
            lines.append(f"  measured rate (noise-free): not measured: {summary['measured_note']}")
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
    from splitspec_core.synthesis.conditioning import conditioning
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
        seed_range(seed, args.monte_carlo, "--monte-carlo")
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
    dt = sc.run.dt if sc.time == "continuous" else 1.0
    summary = summarize(traj, time=sc.time, rate=envelope_rate, noise_free=clean, adaptive=adaptive,
                        certified_rate=cert.certified, faults=sc.faults, dt=dt, sensors=sensor_events(clean, d.detail),
                        transient=conditioning(d.detail).transient_constant if sc.faults and not adaptive else None)
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
                            graph_names=sc.graph_names, dt=dt,
                            sensors=sensor_events(traj, d.detail))  # design.bad_data: sensors set aside, taken back
        unit = plots.time_unit(sc.system)  # system.time_unit on the time axes
        plots.plot_errors(traj, out / "errors.png", time=sc.time, rate=envelope_rate, title=title,
                          marks=marks, noise_free=clean, adaptive=adaptive, unit=unit)
        plots.plot_states(traj, out / "states.png", time=sc.time, title=title, marks=marks, shown=sc.shown_states,
                          unit=unit)
        summary["plots"] = ["errors.png", "states.png"]
        if mc is not None:
            # faults strike every seed at the same step; a random switching signal may differ per seed
            plots.plot_monte_carlo(traj.t, mc, out / "monte_carlo.png", time=sc.time, title=title,
                                   marks=[mk for mk in marks if mk.kind != "switch"], unit=unit)
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
        summary.update(summarize(traj, time=sc.time, rate=sc.design.rate, adaptive=d.g_mode == "adaptive",
                                 faults=sc.faults, dt=sc.run.dt if sc.time == "continuous" else 1.0))
    summary["reference"] = _reference_summary(traj, ref)
    plots = []
    if not args.no_plots:
        from .. import plots as P

        title = f"{sc.name}: {'g = %g' % d.g if d.g is not None else 'q = %d' % d.q if d.q else 'adaptive g'}" \
                f", measurements {Path(meas.path).name}"
        marks = event_marks(traj.t, traj.alive, traj.graph, agent_ids=traj.agent_ids, faults=sc.faults,
                            graph_names=sc.graph_names, dt=sc.run.dt if sc.time == "continuous" else 1.0)
        unit = P.time_unit(sc.system)  # system.time_unit on the time axes
        P.plot_reference(traj, ref, out / "reference.png", time=sc.time, title=title, marks=marks, unit=unit)
        plots.append("reference.png")
        if meas.has_truth:
            P.plot_errors(traj, out / "errors.png", time=sc.time, rate=sc.design.rate, title=title, marks=marks,
                          adaptive=d.g_mode == "adaptive", unit=unit)
            plots.append("errors.png")
        P.plot_states(traj, out / "states.png", time=sc.time, title=title, marks=marks,
                      reference=None if meas.has_truth else ref["kf"], shown=sc.shown_states, unit=unit)
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
