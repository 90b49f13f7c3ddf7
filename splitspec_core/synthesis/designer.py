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
5. resilience analysis (single agent and single arc losses);
6. an approximate split (a weakly observable direction left to consensus): the rate checked on the full error
   matrices, an automatic q or g raised until they meet it (:func:`~.approximate.check_full`).

Steps 1, 2, 4 and 5 are shared (:class:`~.prelude.Prelude`) with the whole-state design (:mod:`.whole_state`:
every agent takes the whole state from its neighbours, its gain from the noise), which replaces step 3 and g;
``design.consensus: auto`` with ``design.gains: optimal`` designs both and keeps the certified one with the smaller
predicted noise.  A refusal or an uncertified rate says the fastest rate the same keys certify (:func:`highest_rate`).

The :class:`Design` it returns holds data (:mod:`.design_data`); its verdict, conditioning and certificate under
loss are functions of it (:mod:`.verdict`, :mod:`.conditioning`, :mod:`.loss_certificate`).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from . import bounds
from .approximate import check_full
from ..errors import AssumptionError, DesignError
from .design_data import Design
from .error_matrix import MAX_NOISE_DIM, predicted_rms, remember_predicted
from ..model.local_design import design_agent, gain_request, whole_placeholder, with_gain
from .prelude import Prelude
from .sampled_rates import exact_g, sampled_g
from .spectral import CERTIFY_MARGIN, certifies
from .verdict import rate_certificate
from .whole_state import design_whole
from ..scenarios import gain_methods
from ..scenarios.specs import Scenario

__all__ = ["design", "scenario_dwell", "highest_rate", "RateReach", "RATE_PROBES"]


def scenario_dwell(sc: Scenario) -> float | None:
    """Average dwell time of the switching signal: design.dwell, random dwell, or shortest schedule piece.

    Parameters
    ----------
    sc : Scenario
        The scenario (its ``design.dwell`` and ``switching``).

    Returns
    -------
    float or None
        ``design.dwell`` when given; random switching: its mean dwell; a schedule over several graphs: its shortest
        piece (with a ``period``, the last piece ends at the period); else None (one graph: no switching).
        Event times (discrete) or seconds (continuous).

    Examples
    --------
    >>> import splitspec_core as ss
    >>> scenario_dwell(ss.load_scenario("examples/paper_discrete_switching.yaml"))
    2.0
    >>> scenario_dwell(ss.load_scenario("examples/paper_discrete.yaml")) is None
    True
    """
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


def design(sc: Scenario, *, compare_q_methods: bool = False, workers: int | None = None,
           reach: bool = True) -> Design:
    """Run the whole design for a scenario.

    ``design.consensus`` picks what each agent takes from its neighbours: ``split`` the paper's (its unobservable
    space), ``whole`` the whole state (:mod:`.whole_state`); ``auto`` (the default) the split, but for
    ``design.gains: optimal`` (the default when the scenario states noise), which designs both and keeps the
    certified one with the smaller predicted steady RMS (:func:`_choose`).

    ``compare_q_methods`` (discrete time) also computes, for information, the q of every other
    q method over the same cases (``Design.q_methods``; ``splitspec design --all-methods``).
    ``workers``: processes for the spectral radii of many large cases (a resilient design of hundreds of
    agents; :func:`splitspec_core.synthesis.bounds.q_spectral`); ``None``: every core this process may use.

    Parameters
    ----------
    sc : Scenario
        The scenario to design.
    compare_q_methods : bool
        Discrete time: also compute every other q method's q, for information (default False).
    workers : int, optional
        Processes for the spectral radii of many large cases (None: every core this process may use).
    reach : bool, default True
        On a refusal, search the fastest rate the same keys certify and add it to the message
        (:func:`highest_rate`: up to ``RATE_PROBES`` more designs); ``compare``'s side rows do without (on the IEEE
        14-bus model at 0.5 /s the search was 60 % of a ``compare``).

    Returns
    -------
    Design
        The estimator (every agent's ``V_i``, ``K_i``, ``P_i``), ``q`` or ``g`` with the bounds that certify it,
        the cases covered, the loss analyses and the warnings (:mod:`.design_data`).

    Raises
    ------
    AssumptionError
        A graph is not strongly connected, the system is not jointly
        observable, explicit gains miss the rate, or ``design.resilience: 1``
        is asked of a network that is not redundant.
    DesignError
        No g or q could be found within limits.

    Examples
    --------
    >>> import splitspec_core as ss
    >>> des = design(ss.load_scenario("examples/paper_discrete.yaml"))
    >>> des.q, des.consensus
    (6, 'split')
    """
    try:
        return _dispatch(sc, compare_q_methods, workers)
    except (AssumptionError, DesignError) as exc:
        found = highest_rate(sc) if reach else None
        if found is None:
            raise
        raise type(exc)(f"{exc}; {found.text}") from None


