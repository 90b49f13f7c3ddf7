"""The one writer of the ``trajectory.npz`` contract (DESIGN.md "Trajectories"), shared by ``simulate`` and ``run``.

Arrays: ``t`` (T,), ``x`` (T, n), ``xhat`` (T, m, n) NaN where dead,
``alive`` (T, m) bool, ``graph`` (T,) int, ``agent_ids`` (m,), and ``g``
(T, m): the gain ``g_i(t)`` of each agent (eq. adaptive for the adaptive gain,
the designed scalar ``g`` for a fixed continuous-time gain), NaN where the
agent is dead and everywhere in discrete time (there is no ``g``); ``lost`` (N, 4)
int64: every consensus message that did not count, one row ``(event time,
sub-round k, sender j, receiver i)`` in that order, and ``lost_cause`` (N,) int8
(0 loss, 1 late, 2 partition: :mod:`splitspec_core.model.impairment`); empty on a
perfect network; ``states`` (n,) str: the states' names (``system.states``, else ``x1 .. xn``).

The file is written atomically: a temporary file in the same directory,
flushed and fsynced, then ``os.replace``; a reader never sees a torn file and
a failed write leaves the previous file in place.
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

import numpy as np

__all__ = ["TRAJECTORY_FILE", "OPTIONAL", "write_trajectory", "no_gains", "lost_arrays"]

TRAJECTORY_FILE = "trajectory.npz"
#: arrays written only when there is something to say: the measurements the estimators were given
#: (``y`` (T, sum s_i), ``y_missing`` (T, m)) and, without truth, what can be known instead of the error
#: (:func:`splitspec_core.studies.no_truth.no_truth_arrays`): ``residual`` (T, m), ``disagreement`` (T,),
#: ``kf`` (T, n) and ``kf_distance`` (T, m)
OPTIONAL = ("y", "y_missing", "residual", "disagreement", "kf", "kf_distance")


def no_gains(T: int, m: int) -> np.ndarray:
    """``g`` where there is none (discrete time): all NaN, shape (T, m)."""
    return np.full((T, m), np.nan)


def lost_arrays(rows) -> tuple:
    """``(lost, lost_cause)`` from ``(tau, k, j, i, cause)`` rows, sorted by ``(tau, k, j, i)``."""
    a = np.array(sorted(rows), dtype=np.int64).reshape(-1, 5)
    return a[:, :4].copy(), a[:, 4].astype(np.int8)


def write_trajectory(path: str | Path, *, t: np.ndarray, x: np.ndarray, xhat: np.ndarray, alive: np.ndarray,
                     graph: np.ndarray, agent_ids: np.ndarray, g: np.ndarray | None = None,
                     lost: np.ndarray | None = None, lost_cause: np.ndarray | None = None,
                     extra: dict | None = None, states=None) -> None:
    """Atomically write ``path`` with the trajectory arrays (``g`` all NaN if None).

    Raises
    ------
    OSError
        If the file cannot be written; ``path`` is left as it was and no temporary file remains.
    """
    path = Path(path)
    T, m = np.shape(alive)
    arrays = dict(t=t, x=x, xhat=xhat, alive=alive, graph=graph, agent_ids=agent_ids,
                  g=no_gains(T, m) if g is None else g,
                  lost=np.zeros((0, 4), dtype=np.int64) if lost is None else np.asarray(lost, dtype=np.int64),
                  lost_cause=np.zeros(0, dtype=np.int8) if lost_cause is None else np.asarray(lost_cause, np.int8))
    if states is not None:
        arrays["states"] = np.array([str(s) for s in states], dtype=str)
    for k, v in (extra or {}).items():
        if k not in OPTIONAL:
            raise ValueError(f"write_trajectory: {k!r} is not an optional array of the contract ({', '.join(OPTIONAL)})")
        if v is not None:
            arrays[k] = np.asarray(v)
    tmp = None
    try:
        fd, tmp = tempfile.mkstemp(prefix=f".{path.stem}.", suffix=".npz.tmp", dir=path.parent)
        with os.fdopen(fd, "wb") as f:
            np.savez(f, **arrays)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        if tmp is not None:
            try:
                Path(tmp).unlink(missing_ok=True)
            except OSError:
                pass
        raise
