"""Scenario files: load, validate, and freeze.

A scenario is one YAML file holding the system ``(A, C_i)``, the neighbour
graphs, the switching signal, the design options, faults and run options (see
``docs/scenario.md`` and ``../shared/DESIGN.md``).  :func:`load_scenario` turns
it into a :class:`Scenario` of frozen dataclasses or raises a
:class:`~splitspec_core.errors.ScenarioError` whose one-line message names the
offending key, e.g. ``system.C.3 has 5 columns, system.A is 4x4``.

Unknown keys are rejected (a typo such as ``q_methd`` would otherwise silently
fall back to a default).  Numbers are bounded (see the limits below) so that
nothing accepted here can overflow later arithmetic, and scenario files are
read only if they are regular files of at most :data:`MAX_FILE_BYTES`.
Every YAML parse of a scenario goes through :func:`load_yaml` (libyaml's C
loader when present).
"""

from __future__ import annotations

import math
import numbers
import os
import stat
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

import numpy as np
import yaml

from .errors import DimensionError, ScenarioError

__all__ = [
    "System",
    "GraphSpec",
    "Switching",
    "DesignSpec",
    "Fault",
    "RunSpec",
    "Scenario",
    "load_scenario",
    "load_yaml",
    "parse_scenario",
    "parse_scenario_text",
    "read_scenario_text",
    "yaml_loader",
    "MAX_MAGNITUDE",
    "MAX_SEED",
    "MAX_FILE_BYTES",
    "GAIN_METHODS",
    "Q_METHODS",
]

GAIN_METHODS = ("place", "riccati", "explicit")
Q_METHODS = ("spectral", "weighted", "two-norm", "mixed")
WEIGHTINGS = ("uniform", "metropolis")
FAULT_ACTIONS = ("kill", "restart", "hang", "drop_arc", "restore_arc")

_TOP_KEYS = ("name", "time", "system", "graphs", "switching", "design", "faults", "run", "positions")
_SYSTEM_KEYS = ("A", "C", "x0", "process_noise", "measurement_noise")
_GRAPH_KEYS = ("arcs", "undirected")
_SWITCHING_KEYS = ("schedule", "period", "random")
_RANDOM_KEYS = ("graphs", "dwell", "seed")
_DESIGN_KEYS = (
    "rate", "gains", "K", "g", "g0", "q", "q_method", "q_max", "resilience",
    "weights", "margin", "rank_tol", "graph_set", "dwell", "riccati",
)
_RICCATI_KEYS = ("process_weight", "measurement_weight")
_RUN_KEYS = ("steps", "dt", "seed", "pace")

# Limits, each with the key(s) it bounds and why (docs/scenario.md, "Files and limits").
# Every number (matrix entries, x0, noise levels, rate, g, g0, margin, times, dt, dwell, pace,
# riccati weights): |x| <= 1e12, so squares and products of a few of them stay far below the
# float limit 1.8e308 (system.process_noise: 1e308 overflowed in process_noise**2, the Riccati weight).
MAX_MAGNITUDE = 1e12
# run.dt >= 1e-9: the sampled model integrates exp(A s) over [0, dt]; at dt = 1e-300 it underflows and the SVD fails.
MIN_DT = 1e-9
# run.pace >= 1e-6 event times per second: the orchestrator sleeps 1/pace s per event time.
MIN_PACE = 1e-6
# design.riccati.*_weight >= 1e-12: the Riccati equations are solved with these as covariances.
MIN_RICCATI_WEIGHT = 1e-12
# switching.random.dwell and switching.period >= 1e-3 sample steps (dt, or 1 event time): the switching
# signal is built piece by piece (memory ~ horizon / dwell), and switching within a step is not seen.
MIN_SWITCH_STEPS = 1e-3
# design.q_max <= 1e6: q is the number of consensus exchanges per event time.
MAX_Q = 1_000_000
# run.seed, switching.random.seed <= 2**63 - 1: seeds travel to the processes as msgpack 64-bit integers.
MAX_SEED = 2**63 - 1
# scenario files: regular files of at most 16 MB (16,000,000 bytes), read with a bounded read; a scenario
# is a few kB, and the checks below cost about 0.6 s per MB with libyaml's C loader.
MAX_FILE_BYTES = 16_000_000


# --------------------------------------------------------------------------
# frozen data
# --------------------------------------------------------------------------


def _frozen(a: np.ndarray) -> np.ndarray:
    a = np.array(a, dtype=float)
    a.setflags(write=False)
    return a


