"""Replay a recorded run in the simulator: the network changes of ``events.jsonl`` as scenario faults.

``splitspec run`` logs every change of the network with the event time from
which it holds (``tau``): ``agent_lost`` (whatever the cause: a scenario
fault, ``kill -9`` from outside, a frozen process, a round timeout),
``agent_rejoined`` (restart by the scenario or by hand), ``arc_dropped`` and
``arc_restored``.  Turned into ``{at: tau * dt, kill | restart | drop_arc |
restore_arc}`` faults they make ``splitspec simulate`` apply the same changes
at the same steps (:func:`splitspec_core.network.fault_step`), so the replay
gives the run's trajectory to round-off.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

from .errors import ScenarioError
from .scenario_model import Fault, Scenario

__all__ = ["load_events", "faults_from_events", "with_recorded_faults"]

_ACTIONS = {"agent_lost": "kill", "agent_rejoined": "restart", "arc_dropped": "drop_arc", "arc_restored": "restore_arc"}


def load_events(path) -> list:
    """The events of an ``events.jsonl`` file (a torn last line, as after a crash, is ignored)."""
    path = Path(path)
    try:
        lines = path.read_text(encoding="utf-8").splitlines()
    except OSError as exc:
        raise ScenarioError(f"cannot read events file {path}: {exc.strerror}") from None
    out = []
    for k, line in enumerate(lines, 1):
        if not line.strip():
            continue
        try:
            e = json.loads(line)
        except json.JSONDecodeError:
            if k == len(lines):
                break  # torn last line of a crashed run
            raise ScenarioError(f"{path}:{k}: not a JSON object (is this a splitspec events.jsonl?)") from None
        if not isinstance(e, dict) or "event" not in e:
            raise ScenarioError(f"{path}:{k}: not a splitspec event (no 'event' field)")
        out.append(e)
    return out


def faults_from_events(events: list, sc: Scenario, *, source: str = "events") -> tuple:
    """Faults reproducing the network changes recorded in ``events``."""
    dt = sc.run.dt if sc.time == "continuous" else 1.0
    faults = []
    for k, e in enumerate(events, 1):
        action = _ACTIONS.get(e.get("event"))
        if action is None:
            continue
        tau = e.get("tau")
        if not isinstance(tau, int) or isinstance(tau, bool) or tau < 0:
            raise ScenarioError(f"{source}: event {k} ({e['event']}) has no valid 'tau'")
        if action in ("kill", "restart"):
            aid = e.get("id")
            if aid not in sc.agent_ids:
                raise ScenarioError(f"{source}: event {k} ({e['event']}) names agent {aid!r}, which is not in the "
                                    f"scenario (agents {', '.join(map(str, sc.agent_ids))}): wrong scenario?")
            faults.append(Fault(at=tau * dt, action=action, agent=aid))
        else:
            arc = e.get("arc")
            if not (isinstance(arc, list) and len(arc) == 2 and all(a in sc.agent_ids for a in arc)):
                raise ScenarioError(f"{source}: event {k} ({e['event']}) has a bad 'arc' {arc!r}")
            faults.append(Fault(at=tau * dt, action=action, arc=(arc[0], arc[1])))
    return tuple(faults)


def with_recorded_faults(sc: Scenario, events_path) -> Scenario:
    """``sc`` with its faults replaced by those recorded in ``events_path``."""
    events = load_events(events_path)
    started = [e for e in events if e["event"] == "orchestrator_started"]
    if started and started[0].get("scenario") not in (None, sc.name):
        raise ScenarioError(f"{events_path} records scenario {started[0]['scenario']!r}, not {sc.name!r}")
    return dataclasses.replace(sc, faults=faults_from_events(events, sc, source=str(events_path)))
