"""The operating commands on a run: ``splitspec kill`` (fault injection), ``stop``, ``recover``, ``view``."""

from __future__ import annotations

import argparse
import os
import sys

from splitspec_core.runtime.cli import EXIT_BAD_INPUT, EXIT_FAILED, UsageError
from splitspec_core.runtime.cli import integer as _integer


def cmd_recover(args: argparse.Namespace) -> int:
    from ..records.recover import RecoverError, recover

    try:
        result = recover(args.out)
    except RecoverError as exc:
        print(f"splitspec: error: {exc}", file=sys.stderr)
        return EXIT_FAILED
    print(result["message"])
    return 0


def cmd_view(args: argparse.Namespace) -> int:
    from ..view import view

    return view(args.out, web=args.web, port=args.port, grpc_port=args.grpc_port)


def port(text: str) -> int:
    """``type=`` for TCP ports: an integer in [1, 65535]."""
    return _integer(text, minimum=1, maximum=65535)


def _resolve_or_say(run_id, role: str, ident):
    """``(pid, host, entry)`` of a process of a live run (:func:`~splitspec_orchestrator.registry.resolve`), or None
    after saying on stderr why not and which runs there are (none, or several: choose with ``--run-id``)."""
    from ..registry import RunChoiceError, describe_run, resolve

    try:
        return resolve(run_id, role, ident)
    except RunChoiceError as exc:
        print(f"splitspec: error: {exc}", file=sys.stderr)
        for run in exc.runs:
            print(f"  {describe_run(run)}", file=sys.stderr)
        return None


SIGNALS = {"KILL": "SIGKILL", "STOP": "SIGSTOP", "CONT": "SIGCONT", "TERM": "SIGTERM", "INT": "SIGINT"}


def cmd_kill(args: argparse.Namespace) -> int:
    # import-light on purpose: a fault injected from outside should land when it is asked for
    import signal
    import socket

    from ..registry import is_own_splitspec_process

    role, ident = ("plant", None) if args.plant else ("orchestrator", None) if args.orchestrator else ("agent", args.agent)
    found = _resolve_or_say(args.run_id, role, ident)
    if found is None:
        return EXIT_BAD_INPUT
    pid, host, entry = found
    rid = entry["run_id"]
    what = {"plant": "the plant", "orchestrator": "the orchestrator"}.get(role, f"agent {ident}")
    if host and host != socket.gethostname():
        raise UsageError(f"{what} runs on host {host} (pid {pid}), not here: run splitspec kill there")
    if not is_own_splitspec_process(pid, started_before=entry.get("written")):
        raise UsageError(f"{what} (pid {pid}) of run {rid!r} is not running any more (that pid is not a "
                         "splitspec process of yours now); nothing signalled")
    sig = getattr(signal, SIGNALS[args.signal])
    try:
        os.kill(pid, sig)
    except ProcessLookupError:
        raise UsageError(f"{what} (pid {pid}) is not running any more") from None
    print(f"sent {SIGNALS[args.signal]} to {what} (pid {pid}) of run {rid!r} "
          f"(orchestrator pid {entry['orchestrator']['pid']}, records in {entry.get('out')})")
    return 0


def cmd_stop(args: argparse.Namespace) -> int:
    """``splitspec stop [--run-id ID]``: SIGTERM to the run's orchestrator, then wait for it to exit."""
    import signal
    import socket
    import time

    from ..registry import is_own_splitspec_process, pid_running

    found = _resolve_or_say(args.run_id, "orchestrator", None)
    if found is None:
        return EXIT_BAD_INPUT
    pid, host, entry = found
    rid = entry["run_id"]
    if host and host != socket.gethostname():
        raise UsageError(f"run {rid!r} is orchestrated on host {host} (pid {pid}), not here: run splitspec stop there")
    if not is_own_splitspec_process(pid, started_before=entry.get("written")):
        raise UsageError(f"the orchestrator (pid {pid}) of run {rid!r} is not running any more; nothing to stop")
    try:
        os.kill(pid, signal.SIGTERM)
    except ProcessLookupError:
        raise UsageError(f"the orchestrator (pid {pid}) of run {rid!r} is not running any more") from None
    deadline = time.monotonic() + max(0.0, float(args.wait))
    while args.wait > 0 and pid_running(pid) and time.monotonic() < deadline:
        time.sleep(0.1)
    if args.wait > 0 and pid_running(pid):
        print(f"splitspec: error: run {rid!r} (orchestrator pid {pid}) still running {args.wait:g} s after SIGTERM",
              file=sys.stderr)
        return EXIT_FAILED
    print(f"stopped run {rid!r} (orchestrator pid {pid}); records in {entry.get('out')}")
    return 0
