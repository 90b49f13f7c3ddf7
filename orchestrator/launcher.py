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

A scenario with ``run.standby: true`` runs under :class:`Supervisor` instead: no process of the run is then the
others' parent but this one.  It starts

* the run's Zenoh router (``splitspec router``, with the run's access control when secure): it outlives every
  orchestrator, so a takeover keeps every link;
* the active orchestrator as the router's client (it starts the plant and the agents, who outlive it: they are
  not its forks and do not die with it, :func:`~splitspec_orchestrator.launcher.spawn` ``parent_death=False``);
* a standby (``splitspec standby``), which takes over when the active one dies.  When an orchestrator dies by a
  signal (SIGKILL, OOM) while its successor lives, a new standby is started (:data:`NEW_STANDBY_DELAY` later), so every takeover has a successor.
  A standby starts in the idle scheduling class for its first :data:`STANDBY_IDLE_SECONDS` (:func:`idle_class`):
  its start-up takes the cores the run's rounds do not want.

This process is the run's child subreaper (``PR_SET_CHILD_SUBREAPER``): the plant and the agents of a dead
orchestrator become its children, so it reaps them and, at the end, stops what is left.  The exit status is the
last active orchestrator's; when the last one dies by a signal with no standby left, the records are recovered
and the status is :data:`~splitspec_orchestrator.launcher.EXIT_ORCHESTRATOR_LOST`, as without a standby.
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


