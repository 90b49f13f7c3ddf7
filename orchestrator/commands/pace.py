"""``splitspec pace``: can this machine keep a scenario's pace?  Measured on a real run, before a deployment.

A paced run (``run.pace: P``) gives every event time ``1000 / P`` ms of wall clock.  Whether the round (the
ticks, the measurements, the ``q`` consensus exchanges of every agent, the records) fits in that period
depends on the scenario (``m``, ``n``, ``q``, the graph, the network's impairments) and on this machine and
its load, so it is measured rather than estimated: the scenario runs as real processes, exactly as
``splitspec run`` starts them (orchestrator with its embedded router, plant, one process per agent, secure),
unpaced, for about ``--seconds`` of rounds, and is then stopped as Ctrl-C stops a run.  What runs is a
temporary copy of the scenario with

* ``faults: []`` (a kill or a freeze is not the steady state a pace has to hold),
* ``run.pace`` removed and ``run.steps`` generous (:data:`PROBE_STEPS`: the run is stopped long before;
  the orchestrator's memory does not grow with ``steps``),
* ``run.keep`` removed: a paced scenario that runs until stopped is what ``pace`` is for, but the measuring run is
  a run of ``run.steps``, stopped after ``--seconds``, and its records stay whole (retention removes closed
  segments between rounds, far larger than a few seconds of records: no part of a round's cost); the disk line
  then says what ``run.keep.hours`` and ``run.keep.gigabytes`` keep on hand at the measured growth,
* ``system.file`` written in (the copy lives in another folder),
* ``sources:`` removed: the simulated plant stands in for live sensors (they need a pace and a publisher);

the network's impairments (loss, delay, deadline) are kept: they are part of a round's cost.

The measure is the wall time per event time in steady state: the differences of the rows' arrival times
(``chunks/rows-*.arrows``, column ``wall``), without the first :data:`WARMUP_FRACTION` of them (at least
:data:`WARMUP_ROWS`).  A run whose records have no row chunks gives only the mean over its rounds
(``run_finished``'s ``seconds / rounds``, or from ``run_started`` to ``run_interrupted`` over the rows of
``trajectory.npz``); the rule then applies to the mean, and the verdict says so.

The rule: pace P is feasible on this machine when the 90th percentile of the measured ms per event time is
below :data:`MARGIN` (90 %) of a period, ``0.9 * 1000 / P`` ms.  The margin leaves room for the rounds
slower than the 90th percentile and for a load that changes; a pace close to it is worth measuring again
under the load of the deployment.  Exit status: 0 feasible (or no pace to check: the capacity only),
1 not feasible (or the measuring run failed: the error line says which), 2 bad input.
"""

from __future__ import annotations

import argparse
import json
import math
import signal
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from splitspec_core.errors import SplitspecError

from . import out_dir

#: feasible when the p90 ms per event time is below this fraction of a period
MARGIN = 0.9
#: the measuring run's run.steps: far more than any machine runs in --seconds (it is stopped first)
PROBE_STEPS = 10_000_000
#: the first rows left out of the steady state: this fraction of the intervals, and at least WARMUP_ROWS
WARMUP_FRACTION = 0.05
WARMUP_ROWS = 3
#: seconds the stopped run gets to write its records and stop its processes
STOP_SECONDS = 60.0
#: the fewest rows the disk's growth is measured over, and how long past ``--seconds`` the run may go on for them
DISK_MIN_ROWS = 10
DISK_EXTRA_SECONDS = 3.0
EXIT_NOT_FEASIBLE = 1


@dataclass(frozen=True)
class PaceMeasurement:
    """Wall time per event time of a real, unpaced run in steady state.

    ``mean_ms``: the mean ms per event time (its inverse is the capacity); ``p90_ms``, ``median_ms``: from the
    per-row wall times, None when the run recorded none (then the rule applies to the mean);
    ``event_times``: how many event times the figures cover.
    """

    mean_ms: float
    event_times: int
    p90_ms: float | None = None
    median_ms: float | None = None

    @property
    def capacity(self) -> float:
        """Event times per second this machine sustains (``1000 / mean_ms``)."""
        return 1000.0 / self.mean_ms

    @property
    def judged_ms(self) -> float:
        """What the rule compares with a period: the p90, or the mean when there is no p90."""
        return self.mean_ms if self.p90_ms is None else self.p90_ms

    @property
    def highest_pace(self) -> float:
        """The highest pace the rule accepts: ``MARGIN * 1000 / judged_ms`` (strictly below it, to be exact)."""
        return MARGIN * 1000.0 / self.judged_ms


