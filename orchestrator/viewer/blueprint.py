"""Rerun entity paths of a run's recording, its colours and node positions, and its default blueprint.

What each entity holds, its timelines, and which entities exist in which run are the contract of
docs/reference/files.md, section "Rerun recording"; the constants below are their paths in the code.  The
topology and what a misbehaving network draws over it: :mod:`splitspec_orchestrator.viewer.topology_view`
(dots, because an edge of a Rerun 0.41 graph has no colour or dash of its own); a run on measurements:
:mod:`splitspec_orchestrator.viewer.reference_view`.

Entities per run (counted in docs/reference/files.md): at m = 32, n = 6, 92 instead of the 278 of one entity
per agent and state component (``state/<k>/agent_<id>``, ``n (m + 1)`` of them with the truth), which the
recorder paid for in every flush (one ``send_columns`` chunk per entity) and the viewer in every query.

Why a batch per component and not one entity per agent holding its n components: the
default blueprint keeps one view per state component (m + 1 lines each), and a Rerun 0.41
time-series view cannot take one element of a batch.  A view's contents select entities,
not instances; a component mapping's selector (``[N]``, experimental in 0.41) is applied
to each instance's value (a Float64 for ``Scalars``: nothing to index), so it cannot pick
one instance of the batch; per-view ``SeriesLines`` ``visible_series`` overrides hide lines
but each of the n views would still query all ``n (m + 1)`` of them and list them all in
its legend (as the SDK's docstring says).  A batch per component keeps the per-component
views as they were at ``2n`` entities (fewer than the ``m + 1`` of a batch per agent).  The
price: a dead agent's values are NaN inside the batch (the line breaks there) instead of
absent, and its state lines get no ``Clear`` of their own (the loss makes every later value
NaN, which breaks them as well).
"""

from __future__ import annotations

import math
from typing import Mapping

from splitspec_core.model.rows import ROUND_FIELDS, column
from splitspec_core.scenarios.faults import fault_marks

__all__ = ["ERRORS", "ERRORS_MAX", "ERRORS_LOG10", "ERRORS_LOG10_MAX", "ENVELOPE", "STATE", "ROUNDS", "PER_AGENT_TAB",
           "RESIDUAL", "RESIDUAL_LOG10", "DISAGREEMENT", "DISAGREEMENT_LOG10", "KF_DISTANCE", "KF_DISTANCE_LOG10",
           "MARKS", "MARK_KINDS", "TOPOLOGY", "TOPOLOGY_GRAPH", "TOPOLOGY_LOST",
           "TOPOLOGY_PARTITION", "TOPOLOGY_STATUS", "EVENTS", "TL_EVENT", "TL_TIME", "TL_WALL",
           "REFERENCE_TAB", "agent_path", "state_path", "state_labels", "color", "circle_positions", "default_blueprint",
           "reference_views"]

ERRORS = "errors"
ERRORS_MAX = "errors/max"
ERRORS_LOG10 = "errors_log10"
ERRORS_LOG10_MAX = "errors_log10/max"
ENVELOPE = "errors_log10/envelope"
STATE = "state"
RESIDUAL = "residual"
RESIDUAL_LOG10 = "residual_log10"
DISAGREEMENT = "disagreement"
DISAGREEMENT_LOG10 = "disagreement_log10"
KF_DISTANCE = "kf_distance"
KF_DISTANCE_LOG10 = "kf_distance_log10"
ROUNDS = "rounds"
ROUND_SERIES = ROUND_FIELDS  # late_ms: behind run.pace (paced runs)
PER_AGENT_TAB = "per agent"  # the tab of the reported row columns (default_blueprint)
# mid-tone colours, drawn on the light theme as on the dark one; lost: the red of the dashed arcs
ROUND_COLORS = {"wall_ms": (31, 119, 180), "attempts": (44, 160, 44), "rejected": (255, 127, 14),
                "lost": (214, 39, 40), "late_ms": (148, 103, 189)}
