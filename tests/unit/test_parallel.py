"""splitspec_core.parallel: the loss cases of a resilient design on worker processes (issue 22, item 2).

fork_map gives the serial loop's results in order, really on other processes, each with one BLAS thread; an
error in a worker reaches the caller; the workers die with a SIGKILLed parent.  A resilient design on workers
gives the q, the verdict and the radii of the design on one process."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

from splitspec_core import parallel
from splitspec_core.synthesis import spectral
from splitspec_core.synthesis.designer import design
from splitspec_core.scenarios.generate import ring_scenario
from splitspec_core.scenarios.load import parse_scenario
from splitspec_orchestrator.registry import pid_running

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="fork_map forks on Linux only")


def _square_and_pid(state, item):
    time.sleep(0.01)  # long enough that one worker does not take every chunk before the other has started
    return state * item * item, os.getpid()


def _blas_threads(state, item):
    from threadpoolctl import threadpool_info

    return sorted({lib["num_threads"] for lib in threadpool_info() if lib["user_api"] == "blas"})


def _fail_on(state, item):
    if item == state:
        raise ValueError(f"item {item} refused")
    return item


def test_fork_map_gives_the_serial_results_in_order_from_other_processes():
    items = list(range(40))
    out = parallel.fork_map(_square_and_pid, 3, items, workers=2)
    assert [v for v, _ in out] == [3 * i * i for i in items]
    pids = {p for _, p in out}
    assert os.getpid() not in pids and len(pids) == 2  # two workers shared the items


def test_fork_map_runs_here_when_there_is_too_little_to_share():
    assert {p for _, p in parallel.fork_map(_square_and_pid, 1, range(40), workers=1)} == {os.getpid()}
    few = range(2 * parallel.MIN_PER_WORKER - 1)  # fewer than MIN_PER_WORKER items per worker for 2 workers
    assert {p for _, p in parallel.fork_map(_square_and_pid, 1, few, workers=2)} == {os.getpid()}


def test_each_worker_uses_one_blas_thread():
    """Two workers with OpenBLAS's own thread pool each oversubscribe the cores (a resilient design of 300 agents
    took 8.2 s on 2 workers against 5.3 s on one process): the workers limit BLAS to one thread."""
    assert parallel.fork_map(_blas_threads, None, range(32), workers=2) == [[1]] * 32


def test_an_error_in_a_worker_reaches_the_caller():
    with pytest.raises(ValueError, match="item 17 refused"):
        parallel.fork_map(_fail_on, 17, range(40), workers=2)


def test_the_workers_die_with_a_sigkilled_parent(tmp_path):
    """A design killed half way leaves no worker behind (PR_SET_PDEATHSIG, asked for by each worker)."""
    script = (
        "import os, sys, time\n"
        "from pathlib import Path\n"
        "from splitspec_core.parallel import fork_map\n"
        "def stay(d, item):\n"
        "    Path(d, str(os.getpid())).touch()\n"
        "    time.sleep(120)\n"
        f"fork_map(stay, {str(tmp_path)!r}, range(32), workers=2)\n")
    parent = subprocess.Popen([sys.executable, "-c", script], stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 60
        while len(list(tmp_path.iterdir())) < 2 and time.monotonic() < deadline:  # both workers are working
            time.sleep(0.05)
        workers = [int(p.name) for p in tmp_path.iterdir()]
        assert len(workers) == 2 and parent.poll() is None, parent.stderr.read() if parent.poll() is not None else ""
        parent.send_signal(signal.SIGKILL)
        parent.wait(timeout=10)
        deadline = time.monotonic() + 10
        while any(pid_running(p) for p in workers) and time.monotonic() < deadline:
            time.sleep(0.05)
        assert not any(pid_running(p) for p in workers)
    finally:
        if parent.poll() is None:
            parent.kill()
            parent.wait()


def test_a_resilient_design_on_workers_equals_the_design_on_one_process(monkeypatch):
    """Every spectral radius iterative (ARPACK), the 121 cases of a resilient chord ring of 120 agents: the same q,
    verdict and methods; each radius the same up to round-off (the workers' BLAS runs on one thread, this
    process's on as many as OpenBLAS chose: other summation orders; 1e-10 relative is far below the 1e-6 the
    iterative radii claim)."""
    monkeypatch.setattr(spectral, "DENSE_MAX", 0)
    calls, real = [], spectral.radii
    monkeypatch.setattr(spectral, "radii", lambda cases, q, **kw: calls.append((len(cases), kw["workers"]))
                        or real(cases, q, **kw))
    raw = ring_scenario(120, 6, resilience=1, rate=0.9, chords=True)
    one, two = (design(parse_scenario(raw, source="<test>"), workers=w) for w in (1, 2))
    assert calls == [(120, 1), (120, 2)]  # the 120 loss cases at once, after the network's own search
    assert one.q == two.q and one.q_result.certified == two.q_result.certified
    assert one.q_result.eig == two.q_result.eig and one.q_result.eig["methods"] == {"iterative": 121}
    assert one.error_radius.keys() == two.error_radius.keys()
    for label, rho in one.error_radius.items():
        assert two.error_radius[label] == pytest.approx(rho, rel=1e-10), label
    assert np.isclose(one.q_result.bound, two.q_result.bound, rtol=1e-10, atol=0)
