"""Row storage of the recorder: one row per event time, grown by doubling, and what each row shows.

Row ``k`` holds event time ``tau[k]``: one array per column of the row schema
(:data:`splitspec_core.model.rows.COLUMNS`, an attribute of its name, filled with its fill): ``t`` (T,),
``x`` (T, n), ``xhat`` (T, m, n) NaN where dead, ``alive`` (T, m), ``graph`` (T,), the agents' reported
columns (T, m) such as ``g``, the fill where dead or none, ``round`` (T, 5) wall ms / attempts / rejected /
lost / late ms (:data:`splitspec_core.model.rows.ROUND_FIELDS`), ``wall`` (T,) ``time.time_ns()`` of the
row's last arrival; and what the recorder keeps of them: ``shown``/``shown_max``:
what Rerun currently shows (retracted with a Clear when it stops being
true); ``env_c``/``env_t0``: the max error and the time where the designed envelope's piece of
row k starts.  ``rows`` = T.  No I/O and no lock: the recorder holds its locks.

A run that goes on until stopped keeps a window of rows: :meth:`RowStore.drop` forgets the first rows once
they are on disk; ``base`` counts them (row ``k`` is the run's row ``base + k``).

The recorder keeps two: the rows as its callers record them, and the rows as
its flushes took them (:meth:`RowStore.take`), which the flushes write out
while the callers go on recording; ``shown``, ``shown_max`` and ``env_start``
are only kept up to date in the second (``env_c``, ``env_t0`` likewise).
"""

from __future__ import annotations

import math

import numpy as np

from splitspec_core.model.rows import COLUMNS, empty

__all__ = ["RowStore"]


