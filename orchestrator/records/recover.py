"""``splitspec recover OUT``: make the records of a killed run agree again.

A run whose orchestrator was killed (SIGKILL, power loss) leaves its chunks (``chunks/``) as of its last
flush (a record batch may be torn), ``trajectory.npz`` as of its last rewrite (a run of ``run.steps``), ``run.rrd``
(or its last segment, ``run-000k.rrd``, of a rolled recording) without a footer (``rerun rrd verify`` fails; a
message may be torn) and possibly a torn last line in ``events.jsonl``.  :func:`recover` takes the chunks (K
rows, event times 0..K-1; ``trajectory.npz`` of a run before chunks existed) as the authority, cuts a torn
batch off, rewrites ``trajectory.npz`` from them if the run kept one with fewer rows (or was to keep one, a run of
``run.steps``, and was killed before its first), and

- rewrites ``run.rrd`` from its whole messages with the data of event times
  ``< K`` and the static data, blueprint, text log and topology up to ``K``
  included, as one RRD with footer, checked with ``rerun rrd verify``;
- drops a torn last line of ``events.jsonl`` and appends a
  ``records_recovered`` event with ``rows: K``;
- removes the recorder's leftovers (disk-space reserve, temporary files).

It is idempotent: records that already agree (a cleanly closed run, or one
recovered before) are left as they are.
"""

from __future__ import annotations

import json
import os
import time
import warnings
from pathlib import Path
from typing import Any

import numpy as np

from splitspec_core.errors import SplitspecError
from splitspec_core.simulation.simulator import Trajectory
from splitspec_core.simulation.trajectory_chunks import chunk_segments, whole_length
from splitspec_core.simulation.trajectory_chunks import read_chunks as read_rows

from .outdir import RESERVE_FILE
from ..viewer.blueprint import default_blueprint
from .recorder import EVENTS_FILE, RRD_FILE, TRAJECTORY_FILE, verify_rrd
from ..viewer.rrd_file import has_footer, read_chunks, rewrite_rrd, rrd_segments, whole_messages_length

__all__ = ["RecoverError", "recover"]

_CLOSING_EVENTS = ("recording_closed", "records_recovered")


class RecoverError(SplitspecError, RuntimeError):
    """The records in the directory cannot be recovered; the message says why."""


def recover(out_dir: str | os.PathLike) -> dict[str, Any]:
    """Make ``trajectory.npz``, ``events.jsonl`` and ``run.rrd`` in ``out_dir`` agree on K event times.

    Returns
    -------
    dict
        ``rows`` (K), ``rrd`` (what happened to run.rrd: ``"kept"``,
        ``"rewritten"`` or ``"missing"``), ``rrd_verified`` (bool or None),
        ``events_torn_line_dropped`` (bool), ``events_appended`` (bool),
        ``changed`` (bool) and ``message``, one line for the CLI.

    Raises
    ------
    RecoverError
        No ``trajectory.npz`` (or unreadable), or a file cannot be rewritten.
    """
    out = Path(out_dir)
    traj, events, rrd = out / TRAJECTORY_FILE, out / EVENTS_FILE, out / RRD_FILE
    if not out.is_dir():
        raise RecoverError(f"{out} is not a directory")
    changed = False
    if chunk_segments(out):  # the chunks, written at every flush, are the authority
        try:
            K, t_last, changed = _recover_chunks(out, traj)
        except OSError as exc:
            raise RecoverError(f"cannot recover {out}: {exc.filename or out}: {exc.strerror or exc}") from None
    elif not traj.exists():
        raise RecoverError(f"{out} holds no {TRAJECTORY_FILE} or chunks/ to recover from")
    else:
        try:
            with np.load(traj) as f:
                t = np.asarray(f["t"])
        except Exception as exc:
            raise RecoverError(f"cannot read {traj}: {exc}") from None
        K = int(t.shape[0])
        t_last = float(t[-1]) if K else 0.0
    rows_file = TRAJECTORY_FILE if traj.exists() else "chunks/"
    segments = rrd_segments(rrd)
    rrd = segments[-1] if segments else rrd  # a rolled recording: only its last segment was being written
    try:
        # Leftovers of the recorder: the reserve first (it may be the room the rewrite needs).
        for leftover in [out / RESERVE_FILE, *out.glob(".trajectory.*.npz.tmp"), *out.glob(".run.*.rrd.tmp")]:
            if leftover.exists():
                leftover.unlink()
                changed = True
        rrd_state, verified = _recover_rrd(rrd, K)
        changed |= rrd_state == "rewritten"
        torn, appended = _recover_events(events, K, t_last, rrd_state)
        changed |= torn or appended
    except OSError as exc:
        raise RecoverError(f"cannot recover {out}: {exc.filename or out}: {exc.strerror or exc}") from None
    if rrd_state == "missing":
        where = f"{rows_file} and {EVENTS_FILE} (no {RRD_FILE})"
    else:
        where = f"{rows_file}, {EVENTS_FILE} and {rrd.name}"
    how = {"rewritten": f"{RRD_FILE} rewritten, verified" if verified else f"{RRD_FILE} rewritten, NOT verified",
           "kept": "nothing to change" if not changed else f"{RRD_FILE} already complete",
           "missing": "nothing to change" if not changed else f"{EVENTS_FILE} repaired"}[rrd_state]
    if torn:
        how += f", torn last line of {EVENTS_FILE} dropped"
    return {"rows": K, "rrd": rrd_state, "rrd_verified": verified, "events_torn_line_dropped": torn,
            "events_appended": appended, "changed": changed,
            "message": f"recovered {out}: {K} event times kept in {where} ({how})"}


