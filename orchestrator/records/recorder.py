"""Run recorder of the orchestrator: ``trajectory.npz``, ``events.jsonl`` and ``run.rrd``.

The orchestrator hands the recorder one row per event time ``tau`` (true state ``x(tau)``, every agent's
estimate ``x_i(tau)``, the alive set and the active graph), the topology on every switch or death, and named
events.  The recorder keeps three records of the run in ``out_dir``.  What each holds, and when it is
written, is stated once, in docs/reference/files.md: ``trajectory.npz`` in section "Trajectory file",
``events.jsonl`` in section "Event log", ``run.rrd`` (its timelines, its entities, the Clears that retract a
value no longer true, the designed envelope) in section "Rerun recording".

:class:`Recorder` checks each call and keeps the order of things: what is recorded, what is flushed, the
first write failure, the close.  Its collaborators do the rest: :mod:`splitspec_orchestrator.records.flusher`
(what the callers recorded and no flush wrote yet; the background thread and when it flushes),
:mod:`splitspec_orchestrator.records.writer` (what a flush writes, in which order; write failures and
consistency), :mod:`splitspec_orchestrator.records.rowstore` (the rows and what each shows),
:mod:`splitspec_orchestrator.records.files` (``trajectory.npz`` rewritten through
:func:`splitspec_core.simulation.trajectory_file.write_trajectory`, the one writer shared with ``simulate``;
``run.rrd`` appended and finished; the cuts after a failure), :mod:`splitspec_orchestrator.records.measured`
(what a run on measurements or live sensors records beyond the rows), :mod:`splitspec_orchestrator.records.events`
(``events.jsonl`` and each event's sentence) and, for Rerun, :mod:`splitspec_orchestrator.viewer.handoff`
(the logs deferred to the next flush, in call order) and :mod:`splitspec_orchestrator.viewer.sink` (the
Rerun stream; entity paths and the default blueprint in :mod:`splitspec_orchestrator.viewer.blueprint`).

The calls of the orchestrator's round loop (:meth:`Recorder.row`, :meth:`Recorder.event`,
:meth:`Recorder.topology`, :meth:`Recorder.mark_lost`) only store what they are given in memory; a
background thread writes it out about every ``flush_seconds`` (the flusher's docstring says when, and what
happens in the caller's thread).  Rerun never stops a run: a viewer that cannot be spawned or reached, or a
failing flush, is logged as a warning and the recording goes on (file only).  A failed write of a record
does stop it (the writer's docstring, "Write failures and consistency").
"""

from __future__ import annotations

import logging
import threading
import time
from pathlib import Path
from typing import Iterable, Mapping

import numpy as np

from splitspec_core.runtime.cli import EVENTS_LOGGER
from splitspec_core.scenarios.labels import default_state_names
from splitspec_core.simulation.trajectory_file import TRAJECTORY_FILE

from ..viewer.handoff import cut_edges
from ..viewer.rrd_file import verify_rrd
from ..viewer.sink import DEFAULT_VIEWER_PORT, RRD_FILE, RerunSink, open_sink
from .checks import RecordingError, check_row, check_run, check_topology
from .events import EVENTS_FILE, EventLog, event_level, event_text
from .files import Continuous, RecordFiles, RecordsWriteError, WriteFailure, strerror
from .retention import Retention, plan
from .flusher import Flusher
from .measured import MeasuredRecords
from .outdir import Reserve
from .rowstore import RowStore
from .writer import RecordWriter

__all__ = ["Recorder", "RecordingError", "RecordsWriteError", "verify_rrd", "TRAJECTORY_FILE",
           "EVENTS_FILE", "RRD_FILE"]

told = logging.getLogger(EVENTS_LOGGER)  # what run.keep removes, on splitspec run's terminal (--log-level events)
RESERVE_BYTES = 4 << 20  # disk-space reserve released on ENOSPC to write the final records
_MAX_INITIAL_ROWS = 1024  # row storage starts at most this big (``steps`` is a hint) and doubles


