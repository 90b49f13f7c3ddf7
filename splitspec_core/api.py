"""The public Python API: build or load a scenario, design, simulate, compare (re-exported by ``splitspec_core``).

Every function here is what a ``splitspec`` command does, minus the files: the CLI's command modules call
these same functions.  Results are frozen dataclasses whose arrays are read-only.

Validation has one path: :func:`scenario` turns its keywords into the mapping a scenario file holds and hands
it to :func:`splitspec_core.scenarios.load.parse_scenario`, the checker of YAML files, so both meet the same
checks with the same one-line messages.

Why one module: it is the public API's one page (what ``help(splitspec_core)`` and the reference show); the
work is in the modules it calls.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path
from types import MappingProxyType
from typing import TYPE_CHECKING, Any, Iterable, Mapping

import numpy as np

from .synthesis.design_data import Design
from .errors import ScenarioError
from .synthesis.verdict import rate_certificate
from .synthesis.report import design_warnings
from .scenarios.checks import DESIGN_KEYS, RUN_KEYS, SYSTEM_KEYS, TOP_KEYS
from .scenarios.control import plant_keywords
from .scenarios.load import ORIGIN, parse_scenario
from .scenarios.load import load_scenario as _load_scenario
from .scenarios.specs import Scenario
from .simulation.simulator import Trajectory
from .model.subspaces import complement
from .studies.comparison import CompareResult, EstimatorResult
from .studies.comparison import compare as _compare

if TYPE_CHECKING:
    from .simulation.montecarlo import MonteCarloRuns

__all__ = ["AgentResult", "Checks", "CompareResult", "DesignResult", "EstimatorResult", "compare", "design", "protocol_limit",
           "load_scenario", "scenario", "simulate"]

_SECTIONS = {"system": SYSTEM_KEYS, "design": DESIGN_KEYS, "run": RUN_KEYS}


def _readonly(a: Any) -> np.ndarray:
    a = np.array(a)
    a.setflags(write=False)
    return a


# --------------------------------------------------------------------------
# scenario
# --------------------------------------------------------------------------


def scenario(*, name: str | None = None, time: str | None = None, plant: Any = None, agents: Mapping | None = None,
             file: str | None = None, A: Any = None, B: Any = None, u: Any = None, sample: float | None = None,
             C: Mapping | None = None, x0: Any = None, process_noise: Any = None,
             measurement_noise: float | Mapping | None = None,
             states: Iterable | None = None, outputs: Mapping | None = None, time_unit: str | None = None,
             graphs: Mapping | None = None,
             switching: Mapping | None = None, faults: Iterable | None = None, positions: Mapping | None = None,
             network: Mapping | None = None, sources: Mapping | None = None, rate: float | None = None,
             gains: str | None = None,
             K: Mapping | None = None, g: Any = None, g0: float | None = None, q: Any = None,
             q_method: str | None = None, q_max: int | None = None, resilience: int | None = None,
             weights: str | None = None, margin: float | None = None, rank_tol: float | None = None,
             graph_set: str | None = None, dwell: float | None = None, riccati: Mapping | None = None,
             eigenvalues: str | None = None, undetectable: str | None = None, coordinates: str | None = None,
             consensus: str | None = None, lag: Any = None, bad_data: Any = None,
             steps: int | None = None, dt: float | None = None, seed: int | None = None, pace: float | None = None,
             show: Any = None, keep: Mapping | None = None, record_every: int | None = None,
             standby: bool | None = None, system: Mapping | None = None, design: Mapping | None = None, run: Mapping | None = None,
             **unknown: Any) -> Scenario:
    """A validated scenario from keywords: every scenario-file key, by its own name.

    ``file`` (relative to the working directory), ``A``, ``B``, ``u``, ``sample``, ``C``, ``x0``, ``process_noise``,
    ``measurement_noise``, ``states`` (n names), ``outputs`` (``{agent id: [names]}``), ``time_unit`` (``s``, ``min``, ...) are the file's ``system.*``
    (``process_noise``: a number, n numbers or an n x n matrix; ``measurement_noise``: a number or ``{agent id: std
    or [one per output]}``; numpy arrays welcome);
    ``rate``, ``gains``, ``K``, ``g``, ``q``, ``q_method``, ... its ``design.*``; ``steps``, ``dt``, ``seed``,
    ``pace``, ``show``, ``keep``, ``record_every``, ``standby`` its ``run.*`` (``docs/how-to/scenario.md`` lists them all).  Matrices may be numpy arrays or nested
    lists; ``C`` and ``K`` map agent ids to matrices; a graph is ``{"arcs": [(j, i), ...], "undirected": [...]}``
    or its list of arcs ``[(j, i), ...]`` (``j -> i``: agent i hears agent j).  ``plant``: a python-control
    ``StateSpace`` in place of the system and ``time``, ``agents={id: [its output labels or indices]}``
    (:mod:`splitspec_core.scenarios.control`).  A keyword left at ``None`` is absent from the file, so the file's
    defaults apply.  The sections ``system=``, ``design=``, ``run=`` may also be given whole, as in the file.

    Parameters
    ----------
    name, time : str, optional
        The scenario's name (default ``scenario``; a python-control plant's own name) and ``discrete`` (default) or
        ``continuous``.
    plant, agents : control.StateSpace, mapping, optional
        A python-control plant and ``{agent id: [its output labels or indices]}``, in place of ``A``, ``B``, ``C``.
    file, A, B, u, sample, C, x0, process_noise, measurement_noise, states, outputs, time_unit : optional
        The file's ``system.*`` keys.
    graphs, switching, faults, positions, network, sources : optional
        The file's sections of those names.
    rate, gains, K, g, g0, q, q_method, q_max, resilience, weights, margin, rank_tol, graph_set, dwell, riccati, \
