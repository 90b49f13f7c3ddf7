"""Design output: the JSON contract and the readable report.

Both render the same :class:`~splitspec_core.synthesis.design_data.Design`, the same verdict (computed once by
:func:`splitspec_core.synthesis.verdict.rate_certificate`, the line every command prints) and
the same analyses of it (:func:`~splitspec_core.synthesis.conditioning.conditioning`,
:func:`~splitspec_core.synthesis.loss_certificate.loss_certificate`), and must say the same thing; the JSON is the
contract (``../shared/DESIGN.md``), the text its reading.

Why one module: the JSON and the text are two renderings of one design that must not drift apart (the same
figures, the same verdict, the same warnings, each once): side by side, a field added to one is seen missing from
the other.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from ..errors import SplitspecError
from .advice import advice, advice_lines, fastest_rate
from .bounds import QResult
from .conditioning import conditioning
from .design_data import Design, cached_analysis
from .designer import design
from .loss_certificate import loss_certificate
from .exchange_limit import design_exchanges
from .bad_data import bad_data, report_lines as bad_data_lines
from ..model.gains import poles_text
from ..model.graphs import is_doubly_stochastic, perron_vector
from ..scenarios import gain_methods
from ..scenarios.labels import heaviest, spread
from .kalman import SHIFTED_NAME, SHIFTED_NOTE
from .spectral import certifies, comparison
from .verdict import NO_CERTIFIED_RATE, rate_certificate  # the verdict, rendered here

__all__ = ["design_json", "design_text", "design_warnings"]


MAX_LISTED = 12  # cases whose radius the text report lists (the largest first); --json has them all


def _mat(M: np.ndarray) -> list:
    return np.asarray(M, dtype=float).tolist()


def _complex(z) -> list:
    return [[float(np.real(x)), float(np.imag(x))] for x in np.asarray(z)]


def _num(x):
    if x is None:
        return None
    x = float(x)
    return x if math.isfinite(x) else None


def _q_json(r) -> dict | str:
    if isinstance(r, str):
        return {"error": r}
    return {"q": r.q, "bound": _num(r.bound), "certified": bool(r.certified), "switching": bool(r.switching),
            "p": r.p, "pbar": r.pbar}


def _redundancy(des: Design) -> dict:
    return {
        "redundantly_strongly_connected": des.redundantly_strongly_connected,
        "redundantly_jointly_observable": des.redundantly_jointly_observable,
        "redundantly_jointly_detectable": des.redundantly_jointly_detectable,
        "agent_loss": {
            str(a): {
                "jointly_observable": r.jointly_observable,
                "jointly_detectable": r.detectable,
                "unobservable_direction": r.unobservable_direction,
                "unobserved": _unobserved_json(r.unobserved, des.rate, full=False),
                "strongly_connected": r.strongly_connected,
            }
            for a, r in des.agent_losses.items()
        },
        "arc_loss": {name: {f"{j}->{i}": ok for (j, i), ok in res.items()} for name, res in des.arc_losses.items()},
    }


def _unobserved_json(un, rate: float, *, full: bool = True) -> dict:
    """What no agent (of a set) sees: its dimension, the states carrying it, its spectrum and decay (detectability.py)."""
    out = {"dim": un.dim, "states": heaviest(un.W, un.names, limit=len(un.names) or 1) if un.dim else [],
           "decays": bool(un.decays), "decay": _num(un.decay), "limits_rate": bool(un.decays and un.limits(rate)),
           "envelope_rate": _num(un.envelope(rate)) if un.decays else None}
    if full:
        out.update(eigenvalues=_complex(un.eigs), residual=_num(un.residual), W=_mat(un.W))
    return out


def _whole_json(des: Design) -> dict | None:
    """The whole-state design's choices (:class:`~splitspec_core.synthesis.whole_state.WholeState`), None for the
    split."""
    w = des.whole
    if w is None or des.consensus in ("fusion", "relay"):
        return None
    return {"method": w.method, "alpha": _num(w.alpha), "pi": [float(v) for v in w.pi], "rate_per_step": _num(w.lam_step),
            "central_radius": _num(w.central_radius), "central_rms": _num(w.central_rms),
            "kalman_radius": _num(w.kf_radius), "kalman_rms": _num(w.kf_rms), "reference_rms": _num(w.reference_rms),
            "q_certified": w.q_certified, "exchanges_per": "event time" if des.time == "discrete" else "run.dt",
            "tried": [{"margin": m, "alpha": _num(a), "q": q, "radius": {k: _num(v) for k, v in (r or {}).items()},
                       "predicted_rms": _num(rms)} for m, a, q, r, rms in w.tried]}


def _fusion_json(des: Design) -> dict | None:
    """The fusion design's choices (:class:`~splitspec_core.synthesis.fusion_kind.FusionKind`), None otherwise."""
    if des.consensus != "fusion":
        return None
    k = des.whole
    return {"q": k.q, "rate_per_step": _num(k.lam_step), "radius": _num(k.radius), "certified": bool(k.certified),
            "alpha": {name: _num(d.alpha) for name, d in zip(des.scenario.graph_names, k.designs)},
            "ratio_to_kalman": {name: _num(d.ratio) for name, d in zip(des.scenario.graph_names, k.designs)},
            "limit": _num(k.limit), "fewest_certified_q": k.fewest,
            "exchanges_per": "event time" if des.time == "discrete" else "run.dt"}


