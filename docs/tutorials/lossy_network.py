# ---
# jupyter:
#   jupytext:
#     formats: py:percent
#     text_representation:
#       extension: .py
#       format_name: percent
# ---

# %% [markdown]
# # A lossy network: what is still guaranteed, what a run shows
#
# Real networks lose and delay messages. This tutorial takes a ring of 10 agents (with two chords) whose
# consensus messages are lost with probability 0.1 (0.3 on the chord 1 -> 6) and delayed by 2 +- 1 ms
# against a 20 ms deadline, and asks three questions: what the design still certifies, how the estimator
# behaves as the loss grows (a Monte Carlo sweep), and whether real processes over Zenoh do what the
# simulation says (they do: the run is replayed exactly from its recorded losses).

# %%
import os
from pathlib import Path

import numpy as np

import splitspec_core as ss
from splitspec_core.studies.sweeps import sweep_table
from splitspec_core.synthesis.loss_certificate import loss_certificate

out = Path(os.environ.get("SPLITSPEC_OUT", "out/tutorials")) / "lossy_network"
sc = ss.load_scenario("examples/ring10_lossy.yaml")
print(f"{sc.m} agents, rate {sc.design.rate}, loss {sc.network.loss}, deadline {sc.network.deadline} s")

# %% [markdown]
# ## 1. What the design certifies under loss
#
# A message that does not arrive in time removes its arc for that consensus sub-round, and the receiver
# reweights what it did get (the realized consensus matrix stays row-stochastic). The design certifies the
# rate only when the bound $\|\tilde A\|_2\,\beta^q \le \lambda$ covers *every* graph the losses can leave;
# with loss possible on every arc and a deadline that real delays can miss, it cannot, and says so.

# %%
d = ss.design(sc)
print("q =", d.q)
print("perfect network:", d.checks.certificate)
cert = loss_certificate(d.detail)
print("under this network:", cert.text)

# %% [markdown]
# ## 2. Measure instead: a loss sweep
#
# `ss.network_sweep` (the command line: `splitspec compare SCENARIO --sweep-loss 0 0.1 0.2 0.4`)
# simulates every level over several seeds and reports each one's measured decay rate next to the
# designed one.

# %%
sw = ss.network_sweep(sc, "loss", [0.0, 0.1, 0.2, 0.4], seeds=range(5))
print("\n".join(sweep_table(sw)))

# %% [markdown]
# ## 3. Run it as real processes
#
# `ss.run` starts the orchestrator, the plant and ten agent processes over Zenoh on this machine. The
# losses are drawn from the scenario's seed, so the run and `ss.simulate` drop the same messages; a message
# that really arrives after the 20 ms deadline is dropped too and recorded as *late* (how many depends
# on this machine's load). Every dropped message is in the trajectory (`lost`, `lost_cause`), so the
# simulator can replay the run exactly.

# %%
rec = ss.run(sc, out=out)
lost, cause = rec.trajectory.lost, rec.trajectory.lost_cause
print(f"{len(lost)} consensus messages did not count: {int((cause == 0).sum())} lost, {int((cause == 1).sum())} late")
sim = ss.simulate(sc)
print(f"simulate drew {len(sim.lost)} losses; the run's drawn losses are the same: "
      f"{bool(np.array_equal(sim.lost, lost[cause == 0]))}")
replay = ss.simulate(sc, lost=(lost, cause))
diff = np.nanmax(np.abs(rec.trajectory.xhat - replay.xhat))
print(f"max |run - replay| = {diff:.1e}")
assert diff < 1e-9  # different processes and summation orders: round-off, not exact

# %% [markdown]
# ## 4. Plot
#
# The measured rate at each loss level against the designed rate, and the run's errors.

# %%
import matplotlib.pyplot as plt

fig, axes = plt.subplots(1, 2, figsize=(9, 3.5), layout="constrained")
levels = [r["value"] for r in sw["rows"]]
axes[0].plot(levels, [np.median(r["rates"]) for r in sw["rows"]], "o-", label="measured (median of seeds)")
axes[0].axhline(sw["designed_rate"], color="k", ls="--", label="designed")
axes[0].set_xlabel("loss probability")
axes[0].set_ylabel("decay rate")
axes[0].legend(fontsize=8)
axes[1].semilogy(rec.trajectory.t, rec.trajectory.errors())
axes[1].set_xlabel("event time")
axes[1].set_ylabel("each agent's error (the run)")
plt.show()

# %% [markdown]
# ## Next
#
# * Review the run on a timeline: `ss.view(out)` (lost messages are dotted on the topology panel).
# * [How to simulate networks that misbehave](../../how-to/networks.md): partitions, per-arc loss, replays.
