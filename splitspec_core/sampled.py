"""The sampled-data form of the continuous-time estimator: how fast its error decays.

``simulate`` and ``run`` integrate eq. (split_continuous_observer) with one
exchange per ``run.dt`` (:mod:`splitspec_core.steps`); a g certified for the
ODE (eq. g, thm. arb, eq. split_continuous_g) can still leave this
discrete-time error map slow or unstable when ``dt`` is large against g or
``|K_i C_i|``.  Both the design and the runtime verdict on survivors check it.
"""

from __future__ import annotations

import math

import numpy as np

from . import bounds
from .scenario_model import Scenario
from .steps import sampled_data_matrices

__all__ = ["sampled_rates"]


def sampled_rates(sc: Scenario, agents, cases, g: float) -> dict:
    """Decay rate of the sampled-data estimator (run.dt) per case, over ``agents`` (the ones in the cases).

    Observable parts: ``Q_i (E + D K_i C_i) Q_i'``; unobservable part:
    :func:`bounds.sampled_decay`.  Both are exact for the discretisation used
    by ``simulate`` and ``run`` (see :mod:`splitspec_core.steps`).
    """
    import scipy.linalg as sla  # here only: the agents import this module (through the designer) but never call it

    dt = sc.run.dt
    E, D, _ = sampled_data_matrices(sc.system.A, dt)
    Cs = dict(zip(sc.agent_ids, sc.system.Cs))
    obs = math.inf
    for a in agents:
        if a.dec.n_observable:
            Q = a.dec.Q
            rho = bounds.spectral_radius(Q @ (E + D @ a.K @ Cs[a.id]) @ Q.T)
            obs = min(obs, -math.log(rho) / dt if rho > 0 else math.inf)
    ad = {a.id: a for a in agents}
    out = {}
    for c in cases:
        Vs = [ad[i].V for i in c.graph.ids]
        Et = sla.block_diag(*[V.T @ E @ V for V in Vs]) if c.nbar else np.zeros((0, 0))
        Dt = sla.block_diag(*[V.T @ D @ V for V in Vs]) if c.nbar else np.zeros((0, 0))
        out[c.label] = min(obs, bounds.sampled_decay(c, g, Et, Dt, dt))
    return out