def _relay_json(des: Design) -> dict | None:
    """The relay design's choices (:class:`~splitspec_core.synthesis.relay.RelayDesign`), None otherwise."""
    if des.consensus != "relay":
        return None
    k = des.whole
    return {"q": k.q, "delay": k.D, "rate_per_step": _num(k.lam_step), "radius": _num(k.radius),
            "certified": bool(k.certified), "alpha": _num(k.alpha), "ratio_to_kalman": _num(k.ratio),
            "limit": _num(k.limit), "transient_constant": _num(k.transient_constant) if math.isfinite(
                k.transient_constant) else "inf", "exchanges_per": "event time" if des.time == "discrete" else "run.dt"}


def _conditioning_json(des: Design) -> dict:
    cond = conditioning(des)
    constant = _num(cond.transient_constant) if cond.transient_constant != math.inf else "inf"
    return {
        "transient_constant": constant,
        "transient": {"constant": constant, "graph": cond.transient_case, "method": cond.transient_method},
        "split_residual": _num(des.split_residual),
        "split_exact": bool(des.split_exact),
        "full_error_matrix": {k: (v if isinstance(v, dict) else _num(v)) for k, v in des.full_radius.items()},
        "predicted_rms": None if cond.predicted_rms is None else {
            "graph": cond.predicted_graph, "agents": {str(i): _num(v) for i, v in cond.predicted_rms.items()},
            "all": _num(_all_rms(cond.predicted_rms)), "kalman": _num(cond.kalman_rms),
            "ratio_to_kalman": _num(_ratio(_all_rms(cond.predicted_rms), cond.kalman_rms)),
            "reference": _num(cond.reference_rms),
            "ratio_to_reference": _num(_ratio(_all_rms(cond.predicted_rms), cond.reference_rms))},
    }


def _ratio(a: float, b: float | None) -> float | None:
    return None if b is None or not b > 0 else a / b


def _all_rms(per_agent: dict) -> float:
    """The RMS over agents of their predicted steady-state RMS errors."""
    return math.sqrt(sum(v * v for v in per_agent.values()) / len(per_agent))


def _loss_json(des: Design) -> dict | None:
    c = loss_certificate(des)
    if c is None:
        return None
    return {"certified": bool(c.certified), "text": c.text, "max_lost": c.max_lost, "beta": _num(c.beta),
            "bound": _num(c.bound), "q_needed": c.q_needed, "p_more": _num(c.p_more), "graphs": c.graphs}


def _bad_data_json(des: Design) -> dict | None:
    """``design.bad_data``'s test and each sensor's fallback (:mod:`.bad_data`), None when off."""
    bd = bad_data(des)
    if bd is None:
        return None
    return {"false_alarm": bd.false_alarm, "suspect_after": bd.suspect_after, "warmup": bd.warmup,
            "agents": [{"id": t.agent, "S": t.S.tolist(), "threshold": t.threshold, "graph": t.graph,
                        "fallback": {"radius": {k: _num(v) for k, v in f.radius.items()}, "certified": f.certified,
                                     "stable": f.stable, "text": f.text}}
                       for t, f in zip(bd.tests, bd.fallbacks)]}


