"""The sampled-data form of the continuous-time estimator: how fast its error decays, and the g it can take.

``simulate`` and ``run`` integrate eq. (split_continuous_observer) with one
exchange per ``run.dt`` (:mod:`splitspec_core.model.steps`); a g certified for the
ODE (eq. g, thm. arb, eq. split_continuous_g) can still leave this
discrete-time error map slow or unstable when ``dt`` is large against g or
``|K_i C_i|``.  Both the design and the runtime verdict on survivors check it.
"""

from __future__ import annotations

import math

import numpy as np
import scipy.linalg as sla

from . import bounds
from ..errors import DesignError
from ..scenarios.specs import Scenario
from ..scenarios.sampling import sampled_data_matrices
from .spectral import certifies

__all__ = ["sampled_rates", "sampled_g", "exact_g"]


def sampled_rates(sc: Scenario, agents, cases, g: float, *, dt: float | None = None) -> dict:
    """Decay rate of the sampled-data estimator (run.dt, or ``dt``) per case, over ``agents`` (the ones in the cases).

    Observable parts: ``Q_i (E + D K_i C_i) Q_i'``; unobservable part:
    :func:`bounds.sampled_decay`.  Both are exact for the discretisation used
    by ``simulate`` and ``run`` (see :mod:`splitspec_core.model.steps`).

    Parameters
    ----------
    sc : Scenario
        The continuous-time scenario.
    agents : sequence of AgentDesign
        The agents' designs (their ``dec``, ``gain`` and working ``scale``).
    cases : iterable of bounds.Case
        The cases to check.
    g : float
        The consensus gain.
    dt : float, optional
        The sampling period (default ``run.dt``).

    Returns
    -------
    dict
        ``{case label: decay rate}`` (1/time): the slowest of the observable parts and the case's unobservable
        part; negative when the sampled-data form is unstable.

    Examples
    --------
    >>> import splitspec_core as ss
    >>> from splitspec_core.synthesis.designer import design
    >>> des = design(ss.load_scenario("examples/paper_continuous.yaml"))
    >>> des.g, des.rate, round(sampled_rates(des.scenario, des.agents, des.cases, des.g)["a"], 3)
    (10.0, 1.0, 1.681)
    >>> round(sampled_rates(des.scenario, des.agents, des.cases, des.g, dt=1.0)["a"], 3)  # run.dt far too large
    -2.134
    """
    dt = sc.run.dt if dt is None else dt
    # in the design's working coordinates (the agents' scale: design.coordinates), where Q_i, K_i and V_i live
    scale = agents[0].scale if agents else None
    A = np.asarray(sc.system.A, dtype=float)
    A = A if scale is None else A * scale[None, :] / scale[:, None]
    E, D, _ = sampled_data_matrices(A, dt)
    Cs = {i: (np.asarray(C) if scale is None else np.asarray(C) * scale[None, :]) for i, C in
          zip(sc.agent_ids, sc.system.Cs)}
    obs = math.inf
    for a in agents:
        if a.dec.n_observable:
            Q = a.dec.Q
            rho = bounds.spectral_radius(Q @ (E + D @ a.gain.K @ Cs[a.id]) @ Q.T)
            obs = min(obs, -math.log(rho) / dt if rho > 0 else math.inf)
    out = {}
    for c in cases:
        Vs = c.V_blocks  # the case's V_i (after a loss, V_i minus what the survivors leave unobserved)
        Et = sla.block_diag(*[V.T @ E @ V for V in Vs]) if c.nbar else np.zeros((0, 0))
        Dt = sla.block_diag(*[V.T @ D @ V for V in Vs]) if c.nbar else np.zeros((0, 0))
        out[c.label] = min(obs, bounds.sampled_decay(c, g, Et, Dt, dt))
    return out


