"""`splitspec compare`: the split-spectrum estimator against the best possible and a consensus Kalman filter.

Every estimator sees the same noise realisations and initial conditions (the
simulator's named streams, :mod:`splitspec_core.model.streams`) and the same measurements, as the scenario's
sensor faults change them (:func:`faults_note`):

``split (scenario)``   the scenario's own design (when its gains are explicit)
``split place``        split-spectrum, ``place`` gains
``split riccati``      split-spectrum, ``riccati`` gains (weights: the noise levels)
``split tuned``        split-spectrum, the noise-optimised design of :func:`noise.tune`
``centralized KF``     steady-state Kalman predictor seeing every measurement: the bound
                       no distributed estimator can beat
``KCF``                Olfati-Saber's discrete-time Kalman-consensus filter on the same
                       graph, with as many exchanges per event time as split place

Figures per estimator (:class:`EstimatorResult`, one row of the :class:`CompareResult` :func:`compare`
returns): steady-state RMS error (:func:`~splitspec_core.simulation.metrics.steady_rms`: over the last half
of the run, RMS over agents, then mean and std over seeds), its ratio to the centralized
filter, the predicted (exact) steady-state RMS where available (not for the adaptive
gain, which has no steady state), the noise-free time until the error stays
below 1e-3 of its initial value, messages per event time (one message = one
vector sent by one agent), and for the split-spectrum estimators the rate
certificate of :func:`~splitspec_core.synthesis.verdict.rate_certificate` (the adaptive
gain: asymptotic convergence only, no certified rate).

Every estimator runs its seeds as one batch, the same numbers per seed to
round-off: the split-spectrum variants by
:func:`splitspec_core.simulation.montecarlo.simulate_seeds`, the two baselines by
:func:`splitspec_core.studies.baselines.baseline_seeds`.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from types import MappingProxyType
from typing import Any, Mapping

import numpy as np

from ..simulation.metrics import fit_decay, steady_rms
from ..simulation.montecarlo import simulate_seeds
from .baselines import baseline_seeds, baseline_trajectories
from .transients import SETTLED, choose_steps, measured_start, row_transients, steady_start
from ..synthesis.bounds import nice_ceil
from ..synthesis.design_cache import cached_design
from ..synthesis.designer import SPLIT_BESIDE, design
from ..synthesis.kalman import per_step_rate, references
from ..synthesis.verdict import ADAPTIVE, NO_CERTIFIED_RATE
from ..errors import AssumptionError, DesignError
from ..scenarios import gain_methods
from ..scenarios.faults import PLANT
from ..synthesis.error_matrix import MAX_NOISE_DIM, predicted_rms
from ..synthesis.noise_tuning import tune
from ..synthesis.verdict import rate_certificate
from ..scenarios.noise import noise_json
from ..scenarios.specs import Scenario
from ..simulation.simulator import check_trajectory_memory, simulate

__all__ = ["CompareResult", "EstimatorResult", "compare", "sweep", "sweep_line", "certificate_lines", "settle_time",
           "faults_note", "missing_ratio_lines", "strict_json"]


@dataclass(frozen=True)
class EstimatorResult:
    """One estimator's figures in :func:`compare` (RMS over agents, then mean and std over seeds)."""

    rms_mean: float | None  # None: no steady figure (``note`` says why)
    rms_std: float | None
    ratio_to_centralized: float | None
    predicted_rms: float | None
    settle_time: float | None  # noise-free: first time after which the error stays below 1e-3 of its start
    measured_rate: float | None
    messages_per_event: int
    q: int | None
    g: float | None
    gains: str | None
    certified_rate: bool | None = None  # split-spectrum rows: the design's certificate (None for the baselines)
    certificate: str | None = None
    rate_note: str | None = None  # the adaptive gain: asymptotic convergence only (no certified rate)
    steady_from: float | None = None  # the steady RMS is measured from here (compare.steady_start); None: not settled
    note: str | None = None  # why there is no steady figure, or how its start was found where not certified
    ratio_note: str | None = None  # why there is no ratio to the centralized KF
    consensus: str | None = None  # split or whole (the designs' rows)


