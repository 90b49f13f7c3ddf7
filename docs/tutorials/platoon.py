# ---
# jupyter:
#   jupytext:
#     formats: py:percent
#     text_representation:
#       extension: .py
#       format_name: percent
# ---

# %% [markdown]
# # A vehicle platoon: known inputs, a sampled model, a python-control plant
#
# Four cars drive in a platoon under cooperative adaptive cruise control. Each car follows its desired
# acceleration through its drivetrain's lag, $\dot a_i = (u_i - a_i)/\tau$ with $\tau = 0.1$ s, the engine
# time constant identified for the test vehicles of Ploeg et al., *Design and experimental evaluation of
# cooperative adaptive cruise control* (IEEE ITSC 2011). The desired accelerations $u_i$ are broadcast
# over V2V, so every car's estimator knows them: **known inputs**, $\dot x = A x + B u$. The lead car has
# GPS and a wheel-speed sensor; every follower a radar (the gap to the car ahead) and a wheel-speed sensor,
# all read at 10 Hz; the cars talk to the car before and behind. No car can estimate the platoon alone;
# together they can, at a rate you choose.
#
# The model lives in a MATLAB file, `examples/models/platoon.mat` (written by
# `examples/models/make_platoon.py` with `scipy.io.savemat`), and the scenario `examples/platoon.yaml`
# names its arrays.

# %%
import os
from pathlib import Path

import numpy as np

import splitspec_core as ss
from splitspec_core.synthesis.conditioning import conditioning

out = Path(os.environ.get("SPLITSPEC_OUT", "out/tutorials")) / "platoon"
sc = ss.load_scenario("examples/platoon.yaml")
print(f"{sc.n} states {sc.state_names}, {sc.system.inputs} known inputs, sampled every {sc.system.sample} s")
for i in sc.agent_ids:
    print(f"car {i} measures {sc.output_names(i)}")

# %% [markdown]
# `system.sample: 0.1` takes the file's `A` and `B` as the continuous model and samples them with a
# zero-order hold, so the discrete estimator runs at the sensors' rate. The same plant from
# [python-control](https://python-control.readthedocs.io) (`pip install 'splitspec[control]'`): each car is
# given the outputs it measures, by label.

# %%
import control
import scipy.io

m = scipy.io.loadmat("examples/models/platoon.mat")
names = [str(s[0]) for s in m["states"].ravel()]
outs = [str(s[0]) for i in range(1, 5) for s in m[f"outputs{i}"].ravel()]
plant = control.ss(m["A"], m["B"], np.vstack([m[f"C{i}"] for i in range(1, 5)]), 0, states=names, outputs=outs)
common = dict(plant=plant, agents={1: ["gps1", "speed1"], 2: ["gap2", "speed2"], 3: ["gap3", "speed3"],
                                  4: ["gap4", "speed4"]},
              sample=0.1, x0=sc.system.x0, graphs={"line": {"undirected": [(1, 2), (2, 3), (3, 4)]}}, rate=0.7,
              gains="riccati", steps=150, seed=3, process_noise=0.01, measurement_noise=0.05)
sc2 = ss.scenario(**common)
# exact: the same numbers through the same zero-order hold (one block exponential), in the same order
print("same sampled A and B:", np.array_equal(sc2.system.A, sc.system.A), np.array_equal(sc2.system.B, sc.system.B))

# %% [markdown]
# ## 1. Design
#
# `rate: 0.7` per 0.1 s sample. The report says what that means per second, and that the known inputs do
# not enter the certificate: the plant and every car add the same $B u$, so they cancel from every error.

# %%
d = ss.design(sc)
for line in d.report().splitlines():
    if line.startswith(("  sampled", "  known inputs", "q =", "rate certified", "transient")):
        print(line)

# %% [markdown]
# ## 2. The platoon moves, the errors do not care
#
# The lead car accelerates at 1 m/s² from 1 s to 4 s and brakes at 1.5 m/s² from 8 s to 10 s; each
# follower does the same half a second after the car ahead. Every car's estimate of every car's speed
# follows the truth; the errors fall at the certified rate, and they are the same as those of a platoon
# cruising without commands (the same draws, no inputs), to round-off. They stop falling near 1e-12: the
# round-off of positions some hundreds of metres from the start.

# %%
import matplotlib.pyplot as plt

free = ss.simulate(sc, noise=False)
fig, (a1, a2) = plt.subplots(1, 2, figsize=(10, 3.5), layout="constrained")
for c in range(4):
    k = 3 * c + 1  # v_c
    a1.plot(free.t * 0.1, free.x[:, k], "k", lw=2, alpha=0.5)
    a1.plot(free.t * 0.1, free.xhat[:, :, k], lw=0.8)
a1.set_xlabel("t (s)")
a1.set_ylabel("speed (m/s)")
a1.set_title("v1..v4: truth (grey), every car's estimates", fontsize=9)
e = free.errors()
a2.semilogy(free.t * 0.1, e, lw=1)
a2.semilogy(free.t * 0.1, e[0].max() * conditioning(d.detail).transient_constant * 0.7 ** free.t, "k--", lw=1,
            label="certified envelope")
a2.set_xlabel("t (s)")
a2.set_ylabel(r"$\|\hat x_i - x\|$")
a2.legend(fontsize=8)
plt.show()
still = ss.simulate(sc2, noise=False)  # the python-control plant: no u given, so u = 0
moved = float(np.abs(free.x - still.x).max())
same = float(np.abs((free.xhat - free.x[:, None]) - (still.xhat - still.x[:, None])).max())
print(f"the inputs move the platoon by up to {moved:.1f} m; the errors differ by {same:.1e}")
assert same <= 1e-9 * np.abs(free.x).max()

# %% [markdown]
# ## 3. Under noise, against the centralized Kalman filter

# %%
res = ss.compare(sc, seeds=5)
for name, r in res.estimators.items():
    print(f"{name:15s} steady RMS error {r.rms_mean:7.3g} ({r.ratio_to_centralized:5.3g} x centralized)")

# %% [markdown]
# ## 4. As real processes
#
# In `run` the plant process sends $u(\tau)$ with the measurements and every agent process adds $B u$;
# the run equals the simulation to round-off.

# %%
rec = ss.run(sc, out=out)
diff = np.nanmax(np.abs(rec.trajectory.xhat - ss.simulate(sc).xhat))
print(f"{len(rec.trajectory.t)} event times, q = {rec.design().q}: max |run - simulate| = {diff:.1e}")
assert diff <= 1e-9 * np.nanmax(np.abs(rec.trajectory.xhat))
