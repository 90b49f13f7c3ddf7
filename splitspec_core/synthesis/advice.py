"""Advice that was tried: the knobs a report would name, each designed on the scenario and measured.

A warning about a split design (observability margins, large local gains, a large transient, a steady error far
above the centralized Kalman filter's) used to end with knobs to turn; on real models some of them did not help
when followed (a smaller ``design.rank_tol`` or a slower rate changed nothing; only a smaller ``design.margin``
did).  Here each candidate knob is designed on the scenario and what it gives is said beside it: the rate's
verdict, the transient constant, the predicted steady RMS.  The knobs, each changed alone:

* ``design.gains: optimal`` with ``design.consensus: whole`` (when the scenario has noise): the whole-state design
  (:mod:`.whole_state`), which needs no local observer and so no margin;
* ``design.margin: 0.1`` (when it is larger): the local gains move the slow modes less far;
* ``design.rank_tol`` above the largest warned margin: the weak directions left to consensus; or, when what was
  already left to consensus misses the rate (:func:`.approximate.misses_on_full`), below the weakest one's margin
  (the approximate split's warning): those directions counted;
* a slower ``design.rate``, only ever one this module certified: for a design whose rate is not certified, the fastest
  rate the same keys certify (:func:`~splitspec_core.synthesis.designer.highest_rate`, shown rounded toward slower,
  or exactly as certified when the rounded one is not); else four fifths of it (discrete: ``lam^0.8``).  A rate
  knob whose design is not certified is not proposed: its line says no rate was certified.

Only up to ``m n`` = :data:`ADVICE_DIM` (each knob is a design and its conditioning: seconds each), and never
more than what was computed: a knob whose design is refused says so in its one line.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from ..errors import SplitspecError
from ..scenarios import gain_methods
from .conditioning import MARGIN_WARN, TRANSIENT_WARN, conditioning
from .design_data import Design, cached_analysis
from .approximate import misses_on_full
from .designer import RateReach, design, highest_rate
from .error_matrix import MAX_NOISE_DIM, predicted_rms
from .verdict import rate_certificate

__all__ = ["Tried", "advice", "advice_lines", "fastest_rate", "ADVICE_DIM", "NOISE_WARN"]

#: advice is tried up to this m n
ADVICE_DIM = 400
#: a predicted steady RMS above this many times the centralized Kalman filter's is a problem worth advice
NOISE_WARN = 2.0


@dataclass(frozen=True)
class Tried:
    """One knob, designed: ``knob`` as the scenario would say it, and what it gave (None where not computed)."""

    knob: str
    certified: bool | None = None
    transient: float | None = None
    rms: float | None = None
    error: str | None = None
    note: str | None = None  # a knob not proposed, and why (the rate knob when no slower rate was certified)


def _figures(des: Design) -> tuple:
    """``(certified, transient constant, predicted RMS over agents)`` of a design."""
    sc = des.scenario
    rms = None
    if sc.system.has_noise and not des.adaptive and sc.m * sc.n <= MAX_NOISE_DIM:
        rms = float(np.sqrt(np.mean(predicted_rms(des) ** 2)))
    return bool(rate_certificate(des).certified), conditioning(des).transient_constant, rms


def _problems(des: Design) -> bool:
    """The design has something advice is for: a split design with warned margins or gains, a transient above
    :data:`TRANSIENT_WARN`, or a steady error above :data:`NOISE_WARN` times the Kalman filter's."""
    if des.consensus in ("whole", "fusion", "relay") or des.adaptive:
        return False
    cond = conditioning(des)
    weak = any(a.observability_margin is not None and a.observability_margin < MARGIN_WARN for a in cond.agents)
    c = cond.transient_constant
    noisy = False
    if cond.predicted_rms and cond.kalman_rms:
        rms = math.sqrt(sum(v * v for v in cond.predicted_rms.values()) / len(cond.predicted_rms))
        noisy = rms > NOISE_WARN * cond.kalman_rms
    return weak or bool(cond.warnings) or (c is not None and c > TRANSIENT_WARN) or noisy


