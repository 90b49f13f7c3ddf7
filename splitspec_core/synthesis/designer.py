"""The design engine: scenario -> split-spectrum estimator with its certificates.

Steps (paper, Sections 2-4):

1. per agent: observability decomposition ``V_i, Q_i`` (decided in balanced coordinates, cluster by cluster
   of ``A``'s spectrum: :mod:`splitspec_core.model.modal`);
2. ``(C, A)`` jointly detectable: ``W = V_1 ∩ ... ∩ V_m`` (what no agent sees) decays, or the design refuses,
   naming it (before any gain is judged; :mod:`splitspec_core.model.detectability`);
3. per agent: local gain ``K_i`` and the estimator's ``P_i`` on ``V_i ⊖ W`` (local; each agent can do this from
   ``(A, C, lam)`` and ``W``); every graph strongly connected;
4. centralised: g (continuous) or q (discrete) covering every graph the
   switching signal can use (and, with ``design.resilience: 1``, every graph
   left after a single agent loss), on the quotient by ``W``;
5. resilience analysis (single agent and single arc losses).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

from . import bounds
from ..errors import AssumptionError
from .conditioning import conditioning
from ..model.detectability import Unobserved, not_detectable_text, quotient_basis, still_text, unobserved_of
from .error_matrix import SPLIT_EXACT, check_full
from ..model.gains import beyond_target
from ..model.graphs import build_graph, enumerate_strongly_connected
from .loss_certificate import loss_certificate
from ..model.local_design import AgentDesign, design_agent, riccati_weights, scenario_spectrum, working_scale
from ..model.modal import Spectrum
from ..model.observability import decompose
from .resilience import analyse_agent_losses, analyse_arc_losses
from .sampled_rates import exact_g, sampled_g
from ..scenarios.specs import Scenario

__all__ = ["Design", "design", "scenario_dwell", "NO_CERTIFIED_RATE"]

# thm. split_continuous_adaptive: with the adaptive gain (eq. adaptive) every error tends to zero, at no stated rate
NO_CERTIFIED_RATE = "asymptotic convergence only (no certified rate)"


@dataclass(frozen=True)
class Design:
    """A complete design with diagnostics (see ``design_json`` for the contract).

    ``g`` is ``None`` for discrete time and for the adaptive estimator;
    ``q`` is ``None`` for continuous time.  ``g_certified_by`` names what
    certifies g for the ODE (None: nothing, or the adaptive gain); the verdict
    for the estimator as run is :func:`splitspec_core.synthesis.report.rate_certificate`.
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
    # max over agents of Decomposition.split_residual (and W's); above round-off, full_radius: conditioning.check_full
    split_residual: float = 0.0
    full_radius: dict = field(default_factory=dict)
    # what no agent sees (detectability.py): W, its spectrum, whether it decays; None only for a design built by hand
    unobserved: Unobserved | None = None
    spectrum: Spectrum | None = field(default=None, repr=False, compare=False)  # modal.py: A balanced, its clusters

    @property
    def time(self) -> str:
        return self.scenario.time

    @property
    def rate(self) -> float:
        return self.scenario.design.rate

    @property
    def Ks(self) -> list:
        """Every ``K_i`` the estimator runs (the user's coordinates)."""
        return [a.K for a in self.agents]

    @property
    def Ps(self) -> list:
        """Every ``P_i`` the estimator runs (the user's coordinates)."""
        return [a.P for a in self.agents]

    @property
    def Vs(self) -> list:
        """Every ``R_i`` eq. (adaptive) projects with, in the user's coordinates (:attr:`AgentDesign.V_adaptive`;
        ``V_i`` itself in the user's own working coordinates)."""
        return [a.V_adaptive for a in self.agents]

    @property
    def Ls(self) -> list:
        """Every ``L_i`` (:attr:`AgentDesign.V_lift`): ``P_i = L_i R_i'`` with ``R_i`` of :attr:`Vs`."""
        return [a.V_lift for a in self.agents]

    @property
    def scale(self) -> np.ndarray | None:
        """The working coordinates ``x = diag(scale) x_w`` (``design.coordinates``; None: the user's)."""
        return self.agents[0].scale if self.agents else None

    @property
    def redundantly_strongly_connected(self) -> bool:
        return all(all(r.strongly_connected.values()) for r in self.agent_losses.values())

    @property
    def redundantly_jointly_observable(self) -> bool:
        return all(r.jointly_observable for r in self.agent_losses.values())

    @property
    def redundantly_jointly_detectable(self) -> bool:
        return all(r.detectable for r in self.agent_losses.values())

    @property
    def excluded(self) -> bool:
        """``design.undetectable: exclude`` took effect: directions no agent sees do not decay, and the certificate
        covers the error modulo them only."""
        return self.unobserved is not None and not self.unobserved.decays

    @property
    def envelope_rate(self) -> float:
        """The rate of the certified envelope: ``lam``, or slower when the unobserved directions limit it
        (:meth:`splitspec_core.model.detectability.Unobserved.envelope`); with :attr:`excluded`, ``lam`` (modulo them)."""
        un = self.unobserved
        return self.rate if un is None or self.excluded else un.envelope(self.rate)

    @property
    def A_working(self) -> np.ndarray:
        """``A`` in the working coordinates (``D^-1 A D``)."""
        A = np.asarray(self.scenario.system.A, dtype=float)
        return A if self.scale is None else A * self.scale[None, :] / self.scale[:, None]

    def unobserved_of(self, alive) -> Unobserved:
        """What the agents ``alive`` leave unobserved (``W_S ⊇ W``, :mod:`splitspec_core.model.detectability`)."""
        return unobserved_of(self.scenario, self.spectrum, {a.id: self.unobservable_space(a.id)
                                                            for a in self.agents}, self.scale)(alive)

    def survivor_case(self, label: str, graph, un: Unobserved) -> bounds.Case:
        """The certificate's case of the agents of ``graph`` when they leave ``un.W`` unobserved: ``V_i ⊖ W_S``."""
        ad = {a.id: a for a in self.agents}
        if self.unobserved is None or un.dim == self.unobserved.dim:
            return bounds.make_case(label, graph, [ad[i].V for i in graph.ids], [ad[i].dec.A_un for i in graph.ids])
        A = self.A_working
        Vs = [quotient_basis(self.unobservable_space(i), un.W_working) for i in graph.ids]
        return bounds.make_case(label, graph, Vs, [V.T @ A @ V for V in Vs])

    def unobservable_space(self, agent_id: int) -> np.ndarray:
        """Agent ``agent_id``'s own unobservable space in the working coordinates: ``[V_i ⊖ W, W]`` (orthonormal: the
        two are orthogonal there)."""
        a = next(a for a in self.agents if a.id == agent_id)
        W = self.unobserved.W_working if self.unobserved is not None else np.zeros((a.V.shape[0], 0))
        return np.hstack([a.V, W])

    @property
    def split_exact(self) -> bool:
        """Every V_i an unobservable space to round-off: the split of prop. error holds, the certificates apply."""
        return self.split_residual <= SPLIT_EXACT

    # on first use (the full error matrices cost more than the design itself at scale):
    loss_certificate = cached_property(loss_certificate)  # under network: and partitions (None without)
    conditioning = cached_property(conditioning)  # margins, gain sizes, transient constant, noise


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
    agents; :func:`splitspec_core.synthesis.bounds.q_spectral`); ``None``: every core this process may use.

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
    sp = scenario_spectrum(sc)
    C_all = np.vstack(sc.system.Cs)
    free = beyond_target(sc.time, d.rate, d.margin)  # modes the local gains leave alone (gains.py)
    scale = working_scale(sc, sp)  # design.coordinates: the user's (None) or balanced
    A_w = A if scale is None else np.asarray(A) * scale[None, :] / scale[:, None]
    decs = [decompose(A, C, rank_tol=d.rank_tol, spectrum=sp, free=free, scale=scale) for C in sc.system.Cs]
    # the standing assumption first ((C, A) of eqs. pre_sys1-pre_sys2 jointly observable, or here detectable):
    # without it no K_i helps, so an explicit K_i that misses the rate on a direction nobody sees is not the error
    of = unobserved_of(sc, sp, {aid: dec.V for aid, dec in zip(sc.agent_ids, decs)}, scale)
    un = of(sc.agent_ids)
    warnings: list = []
    if not un.decays:
        if d.undetectable != "exclude":
            raise AssumptionError(not_detectable_text(un, decs, d.rank_tol))
        warnings.append(f"design.undetectable: exclude: no agent sees {still_text(un)}, which does not decay; the "
                        "certificate covers the error modulo the unobserved directions only")
    pw, mw = riccati_weights(sc)
    agents = tuple(
        design_agent(A, C, time=sc.time, rate=d.rate, method=d.gains, margin=d.margin,
                     K=None if d.K is None else d.K[k], rank_tol=d.rank_tol,
                     process_weight=pw, measurement_weight=mw, agent_id=aid, unobserved=un.W_working, dec=decs[k],
                     scale=scale)
        for k, (aid, C) in enumerate(zip(sc.agent_ids, sc.system.Cs))
    )
    graphs = tuple(build_graph(g.name, sc.agent_ids, g.arcs, weights=d.weights) for g in sc.graphs)
    used = sc.switching.graph_names(sc.graph_names)
    by_name = {g.name: g for g in graphs}
    ad = {a.id: a for a in agents}

    full_V = {aid: dec.V for aid, dec in zip(sc.agent_ids, decs)}

    def case_for(label, graph, W=None):
        """The case of ``graph``; ``W``: what its agents leave unobserved when it is not the design's (after a loss):
        then ``V_i ⊖ W`` (detectability.py)."""
        if W is None:
            Vs = [ad[i].V for i in graph.ids]
        else:
            Vs = [quotient_basis(full_V[i], W) for i in graph.ids]
        return bounds.make_case(label, graph, Vs, [V.T @ A_w @ V for V in Vs] if W is not None else
                                [ad[i].dec.A_un for i in graph.ids])

    cases = [case_for(name, by_name[name]) for name in used]
    if d.graph_set == "all":
        for k, arcs in enumerate(enumerate_strongly_connected(sc.m)):
            arcs_ids = tuple((sc.agent_ids[j], sc.agent_ids[i]) for j, i in arcs)
            g = build_graph(f"all#{k + 1}", sc.agent_ids, arcs_ids, weights=d.weights)
            cases.append(case_for(g.name, g))

    graph_arcs = {g.name: g.arcs for g in sc.graphs}
    agent_losses = analyse_agent_losses(of, sc.agent_ids, graph_arcs) if sc.m > 1 else {}
    arc_losses = analyse_arc_losses(sc.agent_ids, graph_arcs)
    if d.resilience:
        for lost, rep in agent_losses.items():
            if not rep.detectable:
                raise AssumptionError(
                    f"design.resilience: 1 needs a redundantly jointly detectable network: without agent {lost}, no "
                    f"agent sees {rep.unobservable_direction}, which does not decay")
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
                W_S = rep.unobserved.W_working
                cases.append(case_for(g.name, g, None if W_S.shape[1] == un.dim else W_S))
    cases = tuple(cases)
    switching = len(used) > 1 or d.graph_set == "all"

    kw: dict = {}
    if sc.time == "continuous":
        kw.update(_design_g(sc, cases, switching, warnings))
        if kw["g"] is not None:
            kw.update(sampled_g(sc, agents, cases, kw, switching, warnings))
    else:
        kw.update(_design_q(sc, cases, switching, warnings, compare_q_methods, workers))
    residual = max([a.dec.split_residual for a in agents] + [un.residual])
    des = Design(scenario=sc, agents=agents, graphs=graphs, cases=cases, agent_losses=agent_losses,
                 arc_losses=arc_losses, warnings=tuple(warnings), split_residual=residual, unobserved=un, spectrum=sp,
                 **kw)
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
            if g == 0.0 and not switching and any(c.nbar for c in cases):
                # eq. (g) says any g works: the unobservable parts decay at the rate on their own, but only at it (an
                # estimator exactly at its rate has no finite transient constant); the exact spectrum's g with the
                # design's margin instead (sampled.exact_g)
                alt = exact_g(cases, rate, d.margin, g_mins)
                if alt:
                    g, by = alt, "spectrum (exact, constant graph)"
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