def measure(out: str | Path) -> PaceMeasurement:
    """The steady-state ms per event time of the run recorded in ``out``.

    From the per-row wall times of ``out/chunks`` when the run wrote them (the differences between
    consecutive event times' rows, the warm-up left out), else the mean over the run's rounds.

    Raises
    ------
    RuntimeError
        The records hold no round to measure.
    """
    out = Path(out)
    rows = _row_intervals(out)
    if rows is not None:
        return PaceMeasurement(mean_ms=float(rows.mean()), event_times=int(rows.size),
                               p90_ms=float(np.percentile(rows, 90)), median_ms=float(np.median(rows)))
    seconds, rounds = _run_mean(out)
    return PaceMeasurement(mean_ms=1000.0 * seconds / rounds, event_times=rounds)


def _row_intervals(out: Path) -> np.ndarray | None:
    """ms between consecutive event times' rows after the warm-up, or None without (enough) row chunks."""
    from splitspec_core.simulation.trajectory_chunks import has_chunks, read_chunks

    if not has_chunks(out):
        return None
    data = read_chunks(out)
    if data is None or len(data["tau"]) < 3:
        return None
    tau, wall = np.asarray(data["tau"]), np.asarray(data["wall"], dtype=np.int64)
    # rows of consecutive event times, both with a recorded arrival (row tau - 1 to row tau: round tau's cost)
    ok = (np.diff(tau) == 1) & (wall[1:] > 0) & (wall[:-1] > 0)
    ms = (np.diff(wall) / 1e6)[ok]
    skip = max(WARMUP_ROWS, int(math.ceil(WARMUP_FRACTION * ms.size)))
    if ms.size - skip < 2:
        return None
    return ms[skip:]


def _run_events(out: Path) -> dict:
    """The first event of each name in ``out/events.jsonl`` (a torn line, as the run writes it, is skipped)."""
    found: dict = {}
    try:
        text = (out / "events.jsonl").read_text(encoding="utf-8")
    except OSError:
        return found
    for line in text.splitlines():
        try:
            e = json.loads(line)
        except ValueError:
            continue
        if isinstance(e, dict) and "event" in e:
            found.setdefault(e["event"], e)
    return found


def _run_mean(out: Path) -> tuple[float, int]:
    """``(seconds, rounds)`` of the run's rounds: ``run_finished``'s, or from ``run_started`` to
    ``run_interrupted`` over the event times of ``trajectory.npz`` (its first row is the start, not a round)."""
    ev = _run_events(out)
    fin = ev.get("run_finished")
    if fin is not None and fin.get("rounds") and fin.get("seconds"):
        return float(fin["seconds"]), int(fin["rounds"])
    started, stopped = ev.get("run_started"), ev.get("run_interrupted")
    rounds = 0
    try:
        with np.load(out / "trajectory.npz") as z:
            rounds = int(z["t"].shape[0]) - 1
    except (OSError, ValueError, KeyError):
        pass
    if started is None or stopped is None or rounds < 1 or not stopped["wall"] > started["wall"]:
        raise RuntimeError(f"the measuring run in {out} recorded no round to measure (no run_finished, or no "
                             "run_started and run_interrupted with rows in trajectory.npz)")
    return float(stopped["wall"] - started["wall"]), rounds


def _num(x: float) -> str:
    """A measured figure for the verdict: three significant digits, no exponent."""
    return f"{x:.0f}" if abs(x) >= 100 else f"{x:.3g}"


