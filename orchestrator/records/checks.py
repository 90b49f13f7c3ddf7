"""What a recorder's calls must be given: :class:`RecordingError` and the checks of their arguments.

Each check raises :class:`RecordingError` naming what does not fit the run (a shape, an agent id, a graph, a
rate) before anything is recorded, and returns the arguments as
:class:`~splitspec_orchestrator.records.recorder.Recorder` stores them.
"""

from __future__ import annotations

import math
from typing import Iterable, Mapping

import numpy as np

from splitspec_core.errors import SplitspecError
from splitspec_core.model.rows import REPORTED, empty

__all__ = ["RecordingError", "check_run", "check_topology", "check_row"]


class RecordingError(SplitspecError, ValueError):
    """A recorder call does not fit the run (shape, agent id, graph, order); the message names it."""


def check_run(*, agent_ids, n: int, time_mode: str, dt: float, graph_names, flush_seconds: float,
              envelope_rate: float | None, positions: Mapping | None) -> list[int]:
    """The recorder's arguments (see :class:`~splitspec_orchestrator.records.recorder.Recorder`); the agent ids."""
    if time_mode not in ("discrete", "continuous"):
        raise RecordingError(f"time_mode must be 'discrete' or 'continuous', got {time_mode!r}")
    ids = [int(a) for a in agent_ids]
    if not ids or len(set(ids)) != len(ids):
        raise RecordingError(f"agent_ids must be non-empty and distinct, got {tuple(agent_ids)}")
    if int(n) < 1:
        raise RecordingError(f"n must be >= 1, got {n}")
    if time_mode == "continuous" and not (math.isfinite(dt) and dt > 0):
        raise RecordingError(f"dt must be a positive number in continuous time, got {dt}")
    if not graph_names:
        raise RecordingError("graph_names must name at least one graph")
    if not flush_seconds >= 0:
        raise RecordingError(f"flush_seconds must be >= 0, got {flush_seconds}")
    if envelope_rate is not None and not (math.isfinite(envelope_rate) and envelope_rate > 0):
        raise RecordingError(f"envelope_rate must be a positive number or None, got {envelope_rate}")
    if positions is not None and set(int(a) for a in positions) != set(ids):
        raise RecordingError(f"positions must give every agent of {tuple(ids)}, got {sorted(positions)}")
    return ids


def check_topology(agent_ids: np.ndarray, graph_names: tuple, graph_name: str, alive_ids: Iterable[int],
                   arcs: Iterable[tuple[int, int]], partition) -> tuple[set[int], list[tuple[str, str]], tuple]:
    """A topology's arguments: the alive ids, the arcs among them as node ids ``(str(j), str(i))``, the
    partition's groups (empty: none)."""
    pos = set(int(a) for a in agent_ids)
    if graph_name not in graph_names:
        raise RecordingError(f"unknown graph {graph_name!r}; expected one of {graph_names}")
    alive = {int(a) for a in alive_ids}
    unknown = sorted(alive - pos)
    if unknown:
        raise RecordingError(f"alive_ids {unknown} are not agents of this run {tuple(agent_ids)}")
    edges = []
    for arc in arcs:
        j, i = (int(v) for v in arc)
        if j not in pos or i not in pos:
            raise RecordingError(f"arc ({j}, {i}) names an agent not in {tuple(agent_ids)}")
        if j in alive and i in alive:
            edges.append((str(j), str(i)))
    groups = tuple(tuple(int(a) for a in g) for g in (partition or ()))
    strangers = sorted({a for g in groups for a in g} - pos)
    if strangers:
        raise RecordingError(f"partition names {strangers}, not agents of this run {tuple(agent_ids)}")
    return alive, edges, groups


def check_row(m: int, n: int, graphs: int, x, xhat, alive, graph: int,
              columns: dict) -> tuple[np.ndarray, np.ndarray, np.ndarray, dict]:
    """A row's arguments, checked.

    Parameters
    ----------
    m, n, graphs : int
        Agents, states, and how many graphs the run has.
    x, xhat, alive, graph
        The row (:meth:`~splitspec_orchestrator.records.recorder.Recorder.row`).
    columns : dict
        Reported row columns by name (:data:`splitspec_core.model.rows.REPORTED`), each (m,) or None.

    Returns
    -------
    tuple
        ``x``, ``xhat``, ``alive`` as arrays and a dict of every reported column as an array of its dtype (its
        fill where not given).

    Raises
    ------
    RecordingError
        A shape, the graph index or a column name that does not fit the run.
    """
    x = np.asarray(x, dtype=float)
    xhat = np.asarray(xhat, dtype=float)
    alive = np.asarray(alive)
    if x.shape != (n,):
        raise RecordingError(f"x has shape {x.shape}; expected ({n},)")
    if xhat.shape != (m, n):
        raise RecordingError(f"xhat has shape {xhat.shape}; expected ({m}, {n})")
    if alive.shape != (m,) or alive.dtype != bool:
        raise RecordingError(f"alive must be a bool array of shape ({m},), "
                             f"got {alive.dtype} {alive.shape}")
    if not 0 <= int(graph) < graphs:
        raise RecordingError(f"graph index {graph} out of range 0..{graphs - 1}")
    unknown = sorted(set(columns) - {c.name for c in REPORTED})
    if unknown:
        raise RecordingError(f"{', '.join(unknown)}: not a reported row column "
                             f"({', '.join(c.name for c in REPORTED)})")
    out = {}
    for c in REPORTED:
        v = columns.get(c.name)
        out[c.name] = empty(c, 1, m, n)[0] if v is None else np.asarray(v, dtype=c.dtype)
        if out[c.name].shape != (m,):
            raise RecordingError(f"{c.name} has shape {out[c.name].shape}; expected ({m},)")
    return x, xhat, alive, out
