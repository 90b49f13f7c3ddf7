"""The design engine: scenario -> split-spectrum estimator with its certificates.

Steps (paper, Sections 2-4):

1. ``(C, A)`` jointly observable (before any gain is judged);
2. per agent: observability decomposition ``V_i, Q_i, P_i`` and local gain
   ``K_i`` (local; each agent can do this from ``(A, C_i, lam)``); every
   graph strongly connected;
3. centralised: g (continuous) or q (discrete) covering every graph the
   switching signal can use (and, with ``design.resilience: 1``, every graph
   left after a single agent loss);
4. resilience analysis (single agent and single arc losses).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

from . import bounds
from .errors import AssumptionError
from .conditioning import conditioning
from .full_matrix import SPLIT_EXACT, check_full
from .gains import LocalGain, design_gain
from .graphs import build_graph, enumerate_strongly_connected
from .loss_certificate import loss_certificate
from .observability import DEFAULT_RANK_TOL, Decomposition, check_joint_observability, decompose
from .resilience import analyse_agent_losses, analyse_arc_losses
from .sampled import sampled_rates
from .scenario_model import Scenario

__all__ = ["AgentDesign", "Design", "certify_network", "design", "design_agent", "scenario_dwell",
           "NO_CERTIFIED_RATE"]

# thm. split_continuous_adaptive: with the adaptive gain (eq. adaptive) every error tends to zero, at no stated rate
NO_CERTIFIED_RATE = "asymptotic convergence only (no certified rate)"


@dataclass(frozen=True)
class AgentDesign:
    """One agent's local design: decomposition and gain."""

    id: int
    dec: Decomposition
    gain: LocalGain

    @property
    def K(self) -> np.ndarray:
        return self.gain.K

    @property
    def V(self) -> np.ndarray:
        return self.dec.V

    @property
    def P(self) -> np.ndarray:
        return self.dec.P


@dataclass(frozen=True)
class Design:
    """A complete design with diagnostics (see ``design_json`` for the contract).

    ``g`` is ``None`` for discrete time and for the adaptive estimator;
    ``q`` is ``None`` for continuous time.  ``g_certified_by`` names what
    certifies g for the ODE (None: nothing, or the adaptive gain); the verdict
    for the estimator as run is :func:`splitspec_core.report.rate_certificate`.
    """

    scenario: Scenario
    agents: tuple
    graphs: tuple  # Graph per scenario graph, scenario order
    cases: tuple  # bounds.Case covered by g or q
    g: float | None = None
    g_mode: str | None = None  # auto | given | adaptive
    g_bounds: dict = field(default_factory=dict)  # case label -> eq. (g)
    g_mins: dict = field(default_factory=dict)  # case label -> exact smallest g
    g_dwell: float | None = None
    dwell: float | None = None
    g_arbitrary: float | None = None
    g_certified_by: str | None = None
    q: int | None = None
    q_result: bounds.QResult | None = None
    q_methods: dict = field(default_factory=dict)  # the q method's result; every method's with compare_q_methods
    error_radius: dict = field(default_factory=dict)  # case label -> spectral radius / abscissa of A_V
    sampled_rate: dict = field(default_factory=dict)  # continuous: case label -> decay rate of the sampled-data form
    agent_losses: dict = field(default_factory=dict)
    arc_losses: dict = field(default_factory=dict)
    warnings: tuple = ()
    # max over agents of Decomposition.split_residual; above round-off, full_radius: conditioning.check_full
    split_residual: float = 0.0
    full_radius: dict = field(default_factory=dict)

    @property
    def time(self) -> str:
        return self.scenario.time

    @property
    def rate(self) -> float:
        return self.scenario.design.rate

    @property
    def Ks(self) -> list:
        return [a.K for a in self.agents]

    @property
    def Ps(self) -> list:
        return [a.P for a in self.agents]

    @property
    def Vs(self) -> list:
        return [a.V for a in self.agents]

    @property
    def redundantly_strongly_connected(self) -> bool:
        return all(all(r.strongly_connected.values()) for r in self.agent_losses.values())

    @property
    def redundantly_jointly_observable(self) -> bool:
        return all(r.jointly_observable for r in self.agent_losses.values())

    @property
    def split_exact(self) -> bool:
        """Every V_i an unobservable space to round-off: the split of prop. error holds, the certificates apply."""
        return self.split_residual <= SPLIT_EXACT

    # on first use (the full error matrices cost more than the design itself at scale):
    loss_certificate = cached_property(loss_certificate)  # under network: and partitions (None without)
    conditioning = cached_property(conditioning)  # margins, gain sizes, transient constant, noise


