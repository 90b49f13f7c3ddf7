"""Estimation quality under noise: the exact steady-state error covariance of a design, and tuning.

The split-spectrum estimators are linear, so with a constant graph the stacked error follows
``e(k+1) = M e(k) + noise``; its steady-state covariance solves a discrete Lyapunov equation
(:func:`splitspec_core.synthesis.error_matrix.error_dynamics` and :func:`~splitspec_core.synthesis.error_matrix.predicted_rms`):
no simulation, no sampling error, what a long simulation's RMS converges to (tested).

:func:`tune` searches q (discrete) or g (continuous) and the gain design
(``place``, or ``riccati`` over a range of process/measurement weight ratios)
for the smallest predicted RMS among the candidates whose rate is still
certified by the design's own certificate.  It never returns a design predicted worse than the scenario's own
certified one: when no candidate beats it (a whole-state design under uneven noise often beats every split), the
scenario's own design is the result (``kept``) and the best candidate turned down is in ``best``.  The weights and
g it tries are rounded to 6 significant digits before they are designed, so the numbers a tuned scenario file
holds are the numbers certified.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Mapping

import numpy as np

from .design_data import Design
from .designer import design
from ..errors import DesignError
from .error_matrix import predicted_rms
from .verdict import rate_certificate
from ..scenarios.specs import Scenario

__all__ = ["DIGITS", "TuneResult", "tune", "tune_lines"]


@dataclasses.dataclass(frozen=True)
class TuneResult:
    """The chosen design and every candidate tried.

    ``candidates``: list of dicts ``{gains, process_weight, measurement_weight, q or g, certified, rms}``
    (``rms``: root mean square over agents of the predicted steady-state RMS).  ``kept``: no certified candidate is
    predicted better than the scenario's own certified design, which is then ``scenario``, ``design`` and ``rms``;
    ``best``: the certified candidate of smallest RMS (one of ``candidates``; None when none is certified).
    """

    scenario: Scenario
    design: Design
    rms: float
    baseline_rms: float
    candidates: list
    kept: bool = False
    best: Mapping | None = None


#: significant digits of the weights and g :func:`tune` tries (and a tuned scenario file holds)
DIGITS = 6


def _rounded(x: float) -> float:
    """``x`` to :data:`DIGITS` significant digits: the number a YAML file holds and a report prints."""
    return float(f"{x:.{DIGITS}g}")


def _rms_all(des: Design) -> float:
    r = predicted_rms(des)
    return float(np.sqrt(np.mean(r ** 2)))


def tune(sc: Scenario, *, extra: int = 6, ratios=(1e-2, 1e-1, 1.0, 1e1, 1e2)) -> TuneResult:
    """Smallest predicted steady-state RMS subject to the rate (certified as the design certifies it).

    Candidates: gains ``place`` and ``riccati`` with process/measurement weights
    ``(r * sigma_p^2, sigma_m^2)`` for each ratio ``r`` (the Kalman choice is
    ``r = 1``; ``sigma_p``, ``sigma_m`` the noise levels of
    :func:`splitspec_core.model.local_design.noise_weights`); discrete: ``q`` from the certified one to ``q + extra``;
    continuous: ``g`` from the certified one to ``3 g`` (6 values).  The
    baseline is the scenario's own design: when it is certified and no certified candidate is predicted better
    (by more than 1e-9 relative), it is kept.  The covariance is that of the
    first graph held constant (a switching scenario is tuned for it).

    Parameters
    ----------
    sc : Scenario
        A scenario with process or measurement noise (the split consensus is tuned).
    extra : int
        Discrete time: how many q above each gain design's certified q are tried.
    ratios : iterable of float
        The process/measurement weight ratios ``r`` of the ``riccati`` candidates.

    Returns
    -------
    TuneResult
        The certified candidate of smallest RMS (its scenario and design, and that RMS), or the scenario's own
        design when that is certified and no worse (``kept``); the baseline's RMS, the best candidate (``best``) and
        every candidate tried (a candidate whose design fails is left out).

    Raises
    ------
    DesignError
        The scenario has no noise, its g is adaptive, or neither a candidate nor the scenario's own design meets the
        rate.

    Examples
    --------
    >>> import splitspec_core as ss
    >>> sc = ss.scenario(A=[[0, 1, 0, 0], [-1, 0, 0, 0], [0, 0, 0, 1], [0, 0, -2, 0]],
    ...                  C={1: [[1, 0, 0, 0]], 2: [[0, 1, 0, 0]], 3: [[0, 0, 1, 0]]},
    ...                  graphs={"a": [(1, 2), (2, 1), (2, 3), (3, 2), (1, 3)]}, rate=0.5, gains="place",
    ...                  process_noise=0.01, measurement_noise=0.1)
    >>> r = tune(sc, extra=2, ratios=(1.0,))
    >>> len(r.candidates), r.scenario.design.gains, r.rms < r.baseline_rms, r.kept
    (6, 'riccati', True, False)
    """
    s = sc.system
    if not s.has_noise:
        raise DesignError("tuning for noise needs system.process_noise or system.measurement_noise > 0")
    if sc.time == "continuous" and sc.design.g == "adaptive":
        raise DesignError("the adaptive gain cannot be tuned for noise (it has no steady state); give g")
    base = design(sc)
    baseline = _rms_all(base)
    p_level, m_level = s.process_noise_level, s.measurement_noise_level  # one number each (noise_weights)
    pw0 = p_level ** 2 if p_level > 0 else 1e-6
    mw0 = m_level ** 2 if m_level > 0 else 1e-6
    gain_options = [("place", None, None)] + [("riccati", _rounded(r * pw0), _rounded(mw0)) for r in ratios]
    cands = []
    best = None
    for gains, pw, mw in gain_options:
        d = dataclasses.replace(sc.design, gains=gains, K=None, consensus="split", q="auto" if sc.time == "discrete" else sc.design.q,
                                process_weight=pw, measurement_weight=mw)
        try:
            des0 = design(dataclasses.replace(sc, design=d))
        except DesignError:
            continue
        if sc.time == "discrete":
            values = [des0.q + k for k in range(extra + 1)]
        else:
            g0 = des0.g if des0.g is not None else 1.0
            values = [_rounded(g0 * f) for f in (1.0, 1.25, 1.5, 2.0, 2.5, 3.0)]
        for v in values:
            dv = dataclasses.replace(d, **({"q": int(v)} if sc.time == "discrete" else {"g": float(v)}))
            try:
                des = design(dataclasses.replace(sc, design=dv))
            except DesignError:
                continue
            certified = rate_certificate(des).certified  # as every command reports it (sampled-data form included)
            rms = _rms_all(des)
            cands.append({"gains": gains, "process_weight": pw, "measurement_weight": mw,
                          ("q" if sc.time == "discrete" else "g"): v, "certified": bool(certified), "rms": rms})
            if certified and math.isfinite(rms) and (best is None or rms < best[0] - 1e-12):
                best = (rms, des, cands[-1])
    own_certified = rate_certificate(base).certified and math.isfinite(baseline)
    if own_certified and (best is None or baseline <= best[0] * (1 + 1e-9)):  # never worse than the scenario's own
        return TuneResult(scenario=sc, design=base, rms=baseline, baseline_rms=baseline, candidates=cands, kept=True,
                          best=None if best is None else best[2])
    if best is None:
        raise DesignError("no candidate design meets the rate")
    return TuneResult(scenario=best[1].scenario, design=best[1], rms=best[0], baseline_rms=baseline, candidates=cands,
                      best=best[2])


def _what(des: Design) -> str:
    """A design in a few words: its gains (and weights), consensus and q or g (6 significant digits)."""
    cd = des.scenario.design
    w = "" if cd.process_weight is None else (f" (process_weight {cd.process_weight:.{DIGITS}g}, measurement_weight "
                                              f"{cd.measurement_weight:.{DIGITS}g})")
    qg = f"q = {des.q}" if des.q is not None else "" if des.g is None else f"g = {des.g:.{DIGITS}g}"
    consensus = "whole state" if des.consensus == "whole" else des.consensus
    return f"gains {cd.gains}{w}, {consensus}" + (f", {qg}" if qg else "")


def tune_lines(res: TuneResult) -> list:
    """What :func:`tune` chose, in the words of ``splitspec design --tune rms``.

    Parameters
    ----------
    res : TuneResult
        A :func:`tune` result.

    Returns
    -------
    list of str
        The design chosen and its predicted RMS against the scenario's own; when the scenario's own design was kept,
        one line saying so with the best candidate turned down and how much worse it is predicted.
    """
    n = len(res.candidates)
    if not res.kept:
        return [f"tuned for noise: {_what(res.design)}",
                f"  predicted steady-state RMS error {res.rms:.4g} (the scenario's design: {res.baseline_rms:.4g}; "
                f"{n} candidates tried, the rate certified for the chosen one)"]
    if res.best is None:
        turned = f"no candidate of the {n} tried is certified at the rate"
    else:
        b = res.best
        qg = f"q = {b['q']}" if "q" in b else f"g = {b['g']:.{DIGITS}g}"
        turned = (f"the best certified of {n} candidates (split, gains {b['gains']}, {qg}) is predicted "
                  f"{b['rms']:.4g}, {b['rms'] / res.rms:.3g}x worse")
    return [f"tuned for noise: kept the scenario's own design ({_what(res.design)}; predicted steady-state RMS error "
            f"{res.rms:.4g}): {turned}"]
