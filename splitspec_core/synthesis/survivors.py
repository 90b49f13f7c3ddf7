"""The runtime's verdict on what is left after losses: does the designed g or q still certify the rate?

The orchestrator asks it at every loss, rejoin and link change of a run (``certify_network``): the survivors'
strong connectivity, what they leave unobserved (:mod:`splitspec_core.model.detectability`: ``W_S``, the intersection of
their own unobservable spaces, and whether it decays), then the design's own certificate recomputed on the
survivors' graphs, on the quotient by ``W_S``.  Cheap enough for every event of a run: no bisection, no search.
"""

from __future__ import annotations

from . import bounds
from .designer import NO_CERTIFIED_RATE, Design
from ..model.graphs import build_graph
from .sampled_rates import sampled_rates

__all__ = ["certify_network"]


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
    :func:`splitspec_core.synthesis.report.rate_certificate`).

    Returns a JSON-ready dict: ``alive``, ``dropped_arcs``,
    ``strongly_connected`` (per graph), ``unreachable`` (per graph, a pair
    ``[j, i]``), ``jointly_observable``, ``unobservable_direction``,
    ``rate_certified`` (bool, or None for the adaptive gain), ``certificate``
    (one line), ``ok``.
    """
    from ..model.network import active_arcs
    from .resilience import network_verdict

    sc = des.scenario
    alive = tuple(a for a in sc.agent_ids if a in set(alive_ids))
    used = sc.switching.graph_names(sc.graph_names)
    arcs = {name: active_arcs(sc, sc.graph_names.index(name), dropped) for name in used}
    v = network_verdict(des.unobserved_of, alive, arcs)
    un_S = v.unobserved
    out = {"alive": list(alive), "dropped_arcs": sorted([list(a) for a in dropped]),
           "strongly_connected": dict(v.strongly_connected),
           "unreachable": {k: list(p) for k, p in v.unreachable.items()},
           "jointly_observable": v.jointly_observable, "detectable": v.detectable,
           "unobservable_direction": v.unobservable_direction}
    rate = sc.design.rate
    excluded = des.excluded and un_S.dim == des.unobserved.dim  # nothing more unobserved than the design excluded
    if not (v.detectable or excluded) or not all(v.strongly_connected.values()):
        cert, text = False, "no rate: " + ("the survivors leave a mode unobserved that does not decay"
                                            if not (v.detectable or excluded) else "a graph is not strongly connected")
    elif des.time == "discrete":
        cases = [des.survivor_case(name, build_graph(name, alive, arcs[name], weights=sc.design.weights), un_S)
                 for name in used]
        res = bounds.choose_q(sc.design.q_method, cases, rate, q=des.q, q_max=sc.design.q_max,
                              eig=sc.design.eigenvalues)
        cert = bool(res.certified)
        text = (f"q = {des.q}: {res.method} bound {res.bound:.4g} {'<=' if cert else '>'} rate {rate:g}"
                + ("" if res.switching or len(cases) == 1 else " (per graph held constant)"))
    elif des.g is None:
        cert, text = None, f"adaptive gain: {NO_CERTIFIED_RATE}"
    else:
        ad = {a.id: a for a in des.agents}
        cases = [des.survivor_case(name, build_graph(name, alive, arcs[name], weights=sc.design.weights), un_S)
                 for name in used]
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
    if cert and un_S.dim and not excluded:
        envelope = un_S.envelope(rate)
        text += f"; {un_S.summary(rate)}"
        out["envelope_rate"] = envelope
    out.update(rate_certified=cert, certificate=text, ok=bool(cert is not False and all(v.strongly_connected.values())
                                                              and (v.detectable or excluded)))
    return out
