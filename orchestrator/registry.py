"""Where running runs can be found on this machine (for ``splitspec kill``).

The orchestrator keeps one small JSON file per run in the runtime directory
(``$SPLITSPEC_RUNTIME_DIR``, else ``$XDG_RUNTIME_DIR/splitspec``, else
``/tmp/splitspec-<uid>``), named ``<run_id>.<orchestrator pid>.json``::

    {"run_id": ..., "endpoint": ..., "out": ..., "host": ...,
     "orchestrator": {"pid": ...}, "plant": {"pid": ..., "host": ...},
     "agents": {"3": {"pid": ..., "host": ...}, ...}}

It is rewritten atomically whenever a process starts (a restarted agent has
a new pid) and removed when the orchestrator exits; a file whose
orchestrator is gone (SIGKILLed) is stale and ignored.
"""

from __future__ import annotations

import json
import os
import tempfile
from pathlib import Path

from splitspec_core.errors import SplitspecError

__all__ = ["runtime_dir", "RunRegistry", "find_runs", "pid_running"]


def runtime_dir() -> Path:
    env = os.environ.get("SPLITSPEC_RUNTIME_DIR")
    if env:
        return Path(env)
    xdg = os.environ.get("XDG_RUNTIME_DIR")
    if xdg and os.path.isdir(xdg):
        return Path(xdg) / "splitspec"
    return Path(tempfile.gettempdir()) / f"splitspec-{os.getuid()}"


def pid_running(pid: int) -> bool:
    """True if ``pid`` is a live (non-zombie) process."""
    try:
        os.kill(int(pid), 0)
    except (ProcessLookupError, ValueError, OverflowError):
        return False
    except PermissionError:
        return True
    try:
        with open(f"/proc/{int(pid)}/stat") as f:
            return f.read().rsplit(")", 1)[-1].split()[0] != "Z"
    except OSError:
        return True


class RunRegistry:
    """The orchestrator's entry: ``update()`` after every change, ``remove()`` at exit."""

    def __init__(self, run_id: str, data: dict):
        self.dir = runtime_dir()
        self.path = self.dir / f"{run_id}.{os.getpid()}.json"
        self.data = {"run_id": run_id, "orchestrator": {"pid": os.getpid()}, "agents": {}, **data}
        find_runs("*")  # sweep entries of orchestrators that were killed

    def update(self) -> None:
        try:
            self.dir.mkdir(parents=True, exist_ok=True, mode=0o700)
            fd, tmp = tempfile.mkstemp(dir=self.dir, prefix=".reg-")
            with os.fdopen(fd, "w") as f:
                json.dump(self.data, f)
            os.replace(tmp, self.path)
        except OSError:
            pass  # the registry is a convenience; a run never fails because of it

    def remove(self) -> None:
        try:
            self.path.unlink()
        except OSError:
            pass


def find_runs(run_id: str) -> list:
    """Registry entries of live orchestrators for ``run_id`` (``*``: every run); stale files are removed."""
    d = runtime_dir()
    out = []
    for p in sorted(d.glob(f"{run_id}.*.json")) if d.is_dir() else ():
        try:
            data = json.loads(p.read_text())
            pid = int(data["orchestrator"]["pid"])
        except (OSError, ValueError, KeyError, TypeError):
            continue
        if run_id != "*" and data.get("run_id") != run_id:
            continue
        if not pid_running(pid):
            try:
                p.unlink()
            except OSError:
                pass
            continue
        out.append(data)
    return out


def resolve(run_id: str, role: str, ident: int | None) -> tuple:
    """``(pid, host, entry)`` of the process ``role``/``ident`` of the one live run ``run_id``."""
    runs = find_runs(run_id)
    if not runs:
        raise SplitspecError(f"no running run with id {run_id!r} on this machine (looked in {runtime_dir()}); "
                             "give --run-id as passed to splitspec run / orchestrator")
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