def verdict(meas: PaceMeasurement, pace: float | None, *, about: str = "") -> tuple[bool, str]:
    """``(feasible, the one verdict line)`` of a measurement against ``pace`` (None: the capacity only, feasible).

    ``about``: appended after ``"; "`` (the scenario's size: ``m = 10, n = 8, q = 4``).
    """
    at = "at p90" if meas.p90_ms is not None else "by the mean"
    detail = (f"p90 {_num(meas.p90_ms)} ms over {meas.event_times} event times" if meas.p90_ms is not None
              else f"mean over {meas.event_times} event times: the run recorded no per-row wall times, the rule "
                   "applies to the mean")
    measured = f"{_num(meas.mean_ms)} ms per event time measured"
    capacity = f"capacity about {_num(meas.capacity)} event times per second"
    highest = f"highest pace with the {MARGIN * 100:.0f} % margin about {_num(meas.highest_pace)}"
    tail = f"; {about}" if about else ""
    if pace is None:
        return True, (f"capacity on this machine: {measured} ({detail}; {capacity}; {highest}; no pace to check: "
                      f"give --pace P or run.pace){tail}")
    period = 1000.0 / pace
    used = 100.0 * meas.judged_ms / period
    feasible = meas.judged_ms < MARGIN * period
    share = f"a period at pace {pace:g} is {_num(period)} ms: {used:.0f} % used {at}"
    if feasible:
        return True, f"pace {pace:g}: feasible on this machine: {measured} ({detail}; {capacity}; {share}){tail}"
    below = " < " + f"{pace:g}" if meas.capacity < pace else ""
    return False, (f"pace {pace:g}: NOT feasible on this machine: {measured} ({detail}; {capacity}{below}; {share}, "
                   f"more than {MARGIN * 100:.0f} %; {highest}){tail}")


def probe_mapping(path: Path) -> tuple[dict, bool]:
    """The measuring run's scenario (see the module docstring) as a mapping, and whether live sensors were
    replaced by the plant."""
    from splitspec_core.scenarios.files import resolve_model_file
    from splitspec_core.scenarios.load import load_yaml, read_scenario_text

    data = dict(resolve_model_file(load_yaml(read_scenario_text(path), source=str(path)), path.parent))
    run = dict(data.get("run") or {})
    run.pop("pace", None)
    run.pop("keep", None)  # a run of run.steps has no retention (module docstring)
    run["steps"] = PROBE_STEPS
    data["run"] = run
    data["faults"] = []
    sensors = data.pop("sources", None) is not None
    return data, sensors


def _describe(design) -> str:
    sc = design.scenario
    if design.two_rate:
        gain = f"q = {design.q}" + ("" if sc.time == "discrete" else " per run.dt")
    elif design.g_mode == "adaptive":
        gain = "g adaptive"
    else:
        gain = f"g = {design.g:.3g}"
    return f"m = {sc.m}, n = {sc.n}, {gain}"


@dataclass(frozen=True)
class DiskRate:
    """What the records grow by per event time, measured between the middle and the end of the measuring run (the
    start's static data left out): ``chunk_bytes`` (``chunks/``, every row) and ``rrd_bytes`` (``run.rrd``, with the
    state panels every ``every`` event times), over ``rows`` event times."""

    chunk_bytes: float
    rrd_bytes: float
    rows: int
    every: int

    def line(self, pace: float, keep_hours: float | None = None, keep_gigabytes: float | None = None,
             segments: tuple | None = None) -> str:
        """One line: the disk per hour and per day at ``pace``, what ``run.keep.hours`` and ``run.keep.gigabytes``
        hold on hand and, given ``segments`` (the bytes past which a row chunk segment and a recording segment close:
        :class:`~splitspec_orchestrator.records.files.Continuous`), when the first of each closes: nothing is removed
        before (a newcomer's 3-minute run with the default 64 and 256 MiB removed nothing and could not tell why)."""
        hour = (self.chunk_bytes + self.rrd_bytes) * pace * 3600
        text = (f"disk: about {hour / 1e9:.3g} GB per hour at pace {pace:g} ({self.chunk_bytes * pace * 3.6e-3:.3g} MB/h "
                f"of row chunks, {self.rrd_bytes * pace * 3.6e-3:.3g} MB/h of Rerun recording with the state panels "
                f"every {self.every} event time{'s' if self.every != 1 else ''}; measured over {self.rows} event times); "
                f"{24 * hour / 1e9:.3g} GB a day")
        if keep_hours is not None:
            text += (f"; run.keep.hours {keep_hours:g}: about {keep_hours * hour / 1e9:.3g} GB on hand plus the segment "
                     "being written of each kind")
        if keep_gigabytes is not None and hour > 0:
            text += (f"; run.keep.gigabytes {keep_gigabytes:g}: reached after about {keep_gigabytes * 1e9 / hour:.3g} h, "
                     "then the oldest closed segments go")
        if segments is not None and (keep_hours is not None or keep_gigabytes is not None):
            closes = [f"a {what} segment closes about every {_duration(size / (rate * pace))} ({size / (1 << 20):g} MiB)"
                      for what, size, rate in (("row chunk", segments[0], self.chunk_bytes),
                                               ("recording", segments[1], self.rrd_bytes)) if rate > 0 and pace > 0]
            if closes:
                text += "; " + " and ".join(closes) + " (run.keep.segment_mb): nothing is removed before one closes"
        return text


