"""Run recorder of the orchestrator: ``trajectory.npz``, ``events.jsonl`` and ``run.rrd``.

The orchestrator hands the recorder one row per event time ``tau`` (true state
``x(tau)``, every agent's estimate ``x_i(tau)``, the alive set and the active
graph), the topology on every switch or death, and named events.  The recorder
keeps three records of the run in ``out_dir``:

``trajectory.npz``
    the trajectory contract of DESIGN.md ("Trajectories"): ``t`` (T,),
    ``x`` (T, n), ``xhat`` (T, m, n) NaN where dead, ``alive`` (T, m) bool,
    ``graph`` (T,) int, ``agent_ids`` (m,), and ``g`` (T, m) (each agent's
    gain, NaN where dead or none).  Rewritten atomically (temporary
    file in ``out_dir``, fsynced, + ``os.replace``) at every flush (see below)
    and always in :meth:`Recorder.close`, so after a crash it holds every row
    up to the last flush.
``events.jsonl``
    one JSON object per line, ``{"event", "t", "wall", **fields}``, written
    and flushed (not fsynced) by :meth:`Recorder.event` itself, line by line.
``run.rrd``
    a Rerun recording (DESIGN.md "Rerun recording"), optionally streamed live
    to a viewer as well; appended by Python at every flush and finished (footer,
    verifiable) at close, see "Write failures and consistency" below.

This module keeps the coordination: :class:`Recorder` buffers what its callers
record, flushes it on a background thread, orders the writes, stops at the first
write failure (:class:`WriteFailure`), salvages and closes.  Its collaborators do
the rest: :mod:`splitspec_orchestrator.records.rowstore` (the rows and what each shows),
:mod:`splitspec_orchestrator.records.files` (``trajectory.npz`` rewritten through
:func:`splitspec_core.simulation.trajectory_file.write_trajectory`, the one writer shared with
``simulate``; ``run.rrd`` appended and finished; the cuts after a failure),
:mod:`splitspec_orchestrator.records.measured` (what a run on measurements or live
sensors records beyond the rows), :mod:`splitspec_orchestrator.recording.sink` (the
Rerun stream; entity paths and the default blueprint in
:mod:`splitspec_orchestrator.recording.blueprint`) and :mod:`splitspec_orchestrator.records.events`
(``events.jsonl`` and each event's sentence).  Why one module: the buffer, the two
locks, the background flusher and the close are one invariant (the three files
agree on K rows, and no caller of the round loop waits for a write) that is easier
to check in one place than spread over modules.

Timelines: ``event`` (sequence ``tau``), ``time`` (duration: ``tau`` seconds
in discrete time, ``tau * dt`` in continuous time) and ``wall`` (timestamp).
A value that stops being true (an agent lost from ``tau`` on after its rows
were logged, or a row re-sent for the same ``tau`` without an agent) is
retracted with a non-recursive ``rr.Clear`` at that event time (in the
per-component state batches ``state/<k>/agents``, by re-sending the row with NaN
for that agent); and a loss gets an explicit Clear of every series of the agent
alone at the loss itself, which breaks the agent's lines in the time-series
views (its state lines break at the NaN of the rows where it is dead).

The designed envelope (``errors_log10/envelope``) is computed row by row, as a
live recording can: it restarts at a row whose alive set gains an agent or
whose graph changed (:func:`splitspec_core.simulation.metrics.envelope_restarts`), from
the max error there, and decays as ``c lam^(tau - tau0)`` (discrete) or ``c
exp(-lam (t - t0))`` (continuous); none with the adaptive gain
(``envelope_rate=None``).

Buffering and the background thread: :meth:`Recorder.row`,
:meth:`Recorder.event` and :meth:`Recorder.topology` -- the calls of the
orchestrator's round loop -- only store what they are given in memory, under
a lock held for that alone (a few microseconds; ``event`` also appends its
line to ``events.jsonl``).  Everything else is a flush, and with
``flush_seconds > 0`` (the orchestrator's 1 s) every flush but the explicit
ones runs on the recorder's background thread: it wakes when
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
not count (``topology/lost``, ``topology/status``: one chunk each), appends what Rerun encoded to ``run.rrd`` (fsynced) and
rewrites ``trajectory.npz`` (fsynced) -- the whole file, so on a long run
(tens of MB) the background thread skips that rewrite at the flushes that
come sooner than 9 times its last duration after it: at most a tenth of its
time goes to it (every flush up to some 10^4 rows at m = 32, n = 6).  So no Rerun call, no ``run.rrd`` or
``trajectory.npz`` write and no fsync happens in the caller's thread, except
in :meth:`Recorder.flush` (explicit: it waits for a background flush under
way, then flushes), :meth:`Recorder.close`, at a normal interpreter exit
without ``close`` (which also finishes ``run.rrd`` with its footer, but
writes no ``recording_closed`` event), and with ``flush_seconds=0``, a
write-through mode for tests where every call flushes before it returns and
no background thread runs.  Values that were never sent need no ``Clear``: a
row re-sent or an agent lost before the flush simply changes what is sent.

Rerun never stops a run: a viewer that cannot be spawned or reached, or a
failing flush, is logged as a warning and the recording goes on (file only).

Write failures and consistency
------------------------------
A failed write of any of the three files (ENOSPC, EROFS, EACCES, EDQUOT...)
*does* stop the recording: it raises :class:`RecordsWriteError`
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
:mod:`splitspec_orchestrator.recording.rrd_file` for the format).  During the run ``run.rrd`` is a
footer-less RRD stream, readable with ``RrdReader(path).stream()``; at
:meth:`Recorder.close` it is rewritten as one RRD with footer, which ``rerun
rrd verify`` accepts.  ``events.jsonl`` and ``run.rrd`` are opened per write
(no file of the run stays open between calls), a torn line or message is cut
back after a failed write.

A flush writes ``run.rrd`` first, then ``trajectory.npz`` (one flush at a
time, whichever thread runs it), so the npz never holds an event time the rrd
lacks and a SIGKILL loses at most the rows of one flush period (plus the
flush under way; on a long run, those since the last rewrite of
``trajectory.npz``, which ``splitspec recover`` cuts ``run.rrd`` back to)
from both.  ``close(finished=False)`` after a write failure does
not raise: it removes the disk-space reserve (``.splitspec-reserve``, a few
MB preallocated at start, :class:`splitspec_orchestrator.records.outdir.Reserve`), writes what
the failure left unwritten, and leaves K = :attr:`Recorder.rows_kept` rows in
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

import atexit
import logging
import math
import threading
import time
import weakref
from pathlib import Path
from typing import Any, Iterable, Mapping

import numpy as np

from splitspec_core.errors import SplitspecError
from splitspec_core.scenarios.labels import default_state_names
from splitspec_core.simulation.trajectory_file import TRAJECTORY_FILE

from ..recording import blueprint as bp
from .events import EVENTS_FILE, EventLog, event_level, event_text
from .measured import MeasuredRecords
from .outdir import Reserve
from .files import RecordFiles, RecordsWriteError, strerror
from ..recording.sink import RRD_FILE, RerunSink, RowBatch
from ..recording.rrd_file import verify_rrd
from .rowstore import RowStore
from ..recording.topology_view import cut_arcs, partition_text

__all__ = ["Recorder", "RecordingError", "RecordsWriteError", "WriteFailure", "verify_rrd", "TRAJECTORY_FILE",
           "EVENTS_FILE", "RRD_FILE"]

log = logging.getLogger(__name__)

RESERVE_BYTES = 4 << 20  # disk-space reserve released on ENOSPC to write the final records
_MAX_INITIAL_ROWS = 1024  # row storage starts at most this big (``steps`` is a hint) and doubles
# The background thread's rewrites of trajectory.npz take at most this share of its time: a rewrite
# that took w seconds is followed by none before 9 w have passed (a long run's trajectory is large).
_NPZ_DUTY = 0.1
# Rows per piece of a flush: rerun's BinaryStream.read returns what was encoded as one bytes object
# and holds the GIL meanwhile (~20 ms for 8 MB here), so a flush after a burst of rows sends and
# reads them back 512 rows at a time: a caller waiting for the GIL waits for one piece at most.
_SEND_ROWS = 512

# Recorders not closed yet: flushed at interpreter exit (and when dropped, see __del__), so a
# normal exit without close() loses no buffered row.  The handler is registered after rerun is imported (which registers
# Rerun's shutdown) so that, atexit being last-in first-out, it runs before that shutdown.
_OPEN: "weakref.WeakSet[Recorder]" = weakref.WeakSet()
_exit_flush_registered = False


def _register_exit_flush() -> None:
    global _exit_flush_registered
    if not _exit_flush_registered:
        atexit.register(_flush_open_recorders)
        _exit_flush_registered = True


def _flush_open_recorders() -> None:
    for rec in list(_OPEN):
        try:
            with rec._io, rec._lock:  # waits for a background flush under way
                if not rec._closed and rec._failure is None:
                    rec._flush(final=True)  # the last flush: a mark still waiting for its row goes too
                    # run.rrd with its footer, as a Rerun FileSink would leave it; nothing is recorded after this
                    rec._closed = True
                    rec._stop.set()
                    rec._wake.set()
                    rec._files.finish_rrd(rec._rows_kept)
                    rec._reserve.release()
        except Exception as exc:
            log.warning("flush at exit failed (%s: %s)", type(exc).__name__, exc)


class RecordingError(SplitspecError, ValueError):
    """A recorder call does not fit the run (shape, agent id, graph, order); the message names it."""


class WriteFailure:
    """The first failed write of a recorder's records (the recording stops at it), and whether a caller has
    seen it (raised to it); shared with :class:`~splitspec_orchestrator.records.files.RecordFiles`."""

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


class Recorder:
    """Records one run to ``out_dir`` (see the module docstring for the files and entities).

    Parameters
    ----------
    out_dir : directory of the run (created if missing)
    agent_ids : agent ids in the scenario's order; column ``i`` of ``xhat``/``alive`` is ``agent_ids[i]``
    n : state dimension
    steps : expected number of steps (capacity hint only; more rows are accepted)
    time_mode : ``"discrete"`` (``t = tau``) or ``"continuous"`` (``t = tau * dt``)
    dt : sampling step of continuous time (ignored in discrete time)
    graph_names : the scenario's graphs, in order; ``graph`` indices refer to it
    run_id : Rerun recording id
    scenario_name : shown as the recording's name
    viewer : ``None`` file only; ``"spawn"`` spawn a viewer and stream to it;
        otherwise the URL (``rerun+http://host:port/proxy``, or ``host:port``)
        of a running viewer to stream to.  ``run.rrd`` is written in every case.
    flush_seconds : wall-time period of the background thread's flushes (buffered rows and
        queued logs to Rerun and ``run.rrd``, ``trajectory.npz`` rewritten); ``0``: no background
        thread, every call flushes before it returns (write-through, for tests)
    viewer_port : port of a spawned viewer
    connect_timeout : seconds to wait when checking that a viewer is reachable
    reserve_bytes : size of the disk-space reserve ``.splitspec-reserve`` kept in ``out_dir``
        until close (at most 1/8 of the free space; ``0``: none)
    envelope_rate : designed rate ``lam`` of ``errors_log10/envelope`` (None: no envelope, e.g. adaptive gain)
    states : the states' names (``system.states``): the ``state/<name>/...`` entities and ``trajectory.npz``'s
        ``states``; None: ``state/<k>/...`` and ``x1 .. xn``
    gains : log ``gains/agent_<id>`` (continuous time)
    positions : ``{agent id: (x, y)}`` of the topology's nodes (None: a circle)

    Raises
    ------
    RecordsWriteError
        If ``out_dir``, ``events.jsonl`` or ``run.rrd`` cannot be created.
    """

    def __init__(self, out_dir: Path, *, agent_ids: tuple[int, ...], n: int, steps: int, time_mode: str,
                 dt: float, graph_names: tuple[str, ...], run_id: str, scenario_name: str,
                 viewer: str | None = None, flush_seconds: float = 1.0,
                 viewer_port: int = 9876, connect_timeout: float = 1.0,
                 reserve_bytes: int = RESERVE_BYTES, envelope_rate: float | None = None, gains: bool = False,
                 positions: Mapping[int, tuple[float, float]] | None = None, states: tuple | None = None,
                 shown: tuple | None = None):
        if time_mode not in ("discrete", "continuous"):
            raise RecordingError(f"time_mode must be 'discrete' or 'continuous', got {time_mode!r}")
        ids = [int(a) for a in agent_ids]
        if not ids or len(set(ids)) != len(ids):
            raise RecordingError(f"agent_ids must be non-empty and distinct, got {tuple(agent_ids)}")
        if int(n) < 1:
            raise RecordingError(f"n must be >= 1, got {n}")
        if time_mode == "continuous" and not (math.isfinite(dt) and dt > 0):
            raise RecordingError(f"dt must be a positive number in continuous time, got {dt}")
        if not graph_names:
            raise RecordingError("graph_names must name at least one graph")
        if not flush_seconds >= 0:
            raise RecordingError(f"flush_seconds must be >= 0, got {flush_seconds}")
        if envelope_rate is not None and not (math.isfinite(envelope_rate) and envelope_rate > 0):
            raise RecordingError(f"envelope_rate must be a positive number or None, got {envelope_rate}")
        if positions is not None and set(int(a) for a in positions) != set(ids):
            raise RecordingError(f"positions must give every agent of {tuple(ids)}, got {sorted(positions)}")

        self.out_dir = Path(out_dir)
        try:
            self.out_dir.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise RecordsWriteError(self.out_dir, strerror(exc)) from None
        self.agent_ids = np.array(ids, dtype=np.int64)
        self.m, self.n = len(ids), int(n)
        self.time_mode, self.dt = time_mode, float(dt)
        self.graph_names = tuple(graph_names)
        self.run_id, self.scenario_name = str(run_id), str(scenario_name)
        self.flush_seconds = float(flush_seconds)
        self.envelope_rate = None if envelope_rate is None else float(envelope_rate)
        self._pos = {a: k for k, a in enumerate(ids)}
        self._no_gains = np.full(self.m, np.nan)  # read only
        # Two locks, always taken in this order: _io (one flush at a time; the rows taken, the Rerun
        # sink and the files), then _lock (what the callers record; held for memory work only).
        self._io = threading.RLock()
        self._lock = threading.RLock()
        self._closed = False
        self._lost: dict = {}  # tau -> rows (tau, k, j, i, cause) of the consensus messages that did not count

        cap = max(min(int(steps) + 1, _MAX_INITIAL_ROWS), 16)
        self._s = RowStore(self.m, self.n, capacity=cap)  # the rows recorded (under _lock)
        self._d = RowStore(self.m, self.n, capacity=cap)  # the rows taken by flushes (under _io)
        # a run on measurements or live sensors (set_y_source): what it records beyond the rows
        self._meas = MeasuredRecords(self._lock, taken=self._d, agent_ids=self.agent_ids, pos=self._pos)
        # Buffer: rows _taken.. of _s were never taken by a flush; _changed holds taken rows that
        # changed since (re-sent tau, agent lost): taken and sent again whole.  _queued_events /
        # _queued_topology hold the deferred Rerun logs of event() / topology() in call order, sent
        # as one chunk each.  _request: a flush of the first _request rows asked for (mark_lost).
        self._taken = 0
        self._changed: set[int] = set()
        self._queued_events: list[tuple[int, float, str, str, int]] = []
        # (tau, t, graph name, alive, edges, wall_ns, cut edges, partition text)
        self._queued_topology: list[tuple[int, float, str, set[int], list[tuple[str, str]], int, frozenset, str]] = []
        self._queued_marks: list[tuple[int, float, str, int]] = []  # (tau, t, kind, wall_ns); y set at flush
        self._queued_clears: list[tuple[int, float, int, int]] = []  # loss clears (tau, t, agent, wall_ns)
        self._request: int | None = None
        self._npz_next = 0.0  # monotonic time before which the background thread does not rewrite it
        self._last_flush = time.monotonic()

        # Write failures (see the module docstring): the first one and whether a caller has seen it;
        # what is on disk: rows of trajectory.npz and of run.rrd (self._files), bytes of events.jsonl.
        self._failed = WriteFailure(self._lock)
        self._rows_kept = 0
        self._events_path = self.out_dir / EVENTS_FILE
        try:
            self._events = EventLog(self._events_path)  # create / empty events.jsonl
        except OSError as exc:
            raise RecordsWriteError(self._events_path, strerror(exc)) from None
        if states is not None and len(states) != self.n:
            raise RecordingError(f"states names {len(states)} states; expected {self.n}")
        names = tuple(str(s) for s in states) if states is not None else None
        sink: RerunSink | None = None
        try:
            sink = RerunSink(self.out_dir, run_id=self.run_id, scenario_name=self.scenario_name,
                                  agent_ids=self.agent_ids, n=self.n, time_mode=time_mode, dt=self.dt,
                                  graph_names=self.graph_names, envelope=self.envelope_rate is not None,
                                  gains=bool(gains), positions=dict(positions) if positions else None,
                                  viewer=viewer, viewer_port=viewer_port, connect_timeout=connect_timeout,
                                  states=names, shown=shown)
        except Exception as exc:  # Rerun must never stop a run
            log.warning("Rerun recording disabled (%s: %s); writing trajectory.npz and events.jsonl only",
                        type(exc).__name__, exc)
            sink = None
        # trajectory.npz and run.rrd (self._rec is its sink)
        self._files = RecordFiles(self.out_dir, agent_ids=self.agent_ids, taken=self._d, lost=self._lost,
                                  extra=self._meas.arrays, failure=self._failed, sink=sink,
                                  states=names or default_state_names(self.n))
        if sink is not None:
            self._files.append_rrd()  # header, properties, styles and blueprint: run.rrd exists from the start
        self._reserve = Reserve(self.out_dir, reserve_bytes)
        _OPEN.add(self)
        _register_exit_flush()
        self._stop = threading.Event()
        self._wake = threading.Event()
        self._watcher = None
        if self.flush_seconds > 0:  # with 0 every call flushes itself: nothing is left waiting
            self._watcher = threading.Thread(target=_watch, args=(weakref.ref(self), self._stop, self._wake),
                                             name="splitspec-recorder-flush", daemon=True)
            self._watcher.start()

    # ------------------------------------------------------------------ time helpers

    def _t_of_tau(self, tau: int) -> float:
        return float(tau) if self.time_mode == "discrete" else tau * self.dt

    def _tau_of_t(self, t: float) -> int:
        return int(round(t)) if self.time_mode == "discrete" else int(round(t / self.dt))

    @property
    def _rec(self) -> RerunSink | None:
        """The Rerun sink (None: file records only, or after close)."""
        return self._files.sink

    @property
    def _failure(self) -> RecordsWriteError | None:
        """The first write failure (the recording has stopped), None if none."""
        return self._failed.error

    # ------------------------------------------------------------------ public API

    @property
    def rows_recorded(self) -> int:
        """Number of rows (distinct event times) recorded so far: T of ``trajectory.npz``."""
        return self._s.rows

    @property
    def rows_kept(self) -> int:
        """Rows (event times) that ``trajectory.npz`` and ``run.rrd`` both hold on disk.

        During the run: as of the last successful flush (a background flush may be under way).  After :meth:`close`:
        K, the rows of the closed records (``rows_recorded`` after a normal
        close; after a write failure, as many as the disk allowed).
        """
        return self._rows_kept

    def event(self, event: str, t: float, *, level: str | None = None, note: str | None = None, **fields) -> None:
        """Append ``{"event", "t", "wall", **fields}`` to ``events.jsonl`` and log it to Rerun.

        ``t`` is the event time in the run's units (``tau`` in discrete time,
        seconds in continuous time); the TextLog is placed at ``tau = t`` or
        ``tau = round(t / dt)``.  Level WARN when the name contains
        lost/rejected/error/failed, else INFO, unless ``level`` is given.
        The Rerun text is one short sentence (:func:`splitspec_orchestrator.records.events.event_text`;
        ``note`` replaces it); ``events.jsonl`` always has every field.  Losses,
        rejoins, graph switches and link faults also get a point on ``marks/<kind>``.
        """
        if level is None:
            level = event_level(event)
        self._event(event, t, level, fields, note)

    def _event(self, event: str, t: float, level: str, fields: dict[str, Any], note: str | None = None) -> None:
        if "wall" in fields:
            raise RecordingError(f"event {event!r}: field name 'wall' is reserved")
        with self._lock:
            self._check_open("event")
            self._check_failed()
            line = self._events.line(event, t, time.time(), fields)  # TypeError before any write
            try:
                self._events._write(line)
            except OSError as exc:
                raise self._fail(self._events_path, exc, self._tau_of_t(t)) from None
            if self._rec is not None:
                tau, wall = self._tau_of_t(t), time.time_ns()
                self._queued_events.append((tau, float(t), event_text(event, fields, note), level, wall))
                kind = bp.MARK_OF_EVENT.get(event)
                if kind is not None:
                    self._queued_marks.append((tau, float(t), kind, wall))
        self._write_through()

    def topology(self, tau: int, graph_name: str, alive_ids: Iterable[int],
                 arcs: Iterable[tuple[int, int]], *, partition=None) -> None:
        """Log the communication graph at ``tau``: every agent as a node, arcs ``(j, i)`` among alive agents.

        An arc ``(j, i)`` means agent ``i`` receives from agent ``j`` (drawn j -> i).
        Arcs touching a dead agent are not drawn.  ``partition``: the groups of agent ids of a
        partition in force (:mod:`splitspec_core.model.impairment`), None or empty for none: the arcs
        between groups are drawn dashed (``topology/partition``) and the graph's label names it.
        """
        if graph_name not in self.graph_names:
            raise RecordingError(f"unknown graph {graph_name!r}; expected one of {self.graph_names}")
        alive = {int(a) for a in alive_ids}
        unknown = sorted(alive - set(self._pos))
        if unknown:
            raise RecordingError(f"alive_ids {unknown} are not agents of this run {tuple(self.agent_ids)}")
        edges = []
        for arc in arcs:
            j, i = (int(v) for v in arc)
            if j not in self._pos or i not in self._pos:
                raise RecordingError(f"arc ({j}, {i}) names an agent not in {tuple(self.agent_ids)}")
            if j in alive and i in alive:
                edges.append((str(j), str(i)))
        groups = tuple(tuple(int(a) for a in g) for g in (partition or ()))
        strangers = sorted({a for g in groups for a in g} - set(self._pos))
        if strangers:
            raise RecordingError(f"partition names {strangers}, not agents of this run {tuple(self.agent_ids)}")
        cut = frozenset((str(j), str(i)) for j, i in
                        cut_arcs(groups, [(int(j), int(i)) for j, i in edges], self.agent_ids.tolist()))
        with self._lock:
            self._check_open("topology")
            self._check_failed()
            if self._rec is not None:
                self._queued_topology.append((int(tau), self._t_of_tau(int(tau)), graph_name, alive, edges,
                                              time.time_ns(), cut, partition_text(groups) if groups else ""))
        self._write_through()

    def row(self, tau: int, x: np.ndarray, xhat: np.ndarray, alive: np.ndarray, graph: int, *,
            gains: np.ndarray | None = None, wall_ms: float | None = None, attempts: int | None = None,
            rejected: int | None = None, lost=None) -> None:
        """Record event time ``tau``: ``x`` (n,), ``xhat`` (m, n), ``alive`` (m,) bool, graph index.

        ``gains`` (m,): each agent's ``g_i(tau)`` (None: no gain, discrete
        time); ``wall_ms``, ``attempts``, ``rejected``: the round's
        diagnostics (``rounds/...``), None if unknown; ``lost``: the round's
        consensus messages that did not count, rows ``(tau, k, j, i, cause)``
        (``trajectory.npz`` ``lost``/``lost_cause``; their count is ``rounds/lost``;
        None: unknown, as in a recorder fed by hand).

        Rows come in increasing ``tau``; a row re-sent for an already recorded
        ``tau`` replaces it.  Rows of dead agents are stored as NaN whatever
        ``xhat`` holds there.  The row is only stored in memory: it reaches
        Rerun, ``run.rrd`` and ``trajectory.npz`` at the next flush, on the
        recorder's background thread (see the module docstring).
        """
        tau = int(tau)
        x = np.asarray(x, dtype=float)
        xhat = np.asarray(xhat, dtype=float)
        alive = np.asarray(alive)
        if x.shape != (self.n,):
            raise RecordingError(f"x has shape {x.shape}; expected ({self.n},)")
        if xhat.shape != (self.m, self.n):
            raise RecordingError(f"xhat has shape {xhat.shape}; expected ({self.m}, {self.n})")
        if alive.shape != (self.m,) or alive.dtype != bool:
            raise RecordingError(f"alive must be a bool array of shape ({self.m},), "
                                 f"got {alive.dtype} {alive.shape}")
        if not 0 <= int(graph) < len(self.graph_names):
            raise RecordingError(f"graph index {graph} out of range 0..{len(self.graph_names) - 1}")
        g = self._no_gains if gains is None else np.asarray(gains, dtype=float)
        if g.shape != (self.m,):
            raise RecordingError(f"gains has shape {g.shape}; expected ({self.m},)")
        diag = [np.nan if v is None else float(v) for v in (wall_ms, attempts, rejected,
                                                             None if lost is None else len(lost))]
        with self._lock:
            if lost is not None:
                self._lost[tau] = tuple(tuple(int(v) for v in r) for r in lost)
            self._check_open("row")
            self._check_failed()
            k = self._s.row_of_tau.get(tau)
            if k is None:
                if self._s.rows and tau < self._s.tau[self._s.rows - 1]:
                    raise RecordingError(f"row for tau={tau} arrives after tau={self._s.tau[self._s.rows - 1]}; "
                                         "rows must come in increasing tau")
                k = self._s.append_slot(tau)
            elif k < self._taken:
                self._changed.add(k)  # already taken by a flush: take and send the whole row again (newest wins)
            self._s.t[k] = self._t_of_tau(tau)
            self._s.x[k] = x
            self._s.xhat[k] = np.where(alive[:, None], xhat, np.nan)
            self._s.alive[k] = alive
            self._s.graph[k] = int(graph)
            self._s.g[k] = np.where(alive, g, np.nan)
            self._s.round[k] = diag
            self._s.wall[k] = time.time_ns()
        self._write_through()

    def _batch(self, K: np.ndarray, err: np.ndarray, show: np.ndarray) -> RowBatch:
        """Rows ``K`` (taken) as the sink logs them; ``clear`` where an earlier flush showed a value no longer true."""
        show_max = show.any(axis=1)
        err_max = np.max(np.where(show, err, -np.inf), axis=1)
        S = self._d
        return RowBatch(seq=S.tau[K], t=S.t[K], wall=S.wall[K], x=S.x[K], xhat=S.xhat[K], err=err, show=show,
                        clear=S.shown[K] & ~show, err_max=err_max, show_max=show_max,
                        clear_max=S.shown_max[K] & ~show_max, env=S.envelope(K, self.envelope_rate, self.time_mode),
                        gains=S.g[K], rounds=S.round[K])

    def mark_lost(self, tau: int, agent_id: int) -> None:
        """Agent ``agent_id`` is lost from event time ``tau`` on: NaN/False in every recorded row with ``tau' >= tau``.

        Buffered rows simply lose the agent's values; rows already in Rerun get a
        ``Clear`` (and a new ``errors/max``; NaN for the agent in ``state/<k>/agents``);
        every series of the agent alone gets a ``Clear`` at ``tau`` itself (a break in
        its lines).  Then a flush of every row recorded so far is asked of the
        background thread (done at once in this call with ``flush_seconds=0``).
        """
        i = self._pos.get(int(agent_id))
        if i is None:
            raise RecordingError(f"agent {agent_id} is not an agent of this run {tuple(self.agent_ids)}")
        with self._lock:
            self._check_open("mark_lost")
            self._check_failed()
            T = self._s.rows
            rows = np.nonzero(self._s.tau[:T] >= int(tau))[0]
            for k in rows:
                if not self._s.alive[k, i]:
                    continue
                self._s.alive[k, i] = False
                self._s.xhat[k, i] = np.nan
                self._s.g[k, i] = np.nan
                if k < self._taken:
                    self._changed.add(int(k))
            if self._rec is not None:
                self._queued_clears.append((int(tau), self._t_of_tau(int(tau)), int(agent_id), time.time_ns()))
            for t_, lost in list(self._lost.items()):  # a dead agent sends and receives nothing from tau on
                if t_ >= int(tau):
                    kept = tuple(r for r in lost if int(agent_id) not in (r[2], r[3]))
                    if len(kept) != len(lost):
                        self._lost[t_] = kept
                        k = self._s.row_of_tau.get(t_)
                        if k is not None:  # rounds/lost counts what trajectory.npz keeps
                            self._s.round[k, 3] = len(kept)
                            if k < self._taken:
                                self._changed.add(int(k))
            self._request = T
        if self.flush_seconds == 0:
            self._write_through()
        else:
            self._wake.set()

    def flush(self) -> None:
        """Send the buffered rows and queued logs to Rerun and ``run.rrd``, rewrite ``trajectory.npz``: now,
        in the caller's thread (waiting for a background flush under way); the round loop never calls it.

        Raises
        ------
        RecordsWriteError
            If a record cannot be written (now, or earlier by the background thread).
        """
        with self._io:
            with self._lock:
                self._check_open("flush")
                self._check_failed()
            self._flush()  # not the last: a mark whose row is not recorded yet still waits for it

    def close(self, *, finished: bool = True) -> None:
        """Flush, write ``trajectory.npz`` with the rows so far, finish ``run.rrd`` and ``events.jsonl``.

        The last event is ``recording_closed`` with ``finished`` and ``rows``
        (K = :attr:`rows_kept`); ``finished=False`` (run ended early, or a
        write failed) is a WARN event.  ``run.rrd`` is rewritten as one RRD
        with footer; after a write failure only event times before the K-th
        row's successor are kept in it (see the module docstring).  Calling
        close twice is harmless.

        Raises
        ------
        RecordsWriteError
            Only with ``finished=True`` and a write failure that no earlier call
            reported (it happened in this close); the records are left
            consistent first.  ``close(finished=False)`` never raises it.
        """
        with self._io, self._lock:  # waits for a background flush under way
            if self._closed:
                return
            self._closed = True
            self._meas.closed = True
            if self._meas.source is not None:
                self._files.npz_dirty = True  # the last write adds what is known without truth (MeasuredRecords.arrays)
            self._stop.set()
            self._wake.set()
            _OPEN.discard(self)
            try:
                if self._failure is None:
                    try:
                        self._flush(final=True)
                    except RecordsWriteError:
                        pass
                    self._meas.send_after_run(self._rec)
                if self._failure is not None:
                    self._reserve.release()  # room for the final records
                    self._salvage()
                K = self._rows_kept
                ok = bool(finished) and self._failure is None
                if self._failure is not None:
                    # finish run.rrd first, fewer rows if its rewrite does not fit: the close event then
                    # states what all three records hold
                    K = self._rows_kept = self._files.finish_rrd_fitting(K)
                fields: dict[str, Any] = {"finished": ok, "rows": K}
                if self._failure is not None:
                    fields["error"] = str(self._failure)
                    try:
                        self._events.write("recording_closed", float(self._d.t[K - 1]) if K else 0.0, time.time(),
                                           fields)
                    except OSError as exc:
                        self._fail(self._events_path, exc, None)
                else:
                    self._close_event(float(self._d.t[K - 1]) if K else 0.0, "INFO" if ok else "WARN", fields)
                    self._files.finish_rrd(K)
            finally:
                self._reserve.release()
                if self._rec is not None:
                    self._rec.disconnect()
                    self._files.sink = None
        if self._watcher is not None and self._watcher is not threading.current_thread():
            self._watcher.join(timeout=10.0)
        if self._failure is not None and not self._failed.reported and finished:
            self._failed.reported = True
            raise self._failure

    def __del__(self) -> None:
        # Dropped without close(): send what is buffered (logging used to be immediate).
        try:
            if not self._closed and self._failure is None:
                with self._io:
                    self._flush(final=True)
        except Exception:
            pass

    def __enter__(self) -> "Recorder":
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        self.close(finished=exc_type is None)

    # ------------------------------------------------------------------ internals

    def _check_open(self, what: str) -> None:
        if self._closed:
            raise RecordingError(f"{what}() called after close()")

    def _check_failed(self) -> None:
        """After a write failure the recording has stopped: every call raises it again."""
        if self._failure is not None:
            self._failed.reported = True
            raise self._failure

    def _fail(self, path: Path, exc: OSError, tau: int | None) -> RecordsWriteError:
        """The :class:`RecordsWriteError` of ``exc``; the first one is kept (the recording stops)."""
        return self._failed.fail(path, exc, tau)

    def _write_through(self) -> None:
        """``flush_seconds=0``: flush in the caller's thread after every call.  Otherwise nothing: the
        background thread flushes.  Called without ``_lock`` held (the locks are taken ``_io`` first)."""
        if self.flush_seconds == 0:
            with self._io:
                with self._lock:
                    self._check_failed()
                    if self._closed:
                        return
                self._flush()

    def _pending(self) -> bool:
        """Something recorded that no flush took or wrote yet (``trajectory.npz`` included).  ``_io`` and
        ``_lock`` held."""
        return (self._taken < self._s.rows or bool(self._changed) or bool(self._queued_events)
                or bool(self._queued_topology) or bool(self._queued_marks) or bool(self._queued_clears)
                or self._request is not None or (self._rec is not None and bool(self._rec.pending))
                or self._files.npz_dirty)

    def _grow_ahead(self) -> None:
        """Background thread: double the recorded rows' storage before a caller's row fills it.  The new
        columns are allocated and touched outside ``_lock`` (fresh memory is slow: ~0.2 s for the 50 MB of
        32768 rows at m = 32, n = 6 on the 2-core dev VM); only the copy of the rows is under it."""
        cap = self._s.capacity
        if self._s.rows <= cap * 3 // 4:
            return
        spare = self._s.spare(2 * cap)
        with self._lock:
            if self._s.capacity == cap:  # no caller grew it meanwhile
                self._s.adopt(spare)

    def _background_flush(self) -> bool:
        """One turn of :func:`_watch`: flush if due or asked for.  False when the recorder is closed."""
        with self._io:
            self._grow_ahead()
            self._d.reserve(self._s.rows)  # any growth of the taken rows outside _lock
            with self._lock:
                if self._closed or self._failure is not None:
                    return False  # the recording has stopped: close() writes what is left
                upto = self._request
                if upto is None:
                    if time.monotonic() - self._last_flush < self.flush_seconds:
                        return True
                    if not self._pending():
                        self._last_flush = time.monotonic()  # idle: look again in flush_seconds
                        return True
                taken = self._take(upto)
            try:
                self._write(*taken, trajectory=upto is not None or time.monotonic() >= self._npz_next)
            except RecordsWriteError:  # stored: the next recorder call raises it
                with self._lock:
                    self._failed.reported = False
            except Exception as exc:
                log.warning("background flush failed (%s: %s)", type(exc).__name__, exc)
        return True

    def _flush(self, *, final: bool = False) -> None:
        """Take what was recorded (under ``_lock``, memory only), then write it out (``_io`` held, not ``_lock``).

        ``final``: the recording's last flush (close, exit, salvage): marks whose row never came are
        written too.  The writes: rows, then queued logs, to Rerun and ``run.rrd``; then ``trajectory.npz`` --
        ``run.rrd`` first, so ``trajectory.npz`` never holds a row that ``run.rrd`` lacks.

        Raises
        ------
        RecordsWriteError
            If ``run.rrd`` or ``trajectory.npz`` cannot be written.
        """
        with self._io:
            self._d.reserve(self._s.rows)  # any growth of the taken rows outside _lock
            with self._lock:
                taken = self._take(None, final=final)
            self._write(*taken)

    def _take(self, upto: int | None, *, final: bool = False) -> tuple:
        """Copy the rows recorded since the last flush (and changed ones) into the taken rows; take the
        queued logs.  ``_io`` and ``_lock`` held; no I/O, O(rows taken) work."""
        self._last_flush = time.monotonic()
        T = self._s.rows if upto is None else max(min(int(upto), self._s.rows), self._taken)
        changed = np.array(sorted(self._changed), dtype=np.int64)  # all below _taken
        K = np.concatenate([changed, np.arange(self._taken, T, dtype=np.int64)])
        if len(K):
            self._d.take(self._s, self._taken, T, changed)
            self._files.npz_dirty = True
        self._taken = T
        self._changed.clear()
        if self._request is not None and self._request <= T:
            self._request = None
        # a mark stands at the height of its own row's max error: one whose row is not taken yet (the
        # topology of tau arrives before its row) waits for the next flush (close() takes them all)
        last = int(self._s.tau[T - 1]) if T else None
        ready, later = [], []
        for mk in self._queued_marks:
            (ready if final or (last is not None and mk[0] <= last) else later).append(mk)
        # per row taken: its consensus messages that did not count, and whether the previous row's did not all
        # count (the topology view's per-event-time overlay, TopologyView.send_lost)
        lost = []
        if self._rec is not None and self._lost:
            S = self._s
            for k in K:
                prev = bool(self._lost.get(int(S.tau[k - 1]))) if k else False
                lost.append((int(S.tau[k]), float(S.t[k]), int(S.wall[k]), self._lost.get(int(S.tau[k])) or (), prev))
        taken = (K, self._queued_events, self._queued_topology, ready, self._queued_clears, lost)
        self._queued_events, self._queued_topology, self._queued_marks, self._queued_clears = [], [], later, []
        return taken

    def _write(self, K: np.ndarray, events: list, topology: list, marks: list, clears: list, lost: list, *,
               trajectory: bool = True) -> None:
        """Write out what :meth:`_take` took.  ``_io`` held; ``_lock`` only for the bookkeeping at the end.

        ``trajectory=False``: leave ``trajectory.npz`` for a later flush (see ``_NPZ_DUTY``).
        """
        D = self._d
        sink = self._rec
        for lo in range(0, len(K), _SEND_ROWS):
            part = K[lo:lo + _SEND_ROWS]
            err, show = self._meas.row_errors(part)
            if sink is not None:
                sink.guarded("row log", lambda: sink.send_rows(self._batch(part, err, show)))
            # What Rerun now shows (also when a send failed: it is not retried).
            D.shown[part] = show
            D.shown_max[part] = show.any(axis=1)
            if sink is not None and lo + _SEND_ROWS < len(K):
                sink.read_pending()  # a piece at a time (see _SEND_ROWS); run.rrd gets it below
        if sink is not None:
            if clears:
                sink.guarded("loss clears", sink.send_loss_clears, clears)
            if events:
                sink.guarded("event log", sink.send_events, events)
            if marks:
                sink.guarded("marks", sink.send_marks, [(tau, t, kind, self._meas.mark_y(tau), wall)
                                                        for tau, t, kind, wall in marks])
            if topology:
                sink.guarded("topology log", sink.send_topology, topology)
            if lost:  # after the topology it is drawn over
                sink.guarded("lost messages log", sink.send_lost, lost)
        files = self._files
        if len(K) or events or topology or marks or clears or (sink is not None and sink.pending):
            files.append_rrd()
        if trajectory and (files.npz_dirty or files.npz_rows != D.rows):
            t0 = time.monotonic()
            files.write_trajectory()
            self._npz_next = time.monotonic() + (time.monotonic() - t0) * (1 - _NPZ_DUTY) / _NPZ_DUTY
        with self._lock:
            self._rows_kept = min(files.npz_rows, files.rrd_rows) if sink is not None else files.npz_rows

    def set_measurements(self, sc, meas) -> None:
        """The run plays a measurements file (:class:`splitspec_core.scenarios.measurements.Measurements`): see
        :meth:`set_y_source`; the truth is the file's ``x`` if it has one."""
        from ..recording.reference_view import file_rows

        self.set_y_source(sc, file_rows(meas), truth=meas.has_truth)
        self._meas.inputs = meas.u

    def set_y_source(self, sc, y_row, *, truth: bool) -> None:
        """The estimators run on measurements ``y_row(tau) -> (y, missing) | None``
        (:data:`splitspec_orchestrator.recording.reference_view.YRow`); call before the first row.

        ``trajectory.npz`` gets their ``y`` and ``y_missing`` rows, and at the close what is known without
        truth (:func:`splitspec_core.studies.no_truth.no_truth_arrays`); ``run.rrd`` the same as it goes
        (:mod:`splitspec_orchestrator.recording.reference_view`) and, ``truth=False``, no error and no truth at all.
        """
        from ..recording.reference_view import ReferenceRows

        rows = ReferenceRows(sc.system.Cs, y_row)
        with self._io, self._lock:
            if self._s.rows:
                raise RecordingError("set_y_source() after the first row: the recording already shows its errors")
            self._meas.use(sc, rows, truth=truth)
            if self._rec is not None:
                self._rec.guarded("reference setup", lambda: self._rec.set_reference(rows, truth=truth))

    def set_live_sources(self, sc) -> None:
        """Live sensors (scenario ``sources:``): the estimators run on the ``y_i`` each agent reports having used
        (:meth:`live_y`, from its ``xhat``), without a truth (:meth:`set_y_source`); call before the first row."""
        self.set_y_source(sc, self._meas.live_source(sc), truth=False)

    def live_y(self, tau: int, used) -> None:
        """Event time ``tau``'s ``(agent id, y_i(tau) or None)`` of the agents alive (the others: missing, NaN);
        before :meth:`row` of ``tau``, so that a flush never takes the row without its measurements."""
        self._meas.live_y(tau, used)

    def _salvage(self) -> None:
        """After a write failure: write what is left, then make the rows on disk agree
        (:meth:`RecordFiles.salvage`).  Never raises."""
        try:
            self._flush(final=True)
        except RecordsWriteError:
            pass
        self._rows_kept = self._files.salvage()

    def _close_event(self, t: float, level: str, fields: dict[str, Any]) -> None:
        """The last event, ``recording_closed``: to ``events.jsonl`` and ``run.rrd`` if they can take it."""
        try:
            self._events.write("recording_closed", t, time.time(), fields)
        except OSError as exc:
            self._fail(self._events_path, exc, self._tau_of_t(t))
        if self._rec is not None:
            text = event_text("recording_closed", fields)
            self._rec.guarded("event log", self._rec.send_events,
                              [(self._tau_of_t(t), t, text, level, time.time_ns())])
            try:
                self._files.append_rrd()
            except RecordsWriteError:
                pass


def _watch(ref: "weakref.ref[Recorder]", stop: threading.Event, wake: threading.Event) -> None:
    """The background flusher: every flush of a recorder with ``flush_seconds > 0`` but the explicit ones.

    Flushes when ``flush_seconds`` have passed since the last flush and something is pending, and at
    once when a flush is asked for (:meth:`Recorder.mark_lost` sets ``wake``).  The recorder's
    callers only ever wait for it on ``_lock``, held for the memory part of a flush (:meth:`Recorder._take`).
    """
    while True:
        rec = ref()
        if rec is None:
            return
        wait = 0.0 if rec._request is not None else max(0.01, rec._last_flush + rec.flush_seconds - time.monotonic())
        del rec  # no strong reference while waiting
        wake.wait(wait)
        wake.clear()  # a request set meanwhile is still in rec._request: seen on the next turn
        if stop.is_set():
            return
        rec = ref()
        if rec is None:
            return
        try:
            if not rec._background_flush():
                return
        finally:
            del rec
