"""Run recorder of the orchestrator: ``trajectory.npz``, ``events.jsonl`` and ``run.rrd``.

The orchestrator hands the recorder one row per event time ``tau`` (true state
``x(tau)``, every agent's estimate ``x_i(tau)``, the alive set and the active
graph), the topology on every switch or death, and named events.  The recorder
keeps three records of the run in ``out_dir``:

``trajectory.npz``
    the trajectory contract of DESIGN.md ("Trajectories"): ``t`` (T,),
    ``x`` (T, n), ``xhat`` (T, m, n) NaN where dead, ``alive`` (T, m) bool,
    ``graph`` (T,) int, ``agent_ids`` (m,).  Rewritten atomically (temporary
    file in ``out_dir`` + ``os.replace``) at every flush (see below) and always
    in :meth:`Recorder.close`, so after a crash it holds every row up to the
    last flush.
``events.jsonl``
    one JSON object per line, ``{"event", "t", "wall", **fields}``, flushed
    after every line.
``run.rrd``
    a Rerun recording (DESIGN.md "Rerun recording"), optionally streamed live
    to a viewer as well; appended by Python at every flush and finished (footer,
    verifiable) at close, see "Write failures and consistency" below.

Rerun entities (``<id>`` is an agent id, ``<k>`` = 1..n a state component):

=========================  ==================================================
``errors/agent_<id>``      ``|x_i(tau) - x(tau)|_2``, alive agents only
``errors/max``             ``max_i |x_i(tau) - x(tau)|_2`` over alive agents
``state/<k>/truth``        ``x_k(tau)``
``state/<k>/agent_<id>``   ``x_{i,k}(tau)``, alive agents only
``topology``               GraphNodes (every agent, lost ones grey) + directed
                           GraphEdges ``(j, i)``: i receives from j
``events``                 TextLog (WARN for lost/rejected/error/failed)
=========================  ==================================================

Timelines: ``event`` (sequence ``tau``), ``time`` (duration: ``tau`` seconds
in discrete time, ``tau * dt`` in continuous time) and ``wall`` (timestamp).
A value that stops being true (an agent lost from ``tau`` on after its rows
were logged, or a row re-sent for the same ``tau`` without an agent) is
retracted with a non-recursive ``rr.Clear`` at that event time; :func:`read_rrd`
applies those clears, as the viewer's latest-at queries do.

Buffering: :meth:`Recorder.row` only stores the row (a few microseconds).
Rows reach Rerun in batches: one ``send_columns`` chunk per entity per flush
(an agent's chunks hold only the event times where it is shown).  The Rerun
logs of :meth:`Recorder.event` and :meth:`Recorder.topology` are queued and
sent after the rows buffered before them, one chunk per flush each.  A flush
(buffered rows, then queued logs, then ``trajectory.npz``) happens when
``flush_seconds`` of wall time have passed since the last one -- checked on
every recorder call and by a background thread, so a live viewer is never
more than about ``flush_seconds`` behind even when rows stop coming -- and on
:meth:`Recorder.mark_lost`, :meth:`Recorder.flush`, :meth:`Recorder.close`
and at a normal interpreter exit without ``close`` (which also finishes
``run.rrd`` with its footer, but writes no ``recording_closed`` event).  ``events.jsonl`` is still
written and flushed line by line.  Values that were never sent need no
``Clear``: a row re-sent or an agent lost before the flush simply changes
what is sent.

Rerun never stops a run: a viewer that cannot be spawned or reached, or a
failing flush, is logged as a warning and the recording goes on (file only).

Write failures and consistency
------------------------------
A failed write of any of the three files (ENOSPC, EROFS, EACCES, EDQUOT...)
*does* stop the recording: it raises :class:`RecordsWriteError`
(``cannot write <path>: <strerror>``, with ``path``, ``strerror``, ``tau``)
from the call that hit it, or -- when the background flusher hit it -- from the
next ``row``/``event``/``topology``/``mark_lost``/``flush``; every later call
raises it again.

``run.rrd`` is written by Python, not by Rerun's ``FileSink`` (whose Rust
thread never reports a failed write): the recording logs into an
``rr.binary_stream()`` and each flush appends the bytes read from it to
``run.rrd`` with ordinary file calls that raise ``OSError`` (see
:mod:`orchestrator.rrdfile` for the format).  During the run ``run.rrd`` is a
footer-less RRD stream, readable with ``RrdReader(path).stream()``; at
:meth:`Recorder.close` it is rewritten as one RRD with footer, which ``rerun
rrd verify`` accepts.  ``events.jsonl`` and ``run.rrd`` are opened per write
(no file of the run stays open between calls), a torn line or message is cut
back after a failed write.

A flush writes ``run.rrd`` first, then ``trajectory.npz``, so the npz never
holds an event time the rrd lacks and a SIGKILL loses at most the rows of one
flush period from both.  ``close(finished=False)`` after a write failure does
not raise: it removes the disk-space reserve (``.splitspec-reserve``, a few
MB preallocated at start, :class:`orchestrator.outdir.Reserve`), writes what
the failure left unwritten, and leaves K = :attr:`Recorder.rows_kept` rows in
``trajectory.npz``, the data of those K event times only in ``run.rrd``
(rewritten, verifiable; text log and topology up to the next event time) and
a last ``recording_closed`` event with ``rows: K`` in ``events.jsonl`` -- each
as far as the disk allows.  On a read-only file system nothing more can be
written: K is what the last successful flush left in both ``trajectory.npz``
and the footer-less ``run.rrd``; ``splitspec recover`` (:mod:`orchestrator.recover`)
finishes the job once the disk is writable.  The same command repairs the
records of a killed run.
"""

from __future__ import annotations

import atexit
import json
import logging
import math
import os
import socket
import subprocess
import sys
import tempfile
import threading
import time
import weakref
from pathlib import Path
from typing import Any, Iterable
from urllib.parse import urlsplit