def _duration(seconds: float) -> str:
    """``seconds`` as a person says it: ``40 s``, ``12 min``, ``3.2 h``, ``5.1 days``."""
    if seconds < 90:
        return f"{seconds:.2g} s"
    if seconds < 5400:
        return f"{seconds / 60:.2g} min"
    return f"{seconds / 3600:.2g} h" if seconds < 172800 else f"{seconds / 86400:.2g} days"


def record_sizes(out: Path) -> tuple[int, int, int] | None:
    """``(rows, chunk bytes, rrd bytes)`` of a run's records as they stand; None when a flush came while they were
    read (the rows and the bytes would not be of the same records: a run's first flush caught between reading its
    rows and their size once made a window of rows with no byte in it)."""
    from splitspec_core.simulation.trajectory_chunks import chunk_segments, read_chunks

    from ..viewer.rrd_file import rrd_segments

    def size(p: Path) -> int:
        try:
            return p.stat().st_size
        except OSError:
            return 0

    def chunk_bytes() -> int:
        return sum(size(p) for _, p in chunk_segments(out))

    before = chunk_bytes()
    try:
        rows = read_chunks(out)
    except Exception:  # noqa: BLE001 - a segment caught mid-write: no sample this time
        return None
    if chunk_bytes() != before:
        return None
    return (0 if rows is None else len(rows["tau"]), before, sum(size(p) for p in rrd_segments(out / "run.rrd")))


def run_probe(scenario: Path, out: Path, *, seconds: float, log_path: Path, every: int = 1) -> DiskRate | None:
    """Run ``splitspec run SCENARIO --out OUT`` (its output to ``log_path``) and stop it as Ctrl-C does once it
    has run its rounds for ``seconds`` (counted from its ``run_started`` event, so start-up is not counted; up to
    :data:`DISK_EXTRA_SECONDS` longer while its records hold fewer than :data:`DISK_MIN_ROWS` rows since the middle).
    Returns the records' growth per event time between the middle and the end (:class:`DiskRate`; None if too
    few rows came), the recording's state panels every ``every`` event times.

    Raises
    ------
    RuntimeError
        The run failed (its own error line), or did not stop within :data:`STOP_SECONDS` of the signal.
    """
    from ..launcher import cli_command
    from ..registry import new_run_id

    cmd = cli_command("run", scenario, "--out", out, "--run-id", new_run_id())
    with open(log_path, "wb") as log:
        proc = subprocess.Popen(cmd, stdin=subprocess.DEVNULL, stdout=log, stderr=subprocess.STDOUT)
    mid = end = None
    try:
        started = None
        while proc.poll() is None:
            now = time.monotonic()
            if started is None and "run_started" in _run_events(out):
                started = now
            if started is not None and mid is None and now - started >= seconds / 2:
                mid = record_sizes(out)  # (None: a flush came while it was read; sampled again next time)
            if mid is not None and now - started >= seconds:
                end = record_sizes(out)
                # the records grow a flush at a time (the recorder's 1 s, the recording's own): run on, up to
                # DISK_EXTRA_SECONDS, until the window from the middle holds DISK_MIN_ROWS rows and a flush of each
                # kind, so a short run still measures its disk
                grown = end is not None and end[0] - mid[0] >= DISK_MIN_ROWS and end[1] > mid[1] and end[2] > mid[2]
                if grown or now - started >= seconds + DISK_EXTRA_SECONDS:
                    proc.send_signal(signal.SIGINT)  # the run writes its records and stops its processes
                    break
                time.sleep(0.2)
            time.sleep(0.05)
        try:
            code = proc.wait(timeout=STOP_SECONDS)
        except subprocess.TimeoutExpired:
            raise RuntimeError(f"the measuring run did not stop within {STOP_SECONDS:g} s of Ctrl-C") from None
    finally:
        if proc.poll() is None:  # interrupted ourselves, or the run hangs: Ctrl-C first, then kill it
            proc.send_signal(signal.SIGINT)
            try:
                proc.wait(timeout=STOP_SECONDS)
            except subprocess.TimeoutExpired:
                proc.kill()  # its orchestrator and the rest die with it (PR_SET_PDEATHSIG)
                proc.wait()
    if code not in (0, 130):
        raise RuntimeError(_failure(log_path, code))
    if mid is None or end is None or end[0] - mid[0] < DISK_MIN_ROWS:
        return None
    rows = end[0] - mid[0]
    return DiskRate((end[1] - mid[1]) / rows, (end[2] - mid[2]) / rows, rows, every)


