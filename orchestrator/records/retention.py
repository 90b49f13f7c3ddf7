"""``run.keep``: a run until stopped removes its oldest closed segments as it goes, so its records stay bounded.

A run until stopped writes its rows to append-only chunk segments (``chunks/rows-<tau>.arrows``, a new one past
``SPLITSPEC_CHUNK_MB``) and its Rerun recording to segments (``run.rrd``, ``run-0001.rrd`` ..., a new one past
``SPLITSPEC_RRD_ROLL_MB``).  A segment is *closed* once the next one has started (and, for the recording, once the
child process finishing it has exited).  After each flush :meth:`Retention.sweep` (at most every
:data:`SWEEP_SECONDS`) removes

- with ``run.keep.hours: H``, every closed segment closed at least ``H`` hours ago (wall time; the recording's
  ``run.keep.recording_hours`` when given: a longer review of the thinned recording), and
- with ``run.keep.gigabytes: G``, the oldest closed segments (by their last event time, chunks and recording
  alike) while the records (``chunks/`` and every ``run*.rrd``) take more than ``G`` x 10^9 bytes.

The segment being written is never removed: the disk holds at most about ``H`` hours plus one segment of each
kind (or ``G`` plus one segment of each).  Records a standby took over (:mod:`splitspec_orchestrator.takeover`)
hold the dead orchestrators' segments too: they are closed, from their last write on, and removed by the same
rules.  The run says at its start what retention will do (:func:`plan`: a ``records_retention`` event and a log
line: the segment sizes, ``run.keep.segment_mb`` or the defaults, and the limits).  Each removal is a
``records_removed`` event (``file``, ``first_tau``,
``last_tau``, ``bytes``, ``reason``) in ``events.jsonl`` and the Rerun log; :func:`splitspec_core.runs.kept_span`
reads them back (``ss.load_run``, ``splitspec view`` say which span is still on disk).  A removal that fails
(the file is gone, a permission) is a warning: retention never stops a run.
"""

from __future__ import annotations

import logging
import os
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

from splitspec_core.simulation.trajectory_chunks import chunk_segments

from ..viewer.rrd_file import has_footer, rrd_index, rrd_segments
from ..viewer.sink import RRD_FILE

__all__ = ["Retention", "SWEEP_SECONDS", "records_bytes", "plan"]

log = logging.getLogger(__name__)

#: seconds between two sweeps (a sweep lists the segments; a flush comes every second)
SWEEP_SECONDS = 5.0


@dataclass
class _Segment:
    kind: str  # "chunks" or "recording"
    path: Path
    first: int | None
    last: int | None
    closed_at: float  # time.time() when it closed (or was first seen closed)
    forget: Callable[[], None]  # drop it from its writer's list once removed


def records_bytes(out_dir: str | Path) -> int:
    """The bytes the records of a run take on disk that retention counts: ``chunks/`` and every ``run*.rrd``.

    Parameters
    ----------
    out_dir : str or Path
        The run's directory.

    Returns
    -------
    int
        Their sizes summed (files that vanish meanwhile count 0).
    """
    out_dir = Path(out_dir)
    paths = [p for _, p in chunk_segments(out_dir)] + rrd_segments(out_dir / RRD_FILE)
    total = 0
    for p in paths:
        try:
            total += os.path.getsize(p)
        except OSError:
            pass
    return total


