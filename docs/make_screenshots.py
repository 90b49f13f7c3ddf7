"""Screenshots of a run in Rerun's web viewer, taken in a real (headless) Chromium.

Runs ``examples/ring10_faults_switching.yaml`` (or takes a run's output directory with
``--run-dir``), serves ``run.rrd`` with the web viewer exactly as
``splitspec view`` does, opens it in headless Chromium through Playwright, waits
until the viewer has the whole recording, then moves the time cursor to each
chosen event time and saves a screenshot to ``docs/figures/``:

    view_ring10_faults_switching_kill.png     after agent 3 is killed (10) and agent 5 hangs (20)
    view_ring10_faults_switching_rejoin.png   after the restarts of 3 and 5 (30, 35)
    view_ring10_faults_switching_switch.png   on the other graph (switch at 45, back at 52)
    view_ring10_faults_switching_end.png      the end of the run (60)

With ``--network``, instead, the two screenshots of a network that misbehaves, in ``docs/``:

    lossy_ring.png   examples/ring10_lossy.yaml at event time 20, the ``rounds`` tab in front:
                     the messages that did not count per event time (``round lost``), the arcs
                     that lost one in event time 20 dashed red, their count under the graph
    partition.png    examples/ring10_partition.yaml at event time 30: the cut arcs dashed purple,
                     the partition named above the graph, its mark (5) and the heal's (35) on the
                     log error plot

With ``--measured``, the screenshot of a run on measurements without the truth, in ``docs/``:

    measured.png     examples/ring10_noise.yaml run on its own simulated measurements with the truth
                     columns removed and 10 % of agent 3's measurements blanked (``run --measurements``),
                     at its end (200): the reference tab the default blueprint opens on for such a run,
                     log10 residuals, disagreement and distance to the centralized Kalman filter

The default blueprint opens on the log errors (on the reference tab for a run on measurements); for a screenshot of another tab the viewer is
given a copy of ``run.rrd`` whose default blueprint is the same one opened on that tab
(``blueprint.default_blueprint(active_tab=...)``), rather than a click on the canvas.

A PNG larger than ``--max-kb`` is saved again with an adaptive palette of 256 colours (the
viewer's flat colours survive it; the file shrinks about threefold).

Setup, once (no browser download: Debian's chromium is used):

    apt-get install chromium
    .venv/bin/python -m pip install -e '.[screenshots]'     # playwright
    .venv/bin/python docs/make_screenshots.py
    .venv/bin/python docs/make_screenshots.py --network      # docs/lossy_ring.png, docs/partition.png
    .venv/bin/python docs/make_screenshots.py --measured     # docs/measured.png

How the viewer is driven. Readiness and the time cursor go through the page's
own viewer handle, ``window._handle`` (the ``WebHandle`` the served
``index.html`` keeps): ``viewer_state()`` returns the Viewer Control API's
``GetViewerStateResponse`` (protobuf: open recordings, their timelines with
time ranges, the time cursor), and ``viewer_control(bytes)`` performs one
``ViewerControlRequest``, here ``set_time_cursor`` on the ``event`` timeline
(which also pauses playback). The few fields needed are encoded and decoded by
hand below (rerun 0.41; that API carries no compatibility guarantee, so every
step is checked: the recording must reach the run's last event time, and the
cursor must read back as the time asked for, else the script stops with a
message saying which). The Python ``ViewerClient`` cannot do this: the
``rerun --web-viewer`` process is only a message proxy and answers its
requests with ``Unimplemented``. The viewer renders with a software rasterizer
in headless Chromium: 20 to 60 s until the recording is on screen, and 9 to
17 s per screenshot, on two shared cores.
"""

from __future__ import annotations

import argparse
import io
import json
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from splitspec_orchestrator.view import start_web_viewer, stop_viewer  # noqa: E402  (the same server as `splitspec view`)