@dataclass(frozen=True)
class System:
    """The plant ``x+ = A x + v``, ``y_i = C_i x + w_i``.

    Attributes
    ----------
    A : (n, n) array
        System matrix ``A``.
    Cs : tuple of (s_i, n) arrays
        Output matrices ``C_i`` in agent order (see ``Scenario.agent_ids``).
    x0 : (n,) array or None
        Initial state; ``None`` means drawn from the seed.
    process_noise : float
        Standard deviation of ``v`` (discrete) or its intensity (continuous:
        ``E[v(t) v(s)'] = process_noise I delta(t - s)``).
    measurement_noise : float
        Standard deviation of each measurement noise sample ``w_i``.
    """

    A: np.ndarray
    Cs: tuple
    x0: np.ndarray | None
    process_noise: float = 0.0
    measurement_noise: float = 0.0

    @property
    def n(self) -> int:
        return self.A.shape[0]


@dataclass(frozen=True)
class GraphSpec:
    """A named neighbour graph: arcs ``(j, i)`` mean agent i hears agent j.

    Self-arcs are implicit and not listed; arcs are agent ids, deduplicated.
    """

    name: str
    arcs: tuple  # tuple[tuple[int, int], ...]


@dataclass(frozen=True)
class Switching:
    """The switching signal.

    ``kind`` is ``constant`` (first graph forever), ``schedule`` (pieces
    ``(start, graph)``, optionally repeated every ``period``) or ``random``
    (Poisson switching among ``graphs`` with mean dwell ``dwell``).
    Times are event times (discrete) or seconds (continuous).
    """

    kind: str
    schedule: tuple = ()  # tuple[tuple[float, str], ...]
    period: float | None = None
    graphs: tuple = ()  # graph names used by random switching
    dwell: float | None = None
    seed: int | None = None

    def graph_names(self, all_names: tuple) -> tuple:
        """Names of the graphs this signal can select, in scenario order."""
        if self.kind == "constant":
            return (all_names[0],)
        used = {g for _, g in self.schedule} if self.kind == "schedule" else set(self.graphs)
        return tuple(name for name in all_names if name in used)


@dataclass(frozen=True)
class DesignSpec:
    """Design options (``design:`` section).

    ``g`` is a float, ``"auto"`` or ``"adaptive"`` (continuous only);
    ``q`` an int or ``"auto"`` (discrete only).
    """

    rate: float
    gains: str = "place"
    K: tuple | None = None  # explicit gains, tuple of (n, s_i) arrays in agent order
    g: Any = "auto"
    g0: float = 0.0
    q: Any = "auto"
    q_method: str = "spectral"
    q_max: int = 100_000
    resilience: int = 0
    weights: str = "uniform"
    margin: float = 0.5
    rank_tol: float = 1e-9
    graph_set: str = "scenario"
    dwell: float | None = None
    riccati_process_weight: float | None = None
    riccati_measurement_weight: float | None = None


@dataclass(frozen=True)
class Fault:
    """One scheduled fault: ``action`` at time ``at`` on ``agent`` or ``arc``."""

    at: float
    action: str
    agent: int | None = None
    arc: tuple | None = None


@dataclass(frozen=True)
class RunSpec:
    """Run options: number of steps, sample time (continuous), seed, pace."""

    steps: int = 60
    dt: float | None = None
    seed: int = 0
    pace: float | None = None


@dataclass(frozen=True)
class Scenario:
    """A validated scenario.  Agent order everywhere is ``agent_ids`` order."""

    name: str
    time: str
    agent_ids: tuple
    system: System
    graphs: tuple  # tuple[GraphSpec, ...]
    switching: Switching
    design: DesignSpec
    faults: tuple = ()
    run: RunSpec = field(default_factory=RunSpec)
    source: str = "<scenario>"
    positions: dict | None = None  # agent id -> (x, y) of the topology drawing; None: a circle

    @property
    def m(self) -> int:
        return len(self.agent_ids)

    @property
    def n(self) -> int:
        return self.system.n

    @property
    def graph_names(self) -> tuple:
        return tuple(g.name for g in self.graphs)

    def graph(self, name: str) -> GraphSpec:
        for g in self.graphs:
            if g.name == name:
                return g
        raise KeyError(name)

    def index_of(self, agent_id: int) -> int:
        """Position of ``agent_id`` in ``agent_ids``."""
        return self.agent_ids.index(agent_id)


# --------------------------------------------------------------------------
# validation helpers
# --------------------------------------------------------------------------


def _require_map(value: Any, key: str) -> Mapping:
    if not isinstance(value, Mapping):
        raise ScenarioError(f"{key} must be a mapping, got {_describe(value)}")
    return value


def _describe(value: Any) -> str:
    if value is None:
        return "nothing (null)"
    if isinstance(value, str):
        return f"the string {_short(repr(value))}"
    if isinstance(value, bool):
        return f"the boolean {value}"
    if isinstance(value, list):
        return f"a list of {len(value)} items"
    if isinstance(value, Mapping):
        return "a mapping"
    if isinstance(value, np.ndarray):
        return f"an array of shape {value.shape}"
    return f"{type(value).__name__} {_short(repr(value))}"


