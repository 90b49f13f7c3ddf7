"""Read a run's ``.rrd`` back (tests and benchmarks only): scalar series, clears, text log, topology.

Column names of a chunk's record batch in rerun 0.41 (found by experiment):
index columns are named after their timeline, data columns ``Archetype:field``.
"""

from __future__ import annotations

import math
import re
from pathlib import Path

from splitspec_orchestrator.viewer.blueprint import EVENTS, STATE, TL_EVENT, TOPOLOGY
from splitspec_orchestrator.records.recorder import RecordingError, verify_rrd

__all__ = ["read_rrd", "read_rrd_vectors", "read_rrd_state", "read_rrd_logs", "read_rrd_clears", "read_rrd_nodes",
           "read_rrd_graph", "rrd_entities", "verify_rrd"]

_COL_SCALARS = "Scalars:scalars"
_COL_CLEAR = "Clear:is_recursive"
_COL_ROW_ID = "rerun.controls.RowId"


#: the entities that hold one batch of values per row (every agent's k-th state component)
BATCH_ENTITY = re.compile(r"state/[^/]+/agents")  # the component: its index, or its name (system.states)


def read_rrd(path: str | Path) -> dict[str, list[tuple[int, float]]]:
    """Every scalar series of an ``.rrd``: entity path -> sorted ``[(event index, value), ...]``.

    Entity paths are returned without the leading ``/`` (``"errors/max"``).
    Per event index the latest logged row wins (by Rerun row id), and a
    ``Clear`` logged later at the same event index on the entity (or a
    recursive one on an ancestor) removes the value, as the viewer's latest-at
    query does.  Only rows on the ``event`` timeline are read.  Entities that
    hold a batch per row (``state/<k>/agents``) are in :func:`read_rrd_vectors`
    and :func:`read_rrd_state`, not here.
    """
    out = {}
    for entity, rows in read_rrd_vectors(path).items():
        if BATCH_ENTITY.fullmatch(entity):
            continue
        if not all(len(v) == 1 for _, v in rows):  # a series logged as a batch by mistake is an error, not absent
            raise RecordingError(f"{entity}: a scalar series holds a batch of values")
        out[entity] = [(ev, float(vals[0])) for ev, vals in rows]
    return out


def read_rrd_vectors(path: str | Path) -> dict[str, list[tuple[int, list[float]]]]:
    """Every Scalars entity of an ``.rrd``, batches included: entity path -> sorted ``[(event, [values])]``.

    The same latest-row and ``Clear`` rules as :func:`read_rrd`.

    Raises
    ------
    RecordingError
        If an entity's rows do not all hold the same number of values (the viewer draws one line
        per instance of the first row).
    """
    from rerun.chunk import RrdReader

    # (entity, event) -> (row id, values or None for a clear)
    latest: dict[tuple[str, int], tuple[bytes, list | None]] = {}
    clears: list[tuple[str, int, bytes, bool]] = []
    scalar_entities: set[str] = set()
    for chunk in RrdReader(path).stream():
        if chunk.is_static or TL_EVENT not in chunk.timeline_names:
            continue
        batch = chunk.to_record_batch()
        names = batch.schema.names
        if _COL_SCALARS not in names and _COL_CLEAR not in names:
            continue
        entity = chunk.entity_path.lstrip("/")
        events = batch.column(TL_EVENT).to_pylist()
        row_ids = batch.column(_COL_ROW_ID).to_pylist()
        if _COL_SCALARS in names:
            scalar_entities.add(entity)
            for ev, rid, vals in zip(events, row_ids, batch.column(_COL_SCALARS).to_pylist()):
                if ev is None or vals is None:
                    continue
                _keep_latest(latest, (entity, ev), rid, [float(v) for v in vals])
        if _COL_CLEAR in names:
            for ev, rid, rec in zip(events, row_ids, batch.column(_COL_CLEAR).to_pylist()):
                if ev is not None and rec is not None:
                    clears.append((entity, ev, rid, bool(rec[0])))
    for c_entity, ev, rid, recursive in clears:
        for entity in scalar_entities:
            if entity == c_entity or (recursive and entity.startswith(c_entity + "/")):
                _keep_latest(latest, (entity, ev), rid, None)
    out: dict[str, list[tuple[int, list[float]]]] = {}
    for (entity, ev), (_, values) in sorted(latest.items()):
        if values is not None:
            out.setdefault(entity, []).append((ev, values))
    for entity, rows in out.items():
        widths = {len(v) for _, v in rows}
        if len(widths) != 1:
            raise RecordingError(f"{entity} holds rows of {sorted(widths)} values; expected one width")
    return out


