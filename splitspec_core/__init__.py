"""splitspec: the split-spectrum distributed estimator (Wang, Liu, Anderson, Morse), designed, simulated, deployed.

A network of m agents observes ``x`` through ``y_i = C_i x`` (agent i alone may see only part of
the state), talks to its neighbours only, and every agent recovers all of ``x`` exponentially
fast at the chosen rate: errors within ``c exp(-lam t)`` (continuous time) or ``c lam^tau``
(discrete time, ``q`` consensus exchanges per event time ``tau``).

Quick start (numpy arrays or lists; every scenario-file key is a keyword)::

    import numpy as np
    import splitspec_core as ss
    A = np.array([[0, 1, 0, 0], [-1, 0, 0, 0], [0, 0, 0, 1], [0, 0, -2, 0]])
    sc = ss.scenario(A=A, C={1: [[1, 0, 0, 0]], 2: [[0, 1, 0, 0]], 3: [[0, 0, 1, 0]]},
                     graphs={"a": [(1, 2), (2, 1), (2, 3), (3, 2), (1, 3)]},
                     time="discrete", rate=0.5, gains="place")
    d = ss.design(sc)                         # d.q, d.agents[1].K, d.checks.certificate
    tr = ss.simulate(sc, steps=40, seed=1)    # tr.x (T, n), tr.xhat (T, m, n), tr.errors()
    cmp = ss.compare(ss.load_scenario("examples/paper_discrete_noise.yaml"), seeds=5)
    sw = ss.network_sweep(ss.load_scenario("examples/ring10_lossy.yaml"), "loss", [0, 0.1, 0.4], seeds=range(5))
    rec = ss.run(sc, out="out/mine")          # real processes over Zenoh; rec.trajectory, rec.events
    rec = ss.load_run("out/mine")             # any run's records read back; ss.view("out/mine") opens run.rrd

Notation (paper symbol, code name, shape, where in the paper; m agents, n states, s_i outputs
of agent i, r_i = rank of agent i's observable part):

===============  ====================  ===========  ==========================================
symbol           code                  shape        paper
===============  ====================  ===========  ==========================================
A                ``A``                 (n, n)       system, eq. (pre_sys2) / (split_syss_d)
C_i              ``Cs[i]``, ``C``      (s_i, n)     agent i's output ``y_i = C_i x``
K_i              ``K``                 (n, s_i)     local gain, ``A + K_i C_i`` (eq. QA1)
Q_i              ``Q``                 (r_i, n)     orthonormal basis of the observable part
Abar_i, Cbar_i   ``Abar``, ``Cbar``    (r_i, r_i)   observable part ``Q_i A Q_i'``, ``C_i Q_i'``
V_i              ``V``                 (n, n-r_i)   orthonormal basis of the unobservable space
P_i              ``P``                 (n, n)       projection ``V_i V_i'`` (eq. split_continuous_observer)
S(t), Sbar       ``S``                 (m, m)       row-stochastic neighbour matrix; ``S kron I_n``
Atil             ``Atil``              (sum, sum)   ``V' Abar V`` block diagonal (eq. split_AV)
B                ``B``                 (sum, sum)   ``V' Sbar V`` (eq. split_discrete_ench)
A_V              ``A_V``               (sum, sum)   ``Atil B^q`` (discrete), ``Atil - g(I - B)`` (cont.)
g                ``g``                 scalar       consensus gain (eq. g, split_continuous_g)
g_i(t)           ``g``                 (T, m)       adaptive gains (eq. adaptive); ``Trajectory.g``
q                ``q``                 integer      consensus exchanges per event time (eq. split-discrete-p1..p3)
lam              ``rate``              scalar       decay rate
x_i, xhat        ``xhat``              (T, m, n)    agent i's estimate of x
e_i              ``errors()``          (T, m)       ``|x_i - x|`` per agent
M                ``full_error_matrix`` (mn, mn)     full error map of one step (eq. split-discrete-error)
c                ``transient_constant`` scalar      ``sup_k ||M^k|| / lam^k`` (conditioning.py; not in the paper)
margin           ``margin``            scalar       graded observability margin (observability.py)
===============  ====================  ===========  ==========================================

Layout: the math lives here (pure functions, no I/O); the per-agent steps the simulator and the
agent processes share are :mod:`splitspec_core.model.steps`; :mod:`splitspec_core.runtime` holds what
the processes need (Zenoh bus, wire codec, security) and is never imported by the math.
"""

from __future__ import annotations

import importlib as _importlib
from typing import Any as _Any

# Loaded on first use (PEP 562): `import splitspec_core` itself costs nothing, so the runtime's
# light entry points (``splitspec kill``, the process shells) do not pay for numpy and scipy.
_PUBLIC = {
    "scenario": "api", "load_scenario": "api", "design": "api", "simulate": "api", "compare": "api",
    "DesignResult": "api", "AgentResult": "api", "Checks": "api", "CompareResult": "api",
    "EstimatorResult": "api", "network_sweep": "studies.sweeps", "protocol_limit": "api", "Scenario": "scenarios.specs", "Trajectory": "simulation.simulator",
    "MonteCarloRuns": "simulation.montecarlo",
    "SplitspecError": "errors", "ScenarioError": "errors", "DimensionError": "errors",
    "AssumptionError": "errors", "DesignError": "errors",
    "run": "runs", "load_run": "runs", "view": "runs", "RunRecord": "runs", "RunError": "runs",
}
__all__ = list(_PUBLIC)


def __getattr__(name: str) -> _Any:
    if name in _PUBLIC:
        value = getattr(_importlib.import_module(f".{_PUBLIC[name]}", __name__), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__() -> list:
    return sorted(_PUBLIC)
