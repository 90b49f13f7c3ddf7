"""The network as it evolves during a run: switching, faults, alive agents, weights.

Shared by the simulator and the orchestrator, so both apply switches and
faults at the same steps and hand every agent the same neighbour weights.

* the switching signal is sampled once per step (``graph_sequence``);
* a fault at time ``at`` takes effect at step ``k = ceil(at / dt)``
  (``dt = 1`` in discrete time): a killed (or frozen) agent takes no part from
  step k on; a restarted agent rejoins at step k with a fresh estimate;
  ``drop_arc``/``restore_arc`` remove/re-add one arc from every graph (with
  Metropolis weights, the link in both directions, keeping graphs undirected);
  ``partition``/``heal`` start/end a partition: the arcs stay, but no consensus
  message between groups counts (:mod:`splitspec_core.model.impairment`);
  what each kind of fault does is its class in :mod:`splitspec_core.scenarios.faults`;
* neighbour sets are the active graph restricted to the alive agents, with
  the scenario's weights recomputed on that restricted graph.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from .graphs import SwitchingSignal, build_graph, graph_sequence, switch_times
from ..scenarios.faults import PLANT
from ..scenarios.specs import Scenario
from .plant import RecordedPlant, output_rows
from .streams import stream

__all__ = ["Plan", "make_plan", "active_arcs", "consensus_rows", "fault_schedule", "fault_step", "NetworkState",
           "SensorDraws", "given_measurements", "sensor_schedule"]


def fault_step(at: float, dt: float) -> int:
    """Step index at which a fault at time ``at`` takes effect.

    Parameters
    ----------
    at : float
        The fault's time (seconds; event times in discrete time).
    dt : float
        The step (1 in discrete time).

    Returns
    -------
    int
        ``ceil(at / dt)``, with a tolerance of 1e-9 steps so that ``at`` a multiple of ``dt`` up to
        round-off maps to that step.

    Examples
    --------
    >>> fault_step(0.3, 0.1), fault_step(0.31, 0.1), fault_step(5.0, 1.0)
    (3, 4, 5)
    """
    return int(math.ceil(at / dt - 1e-9))


@dataclass(frozen=True)
class Plan:
    """Everything about a run that is fixed by the scenario and the seed, except noise.

    Attributes
    ----------
    steps : int
    dt : float
        1 for discrete time.
    graph_seq : (steps + 1,) int array or None
        Active graph index per step (scenario order); ``None`` for a plan made
        with ``sequence=False`` (a run of any length), which samples
        ``signal`` step by step instead (:meth:`graph_at`).
    faults : dict
        ``{step: [Fault, ...]}``.
    """

    steps: int
    dt: float
    graph_seq: np.ndarray | None
    faults: dict
    signal: SwitchingSignal | None = None

    def times(self) -> np.ndarray:
        """The times of the plan's steps, ``k dt`` for ``k = 0 .. steps``.

        Returns
        -------
        (steps + 1,) ndarray
            The times, in seconds (event times in discrete time).
        """
        return np.arange(self.steps + 1) * self.dt

    def graph_at(self, k: int) -> int:
        """Active graph index at step ``k`` (non-decreasing ``k`` when sampled lazily).

        Parameters
        ----------
        k : int
            The step.

        Returns
        -------
        int
            The index of the active graph in the scenario's graph order.
        """
        return int(self.graph_seq[k]) if self.graph_seq is not None else self.signal.at(k)


def _switching_rng(sc: Scenario, seed: int):
    sw = sc.switching
    if sw.kind != "random":
        return None
    return np.random.default_rng(sw.seed) if sw.seed is not None else stream(seed, "switching")


def make_plan(sc: Scenario, seed: int, steps: int | None = None, *, sequence: bool = True) -> Plan:
    """The run's switching signal and fault schedule.

    ``sequence=False``: no per-step array (O(1) memory whatever ``steps``); the
    graph of each step comes from :meth:`Plan.graph_at`, drawn exactly as the
    array would be.

    Parameters
    ----------
    sc : Scenario
        The scenario (its switching, graphs, faults and time).
    seed : int
        The run's seed: a random switching signal draws from its ``switching`` stream, unless
        ``switching.seed`` is set.
    steps : int or None, optional
        The number of steps; None (default): ``run.steps``.
    sequence : bool, optional
        True (default): sample the graph of every step into ``graph_seq``; False: sample lazily.

    Returns
    -------
    Plan
        The run's steps, ``dt``, graph sequence or signal, and fault schedule (faults after
        ``steps`` left out).

    Examples
    --------
    >>> import splitspec_core as ss
    >>> sc = ss.load_scenario("examples/paper_discrete.yaml")
    >>> plan = make_plan(sc, 0, 5)
    >>> plan.graph_seq.tolist(), plan.dt, plan.faults
    ([0, 0, 0, 0, 0, 0], 1.0, {})
    """
    steps = sc.run.steps if steps is None else steps
    dt = sc.run.dt if sc.time == "continuous" else 1.0
    sw = sc.switching
    seq = signal = None
    if sequence:
        pieces = switch_times(sw, sc.graph_names, (steps + 1) * dt, _switching_rng(sc, seed))
        seq = graph_sequence(pieces, steps + 1, dt=dt)
    else:
        signal = SwitchingSignal(sw, sc.graph_names, dt=dt, rng=_switching_rng(sc, seed))
    return Plan(steps=steps, dt=dt, graph_seq=seq, faults=fault_schedule(sc.faults, dt, steps), signal=signal)


def fault_schedule(faults, dt: float, steps: int | None = None) -> dict:
    """``{step: [Fault, ...]}``: each fault at the step it takes effect (:func:`fault_step`), in order.

    Parameters
    ----------
    faults : iterable of Fault
        The scenario's faults (sorted by time).
    dt : float
        The step (1 in discrete time).
    steps : int, optional
        Faults after this step are left out (None: none is).

    Returns
    -------
    dict
        ``{step: [Fault, ...]}``.
    """
    out: dict = {}
    for f in faults:
        k = fault_step(f.at, dt)
        if steps is None or k <= steps:
            out.setdefault(k, []).append(f)
    return out


def active_arcs(sc: Scenario, graph_index: int, dropped=frozenset()) -> tuple:
    """Arcs ``(j, i)`` of graph ``graph_index`` minus the dropped ones.

    With Metropolis weights (undirected graphs) a dropped arc is a failed link:
    both directions go.

    Parameters
    ----------
    sc : Scenario
        The scenario (its graphs and ``design.weights``).
    graph_index : int
        The graph, by index in the scenario's graph order.
    dropped : collection of (int, int), optional
        Dropped arcs ``(j, i)`` by agent id (default: none).

    Returns
    -------
    tuple of (int, int)
        The remaining arcs ``(j, i)`` by agent id, in the graph's order.
    """
    if sc.design.weights == "metropolis":
        dropped = set(dropped) | {(i, j) for j, i in dropped}
    return tuple(a for a in sc.graphs[graph_index].arcs if a not in dropped)


def consensus_rows(sc: Scenario, graph_index: int, alive_ids, dropped=frozenset()) -> dict:
    """``{i: (neighbour ids, weights)}`` for every alive agent i.

    The active graph minus the dropped arcs, restricted to ``alive_ids``;
    weights are row i of ``S`` of that restricted graph (uniform ``1/m_i`` or
    Metropolis).  Neighbours are listed self first, then by position.

    Parameters
    ----------
    sc : Scenario
        The scenario (its agents, graphs and ``design.weights``).
    graph_index : int
        The active graph, by index in the scenario's graph order.
    alive_ids : iterable of int
        The ids of the agents taking part.
    dropped : collection of (int, int), optional
        Dropped arcs ``(j, i)`` by agent id (default: none).

    Returns
    -------
    dict
        ``{i: (neighbour ids, weights)}``, both tuples, for every alive agent id ``i`` in agent
        order; empty when no agent is alive.

    Examples
    --------
    >>> import splitspec_core as ss
    >>> sc = ss.load_scenario("examples/paper_discrete.yaml")
    >>> consensus_rows(sc, 0, [2, 3])
    {2: ((2, 3), (0.5, 0.5)), 3: ((3, 2), (0.5, 0.5))}
    """
    alive_ids = tuple(a for a in sc.agent_ids if a in set(alive_ids))
    if not alive_ids:
        return {}
    arcs = active_arcs(sc, graph_index, dropped)
    g = build_graph(sc.graphs[graph_index].name, alive_ids, arcs, weights=sc.design.weights, check=False)
    rows = {}
    for r, i in enumerate(g.ids):
        cols = [r] + [c for c in range(g.m) if c != r and g.S[r, c] != 0]
        rows[i] = (tuple(g.ids[c] for c in cols), tuple(float(g.S[r, c]) for c in cols))
    return rows


class SensorDraws:
    """The extra noise of one sensor fault: the ``sensor_noise`` stream ``(agent position, its sensor fault)`` of
    each seed (:mod:`~splitspec_core.model.streams`), ``s_i`` normals per step.

    Drawn :data:`CHUNK` steps at a time: a stream's ``normal(size=(CHUNK, s))`` is its ``CHUNK`` successive
    ``normal(size=s)`` draws, so the simulator, the batched Monte Carlo and the plant process draw the same numbers.

    Parameters
    ----------
    seeds : tuple of int or None
        The run's seed, or the batch's seeds (None: unknown; drawing is then refused).
    i, nth : int
        The agent's position and which sensor fault on it (0 the first).
    batch : bool
        Seeds on a trailing axis (the batched Monte Carlo).
    """

    CHUNK = 256

    def __init__(self, seeds, i: int, nth: int, *, batch: bool):
        self.seeds, self.key, self.batch = seeds, (int(i), int(nth)), batch
        self._gens, self._buf, self._k = None, None, 0

    def normal(self, s: int) -> np.ndarray:
        """This step's ``s`` standard normals.

        Parameters
        ----------
        s : int
            The agent's number of outputs.

        Returns
        -------
        (s,) or (s, N) ndarray
            One step's draws (a column per seed in a batch).
        """
        if self._gens is None:
            if self.seeds is None:
                raise ValueError("a sensor fault with noise needs the run's seed: NetworkState(sc, seeds=...)")
            self._gens = [stream(seed, "sensor_noise", *self.key) for seed in self.seeds]
        if self._buf is None or self._k == len(self._buf):
            self._buf = np.stack([g.normal(size=(self.CHUNK, s)) for g in self._gens], axis=-1)  # (CHUNK, s, N)
            self._k = 0
        w = self._buf[self._k]
        self._k += 1
        return w if self.batch else w[:, 0]


class NetworkState:
    """Alive agents, incarnations and dropped arcs as faults apply (agent positions are 0-based).

    ``apply`` returns ``(killed, rejoined)``: positions that stopped taking part
    and ``(position, incarnation)`` of agents that rejoin with a fresh estimate;
    each fault's kind says what it does (:mod:`splitspec_core.scenarios.faults`).
    A freeze is handled as a loss (the runtime declares a frozen agent lost).
    ``measured`` gives the measurements as the sensor faults in force change them; ``seeds`` (the run's seed, or
    the batch's seeds) opens their ``sensor_noise`` streams (:class:`SensorDraws`).
    """

    def __init__(self, sc: Scenario, seeds=None):
        self.ids = sc.agent_ids
        self.alive = np.ones(sc.m, dtype=bool)
        self.incarnation = np.zeros(sc.m, dtype=int)
        self.dropped: set = set()
        self.groups: tuple | None = None  # a partition in force (impairment: no message crosses between groups)
        self.sensors: dict = {}  # position -> (fault, its memory): a sensor fault in force (faults.Fault.measure)
        self.seeds = None if seeds is None else tuple(int(s) for s in np.atleast_1d(seeds))
        self.sensor_faults = np.zeros(sc.m, dtype=int)  # sensor faults put on each agent so far (their streams' key)
        # the last measurement each agent was given (stacked; NaN before its first), kept for a sensor that sticks
        self._holds = any(f.holds_last for f in sc.faults)
        self._last = None

    def put_sensor(self, i: int, fault) -> None:
        """Put agent ``i``'s sensor under ``fault`` (a fresh memory), replacing a sensor fault in force on it.

        Parameters
        ----------
        i : int
            The agent's position (0-based).
        fault : Fault
            A sensor fault (:meth:`~splitspec_core.scenarios.faults.Fault.measure` changes the agent's ``y_i``).
        """
        self.sensors[i] = (fault, {"key": (i, int(self.sensor_faults[i]))})
        self.sensor_faults[i] += 1

    def lose(self, i: int) -> bool:
        """Agent at position ``i`` stops taking part; False if it was not alive.

        Parameters
        ----------
        i : int
            The agent's position (0-based).

        Returns
        -------
        bool
            True if the agent was alive (and is now lost), False if it was already lost.
        """
        if not self.alive[i]:
            return False
        self.alive[i] = False
        return True

    def rejoin(self, i: int) -> int | None:
        """Agent at position ``i`` rejoins with a fresh estimate; its new incarnation (None if alive).

        Parameters
        ----------
        i : int
            The agent's position (0-based).

        Returns
        -------
        int or None
            The agent's new incarnation (previous + 1); None if it was alive (nothing changes).
        """
        if self.alive[i]:
            return None
        self.incarnation[i] += 1
        self.alive[i] = True
        return int(self.incarnation[i])

    def apply(self, faults) -> tuple:
        """Apply ``faults``, each as its kind says (:meth:`~splitspec_core.scenarios.faults.Fault.apply`).

        Parameters
        ----------
        faults : iterable of Fault
            The faults due at one step, in order.

        Returns
        -------
        tuple
            ``(killed, rejoined)``: the positions that stopped taking part, and ``(position, incarnation)`` of
            those that rejoin with a fresh estimate.
        """
        killed, rejoined = [], []
        for f in faults:
            lost, back = f.apply(self)
            killed += lost
            rejoined += back
        return killed, rejoined

    def measured(self, y: np.ndarray, rows: list, missing=None) -> np.ndarray:
        """The measurements as the estimators are given them, with the sensor faults in force.

        A fault's memory gets, at its first measurement, ``before`` (the last measurement the agent was given
        before the fault, its current one if it was given none) and ``draws`` (:class:`SensorDraws`).  Every
        sensor fault in force measures every step (its draws do not depend on who is missing); an agent without
        a measurement at this step (``missing``) keeps its row as it is.

        Parameters
        ----------
        y : (sum s_i,) or (sum s_i, N) array
            The plant's stacked measurements (outputs on axis 0, seeds after).
        rows : list of slice
            Each agent's rows of ``y`` (:func:`~splitspec_core.model.plant.output_rows`).
        missing : (m,) bool array, optional
            The agents without a measurement at this step (a measurements file); None: every agent has one.

        Returns
        -------
        array
            ``y`` itself when no sensor fault is in force; else a copy in which each faulty sensor's rows are
            changed by its fault (:meth:`~splitspec_core.scenarios.faults.Fault.measure`).
        """
        out = y
        if self.sensors:
            out = np.array(y, dtype=float)
            for i, (fault, memo) in self.sensors.items():
                if "before" not in memo:
                    last = None if self._last is None else self._last[rows[i]]
                    memo["before"] = (np.array(y[rows[i]], dtype=float) if last is None or np.isnan(last).any()
                                      else last.copy())
                    memo["draws"] = SensorDraws(self.seeds, *memo["key"], batch=np.ndim(y) > 1)
                value = fault.measure(y[rows[i]], memo)
                if missing is None or not missing[i]:
                    out[rows[i]] = value
        if self._holds:
            if self._last is None:
                self._last = np.full(np.shape(y), np.nan)
            for i, r in enumerate(rows):
                if missing is None or not missing[i]:
                    self._last[r] = out[r]
        return out

    def alive_ids(self) -> list:
        """The ids of the agents taking part, in agent order.

        Returns
        -------
        list of int
            The alive agents' ids.
        """
        return [a for a, ok in zip(self.ids, self.alive) if ok]

    def key(self, graph_index: int) -> tuple:
        """Hashable description of the active network (for caching weights).

        Parameters
        ----------
        graph_index : int
            The active graph's index.

        Returns
        -------
        tuple
            ``(graph_index, alive mask bytes, dropped arcs, partition groups)``.
        """
        return (int(graph_index), self.alive.tobytes(), frozenset(self.dropped), self.groups)

    def rows(self, sc: Scenario, graph_index: int) -> dict:
        """:func:`consensus_rows` of the active network: alive agents, dropped arcs removed.

        Parameters
        ----------
        sc : Scenario
            The scenario this state was made for.
        graph_index : int
            The active graph's index.

        Returns
        -------
        dict
            ``{i: (neighbour ids, weights)}`` for every alive agent id ``i``.
        """
        return consensus_rows(sc, graph_index, self.alive_ids(), frozenset(self.dropped))

    def arcs(self, sc: Scenario, graph_index: int) -> tuple:
        """Arcs of the active graph that still exist (see :func:`active_arcs`).

        Parameters
        ----------
        sc : Scenario
            The scenario this state was made for.
        graph_index : int
            The active graph's index.

        Returns
        -------
        tuple of (int, int)
            The arcs ``(j, i)`` by agent id, dead agents' arcs included.
        """
        return active_arcs(sc, graph_index, self.dropped)


def sensor_schedule(sc: Scenario, steps: int | None = None) -> dict:
    """The scenario's sensor faults (the kinds the plant process applies) at their steps: what the baselines of
    ``compare`` and a run's record of a measurements file apply, as the simulator does.

    Parameters
    ----------
    sc : Scenario
        The scenario (its faults, time and ``run.dt``).
    steps : int, optional
        Faults after this step are left out (None: none is).

    Returns
    -------
    dict
        ``{step: [Fault, ...]}`` (:func:`fault_schedule` of those faults); empty without a sensor fault.
    """
    return fault_schedule([f for f in sc.faults if f.runtime == PLANT], sc.run.dt if sc.time == "continuous" else 1.0,
                          steps)


def given_measurements(sc: Scenario, meas, seed: int):
    """A measurements file as its estimators are given it: the scenario's sensor faults (the kinds the plant
    process applies) applied row by row, as the plant process and :func:`~splitspec_core.simulation.simulator.simulate`
    apply them; what the recorder of a run on the file records as its ``y``.

    Parameters
    ----------
    sc : Scenario
        The scenario (its faults, ``C_i``, time and ``run.dt``).
    meas : :class:`~splitspec_core.scenarios.measurements.Measurements`
        The file.
    seed : int
        The run's seed (a sensor fault's noise is drawn from its ``sensor_noise`` streams).

    Returns
    -------
    Measurements
        ``meas`` itself without a sensor fault; else a copy whose ``y`` is what the estimators were given (a
        missing row as the file has it).
    """
    schedule = sensor_schedule(sc)
    if not schedule:
        return meas
    net, plant, rows = NetworkState(sc, seed), RecordedPlant(meas, sc.n, sc), output_rows(sc.system.Cs)
    y = np.array(meas.y, dtype=float)
    for k in range(len(y)):
        if k:
            plant.advance()
        net.apply(schedule.get(k, ()))
        y[k] = net.measured(plant.measure(), rows, plant.missing())
    return dataclasses.replace(meas, y=y)