def design_json(des: Design) -> dict:
    """The ``splitspec design --json`` object (contract in ``../shared/DESIGN.md``).

    Parameters
    ----------
    des : Design
        The design.

    Returns
    -------
    dict
        JSON-ready (lists, floats, None for non-finite numbers): the scenario's shape, every agent's matrices and
        figures, the graphs, checks, conditioning, warnings, advice, the verdict, and the g (continuous split) or
        q fields.

    Examples
    --------
    >>> import splitspec_core as ss
    >>> from splitspec_core.synthesis.designer import design
    >>> des = design(ss.scenario(A=[[0, 1, 0, 0], [-1, 0, 0, 0], [0, 0, 0, 1], [0, 0, -2, 0]],
    ...                          C={1: [[1, 0, 0, 0]], 2: [[0, 1, 0, 0]], 3: [[0, 0, 1, 0]]},
    ...                          graphs={"a": [(1, 2), (2, 1), (2, 3), (3, 2), (1, 3)]}, rate=0.5, gains="place"))
    >>> j = design_json(des)
    >>> j["q"], j["q_method"], j["certified_rate"], len(j["agents"])
    (6, 'spectral', True, 3)
    """
    sc = des.scenario
    cond = {a.id: a for a in conditioning(des).agents}
    out = {
        "name": sc.name,
        "time": sc.time,
        "rate": sc.design.rate,
        "m": sc.m,
        "n": sc.n,
        "states": list(sc.state_names),
        "outputs": {str(i): list(sc.output_names(i)) for i in sc.agent_ids},
        # a sampled continuous model (system.sample, in system.time_unit; null otherwise) and the rate per unit it means
        "sample": sc.system.sample,
        "time_unit": sc.system.time_unit,  # system.time_unit: of sample, run.dt and the continuous rates
        "continuous_rate": _num(continuous_rate(sc)),
        "inputs": sc.system.inputs,
        "gains": sc.design.gains,
        "agents": [
            {
                "id": a.id,
                "K": _mat(a.K),
                "V": _mat(a.V_user),
                "P": _mat(a.P),
                "poles": _complex(a.gain.poles),
                "n_unobservable": a.dec.n_unobservable,
                "n_unobserved": a.dec.unobserved,
                "unobservable_eigs": _complex(np.linalg.eigvals(a.dec.A_un)) if a.dec.n_unobservable else [],
                "observability_margin": _num(cond[a.id].observability_margin),
                "gain_norm": _num(cond[a.id].gain_norm),
                "gain_ratio": _num(cond[a.id].gain_ratio),
                "weak_margin": _num(cond[a.id].weak),
                "split_residual": _num(cond[a.id].split_residual),
            }
            for a in des.agents
        ],
        "graphs": [
            {"name": g.name, "arcs": [list(a) for a in g.arcs], "S": _mat(g.S),
             "doubly_stochastic": is_doubly_stochastic(g.S), "perron": _mat(perron_vector(g.S))}
            for g in des.graphs
        ],
        "cases": [c.label for c in des.cases],
        "checks": {
            "jointly_observable": des.unobserved is None or des.unobserved.dim == 0,
            "jointly_detectable": des.unobserved is None or des.unobserved.decays,
            "strongly_connected": {g.name: g.strongly_connected for g in des.graphs},
            "redundancy": _redundancy(des),
        },
        "unobserved": None if des.unobserved is None else {**_unobserved_json(des.unobserved, sc.design.rate),
                                                            "excluded": des.excluded},
        "coordinates": "given" if des.scale is None else "balanced",
        "scale": None if des.scale is None else [float(v) for v in des.scale],
        "error_spectrum": {k: _num(v) for k, v in des.error_radius.items()},
        "rank_tol": "auto" if sc.design.rank_tol is None else sc.design.rank_tol,
        "loss_certificate": _loss_json(des),
        "bad_data": _bad_data_json(des),
        **_conditioning_json(des),
        "warnings": design_warnings(des),
        "advice": [{"knob": t.knob, "certified": t.certified, "transient_constant": _num(t.transient),
                    "predicted_rms": _num(t.rms), "refused": t.error, "note": t.note} for t in advice(des)],
    }
    cert = rate_certificate(des)
    reach = fastest_rate(des)
    out.update(certified_rate=cert.certified, certificate=cert.text, envelope_rate=_num(cert.rate),
               rate_note=NO_CERTIFIED_RATE if des.g_mode == "adaptive" else None,
               fastest_certified_rate=None if reach is None else {"rate": reach.rate, "refused": reach.refused},
               fewest_certified_q=fewest_exchanges(des))
    out.update(consensus=des.consensus, consensus_choice=des.chosen, whole_state=_whole_json(des),
               fusion=_fusion_json(des), relay=_relay_json(des))
    ex = design_exchanges(des)
    vec = math.sqrt(sc.n)  # the limit's RMS per state, given here of the error vector as predicted_rms is
    out["exchanges"] = {"per": ex.per, "messages": ex.messages, "numbers": ex.numbers, "limit": None if ex.limit is None
                        else {"q": ex.limit.q, "graph": ex.graph, "ratio_to_kalman": _num(ex.limit.ratio),
                              "rms": _num(vec * ex.limit.rms), "kalman_rms": _num(vec * ex.limit.kf_rms),
                              "agents": {str(i): _num(vec * v) for i, v in zip(sc.agent_ids, ex.limit.agent_rms)}}}
    if sc.time == "continuous" and des.consensus not in ("whole", "fusion", "relay"):
        out.update({
            "g": _num(des.g),
            "g_mode": des.g_mode,
            "g_bound": _num(max(des.g_bounds.values())),
            "g_min": _num(max(des.g_mins.values())),
            "g_bounds": {k: _num(v) for k, v in des.g_bounds.items()},
            "g_mins": {k: _num(v) for k, v in des.g_mins.items()},
            "g_dwell_bound": _num(des.g_dwell),
            "dwell": _num(des.dwell),
            "g_arbitrary_bound": _num(des.g_arbitrary),
            "g_certified_by": des.g_certified_by,
            "g0": sc.design.g0 if des.g_mode == "adaptive" else None,
            "dt": sc.run.dt,
            "sampled_rate": {k: _num(v) for k, v in des.sampled_rate.items()},
        })
    else:
        r: QResult = des.q_result
        out.update({
            "q": des.q,
            "q_method": r.method,
            "q_bound": _num(r.bound),
            "q_certified": bool(r.certified),
            "q_switching_certificate": bool(r.switching),
            "p": r.p,
            "pbar": r.pbar,
            # how the spectral radii behind q were computed: {"methods": {dense|iterative|dense (fallback): count},
            # "tolerance": ARPACK's relative tolerance, 0 when every radius is dense} (splitspec_core.synthesis.spectral)
            "q_eigenvalues": r.eig,
            "q_methods": {k: _q_json(v) for k, v in des.q_methods.items()},
        })
    return out