def _short(text: str, limit: int = 60) -> str:
    """One line of at most ``limit`` characters (error messages are one line)."""
    text = " ".join(text.split())
    return text if len(text) <= limit else text[: limit - 3] + "..."


def _plain(value: Any, depth: int = 0) -> Any:
    """The YAML data model of a value built in Python: arrays and tuples as lists, numpy scalars as
    Python numbers, mappings as dicts.  Applied to every scenario before validation, so a file and
    :func:`splitspec_core.scenario_model` (numpy arrays welcome) meet the same checks with the same messages."""
    if depth > 8:  # deeper than any scenario key: left for the checks to refuse
        return value
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, (list, tuple)):
        return [_plain(v, depth + 1) for v in value]
    if isinstance(value, Mapping):
        return {_plain(k, depth + 1): _plain(v, depth + 1) for k, v in value.items()}
    return value


def _check_keys(mapping: Mapping, allowed: tuple, key: str) -> None:
    for k in mapping:
        if k not in allowed:
            where = f"{key}.{k}" if key else str(k)
            raise ScenarioError(f"unknown key {where} (expected one of: {', '.join(allowed)}){_did_you_mean(k)}")


# every key of the file by its dotted place, for "did you mean" hints
_ALL_KEYS = (
    *_TOP_KEYS, *(f"system.{k}" for k in _SYSTEM_KEYS), *(f"design.{k}" for k in _DESIGN_KEYS),
    *(f"run.{k}" for k in _RUN_KEYS), *(f"switching.{k}" for k in _SWITCHING_KEYS),
    *(f"design.riccati.{k}" for k in _RICCATI_KEYS),
)


def _did_you_mean(key: Any) -> str:
    """``; did you mean design.q_method?`` when ``key`` is (close to) a key that belongs elsewhere."""
    import difflib

    word = str(key)
    places = {k: k.rpartition(".")[2] for k in _ALL_KEYS}
    exact = [k for k, last in places.items() if last == word]
    close = exact or [k for k in _ALL_KEYS if places[k] in difflib.get_close_matches(word, places.values(), n=1)]
    return f"; did you mean {close[0]}?" if close else ""


def _float(value: numbers.Real) -> float:
    """``float(value)``, with integers too large for a float (YAML ``1000...0``) as +-inf."""
    try:
        return float(value)
    except OverflowError:
        return math.inf if value > 0 else -math.inf


def _bounded(x: float, key: str) -> float:
    """``x`` if ``|x| <= MAX_MAGNITUDE``, else a one-line :class:`ScenarioError` naming ``key``."""
    if not math.isfinite(x):
        raise ScenarioError(f"{key} must be finite, got {x}")
    if abs(x) > MAX_MAGNITUDE:
        raise ScenarioError(f"{key} = {x:g} is out of range: numbers must be within +-{MAX_MAGNITUDE:g} "
                            "(larger ones overflow later arithmetic)")
    return x


def _number(value: Any, key: str) -> float:
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise ScenarioError(f"{key} must be a number, got {_describe(value)}")
    return _bounded(_float(value), key)


def _seed(value: Any, key: str) -> int:
    v = _integer(value, key, minimum=0)
    if v > MAX_SEED:
        raise ScenarioError(f"{key} must be <= 2**63 - 1 = {MAX_SEED} (seeds travel to the processes as "
                            f"64-bit integers), got {v}")
    return v


def _integer(value: Any, key: str, *, minimum: int | None = None) -> int:
    if isinstance(value, bool) or not isinstance(value, numbers.Integral):
        if isinstance(value, float) and value.is_integer():
            value = int(value)
        else:
            raise ScenarioError(f"{key} must be an integer, got {_describe(value)}")
    v = int(value)
    if minimum is not None and v < minimum:
        raise ScenarioError(f"{key} must be >= {minimum}, got {v}")
    return v


def _matrix(value: Any, key: str, *, vector: bool = False) -> np.ndarray:
    """Convert a YAML nested list into a finite float array, naming ``key`` on failure."""
    if value is None:
        raise ScenarioError(f"{key} is missing")
    if vector:
        if not isinstance(value, list) or not value:
            raise ScenarioError(f"{key} must be a non-empty list of numbers, got {_describe(value)}")
        rows = [value]
    else:
        if not isinstance(value, list) or not value:
            raise ScenarioError(f"{key} must be a non-empty list of rows, got {_describe(value)}")
        if all(isinstance(r, numbers.Real) and not isinstance(r, bool) for r in value):
            rows = [value]  # a single row written flat: [1, 0, 0]
        else:
            rows = value
    width = None
    for r, row in enumerate(rows):
        if not isinstance(row, list):
            raise ScenarioError(f"{key} row {r + 1} must be a list of numbers, got {_describe(row)}")
        if width is None:
            width = len(row)
        elif len(row) != width:
            raise DimensionError(f"{key} row {r + 1} has {len(row)} entries, row 1 has {width}")
        for c, x in enumerate(row):
            where = f"{key}[{c + 1}]" if vector else f"{key}[{r + 1}][{c + 1}]"
            if isinstance(x, bool) or not isinstance(x, numbers.Real):
                raise ScenarioError(f"{where} must be a number, got {_describe(x)}")
            _bounded(_float(x), where)
    if width == 0:
        raise ScenarioError(f"{key} has empty rows")
    arr = np.array(rows, dtype=float)
    return _frozen(arr[0] if vector else arr)


