"""The ``splitspec`` command line.

Every subcommand catches splitspec's own errors at this boundary: one line on
stderr (``splitspec: error: ...``) and exit status 2 for bad input, 1 for a
failed run; no traceback (set ``SPLITSPEC_DEBUG=1`` to see one).  Bad
arguments are refused by the parser itself (``type=`` functions below, and
:class:`ArgumentParser` whose errors are that same one line, without argparse's
usage block).
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import sys

from splitspec_core.runtime.cli import (EXIT_BAD_INPUT, EXIT_FAILED, MAX_SECONDS, MAX_SEED, ArgumentParser,
                                        UsageError, add_logging_options, add_run_id_option,
                                        error_boundary, setup_logging)
from splitspec_core.runtime.cli import at_least as _at_least
from splitspec_core.runtime.cli import integer as _integer
from splitspec_core.runtime.cli import positive as _positive
from splitspec_core.runtime.cli import seed as _seed

MAX_KCF_EPS = 1e12  # as splitspec_core.scenario.MAX_MAGNITUDE


def _seed_range(first: int, count: int, what: str) -> None:
    """Seeds first .. first + count - 1 must all be valid seeds."""
    if first + count - 1 > MAX_SEED:
        raise UsageError(f"{what}: the last seed {first + count - 1} exceeds 2**63 - 1 = {MAX_SEED}")


def _cmd_design(args: argparse.Namespace) -> int:
    from splitspec_core.design import design
    from splitspec_core.report import design_json, design_text
    from splitspec_core.scenario import load_scenario

    sc = load_scenario(args.scenario)
    if args.write and not args.tune:
        raise UsageError("--write needs --tune")
    if args.tune:
        return _tune(args, sc)
    des = design(sc, compare_q_methods=not args.json)
    if args.json:
        json.dump(design_json(des), sys.stdout, indent=None if args.compact else 2)
        sys.stdout.write("\n")
    else:
        print(design_text(des))
    return 0


def _out_dir(path):
    """``--out`` as a Path: created if missing and proven writable, or one clear line (exit 2)."""
    from .outdir import check_output_dir

    return check_output_dir(path)


def _cmd_recover(args: argparse.Namespace) -> int:
    from .recover import RecoverError, recover

    try:
        result = recover(args.out)
    except RecoverError as exc:
        print(f"splitspec: error: {exc}", file=sys.stderr)
        return EXIT_FAILED
    print(result["message"])
    return 0


def _tune(args: argparse.Namespace, sc) -> int:
    from pathlib import Path

    import yaml

    from splitspec_core.noise import tune
    from splitspec_core.scenario import load_yaml, read_scenario_text

    res = tune(sc)
    d = res.design
    cd = res.scenario.design
    what = ("q", d.q) if sc.time == "discrete" else ("g", d.g)
    weights = None if cd.gains != "riccati" else {"process_weight": float(cd.riccati_process_weight),
                                                  "measurement_weight": float(cd.riccati_measurement_weight)}
    summary = {"gains": cd.gains, what[0]: what[1], "riccati": weights, "predicted_rms": res.rms,
               "baseline_predicted_rms": res.baseline_rms, "candidates": res.candidates}
    if args.json:
        json.dump(summary, sys.stdout, indent=None if args.compact else 2)
        sys.stdout.write("\n")
    else:
        print(f"tuned for noise (process {sc.system.process_noise:g}, measurement {sc.system.measurement_noise:g}): "
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
        try:
            Path(args.write).write_text(f"# {sc.name} tuned for noise by `splitspec design --tune rms`\n"
                                        + yaml.safe_dump(raw, sort_keys=False), encoding="utf-8")
        except OSError as exc:
            raise UsageError(f"cannot write {args.write}: {exc.strerror}") from None
        print(f"wrote {args.write}") if not args.json else None
    return 0


def _cmd_compare(args: argparse.Namespace) -> int:
    from splitspec_core.compare import certificate_lines, compare, sweep, sweep_line
    from splitspec_core.scenario import load_scenario
    from splitspec_core.simulate import check_trajectory_memory

    sc = load_scenario(args.scenario)
    seed0 = sc.run.seed if args.seed is None else args.seed
    _seed_range(seed0, args.seeds, "--seeds")
    check_trajectory_memory(sc, args.steps, key="--steps" if args.steps is not None else "run.steps")
    out = _out_dir(args.out)
    res = compare(sc, seeds=range(seed0, seed0 + args.seeds), steps=args.steps, eps=args.kcf_eps)
    curves = res.pop("_curves")
    lines = [f"{sc.name}: {len(res['seeds'])} seeds x {res['steps']} steps; process noise {sc.system.process_noise:g}, "
             f"measurement noise {sc.system.measurement_noise:g}",
             f"  {'estimator':<17} {'steady RMS':>11} {'+-':>9} {'/ central':>9} {'predicted':>10} "
             f"{'settle 1e-3':>11} {'msgs/event':>10}"]
    for name, r in res["estimators"].items():
        pred = "-" if r["predicted_rms"] is None else f"{r['predicted_rms']:.4g}"
        st = "never" if r["settle_time_1e-3"] is None else f"{r['settle_time_1e-3']:g}"
        lines.append(f"  {name:<17} {r['rms_mean']:11.4g} {r['rms_std']:9.2g} {r['ratio_to_centralized']:9.3f} "
                     f"{pred:>10} {st:>11} {r['messages_per_event']:>10}")
    lines += certificate_lines(res)
    if "tuned" in res:
        tnd = res["tuned"]
        what = f"q = {tnd['q']}" if tnd["q"] is not None else f"g = {tnd['g']:g}"
        w = "" if tnd["gains"] == "place" else (f" (process_weight {tnd['process_weight']:.3g}, measurement_weight "
                                                f"{tnd['measurement_weight']:.3g})")
        lines.append(f"  tuned design: gains {tnd['gains']}{w}, {what}: predicted RMS {tnd['predicted_rms']:.4g} "
                     f"vs {tnd['baseline_predicted_rms']:.4g} for the scenario's design")
    plots = []
    if not args.no_plots:
        from . import plots as P

        P.plot_compare({**res, "_curves": curves}, out / "compare_errors.png", out / "compare_ratios.png")
        plots = ["compare_errors.png", "compare_ratios.png"]
    if args.sweep:
        sw = sweep(sc, seed=seed0, steps=args.steps)
        (out / "sweep.json").write_text(json.dumps(sw, indent=2) + "\n")
        if not args.no_plots:
            from . import plots as P

            P.plot_sweep(sw, out / "sweep.png")
            plots.append("sweep.png")
        lines.append(sweep_line(sw))
    res["plots"] = plots
    (out / "compare.json").write_text(json.dumps(res, indent=2) + "\n")
    lines.append(f"wrote {out}/compare.json" + "".join(f", {p}" for p in plots) +
                 (", sweep.json" if args.sweep else ""))
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


def _cmd_simulate(args: argparse.Namespace) -> int:
    from splitspec_core.analysis import event_marks, monte_carlo_stats, summarize
    from splitspec_core.design import design
    from splitspec_core.report import rate_certificate
    from splitspec_core.scenario import load_scenario
    from splitspec_core.simulate import EXACT_NEEDS_FIXED_G, check_trajectory_memory, simulate, simulate_exact

    sc = load_scenario(args.scenario)
    if args.faults_from:
        from splitspec_core.replay import with_recorded_faults

        sc = with_recorded_faults(sc, args.faults_from)
    if args.exact and sc.time != "continuous":
        raise UsageError("--exact integrates the continuous-time ODE; this scenario is discrete")
    if args.exact and sc.design.g == "adaptive":
        raise UsageError(f"--exact: {EXACT_NEEDS_FIXED_G}, or drop --exact")
    seed = sc.run.seed if args.seed is None else args.seed
    if args.monte_carlo:
        _seed_range(seed, args.monte_carlo, "--monte-carlo")
    check_trajectory_memory(sc, args.steps, key="--steps" if args.steps is not None else "run.steps",
                            copies=max(1, args.monte_carlo or 0))
    des = design(sc)
    out = _out_dir(args.out)
    if args.exact:
        traj = simulate_exact(des, seed=seed, steps=args.steps)
        clean = traj
    else:
        traj = simulate(des, seed=seed, steps=args.steps, progress=None)
        noisy = sc.system.process_noise > 0 or sc.system.measurement_noise > 0
        clean = simulate(des, seed=seed, steps=args.steps, noise=False) if noisy else traj
    traj.save(out / "trajectory.npz")
    adaptive = des.g_mode == "adaptive"
    cert = rate_certificate(des, sampled=not args.exact)  # --exact integrates the ODE itself
    summary = summarize(traj, time=sc.time, rate=sc.design.rate, noise_free=clean, adaptive=adaptive,
                        certified_rate=cert.certified)
    summary.update({"certificate": cert.text, "scenario": sc.name, "seed": seed, "time": sc.time,
                    "g": des.g, "q": des.q, "estimator": "exact ODE" if args.exact else "sampled-data" if
                    sc.time == "continuous" else "discrete two-rate"})
    mc = None
    if args.monte_carlo:
        trajs = [simulate(des, seed=seed + k, steps=args.steps) for k in range(args.monte_carlo)]
        mc = monte_carlo_stats(trajs)
        summary["monte_carlo"] = {k: v for k, v in mc.items() if not hasattr(v, "shape")}
    if not args.no_plots:
        from . import plots

        title = f"{sc.name}: {'g = %g' % des.g if des.g is not None else 'q = %d' % des.q if des.q else 'adaptive g'}"
        marks = event_marks(traj.t, traj.alive, traj.graph, agent_ids=traj.agent_ids, faults=sc.faults,
                            graph_names=sc.graph_names, dt=sc.run.dt if sc.time == "continuous" else 1.0)
        plots.plot_errors(traj, out / "errors.png", time=sc.time, rate=sc.design.rate, title=title, marks=marks,
                          noise_free=clean, adaptive=adaptive)
        plots.plot_states(traj, out / "states.png", time=sc.time, title=title, marks=marks)
        summary["plots"] = ["errors.png", "states.png"]
        if mc is not None:
            # faults strike every seed at the same step; a random switching signal may differ per seed
            plots.plot_monte_carlo(traj.t, mc, out / "monte_carlo.png", time=sc.time, title=title,
                                   marks=[mk for mk in marks if mk.kind != "switch"])
            summary["plots"].append("monte_carlo.png")
    (out / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
    print(_simulate_summary_text(summary, time=sc.time, out=out))
    return 0


def _announce_run_id(args: argparse.Namespace) -> None:
    """Give a run started without ``--run-id`` a fresh unique id and say on stderr how to target it."""
    if args.run_id is None:
        from .registry import new_run_id

        args.run_id = new_run_id()
        print(f"splitspec: run id {args.run_id} (splitspec kill --run-id {args.run_id} --agent I)",
              file=sys.stderr, flush=True)


def _cmd_orchestrator(args: argparse.Namespace) -> int:
    from .driver import main as orch_main

    _announce_run_id(args)
    return orch_main(args)


def _cmd_plant(args: argparse.Namespace) -> int:
    import importlib

    # the orchestrator never imports the process shells; the CLI hands the arguments to them
    return importlib.import_module("splitspec_plant.plant").cli_main(args.rest, prog="splitspec plant")


def _cmd_agent(args: argparse.Namespace) -> int:
    import importlib

    return importlib.import_module("splitspec_agents.agent").cli_main(args.rest, prog="splitspec agent")


def _cmd_run(args: argparse.Namespace) -> int:
    from splitspec_core.design import design
    from splitspec_core.scenario import load_scenario
    from splitspec_core.runtime.wire import Keys

    from .launcher import run_local

    sc = load_scenario(args.scenario)
    design(sc)  # fail fast, with one line, before starting any process
    if args.run_id is not None:
        Keys(args.run_id)  # validates --run-id before any process starts
    out = _out_dir(args.out)
    _announce_run_id(args)
    viewer = "spawn" if args.viewer else args.connect_viewer
    if args.insecure:
        print("splitspec: warning: --insecure: no authentication or access control on the router (any process "
              "that reaches it can connect; messages are still signed with the run's key)", file=sys.stderr)
    code = run_local(str(args.scenario), out, run_id=args.run_id, viewer=viewer, wait=args.wait,
                     round_timeout=args.round_timeout, agent_ids=sc.agent_ids, verbose=args.verbose,
                     secure=not args.insecure)
    rrd = out / "run.rrd"
    if rrd.exists():
        print(f"recording: {rrd}  (open it with: {_splitspec_command()} view {out})")
        print(f"trajectory: {out / 'trajectory.npz'}  events: {out / 'events.jsonl'}")
    return code


def _splitspec_command() -> str:
    """``splitspec`` if that is on PATH, else the script next to this interpreter (``.venv/bin/splitspec``)."""
    import shutil
    from pathlib import Path

    if shutil.which("splitspec"):
        return "splitspec"
    beside = Path(sys.executable).parent / "splitspec"
    try:
        return str(beside.relative_to(Path.cwd()))
    except ValueError:
        return str(beside)


def _cmd_view(args: argparse.Namespace) -> int:
    from .view import view

    return view(args.out, web=args.web, port=args.port, grpc_port=args.grpc_port)


def _port(text: str) -> int:
    """``type=`` for TCP ports: an integer in [1, 65535]."""
    return _integer(text, minimum=1, maximum=65535)


def _cmd_router(args: argparse.Namespace) -> int:
    import signal
    import threading

    from splitspec_core.runtime.bus import lease_ms_for, open_session

    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    session = open_session("router", listen=[args.listen], lease_ms=lease_ms_for("router"))
    logging.getLogger("splitspec.router").info("Zenoh router listening on %s (pid %d)", args.listen, os.getpid())
    try:
        while not stop.wait(0.5):
            pass
    finally:
        session.close()
    return 0


def _cmd_credentials(args: argparse.Namespace) -> int:
    from splitspec_core.scenario import load_scenario
    from splitspec_core.runtime.security import generate

    sc = load_scenario(args.scenario)
    cred = generate(args.out, sc.agent_ids)
    print(f"wrote {cred.dir}/users.txt (for the orchestrator: --secure {cred.dir}) and "
          f"{len(cred.users)} .cred files (plant: --credentials {cred.dir}/plant.cred, agent i: "
          f"--credentials {cred.dir}/agent-i.cred); copy each to its host only")
    return 0


_SIGNALS = {"KILL": "SIGKILL", "STOP": "SIGSTOP", "CONT": "SIGCONT", "TERM": "SIGTERM", "INT": "SIGINT"}


def _cmd_kill(args: argparse.Namespace) -> int:
    # import-light on purpose: a fault injected from outside should land when it is asked for
    import signal
    import socket

    from .registry import RunChoiceError, describe_run, is_own_splitspec_process, resolve

    role, ident = ("plant", None) if args.plant else ("orchestrator", None) if args.orchestrator else ("agent", args.agent)
    try:
        pid, host, entry = resolve(args.run_id, role, ident)
    except RunChoiceError as exc:
        print(f"splitspec: error: {exc}", file=sys.stderr)
        for run in exc.runs:
            print(f"  {describe_run(run)}", file=sys.stderr)
        return EXIT_BAD_INPUT
    rid = entry["run_id"]
    what = {"plant": "the plant", "orchestrator": "the orchestrator"}.get(role, f"agent {ident}")
    if host and host != socket.gethostname():
        raise UsageError(f"{what} runs on host {host} (pid {pid}), not here: run splitspec kill there")
    if not is_own_splitspec_process(pid, started_before=entry["_written"]):
        raise UsageError(f"{what} (pid {pid}) of run {rid!r} is not running any more (that pid is not a "
                         "splitspec process of yours now); nothing signalled")
    sig = getattr(signal, _SIGNALS[args.signal])
    try:
        os.kill(pid, sig)
    except ProcessLookupError:
        raise UsageError(f"{what} (pid {pid}) is not running any more") from None
    print(f"sent {_SIGNALS[args.signal]} to {what} (pid {pid}) of run {rid!r} "
          f"(orchestrator pid {entry['orchestrator']['pid']}, records in {entry.get('out')})")
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = ArgumentParser(
        prog="splitspec",
        description="Split-spectrum distributed state estimation: design, simulate, deploy.",
    )
    add_logging_options(parser)
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=ArgumentParser)
    sub.required = True

    p = sub.add_parser("design", help="check the assumptions and design K_i, V_i, P_i and g or q",
                       description="Check a scenario's assumptions and design the estimator "
                                   "(per-agent V_i, P_i, K_i; g or q with the bound it certifies).")
    p.add_argument("scenario", help="scenario YAML file")
    p.add_argument("--json", action="store_true", help="print the design as one JSON object")
    p.add_argument("--compact", action="store_true", help="with --json: no indentation")
    p.add_argument("--tune", choices=["rms"], help="rms: choose q or g and the gains (place, or riccati over a range "
                   "of weights) for the smallest steady-state RMS error under the scenario's noise, keeping the "
                   "rate certified")
    p.add_argument("--write", metavar="FILE", help="with --tune: write the tuned scenario to FILE")
    p.set_defaults(func=_cmd_design)

    p = sub.add_parser("simulate", help="fast in-process reference simulation: trajectory, summary, plots",
                       description="Simulate the scenario in-process (the reference for `splitspec run`): "
                                   "writes trajectory.npz, summary.json and PNG plots to --out.")
    p.add_argument("scenario", help="scenario YAML file")
    p.add_argument("--out", required=True, help="output directory (created if missing)")
    p.add_argument("--seed", type=_seed, help="override run.seed")
    p.add_argument("--steps", type=_at_least(1), help="override run.steps")
    p.add_argument("--monte-carlo", type=_at_least(1), metavar="N", help="also run N seeds (seed, seed+1, ...) and report "
                                                                 "the mean and spread of the error")
    p.add_argument("--exact", action="store_true", help="continuous time: integrate the exact ODE (noise-free) "
                                                        "instead of the sampled-data estimator")
    p.add_argument("--no-plots", action="store_true", help="skip the PNG plots")
    p.add_argument("--faults-from", metavar="EVENTS", help="replay a run: replace the scenario's faults by the "
                   "losses, rejoins and link changes recorded in a run's events.jsonl (use the run's "
                   "scenario.yaml)")
    p.set_defaults(func=_cmd_simulate)

    p = sub.add_parser("compare", help="estimation quality under noise: against the centralized Kalman filter "
                                       "and a Kalman-consensus filter",
                       description="Run split-spectrum (place, riccati, noise-tuned gains), the centralized "
                                   "steady-state Kalman filter and Olfati-Saber's Kalman-consensus filter on the "
                                   "same noise realisations; report steady-state RMS error, ratio to the "
                                   "centralized filter, settling time and messages per event time.")
    p.add_argument("scenario", help="scenario YAML file (with process and/or measurement noise)")
    p.add_argument("--out", required=True, help="output directory (created if missing)")
    p.add_argument("--seeds", type=_at_least(1), default=5, help="noise realisations: seed, seed+1, ... (default 5)")
    p.add_argument("--seed", type=_seed, help="first seed (default run.seed)")
    p.add_argument("--steps", type=_at_least(4), help="override run.steps")
    p.add_argument("--kcf-eps", type=_positive(MAX_KCF_EPS), help="consensus gain of the Kalman-consensus filter "
                                                  "(default 1 / (1 + max in-degree))")
    p.add_argument("--sweep", action="store_true", help="also sweep q (discrete) or g (continuous): RMS error "
                                                         "and measured rate against it (sweep.json, sweep.png)")
    p.add_argument("--no-plots", action="store_true", help="skip the PNG plots")
    p.set_defaults(func=_cmd_compare)

    p = sub.add_parser("run", help="local multi-process deployment: orchestrator, plant and one process per agent",
                       description="Run the scenario as real processes talking over Zenoh on loopback: the "
                                   "orchestrator (embedded router), the plant and one process per agent. Writes "
                                   "trajectory.npz, events.jsonl and run.rrd to --out.")
    p.add_argument("scenario", help="scenario YAML file")
    p.add_argument("--out", required=True, help="output directory (created if missing)")
    v = p.add_mutually_exclusive_group()
    v.add_argument("--viewer", action="store_true", help="spawn the Rerun viewer and stream live")
    v.add_argument("--connect-viewer", metavar="URL", help="stream live to a running Rerun viewer at URL")
    p.add_argument("--round-timeout", type=_positive(MAX_SECONDS), default=10.0,
                   help="seconds before a silent agent is declared lost")
    sec = p.add_mutually_exclusive_group()
    sec.add_argument("--secure", action="store_true", help="the default: Zenoh user/password authentication and "
                     "access control (only the plant publishes measurements and truth, only agent i publishes as "
                     "agent i, clients without credentials are refused; credentials are generated for the run and "
                     "deleted after)")
    sec.add_argument("--insecure", action="store_true", help="no authentication or access control on the router "
                     "(messages are still signed with the run's key); said on the terminal and in events.jsonl")
    add_run_id_option(p)
    p.set_defaults(func=_cmd_run)

    p = sub.add_parser("orchestrator", help="the round driver (embedded Zenoh router); records the run",
                       description="Serve the scenario and the centralised design, drive the rounds, record.")
    p.add_argument("scenario", help="scenario YAML file")
    p.add_argument("--listen", metavar="ENDPOINT", help="open an embedded Zenoh router here, e.g. tcp/0.0.0.0:7447")
    p.add_argument("--connect", metavar="ENDPOINT", help="instead, join an external Zenoh router as a client")
    p.add_argument("--out", required=True, help="output directory (created if missing)")
    p.add_argument("--viewer", metavar="spawn|URL", default=os.environ.get("SPLITSPEC_VIEWER") or None,
                   help="also stream to a Rerun viewer ('spawn' or a URL; default $SPLITSPEC_VIEWER)")
    p.add_argument("--round-timeout", type=_positive(MAX_SECONDS), default=10.0,
                   help="seconds before a silent agent is declared lost")
    p.add_argument("--secure", dest="secure_dir", metavar="DIR", help="authenticate clients against DIR/users.txt "
                   "and enforce the access-control policy (see `splitspec credentials`)")
    p.add_argument("--spawn-local", action="store_true", help="start the plant and the agents on this machine as "
                   "children of the orchestrator (what `splitspec run` does)")
    add_run_id_option(p)
    p.set_defaults(func=_cmd_orchestrator)

    p = sub.add_parser("view", help="open a run's recording (OUT/run.rrd): native Rerun viewer with a display, "
                       "else the web viewer on loopback",
                       description="Open OUT/run.rrd in the native Rerun viewer when a display exists (DISPLAY or "
                                   "WAYLAND_DISPLAY set); otherwise serve Rerun's web viewer on 127.0.0.1 (free "
                                   "ports unless given), print the URL to open (and the ssh -L line to reach it "
                                   "from another machine) and serve until Ctrl-C.")
    p.add_argument("out", metavar="OUT", help="output directory of a run (splitspec run --out OUT)")
    p.add_argument("--web", action="store_true", help="serve the web viewer even when a display exists")
    p.add_argument("--port", type=_port, help="web viewer page port (default: a free port; implies --web)")
    p.add_argument("--grpc-port", type=_port, help="port the page streams the recording from (default: a free "
                   "port; implies --web)")
    p.set_defaults(func=_cmd_view)

    p = sub.add_parser("router", help="a plain Zenoh router (for hosts without zenohd)",
                       description="Run a Zenoh router in this process until Ctrl-C or SIGTERM: the same as zenohd "
                                   "for splitspec's purposes (multicast scouting off, the link lease of the runtime).")
    p.add_argument("--listen", required=True, metavar="ENDPOINT", help="e.g. tcp/0.0.0.0:7447")
    p.set_defaults(func=_cmd_router)

    p = sub.add_parser("credentials", help="generate Zenoh credentials for a secure deployment by hand",
                       description="Write users.txt (for `orchestrator --secure DIR`) and one <user>.cred file per "
                                   "process (for `plant/agent --credentials FILE`) into DIR, private (0700/0600).")
    p.add_argument("scenario", help="scenario YAML file (for the agent ids)")
    p.add_argument("--out", required=True, help="directory to write (created if missing)")
    p.set_defaults(func=_cmd_credentials)

    p = sub.add_parser("kill", help="inject a fault from outside: signal an agent (or the plant) of a running run",
                       description="Send a signal to one process of a run started on this machine (found through "
                                   "the orchestrator's registry). KILL (default) is a crash, STOP a hang (CONT "
                                   "resumes it); the orchestrator detects either and carries on without the agent.")
    who = p.add_mutually_exclusive_group(required=True)
    who.add_argument("--agent", type=int, metavar="I", help="agent id")
    who.add_argument("--plant", action="store_true", help="the plant (the run stops)")
    who.add_argument("--orchestrator", action="store_true", help="the orchestrator (everything stops)")
    p.add_argument("--signal", default="KILL", choices=sorted(_SIGNALS), help="signal to send (default KILL)")
    p.add_argument("--run-id", help="the run's id (default: the only live run of yours on this machine; with "
                   "several, they are listed and nothing is signalled)")
    p.set_defaults(func=_cmd_kill)

    p = sub.add_parser("recover", help="after a crash: make trajectory.npz, events.jsonl and run.rrd agree",
                       description="Take trajectory.npz (K event times) as the authority: rewrite run.rrd with the "
                                   "event times before K so that rerun rrd verify passes, drop a torn last line "
                                   "of events.jsonl and note records_recovered. Harmless on records that agree.")
    p.add_argument("out", metavar="OUT", help="output directory of the run")
    p.set_defaults(func=_cmd_recover)

    p = sub.add_parser("plant", help="the plant process (needs no scenario file)", add_help=False,
                       description="The true system (splitspec plant --help for its options).")
    p.set_defaults(func=_cmd_plant, rest=[])

    p = sub.add_parser("agent", help="one agent process (needs no scenario file)", add_help=False,
                       description="One agent (splitspec agent --help for its options).")
    p.set_defaults(func=_cmd_agent, rest=[])
    return parser


def main(argv: list | None = None) -> int:
    """``splitspec ARGS``: parse, configure logging, run the command inside the error boundary."""
    parser = build_parser()
    args, rest = parser.parse_known_args(argv)
    if args.func in (_cmd_plant, _cmd_agent):
        args.rest = rest  # the process's own parser reads them
    elif rest:
        parser.error(f"unrecognized arguments: {' '.join(rest)}")
    setup_logging(args)
    return error_boundary(args.func, args)


if __name__ == "__main__":
    sys.exit(main())
