"""What the round in flight has collected: the plant's truth and the agents' estimates, at most two event times.

Round ``tau`` collects ``truth(tau)`` from the plant and, from every alive agent, ``x_i(tau)`` (its admission
estimate, or the previous round's result) and ``x_i(tau + 1)``, each with the row columns the agent reports
(:data:`splitspec_core.model.rows.REPORTED`: of its state, such as ``g_i``, or of the round), the consensus
messages it did not count and, with live sensors, the ``y_i(tau)`` (and live known inputs ``u(tau)``) it used.  :class:`Collected` keeps them until
the round is recorded (:meth:`Collected.take`, a :class:`CollectedRow`), so its buffers hold at most two event
times.  I/O-free.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from splitspec_core.model.rows import REPORTED, empty

__all__ = ["Collected", "CollectedRow"]


@dataclass(frozen=True)
class CollectedRow:
    """Round ``tau``'s row as collected.

    Attributes
    ----------
    x : (n,) the plant's truth (NaN with live sensors)
    xhat : (m, n) the estimates ``x_i(tau)``, NaN for the agents not alive
    alive : (m,) bool
    columns : reported column name -> (m,) its values, the fill for the agents not alive
    lost : ``(tau, k, j, i, cause)`` of every consensus message of the round that did not count
    used : agent id -> the ``y_i(tau)`` it used (live sensors)
    inputs : agent id -> the live known inputs ``u(tau)`` it used (live inputs; [] or absent: none reported)
    """

    x: np.ndarray
    xhat: np.ndarray
    alive: np.ndarray
    columns: dict
    lost: tuple
    used: dict
    inputs: dict


class Collected:
    """The buffers of the rounds in flight (``index``: agent id -> its row; ``m``, ``n``: agents, states)."""

    def __init__(self, index: dict, m: int, n: int, *, plantless: bool):
        self.index, self.m, self.n, self.plantless = index, int(m), int(n), bool(plantless)
        self.truth: dict = {}
        self.est: dict = {}
        self.reports: dict = {}  # tau -> {agent id: its reported columns with x_i(tau)} (rows.report)
        self.est_y: dict = {}  # tau + 1 -> {agent id: y_i(tau) it used, or None} (live sensors)
        self.est_u: dict = {}  # tau + 1 -> {agent id: u(tau) it used} (live known inputs)
        self.est_lost: dict = {}  # tau + 1 -> {agent id: [k, j, cause, ...]}: what the round of tau did not count

    def put_truth(self, tau: int, attempt: int, x, *, at: tuple, in_flight: bool) -> str | None:
        """The plant's ``x(tau)`` of attempt ``attempt``, kept if it is the round in flight's (``at``: its
        ``(tau, attempt)``; ``in_flight``: a round is in flight); else why not, ``stale`` or ``future``."""
        if not in_flight or (tau, attempt) != at:
            return "stale" if (tau, attempt) < at else "future"
        self.truth[tau] = x
        return None

    def put_xhat(self, aid: int, tau: int, attempt: int, x, columns: dict, *, at: tuple, in_flight: bool,
                 same_incarnation: bool, lost=(), y=(), u=()) -> str | None:
        """Agent ``aid``'s estimate ``x_i(tau)`` of attempt ``attempt`` with its reported row ``columns``, kept if
        the round in flight (``at``, ``in_flight`` as in :meth:`put_truth`) takes it and it comes from the agent's
        current incarnation (``same_incarnation``); else why not, ``stale`` or ``future``."""
        at_tau, at_attempt = at
        # x_i(tau) does not depend on the attempt (a fresh estimate at admission, else the last round's result):
        # an admission estimate that crosses a re-run still counts; x_i(tau + 1) only from the round in flight
        current = attempt == at_attempt or (tau == at_tau and attempt < at_attempt)
        if not in_flight or not current or not same_incarnation or tau not in (at_tau, at_tau + 1):
            return "future" if (tau, attempt) > (at_tau + 1, at_attempt) else "stale"
        self.est.setdefault(tau, {})[aid] = x
        self.reports.setdefault(tau, {})[aid] = columns  # its state's with row tau, its round's with row tau - 1
        if tau == at_tau + 1:
            self.est_lost.setdefault(tau, {})[aid] = list(lost)
            if self.plantless:
                self.est_y.setdefault(tau, {})[aid] = y
                if u:
                    self.est_u.setdefault(tau, {})[aid] = u
        return None

    def drop_next(self, tau: int) -> None:
        """Round ``tau`` is re-run: what it collected for ``tau + 1`` no longer counts."""
        self.est.pop(tau + 1, None)
        self.reports.pop(tau + 1, None)
        self.est_y.pop(tau + 1, None)
        self.est_u.pop(tau + 1, None)
        self.est_lost.pop(tau + 1, None)

    def done(self, tau: int, alive, final: bool) -> bool:
        """Round ``tau`` has the truth (but for live sensors) and every alive agent's estimates."""
        if tau not in self.truth and not self.plantless:
            return False
        have_now = self.est.get(tau, {})
        have_next = self.est.get(tau + 1, {})
        n = len(alive)
        if len(have_now) < n or (not final and len(have_next) < n):
            return False  # O(1) for all but the last estimates of a round (called on every one of the m)
        return all(a in have_now for a in alive) and (final or all(a in have_next for a in alive))

    def late(self, tau: int, alive, final: bool) -> list:
        """The alive agents whose estimate round ``tau`` still waits for."""
        have_next = self.est.get(tau + 1, {})
        late = [] if final else sorted(a for a in alive if a not in have_next)
        return late or sorted(a for a in alive if a not in self.est.get(tau, {}))

    def take(self, tau: int, alive) -> CollectedRow:
        """Round ``tau``'s row, out of the buffers (its agents' reports of ``x_i(tau + 1)`` stay for row
        ``tau + 1``).

        A reported column of the agent's state (``g_i(tau)``) comes with ``x_i(tau)``, one of the round with
        ``x_i(tau + 1)`` (none in the final round: the fill).
        """
        xh = np.full((self.m, self.n), np.nan)
        mask = np.zeros(self.m, dtype=bool)
        for a in alive:
            xh[self.index[a]] = self.est[tau][a]
            mask[self.index[a]] = True
        now, after = self.reports.pop(tau, {}), self.reports.get(tau + 1, {})
        columns = {}
        for c in REPORTED:
            values = empty(c, 1, self.m, self.n)[0]
            for a, rep in (now if c.reported == "state" else after).items():
                if a in alive:
                    values[self.index[a]] = rep[c.name]
            columns[c.name] = values
        lost = tuple((tau, t[0], t[1], a, t[2]) for a, flat in sorted(self.est_lost.pop(tau + 1, {}).items())
                     if a in alive for t in zip(flat[0::3], flat[1::3], flat[2::3]))
        x = self.truth[tau] if not self.plantless else np.full(self.n, np.nan)  # live sensors: x unknown
        used = self.est_y.pop(tau + 1, {})
        inputs = self.est_u.pop(tau + 1, {})
        self.truth.pop(tau, None)
        self.est.pop(tau, None)
        return CollectedRow(x=x, xhat=xh, alive=mask, columns=columns, lost=lost, used=used, inputs=inputs)
