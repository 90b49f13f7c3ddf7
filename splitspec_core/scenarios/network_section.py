"""The scenario's ``network:`` section and its ``partition``/``heal`` faults (what misbehaving links do).

``network: {loss, delay: {mean, jitter}, deadline, arcs: [{arc: [j, i], loss, delay}]}`` and
``faults: [{at, partition: [[ids], [ids]]}, {at, heal: true}]``; the meaning is in
:mod:`splitspec_core.model.impairment`.  Bad input gets one line naming the key, as everywhere else.
"""

from __future__ import annotations

from typing import Any

from ..errors import ScenarioError
from .checks import (DELAY_KEYS, NETWORK_ARC_KEYS, NETWORK_KEYS, MAX_NETWORK_SECONDS, check_arc, check_keys,
                              describe, ids_text, check_known_agent, check_number, require_map)
from .specs import NetworkSpec

__all__ = ["parse_network", "parse_groups", "check_heals"]


def _probability(value: Any, key: str) -> float:
    p = check_number(value, key)
    if not 0.0 <= p < 1.0:
        raise ScenarioError(f"{key} must be in [0, 1) (the probability that a message is lost), got {p:g}")
    return p


def _seconds(value: Any, key: str, *, positive: bool = False) -> float:
    s = check_number(value, key)
    if positive and not s > 0:
        raise ScenarioError(f"{key} must be > 0 seconds, got {s:g}")
    if s < 0:
        raise ScenarioError(f"{key} must be >= 0 seconds, got {s:g}")
    if s > MAX_NETWORK_SECONDS:
        raise ScenarioError(f"{key} must be <= {MAX_NETWORK_SECONDS:g} seconds, got {s:g}")
    return s


def _delay(raw: Any, key: str) -> tuple:
    dmap = require_map(raw, key)
    check_keys(dmap, DELAY_KEYS, key)
    mean = _seconds(dmap.get("mean", 0.0), f"{key}.mean")
    jitter = _seconds(dmap.get("jitter", 0.0), f"{key}.jitter")
    if mean + jitter > MAX_NETWORK_SECONDS:
        raise ScenarioError(f"{key}: mean + jitter must be <= {MAX_NETWORK_SECONDS:g} seconds, got "
                            f"{mean + jitter:g}")
    return mean, jitter


def parse_network(raw: Any, ids: tuple, graphs: tuple) -> NetworkSpec:
    """The ``network:`` section (absent: a perfect network).

    Parameters
    ----------
    raw : mapping or None
        ``network:`` as the YAML holds it.
    ids : tuple of int
        The scenario's agent ids.
    graphs : tuple of Graph
        The scenario's graphs (an arc override must name an arc of one of them).

    Returns
    -------
    NetworkSpec
        ``loss``, ``delay_mean``, ``delay_jitter`` (seconds), ``deadline`` (seconds or None) and the per-arc
        overrides ``{(j, i): {"loss", "delay_mean", "delay_jitter"}}``.

    Raises
    ------
    ScenarioError
        One line naming the key: an unknown key, a loss outside [0, 1), a negative or too long delay, a deadline
        not > 0, an override of an arc no graph has or of one arc twice.

    Examples
    --------
    >>> from splitspec_core.model.graphs import build_graph
    >>> ring = build_graph("ring", (1, 2), [(1, 2), (2, 1)])
    >>> net = parse_network({"loss": 0.1, "arcs": [{"arc": [1, 2], "loss": 0.5}]}, (1, 2), (ring,))
    >>> net.loss_of((1, 2)), net.loss_of((2, 1))
    (0.5, 0.1)
    """
    if raw is None:
        return NetworkSpec()
    nmap = require_map(raw, "network")
    check_keys(nmap, NETWORK_KEYS, "network")
    loss = _probability(nmap.get("loss", 0.0), "network.loss")
    mean, jitter = _delay(nmap["delay"], "network.delay") if nmap.get("delay") is not None else (0.0, 0.0)
    deadline = None
    if nmap.get("deadline") is not None:
        deadline = _seconds(nmap["deadline"], "network.deadline", positive=True)
    arcs: dict = {}
    raw_arcs = nmap.get("arcs") or []
    if not isinstance(raw_arcs, list):
        raise ScenarioError(f"network.arcs must be a list of {{arc: [j, i], loss: p}}, got {describe(raw_arcs)}")
    known = {a for g in graphs for a in g.arcs}
    for k, item in enumerate(raw_arcs, 1):
        key = f"network.arcs[{k}]"
        amap = require_map(item, key)
        check_keys(amap, NETWORK_ARC_KEYS, key)
        if "arc" not in amap:
            raise ScenarioError(f"{key}.arc is missing (the arc [j, i] it overrides)")
        arc = check_arc(amap["arc"], f"{key}.arc", ids)
        if arc not in known:
            raise ScenarioError(f"{key}.arc [{arc[0]}, {arc[1]}] is not an arc of any graph (agent {arc[1]} never "
                                f"hears agent {arc[0]})")
        if arc in arcs:
            raise ScenarioError(f"{key}.arc [{arc[0]}, {arc[1]}] is overridden twice")
        over: dict = {}
        if "loss" in amap:
            over["loss"] = _probability(amap["loss"], f"{key}.loss")
        if amap.get("delay") is not None:
            over["delay_mean"], over["delay_jitter"] = _delay(amap["delay"], f"{key}.delay")
        arcs[arc] = over
    return NetworkSpec(loss=loss, delay_mean=mean, delay_jitter=jitter, deadline=deadline, arcs=arcs)