_CERTIFICATE_FIELDS = ("certified_rate", "certificate", "rate_note")


@dataclass(frozen=True)
class CompareResult:
    """``splitspec compare``: split-spectrum variants against the centralized Kalman filter and the KCF.

    ``estimators`` maps names (the scenario's own design, e.g. ``optimal (whole state)`` or ``split (explicit)``;
    ``split place``, ``split riccati``, ``split tuned``, ``centralized KF``, ``centralized at rate`` when the Kalman
    filter is slower than the rate, ``KCF``) to :class:`EstimatorResult`; ``t`` and ``curves`` (name -> (T,) RMS
    error over agents, mean over seeds) are the error curves; ``failed`` the rows that could not be designed;
    ``note`` what the scenario's faults do to the rows (:func:`faults_note`).
    """

    scenario: str
    time: str
    seeds: tuple
    steps: int
    rate: float
    process_noise: Any  # as the scenario gives it (System.process_noise): a number, a vector or a matrix
    measurement_noise: Any  # a number, or {agent id: std or (one per output)}
    exchanges: int
    kcf_eps: float | None
    estimators: Mapping[str, EstimatorResult]
    tuned: Mapping[str, Any] | None
    t: np.ndarray
    curves: Mapping[str, np.ndarray]
    failed: Mapping[str, str] = dataclasses.field(default_factory=lambda: MappingProxyType({}))  # rows not designed, why
    note: str | None = None  # what the scenario's faults do to the rows (faults_note); None without faults
    steps_note: str | None = None  # how the steps were chosen when none were given (transients.choose_steps)

    def to_json(self) -> dict:
        """The ``compare.json`` object.

        Returns
        -------
        dict
            Strict JSON (``json.dumps(..., allow_nan=False)`` takes it): a number that is not finite is ``null``,
            and the row says why (``note``, ``ratio_note``; an infinite predicted RMS: its ``certificate``); a
            baseline's row has no certificate fields; ``tuned``, ``failed``, ``note`` and ``steps_note`` only when
            present.
        """
        out = {"scenario": self.scenario, "time": self.time, "seeds": list(self.seeds), "steps": self.steps,
               "rate": self.rate, "process_noise": noise_json(self.process_noise),  # numbers stay numbers
               "measurement_noise": noise_json(self.measurement_noise), "exchanges": self.exchanges,
               "kcf_eps": self.kcf_eps,
               "estimators": {k: {("settle_time_1e-3" if f == "settle_time" else f): strict_json(getattr(v, f))
                                  for f in v.__dataclass_fields__
                                  if v.certificate is not None or f not in _CERTIFICATE_FIELDS}
                              for k, v in self.estimators.items()}}
        if self.tuned is not None:
            out["tuned"] = dict(self.tuned)
        if self.failed:
            out["failed"] = dict(self.failed)
        if self.note:
            out["note"] = self.note
        if self.steps_note:
            out["steps_note"] = self.steps_note
        return out


