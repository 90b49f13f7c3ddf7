"""The full ``mn x mn`` error dynamics of a design: its matrices, their spectra, noise, and the certificate
of an approximate split.

The full error matrix of one step, for the agents of a case with consensus matrix ``S``:

discrete (eq. split-discrete-error)
    ``M = blkdiag(A + K_i C_i) W^q``,  ``W = I - P (I - Sbar)`` (the consensus sub-round), ``Sbar = S (x) I_n``;
continuous, sampled-data form (:mod:`.steps`)
    ``M = blkdiag(E + D K_i C_i) - g blkdiag(D P_i) (I - Sbar)``, ``E = exp(A dt)``, ``D = int_0^dt exp(A s) ds``;
    and the ODE's own matrix ``Abar - g P (I - Sbar)`` (eq. split_continuous_em).

With an exact observability split these have the spectrum of the split blocks (prop. error,
prop. errordis), which is what the certificates of :mod:`.bounds` use.  When a weakly observable
direction was left to consensus (:mod:`.observability`) the split holds only up to
``split_residual``: :func:`check_full` then checks the rate on these full matrices, for every case
held constant, raises an automatic q or g until they meet it, and says so.

Steady-state noise (:func:`predicted_rms`): with process noise ``v`` (covariance ``Q``) and measurement
noise ``w`` (``R``) the stacked error follows ``e(k+1) = M e(k) - blkdiag(K_i) w(k) - (1 (x) I) v(k)``
(discrete; the sampled-data analogue in continuous time), and its steady-state covariance solves the
discrete Lyapunov equation ``Sigma = M Sigma M' + N``; agent i's RMS error is ``sqrt(trace Sigma_ii)``
(what a long simulation's RMS converges to: tested).
"""

from __future__ import annotations

import math
import re
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:  # the designer imports this module
    from .designer import Design

__all__ = ["full_error_matrix", "ode_error_matrix", "modulo", "full_radius", "check_full", "error_dynamics",
           "predicted_rms", "MAX_DIM", "MAX_RATE_DIM", "SPLIT_EXACT"]

#: the largest ``m n`` for which the full error matrices' powers and Lyapunov equations are formed (the transient
#: constant, the predicted noise)
MAX_DIM = 1000
#: the largest ``m n`` for which an approximate split's rate is checked on the full error matrices (their
#: eigenvalues only: a few seconds per graph at 2000)
MAX_RATE_DIM = 2000
#: a split residual below this is round-off: the split is exact
SPLIT_EXACT = 1e-9


def block_diagonal(blocks) -> np.ndarray:
    """Block diagonal that keeps zero-width blocks (``V_i`` with ``n_i = 0``) as rows (numpy only: agent
    processes import this module and never scipy)."""
    out = np.zeros((sum(b.shape[0] for b in blocks), sum(b.shape[1] for b in blocks)))
    r = c = 0
    for b in blocks:
        out[r:r + b.shape[0], c:c + b.shape[1]] = b
        r += b.shape[0]
        c += b.shape[1]
    return out


def full_error_matrix(A: np.ndarray, Cs, Ks, Ps, S: np.ndarray, *, time: str, q: int | None = None,
                      g: float | None = None, dt: float | None = None) -> np.ndarray:
    """The full error matrix of one event time (discrete) or one sampled-data step (continuous); module docstring."""
    A = np.asarray(A, dtype=float)
    n, m = A.shape[0], len(Cs)
    SI = np.kron(S, np.eye(n))
    if time == "discrete":
        W = np.eye(m * n) - block_diagonal(Ps) @ (np.eye(m * n) - SI)  # eq. (split-discrete-p1..p3), one sub-round
        return block_diagonal([A + K @ C for K, C in zip(Ks, Cs)]) @ np.linalg.matrix_power(W, int(q))
    from ..scenarios.sampling import sampled_data_matrices

    E, D, _ = sampled_data_matrices(A, dt)
    return (block_diagonal([E + D @ K @ C for K, C in zip(Ks, Cs)])
            - g * block_diagonal([D @ P for P in Ps]) @ (np.eye(m * n) - SI))