import numpy as np

from splitspec_core.errors import SplitspecError

from .outdir import Reserve
from .rrdfile import RrdAppender, rewrite_rrd

__all__ = ["Recorder", "RecordingError", "RecordsWriteError", "read_rrd", "verify_rrd"]

log = logging.getLogger(__name__)

APPLICATION_ID = "splitspec"
TRAJECTORY_FILE = "trajectory.npz"
EVENTS_FILE = "events.jsonl"
RRD_FILE = "run.rrd"
RESERVE_BYTES = 4 << 20  # disk-space reserve released on ENOSPC to write the final records
_MAX_INITIAL_ROWS = 1024  # row storage starts at most this big (``steps`` is a hint) and doubles

# Rerun entity paths and timelines (built here only).
ERRORS = "errors"
ERRORS_MAX = "errors/max"
STATE = "state"
TOPOLOGY = "topology"
EVENTS = "events"
TL_EVENT, TL_TIME, TL_WALL = "event", "time", "wall"

# Column names of a chunk's record batch in rerun 0.41 (found by experiment:
# index columns are named after their timeline, data columns "Archetype:field").
_COL_SCALARS = "Scalars:scalars"
_COL_CLEAR = "Clear:is_recursive"
_COL_ROW_ID = "rerun.controls.RowId"

_WARN_WORDS = ("lost", "rejected", "error", "failed")
_DEFAULT_VIEWER_PORT = 9876
_PALETTE = [  # matplotlib tab10
    (31, 119, 180), (255, 127, 14), (44, 160, 44), (214, 39, 40), (148, 103, 189),
    (140, 86, 75), (227, 119, 194), (127, 127, 127), (188, 189, 34), (23, 190, 207),
]
_DEAD_COLOR = (90, 90, 90)
_MAX_COLOR = (235, 235, 235)
_TRUTH_COLOR = (235, 235, 235)

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
            with rec._lock:
                if not rec._closed and rec._failure is None:
                    rec._flush()
                    # run.rrd with its footer, as a Rerun FileSink would leave it; nothing is recorded after this
                    rec._closed = True
                    rec._stop.set()
                    rec._finish_rrd(rec._rows_kept)
                    rec._reserve.release()
        except Exception as exc:
            log.warning("flush at exit failed (%s: %s)", type(exc).__name__, exc)


class RecordingError(SplitspecError, ValueError):
    """A recorder call does not fit the run (shape, agent id, graph, order); the message names it."""


class RecordsWriteError(SplitspecError, RuntimeError):
    """A record of the run (``trajectory.npz``, ``events.jsonl``, ``run.rrd``) could not be written.

    One line, ``cannot write <path>: <strerror>``.  Attributes: ``path``,
    ``strerror`` (e.g. ``No space left on device``) and ``tau``, the event time
    being recorded when the write failed (None if unknown).
    """

    def __init__(self, path: str | Path, strerror: str, tau: int | None = None):
        self.path, self.strerror, self.tau = Path(path), str(strerror), tau
        super().__init__(f"cannot write {self.path}: {self.strerror}")


def _strerror(exc: OSError) -> str:
    if exc.strerror:
        return exc.strerror
    if exc.errno:
        return os.strerror(exc.errno)
    return str(exc) or type(exc).__name__


def _agent_path(prefix: str, agent_id: int) -> str:
    return f"{prefix}/agent_{agent_id}"


def _state_path(k: int, who: str) -> str:
    """``state/<k>/<who>`` with the 1-based component index ``k``."""
    return f"{STATE}/{k}/{who}"


def _json_default(obj: Any) -> Any:
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, (set, frozenset)):
        return sorted(obj)
    if isinstance(obj, Path):
        return str(obj)
    raise TypeError(f"event field of type {type(obj).__name__} is not JSON serialisable")


def _reachable(host: str, port: int, timeout: float) -> bool:
    try:
        with socket.create_connection((host, port), timeout=timeout):
            return True
    except OSError:
        return False


def _viewer_url(viewer: str) -> str:
    """Accept a full ``rerun+http://host:port/proxy`` URL or a bare ``host:port``."""
    return viewer if "://" in viewer else f"rerun+http://{viewer}/proxy"


def _url_host_port(url: str) -> tuple[str, int]:
    parts = urlsplit(url)
    default = 443 if parts.scheme.endswith("https") else _DEFAULT_VIEWER_PORT
    return parts.hostname or "127.0.0.1", parts.port or default


def _blueprint(time_mode: str):
    """The default blueprint of a run's recording (the time panel follows ``time_mode``)."""
    import rerun.blueprint as rrb

    # No log-scale y axis in rerun 0.41's ScalarAxis (rerun issue #6773); errors are
    # positive, so a log axis can be switched on if a later viewer offers one.
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Vertical(
                rrb.TimeSeriesView(origin=ERRORS, name="estimation errors |x_i - x|"),
                rrb.TimeSeriesView(origin=STATE, name="state: truth and estimates"),
            ),
            rrb.Vertical(
                rrb.GraphView(origin=TOPOLOGY, name="communication graph"),
                rrb.TextLogView(origin=EVENTS, name="events"),
            ),
            column_shares=[2, 1],
        ),
        rrb.TimePanel(timeline=TL_EVENT if time_mode == "discrete" else TL_TIME),
    )


