"""Summaries of trajectories: errors per agent, measured decay rate, steady-state RMS error, Monte Carlo statistics."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..synthesis.verdict import NO_CERTIFIED_RATE
from ..model.network import fault_step
from ..scenarios.faults import ORCHESTRATOR
from .simulator import Trajectory

__all__ = ["max_error", "fit_decay", "fault_effects", "faults_in_force", "transient_steps", "envelope_constant",
           "envelope_restarts", "envelope", "Mark", "event_marks",
           "summarize", "steady_rms", "monte_carlo_stats", "rms_stats", "NO_CERTIFIED_RATE"]


def max_error(traj: Trajectory) -> np.ndarray:
    """``max_i |x_i(t) - x(t)|`` over alive agents, shape (T,) (NaN when nobody is alive).

    Parameters
    ----------
    traj : Trajectory
        The run.

    Returns
    -------
    (T,) ndarray
        The largest error norm over the alive agents at each step.
    """
    e = traj.errors()
    out = np.full(e.shape[0], np.nan)
    ok = np.any(np.isfinite(e), axis=1)
    out[ok] = np.nanmax(e[ok], axis=1)
    return out


def _fit_window(err: np.ndarray, scale, floor_rel: float, after: int, skip: int) -> tuple:
    """``(start, end, usable)`` of :func:`fit_decay`: ``end`` the first sample from ``after`` on at the round-off
    floor (or NaN), ``start`` the later of ``after + skip`` and the middle of ``[after, end)``; ``usable`` whether any
    sample from ``after`` on is above the floor."""
    tail = err[after:]
    ok = np.isfinite(tail)
    if not ok.any():
        return after, after, False
    floor = floor_rel * max(np.nanmax(tail), 1e-300)
    if scale is not None:
        floor = np.maximum(floor, floor_rel * np.asarray(scale, dtype=float)[after:])
    below = np.nonzero(~ok | (tail <= floor))[0]
    end = after + (below[0] if below.size else tail.size)
    return max(after + skip, after + (end - after) // 2), end, end > after


def fit_decay(t: np.ndarray, err: np.ndarray, *, time: str, scale: np.ndarray | None = None,
              floor_rel: float = 1e-9, after: int = 0, skip: int = 0) -> float | None:
    """Exponential decay measured over the tail of a noise-free error curve.

    Least-squares slope of ``log err`` against ``t`` over the second half of
    the samples from ``after`` (the last fault's effect, :func:`fault_effects`; default the start) above the
    round-off floor, and not before ``after + skip`` (the certified transient after it: :func:`transient_steps`).
    The floor is ``floor_rel * max(scale(t), max err)``: pass ``scale = |x(t)|`` since
    round-off grows with the state (an unstable plant makes it grow).  Returns
    the rate ``lam`` in the scenario's convention: continuous ``err ~ exp(-lam t)``,
    discrete ``err ~ lam^tau``; ``None`` with fewer than 6 usable samples.

    Parameters
    ----------
    t : (T,) ndarray
        The times (event indices in discrete time).
    err : (T,) array_like
        The error curve (e.g. :func:`max_error` of a noise-free run); NaN ends the usable samples.
    time : str
        ``"continuous"`` or ``"discrete"``.
    scale : (T,) array_like or None, optional
        The state's size ``|x(t)|``, for the round-off floor; None (default): the floor is
        ``floor_rel * max err`` only.
    floor_rel : float, optional
        The relative round-off floor (default 1e-9).
    after : int, optional
        The first step the fit may look at (default 0): the samples before it are disturbed.
    skip : int, optional
        Steps after ``after`` the fit leaves out besides the first half (default 0).

    Returns
    -------
    float or None
        The measured rate ``lam``, or None.

    Examples
    --------
    >>> import numpy as np
    >>> t = np.arange(20.0)
    >>> round(float(fit_decay(t, 3 * 0.5 ** t, time="discrete")), 6)
    0.5
    >>> round(float(fit_decay(t, np.exp(-2 * t), time="continuous")), 6)
    2.0
    >>> err = np.where(t < 8, 0.9 ** t, 0.5 ** (t - 8))  # a fault's effect at step 8: 0.5 per step after it
    >>> round(float(fit_decay(t, err, time="discrete", after=8)), 6)
    0.5
    """
    err = np.asarray(err, dtype=float)
    start, end, _ = _fit_window(err, scale, floor_rel, int(after), int(skip))
    if end - start < 6:
        return None
    slope = np.polyfit(t[start:end], np.log(err[start:end]), 1)[0]
    return -slope if time == "continuous" else math.exp(slope)


def fault_effects(t: np.ndarray, alive: np.ndarray, *, faults=(), dt: float = 1.0, sensors=()) -> np.ndarray:
    """The steps where a fault changed the error dynamics: what a decay rate must not be measured across.

    Every loss and rejoin of the recorded ``alive`` (T, m), every scenario fault's step ``ceil(at / dt)`` (a kill,
    a restart, a sensor corrupted or repaired, an arc dropped or restored, ...; not an orchestrator's kill, which
    leaves the estimates alone) and every sensor the bad-data test set aside or took back (``sensors``:
    :func:`sensor_events` of the same run).  Graph switches of the scenario's own switching are not faults: the
    design certifies them.

    Parameters
    ----------
    t : (T,) array_like
        The times.
    alive : (T, m) array_like of bool
        The agents alive at each step.
    faults : iterable of Fault, optional
        The scenario's faults (default: none).
    dt : float, optional
        The step (default 1: discrete time), for the faults' steps.
    sensors : sequence of tuple, optional
        The run's :func:`sensor_events` (default: none).

    Returns
    -------
    (E,) int ndarray
        The steps in ``[1, T)``, in order, each once.

    Examples
    --------
    >>> import numpy as np
    >>> alive = np.array([[1, 1], [1, 0], [1, 0], [1, 1], [1, 1]], dtype=bool)
    >>> fault_effects(np.arange(5.0), alive, sensors=[(2.0, 1, "sensor_suspect", 9.0, 4.0)])
    array([1, 2, 3])
    """
    t = np.asarray(t, dtype=float)
    alive = np.asarray(alive, dtype=bool)
    T = t.shape[0]
    steps = set()
    if T > 1:
        steps |= set((np.nonzero((alive[1:] != alive[:-1]).any(axis=1))[0] + 1).tolist())
    steps |= {fault_step(f.at, dt) for f in faults if f.runtime != ORCHESTRATOR}
    steps |= {int(np.searchsorted(t, when)) for when, *_ in sensors}
    return np.array(sorted(k for k in steps if 0 < k < T), dtype=int)


def faults_in_force(faults) -> list:
    """The faults still in force at the end of a run: a kind with an end (a sensor corrupted, an arc dropped, a
    partition) that no later fault ends (:meth:`~splitspec_core.scenarios.faults.Fault.end`).  A loss (a kill, a
    freeze) is not counted: the survivors' decay is the design's own (``design.resilience``).

    Parameters
    ----------
    faults : iterable of Fault
        The scenario's faults.

    Returns
    -------
    list of Fault
        The faults in force at the end, in the scenario's order.

    Examples
    --------
    >>> from splitspec_core.scenarios.faults import make_fault
    >>> fs = [make_fault("corrupt", 5.0, agent=2, bias=1.0), make_fault("drop_arc", 6.0, arc=(1, 3)),
    ...       make_fault("restore_arc", 9.0, arc=(1, 3))]
    >>> [f.action for f in faults_in_force(fs)]
    ['corrupt']
    """
    faults = list(faults)
    return [f for f in faults if f.ends_with and f.loss_word is None
            and not any(g.at >= f.at and g == f.end(g.at) for g in faults)]


def transient_steps(c: float | None, r: float) -> int:
    """The certified transient in steps: the first ``k`` with ``c r^k <= 1``, where the envelope ``c r^k |e(k0)|``
    of an error restarted at ``k0`` is back below ``|e(k0)|`` (``c`` the transient constant, ``r`` the rate per step).

    Parameters
    ----------
    c : float or None
        The design's transient constant (:func:`~splitspec_core.synthesis.conditioning.conditioning`); None or not
        finite: not known (0 steps: no transient is certified).
    r : float
        The rate per step, in (0, 1).

    Returns
    -------
    int
        ``ceil(log c / log(1 / r))``, 0 when ``c <= 1`` or nothing bounds it.

    Examples
    --------
    >>> transient_steps(10.0, 0.5), transient_steps(None, 0.5), transient_steps(0.8, 0.9)
    (4, 0, 0)
    """
    if c is None or not math.isfinite(c) or c <= 1 or not 0 < r < 1:
        return 0
    return max(0, math.ceil(math.log(c) / -math.log(r) - 1e-9))


def envelope_constant(t: np.ndarray, err: np.ndarray, *, time: str, rate: float,
                      scale: np.ndarray | None = None, floor_rel: float = 1e-9) -> float:
    """Smallest ``c`` with ``err(t) <= c rate^t`` (discrete) or ``c exp(-rate t)`` (continuous).

    Samples at the round-off floor (``floor_rel * scale(t)``, as in
    :func:`fit_decay`) are ignored: there the error is float noise, not decay.

    Parameters
    ----------
    t : (T,) ndarray
        The times, from the start of the envelope.
    err : (T,) array_like
        The errors.
    time : str
        ``"continuous"`` or ``"discrete"``.
    rate : float
        The designed rate ``lam``.
    scale : (T,) array_like or None, optional
        The state's size ``|x(t)|``, for the round-off floor; None (default): no sample is ignored.
    floor_rel : float, optional
        The relative round-off floor (default 1e-9).

    Returns
    -------
    float
        ``max_t err(t) / envelope(t)`` over the finite samples; NaN when there is none.

    Examples
    --------
    >>> import numpy as np
    >>> envelope_constant(np.arange(5.0), 3 * 0.5 ** np.arange(5.0), time="discrete", rate=0.6)
    3.0
    """
    env = np.exp(-rate * t) if time == "continuous" else rate ** t
    err = np.asarray(err, dtype=float)
    if scale is not None:
        err = np.where(err > floor_rel * np.asarray(scale, dtype=float), err, np.nan)
    ratio = err / env
    return float(np.nanmax(ratio[np.isfinite(ratio)])) if np.isfinite(ratio).any() else float("nan")


def envelope_restarts(alive: np.ndarray, graph: np.ndarray) -> np.ndarray:
    """Steps where the designed envelope starts afresh: 0, every rejoin and every graph switch.

    A rejoining agent starts from a fresh estimate, so the guarantee (``|e| <= c lam^tau``, or
    ``c exp(-lam t)``) holds again from that step with a new constant; a switch moves the error
    dynamics to another matrix (``A_V(tau)``, eq. split_discrete_ench), whose certificate is its own.
    A loss alone does not restart it: the survivors' errors keep decaying.

    Parameters
    ----------
    alive : (T, m) array_like of bool
        The agents alive at each step.
    graph : (T,) array_like of int
        The active graph at each step.

    Returns
    -------
    (R,) int ndarray
        The restart steps, in order, starting with 0 (empty when ``T == 0``).

    Examples
    --------
    >>> import numpy as np
    >>> alive = np.array([[1, 1], [1, 0], [1, 1], [1, 1]], dtype=bool)
    >>> envelope_restarts(alive, np.array([0, 0, 0, 1]))
    array([0, 2, 3])
    """
    alive = np.asarray(alive, dtype=bool)
    graph = np.asarray(graph)
    T = alive.shape[0]
    if T == 0:
        return np.zeros(0, dtype=int)
    rejoin = np.zeros(T, dtype=bool)
    rejoin[1:] = (alive[1:] & ~alive[:-1]).any(axis=1)
    switch = np.zeros(T, dtype=bool)
    switch[1:] = graph[1:] != graph[:-1]
    switch[0] = rejoin[0] = True
    return np.nonzero(rejoin | switch)[0]


def envelope(t: np.ndarray, err_max: np.ndarray, restarts, *, time: str, rate: float, fit: bool = False,
             scale: np.ndarray | None = None, floor_rel: float = 1e-9) -> np.ndarray:
    """The designed envelope, restarted at ``restarts`` (see :func:`envelope_restarts`), shape (T,).

    On each piece ``[k0, k1)``: ``c lam^(t - t_k0)`` (discrete) or ``c exp(-lam (t - t_k0))``
    (continuous).  ``fit=False`` (what a live recording can know): ``c = err_max[k0]``, the envelope
    starts at the error it restarts from.  ``fit=True`` (a finished trajectory): ``c`` is the
    smallest constant above the piece's errors (samples at the round-off floor
    ``floor_rel * scale`` ignored, as in :func:`envelope_constant`).  NaN where there is no error.

    Parameters
    ----------
    t : (T,) array_like
        The times.
    err_max : (T,) array_like
        The largest error over the agents (:func:`max_error`).
    restarts : iterable of int
        The restart steps (:func:`envelope_restarts`); 0 is added when missing, out-of-range steps are
        ignored.
    time : str
        ``"continuous"`` or ``"discrete"``.
    rate : float
        The designed rate ``lam``.
    fit : bool, optional
        False (default): ``c`` is the piece's first error; True: the smallest ``c`` above the piece.
    scale : (T,) array_like or None, optional
        The state's size ``|x(t)|`` for the round-off floor (``fit=True`` only); None (default): none.
    floor_rel : float, optional
        The relative round-off floor (default 1e-9).

    Returns
    -------
    (T,) ndarray
        The envelope; NaN on a piece whose ``c`` is not a positive number.

    Examples
    --------
    >>> import numpy as np
    >>> envelope(np.arange(4.0), np.array([4.0, 2.0, 8.0, 4.0]), [0, 2], time="discrete", rate=0.5)
    array([4., 2., 8., 4.])
    """
    t = np.asarray(t, dtype=float)
    err = np.asarray(err_max, dtype=float)
    T = t.shape[0]
    env = np.full(T, np.nan)
    starts = [int(k) for k in restarts if 0 <= int(k) < T]
    if not starts or starts[0] != 0:
        starts = [0] + starts
    for a, k0 in enumerate(starts):
        k1 = starts[a + 1] if a + 1 < len(starts) else T
        dt = t[k0:k1] - t[k0]
        decay = np.exp(-rate * dt) if time == "continuous" else rate ** dt
        piece = err[k0:k1]
        if fit:
            sc = None if scale is None else np.asarray(scale, dtype=float)[k0:k1]
            c = envelope_constant(dt, piece, time=time, rate=rate, scale=sc, floor_rel=floor_rel)
        else:
            c = piece[0]
        if np.isfinite(c) and c > 0:
            env[k0:k1] = c * decay
    return env


@dataclass(frozen=True)
class Mark:
    """One event of a run, to mark on a plot: ``kind`` is ``loss``, ``rejoin``, ``switch``, ``arc``, ``fault`` (a
    fault kind's own mark: :meth:`splitspec_core.scenarios.faults.Fault.plot_mark`) or ``sensor`` (a sensor set aside
    or taken back by its bad-data test: :func:`sensor_events`)."""

    step: int
    t: float
    kind: str
    label: str


MARK_KINDS = ("loss", "rejoin", "switch", "arc", "fault", "sensor")
_MARK_PREFIX = {"arc": "arc "}  # "arc 1-6 down, 2-3 up": one mark per step and kind, its words joined


def _fault_marks(k: int, t: float, said: dict) -> list:
    """The marks of step ``k``'s faults, one per kind (``said``: step -> {kind: [words]})."""
    return [Mark(k, t, kind, _MARK_PREFIX.get(kind, "") + ", ".join(words)) for kind, words in said.get(k, {}).items()]