@cached_analysis
def fewest_exchanges(des: Design) -> int | None:
    """A two-rate design whose given ``design.q`` (the budget) does not certify the rate: the fewest exchanges that do
    with the same design keys (the design again with ``design.q: auto``; the fusion kind's own search), else None
    (certified, ``q`` not given, or no q up to ``design.q_max`` certifies).

    Parameters
    ----------
    des : Design
        The design (computed once per design).

    Returns
    -------
    int or None
    """
    sc = des.scenario
    if not des.two_rate or sc.design.q == "auto" or rate_certificate(des).certified:
        return None
    if des.consensus == "fusion":
        return des.whole.fewest
    if des.consensus == "relay":  # its certificate is the centralized predictor's: no q changes it
        return None
    try:
        auto = design(dataclasses.replace(sc, design=dataclasses.replace(sc.design, q="auto")))
    except SplitspecError:
        return None
    return int(auto.q) if rate_certificate(auto).certified else None


def continuous_rate(sc) -> float | None:
    """A sampled continuous model's (``system.sample``) rate per unit of time (``system.time_unit``): ``lam^tau`` per step is
    ``exp(-a t)`` with ``a = -ln(lam) / dt``; None for other scenarios.

    Parameters
    ----------
    sc : Scenario
        Its ``system.sample`` (in ``system.time_unit``) and ``design.rate``.

    Returns
    -------
    float or None
        ``a`` in 1/``system.time_unit``.
    """
    if sc.system.sample is None:
        return None
    return -math.log(sc.design.rate) / sc.system.sample


def model_lines(sc) -> list:
    """The report's lines on a sampled model and on known inputs (none for a plain model).

    Parameters
    ----------
    sc : Scenario
        Its ``system.sample``, ``system.B`` and ``system.u``.

    Returns
    -------
    list of str
        Indented lines, empty for a plain model.
    """
    out = []
    if sc.system.sample is not None:
        a = continuous_rate(sc)
        unit = sc.system.time_unit  # system.time_unit: the model's time (default s)
        out.append(f"  sampled: the continuous model with system.sample = {sc.system.sample:g} {unit} (zero-order "
                   f"hold); lam = {sc.design.rate:g} per step is lam^(1/dt) = "
                   f"{sc.design.rate ** (1 / sc.system.sample):.4g} {sc.system.per_time}, errors decaying as "
                   f"exp(-{a:.4g} t), t in {unit}")
    if sc.system.B is not None:
        what = "system.u" if sc.system.u is not None else "zero, or a measurements file's u columns"
        out.append(f"  known inputs: {sc.system.inputs} (system.B; u: {what}); every agent adds B u as the plant "
                   "does, so they cancel from the errors and the certificate is the one without them")
    return out