def design_agent(A: np.ndarray, C: np.ndarray, *, time: str, rate: float, method: str = "place",
                 margin: float = 0.5, K: np.ndarray | None = None, rank_tol: float | None = None,
                 process_weight: float = 1.0, measurement_weight: float = 1.0, agent_id: int = 0) -> AgentDesign:
    """The local, fully distributed part of the design for one agent (``V_i, P_i, K_i``)."""
    dec = decompose(A, C, rank_tol=rank_tol)
    label = f"design.K.{agent_id}" if method == "explicit" else f"agent {agent_id}"
    gain = design_gain(dec, method=method, time=time, rate=rate, margin=margin, K=K,
                       process_weight=process_weight, measurement_weight=measurement_weight, label=label)
    return AgentDesign(id=agent_id, dec=dec, gain=gain)


def riccati_weights(sc: Scenario) -> tuple:
    """Riccati weights: explicit ``design.riccati`` or the scenario's noise levels, else 1."""
    d, s = sc.design, sc.system
    pw = d.riccati_process_weight or (s.process_noise**2 if s.process_noise > 0 else 1.0)
    mw = d.riccati_measurement_weight or (s.measurement_noise**2 if s.measurement_noise > 0 else 1.0)
    return pw, mw


def scenario_dwell(sc: Scenario) -> float | None:
    """Average dwell time of the switching signal: design.dwell, random dwell, or shortest schedule piece."""
    if sc.design.dwell is not None:
        return sc.design.dwell
    sw = sc.switching
    if sw.kind == "random":
        return sw.dwell
    if sw.kind == "schedule" and len(sw.graph_names(sc.graph_names)) > 1:
        starts = [t for t, _ in sw.schedule]
        gaps = np.diff(starts).tolist()
        if sw.period is not None:
            gaps.append(sw.period - starts[-1])
        elif not gaps:
            return None
        return float(min(gaps)) if gaps else None
    return None


