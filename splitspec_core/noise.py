"""Estimation quality under noise: the exact steady-state error covariance of a design, and tuning.

The split-spectrum estimators are linear, so with a constant graph the stacked
error ``e = (x_1 - x, ..., x_m - x)`` follows ``e(k+1) = M e(k) + noise``:

discrete (eqs. split-discrete-est1..p3)
    ``e(k+1) = blkdiag(A + K_i C_i) W^q e(k) - blkdiag(K_i) w(k) - (1 (x) I) v(k)``
    with the consensus sub-round ``W = blkdiag(I - P_i) + blkdiag(P_i) (S (x) I)``;
continuous, sampled-data form (see :mod:`splitspec_core.steps`)
    ``e(k+1) = [blkdiag(E + D K_i C_i) - g blkdiag(D P_i) (I - S (x) I)] e(k)
    - blkdiag(D K_i) w(k) - (1 (x) L) v(k)``

with ``w`` the measurement noise (covariance ``R = sigma_m^2 I``) and ``v``
the process noise (covariance ``Q``, the plant's, see
:class:`splitspec_core.simulator.Plant`).  The steady-state covariance solves
the discrete Lyapunov equation ``Sigma = M Sigma M' + N``; agent i's RMS error
is ``sqrt(trace Sigma_ii)``.  No simulation, no sampling error: this is what
a long simulation's RMS converges to (tested).

:func:`tune` searches q (discrete) or g (continuous) and the gain design
(``place``, or ``riccati`` over a range of process/measurement weight ratios)
for the smallest predicted RMS among the candidates whose rate is still
certified by the design's own certificate.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import scipy.linalg as sla

from .designer import Design, design
from .errors import DesignError
from .network import consensus_rows
from .report import rate_certificate
from .scenario_model import Scenario

__all__ = ["error_dynamics", "predicted_rms", "TuneResult", "tune"]


def _S(sc: Scenario, graph_index: int) -> np.ndarray:
    rows = consensus_rows(sc, graph_index, sc.agent_ids)
    pos = {a: k for k, a in enumerate(sc.agent_ids)}
    S = np.zeros((sc.m, sc.m))
    for i, (nbs, ws) in rows.items():
        for j, w in zip(nbs, ws):
            S[pos[i], pos[j]] = w
    return S


def error_dynamics(des: Design, graph_index: int = 0) -> tuple:
    """``(M, N)``: error transition and noise covariance per step (see the module docstring)."""
    from .baselines import sampled_model

    sc = des.scenario
    m, n = sc.m, sc.n
    F, Q, R = sampled_model(sc)
    S = _S(sc, graph_index)
    SI = np.kron(S, np.eye(n))
    Ks = [np.asarray(K) for K in des.Ks]
    Cs = [np.asarray(C) for C in sc.system.Cs]
    Ps = [np.asarray(P) for P in des.Ps]
    if sc.time == "discrete":
        W = sla.block_diag(*[np.eye(n) - P for P in Ps]) + sla.block_diag(*Ps) @ SI
        M = sla.block_diag(*[F + K @ C for K, C in zip(Ks, Cs)]) @ np.linalg.matrix_power(W, int(des.q))
        G = sla.block_diag(*Ks)
    else:
        if des.g is None:
            raise DesignError("the adaptive gain has no steady-state error covariance (g changes with time)")
        from .steps import sampled_data_matrices

        E, D, _ = sampled_data_matrices(np.asarray(sc.system.A), sc.run.dt)
        M = (sla.block_diag(*[E + D @ K @ C for K, C in zip(Ks, Cs)])
             - des.g * sla.block_diag(*[D @ P for P in Ps]) @ (np.eye(m * n) - SI))
        G = sla.block_diag(*[D @ K for K in Ks])
    one = np.kron(np.ones((m, 1)), np.eye(n))
    N = G @ R @ G.T + one @ Q @ one.T
    return M, 0.5 * (N + N.T)


def predicted_rms(des: Design, graph_index: int = 0) -> np.ndarray:
    """Steady-state RMS error ``sqrt(trace Sigma_ii)`` of every agent (inf if the error map is unstable)."""
    sc = des.scenario
    M, N = error_dynamics(des, graph_index)
    if np.max(np.abs(np.linalg.eigvals(M))) >= 1.0:
        return np.full(sc.m, math.inf)
    Sigma = sla.solve_discrete_lyapunov(M, N)
    n = sc.n
    return np.sqrt(np.maximum([np.trace(Sigma[i * n:(i + 1) * n, i * n:(i + 1) * n]) for i in range(sc.m)], 0.0))


@dataclasses.dataclass(frozen=True)
class TuneResult:
    """The chosen design and every candidate tried.

    ``candidates``: list of dicts ``{gains, process_weight, measurement_weight, q or g, certified, rms}``
    (``rms``: root mean square over agents of the predicted steady-state RMS).
    """

    scenario: Scenario
    design: Design
    rms: float
    baseline_rms: float
    candidates: list


def _rms_all(des: Design) -> float:
    r = predicted_rms(des)
    return float(np.sqrt(np.mean(r ** 2)))


def tune(sc: Scenario, *, extra: int = 6, ratios=(1e-2, 1e-1, 1.0, 1e1, 1e2)) -> TuneResult:
    """Smallest predicted steady-state RMS subject to the rate (certified as the design certifies it).

    Candidates: gains ``place`` and ``riccati`` with process/measurement weights
    ``(r * sigma_p^2, sigma_m^2)`` for each ratio ``r`` (the Kalman choice is
    ``r = 1``); discrete: ``q`` from the certified one to ``q + extra``;
    continuous: ``g`` from the certified one to ``3 g`` (7 values).  The
    baseline is the scenario's own design.  The covariance is that of the
    first graph held constant (a switching scenario is tuned for it).
    """
    s = sc.system
    if s.process_noise <= 0 and s.measurement_noise <= 0:
        raise DesignError("tuning for noise needs system.process_noise or system.measurement_noise > 0")
    if sc.time == "continuous" and sc.design.g == "adaptive":
        raise DesignError("the adaptive gain cannot be tuned for noise (it has no steady state); give g")
    base = design(sc)
    baseline = _rms_all(base)
    pw0 = s.process_noise ** 2 if s.process_noise > 0 else 1e-6
    mw0 = s.measurement_noise ** 2 if s.measurement_noise > 0 else 1e-6
    gain_options = [("place", None, None)] + [("riccati", r * pw0, mw0) for r in ratios]
    cands = []
    best = None
    for gains, pw, mw in gain_options:
        d = dataclasses.replace(sc.design, gains=gains, K=None, q="auto" if sc.time == "discrete" else sc.design.q,
                                riccati_process_weight=pw, riccati_measurement_weight=mw)
        try:
            des0 = design(dataclasses.replace(sc, design=d))
        except DesignError:
            continue
        if sc.time == "discrete":
            values = [des0.q + k for k in range(extra + 1)]
        else:
            g0 = des0.g if des0.g is not None else 1.0
            values = [g0 * f for f in (1.0, 1.25, 1.5, 2.0, 2.5, 3.0)]
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
                best = (rms, des)
    if best is None:
        raise DesignError("no candidate design meets the rate")
    return TuneResult(scenario=best[1].scenario, design=best[1], rms=best[0], baseline_rms=baseline, candidates=cands)
