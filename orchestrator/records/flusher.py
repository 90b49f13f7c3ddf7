"""The recorder's buffer and its flushes: what the callers recorded and no flush wrote yet, and when it is written.

A :class:`~splitspec_orchestrator.records.recorder.Recorder` checks each call and stores what it is given in
its :class:`Flusher`: the rows recorded (a :class:`~splitspec_orchestrator.records.rowstore.RowStore`), which of
them a flush took, the consensus messages that did not count, and the Rerun logs deferred to the next flush
(:class:`~splitspec_orchestrator.viewer.handoff.DeferredLogs`, in call order).  A flush takes what was
recorded since the last one (:meth:`Flusher.take`) and has the recorder's
:class:`~splitspec_orchestrator.records.writer.RecordWriter` write it out.

Buffering and the background thread: :meth:`Recorder.row`,
:meth:`Recorder.event` and :meth:`Recorder.topology` -- the calls of the
orchestrator's round loop -- only store what they are given in memory, under
a lock held for that alone (a few microseconds; ``event`` also appends its
line to ``events.jsonl``).  Everything else is a flush, and with
``flush_seconds > 0`` (the orchestrator's 1 s) every flush but the explicit
ones runs on the recorder's background thread (:func:`_watch`): it wakes when
``flush_seconds`` of wall time have passed since the last flush and
something is pending (so a live viewer is never more than about
``flush_seconds`` behind, even when rows stop coming), and at once when
:meth:`Recorder.mark_lost` asks for a flush of every row recorded so far.  A
flush takes what was recorded since the last one under the lock (memory
copies of those rows only), releases it, and then -- while the callers go on
recording -- sends the rows to Rerun (one ``send_columns`` chunk per entity
per flush, per 512 rows after a burst; an agent's chunks hold only the event
times where it is shown; the viewer still draws a retracted value as a lone
point beside the NaN or Clear that retracts it, both being rows at that time),
then the queued logs of ``event``/``topology``/``mark_lost`` (one chunk per
flush each) and, drawn over the topology, the rows' consensus messages that did
not count (``topology/lost``, ``topology/status``: one chunk each), appends what Rerun encoded to ``run.rrd``
(fsynced) and rewrites ``trajectory.npz`` (fsynced) -- the whole file, so on a long run
(tens of MB) the background thread skips that rewrite at the flushes that
come sooner than 9 times its last duration after it: at most a tenth of its
time goes to it (every flush up to some 10^4 rows at m = 32, n = 6).  So no Rerun call, no ``run.rrd`` or
``trajectory.npz`` write and no fsync happens in the caller's thread, except
in :meth:`Recorder.flush` (explicit: it waits for a background flush under
way, then flushes), :meth:`Recorder.close`, at a normal interpreter exit
without ``close`` (:func:`_flush_open_recorders`, which also finishes ``run.rrd`` with its footer, but
writes no ``recording_closed`` event), and with ``flush_seconds=0``, a
write-through mode for tests where every call flushes before it returns and
no background thread runs.  Values that were never sent need no ``Clear``: a
row re-sent or an agent lost before the flush simply changes what is sent.
"""

from __future__ import annotations

import atexit
import logging
import threading
import time
import weakref

import numpy as np

from splitspec_core.model.rows import REPORTED

from ..viewer.handoff import DeferredLogs, lost_rows
from .files import RecordsWriteError, WriteFailure
from .outdir import Reserve
from .rowstore import RowStore
from .writer import RecordWriter

__all__ = ["Flusher"]

log = logging.getLogger(__name__)

# Flushers of recorders not closed yet: flushed at interpreter exit (and when their recorder is dropped, see
# Recorder.__del__), so a normal exit without close() loses no buffered row.  The handler is registered after
# rerun is imported (which registers Rerun's shutdown) so that, atexit being last-in first-out, it runs before
# that shutdown.
_OPEN: "weakref.WeakSet[Flusher]" = weakref.WeakSet()
_exit_flush_registered = False


def _register_exit_flush() -> None:
    global _exit_flush_registered
    if not _exit_flush_registered:
        atexit.register(_flush_open_recorders)
        _exit_flush_registered = True


