"""``splitspec compare --sweep-loss / --sweep-deadline``: what the practice shows on a network that misbehaves.

For each level of the swept parameter, Monte-Carlo simulations over ``seeds`` (the scenario's named streams,
so level ``p`` with seed ``s`` is exactly ``splitspec simulate`` of the scenario with that network and seed):

``loss``      every arc's loss probability is the level (per-arc loss overrides included; delays and the
              deadline as in the scenario);
``deadline``  the sub-round deadline is the level, with the scenario's delay distribution and losses
              (a message counts when its drawn delay is at most the deadline: ``simulate``'s emulation,
              :mod:`splitspec_core.model.impairment`).

Figures per level, each a mean over seeds (with its spread): the measured decay rate (noise-free run, the
tail fit of :func:`~splitspec_core.simulation.metrics.fit_decay` on the worst agent's error; the scenario's
convention, discrete ``lam^tau``, continuous ``exp(-lam t)``), how many seeds meet the designed rate, the
steady-state RMS error when the scenario has noise (:func:`~splitspec_core.simulation.metrics.steady_rms`), the
messages that did not count (per event time, and as a fraction of those sent), and the certificate under
loss of :mod:`splitspec_core.synthesis.loss_certificate` at that level.  Beside them: the designed rate and the
*lossless* figures (the same seeds on a perfect network).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from ..simulation.metrics import fit_decay, steady_rms
from ..synthesis.designer import design
from ..synthesis.loss_certificate import loss_certificate
from ..errors import DesignError, ScenarioError
from ..scenarios.specs import NetworkSpec, Scenario
from ..simulation.simulator import Progress, check_trajectory_memory, simulate

__all__ = ["check_sweep", "network_sweep", "sweep_table", "PARAMETERS", "MAX_LEVELS"]

PARAMETERS = ("loss", "deadline")
#: at most this many levels in one sweep (each costs seeds x one or two simulations)
MAX_LEVELS = 50


def _with_level(sc: Scenario, parameter: str, value) -> Scenario:
    net = sc.network
    if value is None:  # the lossless reference: a perfect network
        net = NetworkSpec()
    elif parameter == "loss":
        arcs = {a: {**o, "loss": float(value)} for a, o in net.arcs.items()}
        net = dataclasses.replace(net, loss=float(value), arcs=arcs)
    else:
        net = dataclasses.replace(net, deadline=float(value))
    return dataclasses.replace(sc, network=net)


def _messages_sent(traj, des, exchanges: int) -> int:
    """Consensus messages the run sends: per event time, ``q`` per arc between alive agents of the graph in use
    (an arc dropped by a ``drop_arc`` fault is counted as sent; such scenarios read the fraction as approximate)."""
    pos = {a: k for k, a in enumerate(des.scenario.agent_ids)}
    arcs = [np.array([(pos[j], pos[i]) for j, i in g.arcs], dtype=np.int64).reshape(-1, 2) for g in des.graphs]
    total = 0
    for k in range(len(traj.t) - 1):
        a = arcs[int(traj.graph[k])]
        al = traj.alive[k]
        total += int(np.count_nonzero(al[a[:, 0]] & al[a[:, 1]])) if len(a) else 0
    return total * exchanges


def _level(des, sc: Scenario, seeds, steps, noisy: bool, bar, done: list) -> dict:
    rates, rms, lost, sent = [], [], [], []
    exchanges = int(des.q) if des.two_rate else 1
    for s in seeds:
        clean = simulate(des, seed=s, steps=steps, noise=False)
        e = clean.errors()
        worst = np.full(e.shape[0], np.nan)
        ok = np.isfinite(e).any(axis=1)
        worst[ok] = np.nanmax(e[ok], axis=1)
        rates.append(fit_decay(clean.t, worst, time=sc.time, scale=np.linalg.norm(clean.x, axis=1)))
        lost.append(len(clean.lost))
        sent.append(_messages_sent(clean, des, exchanges))
        if noisy:
            rms.append(steady_rms(simulate(des, seed=s, steps=steps).errors()))
        done[0] += 1
        bar.update(done[0])
    steps_run = len(clean.t) - 1
    r = np.array([np.nan if x is None else x for x in rates], dtype=float)
    fitted = r[np.isfinite(r)]
    slower = (lambda x: x > des.rate) if sc.time == "discrete" else (lambda x: x < des.rate)
    worst_rate = None
    if fitted.size:
        worst_rate = float(fitted.max() if sc.time == "discrete" else fitted.min())
    return {
        "rate_mean": float(fitted.mean()) if fitted.size else None,
        "rate_std": float(fitted.std(ddof=1)) if fitted.size > 1 else 0.0 if fitted.size else None,
        "rate_worst": worst_rate,
        "rates": [None if not math.isfinite(x) else float(x) for x in r],
        # a seed whose error reached round-off too fast to fit (None) decayed at least as fast as anything fitted
        "meets_design": int(sum(1 for x in r if not math.isfinite(x) or not slower(x))),
        "rms_mean": float(np.mean(rms)) if rms else None,
        "rms_std": float(np.std(rms, ddof=1)) if len(rms) > 1 else (0.0 if rms else None),
        "lost_per_event": float(np.mean(lost)) / max(steps_run, 1),
        "lost_fraction": float(np.sum(lost) / np.sum(sent)) if np.sum(sent) else 0.0,
    }


def check_sweep(sc: Scenario, parameter: str, values) -> None:
    """Refuse a sweep that cannot say anything, in one line (:class:`DesignError`), before any work.

    Parameters
    ----------
    sc : Scenario
        Its ``network:`` (a deadline sweep needs delays).
    parameter : str
        ``loss`` or ``deadline``.
    values : sequence of float
        The levels.

    Raises
    ------
    DesignError
        No level or more than ``MAX_LEVELS``; a deadline sweep without ``network.delay``.
    """
    if not values or len(values) > MAX_LEVELS:
        raise DesignError(f"--sweep-{parameter}: give 1 to {MAX_LEVELS} levels, got {len(values)}")
    if parameter == "deadline" and not sc.network.delayed:
        raise DesignError("--sweep-deadline needs a delay distribution: set network.delay: {mean, jitter} in the "
                          "scenario (without delays every message is on time whatever the deadline)")


def network_sweep(sc: Scenario, parameter: str, values, *, seeds, steps: int | None = None,
                  progress: bool | None = None) -> dict:
    """Monte-Carlo figures of the design against ``loss`` or ``deadline`` levels (see the module docstring).

    Parameters
    ----------
    sc : Scenario
        The scenario (its ``network:`` is replaced by each level).
    parameter : str
        ``loss`` (probability a consensus message is lost) or ``deadline`` (seconds a message may be late).
    values : iterable of float
        The levels, in the order given.
    seeds : iterable of int
        The seeds of every level.
    steps : int, optional
        Default ``run.steps``.
    progress : bool, optional
        A progress bar on a terminal.

    Returns
    -------
    dict
        JSON-ready: ``lossless`` (the perfect network's figures) and one entry of ``rows`` per level (measured rates,
        steady RMS under noise, messages lost, the loss certificate's verdict and line).

    Raises
    ------
    ScenarioError
        ``parameter`` is neither ``loss`` nor ``deadline``.
    DesignError
        :func:`check_sweep` refuses the levels.

    Examples
    --------
    >>> import splitspec_core as ss
    >>> sw = ss.network_sweep(ss.load_scenario("examples/ring10_lossy.yaml"), "loss", [0, 0.2], seeds=range(2),
    ...                       steps=60)
    >>> [row["value"] for row in sw["rows"]], sw["q"]
    ([0.0, 0.2], 6)
    """
    if parameter not in PARAMETERS:
        raise ScenarioError(f"parameter must be one of {PARAMETERS}, got {parameter!r}")
    values = [float(v) for v in values]
    seeds = list(seeds)
    check_sweep(sc, parameter, values)
    check_trajectory_memory(sc, steps, key="--steps" if steps is not None else "run.steps")
    base = design(sc)
    noisy = sc.system.has_noise
    per_sim = 2 if noisy else 1
    bar = Progress((len(values) + 1) * len(seeds), progress, label=f"{parameter} sweep",
                    min_total=1 if per_sim * len(seeds) * (len(values) + 1) >= 20 else 10 ** 9)
    done = [0]
    lossless_sc = _with_level(sc, parameter, None)
    lossless = _level(dataclasses.replace(base, scenario=lossless_sc), lossless_sc, seeds, steps, noisy, bar, done)
    rows = []
    for v in values:
        sv = _with_level(sc, parameter, v)
        dv = dataclasses.replace(base, scenario=sv)  # the design does not depend on the network: only its use
        row = {"value": v, **_level(dv, sv, seeds, steps, noisy, bar, done)}
        cert = loss_certificate(dv)
        row.update(certified=bool(cert.certified) if cert is not None else True,
                   certificate=cert.text if cert is not None else "a perfect network: the design's own certificate")
        rows.append(row)
    return {"scenario": sc.name, "time": sc.time, "parameter": parameter, "values": values, "seeds": seeds,
            "steps": int(steps if steps is not None else sc.run.steps), "q": base.q, "g": base.g,
            "designed_rate": sc.design.rate, "noisy": noisy,
            "delay": {"mean": sc.network.delay_mean, "jitter": sc.network.delay_jitter},
            "loss": sc.network.loss, "deadline": sc.network.deadline, "lossless": lossless, "rows": rows}


def _fmt(x, spec: str = ".4g") -> str:
    return "-" if x is None else format(x, spec)


def sweep_table(sw: dict) -> list:
    """The printed table of a :func:`network_sweep`: one line per level, the lossless and designed rates above.

    Parameters
    ----------
    sw : dict
        A :func:`network_sweep` result.

    Returns
    -------
    list of str
        Three heading lines (what was swept, the designed and lossless figures, the column names), then one line
        per level.
    """
    p = sw["parameter"]
    conv = "lam^tau" if sw["time"] == "discrete" else "exp(-lam t)"
    what = ("every arc's loss probability" if p == "loss" else
            f"the sub-round deadline (s), delays {sw['delay']['mean']:g} +- {sw['delay']['jitter']:g} s, "
            f"loss {sw['loss']:g}")
    ll = sw["lossless"]
    n = len(sw["seeds"])
    lines = [f"{sw['scenario']}: {p} sweep over {what}; {n} seeds x {sw['steps']} steps"
             + (f", q = {sw['q']}" if sw["q"] is not None else ""),
             f"  designed rate {sw['designed_rate']:g} ({conv}); lossless: measured rate {_fmt(ll['rate_mean'])}"
             + (f", steady RMS {_fmt(ll['rms_mean'])}" if sw["noisy"] else ""),
             f"  {p:>9} {'lost/event':>10} {'lost %':>7} {'measured rate':>14} {'+-':>8} {'worst':>8} "
             f"{'meets':>6}" + (f" {'steady RMS':>10} {'+-':>8}" if sw["noisy"] else "") + "  certified"]
    for r in sw["rows"]:
        lines.append(f"  {r['value']:9g} {r['lost_per_event']:10.3g} {100 * r['lost_fraction']:7.2f} "
                     f"{_fmt(r['rate_mean']):>14} {_fmt(r['rate_std'], '.2g'):>8} {_fmt(r['rate_worst']):>8} "
                     f"{r['meets_design']:>3}/{n:<2}"
                     + (f" {_fmt(r['rms_mean']):>10} {_fmt(r['rms_std'], '.2g'):>8}" if sw["noisy"] else "")
                     + f"  {'yes' if r['certified'] else 'no'}")
    return lines
