"""What the recording shows of a run on measurements: residuals, disagreement, distance to the centralized KF.

Without the truth the error ``|x_i - x|`` cannot be shown, and nothing shows a
made-up one (no ``errors``, ``errors_log10`` or ``state/<k>/truth`` entity, not
even NaN rows).  What can be known (:mod:`splitspec_core.studies.no_truth`, the same
functions that write ``trajectory.npz``'s arrays) is logged instead; with the
truth it is logged beside the errors:

* row by row, as the recorder's flushes take the rows: every agent's
  measurement residual ``|y_i - C_i x_i|`` (``residual/agent_<id>``) and the
  consensus disagreement ``max_ij |x_i - x_j|`` (``disagreement``), each with
  its log10 (``residual_log10/...``, ``disagreement_log10``);
* once, after the run: the centralized Kalman filter on the same measurements
  (``state/<k>/kf``) and every agent's distance to it (``kf_distance/agent_<id>``,
  ``kf_distance_log10/agent_<id>``).

A value that cannot be known (a dead agent, a missing measurement, no agent
alive; the log10 of 0) is never logged as NaN: its event time gets a
non-recursive ``Clear`` on the entity instead, which retracts a value an earlier
flush showed there and breaks the line in the time-series view (a time series
otherwise joins the points on either side of a gap).

The recorder is told the measurement behind each event time by a function
``y_row(tau) -> (y, missing) | None`` (:data:`YRow`): ``y`` (sum s_i,) stacked in
agent order as the plant's ``y`` (``C = [C_1; ...; C_m]``), ``missing`` (m,)
bool; None when no measurement of ``tau`` is known (every residual of that row
unknown).  :func:`file_rows` is that function for a measurements file; a live
source gives its own (:meth:`splitspec_orchestrator.records.recorder.Recorder.set_y_source`).
:class:`ReferenceRows` computes the rows (no I/O, no Rerun), :class:`ReferenceView`
logs them (on the recorder's flush path only, like every other row series).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable

import numpy as np

from splitspec_core.studies.no_truth import disagreement, residuals

from . import blueprint as bp

__all__ = ["YRow", "file_rows", "ReferenceBatch", "ReferenceRows", "ReferenceView", "known_parts", "log10", "row_disagreement",
           "progress_text"]

#: the measurement behind event time ``tau``: ``(y (sum s_i,), missing (m,) bool)``, or None if unknown
YRow = Callable[[int], "tuple[np.ndarray, np.ndarray] | None"]


def file_rows(meas) -> YRow:
    """:data:`YRow` of a measurements file (:class:`splitspec_core.scenarios.measurements.Measurements`): row ``tau``."""
    def y_row(tau: int):
        return (meas.y[tau], meas.missing[tau]) if 0 <= tau < len(meas.y) else None

    return y_row


def _grown(a: np.ndarray, rows: int, fill) -> np.ndarray:
    """``a`` with ``rows`` rows, the new ones ``fill``."""
    out = np.full((rows,) + a.shape[1:], fill, dtype=a.dtype)
    out[:len(a)] = a
    return out


def log10(v: np.ndarray) -> np.ndarray:
    """``np.log10(v)`` without warnings: -inf at 0, NaN at NaN or below 0."""
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.log10(v)


def known_parts(path: str, log_path: str, values: np.ndarray) -> list[tuple[str, np.ndarray, np.ndarray]]:
    """``[(entity, values, known)]`` of one series and its log10: ``known`` where a value is logged, a ``Clear``
    elsewhere (NaN: dead, missing, none alive; the log10 of 0 or of NaN)."""
    values = np.asarray(values, dtype=float)
    logs = log10(values)
    return [(path, values, np.isfinite(values)), (log_path, logs, np.isfinite(logs))]


@dataclass
class ReferenceBatch:
    """Rows to log (L of them): their timelines, ``residual`` (L, m) and ``disagreement`` (L,), NaN if unknown."""

    seq: np.ndarray
    t: np.ndarray
    wall: np.ndarray
    residual: np.ndarray
    disagreement: np.ndarray

    def parts(self, agent_ids) -> list[tuple[str, np.ndarray, np.ndarray]]:
        """Every entity of the rows: :func:`known_parts` of each agent's residual, then of the disagreement."""
        out = []
        for i, a in enumerate(agent_ids):
            out += known_parts(bp.agent_path(bp.RESIDUAL, a), bp.agent_path(bp.RESIDUAL_LOG10, a),
                               self.residual[:, i])
        return out + known_parts(bp.DISAGREEMENT, bp.DISAGREEMENT_LOG10, self.disagreement)


