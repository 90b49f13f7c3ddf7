"""Random systems and graphs that satisfy the paper's assumptions by construction.

Used by the property tests and the benchmarks.  ``A`` is block diagonal in a
random orthogonal basis: 2x2 oscillator blocks with distinct frequencies (and
one real mode when n is odd), so no agent alone need observe everything but
every block is observed by someone, hence ``(C, A)`` is jointly observable
(PBH test on distinct eigenvalues).  Graphs are a random directed ring (strongly
connected) plus random extra arcs.

:func:`ring_system` and :func:`ring_arcs` build the resilience benchmark: an
undirected ring (still strongly connected, as a path, after any one agent is
lost) whose agents each observe one oscillator block that every
``nb``-th agent also observes, so the survivors of any single loss still
jointly observe ``(C, A)``.
"""

from __future__ import annotations

import numpy as np

__all__ = ["random_system", "random_strongly_connected_arcs", "ring_system", "ring_arcs", "ring_scenario"]


def _oscillator_blocks(rng: np.random.Generator, n: int, time: str) -> tuple:
    """``(A, edges)``: block-diagonal A of 2x2 oscillators (and one real mode for odd n), distinct eigenvalues."""
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
    return A, np.concatenate([[0], np.cumsum(sizes)])


def random_system(rng: np.random.Generator, m: int, n: int, *, time: str = "discrete",
                  rotate: bool = True) -> tuple:
    """``(A, Cs)``: jointly observable by construction; agent i observes a random subset of blocks.

    Discrete blocks are rotations (eigenvalues on the unit circle, the paper's
    example is of this kind); continuous blocks are undamped oscillators.

    Parameters
    ----------
    rng : numpy.random.Generator
        The random numbers.
    m : int
        Number of agents.
    n : int
        Number of states.
    time : {"discrete", "continuous"}, default "discrete"
        Kind of blocks.
    rotate : bool, default True
        Write the system in a random orthogonal basis (else block diagonal).

    Returns
    -------
    A : (n, n) array
    Cs : list of (1, n) arrays
        One output row per agent.

    Examples
    --------
    >>> import numpy as np
    >>> A, Cs = random_system(np.random.default_rng(0), 3, 4)
    >>> A.shape, [C.shape for C in Cs]
    ((4, 4), [(1, 4), (1, 4), (1, 4)])
    """
    A, edges = _oscillator_blocks(rng, n, time)
    nb = len(edges) - 1
    # every block gets an owner; each agent also sees a few random blocks
    owners = [set() for _ in range(m)]
    for b in range(nb):
        owners[int(rng.integers(m))].add(b)
    for i in range(m):
        extra = rng.integers(0, max(1, nb // 2) + 1)
        owners[i].update(rng.choice(nb, size=min(nb, int(extra)), replace=False).tolist())
        if not owners[i]:
            owners[i].add(int(rng.integers(nb)))
    Cs = [_output_row(rng, n, edges, owners[i]) for i in range(m)]
    return _rotated(rng, A, Cs, rotate)


def _output_row(rng: np.random.Generator, n: int, edges, blocks) -> np.ndarray:
    """A (1, n) output row observing ``blocks`` (random entries, the first of each block never zero)."""
    c = np.zeros((1, n))
    for b in blocks:
        c[0, edges[b]:edges[b + 1]] = rng.normal(size=edges[b + 1] - edges[b])
        c[0, edges[b]] += np.sign(c[0, edges[b]]) * 0.5 + (c[0, edges[b]] == 0)  # never zero
    return c


def _rotated(rng: np.random.Generator, A: np.ndarray, Cs: list, rotate: bool) -> tuple:
    """``(A, Cs)`` in a random orthogonal basis when ``rotate``."""
    if rotate:
        n = A.shape[0]
        T, _ = np.linalg.qr(rng.normal(size=(n, n)))
        A = T @ A @ T.T
        Cs = [c @ T.T for c in Cs]
    return A, Cs


def random_strongly_connected_arcs(rng: np.random.Generator, m: int, *, extra: int = 0,
                                   undirected: bool = False) -> list:
    """Arcs ``(j, i)`` (0-based) of a random ring (a random vertex order) plus ``extra`` random arcs.

    Parameters
    ----------
    rng : numpy.random.Generator
        The random numbers.
    m : int
        Number of agents.
    extra : int, default 0
        Random arcs drawn on top of the ring (a duplicate is merged).
    undirected : bool, default False
        Add every arc's reverse.

    Returns
    -------
    list of (int, int)
        Sorted, without self-arcs.
    """
    order = rng.permutation(m)
    arcs = {(int(order[k]), int(order[(k + 1) % m])) for k in range(m)} if m > 1 else set()
    for _ in range(extra):
        j, i = rng.choice(m, size=2, replace=False) if m > 1 else (0, 0)
        if j != i:
            arcs.add((int(j), int(i)))
    if undirected:
        arcs |= {(i, j) for j, i in arcs}
    return sorted(arcs)


def ring_system(rng: np.random.Generator, m: int, n: int, *, time: str = "discrete", rotate: bool = True) -> tuple:
    """``(A, Cs)``: redundantly jointly observable; agent i observes oscillator block ``i mod nb`` alone.

    ``A`` as in :func:`random_system`; agent i (0-based) has one output, a random
    combination of the coordinates of block ``i mod nb`` (``nb`` = number of
    blocks, ``ceil(n / 2)``).  With ``m >= 2 nb`` every block is observed by at
    least two agents, so any ``m - 1`` agents still jointly observe ``(C, A)``
    (PBH test on distinct eigenvalues).

    Parameters
    ----------
    rng : numpy.random.Generator
        The random numbers.
    m, n : int
        Number of agents and of states.
    time : {"discrete", "continuous"}, default "discrete"
        Kind of blocks.
    rotate : bool, default True
        Write the system in a random orthogonal basis.

    Returns
    -------
    A : (n, n) array
    Cs : list of (1, n) arrays

    Raises
    ------
    ValueError
        If ``m < 2 ceil(n / 2)``.
    """
    A, edges = _oscillator_blocks(rng, n, time)
    nb = len(edges) - 1
    if m < 2 * nb:
        raise ValueError(f"ring_system needs m >= 2 * ceil(n / 2) = {2 * nb} agents for every block to be observed "
                         f"twice, got m = {m}")
    Cs = [_output_row(rng, n, edges, [i % nb]) for i in range(m)]
    return _rotated(rng, A, Cs, rotate)


def ring_arcs(m: int) -> list:
    """Arcs ``(j, i)`` (0-based) of the undirected ring ``0 - 1 - ... - m-1 - 0`` (both directions).

    It is redundantly strongly connected: without any one agent it is a path.

    Parameters
    ----------
    m : int
        Number of agents.

    Returns
    -------
    list of (int, int)
        Sorted.

    Examples
    --------
    >>> ring_arcs(3)
    [(0, 1), (0, 2), (1, 0), (1, 2), (2, 0), (2, 1)]
    """
    arcs = {(k, (k + 1) % m) for k in range(m)} if m > 1 else set()
    return sorted(arcs | {(i, j) for j, i in arcs})


def chord_arcs(rng: np.random.Generator, m: int) -> list:
    """Arcs ``(j, i)`` (0-based) of the undirected ring plus one random undirected chord per agent (to an agent
    that is not a ring neighbour; duplicates merged).  A ring of m mixes in about m^2 steps; with the chords the
    graph is an expander with high probability, whose consensus converges in O(log m) exchanges: the sensor
    networks of hundreds or thousands of agents the method is for.

    Parameters
    ----------
    rng : numpy.random.Generator
        The random numbers.
    m : int
        Number of agents (no chords below 4).

    Returns
    -------
    list of (int, int)
        Sorted.
    """
    arcs = set(ring_arcs(m))
    if m > 3:
        for i in range(m):
            j = (i + 2 + int(rng.integers(m - 3))) % m  # not i, not its two ring neighbours
            arcs |= {(i, j), (j, i)}
    return sorted(arcs)


def ring_scenario(m: int, n: int = 10, *, time: str = "discrete", resilience: int = 0, seed: int = 0,
                  rate: float = 0.5, q_method: str = "spectral", chords: bool = False) -> dict:
    """A scenario mapping (as a YAML file holds it): :func:`ring_system` on the undirected :func:`ring_arcs`
    (with ``chords``, :func:`chord_arcs`: one random chord per agent as well), place gains, ``q`` (discrete) or
    ``g`` (continuous) auto.

    Parameters
    ----------
    m : int
        Number of agents (ids 1..m), at least ``2 ceil(n / 2)``.
    n : int, default 10
        Number of states.
    time : {"discrete", "continuous"}, default "discrete"
        The scenario's time.
    resilience : int, default 0
        ``design.resilience``.
    seed : int, default 0
        Seed of the random system (and chords).
    rate : float, default 0.5
        ``design.rate``.
    q_method : str, default "spectral"
        ``design.q_method`` (discrete only).
    chords : bool, default False
        Add one random chord per agent.

    Returns
    -------
    dict
        Keys ``name``, ``time``, ``system``, ``graphs`` (one graph, ``ring``), ``design``.

    Raises
    ------
    ValueError
        As :func:`ring_system`.

    Examples
    --------
    >>> from splitspec_core.scenarios.sections import parse_scenario
    >>> sc = parse_scenario(ring_scenario(4, 4))
    >>> sc.n, sc.agent_ids, sc.graph_names
    (4, (1, 2, 3, 4), ('ring',))
    """
    rng = np.random.default_rng(seed)
    A, Cs = ring_system(rng, m, n, time=time)
    arcs = chord_arcs(rng, m) if chords else ring_arcs(m)
    design = {"rate": rate, "gains": "place"}
    design.update({"q": "auto", "q_method": q_method} if time == "discrete" else {"g": "auto"})
    design["resilience"] = resilience
    return {
        "name": f"ring{m}", "time": time,
        "system": {"A": A.tolist(), "C": {i + 1: C.tolist() for i, C in enumerate(Cs)}},
        "graphs": {"ring": {"arcs": [[j + 1, i + 1] for j, i in arcs]}},
        "design": design,
    }
