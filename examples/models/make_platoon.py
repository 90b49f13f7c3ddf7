"""Write examples/models/platoon.mat: a platoon of four cars with a first-order drivetrain (a MATLAB v5 file).

Each car i has position p_i, speed v_i and acceleration a_i, and follows its desired acceleration u_i through
its drivetrain's lag: p_i' = v_i, v_i' = a_i, a_i' = (u_i - a_i) / tau, with tau = 0.1 s, the engine time
constant identified for the Toyota Prius test vehicles of Ploeg, Scheepers, van Nunen, van de Wouw and Nijmeijer,
"Design and experimental evaluation of cooperative adaptive cruise control", IEEE ITSC 2011 (Table I).  The
desired accelerations u are known to every car (cooperative adaptive cruise control broadcasts them over V2V).

Sensors: the lead car has GPS (its position) and a wheel-speed sensor; every follower has a radar measuring the
gap to the car ahead (p_{i-1} - p_i) and its own wheel speed.

    python examples/models/make_platoon.py        # writes examples/models/platoon.mat (scipy.io.savemat)
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import scipy
import scipy.io

TAU = 0.1  # s, drivetrain lag (Ploeg et al. 2011, Table I)
CARS = 4


def platoon(cars: int = CARS, tau: float = TAU) -> dict:
    n = 3 * cars
    A = np.zeros((n, n))
    B = np.zeros((n, cars))
    names = []
    for i in range(cars):
        p, v, a = 3 * i, 3 * i + 1, 3 * i + 2
        A[p, v] = 1.0
        A[v, a] = 1.0
        A[a, a] = -1.0 / tau
        B[a, i] = 1.0 / tau
        names += [f"p{i + 1}", f"v{i + 1}", f"a{i + 1}"]
    out = {"A": A, "B": B}
    for i in range(cars):
        C = np.zeros((2, n))
        if i == 0:
            C[0, 0] = 1.0  # GPS: p1
        else:
            C[0, 3 * (i - 1)], C[0, 3 * i] = 1.0, -1.0  # radar: p_{i-1} - p_i
        C[1, 3 * i + 1] = 1.0  # wheel speed: v_i
        out[f"C{i + 1}"] = C
        out[f"outputs{i + 1}"] = np.array(["gps1" if i == 0 else f"gap{i + 1}", f"speed{i + 1}"], dtype=object)
    out["states"] = np.array(names, dtype=object)  # a cell array of strings
    out["made_by"] = f"examples/models/make_platoon.py (scipy {scipy.__version__})"
    return out


def main() -> None:
    path = Path(__file__).with_name("platoon.mat")
    scipy.io.savemat(path, platoon(), do_compression=True)
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
