"""A tour of the Python API: design, simulate and compare split-spectrum estimators built with numpy.

    .venv/bin/python examples/api_tour.py [--plot FILE.png]

Three agents watch two oscillators (the paper's Section 5 system); none sees the whole state.
The tour designs the discrete-time estimator, simulates it, kills an agent, and compares the
design with the centralized Kalman filter under noise.  Every number printed is computed here.
"""

from __future__ import annotations

import argparse

import numpy as np

import splitspec_core as ss


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--plot", metavar="FILE", help="also save the error curves to FILE (matplotlib)")
    args = ap.parse_args()

    # 1. A system built with numpy: two oscillators, agent i sees one coordinate (y_i = C_i x)
    A = np.array([[0.0, 1, 0, 0], [-1, 0, 0, 0], [0, 0, 0, 1], [0, 0, -2, 0]])
    C = {i: np.eye(4)[[i - 1]] for i in (1, 2, 3)}  # C_i = i-th unit row
    ring = {"a": [(1, 2), (2, 1), (2, 3), (3, 2), (1, 3)]}  # (j, i): agent i hears agent j
    sc = ss.scenario(name="tour", A=A, C=C, graphs=ring, time="discrete", rate=0.5, gains="place",
                     steps=40, seed=1)

    # 2. Design: local gains K_i, the unobservable-space bases V_i, and q with its certificate
    d = ss.design(sc)
    print(f"design: q = {d.q} consensus exchanges per event time; {d.checks.certificate}")
    for i, agent in d.agents.items():
        print(f"  agent {i}: K_{i}' = {np.round(agent.K.ravel(), 3)}, poles {np.round(agent.poles.real, 3)}, "
              f"unobservable dimension {agent.n_unobservable}")

    # 3. Simulate: every agent's error decays at least as fast as c 0.5^tau
    tr = ss.simulate(d, steps=40, seed=1)
    err = tr.errors()  # (T, m): |x_i - x| per agent
    worst = err.max(axis=1)
    c = np.max(worst / d.rate ** tr.t)  # the smallest c with |x_i - x| <= c lam^tau for all tau
    print(f"simulate: T = {len(tr.t)}, max error {worst[0]:.3g} -> {worst[-1]:.3g}; "
          f"every error <= {c:.3g} x {d.rate}^tau")

    # 4. Faults are scenario keys too: agent 1 dies at event time 10 and comes back at 25 (agents 2 and 3
    #    alone still hear each other and see both oscillators, so they keep converging meanwhile)
    faulty = ss.scenario(name="tour-faults", A=A, C=C, graphs=ring, rate=0.5, gains="place",
                         faults=[{"at": 10, "kill": 1}, {"at": 25, "restart": 1}])
    tf = ss.simulate(faulty, steps=40, seed=1)
    dead = np.flatnonzero(~tf.alive[:, 0])
    print(f"faults: agent 1 dead for event times {dead.min()}..{dead.max()}; errors at event time 24 "
          f"{np.array2string(tf.errors()[24], precision=2)}, at 40 {np.array2string(tf.errors()[-1], precision=2)}")

    # 5. Compare under noise with the centralized Kalman filter and a Kalman-consensus filter, on two
    #    rotations (the paper's A grows as 1.41^tau in discrete time: too fast for 200 noisy steps in float64)
    def rotation(theta: float) -> np.ndarray:
        return np.array([[np.cos(theta), np.sin(theta)], [-np.sin(theta), np.cos(theta)]])

    R = np.zeros((4, 4))
    R[:2, :2], R[2:, 2:] = rotation(0.3), rotation(0.7)
    noisy = ss.scenario(name="tour-noise", A=R, C=C, graphs=ring, rate=0.5, gains="place",
                        process_noise=0.1, measurement_noise=0.1, steps=200, seed=1)
    cmp = ss.compare(noisy, seeds=3)
    print("compare (steady-state RMS error over 3 seeds):")
    for name, r in cmp.estimators.items():
        print(f"  {name:<16} {r.rms_mean:8.4f}  x{r.ratio_to_centralized:5.2f} of centralized, "
              f"{r.messages_per_event} messages per event time")

    if args.plot:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        fig, ax = plt.subplots(figsize=(7, 4))
        for k, i in enumerate(tr.agent_ids):
            ax.semilogy(tr.t, err[:, k], label=f"agent {i}")
        ax.semilogy(tr.t, err[0].max() * d.rate ** tr.t, "k--", label=f"{d.rate}^tau")
        ax.set_xlabel("event time tau")
        ax.set_ylabel("|x_i - x|")
        ax.legend(loc="lower left")
        fig.savefig(args.plot, dpi=100, bbox_inches="tight")
        print(f"wrote {args.plot}")


if __name__ == "__main__":
    main()