def _agent_id(value: Any, key: str) -> int:
    if isinstance(value, str) and value.strip().isdigit():
        value = int(value)
    if isinstance(value, bool) or not isinstance(value, numbers.Integral) or int(value) < 1:
        raise ScenarioError(f"{key}: agent ids must be positive integers, got {_describe(value)}")
    return int(value)


def _known_agent(value: Any, key: str, ids: tuple) -> int:
    aid = _agent_id(value, key)
    if aid not in ids:
        raise ScenarioError(f"{key} names agent {aid}, which is not in system.C (agents: {_ids_text(ids)})")
    return aid


def _ids_text(ids: tuple) -> str:
    return ", ".join(str(i) for i in ids)


def _arc(value: Any, key: str, ids: tuple) -> tuple:
    if not isinstance(value, list) or len(value) != 2:
        raise ScenarioError(f"{key} must be a pair [j, i] of agent ids, got {_describe(value)}")
    j = _known_agent(value[0], key, ids)
    i = _known_agent(value[1], key, ids)
    return (j, i)


# --------------------------------------------------------------------------
# sections
# --------------------------------------------------------------------------


def _parse_system(raw: Any) -> tuple[System, tuple]:
    sysmap = _require_map(raw, "system")
    _check_keys(sysmap, _SYSTEM_KEYS, "system")
    A = _matrix(sysmap.get("A"), "system.A")
    n = A.shape[0]
    if A.shape != (n, n):
        raise DimensionError(f"system.A must be square, got {A.shape[0]}x{A.shape[1]}")
    craw = sysmap.get("C")
    if craw is None:
        raise ScenarioError("system.C is missing (one output matrix per agent, keyed by agent id)")
    cmap = _require_map(craw, "system.C")
    if not cmap:
        raise ScenarioError("system.C has no agents")
    entries = {}
    for k, v in cmap.items():
        aid = _agent_id(k, "system.C")
        if aid in entries:
            raise ScenarioError(f"system.C.{aid} is given twice")
        C = _matrix(v, f"system.C.{aid}")
        if C.shape[1] != n:
            raise DimensionError(f"system.C.{aid} has {C.shape[1]} columns, system.A is {n}x{n}")
        entries[aid] = C
    ids = tuple(sorted(entries))
    x0 = None
    if sysmap.get("x0") is not None:
        x0 = _matrix(sysmap["x0"], "system.x0", vector=True)
        if x0.shape != (n,):
            raise DimensionError(f"system.x0 has {x0.shape[0]} entries, system.A is {n}x{n}")
    noises = {}
    for k in ("process_noise", "measurement_noise"):
        v = _number(sysmap.get(k, 0.0), f"system.{k}")
        if v < 0:
            raise ScenarioError(f"system.{k} must be >= 0, got {v}")
        noises[k] = v
    system = System(A=A, Cs=tuple(entries[i] for i in ids), x0=x0, **noises)
    return system, ids


def _parse_graphs(raw: Any, ids: tuple) -> tuple:
    if raw is None:
        raise ScenarioError("graphs is missing (at least one named neighbour graph)")
    gmap = _require_map(raw, "graphs")
    if not gmap:
        raise ScenarioError("graphs has no graph")
    out = []
    for name, spec in gmap.items():
        gname = str(name)
        key = f"graphs.{gname}"
        if isinstance(spec, list):  # shorthand: a graph given as its list of arcs
            spec = {"arcs": spec}
        spec = _require_map(spec, key)
        _check_keys(spec, _GRAPH_KEYS, key)
        if "arcs" not in spec and "undirected" not in spec:
            raise ScenarioError(f"{key} needs arcs or undirected")
        arcs: list = []
        for field_name, both in (("arcs", False), ("undirected", True)):
            items = spec.get(field_name)
            if items is None:
                continue
            if not isinstance(items, list):
                raise ScenarioError(f"{key}.{field_name} must be a list of [j, i] pairs, got {_describe(items)}")
            for n_item, item in enumerate(items):
                j, i = _arc(item, f"{key}.{field_name}[{n_item + 1}]", ids)
                for arc in ((j, i), (i, j)) if both else ((j, i),):
                    if arc[0] != arc[1] and arc not in arcs:
                        arcs.append(arc)
        out.append(GraphSpec(name=gname, arcs=tuple(arcs)))
    return tuple(out)


