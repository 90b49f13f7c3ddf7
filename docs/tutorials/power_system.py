# ---
# jupyter:
#   jupytext:
#     formats: py:percent
#     text_representation:
#       extension: .py
#       format_name: percent
# ---

# %% [markdown]
# # A power system: the IEEE 14-bus benchmark, one agent per generator with a PMU
#
# The textbook setting of distributed dynamic state estimation: a multi-machine power system, one estimator
# per generator, each reading its own phasor measurement unit (rotor angle and speed, 50 times a second),
# the estimators talking to their neighbours over a ring. The model is the IEEE 14-bus system's small-signal
# model as the power-system simulator [ANDES](https://github.com/CURENT/andes) linearises it: 5 generators
# (sixth-order round-rotor machines) with their exciters, governors and the buses' frequency-measurement
# filters, 62 states. `examples/models/make_power_models.py` regenerates `examples/models/ieee14_full.npz`
# from ANDES's own test case (ANDES is not a dependency of splitspec; the file records the version that
# made it).
#
# You will load the model from its file, read what the design guarantees for a model that is only jointly
# *detectable*, compare the estimator with the centralized Kalman filter under noise, and run it as real
# processes while generator 3's estimator is killed and restarted.

# %%
import json
import os
from pathlib import Path

import numpy as np

import splitspec_core as ss

out = Path(os.environ.get("SPLITSPEC_OUT", "out/tutorials")) / "power_system"
sc = ss.load_scenario("examples/ieee14_pmu.yaml")
print(Path("examples/ieee14_pmu.yaml").read_text().split("graphs:")[0].split("\nname:")[1])
meta = json.loads(str(np.load("examples/models/ieee14_full.npz")["meta"]))
print(f"{sc.n} states from {meta['case']} (ANDES {meta['andes']}); {sc.m} agents")
print("agent 1 measures", sc.output_names(1), "=", [sc.state_names[k] for k in np.flatnonzero(sc.system.Cs[0].any(0))])

# %% [markdown]
# `system.file` names the `.npz` beside the scenario and each matrix names one of its arrays
# (`A: A`, `C: {1: C_pmu_1, ...}`, `states: states`): a 62 x 62 matrix is not written out in YAML. The
# states keep ANDES's names (`delta_GENROU_1` is generator 1's rotor angle), and every message, report
# line and plot below uses them. The scenario states its noise (process noise intensity 1e-4 on every
# state, a PMU's measurement noise 1e-3) and no `design.gains`: the design is then chosen for that noise.
#
# ## 1. Design: what is guaranteed, and at what noise
#
# Nobody measures the buses' frequency filters (`WO_x_BusFreq_*`, `L_y_BusFreq_*`): the system is not
# jointly observable, and the paper's theorem does not apply as stated. Those directions decay on their own
# (at 50 /s), much faster than the rate asked for (0.3 /s), so the estimator is designed on the rest and
# the certificate says what it covers.
#
# Every PMU sees almost every state of this coupled machine, but most of them only weakly. The paper's split
# has each agent estimate by itself everything it sees at all, with local gains that amplify its sensor's
# noise along those weak directions; the design here tries both that split and *whole-state consensus*:
# each agent corrects its estimate with its own measurement (its gain the centralized Kalman filter's
# columns for its sensor, scaled by its weight in the consensus average), then averages its neighbours'
# estimates `q` times per PMU sample. It keeps the certified one with the smaller predicted steady error.

# %%
from splitspec_core.synthesis.conditioning import conditioning

d = ss.design(sc)
report = d.report().splitlines()
print("\n".join(line for line in report
                if line.startswith(("  design.consensus", "  jointly", "q =", "rate certified", "transient", "noise",
                                    "exchanges"))))

# %% [markdown]
# The rate is certified by the spectral radius of the full error matrix (every agent's error stacked, one
# PMU sample with its `q` exchanges), below `exp(-0.3 x 0.02)` per sample. The predicted steady RMS error is
# the centralized Kalman filter's to within a fraction of a per cent: with five exchanges per sample the
# agents' estimates agree, and their average is the centralized filter. Within 10 % of the Kalman filter no
# design can do better, so the paper's split was not even designed (`design.consensus: split` designs it:
# its predicted steady error here is about a hundred times larger).
#
# That accuracy is paid in messages: the `exchanges` line says what each agent sends per PMU sample (five
# estimates of 62 numbers). With fewer exchanges a sensor `d` hops away reaches an agent only `ceil(d / q) - 1`
# samples late, and no estimator beats the Kalman predictor fed that late: the protocol's limit, per budget `q`.