def design(sc: Scenario, *, compare_q_methods: bool = False, workers: int | None = None) -> Design:
    """Run the whole design for a scenario.

    ``compare_q_methods`` (discrete time) also computes, for information, the q of every other
    q method over the same cases (``Design.q_methods``; ``splitspec design --all-methods``).
    ``workers``: processes for the spectral radii of many large cases (a resilient design of hundreds of
    agents; :func:`splitspec_core.bounds.q_spectral`); ``None``: every core this process may use.

    Raises
    ------
    AssumptionError
        A graph is not strongly connected, the system is not jointly
        observable, explicit gains miss the rate, or ``design.resilience: 1``
        is asked of a network that is not redundant.
    DesignError
        No g or q could be found within limits.
    """
    d = sc.design
    A = sc.system.A
    # the standing assumption first ((C, A) of eqs. pre_sys1-pre_sys2 jointly observable): without it no K_i helps,
    # so an explicit K_i that misses the rate on a direction nobody sees is not the error to report
    jo, warnings = check_joint_observability(A, sc.system.Cs, rank_tol=d.rank_tol), []
    if jo.margin is not None and jo.margin < DEFAULT_RANK_TOL:
        why = f"kept by design.rank_tol: {d.rank_tol:g}" if d.rank_tol is not None else "kept: leaving it out " \
            "would break the split"
        warnings.append(f"(C, A) is jointly observable only with a margin of {jo.margin:.2g} (< {DEFAULT_RANK_TOL:g}, "
                        f"{why}): gains grow like 1 / margin")
    pw, mw = riccati_weights(sc)
    agents = tuple(
        design_agent(A, C, time=sc.time, rate=d.rate, method=d.gains, margin=d.margin,
                     K=None if d.K is None else d.K[k], rank_tol=d.rank_tol,
                     process_weight=pw, measurement_weight=mw, agent_id=aid)
        for k, (aid, C) in enumerate(zip(sc.agent_ids, sc.system.Cs))
    )
    graphs = tuple(build_graph(g.name, sc.agent_ids, g.arcs, weights=d.weights) for g in sc.graphs)
    used = sc.switching.graph_names(sc.graph_names)
    by_name = {g.name: g for g in graphs}
    ad = {a.id: a for a in agents}

    def case_for(label, graph):
        return bounds.make_case(label, graph, [ad[i].V for i in graph.ids], [ad[i].dec.A_un for i in graph.ids])

    cases = [case_for(name, by_name[name]) for name in used]
    if d.graph_set == "all":
        for k, arcs in enumerate(enumerate_strongly_connected(sc.m)):
            arcs_ids = tuple((sc.agent_ids[j], sc.agent_ids[i]) for j, i in arcs)
            g = build_graph(f"all#{k + 1}", sc.agent_ids, arcs_ids, weights=d.weights)
            cases.append(case_for(g.name, g))

    Cs_by_id = dict(zip(sc.agent_ids, sc.system.Cs))
    graph_arcs = {g.name: g.arcs for g in sc.graphs}
    agent_losses = analyse_agent_losses(A, Cs_by_id, graph_arcs, rank_tol=d.rank_tol) if sc.m > 1 else {}
    arc_losses = analyse_arc_losses(sc.agent_ids, graph_arcs)
    if d.resilience:
        for lost, rep in agent_losses.items():
            if not rep.jointly_observable:
                raise AssumptionError(
                    f"design.resilience: 1 needs a redundantly jointly observable network: without agent {lost}, "
                    f"direction {rep.unobservable_direction} is unobservable")
            for name in used:
                if not rep.strongly_connected[name]:
                    j, i = rep.unreachable[name]
                    raise AssumptionError(
                        f"design.resilience: 1 needs a redundantly strongly connected network: without agent "
                        f"{lost}, graph {name} is not strongly connected (agent {j} cannot reach agent {i})")
            survivors = tuple(i for i in sc.agent_ids if i != lost)
            for name in used:  # strongly connected: checked just above (rep.strongly_connected)
                g = build_graph(f"{name} without agent {lost}", survivors, graph_arcs[name], weights=d.weights,
                                check=False)
                cases.append(case_for(g.name, g))
    cases = tuple(cases)
    switching = len(used) > 1 or d.graph_set == "all"

    kw: dict = {}
    if sc.time == "continuous":
        kw.update(_design_g(sc, cases, switching, warnings))
        if kw["g"] is not None:
            kw["sampled_rate"] = _sampled_check(sc, agents, cases, kw["g"], warnings)
    else:
        kw.update(_design_q(sc, cases, switching, warnings, compare_q_methods, workers))
    residual = max((a.dec.split_residual for a in agents), default=0.0)
    des = Design(scenario=sc, agents=agents, graphs=graphs, cases=cases, agent_losses=agent_losses,
                 arc_losses=arc_losses, warnings=tuple(warnings), split_residual=residual, **kw)
    if des.split_exact or (sc.time == "continuous" and des.g is None):
        return des
    return check_full(des, warnings)  # an approximate split: the rate on the full error matrices


