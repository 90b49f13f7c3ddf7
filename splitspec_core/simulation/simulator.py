"""Reference simulator: the ground truth for the multi-process runtime.

Three estimators share one driver (plant, noise streams, switching, faults):

* :class:`BatchEstimator` - vectorised across agents, exploiting the block
  structure: per sub-round one sparse product with ``B = V' Sbar V`` (one
  block per arc: cost grows with the arcs); never a dense ``mn x mn`` matrix;
* :class:`AgentLoopEstimator` - a plain loop calling the per-agent step
  functions of :mod:`splitspec_core.model.steps` (exactly what agent processes run);
* :func:`simulate_exact` - continuous time only: the exact ODE of
  eq. (split_continuous_observer), integrated with a matrix exponential per
  step (graphs piecewise constant), noise-free, for comparison.

Each estimator runs the design's kind (:mod:`.kinds`: the discrete or sampled-data split, the whole state, the
fusion kind) in its form; neither the estimators nor the driver branch on the kind.

Step order at step k (time ``t_k``), the one loop of :mod:`splitspec_core.simulation.loop`: apply faults at
k; record ``x(k), x_i(k)``; measure ``y_i(k) = C_i x(k) + w_i(k)`` (as the sensor faults in force change it);
every alive agent updates to ``x_i(k+1)``; the plant moves to ``x(k+1)``.

Why one module: the three estimators share one driver (plant, seed streams, switching,
faults, restarts, the network's weights); split, what each hands the loop -- the contract ``splitspec run``
reproduces -- would be spread over files.
"""

from __future__ import annotations

import dataclasses

import os
import sys
import time as _time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import scipy.linalg as sla

from ..model import steps as st
from ..synthesis.design_data import Design
from ..errors import ScenarioError
from ..model.network import NetworkState, Plan, make_plan
from ..model.plant import Plant, RecordedPlant, initial_estimate, initial_state, output_rows
from ..model.rows import REPORTED, column, empty
from ..model.screening import Screen
from ..model.impairment import PARTITION, Impairment, crosses, group_of
from ..scenarios.faults import PLANT
from ..scenarios.specs import Scenario
from .kinds import EXACT_NEEDS_FIXED_G, exact_refusal, kind_of, realized_rows, weight_entries
from .loop import run_steps
from .trajectory_file import lost_arrays, write_trajectory

__all__ = [
    "Trajectory",
    "check_trajectory_memory",
    "simulate",
    "simulate_exact",
    "EXACT_NEEDS_FIXED_G",
    "BatchEstimator",
    "AgentLoopEstimator",
    "round_columns",
]


# --------------------------------------------------------------------------
# trajectory
# --------------------------------------------------------------------------