def spawn(args: list, *, env: dict | None = None, pass_fds: tuple = (), parent_death: bool = True) -> subprocess.Popen:
    """Start a splitspec process (``args`` from :func:`cli_command` or :func:`node_command`).

    No ``preexec_fn``: the child asks for SIGTERM at our death itself (it finds our pid in
    :data:`~splitspec_core.runtime.cli.PARENT_ENV`), so ``subprocess`` can vfork instead of copying this
    process's memory map for each of m + 1 children.  ``pass_fds``: descriptors the child keeps (the agent fork
    server's pipes, :mod:`splitspec_orchestrator.forks`).  ``parent_death=False``: the child outlives this process
    (a run with a standby orchestrator: its plant and agents wait for the takeover instead).
    """
    env = {**(os.environ if env is None else env), **ONE_BLAS_THREAD}
    if parent_death:
        env[PARENT_ENV] = str(os.getpid())
    else:
        env.pop(PARENT_ENV, None)
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
              measurements: str | None = None, sensor_ids: tuple = (), until_stopped: bool = False,
              standby: bool = False) -> int:
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
    ``standby`` (``run.standby``): the run gets a router of its own and a standby orchestrator that takes over when
    the active one dies (:class:`Supervisor`).
    """
    port = free_port()
    endpoint = f"tcp/127.0.0.1:{port}"
    orch_cmd = cli_command(*([] if verbose else ["--log-level", "events"]), "orchestrator", scenario,
                           "--connect" if standby else "--listen", endpoint, "--out", out, "--run-id", run_id,
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
    if standby:
        try:
            return Supervisor(scenario, out, run_id=run_id, endpoint=endpoint, orch_cmd=orch_cmd, cred_dir=cred_dir,
                              verbose=verbose, wait=wait, round_timeout=round_timeout,
                              until_stopped=until_stopped).run()
        finally:
            if cred_dir is not None:
                import shutil

                shutil.rmtree(cred_dir, ignore_errors=True)

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


# ---------------------------------------------------------------------- a run with a standby



SUPERVISE_POLL = 0.1  #: seconds between looks at the orchestrators (a run with a standby)
#: seconds after a takeover before the new standby starts: its start-up (imports, a core for about a second) would
#: otherwise fall on the new active one's catch-up of the stalled rounds
NEW_STANDBY_DELAY = 2.0


#: seconds a standby spends in the idle scheduling class after it is started (its imports, its design of the
#: estimator, its warm-up: about 2.5 s of a core on a quiet machine); then the normal class, as the run's processes
STANDBY_IDLE_SECONDS = 4.0


def idle_class(pid: int) -> bool:
    """Put process ``pid`` (just started: one thread) in the idle scheduling class (Linux ``SCHED_IDLE``: it runs on
    a core only when nothing else wants it), where this process may take it out again (:func:`normal_class`: root,
    or ``RLIMIT_NICE`` allowing nice 0); whether it did.

    A standby starts beside a paced run (at the run's start, and :data:`NEW_STANDBY_DELAY` after each takeover): at
    the normal class its start-up, a core for a second or two, made the run's rounds up to 57 ms late on a busy
    2-core machine (the one-hour soak, 50 Hz).  The launcher, which is not idle, takes it out after
    :data:`STANDBY_IDLE_SECONDS` whatever the load (an idle-class process on a saturated machine would wait
    indefinitely).

    Parameters
    ----------
    pid : int
        The process.

    Returns
    -------
    bool
        Whether ``pid`` is now in the idle class.
    """
    if not hasattr(os, "SCHED_IDLE"):
        return False
    try:
        import resource

        if os.geteuid() != 0 and resource.getrlimit(resource.RLIMIT_NICE)[0] < 20:
            return False
        os.sched_setscheduler(pid, os.SCHED_IDLE, os.sched_param(0))
        return True
    except (OSError, ValueError, AttributeError):
        return False


def normal_class(pid: int) -> None:
    """Take every thread of process ``pid`` out of the idle scheduling class (:func:`idle_class`: the threads it
    started since inherited the class).

    Parameters
    ----------
    pid : int
        The process (gone: nothing to do).
    """
    try:
        tasks = [int(t) for t in os.listdir(f"/proc/{pid}/task")]
    except OSError:
        tasks = [pid]
    for tid in tasks:
        try:
            if os.sched_getscheduler(tid) == os.SCHED_IDLE:
                os.sched_setscheduler(tid, os.SCHED_OTHER, os.sched_param(0))
        except OSError:  # a thread (or the process) that ended meanwhile
            pass


def set_child_subreaper() -> bool:
    """Make this process the subreaper of its descendants (Linux ``PR_SET_CHILD_SUBREAPER``): an orphan among them
    becomes its child.  False where the platform has none.

    Returns
    -------
    bool
        Whether the kernel accepted it.
    """
    if not sys.platform.startswith("linux"):
        return False
    import ctypes

    try:
        return ctypes.CDLL(None, use_errno=True).prctl(36, 1, 0, 0, 0) == 0  # PR_SET_CHILD_SUBREAPER
    except (OSError, AttributeError):
        return False


def _adopted_children() -> list:
    """The pids of this process's children (``/proc/self/task/*/children``): its own and the orphans it adopted."""
    pids = []
    try:
        for task in os.listdir("/proc/self/task"):
            with open(f"/proc/self/task/{task}/children", encoding="ascii") as f:
                pids += [int(p) for p in f.read().split()]
    except OSError:
        pass
    return pids


class Supervisor:
    """The processes of a local run with a standby (see the module docstring); :meth:`run` returns the exit code."""

    def __init__(self, scenario: str, out: Path, *, run_id: str, endpoint: str, orch_cmd: list, cred_dir,
                 verbose: bool, wait, round_timeout: float, until_stopped: bool):
        self.out, self.run_id, self.endpoint = Path(out), run_id, endpoint
        self.orch_cmd = orch_cmd
        quiet = [] if verbose else ["--log-level", "warning"]
        secure = ["--secure", str(cred_dir)] if cred_dir is not None else []
        self.router_cmd = cli_command(*quiet, "router", "--listen", endpoint, *secure,
                                      *(["--scenario", scenario, "--run-id", run_id] if secure else []))
        told = [] if verbose else ["--log-level", "events"]  # the run's events, as the active orchestrator's
        self.standby_cmd = cli_command(*told, "standby", "--run-id", run_id, "--connect", endpoint, "--out", out,
                                       "--round-timeout", round_timeout, "--spawn-local", *secure,
                                       *(["--wait", wait] if wait is not None else []))
        self.until_stopped = until_stopped
        self.interrupted = False
        self.active = None  # the orchestrator holding the rounds (as far as this process knows)
        self.lost: tuple | None = None  # (pid, signal) of the last orchestrator lost, its standby promoted
        self.standbys: list = []  # standbys, oldest first: the first takes over
        self.standby_due: float | None = None  # monotonic time to start the next standby (after a takeover)
        self.idle: dict = {}  # pid -> monotonic time it leaves the idle scheduling class (a standby starting)
        self.router = None

    def _spawn(self, cmd: list):
        return spawn(cmd)

    def _spawn_standby(self):
        p = self._spawn(self.standby_cmd)
        if idle_class(p.pid):
            self.idle[p.pid] = time.monotonic() + STANDBY_IDLE_SECONDS
        return p

    def _end_idle(self, *, now: float | None = None) -> None:
        """Standbys whose start-up time is over leave the idle class (all of them: ``now`` None)."""
        for pid, until in list(self.idle.items()):
            if now is None or now >= until:
                normal_class(pid)
                del self.idle[pid]

    def _on_signal(self, signum, _frame) -> None:
        self.interrupted = True
        for p in [self.active, *self.standbys]:
            if p is not None and p.poll() is None:
                p.send_signal(signum)  # the active one writes its records and stops the others; standbys leave

    def run(self) -> int:
        set_child_subreaper()
        old = {s: signal.signal(s, self._on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
        try:
            self.router = self._spawn(self.router_cmd)
            self.active = self._spawn(self.orch_cmd)
            self.standbys.append(self._spawn_standby())
            log.info("started the router (pid %d) on %s, the orchestrator (pid %d) and its standby (pid %d)",
                     self.router.pid, self.endpoint, self.active.pid, self.standbys[0].pid)
            return self._supervise()
        finally:
            stop_all([p for p in [self.active, *self.standbys] if p is not None], grace=5.0)
            self._stop_orphans()
            if self.router is not None:
                stop_all([self.router], grace=3.0)
            for s, h in old.items():
                signal.signal(s, h)

    def _supervise(self) -> int:
        while True:
            time.sleep(SUPERVISE_POLL)
            self._reap_orphans()
            self._end_idle(now=time.monotonic())
            if self.standby_due is not None and time.monotonic() >= self.standby_due and not self.interrupted:
                self.standby_due = None
                self.standbys.append(self._spawn_standby())
            for p in list(self.standbys):
                code = p.poll()
                if code is None:
                    continue
                self.standbys.remove(p)
                if code < 0 and not self.interrupted:  # killed: the run gets a new standby
                    log.warning("the standby orchestrator (pid %d) was killed; starting another", p.pid)
                    self.standbys.append(self._spawn_standby())
                elif code == 0 and self.active is not None and self.active.poll() is None:
                    pass  # it left as the run ends
            code = self.active.poll()
            if code is None:
                continue
            if code < 0 and not self.interrupted and self.standbys:  # its standby takes over
                dead = self.active
                self.active = self.standbys.pop(0)
                if self.active.pid in self.idle:  # it takes the rounds: not a moment longer in the idle class
                    normal_class(self.active.pid)
                    del self.idle[self.active.pid]
                self.lost = (dead.pid, -code)
                log.warning("the orchestrator (pid %d) was lost (%s); its standby (pid %d) takes over", dead.pid,
                            _signal_name(-code), self.active.pid)
                self.standby_due = time.monotonic() + NEW_STANDBY_DELAY
                continue
            if code < 0:
                return _orchestrator_lost(self.active.pid, -code, self.out)
            if code != 0 and self.lost is not None and not self._took_over(self.active.pid):
                return _orchestrator_lost(*self.lost, self.out)  # its standby could not take over (it said why)
            for p in self.standbys:  # the run ended: its standbys leave on its stop
                try:
                    p.wait(timeout=5.0)
                except Exception:  # noqa: BLE001 - stop_all takes care of it
                    pass
            return 130 if self.interrupted and code == 0 and not self.until_stopped else code

    def _took_over(self, pid: int) -> bool:
        """Whether the standby ``pid`` took the run over (it holds the records: ``.orchestrator.json``)."""
        import json

        try:
            return json.loads((self.out / ".orchestrator.json").read_text(encoding="utf-8")).get("pid") == pid
        except (OSError, ValueError, AttributeError):
            return False

    def _reap_orphans(self) -> None:
        """Reap the plant's and agents' exits (orphans this process adopted), never its own Popen children."""
        own = {p.pid for p in [self.active, self.router, *self.standbys] if p is not None}
        for pid in _adopted_children():
            if pid in own:
                continue
            try:
                os.waitpid(pid, os.WNOHANG)
            except ChildProcessError:
                pass

    def _stop_orphans(self, grace: float = 3.0) -> None:
        """At the end: the plant and agents still running (they leave on the orchestrator's stop, or when no
        orchestrator is left) get SIGTERM, then SIGKILL after ``grace`` seconds."""
        own = {p.pid for p in [self.active, self.router, *self.standbys] if p is not None}
        deadline = time.monotonic() + grace
        while time.monotonic() < deadline:
            self._reap_orphans()
            left = [p for p in _adopted_children() if p not in own and _running(p)]
            if not left:
                return
            time.sleep(SUPERVISE_POLL)
        for sig in (signal.SIGTERM, signal.SIGKILL):
            for pid in [p for p in _adopted_children() if p not in own]:
                try:
                    os.kill(pid, sig)
                except ProcessLookupError:
                    pass
            time.sleep(0.5)
            self._reap_orphans()


def _running(pid: int) -> bool:
    from .registry import process_state

    return process_state(pid) not in (None, "Z")


def _signal_name(signum: int) -> str:
    try:
        return signal.Signals(signum).name
    except ValueError:
        return f"signal {signum}"
