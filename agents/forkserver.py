"""The agent fork server: the agent's code imported once, every agent of a local run a fork of it.

An agent process spends most of its start in the interpreter's start and its imports (numpy, Zenoh, the
scenario parser and the local design: ~0.2 s of CPU); m of them starting at once on a few cores took 10 s at
m = 100.  ``splitspec run`` (an orchestrator with ``--spawn-local``) starts this server first; it imports all of
that once, opens no Zenoh session and starts no thread (so forking it is safe), and answers each request with a
fork that runs the agent's own command line (:func:`splitspec_agents.agent.cli_main`).  Each agent is then a
separate OS process as before, with its own sessions, identity and pid; it just starts in a few milliseconds.

Protocol, one JSON object per line: the orchestrator writes ``{"argv": [...]}`` (the agent's arguments) on the requests
descriptor; the server answers ``{"ready": pid}`` once, then ``{"pid": P}`` per request and ``{"exit": P,
"code": C}`` (``Popen.returncode``'s convention) when a child ends (the server reaps its children).  The server
ends when the requests descriptor closes, and dies with the orchestrator (``PR_SET_PDEATHSIG``); each agent dies
with the server (the same), so none outlives the run.

    python -m splitspec_agents.forkserver --requests FD --replies FD [--run-id ID]
"""

from __future__ import annotations

import argparse
import json
import os
import select
import signal
import sys

#: a request line longer than this is refused (and ends the server): an agent's argv is < 1 KB
MAX_LINE = 1 << 20


def _send(fd: int, obj: dict) -> None:
    data = (json.dumps(obj) + "\n").encode()
    while data:
        data = data[os.write(fd, data):]


def _reap(replies: int) -> None:
    while True:
        try:
            pid, status = os.waitpid(-1, os.WNOHANG)
        except ChildProcessError:
            return
        if pid == 0:
            return
        _send(replies, {"exit": pid, "code": os.waitstatus_to_exitcode(status)})


def _child(argv: list, server: int, close: tuple) -> None:
    """In the fork: the agent's command line ``argv``, then ``os._exit`` with its status (never returns)."""
    code = 1
    try:
        signal.set_wakeup_fd(-1)
        for sig in (signal.SIGCHLD, signal.SIGINT, signal.SIGTERM):
            signal.signal(sig, signal.SIG_DFL)
        for fd in close:
            os.close(fd)
        from splitspec_core.runtime.cli import die_with_parent

        die_with_parent(server)  # and at once if the server is already gone
        _name(argv)
        from .agent import cli_main

        code = cli_main(argv)
    except SystemExit as exc:
        code = exc.code if isinstance(exc.code, int) else 1
    except BaseException:  # noqa: BLE001 - the child must end here, whatever happened, with a status
        import traceback

        traceback.print_exc()
        code = 1
    finally:
        for stream in (sys.stdout, sys.stderr):
            try:
                stream.flush()
            except Exception:  # noqa: BLE001 - a closed pipe: nothing more to say
                pass
        os._exit(code)


def _name(argv: list) -> None:
    """The process's name (``ps -o comm``, ``top``) ``agent <id>``: every fork shares the server's command line."""
    try:
        ident = argv[argv.index("--id") + 1]
        import ctypes

        ctypes.CDLL(None).prctl(15, f"agent {ident}".encode()[:15])  # PR_SET_NAME
    except (ValueError, IndexError, OSError, AttributeError):
        pass


def serve(requests: int, replies: int) -> int:
    """Import what an agent needs, then fork one agent per request until ``requests`` closes."""
    from splitspec_core.runtime.cli import die_with_parent

    die_with_parent()
    import numpy  # noqa: F401 - the imports every agent needs, done once here
    import zenoh  # noqa: F401

    from splitspec_core.runtime import node  # noqa: F401

    from . import agent, measure  # noqa: F401

    wake_r, wake_w = os.pipe()
    os.set_blocking(wake_w, False)
    signal.set_wakeup_fd(wake_w)
    signal.signal(signal.SIGCHLD, lambda *_: None)  # only to wake the select below (set_wakeup_fd)
    server = os.getpid()
    _send(replies, {"ready": server})
    buf = b""
    while True:
        try:
            ready, _, _ = select.select([requests, wake_r], [], [])
        except InterruptedError:
            continue
        if wake_r in ready:
            os.read(wake_r, 4096)
        _reap(replies)
        if requests not in ready:
            continue
        data = os.read(requests, 65536)
        if not data:
            return 0
        buf += data
        if len(buf) > MAX_LINE:
            print(f"splitspec_agents.forkserver: error: a request longer than {MAX_LINE} bytes; stopping",
                  file=sys.stderr)
            return 2
        while b"\n" in buf:
            line, buf = buf.split(b"\n", 1)
            try:
                argv = [str(a) for a in json.loads(line)["argv"]]
            except (ValueError, TypeError, KeyError):
                print('splitspec_agents.forkserver: error: a request is not {"argv": [...]}; stopping', file=sys.stderr)
                return 2
            pid = os.fork()
            if pid == 0:
                _child(argv, server, (requests, replies, wake_r, wake_w))
            _send(replies, {"pid": pid})


def main(argv: list | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m splitspec_agents.forkserver",
                                description="Fork agents for a local run (started by the orchestrator).")
    p.add_argument("--requests", type=int, required=True, help="file descriptor the requests arrive on")
    p.add_argument("--replies", type=int, required=True, help="file descriptor the answers go to")
    p.add_argument("--run-id", help="the run it serves (shown in its command line, which its agents share)")
    args = p.parse_args(argv)
    try:
        return serve(args.requests, args.replies)
    except KeyboardInterrupt:  # Ctrl-C reaches the whole process group: the orchestrator says what happened
        return 130
    except OSError as exc:  # a descriptor that is not the orchestrator's pipe
        print(f"splitspec_agents.forkserver: error: {exc.strerror} (--requests {args.requests}, --replies "
              f"{args.replies})", file=sys.stderr)
        return 2


if __name__ == "__main__":
    raise SystemExit(main())