def _parse_switching(raw: Any, names: tuple, time: str) -> Switching:
    if raw is None:
        return Switching(kind="constant")
    smap = _require_map(raw, "switching")
    _check_keys(smap, _SWITCHING_KEYS, "switching")
    if ("schedule" in smap) == ("random" in smap):
        raise ScenarioError("switching needs exactly one of schedule or random")

    def known_graph(value: Any, key: str) -> str:
        g = str(value)
        if g not in names:
            raise ScenarioError(f"{key} names graph {g!r}, which is not in graphs ({', '.join(names)})")
        return g

    if "schedule" in smap:
        sched = smap["schedule"]
        if not isinstance(sched, list) or not sched:
            raise ScenarioError(f"switching.schedule must be a non-empty list of [time, graph], got {_describe(sched)}")
        pieces = []
        for k, piece in enumerate(sched):
            key = f"switching.schedule[{k + 1}]"
            if not isinstance(piece, list) or len(piece) != 2:
                raise ScenarioError(f"{key} must be a pair [time, graph], got {_describe(piece)}")
            t = _number(piece[0], f"{key} time")
            if pieces and t <= pieces[-1][0]:
                raise ScenarioError(f"{key} time {t:g} is not after the previous piece ({pieces[-1][0]:g})")
            pieces.append((t, known_graph(piece[1], key)))
        if pieces[0][0] != 0:
            raise ScenarioError(f"switching.schedule must start at time 0, starts at {pieces[0][0]:g}")
        period = None
        if smap.get("period") is not None:
            period = _number(smap["period"], "switching.period")
            if period <= pieces[-1][0]:
                raise ScenarioError(
                    f"switching.period ({period:g}) must be after the last piece's start ({pieces[-1][0]:g})")
        return Switching(kind="schedule", schedule=tuple(pieces), period=period)

    if "period" in smap:
        raise ScenarioError("switching.period is only for switching.schedule")
    rmap = _require_map(smap["random"], "switching.random")
    _check_keys(rmap, _RANDOM_KEYS, "switching.random")
    graphs = rmap.get("graphs", list(names))
    if not isinstance(graphs, list) or len(graphs) < 2:
        raise ScenarioError(f"switching.random.graphs must list at least two graphs, got {_describe(graphs)}")
    gs = tuple(known_graph(g, f"switching.random.graphs[{k + 1}]") for k, g in enumerate(graphs))
    if "dwell" not in rmap:
        raise ScenarioError("switching.random.dwell is missing (the average dwell time)")
    dwell = _number(rmap["dwell"], "switching.random.dwell")
    if dwell <= 0:
        raise ScenarioError(f"switching.random.dwell must be > 0, got {dwell:g}")
    seed = None if rmap.get("seed") is None else _seed(rmap["seed"], "switching.random.seed")
    return Switching(kind="random", graphs=gs, dwell=dwell, seed=seed)


