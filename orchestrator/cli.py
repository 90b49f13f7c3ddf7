"""The ``splitspec`` command line: the parser and the error boundary; the commands live in :mod:`.commands`.

Every subcommand catches splitspec's own errors at this boundary: one line on
stderr (``splitspec: error: ...``) and exit status 2 for bad input, 1 for a
failed run; no traceback (set ``SPLITSPEC_DEBUG=1`` to see one).  Bad
arguments are refused by the parser itself (``type=`` functions below, and
:class:`ArgumentParser` whose errors are that same one line, without argparse's
usage block).
"""

from __future__ import annotations

import argparse
import os
from typing import Callable

from splitspec_core.runtime.cli import EXIT_BAD_INPUT, EXIT_FAILED  # noqa: F401 - the exit statuses, for callers
from splitspec_core.runtime.cli import (MAX_SECONDS, ArgumentParser, add_logging_options, add_run_id_option,
                                        error_boundary, setup_logging)
from splitspec_core.runtime.cli import at_least as _at_least
from splitspec_core.runtime.cli import positive as _positive
from splitspec_core.runtime.cli import seed as _seed

from .commands.operate import SIGNALS, port

MAX_KCF_EPS = 1e12  # as splitspec_core.scenarios.specs.MAX_MAGNITUDE
MAX_NETWORK_SECONDS = 60.0  # as splitspec_core.scenarios.checks.MAX_NETWORK_SECONDS (this module stays light)


def _loss_level(text: str) -> float:
    """``--sweep-loss``: a probability in [0, 1)."""
    try:
        value = float(text)
    except (TypeError, ValueError):
        value = float("nan")
    if not 0.0 <= value < 1.0:  # False for nan too
        raise argparse.ArgumentTypeError(f"must be a loss probability in [0, 1), got {text!r}")
    return value


_loss_level.__name__ = "loss probability"


def _cmd_plant(args: argparse.Namespace) -> int:
    # `splitspec plant` and `splitspec agent` hand their arguments to the process shells: this module is the one
    # place of the orchestrator package that imports them (the "entry" layer, docs/explanation/architecture.md)
    from splitspec_plant.plant import cli_main

    return cli_main(args.rest, prog="splitspec plant")


def _cmd_agent(args: argparse.Namespace) -> int:
    from splitspec_agents.agent import cli_main

    return cli_main(args.rest, prog="splitspec agent")


def _commands_module(module: str):
    """The module of :mod:`.commands` holding a command, imported when the command runs."""
    if module == "study":
        from .commands import study as mod
    elif module == "deploy":
        from .commands import deploy as mod
    elif module == "pace":
        from .commands import pace as mod
    elif module == "simulate":
        from .commands import simulate as mod
    else:
        from .commands import operate as mod
    return mod


