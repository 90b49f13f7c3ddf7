"""How long ``compare`` runs: each row's certified transient, and the steps chosen when none are given.

Each row of :func:`~splitspec_core.studies.comparison.compare` measures its steady RMS after its certified
transient: from the first step ``k`` where the envelope ``c r^k |e(0)|`` of its stacked error (``c`` the transient
constant of :func:`~splitspec_core.synthesis.conditioning.transient_constant`, ``r`` the rate per step, ``|e(0)|``
the largest initial stacked error over the seeds) falls below :data:`SETTLED` of its predicted steady stacked RMS
(:func:`steady_start`).  :func:`row_transients` gives every row that ``k``, uncapped, or why nothing certifies one;
without ``--steps`` :func:`choose_steps` makes the run at least twice the longest of them, so that each row's steady
window is at least as long as its transient.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..scenarios.specs import Scenario
from ..simulation.simulator import physical_memory
from ..synthesis.bounds import nice_ceil
from ..synthesis.conditioning import conditioning, transient_constant
from ..synthesis.kalman import per_step_rate
from .baselines import sampled_model

__all__ = ["AUTO_MAX_STEPS", "SETTLED", "Transient", "choose_steps", "measured_start", "row_transients",
           "steady_start"]

#: the steady state starts when the certified envelope of the transient is below this fraction of the predicted
#: steady RMS error (:func:`steady_start`)
SETTLED = 0.05
#: the most steps :func:`choose_steps` chooses by itself (``--steps`` goes further)
AUTO_MAX_STEPS = 20_000
_UNBOUNDED = 2 ** 62


def steady_start(c: float | None, r: float, e0: float, floor: float, T: int) -> int | None:
    """The first step after the transient: where the certified envelope ``c r^k e0`` of the stacked error (``c`` the
    transient constant, ``r`` the rate per step, ``e0`` the largest initial stacked error over the seeds) falls below
    :data:`SETTLED` of ``floor`` (the predicted steady stacked RMS); None when that is past the run's ``T`` steps or
    nothing bounds it (``c`` unknown or infinite, ``r >= 1``, ``floor`` not finite and positive).

    Parameters
    ----------
    c, r, e0, floor : float
        As above (``c`` may be None).
    T : int
        The run's steps.

    Returns
    -------
    int or None
        The step ``k`` (0 when already below).
    """
    if c is None or not math.isfinite(c) or not 0 < r < 1 or not 0 < floor < math.inf:
        return None
    k = max(0, math.ceil(math.log(SETTLED * floor / (c * max(e0, floor))) / math.log(r)))
    return k if k < T else None


def measured_start(err: np.ndarray, floor: float) -> int | None:
    """The first step after which ``err`` stays below :data:`SETTLED` of ``floor``.

    Parameters
    ----------
    err : (T,) array
        A noise-free run's stacked error per step.
    floor : float
        The predicted steady stacked RMS.

    Returns
    -------
    int or None
        The step; None when it never does within the run.
    """
    above = np.flatnonzero(~(np.asarray(err) <= SETTLED * floor))
    k = 0 if above.size == 0 else int(above[-1]) + 1
    return k if k < len(err) else None


@dataclass(frozen=True)
class Transient:
    """One row's certified transient: ``steps`` (:func:`steady_start`, uncapped) or None and ``why``, and the
    constant ``c`` and rate per step ``r`` of its envelope (``c`` None where not computed)."""

    steps: int | None
    why: str | None
    c: float | None
    r: float


def _transient(c, r: float, e0: float, floor) -> Transient:
    k = None if floor is None else steady_start(c, r, e0, floor, _UNBOUNDED)
    why = None
    if k is None:
        why = ("no predicted steady RMS (adaptive gain, or m n above the noise analysis' limit)" if floor is None else
               f"its predicted steady RMS is {floor:g} (the error does not settle)" if not 0 < floor < math.inf else
               "no transient constant computed (m n too large)" if c is None else
               "its transient constant is infinite (the error map's radius is not below the rate)"
               if not math.isfinite(c) else f"its rate per step {r:.6g} is not below 1")
    return Transient(steps=k, why=why, c=c, r=r)


def row_transients(sc: Scenario, variants: dict, e0: dict, predicted: dict, central: dict) -> dict:
    """Every row's certified transient (:class:`Transient`), before any run is long enough for it.

    Parameters
    ----------
    sc : Scenario
        The scenario.
    variants : dict
        ``{row name: Design}``, the designs compared: their transient constant and envelope rate
        (:func:`~splitspec_core.synthesis.conditioning.conditioning`).
    e0 : dict
        ``{row name: largest initial stacked error over the seeds}``.
    predicted : dict
        ``{row name: predicted steady RMS over agents or None}``.
    central : dict
        ``{row name: centralized predictor}`` (``L``, ``radius``, ``rms``): its constant at a rate just slower than
        its radius.

    Returns
    -------
    dict
        ``{row name: Transient}`` for every design and centralized predictor.
    """
    out = {}
    for name, des in variants.items():
        floor = None if predicted[name] is None else predicted[name] * math.sqrt(sc.m)  # stacked over the m agents
        out[name] = _transient(conditioning(des).transient_constant, per_step_rate(sc, des.envelope_rate), e0[name],
                               floor)
    F, _, _ = sampled_model(sc)
    C = np.vstack([np.asarray(c, dtype=float) for c in sc.system.Cs])
    for name, p in central.items():
        r = p.radius ** 0.9  # a rate just slower than its radius: a finite constant
        out[name] = _transient(transient_constant(F - p.L @ C, r).constant, r, e0[name], p.rms)
    return out


def choose_steps(sc: Scenario, transients: dict) -> tuple:
    """The steps of a ``compare`` given no ``--steps``: ``run.steps``, or twice the longest certified transient when
    that is longer (rounded up to two significant digits), at most :data:`AUTO_MAX_STEPS` and what fits in memory;
    ``run.steps`` for an unstable plant (a longer run of it reaches round-off).

    Parameters
    ----------
    sc : Scenario
        The scenario (``run.steps``, its sampled model, ``m n``).
    transients : dict
        ``{row name: Transient}`` (:func:`row_transients`).

    Returns
    -------
    (int, str or None)
        The steps, and one sentence saying how they were chosen (None: ``run.steps``, long enough).
    """
    steps = sc.run.steps
    known = {name: t.steps for name, t in transients.items() if t.steps is not None}
    if not known:
        return steps, None
    name = max(known, key=known.get)
    k = known[name]
    if 2 * k <= steps:
        return steps, None
    want = int(nice_ceil(2 * k))
    rho = float(np.max(np.abs(np.linalg.eigvals(sampled_model(sc)[0]))))
    if rho > 1:
        return steps, (f"run.steps {steps} kept: the {name}'s certified transient is {k} steps, but the plant is "
                       f"unstable (spectral radius {rho:.4g} per step) and a longer run of it reaches round-off: "
                       "give --steps to choose")
    have = physical_memory()
    limit = AUTO_MAX_STEPS if have is None else min(AUTO_MAX_STEPS, have // (8 * sc.m * sc.n) - 1)
    chosen = max(steps, min(want, limit))
    return chosen, (f"chosen {chosen} (run.steps {steps} is shorter than twice the longest certified transient, the "
                    f"{name}'s {k} steps)" + ("" if chosen == want else f"; {want} would be, but compare chooses at "
                                              f"most {limit} by itself: give --steps for more"))