def _dispatch(sc: Scenario, compare_q_methods: bool, workers: int | None) -> Design:
    d = sc.design
    if d.consensus in ("whole", "fusion", "relay"):
        return _design(sc, d.consensus, compare_q_methods, workers)
    if d.consensus == "auto" and not gain_methods.method(d.gains).local:  # a central method: both structures
        return _choose(sc, compare_q_methods, workers)
    return _design(sc, "split", compare_q_methods, workers)


#: the bisection of :func:`highest_rate`: at most this many designs
RATE_PROBES = 7


@dataclasses.dataclass(frozen=True)
class RateReach:
    """The fastest rate a scenario's design keys certify (:func:`highest_rate`): ``rate`` certified, ``refused``
    not (the bisection's bracket), and the line that says so."""

    rate: float
    refused: float
    text: str
    shown: float | None = None  # ``rate`` as the line shows it: rounded toward slower


def highest_rate(sc: Scenario, *, probes: int = RATE_PROBES) -> RateReach | None:
    """When a design at ``design.rate`` is refused or not certified: the fastest rate the same design keys certify,
    found by bisection between the rate asked and one far slower (a hundredth of it; discrete time:
    ``1 - (1 - lam) / 100``), with the line that says it (``the fastest rate these design keys certify is about
    0.31 ...``); None when even the slow end is refused (the refusal is not about the rate).

    Parameters
    ----------
    sc : Scenario
        The scenario whose ``design.rate`` was refused or not certified (the other design keys are kept).
    probes : int
        How many designs the search runs at most (default :data:`RATE_PROBES`): the slow end, then ``probes - 1``
        bisection steps (geometric in ``lam``, continuous; in ``1 - lam``, discrete).

    Returns
    -------
    RateReach or None
        The fastest rate certified and the slowest refused that the search found, with the line; None when the slow
        end is refused too.

    Examples
    --------
    The paper's explicit gains (poles 0.2 and 0.3) cannot meet a rate 0.25 whatever q:

    >>> import dataclasses
    >>> import splitspec_core as ss
    >>> sc = ss.load_scenario("examples/paper_discrete.yaml")
    >>> fast = dataclasses.replace(sc, design=dataclasses.replace(sc.design, rate=0.25))
    >>> reach = highest_rate(fast, probes=3)
    >>> reach.rate > 0.3 > reach.refused
    True
    """
    d = sc.design

    def ok(rate: float) -> bool:
        try:
            des = _dispatch(dataclasses.replace(sc, design=dataclasses.replace(d, rate=rate)), False, None)
        except (AssumptionError, DesignError):
            return False
        return bool(rate_certificate(des).certified)

    # a faster rate is a larger one in continuous time, a smaller lam in discrete time
    slow = d.rate / 100.0 if sc.time == "continuous" else 1.0 - (1.0 - d.rate) / 100.0
    if not ok(slow):
        return None
    good, bad = slow, d.rate
    for _ in range(max(0, probes - 1)):
        mid = math.sqrt(good * bad) if sc.time == "continuous" else 1.0 - math.sqrt((1.0 - good) * (1.0 - bad))
        good, bad = (mid, bad) if ok(mid) else (good, mid)
    unit = "" if sc.time == "continuous" else " per event time"
    slower_up = sc.time == "discrete"  # a slower rate: a larger lam (discrete), a smaller one (continuous)
    digits = 3
    while digits < 10 and _rounded(good, digits, slower_up) == _rounded(bad, digits, not slower_up):
        digits += 1  # never "0.996 certified, 0.996 not"
    # each printed toward its own side: the certified one rounded slower, the refused one faster, so the line never
    # calls a rate certified that is faster than the one designed
    shown, refused = _rounded(good, digits, slower_up), _rounded(bad, digits, not slower_up)
    return RateReach(good, bad, f"the fastest rate these design keys certify is about {shown:g}{unit} "
                                f"(design.rate {good:.10g} certified, {refused:g} not; {probes} designs)", shown)


