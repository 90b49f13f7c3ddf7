"""Command-line conventions every splitspec process shares: one-line errors, typed options, the error boundary.

``splitspec`` (:mod:`splitspec_orchestrator.cli`), ``python -m splitspec_agents`` and
``python -m splitspec_plant`` parse with :class:`ArgumentParser` and run their command through
:func:`error_boundary`, so bad input anywhere ends the same way: one line
``splitspec: error: ...`` on stderr and a non-zero exit (2 bad input, 1 failure, 130 Ctrl-C),
never a traceback (``SPLITSPEC_DEBUG=1`` re-raises for debugging).
"""

from __future__ import annotations

import argparse
import logging
import math
import os
import sys
from typing import Callable

from ..errors import ScenarioError as UsageError  # bad CLI arguments
from ..errors import NetworkError, SplitspecError
from ..parallel import sigterm_at_parent_death

__all__ = ["ArgumentParser", "EXIT_BAD_INPUT", "EXIT_FAILED", "MAX_SECONDS", "MAX_SEED", "UsageError",
           "add_logging_options", "add_node_options", "at_least", "error_boundary", "positive", "seed",
           "add_run_id_option", "node_cli", "setup_logging", "integer", "default_wait", "DEFAULT_WAIT",
           "PARENT_ENV", "die_with_parent", "sigterm_at_parent_death", "EVENTS_LOGGER"]

#: the logger of a run's events as the orchestrator tells them (a fault and its end, a loss and a rejoin, a sensor set
#: aside and taken back, the survivors' verdict): ``--log-level events`` shows them, at INFO too, beside every
#: warning and nothing else at INFO (``splitspec run``'s terminal)
EVENTS_LOGGER = "splitspec.events"

EXIT_BAD_INPUT = 2
EXIT_FAILED = 1
EXIT_INTERRUPTED = 130

MAX_SEED = 2**63 - 1  # as splitspec_core.scenarios.specs.MAX_SEED: seeds travel to the processes as 64-bit integers
MAX_SECONDS = 1e6  # --wait, --round-timeout: finite waits that threading and time.sleep accept (11.6 days)
DEFAULT_WAIT = 60.0  # --wait of a plant or agent process (seconds)

#: the pid of the process that spawned this one, set by ``splitspec_orchestrator.launcher.spawn``: the process
#: then asks for SIGTERM when that parent dies (:func:`die_with_parent`)
PARENT_ENV = "SPLITSPEC_PARENT_PID"


def die_with_parent(parent: int | None = None) -> None:
    """SIGTERM when the process that spawned this one dies (``PR_SET_PDEATHSIG``), if it set :data:`PARENT_ENV`
    (or, ``parent``, when this is a fork of process ``parent``: an agent of the agent fork server).

    Asked for here, in the child, rather than between fork and exec in the parent: a ``preexec_fn`` makes
    ``subprocess`` fork (copy the page tables of) the whole orchestrator for every process it starts, where it
    can otherwise use vfork (33 spawns at m = 32: ~0.35 s of its CPU before the run starts).  A parent that
    died before the request (this interpreter was starting) is no longer this process's parent: SIGTERM now.

    Parameters
    ----------
    parent : int, optional
        The parent's pid; None: read (and remove) :data:`PARENT_ENV`, and do nothing when it is not set or the
        platform has no parent-death signal.
    """
    if parent is None:
        parent = os.environ.pop(PARENT_ENV, None)
    if not parent or not sigterm_at_parent_death():
        return
    if str(os.getppid()) != str(parent):
        import signal

        os.kill(os.getpid(), signal.SIGTERM)


def default_wait(m: int) -> float:
    """The orchestrator's default ``--wait`` for m agents: 60 s plus 1 s per agent (m processes start at once,
    on as few cores as the machine has; one m = 32 run did not start within a flat 60 s under load).

    Parameters
    ----------
    m : int
        Number of agents.

    Returns
    -------
    float
        Seconds.
    """
    return DEFAULT_WAIT + float(m)


class ArgumentParser(argparse.ArgumentParser):
    """argparse with every error as one line ``splitspec: error: ...`` and exit status 2 (no usage block)."""

    def error(self, message: str):
        """Exit with status 2 after one line ``splitspec: error: ...`` on stderr (``argument --steps: must be ...``
        shortened to ``--steps must be ...``).

        Parameters
        ----------
        message : str
            argparse's message.
        """
        message = " ".join(str(message).split())
        # "argument --steps: must be >= 1, got 0" (from the type= functions below) -> "--steps must be >= 1, got 0"
        option, sep, rest = message.removeprefix("argument ").partition(": ")
        if message.startswith("argument ") and sep and rest.startswith("must "):
            message = f"{option} {rest}"
        self.exit(EXIT_BAD_INPUT, f"splitspec: error: {message}\n")