MARKS = "marks"
TOPOLOGY = "topology"
TOPOLOGY_GRAPH = "topology/graph"
TOPOLOGY_LOST = "topology/lost"
TOPOLOGY_PARTITION = "topology/partition"
TOPOLOGY_STATUS = "topology/status"
EVENTS = "events"
TL_EVENT, TL_TIME, TL_WALL = "event", "time", "wall"

# Event name -> mark kind (entity ``marks/<kind>``), with its marker and colour: the fault kinds declare theirs
# (splitspec_core.scenarios.faults: agent_lost, agent_rejoined, arc_dropped, partition, ...), a few are the runtime's
_FAULT_MARKS, _FAULT_MARK_STYLES = fault_marks()
# the bad-data test's (splitspec_core.synthesis.bad_data): a sensor set aside and taken back
MARK_OF_EVENT = {**_FAULT_MARKS, "graph_switched": "graph_switch", "fault_skipped": "fault",
                 "sensor_suspect": "suspect", "sensor_restored": "restored",
                 "orchestrator_takeover": "takeover"}  # a standby took the run over (its kind's mark: kill_orchestrator)
MARK_KINDS = {  # kind: (legend name, marker, colour)
    "lost": ("agent lost", "Cross", (214, 39, 40)),
    "rejoined": ("agent rejoined", "Up", (44, 160, 44)),
    "graph_switch": ("graph switch", "Diamond", (255, 200, 0)),
    "fault": ("scenario fault (link)", "Asterisk", (255, 127, 14)),
    "partition": ("partition", "Down", (148, 103, 189)),
    "healed": ("partition healed", "Plus", (23, 190, 207)),
    "suspect": ("sensor suspect (bad data)", "Circle", (227, 119, 194)),
    "restored": ("sensor restored", "Square", (140, 86, 75)),
    **_FAULT_MARK_STYLES,
}

PALETTE = [  # matplotlib tab10
    (31, 119, 180), (255, 127, 14), (44, 160, 44), (214, 39, 40), (148, 103, 189),
    (140, 86, 75), (227, 119, 194), (127, 127, 127), (188, 189, 34), (23, 190, 207),
]
DEAD_COLOR = (90, 90, 90)
MAX_COLOR = (235, 235, 235)
TRUTH_COLOR = (235, 235, 235)
KF_COLOR = TRUTH_COLOR  # without the truth the filter is drawn in its place
KF_BESIDE_TRUTH_COLOR = (150, 150, 150)
DISAGREEMENT_COLOR = (110, 110, 110)  # alone in its view: a grey that shows on the dark and the light theme
ENVELOPE_COLOR = (255, 80, 80)
LOST_COLOR = (214, 39, 40)  # an arc that lost a message (topology/lost)
LATE_COLOR = (255, 127, 14)  # ... whose missing messages all came too late
CUT_COLOR = MARK_KINDS["partition"][2]  # an arc cut by a partition (topology/partition)
STATUS_COLOR = (214, 39, 40)
GRAPH_LABEL_COLOR = (150, 150, 150)  # topology/graph: legible on the light theme as on the dark one
CIRCLE_RADIUS = 100.0


def agent_path(prefix: str, agent_id: int) -> str:
    return f"{prefix}/agent_{agent_id}"


def state_path(label, who: str) -> str:
    """``state/<label>/<who>``: ``label`` is the state's name (``system.states``) or its 1-based index; ``who`` is
    ``truth``, ``kf`` or ``agents``."""
    return f"{STATE}/{label}/{who}"


def state_labels(n: int, names=None) -> tuple:
    """``((entity label, display name), ...)`` of the n states: the scenario's names (``system.states``) for both,
    else the 1-based index and ``x<k>``."""
    if names:
        return tuple((str(s), str(s)) for s in names)
    return tuple((str(k), f"x{k}") for k in range(1, n + 1))


def color(i: int) -> tuple[int, int, int]:
    """Colour of the agent in column ``i``."""
    return PALETTE[i % len(PALETTE)]


