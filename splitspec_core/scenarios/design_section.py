"""The scenario's ``design:`` section: the rate, the gains and their method, the consensus subspace, g or q and their
certificates' options (what each key means: ``docs/how-to/scenario.md``).  Bad input gets one line naming the key,
as everywhere else.
"""

from __future__ import annotations

from typing import Any

from ..errors import ScenarioError
from .checks import (BAD_DATA_KEYS, DESIGN_KEYS, MAX_Q, MIN_RICCATI_WEIGHT, RICCATI_KEYS, check_keys, check_known_agent,
                     check_matrix, check_shapes, describe, ids_text, read, require_map)
from . import gain_methods
from .specs import DesignSpec, System

__all__ = ["parse_design"]


def parse_design(raw: Any, time: str, system: System, ids: tuple) -> DesignSpec:
    """The ``design:`` section of a scenario of ``time`` over ``system`` and the agents ``ids``, checked key by key
    (one line naming the key when one is wrong).

    Besides each key's own kind and limits (:func:`~splitspec_core.scenarios.checks.read`), the rules that join keys:
    ``design.rate`` > 0 (continuous) or in (0, 1) (discrete); ``design.gains`` defaults to ``optimal`` when
    ``system`` states noise, else ``place``; a method that needs noise or ``design.K`` gets it; ``design.g`` is
    continuous time's and the split's, ``design.q`` discrete time's and the whole state's; ``q <= q_max <=``
    :data:`~splitspec_core.scenarios.checks.MAX_Q`; ``resilience`` 0 or 1; ``margin`` in (0, 10]; ``rank_tol`` in
    (0, 1); ``dwell`` > 0; the Riccati weights at least
    :data:`~splitspec_core.scenarios.checks.MIN_RICCATI_WEIGHT`.

    Parameters
    ----------
    raw : Any
        The ``design:`` mapping as the file holds it (after :func:`~splitspec_core.scenarios.checks.plain`).
    time : str
        The scenario's ``discrete`` or ``continuous``.
    system : System
        The parsed ``system:`` section (its noise decides the default gains; ``A`` and ``C_i`` check ``design.K``).
    ids : tuple of int
        The agent ids, in agent order (the order of ``system.Cs``).

    Returns
    -------
    DesignSpec
        The design options; ``K`` a tuple of n x s_i arrays in agent order (None unless the method needs it),
        ``rank_tol`` None for ``auto``.

    Raises
    ------
    ScenarioError
        A key that is wrong alone or with the others (one line naming it).
    DimensionError
        A ``design.K.<id>`` that is not n x s_i.

    Examples
    --------
    >>> import numpy as np
    >>> from splitspec_core.scenarios.specs import System
    >>> system = System(A=np.eye(2), Cs=(np.eye(2)[:1], np.eye(2)[1:]), x0=None)
    >>> d = parse_design({"rate": 0.5, "q": 3}, "discrete", system, (1, 2))
    >>> d.gains, d.q, d.q_method, d.consensus
    ('place', 3, 'spectral', 'auto')
    >>> parse_design({"rate": 1.5}, "discrete", system, (1, 2))
    Traceback (most recent call last):
    ...
    splitspec_core.errors.ScenarioError: design.rate must be in (0, 1) for discrete time, got 1.5
    """
    dmap = require_map(raw, "design")
    check_keys(dmap, DESIGN_KEYS, "design")
    rate = read(dmap, "design", "rate")
    if time == "continuous" and not rate > 0:
        raise ScenarioError(f"design.rate must be > 0 for continuous time, got {rate:g}")
    if time == "discrete" and not 0 < rate < 1:
        raise ScenarioError(f"design.rate must be in (0, 1) for discrete time, got {rate:g}")
    # no design.gains: the noise-optimal design when the scenario states noise (synthesis/whole_state.py), else place
    gains = read(dmap, "design", "gains", default=gain_methods.NOISY_DEFAULT if _noisy(system) else None)
    method = gain_methods.method(gains)  # what it needs and allows (scenarios/gain_methods.py)
    consensus = read(dmap, "design", "consensus")
    if consensus == "whole" and method.whole is None:
        takes = gain_methods.listed(tuple(g.name for g in gain_methods.METHODS.values() if g.whole is not None))
        raise ScenarioError(f"design.consensus: whole takes design.gains {takes} ({gains} sets the split's local "
                            "poles)")
    if consensus in ("fusion", "relay"):
        _check_noise_kind(consensus, dmap, system)
    if method.needs_noise and not _noisy(system):
        raise ScenarioError(f"design.gains: {gains} minimizes the error under noise: set system.process_noise "
                            "and/or system.measurement_noise")
    # the whole-state design exchanges q times per event time (continuous: per run.dt) and has no g
    whole_possible = consensus in ("whole", "fusion", "relay") or (consensus == "auto" and not method.local)
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
    elif dmap.get("K") is not None:  # null: absent, as every key
        takes = gain_methods.listed(gain_methods.names_where(needs_K=True))
        raise ScenarioError(f"design.K is only used with design.gains: {takes} (gains is {gains})")

    g = read(dmap, "design", "g")  # a number, auto or adaptive
    if time == "discrete" and "g" in dmap:
        raise ScenarioError("design.g is for continuous time; discrete time uses design.q")
    if consensus in ("whole", "fusion", "relay") and "g" in dmap:
        raise ScenarioError(f"design.g is the split design's consensus gain; design.consensus: {consensus} exchanges "
                            "design.q times per run.dt")
    if not method.local and g == "adaptive":
        raise ScenarioError("design.g: adaptive has no steady state to optimize for noise: with it use design.gains "
                            f"{gain_methods.listed(gain_methods.names_where(local=True, needs_K=False))}")
    if g not in ("auto", "adaptive"):
        if g < 0:
            raise ScenarioError(f"design.g must be >= 0, 'auto' or 'adaptive', got {g:g}")
    g0 = read(dmap, "design", "g0")
    if g0 < 0:
        raise ScenarioError(f"design.g0 must be >= 0, got {g0:g}")
    q = read(dmap, "design", "q")  # an integer >= 1 or auto
    if time == "continuous" and "q" in dmap and not whole_possible:
        raise ScenarioError("design.q is for discrete time and the whole-state design; the split design in continuous "
                            "time uses design.g")
    q_method = read(dmap, "design", "q_method")
    q_max = read(dmap, "design", "q_max")
    if q_max > MAX_Q:
        raise ScenarioError(f"design.q_max must be <= {MAX_Q} (consensus exchanges per event time), got {q_max}")
    if q != "auto" and q > q_max:
        raise ScenarioError(f"design.q = {q} exceeds design.q_max = {q_max}")
    lag = read(dmap, "design", "lag")
    if "lag" in dmap and consensus not in ("relay", "auto"):
        raise ScenarioError(f"design.lag is the relay kind's (design.consensus: relay), not {consensus}'s")
    resilience = read(dmap, "design", "resilience")
    if resilience > 1:
        raise ScenarioError(f"design.resilience must be 0 or 1, got {resilience}")
    weights = read(dmap, "design", "weights")
    margin = read(dmap, "design", "margin")
    if not 0 < margin <= 10:
        raise ScenarioError(f"design.margin must be in (0, 10], got {margin:g}")
    rank_tol = read(dmap, "design", "rank_tol")  # auto: observability.DEFAULT_RANK_TOL (graded margins)
    if rank_tol == "auto":
        rank_tol = None
    elif not 0 < rank_tol < 1:
        raise ScenarioError(f"design.rank_tol must be auto or a number in (0, 1), got {rank_tol:g}")
    graph_set = read(dmap, "design", "graph_set")
    dwell = read(dmap, "design", "dwell")
    if dwell is not None and dwell <= 0:
        raise ScenarioError(f"design.dwell must be > 0, got {dwell:g}")
    undetectable = read(dmap, "design", "undetectable")
    coordinates = read(dmap, "design", "coordinates")
    eigenvalues = read(dmap, "design", "eigenvalues")
    pw = mw = None
    if dmap.get("riccati") is not None:
        rmap = require_map(dmap["riccati"], "design.riccati")
        check_keys(rmap, RICCATI_KEYS, "design.riccati")
        pw, mw = (read(rmap, "design.riccati", k) for k in RICCATI_KEYS)
        for k, w in zip(RICCATI_KEYS, (pw, mw)):
            if w is not None and not w >= MIN_RICCATI_WEIGHT:
                raise ScenarioError(f"design.riccati.{k} must be >= {MIN_RICCATI_WEIGHT:g}, got {rmap[k]}")
    bad_data, bad_data_default = _bad_data(dmap, system)
    return DesignSpec(
        rate=rate, gains=gains, K=K, g=g, g0=g0, q=q, q_method=q_method, q_max=q_max,
        resilience=resilience, weights=weights, margin=margin, rank_tol=rank_tol,
        graph_set=graph_set, dwell=dwell, process_weight=pw, measurement_weight=mw,
        eigenvalues=eigenvalues, undetectable=undetectable, coordinates=coordinates, consensus=consensus,
        bad_data=bad_data, bad_data_default=bad_data_default, lag=lag,
    )


