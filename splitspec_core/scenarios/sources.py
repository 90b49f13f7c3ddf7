"""The scenario's ``sources:`` section: live sensors, one per agent, instead of a simulated plant.

``sources: {<agent id>: {key: KEY, max_age: SECONDS}}`` (or ``<agent id>: KEY``, the default ``max_age``)
names, for every agent, the Zenoh key on which the user's own process publishes ``y_i``.  The key is
relative to the run's sensor space: agent i's sensor publishes on ``splitspec/<run_id>/sensors/<KEY>``
(:meth:`splitspec_core.runtime.wire.Keys.sensor`), where the secure run's access control can give it that
key and nothing else (user ``sensor-<id>``).  An absolute key elsewhere is not supported: a bridge that
republishes there is the way.

Rules (one line each, naming the key):

* every agent has a source (an agent without one would only ever predict: an error, not a silent default);
  ids must be agents of ``system.C``; keys are distinct;
* a key is one or more ``/``-separated chunks of letters, digits, ``_ . -`` (no wildcard, no leading or
  trailing ``/``): a concrete key a publisher can put on and a policy can name;
* ``max_age`` > 0 and <= :data:`MAX_AGE` seconds; default :data:`DEFAULT_AGE_PERIODS` event periods
  (``2 / run.pace``): a value is used at an event time if it arrived at most ``max_age`` before it;
* ``sources`` needs ``run.pace`` (event times are wall-clock instants only when the run is paced);
* ``sources.inputs`` (``{key, max_age}`` or a key): where the user's process publishes the known inputs ``u``
  (``system.B``'s p columns, :mod:`splitspec_core.scenarios.inputs`), every agent subscribing; required with ``system.B``,
  refused without it.  At an event time an agent takes the newest ``u`` at most ``max_age`` old, else holds the
  last one it took (zero before the first): commands are held, not dropped.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from typing import Any

from ..errors import ScenarioError
from .checks import check_keys, describe, ids_text, check_known_agent, check_number, require_map

__all__ = ["Source", "parse_sources", "parse_input_source", "DEFAULT_AGE_PERIODS", "INPUTS", "MAX_AGE", "SOURCE_KEYS"]

#: the entry of ``sources:`` that names the known inputs' key (not an agent id)
INPUTS = "inputs"

SOURCE_KEYS = ("key", "max_age")
#: the default max_age, in event periods (1 / run.pace): one period late is normal, two means the sensor lags
DEFAULT_AGE_PERIODS = 2.0
#: seconds: a bound on max_age (an hour-old measurement is not a live sensor)
MAX_AGE = 3600.0
_KEY = re.compile(r"[A-Za-z0-9_.\-]+(/[A-Za-z0-9_.\-]+)*")


@dataclass(frozen=True)
class Source:
    """Agent i's live sensor: the key (relative to ``splitspec/<run>/sensors/``) and the largest age used."""

    key: str
    max_age: float


def parse_sources(raw: Any, ids: tuple, pace: float | None) -> dict | None:
    """``{agent id: Source}`` in ``ids`` order, or None without a ``sources:`` section.

    The ``inputs`` entry is checked here (key form, distinct keys) but left out of the result
    (:func:`parse_input_source`).

    Parameters
    ----------
    raw : mapping or None
        ``sources:`` as the YAML holds it.
    ids : tuple of int
        The scenario's agent ids.
    pace : float or None
        ``run.pace`` (event times per second); the default ``max_age`` is ``DEFAULT_AGE_PERIODS / pace``.

    Returns
    -------
    dict of int to Source, or None

    Raises
    ------
    ScenarioError
        One line naming the key (module docstring's rules): no ``run.pace``, an unknown agent, a bad key or
        ``max_age``, a key used twice, an agent without a source.

    Examples
    --------
    >>> parse_sources({1: "lab/y1", 2: {"key": "lab/y2", "max_age": 0.5}}, (1, 2), 10.0)
    {1: Source(key='lab/y1', max_age=0.2), 2: Source(key='lab/y2', max_age=0.5)}
    """
    if raw is None:
        return None
    smap = require_map(raw, "sources")
    if pace is None:
        raise ScenarioError("sources needs run.pace (event times per second): live sensors are sampled at "
                            "wall-clock event times")
    out: dict = {}
    seen: dict = {}
    for k, v in smap.items():
        aid = k if k == INPUTS else check_known_agent(k, "sources", ids)
        src = _source(v, f"sources.{aid}", f"chain/{aid}", pace)
        if src.key in seen:
            raise ScenarioError(f"sources.{aid}.key {src.key!r} is also {_whose(seen[src.key])} source (one key "
                                "each)")
        seen[src.key] = aid
        if aid != INPUTS:
            out[aid] = src
    missing = [a for a in ids if a not in out]
    if missing:
        raise ScenarioError(f"sources has no key for agent{'s' * (len(missing) > 1)} {ids_text(tuple(missing))} "
                            "(every agent needs its sensor)")
    return {a: out[a] for a in ids}


def _whose(aid) -> str:
    return "the inputs'" if aid == INPUTS else f"agent {aid}'s"


def _source(v: Any, where: str, example: str, pace: float) -> Source:
    if isinstance(v, str):
        v = {"key": v}
    vmap = require_map(v, where)
    check_keys(vmap, SOURCE_KEYS, where)
    key = vmap.get("key")
    if not isinstance(key, str) or not _KEY.fullmatch(key):
        raise ScenarioError(f"{where}.key must be a key like {example} (chunks of letters, digits, _ . - "
                            f"separated by /, no wildcard; relative to splitspec/<run>/sensors/), got "
                            f"{describe(key)}")
    age = DEFAULT_AGE_PERIODS / pace
    if vmap.get("max_age") is not None:
        age = check_number(vmap["max_age"], f"{where}.max_age")
        if not 0 < age <= MAX_AGE:
            raise ScenarioError(f"{where}.max_age must be > 0 and <= {MAX_AGE:g} seconds, got {age:g}")
    return Source(key=key, max_age=float(age))


def parse_input_source(raw: Any, pace: float | None, inputs: int) -> Source | None:
    """``sources.inputs`` (checked by :func:`parse_sources` first), against the scenario's ``inputs`` (the columns of
    ``system.B``): required with live sensors and known inputs, refused without known inputs.

    Parameters
    ----------
    raw : mapping or None
        ``sources:`` as the YAML holds it.
    pace : float or None
        ``run.pace``.
    inputs : int
        ``p``, the columns of ``system.B`` (0: no known inputs).

    Returns
    -------
    Source or None
        None without ``sources:`` or without known inputs.

    Raises
    ------
    ScenarioError
        ``sources.inputs`` without ``system.B``, or ``system.B`` with live sensors and no ``sources.inputs``.
    """
    if raw is None:
        return None
    given = isinstance(raw, dict) and INPUTS in raw
    if given and not inputs:
        raise ScenarioError("sources.inputs names where u is published, and the scenario has no system.B (known "
                            "inputs: x+ = A x + B u)")
    if not given and inputs:
        raise ScenarioError("system.B (known inputs) with live sensors (sources:): give sources.inputs, the key your "
                            "process publishes u on (every agent takes it), or leave system.B out")
    return _source(raw[INPUTS], f"sources.{INPUTS}", "plant/u", pace) if given else None
