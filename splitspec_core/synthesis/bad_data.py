"""Sensors that lie: each agent's test of its own measurement, and the certified fallback of a suspect sensor.

The innovation each agent forms
    The update of eq. (split-discrete-est1), ``x_i(tau+1) = A z_i(q) + K_i (C_i z_i(q) - y_i(tau))``, uses
    ``r_i = y_i(tau) - C_i z_i(q)``.  The consensus sub-rounds move ``z_i`` only inside agent i's unobservable
    subspace (``z_i + P_i (avg - z_i)``, and ``C_i P_i = 0``), so ``C_i z_i(q) = C_i x_i(tau)`` and
    ``r_i = C_i e_i(tau) + w_i(tau)``, ``e_i = x - x_i``.  The whole-state design updates ``x_i(tau)`` itself
    (``r_i`` the same), and so does continuous time's sampled-data form (``K_i (C_i x_i(k) - y_i(k))``).

Its covariance (the design's prediction)
    ``S_i = C_i Sigma_ii C_i' + R_i`` with ``Sigma`` the steady state of the full error system
    ``e(tau+1) = M e(tau) + noise`` (``Sigma = M Sigma M' + N``,
    :func:`splitspec_core.synthesis.error_matrix.error_dynamics`); ``e(tau)`` is independent of ``w_i(tau)``.
    With several graphs (switching) each agent takes, conservatively, the graph whose ``C_i Sigma_ii C_i'`` has the
    largest trace (each graph held constant).

The test
    ``d_i = r_i' S_i^-1 r_i``, chi-square with ``s_i`` degrees of freedom for Gaussian noise at the steady state;
    the measurement fails when ``d_i > chi2.ppf(1 - false_alarm, s_i)`` and is not used (the agent's update
    without a measurement, :func:`splitspec_core.model.steps.prediction_update`).  ``S_i^-1`` and the threshold are
    computed here once and sent to each agent process (:func:`agent_config`), so the agents and the simulator use
    the same floats.

Warm-up
    ``S_i`` is the steady state's: an agent's first measurements after its admission (a fresh estimate) are used
    untested, ``warmup`` of them, as many as the event times the certified envelope takes to fall by ``10^3``
    (``ceil(ln 1000 / -ln lam)`` event times in discrete time, ``ceil(ln 1000 / (lam dt))`` steps in continuous
    time); else the initial error fails every test and the agent, using no measurement, never settles.  Counted
    in measurements, not event times (:func:`splitspec_core.model.steps.warmup_step`): an estimate does not settle
    before its measurements come, and a stream may start late (a live sensor started after the run, a recorded
    file whose first rows are empty: counted in event times, every agent's first measurements failed, all its
    sensors became suspect and none was ever restored).  In the whole-state design any agent's rejoin starts it
    again for every sensor not suspect (:meth:`splitspec_core.model.screening.Screen.rejoined`: the fresh estimate's
    error reaches the neighbours' measured directions through the average; the split's consensus does not touch
    them).

Suspect and restored (:func:`splitspec_core.model.steps.sensor_watch`)
    ``suspect_after = k`` failed tests in a row make the sensor suspect: from the next event time its agent uses no
    measurement and takes its neighbours' whole estimate (``P_i = I`` in its consensus sub-rounds, ``K_i = 0``; the
    whole-state design has ``P_i = I`` already); it keeps testing, against the same ``S_i``, and ``k`` clean tests in
    a row restore it.

The fallback's certificate (:func:`fallback_radius`)
    Per agent i and per graph held constant: the full error matrix with agent i in that mode (``K_i = 0``,
    ``P_i = I``), its spectral radius against the rate (continuous split: the sampled-data form's decay rate
    ``-log rho / dt`` against ``lam``).  Certified when it meets the rate on every graph; "can be lost at a slower
    rate" when it is stable but slower; else the sensor cannot be lost, and the line says why (what only that
    sensor sees, :meth:`~splitspec_core.synthesis.design_data.Design.unobserved_of`).  Nothing else is claimed: a
    spectral radius per constant graph is not a certificate under switching.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..errors import DesignError
from .design_data import Design, cached_analysis
from .error_matrix import MAX_NOISE_DIM, error_dynamics, full_error_matrix

#: the design kinds without a bad-data test (scenarios/design_section.py refuses design.bad_data given with them)
NO_TEST_KINDS = ("fusion", "relay")

#: how far inside the unit circle (per step; continuous split: times run.dt, of the decay rate) a fallback's radius
#: must be to count as decaying: an eigenvalue of modulus 1 comes out within ~1e-15 of it either way
STABLE_MARGIN = 1e-9

__all__ = ["SensorTest", "Fallback", "BadData", "bad_data", "default_off_reason", "agent_config", "fallback_radius",
           "report_lines"]


@dataclass(frozen=True)
class SensorTest:
    """Agent ``agent``'s test: ``S`` (s_i x s_i) the predicted innovation covariance, ``S_inv`` its inverse,
    ``threshold`` the chi-square quantile, ``graph`` the graph whose steady state gave ``S``."""

    agent: int
    S: np.ndarray
    S_inv: np.ndarray
    threshold: float
    graph: str


@dataclass(frozen=True)
class Fallback:
    """Agent ``agent``'s sensor lost (its agent in the fallback mode): ``radius`` per graph (discrete, whole-state:
    spectral radius; continuous split: decay rate), ``certified`` (the rate met on every graph), ``stable``, and
    the one-line ``text``."""

    agent: int
    radius: dict
    certified: bool
    stable: bool
    text: str


@dataclass(frozen=True)
class BadData:
    """The design's bad-data detection (module docstring): the options and each agent's test and fallback."""

    false_alarm: float
    suspect_after: int
    warmup: int
    tests: tuple
    fallbacks: tuple
    flatline: bool = True

    def test_of(self, agent_id: int) -> SensorTest:
        """Agent ``agent_id``'s :class:`SensorTest`.

        Parameters
        ----------
        agent_id : int
            An agent of the design.

        Returns
        -------
        SensorTest
            Its covariance, inverse and threshold.
        """
        return next(t for t in self.tests if t.agent == agent_id)


def _S_of(sc, graph_index: int) -> np.ndarray:
    """The consensus matrix ``S`` (m x m, agent order) of the scenario's graph ``graph_index``, every agent alive."""
    from ..model.network import consensus_rows

    pos = {a: k for k, a in enumerate(sc.agent_ids)}
    S = np.zeros((sc.m, sc.m))
    for i, (nbs, ws) in consensus_rows(sc, graph_index, sc.agent_ids).items():
        for j, w in zip(nbs, ws):
            S[pos[i], pos[j]] = w
    return S