def sensor_events(traj: Trajectory, des) -> list:
    """The ``sensor_suspect`` / ``sensor_restored`` events of a trajectory of ``des`` (``design.bad_data``), replayed
    from its ``y_statistic`` as a run's orchestrator does (:func:`splitspec_core.model.screening.sensor_events`).

    Parameters
    ----------
    traj : Trajectory
        A simulated or recorded run.
    des : Design
        Its design.

    Returns
    -------
    list of tuple
        ``(t, agent id, event, d_i, threshold)`` in time order; empty when ``design.bad_data`` is off or the
        trajectory has no ``y_statistic``.
    """
    from ..model.screening import sensor_events as replayed
    from ..synthesis.bad_data import bad_data

    bd = bad_data(des)
    return [] if bd is None or "y_statistic" not in traj.columns else replayed(traj, bd)


def event_marks(t: np.ndarray, alive: np.ndarray, graph: np.ndarray, *, agent_ids, faults=(),
                graph_names=None, dt: float = 1.0, sensors=()) -> tuple:
    """Losses, rejoins, graph switches and arc faults of a run, one :class:`Mark` per (step, kind).

    Losses, rejoins and switches come from the recorded ``alive`` (T, m) and
    ``graph`` (T,) (``trajectory.npz``), so a recording marks what happened.
    ``faults`` (the scenario's :class:`~splitspec_core.scenarios.faults.Fault` list)
    names the loss (each kind's ``loss_word``: ``killed``, ``frozen``) and adds what ``alive`` and
    ``graph`` cannot show, each kind's :meth:`~splitspec_core.scenarios.faults.Fault.plot_mark` (``drop_arc`` /
    ``restore_arc``, ...) at step ``ceil(at / dt)`` (as :func:`splitspec_core.model.network.fault_step`).

    Parameters
    ----------
    t : (T,) array_like
        The times.
    alive : (T, m) array_like of bool
        The agents alive at each step.
    graph : (T,) array_like of int
        The active graph at each step.
    agent_ids : sequence of int
        The agents' ids, in the order of ``alive``'s columns.
    faults : iterable of Fault, optional
        The scenario's faults (default: none).
    graph_names : sequence of str or None, optional
        The graphs' names, by index; None (default): the marks name the index.
    dt : float, optional
        The step (default 1: discrete time), for the faults' steps.
    sensors : sequence of tuple, optional
        :func:`sensor_events` of the run: a ``sensor`` mark at each (``3 suspect``, ``3 restored``); default none.

    Returns
    -------
    tuple of Mark
        The marks in step order (the faults' own marks of step 0 first).

    Examples
    --------
    >>> import numpy as np
    >>> alive = np.array([[1, 1], [1, 0], [1, 1], [1, 1]], dtype=bool)
    >>> for mk in event_marks(np.arange(4.0), alive, np.array([0, 0, 0, 1]), agent_ids=[1, 2], graph_names=("a", "b")):
    ...     print(mk.step, mk.kind, mk.label)
    1 loss 2 lost
    2 rejoin 2 rejoins
    3 switch graph b
    """
    t = np.asarray(t, dtype=float)
    alive = np.asarray(alive, dtype=bool)
    graph = np.asarray(graph)
    ids = [int(a) for a in agent_ids]
    T = t.shape[0]
    why = {}  # (step, agent id) -> word from the fault list
    said: dict = {}  # step -> {plot mark kind: [words, ...]} of the faults' own marks (arcs, sensors, ...)
    for f in faults:
        k = fault_step(f.at, dt)
        if k >= T:
            continue
        if f.loss_word is not None:
            why[(k, int(f.agent))] = f.loss_word
        mark = f.plot_mark()
        if mark is not None:
            said.setdefault(k, {}).setdefault(mark[0], []).append(mark[1])
    for when, agent, event, *_ in sensors:  # the bad-data test's (design.bad_data)
        k = int(np.searchsorted(t, when))
        said.setdefault(k, {}).setdefault("sensor", []).append(f"{agent} {event.split('_')[1]}")
    marks = []
    for k in range(1, T):
        lost = np.nonzero(alive[k - 1] & ~alive[k])[0]
        back = np.nonzero(~alive[k - 1] & alive[k])[0]
        if lost.size:
            words = [f"{ids[a]} {why.get((k, ids[a]), 'lost')}" for a in lost]
            marks.append(Mark(k, float(t[k]), "loss", ", ".join(words)))
        if back.size:
            marks.append(Mark(k, float(t[k]), "rejoin", ", ".join(str(ids[a]) for a in back) + " rejoins"))
        if graph[k] != graph[k - 1]:
            g = int(graph[k])
            name = graph_names[g] if graph_names is not None and g < len(graph_names) else str(g)
            marks.append(Mark(k, float(t[k]), "switch", f"graph {name}"))
        marks += _fault_marks(k, float(t[k]), said)
    if 0 in said:
        marks[:0] = _fault_marks(0, float(t[0]), said)
    return tuple(marks)


