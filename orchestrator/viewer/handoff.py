"""What the records hand the Rerun recording at a flush: the rows as a batch, and the logs deferred until then.

The recorder (:class:`splitspec_orchestrator.records.recorder.Recorder`) makes no Rerun call in its callers'
threads.  Its ``event``, ``topology`` and ``mark_lost`` queue what they log in one :class:`DeferredLogs`, in
call order: a :class:`TextLine` per event (and a :class:`Mark` beside it for a loss, a rejoin, a graph
switch, a link fault, a partition or a heal), a :class:`TopologyLog` per topology, a :class:`LossClear` per
loss.  A flush takes the queue (:meth:`DeferredLogs.take`; a mark waits for the flush that takes its own
row, whose max error it stands on) and, after the rows it took (:class:`RowBatch`), sends it with
:func:`send_logs`: one chunk per kind -- the loss clears, the text lines, the marks, the topologies, then the
consensus messages that did not count, drawn over the topology (:class:`LostRow`, :func:`lost_rows`).

This module holds the data and its order; :class:`~splitspec_orchestrator.viewer.sink.RerunSink` (and
:class:`~splitspec_orchestrator.viewer.topology_view.TopologyView`) make the Rerun calls.  Entity paths:
:mod:`splitspec_orchestrator.viewer.blueprint`; what they hold: docs/reference/files.md, section "Rerun
recording".
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Callable, Iterable, Mapping, Union

import numpy as np

from . import blueprint as bp
from .topology_view import cut_arcs, partition_text

__all__ = ["RowBatch", "TextLine", "Mark", "TopologyLog", "LossClear", "Deferred", "LostRow", "DeferredLogs",
           "cut_edges", "lost_rows", "send_logs"]


@dataclass
class RowBatch:
    """Rows to log (L of them, increasing ``tau``); per-agent arrays are (L, m).

    ``show``: where an agent's values are logged (alive, finite); ``clear``:
    where a value shown by an earlier batch is no longer true (Clear).
    ``env``: the designed envelope, NaN where none; ``rounds``: (L, 5) wall ms,
    attempts, rejected, consensus messages lost, lateness against ``run.pace`` in ms (NaN unknown);
    ``columns``: the agents' reported row columns by name (:data:`splitspec_core.model.rows.REPORTED`), (L, m) each.
    """

    seq: np.ndarray
    t: np.ndarray
    wall: np.ndarray
    x: np.ndarray
    xhat: np.ndarray
    err: np.ndarray
    show: np.ndarray
    clear: np.ndarray
    err_max: np.ndarray
    show_max: np.ndarray
    clear_max: np.ndarray
    env: np.ndarray
    rounds: np.ndarray
    columns: dict

    @classmethod
    def of(cls, *, seq, t, wall, x, xhat, err: np.ndarray, show: np.ndarray, shown: np.ndarray,
           shown_max: np.ndarray, env, rounds, columns: dict) -> "RowBatch":
        """Rows as the sink logs them: ``err``/``show`` what they show now, ``shown``/``shown_max`` what earlier
        batches showed of them (a value shown that is no longer shown is cleared)."""
        show_max = show.any(axis=1)
        err_max = np.max(np.where(show, err, -np.inf), axis=1)
        return cls(seq=seq, t=t, wall=wall, x=x, xhat=xhat, err=err, show=show, clear=shown & ~show,
                   err_max=err_max, show_max=show_max, clear_max=shown_max & ~show_max, env=env, rounds=rounds,
                   columns=columns)


@dataclass(frozen=True, slots=True)
class TextLine:
    """An event's sentence on the ``events`` TextLog."""

    tau: int
    t: float
    text: str
    level: str
    wall: int  # time.time_ns()


@dataclass(frozen=True, slots=True)
class Mark:
    """A point on ``marks/<kind>`` at an event; its height is read when its row is taken."""

    tau: int
    t: float
    kind: str
    wall: int


@dataclass(frozen=True, slots=True)
class TopologyLog:
    """The communication graph at ``tau``: the alive agents, the arcs ``(j, i)`` among them (as node ids),
    those of them a partition in force cuts, and the partition's text (empty: none)."""

    tau: int
    t: float
    graph: str
    alive: frozenset
    edges: tuple
    wall: int
    cut: frozenset
    partition: str


@dataclass(frozen=True, slots=True)
class LossClear:
    """An agent lost at ``tau``: a Clear on each of its own series there."""

    tau: int
    t: float
    agent: int
    wall: int