def _used_graphs(sc) -> list:
    """``[(index, name)]`` of the graphs the switching signal uses, in scenario order."""
    used = set(sc.switching.graph_names(sc.graph_names))
    return [(k, name) for k, name in enumerate(sc.graph_names) if name in used]


def fallback_radius(des: Design, agent_id: int, graph_index: int) -> float:
    """The decay of the full error matrix of graph ``graph_index`` (held constant) with agent ``agent_id`` in the
    fallback mode: ``K_i = 0`` (no measurement), ``P_i = I`` (its neighbours' whole estimate).

    Parameters
    ----------
    des : Design
        The design (fixed g in continuous time with the split design).
    agent_id : int
        The agent whose sensor is set aside.
    graph_index : int
        One of the scenario's graphs (scenario order).

    Returns
    -------
    float
        Discrete time and the whole-state design: the spectral radius (must be below the rate); continuous time
        with the split design: ``-log rho / run.dt``, the sampled-data form's decay rate (must be at least the
        rate).
    """
    sc = des.scenario
    k = sc.agent_ids.index(agent_id)
    Ks = [np.asarray(K, dtype=float) for K in des.Ks]
    Ps = [np.asarray(P, dtype=float) for P in des.Ps]
    Ks[k] = np.zeros_like(Ks[k])
    Ps[k] = np.eye(sc.n)
    M = full_error_matrix(sc.system.A, [np.asarray(C) for C in sc.system.Cs], Ks, Ps, _S_of(sc, graph_index),
                          time=sc.time, q=des.q, g=des.g, dt=sc.run.dt, consensus=des.consensus)
    rho = float(np.max(np.abs(np.linalg.eigvals(M))))
    if sc.time == "continuous" and des.consensus != "whole":
        return -math.log(rho) / sc.run.dt if rho > 0 else math.inf
    return rho


