"""The soak's machine canary (benchmarks/_canary.py): a real sleeper process writes its records, and the stalls
it reports are the ones in them."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

BENCH = Path(__file__).resolve().parents[2] / "benchmarks"
sys.path.insert(0, str(BENCH))
import _canary  # noqa: E402  (the benchmarks' folder, as their scripts import it)


def test_the_sleeper_writes_a_tick_per_period_until_terminated(tmp_path):
    path = tmp_path / "c.f64"
    proc = subprocess.Popen([sys.executable, str(BENCH / "_canary.py"), str(path), "0.02"])
    try:
        deadline = time.monotonic() + 30
        while len(_canary.read(path)) < 60 and time.monotonic() < deadline:
            time.sleep(0.2)
    finally:
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(timeout=10) == 0
    rec = _canary.read(path)
    assert len(rec) >= 60 and rec.shape[1] == len(_canary.FIELDS)
    assert np.all(np.diff(rec[:, 0]) > 0) and np.all(np.diff(rec[:, 2]) >= 0) and np.all(np.diff(rec[:, 3]) >= 0)
    ticks = np.diff(rec[:, 0])
    # a grid of 20 ms, missed deadlines skipped: every gap a whole number of periods, give or take the wake-ups
    assert abs(float(np.median(ticks)) - 0.02) < 0.005, np.median(ticks)
    assert np.all(rec[:, 1] >= 0)


def test_stalls_are_the_late_wake_ups_and_the_windows_of_heavy_steal():
    hz = os.sysconf("SC_CLK_TCK")
    t = np.arange(100) * 0.02 + 1000.0
    late = np.full(100, 0.3)
    late[10] = 35.0  # woke 35 ms late at tick 10
    steal = np.zeros(100)
    # from tick 50 on, a whole core stolen for 0.3 s (15 ticks), then nothing
    steal[50:65] = np.arange(1, 16) * 0.02 * hz
    steal[65:] = steal[64]
    rec = np.c_[t, late, steal, np.zeros(100)]
    st = _canary.stalls(rec, over_ms=10.0)
    assert st[0] == (t[10] - 0.035, t[10])
    assert len(st) == 2 and st[1][0] < t[52] and t[64] <= st[1][1] <= t[64] + 0.2 + 1e-9, st
    # a little steal (a tenth of a core) all along is no stall
    rec[:, 2] = np.arange(100) * 0.02 * hz * 0.1
    assert _canary.stalls(rec, over_ms=10.0) == [(t[10] - 0.035, t[10])]