def summarize(traj: Trajectory, *, time: str, rate: float | None, noise_free: Trajectory | None = None,
              adaptive: bool = False, certified_rate: bool | None = None, faults=(), dt: float = 1.0, sensors=(),
              transient: float | None = None) -> dict:
    """Final and max error per agent, measured decay rate vs the designed rate, alive agents.

    ``adaptive=True`` (the adaptive gain, thm. split_continuous_adaptive): the
    estimator converges asymptotically with no certified rate, so there is no
    designed envelope (``envelope_c`` None) and no verdict against the design
    (``measured_meets_design`` None); ``measured_rate`` stays, as information.
    ``certified_rate`` is whether the design certifies ``rate`` (always False
    for the adaptive gain; default True otherwise).  ``rate`` None: no envelope and no verdict either (the
    certificate covers the error modulo directions no agent sees, which do not decay: ``design.undetectable:
    exclude``).  The measured rate is fitted after the last fault's effect (:func:`fault_effects` of ``faults``
    and ``sensors``) and the certified transient after it (:func:`transient_steps` of ``transient``): a rate
    measured across a kill, a rejoin or a lying sensor measures the fault, not the design; with too few event
    times left, or a fault still in force at the end (:func:`faults_in_force`), ``measured_rate`` is None and
    ``measured_note`` says why.

    Parameters
    ----------
    traj : Trajectory
        The run.
    time : str
        ``"continuous"`` or ``"discrete"``.
    rate : float or None
        The designed rate ``lam``; None: no envelope and no verdict.
    noise_free : Trajectory or None, optional
        The same run without noise, for the measured rate and the envelope; None (default): ``traj``.
    adaptive : bool, optional
        The adaptive gain (default False).
    certified_rate : bool or None, optional
        Whether the design certifies ``rate``; None (default): True (False with the adaptive gain).
    faults : iterable of Fault, optional
        The scenario's faults (default: none), for :func:`fault_effects`.
    dt : float, optional
        The step (default 1: discrete time), for the faults' steps.
    sensors : sequence of tuple, optional
        :func:`sensor_events` of the noise-free run (default: none).
    transient : float or None, optional
        The design's transient constant (default None: no transient skipped after a fault's effect).

    Returns
    -------
    dict
        ``steps``, ``designed_rate``, ``certified_rate``, ``rate_note``, ``measured_rate`` (float or None),
        ``measured_from`` (the time the fit starts, None when nothing is fitted), ``measured_after_fault`` (the
        time of the last fault's effect, None when none), ``measured_note`` (why no rate was measured because of
        a fault, else None), ``measured_meets_design`` (bool or None), ``envelope_c`` (the constant when the
        envelope never
        restarts, else None), ``envelope_pieces`` (``[t, c]`` per restart), ``alive_at_end`` (agent ids)
        and ``agents`` (agent id as str -> ``final_error``, ``max_error``, ``alive_at_end``).

    Examples
    --------
    >>> import splitspec_core as ss
    >>> from splitspec_core.simulation.simulator import simulate
    >>> des = ss.design(ss.load_scenario("examples/paper_discrete.yaml")).detail
    >>> s = summarize(simulate(des), time="discrete", rate=0.5)
    >>> round(s["measured_rate"], 2), s["measured_meets_design"], s["alive_at_end"]
    (0.47, True, [1, 2, 3])
    """
    bare = adaptive or rate is None  # nothing to hold the errors against
    e = traj.errors()
    ref = noise_free if noise_free is not None else traj
    xnorm = np.linalg.norm(ref.x, axis=1)
    effects = fault_effects(ref.t, ref.alive, faults=faults, dt=dt, sensors=sensors)
    after = int(effects[-1]) if effects.size else 0
    r = None if rate is None else rate if time == "discrete" else math.exp(-rate * dt)
    skip = transient_steps(transient, r) if after and r is not None else 0
    emax_ref = max_error(ref)
    measured = fit_decay(ref.t, emax_ref, time=time, scale=xnorm, after=after, skip=skip)
    start, end, usable = _fit_window(emax_ref, xnorm, 1e-9, after, skip)
    note = None
    lasting = faults_in_force(faults)
    if lasting:  # the tail is the fault's, not the design's
        f = lasting[-1]
        k = fault_step(f.at, dt)
        at = f"tau = {k}" if time == "discrete" else f"t = {f.at:g}"
        measured, note = None, f"{f.text(f.payload(k))} from {at} to the end of the run: the tail measures the fault"
    elif measured is None and after:
        at = f"tau = {after}" if time == "discrete" else f"t = {ref.t[after]:g}"
        cut = f" and its certified transient ({skip} steps)" if skip else ""
        floor = f"tau = {end}" if time == "discrete" else f"t = {ref.t[min(end, len(ref.t) - 1)]:g}"
        note = (f"the noise-free error is at round-off after the last fault's effect ({at})" if not usable else
                f"the noise-free error is at round-off from {floor}, before the certified transient after the last "
                f"fault's effect ({at}, {skip} steps) ends: nothing is left to fit, however long the run"
                if end < len(ref.t) and end <= after + skip else
                f"{max(end - start, 0)} steps after the last fault's effect ({at}){cut}, 6 needed: a longer run "
                "(--steps) measures it")
    per_agent = {}
    for k, aid in enumerate(traj.agent_ids.tolist()):
        col = e[:, k]
        finite = np.isfinite(col)
        per_agent[str(aid)] = {
            "final_error": float(col[-1]) if finite[-1] else None,
            "max_error": float(np.nanmax(col)) if finite.any() else None,
            "alive_at_end": bool(traj.alive[-1, k]),
        }
    meets = None
    if measured is not None and not bare:
        meets = bool(measured >= rate * (1 - 1e-3) if time == "continuous" else measured <= rate * (1 + 1e-3))
    restarts = envelope_restarts(ref.alive, ref.graph)
    pieces = []  # [t of the restart, smallest c on that piece], as envelope(..., fit=True)
    if not bare:
        for a, k0 in enumerate(restarts):
            k1 = restarts[a + 1] if a + 1 < restarts.size else ref.t.size
            c = envelope_constant(ref.t[k0:k1] - ref.t[k0], emax_ref[k0:k1], time=time, rate=rate, scale=xnorm[k0:k1])
            pieces.append([float(ref.t[k0]), c if math.isfinite(c) else None])
    env_c = pieces[0][1] if len(pieces) == 1 else None  # one constant only where the envelope never restarts
    return {
        "steps": int(traj.t.size - 1),
        "designed_rate": None if adaptive else rate,
        "certified_rate": False if adaptive else (True if certified_rate is None else bool(certified_rate)),
        "rate_note": NO_CERTIFIED_RATE if adaptive else None,
        "measured_rate": measured,
        "measured_from": float(ref.t[start]) if measured is not None else None,
        "measured_after_fault": float(ref.t[after]) if after else None,
        "measured_note": note,
        "measured_meets_design": meets,
        "envelope_c": env_c,
        "envelope_pieces": pieces,
        "alive_at_end": [int(a) for a, ok in zip(traj.agent_ids, traj.alive[-1]) if ok],
        "agents": per_agent,
    }


