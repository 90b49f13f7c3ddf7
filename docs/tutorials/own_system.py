# ---
# jupyter:
#   jupytext:
#     formats: py:percent
#     text_representation:
#       extension: .py
#       format_name: percent
# ---

# %% [markdown]
# # Your own system in a notebook
#
# Your system is not in a YAML file yet: it is a model you wrote down. This tutorial builds one with numpy,
# designs the estimator for it, looks at the design's health (observability margins, gain sizes), compares
# it under noise with the centralized Kalman filter, and finally estimates the state from a measurement
# log instead of the built-in plant, as you will with your own recordings.
#
# The system: three unit masses in a chain between two walls, springs of 16 N/m, damping 0.3 N s/m, sampled
# every 0.1 s. Agent $i$ sits on mass $i$ and measures its position and velocity; the agents talk along the
# line 1 - 2 - 3. The middle agent never sees the mode in which masses 1 and 3 swing against each other
# while mass 2 stays still: no agent can estimate the state alone in a well-conditioned way.

# %%
import os
from pathlib import Path

import numpy as np
from scipy.linalg import expm

import splitspec_core as ss

out = Path(os.environ.get("SPLITSPEC_OUT", "out/tutorials")) / "own_system"
out.mkdir(parents=True, exist_ok=True)

k, c, dt = 16.0, 0.3, 0.1
Kspring = k * np.array([[2.0, -1, 0], [-1, 2, -1], [0, -1, 2]])
Ac = np.block([[np.zeros((3, 3)), np.eye(3)], [-Kspring, -c * np.eye(3)]])  # x = (p1, p2, p3, v1, v2, v3)
A = expm(Ac * dt)  # the exact motion over one event period
C = {i: np.eye(6)[[i - 1, i + 2]] for i in (1, 2, 3)}  # agent i: position and velocity of mass i
print("eigenvalue moduli of A:", np.round(np.abs(np.linalg.eigvals(A)), 4))

# %% [markdown]
# ## 1. The scenario, from keywords
#
# `ss.scenario` takes every scenario-file key as a keyword and checks it the same way (a mistake is one
# line naming the key). `gains="riccati"` computes each agent's local gain from a Riccati equation of
# its observable part; `rank_tol` decides how weakly a direction may be seen and still count as observed
# (see [Explanation: the method](../../explanation/method.md)).

# %%
sc = ss.scenario(name="chain", A=A, C=C, graphs={"line": {"undirected": [(1, 2), (2, 3)]}},
                 time="discrete", rate=0.9, gains="riccati", rank_tol=0.02,
                 process_noise=0.001, measurement_noise=0.01, steps=150, seed=1)
d = ss.design(sc)
print(d.checks.certificate)
for w in d.checks.warnings:
    print("warning:", w)
for i, a in d.agents.items():
    print(f"agent {i}: keeps {6 - a.n_unobservable} of 6 directions, |K_{i}| = {np.linalg.norm(a.K, 2):.3g}")

# %% [markdown]
# A mistake is one line, as it would be in a file:

# %%
try:
    ss.scenario(A=A, C={1: np.eye(5)[:1]}, graphs={"g": [(1, 1)]}, rate=0.9)
except ss.ScenarioError as exc:
    print("ScenarioError:", exc)

# %% [markdown]
# ## 2. Under noise, against the centralized Kalman filter
#
# `ss.compare` simulates several seeds of the split-spectrum estimator (with its gains variants), the
# centralized Kalman filter (one filter seeing every output: the best any estimator can do) and a
# Kalman-consensus filter, and reports each one's steady-state RMS error.

# %%
cmp = ss.compare(sc, seeds=5)
for name, r in cmp.estimators.items():
    ratio = "" if r.ratio_to_centralized is None else f" (x {r.ratio_to_centralized:.2f} of centralized)"
    print(f"{name:>16}: RMS {r.rms_mean:.4f} +- {r.rms_std:.4f}{ratio}")

# %% [markdown]
# ## 3. Your measurements instead of the simulated plant
#
# A measurement log is a CSV (or NPZ) file: a column `t`, one column per output `y<id>.<row>` and,
# when you know it, the true state `x.<k>`; an empty cell is a missing measurement (the agent only
# predicts at that step). Here we write one from a simulation, with every fifth of agent 2's
# measurements dropped, as a stand-in for a log of yours.

# %%
sim = ss.simulate(sc, keep_y=True)
missing = np.zeros((len(sim.t), 3), dtype=bool)
missing[::5, 1] = True
from splitspec_core.scenarios.measurements import write_measurements

log = out / "log.csv"
write_measurements(log, t=sim.t * dt, y=sim.y, agent_ids=sc.agent_ids, sizes=[2, 2, 2], x=sim.x, missing=missing)
print(log.read_text().splitlines()[0])
print(f"{len(sim.t)} rows, {missing.sum()} measurements missing")

# %% [markdown]
# `ss.simulate(sc, measurements=log)` runs the same estimator on the file (`splitspec simulate
# SCENARIO --measurements FILE` and `splitspec run ... --measurements FILE` do the same, the latter as
# real processes). With the truth in the file the errors are known; without it, the trajectory carries
# the residuals $y_i - C_i \hat x_i$ and the agents' disagreement instead.

# %%
est = ss.simulate(sc, measurements=log)
rms = np.sqrt(np.nanmean(est.errors()[50:] ** 2))
print(f"RMS error after tau = 50, from the log: {rms:.4f}")
print(f"agent 2 predicted only at {int(est.y_missing[:, 1].sum())} steps")

# %% [markdown]
# ## 4. Plot

# %%
import matplotlib.pyplot as plt

fig, axes = plt.subplots(2, 1, figsize=(7, 5), sharex=True, layout="constrained")
for name in ("centralized KF", "split riccati", "KCF"):
    if name in cmp.curves:
        axes[0].semilogy(cmp.t, cmp.curves[name], label=name)
axes[0].set_ylabel("RMS error (5 seeds)")
axes[0].legend(fontsize=8)
axes[1].plot(est.t, est.x[:, 0], "k", label="p1 (truth)")
for kk, i in enumerate(sc.agent_ids):
    axes[1].plot(est.t, est.xhat[:, kk, 0], "--", label=f"agent {i}'s estimate of p1")
axes[1].set_xlabel("event time")
axes[1].legend(fontsize=8)
plt.show()

# %% [markdown]
# ## Next
#
# * Save the scenario as a file for the command line: every keyword is the file's key
#   ([How to write a scenario](../../how-to/scenario.md)).
# * Feed live sensors instead of a file: [Estimate from your own measurements](../../how-to/sensors.md).