def read_rrd_state(path: str | Path) -> dict[str, list[tuple[int, float]]]:
    """The state series as one scalar series per agent: ``state/<k>/truth`` and ``state/<k>/agent_<id>``.

    ``state/<k>/agents`` (a batch of m per event time, instance i = the i-th agent id of the
    recording's ``splitspec`` property ``agent_ids``) is split into one series per agent; NaN
    values (the agent dead) are left out, as the viewer draws none.
    """
    ids = _agent_ids(path)
    out: dict[str, list[tuple[int, float]]] = {}
    for entity, rows in read_rrd_vectors(path).items():
        if not entity.startswith(f"{STATE}/"):
            continue
        if entity.endswith("/truth"):
            out[entity] = [(ev, v[0]) for ev, v in rows]
        elif entity.endswith("/agents"):
            base = entity[: -len("agents")]
            for ev, values in rows:
                if len(values) != len(ids):
                    raise RecordingError(f"{entity} at event {ev} holds {len(values)} values for {len(ids)} agents")
                for a, v in zip(ids, values):
                    if not math.isnan(v):
                        out.setdefault(f"{base}agent_{a}", []).append((ev, v))
    return out


def _agent_ids(path: str | Path) -> list[int]:
    """``agent_ids`` of the recording's ``splitspec`` property (the order of the ``state/<k>/agents`` batches)."""
    from rerun.chunk import RrdReader

    for chunk in RrdReader(path).stream():
        if chunk.entity_path == "/__properties/splitspec":
            batch = chunk.to_record_batch()
            for name in batch.schema.names:
                if name.endswith("agent_ids"):
                    return [int(a) for a in batch.column(name).to_pylist()[0]]
    raise RecordingError(f"{path} has no splitspec property with agent_ids")


def _keep_latest(latest: dict, key: tuple[str, int], row_id: bytes, value: float | None) -> None:
    # Row ids are TUIDs: big-endian (nanoseconds, counter), so byte order is log order.
    old = latest.get(key)
    if old is None or row_id > old[0]:
        latest[key] = (row_id, value)


def read_rrd_logs(path: str | Path) -> dict[str, list]:
    """The text log and topology of an ``.rrd``.

    Returns ``{"events": [(event index, level, text), ...], "topology": [(event index, [node labels],
    [(j, i) edges]), ...]}`` in logging order.
    """
    from rerun.chunk import RrdReader

    out: dict[str, list] = {"events": [], "topology": []}
    for chunk in RrdReader(path).stream():
        if chunk.is_static or TL_EVENT not in chunk.timeline_names:
            continue
        batch = chunk.to_record_batch()
        names = batch.schema.names
        taus = batch.column(TL_EVENT).to_pylist()
        if chunk.entity_path == f"/{EVENTS}" and "TextLog:text" in names:
            for tau, text, level in zip(taus, batch.column("TextLog:text").to_pylist(),
                                        batch.column("TextLog:level").to_pylist()):
                out["events"].append((tau, level[0] if level else None, text[0]))
        elif chunk.entity_path == f"/{TOPOLOGY}" and "GraphNodes:labels" in names:
            edges = batch.column("GraphEdges:edges").to_pylist() if "GraphEdges:edges" in names else [None] * len(taus)
            for tau, labels, es in zip(taus, batch.column("GraphNodes:labels").to_pylist(), edges):
                pairs = [(int(e["first"]), int(e["second"])) if isinstance(e, dict) else tuple(map(int, e))
                         for e in (es or [])]
                out["topology"].append((tau, labels, pairs))
    return out


def read_rrd_clears(path: str | Path) -> dict[str, list[int]]:
    """Entity path -> sorted event indices of the non-recursive ``Clear`` rows logged on it."""
    from rerun.chunk import RrdReader

    out: dict[str, set] = {}
    for chunk in RrdReader(path).stream():
        if chunk.is_static or TL_EVENT not in chunk.timeline_names:
            continue
        batch = chunk.to_record_batch()
        if _COL_CLEAR not in batch.schema.names:
            continue
        entity = chunk.entity_path.lstrip("/")
        for ev, rec in zip(batch.column(TL_EVENT).to_pylist(), batch.column(_COL_CLEAR).to_pylist()):
            if ev is not None and rec is not None:
                out.setdefault(entity, set()).add(ev)
    return {k: sorted(v) for k, v in out.items()}