def _fallback(des: Design, agent_id: int, graphs: list) -> Fallback:
    sc = des.scenario
    per_rate = sc.time == "continuous" and des.consensus != "whole"
    radius = {name: fallback_radius(des, agent_id, gi) for gi, name in graphs}
    lam = des.rate
    target, against = lam, f"rate {lam:g}"
    if sc.time == "continuous" and not per_rate:  # the whole-state design's per-step radius: exp(-rate run.dt)
        target = math.exp(-lam * sc.run.dt)
        against = f"exp(-rate dt) = {target:.5g} (rate {lam:g} {sc.system.per_time})"
    # directions only this sensor sees that do not decay: the fallback's radius is 1 there, which round-off may
    # put a hair either side (1 - 4e-16 under one OpenBLAS kernel): the detectability analysis decides, not it
    others = [a for a in sc.agent_ids if a != agent_id]
    un = des.unobserved_of(others)
    blind = bool(un.dim) and not un.decays
    if per_rate:
        certified = not blind and all(r >= lam for r in radius.values())
        stable = not blind and all(r > STABLE_MARGIN / sc.run.dt for r in radius.values())
        worst = min(radius.values())
        what = f"decay rate {worst:.4g}"
    else:
        certified = not blind and all(r <= target for r in radius.values())
        stable = not blind and all(r < 1 - STABLE_MARGIN for r in radius.values())
        worst = max(radius.values())
        what = f"radius {worst:.4g}"
    scope = "every graph held constant" if len(graphs) > 1 else f"graph {graphs[0][1]}"
    if certified:
        text = f"agent {agent_id}'s sensor can be lost: {what} meets {against} ({scope})"
    elif stable:
        text = (f"agent {agent_id}'s sensor can be lost at a slower rate: {what} against {against} ({scope}); "
                "not certified at the rate")
    else:
        why = (f"the others leave {un.dim} direction{'s' if un.dim != 1 else ''} unobserved that do not decay "
               "(only this sensor sees them)" if blind else f"{what}: the fallback is unstable")
        text = f"agent {agent_id}'s sensor cannot be lost: {why}"
    return Fallback(agent_id, radius, certified, stable, text)


@cached_analysis  # once per design: one Lyapunov equation per graph, one eigenvalue problem per agent and graph
def bad_data(des: Design) -> BadData | None:
    """The bad-data detection of a design whose scenario asks for it (``design.bad_data``; module docstring).

    On by default when the scenario states measurement noise (``DesignSpec.bad_data_default``): then a design that
    cannot calibrate the test (the reasons below, an output without noise, or ``design.consensus: fusion`` or
    ``relay``, which have none) has it off, and :func:`report_lines` says why; given explicitly, those refuse.

    Parameters
    ----------
    des : Design
        The design; its scenario's noise and graphs give ``S_i``.

    Returns
    -------
    BadData or None
        Every agent's test and its sensor's fallback; None when ``design.bad_data`` is off.

    Raises
    ------
    DesignError
        No steady state to calibrate against: the adaptive gain, ``design.undetectable: exclude`` (directions that
        do not decay), an error system too large for the Lyapunov equation, an unstable error map, or a singular
        ``S_i`` (only when ``design.bad_data`` is given; by default the test is then off).
    """
    d = des.scenario.design
    if d.bad_data is None or (d.bad_data_default and des.consensus in NO_TEST_KINDS):
        return None
    try:
        return _calibrated(des)
    except DesignError:
        if d.bad_data_default:
            return None
        raise


def default_off_reason(des: Design) -> str | None:
    """Why a test that is on by default (the scenario states measurement noise, ``design.bad_data`` absent) is off
    for ``des``, in words; None when it is on or not on by default.

    Parameters
    ----------
    des : Design
        The design.

    Returns
    -------
    str or None
        The reason (an output without noise, a kind without the test, or the design's own error line).
    """
    d = des.scenario.design
    if not d.bad_data_default or bad_data(des) is not None:
        return None
    if d.bad_data is None:
        return "system.measurement_noise is 0 on some output: the test is calibrated against it"
    if des.consensus in NO_TEST_KINDS:
        return f"design.consensus: {des.consensus} has no bad-data test"
    try:
        _calibrated(des)
    except DesignError as exc:
        return str(exc).removeprefix("design.bad_data ").removeprefix("design.bad_data: ")
    return None  # (not reached: bad_data would have been on)