def _recover_chunks(out: Path, traj: Path) -> tuple[int, float, bool]:
    """The chunks cut back to their whole record batches (a batch torn by the kill); ``trajectory.npz``, if the run
    kept one, rewritten from them when they hold more rows (they are written at every flush, it less often).
    Returns ``(K, t of the last row, changed)``."""
    changed = False
    for _, path in chunk_segments(out):
        whole, size = whole_length(path), path.stat().st_size
        if whole == 0:
            path.unlink()  # not even its schema: created as the run was killed
            changed = True
        elif whole < size:
            os.truncate(path, whole)
            changed = True
    rows = read_rows(out)
    K = 0 if rows is None else len(rows["tau"])
    if rows is not None and (traj.exists() or _keeps_trajectory(out / EVENTS_FILE)):
        try:
            with np.load(traj) as f:
                T = int(f["t"].shape[0])
        except Exception:  # noqa: BLE001 - unreadable or not written yet: the chunks replace it
            T = -1
        if T < K:
            Trajectory.from_arrays(rows).save(traj)
            changed = True
    return K, float(rows["t"][-1]) if K else 0.0, changed


def _keeps_trajectory(events: Path) -> bool:
    """Whether the run kept a ``trajectory.npz`` (a run of ``run.steps``: its ``run_started`` names its steps; a run
    until stopped says ``steps: null`` and keeps its rows in the chunks alone).  A run killed before its first rewrite
    of ``trajectory.npz`` (seen on a busy machine: the chunks held 10 rows, ``trajectory.npz`` none) gets one from
    the chunks all the same."""
    try:
        with open(events, "rb") as f:
            for line in f:
                if b'"run_started"' in line:
                    try:
                        return json.loads(line).get("steps") is not None
                    except ValueError:
                        return False
    except OSError:
        pass
    return False


def _recover_rrd(rrd: Path, K: int) -> tuple[str, bool | None]:
    """``("kept" | "rewritten" | "missing", verified)``: run.rrd cut to event times < K, with footer."""
    if not rrd.exists():
        return "missing", None
    if has_footer(rrd) and _max_data_event(rrd) < K:
        ok, _ = verify_rrd(rrd)
        if ok:
            return "kept", True
    if not has_footer(rrd):
        whole = whole_messages_length(rrd)
        if whole == 0:
            raise RecoverError(f"{rrd} holds no readable Rerun data")
        if whole < rrd.stat().st_size:
            os.truncate(rrd, whole)  # a message torn by the kill
    rewrite_rrd(rrd, rrd, blueprint=_blueprint(rrd), cutoff=K)
    ok, _ = verify_rrd(rrd)
    return "rewritten", ok