def _rounded(x: float, digits: int, up: bool) -> float:
    """``x`` rounded up (or down) to ``digits`` significant digits."""
    if x <= 0 or not math.isfinite(x):
        return x
    step = 10.0 ** (math.floor(math.log10(x)) - digits + 1)
    k = x / step
    k = math.ceil(k - 1e-9) if up else math.floor(k + 1e-9)
    return float(f"{k * step:.{digits}g}")


def _choose(sc: Scenario, compare_q_methods: bool, workers: int | None) -> Design:
    """``design.gains: optimal`` with ``design.consensus: auto``: the whole-state design and the split (its ``riccati``
    or ``place`` gains, :func:`_best_split`) both, and the certified one with the smaller predicted steady RMS kept;
    when neither noise can be predicted (``m n`` above ``MAX_NOISE_DIM``) the split, which costs fewer exchanges;
    neither certified: the one with the smaller predicted RMS.  ``Design.chosen`` says which and why."""
    pre = Prelude.of(sc)
    found, errors = {}, {}
    skip = None
    for structure in ("whole", "split"):
        if structure == "split":
            skip = _skip_split(found.get("whole"))
            if skip:
                break
        try:
            found[structure] = _design(pre, structure, compare_q_methods, workers) if structure == "whole" else \
                _best_split(pre, compare_q_methods, workers)
        except (AssumptionError, DesignError) as exc:
            errors[structure] = exc
    if skip:
        return _with_budget(pre, _annotated(found["whole"], f"design.consensus: auto chose the whole state ({skip}; "
                                                           "the split was not designed: design.consensus: split "
                                                           "designs it)"), compare_q_methods, workers)
    if not found:  # the split's refusal is the paper's: say it, and what the whole state met
        raise type(errors["split"])(f"{errors['split']} (and the whole-state design: {errors['whole']})")
    figures = {k: (bool(rate_certificate(des).certified), _predicted_all(des)) for k, des in found.items()}
    certified = [k for k, (ok, _) in figures.items() if ok] or list(figures)
    if len(certified) == 1:
        pick = certified[0]
    else:
        w, s_ = (figures[k][1] for k in ("whole", "split"))
        pick = "split" if w is None and s_ is None else \
            ("whole" if (math.inf if w is None else w) <= (math.inf if s_ is None else s_) else "split")
    other = "split" if pick == "whole" else "whole"
    return _with_budget(pre, _annotated(found[pick], _chosen_text(pick, other, figures, errors, found)),
                        compare_q_methods, workers)


def _fusion_offered(sc: Scenario) -> bool:
    """The fusion kind's preconditions (scenarios.design_section refuses it otherwise): measurement noise on every
    output, no bad-data test given (the default one is off with these kinds: synthesis/bad_data.py), no resilience,
    no given gains."""
    s, d = sc.system, sc.design
    return (s.measurement_noise_present and not bool((s.measurement_std <= 0).any())
            and (d.bad_data is None or d.bad_data_default)
            and d.resilience == 0 and d.K is None)


#: beside a certified relay design, the fusion kind is designed too only up to this m n (its design is a Smith
#: doubling of size m n per policy step: minutes at the IEEE 39-bus model's 1700, issue 44; the relay's a few n x n
#: Riccati equations) and only when the relay's gain is shifted (unshifted it is the protocol's limit: nothing within
#: the budget is more accurate)
FUSION_BESIDE_RELAY = 600


def _relay_offered(sc: Scenario) -> bool:
    """The relay kind's preconditions: the fusion kind's, and one graph."""
    return _fusion_offered(sc) and len(sc.graph_names) == 1


