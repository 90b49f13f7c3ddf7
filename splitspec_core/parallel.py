"""Independent computations of one design on every core: the cases of a resilient design, one per process.

A resilient design of 1000 agents asks for the spectral radius of 1001 cases (the network and the network
without each agent); each costs tens of milliseconds of ARPACK, which holds the GIL for most of it, so threads do
not help.  :func:`fork_map` forks worker processes that inherit the cases (nothing is pickled but the results),
evaluates a pure function of ``(state, item)`` in them, and returns the results in order: the same numbers as the
serial loop, because each is the same code on the same data.

Fork only (Linux): a forked child starts at once and shares the parent's memory copy-on-write; spawn or forkserver
would import the user's ``__main__`` again (a script that designs at its top level would then design again in
every worker).  Elsewhere, for small inputs, or with one worker, the loop runs serially in this process.

The workers die with this process (``PR_SET_PDEATHSIG``): a design killed half way leaves no process behind.
"""

from __future__ import annotations

import os
import sys
import warnings
from typing import Callable, Sequence

__all__ = ["available_workers", "fork_map", "sigterm_at_parent_death"]

PR_SET_PDEATHSIG = 1
MIN_PER_WORKER = 8  # items per worker below which forking costs more than it saves

_state = None  # in a worker only: what fork_map's initializer received
_fn = None
_blas = None  # in a worker only: its BLAS thread limit, kept alive


def available_workers() -> int:
    """The CPUs this process may run on (its affinity mask, as ``taskset`` or a container sets it).

    Returns
    -------
    int
        At least 1; ``os.cpu_count()`` where the affinity mask cannot be read (not Linux).
    """
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # not Linux
        return max(1, os.cpu_count() or 1)


def sigterm_at_parent_death() -> bool:
    """Ask the kernel for SIGTERM when this process's parent dies (``PR_SET_PDEATHSIG``); False if it cannot.

    Returns
    -------
    bool
        True when the request was made; False where ``libc.so.6`` or ``prctl`` is missing (not Linux).
    """
    import ctypes
    import signal

    try:
        ctypes.CDLL("libc.so.6", use_errno=True).prctl(PR_SET_PDEATHSIG, signal.SIGTERM)
    except (OSError, AttributeError):
        return False
    return True


def _init(fn, state) -> None:
    global _state, _fn, _blas
    from threadpoolctl import threadpool_limits

    sigterm_at_parent_death()
    # one BLAS thread per worker: the workers are the parallelism (two workers with OpenBLAS's two threads each
    # ran slower than one process on 2 cores: 8.2 s against 5.3 s for a resilient design of 300 agents)
    _blas = threadpool_limits(1)
    _fn, _state = fn, state


def _call(item):
    return _fn(_state, item)


def fork_map(fn: Callable, state, items: Sequence, *, workers: int | None = None) -> list:
    """``[fn(state, item) for item in items]``, spread over ``workers`` forked processes.

    Parameters
    ----------
    fn : callable
        A module-level function ``fn(state, item) -> result`` (the result is pickled back; ``state`` is not: the
        workers inherit it).
    state
        What every call needs (inherited by the forked workers).
    items : sequence
        Small, picklable (indices, say).
    workers : int or None
        Processes to use; ``None``: :func:`available_workers`.  Serial when 1, when there are fewer than
        ``MIN_PER_WORKER`` items per worker, or without ``fork``.

    Returns
    -------
    list
        The results in the order of ``items``: the serial loop's values.

    Examples
    --------
    >>> fork_map(pow, 2, range(5))  # few items: the serial loop
    [1, 2, 4, 8, 16]
    """
    items = list(items)
    workers = available_workers() if workers is None else int(workers)
    workers = min(workers, len(items) // MIN_PER_WORKER)
    if workers <= 1 or not sys.platform.startswith("linux"):
        return [fn(state, item) for item in items]
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor

    with warnings.catch_warnings():
        # Python >= 3.12 warns when a process with other threads forks.  Here those are OpenBLAS's idle pool
        # (re-created in the child through its pthread_atfork handlers) and whatever the caller runs; the workers
        # run numpy and scipy only and touch none of the caller's locks.
        warnings.filterwarnings("ignore", message=r".*multi-threaded, use of fork\(\)", category=DeprecationWarning)
        # a worker that dies (killed, out of memory) raises BrokenProcessPool here instead of hanging the map
        with ProcessPoolExecutor(workers, mp_context=multiprocessing.get_context("fork"), initializer=_init,
                                 initargs=(fn, state)) as pool:
            # chunks of a few items: each worker stays busy, and a slow item (a dense fallback) idles no other
            return list(pool.map(_call, items, chunksize=max(1, len(items) // (4 * workers))))
