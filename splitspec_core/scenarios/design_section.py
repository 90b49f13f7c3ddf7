"""The scenario's ``design:`` section: the rate, the gains and their method, the consensus subspace, g or q and their
certificates' options (what each key means: ``docs/how-to/scenario.md``).  Bad input gets one line naming the key,
as everywhere else.
"""

from __future__ import annotations

from typing import Any

from ..errors import ScenarioError
from .checks import (DESIGN_CHOICES, DESIGN_KEYS, MAX_Q, MIN_RICCATI_WEIGHT, RICCATI_KEYS, check_integer, check_keys,
                     check_known_agent, check_matrix, check_number, check_shapes, ids_text, require_map)
from . import gain_methods
from .specs import DesignSpec, System

__all__ = ["parse_design"]


def parse_design(raw: Any, time: str, system: System, ids: tuple) -> DesignSpec:
    """The ``design:`` section of a scenario of ``time`` over ``system`` and the agents ``ids``, checked key by key
    (one line naming the key when one is wrong)."""
    dmap = require_map(raw, "design")
    check_keys(dmap, DESIGN_KEYS, "design")
    if "rate" not in dmap:
        raise ScenarioError("design.rate is missing (the decay rate lambda)")
    rate = check_number(dmap["rate"], "design.rate")
    if time == "continuous" and not rate > 0:
        raise ScenarioError(f"design.rate must be > 0 for continuous time, got {rate:g}")
    if time == "discrete" and not 0 < rate < 1:
        raise ScenarioError(f"design.rate must be in (0, 1) for discrete time, got {rate:g}")
    # no design.gains: the noise-optimal design when the scenario states noise (synthesis/whole_state.py), else place
    gains = _choice(dmap, "gains", default=gain_methods.NOISY_DEFAULT if _noisy(system) else None)
    method = gain_methods.method(gains)  # what it needs and allows (scenarios/gain_methods.py)
    consensus = _choice(dmap, "consensus")
    if consensus == "whole" and method.whole is None:
        takes = [g.name for g in gain_methods.METHODS.values() if g.whole is not None]
        whole = ", ".join(takes[:-1]) + " or " + takes[-1]
        raise ScenarioError(f"design.consensus: whole takes design.gains {whole} ({gains} sets the split's local "
                            "poles)")
    if method.needs_noise and not _noisy(system):
        raise ScenarioError(f"design.gains: {gains} minimizes the error under noise: set system.process_noise "
                            "and/or system.measurement_noise")
    # the whole-state design exchanges q times per event time (continuous: per run.dt) and has no g
    whole_possible = consensus == "whole" or (consensus == "auto" and not method.local)
    K = None
    if method.needs_K:
        kraw = dmap.get("K")
        if kraw is None:
            raise ScenarioError(f"design.K is missing (design.gains is {gains}: one n x s_i matrix per agent)")
        kmap = require_map(kraw, "design.K")
        given = {}
        for k, v in kmap.items():
            aid = check_known_agent(k, "design.K", ids)
            given[aid] = check_matrix(v, f"design.K.{aid}")
        missing = [i for i in ids if i not in given]
        if missing:
            raise ScenarioError(f"design.K has no gain for agent(s) {ids_text(tuple(missing))}")
        Ks = []
        for aid, C in zip(ids, system.Cs):
            K_i = given[aid]
            check_shapes(system.A, {aid: C}, Ks={aid: K_i})
            Ks.append(K_i)
        K = tuple(Ks)
    elif "K" in dmap:
        raise ScenarioError(f"design.K is only used with design.gains: {' or '.join(gain_methods.names_where(needs_K=True))} "
                            f"(gains is {gains})")

    g = dmap.get("g", "auto")
    if time == "discrete" and "g" in dmap:
        raise ScenarioError("design.g is for continuous time; discrete time uses design.q")
    if consensus == "whole" and "g" in dmap:
        raise ScenarioError("design.g is the split design's consensus gain; design.consensus: whole exchanges "
                            "design.q times per run.dt")
    if not method.local and g == "adaptive":
        raise ScenarioError("design.g: adaptive has no steady state to optimize for noise: with it use design.gains "
                            f"{' or '.join(gain_methods.names_where(local=True, needs_K=False))}")
    if g not in ("auto", "adaptive"):
        g = check_number(g, "design.g")
        if g < 0:
            raise ScenarioError(f"design.g must be >= 0, 'auto' or 'adaptive', got {g:g}")
    g0 = check_number(dmap.get("g0", 0.0), "design.g0")
    if g0 < 0:
        raise ScenarioError(f"design.g0 must be >= 0, got {g0:g}")
    q = dmap.get("q", "auto")
    if time == "continuous" and "q" in dmap and not whole_possible:
        raise ScenarioError("design.q is for discrete time and the whole-state design; the split design in continuous "
                            "time uses design.g")
    if q != "auto":
        q = check_integer(q, "design.q", minimum=1)
    q_method = _choice(dmap, "q_method")
    q_max = check_integer(dmap.get("q_max", 100_000), "design.q_max", minimum=1)
    if q_max > MAX_Q:
        raise ScenarioError(f"design.q_max must be <= {MAX_Q} (consensus exchanges per event time), got {q_max}")
    if q != "auto" and q > q_max:
        raise ScenarioError(f"design.q = {q} exceeds design.q_max = {q_max}")
    resilience = check_integer(dmap.get("resilience", 0), "design.resilience", minimum=0)
    if resilience > 1:
        raise ScenarioError(f"design.resilience must be 0 or 1, got {resilience}")
    weights = _choice(dmap, "weights")
    margin = check_number(dmap.get("margin", 0.5), "design.margin")
    if not 0 < margin <= 10:
        raise ScenarioError(f"design.margin must be in (0, 10], got {margin:g}")
    rank_tol = dmap.get("rank_tol", "auto")  # auto: observability.DEFAULT_RANK_TOL (graded margins)
    if rank_tol == "auto" or rank_tol is None:
        rank_tol = None
    else:
        rank_tol = check_number(rank_tol, "design.rank_tol")
        if not 0 < rank_tol < 1:
            raise ScenarioError(f"design.rank_tol must be auto or a number in (0, 1), got {rank_tol:g}")
    graph_set = _choice(dmap, "graph_set")
    dwell = None
    if dmap.get("dwell") is not None:
        dwell = check_number(dmap["dwell"], "design.dwell")
        if dwell <= 0:
            raise ScenarioError(f"design.dwell must be > 0, got {dwell:g}")
    undetectable = _choice(dmap, "undetectable")
    coordinates = _choice(dmap, "coordinates")
    eigenvalues = _choice(dmap, "eigenvalues")
    pw = mw = None
    if dmap.get("riccati") is not None:
        rmap = require_map(dmap["riccati"], "design.riccati")
        check_keys(rmap, RICCATI_KEYS, "design.riccati")
        for k in RICCATI_KEYS:
            if k in rmap and not check_number(rmap[k], f"design.riccati.{k}") >= MIN_RICCATI_WEIGHT:
                raise ScenarioError(f"design.riccati.{k} must be >= {MIN_RICCATI_WEIGHT:g}, got {rmap[k]}")
        pw = None if "process_weight" not in rmap else float(rmap["process_weight"])
        mw = None if "measurement_weight" not in rmap else float(rmap["measurement_weight"])
    return DesignSpec(
        rate=rate, gains=gains, K=K, g=g, g0=g0, q=q, q_method=q_method, q_max=q_max,
        resilience=resilience, weights=weights, margin=margin, rank_tol=rank_tol,
        graph_set=graph_set, dwell=dwell, process_weight=pw, measurement_weight=mw,
        eigenvalues=eigenvalues, undetectable=undetectable, coordinates=coordinates, consensus=consensus,
    )


def _choice(dmap: dict, key: str, default: str | None = None) -> str:
    """``design.<key>``, one of its words (:data:`~splitspec_core.scenarios.checks.DESIGN_CHOICES`), else its
    default (or ``default``); one line naming the key and the words when it is another."""
    words, fallback = DESIGN_CHOICES[key]
    value = dmap.get(key, fallback if default is None else default)
    if not isinstance(value, str) or value not in words:
        listed = " or ".join(words) if len(words) == 2 else "one of " + ", ".join(words)
        raise ScenarioError(f"design.{key} must be {listed}, got {value!r}")
    return value


def _noisy(system: System) -> bool:
    """The scenario states noise: process or measurement noise above zero (``System.has_noise``)."""
    return system.has_noise