def integer(text: str, *, minimum: int, maximum: int | None = None) -> int:
    """An integer option in [minimum, maximum] (base 10), else ``argparse.ArgumentTypeError``.

    Parameters
    ----------
    text : str
        The option's text.
    minimum : int
        Smallest value accepted.
    maximum : int, optional
        Largest value accepted (None: no bound).

    Returns
    -------
    int

    Raises
    ------
    argparse.ArgumentTypeError
        ``must be an integer``, ``must be >= ...`` or ``must be <= ...``, with the value given.

    Examples
    --------
    >>> integer("12", minimum=1)
    12
    >>> integer("0", minimum=1)
    Traceback (most recent call last):
        ...
    argparse.ArgumentTypeError: must be >= 1, got 0
    """
    try:
        value = int(text, 10)
    except (TypeError, ValueError):
        raise argparse.ArgumentTypeError(f"must be an integer, got {text!r}") from None
    if value < minimum:
        raise argparse.ArgumentTypeError(f"must be >= {minimum}, got {value}")
    if maximum is not None and value > maximum:
        raise argparse.ArgumentTypeError(f"must be <= {maximum}, got {value}")
    return value


def seed(text: str) -> int:
    """``--seed``: an integer in [0, 2**63 - 1].

    Parameters
    ----------
    text : str
        The option's text.

    Returns
    -------
    int

    Raises
    ------
    argparse.ArgumentTypeError
        As :func:`integer`.
    """
    return integer(text, minimum=0, maximum=MAX_SEED)


def at_least(minimum: int) -> Callable[[str], int]:
    """``type=`` for counts: an integer >= ``minimum``.

    Parameters
    ----------
    minimum : int
        Smallest value accepted.

    Returns
    -------
    callable
        ``str -> int``, raising ``argparse.ArgumentTypeError`` as :func:`integer`.
    """
    def parse(text: str) -> int:
        return integer(text, minimum=minimum)

    parse.__name__ = f"integer >= {minimum}"
    return parse


def positive(maximum: float) -> Callable[[str], float]:
    """``type=`` for seconds and gains: a finite number in (0, ``maximum``].

    Parameters
    ----------
    maximum : float
        Largest value accepted.

    Returns
    -------
    callable
        ``str -> float``, raising ``argparse.ArgumentTypeError`` for anything else.

    Examples
    --------
    >>> wait = positive(MAX_SECONDS)
    >>> wait("2.5")
    2.5
    >>> wait("inf")
    Traceback (most recent call last):
        ...
    argparse.ArgumentTypeError: must be a number in (0, 1e+06], got 'inf'
    """
    def parse(text: str) -> float:
        try:
            value = float(text)
        except (TypeError, ValueError):
            value = math.nan
        if not math.isfinite(value) or not 0 < value <= maximum:
            raise argparse.ArgumentTypeError(f"must be a number in (0, {maximum:g}], got {text!r}")
        return value

    parse.__name__ = "positive number"
    return parse


def add_logging_options(p: argparse.ArgumentParser) -> None:
    """Add ``-v/--verbose`` and ``--log-level`` (read by :func:`setup_logging`).

    Parameters
    ----------
    p : argparse.ArgumentParser
        The parser to add them to.
    """
    p.add_argument("-v", "--verbose", action="store_true", help="log more")
    p.add_argument("--log-level", default=None, choices=["debug", "info", "events", "warning", "error"],
                   help="logging level (default info; debug with -v; events: the warnings and a run's events)")


def setup_logging(args: argparse.Namespace) -> None:
    """Configure the root logger from ``--log-level`` / ``-v`` (a no-op when it is already configured).

    Parameters
    ----------
    args : argparse.Namespace
        Parsed options; ``log_level`` and ``verbose`` are read if present (default level INFO, DEBUG with ``-v``;
        ``events``: WARNING, and INFO for :data:`EVENTS_LOGGER`).
    """
    level = args.log_level.upper() if getattr(args, "log_level", None) else \
        ("DEBUG" if getattr(args, "verbose", False) else "INFO")
    if level == "EVENTS":
        level = "WARNING"
        logging.getLogger(EVENTS_LOGGER).setLevel(logging.INFO)
    logging.basicConfig(level=level, format="%(asctime)s %(name)s %(levelname)s %(message)s")


