"""Replay a recorded run in the simulator: the network changes of ``events.jsonl`` as scenario faults.

``splitspec run`` logs every change of the network with the event time from
which it holds (``tau``): ``agent_lost`` (whatever the cause: a scenario
fault, ``kill -9`` from outside, a frozen process, a round timeout),
``agent_rejoined`` (restart by the scenario or by hand), ``arc_dropped``,
``arc_restored``, ``partition`` and ``healed``.  Turned into ``{at: tau * dt,
kill | restart | drop_arc | restore_arc | partition | heal}`` faults they make
``splitspec simulate`` apply the same changes at the same steps
(:func:`splitspec_core.model.network.fault_step`); with the consensus messages the
run recorded as not counted (``trajectory.npz`` ``lost``: injected losses,
partitions, and real arrivals after the deadline) the replay drops exactly
those, so it gives the run's trajectory to round-off.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

from ..errors import ScenarioError
from .specs import Fault, Scenario

__all__ = ["load_events", "faults_from_events", "with_recorded_faults", "recorded_run"]

_ACTIONS = {"agent_lost": "kill", "agent_rejoined": "restart", "arc_dropped": "drop_arc", "arc_restored": "restore_arc",
            "partition": "partition", "healed": "heal"}


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
        if action == "partition":
            groups = e.get("groups")
            if not (isinstance(groups, list) and groups and all(isinstance(g, list) and all(a in sc.agent_ids for a in g)
                                                                for g in groups)):
                raise ScenarioError(f"{source}: event {k} (partition) has bad 'groups' {groups!r}")
            faults.append(Fault(at=tau * dt, action="partition", groups=tuple(tuple(g) for g in groups)))
        elif action == "heal":
            faults.append(Fault(at=tau * dt, action="heal"))
        elif action in ("kill", "restart"):
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


def recorded_run(path) -> tuple:
    """``(events.jsonl path, (lost, lost_cause) or None)`` of a run: ``path`` is its output directory or its
    ``events.jsonl``; the consensus messages that did not count come from the ``trajectory.npz`` beside it
    (None when there is none, or it has no ``lost`` rows)."""
    import numpy as np

    path = Path(path)
    events = path / "events.jsonl" if path.is_dir() else path
    traj = events.parent / "trajectory.npz"
    lost = None
    if traj.is_file():
        try:
            with np.load(traj) as f:
                if "lost" in f.files and len(f["lost"]):
                    lost = (f["lost"], f["lost_cause"] if "lost_cause" in f.files else None)
        except (OSError, ValueError) as exc:
            raise ScenarioError(f"cannot read {traj}: {exc}") from None
    return events, lost


def with_recorded_faults(sc: Scenario, events_path) -> Scenario:
    """``sc`` with its faults replaced by those recorded in ``events_path``."""
    events = load_events(events_path)
    started = [e for e in events if e["event"] == "orchestrator_started"]
    if started and started[0].get("scenario") not in (None, sc.name):
        raise ScenarioError(f"{events_path} records scenario {started[0]['scenario']!r}, not {sc.name!r}")
    return dataclasses.replace(sc, faults=faults_from_events(events, sc, source=str(events_path)))