@cached_analysis
def advice(des: Design) -> tuple:
    """The knobs tried on ``des``'s scenario (module docstring), as :class:`Tried`; empty when there is nothing to
    advise or the design is larger than :data:`ADVICE_DIM`.

    Parameters
    ----------
    des : Design
        A design (computed once per design: each knob is a design of its own).

    Returns
    -------
    tuple of Tried
        One per knob that applies, in the module docstring's order; a refused design has ``error`` set.

    Examples
    --------
    >>> import splitspec_core as ss
    >>> des = design(ss.load_scenario("examples/platoon.yaml"))
    >>> [(t.knob, t.certified) for t in advice(des)]  # doctest: +NORMALIZE_WHITESPACE
    [('design.gains: optimal, design.consensus: whole', True), ('design.margin: 0.1', True),
     ('design.rate: 0.752', True)]
    """
    sc = des.scenario
    d = sc.design
    if sc.m * sc.n > ADVICE_DIM or not _problems(des):
        return ()
    knobs = []
    if sc.system.has_noise:
        knobs.append(("design.gains: optimal, design.consensus: whole", dict(gains="optimal", consensus="whole",
                                                                             K=None)))
    method = gain_methods.method(d.gains)
    if d.margin > 0.1 and method.margin:
        knobs.append(("design.margin: 0.1", dict(margin=0.1)))
    margins = [a.observability_margin for a in conditioning(des).agents
               if a.observability_margin is not None and a.observability_margin < MARGIN_WARN]
    if misses_on_full(des) and not method.needs_K:
        # what was left to consensus misses the rate: the knob is the warning's, design.rank_tol below the weakest
        # direction's margin (count it), never above (leave more to consensus)
        weakest = min([a.dec.weak for a in des.agents if a.dec.weak > 0] or [des.split_residual])
        tol = float(f"{weakest / 10:.1g}")
        if tol > 0:
            knobs.append((f"design.rank_tol: {tol:g}", dict(rank_tol=tol)))
    elif margins and not method.needs_K:
        tol = float(f"{10 * max(margins):.1g}")
        if tol < 1:
            knobs.append((f"design.rank_tol: {tol:g}", dict(rank_tol=tol)))
    out = []
    for text, keys in knobs:
        out.append(_tried(sc, text, keys))
    out.append(_rate_knob(des))
    return tuple(out)


def _tried(sc, text: str, keys: dict) -> Tried:
    """``keys`` designed on ``sc``: what it gave, or its refusal."""
    try:
        alt = design(dataclasses.replace(sc, design=dataclasses.replace(sc.design, **keys)))
    except SplitspecError as exc:
        return Tried(text, error=str(exc).split(";")[0])
    ok, c, rms = _figures(alt)
    return Tried(text, certified=ok, transient=c, rms=rms)


@cached_analysis
def fastest_rate(des: Design):
    """A design whose rate is not certified (the adaptive gain aside): the fastest rate its keys certify
    (:func:`~splitspec_core.synthesis.designer.highest_rate`, a bisection of a few designs), else None.

    Parameters
    ----------
    des : Design
        The design (computed once per design).

    Returns
    -------
    RateReach or None
        The bisection's certified and refused rates and its line; None when the rate is certified, for the adaptive
        gain, or when even a rate far slower is refused.
    """
    if des.adaptive or rate_certificate(des).certified:
        return None
    return highest_rate(des.scenario)


def _rate_knob(des: Design) -> Tried:
    """The slower rate (module docstring): always one that was designed and certified, or a line saying none was."""
    sc = des.scenario
    d = sc.design
    if rate_certificate(des).certified:
        slower = d.rate * 0.8 if sc.time == "continuous" else d.rate ** 0.8
        candidates = [float(f"{slower:.3g}")]
    else:
        reach: RateReach | None = fastest_rate(des)
        if reach is None:
            slow = d.rate / 100.0 if sc.time == "continuous" else 1.0 - (1.0 - d.rate) / 100.0
            return Tried("design.rate", note=f"no rate certified with these design keys, down to {slow:.4g}")
        candidates = [reach.shown, reach.rate] if reach.shown not in (None, reach.rate) else [reach.rate]
    for rate in candidates:
        t = _tried(sc, f"design.rate: {rate:.10g}", dict(rate=rate))
        if t.certified:
            return t
    return Tried("design.rate", note=f"no slower rate certified with these design keys (design.rate "
                                     f"{candidates[0]:g} is not), so none is proposed")


def advice_lines(des: Design) -> list:
    """The report's lines: what each knob gave against the design's own figures.

    Parameters
    ----------
    des : Design
        A design.

    Returns
    -------
    list of str
        A heading with the design's own figures, then one indented line per knob (:func:`advice`); empty when
        there is nothing to advise.
    """
    tried = advice(des)
    if not tried:
        return []
    ok, c, rms = _figures(des)

    def figs(t_ok, t_c, t_rms) -> str:
        parts = ["rate certified" if t_ok else "rate NOT certified"]
        if t_c is not None:
            parts.append(f"transient {'infinite' if math.isinf(t_c) else f'{t_c:.3g}'}")
        if t_rms is not None:
            parts.append(f"predicted RMS {t_rms:.4g}")
        return ", ".join(parts)

    lines = [f"advice (each knob designed on this scenario; this design: {figs(ok, c, rms)}):"]
    for t in tried:
        lines.append(f"  {t.knob}: " + (t.note if t.note else f"refused: {t.error}" if t.error else
                                        figs(t.certified, t.transient, t.rms)))
    return lines
