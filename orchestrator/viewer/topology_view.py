"""The communication graph of a run's recording: ``topology`` and what a misbehaving network adds to it.

:class:`TopologyView` logs, for :class:`splitspec_orchestrator.viewer.sink.RerunSink`, the topology
(``topology``: the agents at fixed positions, the arcs among the alive ones; ``topology/graph``: the
active graph's name) and what the view shows of a network that misbehaves: arcs that lost
messages, a partition's cut.

Rerun 0.41 draws every ``GraphEdges`` edge of a graph view with one stroke: an edge has no colour,
width or dash of its own (``rerun.archetypes.GraphEdges`` holds only ``edges`` and ``graph_type``),
and a graph's node ids belong to their entity (an edge of another entity cannot reach the agents of
``topology``).  So an arc is "dashed" by taking it out of ``topology``'s edges and drawing it as a
row of small dots (``GraphNodes`` without labels) on an entity of its own, at fixed positions along
the arc:

``topology/lost``
    per event time, every arc ``j -> i`` that lost at least one consensus message of that event
    time (cause ``loss``: red; only ``late``: orange); none when nothing was lost.
``topology/partition``
    while a partition is in force, every arc between two groups (purple): no message crosses it.
``topology/status``
    one text node under the graph: what did not count in this event time, by cause.

The partition itself is named on ``topology/graph`` (a second line ``partition 1 2 3 | 4 5``, in
the cut's colour).  An overlay is drawn over the topology in force at its event time; a topology
logged later for an earlier event time (an agent lost, noticed late) redraws the overlays after it.

A rolled recording (``run-0001.rrd`` ...) starts each segment with the topology in force
(:meth:`TopologyView.relog`, at the segment's first event time): the topology is logged only when it
changes, and a segment opened alone would otherwise show no graph until the next change.

The dots of arc ``j -> i`` run from the edge of ``j``'s label box to the edge of ``i``'s, a little to
the right of the direction of travel (so ``i -> j`` lies beside it, not on it), and grow towards
``i`` (the arc's direction).  Label boxes are estimated from the label's length (the viewer's font
at 1 scene unit per pixel: about 6.3 units per character and 20 units high).

What it costs: one chunk per entity per flush (every row of the flush in it), never a log call
per message or per arc; nothing at all where every message counted.  It runs on the recorder's
flush thread like every Rerun call.
"""

from __future__ import annotations

import bisect
import math
from typing import Callable, Iterable, Mapping

import numpy as np

from splitspec_core.model.impairment import CAUSES, LATE, LOSS, PARTITION, crosses, group_of

from . import blueprint as bp

__all__ = ["TopologyView", "cut_arcs", "lost_arcs", "dash_dots", "status_text", "partition_text"]

LABEL_CHAR = 6.3  # scene units per character of a node label (rerun 0.41's graph view font, measured)
LABEL_PAD = 6.0
LABEL_HEIGHT = 20.0
DOT_SPACING = 7.0  # scene units between two dots of a dashed arc
SIDE = 3.0  # offset of a dashed arc to the right of its direction of travel
RADII = (1.2, 2.6)  # first (sender) and last (receiver) dot


def cut_arcs(groups, arcs: Iterable[tuple[int, int]], ids: Iterable[int]) -> list[tuple[int, int]]:
    """The arcs ``(j, i)`` that cross between the groups of partition ``groups`` (none without one)."""
    gmap = group_of(groups, list(ids))
    return [(j, i) for j, i in arcs if crosses(gmap, j, i)]


def lost_arcs(rows: Iterable) -> dict[tuple[int, int], int]:
    """``(j, i) -> cause`` of every arc that lost a message of ``rows`` (``(tau, k, j, i, cause)``) to
    ``loss`` or ``late``: ``LOSS`` if any of its messages was lost, else ``LATE``.  Partition causes are
    left out (the cut is drawn as such)."""
    out: dict[tuple[int, int], int] = {}
    for r in rows:
        cause = int(r[4])
        if cause == PARTITION:
            continue
        arc = (int(r[2]), int(r[3]))
        if out.get(arc) != LOSS:
            out[arc] = LOSS if cause == LOSS else LATE
    return out


def _exit(dx: float, dy: float, half_w: float, half_h: float) -> float:
    """Distance along the unit direction ``(dx, dy)`` from a box's centre to its border."""
    tx = half_w / abs(dx) if dx else math.inf
    ty = half_h / abs(dy) if dy else math.inf
    return min(tx, ty)


def _half_box(label: str) -> tuple[float, float]:
    return (LABEL_CHAR * len(label) + LABEL_PAD) / 2, LABEL_HEIGHT / 2


