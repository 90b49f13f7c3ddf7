# ---
# jupyter:
#   jupytext:
#     formats: py:percent
#     text_representation:
#       extension: .py
#       format_name: percent
# ---

# %% [markdown]
# # Your first design and simulation: the paper's example
#
# The paper's Section 5 example: two oscillators ($n = 4$ states), three agents, each measuring one
# coordinate of the state, so **no agent can observe the system alone**. You will design the
# split-spectrum estimator, read what is guaranteed, simulate it and check the guarantee on the
# trajectory. About a second of computing; nothing but `numpy`, `scipy` and `matplotlib`.
#
# Run it yourself from the repository root: `.venv/bin/python docs/tutorials/first_design.py`, or open it
# in Jupyter (it is a [jupytext](https://jupytext.readthedocs.io) notebook).

# %%
import numpy as np

import splitspec_core as ss

sc = ss.load_scenario("examples/paper_discrete.yaml")
print(f"{sc.m} agents, n = {sc.n} states, time: {sc.time}, graphs: {', '.join(sc.graph_names)}")

# %% [markdown]
# ## 1. The system and what each agent sees
#
# $x(\tau + 1) = A x(\tau)$ and agent $i$ measures $y_i = C_i x$. Agent $i$ can reconstruct only the
# part of $x$ its pair $(C_i, A)$ observes; the rest it must learn from its neighbours. The scenario file
# holds $A$, the $C_i$, the communication graphs (`(j, i)`: agent $i$ hears agent $j$), the rate
# $\lambda = 0.5$ to achieve, and the paper's local gains $K_i$.

# %%
print("A =\n", sc.system.A)
for i, C in zip(sc.agent_ids, sc.system.Cs):
    print(f"C_{i} = {C}")

# %% [markdown]
# ## 2. Design: the certificate
#
# `ss.design` checks the assumptions (joint observability, strong connectivity), splits each agent's
# state space into the part it observes (spanned by the rows of $Q_i$; gain $K_i$ places its poles) and
# the part it does not ($V_i$, consensus), and chooses $q$, the number of consensus exchanges per event
# time, so that the error contracts at least as fast as $\lambda^\tau$: the spectral radius of
# $\tilde A (V' \bar S V)^q$ must not exceed $\lambda$ (eq. split_discrete_ench; the paper finds
# $q = 6$ for this example).

# %%
d = ss.design(sc)
print("q =", d.q)
print("certificate:", d.checks.certificate)
for i, a in d.agents.items():
    print(f"agent {i}: observes {4 - a.n_unobservable} of 4 directions, poles {np.round(a.poles.real, 3)}")

# %% [markdown]
# The full report is what `splitspec design examples/paper_discrete.yaml` prints:

# %%
print(d.report())

# %% [markdown]
# ## 3. Simulate and check the guarantee
#
# `ss.simulate` is the reference the multi-process runtime reproduces (same scenario and seed, same
# trajectory to round-off). The initial estimates are drawn from the scenario's seed. Without noise the
# stacked error $e(\tau)$ of all agents obeys $\|e(\tau)\| \le c\,\lambda^\tau \|e(0)\|$, with the
# transient constant $c = \sup_k \|M^k\| / \lambda^k$ of the full error map $M$ the design reports.

# %%
tr = ss.simulate(sc)
e = np.linalg.norm(np.nan_to_num(tr.xhat - tr.x[:, None, :]).reshape(len(tr.t), -1), axis=1)
c = d.to_json()["transient"]["constant"]
tau = np.arange(len(e))
bound = c * d.rate ** tau * e[0]

# The state grows like sqrt(2)^tau (A has eigenvalues +-i sqrt(2)): near tau = 40, |x| ~ 1e6 and an error
# of 1e-9 is round-off of the estimate, not the estimator's. Check the bound above that floor.
x_size = np.linalg.norm(tr.x, axis=1)
above = e > 1e-13 * x_size
print(f"c = {c}; |e| from {e[0]:.3g} to {e[above][-1]:.3g} at tau = {tau[above][-1]}")
print("within c lam^tau |e(0)| at every such tau:", bool(np.all(e[above] <= bound[above])))
assert np.all(e[above] <= bound[above])
print(f"largest e(tau) / (c lam^tau e(0)): {np.max(e[above] / bound[above]):.3f}")

# %% [markdown]
# ## 4. Plot
#
# Every agent's error, the dashed bound $c\,\lambda^\tau\|e(0)\|$, and the round-off floor where the
# state's size takes over.

# %%
import matplotlib.pyplot as plt

fig, ax = plt.subplots(figsize=(7, 3.5), layout="constrained")
for k, i in enumerate(tr.agent_ids):
    ax.semilogy(tau, tr.errors()[:, k], label=f"agent {i}")
ax.semilogy(tau, bound, "k--", label=r"$c\,\lambda^\tau \|e(0)\|$")
ax.semilogy(tau, 1e-16 * x_size, ":", color="grey", label="round-off of x")
ax.set_xlabel(r"event time $\tau$")
ax.set_ylabel(r"$\|\hat x_i - x\|$")
ax.legend(fontsize=8)
plt.show()

# %% [markdown]
# ## Next
#
# * Change the rate: edit `design.rate` in a copy of the file and watch $q$ grow as $\lambda$ shrinks.
# * [Your own system in a notebook](own_system.md): build the scenario from numpy arrays.
# * The method and its guarantees: [Explanation](../../explanation/method.md).