def _bad_data(dmap: dict, system: System) -> tuple:
    """``design.bad_data``: ``(test, default)``, ``test`` None (off) or ``(false_alarm, suspect_after)``, ``default``
    True when the key is absent and the scenario states measurement noise.

    Absent: on, with the declared defaults, when the scenario states measurement noise (a lie spreading silently is
    the worse default; the test is calibrated by the noise the user stated), off without it.  ``off`` or ``false``
    (YAML reads ``off`` and ``no`` as false): off.  ``on`` or ``true``: on with the declared defaults, as ``{}``.
    Given on, it needs measurement noise above 0 on every output: the test's threshold is calibrated against it
    (noise-free data has nothing to calibrate against, and a singular innovation covariance)."""
    raw = dmap.get("bad_data")
    if raw is None:
        if not system.measurement_noise_present:
            return None, False
        # on by default; an output without noise cannot be tested (synthesis/bad_data.py's report line says so)
        return (None if bool((system.measurement_std <= 0).any()) else _defaults()), True
    if raw is False or raw == "off":
        return None, False
    if raw is True or raw == "on":
        raw = {}
    if not isinstance(raw, dict):
        raise ScenarioError(f"design.bad_data must be off, on or a map {{false_alarm, suspect_after}}, got "
                            f"{describe(raw)}")
    bmap = require_map(raw, "design.bad_data")
    check_keys(bmap, BAD_DATA_KEYS, "design.bad_data")
    p, k = (read(bmap, "design.bad_data", key) for key in BAD_DATA_KEYS)
    if not 0 < p < 0.5:
        raise ScenarioError(f"design.bad_data.false_alarm must be in (0, 0.5), got {p:g}")
    if not system.measurement_noise_present or bool((system.measurement_std <= 0).any()):
        raise ScenarioError("design.bad_data needs system.measurement_noise above 0 on every output: the test is "
                            "calibrated against it (use design.bad_data: off)")
    return (float(p), int(k)), False


