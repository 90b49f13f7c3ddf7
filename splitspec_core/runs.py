"""Runs from Python: start a multi-process run (:func:`run`), read any run's records back (:func:`load_run`), open
its recording (:func:`view`).  Re-exported by ``splitspec_core`` as ``ss.run``, ``ss.load_run``, ``ss.view``.

A run is real OS processes talking over Zenoh (the orchestrator, the plant, one per agent), so :func:`run`
starts ``splitspec run`` as a child process of this interpreter (``python -m splitspec_orchestrator``) and waits
for it: this layer never imports the runtime.  What it returns is what :func:`load_run` reads from the output
directory, the same :class:`~splitspec_core.simulation.simulator.Trajectory` that :func:`splitspec_core.simulate` returns
(a run equals the simulation of the same scenario and seed to round-off), the events of ``events.jsonl`` and
the scenario the run wrote (``scenario.yaml``), whose design :meth:`RunRecord.design` gives.

    import splitspec_core as ss
    sc = ss.load_scenario("examples/ring10_faults.yaml")
    rec = ss.run(sc, out="out/ring10")            # blocks until the run ends; progress=True to see it
    sim = ss.simulate(sc)
    abs(rec.trajectory.xhat - sim.xhat)            # round-off (NaN where an agent was dead)
    [e["event"] for e in rec.events]                # agent_lost, agent_rejoined, ...
    ss.view("out/ring10")                           # the Rerun viewer (native, or the web viewer's URL)
"""

from __future__ import annotations

import importlib.util
import json
import signal
import subprocess
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Iterable


from .errors import ScenarioError, SplitspecError
from .scenarios.checks import plain
from .scenarios.files import resolve_model_file
from .scenarios.load import ORIGIN, dump_yaml, load_scenario, load_yaml
from .scenarios.specs import Scenario
from .simulation.simulator import Trajectory

__all__ = ["RunRecord", "RunError", "load_run", "run", "view", "read_events", "end_event", "closing_line"]



class RunError(SplitspecError):
    """``splitspec run`` ended with a non-zero status; the message is its last line (what went wrong)."""

    def __init__(self, message: str, status: int):
        super().__init__(message)
        self.status = status


@dataclass(frozen=True)
class RunRecord:
    """A run's records, read back from its output directory ``out``.

    Attributes
    ----------
    out : Path
    scenario : Scenario
        ``out/scenario.yaml``, the scenario the run played
    trajectory : Trajectory
        ``out/trajectory.npz`` (or the chunks, ``out/chunks/``): ``t``, ``x`` (NaN rows where the truth is unknown), ``xhat`` (T, m, n), ``alive``,
        ``graph``, ``columns`` (``g`` ...), ``lost``, ``y``/``y_missing`` on measurements or live sensors, and ``u``
        (T, p) with known inputs
    events : tuple of dict
        ``out/events.jsonl``, one dict per line (``event``, ``t``, ``wall`` and the event's fields)
    """

    out: Path
    scenario: Scenario
    trajectory: Trajectory
    events: tuple

    def design(self):
        """The scenario's design (:func:`splitspec_core.design`): what the agents computed for themselves.

        Returns
        -------
        DesignResult
            ``splitspec_core.design(self.scenario)``, computed anew.
        """
        from .api import design

        return design(self.scenario)

    def named(self, event: str) -> list:
        """The events called ``event``, in order.

        Parameters
        ----------
        event : str
            An event's name (``agent_lost``, ``run_finished``, ...).

        Returns
        -------
        list of dict
            Those events in the order of ``events.jsonl`` (empty if none).
        """
        return [e for e in self.events if e.get("event") == event]

    @property
    def summary(self) -> dict | None:
        """The event that ended the run (``run_finished``, ``run_interrupted`` or ``run_failed``) with what it did:
        ``event_times``, ``seconds``, ``rounds_per_second``, ``final_max_error`` or ``final_disagreement``,
        ``agents_lost``, ``agents_rejoined``, ``messages_lost`` and, paced, ``pace``, ``pace_kept``,
        ``late_event_times``, ``max_lateness_ms``; None if the run never ended (killed)."""
        return end_event(self.events)

    @property
    def takeovers(self) -> list:
        """The standby takeovers of the run (``orchestrator_takeover`` events: ``t``, ``tau``, ``pid``, ``host``,
        ``epoch``, ``previous_pid``, ``previous_host``, ``stall_ms``), in order; empty without any."""
        return self.named("orchestrator_takeover")

    @property
    def closing_line(self) -> str | None:
        """The one line ``splitspec run`` ends with (:func:`closing_line`); None if the run never ended."""
        end = self.summary
        return None if end is None else closing_line(end)

    @property
    def on_disk(self) -> str | None:
        """What ``run.keep`` removed and which span is still on disk (:func:`kept_span`), one line; when it removed
        nothing, why (:func:`nothing_removed`); None for a run without ``run.keep``."""
        span = kept_span(self.events)
        if span is None:
            return nothing_removed(self.out, self.events)
        t = self.trajectory.t
        held = (f"the rows of t = {t[0]:g} .. {t[-1]:g} ({len(t)} event times) are on disk" if len(t) else
                "no row is on disk")
        return f"{span['text']}; {held}"


