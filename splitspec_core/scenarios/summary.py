"""What ``print(scenario)`` and ``repr(scenario)`` show: a summary of a scenario, not every matrix.

A 62-state model's ``repr`` used to print every entry of ``A``, the ``C_i`` and the noise; a notebook cell that
ends with a scenario now shows its name, time, sizes, state names, graphs, switching, design keys, noise, faults and
run in a few lines (the matrices are ``scenario.system.A`` and the like).
"""

from __future__ import annotations

import dataclasses

__all__ = ["summary"]


def _names(names, limit: int = 6) -> str:
    names = list(names)
    shown = ", ".join(str(n) for n in names[:limit])
    return shown + (f", ... ({len(names)} in all)" if len(names) > limit else "")


def _number(value) -> str:
    try:
        return f"{float(value):g}"
    except (TypeError, ValueError):
        return "per state / per agent"


def summary(sc) -> str:
    """The lines of ``repr(sc)``: name, time and source; states; agents and their outputs; graphs and switching;
    the design (the rate, the gains and every other design key that differs from its default); noise; faults; run.

    Parameters
    ----------
    sc : Scenario
        The scenario.

    Returns
    -------
    str
        Eight lines, no trailing newline.

    Examples
    --------
    >>> from splitspec_core.scenarios.load import load_scenario
    >>> print(summary(load_scenario("examples/paper_discrete.yaml")))
    Scenario 'paper-discrete' (discrete time, from examples/paper_discrete.yaml)
      system: n = 4 states (x1, x2, x3, x4)
      agents: m = 3 (1, 2, 3), outputs per agent {1: 1, 2: 1, 3: 1}
      graphs: a (5 arcs); b (4 arcs); switching: constant
      design: rate 0.5, gains explicit, K given
      noise: none
      faults: none
      run: 40 steps, seed 7
    """
    s = sc.system
    outputs = ", ".join(f"{i}: {len(sc.output_names(i))}" for i in sc.agent_ids)
    graphs = "; ".join(f"{g.name} ({len(g.arcs)} arcs)" for g in sc.graphs)
    sw = sc.switching
    switching = sw.kind  # constant, schedule or random
    if sw.kind == "schedule":
        switching += f" ({len(sw.schedule)} changes)"
    elif sw.kind == "random":
        switching += f" (dwell {sw.dwell:g})"
    d = sc.design
    defaults = type(d)(rate=d.rate)  # DesignSpec's defaults (not imported: specs.py imports this module)
    keys = [f"rate {d.rate:g}", f"gains {d.gains}"] + [
        f"{f.name} {getattr(d, f.name)}" for f in dataclasses.fields(d)
        if f.name not in ("rate", "gains", "K", "bad_data_default") and getattr(d, f.name) != getattr(defaults, f.name)
        and not (f.name == "bad_data" and d.bad_data_default)]  # the test on by default is the default
    if d.K is not None:
        keys.append("K given")
    noise = (f"process {_number(s.process_noise)}, measurement {_number(s.measurement_noise)}" if s.has_noise
             else "none")
    faults = ", ".join(f"{f.action} at {f.at:g}" for f in sc.faults[:4]) + (" ..." if len(sc.faults) > 4 else "")
    r = sc.run
    run = (f"dt {r.dt:g}, " if r.dt is not None else "") + (
        "until stopped" if r.until_stopped else f"{r.steps} steps") + f", seed {r.seed}" + (
        f", pace {r.pace:g}" if r.pace is not None else "")
    lines = [
        f"Scenario {sc.name!r} ({sc.time} time, from {sc.source})",
        f"  system: n = {sc.n} states ({_names(sc.state_names)})"
        + (f", {s.inputs} known inputs" if s.inputs else ""),
        f"  agents: m = {sc.m} ({_names(sc.agent_ids, 10)}), outputs per agent {{{outputs}}}"
        if sc.m <= 10 else f"  agents: m = {sc.m} ({_names(sc.agent_ids, 10)})",
        f"  graphs: {graphs}; switching: {switching}",
        f"  design: {', '.join(keys)}",
        f"  noise: {noise}",
        f"  faults: {faults or 'none'}",
        f"  run: {run}",
    ]
    return "\n".join(lines)