def dash_dots(arcs: Iterable[tuple[int, int]], positions: Mapping[int, tuple[float, float]],
              labels: Mapping[int, str]) -> tuple[list[str], list[tuple[float, float]], list[float], list[int]]:
    """The dots drawing ``arcs`` dashed: ``(node ids, positions, radii, arc index of each dot)``.

    Node ids are ``"<j>><i>:<n>"`` (unique per entity and event time).  At least two dots per arc,
    also where the label boxes leave no room between them (then around the arc's middle).
    """
    ids, pos, radii, which = [], [], [], []
    for a, (j, i) in enumerate(arcs):
        (xj, yj), (xi, yi) = positions[j], positions[i]
        length = math.hypot(xi - xj, yi - yj)
        if length == 0:
            continue
        dx, dy = (xi - xj) / length, (yi - yj) / length
        nx, ny = -dy, dx  # right of travel on screen (y grows downwards)
        lo = _exit(dx, dy, *_half_box(labels.get(j, ""))) + 2.0
        hi = length - _exit(dx, dy, *_half_box(labels.get(i, ""))) - 2.0
        if hi - lo < DOT_SPACING:
            mid = length / 2
            lo, hi = mid - DOT_SPACING / 2, mid + DOT_SPACING / 2
        count = max(2, int((hi - lo) // DOT_SPACING) + 1)
        for n in range(count):
            f = n / (count - 1)
            s = lo + f * (hi - lo)
            ids.append(f"{j}>{i}:{n}")
            pos.append((xj + s * dx + SIDE * nx, yj + s * dy + SIDE * ny))
            radii.append(RADII[0] + f * (RADII[1] - RADII[0]))
            which.append(a)
    return ids, pos, radii, which


def partition_text(groups) -> str:
    """``partition 1 2 3 | 4 5`` (the groups of a partition in force)."""
    return "partition " + " | ".join(" ".join(str(a) for a in g) for g in groups)


def status_text(rows, arcs: Mapping[tuple[int, int], int]) -> str:
    """One line for the event time: how many messages did not count, by cause, and how many arcs are dashed.

    ``rows``: the event time's ``(tau, k, j, i, cause)``; ``arcs``: :func:`lost_arcs` of them.
    Empty when nothing was lost.
    """
    counts = [0] * len(CAUSES)
    for r in rows:
        counts[int(r[4])] += 1
    parts = []
    if any(counts):
        by = ", ".join(f"{c} {name}" for name, c in zip(CAUSES, counts) if c)
        total = sum(counts)
        parts.append(f"{total} message{'s' if total > 1 else ''} did not count ({by})")
        if arcs:
            parts.append(f"{len(arcs)} arc{'s' if len(arcs) > 1 else ''} dashed")
    return "; ".join(parts)


def _pairs(edges: list[tuple[str, str]]) -> np.ndarray:
    """Edges as an (E, 2) array of strings: rerun converts that in one go (a list, pair by pair: ~10 us each)."""
    return np.array(edges, dtype=str).reshape(-1, 2) if edges else np.empty((0, 2), dtype=str)


class TopologyView:
    """The topology entities of one recording (see the module docstring); the caller guards every call.

    ``index(rr, taus, seconds, walls_ns)``: the timeline columns of a batch of rows.
    """

    def __init__(self, rec, agent_ids: list[int], positions: Mapping[int, tuple[float, float]], *,
                 index: Callable):
        self.rec, self.agent_ids, self.positions, self._index = rec, list(agent_ids), dict(positions), index
        self._topologies_tau: list[int] = []  # taus of the topologies logged, sorted
        self._topologies: list[tuple[list, dict]] = []  # (edges drawn, {agent: label}) at each of them
        self._labels: dict = {}  # the node labels of the latest topology
        self._cut_shown = False  # topology/partition holds dots now
        self._overlaid: dict[int, tuple] = {}  # tau -> (tau, t, wall_ns, lost) of every overlay logged
        self._dash_cache: dict[tuple, tuple] = {}  # (j, i, label of j, label of i) -> dash_dots of arc j -> i
        self._logs: dict[int, object] = {}  # tau -> the TopologyLog logged for it (not the copies of relog)
        self._copies: dict[int, tuple[float, int]] = {}  # tau -> (t, wall_ns) of every copy relog logged

    def send_topology(self, logs: list, *, copy: bool = False) -> None:
        """One row per topology logged (:class:`~splitspec_orchestrator.viewer.handoff.TopologyLog`): GraphNodes
        (fixed positions, lost grey) + the edges not ``cut`` (a subset of ``edges``, the arcs a partition in force
        cuts).

        The active graph's name (and ``partition``, its text, if any) is a label node on ``topology/graph``
        above the agents; the cut arcs are dashed on ``topology/partition`` (logged while a partition is in
        force, and once more, empty, when it ends).  Per-event-time overlays (:meth:`send_lost`) already logged
        at or after a row's ``tau`` are logged again on the new topology.  ``copy``: ``logs`` are :meth:`relog`'s
        copies, not topologies of their own.
        """
        import rerun as rr

        ids = self.agent_ids
        pos = [self.positions[a] for a in ids]
        node_ids, labels, colors, positions, edges, edge_counts = [], [], [], [], [], []
        cut_dots: list[tuple] = []
        for g in logs:
            node_ids += [str(a) for a in ids]
            row_labels = [f"agent {a}" if a in g.alive else f"agent {a} (lost)" for a in ids]
            labels += row_labels
            colors += [bp.color(k) if a in g.alive else bp.DEAD_COLOR for k, a in enumerate(ids)]
            positions += pos
            kept = [e for e in g.edges if e not in g.cut]
            edges += kept
            edge_counts.append(len(kept))
            self._topology_at(int(g.tau), kept, dict(zip(ids, row_labels)))
            cut_dots.append(self._dots(sorted((int(j), int(i)) for j, i in g.cut), self._labels))
        taus, seconds, walls = [g.tau for g in logs], [g.t for g in logs], [g.wall for g in logs]
        names, cuts, parts = [g.graph for g in logs], [g.cut for g in logs], [g.partition for g in logs]
        rows = len(logs)
        index = self._index(rr, taus, seconds, walls)
        columns = [*rr.GraphNodes.columns(node_ids=node_ids, labels=labels, colors=colors,
                                          positions=positions).partition([len(ids)] * rows),
                   *rr.GraphEdges.columns(edges=_pairs(edges)).partition(edge_counts),
                   *rr.GraphEdges.columns(graph_type=["directed"] * rows),
                   *rr.AnyValues.columns(graph_name=list(names))]
        self.rec.send_columns(bp.TOPOLOGY, indexes=index, columns=columns)
        self.rec.send_columns(bp.TOPOLOGY_GRAPH, indexes=index, columns=rr.GraphNodes.columns(
            node_ids=["graph"] * rows, labels=[f"graph: {name}" + (f"\n{part}" if part else "")
                                               for name, part in zip(names, parts)],
            positions=[bp.graph_label_position(self.positions, lines=2 if part else 1) for part in parts],
            colors=[bp.CUT_COLOR if part else bp.GRAPH_LABEL_COLOR for part in parts], radii=[1.0] * rows))
        if self._cut_shown or any(cuts):
            self._send_dots(bp.TOPOLOGY_PARTITION, index, cut_dots, [bp.CUT_COLOR] * sum(len(d[0]) for d in cut_dots))
            self._cut_shown = bool(cuts[-1])
        redo = [v for tau, v in self._overlaid.items() if tau >= min(taus)]
        if redo:
            self._send_overlays(rr, sorted(redo))
        if copy:
            return
        for g in logs:
            self._logs[int(g.tau)] = g
        # a topology logged late, before a segment's copy: the copy (in force there) is logged again
        stale = sorted(tau for tau in self._copies if tau >= min(taus) and tau not in set(taus))
        if stale:
            self.send_topology([self._copy(tau, *self._copies[tau]) for tau in stale], copy=True)

    def relog(self, newest: tuple[int, float, int] | None) -> None:
        """Log the topology in force again, at the event time a new segment of a rolled recording starts with.

        That event time is the later of ``newest`` (``(tau, t, wall_ns)`` of the newest row logged, None: none)
        and the newest topology's; the copy holds what :meth:`send_topology` logs (nodes, labels, edges, the
        graph's name, a partition's cut) and the overlays already logged at it.  Nothing before the first
        topology.  A topology logged later for an earlier event time logs the copy again (as in force then).
        """
        if not self._logs:
            return
        last = self._logs[max(self._logs)]
        tau, t, wall = (int(last.tau), last.t, last.wall) if newest is None or newest[0] <= last.tau else newest
        self._copies[int(tau)] = (float(t), int(wall))
        self.send_topology([self._copy(int(tau), float(t), int(wall))], copy=True)

    def _copy(self, tau: int, t: float, wall: int):
        """The topology logged for the latest event time at or before ``tau``, moved to ``tau``."""
        import dataclasses

        return dataclasses.replace(self._logs[max(k for k in self._logs if k <= tau)], tau=tau, t=t, wall=wall)

    def _dots(self, arcs: list[tuple[int, int]], labels: Mapping[int, str]) -> tuple:
        """:func:`dash_dots` of ``arcs``, arc by arc from a cache (the same arcs come back event time after
        event time; the labels they run between change their ends)."""
        ids, pos, radii, which = [], [], [], []
        for a, (j, i) in enumerate(arcs):
            key = (j, i, labels.get(j, ""), labels.get(i, ""))
            dots = self._dash_cache.get(key)
            if dots is None:
                dots = self._dash_cache[key] = dash_dots([(j, i)], self.positions, labels)[:3]
            ids += dots[0]
            pos += dots[1]
            radii += dots[2]
            which += [a] * len(dots[0])
        return ids, pos, radii, which

    def _topology_at(self, tau: int, edges: list, labels: dict) -> None:
        """Keep the topology logged at ``tau`` (edges drawn, node labels): the base of later overlays."""
        self._labels = labels
        k = bisect.bisect_right(self._topologies_tau, tau)
        if k and self._topologies_tau[k - 1] == tau:
            self._topologies[k - 1] = (edges, labels)
        else:
            self._topologies_tau.insert(k, tau)
            self._topologies.insert(k, (edges, labels))

    def _send_dots(self, path: str, index: list, dots: list[tuple], colors: list) -> None:
        """One GraphNodes chunk of dashed arcs, one row per ``index`` row (``dots``: :func:`dash_dots` per
        row; ``colors``: one per dot, all rows); a row without dots is an empty batch (it clears the last)."""
        import rerun as rr

        node_ids, positions, radii = [], [], []
        for ids_, pos_, radii_, _ in dots:
            node_ids += ids_
            positions += pos_
            radii += radii_
        self.rec.send_columns(path, indexes=index, columns=[
            *rr.GraphNodes.columns(node_ids=node_ids, positions=positions, radii=radii,
                                   colors=colors).partition([len(d[0]) for d in dots]),
            *rr.GraphNodes.columns(show_labels=[False] * len(dots))])

    def send_lost(self, rows: list) -> None:
        """One :class:`~splitspec_orchestrator.viewer.handoff.LostRow` per row taken, in the order taken.

        An event time whose consensus messages did not all count (``lost``: ``(tau, k, j, i, cause)``) gets
        ``topology`` edges without its arcs that lost one, those arcs dashed on ``topology/lost`` and its
        counts on ``topology/status``; the next event time without any puts them back (and so does a row
        logged again that had them).  Nothing is logged for a network that loses nothing.
        """
        import rerun as rr

        todo = [(r.tau, r.t, r.wall, r.lost) for r in rows if r.lost or r.prev or r.tau in self._overlaid]
        if todo:
            self._send_overlays(rr, todo)

    def _send_overlays(self, rr, todo: list[tuple[int, float, int, tuple]]) -> None:
        """Log the overlays of ``todo`` (``(tau, t, wall_ns, lost)``): ``topology`` edges, ``topology/lost``,
        ``topology/status``, one chunk each."""
        taus, seconds, walls = (np.asarray([row[c] for row in todo]) for c in range(3))
        index = self._index(rr, taus, seconds, walls)
        edges, edge_counts, dots, colors, texts = [], [], [], [], []
        based = np.zeros(len(todo), dtype=bool)
        for r, (tau, t, wall, lost) in enumerate(todo):
            self._overlaid[int(tau)] = (int(tau), t, wall, lost)
            arcs = lost_arcs(lost)
            k = bisect.bisect_right(self._topologies_tau, int(tau))
            row_dots: tuple = ([], [], [], [])
            if k:  # drawn over the topology in force: its edges without the dashed arcs
                base, labels = self._topologies[k - 1]
                drawn = {(int(j), int(i)) for j, i in base}
                dashed = sorted(a for a in arcs if a in drawn)
                kept = [e for e in base if (int(e[0]), int(e[1])) not in arcs]
                edges += kept
                edge_counts.append(len(kept))
                based[r] = True
                row_dots = self._dots(dashed, labels)
                colors += [bp.LOST_COLOR if arcs[dashed[w]] == LOSS else bp.LATE_COLOR for w in row_dots[3]]
            dots.append(row_dots)
            texts.append(status_text(lost, arcs))
        if based.any():
            self.rec.send_columns(bp.TOPOLOGY, indexes=self._index(rr, taus[based], seconds[based], walls[based]),
                                  columns=rr.GraphEdges.columns(edges=_pairs(edges)).partition(edge_counts))
        self._send_dots(bp.TOPOLOGY_LOST, index, dots, colors)
        shown = [x for x in texts if x]
        pos = bp.status_label_position(self.positions)
        self.rec.send_columns(bp.TOPOLOGY_STATUS, indexes=index, columns=[
            *rr.GraphNodes.columns(node_ids=["status"] * len(shown), labels=shown, positions=[pos] * len(shown),
                                   colors=[bp.STATUS_COLOR] * len(shown), radii=[1.0] * len(shown)
                                   ).partition([1 if x else 0 for x in texts])])