def strict_json(value):
    """``value`` with every float that is not finite replaced by None: JSON has no NaN or Infinity.

    Parameters
    ----------
    value : object
        Plain data (dicts, lists, tuples, numbers, strings, None).

    Returns
    -------
    object
        The same data (tuples as lists); ``json.dumps(..., allow_nan=False)`` takes it.

    Examples
    --------
    >>> strict_json({"rms": float("nan"), "rows": [1.0, float("inf")]})
    {'rms': None, 'rows': [1.0, None]}
    """
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {k: strict_json(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [strict_json(v) for v in value]
    return value


def _readonly(a) -> np.ndarray:
    a = np.array(a)
    a.setflags(write=False)
    return a


def settle_time(t: np.ndarray, err: np.ndarray, *, rel: float = 1e-3) -> float | None:
    """First time after which the (worst agent's) error stays below ``rel`` times its initial value.

    Parameters
    ----------
    t, err : (T,) array, (T,) or (T, m) array
        The times and the errors (per agent: the worst, NaN ignored).
    rel : float
        The fraction of the initial error.

    Returns
    -------
    float or None
        A time of ``t``; None when the error is still above at the end.

    Examples
    --------
    >>> settle_time(np.arange(5.0), np.array([1.0, 0.5, 1e-4, 1e-5, 0.0]))
    2.0
    """
    e = np.asarray(err, dtype=float).reshape(len(t), -1)
    worst = np.nanmax(e, axis=1)
    above = np.nonzero(worst > rel * worst[0])[0]
    if above.size == 0:
        return float(t[0])
    k = above[-1] + 1
    return float(t[k]) if k < len(t) else None


def _errors(xhat: np.ndarray, x: np.ndarray) -> np.ndarray:
    if xhat.ndim == 2:
        return np.linalg.norm(xhat - x, axis=1)
    return np.linalg.norm(xhat - x[:, None, :], axis=2)


def _variant(sc: Scenario, gains: str) -> Scenario:
    d = dataclasses.replace(sc.design, gains=gains, K=None, consensus="split")
    return dataclasses.replace(sc, design=d)


#: ``split tuned`` (:func:`~splitspec_core.synthesis.noise_tuning.tune`: about 40 designs) only up to this m n
TUNE_MAX = 400
def _scenario_row(sc: Scenario, des) -> str:
    """The name of the scenario's own design in :func:`compare`."""
    method = gain_methods.method(sc.design.gains)
    if des.consensus in ("fusion", "relay"):
        return f"{des.consensus} (q = {des.q})"
    if not method.local:
        return f"{method.name} ({'whole state' if des.consensus == 'whole' else 'split'})"
    if des.consensus == "whole":
        return f"whole ({sc.design.gains})"
    return "split (scenario)" if method.needs_K else f"split {sc.design.gains}"


def compare(sc: Scenario, *, seeds, steps: int | None = None, eps: float | None = None) -> CompareResult:
    """Run every estimator on the same realisations: their figures and mean error curves (frozen, read-only).

    Rows: the scenario's own design (``optimal (whole state)`` by default under noise), the paper's split with
    ``place`` and ``riccati`` gains (not beside a whole-state design above ``m n`` = ``SPLIT_BESIDE``) and, when
    the scenario's design is a split, tuned (:func:`~splitspec_core.synthesis.noise_tuning.tune`, up to ``m n`` =
    :data:`TUNE_MAX`), the centralized Kalman filter, the centralized Kalman filter designed for A/rate
    (``centralized at rate``, a rate-shifted Riccati design, not the optimum under the rate:
    :func:`~splitspec_core.synthesis.kalman.references`; only when the Kalman filter is
    slower than the rate) and the KCF with as many exchanges as the scenario's design.  Each row's steady RMS is
    measured after its own transient: from :func:`steady_start` of its certified envelope (the Kalman filter's from
    its radius and transient constant; the KCF, which certifies nothing, from the latest of the others'); a row
    whose transient outlasts the run has none (``steady_from`` None) and says so in ``note``; a row without a ratio
    to the centralized KF says why in ``ratio_note``.  Without ``steps`` the run is ``run.steps`` or, when that is
    shorter, twice the longest certified transient
    (:func:`~splitspec_core.studies.transients.choose_steps`; ``steps_note`` says so).

    Parameters
    ----------
    sc : Scenario
        A scenario with noise.
    seeds : iterable of int
        The seeds every estimator runs.
    steps, eps : int, float, optional
        Steps per run (default: ``run.steps``, or longer for every certified transient to end within the run, as
        above); the KCF's consensus gain (default ``1 / (1 + max in-degree)``).

    Returns
    -------
    CompareResult
        Frozen; ``failed`` names the rows that could not be designed and why.

    Raises
    ------
    DesignError
        The scenario has no noise.
    ScenarioError
        The trajectories would not fit in memory.

    Examples
    --------
    >>> import splitspec_core as ss
    >>> sc = ss.scenario(A=[[0.9, 0.2], [0, 0.8]], C={1: [[1, 0]], 2: [[0, 1]]}, graphs={"a": [(1, 2), (2, 1)]},
    ...                  rate=0.5, process_noise=0.1, measurement_noise=0.1)
    >>> list(compare(sc, seeds=[0, 1], steps=100).estimators)
    ['optimal (whole state)', 'split place', 'split riccati', 'centralized KF', 'KCF']
    """
    seeds = list(seeds)
    check_trajectory_memory(sc, steps)
    if not sc.system.has_noise:
        raise DesignError("compare needs noise: set system.process_noise and/or system.measurement_noise")
    own = cached_design(sc)
    variants = {_scenario_row(sc, own): own}
    for gains in ("place", "riccati"):
        name = f"split {gains}"
        if name in variants:
            continue
        if sc.m * sc.n > SPLIT_BESIDE and own.consensus == "whole":
            variants[name] = (f"not designed at m n = {sc.m * sc.n} (the split's full error matrices and g search cost "
                              "minutes there): splitspec design with design.consensus: split designs it")
            continue
        try:
            variants[name] = design(_variant(sc, gains), reach=False)  # a side row: why, not how fast it could go
        except (DesignError, AssumptionError) as exc:  # e.g. a local Riccati equation without a solution, or
            variants[name] = str(exc)  # place's poles outside the rate: that row fails, the others are compared
    tuned = None
    if sc.m * sc.n <= TUNE_MAX and own.consensus == "split":  # the split's own search for the noise (~40 designs)
        try:
            method = gain_methods.method(sc.design.gains)  # a central method: tune its split's default
            tuned = tune(sc if method.local else _variant(sc, method.split[0]))
            if not tuned.kept:  # kept: no candidate beats the split it started from, a row of its own already
                variants["split tuned"] = tuned.design
        except (DesignError, AssumptionError):
            pass
    failed = {k: v for k, v in variants.items() if isinstance(v, str)}
    variants = {k: v for k, v in variants.items() if not isinstance(v, str)}
    two_rate = own.two_rate
    exchanges = own.q if two_rate else 1
    kf, ref = references(sc, own.envelope_rate)
    extra = {} if ref is None or ref is kf else {"centralized at rate": ref.L}
    central = {"centralized KF": kf, **({"centralized at rate": ref} if extra else {})}
    # the adaptive gain has no steady state (g_i(t) keeps moving), so no predicted RMS; none above MAX_NOISE_DIM
    predicted = {name: _predicted_all(des) for name, des in variants.items()}
    predicted.update({name: p.rms for name, p in central.items()})
    steps_note = None
    if steps is None:  # long enough for every certified transient: from the initial errors of a one-step run
        first = _runs(sc, variants, seeds, 1, exchanges, eps, extra)
        transients = row_transients(sc, variants, _initial_errors(first), predicted, central)
        steps, steps_note = choose_steps(sc, transients)
        check_trajectory_memory(sc, steps)
    # every seed at once, per seed the errors of a single-seed run to round-off: the split-spectrum variants by
    # montecarlo.simulate_seeds, the baselines by baselines.baseline_seeds (the same MonteCarloRuns statistics)
    runs = _runs(sc, variants, seeds, steps, exchanges, eps, extra)
    curves = {name: r.rms() for name, r in runs.items()}
    T = runs["centralized KF"].t
    # noise-free transients (first seed)
    settle, rate, clean = {}, {}, {}  # clean: the noise-free stacked error ||e(k)||, (T,)
    for name, des in variants.items():
        tr = simulate(des, seed=seeds[0], steps=steps, noise=False, progress=False)
        e = tr.errors()
        settle[name] = settle_time(tr.t, e)
        rate[name] = fit_decay(tr.t, np.nanmax(e, axis=1), time=sc.time, scale=np.linalg.norm(tr.x, axis=1))
        clean[name] = np.sqrt(np.nansum(e ** 2, axis=1))
    b0 = baseline_trajectories(sc, seeds[0], exchanges=exchanges, steps=steps, noise=False, eps=eps)
    for name, key in (("centralized KF", "centralized"), ("KCF", "kcf")):
        e = _errors(b0[key], b0["x"])
        settle[name] = settle_time(b0["t"], e)
        worst = e if e.ndim == 1 else np.nanmax(e, axis=1)
        rate[name] = fit_decay(b0["t"], worst, time=sc.time, scale=np.linalg.norm(b0["x"], axis=1))
        clean[name] = e if e.ndim == 1 else np.sqrt(np.nansum(e ** 2, axis=1))
    transients = row_transients(sc, variants, _initial_errors(runs), predicted, central)
    starts, notes = _steady_starts(sc, transients, predicted, len(T), clean)
    m = sc.m
    messages = {name: m * des.q if des.two_rate else m for name, des in variants.items()}
    messages["KCF"] = m * exchanges
    for name in central:
        messages[name] = m  # every agent sends its measurement to the centre
    rms = {name: (r.steady_rms(start=starts[name]) if starts[name] is not None else None) for name, r in runs.items()}
    kf_rms = None if rms["centralized KF"] is None else float(np.mean(rms["centralized KF"]))
    table = {}
    for name in list(variants) + [*central, "KCF"]:
        r = rms[name]
        des = variants.get(name)
        cert = None if des is None else rate_certificate(des)
        k0 = starts[name]
        ratio, why = _ratio(r, kf_rms, notes, name)
        table[name] = EstimatorResult(
            rms_mean=None if r is None else float(r.mean()),
            rms_std=None if r is None else float(r.std(ddof=1)) if len(r) > 1 else 0.0,
            ratio_to_centralized=ratio, ratio_note=why,
            predicted_rms=predicted.get(name), settle_time=settle.get(name), measured_rate=rate.get(name),
            messages_per_event=messages[name],
            q=None if des is None else des.q, g=None if des is None else des.g,
            gains=None if des is None else des.scenario.design.gains,
            certified_rate=None if cert is None else cert.certified, certificate=None if cert is None else cert.text,
            rate_note=NO_CERTIFIED_RATE if des is not None and des.adaptive else None,
            steady_from=None if k0 is None else float(T[k0]), note=notes.get(name),
            consensus=None if des is None else des.consensus)
    tuned_json = None
    if tuned is not None:
        cd = tuned.design.scenario.design
        tuned_json = MappingProxyType({
            "gains": cd.gains, "process_weight": cd.process_weight,
            "measurement_weight": cd.measurement_weight, "q": tuned.design.q, "g": tuned.design.g,
            "predicted_rms": tuned.rms, "baseline_predicted_rms": tuned.baseline_rms, "kept": tuned.kept})
    return CompareResult(
        scenario=sc.name, time=sc.time, seeds=tuple(seeds), steps=int(len(T) - 1), rate=sc.design.rate,
        process_noise=sc.system.process_noise, measurement_noise=sc.system.measurement_noise, exchanges=exchanges,
        kcf_eps=eps, estimators=MappingProxyType(table), tuned=tuned_json, t=_readonly(T),
        curves=MappingProxyType({k: _readonly(np.mean(v, axis=0)) for k, v in curves.items()}),
        failed=MappingProxyType(failed), note=faults_note(sc), steps_note=steps_note)


def faults_note(sc: Scenario) -> str | None:
    """What the scenario's faults do to the rows of :func:`compare`: its sensor faults change the measurements of
    every row alike (the baselines' too: :func:`~splitspec_core.studies.baselines.baseline_seeds`); its other faults
    strike the split-spectrum rows only (the baselines run on the first graph, every agent alive).

    Parameters
    ----------
    sc : Scenario
        The scenario.

    Returns
    -------
    str or None
        One sentence; None when the scenario has no fault.
    """
    sensors = sorted({f.agent for f in sc.faults if f.runtime == PLANT})
    others = list(dict.fromkeys(f.action for f in sc.faults if f.runtime != PLANT))
    parts = []
    if sensors:
        parts.append("the scenario's sensor faults (agent" + ("s " if len(sensors) > 1 else " ")
                     + ", ".join(map(str, sensors)) + ") were applied to the measurements of every row, the centralized "
                     "KF and the KCF included: every estimator was given the same corrupted measurements")
    if others:
        parts.append(f"its {', '.join(others)} faults strike the split-spectrum rows only (the baselines run on the "
                     "first graph, every agent alive)")
    return "; ".join(parts) or None


def _predicted_all(des) -> float | None:
    """RMS over agents of a design's predicted steady RMS errors; None when not computed (adaptive gain, or ``m n``
    above ``MAX_NOISE_DIM``)."""
    sc = des.scenario
    if des.adaptive or sc.m * sc.n > MAX_NOISE_DIM:
        return None
    return float(np.sqrt(np.mean(predicted_rms(des) ** 2)))


def _runs(sc: Scenario, variants: dict, seeds: list, steps: int, exchanges: int, eps, extra: dict) -> dict:
    """Every row's :class:`~splitspec_core.simulation.montecarlo.MonteCarloRuns` on the same realisations."""
    runs = {name: simulate_seeds(des, seeds, steps=steps) for name, des in variants.items()}
    b = baseline_seeds(sc, seeds, exchanges=exchanges, steps=steps, eps=eps, gains=extra)
    runs.update({"centralized KF": b["centralized"], "KCF": b["kcf"], **{k: b[k] for k in extra}})
    return runs


def _initial_errors(runs: dict) -> dict:
    """Per row, the largest initial stacked error over the seeds (the same in a run of any length)."""
    return {name: float(np.sqrt(np.max(r.sq_error[:, 0]))) for name, r in runs.items()}


def _ratio(r, kf_rms: float | None, notes: dict, name: str) -> tuple:
    """``(ratio to the centralized KF, None)``, or ``(None, why not)``."""
    if r is None:
        return None, f"no steady figure: {notes[name]}"
    if kf_rms is None:
        return None, f"the centralized KF has no steady figure: {notes['centralized KF']}"
    if not kf_rms > 0:
        return None, "the centralized KF's steady RMS is 0"
    return float(r.mean() / kf_rms), None


def _steady_starts(sc: Scenario, transients: dict, predicted: dict, T: int, clean: dict) -> tuple:
    """``(start, note)``: each row's first steady step and, where it is not its certified transient's end, why.

    A row's certified transient (:func:`~splitspec_core.studies.transients.row_transients`) within the run's ``T``
    steps is its start.  Where no constant was computed (a design above ``m n`` = ``MAX_DIM``), or a centralized
    predictor's bound outlasts the run (loose at n = 170, IEEE 39-bus): measured, the first step after which the
    noise-free run's stacked error (``clean``, same initial values) stays below :data:`SETTLED` of the predicted
    steady one.  The KCF, which certifies nothing, from the latest of the others.  A row with no start has a note
    saying why.
    """
    out, notes = {}, {}
    for name, tr in transients.items():
        k = tr.steps if tr.steps is not None and tr.steps < T else None
        central = name in ("centralized KF", "centralized at rate")
        floor = None if predicted[name] is None else predicted[name] * (1.0 if central else math.sqrt(sc.m))
        if k is None and (tr.c is None or central) and floor and math.isfinite(floor) and name in clean:
            k = measured_start(clean[name], floor)
            if k is not None:
                notes[name] = (f"steady from the noise-free run's error below {SETTLED:g} of the predicted (" + (
                    f"its certified envelope, constant {tr.c:.3g} at rate {tr.r:.6g} per step, outlasts the run)"
                    if central else f"no certified transient constant at m n = {sc.m * sc.n})"))
        if k is None:
            notes[name] = (f"its certified transient is {tr.steps} steps, the run {T - 1}: give --steps "
                           f"{int(nice_ceil(2 * tr.steps))} or more" if tr.steps is not None else
                           f"no certified transient: {tr.why}; nor did its noise-free run settle within the run"
                           if tr.c is None or central else f"no certified transient: {tr.why}")
        out[name] = k
    settled = [k for k in out.values() if k is not None]
    out["KCF"] = max(settled) if settled else None
    if not settled:
        notes["KCF"] = "it certifies nothing, and no other row's transient ended within the run"
    return out, notes


def sweep(sc: Scenario, *, seed: int, steps: int | None = None, values=None) -> dict:
    """RMS error (predicted and simulated) and measured rate against q (discrete) or g (continuous).

    A row is ``certified`` as :func:`~splitspec_core.synthesis.verdict.rate_certificate`
    judges the design at that value, for the estimator the row simulates
    (continuous: the sampled-data form with ``run.dt``, so a g certified for
    the ODE alone is not certified); ``certificate`` says why in one line.

    Parameters
    ----------
    sc : Scenario
        The scenario.
    seed, steps : int, int or None
        The simulations' seed and steps (default ``run.steps``).
    values : iterable of number, optional
        The q or g values; default ``1 .. max(2 q, q + 6)``, or eight g around the designed one.

    Returns
    -------
    dict
        ``scenario``, ``parameter`` (``q`` or ``g``), ``designed``, ``designed_note``, ``rate``, ``seed`` and
        ``rows`` (per value its certificate, predicted and simulated RMS and measured rate, or ``error``).
    """
    base = cached_design(sc)
    discrete = base.two_rate  # q exchanges per event time: discrete time, or the whole-state design
    if values is None:
        if discrete:
            q0 = base.q
            values = list(range(1, max(2 * q0, q0 + 6) + 1))
        else:  # the adaptive gain: fixed values around the auto g (eq. g) for comparison
            g0 = base.g if base.g is not None else nice_ceil(max(base.g_bounds.values()) * (1 + 1e-9)) or 1.0
            values = [g0 * f for f in (0.25, 0.5, 0.75, 1.0, 1.5, 2.0, 3.0, 4.0)]
    rows = []
    for v in values:
        d = dataclasses.replace(sc.design, **({"q": int(v)} if discrete else {"g": float(v)}))
        try:
            des = design(dataclasses.replace(sc, design=d))
        except (DesignError, AssumptionError) as exc:
            rows.append({"value": v, "error": str(exc)})
            continue
        cert = rate_certificate(des)
        noisy = simulate(des, seed=seed, steps=steps, progress=False)
        clean = simulate(des, seed=seed, steps=steps, noise=False, progress=False)
        e = clean.errors()
        rate = fit_decay(clean.t, np.nanmax(e, axis=1), time=sc.time, scale=np.linalg.norm(clean.x, axis=1))
        pred = predicted_rms(des)
        rows.append({"value": v, "certified": cert.certified, "certificate": cert.text, "predicted_rms": float(np.sqrt(np.mean(pred ** 2))),
                     "simulated_rms": steady_rms(noisy.errors()), "measured_rate": rate})
    return {"scenario": sc.name, "parameter": "q" if discrete else "g", "designed": base.q if discrete else base.g,
            "designed_note": ADAPTIVE if base.g_mode == "adaptive" else None,
            "rate": sc.design.rate, "seed": seed, "rows": rows}


def certificate_lines(res: CompareResult) -> list:
    """One line per split-spectrum estimator of a :func:`compare` result: its rate certificate.

    Parameters
    ----------
    res : CompareResult
        A :func:`compare` result.

    Returns
    -------
    list of str
        ``  name: rate certified: ...`` (indented).
    """
    lines = []
    for name, r in res.estimators.items():
        if r.certificate is None:
            continue
        verdict = "" if r.rate_note else ("rate certified: " if r.certified_rate else "rate NOT certified: ")
        lines.append(f"  {name}: {verdict}{r.certificate}")
    return lines


def missing_ratio_lines(res: CompareResult) -> list:
    """Why the rows of a :func:`compare` result without a ratio to the centralized KF have none: one line per reason.

    Parameters
    ----------
    res : CompareResult
        A :func:`compare` result.

    Returns
    -------
    list of str
        ``  row, row: ratio n/a: reason`` (indented); empty when every row has its ratio.
    """
    rows = {}
    for name, r in res.estimators.items():
        if r.ratio_note:
            rows.setdefault(r.ratio_note, []).append(name)
    return [f"  {', '.join(names)}: ratio n/a: {reason}" for reason, names in rows.items()]


def sweep_line(sw: dict) -> str:
    """The one-line summary of a :func:`sweep`: predicted RMS per value, certified values starred.

    Parameters
    ----------
    sw : dict
        A :func:`sweep` result.

    Returns
    -------
    str
        Indented; values whose design failed are left out.
    """
    text = f"  sweep of {sw['parameter']}: " + ", ".join(
        f"{r['value']:g}: RMS {r['predicted_rms']:.3g}{'*' if r['certified'] else ''}" for r in sw["rows"]
        if "error" not in r) + "  (* rate certified)"
    if sw.get("designed_note"):
        text += f"; fixed values for comparison, the scenario's {sw['designed_note']}"
    return text