def _rerun_command() -> list[str]:
    """The bundled ``rerun`` CLI: the executable next to ``sys.executable``, else ``python -m rerun``."""
    exe = Path(sys.executable).parent / ("rerun.exe" if os.name == "nt" else "rerun")
    return [str(exe)] if exe.exists() else [sys.executable, "-m", "rerun"]


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
    flush_seconds : wall-time period of the flushes (buffered rows and queued logs to Rerun,
        ``trajectory.npz`` rewritten); ``0`` flushes on every call
    viewer_port : port of a spawned viewer
    connect_timeout : seconds to wait when checking that a viewer is reachable
    reserve_bytes : size of the disk-space reserve ``.splitspec-reserve`` kept in ``out_dir``
        until close (at most 1/8 of the free space; ``0``: none)

    Raises
    ------
    RecordsWriteError
        If ``out_dir``, ``events.jsonl`` or ``run.rrd`` cannot be created.
    """

    def __init__(self, out_dir: Path, *, agent_ids: tuple[int, ...], n: int, steps: int, time_mode: str,
                 dt: float, graph_names: tuple[str, ...], run_id: str, scenario_name: str,
                 viewer: str | None = None, flush_seconds: float = 1.0,
                 viewer_port: int = _DEFAULT_VIEWER_PORT, connect_timeout: float = 1.0,
                 reserve_bytes: int = RESERVE_BYTES):
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

        self.out_dir = Path(out_dir)
        try:
            self.out_dir.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise RecordsWriteError(self.out_dir, _strerror(exc)) from None
        self.agent_ids = np.array(ids, dtype=np.int64)
        self.m, self.n = len(ids), int(n)
        self.time_mode, self.dt = time_mode, float(dt)
        self.graph_names = tuple(graph_names)
        self.run_id, self.scenario_name = str(run_id), str(scenario_name)
        self.flush_seconds = float(flush_seconds)
        self._pos = {a: k for k, a in enumerate(ids)}
        self._lock = threading.RLock()
        self._closed = False

        # Row storage: starts small (steps is only a hint) and grows by doubling; T = self._rows.
        cap = max(min(int(steps) + 1, _MAX_INITIAL_ROWS), 16)
        self._t = np.zeros(cap)
        self._x = np.zeros((cap, self.n))
        self._xhat = np.full((cap, self.m, self.n), np.nan)
        self._alive = np.zeros((cap, self.m), dtype=bool)
        self._graph = np.zeros(cap, dtype=np.int64)
        self._tau = np.zeros(cap, dtype=np.int64)
        self._wall = np.zeros(cap, dtype=np.int64)  # time.time_ns() of the row's (last) arrival
        # What is currently shown in Rerun per row (to retract with Clear when it stops being true).
        self._shown = np.zeros((cap, self.m), dtype=bool)
        self._shown_max = np.zeros(cap, dtype=bool)
        self._rows = 0
        self._row_of_tau: dict[int, int] = {}
        # Buffer: rows _sent.._rows-1 were never sent to Rerun; _dirty holds sent rows that changed
        # (re-sent tau, agent lost) and are sent again whole.  _queued_events / _queued_topology hold
        # the deferred Rerun logs of event() / topology() in call order, sent as one chunk each.
        self._sent = 0
        self._dirty: set[int] = set()
        self._queued_events: list[tuple[int, float, str, str, int]] = []
        self._queued_topology: list[tuple[int, float, str, set[int], list[tuple[str, str]], int]] = []
        self._traj_dirty = False
        self._last_flush = time.monotonic()

        # Write failures (see the module docstring): the first one, whether a caller has seen it,
        # what is on disk (rows of trajectory.npz and of run.rrd, bytes of events.jsonl).
        self._failure: RecordsWriteError | None = None
        self._failure_reported = False
        self._npz_rows = 0
        self._rrd_rows = 0
        self._rows_kept = 0
        self._events_path = self.out_dir / EVENTS_FILE
        self._events_size = 0
        try:
            self._write_events(b"", mode="wb")  # create / empty events.jsonl
        except OSError as exc:
            raise RecordsWriteError(self._events_path, _strerror(exc)) from None
        self._rrd_file = RrdAppender(self.out_dir / RRD_FILE)
        self._rrd_pending: list[bytes] = []  # read from Rerun, not yet on disk
        self._stream = None
        self._rec = None
        self._viewer_warned = False
        try:
            self._rec = self._open_rerun(viewer, viewer_port=viewer_port, connect_timeout=connect_timeout)
        except Exception as exc:  # Rerun must never stop a run
            log.warning("Rerun recording disabled (%s: %s); writing trajectory.npz and events.jsonl only",
                        type(exc).__name__, exc)
            self._rec = None
        if self._rec is not None:
            self._append_rrd()  # header, properties, styles and blueprint: run.rrd exists from the start
        self._reserve = Reserve(self.out_dir, reserve_bytes)
        _OPEN.add(self)
        _register_exit_flush()
        self._stop = threading.Event()
        self._watcher = None
        if self.flush_seconds > 0:  # with 0 every call flushes: nothing is left waiting
            self._watcher = threading.Thread(target=_watch, args=(weakref.ref(self), self._stop),
                                             name="splitspec-recorder-flush", daemon=True)
            self._watcher.start()

    # ------------------------------------------------------------------ Rerun setup

    def _open_rerun(self, viewer: str | None, *, viewer_port: int, connect_timeout: float):
        import rerun as rr

        rec = rr.RecordingStream(application_id=APPLICATION_ID, recording_id=self.run_id)
        # run.rrd: Python appends what it reads from this stream (see the module docstring).
        self._stream = rr.binary_stream(rec)
        sinks: list[Any] = [self._stream]
        live = self._viewer_sink(rr, rec, viewer, viewer_port=viewer_port, connect_timeout=connect_timeout)
        if live is not None:
            sinks.append(live)
        # Both sinks at once: set_sinks replaces the stream's sinks with this tee.
        rec.set_sinks(*sinks, default_blueprint=self._blueprint())
        rec.send_recording_name(f"{self.scenario_name} ({self.run_id})")
        rec.send_property("splitspec", rr.AnyValues(
            scenario=self.scenario_name, run_id=self.run_id, time_mode=self.time_mode, dt=self.dt,
            n=self.n, m=self.m, agent_ids=self.agent_ids.tolist(), graphs=list(self.graph_names)))
        self._log_static_styles(rr, rec)
        return rec

    def _viewer_sink(self, rr, rec, viewer: str | None, *, viewer_port: int, connect_timeout: float):
        """The ``rr.GrpcSink`` of the live viewer, or None (file only, with a warning)."""
        if viewer is None:
            return None
        if viewer == "spawn":
            if sys.platform.startswith("linux") and not any(
                    os.environ.get(v) for v in ("DISPLAY", "WAYLAND_DISPLAY", "WAYLAND_SOCKET")):
                # The native viewer exits at once without a display; rr.spawn would wait ~6 s for it.
                log.warning("no display (DISPLAY/WAYLAND_DISPLAY unset): not spawning a Rerun viewer; "
                            "recording to %s only", RRD_FILE)
                return None
            cmd = _rerun_command()
            try:
                # connect=False: the gRPC sink is added with the file sink in set_sinks.
                rr.spawn(port=viewer_port, connect=False, recording=rec,
                         executable_path=cmd[0] if len(cmd) == 1 else None)
            except Exception as exc:
                log.warning("could not spawn a Rerun viewer (%s: %s); recording to %s only",
                            type(exc).__name__, exc, RRD_FILE)
                return None
            url = f"rerun+http://127.0.0.1:{viewer_port}/proxy"
        else:
            url = _viewer_url(viewer)
        host, port = _url_host_port(url)
        # GrpcSink does not fail on an unreachable viewer: set_sinks blocks ~5 s and
        # every later flush raises.  Check first and fall back to the file.
        if not _reachable(host, port, connect_timeout):
            log.warning("Rerun viewer at %s is not reachable; recording to %s only", url, RRD_FILE)
            return None
        try:
            return rr.GrpcSink(url)
        except Exception as exc:
            log.warning("invalid Rerun viewer URL %r (%s); recording to %s only", url, exc, RRD_FILE)
            return None

    def _blueprint(self):
        return _blueprint(self.time_mode)

    def _color(self, i: int) -> tuple[int, int, int]:
        return _PALETTE[i % len(_PALETTE)]

    def _log_static_styles(self, rr, rec) -> None:
        rec.log(ERRORS_MAX, rr.SeriesLines(names="max", colors=[_MAX_COLOR], widths=2.0), static=True)
        for i, a in enumerate(self.agent_ids):
            rec.log(_agent_path(ERRORS, a), rr.SeriesLines(names=f"agent {a}", colors=[self._color(i)]),
                    static=True)
        for k in range(1, self.n + 1):
            rec.log(_state_path(k, "truth"), rr.SeriesLines(names=f"x{k} truth", colors=[_TRUTH_COLOR],
                                                            widths=2.0), static=True)
            for i, a in enumerate(self.agent_ids):
                rec.log(_state_path(k, f"agent_{a}"),
                        rr.SeriesLines(names=f"x{k} agent {a}", colors=[self._color(i)]), static=True)

    def _rerun(self, what: str, fn, *args) -> None:
        """Run one Rerun logging step; a failure is a warning, never an exception."""
        if self._rec is None:
            return
        try:
            fn(*args)
        except Exception as exc:
            log.warning("Rerun %s failed (%s: %s); continuing", what, type(exc).__name__, exc)

    # ------------------------------------------------------------------ time helpers

    def _t_of_tau(self, tau: int) -> float:
        return float(tau) if self.time_mode == "discrete" else tau * self.dt

    def _tau_of_t(self, t: float) -> int:
        return int(round(t)) if self.time_mode == "discrete" else int(round(t / self.dt))

    # ------------------------------------------------------------------ public API

    @property
    def rows_recorded(self) -> int:
        """Number of rows (distinct event times) recorded so far: T of ``trajectory.npz``."""
        return self._rows

    @property
    def rows_kept(self) -> int:
        """Rows (event times) that ``trajectory.npz`` and ``run.rrd`` both hold on disk.

        During the run: as of the last successful flush.  After :meth:`close`:
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
        ``note`` replaces the fields in the Rerun text (``"<event>: <note>"``);
        ``events.jsonl`` always has every field.
        """
        if level is None:
            level = "WARN" if any(w in event.lower() for w in _WARN_WORDS) else "INFO"
        self._event(event, t, level, fields, note)

    def _event(self, event: str, t: float, level: str, fields: dict[str, Any], note: str | None = None) -> None:
        if "wall" in fields:
            raise RecordingError(f"event {event!r}: field name 'wall' is reserved")
        with self._lock:
            self._check_open("event")
            self._check_failed()
            wall = time.time()
            line = json.dumps({"event": event, "t": t, "wall": wall, **fields}, default=_json_default)
            try:
                self._write_events((line + "\n").encode("utf-8"))
            except OSError as exc:
                raise self._fail(self._events_path, exc, self._tau_of_t(t)) from None
            if self._rec is not None:
                text = f"{event}: {note}" if note else event + "".join(f" {k}={v}" for k, v in fields.items())
                self._queued_events.append((self._tau_of_t(t), float(t), text, level, time.time_ns()))
            self._maybe_flush()

    def topology(self, tau: int, graph_name: str, alive_ids: Iterable[int],
                 arcs: Iterable[tuple[int, int]]) -> None:
        """Log the communication graph at ``tau``: every agent as a node, arcs ``(j, i)`` among alive agents.

        An arc ``(j, i)`` means agent ``i`` receives from agent ``j`` (drawn j -> i).
        Arcs touching a dead agent are not drawn.
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
        with self._lock:
            self._check_open("topology")
            self._check_failed()
            if self._rec is not None:
                self._queued_topology.append((int(tau), self._t_of_tau(int(tau)), graph_name, alive, edges,
                                              time.time_ns()))
            self._maybe_flush()

    @staticmethod
    def _index_columns(rr, taus, seconds, walls_ns) -> list:
        """The three timeline columns (``event``, ``time``, ``wall``) of a batch of rows."""
        dur = np.round(np.asarray(seconds, dtype=float) * 1e9).astype(np.int64).astype("timedelta64[ns]")
        return [rr.TimeColumn(TL_EVENT, sequence=np.asarray(taus, dtype=np.int64)),
                rr.TimeColumn(TL_TIME, duration=dur),
                rr.TimeColumn(TL_WALL, timestamp=np.asarray(walls_ns, dtype=np.int64).astype("datetime64[ns]"))]

    def _send_events(self, queued: list[tuple[int, float, str, str, int]]) -> None:
        """Queued event() logs as one TextLog chunk on ``events`` (one row per event, in call order)."""
        import rerun as rr

        taus, seconds, texts, levels, walls = zip(*queued)
        self._rec.send_columns(EVENTS, indexes=self._index_columns(rr, taus, seconds, walls),
                               columns=rr.TextLog.columns(text=list(texts), level=list(levels)))

    def _send_topology(self, queued: list[tuple[int, float, str, set[int], list[tuple[str, str]], int]]) -> None:
        """Queued topology() logs as one chunk on ``topology``: GraphNodes + directed GraphEdges + graph name."""
        import rerun as rr

        ids = self.agent_ids.tolist()
        node_ids, labels, colors, edges, edge_counts = [], [], [], [], []
        for _, _, _, alive, row_edges, _ in queued:
            node_ids += [str(a) for a in ids]
            labels += [f"agent {a}" if a in alive else f"agent {a} (lost)" for a in ids]
            colors += [self._color(k) if a in alive else _DEAD_COLOR for k, a in enumerate(ids)]
            edges += row_edges
            edge_counts.append(len(row_edges))
        taus, seconds, names, _, _, walls = zip(*queued)
        rows = len(queued)
        columns = [*rr.GraphNodes.columns(node_ids=node_ids, labels=labels, colors=colors).partition([len(ids)] * rows),
                   *rr.GraphEdges.columns(edges=edges).partition(edge_counts),
                   *rr.GraphEdges.columns(graph_type=["directed"] * rows),
                   *rr.AnyValues.columns(graph_name=list(names))]
        self._rec.send_columns(TOPOLOGY, indexes=self._index_columns(rr, taus, seconds, walls), columns=columns)

    def row(self, tau: int, x: np.ndarray, xhat: np.ndarray, alive: np.ndarray, graph: int) -> None:
        """Record event time ``tau``: ``x`` (n,), ``xhat`` (m, n), ``alive`` (m,) bool, graph index.

        Rows come in increasing ``tau``; a row re-sent for an already recorded
        ``tau`` replaces it.  Rows of dead agents are stored as NaN whatever
        ``xhat`` holds there.  The row is buffered: it reaches Rerun and
        ``trajectory.npz`` at the next flush (see the module docstring).
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
        with self._lock:
            self._check_open("row")
            self._check_failed()
            k = self._row_of_tau.get(tau)
            if k is None:
                if self._rows and tau < self._tau[self._rows - 1]:
                    raise RecordingError(f"row for tau={tau} arrives after tau={self._tau[self._rows - 1]}; "
                                         "rows must come in increasing tau")
                k = self._append_slot(tau)
            elif k < self._sent:
                self._dirty.add(k)  # already in Rerun: send the whole row again (newest wins)
            self._t[k] = self._t_of_tau(tau)
            self._x[k] = x
            self._xhat[k] = np.where(alive[:, None], xhat, np.nan)
            self._alive[k] = alive
            self._graph[k] = int(graph)
            self._wall[k] = time.time_ns()
            self._traj_dirty = True
            self._maybe_flush()

    def _append_slot(self, tau: int) -> int:
        k = self._rows
        if k == self._t.shape[0]:
            self._grow()
        self._tau[k] = tau
        self._row_of_tau[tau] = k
        self._rows += 1
        return k

    def _grow(self) -> None:
        def bigger(a: np.ndarray, fill) -> np.ndarray:
            b = np.full((2 * a.shape[0],) + a.shape[1:], fill, dtype=a.dtype)
            b[: a.shape[0]] = a
            return b

        self._t, self._x = bigger(self._t, 0.0), bigger(self._x, 0.0)
        self._xhat, self._alive = bigger(self._xhat, np.nan), bigger(self._alive, False)
        self._graph, self._tau = bigger(self._graph, 0), bigger(self._tau, 0)
        self._wall = bigger(self._wall, 0)
        self._shown, self._shown_max = bigger(self._shown, False), bigger(self._shown_max, False)

    def _row_errors(self, K: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``|x_i - x|_2`` of rows ``K`` (L, m), NaN if dead, and where it is shown (alive and finite)."""
        err = np.linalg.norm(self._xhat[K] - self._x[K][:, None, :], axis=2)
        return err, self._alive[K] & np.isfinite(err)

    def _send_rows(self, K: np.ndarray, err: np.ndarray, show: np.ndarray) -> None:
        """Send rows ``K`` (row indices, increasing ``tau``) to Rerun: one chunk per entity.

        Values go where an agent is shown (alive, finite estimate); a non-recursive
        ``Clear`` goes where a value was shown by an earlier flush and is no longer
        true.  Per entity, each event time appears at most once per flush, so the
        newest flush wins on read.
        """
        import rerun as rr

        send = self._rec.send_columns
        L = len(K)
        seq, t, wall = self._tau[K], self._t[K], self._wall[K]
        x, xhat = self._x[K], self._xhat[K]
        clear = self._shown[K] & ~show
        show_max = show.any(axis=1)
        clear_max = self._shown_max[K] & ~show_max
        err_max = np.max(np.where(show, err, -np.inf), axis=1)

        indexes: dict[bytes, list] = {}
        clears: dict[int, Any] = {}

        def index(mask: np.ndarray) -> list:
            key = mask.tobytes()
            cols = indexes.get(key)
            if cols is None:
                cols = indexes[key] = self._index_columns(rr, seq[mask], t[mask], wall[mask])
            return cols

        def send_clear(path: str, mask: np.ndarray) -> None:
            cnt = int(mask.sum())
            if cnt not in clears:
                clears[cnt] = rr.Clear.columns(is_recursive=np.zeros(cnt, dtype=bool))
            send(path, indexes=index(mask), columns=clears[cnt])

        every = np.ones(L, dtype=bool)
        for c in range(self.n):
            send(_state_path(c + 1, "truth"), indexes=index(every), columns=rr.Scalars.columns(scalars=x[:, c]))
        for i, a in enumerate(self.agent_ids.tolist()):
            mask = show[:, i]
            if mask.any():
                send(_agent_path(ERRORS, a), indexes=index(mask), columns=rr.Scalars.columns(scalars=err[mask, i]))
                for c in range(self.n):
                    send(_state_path(c + 1, f"agent_{a}"), indexes=index(mask),
                         columns=rr.Scalars.columns(scalars=xhat[mask, i, c]))
            mask = clear[:, i]
            if mask.any():
                send_clear(_agent_path(ERRORS, a), mask)
                for c in range(self.n):
                    send_clear(_state_path(c + 1, f"agent_{a}"), mask)
        if show_max.any():
            send(ERRORS_MAX, indexes=index(show_max), columns=rr.Scalars.columns(scalars=err_max[show_max]))
        if clear_max.any():
            send_clear(ERRORS_MAX, clear_max)

    def mark_lost(self, tau: int, agent_id: int) -> None:
        """Agent ``agent_id`` is lost from event time ``tau`` on: NaN/False in every recorded row with ``tau' >= tau``.

        Buffered rows simply lose the agent's values; rows already in Rerun get a
        ``Clear`` (and a new ``errors/max``).  Then everything is flushed.
        """
        i = self._pos.get(int(agent_id))
        if i is None:
            raise RecordingError(f"agent {agent_id} is not an agent of this run {tuple(self.agent_ids)}")
        with self._lock:
            self._check_open("mark_lost")
            self._check_failed()
            T = self._rows
            rows = np.nonzero(self._tau[:T] >= int(tau))[0]
            for k in rows:
                if not self._alive[k, i]:
                    continue
                self._alive[k, i] = False
                self._xhat[k, i] = np.nan
                self._traj_dirty = True
                if k < self._sent and self._shown[k, i]:
                    self._dirty.add(int(k))
            self._flush()

    def flush(self) -> None:
        """Send the buffered rows and queued logs to Rerun and rewrite ``trajectory.npz`` now."""
        with self._lock:
            self._check_open("flush")
            self._check_failed()
            self._flush()

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
        with self._lock:
            if self._closed:
                return
            self._closed = True
            self._stop.set()
            _OPEN.discard(self)
            try:
                if self._failure is None:
                    try:
                        self._flush()
                    except RecordsWriteError:
                        pass
                if self._failure is not None:
                    self._reserve.release()  # room for the final records
                    self._salvage()
                K = self._rows_kept
                ok = bool(finished) and self._failure is None
                fields: dict[str, Any] = {"finished": ok, "rows": K}
                if self._failure is not None:
                    fields["error"] = str(self._failure)
                self._close_event(float(self._t[K - 1]) if K else 0.0, "INFO" if ok else "WARN", fields)
                self._finish_rrd(K)
            finally:
                self._reserve.release()
                if self._rec is not None:
                    self._rerun("disconnect", self._rec.disconnect)
                    self._rec = None
            if self._failure is not None and not self._failure_reported and finished:
                self._failure_reported = True
                raise self._failure

    def __del__(self) -> None:
        # Dropped without close(): send what is buffered (logging used to be immediate).
        try:
            if not self._closed and self._failure is None:
                with self._lock:
                    self._flush()
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
            self._failure_reported = True
            raise self._failure

    def _fail(self, path: Path, exc: OSError, tau: int | None) -> RecordsWriteError:
        """The :class:`RecordsWriteError` of ``exc``; the first one is kept (the recording stops)."""
        err = RecordsWriteError(path, _strerror(exc), tau)
        if self._failure is None:
            self._failure = err
            log.info("recording stopped: %s", err)  # the driver prints the one line
        self._failure_reported = True  # raised to the caller (the background flusher resets this)
        return err

    def _last_tau(self) -> int | None:
        return int(self._tau[self._rows - 1]) if self._rows else None

    def _maybe_flush(self) -> None:
        if time.monotonic() - self._last_flush >= self.flush_seconds:
            self._flush()

    def _pending(self) -> bool:
        return (self._sent < self._rows or bool(self._dirty) or bool(self._queued_events)
                or bool(self._queued_topology) or self._traj_dirty or bool(self._rrd_pending))

    def _flush(self, *, write_trajectory: bool = True) -> None:
        """Buffered rows, then queued logs, to Rerun and ``run.rrd``; then ``trajectory.npz``.  Lock held.

        ``run.rrd`` first: ``trajectory.npz`` never holds a row that ``run.rrd`` lacks.

        Raises
        ------
        RecordsWriteError
            If ``run.rrd`` or ``trajectory.npz`` cannot be written.
        """
        self._last_flush = time.monotonic()
        K = np.array(sorted(self._dirty.union(range(self._sent, self._rows))), dtype=np.int64)
        events, self._queued_events = self._queued_events, []
        topology, self._queued_topology = self._queued_topology, []
        if len(K):
            err, show = self._row_errors(K)
            if self._rec is not None:
                self._rerun("row log", self._send_rows, K, err, show)
            # What Rerun now shows (also when a send failed: it is not retried).
            self._shown[K] = show
            self._shown_max[K] = show.any(axis=1)
        if events:
            self._rerun("event log", self._send_events, events)
        if topology:
            self._rerun("topology log", self._send_topology, topology)
        self._sent = self._rows
        self._dirty.clear()
        if len(K) or events or topology or self._rrd_pending:
            self._append_rrd()
        if write_trajectory and (self._traj_dirty or self._npz_rows != self._rows):
            self._write_trajectory()
        self._rows_kept = min(self._npz_rows, self._rrd_rows) if self._rec is not None else self._npz_rows

    def _append_rrd(self) -> None:
        """Read what Rerun encoded since the last call and append it (and anything left over) to ``run.rrd``."""
        if self._rec is None or self._stream is None:
            return
        sent = self._sent
        try:
            data = self._stream.read(flush=True, flush_timeout_sec=10.0)
        except Exception as exc:  # e.g. a live viewer that does not take the data: do not wait for it
            self._rec_flush_warn(exc)
            data = self._stream.read(flush=False)
        if data:
            self._rrd_pending.append(data)
        while self._rrd_pending:
            try:
                self._rrd_file.append(self._rrd_pending[0])
            except OSError as exc:
                raise self._fail(self._rrd_file.path, exc, self._last_tau()) from None
            except ValueError as exc:  # not what rerun 0.41 encodes: drop it rather than tear the file
                log.warning("Rerun bytes not appended to %s (%s)", RRD_FILE, exc)
            self._rrd_pending.pop(0)
        self._rrd_rows = sent

    def _rec_flush_warn(self, exc: Exception) -> None:
        if not self._viewer_warned:
            log.warning("Rerun flush: %s; run.rrd keeps recording", exc)
            self._viewer_warned = True

    def _write_events(self, data: bytes, *, mode: str = "ab") -> None:
        """Append ``data`` to ``events.jsonl`` (opened for this write only); cut a torn line back.  OSError."""
        try:
            with open(self._events_path, mode) as f:
                f.write(data)
                f.flush()
        except OSError:
            try:
                os.truncate(self._events_path, self._events_size)
            except OSError:
                pass
            raise
        self._events_size = len(data) if mode == "wb" else self._events_size + len(data)

    def _write_trajectory(self, rows: int | None = None) -> None:
        """Atomically (re)write ``trajectory.npz`` with the first ``rows`` rows (default: all so far)."""
        T = self._rows if rows is None else rows
        arrays = dict(t=self._t[:T].copy(), x=self._x[:T].copy(), xhat=self._xhat[:T].copy(),
                      alive=self._alive[:T].copy(), graph=self._graph[:T].copy(), agent_ids=self.agent_ids.copy())
        path = self.out_dir / TRAJECTORY_FILE
        tmp = None
        try:
            fd, tmp = tempfile.mkstemp(prefix=".trajectory.", suffix=".npz.tmp", dir=self.out_dir)
            with os.fdopen(fd, "wb") as f:
                np.savez(f, **arrays)
                f.flush()
                os.fsync(f.fileno())
            os.replace(tmp, path)
        except BaseException as exc:
            if tmp is not None:
                try:
                    Path(tmp).unlink(missing_ok=True)
                except OSError:
                    pass
            if isinstance(exc, OSError):
                raise self._fail(path, exc, int(self._tau[T - 1]) if T else None) from None
            raise
        self._npz_rows = T
        if T == self._rows:
            self._traj_dirty = False

    def _salvage(self) -> None:
        """After a write failure: write what is left, then make the rows on disk agree.  Never raises.

        K = all rows if ``run.rrd`` and ``trajectory.npz`` can now be written,
        else the rows both hold on disk (``trajectory.npz`` is cut to them if it
        holds more and can be rewritten).
        """
        try:
            self._flush()
        except RecordsWriteError:
            pass
        if self._rec is None:
            self._rows_kept = self._npz_rows
            return
        K = min(self._rrd_rows, self._npz_rows)
        if self._npz_rows > K:
            try:
                self._write_trajectory(K)
            except RecordsWriteError:
                K = self._npz_rows  # cannot cut it: run.rrd is cut to the trajectory's rows instead
        self._rows_kept = K

    def _close_event(self, t: float, level: str, fields: dict[str, Any]) -> None:
        """The last event, ``recording_closed``: to ``events.jsonl`` and ``run.rrd`` if they can take it."""
        line = json.dumps({"event": "recording_closed", "t": t, "wall": time.time(), **fields},
                          default=_json_default)
        try:
            self._write_events((line + "\n").encode("utf-8"))
        except OSError as exc:
            self._fail(self._events_path, exc, self._tau_of_t(t))
        if self._rec is not None:
            text = "recording_closed" + "".join(f" {k}={v}" for k, v in fields.items())
            self._rerun("event log", self._send_events, [(self._tau_of_t(t), t, text, level, time.time_ns())])
            try:
                self._append_rrd()
            except RecordsWriteError:
                pass

    def _finish_rrd(self, K: int) -> None:
        """Rewrite ``run.rrd`` as one verifiable RRD; cut after row K-1 if a write failed."""
        if self._rec is None or self._rrd_file.size == 0:
            return
        cutoff = None
        if self._failure is not None or K < self._rows:
            cutoff = int(self._tau[K - 1]) + 1 if K else 0
        try:
            self._rec.flush(timeout_sec=10.0)
        except Exception:
            pass
        try:
            rewrite_rrd(self._rrd_file.path, self._rrd_file.path, blueprint=self._blueprint(), cutoff=cutoff)
        except OSError as exc:
            self._fail(self._rrd_file.path, exc, int(self._tau[K - 1]) if K else None)
        except Exception as exc:  # Rerun could not read its own bytes back: keep the footer-less file
            log.warning("could not finish %s (%s: %s); it is readable but has no footer",
                        self._rrd_file.path, type(exc).__name__, exc)