def design_text(des: Design) -> str:
    """A readable multi-line report of a design.

    Parameters
    ----------
    des : Design
        The design.

    Returns
    -------
    str
        What ``splitspec design`` prints: the agents, graphs, checks, cases, g or q, the verdict, the errors' size,
        warnings and advice.

    Examples
    --------
    >>> import splitspec_core as ss
    >>> from splitspec_core.synthesis.designer import design
    >>> des = design(ss.scenario(A=[[0, 1, 0, 0], [-1, 0, 0, 0], [0, 0, 0, 1], [0, 0, -2, 0]],
    ...                          C={1: [[1, 0, 0, 0]], 2: [[0, 1, 0, 0]], 3: [[0, 0, 1, 0]]},
    ...                          graphs={"a": [(1, 2), (2, 1), (2, 3), (3, 2), (1, 3)]}, rate=0.5, gains="place"))
    >>> text = design_text(des)
    >>> print(text.splitlines()[0])
    splitspec design: scenario  (discrete time, m = 3 agents, n = 4 states)
    >>> [line for line in text.splitlines() if line.startswith("rate ")]
    ['rate certified: q = 6: spectral bound 0.4736 < rate 0.5']
    """
    sc = des.scenario
    d = sc.design
    unit = "exp(-lam t)" if sc.time == "continuous" else "lam^tau"
    adaptive = des.g_mode == "adaptive"
    consensus = {"whole": "the whole state", "fusion": "the whole state, fused with matrix weights (fusion)",
                 "relay": "the sensors' samples, passed on (relay)"}.get(
        des.consensus, "the split (each agent's unobservable space)")
    lines = [
        f"splitspec design: {sc.name}  ({sc.time} time, m = {sc.m} agents, n = {sc.n} states)",
        (f"  rate lam = {d.rate:g} for the local gains only; adaptive g: {NO_CERTIFIED_RATE}; gains: {d.gains}"
         if adaptive else f"  rate lam = {d.rate:g}  (errors decay as {unit}); gains: {d.gains}; consensus on "
                          f"{consensus}"),
    ]
    if des.chosen:
        lines.append(f"  {des.chosen}")
    lines += model_lines(sc)
    cond = conditioning(des)
    lines += [""] + agent_lines(des, cond)
    lines += ["", "graphs"]
    for g in des.graphs:
        ds = "doubly stochastic" if is_doubly_stochastic(g.S) else "not doubly stochastic"
        arcs = ", ".join(f"{j}->{i}" for j, i in g.arcs)
        lines.append(f"  {g.name}: strongly connected, {ds}; arcs {arcs}")
    un = des.unobserved
    if un is None or not un.dim:
        lines += ["", "checks", "  jointly observable: yes"]
    else:
        verdict = "yes" if un.decays else "NO (design.undetectable: exclude)"
        lines += ["", "checks", f"  jointly observable: no; jointly detectable: {verdict}: {un.summary(d.rate)}"]
    lines.append("  every graph strongly connected: yes")
    rsc, rjo, rjd = (des.redundantly_strongly_connected, des.redundantly_jointly_observable,
                     des.redundantly_jointly_detectable)
    lines.append(f"  redundantly strongly connected: {'yes' if rsc else 'no'}; "
                 f"redundantly jointly observable: {'yes' if rjo else 'no'}"
                 + ("" if rjo else f"; redundantly jointly detectable: {'yes' if rjd else 'no'}"))
    for a, r in des.agent_losses.items():
        if not r.ok:
            why = []
            if not r.detectable:
                why.append(f"no agent sees {r.unobservable_direction}, which does not decay")
            why += [f"graph {g} splits (agent {r.unreachable[g][0]} cannot reach {r.unreachable[g][1]})"
                    for g, ok in r.strongly_connected.items() if not ok]
            lines.append(f"    losing agent {a}: " + "; ".join(why))
    for name, res in des.arc_losses.items():
        crit = [f"{j}->{i}" for (j, i), ok in res.items() if not ok]
        if crit:
            lines.append(f"    graph {name}: losing arc {', '.join(crit)} breaks strong connectivity")
    lines += ["", f"cases covered: {', '.join(c.label for c in des.cases)}"]
    if des.consensus == "fusion":
        lines += [""] + fusion_lines(des)
    elif des.consensus == "relay":
        lines += [""] + relay_lines(des)
    elif sc.time == "continuous" and des.consensus != "whole":
        lines.append("")
        if des.g_mode == "adaptive":
            lines.append(f"g: adaptive (eq. adaptive), each agent integrates its own g_i from g0 = {d.g0:g}")
        else:
            by = f"certified by {des.g_certified_by}" if des.g_certified_by else "NOT certified"
            lines.append(f"g = {des.g:g}  ({des.g_mode}; {by})")
        if adaptive:
            lines.append("  for comparison, a fixed g meeting the rate would need:")
        for label in des.g_bounds:
            lines.append(f"  {label}: g_bound (eq. g) = {des.g_bounds[label]:.4g}, "
                         f"g_min (exact spectrum) = {des.g_mins[label]:.4g}"
                         + (f", abscissa of A_V at g = {des.error_radius[label]:.4g}" if label in des.error_radius
                            else ""))
        if des.g_dwell is not None:
            lines.append(f"  average dwell time {des.dwell:g}: g >= {des.g_dwell:.4g} (eq. split_continuous_g)")
        if des.g_arbitrary is not None:
            lines.append(f"  arbitrary switching, doubly stochastic: g >= {des.g_arbitrary:.4g} (thm. arb)")
        if des.sampled_rate:
            worst = min(des.sampled_rate.values())
            lines.append(f"  sampled-data form with run.dt = {sc.run.dt:g}: decay rate {worst:.4g} "
                         f"({'meets' if certifies(-worst, -d.rate) else 'MISSES'} rate {d.rate:g})")
    elif des.consensus == "whole":
        lines += [""] + whole_lines(des)
    else:
        r = des.q_result
        extra = f" (p = {r.p}, pbar = {r.pbar})" if r.p else ""
        scope = "arbitrary switching among the cases" if r.switching else "each graph held constant"
        if des.full_radius and des.consensus == "split":
            # an approximate split: q's bound is the split blocks'; the verdict is the full error matrices' (each
            # listed), so the two lines never read as a certificate and its negation
            lines += ["", f"q = {r.q}  ({d.q_method}{extra}); on the split blocks only, bound "
                          f"{comparison(r.bound, d.rate)} for {scope} (the split is approximate: the verdict below is "
                          "the full error matrices')"]
            lines += radius_lines(des.full_radius, "spectral radius of the full error matrix", ".4g")
        else:
            lines += ["", f"q = {r.q}  ({d.q_method}{extra}); bound {comparison(r.bound, d.rate)} for {scope}"]
        lines += radius_lines(des.error_radius, "spectral radius of Atil B^q", ".4g")
        if r.eig and r.eig.get("methods"):
            how = ", ".join(f"{k} {v}" for k, v in r.eig["methods"].items())
            tol = f" (ARPACK relative tolerance {r.eig['tolerance']:g})" if r.eig.get("tolerance") else ""
            lines.append(f"  spectral radii computed: {how}{tol}")
        if len(des.q_methods) > 1:
            lines.append("  other methods:")
            for meth, res in des.q_methods.items():
                if meth == d.q_method:
                    continue
                if isinstance(res, str):
                    lines.append(f"    {meth}: {res}")
                else:
                    ex = f" (p = {res.p}, pbar = {res.pbar})" if res.p else ""
                    lines.append(f"    {meth}: q = {res.q}{ex}, bound {res.bound:.4g}")
    cert = rate_certificate(des)
    verdict = "rate" if adaptive else f"rate {'certified' if cert.certified else 'NOT certified'}"
    lines += ["", f"{verdict}: {cert.text}"]
    reach = fastest_rate(des)
    if reach is not None:
        lines.append(f"  {reach.text}")
    fewest = fewest_exchanges(des)
    if fewest is not None and des.consensus not in ("fusion", "relay"):  # the fusion kind's warning says it already
        per = "event time" if sc.time == "discrete" else "run.dt"
        lines.append(f"  the fewest exchanges that certify rate {d.rate:g} with these design keys: q = {fewest} per "
                     f"{per} (design.q: auto), against the budget design.q = {d.q}")
    loss = loss_certificate(des)
    if loss is not None:
        lines.append(loss.text)  # "rate certified under loss: ..." or "not certified under loss: ..."
    tested = bad_data_lines(des)  # design.bad_data: the test, then each sensor's loss (bad_data.py)
    if tested:
        lines += ["", tested[0]] + [f"  {t}" for t in tested[1:]]
    lines += _size_lines(des)
    warnings = design_warnings(des)
    if warnings:
        lines += [""] + [f"warning: {w}" for w in warnings]
    more = advice_lines(des)
    if more:
        lines += [""] + more
    return "\n".join(lines)