def steady_rms(err=None, *, sq_error=None, count=None, tail: float = 0.5, start: int | None = None,
               per_step: bool = False):
    """The steady-state RMS error: the one definition behind every "steady RMS" figure.

    The RMS error over the agents alive and the steps of the run's last ``tail`` (from step ``int((1 - tail) T)``,
    or from ``start``).  The errors come either as ``err``, one run's ``|x_i - x|`` per step and agent, (T,) or
    (T, m) (``Trajectory.errors()``, NaN while an agent is dead), or as ``sq_error`` (..., T), per step the squared
    errors summed over the agents counted, with ``count`` (..., T) how many (None: one, ``sq_error`` is already a
    per-step mean square); time on the last axis (:class:`~splitspec_core.simulation.montecarlo.MonteCarloRuns`:
    a row per seed).  What distinguishes its users:

    ``per_step=False``, ``tail=0.5`` (``compare``, ``sweep``, the network sweeps, ``MonteCarloRuns.steady_rms``):
        every alive agent at every step weighs the same, ``sqrt(sum_k sq_k / sum_k count_k)``;
    ``per_step=True``, ``tail=0.2`` (the Monte Carlo statistics, :func:`rms_stats`):
        every step weighs the same, ``sqrt(mean_k sq_k / count_k)``, the RMS over steps of the per-step RMS over agents.

    The two differ only when agents die or rejoin in the tail.  NaN where nobody is counted.  Returns a float for
    ``err``, else an array of ``sq_error.shape[:-1]``.

    Parameters
    ----------
    err : (T,) or (T, m) array_like, optional
        One run's error norms; give this or ``sq_error``.
    sq_error : (..., T) array_like, optional
        Per step, the squared errors summed over the agents counted.
    count : (..., T) array_like, optional
        How many agents ``sq_error`` sums; None (default): one.
    tail : float, optional
        The fraction of the run, at its end, that is counted (default 0.5).
    start : int or None, optional
        The first step counted, instead of ``tail``; None (default): from ``tail``.
    per_step : bool, optional
        False (default): every alive agent-step weighs the same; True: every step weighs the same.

    Returns
    -------
    float or ndarray
        A float for ``err``, an array of ``sq_error.shape[:-1]`` for ``sq_error``.

    Raises
    ------
    TypeError
        Neither or both of ``err`` and ``sq_error`` given.

    Examples
    --------
    >>> import numpy as np
    >>> round(steady_rms(np.array([[1.0, np.nan], [3.0, 4.0]]), tail=1.0), 6)
    2.94392
    >>> steady_rms(sq_error=np.array([[2.0, 8.0]]), count=np.array([[2, 2]]), tail=1.0).round(6)
    array([1.581139])
    """
    if (err is None) == (sq_error is None):
        raise TypeError("steady_rms: give err, or sq_error (and count)")
    if err is not None:  # (T, m): every agent's squared error, counted where it is alive
        e = np.asarray(err, dtype=float)
        e = e.reshape(e.shape[0], -1)
        n = ~np.isnan(e)
        sq = np.where(n, e ** 2, 0.0)
    else:  # (..., T, 1): the sums over the agents
        sq = np.asarray(sq_error, dtype=float)[..., None]
        n = np.ones(sq.shape) if count is None else np.asarray(count)[..., None]
    k0 = int((1 - tail) * sq.shape[-2]) if start is None else int(start)
    with np.errstate(invalid="ignore", divide="ignore"):
        if per_step:
            out = np.sqrt(np.mean(sq[..., k0:, :].sum(axis=-1) / n[..., k0:, :].sum(axis=-1), axis=-1))
        else:
            out = np.sqrt(sq[..., k0:, :].sum(axis=(-2, -1)) / n[..., k0:, :].sum(axis=(-2, -1)))
    return float(out) if err is not None else out