class Recorder:
    """Records one run to ``out_dir`` (what the files hold: docs/reference/files.md; how: the module docstring).

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
    columns : the reported row columns (:data:`splitspec_core.model.rows.REPORTED`) this run shows in Rerun, one
        series per agent each (``gains/agent_<id>`` for ``g``, continuous time); every reported column is in
        ``trajectory.npz`` and the chunks whatever this says
    continuous : a run until stopped (:class:`~.files.Continuous`): no ``trajectory.npz``, a window of rows held
    positions : ``{agent id: (x, y)}`` of the topology's nodes (None: a circle)

    Raises
    ------
    RecordsWriteError
        If ``out_dir``, ``events.jsonl`` or ``run.rrd`` cannot be created.
    """

    def __init__(self, out_dir: Path, *, agent_ids: tuple[int, ...], n: int, steps: int, time_mode: str,
                 dt: float, graph_names: tuple[str, ...], run_id: str, scenario_name: str,
                 viewer: str | None = None, flush_seconds: float = 1.0,
                 viewer_port: int = DEFAULT_VIEWER_PORT, connect_timeout: float = 1.0,
                 reserve_bytes: int = RESERVE_BYTES, envelope_rate: float | None = None, columns: tuple = (),
                 positions: Mapping[int, tuple[float, float]] | None = None, states: tuple | None = None,
                 shown: tuple | None = None, continuous: Continuous | None = None, record_every: int = 1,
                 resume: tuple | None = None):
        ids = check_run(agent_ids=agent_ids, n=n, time_mode=time_mode, dt=dt, graph_names=graph_names,
                        flush_seconds=flush_seconds, envelope_rate=envelope_rate, positions=positions)

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
        # Two locks, always taken in this order: _io (one flush at a time; the rows taken, the Rerun
        # sink and the files), then _lock (what the callers record; held for memory work only).
        self._io = threading.RLock()
        self._lock = threading.RLock()
        self._lost: dict = {}  # tau -> rows (tau, k, j, i, cause) of the consensus messages that did not count

        cap = max(min(int(steps) + 1, _MAX_INITIAL_ROWS), 16)
        self._s = RowStore(self.m, self.n, capacity=cap)  # the rows recorded (under _lock)
        taken = RowStore(self.m, self.n, capacity=cap)  # the rows taken by flushes (under _io, in self._w)
        # a run on measurements or live sensors (set_y_source): what it records beyond the rows
        self._meas = MeasuredRecords(self._lock, taken=taken, agent_ids=self.agent_ids, pos=self._pos)
        started = time.monotonic()

        # Write failures (records.writer's docstring): the first one and whether a caller has seen it.
        self._failed = WriteFailure(self._lock)
        events_path = self.out_dir / EVENTS_FILE
        # resume: (rows on disk, the rrd segment to write) of records a standby takes over (records.recover made
        # them agree first): events.jsonl and the chunks go on, run.rrd in a new segment, trajectory.npz rebuilt
        # from the chunks at the close
        self.resumed = resume
        try:
            self._events = EventLog(events_path, append=resume is not None)  # create / empty events.jsonl
        except OSError as exc:
            raise RecordsWriteError(events_path, strerror(exc)) from None
        if states is not None and len(states) != self.n:
            raise RecordingError(f"states names {len(states)} states; expected {self.n}")
        names = tuple(str(s) for s in states) if states is not None else None
        sink = open_sink(self.out_dir, run_id=self.run_id, scenario_name=self.scenario_name,
                         agent_ids=self.agent_ids, n=self.n, time_mode=time_mode, dt=self.dt,
                         graph_names=self.graph_names, envelope=self.envelope_rate is not None,
                         columns=tuple(columns), positions=dict(positions) if positions else None,
                         viewer=viewer, viewer_port=viewer_port, connect_timeout=connect_timeout,
                         states=names, shown=shown, roll_bytes=continuous.rrd_bytes if continuous else None,
                         record_every=record_every, segment=0 if resume is None else resume[1])
        # trajectory.npz and run.rrd (self._rec is its sink), written by the flushes
        files = RecordFiles(self.out_dir, agent_ids=self.agent_ids, taken=taken, lost=self._lost,
                            extra=self._meas.arrays, failure=self._failed, sink=sink,
                            states=names or default_state_names(self.n), y_rows=self._meas.y_rows,
                            u_rows=self._meas.u_rows,
                            continuous=continuous, dt=self.dt if time_mode == "continuous" else 1.0)
        self._npz_at_close = False  # resumed: trajectory.npz rebuilt from every chunk at the close
        if resume is not None:
            self._s.base = taken.base = files.chunk_rows = files.rrd_rows = int(resume[0])
            self._npz_at_close, files.npz = files.npz, False
        self._w = RecordWriter(taken, files, self._meas, self._events, self._failed, self._lock,
                               envelope_rate=self.envelope_rate, time_mode=time_mode, dt=self.dt)
        self.retention_plan = None  # run.keep's plan (retention.plan), said by the driver at the start
        if continuous is not None and (continuous.keep_hours is not None or continuous.keep_bytes is not None):
            self.retention_plan = plan(continuous)
            self._w.retention = Retention(self.out_dir, files, hours=continuous.keep_hours,
                                          max_bytes=continuous.keep_bytes, emit=self._retention_event,
                                          recording_hours=continuous.keep_recording_hours, prior=resume)
        if sink is not None:
            files.append_rrd()  # header, properties, styles and blueprint: run.rrd exists from the start
        self._reserve = Reserve(self.out_dir, reserve_bytes)
        # what the callers record (the buffer, self._s) and the flushes, on a background thread with flush_seconds > 0
        self._f = Flusher(self._s, self._w, self._failed, self._reserve, io=self._io, lock=self._lock,
                          lost=self._lost, flush_seconds=self.flush_seconds, started=started,
                          window=continuous.window_rows if continuous else None)

    # ------------------------------------------------------------------ time helpers

    def _t_of_tau(self, tau: int) -> float:
        return float(tau) if self.time_mode == "discrete" else tau * self.dt

    def _tau_of_t(self, t: float) -> int:
        return self._w.tau_of_t(t)

    @property
    def _rec(self) -> RerunSink | None:
        """The Rerun sink (None: file records only, or after close)."""
        return self._w.sink

    @property
    def _failure(self) -> RecordsWriteError | None:
        """The first write failure (the recording has stopped), None if none."""
        return self._failed.error

    @property
    def _closed(self) -> bool:
        return self._f.closed

    @property
    def _watcher(self) -> threading.Thread | None:
        """The background flusher's thread (None with ``flush_seconds=0``)."""
        return self._f.watcher

    # ------------------------------------------------------------------ public API

    @property
    def rows_recorded(self) -> int:
        """Number of rows (distinct event times) recorded so far: T of ``trajectory.npz``."""
        return self._s.base + self._s.rows

    @property
    def rows_kept(self) -> int:
        """Rows (event times) that ``trajectory.npz`` and ``run.rrd`` both hold on disk.

        During the run: as of the last successful flush (a background flush may be under way).  After :meth:`close`:
        K, the rows of the closed records (``rows_recorded`` after a normal
        close; after a write failure, as many as the disk allowed).
        """
        return self._w.rows_kept

    def event(self, event: str, t: float, *, level: str | None = None, note: str | None = None, **fields) -> None:
        """Append the event's line to ``events.jsonl`` (docs/reference/files.md, section "Event log") and queue
        its Rerun log.

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
        if "wall" in fields:
            raise RecordingError(f"event {event!r}: field name 'wall' is reserved")
        with self._lock:
            self._check_open("event")
            self._check_failed()
            line = self._events.line(event, t, time.time(), fields)  # TypeError before any write
            try:
                self._events.append(line)
            except OSError as exc:
                raise self._failed.fail(self._events.path, exc, self._tau_of_t(t)) from None
            if self._rec is not None:
                self._f.logs.event(event, self._tau_of_t(t), float(t), event_text(event, fields, note), level)
        self._f.write_through()

    def _retention_event(self, event: str, t: float, fields: dict) -> None:
        """An event of :mod:`.retention`, from a flush (``_io`` held): appended to ``events.jsonl`` and queued for
        Rerun as :meth:`event` does, without flushing (it runs in one); and told on ``splitspec run``'s terminal."""
        told.info("%s", event_text(event, fields))
        with self._lock:
            line = self._events.line(event, t, time.time(), fields)
            try:
                self._events.append(line)
            except OSError as exc:
                raise self._failed.fail(self._events.path, exc, self._tau_of_t(t)) from None
            if self._rec is not None:
                self._f.logs.event(event, self._tau_of_t(t), float(t), event_text(event, fields),
                                   event_level(event))

    def topology(self, tau: int, graph_name: str, alive_ids: Iterable[int],
                 arcs: Iterable[tuple[int, int]], *, partition=None) -> None:
        """Log the communication graph at ``tau``: every agent as a node, arcs ``(j, i)`` among alive agents.

        An arc ``(j, i)`` means agent ``i`` receives from agent ``j`` (drawn j -> i).
        Arcs touching a dead agent are not drawn.  ``partition``: the groups of agent ids of a
        partition in force (:mod:`splitspec_core.model.impairment`), None or empty for none: the arcs
        between groups are drawn dashed (``topology/partition``) and the graph's label names it.
        """
        alive, edges, groups = check_topology(self.agent_ids, self.graph_names, graph_name, alive_ids, arcs, partition)
        cut = cut_edges(groups, edges, self.agent_ids.tolist())
        with self._lock:
            self._check_open("topology")
            self._check_failed()
            if self._rec is not None:
                self._f.logs.topology(int(tau), self._t_of_tau(int(tau)), graph_name, alive, edges, cut, groups)
        self._f.write_through()

    def row(self, tau: int, x: np.ndarray, xhat: np.ndarray, alive: np.ndarray, graph: int, *,
            wall_ms: float | None = None, attempts: int | None = None, rejected: int | None = None, lost=None,
            late_ms: float | None = None, **columns) -> None:
        """Record event time ``tau``: ``x`` (n,), ``xhat`` (m, n), ``alive`` (m,) bool, graph index.

        ``columns``: the agents' reported row columns by name (:data:`splitspec_core.model.rows.REPORTED`),
        (m,) each, e.g. ``g``, each agent's ``g_i(tau)``; one not given is its fill (no gain: discrete
        time); ``wall_ms``, ``attempts``, ``rejected``: the round's
        diagnostics (``rounds/...``), None if unknown, and ``late_ms`` behind ``run.pace``; ``lost``: the round's
        consensus messages that did not count, rows ``(tau, k, j, i, cause)``
        (``trajectory.npz`` ``lost``/``lost_cause``; their count is ``rounds/lost``;
        None: unknown, as in a recorder fed by hand).

        Rows come in increasing ``tau``; a row re-sent for an already recorded
        ``tau`` replaces it.  Rows of dead agents are stored as NaN whatever
        ``xhat`` holds there.  The row is only stored in memory: it reaches
        Rerun, ``run.rrd`` and ``trajectory.npz`` at the next flush, on the
        recorder's background thread (:mod:`splitspec_orchestrator.records.flusher`).
        """
        tau = int(tau)
        x, xhat, alive, reported = check_row(self.m, self.n, len(self.graph_names), x, xhat, alive, graph, columns)
        diag = [np.nan if v is None else float(v) for v in (wall_ms, attempts, rejected,
                                                             None if lost is None else len(lost), late_ms)]
        with self._lock:
            if lost is not None:
                self._lost[tau] = tuple(tuple(int(v) for v in r) for r in lost)
            self._check_open("row")
            self._check_failed()
            recorded = self._s
            last = recorded.tau[recorded.rows - 1] if recorded.rows else None
            if tau not in recorded.row_of_tau and last is not None and tau < last:
                raise RecordingError(f"row for tau={tau} arrives after tau={last}; rows must come in increasing tau")
            self._f.store(tau, self._t_of_tau(tau), x, xhat, alive, graph, reported, diag)
        self._f.write_through()

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
            self._f.lose(int(tau), i, int(agent_id), self._t_of_tau(int(tau)))
        self._f.flush_soon()

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
        row's successor are kept in it (the writer's docstring).  Calling
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
            self._f.close()
            self._meas.closed = True
            if self._meas.source is not None:
                self._w.files.npz_dirty = True  # the last write adds what is known without truth (MeasuredRecords)
            self._f.finish(finished)  # the last flush, run.rrd finished, the recording_closed event
        if self._watcher is not None and self._watcher is not threading.current_thread():
            self._watcher.join(timeout=10.0)
        if self._npz_at_close:
            self._rebuild_trajectory()
        if self._failure is not None and not self._failed.reported and finished:
            self._failed.reported = True
            raise self._failure

    def _rebuild_trajectory(self) -> None:
        """Resumed records: ``trajectory.npz`` from every chunk (the rows before the takeover and after)."""
        from splitspec_core.simulation.simulator import Trajectory
        from splitspec_core.simulation.trajectory_chunks import read_chunks

        try:
            rows = read_chunks(self.out_dir)
            if rows is not None:
                Trajectory.from_arrays(rows).save(self.out_dir / TRAJECTORY_FILE)
        except OSError as exc:
            self._failed.fail(self.out_dir / TRAJECTORY_FILE, exc, None)

    def finish_beside(self, segment: Path):
        """Finish another recording segment of this run (a dead orchestrator's, left without its footer) in a child
        process beside the run, as a rolled one is (:func:`~splitspec_orchestrator.viewer.rrd_file.finish_in_child`):
        its ``Popen``, None without Rerun."""
        from ..viewer.rrd_file import finish_in_child, rrd_index

        args = self.layout_args()
        return None if args is None else finish_in_child(segment, args, has_layout=rrd_index(segment) == 0)

    def layout_args(self) -> dict | None:
        """The arguments of the recording's default layout (what a segment finished beside the run gets; JSON), None
        without Rerun."""
        sink = self._w.sink
        return None if sink is None else sink.blueprint_args()

    def fence_with(self, superseded) -> None:
        """``superseded()``: whether another process holds these records now (a standby took the run over); the
        background flushes ask it first and stop writing for good once it says so (:meth:`abandon` follows)."""
        self._f.fence = superseded

    def abandon(self) -> None:
        """Another orchestrator took these records over (a standby, while this one was cut off): stop writing at
        once; nothing more is flushed, finished or closed here."""
        with self._io, self._lock:
            if self._closed:
                return
            self._f.close()
            self._npz_at_close = False
            self._w.disconnect()

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
        self._failed.check()

    def _flush(self, *, final: bool = False) -> None:
        """A flush now, in the caller's thread (:meth:`Flusher.flush`); ``final``: the recording's last."""
        self._f.flush(final=final)

    def set_measurements(self, sc, meas) -> None:
        """The run plays a measurements file (:class:`splitspec_core.scenarios.measurements.Measurements`): see
        :meth:`set_y_source`; the truth is the file's ``x`` if it has one."""
        from ..viewer.reference_view import file_rows

        self.set_y_source(sc, file_rows(meas), truth=meas.has_truth)
        self.set_inputs(sc, meas.u)

    def set_inputs(self, sc, u=None) -> None:
        """Record the known inputs the estimators use (``system.B``; nothing without): ``u`` (T, p), a measurements
        file's rows, else the scenario's signal, or with live inputs (``sources.inputs``) what :meth:`live_u` is
        given; ``trajectory.npz`` and the chunks get ``u``.  Call before the first row."""
        with self._io, self._lock:
            if self._s.rows:
                raise RecordingError("set_inputs() after the first row: its u would be missing from the records")
            self._meas.set_inputs(sc, u)

    def set_y_source(self, sc, y_row, *, truth: bool) -> None:
        """The estimators run on measurements ``y_row(tau) -> (y, missing) | None``
        (:data:`splitspec_orchestrator.viewer.reference_view.YRow`); call before the first row.

        ``trajectory.npz`` gets their ``y`` and ``y_missing`` rows, and at the close what is known without
        truth (:func:`splitspec_core.studies.no_truth.no_truth_arrays`); ``run.rrd`` the same as it goes
        (:mod:`splitspec_orchestrator.viewer.reference_view`) and, ``truth=False``, no error and no truth at all.
        """
        from ..viewer.reference_view import ReferenceRows

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
        self.set_inputs(sc)

    def live_y(self, tau: int, used) -> None:
        """Event time ``tau``'s ``(agent id, y_i(tau) or None)`` of the agents alive (the others: missing, NaN);
        before :meth:`row` of ``tau``, so that a flush never takes the row without its measurements."""
        self._meas.live_y(tau, used)

    def live_u(self, tau: int, used) -> tuple:
        """Event time ``tau``'s ``(agent id, u(tau))`` of the live known inputs the alive agents took (the first
        agent's is recorded: :meth:`MeasuredRecords.live_u`); before :meth:`row` of ``tau``, as :meth:`live_y`.
        Returns the recorded agent's id and the ids of the agents that took another value."""
        return self._meas.live_u(tau, used)