def _kind_at_budget(sc: Scenario, kind: str, compare_q_methods: bool, workers: int | None) -> Design | None:
    """The design of ``kind`` (fusion or relay) at the budget, None when it refuses."""
    other = dataclasses.replace(sc, design=dataclasses.replace(sc.design, consensus=kind))
    try:
        return _design(Prelude.of(other), kind, compare_q_methods, workers)
    except (AssumptionError, DesignError):
        return None


def _with_budget(pre: Prelude, des: Design, compare_q_methods: bool, workers: int | None) -> Design:
    """``design.q`` given is the budget (issue 44): the relay kind and the fusion kind at that q too (the fusion kind
    beside a certified relay only as :data:`FUSION_BESIDE_RELAY` says); of the certified ones the smallest predicted
    steady RMS is kept, ``des`` when none other is certified or ``des`` is certified and as accurate."""
    sc = pre.sc
    if sc.design.q == "auto" or not _fusion_offered(sc):
        return des
    found = {}
    relay = _kind_at_budget(sc, "relay", compare_q_methods, workers) if _relay_offered(sc) else None
    if relay is not None and rate_certificate(relay).certified:
        found["relay"] = relay
    if relay is None or "relay" not in found or (relay.whole.alpha < 1.0 and sc.m * sc.n <= FUSION_BESIDE_RELAY):
        fused = _kind_at_budget(sc, "fusion", compare_q_methods, workers)
        if fused is not None and rate_certificate(fused).certified:
            found["fusion"] = fused
    if not found:
        return des
    rms = {k: _predicted_all(d) for k, d in found.items()}
    pick = min(found, key=lambda k: math.inf if rms[k] is None else rms[k])
    mine, other = rms[pick], _predicted_all(des)
    if rate_certificate(des).certified and (mine is None or (other is not None and other <= mine)):
        return des
    said = "no prediction" if other is None else f"predicted steady RMS {other:.4g}"
    beside = "".join(f"; {k}: predicted steady RMS {rms[k]:.4g}" for k in found if k != pick)
    return _annotated(found[pick], f"design.consensus: auto chose {pick} at the budget design.q = {sc.design.q} "
                                   f"(predicted steady RMS {mine:.4g}, certified) over {des.consensus} ({said}"
                                   f"{'' if rate_certificate(des).certified else ', rate NOT certified'}{beside})")


def _best_split(pre: Prelude, compare_q_methods: bool, workers: int | None) -> Design:
    """The paper's split for ``design.gains: optimal``: its ``riccati`` gains (weights: the noise) and its ``place``
    gains both, the certified one with the smaller predicted steady RMS kept (the first refusal said when neither
    designs)."""
    found, first = [], None
    for method in gain_methods.method(pre.sc.design.gains).split:
        try:
            des = _design(pre, "split", compare_q_methods, workers, split_gains=method)
        except (AssumptionError, DesignError) as exc:
            first = first or exc
            continue
        rms = _predicted_all(des)
        found.append((not rate_certificate(des).certified, math.inf if rms is None else rms, des))
    if not found:
        raise first
    return min(found, key=lambda f: f[:2])[2]


def _annotated(des: Design, chosen: str) -> Design:
    """``des`` with the line saying why it was chosen; its analyses kept (the line changes none of them)."""
    out = dataclasses.replace(des, chosen=chosen)
    out._analyses.update(des._analyses)
    return out


#: a certified whole-state design within this factor of the centralized Kalman filter's predicted RMS is kept without
#: designing the split (which cannot beat the Kalman filter either)
NEAR_KALMAN = 1.1


#: above this m n the split is not designed beside a certified whole-state design (its approximate split's full error
#: matrices and g search cost minutes there: ieee39, m n = 1700)
SPLIT_BESIDE = 1000


def _skip_split(des: Design | None) -> str | None:
    """Why ``design.consensus: auto`` need not design the split beside the whole-state design ``des``, or None: ``des``
    certified and within :data:`NEAR_KALMAN` of the Kalman filter's predicted RMS (no estimator does better), or
    ``m n`` above :data:`SPLIT_BESIDE`."""
    if des is None or not rate_certificate(des).certified:
        return None
    rms, kf = _predicted_all(des), des.whole.kf_rms
    figure = "noise not predicted" if rms is None else f"predicted steady RMS {rms:.4g}"
    if rms is not None and kf is not None and rms <= NEAR_KALMAN * kf:
        return (f"{figure}, within {NEAR_KALMAN - 1:.0%} of the centralized Kalman filter's {kf:.4g}: no estimator "
                "does better")
    sc = des.scenario
    if sc.m * sc.n > SPLIT_BESIDE:
        return f"{figure}, certified; at m n = {sc.m * sc.n} the split's design costs minutes"
    return None


