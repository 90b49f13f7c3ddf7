"""What the round in flight has collected: the plant's truth and the agents' estimates, at most two event times.

Round ``tau`` collects ``truth(tau)`` from the plant and, from every alive agent, ``x_i(tau)`` (its admission
estimate, or the previous round's result) and ``x_i(tau + 1)`` with ``g_i(tau)``, the consensus messages it did
not count and, with live sensors, the ``y_i(tau)`` it used.  :class:`Collected` keeps them until the round is
recorded (:meth:`Collected.take`), so its buffers hold at most two event times.  I/O-free.
"""

from __future__ import annotations

import numpy as np

__all__ = ["Collected"]


class Collected:
    """The buffers of the rounds in flight (``index``: agent id -> its row; ``m``, ``n``: agents, states)."""

    def __init__(self, index: dict, m: int, n: int, *, plantless: bool):
        self.index, self.m, self.n, self.plantless = index, int(m), int(n), bool(plantless)
        self.truth: dict = {}
        self.est: dict = {}
        self.est_g: dict = {}  # tau -> {agent id: g_i(tau)} from the xhat messages (for Record)
        self.est_y: dict = {}  # tau + 1 -> {agent id: y_i(tau) it used, or None} (live sensors)
        self.est_lost: dict = {}  # tau + 1 -> {agent id: [k, j, cause, ...]}: what the round of tau did not count

    def put_truth(self, tau: int, attempt: int, x, *, at: tuple, in_flight: bool) -> str | None:
        """The plant's ``x(tau)`` of attempt ``attempt``, kept if it is the round in flight's (``at``: its
        ``(tau, attempt)``; ``in_flight``: a round is in flight); else why not, ``stale`` or ``future``."""
        if not in_flight or (tau, attempt) != at:
            return "stale" if (tau, attempt) < at else "future"
        self.truth[tau] = x
        return None

    def put_xhat(self, aid: int, tau: int, attempt: int, x, g: float, *, at: tuple, in_flight: bool,
                 same_incarnation: bool, lost=(), y=()) -> str | None:
        """Agent ``aid``'s estimate ``x_i(tau)`` of attempt ``attempt``, kept if the round in flight (``at``,
        ``in_flight`` as in :meth:`put_truth`) takes it and it comes from the agent's current incarnation
        (``same_incarnation``); else why not, ``stale`` or ``future``."""
        at_tau, at_attempt = at
        # x_i(tau) does not depend on the attempt (a fresh estimate at admission, else the last round's result):
        # an admission estimate that crosses a re-run still counts; x_i(tau + 1) only from the round in flight
        current = attempt == at_attempt or (tau == at_tau and attempt < at_attempt)
        if not in_flight or not current or not same_incarnation or tau not in (at_tau, at_tau + 1):
            return "future" if (tau, attempt) > (at_tau + 1, at_attempt) else "stale"
        self.est.setdefault(tau, {})[aid] = x
        self.est_g.setdefault(tau, {})[aid] = g  # g_i(tau), recorded with row tau
        if tau == at_tau + 1:
            self.est_lost.setdefault(tau, {})[aid] = list(lost)
            if self.plantless:
                self.est_y.setdefault(tau, {})[aid] = y
        return None

    def drop_next(self, tau: int) -> None:
        """Round ``tau`` is re-run: what it collected for ``tau + 1`` no longer counts."""
        self.est.pop(tau + 1, None)
        self.est_y.pop(tau + 1, None)
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

    def take(self, tau: int, alive) -> tuple:
        """Round ``tau``'s row, out of the buffers: ``(x, xhat, mask, gains, lost, used)``.

        ``xhat``/``gains``: one row per agent, NaN for the agents not alive; ``lost``: ``(tau, k, j, i, cause)``
        of every consensus message of the round that did not count; ``used``: agent id -> ``y_i(tau)``.
        """
        xh = np.full((self.m, self.n), np.nan)
        mask = np.zeros(self.m, dtype=bool)
        for a in alive:
            xh[self.index[a]] = self.est[tau][a]
            mask[self.index[a]] = True
        gains = np.full(self.m, np.nan)
        for a, g in self.est_g.pop(tau, {}).items():
            if a in alive:
                gains[self.index[a]] = float(g)
        lost = tuple((tau, t[0], t[1], a, t[2]) for a, flat in sorted(self.est_lost.pop(tau + 1, {}).items())
                     if a in alive for t in zip(flat[0::3], flat[1::3], flat[2::3]))
        x = self.truth[tau] if not self.plantless else np.full(self.n, np.nan)  # live sensors: x unknown
        used = self.est_y.pop(tau + 1, {})
        self.truth.pop(tau, None)
        self.est.pop(tau, None)
        return x, xh, mask, gains, lost, used
