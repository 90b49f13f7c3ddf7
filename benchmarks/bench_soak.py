"""Soak: a paced `splitspec run` without ``run.steps`` (it runs until stopped) for many minutes, watched from outside.

What it measures, sampled every ``--sample-seconds`` from /proc and the records folder while the run goes on:

1. memory: the RSS (``VmRSS`` of /proc/PID/status; ``RssAnon`` beside it, which page cache does not move) of
   every process of the run's tree (the ``/proc/*/stat`` parent links from the `splitspec run` process), each
   labelled by its command line: ``run``, ``orchestrator``, ``fork server``, ``plant``, ``agent <id>`` (the
   agents are forks of the fork server and share its command line; their process name says which);  per role,
   after the warm-up: first, last and largest RSS and the slope by least squares in MB per hour (agents: the
   median and the largest slope over the agents), PASS below 10 MB/h; and, for a sawtooth (memory taken and
   given back every so often, which makes the straight line's slope depend on where the run stopped in a tooth),
   the slopes of each ``--block-minutes`` block's highest and lowest RSS (a drift moves both);
2. records: the size and inode of every file under ``--out`` (``chunks/rows-<tau>.arrows``, ``run.rrd``,
   ``events.jsonl``, ``trajectory.npz`` if any): bytes at the end, bytes per hour, the R^2 of a straight line
   through the total size against time after the warm-up (1: the records grow by what is added, with no
   rewrite spikes), and the rewrites seen (a file that shrank or whose inode changed between two samples;
   counted per file while running and, separately, between the last sample and the run's exit, when the
   closing flush may fix files up).  The chunks are append-only: any rewrite of one is a FAIL.  ``run.rrd`` is
   appended too, but each of its segments is finished (footer, a rewrite through a new inode) when it rolls past
   256 MiB to ``run-0001.rrd`` ... and at the exit (docs/reference/files.md, "Runs until stopped"): those
   rewrites are expected, reported with the lateness of the event times around each;
3. rows: the event times in the chunks (three columns, ``tau``, ``wall``, ``round``, of each segment read with
   pyarrow once it is closed, while the run goes: ``run.keep`` removes the oldest; by ``read_chunks``'s
   last-write-wins rule), every one from the first (missing ones counted), and their rate against ``run.pace``
   (from the chunks' ``wall`` column, first to last row);
4. lateness: the chunks' ``round`` column ``late_ms`` (how late each event time started against the pace):
   p50, p90, p99, max and the event times later than 10% of a period; at the kills and restarts apart (the
   round of a restart's event time waits for the new process; the 25 event times from each are its catch-up),
   and around each recording segment's rewrite without them (PASS within a period); and the end event's own summary
   (``reason``, ``late_event_times``, ``max_lateness_ms``, ``achieved_rate``, ``pace``), n/a where absent;
5. takeovers (``--kill-orchestrator-every S``: ``run.standby: true`` and the active orchestrator killed by the
   scenario every S seconds of running): the stall of each (from the dead one's last tick to its successor's
   first; target under 1 s), the rows missing, and the lateness outside each kill's, restart's and takeover's
   catch-up (its event times until one starts less than a tenth of a period late) against a period.  The standbys
   and the router are processes of the run's tree too (``standby``, ``router``): their memory is reported per
   process;
6. the machine's own timekeeping (:mod:`_canary`, records in ``<out>.canary.f64``): a bare sleeper at the run's
   priority, on a grid of the run's period, with the hypervisor's steal; the event times later than a period
   outside the faults' catch-ups are split into those while the machine itself stalled (the sleeper woke more than
   half a period late, or the hypervisor stole half a core over 0.2 s; and their catch-up) and the others, which alone are the product's (PASS: none).

The clock of ``--minutes`` and ``--warmup-minutes`` starts at the run's ``run_started`` event (its first round;
start-up, which includes the design, is reported apart).  At the end it sends SIGINT to `splitspec run` (as
Ctrl-C does; a run without steps ends as finished) and waits up to 120 s for it to exit.  Ctrl-C on this script
does the same early and still reports.  The machine is shared: quote the load averages printed beside the
figures.  A criterion that fails is printed as FAIL; the exit status is 0 all the same (a benchmark).

The default scenario is generated: m agents on an undirected ring, discrete time, n states in n/2 lightly
damped 2x2 rotations (spectral radius 0.999, distinct frequencies; a real mode 0.95 when n is odd), agent i
measuring the first state of the blocks i, i + m, i + 2m, ... (jointly observable, no agent alone),
process and measurement noise 0.01, ``design: {rate: --rate, gains: place, q: auto, q_method: spectral}``,
``run: {pace: --pace, seed: 1}``.  ``--model power`` runs ``examples/ieee14_pmu.yaml`` instead (the IEEE 14-bus
system, 62 states, 5 generators' agents with PMUs at 50 Hz, continuous time); ``--scenario FILE`` any
scenario file.  Either way ``run.steps`` is removed and ``run.pace`` set to ``--pace``; the scenario that ran
is written beside ``--out`` (``<out>.soak.yaml``, with the run's stdout and stderr in ``<out>.stdout.log``
and ``<out>.stderr.log``).

    .venv/bin/python benchmarks/bench_soak.py [--minutes 30] [--m 10] [--n 50] [--pace 50] [--sample-seconds 5]
        [--warmup-minutes W] [--block-minutes 20] [--out DIR] [--model ring|power | --scenario FILE] [--rate 0.9]
        [--keep-minutes K] [--kill-every S] [--kill-orchestrator-every S] [--no-replay] [--json FILE]

    # a short check of the script itself
    .venv/bin/python benchmarks/bench_soak.py --minutes 1 --sample-seconds 2 --m 4 --n 8
"""

from __future__ import annotations

import argparse
import json
import math
import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import yaml

import _canary
from _common import loadavg
from splitspec_orchestrator.launcher import idle_class, normal_class

ROOT = Path(__file__).resolve().parents[1]
ENV = {**os.environ, "RERUN_ANALYTICS": "0"}
POWER_SCENARIO = ROOT / "examples" / "ieee14_pmu.yaml"
SLOPE_LIMIT_MB_H = 10.0  #: a role's RSS may grow at most this fast after the warm-up
STARTUP_TIMEOUT = 600.0  #: seconds from the spawn to the first round (the design of a large model takes a while)
EXIT_TIMEOUT = 120.0  #: seconds to wait for `splitspec run` to exit after the SIGINT
LATE_FRACTION = 0.1  #: an event time later than this fraction of a period counts as late
RESTART_AFTER = 60.0  #: --kill-every: seconds from a kill to the restart
DISK_WINDOW_S = 600.0  #: the disk on hand is reported as the largest per window of this many seconds
#: the events of every run's start and end (the report counts the others: warnings, losses, restarts)
RESTART_CATCH_UP = 25  #: event times from a kill's or restart's whose lateness is its catch-up (reported apart)
WHOLE_READ_BYTES = 1 << 30  #: chunks up to this size are read whole with read_chunks (a 30 min default soak: ~0.4 GB)
QUIET_EVENTS = {"orchestrator_started", "fork_server_started", "process_started", "process_ready", "run_started",
                "run_finished", "run_interrupted", "recording_closed", "insecure_run"}


# ------------------------------------------------------------------ the scenario

def ring_soak_scenario(m: int, n: int, pace: float, rate: float, damping: float = 0.999) -> dict:
    """m agents on an undirected ring; n states in lightly damped rotations; agent i sees blocks i, i + m, ..."""
    nb = n // 2
    freqs = 0.2 + 1.6 * (np.arange(nb) + 0.5) / max(nb, 1)  # distinct, in (0.2, 1.8) rad per step
    A = np.zeros((n, n))
    for b, w in enumerate(freqs):
        c, s = damping * math.cos(w), damping * math.sin(w)
        A[2 * b:2 * b + 2, 2 * b:2 * b + 2] = [[c, s], [-s, c]]
    if n % 2:
        A[n - 1, n - 1] = 0.95

    def row(k: int) -> list:
        r = [0.0] * n
        r[k] = 1.0
        return r

    C = {}
    for i in range(m):
        rows = [row(2 * b) for b in range(i, nb, m)]
        if n % 2 and i == 0:
            rows.append(row(n - 1))
        if not rows:  # more agents than blocks: the second state of a block someone else sees the first of
            rows.append(row(2 * (i % nb) + 1) if nb else row(n - 1))
        C[i + 1] = rows
    return {"name": f"soak-ring{m}-n{n}", "time": "discrete",
            "system": {"A": np.round(A, 12).tolist(), "C": C, "process_noise": 0.01, "measurement_noise": 0.01},
            "graphs": {"ring": {"undirected": [[i, i % m + 1] for i in range(1, m + 1)]}},
            "design": {"rate": rate, "gains": "place", "q": "auto", "q_method": "spectral"},
            "run": {"pace": pace, "seed": 1}}


