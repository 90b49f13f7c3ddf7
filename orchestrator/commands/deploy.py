"""The deployment commands: ``splitspec run`` (local multi-process), ``orchestrator``, ``router``, ``credentials``."""

from __future__ import annotations

import argparse
import logging
import os
import sys

from splitspec_core.errors import SplitspecError

from . import out_dir


def _announce_run_id(args: argparse.Namespace) -> None:
    """Give a run started without ``--run-id`` a fresh unique id and say on stderr how to target it."""
    if args.run_id is None:
        from ..registry import new_run_id

        args.run_id = new_run_id()
        print(f"splitspec: run id {args.run_id} (splitspec kill --run-id {args.run_id} --agent I)",
              file=sys.stderr, flush=True)


def cmd_orchestrator(args: argparse.Namespace) -> int:
    from splitspec_core.runtime.cli import die_with_parent

    from ..driver import main as orch_main

    die_with_parent()  # started by `splitspec run`: go when it goes
    _announce_run_id(args)
    return orch_main(args)


def cmd_run(args: argparse.Namespace) -> int:
    # the modules the orchestrator itself uses, not the public API (splitspec_core.api imports the simulator
    # and with it scipy: a quarter of a second more before the first process starts)
    from splitspec_core.synthesis.design_cache import cached_design as design
    from splitspec_core.runtime.wire import Keys
    from splitspec_core.scenarios.load import load_scenario

    from ..launcher import run_local

    sc = load_scenario(args.scenario)
    design(sc)  # fail fast, with one line, before starting any process
    if args.measurements and sc.sources:
        raise SplitspecError("run --measurements replaces the plant, and this scenario has live sensors (sources:) "
                             "and no plant: drop one (simulate --measurements plays a file for such a scenario)")
    if args.measurements:
        from splitspec_core.scenarios.measurements import load_measurements

        load_measurements(args.measurements, sc)  # a bad file: one line, before any process
    if args.run_id is not None:
        Keys(args.run_id)  # validates --run-id before any process starts
    out = out_dir(args.out)
    _announce_run_id(args)
    line = default_steps_line(sc, measurements=bool(args.measurements))
    if line:
        print(line, flush=True)
    viewer = "spawn" if args.viewer else args.connect_viewer
    if args.insecure:
        print("splitspec: warning: --insecure: no authentication or access control on the router (any process "
              "that reaches it can connect; messages are still signed with the run's key)", file=sys.stderr)
    code = run_local(str(args.scenario), out, run_id=args.run_id, viewer=viewer, wait=args.wait,
                     round_timeout=args.round_timeout, agent_ids=sc.agent_ids, verbose=args.verbose,
                     secure=not args.insecure, measurements=args.measurements, sensor_ids=tuple(sc.sensor_keys),
                     until_stopped=sc.run.until_stopped, standby=sc.run.standby)
    rrd = out / "run.rrd"
    from ..viewer.rrd_file import rrd_segments

    segments = rrd_segments(rrd)
    if segments:  # run.keep may have removed run.rrd, the first segment: name the first one left
        from splitspec_core.runs import end_event, closing_line, read_events

        from ..view import retention_line

        left = "" if segments[0] == rrd else f", the first of {len(segments)} segments run.keep left"
        print(f"recording: {segments[0]}{left}  (open it with: {_splitspec_command()} view {out})")
        rows = out / "trajectory.npz" if (out / "trajectory.npz").exists() else out / "chunks"
        print(f"trajectory: {rows}  events: {out / 'events.jsonl'}")
        _network_line(sc, out)
        if args.measurements or sc.sources:
            _reference_line(out, sensors=not args.measurements)
        try:
            end = end_event(read_events(out / "events.jsonl"))
        except OSError:
            end = None
        if end is not None:
            print(closing_line(end))
        kept = retention_line(out) if sc.run.keep_hours is not None or sc.run.keep_gigabytes is not None else None
        if kept is not None:  # run.keep: what it removed and what is left, or why nothing went (issue 46)
            print(kept)
    return code


def default_steps_line(sc, *, measurements: bool = False) -> str:
    """The line ``splitspec run`` prints before a run of the default ``run.steps`` (an unpaced scenario without
    them: it does not run until stopped, as a paced one does); empty for any other run (a file of measurements
    decides its own steps)."""
    r = sc.run
    if not r.steps_default or r.until_stopped or measurements:
        return ""
    what = f"{r.steps} steps" + ("" if sc.time == "discrete" else f" of run.dt {r.dt:g} {sc.system.time_unit}")
    return (f"splitspec: run.steps not given: running the default {what} ({r.steps + 1} event times); set run.steps, "
            "or run.pace to run until stopped")