def circle_positions(agent_ids, *, radius: float = CIRCLE_RADIUS) -> dict[int, tuple[float, float]]:
    """Agents evenly on a circle, the first at the top, clockwise (screen y grows downwards)."""
    ids = [int(a) for a in agent_ids]
    m = len(ids)
    return {a: (radius * math.sin(2 * math.pi * k / m), -radius * math.cos(2 * math.pi * k / m))
            for k, a in enumerate(ids)}


def node_positions(agent_ids, given: Mapping[int, tuple[float, float]] | None) -> dict[int, tuple[float, float]]:
    """The scenario's ``positions`` scaled to the circle's size, or the circle when there are none."""
    if not given:
        return circle_positions(agent_ids)
    pts = {int(a): (float(given[a][0]), float(given[a][1])) for a in agent_ids}
    xs, ys = [p[0] for p in pts.values()], [p[1] for p in pts.values()]
    cx, cy = (max(xs) + min(xs)) / 2, (max(ys) + min(ys)) / 2
    span = max(max(xs) - min(xs), max(ys) - min(ys)) or 1.0
    s = 2 * CIRCLE_RADIUS / span
    # scenario y points up, screen y down
    return {a: ((x - cx) * s, -(y - cy) * s) for a, (x, y) in pts.items()}


def graph_label_position(positions: Mapping[int, tuple[float, float]], *, lines: int = 1) -> tuple[float, float]:
    """Where the graph's name goes: above the agents (the centre of a label of ``lines`` lines)."""
    ys = [p[1] for p in positions.values()]
    return 0.0, min(ys) - (0.35 + 0.1 * (lines - 1)) * CIRCLE_RADIUS


def status_label_position(positions: Mapping[int, tuple[float, float]]) -> tuple[float, float]:
    """Where ``topology/status`` goes: below the agents."""
    ys = [p[1] for p in positions.values()]
    return 0.0, max(ys) + 0.35 * CIRCLE_RADIUS


