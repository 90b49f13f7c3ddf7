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

Every run whose system has known inputs (``system.B``) records the ``u(tau)`` its estimators used
(:meth:`MeasuredRecords.set_inputs`, :class:`InputRows`): ``trajectory.npz``'s ``u`` and the chunks' ``u`` column.
That is the scenario's signal, or a measurements file's ``u`` rows, at every event time; with live inputs
(``sources.inputs``) the ``u`` the agents report having taken (:meth:`MeasuredRecords.live_u`; NaN where none did:
no agent alive, the last event time, which has no round).  The centralized Kalman filter runs on that ``u``.

:class:`MeasuredRecords` holds this state for one :class:`~splitspec_orchestrator.records.recorder.Recorder` (which
keeps the buffering, the flushes and their order); it reads the recorder's taken rows (a
:class:`~splitspec_orchestrator.records.rowstore.RowStore`) and shares its lock for the live measurements.
"""

from __future__ import annotations

import threading
from typing import Callable

import numpy as np

from ..viewer.reference_view import ReferenceRows
from .rowstore import RowStore

__all__ = ["MeasuredRecords", "InputRows"]

class InputRows:
    """The known inputs ``u(tau)`` (``p`` of them) of a recorder's event times: ``u_row(tau) -> u | None`` is asked
    once per event time it knows (a live source may know it later: a None is asked again); NaN where unknown.
    No I/O."""

    def __init__(self, p: int, u_row: Callable):
        self.p, self.u_row = int(p), u_row
        self._u, self._known = np.full((64, self.p), np.nan), np.zeros(64, bool)
        self._base = 0  # the event time of row 0 (forget_before)

    def rows(self, taus) -> np.ndarray:
        """``u`` (L, p) of event times ``taus``, NaN where unknown (or forgotten).

        Raises
        ------
        ValueError
            If ``u_row`` gives a row of another width than p.
        """
        idx = np.asarray(taus, dtype=np.int64).reshape(-1) - self._base
        held = idx >= 0
        if held.any() and int(idx.max()) >= len(self._known):
            cap = max(2 * len(self._known), int(idx.max()) + 1)
            u, known = np.full((cap, self.p), np.nan), np.zeros(cap, bool)
            u[:len(self._u)], known[:len(self._known)] = self._u, self._known
            self._u, self._known = u, known
        for k in idx[held][~self._known[idx[held]]].tolist():
            got = self.u_row(int(k + self._base))
            if got is None:
                continue
            got = np.asarray(got, dtype=float).reshape(-1)
            if got.shape != (self.p,):
                raise ValueError(f"the known inputs of event time {k + self._base} have {got.size} values; "
                                 f"expected {self.p} (the columns of system.B)")
            self._u[k], self._known[k] = got, True
        out = np.full((len(idx), self.p), np.nan)
        out[held] = self._u[idx[held]]
        return out

    def forget_before(self, tau: int) -> None:
        """Forget the event times before ``tau`` (a run until stopped holds a window of rows; they are on disk)."""
        d = int(tau) - self._base
        if d <= 0:
            return
        keep = max(0, len(self._known) - d)
        self._u[:keep], self._known[:keep] = self._u[len(self._u) - keep:], self._known[len(self._known) - keep:]
        self._u[keep:], self._known[keep:] = np.nan, False
        self._base = int(tau)


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
        self.inputs: InputRows | None = None  # the known inputs u(tau) the estimators used (set_inputs)
        self._live_rows = None
        self._live: dict = {}  # tau -> (y, missing) from live_y, until the y source has taken it (it keeps it)
        self._live_u: dict = {}  # tau -> u from live_u, until the inputs' rows have taken it (they keep it)

    def set_inputs(self, sc, u: np.ndarray | None = None) -> None:
        """The run's known inputs (none without ``system.B``): live (``sources.inputs``: what :meth:`live_u` is
        given), else the rows of ``u`` (a measurements file's, (T, p)) or the scenario's signal."""
        if sc.system.B is None:
            self.inputs = None
            return
        if sc.input_source is not None:
            self._live_u = {}
            self.inputs = InputRows(sc.system.inputs, self._live_u_row)
            return
        from splitspec_core.model.plant import input_of

        rows = None if u is None else np.asarray(u, dtype=float)

        def u_row(tau: int):
            if rows is None:
                return input_of(sc, tau)  # the signal (zero without system.u), as the plant process sends it
            return rows[tau] if 0 <= tau < len(rows) else None

        self.inputs = InputRows(sc.system.inputs, u_row)

    def _live_u_row(self, tau: int):
        with self._lock:
            return self._live_u.pop(int(tau), None)

    def live_u(self, tau: int, used) -> tuple:
        """Event time ``tau``'s ``(agent id, u(tau))`` of the live known inputs the alive agents took: the first
        agent's in the scenario's order is recorded (each agent samples the inputs as its tick arrives, so agents
        may take different values); ``(the recorded agent's id, the ids of the agents that took another value)``,
        ``(None, [])`` when none reported one."""
        if self.inputs is None:
            return None, []
        got = sorted(((self._pos[int(a)], int(a), np.asarray(v, dtype=float)) for a, v in used
                      if int(a) in self._pos and v is not None and len(v) == self.inputs.p), key=lambda r: r[0])
        if not got:
            return None, []
        u = got[0][2]
        with self._lock:
            self._live_u[int(tau)] = u
        return got[0][1], [a for _, a, v in got[1:] if not np.array_equal(v, u)]

    def u_rows(self, taus: np.ndarray):
        """``u`` (L, p) of event times ``taus`` with known inputs (the chunks' column), else None."""
        return None if self.inputs is None else self.inputs.rows(taus)

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
        if self.inputs is not None:
            self.inputs.forget_before(tau)

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
        """The extra arrays of ``trajectory.npz`` with the first ``T`` rows taken: ``u`` with known inputs; on
        measurements ``y``, ``y_missing`` and, after :attr:`closed`, what is known without truth (kept in
        :attr:`after_run`)."""
        if not T:
            return {}
        taus = self._d.tau[:T].astype(int)
        extra = {} if self.inputs is None else {"u": self.inputs.rows(taus)}
        if self.source is None:
            return extra
        sc, rows = self.source
        y, missing = rows.measurements(taus)
        extra.update(y=y, y_missing=missing)
        if self.closed:  # the centralized Kalman filter over the whole run: once, at the end
            from splitspec_core.studies.no_truth import no_truth_arrays
            from splitspec_core.simulation.simulator import Trajectory

            taken = self._d
            traj = Trajectory(t=taken.t[:T], x=taken.x[:T], xhat=taken.xhat[:T], alive=taken.alive[:T],
                              graph=taken.graph[:T],
                              agent_ids=np.array(self.agent_ids), y=extra["y"], y_missing=extra["y_missing"])
            known = no_truth_arrays(traj, sc, extra.get("u"))
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