class ReferenceRows:
    """The residuals and the disagreement of the recorder's rows (``Cs``: the agents' ``C_i``, in agent order).

    Keeps each event time's disagreement (the height of a mark on the log10 disagreement axis, as the
    max error is with the truth).  No I/O, no Rerun.
    """

    def __init__(self, Cs, y_row: YRow):
        self.Cs = [np.atleast_2d(np.asarray(C, dtype=float)) for C in Cs]
        self.m = len(self.Cs)
        self.size = sum(C.shape[0] for C in self.Cs)
        self.y_row = y_row
        self._dis = np.full(64, np.nan)  # the disagreement of each event time batched so far, by tau
        # the measurements y_row gave, by tau (a None is asked again: a live source may know it later)
        self._y, self._miss, self._known = np.zeros((64, self.size)), np.ones((64, self.m), bool), np.zeros(64, bool)
        self._base = 0  # the event time of row 0 of these arrays (forget_before)

    def measurements(self, taus) -> tuple[np.ndarray, np.ndarray]:
        """``y`` (L, sum s_i) and ``missing`` (L, m) of event times ``taus`` (0.0 and missing where unknown).

        ``y_row`` is asked once per event time that it knows (``trajectory.npz``, rewritten at every
        flush, asks again for every row).

        Raises
        ------
        ValueError
            If ``y_row`` gives a row of the wrong shape.
        """
        taus = np.asarray(taus, dtype=np.int64).reshape(-1)
        idx = taus - self._base  # a run until stopped forgets the oldest (forget_before): unknown there
        held = idx >= 0
        if held.any() and int(idx.max()) >= len(self._known):
            cap = max(2 * len(self._known), int(idx.max()) + 1)
            self._y, self._miss, self._known = (_grown(a, cap, fill) for a, fill in
                                                ((self._y, 0.0), (self._miss, True), (self._known, False)))
        for k in idx[held][~self._known[idx[held]]].tolist():
            got = self.y_row(int(k + self._base))
            if got is None:
                continue
            y, miss = np.asarray(got[0], dtype=float).reshape(-1), np.asarray(got[1], dtype=bool).reshape(-1)
            if y.shape != (self.size,) or miss.shape != (self.m,):
                raise ValueError(f"the measurement of event time {k + self._base} has y {y.shape} and missing "
                                 f"{miss.shape}; expected ({self.size},) and ({self.m},)")
            self._y[k], self._miss[k], self._known[k] = y, miss, True
        Y, missing = np.zeros((len(taus), self.size)), np.ones((len(taus), self.m), dtype=bool)
        Y[held], missing[held] = self._y[idx[held]], self._miss[idx[held]]
        return Y, missing

    def forget_before(self, tau: int) -> None:
        """Forget the event times before ``tau`` (a run until stopped holds a window of rows; they are on disk)."""
        d = int(tau) - self._base
        if d <= 0:
            return
        for name, fill in (("_y", 0.0), ("_miss", True), ("_known", False), ("_dis", np.nan)):
            a = getattr(self, name)
            keep = max(0, len(a) - d)
            a[:keep] = a[len(a) - keep:]
            a[keep:] = fill
        self._base = int(tau)

    def batch(self, seq, t, wall, xhat: np.ndarray) -> ReferenceBatch:
        """Rows of event times ``seq`` with estimates ``xhat`` (L, m, n), NaN where an agent is dead."""
        seq = np.asarray(seq, dtype=np.int64)
        Y, missing = self.measurements(seq)
        dis = disagreement(xhat)
        if len(seq):
            k = seq - self._base
            if int(k.max()) >= len(self._dis):
                self._dis = _grown(self._dis, max(2 * len(self._dis), int(k.max()) + 1), np.nan)
            self._dis[k[k >= 0]] = dis[k >= 0]
        return ReferenceBatch(seq=seq, t=np.asarray(t), wall=np.asarray(wall),
                              residual=residuals(xhat, Y, missing, self.Cs), disagreement=dis)

    def mark_y(self, tau: int) -> float:
        """Height of a mark at ``tau`` on the log10 disagreement axis: at the last event time at or before ``tau``
        with a positive disagreement; 0.0 if there is none."""
        dis = self._dis[:max(0, min(int(tau) + 1 - self._base, len(self._dis)))]
        ok = np.nonzero(np.isfinite(dis) & (dis > 0))[0]
        return math.log10(float(dis[ok[-1]])) if ok.size else 0.0