def _calibrated(des: Design) -> BadData:
    """The test and the fallbacks of :func:`bad_data`, or the :class:`DesignError` saying why none can be had."""
    import scipy.linalg as sla
    from scipy.stats import chi2

    sc = des.scenario
    p, k = sc.design.bad_data
    if des.adaptive:
        raise DesignError("design.bad_data needs the error's steady state, and the adaptive gain has none (g changes "
                          "with time): give design.g a number or auto")
    if des.excluded:
        raise DesignError("design.bad_data needs the error's steady state, and design.undetectable: exclude leaves "
                          "directions that do not decay")
    if sc.m * sc.n > MAX_NOISE_DIM:
        raise DesignError(f"design.bad_data: the steady state of m n = {sc.m * sc.n} errors is beyond "
                          f"{MAX_NOISE_DIM} (one Lyapunov equation of that size)")
    graphs = _used_graphs(sc)
    Rs = sc.system.measurement_covariances
    Cs = [np.asarray(C, dtype=float) for C in sc.system.Cs]
    best: list = [None] * sc.m  # per agent: (trace, C Sigma_ii C', graph name)
    n = sc.n
    for gi, name in graphs:
        M, N = error_dynamics(des, gi)
        if np.max(np.abs(np.linalg.eigvals(M))) >= 1.0:
            raise DesignError(f"design.bad_data: the error map of graph {name} is unstable, no steady state")
        Sigma = sla.solve_discrete_lyapunov(M, N)  # Sigma = M Sigma M' + N
        for a, C in enumerate(Cs):
            CSC = C @ Sigma[a * n:(a + 1) * n, a * n:(a + 1) * n] @ C.T
            if best[a] is None or np.trace(CSC) > best[a][0]:
                best[a] = (float(np.trace(CSC)), CSC, name)
    tests = []
    for a, (aid, C) in enumerate(zip(sc.agent_ids, Cs)):
        S = best[a][1] + Rs[a]  # S_i = C_i Sigma_ii C_i' + R_i
        S = 0.5 * (S + S.T)
        if np.min(np.linalg.eigvalsh(S)) <= 0:
            raise DesignError(f"design.bad_data: agent {aid}'s innovation covariance is singular")
        tests.append(SensorTest(aid, S, np.linalg.solve(S, np.eye(S.shape[0])), float(chi2.isf(p, C.shape[0])),
                                best[a][2]))
    fallbacks = tuple(_fallback(des, aid, graphs) for aid in sc.agent_ids)
    lam = des.rate
    settle = math.log(1e3) / (-math.log(lam) if sc.time == "discrete" else lam * sc.run.dt)
    # the repeat test (model/steps.py flatline) on the plant's and a file's measurements; a live sensor slower than
    # the rounds gives the same sample twice (agents/sensor.py LiveSampler.take), so not there
    return BadData(p, k, int(math.ceil(settle)), tuple(tests), fallbacks, flatline=not sc.sources)


def agent_config(des: Design, process) -> dict:
    """What an agent's process needs of the test: its configuration's ``bad_data`` field, none when off.

    Parameters
    ----------
    des : Design
        The design.
    process : object
        Who asks for its configuration: ``.role`` (``agent``, or another process: nothing) and ``.ident`` (the
        agent's id).

    Returns
    -------
    dict
        ``{"bad_data": {"S_inv": nested list, "threshold": float, "suspect_after": int, "warmup": int, "flatline":
        bool}}``: the
        numbers the simulator uses; ``{}`` when ``design.bad_data`` is off.
    """
    bd = bad_data(des)
    if bd is None or process.role != "agent":
        return {}
    t = bd.test_of(process.ident)
    return {"bad_data": {"S_inv": t.S_inv.tolist(), "threshold": t.threshold, "suspect_after": bd.suspect_after,
                         "warmup": bd.warmup, "flatline": bd.flatline}}


def report_lines(des: Design) -> list:
    """The design report's lines on bad data: the test, then one line per sensor on its loss.

    Parameters
    ----------
    des : Design
        The design.

    Returns
    -------
    list of str
        Empty when ``design.bad_data`` is off; when it is on by default, first the line that says so; when the
        default is off for this design, the one line saying why.
    """
    bd = bad_data(des)
    if bd is None:
        why = default_off_reason(des)
        return [] if why is None else [f"bad-data test: off ({why}; on by default when the scenario states "
                                       "measurement noise)"]
    thresholds = {t.S.shape[0]: t.threshold for t in bd.tests}
    steps = "event times" if des.time == "discrete" else f"steps of run.dt = {des.scenario.run.dt:g}"
    which = ", ".join(f"{v:.4g} for s_i = {s}" for s, v in sorted(thresholds.items()))
    lines = [f"bad data: each agent tests r_i' S_i^-1 r_i against chi2(s_i) at false alarm {bd.false_alarm:g} "
             f"(threshold {which}), its first {bd.warmup} measurements ({steps}) untested; suspect after "
             f"{bd.suspect_after} failures in a row, restored after {bd.suspect_after} clean tests"
             + ("; a measurement repeating the last one exactly fails (a stuck sensor)" if bd.flatline else
                "; no repeat test (live sensors may give a sample twice)")]
    lines += [f.text for f in bd.fallbacks]
    if des.scenario.design.bad_data_default:  # the first line says it is the default, the rest stand under it
        lines = ["bad-data test: on (default: the scenario states measurement noise; design.bad_data: off turns it "
                 "off)"] + lines
    return lines
