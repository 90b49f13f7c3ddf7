# ---
# jupyter:
#   jupytext:
#     formats: py:percent
#     text_representation:
#       extension: .py
#       format_name: percent
# ---

# %% [markdown]
# # Break it on purpose: a multi-process run with kills and rejoins, reviewed in Rerun
#
# Ten agents on a ring with two chords estimate an 8-state system as ten real OS processes, plus a plant
# process and the orchestrator, talking over Zenoh. During the run agent 3 is killed (SIGKILL), the link
# 1 -> 6 fails, agent 5 freezes (SIGSTOP), both agents come back as fresh processes with fresh estimates,
# the link returns, and the network switches to another graph for a while. The design is *resilient*
# (`resilience: 1`): its $q$ is certified after the loss of any one agent or link. Between event times 20
# and 30 the run has lost two agents and a link at once, more than that, and the orchestrator says so. You
# will run it, read its event log, check that the run is the simulation to round-off, and review it on
# Rerun's timeline.
#
# The same from the command line: `splitspec run examples/ring10_faults_switching.yaml --out OUT`, then
# `splitspec view OUT`.

# %%
import os
from pathlib import Path

import numpy as np

import splitspec_core as ss

out = Path(os.environ.get("SPLITSPEC_OUT", "out/tutorials")) / "kill_and_rejoin"
sc = ss.load_scenario("examples/ring10_faults_switching.yaml")
d = ss.design(sc)
print(f"{sc.m} agents, q = {d.q}")
print(d.checks.certificate)
for f in sc.faults:
    print(f)

# %% [markdown]
# ## 1. Run it
#
# `ss.run` starts `splitspec run` as a child process and blocks until the run ends (about 3 s here); the
# records (`trajectory.npz`, `events.jsonl`, `run.rrd`) go to `out`. `faults=` would replace the
# scenario's faults; here the file's are used.

# %%
rec = ss.run(sc, out=out)
kinds = ("agent_lost", "agent_rejoined", "arc_dropped", "arc_restored", "graph_switched", "resilience_verdict")
for e in rec.events:
    if e["event"] in kinds:
        what = e.get("reason") or e.get("after") or e.get("arc") or e.get("graph") or e.get("id") or ""
        extra = f": {e['certificate']}" if e["event"] == "resilience_verdict" else ""
        print(f"tau {e.get('tau', int(e['t'])):>3}  {e['event']:<18} {what}{extra}")

# %% [markdown]
# The orchestrator executes each fault for real (a signal to the process, a link cut in the consensus
# rows) and watches the processes: a killed process's Zenoh liveliness token disappears, a frozen one stops
# answering within its round's time budget. Either way the agent is declared lost, the survivors reweight
# their consensus over the agents still alive, and after every change the orchestrator re-checks the
# design for the survivors (`resilience_verdict`: still strongly connected, still jointly detectable,
# still certified). At event time 20 the answer is no: with agents 3 and 5 gone and the link 1 -> 6 cut,
# the graph is no longer strongly connected and nothing certifies a rate; the survivors run on, and the
# certificate is back once agent 3 rejoins. A restarted process is admitted again at the next event time
# with a fresh estimate.
#
# ## 2. The run is the simulation
#
# The simulator executes the same faults at the same event times: the estimates agree to round-off
# (different processes sum in different orders: not bit-for-bit).

# %%
sim = ss.simulate(sc)
tr = rec.trajectory
same_alive = bool(np.array_equal(tr.alive, sim.alive))
diff = np.nanmax(np.abs(tr.xhat - sim.xhat))
print(f"same agents alive at every step: {same_alive}; max |run - simulate| = {diff:.1e}")
assert same_alive and diff < 1e-9

# %% [markdown]
# ## 3. Plot
#
# Each agent's error; gaps are the times an agent was dead. The killed agent rejoins with a fresh
# estimate (its error jumps) and converges again at the designed rate.

# %%
import matplotlib.pyplot as plt

fig, ax = plt.subplots(figsize=(8, 3.5), layout="constrained")
ax.semilogy(tr.t, tr.errors(), lw=1)
for tau, what in ((10, "kill 3"), (20, "freeze 5"), (30, "restart 3"), (35, "restart 5"), (45, "switch")):
    ax.axvline(tau, color="grey", lw=0.6, ls=":")
    ax.text(tau, ax.get_ylim()[1], what, rotation=90, va="top", ha="right", fontsize=7)
ax.set_xlabel("event time")
ax.set_ylabel(r"$\|\hat x_i - x\|$")
plt.show()

# %% [markdown]
# ## 4. Review it in Rerun
#
# `ss.view(out)` opens `run.rrd`: the native Rerun viewer when there is a display, otherwise the web
# viewer served on 127.0.0.1 (its URL printed; from another machine tunnel the two ports with `ssh -L`).
# In Jupyter with `rerun-notebook` installed, `ss.view(out, inline=True)` shows it in the notebook.
#
# ```python
# ss.view(out)                 # or, in Jupyter: ss.view(out, inline=True)
# ```
#
# The default layout shows every agent's error on one plot, with the event log and the communication
# graph beside it; the time cursor (bottom) scrubs through the run. Browser screenshots of this scenario's
# recording (made by `docs/make_screenshots.py` in a headless Chromium):
#
# After agent 3 is killed (10) and agent 5 hangs (20): both vanish from the graph, their error lines stop,
# the event log names each fault.
#
# ![Rerun after the kill and the freeze](/figures/view_ring10_faults_switching_kill.png)
#
# After the restarts of agents 3 and 5 (30, 35): back in the graph, their errors start high and fall.
#
# ![Rerun after the rejoins](/figures/view_ring10_faults_switching_rejoin.png)
#
# On the other graph (switch at 45, back at 52): the graph panel shows the chords of `ring2`.
#
# ![Rerun on the other graph](/figures/view_ring10_faults_switching_switch.png)
#
# ## Next
#
# * [How to inject faults](../../how-to/faults.md): kill, freeze and restart from outside with
#   `splitspec kill`, cut links, partitions.
# * [The runtime's protocol and fault model](../../explanation/runtime.md).