def _defaults() -> tuple:
    """``(false_alarm, suspect_after)`` as declared (:data:`~splitspec_core.scenarios.keys.BAD_DATA`)."""
    p, k = (read({}, "design.bad_data", key) for key in BAD_DATA_KEYS)
    return float(p), int(k)


def _check_noise_kind(kind: str, dmap: dict, system: System) -> None:
    """``design.consensus: fusion`` or ``relay`` (synthesis/fusion_kind.py, synthesis/relay.py): its gains are the
    noise's, every output's measurement noise above zero; what it does not offer yet is refused here, in one line
    each."""
    if not system.measurement_noise_present or bool((system.measurement_std <= 0).any()):
        raise ScenarioError(f"design.consensus: {kind} chooses its gains for the noise: set system.measurement_noise "
                            "above 0 on every output")
    if dmap.get("gains") not in (None, gain_methods.NOISY_DEFAULT):
        raise ScenarioError(f"design.consensus: {kind} chooses its own gains for the noise: leave design.gains out "
                            f"(got {dmap['gains']})")
    for key, off in (("bad_data", ("off", False, None)), ("resilience", (0, None)), ("K", (None,))):
        if dmap.get(key, None) not in off:
            raise ScenarioError(f"design.{key} is not offered with design.consensus: {kind}")


def _noisy(system: System) -> bool:
    """The scenario states noise: process or measurement noise above zero (``System.has_noise``)."""
    return system.has_noise
