"""Replay a recorded run in the simulator: the network changes of ``events.jsonl`` as scenario faults.

``splitspec run`` logs every change of the network with the event time from
which it holds (``tau``): ``agent_lost`` (whatever the cause: a scenario
fault, ``kill -9`` from outside, a frozen process, a round timeout),
``agent_rejoined`` (restart by the scenario or by hand), ``arc_dropped``,
``arc_restored``, ``partition`` and ``healed``, and the events of every other fault kind
(:mod:`splitspec_core.scenarios.faults`: each kind reads its own event back).  Turned into ``{at: tau * dt,
kill | restart | drop_arc | restore_arc | partition | heal | ...}`` faults they make
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
from .faults import kind_of_event
from .specs import Scenario

__all__ = ["load_events", "faults_from_events", "with_recorded_faults", "recorded_run"]


def load_events(path) -> list:
    """The events of an ``events.jsonl`` file (a torn last line, as after a crash, is ignored).

    Parameters
    ----------
    path : str or os.PathLike
        The ``events.jsonl`` file.

    Returns
    -------
    list of dict
        One dict per event line, in file order (each has an ``event`` field).

    Raises
    ------
    ScenarioError
        The file cannot be read, a line other than the last is not JSON, or a line is not an object
        with an ``event`` field.
    """
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
    """Faults reproducing the network changes recorded in ``events`` (each event word read by the fault kind that
    logs it: :func:`splitspec_core.scenarios.faults.kind_of_event`).

    Parameters
    ----------
    events : list of dict
        The recorded events (:func:`load_events`); events no fault kind logs are skipped.
    sc : Scenario
        The scenario replayed: its ``agent_ids`` resolve agent names, its ``run.dt`` turns event
        times into seconds (continuous time; discrete: ``at = tau``).
    source : str, optional
        What the events came from, named in error messages (default ``"events"``).

    Returns
    -------
    tuple of Fault
        The faults, in event order, each at ``tau * dt``.

    Raises
    ------
    ScenarioError
        An event has no valid non-negative integer ``tau``, or its kind rejects its fields.

    Examples
    --------
    >>> import splitspec_core as ss
    >>> sc = ss.load_scenario("examples/paper_discrete.yaml")
    >>> events = [{"event": "agent_lost", "id": 2, "tau": 5}, {"event": "agent_rejoined", "id": 2, "tau": 9}]
    >>> faults_from_events(events, sc)
    (Kill(at=5.0, agent=2), Restart(at=9.0, agent=2))
    """
    dt = sc.run.dt if sc.time == "continuous" else 1.0
    faults = []
    for k, e in enumerate(events, 1):
        cls = kind_of_event(e.get("event"))
        if cls is None:
            continue
        tau = e.get("tau")
        if not isinstance(tau, int) or isinstance(tau, bool) or tau < 0:
            raise ScenarioError(f"{source}: event {k} ({e['event']}) has no valid 'tau'")
        faults.append(cls(at=tau * dt, **cls.from_event(e, f"{source}: event {k} ({e['event']})", sc.agent_ids)))
    return tuple(faults)


def recorded_run(path) -> tuple:
    """``(events.jsonl path, (lost, lost_cause) or None)`` of a run: ``path`` is its output directory or its
    ``events.jsonl``; the consensus messages that did not count come from the ``trajectory.npz`` beside it
    (None when there is none, or it has no ``lost`` rows).

    Parameters
    ----------
    path : str or os.PathLike
        A run's output directory, or its ``events.jsonl``.

    Returns
    -------
    events : pathlib.Path
        The ``events.jsonl`` path (not checked to exist).
    lost : tuple or None
        ``(lost, lost_cause)`` arrays of ``trajectory.npz`` (``lost_cause`` None when the file has
        none), or None.

    Raises
    ------
    ScenarioError
        ``trajectory.npz`` exists but cannot be read.
    """
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
    """``sc`` with its faults replaced by those recorded in ``events_path``.

    Parameters
    ----------
    sc : Scenario
        The scenario to replay.
    events_path : str or os.PathLike
        The run's ``events.jsonl``.

    Returns
    -------
    Scenario
        A copy of ``sc`` whose ``faults`` are :func:`faults_from_events` of the file.

    Raises
    ------
    ScenarioError
        The file cannot be read, or its ``orchestrator_started`` event names another scenario.
    """
    events = load_events(events_path)
    started = [e for e in events if e["event"] == "orchestrator_started"]
    if started and started[0].get("scenario") not in (None, sc.name):
        raise ScenarioError(f"{events_path} records scenario {started[0]['scenario']!r}, not {sc.name!r}")
    return dataclasses.replace(sc, faults=faults_from_events(events, sc, source=str(events_path)))