def _predicted_all(des: Design) -> float | None:
    """RMS over agents of the predicted steady RMS errors, None when not computed (too large, or adaptive)."""
    sc = des.scenario
    if des.adaptive or sc.m * sc.n > MAX_NOISE_DIM:
        return None
    r = predicted_rms(des)
    return float(np.sqrt(np.mean(r ** 2)))


def _chosen_text(pick: str, other: str, figures: dict, errors: dict, found: dict) -> str:
    """One line: which consensus subspace ``design.consensus: auto`` chose, and why."""
    default = gain_methods.method(found[pick].scenario.design.gains).split[:1] or ("split",)
    gains = found["split"].agents[0].gain.method if "split" in found and found["split"].agents else default[0]
    name = {"whole": "the whole state", "split": f"the split ({gains} gains)"}

    def fig(k):
        ok, rms = figures[k]
        return (f"predicted steady RMS {rms:.4g}" if rms is not None else "noise not predicted") + \
            ("" if ok else ", rate NOT certified")

    text = f"design.consensus: auto chose {name[pick]} ({fig(pick)})"
    if other in figures:
        return text + f" over {name[other]} ({fig(other)})"
    return text + f"; {name[other]} failed: {errors[other]}"


def _design(pre: "Prelude | Scenario", structure: str, compare_q_methods: bool, workers: int | None, *,
            split_gains: str | None = None) -> Design:
    """The design with the consensus ``structure`` (``split`` or ``whole``) on what :class:`~.prelude.Prelude` computed;
    ``split_gains``: the split's gain method for ``design.gains: optimal`` (default ``riccati``)."""
    pre = pre if isinstance(pre, Prelude) else Prelude.of(pre)
    sc, un, scale = pre.sc, pre.un, pre.scale
    d = sc.design
    A = sc.system.A
    warnings = list(pre.warnings)
    cases, switching = pre.cases, pre.switching
    if structure in ("whole", "fusion", "relay"):
        if not un.decays:
            raise AssumptionError(f"design.consensus: {structure} needs every mode no agent sees to decay (the "
                                  "centralized filter it spreads has none for the others): design.consensus: split")
        agents = tuple(whole_placeholder(A, dec, aid, un.W_working, scale) for aid, dec in zip(sc.agent_ids, pre.decs))
    else:
        declared = gain_methods.method(d.gains)
        # a central method's split: its first split method, or the one _best_split asks for
        method = d.gains if declared.local else (split_gains or declared.split[0])
        agents = tuple(
            design_agent(A, C, gain_request(sc, aid, scale, method=method), agent_id=aid, unobserved=un.W_working,
                         dec=pre.decs[k], scale=scale)
            for k, (aid, C) in enumerate(zip(sc.agent_ids, sc.system.Cs))
        )
    residual = max([a.dec.split_residual for a in agents] + [un.residual])
    common = dict(scenario=sc, graphs=pre.graphs, cases=cases, agent_losses=pre.agent_losses,
                  arc_losses=pre.arc_losses, split_residual=residual, unobserved=un, spectrum=pre.sp)
    if structure == "fusion":
        return _fusion(sc, agents, un, warnings, common)
    if structure == "relay":
        from .relay import relay_design

        return relay_design(sc, agents, un.envelope(d.rate), warnings, common)
    if structure == "whole":
        Ks, q, info, radii, cert = design_whole(sc, cases, rate=un.envelope(d.rate),
                                                dwell=scenario_dwell(sc) if switching else None, warnings=warnings)
        method, bound, certified, switches = cert
        agents = tuple(with_gain(a, K, d.gains) for a, K in zip(agents, Ks))
        result = bounds.QResult(q=q, method=method, bound=bound, certified=bool(certified), switching=switches)
        if not certified:
            warnings.append(f"q = {q} does NOT meet rate {d.rate:g} by the {method} ({bound:.6g})")
        des = Design(agents=agents, warnings=tuple(warnings), q=q, q_result=result, q_methods={method: result},
                     error_radius=radii, full_radius=radii, consensus="whole", whole=info, **common)
        if info.predicted is not None:  # its noise, predicted on its first graph while q was chosen: kept
            remember_predicted(des, sc.graph_names.index(cases[0].graph.name), info.predicted)
        return des
    kw: dict = {}
    if sc.time == "continuous":
        kw.update(_design_g(sc, cases, switching, warnings))
        if kw["g"] is not None:
            kw.update(sampled_g(sc, agents, cases, kw, switching, warnings))
    else:
        kw.update(_design_q(sc, cases, switching, warnings, compare_q_methods, workers))
    des = Design(agents=agents, warnings=tuple(warnings), **common, **kw)
    if des.split_exact or (sc.time == "continuous" and des.g is None):
        return des
    return check_full(des, warnings)  # an approximate split: the rate on the full error matrices