def _failure(log_path: Path, code: int) -> str:
    """The measuring run's own error line (else its last line), for a one-line error."""
    try:
        lines = [ln.strip() for ln in log_path.read_text(errors="replace").splitlines() if ln.strip()]
    except OSError:
        lines = []
    errors = [ln for ln in lines if ln.startswith("splitspec: error:")]
    said = (errors or lines or [""])[-1].removeprefix("splitspec: error: ")
    return f"the measuring run failed (exit status {code})" + (f": {said}" if said else "")


def _fresh_out(path) -> Path:
    """``--out``: created if missing, and holding no run's records yet (the measure reads what it finds there)."""
    if Path(path).is_dir():
        old = [name for name in ("events.jsonl", "trajectory.npz", "chunks") if (Path(path) / name).exists()]
        if old:
            raise SplitspecError(f"--out {path} already holds a run's records ({old[0]}): give a new or empty "
                                 "directory")
    return out_dir(path)


def cmd_pace(args: argparse.Namespace) -> int:
    """``splitspec pace SCENARIO [--pace P] [--seconds S] [--out DIR]``: measure, print one verdict line.

    Returns 0 when the pace is feasible (or none is given), :data:`EXIT_NOT_FEASIBLE` when it is not;
    a measuring run that fails is one error line and exit status 1.
    """
    from splitspec_core.scenarios.checks import plain
    from splitspec_core.scenarios.load import dump_yaml, load_scenario
    from splitspec_core.synthesis.design_cache import cached_design as design

    path = Path(args.scenario)
    sc = load_scenario(path)  # the file as given: its own errors first, one line
    pace = args.pace if args.pace is not None else sc.run.pace
    data, sensors = probe_mapping(path)
    # the recording as the deployment would thin it: a run until stopped at this pace (run.record_every's default)
    from splitspec_core.scenarios.specs import RunSpec

    every = sc.run.record_every or RunSpec(pace=pace, until_stopped=sc.run.until_stopped or pace is not None
                                            and sc.run.steps == RunSpec.steps).recorded_every
    data.setdefault("run", {})["record_every"] = every
    keep = _fresh_out(args.out) if args.out else None
    with tempfile.TemporaryDirectory(prefix="splitspec-pace-") as tmp:
        probe = Path(tmp) / "scenario.yaml"
        probe.write_text(dump_yaml(plain(data)), encoding="utf-8")
        des = design(load_scenario(probe))  # fail fast, with one line, before any process starts
        out = keep if keep is not None else Path(tmp) / "run"
        print(f"splitspec: pace: running {sc.name} unpaced for {args.seconds:g} s of rounds ({sc.m} agents, no "
              f"faults){' in ' + str(out) if keep is not None else ''}", file=sys.stderr, flush=True)
        try:
            disk = run_probe(probe, out, seconds=args.seconds, log_path=Path(tmp) / "run.log", every=every)
            meas = measure(out)
        except RuntimeError as exc:  # the run's failure, not the input's: exit status 1
            print(f"splitspec: error: {exc}", file=sys.stderr)
            return EXIT_NOT_FEASIBLE
    about = _describe(des) + ("; the simulated plant stood in for the live sensors" if sensors else "")
    feasible, line = verdict(meas, pace, about=about)
    print(line)
    if disk is not None and feasible:  # (at a pace that cannot be kept the figure would be the machine's, not the run's)
        from ..records.files import Continuous

        sizes = Continuous.from_env(sc.run)
        print(disk.line(pace if pace is not None else meas.capacity, sc.run.keep_hours, sc.run.keep_gigabytes,
                        segments=(sizes.chunk_bytes, sizes.rrd_bytes)))
    return 0 if feasible else EXIT_NOT_FEASIBLE