def _command(target: str) -> Callable[[argparse.Namespace], int]:
    """``"study:cmd_design"`` -> a function importing :mod:`.commands.study` only when the command runs
    (``splitspec kill`` must start fast: it does not load numpy or scipy)."""
    module, _, name = target.partition(":")

    if module not in ("study", "simulate", "deploy", "pace", "operate"):
        raise ValueError(f"no commands module {module!r}")

    def run(args: argparse.Namespace) -> int:
        return getattr(_commands_module(module), name)(args)

    run.__name__ = name
    return run


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
    p.add_argument("--all-methods", action="store_true", help="discrete time: also compute, for comparison, the q "
                   "every other q method (spectral, weighted, two-norm, mixed) would give")
    p.add_argument("--tune", choices=["rms"], help="rms: choose q or g and the gains (place, or riccati over a range "
                   "of weights) for the smallest steady-state RMS error under the scenario's noise, keeping the "
                   "rate certified")
    p.add_argument("--write", metavar="FILE", help="with --tune: write the tuned scenario to FILE")
    p.add_argument("--workers", type=_at_least(1), help="processes for the spectral radii of a large resilient "
                   "design (one case per agent loss); default: every CPU this process may use")
    p.set_defaults(func=_command("study:cmd_design"))

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
    p.add_argument("--faults-from", metavar="RUN", help="replay a run (its output directory, or its events.jsonl): "
                   "the losses, rejoins, link changes and partitions of its events.jsonl replace the scenario's "
                   "faults, and the consensus messages its trajectory.npz records as lost are dropped (use the "
                   "run's scenario.yaml)")
    meas = p.add_mutually_exclusive_group()
    meas.add_argument("--measurements", metavar="FILE", help="estimate from these recorded measurements instead of "
                      "the simulated plant (.npz: t, y_<id>, optional x; .csv: header t, y<id>.<row>, x.<k>; one row "
                      "per event time); without x the outputs hold residuals, disagreement and the distance to the "
                      "centralized Kalman filter")
    meas.add_argument("--write-measurements", metavar="FILE", help="also write the simulated plant's measurements "
                      "and truth as a measurements file (.npz or .csv), which --measurements reads back")
    p.set_defaults(func=_command("simulate:cmd_simulate"))

    p = sub.add_parser("compare", help="estimation quality under noise: against the centralized Kalman filter "
                                       "and a Kalman-consensus filter",
                       description="Run the scenario's design, the paper's split (place, riccati, noise-tuned "
                                   "gains), the centralized steady-state Kalman filter (and the centralized Kalman "
                                   "filter designed for A/rate, a rate-shifted Riccati design, when the Kalman "
                                   "filter is slower) and "
                                   "Olfati-Saber's Kalman-consensus filter on the same noise realisations; report "
                                   "steady-state RMS error after each one's certified transient, ratio to the "
                                   "centralized filter, the predicted RMS, settling time and messages per event "
                                   "time.")
    p.add_argument("scenario", help="scenario YAML file (with process and/or measurement noise)")
    p.add_argument("--out", required=True, help="output directory (created if missing)")
    p.add_argument("--seeds", type=_at_least(1), default=5, help="noise realisations: seed, seed+1, ... (default 5)")
    p.add_argument("--seed", type=_seed, help="first seed (default run.seed)")
    p.add_argument("--steps", type=_at_least(4), help="override run.steps (default: run.steps, or twice the longest "
                   "certified transient when that is longer, which the output says)")
    p.add_argument("--kcf-eps", type=_positive(MAX_KCF_EPS), help="consensus gain of the Kalman-consensus filter "
                                                  "(default 1 / (1 + max in-degree))")
    p.add_argument("--sweep", action="store_true", help="also sweep q (discrete) or g (continuous): RMS error "
                                                         "and measured rate against it (sweep.json, sweep.png)")
    p.add_argument("--sweep-loss", type=_loss_level, nargs="+", metavar="P", help="instead of comparing estimators: "
                   "Monte-Carlo over --seeds per loss probability P (every arc), measured decay rate and steady-state "
                   "error against P beside the designed and lossless rates (loss_sweep.json, loss_sweep.png)")
    p.add_argument("--sweep-deadline", type=_positive(MAX_NETWORK_SECONDS), nargs="+", metavar="D",
                   help="the same against the sub-round deadline D (seconds), with the scenario's network.delay "
                        "(deadline_sweep.json, deadline_sweep.png)")
    p.add_argument("--sweep-rate", type=float, nargs="+", metavar="R",
                   help="instead of comparing estimators: the steady RMS each one would have against the rate asked "
                        "R (design.rate): the whole-state and split designs and the centralized references predicted, "
                        "the KCF measured over --seeds (rate_sweep.json, rate_sweep.png)")
    p.add_argument("--no-plots", action="store_true", help="skip the PNG plots")
    p.set_defaults(func=_command("study:cmd_compare"))

    p = sub.add_parser("run", help="local multi-process deployment: orchestrator, plant and one process per agent",
                       description="Run the scenario as real processes talking over Zenoh on loopback: the "
                                   "orchestrator (embedded router), the plant and one process per agent. Writes "
                                   "trajectory.npz, chunks/, events.jsonl and run.rrd to --out, and ends with one "
                                   "line of what happened. A paced scenario without run.steps runs until Ctrl-C, "
                                   "SIGTERM or splitspec stop (docs/how-to/continuous.md). With live sensors (the "
                                   "scenario's sources:) there is no plant: your sensor processes publish y_i "
                                   "under splitspec/<run-id>/sensors/, and the orchestrator says where and with "
                                   "which credentials (stderr and the sensors event of events.jsonl; "
                                   "docs/how-to/sensors.md).")
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
                     "agent i, only sensor i publishes on agent i's source key, clients without credentials are "
                     "refused; credentials are generated for the run and deleted after)")
    sec.add_argument("--insecure", action="store_true", help="no authentication or access control on the router "
                     "(messages are still signed with the run's key); said on the terminal and in events.jsonl")
    p.add_argument("--measurements", metavar="FILE", help="the plant plays these recorded measurements (.npz or "
                   ".csv, as simulate --measurements; the file decides the steps) instead of simulating the system")
    add_run_id_option(p)
    p.set_defaults(func=_command("deploy:cmd_run"))

    p = sub.add_parser("pace", help="before a deployment: can this machine keep the scenario's pace? (a short real "
                       "run, one verdict line)",
                       description="Run the scenario as `splitspec run` does (real processes over Zenoh), unpaced "
                                   "and without its faults (network impairments kept), for about --seconds of "
                                   "rounds, and measure the wall time per event time in steady state. Pace P is "
                                   "feasible when the 90th percentile of it is below 90 % of a period (0.9 * "
                                   "1000 / P ms). Prints one line; exit status 0 feasible (or no pace: the "
                                   "capacity only), 1 not feasible, 2 bad input.")
    p.add_argument("scenario", help="scenario YAML file")
    p.add_argument("--pace", type=_positive(1e9), metavar="P", help="event times per second to check (default "
                   "the scenario's run.pace; without either, report the capacity only)")
    p.add_argument("--seconds", type=_positive(3600.0), default=5.0, metavar="S",
                   help="seconds of rounds to measure, start-up not counted (default 5)")
    p.add_argument("--out", metavar="DIR", help="keep the measuring run's records in DIR (new or empty; default: a "
                   "temporary directory, deleted)")
    p.set_defaults(func=_command("pace:cmd_pace"))

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
    p.add_argument("--measurements", metavar="FILE", help="the run plays this measurements file: the plant must be "
                   "started with the same file (checked by its sha256); the file decides the steps")
    add_run_id_option(p)
    p.set_defaults(func=_command("deploy:cmd_orchestrator"))

    p = sub.add_parser("standby", help="a standby orchestrator: follows a run and takes it over when its "
                       "orchestrator dies",
                       description="Follow the run --run-id on the Zenoh router at --connect (the ticks, the "
                                   "estimates, the orchestrator's state) and take it over when the active "
                                   "orchestrator's liveliness token goes: the round in flight goes on, the records "
                                   "go on in --out (the run's output folder: on another host, a shared disk). "
                                   "splitspec run starts one itself for a scenario with run.standby: true "
                                   "(docs/how-to/orchestrator.md). Exit 0 when the run ends.")
    p.add_argument("--connect", required=True, metavar="ENDPOINT", help="the run's Zenoh router (not an "
                   "orchestrator's embedded one: it goes with it), e.g. tcp/10.0.0.1:7447")
    p.add_argument("--out", required=True, help="the run's output folder (the active orchestrator's --out)")
    cred = p.add_mutually_exclusive_group()
    cred.add_argument("--credentials", metavar="FILE", help="the orchestrator user's credentials (orchestrator.cred "
                      "of the run's credentials directory) for a secure router")
    cred.add_argument("--secure", dest="secure_dir", metavar="DIR", help="the run's credentials directory: connect "
                      "as the orchestrator user and hand each process it starts its credentials")
    p.add_argument("--viewer", metavar="spawn|URL", default=os.environ.get("SPLITSPEC_VIEWER") or None,
                   help="once it takes over, also stream to a Rerun viewer ('spawn' or a URL)")
    p.add_argument("--round-timeout", type=_positive(MAX_SECONDS), default=10.0,
                   help="seconds before a silent agent is declared lost (once it takes over)")
    p.add_argument("--spawn-local", action="store_true", help="restarts by the scenario start their agents on this "
                   "machine (what `splitspec run` does)")
    add_run_id_option(p, required=True)
    p.set_defaults(func=_command("deploy:cmd_standby"))

    p = sub.add_parser("view", help="open a run's recording (OUT/run.rrd): native Rerun viewer with a display, "
                       "else the web viewer on loopback",
                       description="Open OUT/run.rrd in the native Rerun viewer when a display exists (DISPLAY or "
                                   "WAYLAND_DISPLAY set); otherwise serve Rerun's web viewer on 127.0.0.1 (free "
                                   "ports unless given), print the URL to open (and the ssh -L line to reach it "
                                   "from another machine) and serve until Ctrl-C.")
    p.add_argument("out", metavar="OUT", help="output directory of a run (splitspec run --out OUT)")
    p.add_argument("--web", action="store_true", help="serve the web viewer even when a display exists")
    p.add_argument("--port", type=port, help="web viewer page port (default: a free port; implies --web)")
    p.add_argument("--grpc-port", type=port, help="port the page streams the recording from (default: a free "
                   "port; implies --web)")
    p.set_defaults(func=_command("operate:cmd_view"))

    p = sub.add_parser("router", help="a plain Zenoh router (for hosts without zenohd)",
                       description="Run a Zenoh router in this process until Ctrl-C or SIGTERM: the same as zenohd "
                                   "for splitspec's purposes (multicast scouting off, the link lease of the runtime).")
    p.add_argument("--listen", required=True, metavar="ENDPOINT", help="e.g. tcp/0.0.0.0:7447")
    p.add_argument("--secure", dest="secure_dir", metavar="DIR", help="authenticate clients against DIR/users.txt "
                   "and enforce the access-control policy of the run --run-id of --scenario (a run with a standby "
                   "orchestrator: its orchestrators connect as clients)")
    p.add_argument("--scenario", metavar="FILE", help="with --secure: the run's scenario (its agents and sensors)")
    p.add_argument("--run-id", help="with --secure: the run's id")
    p.set_defaults(func=_command("deploy:cmd_router"))

    p = sub.add_parser("credentials", help="generate Zenoh credentials for a secure deployment by hand",
                       description="Write users.txt (for `orchestrator --secure DIR`) and one <user>.cred file per "
                                   "process (for `plant/agent --credentials FILE`) into DIR, private (0700/0600).")
    p.add_argument("scenario", help="scenario YAML file (for the agent ids)")
    p.add_argument("--out", required=True, help="directory to write (created if missing)")
    p.set_defaults(func=_command("deploy:cmd_credentials"))

    p = sub.add_parser("kill", help="inject a fault from outside: signal an agent (or the plant) of a running run",
                       description="Send a signal to one process of a run started on this machine (found through "
                                   "the orchestrator's registry). KILL (default) is a crash, STOP a freeze (CONT "
                                   "resumes it); the orchestrator detects either and carries on without the agent.")
    who = p.add_mutually_exclusive_group(required=True)
    who.add_argument("--agent", type=int, metavar="I", help="agent id")
    who.add_argument("--plant", action="store_true", help="the plant (the run stops)")
    who.add_argument("--orchestrator", action="store_true", help="the active orchestrator (with run.standby its "
                     "standby takes over; else everything stops)")
    p.add_argument("--signal", default="KILL", choices=sorted(SIGNALS), help="signal to send (default KILL)")
    p.add_argument("--run-id", help="the run's id (default: the only live run of yours on this machine; with "
                   "several, they are listed and nothing is signalled)")
    p.set_defaults(func=_command("operate:cmd_kill"))

    p = sub.add_parser("stop", help="end a running run as it would end by itself: records closed, run_finished",
                       description="Ask a run started on this machine to stop (SIGTERM to its orchestrator, found "
                                   "through the registry). A run without run.steps ends as finished (exit 0, "
                                   "run_finished with reason 'stopped'); a run with steps ends interrupted.")
    p.add_argument("--run-id", help="the run's id (default: the only live run of yours on this machine; with "
                   "several, they are listed and nothing is signalled)")
    p.add_argument("--wait", type=float, default=30.0, metavar="SECONDS",
                   help="wait this long for the orchestrator to exit (0: do not wait; default 30)")
    p.set_defaults(func=_command("operate:cmd_stop"))

    p = sub.add_parser("recover", help="after a crash: make trajectory.npz, events.jsonl and run.rrd agree",
                       description="Take trajectory.npz (K event times) as the authority: rewrite run.rrd with the "
                                   "event times before K so that rerun rrd verify passes, drop a torn last line "
                                   "of events.jsonl and note records_recovered. Harmless on records that agree.")
    p.add_argument("out", metavar="OUT", help="output directory of the run")
    p.set_defaults(func=_command("operate:cmd_recover"))

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

