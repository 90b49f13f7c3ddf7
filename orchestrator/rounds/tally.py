"""What a run did, counted as it goes: the fields of its last event (``run_finished``, ``run_interrupted``,
``run_failed``) and of the closing line of ``splitspec run`` (:func:`splitspec_core.runs.closing_line`).

:class:`RunTally` sees every ``Record`` and ``Event`` action the shell executes (no I/O, no clock): event times
recorded, the last row (its largest error, or without truth its estimates, for the disagreement), agents lost
and rejoined, consensus messages that did not count, and the pace watch's totals.
"""

from __future__ import annotations

import math

from .actions import Event, Record

__all__ = ["RunTally"]


class RunTally:
    """Counts of one run (see the module docstring)."""

    def __init__(self):
        self.event_times = 0  # rows recorded (distinct event times)
        self.last: Record | None = None
        self.agents_lost = 0
        self.agents_rejoined = 0
        self.messages_lost = 0
        self.takeovers = 0  # standbys that took the run over so far (a takeover's successor counts its predecessors')

    def record(self, a: Record) -> None:
        self.event_times += 1
        self.last = a

    def event(self, a: Event) -> None:
        if a.name == "agent_lost":
            self.agents_lost += 1
        elif a.name == "agent_rejoined":
            self.agents_rejoined += 1
        elif a.name == "messages_lost":
            self.messages_lost += int(a.fields.get("count", 0))

    def fields(self, *, seconds: float, pace=None, disagreement=None) -> dict:
        """The end event's fields: ``event_times``, ``seconds`` (wall, from the first round), ``rounds_per_second``,
        ``final_max_error`` (None without truth) or ``final_disagreement`` (``disagreement(xhat, alive)`` of the
        last row, given by the shell), ``agents_lost``, ``agents_rejoined``, ``messages_lost``, ``takeovers`` (a standby
        took the run over: how many times, counted since the run's start) and, paced, the
        :class:`~splitspec_orchestrator.rounds.pace.PaceWatch` summary (``pace``, ``late_event_times``,
        ``max_lateness_ms``)."""
        out = {"event_times": self.event_times, "seconds": round(seconds, 3),
               "rounds_per_second": round(self.event_times / max(seconds, 1e-9), 2)}
        err = self.last.max_error if self.last is not None else math.nan
        if math.isfinite(err):
            out["final_max_error"] = float(f"{err:.6g}")
        elif self.last is not None and disagreement is not None:
            d = disagreement(self.last.xhat, self.last.alive)
            out["final_disagreement"] = float(f"{d:.6g}") if math.isfinite(d) else None
        out.update(agents_lost=self.agents_lost, agents_rejoined=self.agents_rejoined,
                   messages_lost=self.messages_lost)
        if self.takeovers:
            out["takeovers"] = self.takeovers
        if pace is not None:
            out.update(pace.summary())
        return out