def _watch(ref: "weakref.ref[Recorder]", stop: threading.Event) -> None:
    """Background flusher: flush a recorder whose last flush is ``flush_seconds`` old (rows stopped coming)."""
    while True:
        rec = ref()
        if rec is None:
            return
        wait = max(0.01, rec._last_flush + rec.flush_seconds - time.monotonic())
        del rec  # no strong reference while waiting
        if stop.wait(wait):
            return
        rec = ref()
        if rec is None:
            return
        with rec._lock:
            if rec._closed:
                return
            if (rec._failure is None and time.monotonic() - rec._last_flush >= rec.flush_seconds
                    and rec._pending()):
                try:
                    rec._flush()
                except RecordsWriteError:  # stored: the next recorder call raises it
                    rec._failure_reported = False
                except Exception as exc:
                    log.warning("background flush failed (%s: %s)", type(exc).__name__, exc)
        del rec


# ---------------------------------------------------------------------- read-back


def read_rrd(path: str | Path) -> dict[str, list[tuple[int, float]]]:
    """Every Scalars entity of an ``.rrd``: entity path -> sorted ``[(event index, value), ...]``.

    Entity paths are returned without the leading ``/`` (``"errors/max"``).
    Per event index the latest logged row wins (by Rerun row id), and a
    ``Clear`` logged later at the same event index on the entity (or a
    recursive one on an ancestor) removes the value, as the viewer's latest-at
    query does.  Only rows on the ``event`` timeline are read.

    Raises
    ------
    RecordingError
        If a Scalars row holds more than one value (not a scalar series).
    """
    from rerun.chunk import RrdReader

    # (entity, event) -> (row id, value or None for a clear)
    latest: dict[tuple[str, int], tuple[bytes, float | None]] = {}
    clears: list[tuple[str, int, bytes, bool]] = []
    scalar_entities: set[str] = set()
    for chunk in RrdReader(path).stream():
        if chunk.is_static or TL_EVENT not in chunk.timeline_names:
            continue
        batch = chunk.to_record_batch()
        names = batch.schema.names
        if _COL_SCALARS not in names and _COL_CLEAR not in names:
            continue
        entity = chunk.entity_path.lstrip("/")
        events = batch.column(TL_EVENT).to_pylist()
        row_ids = batch.column(_COL_ROW_ID).to_pylist()
        if _COL_SCALARS in names:
            scalar_entities.add(entity)
            for ev, rid, vals in zip(events, row_ids, batch.column(_COL_SCALARS).to_pylist()):
                if ev is None or vals is None:
                    continue
                if len(vals) != 1:
                    raise RecordingError(f"{entity} at event {ev} holds {len(vals)} scalars; expected 1")
                _keep_latest(latest, (entity, ev), rid, float(vals[0]))
        if _COL_CLEAR in names:
            for ev, rid, rec in zip(events, row_ids, batch.column(_COL_CLEAR).to_pylist()):
                if ev is not None and rec is not None:
                    clears.append((entity, ev, rid, bool(rec[0])))
    for c_entity, ev, rid, recursive in clears:
        for entity in scalar_entities:
            if entity == c_entity or (recursive and entity.startswith(c_entity + "/")):
                _keep_latest(latest, (entity, ev), rid, None)
    out: dict[str, list[tuple[int, float]]] = {}
    for (entity, ev), (_, value) in sorted(latest.items()):
        if value is not None:
            out.setdefault(entity, []).append((ev, value))
    return out


