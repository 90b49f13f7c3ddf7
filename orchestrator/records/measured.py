"""What the recorder records of a run on measurements or on live sensors, beside the rows every run has.

A run whose estimators take their ``y`` from a measurements file
(:meth:`splitspec_orchestrator.records.recorder.Recorder.set_measurements`) or from live sensors
(:meth:`~splitspec_orchestrator.records.recorder.Recorder.set_live_sources`) records, in addition (the arrays
and entities: docs/reference/files.md, sections "Trajectory file" and "Rerun recording"):

* ``trajectory.npz``: the ``y`` and ``y_missing`` rows of the event times taken so far and, at the close,
  what is known without the truth (:func:`splitspec_core.studies.no_truth.no_truth_arrays`: the centralized Kalman
  filter on the same measurements and each agent's distance to it), computed once (:meth:`MeasuredRecords.arrays`);
* ``run.rrd``: without the truth, an agent is shown where it is alive with a finite estimate (there is no
  error to show, :meth:`MeasuredRecords.row_errors`), and a mark stands on the log10 disagreement
  (:meth:`MeasuredRecords.mark_y`); at the close, the Kalman filter of the last ``trajectory.npz``
  (:meth:`MeasuredRecords.send_after_run`).

With live sensors the measurement of event time ``tau`` is the ``y_i`` each agent reports having used
(:meth:`MeasuredRecords.live_y`, from its ``xhat``), held until the rows' measurements take it.

:class:`MeasuredRecords` holds this state for one :class:`~splitspec_orchestrator.records.recorder.Recorder` (which
keeps the buffering, the flushes and their order); it reads the recorder's taken rows (a
:class:`~splitspec_orchestrator.records.rowstore.RowStore`) and shares its lock for the live measurements.
"""

from __future__ import annotations

import threading

import numpy as np

from ..viewer.reference_view import ReferenceRows
from .rowstore import RowStore

__all__ = ["MeasuredRecords"]


class MeasuredRecords:
    """The measurements behind a recorder's rows (none by default: a run with the truth, nothing extra).

    Parameters
    ----------
    lock : the recorder's ``_lock`` (what its callers record); guards the live measurements
    taken : the rows taken by the recorder's flushes (its writer's ``rows``, read under its ``_io``)
    agent_ids : agent ids in the scenario's order
    pos : ``{agent id: column}``
    """

    def __init__(self, lock: threading.RLock, *, taken: RowStore, agent_ids: np.ndarray, pos: dict[int, int]):
        self._lock = lock
        self._d = taken
        self.agent_ids = agent_ids
        self._pos = pos
        # a run on measurements (use): (scenario, ReferenceRows), whether it has the truth, and the
        # arrays known at its close (rows, no_truth_arrays) for run.rrd
        self.source: tuple | None = None
        self.truth = True
        self.after_run: tuple | None = None
        self.closed = False  # set by the recorder's close: the next arrays() is the last, with the Kalman filter
        self.inputs = None  # a measurements file's u rows (known inputs), else the scenario's signal applies
        self._live_rows = None
        self._live: dict = {}  # tau -> (y, missing) from live_y, until the y source has taken it (it keeps it)

    def use(self, sc, rows: ReferenceRows, *, truth: bool) -> None:
        """The run's measurements: ``rows`` (:class:`ReferenceRows` of the scenario's ``C_i``)."""
        self.source, self.truth = (sc, rows), bool(truth)

    def live_source(self, sc):
        """Live sensors: the :data:`~splitspec_orchestrator.viewer.reference_view.YRow` of what :meth:`live_y` is given."""
        from splitspec_core.model.plant import output_rows

        self._live_rows = output_rows(sc.system.Cs)
        self._live = {}
        return self._live_row

    def _live_row(self, tau: int):
        with self._lock:
            return self._live.pop(int(tau), None)

    def live_y(self, tau: int, used) -> None:
        """Event time ``tau``'s ``(agent id, y_i(tau) or None)`` of the agents alive (the others: missing, NaN)."""
        rows = self._live_rows
        y, missing = np.full(rows[-1].stop, np.nan), np.ones(len(self.agent_ids), dtype=bool)
        for aid, v in used:
            k = self._pos[int(aid)]
            if v is not None and len(v) == rows[k].stop - rows[k].start:
                y[rows[k]], missing[k] = v, False
        with self._lock:
            self._live[int(tau)] = (y, missing)

    def y_rows(self, taus: np.ndarray):
        """``(y, y_missing)`` of event times ``taus`` on measurements or live sensors (the chunks' columns), else
        None."""
        if self.source is None:
            return None
        return self.source[1].measurements(np.asarray(taus).astype(int))

    def forget_before(self, tau: int) -> None:
        """A run until stopped forgot its rows before ``tau`` (on disk): so do the measurements behind them."""
        if self.source is not None:
            self.source[1].forget_before(tau)

    def row_errors(self, ks: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``|x_i - x|`` of rows ``ks`` and where a row shows agent i: alive with a finite error, or without the
        truth (whose errors are never logged) alive with a finite estimate."""
        err, show = self._d.row_errors(ks)
        if not self.truth:
            show = self._d.alive[ks] & np.isfinite(self._d.xhat[ks]).all(axis=2)
        return err, show

    def mark_y(self, tau: int) -> float:
        """A mark's height: on the log10 max error, or without the truth on the log10 disagreement."""
        if self.truth:
            return self._d.mark_y(tau)
        return self.source[1].mark_y(tau)

    def arrays(self, T: int) -> dict:
        """The extra arrays of ``trajectory.npz`` with the first ``T`` rows taken: none without measurements;
        ``y``, ``y_missing``; after :attr:`closed`, also what is known without truth (kept in :attr:`after_run`)."""
        if self.source is None or not T:
            return {}
        sc, rows = self.source
        taus = self._d.tau[:T].astype(int)
        y, missing = rows.measurements(taus)
        extra = {"y": y, "y_missing": missing}
        if self.closed:  # the centralized Kalman filter over the whole run: once, at the end
            from splitspec_core.studies.no_truth import no_truth_arrays
            from splitspec_core.simulation.simulator import Trajectory

            taken = self._d
            traj = Trajectory(t=taken.t[:T], x=taken.x[:T], xhat=taken.xhat[:T], alive=taken.alive[:T],
                              graph=taken.graph[:T],
                              agent_ids=np.array(self.agent_ids), y=extra["y"], y_missing=extra["y_missing"])
            known = no_truth_arrays(traj, sc, None if self.inputs is None else self.inputs[:T])
            self.after_run = (T, known)
            extra.update(known)
        return extra

    def send_after_run(self, sink) -> None:
        """At the close, after the last flush: the centralized Kalman filter and each agent's distance to it,
        the very arrays the last ``trajectory.npz`` got (:meth:`arrays`), to Rerun (``sink``: a
        :class:`~splitspec_orchestrator.viewer.sink.RerunSink` or None)."""
        done = self.after_run
        if sink is None or sink.reference is None or done is None or done[0] != self._d.rows:
            return
        taken, T, arrays = self._d, done[0], done[1]
        sink.guarded("Kalman filter log", sink.reference.send_after_run, taken.tau[:T], taken.t[:T], taken.wall[:T],
                     arrays["kf"], arrays["kf_distance"])
