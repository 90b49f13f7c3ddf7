# ---
# jupyter:
#   jupytext:
#     formats: py:percent
#     text_representation:
#       extension: .py
#       format_name: percent
# ---

# %% [markdown]
# # From a notebook: design, simulate, run with a kill, compare, plot
#
# A jupytext notebook (open it in Jupyter with jupytext installed, or run it as a script:
# `python docs/tutorials/notebook_workflow.py`; the tests run it so it cannot rot). It designs the
# split-spectrum estimator for a system built with numpy, simulates it, runs the same scenario as
# real processes over Zenoh with an agent killed and restarted, checks that the run is the
# simulation to round-off, and plots both. Outputs go to `out/notebook/` (or `$SPLITSPEC_OUT`).

# %%
import os
from pathlib import Path

import numpy as np

import splitspec_core as ss

out = Path(os.environ.get("SPLITSPEC_OUT", "out/notebook"))

# %% [markdown]
# ## 1. The system and the network
# Two oscillators (the paper's Section 5 system); agent i sees one coordinate, none sees the
# whole state. Agent 2 is killed at event time 10 and restarted at 20 (`faults`).

# %%
A = np.array([[0.0, 1, 0, 0], [-1, 0, 0, 0], [0, 0, 0, 1], [0, 0, -2, 0]])
C = {i: np.eye(4)[[i - 1]] for i in (1, 2, 3)}
graphs = {"a": [(1, 2), (2, 1), (2, 3), (3, 2), (1, 3), (3, 1)]}  # (j, i): agent i hears agent j
faults = [{"at": 10, "kill": 2}, {"at": 20, "restart": 2}]
sc = ss.scenario(name="notebook", A=A, C=C, graphs=graphs, faults=faults, time="discrete", rate=0.5,
                 gains="place", steps=40, seed=1)

# %% [markdown]
# ## 2. Design: what is guaranteed

# %%
d = ss.design(sc)
print("design:", d.checks.certificate)

# %% [markdown]
# ## 3. Simulate (in-process, the reference)

# %%
sim = ss.simulate(sc)
print("simulated max error at the end:", np.nanmax(sim.errors()[-1]))

# %% [markdown]
# ## 4. Run it: one OS process per agent, the kill and the restart for real

# %%
rec = ss.run(sc, out=out)
print([(e["event"], e.get("tau")) for e in rec.events if e["event"] in ("agent_lost", "agent_rejoined")])

# %% [markdown]
# ## 5. Compare: the run is the simulation to round-off

# %%
diff = np.nanmax(np.abs(rec.trajectory.xhat - sim.xhat))
print(f"max |run - simulate| over every estimate: {diff:.2e}")
assert diff <= 1e-12 * np.nanmax(np.abs(sim.xhat))  # round-off of estimates of order 1
assert np.array_equal(rec.trajectory.alive, sim.alive)

# %% [markdown]
# ## 6. Plot
# Matplotlib here; for the whole timeline, `ss.view(out)` opens the Rerun recording of the run (`run.rrd`):
# in Jupyter with `rerun-notebook` installed (`pip install 'rerun-notebook==0.41.*'`) inline in the notebook
# (with the segments a run until stopped rolled it into, `run-0001.rrd` ...), elsewhere the native viewer or the
# web viewer's URL.

# %%
import matplotlib

matplotlib.use("Agg")  # a file here; in Jupyter, drop this line to see the figure inline
import matplotlib.pyplot as plt  # noqa: E402

fig, ax = plt.subplots(figsize=(7, 3.5))
for k, aid in enumerate(rec.trajectory.agent_ids):
    ax.semilogy(rec.trajectory.t, rec.trajectory.errors()[:, k], label=f"run, agent {aid}")
    ax.semilogy(sim.t, sim.errors()[:, k], "k:", lw=0.8)
ax.semilogy(sim.t, 3 * np.max(sim.errors()[0]) * 0.5 ** sim.t, "r--", lw=0.8, label="0.5^tau (scaled)")
ax.set_xlabel("event time tau")
ax.set_ylabel("|x_i - x|")
ax.set_title("run (lines) and simulate (dotted): agent 2 dead for tau 10..19")
ax.legend(fontsize=8)
fig.tight_layout()
fig.savefig(out / "errors.png", dpi=100)
print("wrote", out / "errors.png")

# %% [markdown]
# ## 7. Read any run back later
# `ss.load_run` reads a run's directory (this one, or one `splitspec run` wrote from the command line): the
# same `Trajectory`, the events, and the scenario the run used, whose design it recomputes.

# %%
again = ss.load_run(out)
print(f"{again.scenario.name}: {len(again.trajectory.t)} event times, q = {again.design().q}, "
      f"{len(again.named('agent_lost'))} agent lost, {len(again.named('agent_rejoined'))} rejoined")