def _parse_design(raw: Any, time: str, system: System, ids: tuple) -> DesignSpec:
    dmap = _require_map(raw, "design")
    _check_keys(dmap, _DESIGN_KEYS, "design")
    if "rate" not in dmap:
        raise ScenarioError("design.rate is missing (the decay rate lambda)")
    rate = _number(dmap["rate"], "design.rate")
    if time == "continuous" and not rate > 0:
        raise ScenarioError(f"design.rate must be > 0 for continuous time, got {rate:g}")
    if time == "discrete" and not 0 < rate < 1:
        raise ScenarioError(f"design.rate must be in (0, 1) for discrete time, got {rate:g}")
    gains = str(dmap.get("gains", "place"))
    if gains not in GAIN_METHODS:
        raise ScenarioError(f"design.gains must be one of {', '.join(GAIN_METHODS)}, got {gains!r}")
    K = None
    if gains == "explicit":
        kraw = dmap.get("K")
        if kraw is None:
            raise ScenarioError("design.K is missing (design.gains is explicit: one n x s_i matrix per agent)")
        kmap = _require_map(kraw, "design.K")
        given = {}
        for k, v in kmap.items():
            aid = _known_agent(k, "design.K", ids)
            given[aid] = _matrix(v, f"design.K.{aid}")
        missing = [i for i in ids if i not in given]
        if missing:
            raise ScenarioError(f"design.K has no gain for agent(s) {_ids_text(tuple(missing))}")
        Ks = []
        for aid, C in zip(ids, system.Cs):
            K_i = given[aid]
            if K_i.shape != (system.n, C.shape[0]):
                # no guessing: a flat row [a, b, ...] is 1 x n, not the column n x 1
                hint = "; write a column as [[a], [b], ...]" if C.shape[0] == 1 else ""
                raise DimensionError(
                    f"design.K.{aid} is {K_i.shape[0]}x{K_i.shape[1]}, expected {system.n}x{C.shape[0]} "
                    f"(n x s_i with system.C.{aid} {C.shape[0]}x{C.shape[1]}{hint})")
            Ks.append(K_i)
        K = tuple(Ks)
    elif "K" in dmap:
        raise ScenarioError(f"design.K is only used with design.gains: explicit (gains is {gains})")

    g = dmap.get("g", "auto")
    if time == "discrete" and "g" in dmap:
        raise ScenarioError("design.g is for continuous time; discrete time uses design.q")
    if g not in ("auto", "adaptive"):
        g = _number(g, "design.g")
        if g < 0:
            raise ScenarioError(f"design.g must be >= 0, 'auto' or 'adaptive', got {g:g}")
    g0 = _number(dmap.get("g0", 0.0), "design.g0")
    if g0 < 0:
        raise ScenarioError(f"design.g0 must be >= 0, got {g0:g}")
    q = dmap.get("q", "auto")
    if time == "continuous" and "q" in dmap:
        raise ScenarioError("design.q is for discrete time; continuous time uses design.g")
    if q != "auto":
        q = _integer(q, "design.q", minimum=1)
    q_method = str(dmap.get("q_method", "spectral"))
    if q_method not in Q_METHODS:
        raise ScenarioError(f"design.q_method must be one of {', '.join(Q_METHODS)}, got {q_method!r}")
    q_max = _integer(dmap.get("q_max", 100_000), "design.q_max", minimum=1)
    if q_max > MAX_Q:
        raise ScenarioError(f"design.q_max must be <= {MAX_Q} (consensus exchanges per event time), got {q_max}")
    if q != "auto" and q > q_max:
        raise ScenarioError(f"design.q = {q} exceeds design.q_max = {q_max}")
    resilience = _integer(dmap.get("resilience", 0), "design.resilience", minimum=0)
    if resilience > 1:
        raise ScenarioError(f"design.resilience must be 0 or 1, got {resilience}")
    weights = str(dmap.get("weights", "uniform"))
    if weights not in WEIGHTINGS:
        raise ScenarioError(f"design.weights must be one of {', '.join(WEIGHTINGS)}, got {weights!r}")
    margin = _number(dmap.get("margin", 0.5), "design.margin")
    if not 0 < margin <= 10:
        raise ScenarioError(f"design.margin must be in (0, 10], got {margin:g}")
    rank_tol = _number(dmap.get("rank_tol", 1e-9), "design.rank_tol")
    if not 0 < rank_tol < 1:
        raise ScenarioError(f"design.rank_tol must be in (0, 1), got {rank_tol:g}")
    graph_set = str(dmap.get("graph_set", "scenario"))
    if graph_set not in ("scenario", "all"):
        raise ScenarioError(f"design.graph_set must be scenario or all, got {graph_set!r}")
    dwell = None
    if dmap.get("dwell") is not None:
        dwell = _number(dmap["dwell"], "design.dwell")
        if dwell <= 0:
            raise ScenarioError(f"design.dwell must be > 0, got {dwell:g}")
    pw = mw = None
    if dmap.get("riccati") is not None:
        rmap = _require_map(dmap["riccati"], "design.riccati")
        _check_keys(rmap, _RICCATI_KEYS, "design.riccati")
        for k in _RICCATI_KEYS:
            if k in rmap and not _number(rmap[k], f"design.riccati.{k}") >= MIN_RICCATI_WEIGHT:
                raise ScenarioError(f"design.riccati.{k} must be >= {MIN_RICCATI_WEIGHT:g}, got {rmap[k]}")
        pw = None if "process_weight" not in rmap else float(rmap["process_weight"])
        mw = None if "measurement_weight" not in rmap else float(rmap["measurement_weight"])
    return DesignSpec(
        rate=rate, gains=gains, K=K, g=g, g0=g0, q=q, q_method=q_method, q_max=q_max,
        resilience=resilience, weights=weights, margin=margin, rank_tol=rank_tol,
        graph_set=graph_set, dwell=dwell, riccati_process_weight=pw, riccati_measurement_weight=mw,
    )


