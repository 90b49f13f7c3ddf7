"""What a recorder's flush writes, in which order, and what the records hold after a write failure.

:class:`RecordWriter` holds the rows a :class:`~splitspec_orchestrator.records.recorder.Recorder`'s flushes
took (a :class:`~splitspec_orchestrator.records.rowstore.RowStore` of their own, written out while the callers
go on recording) and writes each flush out: the rows, then the logs queued since the last flush
(:mod:`splitspec_orchestrator.viewer.handoff`), to Rerun and ``run.rrd``; then ``trajectory.npz``
(:class:`~splitspec_orchestrator.records.files.RecordFiles`).  At the close it writes the records' end
(:meth:`RecordWriter.finish`).  Everything here runs under the recorder's ``_io`` lock (one flush at a time).
What the three files hold: docs/reference/files.md, sections "Trajectory file", "Event log" and "Rerun
recording".

Write failures and consistency
------------------------------
A failed write of any of the three files (ENOSPC, EROFS, EACCES, EDQUOT...)
*does* stop the recording: it raises :class:`~splitspec_orchestrator.records.files.RecordsWriteError`
(``cannot write <path>: <strerror>``, with ``path``, ``strerror``, ``tau``)
from the call that hit it (``event`` for ``events.jsonl``; ``flush``,
``close``, or any call with ``flush_seconds=0``), or -- when the background
thread hit it, as it does for ``run.rrd`` and ``trajectory.npz`` during a
run -- from the next ``row``/``event``/``topology``/``mark_lost``/``flush``;
every later call raises it again, and the background thread stops.

``run.rrd`` is written by Python, not by Rerun's ``FileSink`` (whose Rust
thread never reports a failed write): the recording logs into an
``rr.binary_stream()`` and each flush appends the bytes read from it to
``run.rrd`` with ordinary file calls that raise ``OSError`` (see
:mod:`splitspec_orchestrator.viewer.rrd_file` for the format).  ``events.jsonl`` and ``run.rrd`` are
opened per write (no file of the run stays open between calls), a torn line or message is cut
back after a failed write.

A flush writes ``run.rrd`` first, then ``trajectory.npz`` (one flush at a
time, whichever thread runs it), so the npz never holds an event time the rrd
lacks and a SIGKILL loses at most the rows of one flush period (plus the
flush under way; on a long run, those since the last rewrite of
``trajectory.npz``, which ``splitspec recover`` cuts ``run.rrd`` back to)
from both.  ``close(finished=False)`` after a write failure does
not raise: it removes the disk-space reserve (``.splitspec-reserve``, a few
MB preallocated at start, :class:`splitspec_orchestrator.records.outdir.Reserve`), writes what
the failure left unwritten, and leaves K = :attr:`RecordWriter.rows_kept` rows in
``trajectory.npz``, the data of those K event times only in ``run.rrd``
(rewritten, verifiable; text log and topology up to the next event time) and
a last ``recording_closed`` event with ``rows: K`` in ``events.jsonl`` -- each
as far as the disk allows.  On a read-only file system nothing more can be
written: K is what the last successful flush left in both ``trajectory.npz``
and the footer-less ``run.rrd``; ``splitspec recover`` (:mod:`splitspec_orchestrator.records.recover`)
finishes the job once the disk is writable.  The same command repairs the
records of a killed run.
"""

from __future__ import annotations

import threading
import time
from typing import Any

import numpy as np

from splitspec_core.model.rows import REPORTED

from ..viewer.handoff import Deferred, LostRow, RowBatch, TextLine, send_logs
from ..viewer.sink import RerunSink
from .events import EventLog, event_text
from .files import RecordFiles, RecordsWriteError, WriteFailure
from .measured import MeasuredRecords
from .rowstore import RowStore

__all__ = ["RecordWriter"]