def kept_span(events: Iterable[dict]) -> dict | None:
    """What ``run.keep`` removed, from the ``records_removed`` events: the segments and bytes removed and, per kind
    (``chunks``, ``recording``), the first event time still on disk (the last one removed + 1).

    Parameters
    ----------
    events : iterable of dict
        A run's events (:func:`read_events`).

    Returns
    -------
    dict or None
        ``removed`` (segments), ``bytes``, ``chunks_from`` and ``recording_from`` (event times; None: none of that
        kind removed) and ``text``, one line; None when nothing was removed.

    Examples
    --------
    >>> ev = [{"event": "records_removed", "kind": "chunks", "last_tau": 99, "bytes": 2_000_000}]
    >>> kept_span(ev)["text"]
    'run.keep removed 1 segment (2.0 MB): the rows before event time 100'
    """
    gone = [e for e in events if e.get("event") == "records_removed"]
    if not gone:
        return None

    def after(kind: str) -> int | None:
        lasts = [e["last_tau"] for e in gone if e.get("kind") == kind and e.get("last_tau") is not None]
        return max(lasts) + 1 if lasts else None

    chunks_from, recording_from = after("chunks"), after("recording")
    size = sum(int(e.get("bytes") or 0) for e in gone)
    parts = []
    if chunks_from is not None:
        parts.append(f"the rows before event time {chunks_from}")
    if recording_from is not None:
        parts.append(f"the recording before event time {recording_from}")
    text = (f"run.keep removed {len(gone)} segment{'s' if len(gone) != 1 else ''} ({size / 1e6:.1f} MB): "
            + " and ".join(parts))
    return {"removed": len(gone), "bytes": size, "chunks_from": chunks_from, "recording_from": recording_from,
            "text": text}


def nothing_removed(out: str | Path, events: Iterable[dict]) -> str | None:
    """Why ``run.keep`` removed nothing from a run's records, one line: no segment closed yet (the sizes they close
    at, from the ``records_retention`` event the run wrote at its start), or the closed ones not due yet; and what
    the records take.

    Parameters
    ----------
    out : str or Path
        The run's directory.
    events : iterable of dict
        Its events (:func:`read_events`).

    Returns
    -------
    str or None
        The line; None when the run had no ``run.keep`` (no ``records_retention`` event) or removed something
        (:func:`kept_span` says what).
    """
    from .simulation.trajectory_chunks import chunk_segments

    events = list(events)
    plans = [e for e in events if e.get("event") == "records_retention"]
    if not plans or any(e.get("event") == "records_removed" for e in events):
        return None
    out = Path(out)
    chunks = [p for _, p in chunk_segments(out)]
    recording = sorted(out.glob("run*.rrd"))
    size = sum(p.stat().st_size for p in chunks + recording if p.is_file())
    p = plans[-1]
    if len(chunks) > 1 or len(recording) > 1:
        why = "its closed segments were not due yet (" + p.get("text", "").removeprefix("run.keep: ") + ")"
    else:
        why = (f"no segment had closed (a row chunk segment closes past {p.get('chunk_mb', 0):.4g} MiB, a recording "
               f"segment past {p.get('recording_mb', 0):.4g} MiB: set run.keep.segment_mb for a short run)")
    return f"run.keep removed nothing: {why}; the records take {size / 1e6:.1f} MB"


def read_events(path: str | Path) -> tuple:
    """``events.jsonl`` as a tuple of dicts (a line torn by a crash is skipped).

    Parameters
    ----------
    path : str or Path
        The ``events.jsonl`` file.

    Returns
    -------
    tuple of dict
        One dict per line that parses as JSON, in file order.
    """
    out = []
    for line in Path(path).read_text(encoding="utf-8").splitlines():
        try:
            out.append(json.loads(line))
        except ValueError:  # a line torn by a crash (the recorder cuts them back; a copy may still hold one)
            continue
    return tuple(out)


