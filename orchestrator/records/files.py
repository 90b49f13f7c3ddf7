"""The recorder's two files of rows on disk: ``trajectory.npz`` rewritten, ``run.rrd`` appended and finished.

:class:`RecordFiles` writes what a :class:`~splitspec_orchestrator.records.recorder.Recorder` flush took and
knows how many rows each file holds on disk:

``trajectory.npz``
    rewritten whole and atomically by :func:`splitspec_core.simulation.trajectory_file.write_trajectory` (temporary file
    in ``out_dir``, fsynced, ``os.replace``) with the first rows taken, their consensus messages that did
    not count (``lost``, ``lost_cause``) and, on measurements, the arrays of
    :meth:`splitspec_orchestrator.records.measured.MeasuredRecords.arrays`
    (:meth:`RecordFiles.write_trajectory`);
``run.rrd``
    appended with what Rerun encoded since the last flush (:meth:`RecordFiles.append_rrd`, through the
    :class:`~splitspec_orchestrator.viewer.sink.RerunSink`; the format in :mod:`splitspec_orchestrator.viewer.rrd_file`)
    and, at the close, rewritten as one verifiable RRD, cut after the K-th row after a write failure
    (:meth:`RecordFiles.finish_rrd`).

After a write failure the two files are made to agree on K rows, as far as the disk allows:
:meth:`RecordFiles.salvage` (the rows both hold, ``trajectory.npz`` cut to them),
:meth:`RecordFiles.finish_rrd_fitting` (fewer rows, a tenth less each try, when the rewrites do not
fit on a full disk) and :meth:`RecordFiles.cut_trajectory`.  When to write, in which order, and what a
failure stops are :mod:`splitspec_orchestrator.records.writer`'s ("Write failures and consistency"); a
failed write is reported to the recorder's :class:`WriteFailure`, which keeps the first one and gives the
:class:`RecordsWriteError` to raise.  What the files hold: docs/reference/files.md, sections "Trajectory
file" and "Rerun recording".
"""

from __future__ import annotations

import errno
import logging
import os
import threading
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np

from splitspec_core.errors import SplitspecError
from splitspec_core.model.rows import COLUMNS, REPORTED
from splitspec_core.simulation.trajectory_chunks import ChunkWriter
from splitspec_core.simulation.trajectory_file import TRAJECTORY_FILE, lost_arrays, write_trajectory

from ..viewer.sink import RRD_FILE, RerunSink
from .rowstore import RowStore

__all__ = ["RecordFiles", "RecordsWriteError", "WriteFailure", "Continuous"]

log = logging.getLogger(__name__)


class RecordsWriteError(SplitspecError, RuntimeError):
    """A record of the run (``trajectory.npz``, ``events.jsonl``, ``run.rrd``) could not be written.

    One line, ``cannot write <path>: <strerror>``.  Attributes: ``path``,
    ``strerror`` (e.g. ``No space left on device``) and ``tau``, the event time
    being recorded when the write failed (None if unknown).
    """

    def __init__(self, path: str | Path, strerror: str, tau: int | None = None):
        self.path, self.strerror, self.tau = Path(path), str(strerror), tau
        super().__init__(f"cannot write {self.path}: {self.strerror}")


def strerror(exc: OSError) -> str:
    """The reason of a failed write, as :class:`RecordsWriteError` states it."""
    if exc.strerror:
        return exc.strerror
    if exc.errno:
        return os.strerror(exc.errno)
    return str(exc) or type(exc).__name__


class WriteFailure:
    """The first failed write of a recorder's records (the recording stops at it), and whether a caller has
    seen it (raised to it); shared by the recorder, its :class:`~splitspec_orchestrator.records.writer.RecordWriter`
    and its :class:`RecordFiles`."""

    def __init__(self, lock: threading.RLock):
        self._lock = lock  # the recorder's _lock
        self.error: RecordsWriteError | None = None
        self.reported = False

    def fail(self, path: Path, exc: OSError, tau: int | None) -> RecordsWriteError:
        """The :class:`RecordsWriteError` of ``exc``; the first one is kept (the recording stops)."""
        err = RecordsWriteError(path, strerror(exc), tau)
        with self._lock:
            if self.error is None:
                self.error = err
                log.info("recording stopped: %s", err)  # the driver prints the one line
            self.reported = True  # raised to the caller (the background flusher resets this)
        return err

    def check(self) -> None:
        """After a write failure the recording has stopped: every recorder call raises it again."""
        if self.error is not None:
            self.reported = True
            raise self.error


