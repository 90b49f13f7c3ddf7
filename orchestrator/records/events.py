"""The run's event log: ``events.jsonl`` (one JSON object per line) and the one-sentence text shown in Rerun.

What ``events.jsonl`` holds (its line, the events and their fields): docs/reference/files.md, section
"Event log".  :class:`EventLog` opens the file for each write only (no file of the run stays open between
calls) and cuts back a line torn by a failed write.  :func:`event_text` turns an event into the short,
complete sentence of the ``events`` TextLog (``agent 3 lost: killed by the scenario (SIGKILL)``,
``graph a -> b``, ``12 consensus messages did not count (12 loss)``; a fault kind's own event, ``arc 1 -> 6
dropped``, by its kind: :mod:`splitspec_core.scenarios.faults`); unknown events read ``<event> k=v ...``.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

import numpy as np

from splitspec_core.scenarios.faults import fault_event_text
from splitspec_core.model.screening import FLATLINE

__all__ = ["EVENTS_FILE", "EventLog", "event_text", "event_level", "json_default"]

EVENTS_FILE = "events.jsonl"
_WARN_WORDS = ("lost", "rejected", "error", "failed")


def json_default(obj: Any) -> Any:
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, (set, frozenset)):
        return sorted(obj)
    if isinstance(obj, Path):
        return str(obj)
    raise TypeError(f"event field of type {type(obj).__name__} is not JSON serialisable")


def event_level(event: str) -> str:
    """WARN when the name contains lost/rejected/error/failed, else INFO."""
    return "WARN" if any(w in event.lower() for w in _WARN_WORDS) else "INFO"


def _who(fields: dict) -> str:
    role = fields.get("role", "agent")
    return "the plant" if role == "plant" else f"{role} {fields.get('id', '?')}"


_TEXTS = {
    "agent_lost": lambda f: f"agent {f.get('id', f.get('agent', '?'))} lost" + (f": {f['reason']}" if f.get("reason") else ""),
    "agent_rejoined": lambda f: f"agent {f.get('id', '?')} rejoined (incarnation {f.get('incarnation', '?')})",
    "agent_restarting": lambda f: f"agent {f.get('id', '?')} restarting",
    "restart_failed": lambda f: f"restart of agent {f.get('id', '?')} failed: {f.get('reason', '')}",
    "graph_switched": lambda f: f"graph {f.get('previous', '?')} -> {f.get('graph', '?')}",
    "fault_skipped": lambda f: f"{f.get('action', 'fault')} of agent {f.get('id', '?')} skipped: {f.get('reason', '')}",
    "process_started": lambda f: f"{_who(f)} started (pid {f.get('pid')} on {f.get('host')})",
    "process_ready": lambda f: f"{_who(f)} ready {f.get('startup_s')} s after its start (pid {f.get('pid')})",
    "process_exited": lambda f: f"{_who(f)} exited (pid {f.get('pid')}, {f.get('how', f.get('status'))})",
    "process_left": lambda f: f"{_who(f)} left during start-up (pid {f.get('pid')})",
    "message_rejected": lambda f: f"{f.get('count', 1)} message(s)" + (f" from {f['by']}" if f.get("by") else "")
                                  + f" rejected ({f.get('reason', '?')})",
    "messages_lost": lambda f: f"{f['count']} consensus message{'s' if f['count'] != 1 else ''} did not count ("
                               + ", ".join(f"{f[c]} {c}" for c in ("loss", "late", "partition") if f.get(c)) + ")",
    "sensor_lost": lambda f: f"agent {f.get('agent')}'s sensor gave no measurement at event time {f.get('tau')} "
                             "(prediction only until it is back)",
    "sensor_back": lambda f: f"agent {f.get('agent')}'s sensor back at event time {f.get('tau')} (silent for "
                             f"{f.get('silent')} event times)",
    "sensor_suspect": lambda f: f"agent {f.get('agent')}'s sensor suspect (" + (
        "its measurement repeats exactly: stuck" if f.get("statistic") == FLATLINE else
        f"statistic {f.get('statistic'):.4g} over {f.get('threshold'):.4g}") + "): it estimates from its neighbours alone",
    "sensor_restored": lambda f: f"agent {f.get('agent')}'s sensor restored (statistic {f.get('statistic'):.4g} under "
                                 f"{f.get('threshold'):.4g})",
    "records_retention": lambda f: f.get("text"),
    "records_removed": lambda f: f"removed {f.get('file')} (event times {f.get('first_tau')}..{f.get('last_tau')}, "
                                 f"{f.get('bytes', 0) / 1e6:.1f} MB): " + (
        "closed longer ago than run.keep.hours" if f.get("reason") == "hours" else
        "the records were over run.keep.gigabytes"),
    "inputs_differ": lambda f: f"agents {f.get('agents')} took other live inputs than agent {f.get('recorded')} "
                               f"(recorded) at event time {f.get('tau')}",
    "round_retried": lambda f: f"round {f.get('tau')} re-run (attempt {f.get('attempt')}; late: {f.get('late')})",
    "run_started": lambda f: f"run started ({len(f.get('agents', []))} agents, "
                             + (f"{f['steps']} steps)" if f.get("steps") is not None else "until stopped)"),
    "run_finished": lambda f: f"run finished ({f.get('rounds')} rounds in {f.get('seconds')} s)",
    "run_interrupted": lambda f: "run interrupted",
    "pace_not_kept": lambda f: f"cannot keep pace {f.get('pace')}: {f.get('achieved_rate')} event times per second, "
                               f"{f.get('late_ms')} ms behind; limited by {f.get('limit')}",
    "orchestrator_started": lambda f: f"orchestrator started (pid {f.get('pid')})",
    "orchestrator_lost": lambda f: f"the orchestrator (pid {f.get('pid')} on {f.get('host')}, epoch {f.get('epoch')}) "
                                   f"was lost at event time {f.get('tau')}",
    "orchestrator_takeover": lambda f: f"orchestrator epoch {f.get('epoch')} (pid {f.get('pid')} on {f.get('host')}) "
                                       f"took the run over at event time {f.get('tau')}; rounds stalled "
                                       f"{f.get('stall_ms')} ms",
    "standby_joined": lambda f: f"a standby orchestrator follows the run (pid {f.get('pid')} on {f.get('host')})",
    "standby_ready": lambda f: f"the standby (pid {f.get('pid')}) is ready to take over",
    "standby_left": lambda f: f"the standby (pid {f.get('pid')}) left",
    "rows_missing": lambda f: f"event times {f.get('first')}..{f.get('last')} were not recorded (the dead orchestrator "
                              "had not written them, its standby had not followed them)",
    "orchestrator_stalled": lambda f: f"orchestrator frozen for {f.get('seconds')} s",
    "recording_closed": lambda f: f"recording closed ({f.get('rows')} rows"
                                  + ("" if f.get("finished", True) else ", unfinished")
                                  + (f": {f['error']}" if f.get("error") else "") + ")",
}


def event_text(event: str, fields: dict, note: str | None = None) -> str:
    """The one-sentence text of an event for the ``events`` TextLog (never truncated)."""
    if note:
        return note if event == "resilience_verdict" else f"{event}: {note}"
    fmt = _TEXTS.get(event)
    try:
        text = fmt(fields) if fmt is not None else fault_event_text(event, fields)  # a fault kind's own event
        if text is not None:
            return text
    except (TypeError, ValueError):
        pass
    return event + "".join(f" {k}={v}" for k, v in fields.items())


class EventLog:
    """``events.jsonl`` of a run: created empty (or, ``append``, taken as it is), then appended one line at a time.

    Raises
    ------
    OSError
        From :meth:`write` or the constructor when the file cannot be written
        (a torn line is cut back first).
    """

    def __init__(self, path: Path, *, append: bool = False):
        self.path = Path(path)
        self.size = 0
        if append and self.path.exists():  # a standby that takes over a run goes on after the last whole line
            self.size = self.path.stat().st_size
            return
        self._write(b"", mode="wb")

    def line(self, event: str, t: float, wall: float, fields: dict) -> bytes:
        return (json.dumps({"event": event, "t": t, "wall": wall, **fields}, default=json_default) + "\n").encode()

    def write(self, event: str, t: float, wall: float, fields: dict) -> None:
        self._write(self.line(event, t, wall, fields))

    def append(self, line: bytes) -> None:
        """Append a line made by :meth:`line`."""
        self._write(line)

    def _write(self, data: bytes, *, mode: str = "ab") -> None:
        try:
            with open(self.path, mode) as f:
                f.write(data)
                f.flush()
        except OSError:
            try:
                os.truncate(self.path, self.size)
            except OSError:
                pass
            raise
        self.size = len(data) if mode == "wb" else self.size + len(data)