_END_EVENTS = ("run_finished", "run_interrupted", "run_failed")


def end_event(events: Iterable[dict]) -> dict | None:
    """The event that ended the run (``run_finished``, ``run_interrupted`` or ``run_failed``), None if none.

    Parameters
    ----------
    events : iterable of dict
        A run's events (:func:`read_events`).

    Returns
    -------
    dict or None
        The last of the ending events; None if the run never ended (killed).

    Examples
    --------
    >>> end_event([{"event": "agent_lost"}, {"event": "run_finished", "event_times": 5}])
    {'event': 'run_finished', 'event_times': 5}
    """
    ends = [e for e in events if e.get("event") in _END_EVENTS]
    return ends[-1] if ends else None


def closing_line(end: dict) -> str:
    """One line of what a run did, from its end event (:func:`end_event`): how it ended, event times, wall time
    and rate (against the pace, and whether it was kept), the largest error at the end (or, without truth, the
    consensus disagreement), agents lost and rejoined, consensus messages that did not count.

    Parameters
    ----------
    end : dict
        The end event; one without ``event_times`` (an older splitspec's records) gives only how the run ended.

    Returns
    -------
    str
        ``"run finished: ..."`` and its parts separated by ``"; "``.

    Examples
    --------
    >>> closing_line({"event": "run_finished", "event_times": 50, "seconds": 2, "rounds_per_second": 25})
    'run finished: 50 event times in 2 s (25 per second); agents lost 0, rejoined 0; consensus messages lost 0'
    """
    how = {"run_finished": "run finished", "run_interrupted": "run interrupted", "run_failed": "run failed"}
    head = how.get(end.get("event"), str(end.get("event")))
    if end.get("reason") and end.get("event") == "run_finished" and end["reason"] != "steps":
        head += f" ({end['reason']})"
    if "event_times" not in end:  # records of an older splitspec
        return head
    first = (f"{end['event_times']} event times in {end.get('seconds', 0):g} s "
             f"({end.get('rounds_per_second', 0):g} per second")
    if end.get("pace"):
        late = end.get("late_event_times", 0)
        worst = end.get("max_lateness_ms", 0.0)
        first += (f", pace {end['pace']:g} kept" if end.get("pace_kept", True) else
                  f", pace {end['pace']:g} NOT kept") + (f": {late} late, up to {worst:g} ms" if late else "")
    parts = [first + ")"]
    if end.get("final_max_error") is not None:
        parts.append(f"largest error at the end {end['final_max_error']:.3g}")
    elif end.get("final_disagreement") is not None:
        parts.append(f"consensus disagreement at the end {end['final_disagreement']:.3g} (no truth)")
    parts.append(f"agents lost {end.get('agents_lost', 0)}, rejoined {end.get('agents_rejoined', 0)}")
    parts.append(f"consensus messages lost {end.get('messages_lost', 0)}")
    if end.get("takeovers"):
        n = end["takeovers"]
        parts.append(f"{n} orchestrator takeover{'s' * (n > 1)}")
    return f"{head}: " + "; ".join(parts)


def load_run(out: str | Path, *, start: float | None = None, end: float | None = None) -> RunRecord:
    """Read a run's records back: any ``splitspec run`` (or orchestrator) output directory.

    The rows come from ``trajectory.npz``, or from the append-only chunks (``chunks/``,
    :mod:`splitspec_core.simulation.trajectory_chunks`) of a run that went on until stopped, or when a time window
    is asked for: ``start <= t <= end`` (either may be None), reading only the chunks' segments it overlaps.
    Where a run has both, they hold the same rows (the chunks may hold a few more of a run that was killed).

    Parameters
    ----------
    out : str or Path
        The run's output directory.
    start : float, optional
        The window's first time (scenario units), read from the chunks; None: from the first row.
    end : float, optional
        The window's last time; None: to the last row.

    Returns
    -------
    RunRecord
        ``trajectory`` (the rows), ``events`` (events.jsonl), ``scenario`` (the scenario the run played, which
        :func:`splitspec_core.simulate` replays), ``summary`` and ``closing_line``.

    Raises
    ------
    ScenarioError
        One line naming what is missing (``OUT has no trajectory.npz or chunks/: not a run's output directory``).

    Examples
    --------
    >>> import splitspec_core as ss
    >>> rec = ss.load_run("out/demo")  # doctest: +SKIP
    >>> sim = ss.simulate(rec.scenario)  # doctest: +SKIP
    >>> float(abs(rec.trajectory.xhat - sim.xhat).max()) < 1e-9  # doctest: +SKIP
    True
    """
    from .simulation.trajectory_chunks import has_chunks, read_chunks

    out = Path(out)
    if not out.is_dir():
        raise ScenarioError(f"{out} is not a directory (a run's output directory holds trajectory.npz or chunks/, "
                            "events.jsonl and scenario.yaml)")
    npz = out / "trajectory.npz"
    if not npz.is_file() and not has_chunks(out):
        raise ScenarioError(f"{out} has no trajectory.npz or chunks/: not a run's output directory (or the run "
                            "never recorded a row)")
    for name in ("scenario.yaml", "events.jsonl"):
        if not (out / name).is_file():
            raise ScenarioError(f"{out} has no {name}: not a run's output directory (or the run never started)")
    windowed = start is not None or end is not None
    if has_chunks(out) and (windowed or not npz.is_file()):
        arrays = read_chunks(out, start=start, end=end)
        traj = Trajectory.from_arrays(arrays)
    else:
        traj = Trajectory.load(npz)
        if windowed:
            traj = traj.window(start, end)
    return RunRecord(out=out, scenario=load_scenario(out / "scenario.yaml"), trajectory=traj,
                     events=read_events(out / "events.jsonl"))