# %%
p = sum(len(C) for C in sc.system.Cs)  # every PMU's outputs
for q in (1, 2, 3, 5):
    lim = ss.protocol_limit(sc, q)
    print(f"q = {q}: each agent sends {q * sc.n:3d} numbers per sample as estimates, {p} as samples (relay); the "
          f"limit is {lim.ratio:.4f} x the centralized Kalman filter's RMS")

# %% [markdown]
# On this five-bus ring every sensor is at most two hops away: two exchanges already let every agent hear every
# PMU in time, and one costs a percent. The fusion kind (`design.consensus: fusion` with `design.q` the budget;
# [the method's "Few exchanges"](../../explanation/method.md)) met these limits on this model in
# `benchmarks/bench_comm.py`: 1.0097 x at q = 1, 1.0000 x at q = 2, with one estimate per exchange. The relay kind
# (`design.consensus: relay`: the agents pass the PMUs' samples on, each the Kalman predictor of what it holds) is
# the limit itself at every q, and sends every PMU's sample once: 10 numbers per sample against the fusion kind's 62
# per exchange; on the IEEE 39-bus model it is certified at a rate the fusion kind does not reach
# ([the method's "Samples instead of estimates"](../../explanation/method.md)).
#
# ## 2. Noise-free: the error against the certificate
#
# From random initial estimates, every agent's error, with the certified envelope `c exp(-0.3 t) |e(0)|`
# (`c` the transient constant of the report, `|e(0)|` every agent's initial error stacked).

# %%
import matplotlib.pyplot as plt

free = ss.simulate(sc, noise=False)
e = free.errors()
c = conditioning(d.detail).transient_constant
stacked = np.sqrt((e ** 2).sum(axis=1))
envelope = c * stacked[0] * np.exp(-sc.design.rate * free.t)
fig, ax = plt.subplots(figsize=(8, 3.5), layout="constrained")
ax.semilogy(free.t, e, lw=1)
ax.semilogy(free.t, envelope, "k--", lw=1, label="c exp(-0.3 t) |e(0)|")
ax.set_xlabel("t (s)")
ax.set_ylabel(r"$\|\hat x_i - x\|$")
ax.legend(fontsize=8)
plt.show()
late = free.t >= 20
rate = -np.polyfit(free.t[late], np.log(e[late].max(axis=1)), 1)[0]
print(f"measured decay rate over the last 10 s: {rate:.3f} /s (certified 0.3); transient constant c = {c:.3g}")
assert np.all(stacked <= envelope * (1 + 1e-9))

# %% [markdown]
# The errors stay under the envelope and fall faster than the 0.3 /s asked (the certified radius, 0.99076 per
# 20 ms sample, is 0.46 /s).
#
# ## 3. Under noise: against the centralized Kalman filter
#
# `ss.compare` runs every estimator on the same noise realisations: the scenario's design, the paper's split
# with its `place` and `riccati` gains, the centralized Kalman filter that sees every measurement, and the
# Kalman consensus filter (no rate guarantee) with as many exchanges. Each steady RMS error is measured after
# that estimator's own certified transient (`steady from`: where its envelope falls below 5 % of its
# predicted steady error), so the run is longer than the scenario's 30 s: 80 s, two seeds.

# %%
res = ss.compare(sc, seeds=2, steps=4000)
for name, r in res.estimators.items():
    pred = "" if r.predicted_rms is None else f", predicted {r.predicted_rms:.3g}"
    if r.steady_from is None:
        print(f"{name:22s} not settled within the run{pred}")
        continue
    print(f"{name:22s} steady RMS error {r.rms_mean:8.3g} ({r.ratio_to_centralized:5.3g} x centralized{pred}), "
          f"from t = {r.steady_from:g}")