def _flush_open_recorders() -> None:
    for f in list(_OPEN):
        try:
            with f.io, f.lock:  # waits for a background flush under way
                if not f.closed and f.failure.error is None:
                    f.flush(final=True)  # the last flush: a mark still waiting for its row goes too
                    f.close()  # nothing is recorded after this
                    # run.rrd with its footer, as a Rerun FileSink would leave it
                    f.writer.files.finish_rrd(f.writer.rows_kept)
                    f.reserve.release()
        except Exception as exc:
            log.warning("flush at exit failed (%s: %s)", type(exc).__name__, exc)


class Flusher:
    """What one recorder's callers recorded, and its flushes (see the module docstring).

    Two locks, always taken in this order: ``io`` (one flush at a time; the rows taken, the Rerun sink and the
    files: the ``writer``'s), then ``lock`` (what the callers record; held for memory work only).  The
    recorder's calls hold ``lock`` when they call :meth:`store`, :meth:`lose` or queue in :attr:`logs`.

    Parameters
    ----------
    rows : the rows recorded (under ``lock``)
    writer : writes what a flush takes
    failure : the recorder's first write failure
    reserve : the disk-space reserve (released at the exit flush)
    io, lock : the recorder's two locks
    lost : ``{tau: rows (tau, k, j, i, cause)}`` of the consensus messages that did not count (the recorder's)
    flush_seconds : period of the background flushes; ``0``: none, every call flushes (:meth:`write_through`)
    started : ``time.monotonic()`` when the recorder started (the first background flush comes
        ``flush_seconds`` after it)
    window : None: hold every row; a number: once more than twice this many rows are held, forget the oldest
        written ones down to this many (:meth:`trim`; a run that goes on until stopped)
    """

    def __init__(self, rows: RowStore, writer: RecordWriter, failure: WriteFailure, reserve: Reserve, *,
                 io: threading.RLock, lock: threading.RLock, lost: dict, flush_seconds: float, started: float,
                 window: int | None = None):
        self.window = None if window is None else max(1, int(window))
        self.rows, self.writer, self.failure, self.reserve = rows, writer, failure, reserve
        self.io, self.lock = io, lock
        self.lost = lost
        self.flush_seconds = flush_seconds
        # Buffer: rows taken.. of rows were never taken by a flush; changed holds taken rows that changed since
        # (re-sent tau, agent lost): taken and sent again whole.  logs: the deferred Rerun logs of the recorder's
        # event() / topology() / mark_lost(), in call order.  request: a flush of the first request rows asked
        # for (mark_lost).
        self.taken = 0
        self.changed: set[int] = set()
        self.logs = DeferredLogs()
        self.request: int | None = None
        self.last_flush = started
        self.closed = False
        self.fence = None  # () -> bool: another process holds these records now (a standby took the run over)
        _OPEN.add(self)
        _register_exit_flush()
        self.stop = threading.Event()
        self.wake = threading.Event()
        self.watcher = None
        if flush_seconds > 0:  # with 0 every call flushes itself: nothing is left waiting
            self.watcher = threading.Thread(target=_watch, args=(weakref.ref(self), self.stop, self.wake),
                                            name="splitspec-recorder-flush", daemon=True)
            self.watcher.start()

    def close(self) -> None:
        """Nothing is recorded or flushed after this but the recorder's own last flush: stop the background
        thread.  ``lock`` held."""
        self.closed = True
        self.stop.set()
        self.wake.set()
        _OPEN.discard(self)

    def finish(self, finished: bool) -> None:
        """The recording's end, after :meth:`close` (``io`` and ``lock`` held): the last flush, then the records'
        end (:meth:`RecordWriter.finish`; after a write failure, with the reserve released first, what the
        failure left unwritten and the rows on disk made to agree); the Rerun sink dropped."""
        try:
            if self.failure.error is None:
                try:
                    self.flush(final=True)
                except RecordsWriteError:
                    pass
                self.writer.send_after_run()
            if self.failure.error is not None:
                self.reserve.release()  # room for the final records
                self.salvage()
            self.writer.finish(finished)  # run.rrd finished, the recording_closed event
        finally:
            self.reserve.release()
            self.writer.disconnect()

    def salvage(self) -> None:
        """After a write failure: write what is left, then make the rows on disk agree
        (:meth:`RecordWriter.salvage`).  Never raises."""
        try:
            self.flush(final=True)
        except RecordsWriteError:
            pass
        self.writer.salvage()

    # ------------------------------------------------------------------ what the callers record (lock held)

    def store(self, tau: int, t: float, x: np.ndarray, xhat: np.ndarray, alive: np.ndarray, graph: int,
              columns: dict, diag: list) -> None:
        """Row of event time ``tau`` (a new one, after the last; or a re-sent one, which replaces it): dead agents'
        values NaN (the reported ``columns``' fill); ``diag`` the round's diagnostics."""
        recorded = self.rows
        k = recorded.row_of_tau.get(tau)
        if k is None:
            k = recorded.append_slot(tau)
        elif k < self.taken:
            self.changed.add(k)  # already taken by a flush: take and send the whole row again (newest wins)
        recorded.t[k] = t
        recorded.x[k] = x
        recorded.xhat[k] = np.where(alive[:, None], xhat, np.nan)
        recorded.alive[k] = alive
        recorded.graph[k] = int(graph)
        for c in REPORTED:
            getattr(recorded, c.name)[k] = np.where(alive, columns[c.name], c.fill)
        recorded.round[k] = diag
        recorded.wall[k] = time.time_ns()

    def lose(self, tau: int, i: int, agent_id: int, t: float) -> None:
        """Agent ``agent_id`` (column ``i``) lost from event time ``tau`` (time ``t``) on: NaN/False in every
        recorded row from ``tau`` on, its consensus messages forgotten there, its series cleared at ``tau``; a
        flush of every row recorded so far is asked for (:meth:`flush_soon`)."""
        recorded = self.rows
        T = recorded.rows
        for k in np.nonzero(recorded.tau[:T] >= tau)[0]:
            if not recorded.alive[k, i]:
                continue
            recorded.alive[k, i] = False
            recorded.xhat[k, i] = np.nan
            for c in REPORTED:
                getattr(recorded, c.name)[k, i] = c.fill
            if k < self.taken:
                self.changed.add(int(k))
        if self.writer.sink is not None:
            self.logs.loss(tau, t, agent_id)
        for t_, lost in list(self.lost.items()):  # a dead agent sends and receives nothing from tau on
            if t_ >= tau:
                kept = tuple(r for r in lost if agent_id not in (r[2], r[3]))
                if len(kept) != len(lost):
                    self.lost[t_] = kept
                    k = recorded.row_of_tau.get(t_)
                    if k is not None:  # rounds/lost counts what trajectory.npz keeps
                        recorded.round[k, 3] = len(kept)
                        if k < self.taken:
                            self.changed.add(int(k))
        self.request = T

    # ------------------------------------------------------------------ flushes

    def flush_soon(self) -> None:
        """The flush :meth:`lose` asked for: of the background thread (now, in this call, with
        ``flush_seconds=0``).  Called without ``lock`` held."""
        if self.flush_seconds == 0:
            self.write_through()
        else:
            self.wake.set()

    def write_through(self) -> None:
        """``flush_seconds=0``: flush in the caller's thread after every call.  Otherwise nothing: the
        background thread flushes.  Called without ``lock`` held (the locks are taken ``io`` first)."""
        if self.flush_seconds == 0:
            with self.io:
                with self.lock:
                    self.failure.check()
                    if self.closed:
                        return
                self.flush()

    def pending(self) -> bool:
        """Something recorded that no flush took or wrote yet (``trajectory.npz`` included).  ``io`` and
        ``lock`` held."""
        return (self.taken < self.rows.rows or bool(self.changed) or bool(self.logs)
                or self.request is not None or self.writer.pending)

    def grow_ahead(self) -> None:
        """Background thread: double the recorded rows' storage before a caller's row fills it.  The new
        columns are allocated and touched outside ``lock`` (fresh memory is slow: ~0.2 s for the 50 MB of
        32768 rows at m = 32, n = 6 on the 2-core dev VM); only the copy of the rows is under it."""
        cap = self.rows.capacity
        if self.rows.rows <= cap * 3 // 4:
            return
        spare = self.rows.spare(2 * cap)
        with self.lock:
            if self.rows.capacity == cap:  # no caller grew it meanwhile
                self.rows.adopt(spare)

    def background_flush(self) -> bool:
        """One turn of :func:`_watch`: flush if due or asked for.  False when the recorder is closed."""
        with self.io:
            self.grow_ahead()
            self.writer.rows.reserve(self.rows.rows)  # any growth of the taken rows outside lock
            with self.lock:
                if self.closed or self.failure.error is not None:
                    return False  # the recording has stopped: close() writes what is left
                if self.fence is not None and self.fence():  # another orchestrator holds the records now
                    self.closed = True
                    return False
                upto = self.request
                if upto is None:
                    if time.monotonic() - self.last_flush < self.flush_seconds:
                        return True
                    if not self.pending():
                        self.last_flush = time.monotonic()  # idle: look again in flush_seconds
                        return True
                taken = self.take(upto)
            try:
                self.writer.write(*taken, trajectory=upto is not None or time.monotonic() >= self.writer.npz_next)
            except RecordsWriteError:  # stored: the next recorder call raises it
                with self.lock:
                    self.failure.reported = False
            except Exception as exc:
                log.warning("background flush failed (%s: %s)", type(exc).__name__, exc)
            else:
                self.trim()
        return True

    def trim(self) -> None:
        """A run that goes on until stopped (``window``): once more than ``2 window`` rows are held, forget the
        oldest down to ``window`` -- only rows a flush took and wrote, and none changed since -- in both the rows
        recorded and the rows taken (same indices), with their consensus messages that did not count.  ``io``
        held, right after a successful write."""
        W = self.window
        if W is None:
            return
        with self.lock:
            recorded, taken_rows = self.rows, self.writer.rows
            if recorded.rows <= 2 * W:
                return
            d = min(recorded.rows - W, self.taken, min(self.changed, default=self.taken))
            if d <= 0:
                return
            recorded.drop(d)
            taken_rows.drop(d)
            self.taken -= d
            self.changed = {k - d for k in self.changed}
            if self.request is not None:
                self.request = max(0, self.request - d)
            first = int(recorded.tau[0]) if recorded.rows else None
            for tau in [t for t in self.lost if first is None or t < first]:
                del self.lost[tau]
            if first is not None:
                self.writer.meas.forget_before(first)

    def flush(self, *, final: bool = False) -> None:
        """Take what was recorded (under ``lock``, memory only), then write it out (``io`` held, not ``lock``).

        ``final``: the recording's last flush (close, exit, salvage): marks whose row never came are
        written too.  The writes: :meth:`RecordWriter.write`.

        Raises
        ------
        RecordsWriteError
            If ``run.rrd`` or ``trajectory.npz`` cannot be written.
        """
        with self.io:
            self.writer.rows.reserve(self.rows.rows)  # any growth of the taken rows outside lock
            with self.lock:
                taken = self.take(None, final=final)
            self.writer.write(*taken)
            if not final:
                self.trim()

    def take(self, upto: int | None, *, final: bool = False) -> tuple:
        """Copy the rows recorded since the last flush (and changed ones) into the taken rows; take the
        queued logs.  ``io`` and ``lock`` held; no I/O, O(rows taken) work."""
        self.last_flush = time.monotonic()
        recorded = self.rows
        T = recorded.rows if upto is None else max(min(int(upto), recorded.rows), self.taken)
        changed = np.array(sorted(self.changed), dtype=np.int64)  # all below taken
        ks = np.concatenate([changed, np.arange(self.taken, T, dtype=np.int64)])
        if len(ks):
            self.writer.take(recorded, self.taken, T, changed)
        self.taken = T
        self.changed.clear()
        if self.request is not None and self.request <= T:
            self.request = None
        # a mark stands at the height of its own row's max error: one whose row is not taken yet (the
        # topology of tau arrives before its row) waits for the next flush (close() takes them all)
        logs = self.logs.take(int(recorded.tau[T - 1]) if T else None, final=final)
        lost = lost_rows(recorded.tau, recorded.t, recorded.wall, ks, self.lost) \
            if self.writer.sink is not None and self.lost else []
        return ks, logs, lost


def _watch(ref: "weakref.ref[Flusher]", stop: threading.Event, wake: threading.Event) -> None:
    """The background flusher: every flush of a recorder with ``flush_seconds > 0`` but the explicit ones.

    Flushes when ``flush_seconds`` have passed since the last flush and something is pending, and at
    once when a flush is asked for (:meth:`Flusher.flush_soon` sets ``wake``).  The recorder's
    callers only ever wait for it on ``lock``, held for the memory part of a flush (:meth:`Flusher.take`).
    """
    while True:
        f = ref()
        if f is None:
            return
        wait = 0.0 if f.request is not None else max(0.01, f.last_flush + f.flush_seconds - time.monotonic())
        del f  # no strong reference while waiting
        wake.wait(wait)
        wake.clear()  # a request set meanwhile is still in f.request: seen on the next turn
        if stop.is_set():
            return
        f = ref()
        if f is None:
            return
        try:
            if not f.background_flush():
                return
        finally:
            del f