def design_warnings(des: Design) -> list:
    """Every warning of a design, each once: the design's own and its conditioning's (what ``splitspec design``
    prints, ``--json`` lists and ``ss.design(...).checks.warnings`` holds).

    Parameters
    ----------
    des : Design
        The design.

    Returns
    -------
    list of str
        One line each, the design's first, in order, without repeats.
    """
    out = []
    for w in list(des.warnings) + list(conditioning(des).warnings):
        if w not in out:
            out.append(w)
    return out


def _size_lines(des: Design) -> list:
    """The errors' size: the transient constant, and the predicted steady-state error under noise."""
    cond = conditioning(des)
    sc = des.scenario
    unit = "rate^tau" if sc.time == "discrete" else "exp(-lam t)"
    env = des.envelope_rate
    if env is not None and env != sc.design.rate:  # directions no agent sees set a slower envelope
        unit = f"{env:.4g}^tau" if sc.time == "discrete" else f"exp(-{env:.4g} t)"
    c = cond.transient_constant
    if c is None:
        out = [f"transient: {cond.transient_method}"]
    else:
        value = "infinite" if math.isinf(c) else f"{c:.3g}"
        how = cond.transient_method
        # an upper bound rather than the supremum itself: say so, with the largest power actually formed
        bound = f"; {how[how.index('Lyapunov bound'):]}" if "Lyapunov bound" in how else ""
        out = [f"transient: ||e(t)|| <= c {unit} ||e(0)|| with c = {value} (transient_constant; "
               f"graph {cond.transient_case} held constant{bound})"]
    if cond.predicted_rms is not None:
        allrms = _all_rms(cond.predicted_rms)
        per = ", ".join(f"{i}: {v:.3g}" for i, v in cond.predicted_rms.items())
        out.append(f"noise: predicted steady-state RMS error {allrms:.3g}{reference_text(allrms, cond)} (per agent "
                   f"{per}; graph {cond.predicted_graph} held constant, "
                   f"{'the base covariance walked per agent' if des.consensus == 'relay' else 'discrete Lyapunov equation'})")
    elif cond.kalman_rms is not None:
        out.append(f"noise: the steady-state error is not predicted (m n = {sc.m * sc.n}); the centralized Kalman "
                   f"filter's is {cond.kalman_rms:.3g}")
    line = design_exchanges(des).text()
    if line:
        out.append(line)
    return out


