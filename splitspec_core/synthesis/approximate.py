"""An approximate split (a weakly observable direction left to consensus): the rate on the full error matrices.

Prop. error (and errordis) split the spectrum exactly only when every V_i is an exact unobservable space; with
``split_residual`` above round-off the certificates' split blocks are an approximation, so the designer
(:mod:`.designer`) checks the rate on the full error matrix of every case held constant
(:func:`splitspec_core.synthesis.error_matrix.full_radius`) and raises an automatic q or g until it meets it: design
policy, so here and not with the matrices.
"""

from __future__ import annotations

import dataclasses
import re

from . import bounds
from .design_data import Design
from .error_matrix import MAX_RATE_DIM, full_radius
from .spectral import certifies, comparison

__all__ = ["check_full"]


def check_full(des: Design, warnings: list) -> Design:
    """An approximate split (a weakly observable direction left to consensus): the rate on the full error matrices.

    Prop. error (and errordis) split the spectrum exactly only when every V_i is an exact unobservable space;
    with ``split_residual`` above round-off the certificates' split blocks are an approximation, so the
    rate is checked on the full error matrix of every case held constant
    (:func:`splitspec_core.synthesis.error_matrix.full_radius`), and an automatic q or g raised until it meets it
    (:func:`_raise_to_full`): design policy, so here and not with the matrices.
    No switching certificate of the paper covers an approximate split.

    Parameters
    ----------
    des : Design
        A design whose ``split_residual`` is above round-off.
    warnings : list of str
        The design's warnings so far: appended to, and changed in place (a continuous design that misses on the
        ODE loses the sampled-data ``run.dt`` advice).

    Returns
    -------
    Design
        ``des`` with ``full_radius``, ``warnings`` and, where an automatic q or g was raised, the new q (and its
        ``q_result``) or g and ``error_radius``; unchanged but for the warning above ``MAX_RATE_DIM``.
    """
    sc = des.scenario
    worst = max([a.dec.weak for a in des.agents] + [des.split_residual])
    who = ", ".join(str(a.id) for a in des.agents if a.dec.weak > 0) or "every"
    note = (f"agent(s) {who} left a weakly observable direction (margin up to {worst:.2g}) to consensus: the split "
            f"of the error dynamics holds up to {des.split_residual:.2g}")
    if sc.m * sc.n > MAX_RATE_DIM:  # the certificate then says it covers the split blocks only (verdict.py)
        warnings.append(f"{note}; the full error matrices (m n = {sc.m * sc.n} > {MAX_RATE_DIM}) were not checked")
        return dataclasses.replace(des, warnings=tuple(warnings))
    full = full_radius(des, des.cases, q=des.q, g=des.g)
    warnings.append(f"{note}; the rate is checked on the full error matrix of each graph held constant")
    des = dataclasses.replace(des, full_radius=full, warnings=tuple(warnings))
    if not _full_meets(des, full):
        des = _raise_to_full(des, warnings)
    if not _full_meets(des, des.full_radius):
        if des.time == "continuous" and not certifies(max(v["ode"] for v in des.full_radius.values()), -des.envelope_rate):
            # sampled_rates.py's run.dt advice was computed on the split blocks: no run.dt helps when the ODE misses
            warnings[:] = [w for w in warnings if not re.match(r"(the sampled-data estimator is UNSTABLE with g|"
                                                              r"with run\.dt = \S+ the sampled-data estimator)", w)]
        weakest = min([a.dec.weak for a in des.agents if a.dec.weak > 0] or [des.split_residual])
        warnings.append(f"leaving agent(s) {who}'s weak directions to consensus misses the rate on the full error "
                        f"matrix even with more consensus: if the model is accurate to better than {weakest:.2g}, set "
                        f"design.rank_tol below that (e.g. {weakest / 10:.1g}) to count them (larger local gains)")
        des = dataclasses.replace(des, warnings=tuple(warnings))
    return des


def misses_on_full(des: Design) -> bool:
    """An approximate split whose full error matrices miss the rate (by the one rule, :func:`.spectral.certifies`):
    what it left to consensus is what fails, so a larger ``design.rank_tol`` (more left to consensus) is no remedy.

    Parameters
    ----------
    des : Design
        The design.

    Returns
    -------
    bool
        True when ``des.full_radius`` was computed and misses the rate; False for an exact split.
    """
    return bool(des.full_radius) and not _full_meets(des, des.full_radius)


def _full_meets(des: Design, full: dict) -> bool:
    rate = des.envelope_rate  # lam, or slower when directions no agent sees limit it (they are in the full matrix)
    if des.time == "discrete":
        return certifies(max(full.values()), rate)
    return (certifies(max(v["ode"] for v in full.values()), -rate)
            and certifies(-min(v["sampled"] for v in full.values()), -rate))


def _raise_to_full(des: Design, warnings: list) -> Design:
    """An automatic q or g that the full error matrices miss (an approximate split): raised until they meet the rate.

    The split's own certificate chose q (or g) on the split blocks; with the split only approximate the
    coupling it leaves can take the full matrix past the rate, and more consensus (a larger q, a larger g)
    is what brings it back.  Discrete: q + 1, q + 2, ... up to ``min(design.q_max, 4 q + 64)``; continuous:
    g grown by 25 % at a time (from the rate when the split's g is 0), up to 100 times the split's g, stopping
    early when four raises in a row do not improve the full matrix's abscissa (the weak directions then couple
    through the local gains, which no consensus undoes: 21 raises cost a minute at m n = 1600).  A q or g the
    user gave is left alone (the certificate then says it misses the rate).
    """
    sc = des.scenario
    d = sc.design
    if des.time == "discrete":
        if d.q != "auto":
            return des
        for q in range(des.q + 1, min(d.q_max, 4 * des.q + 64) + 1):
            full = full_radius(des, des.cases, q=q)
            if _full_meets(des, full):
                result = bounds.choose_q(d.q_method, des.cases, d.rate, q=q, q_max=d.q_max)
                warnings.append(f"q raised from {des.q} to {q}: with the approximate split, q = {des.q} leaves the full "
                                f"error matrix's spectral radius {comparison(max(des.full_radius.values()), d.rate, limit_text=f'rate {d.rate:g}')}")
                return dataclasses.replace(des, q=q, q_result=result, full_radius=full, warnings=tuple(warnings),
                                           error_radius={c.label: bounds.error_radius(c, q) for c in des.cases})
        return des
    if d.g != "auto":
        return des
    g = des.g if des.g > 0 else d.rate / 1.25
    best, stale = max(v["ode"] for v in des.full_radius.values()), 0
    for _ in range(21):
        g *= 1.25
        full = full_radius(des, des.cases, g=bounds.nice_ceil(g))
        ode = max(v["ode"] for v in full.values())
        best, stale = (ode, 0) if ode < best - 1e-9 * max(1.0, abs(best)) else (best, stale + 1)
        if stale == 4:
            break
        if _full_meets(des, full):
            g = bounds.nice_ceil(g)
            worst = max(v["ode"] for v in des.full_radius.values())
            warnings.append(f"g raised from {des.g:g} to {g:g}: with the approximate split, g = {des.g:g} leaves the full "
                            f"error matrix's spectral abscissa at {worst:.4g} > -{d.rate:g}")
            return dataclasses.replace(des, g=g, full_radius=full, warnings=tuple(warnings),
                                       error_radius={c.label: bounds.abscissa(c, g) for c in des.cases})
    return des
