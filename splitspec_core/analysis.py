"""Summaries of trajectories: errors per agent, measured decay rate, Monte Carlo statistics."""

from __future__ import annotations

import math

import numpy as np

from .simulate import Trajectory

__all__ = ["max_error", "fit_decay", "envelope_constant", "envelope_restarts", "envelope", "summarize",
           "monte_carlo_stats"]


def max_error(traj: Trajectory) -> np.ndarray:
    """``max_i |x_i(t) - x(t)|`` over alive agents, shape (T,) (NaN when nobody is alive)."""
    e = traj.errors()
    out = np.full(e.shape[0], np.nan)
    ok = np.any(np.isfinite(e), axis=1)
    out[ok] = np.nanmax(e[ok], axis=1)
    return out


def fit_decay(t: np.ndarray, err: np.ndarray, *, time: str, scale: np.ndarray | None = None,
              floor_rel: float = 1e-9) -> float | None:
    """Exponential decay measured over the tail of a noise-free error curve.

    Least-squares slope of ``log err`` against ``t`` over the second half of
    the samples above the round-off floor.  The floor is
    ``floor_rel * max(scale(t), max err)``: pass ``scale = |x(t)|`` since
    round-off grows with the state (an unstable plant makes it grow).  Returns
    the rate ``lam`` in the scenario's convention: continuous ``err ~ exp(-lam t)``,
    discrete ``err ~ lam^tau``; ``None`` with fewer than 6 usable samples.
    """
    err = np.asarray(err, dtype=float)
    ok = np.isfinite(err)
    if not ok.any():
        return None
    floor = floor_rel * max(np.nanmax(err), 1e-300)
    if scale is not None:
        floor = np.maximum(floor, floor_rel * np.asarray(scale, dtype=float))
    below = np.nonzero(~ok | (err <= floor))[0]
    end = below[0] if below.size else err.size
    start = end // 2
    if end - start < 6:
        return None
    slope = np.polyfit(t[start:end], np.log(err[start:end]), 1)[0]
    return -slope if time == "continuous" else math.exp(slope)


def envelope_constant(t: np.ndarray, err: np.ndarray, *, time: str, rate: float,
                      scale: np.ndarray | None = None, floor_rel: float = 1e-9) -> float:
    """Smallest ``c`` with ``err(t) <= c rate^t`` (discrete) or ``c exp(-rate t)`` (continuous).

    Samples at the round-off floor (``floor_rel * scale(t)``, as in
    :func:`fit_decay`) are ignored: there the error is float noise, not decay.
    """
    env = np.exp(-rate * t) if time == "continuous" else rate ** t
    err = np.asarray(err, dtype=float)
    if scale is not None:
        err = np.where(err > floor_rel * np.asarray(scale, dtype=float), err, np.nan)
    ratio = err / env
    return float(np.nanmax(ratio[np.isfinite(ratio)])) if np.isfinite(ratio).any() else float("nan")


def envelope_restarts(alive: np.ndarray, graph: np.ndarray) -> np.ndarray:
    """Steps where the designed envelope starts afresh: 0, every rejoin and every graph switch.

    A rejoining agent starts from a fresh estimate, so the guarantee (``|e| <= c lam^tau``, or
    ``c exp(-lam t)``) holds again from that step with a new constant; a switch moves the error
    dynamics to another matrix (``A_V(tau)``, eq. split_discrete_ench), whose certificate is its own.
    A loss alone does not restart it: the survivors' errors keep decaying.
    """
    alive = np.asarray(alive, dtype=bool)
    graph = np.asarray(graph)
    T = alive.shape[0]
    if T == 0:
        return np.zeros(0, dtype=int)
    rejoin = np.zeros(T, dtype=bool)
    rejoin[1:] = (alive[1:] & ~alive[:-1]).any(axis=1)
    switch = np.zeros(T, dtype=bool)
    switch[1:] = graph[1:] != graph[:-1]
    switch[0] = rejoin[0] = True
    return np.nonzero(rejoin | switch)[0]