class RowStore:
    """Preallocated row arrays of one run (``capacity`` rows to start with, doubling when full)."""

    def __init__(self, m: int, n: int, *, capacity: int):
        self.m, self.n = int(m), int(n)
        cap = int(capacity)
        for c in COLUMNS:  # t, x, xhat, alive, graph, tau, wall, the reported columns (g...), round
            setattr(self, c.name, empty(c, cap, self.m, self.n))
        self.env_c = np.full(cap, np.nan)  # the envelope's piece of the row: its max error at the piece's start
        self.env_t0 = np.zeros(cap)  # and the time of that start
        # What is currently shown in Rerun per row (to retract with Clear when it stops being true).
        self.shown = np.zeros((cap, m), dtype=bool)
        self.shown_max = np.zeros(cap, dtype=bool)
        self.rows = 0
        self.base = 0  # rows forgotten before row 0 (drop)
        self.row_of_tau: dict[int, int] = {}

    def append_slot(self, tau: int) -> int:
        """A new row for event time ``tau`` (after the last one); its index."""
        k = self.rows
        if k == self.t.shape[0]:
            self.grow()
        self.tau[k] = tau
        self.row_of_tau[tau] = k
        self.rows += 1
        return k

    _RECORDED = tuple(c.name for c in COLUMNS)  # what take() copies

    def take(self, src: "RowStore", start: int, upto: int, changed: np.ndarray) -> None:
        """Copy the recorded columns of rows ``start..upto-1`` and of ``changed`` (all below ``start``)
        from ``src``; hold ``upto`` rows after it.  Slices for the new rows: a plain memory copy."""
        self.reserve(upto)
        for name in self._RECORDED:
            dst, srcarr = getattr(self, name), getattr(src, name)
            dst[start:upto] = srcarr[start:upto]
            if len(changed):
                dst[changed] = srcarr[changed]
        self.rows = max(self.rows, upto)

    def reserve(self, capacity: int) -> None:
        """Room for ``capacity`` rows at least (doubling, in one step however far)."""
        cap = self.t.shape[0]
        if capacity > cap:
            self.grow(max(2 * cap, int(capacity)))

    _FILL = {**{c.name: c.fill for c in COLUMNS}, "env_c": np.nan, "env_t0": 0.0, "shown": False, "shown_max": False}

    def spare(self, capacity: int) -> dict[str, np.ndarray]:
        """Empty columns for ``capacity`` rows, filled (the memory touched): for :meth:`adopt`, later.

        Reads only the columns' shapes: a thread may prepare them while another records rows.
        """
        return {name: np.full((int(capacity),) + getattr(self, name).shape[1:], fill, dtype=getattr(self, name).dtype)
                for name, fill in self._FILL.items()}

    def adopt(self, spare: dict[str, np.ndarray]) -> None:
        """Move the rows held into ``spare`` (from :meth:`spare`, more rows than now) and use its columns."""
        T = self.rows
        for name in self._FILL:
            new = spare[name]
            new[:T] = getattr(self, name)[:T]
            setattr(self, name, new)

    @property
    def capacity(self) -> int:
        return self.t.shape[0]

    def grow(self, capacity: int | None = None) -> None:
        """Room for ``capacity`` rows (default: twice as many); the rows held are kept."""
        self.adopt(self.spare(2 * self.capacity if capacity is None else capacity))

    def row_errors(self, ks: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``|x_i - x|_2`` of rows ``ks`` (L, m), NaN if dead, and where it is shown (alive and finite)."""
        err = np.linalg.norm(self.xhat[ks] - self.x[ks][:, None, :], axis=2)
        return err, self.alive[ks] & np.isfinite(err)

    def max_errors(self, ks: np.ndarray) -> np.ndarray:
        """``max_i |x_i - x|`` over the shown agents of rows ``ks`` (alive, finite error); -inf where none."""
        err, show = self.row_errors(ks)
        return np.where(show, err, -np.inf).max(axis=1)

    def max_error(self, k: int) -> float:
        """``max_i |x_i - x|`` over the alive agents of row ``k`` (NaN if none)."""
        e = float(self.max_errors(np.array([k]))[0])
        return e if math.isfinite(e) else math.nan

    def envelope(self, ks: np.ndarray, lam: float | None, time_mode: str) -> np.ndarray:
        """The designed envelope at rows ``ks`` (sorted; every earlier row already has its piece).

        Row k starts a piece when it is the run's first, its alive set gains an agent, or its graph changed
        (:func:`splitspec_core.simulation.metrics.envelope_restarts`); on a piece started at k0:
        ``c lam^(t - t_k0)`` or ``c exp(-lam (t - t_k0))``, ``c`` the max error at k0.  The first row of a
        window (``base > 0``) keeps the piece it had.
        """
        env = np.full(len(ks), np.nan)
        for r, k in enumerate(ks.tolist()):
            if k == 0 and self.base:
                pass  # its row before is forgotten: its piece stays as computed
            elif k == 0 or bool((self.alive[k] & ~self.alive[k - 1]).any()) or self.graph[k] != self.graph[k - 1]:
                self.env_c[k], self.env_t0[k] = self.max_error(k), self.t[k]
            else:
                self.env_c[k], self.env_t0[k] = self.env_c[k - 1], self.env_t0[k - 1]
            if lam is None:
                continue
            c, dt = float(self.env_c[k]), self.t[k] - self.env_t0[k]
            if math.isfinite(c) and c > 0:
                env[r] = c * (math.exp(-lam * dt) if time_mode == "continuous" else lam ** dt)
        return env

    def drop(self, d: int) -> None:
        """Forget the first ``d`` rows (on disk already): the others move to the front, ``base`` grows by ``d``."""
        d = min(int(d), self.rows)
        if d <= 0:
            return
        keep = self.rows - d
        for name in self._FILL:
            a = getattr(self, name)
            a[:keep] = a[d:self.rows]
        self.rows, self.base = keep, self.base + d
        self.row_of_tau = {int(tau): k for k, tau in enumerate(self.tau[:keep].tolist())}

    def mark_y(self, tau: int) -> float:
        """Height of a mark at ``tau`` on the log10 error axis: log10 of the max error at (or before) ``tau``.

        The last row at or before ``tau`` with a positive finite max error, searched backwards a block
        of rows at a time (errors that reached exactly 0 could otherwise cost a row-by-row scan of the
        whole run per mark); 0.0 if there is none.
        """
        T = self.rows
        hi = min(max(int(np.searchsorted(self.tau[:T], tau, side="right")), 1), T)
        while hi > 0:
            lo = max(0, hi - 256)
            err = self.max_errors(np.arange(lo, hi))
            ok = np.nonzero(err > 0)[0]
            if ok.size:
                return math.log10(float(err[ok[-1]]))
            hi = lo
        return 0.0
