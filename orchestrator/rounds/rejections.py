"""Rejected messages of a run: counted per (process, reason), summarised once per second.

:class:`Rejections` keeps the orchestrator's own rejections and the running totals the plant and the agents
report with their messages, and turns them into one ``message_rejected`` event per (process, reason) every
:data:`SUMMARY_SECONDS`, never one line per message.  I/O-free: the times are the machine's ``now``.
"""

from __future__ import annotations

from .actions import Event

__all__ = ["Rejections", "SUMMARY_SECONDS"]

SUMMARY_SECONDS = 1.0  #: rejected messages are summarised once per this many seconds


class Rejections:
    """The rejection counts of a run (``now``: the current monotonic time)."""

    def __init__(self, now: float = 0.0):
        self.total = 0
        self.recorded = 0  # total at the last Record
        self._pending: dict = {}
        self._last = now
        self._remote: dict = {}

    def add(self, by: str, reason: str, count: int = 1) -> None:
        """Count ``count`` rejected messages of process ``by`` (summarised once per second)."""
        if count > 0:
            self._pending[(by, reason)] = self._pending.get((by, reason), 0) + count
            self.total += count

    def remote(self, who: str, counts: dict, incarnation: int = 0) -> None:
        """Another process's running totals of rejections (sent with its truth / xhat); a restarted agent (a
        higher incarnation) counts from 0 again, and the totals of an older incarnation are not taken."""
        inc, prev = self._remote.get(who, (incarnation, {}))
        if incarnation < inc:
            return
        if incarnation > inc:
            prev = {}
        self._remote[who] = (incarnation, prev)
        for reason, c in counts.items():
            if isinstance(c, int) and c > prev.get(reason, 0):
                self.add(who, str(reason), c - prev.get(reason, 0))
                prev[reason] = c

    def since_record(self) -> int:
        """The rejections since the previous call (one Record's ``rejected``)."""
        rejected, self.recorded = self.total - self.recorded, self.total
        return rejected

    def summaries(self, now: float, t: float, force: bool = False) -> list:
        """The ``message_rejected`` events due at ``now`` (event time ``t``), all of them if ``force``."""
        if not self._pending or (not force and now - self._last < SUMMARY_SECONDS):
            return []
        out = [Event("message_rejected", t, {"by": by, "reason": reason, "count": c,
                                             "seconds": round(now - self._last, 3)})
               for (by, reason), c in sorted(self._pending.items())]
        self._pending.clear()
        self._last = now
        return out