# The background thread's rewrites of trajectory.npz take at most this share of its time: a rewrite
# that took w seconds is followed by none before 9 w have passed (a long run's trajectory is large).
_NPZ_DUTY = 0.1
# Rows per piece of a flush: rerun's BinaryStream.read returns what was encoded as one bytes object
# and holds the GIL meanwhile (~20 ms for 8 MB here), so a flush after a burst of rows sends and
# reads them back 512 rows at a time: a caller waiting for the GIL waits for one piece at most.
_SEND_ROWS = 512


class RecordWriter:
    """The rows taken by a recorder's flushes, and their writing out (see the module docstring).

    Parameters
    ----------
    taken : the rows taken (:meth:`take` copies them in)
    files : ``trajectory.npz`` and ``run.rrd``, and the Rerun sink (``files.sink``, None: file records only)
    meas : what a run on measurements records beyond the rows
    events : ``events.jsonl`` (the recorder appends its events; the last one, ``recording_closed``, is written here)
    failure : the recorder's first write failure
    lock : the recorder's ``_lock`` (what its callers record): guards :attr:`rows_kept`
    envelope_rate : the designed envelope's rate (None: no envelope)
    time_mode, dt : the run's time (``t = tau`` or ``t = tau * dt``)
    """

    def __init__(self, taken: RowStore, files: RecordFiles, meas: MeasuredRecords, events: EventLog,
                 failure: WriteFailure, lock: threading.RLock, *, envelope_rate: float | None, time_mode: str,
                 dt: float):
        self.rows = taken
        self.files = files
        self.meas = meas
        self.events = events
        self.failure = failure
        self._lock = lock
        self.envelope_rate, self.time_mode, self.dt = envelope_rate, time_mode, dt
        self.rows_kept = 0  # rows (event times) that trajectory.npz and run.rrd both hold on disk
        self.npz_next = 0.0  # monotonic time before which the background thread does not rewrite trajectory.npz
        self.retention = None  # run.keep: a records.retention.Retention (set by the recorder)

    def tau_of_t(self, t: float) -> int:
        """The event time of time ``t`` (``t = tau`` or ``t = tau * dt``)."""
        return int(round(t)) if self.time_mode == "discrete" else int(round(t / self.dt))

    @property
    def sink(self) -> RerunSink | None:
        """The Rerun sink (None: file records only, or after :meth:`disconnect`)."""
        return self.files.sink

    @property
    def pending(self) -> bool:
        """Something taken that is not on disk yet: bytes Rerun encoded, or rows ``trajectory.npz`` lacks."""
        return (self.sink is not None and bool(self.sink.pending)) or self.files.npz_dirty

    def take(self, src: RowStore, start: int, upto: int, changed: np.ndarray) -> None:
        """Copy rows ``start..upto-1`` and ``changed`` of the recorded rows ``src`` (:meth:`RowStore.take`)."""
        self.rows.take(src, start, upto, changed)
        self.files.npz_dirty = True

    def write(self, ks: np.ndarray, logs: list[Deferred], lost: list[LostRow], *, trajectory: bool = True) -> None:
        """Write out the rows ``ks`` taken and the logs taken with them; ``_lock`` only for :attr:`rows_kept`.

        Rows then logs to Rerun and ``run.rrd``, then ``trajectory.npz``; ``trajectory=False``: leave
        ``trajectory.npz`` for a later flush (see ``_NPZ_DUTY``).

        Raises
        ------
        RecordsWriteError
            If ``run.rrd`` or ``trajectory.npz`` cannot be written.
        """
        taken = self.rows
        sink = self.sink
        for lo in range(0, len(ks), _SEND_ROWS):
            part = ks[lo:lo + _SEND_ROWS]
            err, show = self.meas.row_errors(part)
            if sink is not None:
                sink.guarded("row log", lambda: sink.send_rows(self._batch(part, err, show)))
            # What Rerun now shows (also when a send failed: it is not retried).
            taken.shown[part] = show
            taken.shown_max[part] = show.any(axis=1)
            if sink is not None and lo + _SEND_ROWS < len(ks):
                sink.read_pending()  # a piece at a time (see _SEND_ROWS); run.rrd gets it below
        if sink is not None:
            send_logs(sink, logs, lost, self.meas.mark_y)
        files = self.files
        if len(ks) or logs or (sink is not None and sink.pending):
            files.append_rrd()
        files.append_chunk(ks)  # after run.rrd: the chunks never hold an event time run.rrd lacks
        if self.retention is not None and taken.rows:
            self.retention.sweep(float(taken.t[taken.rows - 1]))  # run.keep: the oldest closed segments removed
        if files.npz and trajectory and (files.npz_dirty or files.npz_rows != taken.rows):
            t0 = time.monotonic()
            files.write_trajectory()
            self.npz_next = time.monotonic() + (time.monotonic() - t0) * (1 - _NPZ_DUTY) / _NPZ_DUTY
        with self._lock:
            self.rows_kept = min(files.kept_rows, files.rrd_rows) if sink is not None else files.kept_rows

    def _batch(self, ks: np.ndarray, err: np.ndarray, show: np.ndarray) -> RowBatch:
        """Rows ``ks`` (taken) as the sink logs them."""
        taken = self.rows
        return RowBatch.of(seq=taken.tau[ks], t=taken.t[ks], wall=taken.wall[ks], x=taken.x[ks], xhat=taken.xhat[ks],
                           err=err, show=show,
                           shown=taken.shown[ks], shown_max=taken.shown_max[ks],
                           env=taken.envelope(ks, self.envelope_rate, self.time_mode), rounds=taken.round[ks],
                           columns={c.name: getattr(taken, c.name)[ks] for c in REPORTED})

    def salvage(self) -> None:
        """After a write failure and the last flush: make the rows on disk agree (:meth:`RecordFiles.salvage`)."""
        self.rows_kept = self.files.salvage()

    def finish(self, finished: bool) -> None:
        """The records' end, after the last flush: ``run.rrd`` finished (after a write failure first, with fewer
        rows if its rewrite does not fit, so that the close event states what all three records hold) and the
        last event, ``recording_closed`` with ``finished`` and ``rows`` (:attr:`rows_kept`)."""
        failure = self.failure.error
        kept = self.rows_kept
        ok = bool(finished) and failure is None
        if failure is not None:
            kept = self.rows_kept = self.files.finish_rrd_fitting(kept)
        fields: dict[str, Any] = {"finished": ok, "rows": kept}
        last = kept - 1 - self.rows.base  # the row kept - 1 in the rows held (a run until stopped holds a window)
        t = float(self.rows.t[last]) if kept and 0 <= last < self.rows.rows else (
            float(self.rows.t[self.rows.rows - 1]) if self.rows.rows else 0.0)
        if failure is not None:
            fields["error"] = str(failure)
            try:
                self.events.write("recording_closed", t, time.time(), fields)
            except OSError as exc:
                self.failure.fail(self.events.path, exc, None)
        else:
            self._close_event(t, "INFO" if ok else "WARN", fields)
            self.files.finish_rrd(kept)

    def _close_event(self, t: float, level: str, fields: dict[str, Any]) -> None:
        """The last event, ``recording_closed``: to ``events.jsonl`` and ``run.rrd`` if they can take it."""
        tau = self.tau_of_t(t)
        try:
            self.events.write("recording_closed", t, time.time(), fields)
        except OSError as exc:
            self.failure.fail(self.events.path, exc, tau)
        sink = self.sink
        if sink is not None:
            text = event_text("recording_closed", fields)
            sink.guarded("event log", sink.send_events, [TextLine(tau, t, text, level, time.time_ns())])
            try:
                self.files.append_rrd()
            except RecordsWriteError:
                pass

    def send_after_run(self) -> None:
        """At the close, after the last flush: what a run on measurements logs after the run (the Kalman filter)."""
        self.meas.send_after_run(self.sink)

    def disconnect(self) -> None:
        """Drop the Rerun sink (at the close): nothing more goes to Rerun."""
        if self.sink is not None:
            self.sink.disconnect()
            self.files.sink = None