def _parse_faults(raw: Any, ids: tuple) -> tuple:
    if raw is None:
        return ()
    if not isinstance(raw, list):
        raise ScenarioError(f"faults must be a list of {{at: T, <action>: ...}}, got {_describe(raw)}")
    out = []
    for k, item in enumerate(raw):
        key = f"faults[{k + 1}]"
        fmap = _require_map(item, key)
        _check_keys(fmap, ("at",) + FAULT_ACTIONS, key)
        if "at" not in fmap:
            raise ScenarioError(f"{key}.at is missing (the time of the fault)")
        at = _number(fmap["at"], f"{key}.at")
        if at < 0:
            raise ScenarioError(f"{key}.at must be >= 0, got {at:g}")
        actions = [a for a in FAULT_ACTIONS if a in fmap]
        if len(actions) != 1:
            raise ScenarioError(f"{key} needs exactly one of {', '.join(FAULT_ACTIONS)}")
        action = actions[0]
        if action.endswith("_arc"):
            arc = _arc(fmap[action], f"{key}.{action}", ids)
            if arc[0] == arc[1]:
                raise ScenarioError(f"{key}.{action} [{arc[0]}, {arc[1]}] is a self-arc: self-arcs are implicit "
                                    "and cannot be dropped or restored")
            out.append(Fault(at=at, action=action, arc=arc))
        else:
            out.append(Fault(at=at, action=action, agent=_known_agent(fmap[action], f"{key}.{action}", ids)))
    return tuple(sorted(out, key=lambda f: f.at))


def _parse_run(raw: Any, time: str) -> RunSpec:
    if raw is None:
        raw = {}
    rmap = _require_map(raw, "run")
    _check_keys(rmap, _RUN_KEYS, "run")
    steps = _integer(rmap.get("steps", 60), "run.steps", minimum=1)
    dt = None
    if time == "continuous":
        dt = _number(rmap.get("dt", 0.01), "run.dt")
        if dt < MIN_DT:
            raise ScenarioError(f"run.dt must be >= {MIN_DT:g}, got {dt:g}")
    elif "dt" in rmap:
        raise ScenarioError("run.dt is only for continuous time (discrete steps are event times)")
    seed = _seed(rmap.get("seed", 0), "run.seed")
    pace = None
    if rmap.get("pace") is not None:
        pace = _number(rmap["pace"], "run.pace")
        if pace < MIN_PACE:
            raise ScenarioError(f"run.pace must be >= {MIN_PACE:g} event times per second, got {pace:g}")
    return RunSpec(steps=steps, dt=dt, seed=seed, pace=pace)


# --------------------------------------------------------------------------
# entry points
# --------------------------------------------------------------------------


def parse_scenario(data: Any, *, source: str = "<scenario>") -> Scenario:
    """Validate a scenario given as a parsed mapping (e.g. from YAML or JSON).

    Raises
    ------
    ScenarioError
        With a one-line message naming the offending key.
    """
    if data is None:
        raise ScenarioError(f"{source} is empty")
    data = _plain(data)
    top = _require_map(data, "the scenario")
    _check_keys(top, _TOP_KEYS, "")
    name = str(top.get("name", Path(source).stem))
    time = top.get("time", "discrete")
    if time not in ("discrete", "continuous"):
        raise ScenarioError(f"time must be discrete or continuous, got {_describe(time)}")
    if "system" not in top:
        raise ScenarioError("system is missing (A and one C_i per agent)")
    system, ids = _parse_system(top["system"])
    graphs = _parse_graphs(top.get("graphs"), ids)
    names = tuple(g.name for g in graphs)
    switching = _parse_switching(top.get("switching"), names, time)
    if "design" not in top:
        raise ScenarioError("design is missing (at least design.rate)")
    design = _parse_design(top["design"], time, system, ids)
    faults = _parse_faults(top.get("faults"), ids)
    run = _parse_run(top.get("run"), time)
    _check_switching_against_step(switching, run)
    positions = _parse_positions(top.get("positions"), ids)
    return Scenario(
        name=name, time=time, agent_ids=ids, system=system, graphs=graphs,
        switching=switching, design=design, faults=faults, run=run, source=source, positions=positions,
    )


def _parse_positions(raw: Any, ids: tuple) -> dict | None:
    """``positions: {id: [x, y], ...}``: where each agent is drawn in the topology view (every agent, distinct)."""
    if raw is None:
        return None
    mapping = _require_map(raw, "positions")
    out: dict = {}
    for key, value in mapping.items():
        aid = _known_agent(key, "positions", ids)
        where = f"positions.{aid}"
        if isinstance(value, (str, bytes)) or not isinstance(value, (list, tuple)) or len(value) != 2:
            raise ScenarioError(f"{where} must be a pair [x, y], got {_describe(value)}")
        out[aid] = (_number(value[0], f"{where}[0]"), _number(value[1], f"{where}[1]"))
    missing = [a for a in ids if a not in out]
    if missing:
        raise ScenarioError(f"positions has no [x, y] for agents {_ids_text(tuple(missing))} (give every agent one)")
    seen: dict = {}
    for aid, p in out.items():
        if p in seen:
            raise ScenarioError(f"positions.{aid} = [{p[0]:g}, {p[1]:g}] is also agent {seen[p]}'s position")
        seen[p] = aid
    return {a: out[a] for a in ids}