def default_blueprint(time_mode: str, *, n: int | None = None, envelope: bool = True,
                      columns=(), truth: bool = True, reference: bool = False, active_tab: int | str = 0,
                      states=None, shown=None):
    """The default layout: log errors (envelope, marks) large; topology and event log beside; the rest in tabs.

    Left, tabs: ``errors (log10)`` (the designed envelope and the marks of
    losses, rejoins, switches, faults, partitions and heals on the same axes), ``errors``
    (linear), ``states`` (a grid of one view per component: its truth, bold,
    and the batch of every agent's estimate, m + 1 lines),
    ``per agent`` (one view per reported row column of ``columns``, :data:`splitspec_core.model.rows.REPORTED`:
    every agent's series, such as the gains g_i in continuous time), ``rounds`` (wall time, attempts, rejected
    messages, consensus messages that did not count).  Right: topology (with
    ``topology/lost``, ``topology/partition`` and ``topology/status``, all under its
    origin) above the event log.  ``n`` None (a recording
    whose state dimension is unknown): one view for every state component.
    Rerun 0.41 has no log-scale axis (rerun issue #6773), hence ``errors_log10``.

    ``reference`` (a run on measurements): two tabs first, before the errors, the residuals,
    the disagreement and the distance to the centralized Kalman filter on a log10 scale
    (:data:`REFERENCE_TAB`, the tab shown) and linear (:func:`reference_views`), and the filter's line
    (thin, grey) beside the truth in the state views.  ``truth=False`` (a run on measurements without
    the truth): no error tabs at all, the marks on the log10 disagreement, and the states show the
    filter bold in place of the truth.  Neither (a run of the simulated plant): the layout above.
    ``active_tab``: the tab shown first, by index or name (``"rounds"``); the first by default.
    ``states``: the states' names (``system.states``; :func:`state_labels`).  ``shown``: the indices of the states
    the states tab shows (``run.show``, :attr:`splitspec_core.scenarios.specs.Scenario.shown_states`; None: all);
    the others stay in the recording, a view away (the viewer's entity tree, ``state/<name>``).
    """
    import rerun.blueprint as rrb

    if n:
        what = ("truth, centralized KF and estimates" if reference else "truth and estimates") if truth \
            else ("centralized KF (after the run) and estimates" if reference else "estimates")
        labels = state_labels(n, states)
        picked = [labels[k] for k in shown if 0 <= k < n] if shown is not None else list(labels)
        state_views = rrb.Grid(*[rrb.TimeSeriesView(origin=f"{STATE}/{label}", name=f"{name}: {what}")
                                 for label, name in picked], name="states")
    else:
        state_views = rrb.TimeSeriesView(origin=STATE, name="states")
    rounds = rrb.Vertical(*[rrb.TimeSeriesView(origin=f"{ROUNDS}/{s}", name=f"round {s.replace('_', ' ')}")
                            for s in ROUND_SERIES], name="rounds")
    tabs = reference_views(marks=not truth) if reference or not truth else []
    if truth:
        tabs += [rrb.TimeSeriesView(origin="/", contents=[f"{ERRORS_LOG10}/**", f"{MARKS}/**"],
                                    name="log10 |x_i - x|, designed envelope, marks" if envelope
                                    else "log10 |x_i - x|, marks"),
                 rrb.TimeSeriesView(origin=ERRORS, name="|x_i - x| (linear)")]
    tabs.append(state_views)
    if columns:
        tabs.append(rrb.Vertical(*[rrb.TimeSeriesView(origin=c.path, name=c.label or c.name)
                                   for c in map(column, columns)], name=PER_AGENT_TAB))
    tabs.append(rounds)
    if isinstance(active_tab, str):  # rerun resolves names of views only, not of containers (rounds, states)
        names = [tab.name for tab in tabs]
        if active_tab not in names:
            raise ValueError(f"active_tab {active_tab!r} is not a tab of the default blueprint {names}")
        active_tab = names.index(active_tab)
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Tabs(*tabs, active_tab=active_tab, name="series"),
            rrb.Vertical(
                rrb.GraphView(origin=TOPOLOGY, name="communication graph"),
                rrb.TextLogView(origin=EVENTS, name="events"),
                row_shares=[3, 2],
            ),
            column_shares=[2, 1],
        ),
        rrb.TimePanel(timeline=TL_EVENT if time_mode == "discrete" else TL_TIME),
        collapse_panels=False,
    )


#: the tab of a run on measurements, by the name ``active_tab`` knows it
REFERENCE_TAB = "residuals, disagreement, distance to KF"


def reference_views(*, marks: bool) -> list:
    """The two tabs of a run on measurements: ``REFERENCE_TAB`` (log10) and the same linear.

    Each a column of three views: every agent's measurement residual, the consensus disagreement (one
    line; with ``marks``, the marks of losses, rejoins, switches and faults on it), and every agent's
    distance to the centralized Kalman filter (known after the run: empty until the run ends).
    """
    import rerun.blueprint as rrb

    def column(name: str, dis: str, res: str, kf: str, log: str, with_marks: bool):
        return rrb.Vertical(
            rrb.TimeSeriesView(origin=res, name=f"{log}residuals |y_i - C_i x_i|"),
            rrb.TimeSeriesView(origin="/", contents=[dis] + ([f"{MARKS}/**"] if with_marks else []),
                               name=f"{log}disagreement max_ij |x_i - x_j|" + (", marks" if with_marks else "")),
            rrb.TimeSeriesView(origin=kf, name=f"{log}distance to the centralized KF |x_i - x_KF| (after the run)"),
            name=name)

    return [column(REFERENCE_TAB, DISAGREEMENT_LOG10, RESIDUAL_LOG10, KF_DISTANCE_LOG10, "log10 ", marks),
            column(f"{REFERENCE_TAB} (linear)", DISAGREEMENT, RESIDUAL, KF_DISTANCE, "", False)]