def _reference_line(out, *, sensors: bool) -> None:
    """A run on recorded measurements or live sensors: what is known at the end (for live sensors, how many
    event times had a measurement; the error to the truth when a file has it, else the reference only)."""
    import numpy as np

    try:
        with np.load(out / "trajectory.npz") as z:
            if "kf_distance" not in z.files:
                return
            last = lambda a: float(np.nanmax(a)) if np.isfinite(a).any() else float("nan")  # noqa: E731
            truth = bool(np.isfinite(z["x"]).any())
            if sensors:
                have = ~z["y_missing"][:-1]  # the final event time has no round, so no measurement
                head = (f"live sensors: {int(have.sum())} of {have.size} (event time, agent) measurements used; "
                        "at the end")
            else:
                head = "measurements: at the end"
            text = (f"{head}, consensus disagreement {last(z['disagreement'][-1:]):.3g}, largest distance to the "
                    f"centralized Kalman filter {last(z['kf_distance'][-1]):.3g}")
            if truth:
                err = last(np.linalg.norm(z["xhat"][-1] - z["x"][-1], axis=1))
                text += f", largest error to the file's truth {err:.3g}"
            else:
                text += " (no truth)" if sensors else " (the file has no truth)"
    except (OSError, ValueError, KeyError):
        return
    print(text)


def _network_line(sc, out) -> None:
    """On a network that misbehaves: how many consensus messages did not count, by cause, and how to replay them."""
    import numpy as np

    from splitspec_core.model.impairment import CAUSES

    if not sc.network.impaired and not any(f.drops_messages for f in sc.faults):
        return
    try:
        with np.load(out / "trajectory.npz") as z:
            causes = np.bincount(z["lost_cause"], minlength=len(CAUSES)) if "lost_cause" in z.files else None
    except (OSError, ValueError):
        return
    if causes is None:
        return
    by = ", ".join(f"{int(c)} {name}" for name, c in zip(CAUSES, causes) if c)
    print(f"network: {int(causes.sum())} consensus messages did not count" + (f" ({by})" if by else "")
          + f"; replay them: {_splitspec_command()} simulate {out / 'scenario.yaml'} --out {out / 'replay'} "
            f"--faults-from {out}")


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


def cmd_standby(args: argparse.Namespace) -> int:
    from splitspec_core.runtime.cli import die_with_parent
    from splitspec_core.runtime.wire import Keys

    from ..standby import main as standby_main

    die_with_parent()  # started by `splitspec run`: go when it goes
    Keys(args.run_id)  # validates --run-id
    return standby_main(args)


def cmd_router(args: argparse.Namespace) -> int:
    import signal
    import time

    from splitspec_core.runtime.bus import lease_ms_for, open_session
    from splitspec_core.runtime.cli import die_with_parent

    die_with_parent()  # started by `splitspec run` (a run with a standby): go when it goes
    kw: dict = {}
    if args.secure_dir:
        if not args.scenario or not args.run_id:
            raise SplitspecError("router --secure DIR needs the run's --scenario FILE and --run-id ID (its access "
                                 "control names the run's agents)")
        import splitspec_core as ss
        from splitspec_core.runtime.security import Credentials

        sc = ss.load_scenario(args.scenario)
        kw["extra"] = Credentials.load(args.secure_dir).router_extra(args.run_id, sc.agent_ids, sc.sensor_keys)
    # a plain flag, not a threading.Event: the handler runs in this thread, and Event.set inside Event.wait's own
    # lock (a signal arriving there) deadlocks (it did in `splitspec view`)
    stop: list = []
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.append(True))
    session = open_session("router", listen=[args.listen], lease_ms=lease_ms_for("router"), **kw)
    logging.getLogger("splitspec.router").info("Zenoh router listening on %s (pid %d)", args.listen, os.getpid())
    try:
        while not stop:
            time.sleep(0.2)
    finally:
        session.close()
    return 0


def cmd_credentials(args: argparse.Namespace) -> int:
    import splitspec_core as ss
    from splitspec_core.runtime.security import generate

    sc = ss.load_scenario(args.scenario)
    sensors = tuple(sc.sensor_keys)  # agent ids, and "inputs" for live known inputs
    cred = generate(args.out, sc.agent_ids, sensors)
    print(f"wrote {cred.dir}/users.txt (for the orchestrator: --secure {cred.dir}) and "
          f"{len(cred.users)} .cred files (plant: --credentials {cred.dir}/plant.cred, agent i: "
          f"--credentials {cred.dir}/agent-i.cred" + (f", agent i's sensor: {cred.dir}/sensor-i.cred" if sensors else "")
          + "); copy each to its host only")
    return 0
