"""The one writer of the ``trajectory.npz`` contract (DESIGN.md "Trajectories"), shared by ``simulate`` and ``run``.

Arrays: the row schema's columns with ``npz`` (:data:`splitspec_core.model.rows.COLUMNS`): ``t`` (T,),
``x`` (T, n), ``xhat`` (T, m, n) NaN where dead, ``alive`` (T, m) bool, ``graph`` (T,) int, and every column
the agents report (T, m), its fill where the agent is dead or the run has none -- such as ``g``, the gain
``g_i(t)`` of each agent (eq. adaptive for the adaptive gain, the designed scalar ``g`` for a fixed
continuous-time gain), NaN where the agent is dead and everywhere in discrete time (there is no ``g``); then
``agent_ids`` (m,); ``lost`` (N, 4)
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

from ..model.rows import REPORTED, empty

__all__ = ["TRAJECTORY_FILE", "OPTIONAL", "write_trajectory", "lost_arrays"]

TRAJECTORY_FILE = "trajectory.npz"
#: arrays written only when there is something to say: the measurements the estimators were given
#: (``y`` (T, sum s_i), ``y_missing`` (T, m)), the known inputs they used (``u`` (T, p), a system with ``system.B``:
#: the signal's, a measurements file's or the live inputs' each agent took; NaN where no agent used one) and,
#: without truth, what can be known instead of the error (:func:`splitspec_core.studies.no_truth.no_truth_arrays`):
#: ``residual`` (T, m), ``disagreement`` (T,), ``kf`` (T, n) and ``kf_distance`` (T, m)
OPTIONAL = ("y", "y_missing", "u", "residual", "disagreement", "kf", "kf_distance")


def lost_arrays(rows) -> tuple:
    """``(lost, lost_cause)`` from ``(tau, k, j, i, cause)`` rows, sorted by ``(tau, k, j, i)``.

    Parameters
    ----------
    rows : iterable of tuple of 5 int
        ``(tau, k, j, i, cause)`` of the consensus messages that did not count.

    Returns
    -------
    lost : (N, 4) int64 ndarray
        ``(tau, k, j, i)``, sorted.
    lost_cause : (N,) int8 ndarray
        The causes, in the same order.

    Examples
    --------
    >>> lost, cause = lost_arrays([(3, 1, 2, 1, 0), (1, 2, 1, 3, 2)])
    >>> lost
    array([[1, 2, 1, 3],
           [3, 1, 2, 1]])
    >>> cause
    array([2, 0], dtype=int8)
    """
    a = np.array(sorted(rows), dtype=np.int64).reshape(-1, 5)
    return a[:, :4].copy(), a[:, 4].astype(np.int8)


def write_trajectory(path: str | Path, *, t: np.ndarray, x: np.ndarray, xhat: np.ndarray, alive: np.ndarray,
                     graph: np.ndarray, agent_ids: np.ndarray, columns: dict | None = None,
                     lost: np.ndarray | None = None, lost_cause: np.ndarray | None = None,
                     extra: dict | None = None, states=None) -> None:
    """Atomically write ``path`` with the trajectory arrays.

    Parameters
    ----------
    path : str or Path
    t, x, xhat, alive, graph, agent_ids : numpy.ndarray
        The rows (see the module docstring).
    columns : dict, optional
        The reported columns (:data:`~splitspec_core.model.rows.REPORTED`) by name, (T, m) each; one not given is
        written as its fill.
    lost, lost_cause : numpy.ndarray, optional
        The consensus messages that did not count (none if None).
    extra : dict, optional
        Arrays of :data:`OPTIONAL` (None values left out).
    states : sequence of str, optional
        The states' names.

    Raises
    ------
    OSError
        If the file cannot be written; ``path`` is left as it was and no temporary file remains.
    ValueError
        A key of ``columns`` or ``extra`` that is not one of the contract.
    """
    path = Path(path)
    T, m = np.shape(alive)
    columns = dict(columns or {})
    unknown = set(columns) - {c.name for c in REPORTED}
    if unknown:
        raise ValueError(f"write_trajectory: {sorted(unknown)} are not reported columns "
                         f"({', '.join(c.name for c in REPORTED)})")
    arrays = dict(t=t, x=x, xhat=xhat, alive=alive, graph=graph, agent_ids=agent_ids)
    for c in REPORTED:
        v = columns.get(c.name)
        arrays[c.name] = empty(c, T, m, 0) if v is None else np.asarray(v, dtype=c.dtype)
    arrays.update(lost=np.zeros((0, 4), dtype=np.int64) if lost is None else np.asarray(lost, dtype=np.int64),
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