def monte_carlo_stats(trajs: list, *, tail: float = 0.2) -> dict:
    """Mean and spread across seeds of the RMS error over agents.

    Returns per-time mean/std/10%/90% curves and scalar steady-state
    statistics over the last ``tail`` fraction of the run (:func:`rms_stats` of the
    trajectories' RMS errors; a batched Monte Carlo run gives the same from
    :meth:`splitspec_core.simulation.montecarlo.MonteCarloRuns.stats` without keeping trajectories).

    Parameters
    ----------
    trajs : list of Trajectory
        One run per seed, of the same length.
    tail : float, optional
        The fraction of the run, at its end, that the steady-state statistics cover (default 0.2).

    Returns
    -------
    dict
        As :func:`rms_stats`.
    """
    rms = np.stack([np.sqrt(np.nanmean(tr.errors() ** 2, axis=1)) for tr in trajs])  # (N, T)
    return rms_stats(rms, tail=tail)


def rms_stats(rms: np.ndarray, *, tail: float = 0.2) -> dict:
    """:func:`monte_carlo_stats` of ``rms`` (N, T), the RMS error over agents per seed and step.

    Parameters
    ----------
    rms : (N, T) array_like
        The RMS error over agents, per seed and step.
    tail : float, optional
        The fraction of the run, at its end, that the steady-state statistics cover (default 0.2).

    Returns
    -------
    dict
        ``seeds`` (N); ``mean``, ``std``, ``p10``, ``p90``: (T,) arrays over seeds; ``steady_rms_mean``,
        ``steady_rms_std`` (over seeds of :func:`steady_rms` with ``per_step=True``), ``final_rms_mean``,
        ``final_rms_std``: floats.

    Examples
    --------
    >>> import numpy as np
    >>> st = rms_stats(np.array([[1.0, 0.5], [3.0, 1.5]]), tail=0.5)
    >>> st["mean"], st["final_rms_mean"], st["steady_rms_std"]
    (array([2., 1.]), 1.0, 0.5)
    """
    rms = np.asarray(rms, dtype=float)
    steady = steady_rms(sq_error=rms ** 2, tail=tail, per_step=True)  # per seed: every step weighs the same
    return {
        "seeds": int(rms.shape[0]),
        "mean": rms.mean(axis=0),
        "std": rms.std(axis=0),
        "p10": np.percentile(rms, 10, axis=0),
        "p90": np.percentile(rms, 90, axis=0),
        "steady_rms_mean": float(steady.mean()),
        "steady_rms_std": float(steady.std()),
        "final_rms_mean": float(rms[:, -1].mean()),
        "final_rms_std": float(rms[:, -1].std()),
    }
