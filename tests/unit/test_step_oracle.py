"""An oracle that shares no code with the product (issue 44): for each estimator kind the simulator runs, the error
recursion is written out here from the paper's equations with plain numpy (block matrices, ``np.kron``, ``expm``), and
the simulator's noise-free errors, batched and looped, must follow it step by step.  Only the design's gains
(``K_i``, ``P_i``, ``g``, ``q``) and the graph's weights are taken from the product; ``run == simulate`` proves the
plumbing between processes, this proves the step itself.

The noise-free error ``e_i = x_i - x`` of every kind obeys ``e(k+1) = M e(k)`` with (``S`` the weights ``w_ij``,
``P = blkdiag(P_i)``, ``Sn = S kron I_n``):

* split, discrete (eqs. split-discrete-p1..p3, est1): ``M = blkdiag(A + K_i C_i) (I - P (I - Sn))^q``;
* split, continuous, sampled-data form: ``M = blkdiag(E + D K_i C_i) - g blkdiag(D P_i) (I - Sn)``;
* whole state (P_i = I, update then average): ``M = Sn^q blkdiag(A_s + K_s,i C_i)`` with ``A_s = A``, ``K_s,i = K_i``
  in discrete time and ``A_s = E``, ``K_s,i = D K_i`` on the sampled model;
* fusion (measure, fuse with matrix weights, predict): ``M = (I kron F) W(q) .. W(1) blkdiag(I - L_i C_i)``, ``F = A``
  or ``E``.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import scipy.linalg as sla

import splitspec_core as ss
from splitspec_core.simulation.simulator import simulate
from splitspec_core.synthesis.designer import design
from tests.conftest import EXAMPLES

STEPS = 6
# the recursion and the simulator multiply the same matrices in different orders and groupings: round-off only
REL = 1e-9


def _sampled(A: np.ndarray, dt: float) -> tuple:
    """``E = exp(A dt)``, ``D = int_0^dt exp(A s) ds`` from one exponential of the block matrix [[A, I], [0, 0]]."""
    n = A.shape[0]
    F = sla.expm(np.block([[A, np.eye(n)], [np.zeros((n, 2 * n))]]) * dt)
    return F[:n, :n], F[:n, n:]


def oracle_map(des, graph: int = 0) -> np.ndarray:
    """The full ``(m n) x (m n)`` error map of one event time on the scenario's graph number ``graph``, written from
    the paper (module docstring)."""
    sc = des.scenario
    A, Cs, n, m = np.asarray(sc.system.A), [np.asarray(C) for C in sc.system.Cs], sc.n, sc.m
    Sn = np.kron(des.graphs[graph].S, np.eye(n))
    I = np.eye(m * n)
    Ks = [np.asarray(K) for K in des.Ks]
    if des.consensus == "fusion":
        return _fusion_map(des, graph)
    if des.consensus == "whole":
        if sc.time == "discrete":
            As, Kss = A, Ks
        else:
            As, D = _sampled(A, sc.run.dt)
            Kss = [D @ K for K in Ks]
        local = sla.block_diag(*[As + K @ C for K, C in zip(Kss, Cs)])
        return np.linalg.matrix_power(Sn, int(des.q)) @ local
    P = sla.block_diag(*[np.asarray(P_i) for P_i in des.Ps])
    if sc.time == "discrete":
        local = sla.block_diag(*[A + K @ C for K, C in zip(Ks, Cs)])
        return local @ np.linalg.matrix_power(I - P @ (I - Sn), int(des.q))
    E, D = _sampled(A, sc.run.dt)
    return (sla.block_diag(*[E + D @ K @ C for K, C in zip(Ks, Cs)])
            - float(des.g) * sla.block_diag(*[D @ P_i for P_i in des.Ps]) @ (I - Sn))


def _fusion_map(des, graph: int) -> np.ndarray:
    """The fusion kind: ``M = (I kron F) W(q) .. W(1) blkdiag(I - L_i C_i)``, each ``W(k)`` assembled block by block
    from the agents' weights (``weights[k][i]``: ``[W_ij for j in N_i]`` side by side), ``F`` the per-step model."""
    sc = des.scenario
    n, m = sc.n, sc.m
    fd = des.whole.designs[graph]
    A = np.asarray(sc.system.A)
    F = A if sc.time == "discrete" else _sampled(A, sc.run.dt)[0]
    assert np.allclose(F, fd.F, rtol=1e-12, atol=1e-14)  # what the design runs is the plant's own step
    M = sla.block_diag(*[np.eye(n) - L @ np.asarray(C) for L, C in zip(fd.Ls, sc.system.Cs)])
    for Wk in fd.weights:
        W = np.zeros((m * n, m * n))
        for i, row in enumerate(Wk):
            for a, j in enumerate(fd.neighbours[i]):
                W[i * n:(i + 1) * n, j * n:(j + 1) * n] = row[:, a * n:(a + 1) * n]
        assert np.allclose(W @ np.kron(np.ones((m, 1)), np.eye(n)), np.kron(np.ones((m, 1)), np.eye(n)))  # sum to I
        M = W @ M
    return np.kron(np.eye(m), F) @ M


