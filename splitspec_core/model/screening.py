"""Every agent's bad-data test at once, for the simulator, and the events a run's records imply.

:class:`Screen` runs :func:`~splitspec_core.model.steps.innovation_test` and
:func:`~splitspec_core.model.steps.sensor_watch` for every alive agent of one event time, exactly as each agent
process does for itself (:mod:`splitspec_core.synthesis.bad_data` for the math), and keeps what the round reports:
``y_statistic`` (``d_i``; ``-1.0`` for an alive agent with nothing tested: no measurement, or one of its first
``warmup`` measurements after its admission, while its initial error settles: :func:`~splitspec_core.model.steps.
warmup_step`) and ``y_rejected``
(the measurement was set aside: failed, or its sensor suspect).  :class:`Watch` replays the watch on recorded rows
(``alive``, ``y_statistic``) and says when a sensor became suspect and when it was restored: the orchestrator's
``sensor_suspect`` / ``sensor_restored`` events, and :func:`sensor_events` for a simulated trajectory.
"""

from __future__ import annotations

import numpy as np

from . import steps as st
from .plant import output_rows

__all__ = ["UNTESTED", "FLATLINE", "Screen", "Watch", "sensor_events"]

#: ``y_statistic`` where nothing was tested (the watch holds): the fill of the row column
UNTESTED = -1.0
#: ``y_statistic`` of a measurement that repeats the last one exactly (:func:`~splitspec_core.model.steps.flatline`,
#: a failed test whatever ``d_i``): ``d_i >= 0`` otherwise, so the code is unambiguous and finite on the wire
FLATLINE = -2.0


class Screen:
    """The bad-data tests of the agents of a design (:func:`splitspec_core.synthesis.bad_data.bad_data`).

    ``suspect`` (m,) bool: the sensors suspect at the start of the event time (their agents use
    :meth:`fallback`'s ``P_i = I`` and no measurement); after :meth:`screen`, ``statistic`` and ``rejected`` are the
    round's reported columns and ``events`` has every ``(tau, agent id, event, d_i, threshold)`` so far.
    """

    def __init__(self, bd, Cs, agent_ids):
        self.Cs = [np.asarray(C, dtype=float) for C in Cs]
        self.rows = output_rows(self.Cs)
        self.ids = tuple(agent_ids)
        m = len(self.Cs)
        self.S_inv = [t.S_inv for t in bd.tests]
        self.threshold = [t.threshold for t in bd.tests]
        self.k = bd.suspect_after
        self.warmup = bd.warmup
        self.flat = bd.flatline  # the repeat test (off with live sensors, which may repeat a sample)
        self.last: list = [None] * m  # per agent, the last measurement it was given in this incarnation
        self.suspect = np.zeros(m, dtype=bool)
        self.run = np.zeros(m, dtype=np.int64)
        self.seen = np.zeros(m, dtype=np.int64)  # the measurements of the agent's incarnation (its warm-up)
        self.statistic = np.full(m, UNTESTED)
        self.rejected = np.zeros(m, dtype=bool)
        self.events: list = []

    def reset(self, i: int) -> None:
        """Agent at position ``i`` starts afresh (a loss, a rejoin): its sensor is not suspect.

        Parameters
        ----------
        i : int
            The agent's position.
        """
        self.suspect[i] = False
        self.run[i] = 0
        self.seen[i] = 0
        self.last[i] = None

    def rejoined(self) -> None:
        """An agent rejoined with a fresh estimate in the whole-state design: the warm-up of every sensor not suspect
        starts afresh.

        Its consensus averages whole estimates, so the fresh estimate's error reaches the neighbours' measured
        directions within an event time and their errors are no longer the steady state ``S_i`` predicts (the paper's
        split moves only what each agent does not see, ``C_i P_i = 0``, and needs none of this: the simulator calls
        this for the whole-state design only).  Tested at once, their clean measurements failed, and where
        the sensors so made suspect were the only ones to see a direction (a motor's angle), nobody was left to bring
        their agents back and none was ever restored.  So their measurements are used untested again for ``warmup``
        of them, as after the run's start.  A sensor suspect before stays suspect, set aside and tested (only clean
        tests restore it: a sensor that lies through a rejoin is not taken back untested).  The watches' counts
        hold, as on every untested event time, so :class:`Watch` replays the same decisions from the rows; the agent
        process does the same on a tick that carries a higher incarnation (``agents/agent.py``).
        """
        self.seen[~self.suspect] = 0

    def fallback(self, Ps) -> list:
        """The projections of this event time's consensus: ``I`` for the suspect sensors' agents, ``P_i`` else.

        Parameters
        ----------
        Ps : sequence of (n, n) arrays
            The design's ``P_i``.

        Returns
        -------
        list of (n, n) arrays
            Per agent.
        """
        return [np.eye(P.shape[0]) if s else P for P, s in zip(Ps, self.suspect)]

    def screen(self, tau: int, Z: np.ndarray, y: np.ndarray, missing, alive: np.ndarray) -> np.ndarray:
        """Test every alive agent's measurement of ``tau`` against ``Z`` (what its update applies ``K_i`` to).

        Parameters
        ----------
        tau : int
            The event time.
        Z : (m, n) array
            Per agent, ``z_i(q)`` (split design) or ``x_i(tau)`` (whole-state design, sampled-data form).
        y : (sum s_i,) array
            The stacked measurement.
        missing : (m,) bool array or None
            The agents without a measurement.
        alive : (m,) bool array
            The agents taking part.

        Returns
        -------
        (m,) bool array
            ``missing`` or the measurements set aside: what the update must not use.
        """
        m = len(self.Cs)
        out = np.zeros(m, dtype=bool) if missing is None else np.array(missing, dtype=bool)
        self.statistic = np.full(m, UNTESTED)
        self.rejected = np.zeros(m, dtype=bool)
        for i in np.flatnonzero(alive):
            self.seen[i], tested = st.warmup_step(int(self.seen[i]), not out[i], self.warmup)
            if out[i]:
                continue
            y_i, last = y[self.rows[i]], self.last[i]
            self.last[i] = np.array(y_i, dtype=float)
            if not tested:
                continue  # statistic UNTESTED
            d, failed = st.innovation_test(y_i, self.Cs[i], Z[i], self.S_inv[i], self.threshold[i])
            if self.flat and st.flatline(y_i, last):
                d, failed = FLATLINE, True
            self.statistic[i] = d
            used = not (self.suspect[i] or failed)
            self.suspect[i], self.run[i], event = st.sensor_watch(bool(self.suspect[i]), int(self.run[i]), failed,
                                                                  self.k)
            if event is not None:
                self.events.append((tau, self.ids[i], event, d, self.threshold[i]))
            if not used:
                self.rejected[i] = out[i] = True
        return out


