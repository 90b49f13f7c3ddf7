"""``splitspec compare --sweep-rate``: what each rate asked costs in noise.

For each rate of the sweep (the scenario's ``design.rate`` replaced by it, every other key kept): the steady RMS
error each estimator would have, predicted where it can be (the Lyapunov equation of the full error system,
:func:`~splitspec_core.synthesis.error_matrix.predicted_rms`; the centralized predictors' own), measured for the KCF,
which certifies nothing and has no prediction:

``whole state``          the whole-state design (``design.consensus: whole``, gains ``optimal``: the noise chooses
                         them under the rate's certificate, :mod:`splitspec_core.synthesis.whole_state`);
``split``                the paper's split (gains ``riccati``, the scenario's noise levels as weights);
``centralized KF``       the Kalman filter: the same at every rate (it certifies its own radius, not the rate);
``centralized at rate``  the centralized Kalman filter designed for A/rate (a rate-shifted Riccati design, certified at
                         the rate, not the optimum under it: :func:`~splitspec_core.synthesis.kalman.references`);
``KCF``                  the Kalman-consensus filter with as many exchanges as the whole-state design at that rate,
                         its steady RMS measured on ``seeds`` runs, over each run's last half.

A design that is refused or whose rate is not certified at a level is kept with its verdict (``certified`` False,
``error`` its one line): the sweep shows where each estimator stops.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from ..errors import DesignError, ScenarioError, SplitspecError
from ..scenarios.specs import Scenario
from ..synthesis.designer import design
from ..synthesis.error_matrix import MAX_NOISE_DIM, predicted_rms
from ..synthesis.kalman import references
from ..synthesis.verdict import rate_certificate
from .baselines import baseline_seeds

__all__ = ["rate_sweep", "rate_sweep_table", "check_rates", "MAX_RATES"]

#: at most this many rates in one sweep (each costs two designs and a KCF Monte Carlo)
MAX_RATES = 30


def check_rates(sc: Scenario, rates) -> list:
    """The rates of a sweep, checked as ``design.rate`` is (one line each): continuous ``> 0``, discrete in
    ``(0, 1)``; at most :data:`MAX_RATES`.

    Parameters
    ----------
    sc : Scenario
        Its ``time`` decides the range.
    rates : iterable
        The rates asked (anything ``float`` takes).

    Returns
    -------
    list of float
        The rates, in order.

    Raises
    ------
    ScenarioError
        No rate, more than :data:`MAX_RATES`, or one out of range (the message names it).
    """
    rates = [float(r) for r in rates]
    if not rates:
        raise ScenarioError("--sweep-rate needs at least one rate")
    if len(rates) > MAX_RATES:
        raise ScenarioError(f"--sweep-rate takes at most {MAX_RATES} rates, got {len(rates)}")
    for r in rates:
        if not math.isfinite(r) or (sc.time == "continuous" and not r > 0) or (sc.time == "discrete"
                                                                              and not 0 < r < 1):
            want = f"> 0 ({sc.system.per_time})" if sc.time == "continuous" else "in (0, 1) (per event time)"
            raise ScenarioError(f"--sweep-rate {r:g}: a rate of this {sc.time}-time scenario must be {want}")
    return rates


def _at(sc: Scenario, rate: float, **design_keys) -> Scenario:
    return dataclasses.replace(sc, design=dataclasses.replace(sc.design, rate=rate, **design_keys))


def _row(sc: Scenario, **keys) -> dict:
    """One design of the sweep: ``{certified, rms, q, g, error}``."""
    try:
        des = design(_at(sc, **keys))
    except SplitspecError as exc:
        return {"certified": False, "rms": None, "q": None, "g": None, "error": str(exc)}
    rms = None
    if not des.adaptive and sc.m * sc.n <= MAX_NOISE_DIM:
        rms = float(np.sqrt(np.mean(predicted_rms(des) ** 2)))
    return {"certified": bool(rate_certificate(des).certified), "rms": rms, "q": des.q, "g": des.g, "error": None}


def rate_sweep(sc: Scenario, rates, *, seeds=(0, 1), steps: int | None = None) -> dict:
    """Steady RMS against the rate asked (module docstring): ``{"scenario", "time", "per_time", "rates", "rows":
    [...]}`` (``per_time``: the continuous rate's unit, ``system.time_unit``), a row
    per rate with ``whole``, ``split`` (each :func:`_row`), ``kalman``, ``reference`` (predicted, None where none
    exists) and ``kcf`` (measured: mean over ``seeds`` of the steady RMS over each run's last half).

    Parameters
    ----------
    sc : Scenario
        A scenario with noise; every design key but the rate (and the gains and consensus of the two rows) is kept.
    rates : iterable of float
        The rates (:func:`check_rates`).
    seeds : iterable of int
        The KCF's Monte Carlo seeds.
    steps : int, optional
        The KCF runs' steps (default ``run.steps``).

    Returns
    -------
    dict
        ``scenario``, ``time``, ``rates``, ``seeds`` and ``rows``: per rate ``rate``, ``whole``, ``split``
        (``{certified, rms, q, g, error}``), ``kalman``, ``reference``, ``kcf`` and ``kcf_exchanges``.

    Raises
    ------
    DesignError
        The scenario has no noise.
    ScenarioError
        A rate out of range (:func:`check_rates`).

    Examples
    --------
    >>> import splitspec_core as ss
    >>> sc = ss.scenario(A=[[0.9, 0.2], [0, 0.8]], C={1: [[1, 0]], 2: [[0, 1]]}, graphs={"a": [(1, 2), (2, 1)]},
    ...                  rate=0.5, process_noise=0.1, measurement_noise=0.1)
    >>> res = rate_sweep(sc, [0.5, 0.3], seeds=(0,), steps=100)
    >>> [(r["rate"], r["whole"]["certified"], r["split"]["certified"], round(r["kalman"], 3)) for r in res["rows"]]
    [(0.5, True, True, 0.17), (0.3, True, True, 0.17)]
    """
    if not sc.system.has_noise:
        raise DesignError("--sweep-rate needs noise: set system.process_noise and/or system.measurement_noise")
    rates = check_rates(sc, rates)
    rows = []
    for rate in rates:
        whole = _row(sc, rate=rate, gains="optimal", consensus="whole", K=None)
        split = _row(sc, rate=rate, gains="riccati", consensus="split", K=None)
        kf, ref = references(_at(sc, rate), rate)
        exchanges = whole["q"] if whole["q"] is not None else (split["q"] or 1)
        runs = baseline_seeds(_at(sc, rate), seeds, exchanges=int(exchanges), steps=steps)
        start = runs["kcf"].sq_error.shape[1] // 2  # the KCF certifies nothing: its run's last half
        kcf = float(np.mean(runs["kcf"].steady_rms(start=start)))
        rows.append({"rate": rate, "whole": whole, "split": split, "kalman": None if kf is None else kf.rms,
                     "reference": None if ref is None else ref.rms, "kcf": kcf, "kcf_exchanges": int(exchanges)})
    return {"scenario": sc.name, "time": sc.time, "per_time": sc.system.per_time, "rates": rates, "seeds": list(seeds), "rows": rows}


def rate_sweep_table(res: dict) -> list:
    """The sweep as text lines: per rate, each estimator's steady RMS (``*``: the rate certified).

    Parameters
    ----------
    res : dict
        A :func:`rate_sweep` result.

    Returns
    -------
    list of str
        A heading, the column names, one line per rate.
    """

    def cell(row: dict) -> str:
        if row["rms"] is None:
            return f"{'refused' if row['error'] else '-':>12}"
        return f"{row['rms']:11.4g}{'*' if row['certified'] else ' '}"

    per = res.get("per_time", "per second") if res["time"] == "continuous" else "per event time"
    lines = [f"steady RMS against the rate asked ({per}; * rate certified; KCF measured, the rest predicted):",
             f"  {'rate':>8} {'whole state':>12} {'split':>12} {'central KF':>11} {'KF for A/rate':>13} "
             f"{'KCF':>10} {'q':>4}"]
    for r in res["rows"]:
        q = r["whole"]["q"] if r["whole"]["q"] is not None else "-"
        kf = "-" if r["kalman"] is None else f"{r['kalman']:.4g}"
        ref = "-" if r["reference"] is None else f"{r['reference']:.4g}"
        lines.append(f"  {r['rate']:>8g} {cell(r['whole'])} {cell(r['split'])} {kf:>11} {ref:>13} "
                     f"{r['kcf']:10.4g} {q:>4}")
    return lines
