"""Write examples/rego_ring.yaml: the 20-agent ring of Rego's steady-state distributed Kalman filter benchmark.

F. C. Rego, Y. Pu, A. Alessandretti, A. P. Aguiar, A. M. Pascoal, C. N. Jones, "A distributed Luenberger observer for
linear state feedback systems with quantized and rate-limited communications" and the public MATLAB code of the
steady-state distributed Kalman filter (ffcrego87/Steady-State-Distributed-Kalman-Filter-MATLAB, ``problem.m`` and
``util/setup_script.m``): 20 agents each owning a 2-dimensional random walk (``A = I`` of 40 states), agent i measures
its position relative to both ring neighbours (``x_i - x_{i+1}`` and ``x_i - x_{i-1}``, 2 numbers each), the last
agent its own position alone (the one absolute sensor); ``Q = I``, ``R = I``; an undirected ring, one neighbour on
each side.  The numbers are what the MATLAB code builds; the file is written here, not copied.

    python examples/models/make_rego_ring.py      # writes examples/rego_ring.yaml
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

AGENTS = 20
DIM = 2  # each agent's local state: a planar random walk


def output_matrices(agents: int = AGENTS, dim: int = DIM) -> list:
    """Each agent's ``C_i`` (0-based agent order): two relative sensors, the last agent one absolute sensor."""
    Cs = []
    for i in range(agents):
        if i == agents - 1:
            G = np.zeros((1, agents))
            G[0, i] = 1.0
        else:
            G = np.zeros((2, agents))
            G[0, i] = G[1, i] = 1.0
            G[0, (i + 1) % agents] = -1.0
            G[1, (i - 1) % agents] = -1.0
        Cs.append(np.kron(G, np.eye(dim)))
    return Cs


def scenario_text(agents: int = AGENTS, dim: int = DIM) -> str:
    n = agents * dim
    rows = lambda M: "\n".join(f"    - [{', '.join(f'{v + 0.0:g}' for v in r)}]" for r in M)  # noqa: E731
    Cs = output_matrices(agents, dim)
    lines = [
        "# Rego's 20-agent ring (the steady-state distributed Kalman filter benchmark): 20 planar random walks",
        "# (A = I, 40 states), each agent measuring its position relative to both ring neighbours, the last agent",
        "# its own position; Q = I, R = I; an undirected ring.  Written by examples/models/make_rego_ring.py.",
        "name: rego-ring",
        "time: discrete",
        "system:",
        "  A: identity",
        "  C:",
    ]
    for i, C in enumerate(Cs, start=1):
        lines.append(f"    {i}:")
        lines.append(rows(C).replace("\n    - ", "\n      - ").replace("    - ", "      - ", 1))
    lines += [
        "  process_noise: 1.0",
        "  measurement_noise: 1.0",
        "graphs:",
        "  ring:",
        "    undirected: [" + ", ".join(f"[{i}, {i % agents + 1}]" for i in range(1, agents + 1)) + "]",
        "# one exchange per event time, its estimate fused with matrix weights chosen for the noise (design.consensus:",
        "# fusion); remove consensus and q for the default design (the whole state, q = 33)",
        "design: {rate: 0.9, consensus: fusion, q: 1}",
        "run: {steps: 400, seed: 1}",
    ]
    text = "\n".join(lines) + "\n"
    return text.replace("  A: identity", "  A:\n" + "\n".join(
        f"  - [{', '.join('1' if c == r else '0' for c in range(n))}]" for r in range(n)))


if __name__ == "__main__":
    out = Path(__file__).resolve().parents[1] / "rego_ring.yaml"
    out.write_text(scenario_text())
    print(f"wrote {out}")