def parse_groups(raw: Any, key: str, ids: tuple) -> tuple:
    """``partition: [[ids], [ids], ...]``: disjoint groups of known agents (the unnamed ones are one more group).

    Parameters
    ----------
    raw : list
        The fault's ``partition`` value.
    key : str
        The key named in messages (``faults[k].partition``).
    ids : tuple of int
        The scenario's agent ids.

    Returns
    -------
    tuple of tuple of int
        The groups as given (the unnamed agents not added).

    Raises
    ------
    ScenarioError
        Not a list of non-empty lists, an unknown agent, an agent in two groups, or every agent in one group.

    Examples
    --------
    >>> parse_groups([[1]], "faults[1].partition", (1, 2, 3))
    ((1,),)
    """
    if not isinstance(raw, list) or not raw:
        raise ScenarioError(f"{key} must be a list of groups of agent ids, e.g. [[1, 2], [3, 4]], got "
                            f"{describe(raw)}")
    groups, seen = [], {}
    for g, group in enumerate(raw, 1):
        if not isinstance(group, list) or not group:
            raise ScenarioError(f"{key}[{g}] must be a non-empty list of agent ids, got {describe(group)}")
        members = []
        for item in group:
            aid = check_known_agent(item, f"{key}[{g}]", ids)
            if aid in seen:
                where = "twice in this group" if seen[aid] == g else f"in group {seen[aid]} too"
                raise ScenarioError(f"{key}[{g}] names agent {aid} {where}: the groups of a partition do not overlap")
            seen[aid] = g
            members.append(aid)
        groups.append(tuple(members))
    rest = tuple(a for a in ids if a not in seen)
    if len(groups) + (1 if rest else 0) < 2:
        raise ScenarioError(f"{key} puts every agent ({ids_text(ids)}) in one group: nothing is cut")
    return tuple(groups)


def check_heals(faults: tuple) -> None:
    """A ``heal`` needs a partition in force (faults in time order, as parsed).

    Parameters
    ----------
    faults : tuple of FaultSpec
        The parsed faults, in time order.

    Raises
    ------
    ScenarioError
        Naming the time of a ``heal`` with no ``partition`` before it (since the last heal).
    """
    cut = False
    for k, f in enumerate(faults, 1):
        if f.action == "partition":
            cut = True
        elif f.action == "heal":
            if not cut:
                raise ScenarioError(f"faults: the heal at {f.at:g} has no partition before it to end")
            cut = False