def _mapping(sc: Scenario | str | Path) -> dict:
    # system.file's arrays written in: the processes read the scenario from a temporary folder
    if isinstance(sc, (str, Path)):
        load_scenario(sc)  # the file's own checks first: a missing or bad file is one line
        return resolve_model_file(load_yaml(Path(sc).read_text(encoding="utf-8"), source=str(sc)), Path(sc).parent)
    origin = getattr(sc, ORIGIN, None)
    if origin is None:
        raise ScenarioError("this Scenario was not made by ss.scenario or ss.load_scenario (e.g. it was changed "
                            "with dataclasses.replace): give ss.run the keywords or the file instead")
    if isinstance(origin, Path):
        return resolve_model_file(load_yaml(origin.read_text(encoding="utf-8"), source=str(origin)), origin.parent)
    return resolve_model_file(origin, None)


def run(sc: Scenario | str | Path, *, out: str | Path, faults: Iterable | None = None, secure: bool = True,
        measurements: str | Path | None = None, round_timeout: float | None = None, wait: float | None = None,
        progress: bool = False, timeout: float | None = None) -> RunRecord:
    """Run the scenario as real processes over Zenoh on loopback (``splitspec run``) and read its records back.

    ``sc``: a scenario from :func:`splitspec_core.scenario` or :func:`splitspec_core.load_scenario`, or a
    scenario file.  ``faults``: the scenario's ``faults:`` replaced by these (the file's format, e.g.
    ``[{"at": 10, "kill": 3}, {"at": 20, "restart": 3}]``).  ``secure``, ``measurements``, ``round_timeout``,
    ``wait``: as the command's options.  ``progress``: let the command write its progress and summary to this
    process's terminal (else they are kept, and the last line is the error on failure).  ``timeout``: seconds
    before the run is interrupted (its records are still written); a run until stopped (a paced scenario without
    ``run.steps``) ends as finished then, or when stopped from outside (``splitspec stop``).  The result's
    :attr:`RunRecord.closing_line` and :attr:`RunRecord.summary` say what happened.

    Parameters
    ----------
    sc : Scenario, str or Path
        From :func:`splitspec_core.scenario` or :func:`splitspec_core.load_scenario` (not changed since), or a file.
    out : str or Path
        The run's output directory (created).
    faults : iterable of mapping, optional
        Replaces the scenario's ``faults:``.
    secure : bool
        Zenoh authentication and access control (``--secure``, the default); False: ``--insecure``.
    measurements : str or Path, optional
        A recorded measurements file (.npz or .csv) the plant plays instead of simulating (``--measurements``).
    round_timeout : float, optional
        Seconds before a silent agent is declared lost (``--round-timeout``; default: the command's, 10).
    wait : float, optional
        Seconds to wait for the other processes to start (``--wait``; default: the command's).
    progress : bool
        Show the command's progress and summary on this terminal (default: kept, quiet).
    timeout : float, optional
        Seconds before the run is interrupted as by Ctrl-C (its records are still written); None: no limit.

    Returns
    -------
    RunRecord
        :func:`load_run` of ``out``.

    Raises
    ------
    ScenarioError
        A scenario that cannot be handed to the processes (one line).
    RunError
        The run ended with a non-zero status (its one-line message; ``status`` the exit status).

    Examples
    --------
    >>> import splitspec_core as ss
    >>> sc = ss.load_scenario("examples/ring10.yaml")
    >>> rec = ss.run(sc, out="out/ring10", faults=[{"at": 10, "kill": 3}])  # doctest: +SKIP
    >>> [e["event"] for e in rec.events if e["event"] == "agent_lost"]  # doctest: +SKIP
    ['agent_lost']
    """
    data = dict(_mapping(sc))
    if faults is not None:
        data["faults"] = list(faults)
    out = Path(out)
    with tempfile.TemporaryDirectory(prefix="splitspec-run-") as tmp:
        path = Path(tmp) / "scenario.yaml"
        path.write_text(dump_yaml(plain(data)), encoding="utf-8")
        cmd = [sys.executable, "-m", "splitspec_orchestrator", "run", str(path), "--out", str(out),
               "--secure" if secure else "--insecure"]
        for flag, value in (("--measurements", measurements), ("--round-timeout", round_timeout),
                            ("--wait", wait)):
            if value is not None:
                cmd += [flag, str(value)]
        capture = None if progress else subprocess.PIPE
        proc = subprocess.Popen(cmd, stdout=capture, stderr=capture, text=True)
        try:
            stdout, stderr = proc.communicate(timeout=timeout)
        except subprocess.TimeoutExpired:
            proc.send_signal(signal.SIGINT)  # as Ctrl-C: the run writes its records and stops its processes
            stdout, stderr = proc.communicate()
        except BaseException:  # KeyboardInterrupt in a notebook: stop the run the same way, then re-raise
            proc.send_signal(signal.SIGINT)
            proc.communicate()
            raise
    if proc.returncode != 0:
        lines = [ln for ln in (stderr or "").splitlines() if ln.strip()]
        raise RunError(lines[-1] if lines else f"splitspec run exited with status {proc.returncode}",
                       proc.returncode)
    return load_run(out)