class Retention:
    """Removes a run's closed segments by ``run.keep`` (see the module docstring).

    Parameters
    ----------
    out_dir : Path
        The run's directory.
    files : RecordFiles
        The recorder's files: its chunk writer (``files.chunks``) and Rerun sink (``files.sink``).
    hours : float or None
        ``run.keep.hours``.
    recording_hours : float or None
        ``run.keep.recording_hours``: the recording's segments instead of ``hours`` (None: ``hours``).
    max_bytes : int or None
        ``run.keep.gigabytes`` in bytes.
    emit : callable
        ``emit(event, t, fields)``: writes an event (the recorder's, from within a flush).
    """

    def __init__(self, out_dir: Path, files, *, hours: float | None, max_bytes: int | None,
                 emit: Callable[[str, float, dict], None], recording_hours: float | None = None,
                 prior: tuple | None = None):
        self.out_dir = Path(out_dir)
        # records a standby took over: (rows, rrd segment) where its writers began; the segments before them (the
        # dead orchestrators') are closed too, listed from the folder at the first sweep
        self.prior_before = prior
        self._prior: list | None = None
        self.files = files
        self.seconds = {kind: None if h is None else float(h) * 3600.0
                        for kind, h in (("chunks", hours), ("recording", hours if recording_hours is None
                                                                         else recording_hours))}
        self.max_bytes = None if max_bytes is None else int(max_bytes)
        self.emit = emit
        self._seen: dict[Path, float] = {}  # chunk segments: when each was first seen closed
        self._next = 0.0
        self.every = SWEEP_SECONDS  # seconds between two sweeps
        self.removed = 0  # segments removed so far
        self.removed_bytes = 0

    def closed(self) -> list[_Segment]:
        """The closed segments that may be removed, oldest (by last event time) first."""
        now = time.time()
        segs = []
        cw = self.files.chunks
        if cw is not None:
            for path, last in cw.segments:
                first = _chunk_first(path)
                segs.append(_Segment("chunks", path, first, last, self._seen.setdefault(path, now),
                                     lambda p=path: _forget_chunk(cw, p)))
        if self.prior_before is not None:
            if self._prior is None:
                self._prior = self._scan_prior()
            segs += [seg for seg in self._prior if seg.kind == "chunks" or has_footer(seg.path)]
        sink = self.files.sink
        if sink is not None:
            for c in sink.closed:
                if c.finished:
                    segs.append(_Segment("recording", c.path, c.first, c.last, c.closed_at,
                                         lambda c=c, s=sink: s.closed.remove(c)))
        return sorted(segs, key=lambda s: (-1 if s.last is None else s.last, s.kind))

    def _scan_prior(self) -> list:
        """The segments of the records before a takeover (closed when their orchestrator died: closed at their last
        write); a chunk segment's last event time is the next one's first minus one, a recording segment's is not
        known (None).  A recording segment whose finishing child has not written its footer yet waits."""
        rows, segment = self.prior_before
        prior: list = []
        chunks = [(first, p) for first, p in chunk_segments(self.out_dir) if first < rows]
        for k, (first, p) in enumerate(chunks):
            last = chunks[k + 1][0] - 1 if k + 1 < len(chunks) else rows - 1
            prior.append(_Segment("chunks", p, first, last, _mtime(p), lambda s=p: self._drop_prior(s)))
        for p in rrd_segments(self.out_dir / RRD_FILE):
            if rrd_index(p) < segment:
                prior.append(_Segment("recording", p, None, None, _mtime(p), lambda s=p: self._drop_prior(s)))
        return prior

    def _drop_prior(self, path: Path) -> None:
        self._prior = [seg for seg in self._prior if seg.path != path]

    def sweep(self, t: float, *, force: bool = False) -> list[dict]:
        """Remove what ``run.keep`` says (at most every :data:`SWEEP_SECONDS` unless ``force``); ``t``: the run's
        time of the last row (the events').  Returns the ``records_removed`` events' fields."""
        mono = time.monotonic()
        if not force and mono < self._next:
            return []
        self._next = mono + self.every
        segs = self.closed()
        if not segs:
            return []
        gone: list[tuple[_Segment, str]] = []
        now = time.time()
        gone += [(s, "hours") for s in segs
                 if self.seconds[s.kind] is not None and now - s.closed_at >= self.seconds[s.kind]]
        if self.max_bytes is not None:
            total = records_bytes(self.out_dir) - sum(_size(s.path) for s, _ in gone)
            picked = {id(s) for s, _ in gone}
            for s in segs:
                if total <= self.max_bytes:
                    break
                if id(s) not in picked:
                    gone.append((s, "gigabytes"))
                    total -= _size(s.path)
        done = []
        for s, reason in gone:
            size = _size(s.path)
            try:
                s.path.unlink()
            except FileNotFoundError:
                pass
            except OSError as exc:
                log.warning("run.keep: could not remove %s (%s)", s.path, exc.strerror or exc)
                continue
            s.forget()
            self._seen.pop(s.path, None)
            self.removed += 1
            self.removed_bytes += size
            fields = {"file": s.path.relative_to(self.out_dir).as_posix(), "kind": s.kind,
                      "first_tau": s.first, "last_tau": s.last, "bytes": size, "reason": reason}
            self.emit("records_removed", t, fields)
            done.append(fields)
        return done


def plan(continuous) -> dict:
    """What ``run.keep`` will do in a run until stopped: the ``records_retention`` event's fields, ``text`` one line.

    Parameters
    ----------
    continuous : Continuous
        The run's :class:`~.files.Continuous` (its segment sizes and ``run.keep``'s limits).

    Returns
    -------
    dict
        ``chunk_mb`` and ``recording_mb`` (MiB past which a segment closes), ``hours``, ``recording_hours``,
        ``gigabytes`` (None: not given) and ``text``.

    Examples
    --------
    >>> from splitspec_orchestrator.records.files import Continuous
    >>> plan(Continuous(chunk_bytes=1 << 20, rrd_bytes=4 << 20, keep_hours=0.5))["text"]
    'run.keep: a row chunk segment closes past 1 MiB, a recording segment past 4 MiB (run.keep.segment_mb); closed segments are removed 0.5 h after they close; nothing is removed before the first segment closes'
    """
    c = continuous
    chunk_mb, rrd_mb = c.chunk_bytes / (1 << 20), c.rrd_bytes / (1 << 20)
    gigabytes = None if c.keep_bytes is None else c.keep_bytes / 1e9
    rules = []
    if c.keep_hours is not None:
        rules.append(f"closed segments are removed {c.keep_hours:g} h after they close"
                     + ("" if c.keep_recording_hours is None else
                        f" ({c.keep_recording_hours:g} h for the recording's)"))
    if gigabytes is not None:
        rules.append(f"the oldest closed segments while the records take more than {gigabytes:g} GB")
    text = (f"run.keep: a row chunk segment closes past {chunk_mb:.4g} MiB, a recording segment past {rrd_mb:.4g} MiB "
            f"(run.keep.segment_mb); {'; '.join(rules)}; nothing is removed before the first segment closes")
    return {"chunk_mb": chunk_mb, "recording_mb": rrd_mb, "hours": c.keep_hours,
            "recording_hours": c.keep_recording_hours, "gigabytes": gigabytes, "text": text}


def _size(path: Path) -> int:
    try:
        return os.path.getsize(path)
    except OSError:
        return 0


def _mtime(path: Path) -> float:
    try:
        return os.path.getmtime(path)
    except OSError:
        return time.time()


def _chunk_first(path: Path) -> int | None:
    """A chunk segment's first event time: its name (``rows-<tau>.arrows``)."""
    try:
        return int(path.name.split("-", 1)[1].split(".", 1)[0])
    except (IndexError, ValueError):
        return None


def _forget_chunk(cw, path: Path) -> None:
    cw.segments = [(p, last) for p, last in cw.segments if p != path]