@dataclass(frozen=True)
class Trajectory:
    """A simulated or recorded run (``trajectory.npz`` contract).

    Attributes
    ----------
    t : (T,) float
        Event index (discrete time) or time (continuous time)
    x : (T, n) float
        The true state (all NaN when unknown: measurements without their truth)
    xhat : (T, m, n) float
        The estimates, NaN where the agent is dead
    alive : (T, m) bool
        Which agents ran at each step
    graph : (T,) int
        The active graph's index (scenario order)
    agent_ids : (m,) int
        The agents' ids, in the order of every agent axis
    columns : dict of str to (T, m) arrays
        The columns each agent reports (:data:`splitspec_core.model.rows.REPORTED`), by their name (the same in
        the file), e.g. ``g``: the gains g_i, adaptive g_i(t) or the fixed continuous g, NaN where dead and in
        discrete time; a column a file written before it existed lacks is absent
    lost : (N, 4) int64
        Every consensus message that did not count, one row ``(event time, sub-round k, sender j,
        receiver i)`` (agent ids), sorted (:mod:`splitspec_core.model.impairment`); empty on a perfect network
    lost_cause : (N,) int8
        Why each did not count: 0 loss, 1 late, 2 partition (``impairment.CAUSES``)
    y : (T, sum s_i), optional
        The measurements the estimators were given (a measurements file or live sensors), stacked in agent
        order, 0.0 where missing; None when a simulated plant drew them
    y_missing : (T, m) bool, optional
        No measurement of agent i at that step (the agent predicted only)
    u : (T, p), optional
        The known inputs the estimators used (a system with ``system.B``: the signal's, a measurements file's, or
        the live inputs the agents took), NaN where none was used (no agent alive, a run's last row); None
        without inputs
    states : tuple of str, optional
        The states' names (``system.states``, else ``x1 .. xn``); None for a file written before they existed
    """

    t: np.ndarray
    x: np.ndarray
    xhat: np.ndarray
    alive: np.ndarray
    graph: np.ndarray
    agent_ids: np.ndarray
    columns: dict = field(default_factory=dict)
    lost: np.ndarray = field(default_factory=lambda: np.zeros((0, 4), dtype=np.int64))
    lost_cause: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int8))
    y: np.ndarray | None = None
    y_missing: np.ndarray | None = None
    states: tuple | None = None
    u: np.ndarray | None = None

    @property
    def g(self) -> np.ndarray | None:
        """The gains g_i(t), (T, m) (``columns["g"]``); None for a file written before ``g`` existed."""
        return self.columns.get("g")

    @property
    def has_truth(self) -> bool:
        """``x`` is known (a simulated plant, or measurements with their truth); else it is all NaN."""
        return bool(np.isfinite(self.x).any())

    def errors(self) -> np.ndarray:
        """``|x_i(t) - x(t)|_2`` per agent, shape (T, m), NaN where dead.

        Returns
        -------
        (T, m) ndarray
            The error norms ``e_i(t)``; all NaN where ``x`` is unknown.

        Examples
        --------
        >>> import numpy as np
        >>> tr = Trajectory(t=np.arange(2.0), x=np.zeros((2, 2)), xhat=np.array([[[3.0, 4.0]], [[np.nan, np.nan]]]),
        ...                 alive=np.array([[True], [False]]), graph=np.zeros(2, dtype=int), agent_ids=np.array([1]))
        >>> tr.errors()
        array([[ 5.],
               [nan]])
        """
        return np.linalg.norm(self.xhat - self.x[:, None, :], axis=2)

    def save(self, path: str | Path, extra: dict | None = None) -> None:
        """Atomically write ``path`` (the one writer of the contract, :func:`~splitspec_core.simulation.trajectory_file.write_trajectory`).

        Parameters
        ----------
        path : str or Path
            The ``.npz`` file to write (replaced atomically if it exists).
        extra : dict or None, optional
            More optional arrays of the contract (:data:`~splitspec_core.simulation.trajectory_file.OPTIONAL`),
            written besides ``y``, ``y_missing`` and ``u``; None (default): none.

        Raises
        ------
        OSError
            The file cannot be written (``path`` is left as it was).
        ValueError
            A key of ``extra`` that is not an optional array of the contract.
        """
        write_trajectory(path, t=self.t, x=self.x, xhat=self.xhat, alive=self.alive, graph=self.graph,
                         agent_ids=self.agent_ids, columns=self.columns, lost=self.lost, lost_cause=self.lost_cause,
                         extra={**({"y": self.y, "y_missing": self.y_missing} if self.y is not None else {}),
                                **({"u": self.u} if self.u is not None else {}), **(extra or {})}, states=self.states)

    @classmethod
    def load(cls, path: str | Path) -> "Trajectory":
        """Read a ``trajectory.npz`` written by :meth:`save` (or by ``splitspec run``).

        Parameters
        ----------
        path : str or Path
            The ``.npz`` file.

        Returns
        -------
        Trajectory
            The trajectory (:meth:`from_arrays` of the file's arrays).
        """
        with np.load(path) as f:
            return cls.from_arrays({k: f[k] for k in f.files})

    @classmethod
    def from_arrays(cls, a: dict) -> "Trajectory":
        """From the arrays of the contract (``trajectory.npz``'s, or
        :func:`~splitspec_core.simulation.trajectory_chunks.read_chunks`'s; other keys are ignored).

        Parameters
        ----------
        a : dict
            Array name -> array: at least ``t``, ``x``, ``xhat``, ``alive``, ``graph`` and ``agent_ids``; the
            reported columns, ``lost``, ``lost_cause``, ``y``, ``y_missing``, ``u`` and ``states`` when present.

        Returns
        -------
        Trajectory
            The trajectory over those arrays (not copied).
        """
        extra = {k: a[k] for k in ("lost", "lost_cause", "y", "y_missing", "u") if k in a}
        states = tuple(str(s) for s in a["states"]) if "states" in a else None
        return cls(t=a["t"], x=a["x"], xhat=a["xhat"], alive=a["alive"], graph=a["graph"], agent_ids=a["agent_ids"],
                   columns={c.name: a[c.name] for c in REPORTED if c.name in a}, states=states, **extra)

    def window(self, start: float | None = None, end: float | None = None) -> "Trajectory":
        """The rows with ``start <= t <= end`` (None: no bound), and the lost messages of their event times.

        Parameters
        ----------
        start : float or None, optional
            The first time kept (inclusive); None (default): from the beginning.
        end : float or None, optional
            The last time kept (inclusive); None (default): to the end.

        Returns
        -------
        Trajectory
            A new trajectory with those rows (possibly none); ``lost`` and ``lost_cause`` keep the messages of
            the kept event times (``t`` divided by the first step of ``t``).
        """
        keep = np.ones(len(self.t), dtype=bool)
        if start is not None:
            keep &= self.t >= start
        if end is not None:
            keep &= self.t <= end
        rows = np.nonzero(keep)[0]
        lost, cause = self.lost, self.lost_cause
        if len(lost) and len(rows):
            step = self.t[1] - self.t[0] if len(self.t) > 1 else 1.0
            taus = np.rint(self.t[rows] / step).astype(np.int64)
            sel = np.isin(lost[:, 0], taus)
            lost, cause = lost[sel], cause[sel]
        elif not len(rows):
            lost, cause = lost[:0], cause[:0]
        pick = lambda v: None if v is None else v[rows]  # noqa: E731
        return dataclasses.replace(self, t=self.t[rows], x=self.x[rows], xhat=self.xhat[rows], alive=self.alive[rows],
                                   graph=self.graph[rows], columns={k: v[rows] for k, v in self.columns.items()},
                                   lost=lost, lost_cause=cause,
                                   y=pick(self.y), y_missing=pick(self.y_missing), u=pick(self.u))


# --------------------------------------------------------------------------
# initial conditions and plant (shared with the plant and agent processes)
# --------------------------------------------------------------------------


