"""``splitspec run``: the one-command local deployment.

Starts the orchestrator (embedded Zenoh router on a free loopback port,
multicast scouting off), the plant and one process per agent, supervises
them, forwards Ctrl-C, and leaves no process behind on any exit path:

* every child asks the kernel for SIGTERM when its parent dies
  (``PR_SET_PDEATHSIG``, :func:`splitspec_core.runtime.cli.die_with_parent`),
  even if the parent is SIGKILLed;
* agents and plant exit by themselves when the orchestrator's liveliness
  token disappears;
* on the way out the launcher terminates, then kills, whatever is left.
"""

from __future__ import annotations

import logging
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

from splitspec_core.runtime.cli import PARENT_ENV

log = logging.getLogger("splitspec.run")


def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def cli_command(*args: str) -> list:
    """The command line that runs ``splitspec ARGS`` with this interpreter."""
    return [sys.executable, "-m", "splitspec_orchestrator", *map(str, args)]


def node_command(role: str, *args: str) -> list:
    """The command line of a plant or agent process with this interpreter (``python -m splitspec_plant|agents``)."""
    return [sys.executable, "-m", "splitspec_agents" if role == "agent" else "splitspec_plant", *map(str, args)]


#: one BLAS thread per spawned process: an agent's matrices are n x n (n ~ 10), and m processes that each
#: start a thread per core only contend for the cores the round needs
ONE_BLAS_THREAD = {k: "1" for k in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")}


def spawn(args: list, *, env: dict | None = None, pass_fds: tuple = ()) -> subprocess.Popen:
    """Start a splitspec process (``args`` from :func:`cli_command` or :func:`node_command`).

    No ``preexec_fn``: the child asks for SIGTERM at our death itself (it finds our pid in
    :data:`~splitspec_core.runtime.cli.PARENT_ENV`), so ``subprocess`` can vfork instead of copying this
    process's memory map for each of m + 1 children.  ``pass_fds``: descriptors the child keeps (the agent fork
    server's pipes, :mod:`splitspec_orchestrator.forks`).
    """
    env = {**(os.environ if env is None else env), **ONE_BLAS_THREAD, PARENT_ENV: str(os.getpid())}
    return subprocess.Popen(args, env=env, stdin=subprocess.DEVNULL, pass_fds=pass_fds)


def stop_all(procs: list, *, grace: float = 5.0) -> None:
    """SIGTERM what is still running, then SIGKILL after ``grace`` seconds."""
    for p in procs:
        if p.poll() is None:
            p.terminate()
            try:
                p.send_signal(signal.SIGCONT)  # a stopped (frozen) process acts on the SIGTERM only once resumed
            except ProcessLookupError:
                pass
    deadline = time.monotonic() + grace
    for p in procs:
        try:
            p.wait(timeout=max(0.0, deadline - time.monotonic()))
        except subprocess.TimeoutExpired:
            p.kill()
            p.wait()


EXIT_ORCHESTRATOR_LOST = 3  #: `splitspec run`'s exit status when the orchestrator itself died


def run_local(scenario: str, out: Path, *, run_id: str, viewer: str | None, wait: float | None,
              round_timeout: float, agent_ids: tuple, verbose: bool = False, secure: bool = True,
              measurements: str | None = None, sensor_ids: tuple = (), until_stopped: bool = False) -> int:
    """Start the orchestrator, which starts and parents the plant and the agents; return the exit code.

    The orchestrator is their parent, so it sees a process that dies during start-up at once, with
    its exit status.  ``secure`` (the default): generate credentials for this run in a private
    directory under the runtime directory, start the router with authentication and access control,
    and delete them at the end.  If the orchestrator itself dies (a signal), the others die with it
    (``PR_SET_PDEATHSIG``), the records are recovered (:func:`splitspec_orchestrator.records.recover.recover`) and the
    exit status is :data:`EXIT_ORCHESTRATOR_LOST`.  ``sensor_ids``: agents with a live sensor (scenario
    ``sources:``): the orchestrator starts no plant, and a secure run's directory also holds
    ``sensor-<i>.cred`` for the user's sensor processes (the orchestrator says where).  ``until_stopped``: the
    scenario runs until stopped, so Ctrl-C or SIGTERM ends it as finished (exit 0), not interrupted (130).
    """
    port = free_port()
    endpoint = f"tcp/127.0.0.1:{port}"
    orch_cmd = cli_command(*([] if verbose else ["--log-level", "warning"]), "orchestrator", scenario,
                           "--listen", endpoint, "--out", out, "--run-id", run_id,
                           *(["--wait", wait] if wait is not None else []),
                           "--round-timeout", round_timeout, "--spawn-local",
                           *(["--measurements", Path(measurements).resolve()] if measurements else []))
    if viewer:
        orch_cmd += ["--viewer", viewer]
    cred_dir = None
    if secure:
        import tempfile

        from splitspec_core.runtime.security import generate

        from .registry import runtime_dir

        runtime_dir().mkdir(parents=True, exist_ok=True, mode=0o700)
        cred_dir = Path(tempfile.mkdtemp(prefix=f"creds-{run_id}-", dir=runtime_dir()))
        generate(cred_dir, agent_ids, sensor_ids)
        orch_cmd += ["--secure", str(cred_dir)]
        log.info("secure run: credentials in %s (deleted at the end)", cred_dir)
    procs: list = []
    interrupted = False

    def on_signal(signum, _frame):
        nonlocal interrupted
        interrupted = True
        if procs and procs[0].poll() is None:
            procs[0].send_signal(signum)  # the same: the orchestrator writes its records and stops the others

    old = {s: signal.signal(s, on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        procs.append(spawn(orch_cmd))
        log.info("started the orchestrator (pid %d) on %s; it starts %s%d agents", procs[0].pid, endpoint,
                 "" if sensor_ids else "the plant and ", len(agent_ids))
        code = procs[0].wait()
        if code < 0:  # killed by a signal: nothing of its own was said
            return _orchestrator_lost(procs[0].pid, -code, out)
        return 130 if interrupted and code == 0 and not until_stopped else code
    finally:
        stop_all(procs)
        for s, h in old.items():
            signal.signal(s, h)
        if cred_dir is not None:
            import shutil

            shutil.rmtree(cred_dir, ignore_errors=True)


def _orchestrator_lost(pid: int, signum: int, out: Path) -> int:
    """One line for an orchestrator killed by a signal; the records are recovered first."""
    try:
        name = signal.Signals(signum).name
    except ValueError:
        name = f"signal {signum}"
    what = "its records could not be recovered"
    try:
        from .records.recover import recover

        res = recover(out)
        what = f"records recovered: {res['rows']} event times in {out}"
    except ImportError:
        what = f"records up to the last flush are in {out}"
    except Exception as exc:  # noqa: BLE001 - the one line below says what is left
        what = f"its records could not be recovered ({exc}); try `splitspec recover {out}`"
    print(f"splitspec: error: the orchestrator (pid {pid}) was lost ({name}); the plant and the agents stopped "
          f"with it; {what}", file=sys.stderr)
    return EXIT_ORCHESTRATOR_LOST