def exact_g(cases, rate: float, margin: float, g_mins: dict) -> float | None:
    """The smallest two-digit g whose exact spectrum beats the rate by ``design.margin`` on every case (abscissa of
    A_V(g) below ``-(1 + margin) lam``, eq. split_continuous_split, each graph held constant; the margin, as the
    local gains', keeps the decay clear of the rate: a g at the rate's edge leaves a transient that takes the sampled
    form millions of steps to outlive), or at least the rate when no g gives that margin; None when none does.

    Parameters
    ----------
    cases : iterable of bounds.Case
        The cases (graphs held constant).
    rate : float
        ``lam``.
    margin : float
        ``design.margin``.
    g_mins : dict
        ``{case label: g_min}``, the bisection's start per case.

    Returns
    -------
    float or None
        A :func:`~splitspec_core.synthesis.bounds.nice_ceil` value of g.
    """
    for target in ((1.0 + margin) * rate, rate):
        try:
            need = max(bounds.g_min(c, target, g_hi=max(g_mins[c.label], 1e-9)) for c in cases)
        except DesignError:  # no g up to the bisection's limit reaches this target: try the next
            continue
        g = bounds.nice_ceil(need * (1 + 1e-9))
        for _ in range(40):
            if all(certifies(bounds.abscissa(c, g), -target) for c in cases):
                return g
            g = bounds.nice_ceil(g * 1.25)
    return None


def sampled_g(sc: Scenario, agents, cases, kw: dict, switching: bool, warnings: list) -> dict:
    """The sampled-data form at ``run.dt`` (what ``simulate`` and ``run`` integrate): its decay per case; an automatic g
    for a constant graph whose eq. (g) value leaves it short of the rate is replaced by the exact spectrum's (eq.
    (g) is sufficient, and on stiff models far above what the rate needs: 11000 against an exact 137 on a power
    system, and g dt >> 1 is unstable); still short, the warning says which run.dt would meet it.

    Parameters
    ----------
    sc : Scenario
        The continuous-time scenario.
    agents : sequence of AgentDesign
        The agents' designs.
    cases : iterable of bounds.Case
        The cases the design covers.
    kw : dict
        The g design's fields so far (``g``, ``g_mins``, ``g_certified_by``, ``error_radius``, ...).
    switching : bool
        The scenario switches graphs (then g is never replaced).
    warnings : list of str
        Appended to (the replaced g; a sampled-data form that misses the rate).

    Returns
    -------
    dict
        ``kw`` with ``sampled_rate`` (``{case label: decay rate}``) and, when g was replaced, the new ``g``,
        ``g_certified_by`` and ``error_radius``.
    """
    d = sc.design
    g = kw["g"]
    out = sampled_rates(sc, agents, cases, g)
    if min(out.values()) < d.rate and d.g == "auto" and not switching:
        alt = exact_g(cases, d.rate, d.margin, kw["g_mins"])
        if alt is not None and alt < g:
            alt_out = sampled_rates(sc, agents, cases, alt)
            if min(alt_out.values()) > min(out.values()):
                warnings.append(f"g = {alt:g}, certified by the exact spectrum (the constant graph): eq. (g)'s g = {g:g} "
                                f"leaves the sampled-data form with run.dt = {sc.run.dt:g} decaying at only "
                                f"{min(out.values()):.4g} < rate {d.rate:g}")
                g, out = alt, alt_out
                kw = dict(kw, g=g, g_certified_by="spectrum (exact, constant graph)",
                          error_radius={c.label: bounds.abscissa(c, g) for c in cases})
    _sampled_warn(sc, agents, cases, g, out, warnings)
    return dict(kw, sampled_rate=out)


def _sampled_warn(sc: Scenario, agents, cases, g: float, out: dict, warnings: list) -> None:
    """Warn when the sampled-data form misses the rate, with the largest run.dt (halving, at most 2^-20 of it) that
    would meet it."""
    dt = sc.run.dt
    worst = min(out.values())
    if certifies(-worst, -sc.design.rate):  # the one rule on the decay rate
        return
    need = None
    for k in range(1, 21):
        if certifies(-min(sampled_rates(sc, agents, cases, g, dt=dt / 2 ** k).values()), -sc.design.rate):
            need = dt / 2 ** k
            break
    fix = (f"reduce run.dt (run.dt <= {need:.3g} meets it)" if need is not None
           else "reduce run.dt or g (no run.dt down to 2^-20 of it meets it)")
    if worst <= 0:
        warnings.append(f"the sampled-data estimator is UNSTABLE with g = {g:g} and run.dt = {dt:g} "
                        f"(dt too large against g or the fastest local poles |K_i C_i|): {fix}")
    else:
        warnings.append(f"with run.dt = {dt:g} the sampled-data estimator decays at {worst:.4g} < rate "
                        f"{sc.design.rate:g} (first order in dt against g and |K_i C_i|): {fix}")