def _check_switching_against_step(switching: Switching, run: RunSpec) -> None:
    """Random dwell and schedule period of at least ``MIN_SWITCH_STEPS`` sample steps."""
    step = run.dt if run.dt is not None else 1.0
    floor = MIN_SWITCH_STEPS * step
    unit = f"run.dt = {step:g}" if run.dt is not None else "one event time"
    for key, value in (("switching.random.dwell", switching.dwell), ("switching.period", switching.period)):
        if value is not None and value < floor:
            raise ScenarioError(f"{key} = {value:g} is below {MIN_SWITCH_STEPS:g} sample steps ({floor:g}, with "
                                f"{unit}): switching that fast is not seen by the sampled run")


def yaml_loader() -> type:
    """The YAML loader for scenarios: libyaml's ``CSafeLoader`` when PyYAML has it, else ``SafeLoader``.

    The C loader parses a 10 MB scenario several times faster than the pure-Python one.
    """
    return yaml.CSafeLoader if getattr(yaml, "__with_libyaml__", False) else yaml.SafeLoader


def load_yaml(text: str, *, source: str = "<scenario>") -> Any:
    """Parse scenario YAML text (safe loader); a syntax error is one line with its line and column.

    Every YAML parse of a scenario goes through here: :func:`load_scenario`,
    the ``--tune --write`` of the CLI, and the agent and plant processes
    (which receive the scenario text from the orchestrator).

    Raises
    ------
    ScenarioError
        ``<source>: YAML syntax error at line L, column C: <problem>``.
    """
    try:
        return yaml.load(text, Loader=yaml_loader())  # noqa: S506 - a safe loader
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        problem = getattr(exc, "problem", None) or str(exc).splitlines()[0]
        where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark is not None else ""
        raise ScenarioError(f"{source}: YAML syntax error{where}: {problem}") from None


def parse_scenario_text(text: str, *, source: str = "<scenario>") -> Scenario:
    """:func:`load_yaml` then :func:`parse_scenario`: a scenario from its YAML text."""
    if not text.strip():
        raise ScenarioError(f"{source} is empty")
    data = load_yaml(text, source=source)
    if data is None:
        raise ScenarioError(f"{source} is empty")
    return parse_scenario(data, source=source)


def _megabytes(size: int) -> str:
    return f"{size / 1e6:.1f}"


def read_scenario_text(path: str | Path) -> str:
    """The text of a scenario file: a regular file of at most :data:`MAX_FILE_BYTES`, UTF-8.

    The file is checked with ``os.stat`` before it is opened (a FIFO would
    block, ``/dev/zero`` never ends) and read with a bounded read.

    Raises
    ------
    ScenarioError
        One line naming the file: missing, a directory or other non-regular
        file, too large, unreadable or not UTF-8.
    """
    p = Path(path)
    try:
        st = os.stat(p)
    except FileNotFoundError:
        raise ScenarioError(f"scenario file {p} does not exist") from None
    except (OSError, ValueError) as exc:
        raise ScenarioError(f"cannot read scenario file {p}: {getattr(exc, 'strerror', None) or exc}") from None
    if stat.S_ISDIR(st.st_mode):
        raise ScenarioError(f"scenario file {p} is a directory")
    if not stat.S_ISREG(st.st_mode):
        kind = ("a FIFO" if stat.S_ISFIFO(st.st_mode) else "a character device" if stat.S_ISCHR(st.st_mode)
                else "a block device" if stat.S_ISBLK(st.st_mode) else "a socket" if stat.S_ISSOCK(st.st_mode)
                else "not a regular file")
        raise ScenarioError(f"scenario file {p} is {kind}, not a regular file")
    limit = f"the limit is {MAX_FILE_BYTES / 1e6:g} MB"
    if st.st_size > MAX_FILE_BYTES:
        raise ScenarioError(f"scenario file {p} is {_megabytes(st.st_size)} MB; {limit}")
    try:
        with open(p, "rb") as f:
            data = f.read(MAX_FILE_BYTES + 1)
    except OSError as exc:
        raise ScenarioError(f"cannot read scenario file {p}: {exc.strerror or exc}") from None
    if len(data) > MAX_FILE_BYTES:  # grew since the stat
        raise ScenarioError(f"scenario file {p} is over {MAX_FILE_BYTES / 1e6:g} MB; {limit}")
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise ScenarioError(f"cannot read scenario file {p}: not UTF-8 text ({exc.reason} at byte {exc.start})") \
            from None


def load_scenario(path: str | Path) -> Scenario:
    """Read and validate a YAML scenario file.

    Raises
    ------
    ScenarioError
        If the file is not a regular file, is too large, cannot be read, is
        empty, is not valid YAML, or fails validation; the message is one line
        naming the file or key.
    """
    p = Path(path)
    text = read_scenario_text(p)
    if not text.strip():
        raise ScenarioError(f"scenario file {p} is empty")
    data = load_yaml(text, source=str(p))
    if data is None:
        raise ScenarioError(f"scenario file {p} is empty")
    return parse_scenario(data, source=str(p))