def envelope(t: np.ndarray, err_max: np.ndarray, restarts, *, time: str, rate: float, fit: bool = False,
             scale: np.ndarray | None = None, floor_rel: float = 1e-9) -> np.ndarray:
    """The designed envelope, restarted at ``restarts`` (see :func:`envelope_restarts`), shape (T,).

    On each piece ``[k0, k1)``: ``c lam^(t - t_k0)`` (discrete) or ``c exp(-lam (t - t_k0))``
    (continuous).  ``fit=False`` (what a live recording can know): ``c = err_max[k0]``, the envelope
    starts at the error it restarts from.  ``fit=True`` (a finished trajectory): ``c`` is the
    smallest constant above the piece's errors (samples at the round-off floor
    ``floor_rel * scale`` ignored, as in :func:`envelope_constant`).  NaN where there is no error.
    """
    t = np.asarray(t, dtype=float)
    err = np.asarray(err_max, dtype=float)
    T = t.shape[0]
    env = np.full(T, np.nan)
    starts = [int(k) for k in restarts if 0 <= int(k) < T]
    if not starts or starts[0] != 0:
        starts = [0] + starts
    for a, k0 in enumerate(starts):
        k1 = starts[a + 1] if a + 1 < len(starts) else T
        dt = t[k0:k1] - t[k0]
        decay = np.exp(-rate * dt) if time == "continuous" else rate ** dt
        piece = err[k0:k1]
        if fit:
            sc = None if scale is None else np.asarray(scale, dtype=float)[k0:k1]
            c = envelope_constant(dt, piece, time=time, rate=rate, scale=sc, floor_rel=floor_rel)
        else:
            c = piece[0]
        if np.isfinite(c) and c > 0:
            env[k0:k1] = c * decay
    return env


def summarize(traj: Trajectory, *, time: str, rate: float, noise_free: Trajectory | None = None) -> dict:
    """Final and max error per agent, measured decay rate vs the designed rate, alive agents."""
    e = traj.errors()
    ref = noise_free if noise_free is not None else traj
    xnorm = np.linalg.norm(ref.x, axis=1)
    measured = fit_decay(ref.t, max_error(ref), time=time, scale=xnorm)
    per_agent = {}
    for k, aid in enumerate(traj.agent_ids.tolist()):
        col = e[:, k]
        finite = np.isfinite(col)
        per_agent[str(aid)] = {
            "final_error": float(col[-1]) if finite[-1] else None,
            "max_error": float(np.nanmax(col)) if finite.any() else None,
            "alive_at_end": bool(traj.alive[-1, k]),
        }
    meets = None
    if measured is not None:
        meets = bool(measured >= rate * (1 - 1e-3) if time == "continuous" else measured <= rate * (1 + 1e-3))
    return {
        "steps": int(traj.t.size - 1),
        "designed_rate": rate,
        "measured_rate": measured,
        "measured_meets_design": meets,
        "envelope_c": envelope_constant(ref.t, max_error(ref), time=time, rate=rate, scale=xnorm),
        "alive_at_end": [int(a) for a, ok in zip(traj.agent_ids, traj.alive[-1]) if ok],
        "agents": per_agent,
    }


def monte_carlo_stats(trajs: list, *, tail: float = 0.2) -> dict:
    """Mean and spread across seeds of the RMS error over agents.

    Returns per-time mean/std/10%/90% curves and scalar steady-state
    statistics over the last ``tail`` fraction of the run.
    """
    rms = np.stack([np.sqrt(np.nanmean(tr.errors() ** 2, axis=1)) for tr in trajs])  # (N, T)
    k0 = int((1 - tail) * rms.shape[1])
    steady = np.sqrt(np.mean(rms[:, k0:] ** 2, axis=1))  # per seed
    return {
        "seeds": len(trajs),
        "mean": rms.mean(axis=0),
        "std": rms.std(axis=0),
        "p10": np.percentile(rms, 10, axis=0),
        "p90": np.percentile(rms, 90, axis=0),
        "steady_rms_mean": float(steady.mean()),
        "steady_rms_std": float(steady.std()),
        "final_rms_mean": float(rms[:, -1].mean()),
        "final_rms_std": float(rms[:, -1].std()),
    }