def reference_text(rms: float, cond) -> str:
    """`` = 1.09x the centralized Kalman filter's 0.236 (...)``: a predicted RMS against the two references.

    Parameters
    ----------
    rms : float
        A predicted steady-state RMS error.
    cond : Conditioning
        Its ``kalman_rms`` and ``reference_rms``.

    Returns
    -------
    str
        Starting with `` = ``; the reference is named only when it is above the Kalman filter's; empty without a
        positive Kalman RMS.

    Examples
    --------
    >>> from types import SimpleNamespace
    >>> print(reference_text(0.3, SimpleNamespace(kalman_rms=0.25, reference_rms=0.28)))  # doctest: +NORMALIZE_WHITESPACE
     = 1.2x the centralized Kalman filter's 0.25, 1.07x the centralized Kalman filter designed for A/rate
     (0.28; a rate-shifted Riccati design, not the optimum under the rate)
    """
    kf, ref = cond.kalman_rms, cond.reference_rms
    if kf is None or not kf > 0:
        return ""
    text = f" = {rms / kf:.3g}x the centralized Kalman filter's {kf:.3g}"
    if ref is not None and ref > kf * (1 + 1e-9):
        text += f", {rms / ref:.3g}x {SHIFTED_NAME} ({ref:.3g}; {SHIFTED_NOTE})"
    return text


def agent_lines(des: Design, cond) -> list:
    """Per agent: what it corrects locally and what it takes from its neighbours, named by their largest states.

    Parameters
    ----------
    des : Design
        The design (split or whole-state).
    cond : Conditioning
        Its conditioning (the agents' gain norms and margins).

    Returns
    -------
    list of str
        A heading of two or three lines, then one line per agent.
    """
    sc = des.scenario
    names = sc.state_names
    if des.consensus == "fusion":
        out = ["agents  (fusion: each agent updates with its own measurement, z_i = x_i + L_i (y_i - C_i x_i), fuses",
               "         its neighbours' estimates q times with matrix weights, then predicts; what L_i corrects, by",
               "         its largest states, and ||F L_i||)"]
        for k, (a, c) in enumerate(zip(des.agents, cond.agents)):
            U = np.linalg.svd(np.asarray(a.K, dtype=float), full_matrices=False)[0] if a.K.size else a.K
            out.append(f"  agent {a.id}: s_i = {a.K.shape[1]}, corrects locally {spread(U, names) or 'nothing'}; "
                       f"takes every state from its neighbours; |F L_i| {c.gain_norm:.3g}")
        return out
    if des.consensus == "relay":
        out = ["agents  (relay: each agent passes on every sample it holds once, and walks its base estimate of",
               "         x(tau - D) forward over the samples it holds with the centralized predictor's gains; what",
               "         its own sensor's columns of the base's gain L correct, by its largest states, and ||L_i||)"]
        for k, (a, c) in enumerate(zip(des.agents, cond.agents)):
            U = np.linalg.svd(np.asarray(a.K, dtype=float), full_matrices=False)[0] if a.K.size else a.K
            out.append(f"  agent {a.id}: s_i = {a.K.shape[1]}, its samples correct {spread(U, names) or 'nothing'}; "
                       f"every sensor's samples reach it; |L_i| {c.gain_norm:.3g}")
        return out
    if des.consensus == "whole":
        w = des.whole
        out = ["agents  (consensus on the whole state: each agent updates with its own measurement, then averages its",
               "         neighbours' updated estimates q times; K_i = -L_i / pi_i, L the centralized filter's gain and",
               "         pi_i the agent's weight in the consensus average; what K_i corrects, by its largest states)"]
        for k, (a, c) in enumerate(zip(des.agents, cond.agents)):
            U = np.linalg.svd(np.asarray(a.K, dtype=float), full_matrices=False)[0] if a.K.size else a.K
            out.append(f"  agent {a.id}: s_i = {a.K.shape[1]}, corrects locally {spread(U, names) or 'nothing'}; "
                       f"takes every state from its neighbours; pi_i = {w.pi[k]:.3g}, |K| {c.gain_norm:.3g}")
        return out
    out = ["agents  (n_i = dim of the unobservable space V_i, which it takes from its neighbours; poles of",
           "         Abar_i + Kbar_i Cbar_i; the smallest observability margin counted as seen, and ||K_i||)"]
    for a, c in zip(des.agents, cond.agents):
        margin = "-" if c.observability_margin is None else f"{c.observability_margin:.2g}"
        weak = f", weak direction (margin {c.weak:.2g}) left to consensus" if c.weak > 0 else ""
        takes = f", from its neighbours: {spread(a.V_user, names)}" if a.dec.n_unobservable else ""
        out.append(f"  agent {a.id}: s_i = {a.K.shape[1]}, n_i = {a.dec.n_unobservable}"
                   + (f" (+ {a.dec.unobserved} no agent sees)" if a.dec.unobserved else "")
                   + f", poles {poles_text(a.gain.poles, sc.time)}, margin {margin}, |K| {c.gain_norm:.3g}{weak}"
                   + takes)
    return out


