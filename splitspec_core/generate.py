"""Random systems and graphs that satisfy the paper's assumptions by construction.

Used by the property tests and the benchmarks.  ``A`` is block diagonal in a
random orthogonal basis: 2x2 oscillator blocks with distinct frequencies (and
one real mode when n is odd), so no agent alone need observe everything but
every block is observed by someone, hence ``(C, A)`` is jointly observable
(PBH test on distinct eigenvalues).  Graphs are a random directed ring (strongly
connected) plus random extra arcs.
"""

from __future__ import annotations

import numpy as np

__all__ = ["random_system", "random_strongly_connected_arcs"]


def random_system(rng: np.random.Generator, m: int, n: int, *, time: str = "discrete",
                  rotate: bool = True) -> tuple:
    """``(A, Cs)``: jointly observable by construction; agent i observes a random subset of blocks.

    Discrete blocks are rotations (eigenvalues on the unit circle, the paper's
    example is of this kind); continuous blocks are undamped oscillators.
    """
    sizes = [2] * (n // 2) + ([1] if n % 2 else [])
    nb = len(sizes)
    freqs = np.sort(rng.uniform(0.2, 2.0, size=nb))
    freqs += np.arange(nb) * 1e-2  # keep eigenvalues distinct
    A = np.zeros((n, n))
    k = 0
    for b, s in enumerate(sizes):
        w = freqs[b]
        if s == 2:
            blk = ([[np.cos(w), np.sin(w)], [-np.sin(w), np.cos(w)]] if time == "discrete"
                   else [[0.0, w], [-w, 0.0]])
        else:
            blk = [[rng.uniform(0.5, 1.1)]] if time == "discrete" else [[rng.uniform(-0.5, 0.5)]]
        A[k:k + s, k:k + s] = blk
        k += s
    edges = np.concatenate([[0], np.cumsum(sizes)])
    # every block gets an owner; each agent also sees a few random blocks
    owners = [set() for _ in range(m)]
    for b in range(nb):
        owners[int(rng.integers(m))].add(b)
    for i in range(m):
        extra = rng.integers(0, max(1, nb // 2) + 1)
        owners[i].update(rng.choice(nb, size=min(nb, int(extra)), replace=False).tolist())
        if not owners[i]:
            owners[i].add(int(rng.integers(nb)))
    Cs = []
    for i in range(m):
        c = np.zeros((1, n))
        for b in owners[i]:
            c[0, edges[b]:edges[b + 1]] = rng.normal(size=edges[b + 1] - edges[b])
            c[0, edges[b]] += np.sign(c[0, edges[b]]) * 0.5 + (c[0, edges[b]] == 0)  # never zero
        Cs.append(c)
    if rotate:
        T, _ = np.linalg.qr(rng.normal(size=(n, n)))
        A = T @ A @ T.T
        Cs = [c @ T.T for c in Cs]
    return A, Cs


def random_strongly_connected_arcs(rng: np.random.Generator, m: int, *, extra: int = 0,
                                   undirected: bool = False) -> list:
    """Arcs ``(j, i)`` (0-based) of a random ring (a random vertex order) plus ``extra`` random arcs."""
    order = rng.permutation(m)
    arcs = {(int(order[k]), int(order[(k + 1) % m])) for k in range(m)} if m > 1 else set()
    for _ in range(extra):
        j, i = rng.choice(m, size=2, replace=False) if m > 1 else (0, 0)
        if j != i:
            arcs.add((int(j), int(i)))
    if undirected:
        arcs |= {(i, j) for j, i in arcs}
    return sorted(arcs)
