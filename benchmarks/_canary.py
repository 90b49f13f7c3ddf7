"""The machine's own timekeeping beside a soak: a bare periodic sleeper at the run's priority (imported as
``_canary`` by ``bench_soak.py``, which starts it as ``python benchmarks/_canary.py FILE PERIOD_S``).

Each tick it sleeps to the next deadline of a fixed grid (``PERIOD_S`` apart, missed deadlines skipped, not
caught up) and writes one record: the wall time it woke, how late it woke against its deadline (ms), and the
cumulative jiffies of /proc/stat's first line spent in ``steal`` (the hypervisor ran something else on this
virtual machine's cores) and busy (user, nice, system, irq, softirq: every core of the machine, whoever ran).
A round of the run that starts late while this sleeper, which does nothing, also woke late, or while the
hypervisor stole the cores (reported beside, not counted: :func:`stalls`), was late for the machine, not for the product.  It stops on SIGTERM or when its
parent goes.  The records are float64 rows of :data:`FIELDS`, appended once a second (:func:`read`).
"""

from __future__ import annotations

import os
import signal
import sys
import time
from pathlib import Path

import numpy as np

FIELDS = ("wall_s", "late_ms", "steal_jiffies", "busy_jiffies")
FLUSH_S = 1.0
STEAL_CORES = 0.5  #: a stall: the hypervisor stole at least this much of a core on average ...
STEAL_WINDOW_S = 0.2  #: ... over this many seconds


def cpu_jiffies() -> tuple[float, float]:
    """``(steal, busy)`` cumulative jiffies of every core (/proc/stat's ``cpu`` line)."""
    with open("/proc/stat", "rb") as f:
        v = f.readline().split()
    user, nice, system, _idle, _iowait, irq, softirq, steal = (float(x) for x in v[1:9])
    return steal, user + nice + system + irq + softirq


def read(path: Path) -> np.ndarray:
    """The records written so far, one row per tick, columns :data:`FIELDS` (an empty array without a file)."""
    if not Path(path).exists():
        return np.empty((0, len(FIELDS)))
    raw = np.fromfile(path, dtype=np.float64)
    return raw[: len(raw) // len(FIELDS) * len(FIELDS)].reshape(-1, len(FIELDS))


def stalls(rec: np.ndarray, over_ms: float, steal_cores: float = STEAL_CORES,
           window_s: float = STEAL_WINDOW_S) -> list[tuple[float, float]]:
    """The intervals ``(start, end)`` (wall seconds, merged, in order) in which the machine stalled: the sleeper woke
    more than ``over_ms`` late (from its deadline to its wake-up), or the hypervisor stole at least ``steal_cores``
    of a core on average over the ``window_s`` before a tick (that window).

    Not any steal: on a shared virtual machine the hypervisor steals a little all the time (4 s of 264 core-seconds
    in a 2-minute soak of 2026-11-30, in 304 ticks covering 5.6 % of it), most of it from a core nothing needed
    then.  Half a core over 0.2 s covered 0.2 % of that soak, and the one event time there later than a period that
    the sleeper did not see (22 ms; the sleeper needs little of a core, a round much more) fell in it."""
    out = [(float(w - late / 1e3), float(w)) for w, late in rec[rec[:, 1] > over_ms, :2]]
    if len(rec) > 1:
        t = rec[:, 0]
        j0 = np.searchsorted(t, t - window_s)
        cores = (rec[:, 2] - rec[j0, 2]) / os.sysconf("SC_CLK_TCK") / np.maximum(t - t[j0], 1e-9)
        out += [(float(t[j]), float(t[k])) for k, j in enumerate(j0) if cores[k] >= steal_cores and j < k]
    out.sort()
    merged: list = []
    for a, b in out:
        if merged and a <= merged[-1][1]:
            merged[-1] = (merged[-1][0], max(merged[-1][1], b))
        else:
            merged.append((a, b))
    return merged


def main(path: str, period: float) -> int:
    parent = os.getppid()
    stop = []
    signal.signal(signal.SIGTERM, lambda *_: stop.append(1))
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # a Ctrl-C of the soak: the soak stops this one
    buf: list = []
    next_flush = time.monotonic() + FLUSH_S
    deadline = time.monotonic()
    with open(path, "ab", buffering=0) as f:
        while not stop and os.getppid() == parent:
            deadline += period
            now = time.monotonic()
            if deadline < now:  # missed: skip to the next deadline of the grid, do not catch up
                deadline += period * (int((now - deadline) / period) + 1)
            time.sleep(max(0.0, deadline - time.monotonic()))
            woke = time.monotonic()
            steal, busy = cpu_jiffies()
            buf.append((time.time(), (woke - deadline) * 1e3, steal, busy))
            if woke >= next_flush:
                f.write(np.asarray(buf, dtype=np.float64).tobytes())
                buf.clear()
                next_flush = woke + FLUSH_S
        if buf:
            f.write(np.asarray(buf, dtype=np.float64).tobytes())
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1], float(sys.argv[2])))
