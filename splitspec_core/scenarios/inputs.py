"""Known inputs: ``x+ = A x + B u`` (``x' = A x + B u``), with a signal ``u(t)`` every agent knows.

``system.u`` is the signal, a sum of parts (each a vector of ``p`` numbers, ``p`` the columns of ``system.B``)::

    u: [1.0, -2.0]                       # constant
    u:
      constant: [0.0, 0.0]
      steps: [[0, [1, 0]], [5, [1, 2]]]  # from t = 0 on: [1, 0]; from t = 5 on: [1, 2] (zero before the first)
      sine: [{amplitude: [0.5, 0], period: 10, phase: 0.0}]   # amplitude sin(2 pi t / period + phase)

``t`` is the event time ``k`` (``time: discrete``), ``k * system.sample`` seconds (a sampled continuous model) or
``k * run.dt`` seconds (``time: continuous``; ``u`` is held over each step, as the zero-order hold of the
plant's sampling).  ``system.sample: dt`` (with ``time: discrete``) samples a continuous ``A``, ``B`` with a
zero-order hold (:func:`parse_inputs`): the discrete estimator of a continuous model.  A measurements file may carry ``u`` instead (``u.<k>`` columns,
:mod:`splitspec_core.scenarios.measurements`).

The input cancels from every error: the plant and every estimator add the same ``B u`` (the estimators'
prediction, :mod:`splitspec_core.model.steps`), so no certificate changes.  :func:`input_at` is the one evaluation of
the signal: the simulator and the plant process call it with the same ``t``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Mapping

import numpy as np

from ..errors import DimensionError, ScenarioError
from .checks import MAX_MAGNITUDE, MIN_DT, check_matrix, check_number

__all__ = ["InputSignal", "parse_input", "parse_inputs", "input_at", "input_time"]

_PARTS = ("constant", "steps", "sine")
_SINE_KEYS = ("amplitude", "period", "phase")


@dataclass(frozen=True)
class InputSignal:
    """``u(t) = constant + (the last step at or before t) + sum amplitude sin(2 pi t / period + phase)``."""

    width: int
    constant: tuple = ()  # p floats, or () for none
    steps: tuple = ()  # ((t, (p floats)), ...), t increasing
    sines: tuple = ()  # ((amplitude (p floats), period, phase), ...)


def _vector(value: Any, key: str, width: int) -> tuple:
    """``width`` finite numbers (the scenario's own vector check, then the width against ``system.B``)."""
    out = check_matrix(value, key, vector=True).ravel()
    if len(out) != width:
        raise DimensionError(f"{key} has {len(out)} entries; system.B has {width} columns (one per input)")
    return tuple(float(v) for v in out)


def _positive(value: Any, key: str) -> float:
    v = check_number(value, key)
    if not v > 0:
        raise ScenarioError(f"{key} must be > 0, got {v:g}")
    return v


def parse_input(raw: Any, width: int, key: str = "system.u") -> InputSignal:
    """``system.u`` checked against ``width`` (the columns of ``system.B``); one-line errors naming the key.

    Parameters
    ----------
    raw : list or mapping
        ``system.u`` as the YAML holds it: ``p`` numbers, or a mapping of ``constant``, ``steps``, ``sine``.
    width : int
        ``p``, the columns of ``system.B``.
    key : str, default "system.u"
        The key named in messages.

    Returns
    -------
    InputSignal

    Raises
    ------
    ScenarioError
        An unknown key, a vector of the wrong width (:class:`DimensionError`), step times that do not increase, a
        sine without amplitude or period, a period not > 0.

    Examples
    --------
    >>> sig = parse_input({"constant": [1.0], "steps": [[0, [1]], [5, [2]]]}, 1)
    >>> input_at(sig, 4.0), input_at(sig, 5.0)
    (array([2.]), array([3.]))
    """
    if isinstance(raw, list):
        return InputSignal(width=width, constant=_vector(raw, key, width))
    if not isinstance(raw, Mapping) or not raw:
        raise ScenarioError(f"{key} must be a list of {width} numbers or a mapping of constant, steps, sine")
    for k in raw:
        if k not in _PARTS:
            raise ScenarioError(f"unknown key {key}.{k} (expected one of: {', '.join(_PARTS)})")
    constant = _vector(raw["constant"], f"{key}.constant", width) if raw.get("constant") is not None else ()
    steps = []
    if raw.get("steps") is not None:
        if not isinstance(raw["steps"], list) or not raw["steps"]:
            raise ScenarioError(f"{key}.steps must be a list of [t, [{width} numbers]]")
        for j, item in enumerate(raw["steps"]):
            where = f"{key}.steps[{j + 1}]"
            if not isinstance(item, list) or len(item) != 2:
                raise ScenarioError(f"{where} must be [t, [{width} numbers]], got {item!r}"[:200])
            t = check_number(item[0], f"{where} (its time)")
            if steps and not t > steps[-1][0]:
                raise ScenarioError(f"{where}: times must increase ({t:g} after {steps[-1][0]:g})")
            steps.append((t, _vector(item[1], where, width)))
    sines = []
    if raw.get("sine") is not None:
        if not isinstance(raw["sine"], list) or not raw["sine"]:
            raise ScenarioError(f"{key}.sine must be a list of {{amplitude: [..], period: T, phase: p}}")
        for j, item in enumerate(raw["sine"]):
            where = f"{key}.sine[{j + 1}]"
            if not isinstance(item, Mapping):
                raise ScenarioError(f"{where} must be a mapping {{amplitude: [..], period: T, phase: p}}")
            for k in item:
                if k not in _SINE_KEYS:
                    raise ScenarioError(f"unknown key {where}.{k} (expected one of: {', '.join(_SINE_KEYS)})")
            if "amplitude" not in item or "period" not in item:
                raise ScenarioError(f"{where} needs amplitude and period")
            sines.append((_vector(item["amplitude"], f"{where}.amplitude", width),
                          _positive(item["period"], f"{where}.period"),
                          check_number(item.get("phase", 0.0), f"{where}.phase")))
    return InputSignal(width=width, constant=constant, steps=tuple(steps), sines=tuple(sines))


def input_time(k: int, period: float | None) -> float:
    """The time of step ``k``: ``k`` event times, or ``k * period`` seconds.

    Parameters
    ----------
    k : int
        Step.
    period : float or None
        Seconds per step (``system.sample`` or ``run.dt``); None: discrete event times.

    Returns
    -------
    float
    """
    return float(k) if period is None else k * period


def input_at(sig: InputSignal, t: float) -> np.ndarray:
    """``u(t)``: the one evaluation of the signal (simulator and plant process alike).

    Parameters
    ----------
    sig : InputSignal
        The signal.
    t : float
        Time (:func:`input_time`).

    Returns
    -------
    (width,) float array
        ``constant + (the last step at or before t) + sum amplitude sin(2 pi t / period + phase)``.
    """
    u = np.zeros(sig.width)
    if sig.constant:
        u = u + np.array(sig.constant)
    last = None
    for ts, value in sig.steps:
        if ts <= t:
            last = value
        else:
            break
    if last is not None:
        u = u + np.array(last)
    for amp, period, phase in sig.sines:
        u = u + np.array(amp) * math.sin(2.0 * math.pi * t / period + phase)
    return u


def _sampled(A: Any, B: Any, sample: Any, time: str) -> tuple:
    """``system.sample``: ``(exp(A dt), int_0^dt exp(A s) ds B, dt)`` (zero-order hold), or ``(A, B, None)``."""
    if sample is None:
        return A, B, None
    dt = check_number(sample, "system.sample")
    if time != "discrete":
        raise ScenarioError("system.sample samples a continuous model for time: discrete; with time: continuous the "
                            "estimator itself runs in continuous time (its step is run.dt): leave system.sample out")
    if not dt >= MIN_DT:
        raise ScenarioError(f"system.sample must be >= {MIN_DT:g} (in system.time_unit), got {dt:g}")
    from .sampling import sampled_data_matrices

    with np.errstate(all="ignore"):
        E, D, _ = sampled_data_matrices(A, dt)
    if not (np.all(np.isfinite(E)) and np.all(np.isfinite(D))) or np.abs(E).max() > MAX_MAGNITUDE:
        raise ScenarioError(f"system.sample = {dt:g}: exp(A dt) overflows (|entries| above {MAX_MAGNITUDE:g}); "
                            "a shorter period")
    return E, (None if B is None else D @ B), dt


def parse_inputs(sysmap: Mapping, A: np.ndarray, time: str) -> tuple:
    """``(A, B, u, sample)`` of ``system:``: ``B`` (n x p) checked against ``A``, ``u`` against ``B``'s width,
    and with ``system.sample`` the sampled ``A`` and ``B``; one-line errors naming the key.

    Parameters
    ----------
    sysmap : mapping
        The scenario's ``system:`` section (``B``, ``u``, ``sample`` read).
    A : (n, n) array
        ``system.A``, checked.
    time : {"continuous", "discrete"}
        The scenario's time.

    Returns
    -------
    A : (n, n) array
        ``A``, or ``exp(A dt)`` with ``system.sample``.
    B : (n, p) array or None
        ``B``, or its zero-order-hold ``int_0^dt exp(A s) ds B``.
    u : InputSignal or None
    sample : float or None
        ``system.sample`` (seconds).

    Raises
    ------
    ScenarioError
        ``B`` with the wrong rows, ``u`` without ``B``, ``system.sample`` with continuous time, below the minimum
        step, or one whose ``exp(A dt)`` overflows.
    """
    B = None
    if sysmap.get("B") is not None:
        B = check_matrix(sysmap["B"], "system.B")
        if B.shape[0] != A.shape[0]:
            n = A.shape[0]
            # no guessing: a flat list [a, b, ...] is one row (1 x n), not the column of one input
            hint = "; a flat list is one row: write one input's column as [[a], [b], ...]" if B.shape == (1, n) else ""
            raise DimensionError(f"system.B is {B.shape[0]}x{B.shape[1]}, system.A is {n}x{n} (B is n x p, one "
                                 f"column per input{hint})")
    u = None
    if sysmap.get("u") is not None:
        if B is None:
            raise ScenarioError("system.u needs system.B (the inputs' matrix, n x p: x+ = A x + B u)")
        u = parse_input(sysmap["u"], B.shape[1])
    A, B, sample = _sampled(A, B, sysmap.get("sample"), time)
    return A, B, u, sample