def add_run_id_option(p: argparse.ArgumentParser, *, required: bool = False) -> None:
    """Add ``--run-id`` and ``--wait`` (seconds, in (0, :data:`MAX_SECONDS`]).

    Parameters
    ----------
    p : argparse.ArgumentParser
        The parser to add them to.
    required : bool, default False
        A process joining a run (plant, agent): ``--run-id`` required, ``--wait`` default :data:`DEFAULT_WAIT`.
        Else (the orchestrator) ``--run-id`` is optional (a new id) and ``--wait`` defaults to None
        (:func:`default_wait` decides).
    """
    if required:
        p.add_argument("--run-id", required=True, help="the run's id, as printed by splitspec run / orchestrator "
                       "(key prefix splitspec/<run-id>/)")
    else:
        p.add_argument("--run-id", help="run id: key prefix splitspec/<run-id>/ (default: a new unique id, printed "
                       "at start); several runs can share a router under different ids")
    p.add_argument("--wait", type=positive(MAX_SECONDS), default=DEFAULT_WAIT if required else None,
                   help="seconds to wait for the other processes (default 60" + ("" if required else
                                                                                  ", plus 1 per agent") + ")")


def add_node_options(p: argparse.ArgumentParser) -> None:
    """The options of a plant or agent process: where the router is, who it is, how long to wait.

    Parameters
    ----------
    p : argparse.ArgumentParser
        The parser to add ``--connect``, ``--credentials``, ``--run-id`` and ``--wait`` to.
    """
    p.add_argument("--connect", required=True, metavar="ENDPOINT", help="Zenoh router endpoint, e.g. tcp/host:7447")
    p.add_argument("--credentials", metavar="FILE", help="user:password file for a --secure router")
    add_run_id_option(p, required=True)


def node_cli(build_parser: Callable[[str], argparse.ArgumentParser], main: Callable[[argparse.Namespace], int],
             argv: list | None, prog: str) -> int:
    """A plant or agent process's command line: parse ``argv``, set up logging, run ``main`` in the boundary.

    Parameters
    ----------
    build_parser : callable
        ``prog -> ArgumentParser``.
    main : callable
        ``args -> exit status`` (None: 0).
    argv : list of str or None
        The arguments (None: ``sys.argv[1:]``).
    prog : str
        The program name in messages.

    Returns
    -------
    int
        The exit status (:func:`error_boundary`).
    """
    die_with_parent()
    args = build_parser(prog).parse_args(argv)
    setup_logging(args)
    return error_boundary(main, args)


def error_boundary(func: Callable[[argparse.Namespace], int | None], args: argparse.Namespace) -> int:
    """Run ``func(args)``; the exit status, with every expected failure as one line on stderr.

    SplitspecError (bad input): 2.  NetworkError (no router at the endpoint, the router refused the
    process's credentials, no such run on the router, the router went away), TimeoutError / ValueError
    (no orchestrator answered, an agent id not in the scenario): 1.  Ctrl-C: 130.  A closed stdout
    pipe (``| head``): 0.  With ``SPLITSPEC_DEBUG`` set, the errors are re-raised instead (not Ctrl-C).
    Also shortens the interpreter's thread switch interval (``sys.setswitchinterval``) for Zenoh's threads.

    Parameters
    ----------
    func : callable
        ``args -> exit status`` (None: 0).
    args : argparse.Namespace
        Parsed options.

    Returns
    -------
    int
        The exit status.

    """
    # Zenoh delivers messages on its own threads; a short GIL switch interval lets the process's
    # event loop take them over quickly (the default 5 ms would dominate a round)
    sys.setswitchinterval(2e-4)
    debug = bool(os.environ.get("SPLITSPEC_DEBUG"))
    try:
        return int(func(args) or 0)
    except NetworkError as exc:  # a well-formed command in a deployment that is not (yet) what it names
        if debug:
            raise
        print(f"splitspec: error: {exc}", file=sys.stderr)
        return EXIT_FAILED
    except SplitspecError as exc:
        if debug:
            raise
        print(f"splitspec: error: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except KeyboardInterrupt:
        print("splitspec: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
    except (TimeoutError, ValueError) as exc:
        if debug:
            raise
        print(f"splitspec: error: {exc}", file=sys.stderr)
        return EXIT_FAILED
    except BrokenPipeError:
        return 0