def read_rrd_nodes(path: str | Path, entity: str = TOPOLOGY) -> list[tuple[int, list, list]]:
    """``[(event index, node ids, positions [(x, y)]), ...]`` of the GraphNodes on ``entity``."""
    from rerun.chunk import RrdReader

    out = []
    for chunk in RrdReader(path).stream():
        if chunk.is_static or TL_EVENT not in chunk.timeline_names or chunk.entity_path != f"/{entity}":
            continue
        batch = chunk.to_record_batch()
        names = batch.schema.names
        if "GraphNodes:node_ids" not in names:
            continue
        pos = batch.column("GraphNodes:positions").to_pylist() if "GraphNodes:positions" in names \
            else [None] * batch.num_rows
        labels = batch.column("GraphNodes:labels").to_pylist() if "GraphNodes:labels" in names \
            else [None] * batch.num_rows
        for tau, ids, ps, ls in zip(batch.column(TL_EVENT).to_pylist(), batch.column("GraphNodes:node_ids").to_pylist(),
                                    pos, labels):
            out.append((tau, ids, [tuple(p) for p in (ps or [])], ls))
    return out


def read_rrd_graph(path: str | Path, entity: str, tau: int) -> dict:
    """What the viewer's graph view shows of ``entity`` at event time ``tau`` (latest-at, component by component).

    Returns ``{"edges": [(j, i)], "node_ids": [...], "labels": [...], "colors": [(r, g, b)], "positions":
    [(x, y)]}``, each from the latest row at or before ``tau`` that holds that component (by event time,
    then by Rerun row id); a component never logged by then is absent.
    """
    from rerun.chunk import RrdReader

    best: dict[str, tuple] = {}
    for chunk in RrdReader(path).stream():
        if chunk.is_static or TL_EVENT not in chunk.timeline_names or chunk.entity_path != f"/{entity}":
            continue
        batch = chunk.to_record_batch()
        names = batch.schema.names
        taus = batch.column(TL_EVENT).to_pylist()
        rids = batch.column(_COL_ROW_ID).to_pylist()
        for key, col in (("edges", "GraphEdges:edges"), ("node_ids", "GraphNodes:node_ids"),
                         ("labels", "GraphNodes:labels"), ("colors", "GraphNodes:colors"),
                         ("positions", "GraphNodes:positions")):
            if col not in names:
                continue
            for ev, rid, value in zip(taus, rids, batch.column(col).to_pylist()):
                if ev is None or ev > tau or value is None:
                    continue
                if key not in best or (ev, rid) > best[key][:2]:
                    best[key] = (ev, rid, value)
    out: dict = {}
    for key, (_, _, value) in best.items():
        if key == "edges":
            value = [(int(e["first"]), int(e["second"])) if isinstance(e, dict) else tuple(map(int, e)) for e in value]
        elif key == "colors":  # packed 0xRRGGBBAA
            value = [((c >> 24) & 255, (c >> 16) & 255, (c >> 8) & 255) for c in value]
        elif key == "positions":
            value = [tuple(p) for p in value]
        out[key] = value
    return out


def rrd_entities(path: str | Path) -> set[str]:
    """Every entity path of the recording (without the leading ``/``), static data included."""
    from rerun.chunk import RrdReader

    return {chunk.entity_path.lstrip("/") for chunk in RrdReader(path).stream()}


def read_blueprint(path: str | Path) -> dict[str, list]:
    """The default blueprint stored in an ``.rrd``: ``{"views": [(class, name, origin)], "containers": [name]}``."""
    from rerun.chunk import RrdReader

    reader = RrdReader(path)
    out: dict[str, list] = {"views": [], "containers": []}
    for store in reader.blueprints():
        for chunk in reader.stream(store=store):
            batch = chunk.to_record_batch()
            names = batch.schema.names

            def first(col):
                v = batch.column(col).to_pylist()[0] if col in names else None
                return v[0] if isinstance(v, list) and v else v

            if "ViewBlueprint:class_identifier" in names:
                out["views"].append((first("ViewBlueprint:class_identifier"), first("ViewBlueprint:display_name"),
                                     first("ViewBlueprint:space_origin")))
            elif "ContainerBlueprint:display_name" in names:
                out["containers"].append(first("ContainerBlueprint:display_name"))
    return out