class ReferenceView:
    """Logs :class:`ReferenceBatch` rows and the filter after the run to one recording stream ``rec``.

    ``index(rr, taus, seconds, walls_ns)``: the timeline columns of the sink; ``truth``: the run has
    the truth (the filter's state line is then drawn thinner and grey, beside the truth's).
    """

    def __init__(self, rec, agent_ids, n: int, *, truth: bool, index, labels=None):
        self.rec, self.agent_ids, self.n = rec, [int(a) for a in agent_ids], int(n)
        self.labels = labels or bp.state_labels(self.n)  # (entity label, display name) per state
        self.truth, self._index = bool(truth), index

    def log_static_styles(self, rr) -> None:
        def line(path, name, col, width=None):
            self.rec.log(path, rr.SeriesLines(names=name, colors=[col], **({"widths": width} if width else {})),
                         static=True)

        for path in (bp.DISAGREEMENT, bp.DISAGREEMENT_LOG10):
            line(path, "disagreement", bp.DISAGREEMENT_COLOR, 2.5)
        for i, a in enumerate(self.agent_ids):
            for prefix in (bp.RESIDUAL, bp.RESIDUAL_LOG10, bp.KF_DISTANCE, bp.KF_DISTANCE_LOG10):
                line(bp.agent_path(prefix, a), f"agent {a}", bp.color(i))
        for label, name in self.labels:
            if self.truth:
                line(bp.state_path(label, "kf"), f"{name} centralized KF", bp.KF_BESIDE_TRUTH_COLOR, 2.0)
            else:
                line(bp.state_path(label, "kf"), f"{name} centralized KF", bp.KF_COLOR, 3.0)

    def agent_series(self, agent_id: int) -> list[str]:
        """The row series of one agent alone (what its loss clears)."""
        return [bp.agent_path(bp.RESIDUAL, agent_id), bp.agent_path(bp.RESIDUAL_LOG10, agent_id)]

    def _send(self, rr, seq, t, wall, parts) -> None:
        """Each part's values where known, a non-recursive Clear elsewhere: at most two chunks per entity."""
        for path, values, known in parts:
            if known.any():
                self.rec.send_columns(path, indexes=self._index(rr, seq[known], t[known], wall[known]),
                                      columns=rr.Scalars.columns(scalars=values[known]))
            unknown = ~known
            if unknown.any():
                self.rec.send_columns(path, indexes=self._index(rr, seq[unknown], t[unknown], wall[unknown]),
                                      columns=rr.Clear.columns(is_recursive=np.zeros(int(unknown.sum()), bool)))

    def send_rows(self, b: ReferenceBatch) -> None:
        """The residuals and the disagreement of the batch's rows."""
        import rerun as rr

        self._send(rr, b.seq, b.t, b.wall, b.parts(self.agent_ids))

    def send_after_run(self, seq: np.ndarray, t: np.ndarray, wall: np.ndarray, kf: np.ndarray,
                       kf_distance: np.ndarray) -> None:
        """The centralized Kalman filter ``kf`` (T, n) and every agent's distance to it (T, m), NaN where dead."""
        import rerun as rr

        seq, t, wall = np.asarray(seq, dtype=np.int64), np.asarray(t), np.asarray(wall)
        idx = self._index(rr, seq, t, wall)
        for c in range(self.n):
            self.rec.send_columns(bp.state_path(self.labels[c][0], "kf"), indexes=idx,
                                  columns=rr.Scalars.columns(scalars=kf[:, c]))
        parts = []
        for i, a in enumerate(self.agent_ids):
            parts += known_parts(bp.agent_path(bp.KF_DISTANCE, a), bp.agent_path(bp.KF_DISTANCE_LOG10, a),
                                 kf_distance[:, i])
        self._send(rr, seq, t, wall, parts)


def progress_text(max_error: float, xhat: np.ndarray, alive: np.ndarray | None = None) -> str:
    """The figure of a live progress line: ``max error`` with the truth, else the consensus ``disagreement``
    (``max_ij |x_i - x_j|`` over the ``alive`` rows of ``xhat`` (m, n), NaN rows dead) -- never an error the run
    cannot know.  For the orchestrator's ``Progress`` line (``rounds.Record.max_error`` is NaN without truth)."""
    if math.isfinite(max_error):
        return f"max error {max_error:9.3e}"
    return f"disagreement {row_disagreement(xhat, alive):9.3e}"


def row_disagreement(xhat: np.ndarray, alive: np.ndarray | None = None) -> float:
    """``max_ij |x_i - x_j|`` over the ``alive`` rows of one event time's ``xhat`` (m, n) (NaN with none alive):
    :func:`splitspec_core.studies.no_truth.disagreement` of that row."""
    xhat = np.array(xhat, dtype=float)
    if alive is not None:
        xhat[~np.asarray(alive, dtype=bool)] = np.nan
    return float(disagreement(xhat[None])[0])