def _in_jupyter() -> bool:
    """Running in a Jupyter kernel (IPython with a kernel attached), where a widget can be displayed."""
    shell = sys.modules.get("IPython")
    ip = shell.get_ipython() if shell is not None and hasattr(shell, "get_ipython") else None
    return ip is not None and getattr(ip, "kernel", None) is not None


def view(out: str | Path, *, web: bool = False, port: int | None = None, inline: bool | None = None):
    """Open ``out/run.rrd``, the run's Rerun recording (with ``run-0001.rrd`` ..., the segments a run until stopped
    rolled it into: one recording).

    ``inline=True`` (the default inside a Jupyter kernel where ``rerun-notebook`` is installed): Rerun's notebook
    widget, returned (display it by returning it from the cell). Otherwise ``splitspec view OUT``: the native
    Rerun viewer with a display, else (or with ``web``, or a ``port``) the web viewer served on 127.0.0.1, its
    URL printed; returns the viewer's process (``.send_signal(signal.SIGINT)`` stops it as Ctrl-C does).

    Parameters
    ----------
    out : str or Path
        The run's output directory.
    web : bool
        The web viewer even with a display.
    port : int, optional
        The web viewer's port (default: a free one).
    inline : bool, optional
        Rerun's notebook widget (default inside Jupyter when ``rerun-notebook`` is installed).

    Returns
    -------
    subprocess.Popen or the notebook widget
        The viewer.

    Raises
    ------
    ScenarioError
        ``out`` has no ``run.rrd``; ``inline=True`` without ``rerun-notebook`` installed.

    Examples
    --------
    >>> import splitspec_core as ss
    >>> viewer = ss.view("out/demo", web=True)  # doctest: +SKIP
    """
    out = Path(out)
    if not (out / "run.rrd").is_file() and not any(out.glob("run-[0-9][0-9][0-9][0-9]*.rrd")):
        raise ScenarioError(f"{out} has no run.rrd: not a run's output directory")
    if inline is None:
        inline = not web and port is None and _in_jupyter() and importlib.util.find_spec("rerun_notebook") is not None
    if inline:
        # The widget lives with the rest of Rerun in the orchestrator package (this layer never imports Rerun): its
        # one module this layer may import ("widget", docs/explanation/architecture.md), only when asked for.
        from splitspec_orchestrator.viewer.notebook_view import notebook_viewer

        return notebook_viewer(out)
    cmd = [sys.executable, "-m", "splitspec_orchestrator", "view", str(out)] + (["--web"] if web else [])
    return subprocess.Popen(cmd + (["--port", str(port)] if port is not None else []))