def _fewer(kept: int) -> int:
    """The rows of the next try of :meth:`RecordFiles.finish_rrd_fitting`: a tenth less (at least one less, at
    least one row)."""
    return max(1, kept - max(1, kept // 10))


@dataclass(frozen=True)
class Continuous:
    """How a run that goes on until stopped keeps its records bounded (docs/reference/files.md, "Runs until
    stopped"): ``window_rows`` rows held in memory (at most about twice as many), a new chunk segment past
    ``chunk_bytes``, ``run.rrd`` rolled to ``run-0001.rrd`` ... past ``rrd_bytes``.  :meth:`from_env` reads
    ``SPLITSPEC_WINDOW_ROWS``, ``SPLITSPEC_CHUNK_MB`` and ``SPLITSPEC_RRD_ROLL_MB`` (defaults 1024, 64, 256; the
    segment sizes ``run.keep.segment_mb`` when the scenario gives it, the variables overriding it); ``keep_hours``
    and ``keep_bytes`` are ``run.keep``'s (:mod:`.retention`)."""

    window_rows: int = 1024
    chunk_bytes: int = 64 << 20
    rrd_bytes: int = 256 << 20
    keep_hours: float | None = None  # run.keep.hours (records.retention)
    keep_bytes: int | None = None  # run.keep.gigabytes, in bytes
    keep_recording_hours: float | None = None  # run.keep.recording_hours (None: keep_hours)

    @classmethod
    def from_env(cls, run=None) -> "Continuous":
        segment_mb = getattr(run, "keep_segment_mb", None)  # run.keep.segment_mb: both kinds of segment

        def mb(name: str, default: int) -> int:
            given = default if segment_mb is None else segment_mb
            try:
                return max(1 << 16, int(float(os.environ.get(name, given)) * (1 << 20)))
            except ValueError:
                return int(given * (1 << 20))

        try:
            window = max(16, int(os.environ.get("SPLITSPEC_WINDOW_ROWS", 1024)))
        except ValueError:
            window = 1024
        keep_hours = getattr(run, "keep_hours", None)
        gigabytes = getattr(run, "keep_gigabytes", None)
        return cls(window, mb("SPLITSPEC_CHUNK_MB", 64), mb("SPLITSPEC_RRD_ROLL_MB", 256), keep_hours,
                   None if gigabytes is None else int(gigabytes * 1e9), getattr(run, "keep_recording_hours", None))


class RecordFiles:
    """``trajectory.npz`` and ``run.rrd`` of one recorder, and the rows each holds on disk.

    Parameters
    ----------
    out_dir : directory of the run
    agent_ids : agent ids in the scenario's order
    taken : the rows taken by the recorder's flushes (its writer's ``rows``; everything here runs under its ``_io``)
    lost : ``{tau: rows (tau, k, j, i, cause)}`` of the consensus messages that did not count (the recorder's)
    extra : ``extra(T)``, the further arrays of a ``trajectory.npz`` with the first ``T`` rows
    failure : the recorder's :class:`WriteFailure`
    sink : the recorder's :class:`RerunSink`, None without Rerun (and once the recorder has dropped it)
    states : the states' names (``trajectory.npz``'s ``states``)
    y_rows : ``y_rows(taus)``: ``(y, y_missing)`` of those event times on measurements or live sensors, else None
    u_rows : ``u_rows(taus)``: ``u`` (L, p) of those event times with known inputs, else None
    continuous : None: keep ``trajectory.npz`` (rewritten); else a run until stopped, whose rows are only in the
        chunks (segments of ``continuous.chunk_bytes``)
    dt : the sampling step (1 in discrete time)
    """

    def __init__(self, out_dir: Path, *, agent_ids: np.ndarray, taken: RowStore, lost: dict,
                 extra: Callable[[int], dict], failure, sink: RerunSink | None, states: tuple = (),
                 y_rows: Callable | None = None, continuous: Continuous | None = None, dt: float = 1.0,
                 u_rows: Callable | None = None):
        self.out_dir = out_dir
        self.npz = continuous is None
        self._chunk_bytes = (continuous or Continuous()).chunk_bytes
        self._y_rows = y_rows
        self._u_rows = u_rows
        self.chunks: ChunkWriter | None = None  # made at the first append (the width of y is known then)
        self._dt = float(dt)
        self.chunk_rows = 0  # rows (counted from the run's first) the chunks hold on disk
        self.states = tuple(states)
        self.agent_ids = agent_ids
        self._d = taken
        self._lost = lost
        self._extra = extra
        self._failure = failure
        self.sink = sink
        self.rrd_path = out_dir / RRD_FILE
        self.npz_rows = 0  # rows trajectory.npz holds on disk
        self.rrd_rows = 0  # rows run.rrd holds on disk (counted from the run's first, like chunk_rows)
        self.npz_dirty = False  # rows taken since trajectory.npz was last written (under the recorder's _io)

    def last_tau(self) -> int | None:
        """The event time of the last row taken by a flush (what a failed write was writing)."""
        return int(self._d.tau[self._d.rows - 1]) if self._d.rows else None

    def append_rrd(self) -> None:
        """Read what Rerun encoded since the last call and append it (and anything left over) to ``run.rrd``."""
        if self.sink is None:
            return
        taken = self._d.rows
        self.sink.read_pending()
        try:
            self.sink.write_pending()
        except OSError as exc:
            raise self._failure.fail(self.rrd_path, exc, self.last_tau()) from None
        self.rrd_rows = self._d.base + taken

    def append_chunk(self, ks: np.ndarray) -> None:
        """Append the taken rows ``ks`` (and the consensus messages of their event times that did not count) to the
        chunks, one record batch (:class:`~splitspec_core.simulation.trajectory_chunks.ChunkWriter`)."""
        taken = self._d
        if len(ks):
            taus = taken.tau[ks]
            ys = self._y_rows(taus) if self._y_rows is not None else None
            us = self._u_rows(taus) if self._u_rows is not None else None
            if self.chunks is None:
                self.chunks = ChunkWriter(self.out_dir, agent_ids=self.agent_ids, states=self.states, n=taken.n,
                                          dt=self._dt, p=0 if ys is None else ys[0].shape[1],
                                          segment_bytes=self._chunk_bytes, inputs=0 if us is None else us.shape[1])
            cols = {c.name: getattr(taken, c.name)[ks] for c in COLUMNS}  # the row schema's (tau, t, x, xhat, ...)
            cols["lost"] = [[r[1:] for r in self._lost.get(int(tau), ())] for tau in taus.tolist()]
            if ys is not None and self.chunks.p:
                cols["y"], cols["y_missing"] = ys
            if us is not None and self.chunks.inputs:
                cols["u"] = us
            try:
                self.chunks.append(cols)
            except OSError as exc:
                path = self.chunks.path or self.out_dir / "chunks"
                raise self._failure.fail(path, exc, int(taus.max())) from None
        self.chunk_rows = taken.base + taken.rows

    def write_trajectory(self, rows: int | None = None) -> None:
        """Atomically (re)write ``trajectory.npz`` with the first ``rows`` rows taken (default: all); nothing
        for a run until stopped (no ``trajectory.npz``: its rows are in the chunks)."""
        taken = self._d
        if not self.npz:
            self.npz_dirty = False
            return
        T = taken.rows if rows is None else rows
        path = self.out_dir / TRAJECTORY_FILE
        try:
            last = int(taken.tau[T - 1]) if T else -1
            lost, cause = lost_arrays([r for tau, rows in list(self._lost.items()) if tau <= last for r in rows])
            write_trajectory(path, t=taken.t[:T], x=taken.x[:T], xhat=taken.xhat[:T], alive=taken.alive[:T],
                             graph=taken.graph[:T],
                             agent_ids=self.agent_ids, columns={c.name: getattr(taken, c.name)[:T] for c in REPORTED},
                             lost=lost, lost_cause=cause,
                             extra=self._extra(T), states=self.states or None)
        except OSError as exc:
            raise self._failure.fail(path, exc, int(taken.tau[T - 1]) if T else None) from None
        self.npz_rows = T
        if T == taken.rows:
            self.npz_dirty = False

    @property
    def kept_rows(self) -> int:
        """Rows of the record of rows on disk: ``trajectory.npz``'s, or the chunks' for a run until stopped."""
        return self.npz_rows if self.npz else self.chunk_rows

    def _tau(self, kept: int) -> int | None:
        """The event time of the run's row ``kept - 1`` if it is held (a run until stopped holds a window)."""
        k = kept - 1 - self._d.base
        return int(self._d.tau[k]) if 0 <= k < self._d.rows else None

    def salvage(self) -> int:
        """After a write failure and the last flush: make the rows on disk agree.  Never raises.

        Returns the rows kept: all rows if ``run.rrd`` and ``trajectory.npz`` could be written, else the rows both hold
        on disk (``trajectory.npz`` is cut to them if it holds more and can be rewritten).
        """
        if not self.npz:  # a run until stopped: the chunks are never cut (append only), run.rrd is
            return min(self.rrd_rows, self.chunk_rows) if self.sink is not None else self.chunk_rows
        if self.sink is None:
            return self.npz_rows
        kept = min(self.rrd_rows, self.npz_rows)
        if self.npz_rows > kept:
            try:
                self.write_trajectory(kept)
            except RecordsWriteError:
                kept = self.npz_rows  # cannot cut it: run.rrd is cut to the trajectory's rows instead
        return kept

    def finish_rrd_fitting(self, kept: int) -> int:
        """After a write failure: finish ``run.rrd`` and cut ``trajectory.npz`` to ``kept`` rows, or to fewer (a tenth
        less each try) when the rewrites do not fit on the full disk.  The trajectory is cut first: a shorter
        trajectory frees room for the rrd's rewrite.  Returns the rows kept (what the close event states)."""
        if self.sink is None or kept == 0 or not self.npz:
            self.finish_rrd(kept)
            return kept
        for _ in range(40):
            if kept != self.npz_rows and not self.cut_trajectory(kept):
                if kept <= 1:
                    break
                kept = _fewer(kept)
                continue
            try:
                self.sink.finish(int(self._d.tau[kept - 1]) + 1)
            except OSError as exc:
                if exc.errno != errno.ENOSPC or kept <= 1:
                    self._failure.fail(self.rrd_path, exc, int(self._d.tau[kept - 1]))
                    break
                kept = _fewer(kept)
                continue
            break
        return min(kept, self.npz_rows)

    def cut_trajectory(self, kept: int) -> bool:
        """After a write failure: cut ``trajectory.npz`` to its first ``kept`` rows.  The atomic rewrite needs room
        for both files; when that room is gone, the longer file (whose rows are all in memory) is removed
        first and the shorter one written in its place.  True when ``trajectory.npz`` holds ``kept`` rows."""
        try:
            self.write_trajectory(kept)
            return True
        except RecordsWriteError:
            pass
        try:
            (self.out_dir / TRAJECTORY_FILE).unlink(missing_ok=True)
            self.npz_rows = 0
            self.write_trajectory(kept)
            return True
        except (OSError, RecordsWriteError):
            return False

    def finish_rrd(self, kept: int) -> None:
        """Rewrite ``run.rrd`` as one verifiable RRD; cut after row ``kept - 1`` if a write failed."""
        if self.sink is None:
            return
        cutoff = None
        if self._failure.error is not None or kept < self._d.base + self._d.rows:
            tau = self._tau(kept)
            cutoff = 0 if not kept else (tau + 1 if tau is not None else None)
        try:
            self.sink.finish(cutoff)
        except OSError as exc:
            self._failure.fail(self.rrd_path, exc, self._tau(kept))