def _design_g(sc: Scenario, cases, switching: bool, warnings: list) -> dict:
    d = sc.design
    rate = d.rate
    g_bounds = {c.label: bounds.g_bound(c, rate) for c in cases}
    g_mins = {c.label: bounds.g_min(c, rate, g_hi=max(g_bounds[c.label], 1e-9)) for c in cases}
    dwell = scenario_dwell(sc) if switching else None
    g_dw = bounds.g_dwell_bound(cases, rate, dwell) if (switching and dwell) else None
    g_arb = bounds.g_arbitrary_bound(cases, rate) if switching else None
    per_graph = max(g_bounds.values())
    if not switching:
        certified = {"eq:g": per_graph}
    else:
        certified = {k: v for k, v in (("thm:arb", g_arb), ("eq:split_continuous_g", g_dw)) if v is not None}
    if d.g == "adaptive":
        g, mode, by = None, "adaptive", None  # thm. split_continuous_adaptive: NO_CERTIFIED_RATE
    elif d.g == "auto":
        mode = "auto"
        if certified:
            by = min(certified, key=certified.get)
            g = bounds.nice_ceil(certified[by] * (1 + 1e-9))
        else:
            by = None
            g = bounds.nice_ceil(per_graph * (1 + 1e-9))
            warnings.append("g is not certified for switching: the graphs are not all doubly stochastic and no "
                            "dwell time is known (set design.dwell or design.weights: metropolis); g covers "
                            "each graph held constant (eq. g)")
    else:
        g, mode = float(d.g), "given"
        ok = [k for k, v in certified.items() if g >= v]
        by = min(ok, key=certified.get) if ok else None
        if by is None:
            if all(bounds.abscissa(c, g) <= -rate for c in cases):
                what = "each graph held constant" if switching else "the constant graph"
                warnings.append(f"g = {g:g} is below the sufficient bound but the exact spectrum meets the rate for "
                                f"{what}")
                by = None if switching else "spectrum (exact, constant graph)"
            else:
                bad = [c.label for c in cases if bounds.abscissa(c, g) > -rate]
                warnings.append(f"g = {g:g} does NOT meet rate {rate:g} on {', '.join(bad)}")
    radius = {c.label: bounds.abscissa(c, g) for c in cases} if g is not None else {}
    return dict(g=g, g_mode=mode, g_bounds=g_bounds, g_mins=g_mins, g_dwell=g_dw, dwell=dwell,
                g_arbitrary=g_arb, g_certified_by=by, error_radius=radius)


def _sampled_check(sc: Scenario, agents, cases, g: float, warnings: list) -> dict:
    """:func:`sampled.sampled_rates` for the design; warn when the sampled-data form misses the rate."""
    dt = sc.run.dt
    out = sampled_rates(sc, agents, cases, g)
    worst = min(out.values())
    if worst <= 0:
        warnings.append(f"the sampled-data estimator is UNSTABLE with g = {g:g} and run.dt = {dt:g} "
                        f"(dt too large against g or |K_i C_i|): reduce run.dt")
    elif worst < sc.design.rate:
        warnings.append(f"with run.dt = {dt:g} the sampled-data estimator decays at {worst:.4g} < rate "
                        f"{sc.design.rate:g} (first order in dt against g and |K_i C_i|): reduce run.dt")
    return out


def _design_q(sc: Scenario, cases, switching: bool, warnings: list, compare: bool, workers: int | None) -> dict:
    d = sc.design
    rate = d.rate
    given = None if d.q == "auto" else int(d.q)
    result = bounds.choose_q(d.q_method, cases, rate, q=given, q_max=d.q_max, eig=d.eigenvalues, workers=workers)
    if switching and not result.switching:
        warnings.append(f"q_method {d.q_method} certifies each graph held constant; the scenario switches among "
                        f"{len(cases)} graphs: use q_method two-norm or mixed for a switching certificate")
    if not result.certified:
        warnings.append(f"q = {result.q} does NOT meet rate {rate:g} by the {d.q_method} certificate "
                        f"(bound {result.bound:.4g})")
    others = {}
    for meth in ("spectral", "weighted", "two-norm", "mixed") if compare else ():
        if meth == d.q_method:
            continue
        try:
            others[meth] = bounds.choose_q(meth, cases, rate, q_max=d.q_max)
        except Exception as exc:  # noqa: BLE001 - comparison only; the chosen method already succeeded
            others[meth] = str(exc)
    others[d.q_method] = result
    # rho(Atil B^q) per case (eq. split_discrete_rho); the spectral q search has computed them already
    radius = {c.label: bounds.error_radius(c, result.q, rate=rate, method=d.eigenvalues) for c in cases}
    return dict(q=result.q, q_result=result, q_methods=others, error_radius=radius)