class Watch:
    """The watch of every sensor replayed on recorded rows (:func:`~splitspec_core.model.steps.sensor_watch`): what
    the agents decided, from their reported ``y_statistic``."""

    def __init__(self, bd, agent_ids):
        self.ids = tuple(agent_ids)
        self.threshold = np.array([t.threshold for t in bd.tests])
        self.k = bd.suspect_after
        self.suspect = np.zeros(len(self.ids), dtype=bool)
        self.run = np.zeros(len(self.ids), dtype=np.int64)

    def row(self, tau: int, alive, statistic) -> list:
        """The events of the round of ``tau``.

        Parameters
        ----------
        tau : int
            The event time of the row.
        alive : (m,) bool array
            The agents alive at ``tau`` (a lost agent's watch starts afresh).
        statistic : (m,) array
            Their ``y_statistic`` (:data:`UNTESTED`: nothing tested).

        Returns
        -------
        list of tuple
            ``(tau, agent id, event, d_i, threshold)``, ``event`` ``sensor_suspect`` or ``sensor_restored``.
        """
        out = []
        for i, aid in enumerate(self.ids):
            d = float(statistic[i])
            if not alive[i]:
                self.suspect[i], self.run[i] = False, 0
                continue
            if not np.isfinite(d) or d == UNTESTED:
                continue
            failed = d == FLATLINE or d > self.threshold[i]
            self.suspect[i], self.run[i], event = st.sensor_watch(bool(self.suspect[i]), int(self.run[i]), failed,
                                                                  self.k)
            if event is not None:
                out.append((tau, aid, event, d, float(self.threshold[i])))
        return out


def sensor_events(tr, bd) -> list:
    """The ``sensor_suspect`` / ``sensor_restored`` events of a trajectory (simulated or recorded).

    Parameters
    ----------
    tr : Trajectory
        With its ``y_statistic`` column (``design.bad_data`` on).
    bd : BadData
        The design's :func:`splitspec_core.synthesis.bad_data.bad_data`.

    Returns
    -------
    list of tuple
        ``(t, agent id, event, d_i, threshold)`` in time order (``t``: the row's time).
    """
    w = Watch(bd, tr.agent_ids.tolist())
    stat = tr.columns["y_statistic"]
    out = []
    for k in range(len(tr.t)):
        out += [(float(tr.t[k]),) + e[1:] for e in w.row(k, tr.alive[k], stat[k])]
    return out