Deferred = Union[TextLine, Mark, TopologyLog, LossClear]


@dataclass(frozen=True, slots=True)
class LostRow:
    """A row taken by a flush: its consensus messages that did not count (rows ``(tau, k, j, i, cause)``), and
    whether the previous row's did not all count (the topology view's per-event-time overlay)."""

    tau: int
    t: float
    wall: int
    lost: tuple
    prev: bool


class DeferredLogs:
    """The Rerun logs queued since the last flush, one list in call order (the caller holds its lock)."""

    def __init__(self) -> None:
        self._queue: list[Deferred] = []

    def __bool__(self) -> bool:
        return bool(self._queue)

    def event(self, event: str, tau: int, t: float, text: str, level: str) -> None:
        """An event's :class:`TextLine`, and its :class:`Mark` if the event has a kind of mark."""
        wall = time.time_ns()
        self._queue.append(TextLine(tau, t, text, level, wall))
        kind = bp.MARK_OF_EVENT.get(event)
        if kind is not None:
            self._queue.append(Mark(tau, t, kind, wall))

    def topology(self, tau: int, t: float, graph: str, alive: Iterable[int], edges: Iterable[tuple[str, str]],
                 cut: frozenset, groups: tuple) -> None:
        """A :class:`TopologyLog` (``cut``: :func:`cut_edges`; ``groups``: the partition in force, empty: none)."""
        self._queue.append(TopologyLog(tau, t, graph, frozenset(alive), tuple(edges), time.time_ns(), cut,
                                       partition_text(groups) if groups else ""))

    def loss(self, tau: int, t: float, agent: int) -> None:
        """A :class:`LossClear` of agent ``agent`` at ``tau``."""
        self._queue.append(LossClear(tau, t, agent, time.time_ns()))

    def take(self, last_tau: int | None, *, final: bool = False) -> list[Deferred]:
        """Everything queued, in call order, but the marks of an event time after ``last_tau`` (the last row
        taken, None: none), which wait for their row; ``final``: those too."""
        ready: list[Deferred] = []
        later: list[Deferred] = []
        for item in self._queue:
            waits = type(item) is Mark and not final and (last_tau is None or item.tau > last_tau)
            (later if waits else ready).append(item)
        self._queue = later
        return ready


def cut_edges(groups: tuple, edges: Iterable[tuple[str, str]], agent_ids: list[int]) -> frozenset:
    """The ``edges`` (node ids ``(j, i)``) that cross between the groups of partition ``groups`` (none without)."""
    return frozenset((str(j), str(i)) for j, i in cut_arcs(groups, [(int(j), int(i)) for j, i in edges], agent_ids))


def lost_rows(tau: np.ndarray, t: np.ndarray, wall: np.ndarray, ks: np.ndarray,
              lost: Mapping[int, tuple]) -> list[LostRow]:
    """The :class:`LostRow` of rows ``ks`` (``tau``, ``t``, ``wall``: the rows' columns; ``lost``: event time ->
    its consensus messages that did not count)."""
    out = []
    for k in ks:
        prev = bool(lost.get(int(tau[k - 1]))) if k else False
        out.append(LostRow(int(tau[k]), float(t[k]), int(wall[k]), lost.get(int(tau[k])) or (), prev))
    return out


def send_logs(sink, logs: list[Deferred], lost: list[LostRow], mark_y: Callable[[int], float]) -> None:
    """Send what a flush took to ``sink`` (a :class:`~splitspec_orchestrator.viewer.sink.RerunSink`): one chunk
    per kind, loss clears, text lines, marks (at height ``mark_y(tau)``), topologies, then the overlays of ``lost``
    drawn over them.  Each is guarded (a failure is a warning); ``mark_y`` is not."""
    clears = [item for item in logs if type(item) is LossClear]
    lines = [item for item in logs if type(item) is TextLine]
    marks = [item for item in logs if type(item) is Mark]
    topologies = [item for item in logs if type(item) is TopologyLog]
    if clears:
        sink.guarded("loss clears", sink.send_loss_clears, clears)
    if lines:
        sink.guarded("event log", sink.send_events, lines)
    if marks:
        sink.guarded("marks", sink.send_marks, marks, [mark_y(m.tau) for m in marks])
    if topologies:
        sink.guarded("topology log", sink.send_topology, topologies)
    if lost:  # after the topology it is drawn over
        sink.guarded("lost messages log", sink.send_lost, lost)