def _fusion(sc: Scenario, agents: tuple, un, warnings: list, common: dict) -> Design:
    """The fusion kind (:mod:`.fusion_kind`): its gains per graph, certified by each graph's full error map."""
    from .fusion_kind import design_fusion_kind

    d = sc.design
    kind = design_fusion_kind(sc, un.envelope(d.rate), warnings)
    F = kind.designs[0].F
    # each agent's K_i in the predictor's form without neighbours (x+ = F x - F L_i (C_i x - y_i)): its size for the
    # reports; what runs is L_i and the weights (fusion_kind.agent_fusion)
    agents = tuple(with_gain(a, -F @ kind.designs[0].Ls[k], "fusion") for k, a in enumerate(agents))
    radii = {c.label: kind.designs[sc.graph_names.index(c.graph.name)].radius for c in common["cases"]
             if c.graph.name in sc.graph_names}
    result = bounds.QResult(q=kind.q, method="full error matrix", bound=kind.radius, certified=kind.certified,
                            switching=len(sc.graph_names) > 1)
    return Design(agents=agents, warnings=tuple(warnings), q=kind.q, q_result=result,
                  q_methods={"full error matrix": result}, error_radius=radii, full_radius=radii, consensus="fusion",
                  whole=kind, **common)


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
        g, mode, by = None, "adaptive", None  # thm. split_continuous_adaptive: verdict.NO_CERTIFIED_RATE
    elif d.g == "auto":
        mode = "auto"
        if certified:
            by = min(certified, key=certified.get)
            # above the bound by the one rule's margin (spectral.certifies: the bound below g), then rounded up
            g = bounds.nice_ceil(certified[by] * (1 + 2 * CERTIFY_MARGIN))
            if g == 0.0 and not switching and any(c.nbar for c in cases):
                # eq. (g) says any g works: the unobservable parts decay at the rate on their own, but only at it (an
                # estimator exactly at its rate has no finite transient constant); the exact spectrum's g with the
                # design's margin instead (sampled.exact_g)
                alt = exact_g(cases, rate, d.margin, g_mins)
                if alt:
                    g, by = alt, "spectrum (exact, constant graph)"
        else:
            by = None
            g = bounds.nice_ceil(per_graph * (1 + 2 * CERTIFY_MARGIN))
            warnings.append("g is not certified for switching: the graphs are not all doubly stochastic and no "
                            "dwell time is known (set design.dwell or design.weights: metropolis); g covers "
                            "each graph held constant (eq. g)")
    else:
        g, mode = float(d.g), "given"
        ok = [k for k, v in certified.items() if certifies(v, g)]  # the one rule: the sufficient bound below g
        by = min(ok, key=certified.get) if ok else None
        if by is None:
            if all(certifies(bounds.abscissa(c, g), -rate) for c in cases):
                what = "each graph held constant" if switching else "the constant graph"
                warnings.append(f"g = {g:g} is below the sufficient bound but the exact spectrum meets the rate for "
                                f"{what}")
                by = None if switching else "spectrum (exact, constant graph)"
            else:
                bad = [c.label for c in cases if not certifies(bounds.abscissa(c, g), -rate)]
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