def physical_memory() -> int | None:
    """Bytes of physical memory (``SC_PHYS_PAGES * SC_PAGE_SIZE``), or None where unknown.

    Returns
    -------
    int or None
        The bytes; None where the platform cannot say.
    """
    try:
        return os.sysconf("SC_PHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (ValueError, OSError, AttributeError):
        return None


def check_trajectory_memory(sc: Scenario, steps: int | None = None, *, key: str | None = None,
                            copies: int = 1) -> None:
    """Refuse a run whose preallocated trajectory cannot fit in this machine's memory.

    :func:`simulate`, :func:`simulate_exact` and the baselines preallocate
    ``(T, m, n)`` float64 arrays, ``T = steps + 1``; ``copies`` of them are
    held at once (e.g. a Monte Carlo run).  The multi-process ``run`` grows
    its rows as it goes and does not call this.

    Raises
    ------
    ScenarioError
        ``run.steps = S needs X GiB for the trajectory (T x m x n float64); this machine has Y GiB``
        (``key`` names the option, default ``run.steps`` or ``steps``).

    Parameters
    ----------
    sc : Scenario
        The scenario (its ``m``, ``n`` and ``run.steps``).
    steps : int or None, optional
        The steps of the run; None (default): ``run.steps``.
    key : str or None, optional
        The option the error names; None (default): ``steps`` if ``steps`` is given, else ``run.steps``.
    copies : int, optional
        The trajectories held at once (default 1).
    """
    given = steps is not None
    steps = sc.run.steps if steps is None else int(steps)
    need = copies * (steps + 1) * sc.m * sc.n * 8
    have = physical_memory()
    if have is None or need <= have:
        return
    key = key or ("steps" if given else "run.steps")
    what = "the trajectory (T x m x n float64)" if copies == 1 else \
        f"{copies} trajectories ({copies} x T x m x n float64)"
    raise ScenarioError(f"{key} = {steps} needs {need / 2**30:.1f} GiB for {what}; "
                        f"this machine has {have / 2**30:.1f} GiB")


# --------------------------------------------------------------------------
# estimators
# --------------------------------------------------------------------------


class _EstimatorBase:
    """What every form of the estimator holds: the design's matrices, the bad-data test, and its kind
    (:mod:`.kinds`: the one dispatch on which estimator the design is, made here once)."""

    def __init__(self, des: Design):
        sc = des.scenario
        self.des, self.sc = des, sc
        self.m, self.n = sc.m, sc.n
        self.A = np.array(sc.system.A)
        self.Cs = [np.asarray(C) for C in sc.system.Cs]
        self.Ks = [np.asarray(K) for K in des.Ks]
        self.Ps = [np.asarray(P) for P in des.Ps]
        self.Vs = [np.asarray(V) for V in des.Vs]  # R_i: eq. (adaptive) projects with R_i' (= V_i' unless balanced)
        self.Ls = [np.asarray(L) for L in des.Ls]  # L_i: P_i = L_i R_i' (the working coordinates: local_design.py)
        self.pos = {a: k for k, a in enumerate(sc.agent_ids)}
        self.rows_y = output_rows(self.Cs)
        self.graph = 0  # the active graph's index, set per step by simulate (the fusion kind's gains are per graph)
        # design.bad_data: every agent tests its measurement before its update (model/screening.py, the agents' own
        # steps.innovation_test); a suspect sensor's agent takes P_i = I and no measurement; ``tau`` set per step
        from ..synthesis.bad_data import bad_data

        bd = bad_data(des)
        self.screen = None if bd is None else Screen(bd, self.Cs, sc.agent_ids)
        self.tau = 0
        self.kind = kind_of(des)(self)

    def screen_of(self, Z: np.ndarray, y: np.ndarray, missing, alive: np.ndarray):
        """The bad-data test of every alive agent against ``Z`` (what its update applies K_i to).

        Parameters
        ----------
        Z : (m, n) ndarray
            What each agent's update starts from.
        y : (sum s_i,) ndarray
            The stacked measurement.
        missing : (m,) bool ndarray or None
            Agents without a measurement this step.
        alive : (m,) bool ndarray
            The agents taking part.

        Returns
        -------
        (m,) bool ndarray or None
            ``missing`` with the measurements set aside (``missing`` itself without the test).
        """
        return missing if self.screen is None else self.screen.screen(self.tau, Z, y, missing, alive)

    def projections(self) -> list:
        """This event time's ``P_i``: ``I`` for the agents whose sensor is suspect (their fallback).

        Returns
        -------
        list of (n, n) ndarray
        """
        return self.Ps if self.screen is None or not self.screen.suspect.any() else self.screen.fallback(self.Ps)


class NetworkWeights:
    """The estimator's weights of each network a run meets, computed once each: ``(W, rows, entries)`` of the
    active graph restricted to the alive agents, the arcs left and the partition (``NetworkState.key``)."""

    def __init__(self, est, sc: Scenario):
        self.est, self.sc, self.cache = est, sc, {}

    def __call__(self, net: NetworkState, graph: int) -> tuple:
        """The weights of the network ``net`` is now, on the graph of index ``graph``.

        Parameters
        ----------
        net : NetworkState
            Alive agents, dropped arcs, partition.
        graph : int
            The active graph's index (scenario order).

        Returns
        -------
        tuple
            ``(est.weights(rows), rows, weight_entries(sc, rows))``, computed once per network.
        """
        key = net.key(graph)
        W = self.cache.get(key)
        if W is None:
            rows = net.rows(self.sc, key[0])
            W = self.cache[key] = (self.est.weights(rows), rows, weight_entries(self.sc, rows))
        return W


class BatchEstimator(_EstimatorBase):
    """Vectorised estimator: state ``X`` (m, n); sparse weights; batched per-agent matrices (each kind's batch form,
    :mod:`.kinds`: the split's lossless sub-rounds in unobservable-space coordinates, one sparse product per
    sub-round with about ``sum_arcs n_i n_j`` non-zeros, never a dense ``mn x mn`` matrix)."""

    def weights(self, rows: dict):
        """The step's weights of a network, in the kind's batch form (:meth:`.kinds.Kind.weights`).

        Parameters
        ----------
        rows : dict
            ``{i: (neighbour ids, weights)}`` of the alive agents (:func:`splitspec_core.model.network.consensus_rows`).

        Returns
        -------
        object
            Sparse ``S``; the split's ``(B, G, S)`` with ``B = V'(W (x) I)V`` and ``G = V'(W (x) I)``; the fusion
            kind's rows themselves.
        """
        return self.kind.weights(rows)

    def step(self, X: np.ndarray, y: np.ndarray, W, alive: np.ndarray, missing=None, bu=None) -> np.ndarray:
        """One step; ``missing`` (m,) bool: agents without a measurement this step (prediction only); ``bu`` (n,):
        the known input's ``B u`` every agent adds (steps.measurement_update), None without inputs.

        Parameters
        ----------
        X : (m, n) ndarray
            The estimates ``x_i(k)``, a row per agent (rows of dead agents are ignored).
        y : (sum s_i,) ndarray
            The stacked measurement ``y(k)``.
        W : object
            :meth:`weights` of the step's network.
        alive : (m,) bool ndarray
            The agents taking part.
        missing : (m,) bool ndarray or None, optional
            Agents without a measurement this step; None (default): every agent has one.
        bu : (n,) ndarray or None, optional
            The known input's ``B u(k)``; None (default): no inputs.

        Returns
        -------
        (m, n) ndarray
            The estimates ``x_i(k+1)``, zero rows for the dead agents.  In continuous time with the adaptive
            gain this also advances the alive agents' ``g`` (eq. adaptive).
        """
        return self.kind.step(X, y, W, alive, missing, bu)

    def realized(self, rows: dict, entries: tuple, counts: list) -> list:
        """Each exchange's realized weights (:meth:`.kinds.Kind.realized`).

        Parameters
        ----------
        rows : dict
            ``{i: (neighbour ids, weights)}`` of the step's network.
        entries : tuple
            :func:`weight_entries` of ``rows``.
        counts : list of (E_off,) bool ndarray
            One per exchange, True where an off-diagonal entry's message counts.

        Returns
        -------
        list
            ``S_k`` per exchange (a :class:`~.kinds.RealizedS`: a receiver's missing messages' weight goes to itself
            (Metropolis), or its row is re-weighted ``1 / (1 + counted)`` (uniform)); the fusion kind's rows.
        """
        return self.kind.realized(rows, entries, counts)

    def step_realized(self, X: np.ndarray, y: np.ndarray, Ws: list, alive: np.ndarray, missing=None,
                      bu=None) -> np.ndarray:
        """One step with realized weights per exchange (``Ws``: q ``S_k``, or one in continuous time): the split's
        eq. (split-discrete-p2) as ``z <- z + P_i (S_k z - z)_i``, then eq. (split-discrete-est1).

        Parameters
        ----------
        X : (m, n) ndarray
            The estimates ``x_i(k)``.
        y : (sum s_i,) ndarray
            The stacked measurement ``y(k)``.
        Ws : list
            :meth:`realized` of the step: one per exchange.
        alive : (m,) bool ndarray
            The agents taking part.
        missing : (m,) bool ndarray or None, optional
            Agents without a measurement this step; None (default): every agent has one.
        bu : (n,) ndarray or None, optional
            The known input's ``B u(k)``; None (default): no inputs.

        Returns
        -------
        (m, n) ndarray
            The estimates ``x_i(k+1)``, zero rows for the dead agents.
        """
        return self.kind.step_realized(X, y, Ws, alive, missing, bu)


class AgentLoopEstimator(_EstimatorBase):
    """Plain per-agent loop over the step functions of :mod:`splitspec_core.model.steps` (each kind's loop form)."""

    def weights(self, rows: dict) -> dict:
        """The consensus rows themselves: each agent reads its own row, as an agent process does.

        Parameters
        ----------
        rows : dict
            ``{i: (neighbour ids, weights)}`` of the alive agents.

        Returns
        -------
        dict
            ``rows``, unchanged.
        """
        return rows

    def step(self, X: np.ndarray, y: np.ndarray, rows: dict, alive: np.ndarray, missing=None, bu=None) -> np.ndarray:
        """One step, agent by agent, with the step functions of :mod:`splitspec_core.model.steps`
        (:meth:`.kinds.Kind.loop`): every message counting.

        Parameters
        ----------
        X : (m, n) ndarray
            The estimates ``x_i(k)``, a row per agent.
        y : (sum s_i,) ndarray
            The stacked measurement ``y(k)``.
        rows : dict
            ``{i: (neighbour ids, weights)}`` of the alive agents (:meth:`weights`).
        alive : (m,) bool ndarray
            The agents taking part (those of ``rows``).
        missing : (m,) bool ndarray or None, optional
            Agents without a measurement this step; None (default): every agent has one.
        bu : (n,) ndarray or None, optional
            The known input's ``B u(k)``; None (default): no inputs.

        Returns
        -------
        (m, n) ndarray
            The estimates ``x_i(k+1)``, zero rows for the agents not in ``rows``.
        """
        return self.kind.loop(X, y, [rows] * self.kind.exchanges, alive, missing, bu)

    def realized(self, rows: dict, entries: tuple, counts: list) -> list:
        """Each exchange's realized rows ``{i: (nbs, ws)}``, by the agents' own :func:`impairment.realized_row`.

        Parameters
        ----------
        rows : dict
            ``{i: (neighbour ids, weights)}`` of the step's network.
        entries : tuple
            :func:`weight_entries` of ``rows``.
        counts : list of (E_off,) bool ndarray
            One per exchange, True where an off-diagonal entry's message counts.

        Returns
        -------
        list of dict
            Per exchange, ``{i: (neighbour ids, weights)}`` of the messages that count.
        """
        return realized_rows(self.sc, rows, entries, counts)

    def step_realized(self, X: np.ndarray, y: np.ndarray, Ws: list, alive: np.ndarray, missing=None,
                      bu=None) -> np.ndarray:
        """One step with each exchange's realized rows (``Ws``: per exchange, ``{i: (nbs, ws)}``), exactly as the
        agent processes compute it (:func:`splitspec_core.model.impairment.realized_row`).

        Parameters
        ----------
        X : (m, n) ndarray
            The estimates ``x_i(k)``.
        y : (sum s_i,) ndarray
            The stacked measurement ``y(k)``.
        Ws : list of dict
            :meth:`realized` of the step, one per exchange (continuous time: the first is used).
        alive : (m,) bool ndarray
            The agents taking part.
        missing : (m,) bool ndarray or None, optional
            Agents without a measurement this step; None (default): every agent has one.
        bu : (n,) ndarray or None, optional
            The known input's ``B u(k)``; None (default): no inputs.

        Returns
        -------
        (m, n) ndarray
            The estimates ``x_i(k+1)``, zero rows for the agents not in ``Ws[0]``.
        """
        return self.kind.loop(X, y, Ws, alive, missing, bu)


# --------------------------------------------------------------------------
# driver
# --------------------------------------------------------------------------


class Progress:
    """A one-line progress bar on stderr, only when it is a terminal and the run is long."""

    def __init__(self, total: int, enabled: bool | None, *, label: str = "simulating", min_total: int = 2000):
        self.total, self.label = total, label
        self.enabled = sys.stderr.isatty() if enabled is None else enabled
        self.enabled = self.enabled and total >= min_total
        self.t0 = _time.monotonic()
        self.last = 0.0

    def update(self, k: int) -> None:
        """Redraw the bar at step ``k`` (at most every 0.2 s, and always at the end; nothing when disabled).

        Parameters
        ----------
        k : int
            The steps done (``total``: the bar ends its line).
        """
        if not self.enabled:
            return
        now = _time.monotonic()
        if now - self.last < 0.2 and k < self.total:
            return
        self.last = now
        frac = k / self.total
        bar = "#" * int(30 * frac)
        sys.stderr.write(f"\r{self.label} [{bar:<30}] {100 * frac:5.1f}%  {now - self.t0:6.1f}s")
        if k >= self.total:
            sys.stderr.write("\n")
        sys.stderr.flush()


def simulate(des: Design, *, seed: int | None = None, steps: int | None = None, noise: bool = True,
             estimator: str = "batch", progress: bool | None = False, plan: Plan | None = None,
             lost=None, measurements=None, keep_y: bool = False) -> Trajectory:
    """Simulate the scenario of a design (see the module docstring).

    Parameters
    ----------
    des : Design
        The design (:attr:`splitspec_core.api.DesignResult.detail`); its scenario is simulated.
    seed : int, optional
        Defaults to ``run.seed``; fixes initial state, estimates, noise and random switching.
    steps : int, optional
        Defaults to ``run.steps``.
    noise : bool
        False zeroes process and measurement noise (the draws still happen) and leaves out the bad-data test
        the stated noise turns on by default (``design.bad_data`` given: it runs).
    estimator : str
        ``batch`` (vectorised) or ``loop`` (per-agent step functions).
    progress : bool or None
        None shows a progress bar when stderr is a terminal and the run is long.
    plan : Plan, optional
        The run's switching and faults, made with ``sequence=True`` (:func:`~splitspec_core.model.network.make_plan`);
        its ``steps`` win over ``steps``.  Default: made from the scenario, ``seed`` and ``steps``.
    lost : (N, 4) int array, or ``(lost, lost_cause)``, optional
        Replay: exactly these consensus messages do not count (a run's recorded ``lost``), instead of the
        scenario's drawn losses (:mod:`splitspec_core.model.impairment`).
    measurements : :class:`~splitspec_core.scenarios.measurements.Measurements`, optional
        The user's recorded ``y`` instead of the simulated plant: ``steps`` defaults to the file's (``T - 1``),
        ``x`` is the file's truth (NaN without one), an agent without a measurement at a row predicts only;
        the trajectory then also holds ``y`` and ``y_missing``.
    keep_y : bool
        Also record the simulated plant's measurements in ``y`` (what ``simulate --write-measurements`` writes).

    Returns
    -------
    Trajectory
        ``T = steps + 1`` rows: ``x(k)`` and ``x_i(k)`` for ``k = 0 .. steps``, who was alive, the active
        graph, the reported columns (``g``, ``messages_used``), the consensus messages that did not count and,
        with known inputs (``system.B``), ``u(k)`` of every row (the file's, else the signal's).

    Raises
    ------
    ScenarioError
        More ``steps`` than the measurements hold, or a trajectory that cannot fit in memory.

    Examples
    --------
    >>> import splitspec_core as ss
    >>> des = ss.design(ss.load_scenario("examples/paper_discrete.yaml")).detail
    >>> tr = simulate(des, steps=20)
    >>> tr.xhat.shape
    (21, 3, 4)
    >>> tr.errors()[0].round(3)
    array([2.5  , 4.575, 2.538])
    >>> bool(tr.errors()[-1].max() < 1e-4)
    True
    """
    sc = des.scenario
    seed = sc.run.seed if seed is None else seed
    if measurements is not None:
        if steps is not None and steps > measurements.steps:
            raise ScenarioError(f"measurements {measurements.path} has {measurements.steps} steps; "
                                f"{steps} asked for")
        steps = measurements.steps if steps is None else steps
    check_trajectory_memory(sc, plan.steps if plan is not None else steps)
    plan = plan or make_plan(sc, seed, steps)
    est = BatchEstimator(des) if estimator == "batch" else AgentLoopEstimator(des)
    if not noise and measurements is None and sc.design.bad_data_default:
        # the default bad-data test is calibrated by the stated noise, and a noise-free simulation has none: its
        # transients and exact repeats would be taken for lies (the estimator would no longer be the linear one
        # the certificate is about); a test the scenario asks for (design.bad_data given) runs as asked
        est.screen = None
    plant = Plant(sc, seed, noise=noise) if measurements is None else RecordedPlant(measurements, sc.n, sc)
    B = None if sc.system.B is None else np.asarray(sc.system.B)
    m, n, T = sc.m, sc.n, plan.steps + 1
    ids = sc.agent_ids
    X = np.stack([initial_estimate(n, seed, i) for i in range(m)])
    net = NetworkState(sc, seed)
    alive = net.alive
    xs = np.zeros((T, n))
    xh = np.full((T, m, n), np.nan)
    al = np.zeros((T, m), dtype=bool)
    g = np.full((T, m), np.nan)  # g_i(t): adaptive or fixed in continuous time; none in discrete time
    rounds = {c.name: empty(c, T, m, n) for c in REPORTED if c.reported == "round"}  # round_columns, per row
    bar = Progress(plan.steps, progress)
    weights = NetworkWeights(est, sc)
    # a misbehaving network (impairment.py): messages that do not count, drawn (or replayed from a run's record)
    imp = Impairment(sc.network, seed) if sc.network.impaired and lost is None else None
    replay = _replay_index(lost) if lost is not None else None
    impaired = imp is not None or replay is not None or any(f.drops_messages for f in sc.faults)
    exchanges = est.kind.exchanges  # q; one per run.dt in the sampled-data form
    lost_rows: list = []
    # the measurements the estimators were given (a file's rows, the sensor faults in force applied)
    ys = np.zeros((T, sum(np.shape(C)[0] for C in sc.system.Cs))) if keep_y or measurements is not None else None
    rows_y = output_rows(sc.system.Cs)
    us = None if B is None else np.zeros((T, sc.system.inputs))  # the known inputs u(k) (trajectory u)

    def restart(killed, rejoined):
        for i in killed:
            X[i] = 0.0
            if est.screen is not None:
                est.screen.reset(i)
        for i, inc in rejoined:
            X[i] = initial_estimate(n, seed, i, inc)
            if est.screen is not None:
                est.screen.reset(i)
            est.kind.restart(i)
        if rejoined and est.screen is not None and est.kind.spreads_rejoins:
            est.screen.rejoined()  # a fresh estimate in the average: the others' warm-up afresh (not a suspect's)

    def record(k):
        xs[k] = plant.x
        if us is not None:  # u(k): what every agent adds at step k (the last row's too: the signal's, the file's)
            us[k] = plant.input()
        xh[k][alive] = X[alive]
        al[k] = alive
        gains = est.kind.gains()
        if gains is not None:
            g[k][alive] = gains[alive]

    def update(k, y):
        nonlocal X
        if ys is not None:
            ys[k] = y
        W = weights(net, plan.graph_seq[k])
        before = len(lost_rows)
        Ws = realized_step(est, sc, W, k, exchanges, imp, replay, net.groups, lost_rows) if impaired else None
        est.tau, est.graph = k, int(plan.graph_seq[k])
        for name, values in round_columns(sc, W[1], exchanges, lost_rows[before:]).items():
            rounds[name][k] = values
        bu = st.known_input(B, plant.input())  # the known input every agent adds (the agent process: the same)
        missing = plant.missing()
        X = (est.step(X, y, W[0], alive, missing, bu) if Ws is None
             else est.step_realized(X, y, Ws, alive, missing, bu))
        if est.screen is not None:  # the round's test (model/screening.py), reported as each agent does
            rounds["y_rejected"][k] = est.screen.rejected
            rounds["y_statistic"][k] = est.screen.statistic

    def advance(k):
        plant.advance()
        bar.update(k + 1)

    def last(k):
        if ys is not None:  # the last row's measurement (drawn after every other draw)
            ys[k] = net.measured(plant.measure(), rows_y, plant.missing())

    run_steps(plan, net, rows_y, restart=restart, record=record, measure=lambda k: plant.measure(), update=update,
              advance=advance, last=last, missing=lambda k: plant.missing())
    lost_a, cause_a = lost_arrays(lost_rows)
    recorded = {}
    if measurements is not None:  # what the estimators were given, for the views without truth
        recorded = {"y": ys, "y_missing": measurements.missing[:T].copy()}
    elif ys is not None:
        recorded = {"y": ys, "y_missing": np.zeros((T, m), dtype=bool)}
    return Trajectory(t=plan.times(), x=xs, xhat=xh, alive=al, graph=plan.graph_seq.copy(),
                      agent_ids=np.array(ids), columns={"g": g, **rounds}, lost=lost_a, lost_cause=cause_a,
                      states=sc.state_names, u=us,
                      **recorded)


def round_columns(sc: Scenario, rows: dict, exchanges: int, lost) -> dict:
    """The reported row columns of the round (:mod:`splitspec_core.model.rows`, ``reported="round"``) that the
    network decides, whatever the seed's noise: what each agent process counts in its round.

    Parameters
    ----------
    sc : Scenario
    rows : dict
        The round's consensus rows ``{agent id: (neighbours, weights)}`` of the alive agents (itself included).
    exchanges : int
        The round's consensus exchanges (q; 1 in continuous time's sampled-data form).
    lost : sequence of tuple
        ``(tau, k, j, i, cause)`` of the round's consensus messages that did not count.

    Returns
    -------
    dict
        Column name -> (m,) its values, the fill for the agents not in ``rows``: ``messages_used``, the
        neighbours' messages each agent counted over the round's exchanges.
    """
    pos = {a: k for k, a in enumerate(sc.agent_ids)}
    used = empty(column("messages_used"), 1, sc.m, sc.n)[0]
    for i, (nbs, _) in rows.items():  # every neighbour's message of every exchange, but those that did not count
        used[pos[i]] = exchanges * sum(1 for j in nbs if j != i)
    for r in lost:
        used[pos[r[3]]] -= 1
    return {"messages_used": used}


def _replay_index(lost) -> dict:
    """``{(tau, k): {(j, i): cause}}`` from recorded ``(lost, lost_cause)`` arrays (or rows ``(tau, k, j, i)``)."""
    rows, causes = (lost if isinstance(lost, tuple) else (lost, None))
    rows = np.asarray(rows, dtype=np.int64).reshape(-1, 4)
    causes = np.zeros(len(rows), dtype=np.int64) if causes is None else np.asarray(causes)
    out: dict = {}
    for (tau, k, j, i), c in zip(rows.tolist(), causes.tolist()):
        out.setdefault((tau, k), {})[(j, i)] = int(c)
    return out


def realized_step(est, sc: Scenario, W: tuple, tau: int, exchanges: int, imp, replay, groups, lost_rows: list):
    """The realized weights of step ``tau``'s exchanges, or None when every message counts (the lossless path).

    A message ``(tau, k, j, i)`` does not count when a partition in force separates j and i, when it is drawn
    lost (or late past the deadline, emulated), or, in a replay, when the run recorded it so; its row
    ``(tau, k, j, i, cause)`` goes to ``lost_rows``.

    Parameters
    ----------
    est : BatchEstimator or AgentLoopEstimator
        The estimator, whose :meth:`~BatchEstimator.realized` builds the weights.
    sc : Scenario
        The scenario (its agent order).
    W : tuple
        ``(weights, rows, entries)`` of the step's network (:class:`NetworkWeights`).
    tau : int
        The event time.
    exchanges : int
        The consensus exchanges of the step (``q``; 1 in continuous time).
    imp : Impairment or None
        The network's drawn losses and delays; None: none drawn.
    replay : dict or None
        ``{(tau, k): {(j, i): cause}}`` of a replayed run; None: no replay (it takes precedence over
        ``imp`` and the partition).
    groups : tuple or None
        The partition in force (``NetworkState.groups``); None: none.
    lost_rows : list
        Appended to: ``(tau, k, j, i, cause)`` of every message that does not count.

    Returns
    -------
    list or None
        ``est.realized(...)``: one realized weights per exchange; None when every message counts.
    """
    _, rows, entries = W
    ri, ci, _, off = entries
    ids = np.array(sc.agent_ids)
    js, is_ = ids[ci[off]], ids[ri[off]]
    if not len(js):
        return None
    gmap = group_of(groups, sc.agent_ids)
    cross = np.array([crosses(gmap, int(j), int(i)) for j, i in zip(js, is_)]) if gmap else None
    counts, any_lost = [], False
    # every sub-round's draws at once (the same numbers as one sub-round at a time: counter-based)
    drawn = imp.dropped(tau, np.arange(1, exchanges + 1)[:, None], js, is_) if imp is not None and replay is None \
        else None
    for kk in range(1, exchanges + 1):
        cause = np.full(len(js), -1, dtype=np.int64)
        if replay is not None:
            rec = replay.get((tau, kk))
            if rec:
                cause = np.array([rec.get((int(j), int(i)), -1) for j, i in zip(js, is_)], dtype=np.int64)
        else:
            if cross is not None:
                cause[cross] = PARTITION
            if drawn is not None:
                cause = np.where(cause < 0, drawn[kk - 1], cause)
        gone = np.flatnonzero(cause >= 0)
        if gone.size:
            any_lost = True
            lost_rows.extend((tau, kk, int(js[e]), int(is_[e]), int(cause[e])) for e in gone)
        counts.append(cause < 0)
    return est.realized(rows, entries, counts) if any_lost else None




def simulate_exact(des: Design, *, seed: int | None = None, steps: int | None = None) -> Trajectory:
    """Continuous time, noise-free: the exact ODE of eq. (split_continuous_observer).

    The augmented state ``(x, x_1, ..., x_m)`` obeys a linear ODE that is
    constant between steps (graph and alive set held), integrated with one
    matrix exponential per distinct step matrix.  Same initial conditions,
    switching and faults as :func:`simulate`.

    Parameters
    ----------
    des : Design
        The design (continuous time, fixed ``g``, split consensus).
    seed : int or None, optional
        The seed of the initial state, estimates and random switching; None (default): ``run.seed``.
    steps : int or None, optional
        The steps; None (default): ``run.steps``.

    Returns
    -------
    Trajectory
        The exact trajectory; ``g`` is the fixed gain where alive.

    Raises
    ------
    ScenarioError
        A discrete scenario, the adaptive gain, the whole-state design, an impaired network or a partition,
        a sensor fault, or a trajectory that cannot fit in memory.
    """
    sc = des.scenario
    refusal = exact_refusal(des)
    if refusal:
        raise ScenarioError(refusal)
    if sc.network.impaired or any(f.drops_messages for f in sc.faults):
        raise ScenarioError("the exact ODE has no messages to lose: it cannot model network: or partition faults "
                            "(simulate without --exact)")
    if sc.system.B is not None:
        raise ScenarioError("the exact ODE has no known input: it cannot model system.B and system.u (simulate "
                            "without --exact)")
    sensors = sorted({f.action for f in sc.faults if f.runtime == PLANT})
    if sensors:
        raise ScenarioError(f"the exact ODE measures every output exactly: it cannot model {', '.join(sensors)} "
                            "faults (simulate without --exact)")
    seed = sc.run.seed if seed is None else seed
    check_trajectory_memory(sc, steps)
    plan = make_plan(sc, seed, steps)
    m, n, T = sc.m, sc.n, plan.steps + 1
    ids = sc.agent_ids
    A = np.array(sc.system.A)
    g = float(des.g)
    z = np.concatenate([initial_state(sc, seed)] + [initial_estimate(n, seed, i) for i in range(m)])
    net = NetworkState(sc, seed)
    alive = net.alive
    xs = np.zeros((T, n))
    xh = np.full((T, m, n), np.nan)
    al = np.zeros((T, m), dtype=bool)
    cache: dict = {}
    pos = {a: r for r, a in enumerate(ids)}

    def restart(killed, rejoined):
        for i, inc in rejoined:
            z[n * (i + 1):n * (i + 2)] = initial_estimate(n, seed, i, inc)

    def record(k):
        xs[k] = z[:n]
        for i in range(m):
            if alive[i]:
                xh[k, i] = z[n * (i + 1):n * (i + 2)]
        al[k] = alive

    def update(k, y):  # plant and estimates together: z(k+1) = Phi z(k), Phi = exp(M dt) of the network at k
        nonlocal z
        key = net.key(plan.graph_seq[k])
        Phi = cache.get(key)
        if Phi is None:
            rows = net.rows(sc, key[0])
            M = np.zeros(((m + 1) * n, (m + 1) * n))
            M[:n, :n] = A
            for i_id, (nbs, ws) in rows.items():
                i = pos[i_id]
                bi = slice(n * (i + 1), n * (i + 2))
                K, C, P = des.Ks[i], sc.system.Cs[i], des.Ps[i]
                # dx_i = (A + K_i C_i) x_i - K_i C_i x - g P_i (x_i - sum_j w_ij x_j)
                M[bi, bi] += A + K @ C - g * P
                M[bi, :n] += -K @ C
                for j_id, w in zip(nbs, ws):
                    bj = slice(n * (pos[j_id] + 1), n * (pos[j_id] + 2))
                    M[bi, bj] += g * w * P
            Phi = sla.expm(M * plan.dt)
            cache[key] = Phi
        z = Phi @ z

    run_steps(plan, net, output_rows(sc.system.Cs), restart=restart, record=record, update=update)
    return Trajectory(t=plan.times(), x=xs, xhat=xh, alive=al, graph=plan.graph_seq.copy(), agent_ids=np.array(ids),
                      columns={"g": np.where(al, g, np.nan)}, states=sc.state_names)
