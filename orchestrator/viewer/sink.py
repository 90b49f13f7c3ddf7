"""The Rerun side of the recorder: one recording stream, its live viewer, and ``run.rrd`` appended by Python.

:class:`RerunSink` logs what :class:`splitspec_orchestrator.records.recorder.Recorder` hands it
(:mod:`splitspec_orchestrator.viewer.handoff`: batches of rows, text events, topology, marks, loss clears)
with ``send_columns``, one chunk per entity per batch, on the timelines ``event``
(sequence ``tau``), ``time`` (duration) and ``wall`` (timestamp).  Entity paths,
colours and the default blueprint are in :mod:`splitspec_orchestrator.viewer.blueprint`;
the topology and what a misbehaving network draws over it (arcs that lost
messages, a partition's cut) in :mod:`splitspec_orchestrator.viewer.topology_view`.

A run on measurements (:meth:`RerunSink.set_reference`) also logs what
:mod:`splitspec_orchestrator.viewer.reference_view` computes (residuals, disagreement,
after the run the centralized Kalman filter); without the truth it logs no
error and no truth at all: their styles are logged with the first rows, once
that is known, and the default blueprint is sent again.

A lost agent's own series (``errors``, ``errors_log10``, its reported row columns' such as ``gains``,
``residual``) get a
non-recursive ``rr.Clear`` at the loss's event time: the time-series view
draws a Clear on the entity itself as a break of the line
(``collect_recursive_clears`` in rerun's series visualizer keeps non-recursive
clears of the queried entity), so no line crosses a dead interval.  Its
state estimates live in the per-component batches ``state/<k>/agents`` shared
with the other agents, which cannot be cleared for one agent: there the agent's
values are NaN at every event time it is dead (or re-sent as NaN when the loss
is noticed after they were logged), and a NaN breaks the line as well.

The recording logs into an ``rr.binary_stream()`` (plus a ``GrpcSink`` for a
live viewer); :meth:`RerunSink.write_pending` appends what it encoded to
``run.rrd`` with ordinary file calls whose ``OSError`` the recorder reports
(see :mod:`splitspec_orchestrator.viewer.rrd_file`), rolled into segments on a run until stopped
(:meth:`RerunSink.roll`).  Rerun itself never stops a run: a viewer that cannot be spawned or reached is a
warning and the recording goes on.

Why one module: it is the one holder of the run's Rerun recording stream; every method logs one kind of thing
to it or moves its bytes to ``run.rrd``, and the views that compute what to log live beside it
(:mod:`.topology_view`, :mod:`.reference_view`).
"""

from __future__ import annotations

import logging
import os
import socket
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any
from urllib.parse import urlsplit

import numpy as np

from splitspec_core.model.rows import column, present

from . import blueprint as bp
from .handoff import LossClear, LostRow, Mark, RowBatch, TextLine, TopologyLog
from .reference_view import ReferenceRows, ReferenceView, log10
from .rrd_file import (APPLICATION_ID, RrdAppender, finish_in_child, optimize_rrd, rerun_command, rewrite_rrd,
                       segment_path, wait_finished)
from .topology_view import TopologyView

__all__ = ["RerunSink", "ClosedSegment", "open_sink", "APPLICATION_ID", "RRD_FILE"]

log = logging.getLogger(__name__)

RRD_FILE = "run.rrd"
DEFAULT_VIEWER_PORT = 9876


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
    default = 443 if parts.scheme.endswith("https") else DEFAULT_VIEWER_PORT
    return parts.hostname or "127.0.0.1", parts.port or default


def open_sink(out_dir: Path, **options) -> "RerunSink | None":
    """The run's :class:`RerunSink` (``options``: its keyword arguments), or None -- file records only -- with a
    warning when Rerun fails to start: Rerun must never stop a run."""
    try:
        return RerunSink(out_dir, **options)
    except Exception as exc:
        log.warning("Rerun recording disabled (%s: %s); writing trajectory.npz and events.jsonl only",
                    type(exc).__name__, exc)
        return None


