"""Where running runs can be found on this machine (for ``splitspec kill``).

The orchestrator keeps one small JSON file per run in the runtime directory
(``$SPLITSPEC_RUNTIME_DIR``, else ``$XDG_RUNTIME_DIR/splitspec``, else
``/tmp/splitspec-<uid>``; created 0700), named ``<run_id>.<orchestrator pid>.json``::

    {"run_id": ..., "endpoint": ..., "out": ..., "host": ..., "started": <unix time>,
     "written": {"boot_id": ..., "ticks": <kernel clock ticks when written>}, "orchestrator": {"pid": ...}, "plant": {"pid": ..., "host": ...},
     "agents": {"3": {"pid": ..., "host": ...}, ...}}

It is rewritten atomically whenever a process starts (a restarted agent has
a new pid) and removed when the orchestrator exits; a file whose
orchestrator is gone (SIGKILLed) is stale: ignored and removed.

Only this user's runs count: a directory or file owned by another uid is
ignored, and a pid is signalled only while it is a live splitspec process of
this user that started before the entry naming it was written (a pid reused
by anything else, even another splitspec process, is left alone).

Standard library only: ``splitspec kill`` imports this module and must start
in a few tens of milliseconds.
"""

from __future__ import annotations

import json
import os
import tempfile
import threading
import time
from pathlib import Path

from splitspec_core.errors import SplitspecError

__all__ = ["runtime_dir", "RunRegistry", "find_runs", "pid_running", "process_state", "new_run_id",
           "check_run_id", "is_own_splitspec_process", "resolve", "RunChoiceError", "describe_run"]

# the characters splitspec_core.runtime.wire.Keys refuses in a run id (a Zenoh key chunk; tests check both agree)
_FORBIDDEN = frozenset("/*$?#")


class RunChoiceError(SplitspecError, ValueError):
    """No run id given and not exactly one live run: ``runs`` lists the live ones."""

    def __init__(self, message: str, runs: list):
        super().__init__(message)
        self.runs = runs


def new_run_id() -> str:
    """A fresh run id: ``r`` + 8 hex digits (32 random bits), a valid Zenoh key chunk."""
    import secrets  # here, not at the top: kill does not need it

    return "r" + secrets.token_hex(4)


def check_run_id(run_id: str) -> str:
    """``run_id`` if it is usable as a key chunk and a file name (the rule of ``wire.Keys``)."""
    if not run_id or _FORBIDDEN & set(run_id):
        raise SplitspecError(f"--run-id must be non-empty without / * $ ? #, got {run_id!r}")
    return run_id


def runtime_dir() -> Path:
    env = os.environ.get("SPLITSPEC_RUNTIME_DIR")
    if env:
        return Path(env)
    xdg = os.environ.get("XDG_RUNTIME_DIR")
    if xdg and os.path.isdir(xdg):
        return Path(xdg) / "splitspec"
    return Path(tempfile.gettempdir()) / f"splitspec-{os.getuid()}"


def process_state(pid: int) -> str | None:
    """The state letter of process ``pid`` on this host (``/proc/PID/stat``: ``R`` running, ``S`` sleeping, ``D``
    in the disk, ``T`` stopped by a signal, ``t`` by a debugger, ``Z`` a zombie, ...); None if there is none.

    Examples
    --------
    >>> process_state(os.getpid())
    'R'
    """
    try:
        with open(f"/proc/{int(pid)}/stat", encoding="ascii", errors="replace") as f:
            return f.read().rsplit(")", 1)[-1].split()[0]
    except (OSError, ValueError, OverflowError, IndexError):
        return None


def pid_running(pid: int) -> bool:
    """True if ``pid`` is a live (non-zombie) process."""
    try:
        os.kill(int(pid), 0)
    except (ProcessLookupError, ValueError, OverflowError):
        return False
    except PermissionError:
        return True
    return process_state(pid) != "Z"  # (unreadable: alive, as the signal said)


def _start_ticks(path: str) -> int | None:
    """Field 22 (starttime, clock ticks since boot) of a /proc ``stat`` file."""
    try:
        with open(path) as f:
            return int(f.read().rsplit(")", 1)[-1].split()[19])
    except (OSError, ValueError, IndexError):
        return None


def _boot_id() -> str | None:
    try:
        with open("/proc/sys/kernel/random/boot_id") as f:
            return f.read().strip()
    except OSError:
        return None


def now_mark() -> dict:
    """This instant on the kernel's own process clock: ``{"boot_id", "ticks"}``.

    The ticks are the start time of a thread created now, read from /proc exactly as a process's start is
    read, so comparing the two involves no wall clock (on CI a VM's wall clock, stepped or restored from
    a snapshot, placed a fresh process more than 10 s in the future of time.time()).
    """
    box = []
    t = threading.Thread(target=lambda: box.append(_start_ticks(f"/proc/self/task/{threading.get_native_id()}/stat")))
    t.start()
    t.join()
    return {"boot_id": _boot_id(), "ticks": box[0] if box else None}