def _keep_latest(latest: dict, key: tuple[str, int], row_id: bytes, value: float | None) -> None:
    # Row ids are TUIDs: big-endian (nanoseconds, counter), so byte order is log order.
    old = latest.get(key)
    if old is None or row_id > old[0]:
        latest[key] = (row_id, value)


def read_rrd_logs(path: str | Path) -> dict[str, list]:
    """The text log and topology of an ``.rrd``.

    Returns ``{"events": [(event index, level, text), ...], "topology": [(event index, [node labels],
    [(j, i) edges]), ...]}`` in logging order.
    """
    from rerun.chunk import RrdReader

    out: dict[str, list] = {"events": [], "topology": []}
    for chunk in RrdReader(path).stream():
        if chunk.is_static or TL_EVENT not in chunk.timeline_names:
            continue
        batch = chunk.to_record_batch()
        names = batch.schema.names
        taus = batch.column(TL_EVENT).to_pylist()
        if chunk.entity_path == f"/{EVENTS}" and "TextLog:text" in names:
            for tau, text, level in zip(taus, batch.column("TextLog:text").to_pylist(),
                                        batch.column("TextLog:level").to_pylist()):
                out["events"].append((tau, level[0] if level else None, text[0]))
        elif chunk.entity_path == f"/{TOPOLOGY}" and "GraphNodes:labels" in names:
            edges = batch.column("GraphEdges:edges").to_pylist() if "GraphEdges:edges" in names else [None] * len(taus)
            for tau, labels, es in zip(taus, batch.column("GraphNodes:labels").to_pylist(), edges):
                pairs = [(int(e["first"]), int(e["second"])) if isinstance(e, dict) else tuple(map(int, e))
                         for e in (es or [])]
                out["topology"].append((tau, labels, pairs))
    return out


def verify_rrd(path: str | Path, *, timeout: float = 120.0) -> tuple[bool, str]:
    """Run the bundled ``rerun rrd verify <path>``; return (exit code 0, stdout + stderr)."""
    env = {**os.environ, "RERUN_ANALYTICS": os.environ.get("RERUN_ANALYTICS", "0")}
    try:
        proc = subprocess.run([*_rerun_command(), "rrd", "verify", str(path)], capture_output=True,
                              text=True, timeout=timeout, env=env)
    except (OSError, subprocess.TimeoutExpired) as exc:
        return False, f"could not run rerun rrd verify: {exc}"
    return proc.returncode == 0, (proc.stdout + proc.stderr).strip()