def radius_lines(radii: dict, what: str, fmt: str) -> list:
    """One line per case, the largest first, at most :data:`MAX_LISTED` (the rest counted): ``  label: what = r``.

    Parameters
    ----------
    radii : dict
        ``{case label: radius}``.
    what : str
        The quantity's name in each line.
    fmt : str
        The format spec of the radii (``.4g``).

    Returns
    -------
    list of str
        Indented lines; the last counts the cases not listed.

    Examples
    --------
    >>> radius_lines({"a": 0.5, "b": 0.7}, "rho", ".2f")
    ['  b: rho = 0.70', '  a: rho = 0.50']
    """
    ordered = sorted(radii.items(), key=lambda kv: -kv[1])
    shown = ordered if len(ordered) <= MAX_LISTED else ordered[:MAX_LISTED - 1]
    out = [f"  {label}: {what} = {rad:{fmt}}" for label, rad in shown]
    if len(shown) < len(ordered):
        out.append(f"  ... and {len(ordered) - len(shown)} more cases, each at most {ordered[len(shown)][1]:{fmt}}")
    return out


def fusion_lines(des: Design) -> list:
    """The fusion design's q, its certificate per graph, and what its gains are.

    Parameters
    ----------
    des : Design
        A fusion design (``des.consensus == "fusion"``).

    Returns
    -------
    list of str
        The q line, one line per graph (:func:`radius_lines`) and the gains' line.
    """
    sc = des.scenario
    k = des.whole
    per = "event time" if sc.time == "discrete" else f"run.dt = {sc.run.dt:g}"
    how = "design.q: the budget given" if sc.design.q != "auto" else \
        "the smallest whose protocol limit is within 1 % of the Kalman filter, raised until certified"
    out = [f"q = {des.q} exchanges per {per}  (fusion; {how}); spectral radius of the full error map "
           f"{comparison(k.radius, k.lam_step, digits=6)} per step for each graph held constant"]
    out += radius_lines(des.full_radius, "spectral radius of the full error map", ".6g")
    gains = "the noise's steady-state gains" if k.alpha == 1.0 else \
        f"the steady-state gains of the model shifted by alpha = {k.alpha:.6g} (the noise's are slower than the rate)"
    out.append(f"  gains: {gains}; predicted {k.designs[0].ratio:.4g}x the Kalman predictor's RMS, its limit at q = "
               f"{des.q}: {k.limit:.4g}x")
    return out


def relay_lines(des: Design) -> list:
    """The relay design's q, its delays, its certificate and what its gains are.

    Parameters
    ----------
    des : Design
        A relay design (``des.consensus == "relay"``).

    Returns
    -------
    list of str
    """
    sc = des.scenario
    k = des.whole
    per = "event time" if sc.time == "discrete" else f"run.dt = {sc.run.dt:g}"
    how = "design.q: given" if sc.design.q != "auto" else \
        "the smallest whose protocol limit is within 1 % of the Kalman filter"
    late = int(k.delays.max())
    behind = f"; the base {k.D} behind (design.lag {k.lag})" if k.lag else ""
    out = [f"q = {des.q} exchanges per {per}  (relay; {how}); every sample reaches every agent at most {late} event "
           f"time{'s' if late != 1 else ''} late{behind}; spectral radius of the base's error map "
           f"{comparison(k.radius, k.lam_step, digits=6)} per step"]
    gains = "the Kalman predictor's gain" if k.alpha == 1.0 else \
        f"the Riccati predictor of the model shifted by alpha = {k.alpha:.6g} (the Kalman predictor is slower than the rate)"
    out.append(f"  base: {gains}; the walk: the Kalman gains of the samples held at each lag; predicted {k.ratio:.4g}x "
               f"the Kalman predictor's RMS, the protocol's limit at q = {des.q}: {k.limit:.4g}x")
    return out


def whole_lines(des: Design) -> list:
    """The whole-state design's q, its certificate per case, and the centralized filter it spreads.

    Parameters
    ----------
    des : Design
        A whole-state design (``des.consensus == "whole"``).

    Returns
    -------
    list of str
        The q line, one line per case (:func:`radius_lines`) and, unless the gains were given, the centralized
        filter's line.
    """
    sc = des.scenario
    r, w = des.q_result, des.whole
    per = "event time" if sc.time == "discrete" else f"run.dt = {sc.run.dt:g}"
    scope = ("arbitrary switching among the graphs" if r.method == "mixing bound" else
             "switching with the scenario's dwell time" if r.method == "dwell-time bound" else "each graph held constant")
    raised = "" if des.q == w.q_certified else f"; raised from {w.q_certified} for the noise"
    out = [f"q = {des.q} exchanges per {per}  (whole-state consensus; the smallest the {r.method} certifies"
           f"{raised}); bound {comparison(r.bound, w.lam_step, digits=6)} per step for {scope}"]
    out += radius_lines(des.full_radius, "spectral radius of the full error matrix", ".6g")
    if not gain_methods.method(w.method).needs_K:  # a centralized filter it spreads, not the user's K_i
        which = "the Kalman predictor" if w.alpha == 1.0 else f"the Riccati design shifted by alpha = {w.alpha:.6g}"
        out.append(f"  the centralized filter it spreads: {which} of the per-step model with the scenario's noise, "
                   f"radius {w.central_radius:.6g}, predicted steady RMS {w.central_rms:.4g}")
    return out