def certify_network(des: Design, alive_ids, dropped=frozenset()) -> dict:
    """Does the designed g or q still certify the rate on what is left after losses?

    The survivors ``alive_ids`` on every graph the switching signal uses,
    minus the ``dropped`` arcs: strong connectivity and joint observability
    (:func:`resilience.network_verdict`), then, when both hold, the design's
    own certificate recomputed on the survivors' graphs: ``q`` with the
    design's q method (rho(Atil B^q) <= lam for ``spectral``, eq. split_discrete_rho),
    ``g`` against eq. (g) or, failing that, the exact spectrum of A_V(g)
    (eq. split_continuous_split) per graph held constant.  Cheap enough to
    call at every loss during a run (no bisection).  A continuous g must also
    make the sampled-data form with ``run.dt`` decay at the rate (as
    :func:`splitspec_core.report.rate_certificate`).

    Returns a JSON-ready dict: ``alive``, ``dropped_arcs``,
    ``strongly_connected`` (per graph), ``unreachable`` (per graph, a pair
    ``[j, i]``), ``jointly_observable``, ``unobservable_direction``,
    ``rate_certified`` (bool, or None for the adaptive gain), ``certificate``
    (one line), ``ok``.
    """
    from .network import active_arcs
    from .resilience import network_verdict

    sc = des.scenario
    alive = tuple(a for a in sc.agent_ids if a in set(alive_ids))
    used = sc.switching.graph_names(sc.graph_names)
    arcs = {name: active_arcs(sc, sc.graph_names.index(name), dropped) for name in used}
    v = network_verdict(sc.system.A, dict(zip(sc.agent_ids, sc.system.Cs)), alive, arcs,
                        rank_tol=sc.design.rank_tol)
    out = {"alive": list(alive), "dropped_arcs": sorted([list(a) for a in dropped]),
           "strongly_connected": dict(v.strongly_connected),
           "unreachable": {k: list(p) for k, p in v.unreachable.items()},
           "jointly_observable": v.jointly_observable, "unobservable_direction": v.unobservable_direction}
    rate = sc.design.rate
    if not v.ok:
        cert, text = False, "no rate: " + ("the survivors are not jointly observable" if not v.jointly_observable
                                            else "a graph is not strongly connected")
    elif des.time == "discrete":
        ad = {a.id: a for a in des.agents}
        cases = [bounds.make_case(name, build_graph(name, alive, arcs[name], weights=sc.design.weights),
                                  [ad[i].V for i in alive], [ad[i].dec.A_un for i in alive]) for name in used]
        res = bounds.choose_q(sc.design.q_method, cases, rate, q=des.q, q_max=sc.design.q_max,
                              eig=sc.design.eigenvalues)
        cert = bool(res.certified)
        text = (f"q = {des.q}: {res.method} bound {res.bound:.4g} {'<=' if cert else '>'} rate {rate:g}"
                + ("" if res.switching or len(cases) == 1 else " (per graph held constant)"))
    elif des.g is None:
        cert, text = None, f"adaptive gain: {NO_CERTIFIED_RATE}"
    else:
        ad = {a.id: a for a in des.agents}
        cases = [bounds.make_case(name, build_graph(name, alive, arcs[name], weights=sc.design.weights),
                                  [ad[i].V for i in alive], [ad[i].dec.A_un for i in alive]) for name in used]
        gb = max(bounds.g_bound(c, rate) for c in cases)
        if des.g >= gb:
            cert, text = True, f"g = {des.g:g} >= eq. (g) bound {gb:.4g} on the survivors' graphs"
        else:
            worst = max(bounds.abscissa(c, des.g) for c in cases)
            cert = worst <= -rate
            text = (f"g = {des.g:g} < eq. (g) bound {gb:.4g}; exact spectral abscissa {worst:.4g} "
                    f"{'<=' if cert else '>'} -{rate:g} (per graph held constant)")
        if cert:  # what runs is the sampled-data form (steps.py): it must decay at the rate too
            dt, sampled = sc.run.dt, min(sampled_rates(sc, [ad[i] for i in alive], cases, des.g).values())
            if sampled < rate:
                cert = False
                text += (f"; but its sampled-data form with run.dt = {dt:g} "
                         + (f"is UNSTABLE (decay rate {sampled:.4g})" if sampled <= 0 else
                            f"decays at only {sampled:.4g} < rate {rate:g}"))
    out.update(rate_certified=cert, certificate=text, ok=bool(v.ok and cert is not False))
    return out