# %% [markdown]
# The certified estimator is now worth using under noise: its steady error is the centralized Kalman filter's,
# as predicted, with a rate guarantee the Kalman consensus filter does not have (its error is about 1.5 times
# the centralized filter's here). The paper's split pays for estimating every weakly seen direction locally:
# with `riccati` gains its steady error is about a hundred times the centralized filter's, with `place` gains
# several hundred, each as predicted. What each rate costs is `splitspec compare --sweep-rate`: at 0.5 /s the
# Kalman filter itself is too slow, and the whole-state design follows the centralized Riccati design shifted by
# that rate.
#
# ## 4. Losing an agent: what the whole state assumes
#
# The whole-state gains fuse every sensor: agent `i`'s gain is its sensor's share of the centralized filter
# divided by its consensus weight (1/5). With one agent gone the four survivors' average over-corrects and
# misses that sensor: the design says so before anything runs. Asked to be certified after any single agent
# loss (`design.resilience: 1`), it falls back to the paper's split, whose agents each keep their own gain:
#
# %%
resilient = ss.load_scenario("examples/ieee14_pmu_resilient.yaml")  # ieee14_pmu.yaml with design.resilience: 1
r = ss.design(resilient).to_json()
print(r["consensus_choice"])
print(f"resilient design: {r['consensus']}, predicted steady RMS {r['predicted_rms']['all']:.3g} "
      f"({r['predicted_rms']['ratio_to_kalman']:.3g} x the centralized Kalman filter)")

# %% [markdown]
# That is what resilience costs on this model today: a hundred times the centralized filter's noise, against
# the whole-state design's one. Without `design.resilience` the runtime still judges every loss as it happens
# (the `resilience_verdict` event) and says when the survivors are no longer certified.
#
# ## 5. Real processes: generator 3's estimator killed and restarted
#
# `ss.run` starts the orchestrator, a plant process and five agent processes talking over Zenoh on
# loopback, with noise. `faults=` kills agent 3 at 10 s (SIGKILL) and restarts it at 15 s; the processes
# receive the scenario with the model's arrays written in, and `rec.scenario` is the scenario the run
# played (its `scenario.yaml`, with those faults), which the simulator replays. The run plays the resilient
# design, certified through the loss.

# %%
rec = ss.run(resilient, out=out, faults=[{"at": 10, "kill": 3}, {"at": 15, "restart": 3}])
for ev in rec.events:
    if ev["event"] in ("agent_lost", "agent_rejoined", "resilience_verdict"):
        print(f"t = {ev['t']:5.2f}  {ev['event']:<18} {ev.get('reason') or ev.get('certificate', '')[:70]}")
sim = ss.simulate(rec.scenario)
diff = np.nanmax(np.abs(rec.trajectory.xhat - sim.xhat))
print(f"max |run - simulate| = {diff:.1e} (estimates up to {np.nanmax(np.abs(sim.xhat)):.3g})")
assert np.array_equal(rec.trajectory.alive, sim.alive) and diff <= 1e-9 * np.nanmax(np.abs(sim.xhat))
assert all(ev["ok"] for ev in rec.events if ev["event"] == "resilience_verdict")  # certified through the loss

# %% [markdown]
# ## 6. Review it in Rerun
#
# ```python
# ss.view(out)     # the native viewer with a display, else the web viewer on 127.0.0.1
# ```
#
# The recording holds all 62 states of every agent, but the default layout's states tab shows the ten the
# agents measure (each generator's `delta` and `omega`): `run.show` picks others by name or pattern
# (`show: [omega_*, e1q_GENROU_3]`). Each agent's error is one line on the log-scale errors tab, with the
# kill and the rejoin marked on it. The red line is the designed *rate* drawn from the largest error at the
# start (and again at the rejoin), not the bound: the errors may rise above it first (by up to the transient
# constant), and only their slope is to be compared with it. A screenshot of this run's recording at
# 20 s (made by `docs/make_screenshots.py --run-dir OUT --at pmu=1000` in a headless Chromium):
#
# ![the IEEE 14-bus run in Rerun](/figures/view_ieee14_pmu.png)

# %%
print("states tab:", [sc.state_names[k] for k in sc.shown_states])
print("run.rrd:", f"{(out / 'run.rrd').stat().st_size / 1e6:.1f} MB")