def kill_faults(sc: dict, every: float, seconds: float) -> list:
    """An agent killed every ``every`` seconds of running (each agent in turn) and restarted :data:`RESTART_AFTER`
    seconds later, over ``seconds``; ``at`` in the scenario's time (event times in discrete time: the pace's)."""
    from splitspec_core.scenarios.sections import parse_scenario

    ids = [int(a) for a in parse_scenario({k: v for k, v in sc.items() if k != "faults"}).agent_ids]
    pace = float(sc["run"]["pace"])
    unit = 1.0 if sc.get("time") == "continuous" else pace  # scenario time per second of running
    faults, k = [], 1
    while k * every < seconds:
        aid = ids[(k - 1) % len(ids)]
        faults += [{"at": round(k * every * unit, 6), "kill": aid},
                   {"at": round((k * every + RESTART_AFTER) * unit, 6), "restart": aid}]
        k += 1
    return faults


def orchestrator_kills(sc: dict, every: float, seconds: float) -> list:
    """The active orchestrator killed (``kill: orchestrator``) every ``every`` seconds of running over ``seconds``,
    half a period apart from the agents' kills; ``at`` in the scenario's time."""
    pace = float(sc["run"]["pace"])
    unit = 1.0 if sc.get("time") == "continuous" else pace
    return [{"at": round((k * every + 0.5 / pace) * unit, 6), "kill": "orchestrator"}
            for k in range(1, int(seconds // every) + 1) if k * every < seconds]


def file_scenario(path: Path, pace: float) -> dict:
    """The scenario of ``path`` with ``run.steps`` removed, ``run.pace`` set and a relative ``system.file`` made
    absolute (the copy is written elsewhere)."""
    sc = yaml.safe_load(path.read_text())
    run = dict(sc.get("run") or {})
    run.pop("steps", None)
    run["pace"] = pace
    sc["run"] = run
    system = sc.get("system") or {}
    if isinstance(system.get("file"), str) and not Path(system["file"]).is_absolute():
        system["file"] = str((path.parent / system["file"]).resolve())
    return sc


# ------------------------------------------------------------------ sampling

def _read(path: str) -> str | None:
    try:
        with open(path, "rb") as f:
            return f.read().decode(errors="replace")
    except OSError:
        return None


def process_tree(root: int) -> list[int]:
    """``root`` and its descendants, from the parent links of /proc/*/stat."""
    children: dict = {}
    for d in os.listdir("/proc"):
        if not d.isdigit():
            continue
        stat = _read(f"/proc/{d}/stat")
        if stat is None:
            continue
        try:
            ppid = int(stat.rsplit(")", 1)[1].split()[1])
        except (IndexError, ValueError):
            continue
        children.setdefault(ppid, []).append(int(d))
    out, todo = [], [root]
    while todo:
        pid = todo.pop()
        out.append(pid)
        todo.extend(children.get(pid, ()))
    return out


def label(pid: int, root: int) -> str | None:
    """What the process is, from its command line (and, for a forked agent, its name); None if it is gone."""
    cmd = _read(f"/proc/{pid}/cmdline")
    comm = (_read(f"/proc/{pid}/comm") or "").strip()
    if cmd is None:
        return None
    args = cmd.split("\0")
    if pid == root:
        return "run"
    if comm.startswith("agent "):
        return comm
    if "splitspec_agents.forkserver" in args:
        return "fork server"
    if "splitspec_plant" in args:
        return "plant"
    if "splitspec_agents" in args:
        return f"agent {args[args.index('--id') + 1]}" if "--id" in args[:-1] else "agent ?"
    if "splitspec_orchestrator" in args and "orchestrator" in args:
        return "orchestrator"
    if "splitspec_orchestrator" in args and "standby" in args:
        return "standby"  # a standby orchestrator (run.standby), active once it took over
    if "splitspec_orchestrator" in args and "router" in args:
        return "router"
    return comm or "?"


def memory(pid: int) -> tuple | None:
    """``(VmRSS, RssAnon)`` in kB, or None if the process is gone (or a zombie: no VmRSS)."""
    status = _read(f"/proc/{pid}/status")
    if status is None:
        return None
    vals = {}
    for line in status.splitlines():
        key, _, rest = line.partition(":")
        if key in ("VmRSS", "RssAnon"):
            vals[key] = int(rest.split()[0])
    if "VmRSS" not in vals:
        return None
    return vals["VmRSS"], vals.get("RssAnon", 0)


def cpu_seconds(pid: int) -> float | None:
    stat = _read(f"/proc/{pid}/stat")
    try:
        f = stat.rsplit(")", 1)[1].split()
        return (int(f[11]) + int(f[12])) / os.sysconf("SC_CLK_TCK")
    except (AttributeError, IndexError, ValueError):
        return None


def processes(root: int) -> dict:
    """``{"<label>/<pid>": {"label", "pid", "rss_kb", "anon_kb", "cpu_s"}}`` of the run's process tree now."""
    out = {}
    for pid in process_tree(root):
        lab, mem = label(pid, root), memory(pid)
        if lab is None or mem is None:
            continue
        out[f"{lab}/{pid}"] = {"label": lab, "pid": pid, "rss_kb": mem[0], "anon_kb": mem[1], "cpu_s": cpu_seconds(pid)}
    return out


def record_files(out: Path) -> dict:
    """``{relative path: (bytes, inode)}`` of every file under ``out``."""
    files = {}
    for dirpath, _dirs, names in os.walk(out):
        for name in names:
            p = Path(dirpath) / name
            try:
                st = p.stat()
            except OSError:
                continue
            files[str(p.relative_to(out))] = (st.st_size, st.st_ino)
    return files


class FileWatch:
    """Per file: rewrites (it shrank or its inode changed since the previous sample) and removals."""

    def __init__(self):
        self.last: dict = {}
        self.rewrites: dict = {}  # path -> count while running
        self.rewrites_close: dict = {}  # path -> count between the last sample and the exit
        self.removed: dict = {}  # path -> count (gone between two samples)
        self.notes: list = []
        self.walls: list = []  # (the sample's Unix time, path) of every rewrite while running

    def see(self, files: dict, t: float, *, wall: float = math.nan, closing: bool = False) -> None:
        into = self.rewrites_close if closing else self.rewrites
        for path, (size, ino) in files.items():
            prev = self.last.get(path)
            if prev is not None and (size < prev[0] or ino != prev[1]):
                into[path] = into.get(path, 0) + 1
                if not closing:
                    self.walls.append((wall, path))
                self.notes.append(f"{t:8.1f} s {path}: {'inode changed' if ino != prev[1] else 'shrank'} "
                                  f"({prev[0]} -> {size} bytes){' at close' if closing else ''}")
        for path in self.last.keys() - files.keys():
            self.removed[path] = self.removed.get(path, 0) + 1
            self.notes.append(f"{t:8.1f} s {path}: removed{' at close' if closing else ''}")
        self.last = dict(files)


def events(out: Path) -> list:
    text = _read(str(out / "events.jsonl")) or ""
    evs = []
    for line in text.splitlines():
        try:
            evs.append(json.loads(line))
        except ValueError:
            continue  # a torn last line while it is being written
    return evs


def first_event(evs: list, *names: str) -> dict | None:
    return next((e for e in evs if e.get("event") in names), None)


# ------------------------------------------------------------------ the run's rows

def block_slopes(t_h: np.ndarray, y: np.ndarray, block_h: float) -> tuple[float, float, int]:
    """Least-squares slopes of the highest and of the lowest ``y`` in each whole block of ``block_h`` hours from the
    first ``t_h`` (each at its block's middle), and the number of blocks (nan slopes under 3 blocks)."""
    if len(t_h) < 2 or block_h <= 0:
        return math.nan, math.nan, 0
    k = np.floor((t_h - t_h[0]) / block_h).astype(int)
    whole = [b for b in np.unique(k) if (b + 1) * block_h <= t_h[-1] - t_h[0] + 1e-9]
    if len(whole) < 3:
        return math.nan, math.nan, len(whole)
    mid = np.array([t_h[0] + (b + 0.5) * block_h for b in whole])
    hi = np.array([y[k == b].max() for b in whole])
    lo = np.array([y[k == b].min() for b in whole])
    return float(np.polyfit(mid, hi, 1)[0]), float(np.polyfit(mid, lo, 1)[0]), len(whole)


def _segment_columns(path: Path) -> tuple | None:
    """``(tau, wall, round)`` of every whole batch of one chunk segment (pyarrow, those three columns alone; a torn
    last batch is left out), None if it cannot be opened."""
    import pyarrow as pa

    try:
        reader = pa.ipc.open_stream(pa.memory_map(str(path)))
    except (OSError, pa.ArrowInvalid):
        return None
    taus, walls, rounds = [], [], []
    while True:
        try:
            b = reader.read_next_batch()
        except StopIteration:
            break
        except (OSError, pa.ArrowInvalid):
            break  # a torn last batch
        taus.append(b.column("tau").to_numpy(zero_copy_only=False).astype(np.int64))
        walls.append(b.column("wall").to_numpy(zero_copy_only=False).astype(np.int64))
        rounds.append(b.column("round").flatten().to_numpy(zero_copy_only=False).astype(float)
                      .reshape(-1, b.schema.field("round").type.list_size))
    if not taus:
        return np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros((0, 5)), reader.schema.metadata
    return np.concatenate(taus), np.concatenate(walls), np.concatenate(rounds), reader.schema.metadata


class ChunkTail:
    """The three columns of every chunk segment, read once it is closed (the next one exists), while the run goes:
    ``run.keep`` removes the oldest segments, and with them the rows a report at the end would see.  ``seen``:
    segment start event time -> ``(tau, wall, round, metadata)``."""

    def __init__(self, out: Path):
        self.out = out
        self.seen: dict = {}

    def take(self) -> None:
        from splitspec_core.simulation.trajectory_chunks import chunk_segments

        segs = chunk_segments(self.out) if self.out.exists() else []
        for first, path in segs[:-1]:  # the last is being written
            if first not in self.seen:
                cols = _segment_columns(path)
                if cols is not None:
                    self.seen[first] = cols


def chunk_rows(out: Path, *, whole_limit: int = WHOLE_READ_BYTES, tail: ChunkTail | None = None) -> dict | None:
    """``tau``, ``wall`` and ``round`` of every event time in the chunks (the last row written of each), plus ``m``,
    ``n``, ``segments`` and ``how`` they were read; None without chunks.

    With ``tail``: the segments it read while the run went (removed since or not) and the others on disk, every one
    by its three columns.  Else, up to ``whole_limit`` bytes of segments: ``read_chunks(out)``; beyond (a long soak:
    ``read_chunks`` holds every column, ``xhat`` too, several times over while it converts): the three columns
    alone.  Segments in order, the last batch holding an event time wins.  Not ``read_chunks`` by time windows: a
    window's ``end`` misses a row written again into the segment that starts after it."""
    from splitspec_core.simulation.trajectory_chunks import chunk_segments, read_chunks

    segs = chunk_segments(out)
    if not segs and not (tail and tail.seen):
        return None
    size = sum(p.stat().st_size for _, p in segs if p.exists())
    if tail is None and size <= whole_limit:
        c = read_chunks(out)
        if c is None:
            return None
        return {"tau": c["tau"], "wall": c["wall"], "round": c["round"], "m": len(c["agent_ids"]),
                "n": len(c["states"]), "segments": len(segs), "how": "read_chunks",
                "first_on_disk": int(c["tau"][0]) if len(c["tau"]) else None}
    per = dict(tail.seen) if tail is not None else {}
    for first, path in segs:
        if first not in per:
            cols = _segment_columns(path)
            if cols is not None:
                per[first] = cols
    if not per:
        return None
    order = [per[k] for k in sorted(per)]
    tau = np.concatenate([c[0] for c in order])
    wall = np.concatenate([c[1] for c in order])
    rnd = np.concatenate([c[2] for c in order])
    meta = next((c[3] for c in order if c[3]), None) or {}
    _, first_rev = np.unique(tau[::-1], return_index=True)
    keep = len(tau) - 1 - first_rev  # the last row written of each event time, in event-time order
    m = len(json.loads(meta.get(b"agent_ids", b"[]")))
    n = len(json.loads(meta.get(b"states", b"[]")))
    how = (f"pyarrow, 3 columns, each segment read once closed ({len(per)} segments, {len(per) - len(segs)} "
           f"removed since)" if tail is not None else f"pyarrow, 3 columns ({size / 2 ** 30:.1f} GiB of segments)")
    on_disk = [per[k][0] for k, _ in segs if k in per and len(per[k][0])]
    return {"tau": tau[keep], "wall": wall[keep], "round": rnd[keep], "m": m, "n": n, "segments": len(per),
            "how": how, "first_on_disk": int(min(t.min() for t in on_disk)) if on_disk else None}


# ------------------------------------------------------------------ figures

CONTROL_SHIFT_S = 37.0  #: the machine's stalls moved by this many seconds: what they would hold by chance


def machine_made(tau: np.ndarray, wall_s: np.ndarray, late: np.ndarray, a: np.ndarray, b: np.ndarray,
                 period_ms: float) -> np.ndarray:
    """Which event times the machine made late: one started at ``wall_s`` and scheduled at ``s = wall_s - late``
    whose ``[s - period, wall_s]`` meets a stall ``[a_j, b_j]`` (sorted, disjoint), or in the catch-up of one that
    did (every event time since started at least a tenth of a period late)."""
    made = np.zeros(len(tau), dtype=bool)
    for k in np.where(np.isfinite(late) & (late > LATE_FRACTION * period_ms))[0]:
        j = np.searchsorted(b, wall_s[k] - late[k] / 1e3 - period_ms / 1e3)  # the first stall ending after that
        if j < len(a) and a[j] <= wall_s[k]:
            made[k] = True
        elif k and made[k - 1] and tau[k - 1] == tau[k] - 1:
            made[k] = True
    return made


def machine_stalls(path: Path, tau: np.ndarray, wall: np.ndarray, late: np.ndarray, apart: np.ndarray,
                   period_ms: float) -> dict:
    """The event times later than a period outside the faults' catch-ups (``apart``), split by whether the machine
    itself stalled then (:mod:`_canary`: its bare sleeper at the run's priority woke more than half a period late,
    or the hypervisor stole half a core over 0.2 s; :func:`machine_made`), printed and returned.  Beside it, a
    control: the same stalls moved by ``CONTROL_SHIFT_S`` either way, which hold as many only if the stalls cover so
    much of the run that any event time falls in one."""
    rec = _canary.read(path)
    if not len(rec):
        print("  the machine's own timekeeping: n/a (no records of the sleeper)")
        return {}
    per = np.diff(rec[:, 0])
    span = float(rec[-1, 0] - rec[0, 0]) if len(rec) > 1 else math.nan
    st = _canary.stalls(rec, period_ms / 2)
    a = np.array([x[0] for x in st]) if st else np.empty(0)
    b = np.array([x[1] for x in st]) if st else np.empty(0)
    steal_s = (rec[-1, 2] - rec[0, 2]) / os.sysconf("SC_CLK_TCK")
    busy = (rec[-1, 3] - rec[0, 3]) / os.sysconf("SC_CLK_TCK") / span if span > 0 else math.nan
    wall_s = wall / 1e9
    over = apart & (late > period_ms)
    made = machine_made(tau, wall_s, late, a, b, period_ms)
    mine, theirs = over & made, over & ~made
    control = [int((over & machine_made(tau, wall_s, late, a + d, b + d, period_ms)).sum())
               for d in (CONTROL_SHIFT_S, -CONTROL_SHIFT_S)]
    worst = float(late[theirs].max()) if theirs.any() else 0.0
    lates = rec[:, 1]
    cover = float(np.sum(b - a))
    print(f"  the machine's own timekeeping (a bare sleeper at the run's priority, {len(rec)} ticks over "
          f"{fmt(span, '.0f')} s, median tick {fmt(float(np.median(per)) * 1e3 if len(per) else math.nan, '.2f')} ms): "
          f"woke late p99 {np.percentile(lates, 99):.2f} ms, max {lates.max():.1f} ms; steal {steal_s:.1f} s in all "
          f"({100 * steal_s / span:.1f}% of a core); the machine busy {fmt(busy, '.2f')} cores on average; {len(st)} "
          f"stalls (woke more than {period_ms / 2:g} ms late, or {_canary.STEAL_CORES:g} core stolen over "
          f"{_canary.STEAL_WINDOW_S:g} s) covering {cover:.1f} s ({100 * cover / span:.2f}% of the run)")
    print(f"  of the {int(over.sum())} event times later than a period outside the faults' catch-ups: "
          f"{int(mine.sum())} while the machine stalled (or in the catch-up after; the same stalls moved "
          f"{CONTROL_SHIFT_S:g} s later or earlier hold {control[0]} and {control[1]}), {int(theirs.sum())} not (max "
          f"{worst:.1f} ms): " + ("PASS" if not theirs.any() else "FAIL"))
    return {"ticks": int(len(rec)), "late_p99_ms": float(np.percentile(lates, 99)), "late_max_ms": float(lates.max()),
            "stalls": len(st), "stall_seconds": cover, "stall_fraction": cover / span, "steal_seconds": float(steal_s),
            "busy_cores": busy, "over_period": int(over.sum()), "over_period_machine": int(mine.sum()),
            "control_shifted": control, "over_period_not_machine": int(theirs.sum()), "late_max_not_machine": worst,
            "not_machine_taus": [int(t) for t in tau[theirs][:200]]}


def slope_r2(t: np.ndarray, y: np.ndarray) -> tuple:
    """Least-squares slope of y against t and the fit's R^2 (nan with fewer than 3 points; R^2 1 if y is flat)."""
    if len(t) < 3 or np.ptp(t) == 0:
        return math.nan, math.nan
    a, b = np.polyfit(t, y, 1)
    ss = float(np.sum((y - y.mean()) ** 2))
    r2 = 1.0 if ss == 0 else 1.0 - float(np.sum((y - (a * t + b)) ** 2)) / ss
    return float(a), r2


def fmt(v, spec: str = ".1f", na: str = "n/a") -> str:
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return na
    return format(v, spec)


def machine() -> str:
    cpu = "n/a"
    for line in (_read("/proc/cpuinfo") or "").splitlines():
        if line.startswith("model name"):
            cpu = line.split(":", 1)[1].strip()
            break
    mem = "n/a"
    for line in (_read("/proc/meminfo") or "").splitlines():
        if line.startswith("MemTotal:"):
            mem = f"{int(line.split()[1]) / 1024 ** 2:.1f} GiB"
            break
    try:
        usable = len(os.sched_getaffinity(0))
    except AttributeError:
        usable = os.cpu_count()
    return f"{cpu}; {os.cpu_count()} cores ({usable} usable); {mem} memory"


KIND_ORDER = ["chunks/rows-*.arrows", "run*.rrd", "events.jsonl", "trajectory.npz"]


def kind(path: str) -> str:
    """The records table's row of a file: the chunk segments together, the rrd segments together, others alone."""
    if path.startswith("chunks/") and path.endswith(".arrows"):
        return KIND_ORDER[0]
    if "/" not in path and path.startswith("run") and path.endswith(".rrd"):
        return KIND_ORDER[1]
    return path


def active_series(samples: list, evs: list, after_s: float, settle_s: float) -> dict:
    """The RSS of the orchestrator holding the rounds at each sample (``orchestrator_started`` and each
    ``orchestrator_takeover`` name its pid and wall time), from ``after_s`` of the run on and each epoch's first
    ``settle_s`` left out: ``points`` [(t, MB)], ``epochs`` (how many held the rounds), ``peaks`` (each epoch's largest
    RSS, MB, in order)."""
    starts = [(float(e["wall"]), int(e["pid"])) for e in evs
              if e.get("event") in ("orchestrator_started", "orchestrator_takeover") and "pid" in e and "wall" in e]
    starts.sort()
    points, peaks = [], {}
    for s in samples:
        if s["t"] is None or s["t"] < after_s:
            continue
        began = [b for b in starts if b[0] <= s["wall"]]
        if not began:
            continue
        wall0, pid = began[-1]
        rss = next((p["rss_kb"] / 1024 for p in s["procs"].values() if p["pid"] == pid), None)
        if rss is None:
            continue
        peaks[wall0] = max(peaks.get(wall0, 0.0), rss)
        if s["wall"] - wall0 >= settle_s:
            points.append((s["t"], rss))
    return {"points": points, "epochs": len(starts), "peaks": [peaks[k] for k in sorted(peaks)]}


def role_of(lab: str) -> str:
    return "agent" if lab.startswith("agent ") else lab


def progress(t: float, sample: dict) -> None:
    """One line of a sample while the run goes on: RSS per role (agents: median and largest), records' bytes."""
    rss: dict = {}
    for p in sample["procs"].values():
        rss.setdefault(role_of(p["label"]), []).append(p["rss_kb"] / 1024)
    parts = []
    for role, v in rss.items():
        parts.append(f"agents {np.median(v):.1f} (max {max(v):.1f})" if role == "agent" and len(v) > 1
                     else f"{role} {max(v):.1f}")
    size = sum(b for b, _ in sample["files"].values())
    print(f"# {t / 60:6.2f} min: RSS MB {', '.join(parts)}; records {size / 1e6:.2f} MB; load {loadavg()}", flush=True)


# ------------------------------------------------------------------ main

def replay(out: Path, scen: Path) -> dict:
    """``splitspec simulate --faults-from OUT`` (every event time from the first, the kills and restarts at the
    event times they happened) against the rows still on disk: the largest difference of the estimates, where the
    same agents are alive."""
    import splitspec_core as ss
    from splitspec_core.simulation.simulator import Trajectory

    sim_out = out.parent / f"{out.name}.replay"
    t0 = time.monotonic()
    r = subprocess.run([sys.executable, "-m", "splitspec_orchestrator", "simulate", str(out / "scenario.yaml"),
                        "--out", str(sim_out), "--no-plots", "--faults-from", str(out)], cwd=ROOT, env=ENV,
                       capture_output=True, text=True)
    secs = time.monotonic() - t0
    if r.returncode != 0:
        last = (r.stderr.strip().splitlines() or ["?"])[-1]
        print(f"replay: simulate failed after {secs:.0f} s: {last}")
        return {"ok": False, "error": last}
    rec = ss.load_run(out).trajectory
    sim = Trajectory.load(sim_out / "trajectory.npz")
    k = np.searchsorted(sim.t, rec.t - 1e-9)
    same_t = bool(np.allclose(sim.t[k], rec.t, rtol=0, atol=1e-9))
    alive = bool(np.array_equal(sim.alive[k], rec.alive))
    both = np.isfinite(rec.xhat) & np.isfinite(sim.xhat[k])
    diff = float(np.max(np.abs(rec.xhat[both] - sim.xhat[k][both]))) if both.any() else math.nan
    scale = float(np.nanmax(np.abs(sim.xhat[k])))
    ok = same_t and alive and diff <= 1e-9 * max(1.0, scale)
    print(f"replay: simulate --faults-from ran {len(sim.t)} event times in {secs:.0f} s; the {len(rec.t)} rows on disk "
          f"(t = {rec.t[0]:g} .. {rec.t[-1]:g}): same times {same_t}, same agents alive {alive}, largest difference "
          f"{diff:.3g} (estimates up to {scale:.3g}): {'PASS' if ok else 'FAIL'} (round-off: 1e-9 of the scale)")
    import shutil

    shutil.rmtree(sim_out, ignore_errors=True)  # a large trajectory.npz
    return {"ok": ok, "rows": int(len(rec.t)), "sim_rows": int(len(sim.t)), "max_diff": diff, "scale": scale,
            "same_t": same_t, "same_alive": alive, "seconds": secs}


def main() -> int:
    # Started in the background (nohup ... &), SIGINT arrives ignored and would stay ignored in `splitspec run`
    # (an ignored signal survives exec): the SIGINT that stops the run at the end would do nothing.
    signal.signal(signal.SIGINT, signal.default_int_handler)
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--minutes", type=float, default=30.0, help="minutes of running (from the first round)")
    ap.add_argument("--m", type=int, default=10, help="agents of the generated ring")
    ap.add_argument("--n", type=int, default=50, help="states of the generated ring")
    ap.add_argument("--pace", type=float, default=50.0, help="event times per second (run.pace)")
    ap.add_argument("--rate", type=float, default=0.9, help="design.rate of the generated ring (0.9: q = 4 at m = 10, "
                    "n = 50)")
    ap.add_argument("--sample-seconds", type=float, default=5.0)
    ap.add_argument("--warmup-minutes", type=float, help="default: min(5, 20%% of --minutes)")
    ap.add_argument("--settle-minutes", type=float, default=2.0,
                    help="with orchestrator kills: the minutes after each takeover left out of the active "
                         "orchestrator's memory slope (default 2)")
    ap.add_argument("--block-minutes", type=float, default=20.0,
                    help="the blocks of the sawtooth-proof memory slopes (default 20)")
    ap.add_argument("--out", type=Path, help="the run's records (default: a fresh folder under /tmp)")
    ap.add_argument("--model", choices=("ring", "power"), default="ring",
                    help=f"ring: the generated ring (--m, --n); power: {POWER_SCENARIO.relative_to(ROOT)}")
    ap.add_argument("--scenario", type=Path, help="this scenario file instead (run.steps removed, run.pace set)")
    ap.add_argument("--json", type=Path, help="write every sample and the results here")
    ap.add_argument("--keep-minutes", type=float, help="run.keep.hours of the run, in minutes (default: keep all)")
    ap.add_argument("--kill-every", type=float, default=0.0,
                    help="seconds: kill an agent (each in turn) every this many seconds of running and restart it "
                         f"{RESTART_AFTER:g} s later (0: no fault)")
    ap.add_argument("--kill-orchestrator-every", type=float, default=0.0, metavar="S",
                    help="seconds: with run.standby, kill the active orchestrator (the scenario's kill: orchestrator) "
                         "every this many seconds of running; its standby takes over (0: never)")
    ap.add_argument("--no-replay", action="store_true", help="skip replaying the rows left on disk with simulate")
    args = ap.parse_args()
    if not args.minutes > 0 or not args.sample_seconds > 0 or not args.pace > 0:
        ap.error("--minutes, --sample-seconds and --pace must be positive")
    if args.model == "ring" and args.scenario is None and (args.m < 2 or args.n < 2):
        ap.error("the generated ring needs --m >= 2 and --n >= 2")
    if args.scenario is not None and args.model != "ring":
        ap.error("--scenario and --model power are exclusive")
    warmup = min(5.0, 0.2 * args.minutes) if args.warmup_minutes is None else args.warmup_minutes
    if not 0 <= warmup < args.minutes:
        ap.error("--warmup-minutes must be in [0, --minutes)")

    if args.out is None:
        out = Path(tempfile.mkdtemp(prefix="bench_soak_")) / "run"
    else:
        out = args.out.resolve()
        if out.exists() and any(out.iterdir()):
            ap.error(f"--out {out}: not empty")
    out.parent.mkdir(parents=True, exist_ok=True)
    if args.scenario is not None:
        sc = file_scenario(args.scenario.resolve(), args.pace)
    elif args.model == "power":
        sc = file_scenario(POWER_SCENARIO, args.pace)
    else:
        sc = ring_soak_scenario(args.m, args.n, args.pace, args.rate)
    if args.keep_minutes is not None:
        sc.setdefault("run", {})["keep"] = {"hours": args.keep_minutes / 60.0}
    if args.kill_every > 0:
        sc["faults"] = kill_faults(sc, args.kill_every, args.minutes * 60)
        # the agents are killed: design for it (every single loss certified; the IEEE 14-bus default design's
        # survivors diverge: spectral radius 1.68 per step after any one loss)
        sc.setdefault("design", {}).setdefault("resilience", 1)
    if args.kill_orchestrator_every > 0:
        sc.setdefault("run", {})["standby"] = True
        sc["faults"] = sorted(sc.get("faults", []) + orchestrator_kills(sc, args.kill_orchestrator_every,
                                                                         args.minutes * 60), key=lambda f: f["at"])
    scen = out.parent / f"{out.name}.soak.yaml"
    scen.write_text(yaml.safe_dump(sc, sort_keys=False))
    run_id = f"soak-{os.getpid()}"

    load_start = loadavg()
    print(f"# machine: {machine()}", flush=True)
    print(f"# load average at start {load_start}", flush=True)
    print(f"# scenario {scen} ({sc.get('name')}); records {out}; run id {run_id}", flush=True)
    print(f"# {args.minutes:g} min from the first round, warm-up {warmup:g} min, a sample every "
          f"{args.sample_seconds:g} s, pace {args.pace:g}/s", flush=True)

    stdout = open(out.parent / f"{out.name}.stdout.log", "w")
    stderr = open(out.parent / f"{out.name}.stderr.log", "w")
    t_spawn = time.monotonic()
    # its own session: a Ctrl-C of this script reaches the run only as the SIGINT sent below (once)
    proc = subprocess.Popen([sys.executable, "-m", "splitspec_orchestrator", "run", str(scen), "--out", str(out),
                             "--run-id", run_id], cwd=ROOT, env=ENV, stdout=stdout, stderr=stderr,
                            stdin=subprocess.DEVNULL, start_new_session=True)
    # the watcher must not take the run's cores: it reads each closed chunk segment (67 MB, a second or two of a
    # core), which made rounds up to 165 ms late beside it in the hour of 2026-11-30; the run's processes are
    # started already (its own are started by the run), so only this process goes to the idle class
    # the machine's own timekeeping beside the run, at the run's priority (this one's, before it goes idle)
    canary_path = out.parent / f"{out.name}.canary.f64"
    canary_path.unlink(missing_ok=True)
    canary = subprocess.Popen([sys.executable, str(Path(__file__).with_name("_canary.py")), str(canary_path),
                               repr(1.0 / args.pace)], stdin=subprocess.DEVNULL)
    idle = idle_class(os.getpid())
    samples: list = []  # {"t" (s since the first round, None before), "wall", "procs", "files"}
    watch = FileWatch()
    tail = ChunkTail(out)  # every row's lateness, read before run.keep removes it
    t_first = None  # monotonic time of run_started
    startup_s = None
    ended_by_itself = None
    stopped_by_user = False
    next_at = time.monotonic()
    next_progress = 0.0  # a progress line every minute of running
    try:
        while True:
            now = time.monotonic()
            if t_first is None:
                started = first_event(events(out), "run_started")
                if started is not None:
                    # its wall time, on the monotonic clock (seen up to a sample late)
                    t_first = now - min(max(0.0, time.time() - float(started.get("wall", time.time()))),
                                        args.sample_seconds)
                    startup_s = t_first - t_spawn
                    print(f"# first round {startup_s:.1f} s after the spawn (start-up, design included)", flush=True)
                elif now - t_spawn > STARTUP_TIMEOUT:
                    print(f"# no run_started within {STARTUP_TIMEOUT:g} s: stopping", flush=True)
                    break
            t = now - t_first if t_first is not None else None  # None: before the first round
            if proc.poll() is not None:
                ended_by_itself = now - (t_first or t_spawn)
                break
            files = record_files(out) if out.exists() else {}
            wall = time.time()
            watch.see(files, math.nan if t is None else t, wall=wall)
            tail.take()
            samples.append({"t": None if t is None else round(t, 3), "wall": wall,
                            "procs": processes(proc.pid), "files": files})
            if t is not None and t >= next_progress:
                progress(t, samples[-1])
                next_progress += 60.0
            if t is not None and t >= args.minutes * 60:
                break
            next_at += args.sample_seconds
            time.sleep(max(0.0, next_at - time.monotonic()))
    except KeyboardInterrupt:
        stopped_by_user = True
        print("# interrupted (Ctrl-C): stopping the run and reporting what there is", flush=True)
    t_stop = time.monotonic()
    code = proc.poll()
    exit_s = None
    if code is None:
        proc.send_signal(signal.SIGINT)
        try:
            code = proc.wait(timeout=EXIT_TIMEOUT)
            exit_s = time.monotonic() - t_stop
        except subprocess.TimeoutExpired:
            print(f"# `splitspec run` still running {EXIT_TIMEOUT:g} s after SIGINT: killing its process group",
                  flush=True)
            os.killpg(proc.pid, signal.SIGKILL)
            code = proc.wait()
    canary.terminate()
    canary.wait()
    stdout.close()
    stderr.close()
    final_files = record_files(out) if out.exists() else {}
    watch.see(final_files, (t_stop - t_first) if t_first is not None else math.nan, closing=True)
    load_end = loadavg()

    # ---------------------------------------------------------------- report
    evs = events(out)
    orch = first_event(evs, "orchestrator_started") or {}
    end = first_event(evs, "run_finished", "run_interrupted", "run_failed") or {}
    rows = chunk_rows(out, tail=tail)
    m = rows["m"] if rows else (args.m if args.model == "ring" and args.scenario is None else None)
    n = rows["n"] if rows else (args.n if args.model == "ring" and args.scenario is None else None)
    ran_s = (t_stop - t_first) if t_first is not None else 0.0
    print()
    print(f"machine: {machine()}")
    print(f"load average: start {load_start}; end {load_end}")
    q_or_g = (f"q {orch['q']}" if orch.get("q") is not None else f"g {orch['g']:.4g}" if orch.get("g") is not None
              else "q/g n/a")
    print(f"run: {sc.get('name')} m {fmt(m, 'd')} n {fmt(n, 'd')} {q_or_g} pace {args.pace:g}/s; "
          f"{ran_s / 60:.2f} of {args.minutes:g} min run (from the first round), start-up "
          f"{fmt(startup_s, '.1f')} s, warm-up {warmup:g} min")
    errlog = out.parent / f"{out.name}.stderr.log"
    errors = [line for line in (_read(str(errlog)) or "").splitlines() if "error" in line.lower()]
    if ended_by_itself is not None:
        started = "" if t_first is not None else " before its first round"
        print(f"NOTE: the run ended by itself{started} after {ended_by_itself:.1f} s (exit {code}), before the "
              f"{args.minutes:g} min" + (": it does not run until stopped (yet?)" if code == 0 else "")
              + "; what it recorded is reported below")
    else:
        print(f"stop: SIGINT{' (Ctrl-C of this script)' if stopped_by_user else ''}; `splitspec run` exited "
              f"{code} after {fmt(exit_s, '.1f')} s")
    if code != 0 or errors:
        print(f"  its stderr ({errlog}): " + (errors[-1] if errors else "no line with 'error'"))

    # memory, per role
    results: dict = {"machine": machine(), "load_start": load_start, "load_end": load_end, "m": m, "n": n,
                     "q": orch.get("q"), "g": orch.get("g"), "pace": args.pace, "minutes": args.minutes,
                     "ran_minutes": ran_s / 60, "startup_s": startup_s, "warmup_minutes": warmup, "exit": code,
                     "ended_by_itself_s": ended_by_itself, "end_event": end, "roles": {}}
    after = [s for s in samples if s["t"] is not None and s["t"] >= warmup * 60]
    series: dict = {}  # "<label>/<pid>" -> [(t, rss MB, anon MB, cpu s)]
    for s in after:
        for key, p in s["procs"].items():
            series.setdefault(key, []).append((s["t"], p["rss_kb"] / 1024, p["anon_kb"] / 1024, p["cpu_s"]))
    print(f"\nmemory after the warm-up ({len(after)} samples; slope by least squares, limit "
          f"{SLOPE_LIMIT_MB_H:g} MB/h; anon: RssAnon's slope; CPU: % of one core)")
    print(f"{'process':>13} {'n':>3} {'first MB':>8} {'last MB':>8} {'max MB':>8} {'MB/h':>8} {'anon MB/h':>9} "
          f"{'CPU %':>6}  verdict")
    by_role: dict = {}
    for key, pts in series.items():
        by_role.setdefault(role_of(key.split("/")[0]), []).append((key, pts))
    order = ["run", "router", "orchestrator", "standby", "fork server", "plant", "agent"]
    for role in order + sorted(set(by_role) - set(order)):
        if role not in by_role:
            continue
        per = []
        for key, pts in by_role[role]:
            a = np.array([(p[0], p[1], p[2]) for p in pts])
            cpu = [(p[0], p[3]) for p in pts if p[3] is not None]
            slope, _ = slope_r2(a[:, 0] / 3600, a[:, 1])
            anon, _ = slope_r2(a[:, 0] / 3600, a[:, 2])
            pct = (100 * (cpu[-1][1] - cpu[0][1]) / (cpu[-1][0] - cpu[0][0])
                   if len(cpu) > 1 and cpu[-1][0] > cpu[0][0] else math.nan)
            per.append({"process": key, "samples": len(pts), "first_mb": float(a[0, 1]), "last_mb": float(a[-1, 1]),
                        "max_mb": float(a[:, 1].max()), "slope_mb_h": slope, "anon_slope_mb_h": anon, "cpu_pct": pct})
        slopes = [p["slope_mb_h"] for p in per if math.isfinite(p["slope_mb_h"])]
        worst = max(slopes) if slopes else math.nan
        verdict = "n/a" if not slopes else "PASS" if worst < SLOPE_LIMIT_MB_H else "FAIL"
        results["roles"][role] = {"processes": per, "verdict": verdict}
        if role == "agent":
            med = float(np.median(slopes)) if slopes else math.nan
            anons = [p["anon_slope_mb_h"] for p in per if math.isfinite(p["anon_slope_mb_h"])]
            print(f"{'agents':>13} {len(per):>3} {np.median([p['first_mb'] for p in per]):>8.1f} "
                  f"{np.median([p['last_mb'] for p in per]):>8.1f} {max(p['max_mb'] for p in per):>8.1f} "
                  f"{fmt(med, '8.2f'):>8} {fmt(float(np.median(anons)) if anons else math.nan, '9.2f'):>9} "
                  f"{fmt(float(np.nanmedian([p['cpu_pct'] for p in per])), '6.1f'):>6}  median over the agents "
                  "(first, last: medians; max: the largest)")
            print(f"{'':>13} {'':>3} {'':>8} {'':>8} {'':>8} {fmt(worst, '8.2f'):>8} "
                  f"{fmt(max(anons) if anons else math.nan, '9.2f'):>9} {'':>6}  the largest slope: {verdict}")
            results["roles"][role].update(median_slope_mb_h=med, max_slope_mb_h=worst)
            if len(per) > (m or len(per)):
                print(f"{'':>13} note: {len(per)} agent processes for {m} agents (some restarted)")
        else:
            for p in per:
                name = p["process"].split("/")[0] + ("" if len(per) == 1 else f" ({p['process'].split('/')[1]})")
                print(f"{name:>13} {1:>3} {p['first_mb']:>8.1f} {p['last_mb']:>8.1f} {p['max_mb']:>8.1f} "
                      f"{fmt(p['slope_mb_h'], '8.2f'):>8} {fmt(p['anon_slope_mb_h'], '9.2f'):>9} "
                      f"{fmt(p['cpu_pct'], '6.1f'):>6}  {verdict}")
    if not series:
        print("  no samples after the warm-up")
    else:
        # a sawtooth (memory taken and given back every so often) makes the straight line's slope depend on where
        # the run stopped in a tooth: the slopes of the blocks' highest and lowest RSS say whether it drifts
        print(f"by blocks of {args.block_minutes:g} min after the warm-up: slopes (MB/h) of each block's highest and "
              f"lowest RSS (a drift moves both; a sawtooth neither)")
        for key, pts in sorted(series.items(), key=lambda kv: order.index(role_of(kv[0].split("/")[0]))
                               if role_of(kv[0].split("/")[0]) in order else len(order)):
            hi, lo, nb = block_slopes(np.array([p[0] for p in pts]) / 3600, np.array([p[1] for p in pts]),
                                      args.block_minutes / 60)
            if nb >= 3 and role_of(key.split("/")[0]) != "agent":
                print(f"{key:>24}: {nb} blocks, highest {hi:8.2f}, lowest {lo:8.2f}")
                results.setdefault("blocks", {})[key] = {"blocks": nb, "max_slope_mb_h": hi, "min_slope_mb_h": lo}
            elif nb >= 3:
                results.setdefault("blocks", {})[key] = {"blocks": nb, "max_slope_mb_h": hi, "min_slope_mb_h": lo}
        agents = [v for k, v in results.get("blocks", {}).items() if role_of(k.split("/")[0]) == "agent"]
        if agents:
            print(f"{'agents':>24}: {len(agents)} processes, largest highest {max(a['max_slope_mb_h'] for a in agents):8.2f}"
                  f", largest lowest {max(a['min_slope_mb_h'] for a in agents):8.2f}")

    # whoever holds the rounds: with orchestrator kills each active process lives one epoch, shorter than its warm-up
    # (a taken-over one grows for a minute or two as it takes the records on); the deployment's memory is the
    # active one's at each moment, each epoch's first --settle-minutes left out
    held = active_series(samples, evs, warmup * 60, args.settle_minutes * 60)
    if held["epochs"] > 1:
        a = np.array(held["points"]).reshape(-1, 2)  # none left when each epoch is shorter than its settling
        slope, _ = slope_r2(a[:, 0] / 3600, a[:, 1]) if len(a) else (math.nan, None)
        hi, lo, nb = block_slopes(a[:, 0] / 3600, a[:, 1], args.block_minutes / 60) if len(a) else (math.nan,) * 3
        verdict = "n/a" if not math.isfinite(slope) else "PASS" if slope < SLOPE_LIMIT_MB_H else "FAIL"
        print(f"the active orchestrator, whoever holds the rounds ({held['epochs']} epochs, each one's first "
              f"{args.settle_minutes:g} min left out, {len(a)} samples): {fmt(a[:, 1].min() if len(a) else math.nan)} to "
              f"{fmt(a[:, 1].max() if len(a) else math.nan)} MB, slope {fmt(slope, '.2f')} MB/h: {verdict}; by blocks of {args.block_minutes:g} min: highest "
              f"{fmt(hi, '.2f')}, lowest {fmt(lo, '.2f')} ({nb} blocks); each epoch's peak: "
              + ", ".join(f"{x:.1f}" for x in held["peaks"]) + " MB")
        results["active_orchestrator"] = {"epochs": held["epochs"], "samples": len(a), "slope_mb_h": slope,
                                          "block_max_slope_mb_h": hi, "block_min_slope_mb_h": lo,
                                          "peaks_mb": held["peaks"], "verdict": verdict}

    # records
    total_end = sum(size for size, _ in final_files.values())
    ta = np.array([s["t"] for s in after], dtype=float)
    tot = np.array([sum(size for size, _ in s["files"].values()) for s in after], dtype=float)
    rate_b, r2 = slope_r2(ta / 3600, tot)
    chunk_paths = sorted(p for p in set(final_files) | set(watch.rewrites) | set(watch.removed)
                         | set(watch.rewrites_close) if p.startswith("chunks/"))
    chunk_rewrites = sum(watch.rewrites.get(p, 0) + watch.rewrites_close.get(p, 0) for p in chunk_paths)
    print(f"\nrecords: {total_end / 1e6:.2f} MB at the end in {len(final_files)} files; "
          f"{fmt(rate_b / 1e6 if math.isfinite(rate_b) else rate_b, '.1f')} MB/h after the warm-up "
          f"(R^2 of a straight line: {fmt(r2, '.5f')}); rewrites of the chunks: {chunk_rewrites} "
          f"({'n/a' if not chunk_paths else 'PASS' if chunk_rewrites == 0 else 'FAIL'}: append-only)")
    print(f"{'files':>22} {'count':>5} {'bytes':>12} {'MB/h':>8} {'R^2':>8} {'rewrites':>8} {'at close':>8} "
          f"{'removed':>7}")
    groups: dict = {}
    for path in set(final_files) | set(watch.removed) | set(watch.rewrites) | set(watch.rewrites_close):
        groups.setdefault(kind(path), []).append(path)
    per_kind = {}
    for name in sorted(groups, key=lambda k: (k not in KIND_ORDER, KIND_ORDER.index(k) if k in KIND_ORDER else 0, k)):
        paths = groups[name]
        ys = np.array([sum(s["files"][p][0] for p in paths if p in s["files"]) for s in after], dtype=float)
        sl, fr2 = slope_r2(ta / 3600, ys)
        size = sum(final_files[p][0] for p in paths if p in final_files)
        count = sum(p in final_files for p in paths)
        rw, rc, rm = (sum(d.get(p, 0) for p in paths) for d in (watch.rewrites, watch.rewrites_close, watch.removed))
        per_kind[name] = {"files": count, "bytes": size, "mb_h": sl / 1e6 if math.isfinite(sl) else None, "r2": fr2,
                          "rewrites": rw, "rewrites_at_close": rc, "removed": rm}
        print(f"{name:>22} {count:>5} {size if count else 'gone':>12} {fmt(sl / 1e6, '8.2f'):>8} {fmt(fr2, '8.5f'):>8} "
              f"{rw:>8} {rc:>8} {rm:>7}")
    for note in watch.notes[:20]:
        print(f"  {note}")
    if len(watch.notes) > 20:
        print(f"  ... {len(watch.notes) - 20} more (--json has them all)")
    results["records"] = {"bytes_end": total_end, "mb_h": rate_b / 1e6 if math.isfinite(rate_b) else None, "r2": r2,
                          "chunk_rewrites": chunk_rewrites, "kinds": per_kind, "notes": watch.notes,
                          "files_end": {p: size for p, (size, _) in final_files.items()}}

    # rows and lateness
    period_ms = 1e3 / args.pace
    if rows is None:
        print("\nrows: no chunks (chunks/rows-*.arrows) in the records")
        results["rows"] = None
    else:
        tau, wall, late = rows["tau"], rows["wall"], rows["round"][:, 4]
        span = (wall[-1] - wall[0]) / 1e9 if len(wall) > 1 else math.nan
        rps = (len(tau) - 1) / span if span and math.isfinite(span) and span > 0 else math.nan
        gaps = int(tau[-1] - tau[0] + 1 - len(tau)) if len(tau) else 0
        print(f"\nrows ({rows['how']}): {len(tau)} event times in {rows['segments']} chunk segment(s) (tau {tau[0]}..{tau[-1]}, "
              f"{gaps} missing); {fmt(rps, '.2f')} per second over {fmt(span, '.1f')} s of wall clock, "
              f"{fmt(rps / args.pace if math.isfinite(rps) else math.nan, '.4f')} x pace")
        fin = late[np.isfinite(late)]
        results["rows"] = {"rows": int(len(tau)), "missing": gaps, "rows_per_second": rps, "segments": rows["segments"],
                           "late_ms_recorded": int(len(fin))}
        if len(fin):
            p50, p90, p99 = np.percentile(fin, [50, 90, 99])
            nlate = int(np.sum(fin > LATE_FRACTION * period_ms))
            print(f"lateness (late_ms of {len(fin)} event times, period {period_ms:g} ms): p50 {p50:.2f} p90 {p90:.2f} "
                  f"p99 {p99:.2f} max {fin.max():.2f} ms; later than {LATE_FRACTION:.0%} of a period "
                  f"({LATE_FRACTION * period_ms:g} ms): {nlate} ({100 * nlate / len(fin):.2f}%)")
            results["rows"].update(late_p50=p50, late_p90=p90, late_p99=p99, late_max=float(fin.max()),
                                   late_over_10pct=nlate)
            # a fault: the round of a restart's event time waits for the new process's token (spawn to ready), a
            # kill's for the loss to be seen; the next ones catch up.  Reported apart, and left out of the lateness
            # around the rolls
            restarts = sorted(int(e["tau"]) for e in evs if e.get("event") in ("agent_restarting", "agent_lost",
                                                                                "orchestrator_takeover")
                              and e.get("tau") is not None)
            catch_up = np.zeros(len(tau), dtype=bool)
            for r in restarts:
                catch_up |= (tau >= r) & (tau < r + RESTART_CATCH_UP)
            takeovers = [e for e in evs if e.get("event") == "orchestrator_takeover"]
            if takeovers:  # each stall: from the dead one's last tick to its successor's first
                stalls = np.array([float(e["stall_ms"]) for e in takeovers])
                print(f"  {len(takeovers)} orchestrator takeovers: stall median {np.median(stalls):.0f} ms, max "
                      f"{stalls.max():.0f} ms ({'PASS' if stalls.max() < 1000 else 'FAIL'}: under 1 s); "
                      f"{sum(e.get('event') == 'rows_missing' for e in evs)} rows_missing events")
                results["rows"].update(takeovers=len(takeovers), stall_ms_median=float(np.median(stalls)),
                                       stall_ms_max=float(stalls.max()), stalls_ms=stalls.tolist())
            if restarts:
                at = np.isin(tau, restarts) & np.isfinite(late)
                rest = ~catch_up & np.isfinite(late)
                # each fault's own catch-up: from its event time to the first one that starts less than a tenth of
                # a period late (a takeover on a restart's event time waits for both, and takes longer than 25)
                caught = np.zeros(len(tau), dtype=bool)
                longest = 0
                index = {int(t): k for k, t in enumerate(tau)}
                for r in restarts:
                    k = index.get(r)
                    if k is None:
                        continue
                    j = k + 1
                    while j < len(tau) and not late[j] < LATE_FRACTION * period_ms:
                        j += 1
                    caught[k:j] = True
                    longest = max(longest, j - k)
                apart = ~caught & np.isfinite(late)
                outside = float(late[apart].max()) if apart.any() else math.nan
                print(f"  outside each kill's, restart's and takeover's catch-up (its event times until one starts "
                      f"less than {LATE_FRACTION * period_ms:g} ms late; the longest {longest}): max late "
                      f"{fmt(outside, '.1f')} ms, {int(np.sum(late[apart] > period_ms))} event times later than a "
                      "period: " + ("n/a" if not math.isfinite(outside) else "PASS" if outside <= period_ms else "FAIL"))
                results["rows"].update(late_max_outside_catch_up=outside, longest_catch_up=longest)
                print(f"  at the {len(restarts)} kills and restarts (the round waits for the loss or the new "
                      f"process): max late "
                      f"{fmt(float(late[at].max()) if at.any() else math.nan, '.1f')} ms, median "
                      f"{fmt(float(np.median(late[at])) if at.any() else math.nan, '.1f')} ms; every other event time "
                      f"(the {RESTART_CATCH_UP} after each left out): max late "
                      f"{fmt(float(late[rest].max()) if rest.any() else math.nan, '.2f')} ms, p99 "
                      f"{fmt(float(np.percentile(late[rest], 99)) if rest.any() else math.nan, '.2f')} ms")
                results["rows"].update(restarts=len(restarts),
                                       late_max_at_restarts=float(late[at].max()) if at.any() else None,
                                       late_max_apart=float(late[rest].max()) if rest.any() else None)
            outside_faults = apart if restarts else np.isfinite(late)
            results["machine_stalls"] = machine_stalls(canary_path, tau, wall, late, outside_faults, period_ms)
            # a file rewritten while running (run.rrd's segment finished as it rolls): the lateness around it
            near = []
            for w, path in watch.walls:
                lo, hi = (w - args.sample_seconds - 5.0) * 1e9, (w + 5.0) * 1e9
                sel = (wall >= lo) & (wall <= hi) & np.isfinite(late) & ~catch_up
                near.append({"path": path, "wall": w, "rows": int(sel.sum()),
                             "restart_rows_left_out": int(((wall >= lo) & (wall <= hi) & catch_up).sum()),
                             "late_max": float(late[sel].max()) if sel.any() else None,
                             "late_over_10pct": int(np.sum(late[sel] > LATE_FRACTION * period_ms))})
            for e in near[:20]:
                print(f"  around the rewrite of {e['path']} (the sample's {args.sample_seconds:g} s before it, 5 s "
                      f"either side): {e['rows']} event times, max late {fmt(e['late_max'], '.1f')} ms, "
                      f"{e['late_over_10pct']} later than {LATE_FRACTION:.0%} of a period"
                      + (f" ({e['restart_rows_left_out']} after a kill or restart left out)" if e["restart_rows_left_out"]
                         else ""))
            if near:
                worst = max((e["late_max"] for e in near if e["late_max"] is not None), default=math.nan)
                print(f"  around every rewrite ({len(near)}): max late {fmt(worst, '.1f')} ms: "
                      + ("n/a" if not math.isfinite(worst) else "PASS" if worst <= period_ms else "FAIL")
                      + f" against a period ({period_ms:g} ms)")
            results["rows"]["around_rewrites"] = near
        else:
            print("lateness: n/a (the chunks' late_ms is NaN or absent in every row)")
    keys = ("reason", "late_event_times", "max_lateness_ms", "achieved_rate", "pace", "pace_kept")
    print(f"end event: {end.get('event', 'none')}: " + ", ".join(f"{k} {end[k] if k in end else 'n/a'}" for k in keys)
          + f"; event_times {end.get('event_times', 'n/a')}, rounds_per_second {end.get('rounds_per_second', 'n/a')}, "
            f"messages_lost {end.get('messages_lost', 'n/a')}, agents_lost {end.get('agents_lost', 'n/a')}")

    # retention (run.keep): what went, what is on hand over time, and no row lost at the cut
    removed = [e for e in evs if e.get("event") == "records_removed"]
    disk = [(s["t"], sum(size for size, _ in s["files"].values())) for s in samples if s["t"] is not None]
    results["retention"] = {"removed": len(removed), "removed_bytes": sum(int(e.get("bytes") or 0) for e in removed)}
    if disk:
        print(f"\ndisk on hand (every file under --out), the largest per {DISK_WINDOW_S / 60:g} min of running:")
        per = {}
        for t, b in disk:
            k = int(t // DISK_WINDOW_S)
            per[k] = max(per.get(k, 0), b)
        print("  " + "  ".join(f"{k * DISK_WINDOW_S / 60:g}-{(k + 1) * DISK_WINDOW_S / 60:g} min {v / 1e6:.0f} MB"
                                 for k, v in sorted(per.items())))
        results["retention"]["disk_max_per_window_mb"] = {str(k): v / 1e6 for k, v in sorted(per.items())}
        if args.keep_minutes is not None:
            filled = [b for t, b in disk if t >= args.keep_minutes * 60 + DISK_WINDOW_S]
            if filled:
                print(f"  after the retention window filled ({args.keep_minutes:g} min + {DISK_WINDOW_S / 60:g}): "
                      f"largest {max(filled) / 1e6:.0f} MB, smallest {min(filled) / 1e6:.0f} MB, at the end "
                      f"{disk[-1][1] / 1e6:.0f} MB")
                results["retention"].update(filled_max_mb=max(filled) / 1e6, filled_min_mb=min(filled) / 1e6)
    if removed:
        kinds = {}
        for e in removed:
            kinds.setdefault(e.get("kind"), []).append(e)
        print(f"run.keep removed {len(removed)} segments ({results['retention']['removed_bytes'] / 1e9:.2f} GB): "
              + ", ".join(f"{k} {len(v)}" for k, v in sorted(kinds.items())))
        if rows is not None and kinds.get("chunks"):
            cut = max(e["last_tau"] for e in kinds["chunks"]) + 1
            first = rows["first_on_disk"] if rows["first_on_disk"] is not None else cut + 1
            ok = first <= cut
            print(f"  rows: the last removed chunk ended at event time {cut - 1}; the first row on disk is {first}: "
                  + ("none lost at the cut (PASS)" if ok else f"{first - cut} lost at the cut (FAIL)"))
            results["retention"].update(cut=cut, first_on_disk=first, lost_at_cut=max(0, first - cut))
    if idle:
        normal_class(os.getpid())  # the run is over: the replay at the normal class
    if rows is not None and not args.no_replay:
        results["replay"] = replay(out, scen)

    counts: dict = {}
    for e in evs:  # what happened besides the start-up: warnings, losses, restarts
        if e.get("event") not in QUIET_EVENTS:
            counts[e.get("event")] = counts.get(e.get("event"), 0) + 1
    print("other events: " + (", ".join(f"{k} {v}" for k, v in sorted(counts.items())) or "none"))
    results["event_counts"] = counts
    last = [line for line in (_read(str(out.parent / f"{out.name}.stdout.log")) or "").splitlines() if line.strip()]
    if last:
        print(f"splitspec run said: {last[-1]}")

    if args.json is not None:
        args.json.write_text(json.dumps({"args": {k: str(v) if isinstance(v, Path) else v for k, v in vars(args).items()},
                                         "scenario": str(scen), "out": str(out), "results": results,
                                         "samples": samples}, default=float, indent=1))
        print(f"# samples and results in {args.json}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
