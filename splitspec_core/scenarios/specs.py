"""The frozen scenario: :class:`Scenario` and its parts, each checked when built.

A scenario is one YAML file holding the system ``(A, C_i)``, the neighbour graphs, the switching signal, the design
options, faults and run options (see ``docs/how-to/scenario.md`` and ``../shared/DESIGN.md``).  This module holds
what it becomes: frozen dataclasses whose ``__post_init__`` checks (e.g. the shapes of ``A``, ``C_i`` and ``K_i``
through :func:`splitspec_core.scenarios.checks.check_shapes`) hold for a scenario built directly as well as for one
parsed from a file.

Three modules, one path, imported in one direction: the value checkers
(:mod:`splitspec_core.scenarios.checks`), this one (the frozen data), the section
parsers (:mod:`splitspec_core.scenarios.sections`, which build this module's
dataclasses), and the entry points that read, parse and validate a file or text
(:mod:`splitspec_core.scenarios.load`: ``load_scenario``, ``parse_scenario``,
``parse_scenario_text``, ``load_yaml``, ``read_scenario_text``).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..errors import DimensionError, ScenarioError
from .labels import default_output_names, default_state_names
from .summary import summary
from .checks import (GAIN_METHODS, MAX_MAGNITUDE, MAX_SEED, Q_METHODS, check_agent_id, check_shapes,  # noqa: F401
                     ids_text, plain)
from .noise import (measurement_level, measurement_std, parse_measurement_noise, parse_process_noise,
                    process_covariance, process_level)

__all__ = [
    "System",
    "GraphSpec",
    "Switching",
    "DesignSpec",
    "NetworkSpec",
    "RunSpec",
    "Scenario",
    "MAX_MAGNITUDE",
    "MAX_SEED",
    "GAIN_METHODS",
    "Q_METHODS",
]


# --------------------------------------------------------------------------
# frozen data
# --------------------------------------------------------------------------


@dataclass(frozen=True)
class System:
    """The plant ``x+ = A x + v``, ``y_i = C_i x + w_i``.

    Attributes
    ----------
    A : (n, n) array
        System matrix ``A``.
    Cs : tuple of (s_i, n) arrays
        Output matrices ``C_i`` in agent order (see ``Scenario.agent_ids``).
    x0 : (n,) array or None
        Initial state; ``None`` means drawn from the seed.
    process_noise : float or (n,) array or (n, n) array
        ``system.process_noise`` as given (for text and JSON; compute with :attr:`process_covariance`).  A
        number: discrete, the std ``sigma`` of every state's ``v`` (covariance ``sigma^2 I`` per step);
        continuous, the intensity ``q`` (``E[v(t) v(s)'] = q I delta(t - s)``).  A vector: the same per state
        (discrete: stds, covariance ``diag(v^2)``; continuous: intensities, ``diag(v)``).  A matrix: the
        covariance per step (discrete) or the intensity matrix (continuous), symmetric positive semidefinite.
    measurement_noise : float or dict
        ``system.measurement_noise`` as given (compute with :attr:`measurement_std` and the covariances): a
        number, the std of every output's noise sample; or ``{agent id: std or (one std per output)}`` in agent
        order, every agent listed.
    states : tuple of str or None
        The states' names (``system.states``); None: ``x1 .. xn``.
    outputs : dict or None
        Agent id -> the names of its outputs (``system.outputs``); an agent not in it has ``y<i>``, ``y<i>_k``.
    B : (n, p) array or None
        The known inputs' matrix (``system.B``: ``x+ = A x + B u``); sampled with ``A`` when ``sample`` is set.
    u : :class:`~splitspec_core.scenarios.inputs.InputSignal` or None
        The input signal (``system.u``); None: zero (or a measurements file's ``u`` columns).
    sample : float or None
        ``system.sample``: the period a continuous model given as ``A``, ``B`` was sampled with (zero-order hold);
        ``A`` and ``B`` here are then the sampled ones, ``A_continuous`` the model as given.
    time : str
        ``discrete`` or ``continuous``, the scenario's ``time`` (how ``A`` and the process noise are read).
    time_unit : str
        ``system.time_unit``: the unit of the model's time (``sample``, ``run.dt``, continuous rates), for printing.

    The noise's derived quantities (:mod:`splitspec_core.scenarios.noise`), which every computation uses:
    :attr:`process_covariance`, :attr:`measurement_std`, :attr:`measurement_covariance`,
    :attr:`measurement_covariances`, :attr:`process_noise_present`, :attr:`measurement_noise_present`,
    :attr:`has_noise`, and the one-number summaries :attr:`process_noise_level`, :attr:`measurement_noise_level`.
    """

    A: np.ndarray
    Cs: tuple
    x0: np.ndarray | None
    process_noise: Any = 0.0
    measurement_noise: Any = 0.0
    states: tuple | None = None
    outputs: dict | None = None
    B: np.ndarray | None = None
    u: Any = None
    sample: float | None = None
    A_continuous: np.ndarray | None = None
    time: str = "discrete"
    time_unit: str = "s"  # system.time_unit: the model time's unit, printed after its times and rates

    @property
    def per_time(self) -> str:
        """``per second`` (``system.time_unit: s``, the default), else ``per <unit>``: after a rate, a str."""
        return "per second" if self.time_unit == "s" else f"per {self.time_unit}"

    def __post_init__(self) -> None:
        # built directly, a system still meets the parser's noise checks (and holds what they return)
        n = np.shape(self.A)[0]
        object.__setattr__(self, "process_noise", parse_process_noise(plain(self.process_noise), n))
        raw = plain(self.measurement_noise)
        if isinstance(raw, dict):
            if len(raw) != len(self.Cs):
                raise DimensionError(f"system.measurement_noise lists {len(raw)} agents, system.Cs holds "
                                     f"{len(self.Cs)} output matrices")
            sizes = {check_agent_id(k, "system.measurement_noise"): int(np.shape(C)[0])
                     for k, C in zip(raw, self.Cs)}
            raw = parse_measurement_noise(raw, sizes)
        else:
            raw = parse_measurement_noise(raw, {})
        object.__setattr__(self, "measurement_noise", raw)

    @property
    def output_sizes(self) -> tuple:
        """``(s_1, ..., s_m)``, a tuple of int: the number of outputs of each agent, in agent order."""
        return tuple(int(np.shape(C)[0]) for C in self.Cs)

    @property
    def process_covariance(self) -> np.ndarray:
        """``(n, n)``: discrete, the covariance of ``v`` per step (``sigma^2 I``, ``diag(v^2)`` or the matrix);
        continuous, the intensity matrix of white ``v`` (``q I``, ``diag(v)`` or the matrix; the plant samples
        it exactly, :func:`splitspec_core.scenarios.sampling.sampled_data_matrices`)."""
        return process_covariance(self.process_noise, self.n, self.time)

    @property
    def measurement_std(self) -> np.ndarray:
        """``(p,)``, ``p = sum s_i``: every output's noise std, stacked in agent order like ``y``."""
        return measurement_std(self.measurement_noise, self.output_sizes)

    @property
    def measurement_covariance(self) -> np.ndarray:
        """``(p, p)``: ``R = diag(std^2)``, the stacked outputs' noise covariance (``sigma^2 I`` for a number)."""
        if not isinstance(self.measurement_noise, dict):
            return self.measurement_noise ** 2 * np.eye(sum(self.output_sizes))
        return np.diag(self.measurement_std ** 2)

    @property
    def measurement_covariances(self) -> list:
        """``[R_1, ..., R_m]``: each agent's ``(s_i, s_i)`` noise covariance, in agent order."""
        R = self.measurement_covariance
        offsets = np.cumsum((0,) + self.output_sizes)
        return [R[a:b, a:b] for a, b in zip(offsets[:-1], offsets[1:])]

    @property
    def process_noise_present(self) -> bool:
        """Whether there is some process noise (a covariance or intensity that is not zero), a bool."""
        return bool(np.any(self.process_covariance))

    @property
    def measurement_noise_present(self) -> bool:
        """Whether some output has measurement noise (a std above 0), a bool."""
        return bool(np.any(self.measurement_std > 0))

    @property
    def has_noise(self) -> bool:
        """Whether process or measurement noise is present, a bool (what ``design.gains: optimal`` and ``kalman``
        need, and what makes ``optimal`` the default)."""
        return self.process_noise_present or self.measurement_noise_present

    @property
    def process_noise_level(self) -> float:
        """One float for the process noise in a scalar's units (the number itself; for a vector or a matrix
        :func:`splitspec_core.scenarios.noise.process_level`: the root mean variance, or the mean intensity)."""
        return process_level(self.process_noise, self.n, self.time)

    @property
    def measurement_noise_level(self) -> float:
        """One float for the measurement noise: the number itself, or the root mean square of the outputs' stds."""
        return measurement_level(self.measurement_noise, self.output_sizes)

    @property
    def inputs(self) -> int:
        """The number of known inputs, an int (columns of ``B``; 0 without ``B``)."""
        return 0 if self.B is None else int(self.B.shape[1])

    @property
    def n(self) -> int:
        """The number of states ``n``, an int (the rows of ``A``)."""
        return self.A.shape[0]


@dataclass(frozen=True)
class GraphSpec:
    """A named neighbour graph: arcs ``(j, i)`` mean agent i hears agent j.

    Self-arcs are implicit and not listed; arcs are agent ids, deduplicated.
    """

    name: str
    arcs: tuple  # tuple[tuple[int, int], ...]


@dataclass(frozen=True)
class Switching:
    """The switching signal.

    ``kind`` is ``constant`` (first graph forever), ``schedule`` (pieces
    ``(start, graph)``, optionally repeated every ``period``) or ``random``
    (Poisson switching among ``graphs`` with mean dwell ``dwell``).
    Times are event times (discrete) or seconds (continuous).
    """

    kind: str
    schedule: tuple = ()  # tuple[tuple[float, str], ...]
    period: float | None = None
    graphs: tuple = ()  # graph names used by random switching
    dwell: float | None = None
    seed: int | None = None

    def graph_names(self, all_names: tuple) -> tuple:
        """Names of the graphs this signal can select, in scenario order.

        Parameters
        ----------
        all_names : tuple of str
            Every graph's name, in scenario order (``Scenario.graph_names``).

        Returns
        -------
        tuple of str
            ``constant``: the first graph alone; ``schedule``: the graphs its pieces name; ``random``: its ``graphs``.
        """
        if self.kind == "constant":
            return (all_names[0],)
        used = {g for _, g in self.schedule} if self.kind == "schedule" else set(self.graphs)
        return tuple(name for name in all_names if name in used)


@dataclass(frozen=True)
class DesignSpec:
    """Design options (``design:`` section).

    ``g`` is a float, ``"auto"`` or ``"adaptive"`` (continuous only);
    ``q`` an int or ``"auto"`` (discrete only).
    """

    rate: float
    gains: str = "place"
    K: tuple | None = None  # explicit gains, tuple of (n, s_i) arrays in agent order
    g: Any = "auto"
    g0: float = 0.0
    q: Any = "auto"
    q_method: str = "spectral"
    q_max: int = 100_000
    resilience: int = 0
    weights: str = "uniform"
    margin: float = 0.5
    rank_tol: float | None = None  # None: auto (observability.DEFAULT_RANK_TOL)
    graph_set: str = "scenario"
    dwell: float | None = None
    process_weight: float | None = None  # design.riccati.process_weight (None: the noise level, squared, else 1)
    measurement_weight: float | None = None  # design.riccati.measurement_weight (the same)
    eigenvalues: str = "auto"  # spectral q's radii: auto, dense or iterative (splitspec_core.synthesis.spectral)
    undetectable: str = "refuse"  # refuse | exclude: a mode no agent sees that does not decay (detectability.py)
    coordinates: str = "auto"  # auto | given | balanced: where the estimator's projections are orthogonal (local_design)
    consensus: str = "auto"  # auto | split | whole: what each agent takes from its neighbours (synthesis/whole_state.py)
    lag: Any = "auto"  # the relay kind's base: extra event times behind (an int >= 0 or auto; synthesis/relay.py)
    # design.bad_data: None (off) or (false_alarm, suspect_after): each agent tests its measurement (synthesis/bad_data.py)
    bad_data: tuple | None = None
    # the key was absent and the scenario states measurement noise: the test is on by default (off where the design
    # cannot calibrate it, synthesis/bad_data.py says why)
    bad_data_default: bool = False


@dataclass(frozen=True)
class NetworkSpec:
    """``network:``: what happens to consensus messages (see :mod:`splitspec_core.model.impairment`).

    ``loss``: probability that one consensus message does not count in its sub-round (every arc);
    ``delay_mean``, ``delay_jitter``: seconds added to every message in ``run`` (uniform in
    ``mean +- jitter``, never negative); ``deadline``: seconds a sub-round waits for its neighbours
    (None: for all of them, lossless); ``arcs``: ``{(j, i): {"loss": p, "delay_mean": s,
    "delay_jitter": s}}`` overrides per arc.
    """

    loss: float = 0.0
    delay_mean: float = 0.0
    delay_jitter: float = 0.0
    deadline: float | None = None
    arcs: dict = field(default_factory=dict)

    @property
    def lossy(self) -> bool:
        """Whether some message may be lost by draw (a loss probability above 0 somewhere), a bool."""
        return self.loss > 0 or any(o.get("loss", 0.0) > 0 for o in self.arcs.values())

    @property
    def delayed(self) -> bool:
        """Whether some message is held in ``run`` (a delay mean or jitter above 0, on every arc or one), a bool."""
        return self.delay_mean > 0 or self.delay_jitter > 0 or any(
            o.get("delay_mean", 0.0) > 0 or o.get("delay_jitter", 0.0) > 0 for o in self.arcs.values())

    @property
    def impaired(self) -> bool:
        """Whether anything goes beyond the perfect network (every message, on time): loss, delay or a deadline; a
        bool."""
        return self.lossy or self.delayed or self.deadline is not None

    def loss_of(self, arc: tuple) -> float:
        """The loss probability of the consensus messages along ``arc``: its override, else ``loss``.

        Parameters
        ----------
        arc : tuple of int
            ``(j, i)``: agent i hears agent j.

        Returns
        -------
        float
            The probability, in [0, 1), that one message along ``arc`` does not count.
        """
        return self.arcs.get(arc, {}).get("loss", self.loss)

    def delay_of(self, arc: tuple) -> tuple:
        """The delay of the messages along ``arc`` in ``run``: its override, else ``delay_mean`` and ``delay_jitter``.

        Parameters
        ----------
        arc : tuple of int
            ``(j, i)``: agent i hears agent j.

        Returns
        -------
        tuple of float
            ``(mean, jitter)`` in seconds.
        """
        o = self.arcs.get(arc, {})
        return o.get("delay_mean", self.delay_mean), o.get("delay_jitter", self.delay_jitter)


@dataclass(frozen=True)
class RunSpec:
    """Run options: number of steps, sample time (continuous), seed, pace, and the states the default views show
    (``show``: names or ``fnmatch`` patterns; None: :func:`splitspec_core.scenarios.labels.shown_states`'s default).

    ``until_stopped``: ``run.steps`` was omitted from a paced run or one fed by live sensors (``sources:``):
    ``splitspec run`` goes on until it is stopped (Ctrl-C, SIGTERM, ``splitspec stop``); ``steps`` is then 60,
    the horizon of ``simulate`` (which needs one) when given no ``--steps``.

    ``keep_hours``, ``keep_gigabytes``: ``run.keep`` (a run until stopped only): a closed segment of the records
    (``chunks/rows-*.arrows``, ``run-*.rrd``) is removed that many hours after it closed, and the oldest closed
    ones while the records take more than that many 10^9 bytes (None: no limit); ``keep_recording_hours``: the
    recording's segments that many hours instead (None: ``keep_hours``); ``keep_segment_mb``: the MiB past which a
    segment closes, chunks and recording alike (None: orchestrator.records.files's 64 and 256).  ``record_every``: the Rerun
    recording's state panels every this many event times (:attr:`recorded_every` resolves the default).
    ``steps_default``: ``run.steps`` was omitted and ``steps`` is the default (what ``splitspec run`` of an unpaced
    scenario says it runs).  ``standby``: ``splitspec run`` starts a standby orchestrator that takes over when the
    active one dies (``run.standby``; docs/how-to/orchestrator.md).
    """

    steps: int = 60
    dt: float | None = None
    seed: int = 0
    pace: float | None = None
    show: tuple | None = None
    until_stopped: bool = False
    keep_hours: float | None = None
    keep_gigabytes: float | None = None
    keep_recording_hours: float | None = None
    record_every: int | None = None
    steps_default: bool = False
    standby: bool = False
    keep_segment_mb: float | None = None  # run.keep.segment_mb: MiB past which a segment closes (None: 64 and 256)

    @property
    def recorded_every(self) -> int:
        """``run.record_every``, or its default: 1, and for a run until stopped at a pace over 10 event times per
        second the event times of 0.1 s (5 at pace 50): a long run's recording sized for review.

        Returns
        -------
        int
            Every how many event times the recording's state panels get a row (at least 1).

        Examples
        --------
        >>> RunSpec(pace=50.0, until_stopped=True).recorded_every, RunSpec(pace=50.0).recorded_every
        (5, 1)
        """
        if self.record_every is not None:
            return int(self.record_every)
        if self.until_stopped and self.pace is not None and self.pace > 10:
            return max(1, int(round(self.pace / 10)))
        return 1


@dataclass(frozen=True)
class Scenario:
    """A validated scenario.  Agent order everywhere is ``agent_ids`` order.

    Built by :func:`splitspec_core.scenario`, :func:`splitspec_core.load_scenario` or directly from the dataclasses
    above (the shapes, the agents and the time are checked either way); ``print`` shows a summary.

    Examples
    --------
    >>> import splitspec_core as ss
    >>> sc = ss.load_scenario("examples/paper_discrete.yaml")
    >>> sc.agent_ids, sc.graph_names, sc.index_of(3)
    ((1, 2, 3), ('a', 'b'), 2)
    >>> sc.graph("b").arcs
    ((1, 2), (2, 1), (2, 3), (3, 2))
    >>> sc.output_names(2), sc.state_names
    (('y2',), ('x1', 'x2', 'x3', 'x4'))
    """

    name: str
    time: str
    agent_ids: tuple
    system: System
    graphs: tuple  # tuple[GraphSpec, ...]
    switching: Switching
    design: DesignSpec
    faults: tuple = ()
    run: RunSpec = field(default_factory=RunSpec)
    source: str = "<scenario>"
    positions: dict | None = None  # agent id -> (x, y) of the topology drawing; None: a circle
    network: NetworkSpec = field(default_factory=NetworkSpec)
    sources: dict | None = None  # agent id -> scenario_sources.Source: live sensors (run only)
    input_source: Any = None  # scenario_sources.Source of sources.inputs: where live known inputs u arrive

    __repr__ = summary  # print(scenario): a summary, not every matrix (scenarios/summary.py)

    @property
    def m(self) -> int:
        """The number of agents ``m``, an int."""
        return len(self.agent_ids)

    @property
    def n(self) -> int:
        """The number of states ``n``, an int."""
        return self.system.n

    @property
    def graph_names(self) -> tuple:
        """Every graph's name, a tuple of str in scenario order (a trajectory's ``graph`` indexes it)."""
        return tuple(g.name for g in self.graphs)

    def graph(self, name: str) -> GraphSpec:
        """The graph named ``name``.

        Parameters
        ----------
        name : str
            A graph's name (a key of ``graphs:``).

        Returns
        -------
        GraphSpec
            Its name and arcs.

        Raises
        ------
        KeyError
            No graph has that name.
        """
        for g in self.graphs:
            if g.name == name:
                return g
        raise KeyError(name)

    def index_of(self, agent_id: int) -> int:
        """Position of ``agent_id`` in ``agent_ids``.

        Parameters
        ----------
        agent_id : int
            An agent of the scenario.

        Returns
        -------
        int
            Its 0-based index in agent order (``system.Cs``, the rows of ``xhat``).

        Raises
        ------
        ValueError
            ``agent_id`` is not an agent of the scenario.
        """
        return self.agent_ids.index(agent_id)

    @property
    def state_names(self) -> tuple:
        """The states' names, a tuple of n str: ``system.states``, else ``x1 .. xn``."""
        return self.system.states if self.system.states is not None else default_state_names(self.n)

    @property
    def sensor_keys(self) -> dict:
        """``{agent id: key}`` of the live sensors, and ``"inputs": key`` of the live known inputs (relative keys;
        each publisher is user ``sensor-<id>`` or ``sensor-inputs`` of a secure run)."""
        out = {a: s.key for a, s in (self.sources or {}).items()}
        if self.input_source is not None:
            out["inputs"] = self.input_source.key
        return out

    @property
    def shown_states(self) -> tuple:
        """Indices of the states ``run.rrd``'s states tab and ``states.png`` show (``run.show``; every state of a
        small model, else those the agents measure: :func:`splitspec_core.scenarios.labels.shown_states`)."""
        from .labels import shown_states

        return shown_states(self.state_names, self.run.show, self.system.Cs)

    @property
    def states_named(self) -> bool:
        """Whether the scenario names its states (``system.states``)."""
        return self.system.states is not None

    def output_names(self, agent_id: int) -> tuple:
        """Agent ``agent_id``'s output names: ``system.outputs.<id>``, else ``y<id>`` / ``y<id>_1 ..``.

        Parameters
        ----------
        agent_id : int
            An agent of the scenario.

        Returns
        -------
        tuple of str
            One name per row of its ``C_i`` (s_i names).

        Raises
        ------
        ValueError
            ``agent_id`` is not an agent of the scenario (and ``system.outputs`` does not name it).
        """
        given = (self.system.outputs or {}).get(agent_id)
        if given is not None:
            return given
        return default_output_names(agent_id, int(np.shape(self.system.Cs[self.index_of(agent_id)])[0]))

    def __post_init__(self) -> None:
        # built directly from the dataclasses, a scenario still meets the parser's shape checks
        if len(self.agent_ids) != len(self.system.Cs):
            raise DimensionError(f"agent_ids lists {len(self.agent_ids)} agents, system.Cs holds "
                                 f"{len(self.system.Cs)} output matrices")
        Cs = dict(zip(self.agent_ids, self.system.Cs))
        Ks = None if self.design.K is None else dict(zip(self.agent_ids, self.design.K))
        check_shapes(self.system.A, Cs, self.system.x0, Ks)
        if self.system.time != self.time:
            raise ScenarioError(f"system.time is {self.system.time!r}, the scenario's time is {self.time!r}")
        given = self.system.measurement_noise
        if isinstance(given, dict) and tuple(given) != tuple(self.agent_ids):
            raise ScenarioError(f"system.measurement_noise lists agents {ids_text(tuple(given))}, the scenario's "
                                f"agents are {ids_text(tuple(self.agent_ids))}")