def is_own_splitspec_process(pid: int, *, started_before: dict | None = None) -> bool:
    """``pid`` is a live splitspec process of this user (started no later than the mark ``started_before``).

    The guard against a reused pid before signalling one read from the registry: ``started_before`` is
    the entry's :func:`now_mark` when it was written (a mark of another boot, or a process that started
    more than a second after it, is not the process the entry names).
    """
    try:
        pid = int(pid)
        if pid <= 0 or not pid_running(pid) or os.stat(f"/proc/{pid}").st_uid != os.getuid():
            return False
        with open(f"/proc/{pid}/cmdline", "rb") as f:
            cmd = f.read()
    except (OSError, ValueError, TypeError, OverflowError):
        return False
    if b"splitspec" not in cmd:
        return False
    if isinstance(started_before, dict) and isinstance(started_before.get("ticks"), int):
        if started_before.get("boot_id") != _boot_id():
            return False
        t0 = _start_ticks(f"/proc/{pid}/stat")
        if t0 is None or t0 > started_before["ticks"] + os.sysconf("SC_CLK_TCK"):
            return False
    return True


class RunRegistry:
    """The orchestrator's entry: ``update()`` after every change, ``remove()`` at exit."""

    def __init__(self, run_id: str, data: dict):
        self.dir = runtime_dir()
        self.path = self.dir / f"{check_run_id(run_id)}.{os.getpid()}.json"
        self.data = {"run_id": run_id, "orchestrator": {"pid": os.getpid()}, "agents": {},
                     "started": time.time(), **data}
        find_runs("*")  # sweep entries of orchestrators that were killed

    def update(self) -> None:
        try:
            self.dir.mkdir(parents=True, exist_ok=True, mode=0o700)
            fd, tmp = tempfile.mkstemp(dir=self.dir, prefix=".reg-")
            with os.fdopen(fd, "w") as f:
                json.dump({**self.data, "written": now_mark()}, f)
            os.replace(tmp, self.path)
        except OSError:
            pass  # the registry is a convenience; a run never fails because of it

    def remove(self) -> None:
        try:
            self.path.unlink()
        except OSError:
            pass


def _own_dir(d: Path) -> bool:
    try:
        return d.is_dir() and d.stat().st_uid == os.getuid()
    except OSError:
        return False


def find_runs(run_id: str) -> list:
    """Registry entries of this user's live orchestrators for ``run_id`` (``*``: every run).

    Files of other users are ignored; stale files (orchestrator gone) are removed.
    """
    d = runtime_dir()
    if not _own_dir(d):
        return []
    uid = os.getuid()
    out = []
    for p in sorted(d.glob("*.json")):  # <run_id>.<pid>.json; the run id is taken from the content
        try:
            st = p.lstat()
            if not p.is_file() or p.is_symlink() or st.st_uid != uid:
                continue  # not ours: never trusted, never removed
            data = json.loads(p.read_text())
            pid = int(data["orchestrator"]["pid"])
        except (OSError, ValueError, KeyError, TypeError):
            continue
        if run_id != "*" and data.get("run_id") != run_id:
            continue
        if not is_own_splitspec_process(pid, started_before=data.get("written")):
            try:
                p.unlink()
            except OSError:
                pass
            continue
        out.append(data)
    return sorted(out, key=lambda e: (_number(e.get("started")), int(e["orchestrator"]["pid"])))


def _number(x) -> float:
    return float(x) if isinstance(x, (int, float)) else 0.0


def describe_run(entry: dict) -> str:
    """One line: run id, orchestrator pid, output directory, start time."""
    t = entry.get("started")
    when = time.strftime("%Y-%m-%d %H:%M:%S", time.localtime(t)) if _number(t) else "?"
    return (f"{entry.get('run_id')}  orchestrator pid {entry['orchestrator']['pid']}  out {entry.get('out')}  "
            f"started {when}")


def resolve(run_id: str | None, role: str, ident: int | None) -> tuple:
    """``(pid, host, entry)`` of the process ``role``/``ident`` of one live run of this user.

    ``run_id`` None: the only live run on this machine; with none or several, :class:`RunChoiceError`.
    """
    d = runtime_dir()
    if d.exists() and not _own_dir(d):
        raise SplitspecError(f"the run registry {d} is not owned by you (uid {os.getuid()}); not using it")
    if run_id is None:
        runs = find_runs("*")
        if len(runs) != 1:
            what = "no live run" if not runs else f"{len(runs)} live runs"
            hint = ("start one with splitspec run / orchestrator" if not runs
                    else "choose one with --run-id")
            raise RunChoiceError(f"{what} of yours on this machine (looked in {d}); {hint}", runs)
        run_id = runs[0]["run_id"]
    else:
        runs = find_runs(check_run_id(run_id))
    if not runs:
        raise SplitspecError(f"no running run with id {run_id!r} on this machine (looked in {d}); "
                             "give --run-id as printed by splitspec run / orchestrator")
    if len(runs) > 1:
        pids = ", ".join(str(r["orchestrator"]["pid"]) for r in runs)
        raise SplitspecError(f"{len(runs)} runs with id {run_id!r} are running (orchestrator pids {pids}); "
                             "give each run its own --run-id")
    entry = runs[0]
    if role == "orchestrator":
        return int(entry["orchestrator"]["pid"]), entry.get("host"), entry
    if role == "plant":
        info = entry.get("plant")
        what = "the plant"
    else:
        info = entry["agents"].get(str(ident))
        what = f"agent {ident}"
    if not info:
        known = ", ".join(sorted(entry["agents"], key=lambda s: int(s))) or "none yet"
        raise SplitspecError(f"{what} has not started in run {run_id!r} (agents started: {known})")
    return int(info["pid"]), info.get("host"), entry