def modulo(M: np.ndarray, W: np.ndarray, m: int) -> np.ndarray:
    """The error map ``M`` (every agent's error stacked) modulo the directions ``W`` (orthonormal, A-invariant, no agent
    sees them): ``(I_m (x) U_o') M (I_m (x) U_o)`` with ``U_o`` spanning ``W^⊥``.  ``M`` is block triangular in the
    coordinates ``(U_o' e_i, W' e_i)`` (:mod:`splitspec_core.model.detectability`), so this is the map of the quotient's
    errors, whatever ``W``'s part does."""
    from ..model.subspaces import complement

    if W.shape[1] == 0:
        return M
    T = np.kron(np.eye(m), complement(W))
    return T.T @ M @ T


def ode_error_matrix(A: np.ndarray, Cs, Ks, Ps, S: np.ndarray, g: float) -> np.ndarray:
    """``Abar - g P (I - Sbar)`` (eq. split_continuous_em)."""
    n, m = np.shape(A)[0], len(Cs)
    return (block_diagonal([np.asarray(A) + K @ C for K, C in zip(Ks, Cs)])
            - g * block_diagonal(Ps) @ (np.eye(m * n) - np.kron(S, np.eye(n))))


def _case_parts(des: "Design", case):
    sc = des.scenario
    ad = {a.id: a for a in des.agents}
    Cs = dict(zip(sc.agent_ids, sc.system.Cs))
    ids = case.graph.ids
    return ([np.asarray(Cs[i]) for i in ids], [ad[i].K for i in ids], [ad[i].P for i in ids])


def full_radius(des: "Design", cases, *, q: int | None = None, g: float | None = None) -> dict:
    """Per case: the full error matrix's decay, in the certificate's terms.

    Discrete: the spectral radius of ``M`` (must be below ``lam``).  Continuous: ``{"ode": spectral
    abscissa of Abar - g P (I - Sbar)`` (must be at most ``-lam``), ``"sampled": -log rho(M) / dt`` (the decay
    rate of the sampled-data form, at least ``lam``)}.
    """
    sc = des.scenario
    A = np.asarray(sc.system.A)
    out = {}

    def mod(M, k):  # design.undetectable: exclude: what the certificate covers is the error modulo W
        return modulo(M, des.unobserved.W, k) if des.excluded else M

    for case in cases:
        Cs, Ks, Ps = _case_parts(des, case)
        if sc.time == "discrete":
            M = mod(full_error_matrix(A, Cs, Ks, Ps, case.graph.S, time="discrete", q=q), len(Cs))
            out[case.label] = float(np.max(np.abs(np.linalg.eigvals(M))))
        else:
            ode = float(np.max(np.linalg.eigvals(mod(ode_error_matrix(A, Cs, Ks, Ps, case.graph.S, g),
                                                     len(Cs))).real))
            M = mod(full_error_matrix(A, Cs, Ks, Ps, case.graph.S, time="continuous", g=g, dt=sc.run.dt), len(Cs))
            rho = float(np.max(np.abs(np.linalg.eigvals(M))))
            out[case.label] = {"ode": ode, "sampled": -math.log(rho) / sc.run.dt if rho > 0 else math.inf}
    return out