def _max_data_event(rrd: Path) -> int:
    """Largest event time of the data (every entity but the text log and topology) in ``rrd``; -1 if none."""
    _, chunks = read_chunks(rrd)
    top = -1
    for chunk in chunks:
        if chunk.is_static or "event" not in chunk.timeline_names or chunk.entity_path in ("/events", "/topology"):
            continue
        events = [e for e in chunk.to_record_batch().column("event").to_pylist() if e is not None]
        if events:
            top = max(top, max(events))
    return top


def _run_properties(rrd: Path, name: str = "splitspec") -> dict:
    """The recording's ``splitspec`` property (``time_mode``, ``n``, ``envelope``, ``columns``...), or another one
    (``measurements``: ``truth``, of a run on measurements); {} if absent."""
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message="RRD file has no footer")
        _, chunks = read_chunks(rrd)
        for chunk in chunks:
            if chunk.entity_path == f"/__properties/{name}":
                batch = chunk.to_record_batch()
                out = {}
                for name in batch.schema.names:
                    value = batch.column(name).to_pylist()[0]
                    out[name] = value[0] if isinstance(value, list) and len(value) == 1 else value
                return out
    return {}


def _columns(props: dict) -> tuple:
    """The reported row columns a recording shows (``columns``: their names, comma-separated; a recording made
    before it: ``g`` if it has ``gains``), those the row schema still has."""
    from splitspec_core.model.rows import REPORTED

    names = props.get("columns")
    names = str(names).split(",") if names is not None else (["g"] if props.get("gains") else [])
    return tuple(c.name for c in REPORTED if c.name in names)


def _blueprint(rrd: Path):
    """The run's default blueprint, rebuilt from the recording's properties (discrete time if absent)."""
    props = _run_properties(rrd)
    measured = _run_properties(rrd, "measurements")
    n = props.get("n")
    states = props.get("states")
    states = [states] if isinstance(states, str) else states  # a one-element list comes back as its element
    shown = props.get("shown")
    shown = [shown] if isinstance(shown, int) else shown
    return default_blueprint(str(props.get("time_mode", "discrete")), n=int(n) if isinstance(n, int) else None,
                             envelope=bool(props.get("envelope", True)), columns=_columns(props),
                             reference=bool(measured), truth=bool(measured.get("truth", True)),
                             states=[str(s) for s in states] if isinstance(states, list) and states else None,
                             shown=[int(k) for k in shown] if isinstance(shown, list) else None)


def _recover_events(events: Path, K: int, t_last: float, rrd_state: str) -> tuple[bool, bool]:
    """``(torn line dropped, records_recovered appended)``."""
    if not events.exists():
        return False, False
    data = events.read_bytes()
    keep = len(data)
    if data and not data.endswith(b"\n"):
        keep = data.rfind(b"\n") + 1  # a line the kill cut short
    lines = data[:keep].splitlines()
    while lines:  # a last line that is not JSON (torn mid-record, padded) goes too
        try:
            last = json.loads(lines[-1])
            break
        except ValueError:
            keep -= len(lines.pop()) + 1
    else:
        last = None
    torn = keep < len(data)
    if torn:
        os.truncate(events, keep)
    if (isinstance(last, dict) and last.get("event") in _CLOSING_EVENTS and last.get("rows") == K
            and rrd_state != "rewritten"):
        return torn, False
    line = json.dumps({"event": "records_recovered", "t": t_last, "wall": time.time(), "rows": K,
                       "run_rrd": rrd_state})
    with open(events, "ab") as f:
        f.write((line + "\n").encode("utf-8"))
        f.flush()
        os.fsync(f.fileno())
    return torn, True
