"""The sections of a scenario (system, graphs, switching, design, faults, run, positions), parsed in file order;
``network:`` in :mod:`splitspec_core.scenarios.network_section`.

:func:`parse_scenario` takes the mapping a YAML file holds (or :func:`splitspec_core.scenario`
builds) and returns the frozen :class:`~splitspec_core.scenarios.specs.Scenario`, or raises a
one-line :class:`~splitspec_core.errors.ScenarioError` naming the key.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from ..errors import ScenarioError
from .checks import (GRAPH_KEYS, KEEP_KEYS, RANDOM_KEYS, RUN_KEYS, SWITCHING_KEYS, SYSTEM_KEYS, TOP_KEYS, MIN_DT, MIN_PACE,
                     MIN_SWITCH_STEPS, check_agent_id, check_arc, check_keys,
                     describe, ids_text, check_known_agent, check_matrix, check_names, check_number,
                     read, require_map, check_seed, check_shapes, plain)
from .inputs import parse_inputs
from .labels import default_state_names
from .noise import parse_measurement_noise, parse_process_noise
from .files import resolve_model_file
from .specs import GraphSpec, RunSpec, Scenario, Switching, System
from .design_section import parse_design
from .faults import parse_faults
from .network_section import parse_network
from .sources import parse_input_source, parse_sources

#: run.keep.segment_mb's least: 64 KiB (orchestrator.records.files.Continuous floors its sizes there too)
MIN_SEGMENT_MB = 1 / 16
#: system.time_unit's longest word
MAX_UNIT = 12


def _parse_system(raw: Any, time: str = "discrete") -> tuple[System, tuple]:
    sysmap = require_map(raw, "system")
    check_keys(sysmap, SYSTEM_KEYS, "system")
    A = check_matrix(sysmap.get("A"), "system.A")
    check_shapes(A, {})
    A_given = A
    A, B, u, sample = parse_inputs(sysmap, A, time)  # system.B, system.u, system.sample
    craw = sysmap.get("C")
    if craw is None:
        raise ScenarioError("system.C is missing (one output matrix per agent, keyed by agent id)")
    cmap = require_map(craw, "system.C")
    if not cmap:
        raise ScenarioError("system.C has no agents")
    entries = {}
    for k, v in cmap.items():
        aid = check_agent_id(k, "system.C")
        if aid in entries:
            raise ScenarioError(f"system.C.{aid} is given twice")
        C = check_matrix(v, f"system.C.{aid}")
        check_shapes(A, {aid: C})
        entries[aid] = C
    ids = tuple(sorted(entries))
    x0 = None
    if sysmap.get("x0") is not None:
        x0 = check_matrix(sysmap["x0"], "system.x0", vector=True)
        check_shapes(A, {}, x0)
    noises = {"process_noise": parse_process_noise(sysmap.get("process_noise", 0.0), A.shape[0]),
              "measurement_noise": parse_measurement_noise(sysmap.get("measurement_noise", 0.0),
                                                           {i: entries[i].shape[0] for i in ids})}
    states = None
    if sysmap.get("states") is not None:
        states = check_names(sysmap["states"], "system.states", A.shape[0], f"one per state, system.A is {A.shape[0]}x"
                                                                        f"{A.shape[0]}")
    outputs = None
    if sysmap.get("outputs") is not None:
        omap = require_map(sysmap["outputs"], "system.outputs")
        outputs = {}
        for k, v in omap.items():
            aid = check_known_agent(k, "system.outputs", ids)
            s_i = entries[aid].shape[0]
            outputs[aid] = check_names(v, f"system.outputs.{aid}", s_i, f"one per row of system.C.{aid}")
    system = System(A=A, Cs=tuple(entries[i] for i in ids), x0=x0, states=states, outputs=outputs, B=B, u=u,
                    sample=sample, A_continuous=A_given if sample is not None else None, time=time,
                    time_unit=_time_unit(read(sysmap, "system", "time_unit")), **noises)
    return system, ids


def _time_unit(value: Any) -> str:
    """``system.time_unit``: a short word of letters (``s``, ``min``, ``h``, ``ms``, ``day``), printed after times."""
    if not isinstance(value, str) or not value.isalpha() or len(value) > MAX_UNIT:
        raise ScenarioError(f"system.time_unit must be a short word of letters (s, min, h, ms; at most {MAX_UNIT}), "
                            f"got {describe(value)}")
    return value


def _parse_graphs(raw: Any, ids: tuple) -> tuple:
    if raw is None:
        raise ScenarioError("graphs is missing (at least one named neighbour graph)")
    gmap = require_map(raw, "graphs")
    if not gmap:
        raise ScenarioError("graphs has no graph")
    out = []
    for name, spec in gmap.items():
        gname = str(name)
        key = f"graphs.{gname}"
        if isinstance(spec, list):  # shorthand: a graph given as its list of arcs
            spec = {"arcs": spec}
        spec = require_map(spec, key)
        check_keys(spec, GRAPH_KEYS, key)
        if "arcs" not in spec and "undirected" not in spec:
            raise ScenarioError(f"{key} needs arcs or undirected")
        arcs: list = []
        for field_name, both in (("arcs", False), ("undirected", True)):
            items = spec.get(field_name)
            if items is None:
                continue
            if not isinstance(items, list):
                raise ScenarioError(f"{key}.{field_name} must be a list of [j, i] pairs, got {describe(items)}")
            for n_item, item in enumerate(items):
                j, i = check_arc(item, f"{key}.{field_name}[{n_item + 1}]", ids)
                for arc in ((j, i), (i, j)) if both else ((j, i),):
                    if arc[0] != arc[1] and arc not in arcs:
                        arcs.append(arc)
        out.append(GraphSpec(name=gname, arcs=tuple(arcs)))
    return tuple(out)


def _parse_switching(raw: Any, names: tuple, time: str) -> Switching:
    if raw is None:
        return Switching(kind="constant")
    smap = require_map(raw, "switching")
    check_keys(smap, SWITCHING_KEYS, "switching")
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
            raise ScenarioError(f"switching.schedule must be a non-empty list of [time, graph], got {describe(sched)}")
        pieces = []
        for k, piece in enumerate(sched):
            key = f"switching.schedule[{k + 1}]"
            if not isinstance(piece, list) or len(piece) != 2:
                raise ScenarioError(f"{key} must be a pair [time, graph], got {describe(piece)}")
            t = check_number(piece[0], f"{key} time")
            if pieces and t <= pieces[-1][0]:
                raise ScenarioError(f"{key} time {t:g} is not after the previous piece ({pieces[-1][0]:g})")
            pieces.append((t, known_graph(piece[1], key)))
        if pieces[0][0] != 0:
            raise ScenarioError(f"switching.schedule must start at time 0, starts at {pieces[0][0]:g}")
        period = None
        if smap.get("period") is not None:
            period = check_number(smap["period"], "switching.period")
            if period <= pieces[-1][0]:
                raise ScenarioError(
                    f"switching.period ({period:g}) must be after the last piece's start ({pieces[-1][0]:g})")
        return Switching(kind="schedule", schedule=tuple(pieces), period=period)

    if "period" in smap:
        raise ScenarioError("switching.period is only for switching.schedule")
    rmap = require_map(smap["random"], "switching.random")
    check_keys(rmap, RANDOM_KEYS, "switching.random")
    graphs = rmap.get("graphs", list(names))
    if not isinstance(graphs, list) or len(graphs) < 2:
        raise ScenarioError(f"switching.random.graphs must list at least two graphs, got {describe(graphs)}")
    gs = tuple(known_graph(g, f"switching.random.graphs[{k + 1}]") for k, g in enumerate(graphs))
    if "dwell" not in rmap:
        raise ScenarioError("switching.random.dwell is missing (the average dwell time)")
    dwell = check_number(rmap["dwell"], "switching.random.dwell")
    if dwell <= 0:
        raise ScenarioError(f"switching.random.dwell must be > 0, got {dwell:g}")
    seed = None if rmap.get("seed") is None else check_seed(rmap["seed"], "switching.random.seed")
    return Switching(kind="random", graphs=gs, dwell=dwell, seed=seed)


def _parse_show(raw: Any, names: tuple) -> tuple | None:
    """``run.show``: names or ``fnmatch`` patterns of states, each matching at least one."""
    import fnmatch

    if raw is None:
        return None
    items = [raw] if isinstance(raw, str) else raw
    if not isinstance(items, list) or not items or not all(isinstance(p, str) and p for p in items):
        raise ScenarioError(f"run.show must be a list of state names or patterns (x*, delta_*), got {describe(raw)}")
    for k, p in enumerate(items):
        if not any(fnmatch.fnmatchcase(name, p) for name in names):
            shown = ", ".join(names[:6]) + (" ..." if len(names) > 6 else "")
            raise ScenarioError(f"run.show[{k + 1}] = {p!r} matches no state (the states: {shown})")
    return tuple(items)


def _parse_run(raw: Any, time: str, names: tuple = (), live: bool = False) -> RunSpec:
    if raw is None:
        raw = {}
    rmap = require_map(raw, "run")
    check_keys(rmap, RUN_KEYS, "run")
    steps = read(rmap, "run", "steps")
    dt = None
    if time == "continuous":
        dt = read(rmap, "run", "dt")
        if dt < MIN_DT:
            raise ScenarioError(f"run.dt must be >= {MIN_DT:g}, got {dt:g}")
    elif "dt" in rmap:
        raise ScenarioError("run.dt is only for continuous time (discrete steps are event times)")
    seed = check_seed(read(rmap, "run", "seed"), "run.seed")
    pace = read(rmap, "run", "pace")
    if pace is not None:
        if pace < MIN_PACE:
            raise ScenarioError(f"run.pace must be >= {MIN_PACE:g} event times per second, got {pace:g}")
    omitted = "steps" not in rmap
    until_stopped = omitted and bool(pace or live)
    hours, gigabytes, recording, segment_mb = _parse_keep(rmap.get("keep"), until_stopped)
    return RunSpec(steps, dt, seed, pace, _parse_show(rmap.get("show"), names), until_stopped, hours, gigabytes,
                   recording, read(rmap, "run", "record_every"), omitted, bool(read(rmap, "run", "standby")),
                   keep_segment_mb=segment_mb)


def _parse_keep(raw: Any, until_stopped: bool) -> tuple:
    """``run.keep``: ``(hours, gigabytes, recording_hours, segment_mb)``, each None when not given.  Only a run until
    stopped has segments to remove: a run of ``run.steps`` keeps its whole ``trajectory.npz``.  ``segment_mb`` at
    least :data:`MIN_SEGMENT_MB` (64 KiB: smaller, the run would write little but segments)."""
    if raw is None:
        return None, None, None, None
    kmap = require_map(raw, "run.keep")
    check_keys(kmap, KEEP_KEYS, "run.keep")
    if not kmap:
        raise ScenarioError("run.keep needs hours or gigabytes (or both)")
    if not until_stopped:
        raise ScenarioError("run.keep is for a run that goes on until stopped (a paced run without run.steps): a run "
                            "of run.steps keeps its whole trajectory.npz")
    values = {k: read(kmap, "run.keep", k) for k in KEEP_KEYS}
    for k, v in values.items():
        if v is not None and v <= 0:
            raise ScenarioError(f"run.keep.{k} must be > 0, got {v:g}")
    if not set(kmap) & {"hours", "gigabytes"}:
        raise ScenarioError(f"run.keep.{sorted(kmap)[0]} needs hours or gigabytes for the row chunks")
    if values["segment_mb"] is not None and values["segment_mb"] < MIN_SEGMENT_MB:
        raise ScenarioError(f"run.keep.segment_mb must be >= {MIN_SEGMENT_MB:g} (64 KiB), got {values['segment_mb']:g}")
    return values["hours"], values["gigabytes"], values["recording_hours"], values["segment_mb"]


def parse_scenario(data: Any, *, source: str = "<scenario>", base: Path | None = None) -> Scenario:
    """Validate a scenario given as a parsed mapping (e.g. from YAML or JSON).

    The sections are parsed in file order (system, graphs, switching, design, faults, run, positions, network,
    sources), each by its parser; the first mistake stops it.

    Parameters
    ----------
    data : Any
        The mapping a scenario file holds (or :func:`splitspec_core.scenario` builds); numpy arrays and tuples are
        welcome (:func:`~splitspec_core.scenarios.checks.plain`).  None: an empty file.
    source : str
        Where it came from, for messages and the default name (the file name's stem).
    base : Path, optional
        The folder a relative ``system.file`` is read from (None: the working directory;
        :mod:`splitspec_core.scenarios.files`).

    Returns
    -------
    Scenario
        Frozen and validated; agent ids sorted (agent order).

    Raises
    ------
    ScenarioError
        With a one-line message naming the offending key (a :class:`~splitspec_core.errors.DimensionError` for
        shapes that do not agree).

    Examples
    --------
    >>> sc = parse_scenario({"system": {"A": [[0.9, 0.2], [0, 0.8]], "C": {2: [[0, 1]], 1: [[1, 0]]}},
    ...                      "graphs": {"a": [[1, 2], [2, 1]]}, "design": {"rate": 0.5}}, source="two.yaml")
    >>> sc.name, sc.agent_ids, sc.design.gains, sc.run.steps
    ('two', (1, 2), 'place', 60)
    >>> parse_scenario({"system": {"A": [[1, 0]], "C": {1: [[1, 0]]}}})
    Traceback (most recent call last):
    ...
    splitspec_core.errors.DimensionError: system.A must be square, got 1x2
    """
    if data is None:
        raise ScenarioError(f"{source} is empty")
    data = plain(resolve_model_file(data, base))
    top = require_map(data, "the scenario")
    check_keys(top, TOP_KEYS, "")
    name = str(top.get("name", Path(source).stem))
    time = read(top, "", "time")
    if "system" not in top:
        raise ScenarioError("system is missing (A and one C_i per agent)")
    system, ids = _parse_system(top["system"], time)
    graphs = _parse_graphs(top.get("graphs"), ids)
    names = tuple(g.name for g in graphs)
    switching = _parse_switching(top.get("switching"), names, time)
    if "design" not in top:
        raise ScenarioError("design is missing (at least design.rate)")
    design = parse_design(top["design"], time, system, ids)
    faults = parse_faults(top.get("faults"), ids, outputs={i: C.shape[0] for i, C in zip(ids, system.Cs)})
    run = _parse_run(top.get("run"), time, system.states or default_state_names(system.n), bool(top.get("sources")))
    _check_switching_against_step(switching, run)
    positions = _parse_positions(top.get("positions"), ids)
    network = parse_network(top.get("network"), ids, graphs)
    sources = parse_sources(top.get("sources"), ids, run.pace)
    input_source = parse_input_source(top.get("sources"), run.pace, system.inputs)
    return Scenario(
        name=name, time=time, agent_ids=ids, system=system, graphs=graphs,
        switching=switching, design=design, faults=faults, run=run, source=source, positions=positions,
        network=network, sources=sources, input_source=input_source,
    )


def _parse_positions(raw: Any, ids: tuple) -> dict | None:
    """``positions: {id: [x, y], ...}``: where each agent is drawn in the topology view (every agent, distinct)."""
    if raw is None:
        return None
    mapping = require_map(raw, "positions")
    out: dict = {}
    for key, value in mapping.items():
        aid = check_known_agent(key, "positions", ids)
        where = f"positions.{aid}"
        if isinstance(value, (str, bytes)) or not isinstance(value, (list, tuple)) or len(value) != 2:
            raise ScenarioError(f"{where} must be a pair [x, y], got {describe(value)}")
        out[aid] = (check_number(value[0], f"{where}[0]"), check_number(value[1], f"{where}[1]"))
    missing = [a for a in ids if a not in out]
    if missing:
        raise ScenarioError(f"positions has no [x, y] for agents {ids_text(tuple(missing))} (give every agent one)")
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