CHROMIUM = "/usr/bin/chromium"
CHROMIUM_ARGS = ["--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                 "--disable-background-networking", "--disable-component-update", "--disable-sync"]
TIMELINE = "event"
DEFAULT_SCENARIO = ROOT / "examples" / "ring10_faults_switching.yaml"
# kill 3 at 10, arc 1->6 dropped at 15, freeze 5 at 20, restart 3 at 30 and 5 at 35, arc back at 40,
# graph ring -> ring2 at 45 and back at 52
DEFAULT_TIMES = {"kill": 24, "rejoin": 38, "switch": 48, "end": 60}
# --network: (scenario, {screenshot name: event time}, tab in front or None), written to docs/<name>.png
NETWORK_SHOTS = [(ROOT / "examples" / "ring10_lossy.yaml", {"lossy_ring": 20}, "rounds"),
                 (ROOT / "examples" / "ring10_partition.yaml", {"partition": 30}, None)]


MEASURED_SCENARIO = ROOT / "examples" / "ring10_noise.yaml"
MEASURED_BLANKED = (3, 0.1, 3)  # agent, share of its rows without a measurement, seed of their choice


def measured_run(run_dir: Path) -> Path:
    """``MEASURED_SCENARIO`` run on its own simulated measurements without the truth, into ``run_dir``."""
    import numpy as np

    from splitspec_core.scenarios.measurements import load_measurements, write_measurements
    from splitspec_core.scenarios.load import load_scenario

    work = run_dir.parent / f"{run_dir.name}-files"
    work.mkdir(parents=True, exist_ok=True)
    subprocess.run([sys.executable, "-m", "splitspec_orchestrator", "simulate", str(MEASURED_SCENARIO), "--out",
                    str(work / "sim"), "--no-plots", "--write-measurements", str(work / "full.npz")], cwd=ROOT,
                   check=True, stdout=subprocess.DEVNULL)
    sc = load_scenario(MEASURED_SCENARIO)
    full = load_measurements(work / "full.npz", sc)
    agent, share, seed = MEASURED_BLANKED
    missing = full.missing.copy()
    T = len(full.t)
    missing[np.random.default_rng(seed).choice(T, int(share * T), replace=False), list(sc.agent_ids).index(agent)] = True
    write_measurements(work / "notruth.csv", t=full.t, y=full.y, agent_ids=sc.agent_ids,
                       sizes=[np.shape(C)[0] for C in sc.system.Cs], missing=missing)
    subprocess.run([sys.executable, "-m", "splitspec_orchestrator", "run", str(MEASURED_SCENARIO), "--out",
                    str(run_dir), "--measurements", str(work / "notruth.csv")], cwd=ROOT, check=True,
                   stdout=subprocess.DEVNULL)
    return run_dir


class ScreenshotError(RuntimeError):
    """The viewer did not get where it was asked to within its time: the message says where it stopped."""


# --- the few protobuf fields of the Viewer Control API that are needed (wire format by hand) --------------

def _varint(data: bytes, i: int) -> tuple[int, int]:
    value = shift = 0
    while True:
        byte = data[i]
        i += 1
        value |= (byte & 0x7F) << shift
        shift += 7
        if byte < 0x80:
            return value, i


def _fields(data: bytes) -> list:
    """Top-level ``(field number, value)`` pairs: ints for varints, bytes for length-delimited fields."""
    out, i = [], 0
    while i < len(data):
        key, i = _varint(data, i)
        number, wire = key >> 3, key & 7
        if wire == 0:
            value, i = _varint(data, i)
        elif wire == 2:
            length, i = _varint(data, i)
            value, i = bytes(data[i:i + length]), i + length
        elif wire == 1:
            value, i = int.from_bytes(data[i:i + 8], "little"), i + 8
        elif wire == 5:
            value, i = int.from_bytes(data[i:i + 4], "little"), i + 4
        else:
            raise ScreenshotError(f"unexpected protobuf wire type {wire} in the viewer's state")
        out.append((number, value))
    return out


def _get(data: bytes, number: int, default=None):
    return next((v for n, v in _fields(data) if n == number), default)


def _encode_varint(value: int) -> bytes:
    value &= (1 << 64) - 1
    out = bytearray()
    while True:
        byte, value = value & 0x7F, value >> 7
        out.append(byte | (0x80 if value else 0))
        if not value:
            return bytes(out)


def _field(number: int, value) -> bytes:
    if isinstance(value, int):
        return _encode_varint(number << 3) + _encode_varint(value)
    value = value.encode() if isinstance(value, str) else value
    return _encode_varint(number << 3 | 2) + _encode_varint(len(value)) + value


PAUSED = 1  # play state: 1 paused, 2 playing, 3 following (rerun 0.41)


def set_time_cursor_request(timeline: str, sequence: int) -> bytes:
    """``ViewerControlRequest{set_time_cursor(6): {timeline(2): {name(1)}, time(3): {sequence(1)}, play_state(5)}}``.

    Without ``play_state = PAUSED`` the viewer plays on from the new time (found by trying: the cursor
    moved on by about six event times a second while a screenshot was taken).
    """
    return _field(6, _field(2, _field(1, timeline)) + _field(3, _field(1, sequence)) + _field(5, PAUSED))


@dataclass(frozen=True)
class RecordingState:
    """What the viewer has of the active recording: the timeline's last time, and where the cursor is."""

    store_id: str | None
    timelines: dict  # name -> (start, end), or None while the timeline has no data
    cursor_timeline: str | None
    cursor: int | None
    play_state: int | None


def recording_state(state: bytes) -> RecordingState:
    """Decode ``GetViewerStateResponse``: active_store_id (2), recordings (3) with store_id (1),
    timelines (2: timeline {name}, time_type, time_range {start, end}), current_time (3) and play state (5)."""
    active = _get(state, 2)
    active = active.decode() if active is not None else None
    for number, rec in _fields(state):
        if number != 3 or (active is not None and _get(rec, 1, b"").decode() != active):
            continue
        timelines = {}
        for n, tl in _fields(rec):
            if n == 2:
                name = _get(_get(tl, 1, b""), 1, b"").decode()
                rng = _get(tl, 3)
                timelines[name] = None if rng is None else (_get(rng, 1, 0), _get(rng, 2, 0))
        cursor = _get(rec, 3)
        cursor_name = None if cursor is None else _get(_get(cursor, 1, b""), 1, b"").decode()
        cursor_time = None if cursor is None or _get(cursor, 3) is None else _get(_get(cursor, 3), 1, 0)
        return RecordingState(active, timelines, cursor_name, cursor_time, _get(rec, 5))
    return RecordingState(active, {}, None, None, None)


# --- the page -------------------------------------------------------------------------------------------

def _state(page) -> RecordingState | None:
    data = page.evaluate("window._handle ? Array.from(window._handle.viewer_state()) : null")
    return None if data is None else recording_state(bytes(data))


def _poll(what: str, check, *, timeout: float, interval: float = 1.0, last=lambda: ""):
    deadline = time.monotonic() + timeout
    while True:
        result = check()
        if result:
            return result
        if time.monotonic() > deadline:
            raise ScreenshotError(f"timed out after {timeout:g} s waiting for {what}; last seen: {last()}")
        time.sleep(interval)


def _painted(page) -> bool:
    """The canvas shows something: the screenshot has more than a handful of colours (not blank, not a spinner)."""
    from PIL import Image

    image = Image.open(io.BytesIO(page.screenshot())).convert("RGB").resize((160, 100))
    return len(image.getcolors(maxcolors=160 * 100) or ()) > 50


def last_event_time(run_dir: Path) -> int:
    """The run's last event time, from ``recording_closed`` (or the last record) in events.jsonl."""
    lines = [json.loads(line) for line in (run_dir / "events.jsonl").read_text().splitlines() if line.strip()]
    closed = [e for e in lines if e.get("event") == "recording_closed"]
    return int(round((closed or lines)[-1]["t"]))


def recording_info(rrd: Path) -> dict:
    """The recording's ``splitspec`` property (time_mode, n, envelope, gains, ...), as the recorder wrote it, and
    ``measurements``: None, or for a run on measurements ``{"truth": bool}`` (its ``measurements`` property)."""
    from rerun.chunk import RrdReader

    def values(chunk) -> dict:
        batch = chunk.to_record_batch()
        out = {}
        for name in batch.schema.names:
            value = batch.column(name).to_pylist()[0]
            out[name.rpartition(":")[2]] = value[0] if isinstance(value, list) and len(value) == 1 else value
        return out

    found: dict = {}
    for chunk in RrdReader(rrd).stream():
        if chunk.entity_path in ("/__properties/splitspec", "/__properties/measurements"):
            found[chunk.entity_path.rpartition("/")[2]] = values(chunk)
    if "splitspec" not in found:
        raise ScreenshotError(f"{rrd} has no splitspec property: not a recording of `splitspec run`")
    return {**found["splitspec"], "measurements": found.get("measurements")}


def with_tab(run_dir: Path, tab: str, dest: Path) -> Path:
    """A copy of ``run_dir``'s ``run.rrd`` in ``dest`` whose default blueprint opens on ``tab``; events.jsonl beside it."""
    import shutil

    from splitspec_orchestrator.viewer.blueprint import default_blueprint
    from splitspec_orchestrator.viewer.rrd_file import rewrite_rrd

    info = recording_info(run_dir / "run.rrd")
    measured = info["measurements"]
    dest.mkdir(parents=True, exist_ok=True)
    rewrite_rrd(run_dir / "run.rrd", dest / "run.rrd", blueprint=default_blueprint(
        info["time_mode"], n=int(info["n"]), envelope=bool(info["envelope"]), gains=bool(info["gains"]),
        reference=measured is not None, truth=measured is None or bool(measured["truth"]), active_tab=tab))
    shutil.copy(run_dir / "events.jsonl", dest / "events.jsonl")
    return dest


def fit_png(path: Path, max_bytes: int) -> None:
    """Save ``path`` again with an adaptive 256-colour palette if it is larger than ``max_bytes``."""
    from PIL import Image

    if max_bytes <= 0 or path.stat().st_size <= max_bytes:
        return
    with Image.open(path) as image:
        small = image.convert("RGB").quantize(colors=256, method=Image.Quantize.MEDIANCUT, dither=Image.Dither.NONE)
    small.save(path, optimize=True)


def screenshots(run_dir: Path, times: dict, *, figures: Path, prefix: str, size: tuple[int, int],
                timeout: float, chromium: str, max_bytes: int = 0) -> list:
    """Screenshot ``run_dir``'s recording at each ``{name: event time}`` of ``times``: ``figures/<prefix>_<name>.png``
    (``figures/<name>.png`` with an empty prefix)."""
    from playwright.sync_api import sync_playwright

    end = last_event_time(run_dir)
    log = tempfile.TemporaryFile()
    proc, viewer = start_web_viewer(run_dir / "run.rrd", log_file=log)
    written = []
    try:
        with tempfile.TemporaryDirectory(prefix="splitspec-chromium-") as profile, sync_playwright() as pw:
            browser = pw.chromium.launch_persistent_context(
                profile, executable_path=chromium, headless=True, args=CHROMIUM_ARGS,
                viewport={"width": size[0], "height": size[1]})
            try:
                page = browser.pages[0] if browser.pages else browser.new_page()
                t0 = time.monotonic()
                page.goto(viewer.url)
                seen = {}

                def loaded():
                    seen["state"] = _state(page)
                    st = seen["state"]
                    return st is not None and (st.timelines.get(TIMELINE) or (0, -1))[1] >= end

                _poll(f"the recording up to {TIMELINE} {end}", loaded, timeout=timeout, last=lambda: seen.get("state"))
                t_loaded = time.monotonic() - t0
                _poll("the viewer to paint the recording", lambda: _painted(page), timeout=timeout, interval=2.0)
                print(f"viewer: recording loaded after {t_loaded:.0f} s, painted after {time.monotonic() - t0:.0f} s "
                      f"({viewer.url})")
                for name, t in times.items():
                    t1 = time.monotonic()
                    page.evaluate("async (bytes) => { await window._handle.viewer_control(new Uint8Array(bytes)); }",
                                  list(set_time_cursor_request(TIMELINE, t)))
                    def at_t():
                        s = _state(page)
                        return s and s.cursor_timeline == TIMELINE and s.cursor == t and s.play_state == PAUSED

                    _poll(f"the time cursor paused at {TIMELINE} {t}", at_t, timeout=30, interval=0.2,
                          last=lambda: _state(page))
                    path = figures / (f"{prefix}_{name}.png" if prefix else f"{name}.png")
                    page.screenshot(path=str(path))
                    if not at_t():
                        raise ScreenshotError(f"the time cursor left {TIMELINE} {t} while {path.name} was taken: "
                                              f"{_state(page)}")
                    fit_png(path, max_bytes)
                    written.append(path)
                    print(f"  {path.relative_to(ROOT) if path.is_relative_to(ROOT) else path}: {TIMELINE} {t} "
                          f"({time.monotonic() - t1:.0f} s, {path.stat().st_size // 1024} kB)")
            finally:
                browser.close()
    finally:
        stop_viewer(proc)
    return written


def _times(items: list) -> dict:
    times = {}
    for item in items:
        name, sep, value = item.partition("=")
        if not sep or not name.isidentifier() or not value.isdigit():
            raise SystemExit(f"make_screenshots: error: --at wants NAME=EVENT_TIME, got {item!r}")
        times[name] = int(value)
    return times


def main(argv: list | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--scenario", type=Path, default=DEFAULT_SCENARIO, help="scenario to run (default ring10_faults_switching)")
    p.add_argument("--run-dir", type=Path, help="use this run's output directory instead of running the scenario")
    p.add_argument("--at", action="append", default=[], metavar="NAME=T",
                   help="screenshot NAME at event time T (repeatable; default " +
                        ", ".join(f"{k}={v}" for k, v in DEFAULT_TIMES.items()) + ")")
    p.add_argument("--figures", type=Path, default=ROOT / "docs" / "figures", help="where to write the PNGs")
    p.add_argument("--prefix", help="file name prefix (default view_<scenario file stem>; '' for none)")
    p.add_argument("--size", default="1600x1000", help="browser viewport WIDTHxHEIGHT (default 1600x1000)")
    p.add_argument("--timeout", type=float, default=240.0, help="seconds to wait for the viewer (default 240)")
    p.add_argument("--chromium", default=CHROMIUM, help=f"Chromium executable (default {CHROMIUM})")
    p.add_argument("--network", action="store_true",
                   help="the screenshots of a misbehaving network instead: docs/lossy_ring.png, docs/partition.png")
    p.add_argument("--measured", action="store_true",
                   help="the screenshot of a run on measurements without the truth instead: docs/measured.png")
    p.add_argument("--max-kb", type=int, default=None,
                   help="save a larger PNG with a 256-colour palette (default: 200 with --network or "
                        "--measured, else none)")
    p.add_argument("--tab", help="the tab of the series to show (default: the log errors; e.g. rounds, states)")
    args = p.parse_args(argv)
    width, _, height = args.size.partition("x")
    if not Path(args.chromium).is_file():
        raise SystemExit(f"make_screenshots: error: no Chromium at {args.chromium} (apt-get install chromium, "
                         "or give --chromium PATH)")
    if args.network:
        if args.run_dir or args.at or args.tab:
            raise SystemExit("make_screenshots: error: --network runs its own scenarios at its own times "
                             "and tabs (no --run-dir, --at or --tab)")
        jobs = [(scenario, None, times, ROOT / "docs", "", tab) for scenario, times, tab in NETWORK_SHOTS]
    elif args.measured:
        if args.run_dir or args.at or args.tab or args.network:
            raise SystemExit("make_screenshots: error: --measured makes its own run at its own time and tab "
                             "(no --run-dir, --at, --tab or --network)")
        t0 = time.monotonic()
        run_dir = measured_run(ROOT / "out" / "screenshots" / "measured")
        print(f"ran {MEASURED_SCENARIO.name} on measurements without truth into {run_dir} in "
              f"{time.monotonic() - t0:.0f} s")
        jobs = [(MEASURED_SCENARIO, run_dir, {"measured": last_event_time(run_dir)}, ROOT / "docs", "", None)]
    else:
        times = _times(args.at) if args.at else dict(DEFAULT_TIMES)
        prefix = args.prefix if args.prefix is not None else \
            f"view_{(args.scenario if args.run_dir is None else args.run_dir).stem}"
        jobs = [(args.scenario, args.run_dir, times, args.figures, prefix, args.tab)]
    max_kb = args.max_kb if args.max_kb is not None else (200 if args.network or args.measured else 0)
    for scenario, run_dir, times, figures, prefix, tab in jobs:
        if run_dir is None:
            run_dir = ROOT / "out" / "screenshots" / scenario.stem
            t0 = time.monotonic()
            subprocess.run([sys.executable, "-m", "splitspec_orchestrator", "run", str(scenario), "--out",
                            str(run_dir)], cwd=ROOT, check=True, stdout=subprocess.DEVNULL)
            print(f"ran {scenario.name} into {run_dir} in {time.monotonic() - t0:.0f} s")
        figures.mkdir(parents=True, exist_ok=True)
        try:
            if tab is not None:
                run_dir = with_tab(run_dir, tab, ROOT / "out" / "screenshots" / f"{run_dir.name}-{tab}")
            screenshots(run_dir, times, figures=figures, prefix=prefix, size=(int(width), int(height)),
                        timeout=args.timeout, chromium=args.chromium, max_bytes=max_kb * 1024)
        except ScreenshotError as exc:
            print(f"make_screenshots: error: {exc}", file=sys.stderr)
            return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