@dataclass
class ClosedSegment:
    """A rolled segment of ``run.rrd``: its ``path``, the first and last event time of the rows sent to it (None:
    none), the child process finishing it (:func:`~.rrd_file.finish_in_child`) and ``time.time()`` at the roll."""

    path: Path
    first: int | None
    last: int | None
    proc: Any
    closed_at: float

    @property
    def finished(self) -> bool:
        """Its rewrite is over (it may be removed)."""
        return self.proc is None or self.proc.poll() is not None


class RerunSink:
    """One run's Rerun recording (see the module docstring).  Constructing it may raise anything Rerun raises."""

    def __init__(self, out_dir: Path, *, run_id: str, scenario_name: str, agent_ids: np.ndarray, n: int,
                 time_mode: str, dt: float, graph_names: tuple, envelope: bool, columns: tuple,
                 positions: dict, viewer: str | None, viewer_port: int, connect_timeout: float,
                 states: tuple | None = None, shown: tuple | None = None, roll_bytes: int | None = None,
                 record_every: int = 1, segment: int = 0):
        import rerun as rr

        self.record_every = max(1, int(record_every))  # run.record_every: the state panels' decimation

        self.agent_ids = [int(a) for a in agent_ids]
        self.n, self.time_mode, self.envelope = int(n), time_mode, bool(envelope)
        self.columns = tuple(column(c) for c in columns)  # the reported row columns shown, a series per agent
        self.states = tuple(states) if states else None  # system.states: the state/<name> entities
        self.shown = None if shown is None else tuple(int(k) for k in shown)  # run.show: the states tab's views
        self.labels = bp.state_labels(self.n, self.states)
        self.positions = bp.node_positions(self.agent_ids, positions)
        # segment: 0 for a new run; a standby that takes over a run writes its next segment (records resumed)
        self.rrd_file = RrdAppender(segment_path(Path(out_dir) / RRD_FILE, int(segment)))
        self.roll_bytes = roll_bytes  # run.rrd rolls to run-0001.rrd ... past this size (None: never)
        self.segment = int(segment)  # the segment being written (0: run.rrd)
        self.finishing: list = []  # child processes finishing rolled segments (finish_in_child)
        self.span: list = [None, None]  # first and last event time of the rows sent to the segment being written
        self.closed: list[ClosedSegment] = []  # the rolled segments not removed (run.keep: records.retention)
        self.pending: list[bytes] = []  # read from Rerun, not yet on disk
        self.newest: tuple[int, float, int] | None = None  # (tau, t, wall_ns) of the newest row logged (roll)
        self._viewer_warned = False
        # a run on measurements (set_reference): whether it has the truth, its rows and its view
        self.truth, self.reference_rows, self.reference = True, None, None
        self._truth_styled = False  # the styles of the errors and the truth: logged with the first rows
        self.rec = rec = rr.RecordingStream(application_id=APPLICATION_ID, recording_id=run_id)
        self.topology = TopologyView(rec, self.agent_ids, self.positions, index=self._index)
        self.stream = rr.binary_stream(rec)
        sinks: list[Any] = [self.stream]
        live = self._viewer_sink(rr, rec, viewer, viewer_port=viewer_port, connect_timeout=connect_timeout)
        if live is not None:
            sinks.append(live)
        rec.set_sinks(*sinks, default_blueprint=self.blueprint())  # both sinks at once (a tee)
        self._name = f"{scenario_name} ({run_id})"
        self._properties = dict(
            scenario=scenario_name, run_id=run_id, time_mode=time_mode, dt=dt, n=self.n, m=len(self.agent_ids),
            agent_ids=self.agent_ids, graphs=list(graph_names), envelope=self.envelope,
            columns=",".join(c.name for c in self.columns),
            **({"states": list(self.states)} if self.states else {}),
            **({"shown": list(self.shown)} if self.shown is not None else {}))
        self._log_statics(rr)

    def _log_statics(self, rr) -> None:
        """What every segment of ``run.rrd`` holds: the recording's name and properties, the series' styles."""
        self.rec.send_recording_name(self._name)
        self.rec.send_property("splitspec", rr.AnyValues(**self._properties))
        self._log_static_styles(rr, self.rec)

    # ------------------------------------------------------------------ setup

    def blueprint(self):
        return bp.default_blueprint(**self.blueprint_args())

    def blueprint_args(self) -> dict:
        """The arguments of :func:`~splitspec_orchestrator.viewer.blueprint.default_blueprint` (JSON)."""
        return dict(time_mode=self.time_mode, n=self.n, envelope=self.envelope,
                    columns=[c.name for c in self.columns], truth=self.truth,
                    reference=self.reference is not None, states=list(self.states) if self.states else None,
                    shown=list(self.shown) if self.shown is not None else None)

    def set_reference(self, rows: ReferenceRows, *, truth: bool) -> None:
        """The run is on measurements (``rows``): log its residuals, disagreement and filter, the errors and the
        truth only if it has the truth; the default blueprint opens on the reference tab.  Before the first rows."""
        import rerun as rr

        self.truth, self.reference_rows = bool(truth), rows
        self.reference = ReferenceView(self.rec, self.agent_ids, self.n, truth=self.truth, index=self._index,
                                       labels=self.labels)
        self.reference.log_static_styles(rr)
        self.rec.send_property("measurements", rr.AnyValues(truth=self.truth))
        self.rec.send_blueprint(self.blueprint(), make_active=True, make_default=True)

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
            cmd = rerun_command()
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

    def _log_static_styles(self, rr, rec) -> None:
        def line(path, name, col, width=None):
            rec.log(path, rr.SeriesLines(names=name, colors=[col], **({"widths": width} if width else {})),
                    static=True)

        for kind, (name, marker, col) in bp.MARK_KINDS.items():
            rec.log(f"{bp.MARKS}/{kind}", rr.SeriesPoints(names=name, colors=[col], markers=marker,
                                                          marker_sizes=6.0), static=True)
        for i, a in enumerate(self.agent_ids):
            for c in self.columns:
                line(bp.agent_path(c.path, a), f"{c.name} agent {a}", bp.color(i))
        m = len(self.agent_ids)
        for label, name in self.labels:
            # one batch of m scalars: one name, colour and width per instance (agent)
            rec.log(bp.state_path(label, "agents"), rr.SeriesLines(
                names=[f"{name} agent {a}" for a in self.agent_ids], colors=[bp.color(i) for i in range(m)],
                widths=[1.0] * m), static=True)
        for s in bp.ROUND_SERIES:
            line(f"{bp.ROUNDS}/{s}", s.replace("_", " "), bp.ROUND_COLORS[s])

    def _log_truth_styles(self, rr) -> None:
        """The styles of the errors and the truth: with the first rows, once it is known whether the run has
        the truth (a run on measurements says so after the sink exists: :meth:`set_reference`)."""
        self._truth_styled = True
        if not self.truth:
            return

        def line(path, name, col, width=None):
            self.rec.log(path, rr.SeriesLines(names=name, colors=[col], **({"widths": width} if width else {})),
                         static=True)

        line(bp.ERRORS_MAX, "max", bp.MAX_COLOR, 2.5)
        line(bp.ERRORS_LOG10_MAX, "max", bp.MAX_COLOR, 2.5)
        if self.envelope:
            line(bp.ENVELOPE, "designed envelope", bp.ENVELOPE_COLOR, 2.0)
        for i, a in enumerate(self.agent_ids):
            line(bp.agent_path(bp.ERRORS, a), f"agent {a}", bp.color(i))
            line(bp.agent_path(bp.ERRORS_LOG10, a), f"agent {a}", bp.color(i))
        for label, name in self.labels:
            line(bp.state_path(label, "truth"), f"{name} truth", bp.TRUTH_COLOR, 3.0)

    def guarded(self, what: str, fn, *args) -> None:
        """Run one Rerun logging step; a failure is a warning, never an exception."""
        try:
            fn(*args)
        except Exception as exc:
            log.warning("Rerun %s failed (%s: %s); continuing", what, type(exc).__name__, exc)

    @staticmethod
    def _index(rr, taus, seconds, walls_ns) -> list:
        """The three timeline columns (``event``, ``time``, ``wall``) of a batch of rows."""
        dur = np.round(np.asarray(seconds, dtype=float) * 1e9).astype(np.int64).astype("timedelta64[ns]")
        return [rr.TimeColumn(bp.TL_EVENT, sequence=np.asarray(taus, dtype=np.int64)),
                rr.TimeColumn(bp.TL_TIME, duration=dur),
                rr.TimeColumn(bp.TL_WALL, timestamp=np.asarray(walls_ns, dtype=np.int64).astype("datetime64[ns]"))]

    def agent_series(self, agent_id: int) -> list[str]:
        """Every series entity of one agent alone (what a loss clears; not the shared ``state/<k>/agents``)."""
        paths = [bp.agent_path(bp.ERRORS, agent_id), bp.agent_path(bp.ERRORS_LOG10, agent_id)] if self.truth else []
        if self.reference is not None:
            paths += self.reference.agent_series(agent_id)
        paths += [bp.agent_path(c.path, agent_id) for c in self.columns]
        return paths

    # ------------------------------------------------------------------ logging

    def send_rows(self, b: RowBatch) -> None:
        """One chunk per entity: values where shown, a non-recursive Clear where a shown value stopped being true.

        ``state/<k>/agents`` gets every row of the batch, m values each, NaN where an agent is not
        shown (a row re-sent without an agent retracts its value that way).  Per entity, each event
        time appears at most once per batch, so the newest batch wins on read.
        """
        import rerun as rr

        self._note_newest(b)
        if not self._truth_styled:
            self._log_truth_styles(rr)
        if self.reference is not None:
            self.reference.send_rows(self.reference_rows.batch(b.seq, b.t, b.wall, b.xhat))
        send = self.rec.send_columns
        L = len(b.seq)
        indexes: dict[bytes, list] = {}
        clears: dict[int, Any] = {}

        def index(mask: np.ndarray) -> list:
            key = mask.tobytes()
            cols = indexes.get(key)
            if cols is None:
                cols = indexes[key] = self._index(rr, b.seq[mask], b.t[mask], b.wall[mask])
            return cols

        def scalars(path: str, mask: np.ndarray, values: np.ndarray) -> None:
            if mask.any():
                send(path, indexes=index(mask), columns=rr.Scalars.columns(scalars=values[mask]))

        def clear(path: str, mask: np.ndarray) -> None:
            cnt = int(mask.sum())
            if cnt:
                if cnt not in clears:
                    clears[cnt] = rr.Clear.columns(is_recursive=np.zeros(cnt, dtype=bool))
                send(path, indexes=index(mask), columns=clears[cnt])

        if L:
            lo, hi = int(b.seq.min()), int(b.seq.max())
            self.span = [lo if self.span[0] is None else min(lo, self.span[0]),
                         hi if self.span[1] is None else max(hi, self.span[1])]
        every = np.ones(L, dtype=bool)
        # run.record_every: the state panels (states, truth, the agents' reported columns) at the event times it
        # divides; the errors, the envelope, the rounds, events and marks at every one
        panel = (b.seq % self.record_every == 0) if self.record_every > 1 else every
        lerr, lmax = log10(b.err), log10(b.err_max)
        shown = np.where(b.show[:, :, None], b.xhat, np.nan)  # (L, m, n)
        for c in range(self.n):
            if self.truth:
                scalars(bp.state_path(self.labels[c][0], "truth"), panel, b.x[:, c])
            scalars(bp.state_path(self.labels[c][0], "agents"), panel, shown[:, :, c])  # (L, m): a batch of m per row
        for i, a in enumerate(self.agent_ids):
            mask = b.show[:, i]
            if self.truth:
                scalars(bp.agent_path(bp.ERRORS, a), mask, b.err[:, i])
                scalars(bp.agent_path(bp.ERRORS_LOG10, a), mask & np.isfinite(lerr[:, i]), lerr[:, i])
                for path in (bp.agent_path(bp.ERRORS, a), bp.agent_path(bp.ERRORS_LOG10, a)):
                    clear(path, b.clear[:, i])
            for c in self.columns:
                values = b.columns[c.name][:, i]
                scalars(bp.agent_path(c.path, a), mask & panel & present(c, values), values.astype(float))
                clear(bp.agent_path(c.path, a), b.clear[:, i])
        if self.truth:
            scalars(bp.ERRORS_MAX, b.show_max, b.err_max)
            scalars(bp.ERRORS_LOG10_MAX, b.show_max & np.isfinite(lmax), lmax)
            clear(bp.ERRORS_MAX, b.clear_max)
            clear(bp.ERRORS_LOG10_MAX, b.clear_max)
        if self.envelope and self.truth:
            lenv = log10(b.env)
            scalars(bp.ENVELOPE, np.isfinite(lenv), lenv)
        for s, col in zip(bp.ROUND_SERIES, b.rounds.T):
            scalars(f"{bp.ROUNDS}/{s}", np.isfinite(col), col)

    def _note_newest(self, b: RowBatch) -> None:
        """Keep the newest row's index (a rolled segment starts with the topology there: :meth:`roll`)."""
        if len(b.seq):
            k = int(np.argmax(b.seq))
            if self.newest is None or int(b.seq[k]) > self.newest[0]:
                self.newest = (int(b.seq[k]), float(b.t[k]), int(b.wall[k]))

    def send_events(self, lines: list[TextLine]) -> None:
        """One TextLog chunk on ``events``, in call order."""
        import rerun as rr

        self.rec.send_columns(bp.EVENTS, indexes=self._index(rr, [e.tau for e in lines], [e.t for e in lines],
                                                             [e.wall for e in lines]),
                              columns=rr.TextLog.columns(text=[e.text for e in lines], level=[e.level for e in lines]))

    def send_marks(self, marks: list[Mark], heights: list[float]) -> None:
        """One point per mark on ``marks/<kind>``, at its height (one chunk per kind)."""
        import rerun as rr

        for kind in bp.MARK_KINDS:
            rows = [(m, y) for m, y in zip(marks, heights) if m.kind == kind]
            if rows:
                self.rec.send_columns(f"{bp.MARKS}/{kind}", indexes=self._index(
                    rr, [m.tau for m, _ in rows], [m.t for m, _ in rows], [m.wall for m, _ in rows]),
                    columns=rr.Scalars.columns(scalars=np.asarray([y for _, y in rows], dtype=float)))

    def send_loss_clears(self, clears: list[LossClear]) -> None:
        """A non-recursive Clear on each of the lost agent's series at the loss's event time."""
        import rerun as rr

        for c in clears:
            idx = self._index(rr, [c.tau], [c.t], [c.wall])
            for path in self.agent_series(c.agent):
                self.rec.send_columns(path, indexes=idx, columns=rr.Clear.columns(is_recursive=[False]))

    def send_topology(self, logs: list[TopologyLog]) -> None:
        """See :meth:`splitspec_orchestrator.viewer.topology_view.TopologyView.send_topology`."""
        self.topology.send_topology(logs)

    def send_lost(self, rows: list[LostRow]) -> None:
        """See :meth:`splitspec_orchestrator.viewer.topology_view.TopologyView.send_lost`."""
        self.topology.send_lost(rows)

    # ------------------------------------------------------------------ run.rrd

    def read_pending(self) -> None:
        """Take what Rerun encoded since the last call (waiting at most 10 s for it)."""
        try:
            data = self.stream.read(flush=True, flush_timeout_sec=10.0)
        except Exception as exc:  # e.g. a live viewer that does not take the data: do not wait for it
            if not self._viewer_warned:
                log.warning("Rerun flush: %s; run.rrd keeps recording", exc)
                self._viewer_warned = True
            data = self.stream.read(flush=False)
        if data:
            self.pending.append(data)

    def write_pending(self) -> None:
        """Append the pieces read so far to ``run.rrd``.

        Raises
        ------
        OSError
            If ``run.rrd`` cannot be written (the pieces not written stay pending).
        """
        while self.pending:
            try:
                self.rrd_file.append(self.pending[0])
            except ValueError as exc:  # not what rerun 0.41 encodes: drop it rather than tear the file
                log.warning("Rerun bytes not appended to %s (%s)", RRD_FILE, exc)
            self.pending.pop(0)
        self.finishing = [p for p in self.finishing if p.poll() is None]  # reaped
        if self.roll_bytes is not None and self.rrd_file.size >= self.roll_bytes:
            self.roll()

    def roll(self) -> None:
        """Finish the segment being written (footer and manifest: a rewrite of at most about ``roll_bytes``, by a
        child process, so that this one's memory does not depend on it) and write the next ones to the next segment (``run-0001.rrd`` ...), which starts with the stores' openings and
        gets the static data again (name, properties, styles) and the topology in force at its first event time
        (:meth:`~splitspec_orchestrator.viewer.topology_view.TopologyView.relog`); the finished segment gets the
        blueprint from its rewrite: each segment opens alone, and all together as one recording.
        """
        import rerun as rr

        try:
            self.rec.flush(timeout_sec=10.0)
        except Exception:
            pass
        proc = finish_in_child(self.rrd_file.path, self.blueprint_args(), has_layout=self.segment == 0)
        self.finishing.append(proc)
        self.closed.append(ClosedSegment(self.rrd_file.path, self.span[0], self.span[1], proc, time.time()))
        self.span = [None, None]
        infos = self.rrd_file.infos
        self.segment += 1
        self.rrd_file = RrdAppender(segment_path(self._first_path(), self.segment), prefix=infos)
        self._log_statics(rr)
        if self._truth_styled:
            self._log_truth_styles(rr)
        if self.reference is not None:
            self.reference.log_static_styles(rr)
        self.guarded("topology log", self.topology.relog, self.newest)
        # no send_blueprint here: rerun 0.41 keeps some 4 MB per call (measured: the orchestrator's RSS grew by that
        # at every roll); the finished segment gets its default blueprint from the rewrite (finish_in_child)

    def _first_path(self) -> Path:
        """``run.rrd``, the first segment's path."""
        return self.rrd_file.path.with_name(RRD_FILE)

    def finish(self, cutoff: int | None) -> None:
        """Rewrite ``run.rrd`` as one verifiable RRD (with the blueprint), cut at ``cutoff`` if given.

        Raises
        ------
        OSError
            If ``run.rrd`` cannot be rewritten; other failures leave the footer-less file with a warning.
        """
        wait_finished(self.finishing)  # the rolled segments (a run's end: all its records complete)
        self.finishing = []
        if self.rrd_file.size == 0:
            return
        try:
            self.rec.flush(timeout_sec=10.0)
        except Exception:
            pass
        try:
            rewrite_rrd(self.rrd_file.path, self.rrd_file.path, blueprint=self.blueprint(), cutoff=cutoff)
        except OSError:
            raise
        except Exception as exc:  # Rerun could not read its own bytes back: keep the footer-less file
            log.warning("could not finish %s (%s: %s); it is readable but has no footer",
                        self.rrd_file.path, type(exc).__name__, exc)
        else:
            optimize_rrd(self.rrd_file.path)  # its chunks merged: a third of the size (never raises)

    def disconnect(self) -> None:
        self.guarded("disconnect", self.rec.disconnect)
