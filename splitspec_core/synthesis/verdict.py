"""The certificate's verdict on a design's rate, computed here once and rendered by :mod:`.report`.

:func:`rate_certificate` is the verdict on the estimator as it is run: what ``splitspec design`` prints, what
``Checks`` (``ss.design``), ``compare`` and the noise tuning report (cached per design).
:func:`survivors_certificate` is the same certificate recomputed on what is left after losses, for the runtime
(:func:`splitspec_core.synthesis.survivors.certify_network`, at every loss of a run); its one line is phrased by
the same helpers (:func:`q_text`, :func:`sampled_shortfall`, :data:`ADAPTIVE`), so both say the same thing.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from . import bounds
from .design_data import Design, cached_analysis
from .error_matrix import MAX_RATE_DIM, step_blocks, whole_matrix
from .kalman import spectral_radius
from ..model.graphs import build_graph
from .sampled_rates import sampled_rates
from .spectral import certifies, comparison
from .mixing import mixing_bound

__all__ = ["RateCertificate", "rate_certificate", "survivors_certificate", "q_text", "whole_text", "sampled_shortfall",
           "NO_CERTIFIED_RATE", "ADAPTIVE"]

# thm. split_continuous_adaptive: with the adaptive gain (eq. adaptive) every error tends to zero, at no stated rate
NO_CERTIFIED_RATE = "asymptotic convergence only (no certified rate)"
#: the verdict's line for the adaptive gain
ADAPTIVE = f"adaptive gain: {NO_CERTIFIED_RATE}"


@dataclass(frozen=True)
class RateCertificate:
    """A design's verdict on its rate: the one every command reports.

    Attributes
    ----------
    certified : bool or None
        The design certifies that every error decays at the rate ``lam`` (or at ``rate``, slower, when directions
        no agent sees limit it: :mod:`splitspec_core.model.detectability`).  None only in the runtime's verdict on
        the adaptive gain (:func:`survivors_certificate`: no rate is claimed either way); the design's own verdict
        on it is False.
    text : str
        One line: what certifies it, or why nothing does.
    rate : float or None
        The rate of the certified envelope (``Design.envelope_rate``) when certified, else None.
    by : str or None
        What certifies it when certified: the q method (discrete), ``Design.g_certified_by`` (continuous),
        ``full error matrix`` (an approximate split), ``eq:g`` or ``spectrum`` (the survivors' g); else None.
    """

    certified: bool | None
    text: str
    rate: float | None = None
    by: str | None = None


def q_text(q: int, r: bounds.QResult, rate: float, cases: int, *, held: str = "each") -> str:
    """``q = ...: <method> bound ... < rate ...``: the line of q's certificate (``r``) over ``cases`` cases; a
    per-graph method on more than one says so (``held``: ``each`` in the design's report, ``per`` at runtime).

    Parameters
    ----------
    q : int
        The q the line names.
    r : bounds.QResult
        Its certificate (method, bound, certified, switching).
    rate : float
        ``lam``.
    cases : int
        How many cases the certificate covers.
    held : str
        The word before "graph held constant".

    Returns
    -------
    str
        One line.
    """
    # the one rule (spectral.certifies) decided r.certified; the line says the same comparison
    return (f"q = {q}: {r.method} bound {comparison(r.bound, rate, limit_text=f'rate {rate:g}')}"
            + ("" if r.switching or cases == 1 else f" ({held} graph held constant)"))


def sampled_shortfall(dt: float, worst: float, rate: float) -> str:
    """Why a g certified for the ODE is not for what runs: its sampled-data form (:mod:`splitspec_core.model.steps`)
    with step ``dt`` decays at only ``worst``.

    Parameters
    ----------
    dt : float
        ``run.dt``.
    worst : float
        The sampled-data form's slowest decay rate (<= 0: unstable).
    rate : float
        ``lam``.

    Returns
    -------
    str
        A clause (no capital, no full stop).

    Examples
    --------
    >>> sampled_shortfall(0.01, 0.8, 1.0)
    'its sampled-data form with run.dt = 0.01 decays at only 0.8 < rate 1'
    """
    if worst <= 0:
        return f"its sampled-data form with run.dt = {dt:g} is UNSTABLE (decay rate {worst:.4g})"
    return f"its sampled-data form with run.dt = {dt:g} decays at only {worst:.4g} < rate {rate:g}"


def rate_certificate(des: Design, *, sampled: bool = True) -> RateCertificate:
    """Does the design certify its rate for the estimator as it is run?  :func:`_split_certificate`, then what the
    directions no agent sees do to it (``Design.unobserved``): nothing when they decay faster than ``lam``; they limit
    the envelope's rate when they decay slower (``Design.envelope_rate``); with ``design.undetectable: exclude`` the
    certificate covers the error modulo them only.  Computed once per design (and ``sampled``).

    Parameters
    ----------
    des : Design
        The design.
    sampled : bool
        Continuous time: judge the sampled-data form with ``run.dt`` too (what runs); False: the ODE alone.

    Returns
    -------
    RateCertificate
        ``certified`` (False for the adaptive gain), its one line, and when certified the envelope's rate and
        what certifies it.

    Examples
    --------
    >>> import splitspec_core as ss
    >>> from splitspec_core.synthesis.designer import design
    >>> des = design(ss.scenario(A=[[0, 1, 0, 0], [-1, 0, 0, 0], [0, 0, 0, 1], [0, 0, -2, 0]],
    ...                          C={1: [[1, 0, 0, 0]], 2: [[0, 1, 0, 0]], 3: [[0, 0, 1, 0]]},
    ...                          graphs={"a": [(1, 2), (2, 1), (2, 3), (3, 2), (1, 3), (3, 1)]}, rate=0.5,
    ...                          gains="place"))
    >>> rate_certificate(des)
    RateCertificate(certified=True, text='q = 3: spectral bound 0.419 < rate 0.5', rate=0.5, by='spectral')
    """
    return _rate_certificate(des, sampled=bool(sampled))


@cached_analysis
def _rate_certificate(des: Design, *, sampled: bool) -> RateCertificate:
    cert = _split_certificate(des, sampled=sampled)
    un = des.unobserved
    text = cert.text
    if un is not None and un.dim:
        if des.excluded:
            text += (f"; on the error modulo the {un.dim} direction{'s' if un.dim != 1 else ''} no agent sees "
                     f"({un.where()}), which do not all decay (design.undetectable: exclude)")
        else:
            text += f"; {un.summary(des.rate)}"
    return RateCertificate(cert.certified, text, des.envelope_rate if cert.certified else None,
                           cert.by if cert.certified else None)


def _split_certificate(des: Design, *, sampled: bool = True) -> RateCertificate:
    """The certificate of the split (the quotient by what no agent sees, when that is not nothing).

    * adaptive gain: never (thm. split_continuous_adaptive gives asymptotic
      convergence only, :data:`NO_CERTIFIED_RATE`);
    * discrete: the certificate of q's method (``QResult``); the estimator
      runs exactly ``A_V = Atil B^q`` (eq. split_discrete_ench), so the bound
      is about what runs; a per-graph method on a switching scenario says so;
    * continuous: g certified for the ODE (eq. g, thm. arb,
      eq. split_continuous_g, or the exact spectrum of eq. split_continuous_split)
      and, with ``sampled`` (what ``simulate`` and ``run`` integrate: the
      sampled-data form with step ``run.dt``, :mod:`splitspec_core.model.steps`),
      its error map decaying at the rate too (``Design.sampled_rate``: exact,
      per graph held constant).  ``sampled=False`` judges the exact ODE alone.
    """
    sc = des.scenario
    if des.g_mode == "adaptive":
        return RateCertificate(False, ADAPTIVE)
    if des.consensus == "whole":
        return _whole_certificate(des)
    if des.consensus == "fusion":
        return _fusion_certificate(des)
    if des.consensus == "relay":
        return _relay_certificate(des)
    if des.full_radius:
        return _full_certificate(des, sampled=sampled)
    cert = _blocks_certificate(des, sampled=sampled)
    if cert.certified and not des.split_exact:
        # an approximate split whose full error matrices were too large to check (approximate.check_full): the
        # certificate covers the split blocks, not the estimator that runs
        return RateCertificate(False, f"{cert.text}, on the split blocks only: the split is approximate (residual "
                                      f"{des.split_residual:.2g}) and its full error matrices (m n = "
                                      f"{sc.m * sc.n} > {MAX_RATE_DIM}) were not checked")
    return cert


def _blocks_certificate(des: Design, *, sampled: bool) -> RateCertificate:
    """The certificates of the split blocks (:func:`_split_certificate`'s list, after the adaptive gain)."""
    sc = des.scenario
    rate = sc.design.rate
    if des.time == "discrete":
        r = des.q_result
        ok = bool(r.certified)
        return RateCertificate(ok, q_text(r.q, r, rate, len(des.cases)), by=r.method)
    g = des.g
    if des.g_certified_by is None:
        worst = max(des.error_radius.values(), default=-math.inf)
        if not certifies(worst, -rate):  # eq. (split_continuous_split): the ODE's error decays as exp(abscissa t)
            return RateCertificate(False, f"g = {g:g} misses rate {rate:g} even for the ODE (spectral abscissa "
                                          f"of A_V {comparison(worst, -rate)})")
        return RateCertificate(False, f"g = {g:g} meets rate {rate:g} for each graph held constant, but no bound "
                                      "covers the switching (thm. arb, eq. split_continuous_g)")
    by = des.g_certified_by
    ode = f"g = {g:g} certified by {by} for the ODE"
    if not sampled or not des.sampled_rate:
        return RateCertificate(True, ode, by=by)
    dt = sc.run.dt
    worst = min(des.sampled_rate.values())
    if worst <= 0:
        return RateCertificate(False, f"{ode}, but {sampled_shortfall(dt, worst, rate)}: reduce run.dt or g")
    if not certifies(-worst, -rate):  # the one rule on the decay rate: -worst below -rate
        return RateCertificate(False, f"{ode}, but {sampled_shortfall(dt, worst, rate)}: reduce run.dt")
    scope = " (each graph held constant)" if len(des.cases) > 1 else ""
    return RateCertificate(True, f"{ode}; its sampled-data form with run.dt = {dt:g} decays at {worst:.4g} > "
                                 f"{rate:g}{scope}", by=by)


def whole_text(q: int, r: bounds.QResult, des: Design, cases: int, *, held: str = "each") -> str:
    """The line of the whole-state design's certificate ``r`` at ``q`` over ``cases`` cases (:mod:`.whole_state`):
    what certifies it, its bound against the rate per event time (continuous time: per ``run.dt``, and the decay
    rate per second it means), and its scope.

    Parameters
    ----------
    q : int
        The q the line names.
    r : bounds.QResult
        The certificate (``method``: ``full error matrix``, ``mixing bound`` or ``dwell-time bound``).
    des : Design
        The whole-state design (its rate per step, ``des.whole.lam_step``).
    cases : int
        How many cases it covers.
    held : str
        The word before "graph held constant".

    Returns
    -------
    str
        One line ending ``; whole-state consensus``.
    """
    sc = des.scenario
    lam = des.whole.lam_step if des.whole is not None else des.rate
    what = {"full error matrix": "spectral radius of the full error matrix", "mixing bound": "mixing bound",
            "dwell-time bound": "dwell-time bound"}.get(r.method, r.method)
    ok = bool(r.certified)
    if sc.time == "discrete":
        text = f"q = {q}: {what} {comparison(r.bound, lam, limit_text=f'rate {lam:.6g}', digits=6)}"
    else:
        per_s = -math.log(r.bound) / sc.run.dt if 0 < r.bound < math.inf else 0.0
        text = (f"q = {q} exchanges per run.dt = {sc.run.dt:g}: {what} {comparison(r.bound, lam, digits=6)} "
                f"per step (decay rate {per_s:.4g} {'>' if ok else '<='} {-math.log(lam) / sc.run.dt:.4g})")
    if r.method == "mixing bound":
        text += " under arbitrary switching among doubly stochastic graphs"
    elif r.method == "dwell-time bound":
        text += " under switching with the scenario's dwell time"
    elif cases > 1:
        text += f" ({held} graph held constant)"
    return text + "; whole-state consensus"


def _whole_certificate(des: Design) -> RateCertificate:
    """The whole-state design (:mod:`.whole_state`): its q's certificate, computed by the design."""
    r = des.q_result
    return RateCertificate(bool(r.certified), whole_text(des.q, r, des, len(des.cases)), by=r.method)


def _fusion_certificate(des: Design) -> RateCertificate:
    """The fusion kind (:mod:`.fusion_kind`): every graph's full error map below the rate per step."""
    k = des.whole
    per = "per event time" if des.time == "discrete" else f"per run.dt = {des.scenario.run.dt:g}"
    held = " (each graph held constant)" if len(k.designs) > 1 else ""
    return RateCertificate(k.certified, f"q = {des.q}: spectral radius of the full error map "
                                        f"{comparison(k.radius, k.lam_step, digits=6)} {per}{held}; fusion",
                           by="full error matrix")


def _relay_certificate(des: Design) -> RateCertificate:
    """The relay kind (:mod:`.relay`): the base's error map below the rate per step (the agents' errors do not
    couple; each is its walk's fixed map of the base's)."""
    k = des.whole
    per = "per event time" if des.time == "discrete" else f"per run.dt = {des.scenario.run.dt:g}"
    return RateCertificate(k.certified, f"q = {des.q}: spectral radius of the base's error map F - L C "
                                        f"{comparison(k.radius, k.lam_step, digits=6)} {per} (every agent's error "
                                        "its walk's fixed map of it; the graph fixed); relay", by="base error map")


def _full_certificate(des: Design, *, sampled: bool) -> RateCertificate:
    """An approximate split (``Design.full_radius``): the verdict of the full error matrices, each graph held
    constant; no switching certificate of the paper covers it (see :func:`splitspec_core.synthesis.approximate.check_full`).
    The full matrices hold the directions no agent sees too: they are judged against the envelope's rate."""
    sc = des.scenario
    rate = des.envelope_rate
    scope = (f"each graph held constant; the split is approximate (residual {des.split_residual:.2g}), "
             "so no switching certificate applies") if len(des.cases) > 1 else \
        f"the split is approximate (residual {des.split_residual:.2g})"
    by = "full error matrix"
    if des.time == "discrete":
        worst = max(des.full_radius.values())
        ok = certifies(worst, rate)
        return RateCertificate(ok, f"q = {des.q}: spectral radius of the full error matrix "
                                   f"{comparison(worst, rate, limit_text=f'rate {rate:g}')}"
                                   f"{_where(des, des.full_radius, ok)} ({scope})", by=by)
    ode = max(v["ode"] for v in des.full_radius.values())
    smp = min(v["sampled"] for v in des.full_radius.values())
    ok = certifies(ode, -rate) and (certifies(-smp, -rate) or not sampled)
    text = (f"g = {des.g:g}: spectral abscissa of the full error matrix {comparison(ode, -rate)}"
            f"{_where(des, {k: v['ode'] for k, v in des.full_radius.items()}, ok)}")
    if sampled:
        text += f", its sampled-data form with run.dt = {sc.run.dt:g} decays at {smp:.4g}"
    return RateCertificate(ok, f"{text} ({scope})", by=by)


def _where(des: Design, values: dict, ok: bool) -> str:
    """Which case a verdict's worst value is about, when there is more than one: `` on ring without agent 1 (the
    worst of 5 cases; a loss design.resilience: 1 asks to survive; without losses, ring: 0.8859)``; the graphs themselves are named when the worst is a loss case
    (``design.resilience: 1``), so a report never leaves the reader to guess which network a bound is about."""
    if len(values) < 2:
        return ""
    label = max(values, key=values.get)
    nominal = {g.name for g in des.graphs}
    text = f" on {label} (the worst of {len(values)} cases"
    if label not in nominal:
        own = ", ".join(f"{k}: {v:.4g}" for k, v in values.items() if k in nominal)
        text += f"; a loss design.resilience: 1 asks to survive; without losses, {own}" if own else ""
    return text + ")"


def _whole_survivors(des: Design, alive: tuple, arcs: dict) -> tuple:
    """``(certified, text, by)`` of the whole-state design on what is left: every survivor keeps its gain; the full
    error matrix of each graph the switching uses, restricted to the survivors and the arcs still up, held constant
    (:data:`MAX_RATE_DIM`), or the mixing bound of them all (doubly stochastic weights, any size)."""
    sc = des.scenario
    lam = des.whole.lam_step
    ad = {a.id: a for a in des.agents}
    Cs = dict(zip(sc.agent_ids, sc.system.Cs))
    Fs, _ = step_blocks(sc.system.A, [ad[i].K for i in alive], [Cs[i] for i in alive],
                        dt=sc.run.dt if sc.time == "continuous" else None)
    Ss = [build_graph(name, alive, arcs[name], weights=sc.design.weights, check=False).S for name in arcs]
    per = "per event time" if sc.time == "discrete" else "per step"
    if len(alive) * sc.n <= MAX_RATE_DIM and (len(Ss) == 1 or des.q_result.method != "mixing bound"):
        worst = max(spectral_radius(whole_matrix(Fs, S, des.q)) for S in Ss)
        ok = certifies(worst, lam)
        held = " (per graph held constant)" if len(Ss) > 1 else ""
        return ok, (f"q = {des.q}, the gains kept: spectral radius of the survivors' full error matrix "
                    f"{comparison(worst, lam, digits=6)} {per}{held}; whole-state consensus"), "full error matrix"
    bound = mixing_bound(Fs, Ss, des.q, lam)
    ok = certifies(bound, lam)
    return ok, (f"q = {des.q}, the gains kept: mixing bound of the survivors {comparison(bound, lam, digits=6)} "
                f"{per}; whole-state consensus"), "mixing bound"


def survivors_certificate(des: Design, alive: tuple, arcs: dict, network, *, excluded: bool) -> RateCertificate:
    """The design's own certificate recomputed on what is left after losses (no bisection, no search: cheap enough
    for every event of a run).

    ``alive``: the surviving agents; ``arcs``: per graph the switching uses, its arcs still up; ``network``: their
    :func:`~splitspec_core.synthesis.resilience.network_verdict`; ``excluded``: what they leave unobserved is no more
    than ``design.undetectable: exclude`` set aside.  Nothing without strong connectivity and detectability;
    else ``q`` with the design's q method (rho(Atil B^q) < lam for ``spectral``, eq. split_discrete_rho), ``g``
    against eq. (g) or, failing that, the exact spectrum of A_V(g) (eq. split_continuous_split) per graph held
    constant, on the survivors' graphs on the quotient by ``W_S``; a continuous g must also make the sampled-data
    form with ``run.dt`` decay at the rate (as :func:`rate_certificate`).  ``certified`` is None for the
    adaptive gain; ``rate`` the survivors' envelope rate when certified.

    Parameters
    ----------
    des : Design
        The design the run uses.
    alive : tuple of int
        The surviving agents.
    arcs : dict
        ``{graph name: arcs (j, i) still up}`` for each graph the switching uses.
    network : LossReport
        :func:`~splitspec_core.synthesis.resilience.network_verdict` of ``alive`` on ``arcs``.
    excluded : bool
        What the survivors leave unobserved is no more than the design excluded.

    Returns
    -------
    RateCertificate
        ``certified`` (None for the adaptive gain), the one line, the envelope's rate and what certifies it (when
        certified).
    """
    sc = des.scenario
    un_S = network.unobserved
    rate = sc.design.rate
    by = None

    def survivor_cases() -> list:  # the certificate's case per graph, on the survivors' graphs modulo W_S
        return [des.survivor_case(name, build_graph(name, alive, arcs[name], weights=sc.design.weights), un_S)
                for name in arcs]

    if not (network.detectable or excluded) or not all(network.strongly_connected.values()):
        cert, text = False, "no rate: " + ("the survivors leave a mode unobserved that does not decay"
                                            if not (network.detectable or excluded) else
                                            "a graph is not strongly connected")
    elif des.consensus == "fusion":  # the gains kept, the lost weights folded into the receivers' own
        from .fusion_kind import survivors_radius

        worst = survivors_radius(des, alive, arcs)
        lam = des.whole.lam_step
        cert, by = certifies(worst, lam), "full error matrix"
        text = (f"q = {des.q}, the gains kept, the lost neighbours' weights folded into each agent's own: spectral "
                f"radius of the survivors' full error map {comparison(worst, lam, digits=6)} per step; fusion")
    elif des.consensus == "relay":  # the gains kept: the base runs on the samples that still arrive in time
        from .relay import survivors_radius as relay_survivors

        worst = relay_survivors(des, alive, arcs)
        lam = des.whole.lam_step
        cert, by = certifies(worst, lam), "base error map"
        text = (f"q = {des.q}, the gains kept, the lost agents' samples (and those arriving later than the base "
                f"needs) left out: spectral radius of the base's error map {comparison(worst, lam, digits=6)} "
                f"per step; relay")
    elif des.consensus == "whole":  # the gains kept: the survivors' full error matrices (whole_state.py)
        cert, text, by = _whole_survivors(des, alive, arcs)
        un_S = network.unobserved if cert else un_S
    elif des.time == "discrete":
        cases = survivor_cases()
        res = bounds.choose_q(sc.design.q_method, cases, rate, q=des.q, q_max=sc.design.q_max,
                              eig=sc.design.eigenvalues)
        cert, text, by = bool(res.certified), q_text(des.q, res, rate, len(cases), held="per"), res.method
    elif des.g is None:
        cert, text = None, ADAPTIVE
    else:
        ad = {a.id: a for a in des.agents}
        cases = survivor_cases()
        gb = max(bounds.g_bound(c, rate) for c in cases)
        if certifies(gb, des.g):  # the one rule: eq. (g)'s bound below the g used
            cert, text, by = True, f"g = {des.g:g} > eq. (g) bound {gb:.4g} on the survivors' graphs", "eq:g"
        else:
            worst = max(bounds.abscissa(c, des.g) for c in cases)
            cert, by = certifies(worst, -rate), "spectrum"
            text = (f"g = {des.g:g} < eq. (g) bound {gb:.4g}; exact spectral abscissa {comparison(worst, -rate)} "
                    "(per graph held constant)")
        if cert:  # what runs is the sampled-data form (steps.py): it must decay at the rate too
            dt, sampled = sc.run.dt, min(sampled_rates(sc, [ad[i] for i in alive], cases, des.g).values())
            if not certifies(-sampled, -rate):
                cert = False
                text += f"; but {sampled_shortfall(dt, sampled, rate)}"
    envelope = rate
    if cert and un_S.dim and not excluded:
        envelope = un_S.envelope(rate)
        text += f"; {un_S.summary(rate)}"
    return RateCertificate(cert, text, envelope if cert else None, by if cert else None)