def check_full(des: "Design", warnings: list) -> "Design":
    """An approximate split (a weakly observable direction left to consensus): the rate on the full error matrices.

    Prop. error (and errordis) split the spectrum exactly only when every V_i is an exact unobservable space;
    with ``split_residual`` above round-off the certificates' split blocks are an approximation, so the
    rate is checked on the full error matrix of every case held constant (:func:`full_radius`).
    No switching certificate of the paper covers an approximate split.
    """
    import dataclasses

    sc = des.scenario
    worst = max([a.dec.weak for a in des.agents] + [des.split_residual])
    who = ", ".join(str(a.id) for a in des.agents if a.dec.weak > 0) or "every"
    note = (f"agent(s) {who} left a weakly observable direction (margin up to {worst:.2g}) to consensus: the split "
            f"of the error dynamics holds up to {des.split_residual:.2g}")
    if sc.m * sc.n > MAX_RATE_DIM:  # the certificate then says it covers the split blocks only (report.py)
        warnings.append(f"{note}; the full error matrices (m n = {sc.m * sc.n} > {MAX_RATE_DIM}) were not checked")
        return dataclasses.replace(des, warnings=tuple(warnings))
    full = full_radius(des, des.cases, q=des.q, g=des.g)
    warnings.append(f"{note}; the rate is checked on the full error matrix of each graph held constant")
    des = dataclasses.replace(des, full_radius=full, warnings=tuple(warnings))
    if not _full_meets(des, full):
        des = _raise_to_full(des, warnings)
    if not _full_meets(des, des.full_radius):
        if des.time == "continuous" and max(v["ode"] for v in des.full_radius.values()) > -des.envelope_rate:
            # sampled_rates.py's run.dt advice was computed on the split blocks: no run.dt helps when the ODE misses
            warnings[:] = [w for w in warnings if not re.match(r"(the sampled-data estimator is UNSTABLE with g|"
                                                              r"with run\.dt = \S+ the sampled-data estimator)", w)]
        weakest = min([a.dec.weak for a in des.agents if a.dec.weak > 0] or [des.split_residual])
        warnings.append(f"leaving agent(s) {who}'s weak directions to consensus misses the rate on the full error "
                        f"matrix even with more consensus: if the model is accurate to better than {weakest:.2g}, set "
                        f"design.rank_tol below that (e.g. {weakest / 10:.1g}) to count them (larger local gains)")
        des = dataclasses.replace(des, warnings=tuple(warnings))
    return des


def _full_meets(des: "Design", full: dict) -> bool:
    rate = des.envelope_rate  # lam, or slower when directions no agent sees limit it (they are in the full matrix)
    if des.time == "discrete":
        return max(full.values()) < rate
    return max(v["ode"] for v in full.values()) <= -rate and min(v["sampled"] for v in full.values()) >= rate


def _raise_to_full(des: "Design", warnings: list) -> "Design":
    """An automatic q or g that the full error matrices miss (an approximate split): raised until they meet the rate.

    The split's own certificate chose q (or g) on the split blocks; with the split only approximate the
    coupling it leaves can take the full matrix past the rate, and more consensus (a larger q, a larger g)
    is what brings it back.  Discrete: q + 1, q + 2, ... up to ``min(design.q_max, 4 q + 64)``; continuous:
    g grown by 25 % at a time (from the rate when the split's g is 0), up to 100 times the split's g, stopping
    early when four raises in a row do not improve the full matrix's abscissa (the weak directions then couple
    through the local gains, which no consensus undoes: 21 raises cost a minute at m n = 1600).  A q or g the
    user gave is left alone (the certificate then says it misses the rate).
    """
    import dataclasses

    from . import bounds

    sc = des.scenario
    d = sc.design
    if des.time == "discrete":
        if d.q != "auto":
            return des
        for q in range(des.q + 1, min(d.q_max, 4 * des.q + 64) + 1):
            full = full_radius(des, des.cases, q=q)
            if _full_meets(des, full):
                result = bounds.choose_q(d.q_method, des.cases, d.rate, q=q, q_max=d.q_max)
                warnings.append(f"q raised from {des.q} to {q}: with the approximate split, q = {des.q} leaves the full "
                                f"error matrix's spectral radius at {max(des.full_radius.values()):.4g} >= rate {d.rate:g}")
                return dataclasses.replace(des, q=q, q_result=result, full_radius=full, warnings=tuple(warnings),
                                           error_radius={c.label: bounds.error_radius(c, q) for c in des.cases})
        return des
    if d.g != "auto":
        return des
    g = des.g if des.g > 0 else d.rate / 1.25
    best, stale = max(v["ode"] for v in des.full_radius.values()), 0
    for _ in range(21):
        g *= 1.25
        full = full_radius(des, des.cases, g=bounds.nice_ceil(g))
        ode = max(v["ode"] for v in full.values())
        best, stale = (ode, 0) if ode < best - 1e-9 * max(1.0, abs(best)) else (best, stale + 1)
        if stale == 4:
            break
        if _full_meets(des, full):
            g = bounds.nice_ceil(g)
            worst = max(v["ode"] for v in des.full_radius.values())
            warnings.append(f"g raised from {des.g:g} to {g:g}: with the approximate split, g = {des.g:g} leaves the full "
                            f"error matrix's spectral abscissa at {worst:.4g} > -{d.rate:g}")
            return dataclasses.replace(des, g=g, full_radius=full, warnings=tuple(warnings),
                                       error_radius={c.label: bounds.abscissa(c, g) for c in des.cases})
    return des