def _fused(sc, q: int = 2):
    return dataclasses.replace(sc, design=dataclasses.replace(sc.design, consensus="fusion", gains="optimal", q=q,
                                                              resilience=0, K=None))


def _ring_whole():
    sc = ss.load_scenario(EXAMPLES / "ring10_noise.yaml")
    keys = {"gains": "optimal", "consensus": "whole", "resilience": 0, "K": None}
    return dataclasses.replace(sc, design=dataclasses.replace(sc.design, **keys))


def _continuous_whole():
    return ss.scenario(name="cont", time="continuous", A=[[0, 1, 0, 0], [-1, 0, 0, 0], [0, 0, 0, 1], [0, 0, -2, 0]],
                       C={1: [[1, 0, 0, 0]], 2: [[0, 1, 0, 0]], 3: [[0, 0, 1, 0]]}, process_noise=0.25,
                       measurement_noise=0.05, graphs={"a": [(1, 2), (2, 1), (2, 3), (3, 2), (1, 3)]},
                       dt=0.05, steps=40, seed=7, rate=1.0, gains="optimal", consensus="whole")


KINDS = {
    "split-discrete": lambda: ss.load_scenario(EXAMPLES / "paper_discrete.yaml"),
    "split-continuous": lambda: ss.load_scenario(EXAMPLES / "paper_continuous.yaml"),
    "whole-discrete": _ring_whole,
    "whole-continuous": _continuous_whole,
    "fusion-discrete": lambda: _fused(ss.load_scenario(EXAMPLES / "ring10_noise.yaml")),
    "fusion-continuous": lambda: _fused(_continuous_whole(), q=1),
}


@pytest.mark.parametrize("estimator", ["batch", "loop"])
@pytest.mark.parametrize("kind", sorted(KINDS))
def test_the_simulators_errors_follow_the_error_recursion_written_out(kind, estimator):
    """Noise-free, no faults: ``e(k+1) = M e(k)`` for the first event times, every agent, ``M`` of the graph each
    event time ran on."""
    des = design(KINDS[kind]())
    sc = des.scenario
    assert not sc.faults and not sc.network.impaired  # the recursion above is of every agent alive, every message
    assert des.consensus == kind.split("-")[0] and sc.time == kind.split("-")[1]
    tr = simulate(des, steps=STEPS, noise=False, estimator=estimator)
    e = (tr.xhat - tr.x[:, None, :]).reshape(STEPS + 1, -1)  # rows k: e_1(k), ..., e_m(k) stacked
    maps = {g: oracle_map(des, g) for g in set(tr.graph[:STEPS].tolist())}
    moved = 0
    for k in range(STEPS):
        want = maps[int(tr.graph[k])] @ e[k]
        assert np.linalg.norm(e[k + 1] - want) <= REL * max(np.linalg.norm(want), np.linalg.norm(e[k])), (kind, k)
        moved += np.linalg.norm(e[k + 1] - e[k]) > 1e-6 * np.linalg.norm(e[k])
    assert moved == STEPS  # the errors do move: the comparison is not of a frozen trajectory


def test_the_oracle_tells_a_wrong_step_apart():
    """The recursion is sharp: with one exchange fewer (split) it no longer matches the simulator's errors."""
    des = design(KINDS["split-discrete"]())
    tr = simulate(des, steps=2, noise=False)
    e = (tr.xhat - tr.x[:, None, :]).reshape(3, -1)
    wrong = oracle_map(dataclasses.replace(des, q=int(des.q) - 1), int(tr.graph[0]))
    assert np.linalg.norm(e[1] - wrong @ e[0]) > 1e-6 * np.linalg.norm(e[1])