eigenvalues, undetectable, coordinates, consensus, lag, bad_data : optional
        The file's ``design.*`` keys (``rate`` is required).
    steps, dt, seed, pace, show, keep, record_every, standby : optional
        The file's ``run.*`` keys.
    system, design, run : mapping, optional
        A section given whole, as in the file.
    **unknown : Any
        Refused: an unknown keyword is an unknown key of the file (one line naming it, and the key it may be).

    Returns
    -------
    Scenario
        Frozen and validated; ``print`` shows a summary.

    Raises
    ------
    ScenarioError
        The message of the same mistake in a scenario file (it names the key, e.g.
        ``system.C.3 has 5 columns, system.A is 4x4``); an unknown keyword is an unknown key.

    Examples
    --------
    >>> import splitspec_core as ss
    >>> sc = ss.scenario(A=[[0.9, 0.2], [0, 0.8]], C={1: [[1, 0]], 2: [[0, 1]]},
    ...                  graphs={"a": [(1, 2), (2, 1)]}, rate=0.5)
    >>> sc.n, sc.m, sc.time
    (2, 2, 'discrete')
    """
    given = dict(locals())
    top: dict = {k: v for k, v in unknown.items()}  # the checker names them (and suggests the right key)
    if plant is not None or agents is not None:
        plant_keywords(given, plant, agents)
    for key in TOP_KEYS:  # the file's top-level keys (scenarios/keys.py); system, design, run below
        if key not in _SECTIONS and given[key] is not None:
            top[key] = given[key]
    top.setdefault("name", "scenario")
    for section, keys in _SECTIONS.items():
        whole = given[section]
        if whole is not None and not isinstance(whole, Mapping):
            top[section] = whole  # the checker says what is wrong with it
            continue
        part = dict(whole or {})
        for key in keys:
            if given.get(key) is not None:
                if key in part:
                    raise ScenarioError(f"{section}.{key} is given twice: as {key}= and in {section}=")
                part[key] = given[key]
        if part or whole is not None:
            top[section] = part
    sc = parse_scenario(top, source="<python>")
    object.__setattr__(sc, ORIGIN, top)  # what ss.run hands to the processes as YAML
    return sc


def load_scenario(path: str | Path) -> Scenario:
    """A validated scenario from a YAML file (the same checks as :func:`scenario`).

    Parameters
    ----------
    path : str or Path
        A scenario file (``docs/how-to/scenario.md``); ``system.file`` is found beside it.

    Returns
    -------
    Scenario
        Frozen and validated; ``print`` shows a summary.

    Raises
    ------
    ScenarioError
        One line naming the file and the key (a missing file, bad YAML, a wrong value).

    Examples
    --------
    >>> import splitspec_core as ss
    >>> sc = ss.load_scenario("examples/paper_discrete.yaml")
    >>> sc.name, sc.n, sc.m
    ('paper-discrete', 4, 3)
    """
    sc = _load_scenario(path)
    object.__setattr__(sc, ORIGIN, Path(path))  # what ss.run hands to the processes
    return sc


# --------------------------------------------------------------------------
# design
# --------------------------------------------------------------------------


@dataclass(frozen=True)
class AgentResult:
    """Agent i's local design (computed by the agent itself in a run).

    Attributes
    ----------
    id : agent id
    K : (n, s_i) local gain ``K_i`` (convention ``A + K_i C_i``)
    V : (n, n - r_i) orthonormal basis of the unobservable space of ``(C_i, A)``
    Q : (r_i, n) orthonormal basis of its complement (the observable part)
    P : (n, n) the projection on the unobservable space the estimator runs: ``V_i V_i'``, or with
        ``design.coordinates: balanced`` the balanced coordinates' orthogonal projection, ``D P_b D^-1``
    poles : (r_i,) spectrum of ``Abar_i + Kbar_i Cbar_i`` (the observable part's error dynamics)
    """

    id: int
    K: np.ndarray
    V: np.ndarray
    Q: np.ndarray
    P: np.ndarray
    poles: np.ndarray

    @property
    def n_unobservable(self) -> int:
        """``n_i``, an int: the dimension of the unobservable space the agent takes from its neighbours (the columns
        of ``V``)."""
        return int(self.V.shape[1])


@dataclass(frozen=True)
class Checks:
    """The design's assumptions and its certificate (:meth:`of`: computed from a design, whatever built it).

    Attributes
    ----------
    jointly_observable : every direction is seen by some agent: ``W = V_1 ∩ ... ∩ V_m`` is zero (the paper's
        standing assumption on ``(C, A)``, eqs. pre_sys1-pre_sys2); False when ``(C, A)`` is only detectable (what no
        agent sees decays: :func:`design` goes on, detectability.py)
    jointly_detectable : what no agent sees decays; :func:`design` refuses a system where it does not (AssumptionError)
        unless ``design.undetectable: exclude``, so False only then
    unobserved : one line naming the directions no agent sees and their decay (None: none; detectability.py)
    strongly_connected : per graph name, whether every agent reaches every other along its arcs
        (:attr:`splitspec_core.model.graphs.Graph.strongly_connected` of the design's graphs); :func:`design` refuses a
        scenario with a graph that is not (AssumptionError), so False only for a design built otherwise
    rate_certified : the rate is certified for the estimator as it runs (continuous time: the sampled-data form at
        ``run.dt`` too); never for the adaptive gain (asymptotic convergence: thm. split_continuous_adaptive)
    certificate : one line: what certifies the rate, or why nothing does (``splitspec design`` says the same)
    sampled_rate : continuous: the sampled-data estimator's worst decay rate at ``run.dt``; ``warnings``: the report's
    envelope_rate : the certified envelope's rate: ``rate``, or slower (what no agent sees decays slower); None: none
    """

    jointly_observable: bool
    strongly_connected: Mapping[str, bool]
    rate_certified: bool
    certificate: str
    sampled_rate: float | None
    warnings: tuple
    jointly_detectable: bool = True
    unobserved: str | None = None
    envelope_rate: float | None = None

    @classmethod
    def of(cls, des: Design) -> Checks:
        """The checks of ``des``, each computed from it: what its agents leave unobserved (``Design.unobserved``, or
        for a design built without it what its agents' ``V_i`` leave), its graphs' arcs, its certificate.

        Parameters
        ----------
        des : Design
            A design (:func:`splitspec_core.synthesis.designer.design`, or :attr:`DesignResult.detail`).

        Returns
        -------
        Checks
            Frozen; ``strongly_connected`` a read-only mapping; ``sampled_rate`` the slowest over the cases (None
            when the design has none: discrete time); ``warnings`` the report's.

        Examples
        --------
        >>> import splitspec_core as ss
        >>> d = ss.design(ss.load_scenario("examples/paper_discrete.yaml"))
        >>> c = Checks.of(d.detail)
        >>> c.jointly_observable, dict(c.strongly_connected), c.rate_certified, c.envelope_rate
        (True, {'a': True, 'b': True}, True, 0.5)
        """
        un = des.unobserved if des.unobserved is not None else des.unobserved_of(des.scenario.agent_ids)
        cert = rate_certificate(des)
        connected = {g.name: g.strongly_connected for g in des.graphs}
        return cls(jointly_observable=un.dim == 0, jointly_detectable=un.decays, rate_certified=cert.certified,
                   strongly_connected=MappingProxyType(connected), certificate=cert.text,
                   sampled_rate=min(des.sampled_rate.values()) if des.sampled_rate else None,
                   warnings=tuple(design_warnings(des)), unobserved=un.summary(des.rate) if un.dim else None,
                   envelope_rate=cert.rate)


@dataclass(frozen=True)
class DesignResult:
    """A designed split-spectrum estimator.

    Attributes
    ----------
    scenario : the scenario designed
    time, rate : ``discrete`` (errors within c lam^tau) or ``continuous`` (c exp(-lam t))
    q : discrete: consensus exchanges per event time (eq. split_discrete_ench); else None
    g : continuous: the consensus gain (eq. g); None in discrete time and for the adaptive gain
    g_mode : continuous: ``auto``, ``given`` or ``adaptive``; else None
    agents : agent id -> :class:`AgentResult`
    checks : :class:`Checks`
    detail : the full design with every diagnostic (:class:`splitspec_core.synthesis.design_data.Design`)
    """

    scenario: Scenario
    time: str
    rate: float
    q: int | None
    g: float | None
    g_mode: str | None
    agents: Mapping[int, AgentResult]
    checks: Checks
    detail: Design

    def report(self) -> str:
        """The text ``splitspec design`` prints.

        Returns
        -------
        str
            The report: the agents' local designs, q or g with the bound that certifies it, the cases, the loss
            analyses and the warnings (:func:`splitspec_core.synthesis.report.design_text`).

        Examples
        --------
        >>> import splitspec_core as ss
        >>> print(ss.design(ss.load_scenario("examples/paper_discrete.yaml")).report().splitlines()[0])
        splitspec design: paper-discrete  (discrete time, m = 3 agents, n = 4 states)
        """
        from .synthesis.report import design_text

        return design_text(self.detail)

    def to_json(self) -> dict:
        """The object ``splitspec design --json`` prints.

        Returns
        -------
        dict
            JSON-ready (lists, numbers, strings): the same figures as :meth:`report`
            (:func:`splitspec_core.synthesis.report.design_json`), e.g. ``q``, ``agents``, ``certificate``.

        Examples
        --------
        >>> import splitspec_core as ss
        >>> ss.design(ss.load_scenario("examples/paper_discrete.yaml")).to_json()["q"]
        6
        """
        from .synthesis.report import design_json

        return design_json(self.detail)


def protocol_limit(sc: Scenario, q: int, *, graph: str | None = None):
    """The best any estimator can do with ``q`` exchanges per event time on the scenario's network.

    In the two-rate protocol (measure, exchange ``q`` times, predict) a sensor ``d`` hops away reaches an agent's
    estimate ``ceil(d / q) - 1`` event times late, so no estimator beats the centralized Kalman predictor fed each
    sensor that late (:mod:`splitspec_core.synthesis.exchange_limit`).  ``splitspec design`` prints it for the
    design's own ``q`` under noise.

    Parameters
    ----------
    sc : Scenario
        With noise (``system.process_noise``, ``system.measurement_noise``); discrete, or continuous on its model
        sampled with ``run.dt``.
    q : int
        Exchanges per event time (at least 1).
    graph : str, optional
        The graph's name; default the first one.

    Returns
    -------
    ProtocolLimit
        ``ratio`` (the limit over the Kalman predictor's RMS), ``rms`` and ``kf_rms`` per state, ``agent_rms`` per
        agent, ``delays`` (event times each agent hears each sensor late).

    Raises
    ------
    ScenarioError
        An unknown graph.
    DesignError
        No Kalman predictor (the stacked sensors not detectable with the noise), or ``q < 1``.

    Examples
    --------
    >>> import splitspec_core as ss
    >>> sc = ss.load_scenario("examples/rego_ring.yaml")
    >>> [round(ss.protocol_limit(sc, q).ratio, 3) for q in (1, 2, 3)]
    [1.775, 1.401, 1.247]
    """
    from .synthesis.exchange_limit import scenario_limit

    if graph is not None and graph not in sc.graph_names:
        raise ScenarioError(f"protocol_limit: unknown graph {graph!r}; the scenario has {', '.join(sc.graph_names)}")
    return scenario_limit(sc, int(q), graph=0 if graph is None else sc.graph_names.index(graph))


def design(sc: Scenario, *, all_q_methods: bool = False, workers: int | None = None) -> DesignResult:
    """Check the assumptions and design the estimator (``splitspec design``).

    ``all_q_methods=True`` also computes, for information, the q every other certificate
    (spectral, weighted, two-norm, mixed) would give (``detail.q_methods``, in the report).
    ``workers``: processes computing the spectral radii of a large resilient design (one case per agent loss)
    at once; ``None`` (default): every core this process may use; 1: none besides this one.  The same
    numbers either way.

    Parameters
    ----------
    sc : Scenario
        From :func:`scenario` or :func:`load_scenario`.
    all_q_methods : bool
        Also compute the q of every other certificate, for information.
    workers : int, optional
        Processes for a large resilient design's spectral radii.

    Returns
    -------
    DesignResult
        ``q`` (discrete) or ``g`` (continuous), every agent's ``K``, ``V``, ``P``, the ``checks`` (the certificate in
        one line), ``report()`` (what ``splitspec design`` prints) and ``to_json()``.

    Raises
    ------
    AssumptionError
        A graph is not strongly connected, ``(C, A)`` is not jointly detectable, explicit gains miss the rate (named).
    DesignError
        No q below ``design.q_max``, or no g found.

    Examples
    --------
    >>> import splitspec_core as ss
    >>> d = ss.design(ss.load_scenario("examples/paper_discrete.yaml"))
    >>> d.q, d.checks.rate_certified
    (6, True)
    >>> d.checks.certificate
    'q = 6: spectral bound 0.4736 < rate 0.5'
    """
    from .synthesis.design_cache import cached_design as _design

    des = _design(sc, compare_q_methods=all_q_methods, workers=workers)
    agents = {a.id: AgentResult(id=a.id, K=_readonly(a.K), V=_readonly(a.V_user), Q=_readonly(complement(a.V_user).T),
                                P=_readonly(a.P), poles=_readonly(a.gain.poles)) for a in des.agents}
    return DesignResult(scenario=sc, time=sc.time, rate=sc.design.rate, q=des.q, g=des.g, g_mode=des.g_mode,
                        agents=MappingProxyType(agents), checks=Checks.of(des), detail=des)


# --------------------------------------------------------------------------
# simulate
# --------------------------------------------------------------------------


def _designed(sc_or_design: Scenario | DesignResult | Design) -> Design:
    if isinstance(sc_or_design, DesignResult):
        return sc_or_design.detail
    if isinstance(sc_or_design, Design):
        return sc_or_design
    if isinstance(sc_or_design, Scenario):
        return design(sc_or_design).detail
    raise TypeError(f"expected a Scenario or a DesignResult, got {type(sc_or_design).__name__}")


def _with_faults(sc: Scenario | DesignResult | Design, faults: Iterable) -> Scenario | Design:
    """``sc`` (a scenario or a design of one) with its ``faults:`` replaced by ``faults`` (the file's format)."""
    from .scenarios.sections import parse_faults

    if isinstance(sc, DesignResult):
        sc = sc.detail
    base = sc.scenario if isinstance(sc, Design) else sc
    if not isinstance(base, Scenario):
        raise TypeError(f"expected a Scenario or a DesignResult, got {type(sc).__name__}")
    outputs = {i: len(C) for i, C in zip(base.agent_ids, base.system.Cs)}
    new = dataclasses.replace(base, faults=parse_faults(list(faults), base.agent_ids, outputs=outputs))
    return dataclasses.replace(sc, scenario=new) if isinstance(sc, Design) else new


def simulate(sc: Scenario | DesignResult, *, steps: int | None = None, seed: int | None = None,
             seeds: Iterable[int] | None = None, noise: bool = True, exact: bool = False,
             progress: bool | None = False, lost=None, measurements=None, keep_y: bool = False,
             trajectories: bool = False, faults: Iterable | None = None) -> "Trajectory | MonteCarloRuns":
    """Simulate in-process: the reference the multi-process ``splitspec run`` reproduces.

    The same scenario and seed give the trajectory ``splitspec simulate`` writes (and, to
    round-off, the one ``splitspec run`` records).  ``steps`` and ``seed`` default to
    ``run.steps`` and ``run.seed``; ``noise=False`` drops process and measurement noise;
    ``exact=True`` integrates the continuous-time ODE of eq. (split_continuous_observer)
    noise-free instead of the sampled-data estimator.  ``lost``: replay a run's recorded consensus
    losses (its ``trajectory.npz`` ``lost``, or ``(lost, lost_cause)``) instead of drawing the scenario's.
    ``measurements``: the user's recorded ``y`` instead of the simulated plant (a path to an ``.npz`` or
    ``.csv`` file, :mod:`splitspec_core.scenarios.measurements`, or a loaded ``Measurements``); ``keep_y`` records the
    simulated plant's measurements in ``Trajectory.y``.  ``faults``: the scenario's ``faults:`` replaced by these,
    as :func:`splitspec_core.run` takes them (the file's format, e.g. ``[{"at": 10, "kill": 3}, {"at": 20,
    "restart": 3}]``); the trajectory is then the one ``run`` with the same ``faults`` records.

    ``seeds``: a Monte Carlo study, every seed of ``seeds`` on the same design, as one batched
    computation (:mod:`splitspec_core.simulation.montecarlo`: the seeds on a trailing axis of the estimates, each
    seed drawing exactly the numbers ``simulate(sc, seed=s)`` draws).  What a seed changes beyond the
    noise and the initial values runs the seeds one after another instead, with the same results:
    ``network:`` losses and delays (drawn per seed), random switching drawn from the run's seed,
    ``lost``, ``measurements`` and ``exact=True`` (``MonteCarloRuns.fallback`` says which).  Faults,
    switching that does not depend on the seed, partitions, continuous time and the adaptive gain
    are batched.  Only per-step errors are kept (2 N T numbers); ``trajectories=True`` also keeps
    every seed's :class:`Trajectory` (N trajectories: checked against this machine's memory); ``progress``
    is ignored with ``seeds``.

    Parameters
    ----------
    sc : Scenario or DesignResult
        What to simulate (a scenario is designed first).
    steps, seed : int, optional
        Default ``run.steps`` and ``run.seed``.
    seeds : iterable of int, optional
        A Monte Carlo study (returns :class:`MonteCarloRuns`).
    noise : bool
        False drops process and measurement noise (default True).
    exact : bool
        Continuous time: integrate the noise-free ODE instead of the sampled-data estimator (default False).
    progress : bool or None
        A progress bar on stderr (None: when stderr is a terminal and the run is long); ignored with ``seeds``.
    lost : array or tuple, optional
        A run's recorded consensus losses to replay (``lost``, or ``(lost, lost_cause)``).
    measurements : str, Path or Measurements, optional
        The user's recorded ``y`` instead of the simulated plant.
    keep_y : bool
        Record the simulated plant's measurements in ``Trajectory.y`` (one seed only).
    trajectories : bool
        With ``seeds``: also keep every seed's :class:`Trajectory`.
    faults : iterable of mapping, optional
        Replaces the scenario's ``faults:`` (the file's format).

    Returns
    -------
    Trajectory
        Without ``seeds``: ``t`` (T,), ``x`` (T, n), ``xhat`` (T, m, n) (NaN while an agent is dead),
        ``alive`` (T, m), ``graph`` (T,) index into ``scenario.graph_names``, ``columns`` the per-agent row columns
        (:mod:`splitspec_core.model.rows`) such as ``g`` (T, m) g_i(t),
        ``lost`` (N, 4) the consensus messages that did not count; ``errors()``.
    MonteCarloRuns
        With ``seeds``: ``seeds``, ``t`` (T,), ``sq_error`` (N, T) the squared error summed over the
        alive agents per seed and step, ``alive_count`` (N, T), ``rms()`` (N, T), ``stats()`` (the
        Monte Carlo statistics of ``splitspec simulate --monte-carlo``), ``batched``, ``fallback``,
        ``trajectories``.  Per seed it equals the single-seed run to round-off, not bit for bit (the
        batched products sum in another order): relative differences of order 1e-12 are measured.

    Raises
    ------
    ScenarioError
        ``seed`` and ``seeds`` both given, ``seeds`` empty, ``keep_y`` with ``seeds``, ``trajectories`` without
        ``seeds``, ``exact`` with ``measurements``, or a run that cannot fit in memory.

    Examples
    --------
    >>> import splitspec_core as ss
    >>> tr = ss.simulate(ss.load_scenario("examples/paper_discrete.yaml"), steps=40, seed=1)
    >>> tr.xhat.shape
    (41, 3, 4)
    >>> bool(tr.errors()[-1].max() < 1e-6)
    True
    >>> killed = ss.simulate(ss.load_scenario("examples/ring10.yaml"), faults=[{"at": 5, "kill": 3}])
    >>> int(killed.alive[-1].sum())
    9
    """
    from .simulation.simulator import check_trajectory_memory, simulate as _simulate, simulate_exact

    des = _designed(sc if faults is None else _with_faults(sc, faults))
    if measurements is not None and not hasattr(measurements, "sha256"):
        from .scenarios.measurements import load_measurements

        measurements = load_measurements(measurements, des.scenario, steps=steps)
    if seeds is not None:
        from .simulation.montecarlo import simulate_seeds

        if seed is not None:
            raise ScenarioError("give seed (one run) or seeds (a Monte Carlo study), not both")
        if keep_y:
            raise ScenarioError("keep_y records one run's measurements: simulate one seed")
        return simulate_seeds(des, seeds, steps=steps, noise=noise, trajectories=trajectories, lost=lost,
                              measurements=measurements, exact=exact)
    if trajectories:
        raise ScenarioError("trajectories=True keeps every seed's trajectory: give seeds")
    if measurements is None:
        check_trajectory_memory(des.scenario, steps, key="steps" if steps is not None else "run.steps")
    if exact:
        if measurements is not None:
            raise ScenarioError("exact=True integrates the noise-free ODE; measurements drive the sampled-data "
                                "estimator: use one")
        return simulate_exact(des, seed=seed, steps=steps)
    return _simulate(des, seed=seed, steps=steps, noise=noise, progress=progress, lost=lost,
                     measurements=measurements, keep_y=keep_y)


# --------------------------------------------------------------------------
# compare
# --------------------------------------------------------------------------


def compare(sc: Scenario, *, seeds: int | Iterable[int] = 5, seed: int | None = None, steps: int | None = None,
            kcf_eps: float | None = None) -> CompareResult:
    """Estimation quality under noise (``splitspec compare``): every estimator on the same realisations.

    ``seeds``: a count (seeds ``seed, seed + 1, ...``, ``seed`` defaulting to ``run.seed``) or the seeds.

    Parameters
    ----------
    sc : Scenario
        A scenario with noise (``system.process_noise`` and/or ``system.measurement_noise``).
    seeds : int or iterable of int
        A count (from ``seed``) or the seeds themselves.
    seed : int, optional
        The first seed of a count (default ``run.seed``).
    steps : int, optional
        Default ``run.steps``, or longer when that is shorter than twice the longest certified transient
        (``steps_note`` says so); each row's steady RMS is measured after its own certified transient.
    kcf_eps : float, optional
        The Kalman consensus filter's consensus gain (default: its stable choice).

    Returns
    -------
    CompareResult
        ``estimators`` (the scenario's design, the paper's split with place and riccati gains, the centralized
        Kalman filter, the centralized Kalman filter designed for A/rate when the KF is slower, the KCF), the
        rows that could not be designed (``failed``), mean error curves; ``to_json()`` is compare.json (built by
        :mod:`splitspec_core.studies.comparison`).

    Raises
    ------
    DesignError
        The scenario has no noise, or its own design fails.

    Examples
    --------
    >>> import splitspec_core as ss
    >>> res = ss.compare(ss.load_scenario("examples/paper_discrete_noise.yaml"), seeds=3, steps=60)
    >>> sorted(res.estimators)
    ['KCF', 'centralized KF', 'split (scenario)', 'split place', 'split riccati', 'split tuned']
    >>> 1.2 < res.estimators["split place"].ratio_to_centralized < 2.5  # the paper's split: about 1.7x the KF's RMS
    True
    """
    if isinstance(seeds, (int, np.integer)) and not isinstance(seeds, bool):
        if seeds < 1:
            raise ScenarioError(f"seeds must be >= 1, got {seeds}")
        first = sc.run.seed if seed is None else int(seed)
        seeds = range(first, first + int(seeds))
    return _compare(sc, seeds=[int(s) for s in seeds], steps=steps, eps=kcf_eps)