def error_dynamics(des: "Design", graph_index: int = 0) -> tuple:
    """``(M, N)``: the full error matrix of the scenario's graph ``graph_index`` held constant, every agent,
    and the covariance of the noise entering per step (module docstring)."""
    from ..model.plant import sampled_model
    from ..errors import DesignError
    from ..model.network import consensus_rows

    sc = des.scenario
    m, n = sc.m, sc.n
    _, Qn, R = sampled_model(sc)
    rows = consensus_rows(sc, graph_index, sc.agent_ids)
    pos = {a: k for k, a in enumerate(sc.agent_ids)}
    S = np.zeros((m, m))
    for i, (nbs, ws) in rows.items():
        for j, w in zip(nbs, ws):
            S[pos[i], pos[j]] = w
    Ks = [np.asarray(K) for K in des.Ks]
    Cs = [np.asarray(C) for C in sc.system.Cs]
    Ps = [np.asarray(P) for P in des.Ps]
    if sc.time == "discrete":
        M = full_error_matrix(sc.system.A, Cs, Ks, Ps, S, time="discrete", q=des.q)
        G = block_diagonal(Ks)
    else:
        if des.g is None:
            raise DesignError("the adaptive gain has no steady-state error covariance (g changes with time)")
        from ..scenarios.sampling import sampled_data_matrices

        M = full_error_matrix(sc.system.A, Cs, Ks, Ps, S, time="continuous", g=des.g, dt=sc.run.dt)
        _, D, _ = sampled_data_matrices(np.asarray(sc.system.A), sc.run.dt)
        G = block_diagonal([D @ K for K in Ks])
    one = np.kron(np.ones((m, 1)), np.eye(n))
    N = G @ R @ G.T + one @ Qn @ one.T
    return M, 0.5 * (N + N.T)


def predicted_rms(des: "Design", graph_index: int = 0) -> np.ndarray:
    """Steady-state RMS error ``sqrt(trace Sigma_ii)`` of every agent (inf if the error map is unstable)."""
    import scipy.linalg as sla

    sc = des.scenario
    M, N = error_dynamics(des, graph_index)
    if des.excluded:  # the error modulo the directions no agent sees, which do not decay (design.undetectable: exclude)
        M, N = modulo(M, des.unobserved.W, sc.m), modulo(N, des.unobserved.W, sc.m)
    if np.max(np.abs(np.linalg.eigvals(M))) >= 1.0:
        return np.full(sc.m, math.inf)
    Sigma = sla.solve_discrete_lyapunov(M, N)
    n = M.shape[0] // sc.m
    return np.sqrt(np.maximum([np.trace(Sigma[i * n:(i + 1) * n, i * n:(i + 1) * n]) for i in range(sc.m)], 0.0))
