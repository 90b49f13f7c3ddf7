"""Whether a paced run keeps ``run.pace``: each event time's lateness, one warning when it falls behind, the totals.

A paced run starts the round of event time ``tau`` at ``t_run + tau / pace`` on the orchestrator's clock
(:class:`~splitspec_orchestrator.rounds.machine.RoundMachine`); a round that starts later than that is *late*
by the difference.  Lateness is measured per event time (``rounds/late_ms`` in the recording, the chunks'
``round`` column) and counted as late above :data:`LATE_SHARE` of a period.  When every event time for
:data:`SUSTAINED_SECONDS` of wall time (at least :data:`SUSTAINED_MIN` event times) was late, the run cannot keep
its pace: :class:`PaceWatch` says so once, with the rate achieved over those event times and what limits it:

* the rounds themselves take longer than a period: the network's deadline when ``q`` sub-rounds at the
  deadline fill half a period or more, else the machine (m + 2 processes on its cores), naming the agent
  whose estimate came last most often;
* the rounds are quick but start too far apart: the orchestrator's own work between rounds.

No I/O, no clock: the machine hands it ``now``.  :meth:`PaceWatch.summary` gives what ``run_finished``
reports (late event times, the largest lateness).
"""

from __future__ import annotations

from collections import Counter, deque

from .actions import Event, Log

__all__ = ["PaceWatch", "LATE_SHARE", "SUSTAINED_SECONDS", "SUSTAINED_MIN"]

#: an event time is late when its round starts more than this share of a period after its time
LATE_SHARE = 0.1
#: behind when every event time was late for this many seconds of wall time ...
SUSTAINED_SECONDS = 2.0
#: ... and at least this many event times
SUSTAINED_MIN = 10
_RECENT = 200  # event times whose rounds tell what limits the rate


class PaceWatch:
    """Lateness of a run paced at ``pace`` event times per second (see the module docstring).

    ``deadline_s``: the network's sub-round deadline (``network.deadline``; None: rounds wait for everyone),
    ``q``: consensus exchanges per event time, ``m``: agents, ``cores``: the machine's.
    """

    def __init__(self, pace: float, *, q: int, m: int, deadline_s: float | None = None, cores: int | None = None):
        self.pace = float(pace)
        self.period = 1.0 / self.pace
        self.q, self.m, self.deadline_s, self.cores = int(q), int(m), deadline_s, cores
        self.recent: deque = deque(maxlen=_RECENT)  # (start, round seconds, last agent) of the last event times
        self.streak = 0  # event times late in a row
        self.streak_since = 0.0  # the start of the first of them
        self.late_count = 0
        self.max_late = 0.0
        self.warned = False

    @classmethod
    def of(cls, sc, des, *, cores: int | None = None) -> "PaceWatch | None":
        """The watch of scenario ``sc`` (design ``des``), None unpaced."""
        if not sc.run.pace:
            return None
        deadline = getattr(getattr(sc, "network", None), "deadline", None)
        return cls(sc.run.pace, q=int(des.q or 1), m=sc.m, deadline_s=deadline, cores=cores)

    def observe(self, tau: int, late: float, started: float, done: float, last_agent: int | None, t: float) -> list:
        """Event time ``tau``'s round started ``late`` seconds behind the pace at ``started`` and completed at
        ``done``; ``last_agent``: whose estimate completed it.  The warning, once, when the run fell behind."""
        late = max(0.0, float(late))
        self.max_late = max(self.max_late, late)
        self.recent.append((started, done - started, last_agent))
        if late <= LATE_SHARE * self.period:
            self.streak = 0
            return []
        self.late_count += 1
        if self.streak == 0:
            self.streak_since = started
        self.streak += 1
        if self.warned or self.streak < SUSTAINED_MIN or started - self.streak_since < SUSTAINED_SECONDS:
            return []
        self.warned = True
        achieved = (self.streak - 1) / max(started - self.streak_since, 1e-9)
        why = self.limit()
        text = (f"cannot keep pace {self.pace:g}: {achieved:.1f} event times per second over the last "
                f"{self.streak}, {late * 1e3:.0f} ms behind at event time {tau}; limited by {why}")
        fields = {"pace": self.pace, "achieved_rate": round(achieved, 2), "late_ms": round(late * 1e3, 1),
                  "limit": why}
        return [Event("pace_not_kept", t, fields, level="WARN"), Log("warning", text)]

    def limit(self) -> str:
        """What limits the rate, from the recent rounds (see the module docstring)."""
        r = list(self.recent)
        durations = sorted(x[1] for x in r)
        median = durations[len(durations) // 2]
        period_ms = self.period * 1e3
        if median >= 0.9 * self.period:
            if self.deadline_s is not None and self.q * self.deadline_s >= 0.5 * self.period:
                return (f"the network deadline: q = {self.q} sub-rounds of up to {self.deadline_s * 1e3:g} ms in a "
                        f"period of {period_ms:.1f} ms")
            last = Counter(x[2] for x in r if x[2] is not None).most_common(1)
            who = f"; agent {last[0][0]}'s estimate came last in {last[0][1]} of {len(r)}" if last else ""
            cores = f" on {self.cores} cores" if self.cores else ""
            return (f"the machine: a round takes {median * 1e3:.1f} ms (median) against a period of "
                    f"{period_ms:.1f} ms ({self.m} agents, the plant and the orchestrator{cores}){who}")
        starts = [x[0] for x in r]
        gap = (starts[-1] - starts[0]) / max(len(starts) - 1, 1)
        return (f"the orchestrator: rounds take {median * 1e3:.1f} ms (median) but start {gap * 1e3:.1f} ms apart "
                f"(its own work between rounds: recording, Rerun)")

    def summary(self) -> dict:
        """What ``run_finished`` reports: the pace, whether it was kept (no warning), the late event times and the
        largest lateness."""
        return {"pace": self.pace, "pace_kept": not self.warned, "late_event_times": int(self.late_count),
                "max_lateness_ms": round(self.max_late * 1e3, 1)}
