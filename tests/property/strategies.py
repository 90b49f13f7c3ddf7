"""Hypothesis strategies: scenarios that satisfy the paper's assumptions by construction.

System (``x+ = A x`` or ``x' = A x``)
------------------------------------
``A = T blockdiag(D_1..D_b) T'`` with ``T`` orthogonal (or the identity) and
modes ``D_k`` that are either 2x2 blocks with a complex pair or 1x1 real
modes.  Every eigenvalue is distinct and taken from a coarse grid, so the
observability matrices stay well conditioned (no clustered Vandermonde
nodes).  Agent i "owns" a set of blocks: ``C_i = c_i T'`` where each row of
``c_i`` is nonzero (norm >= 0.3) on a subset of the owned blocks and the first
row on every owned block, zero elsewhere.  With distinct eigenvalues the PBH
test gives: the unobservable space of ``(C_i, A)`` is exactly
``T span{e_k : k in unowned blocks}``.  Every block has at least one owner,
hence ``(C, A)`` is jointly observable.  An agent may own nothing (``C_i = 0``,
``V_i = R^n``); ``C_i`` may have a second row, a multiple of the first or well
independent of it (singular value ratio >= 1e-3), or, with ``near_dependent``,
one that differs from a multiple of the first by 1e-4..1e-10.

Rank decisions: the scenarios set ``design.rank_tol: 1e-12`` (the round-off floor of
:mod:`splitspec_core.model.observability`), so the design takes the construction's exact unobservable
spaces and the paper's split holds exactly: these tests check the paper's certificates.  Under
the default threshold (graded margin 1e-3) about one drawn system in twelve has an agent whose
genuinely weak direction (8 states seen through one output: graded margins down to ~1e-4) is left
to consensus instead; ``scenarios(rank_tol="auto")`` draws those too.

Sizes: m = 1..8 agents (mostly 2..8), n = 1..10 states.  An agent observes at
most 8 (discrete) or 6 (continuous) states, and large gain shifts are avoided:
the local gains are numerically meaningless beyond that (see the comment in
:func:`scenarios`), which is a limit of double precision, not of the paper.

Graphs
------
A directed ring through a random vertex order (strongly connected) plus random
extra arcs, optionally made undirected.  Metropolis weights only when every
graph is undirected.  Two graphs switch by a (periodic) schedule or at random.

:func:`scenarios` returns a :class:`Drawn` with the plain scenario dict (same
schema as ``examples/*.yaml``) and the construction facts the tests check the
design against (expected ``V_i`` spans).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from hypothesis import strategies as st

__all__ = ["Drawn", "scenarios", "graph_sequences"]

# eigenvalue grids (distinct, well separated)
_DISCRETE_ANGLES = np.linspace(0.25, 2.85, 14)  # complex pairs r e^{+-i w}
_DISCRETE_REALS = np.round(np.linspace(-1.1, 1.1, 12), 12)  # real modes
_CONT_FREQS = np.linspace(0.3, 3.0, 10)  # complex pairs s +- i w
_CONT_REALS = np.round(np.linspace(-1.0, 1.0, 11), 12)


@dataclass(frozen=True)
class Drawn:
    """A drawn scenario with its construction.

    Attributes
    ----------
    data : dict
        The scenario as a plain mapping (``parse_scenario`` input).
    T : (n, n) array
        Orthogonal change of basis, ``A = T D T'``.
    edges : tuple of int
        Block boundaries of ``D`` (``len = blocks + 1``).
    owned : tuple of frozenset
        Blocks each agent observes, in sorted agent-id order.
    """

    data: dict
    T: np.ndarray
    edges: tuple
    owned: tuple

    def expected_V_basis(self, k: int) -> np.ndarray:
        """Basis (columns of ``T``) of agent k's unobservable space (the unowned blocks)."""
        cols = [c for b in range(len(self.edges) - 1) if b not in self.owned[k]
                for c in range(self.edges[b], self.edges[b + 1])]
        return self.T[:, cols]


def _sizes_m():
    """Mostly 2..8 agents, a single one once in 22 draws."""
    return st.sampled_from([1] + list(range(2, 9)) * 3)


@st.composite
def _modes(draw, n: int, time: str) -> tuple:
    """The diagonal blocks of ``D`` in random order (distinct eigenvalues from the grids)."""
    pairs = draw(st.integers(0, n // 2))
    reals = n - 2 * pairs
    if time == "discrete":
        w_idx = draw(st.lists(st.integers(0, len(_DISCRETE_ANGLES) - 1), min_size=pairs, max_size=pairs, unique=True))
        r_idx = draw(st.lists(st.integers(0, len(_DISCRETE_REALS) - 1), min_size=reals, max_size=reals, unique=True))
        blocks = []
        for k in w_idx:
            rad = draw(st.floats(0.75, 1.1))
            w = _DISCRETE_ANGLES[k]
            blocks.append(rad * np.array([[np.cos(w), np.sin(w)], [-np.sin(w), np.cos(w)]]))
        blocks += [np.array([[_DISCRETE_REALS[k]]]) for k in r_idx]
    else:
        w_idx = draw(st.lists(st.integers(0, len(_CONT_FREQS) - 1), min_size=pairs, max_size=pairs, unique=True))
        r_idx = draw(st.lists(st.integers(0, len(_CONT_REALS) - 1), min_size=reals, max_size=reals, unique=True))
        blocks = []
        for k in w_idx:
            s = draw(st.floats(-0.4, 0.4))
            w = _CONT_FREQS[k]
            blocks.append(np.array([[s, w], [-w, s]]))
        blocks += [np.array([[_CONT_REALS[k]]]) for k in r_idx]
    order = draw(st.permutations(range(len(blocks))))
    return [blocks[k] for k in order]


@st.composite
def _coefficient(draw, size: int) -> np.ndarray:
    """A block of an output row with norm in [0.3, 1.5] (never unobservable by accident)."""
    mag = draw(st.floats(0.3, 1.5))
    if size == 1:
        return np.array([mag * draw(st.sampled_from([-1.0, 1.0]))])
    th = draw(st.floats(0.0, 2 * np.pi))
    return mag * np.array([np.cos(th), np.sin(th)])


@st.composite
def _system(draw, m: int, time: str, n_max: int = 10, own_cap: int = 10, near_dependent: bool = False) -> tuple:
    n = draw(st.integers(1, min(n_max, m * own_cap)))
    blocks = draw(_modes(n, time))
    nb = len(blocks)
    edges = tuple(int(e) for e in np.concatenate([[0], np.cumsum([b.shape[0] for b in blocks])]))
    D = np.zeros((n, n))
    for b, blk in enumerate(blocks):
        D[edges[b]:edges[b + 1], edges[b]:edges[b + 1]] = blk
    # every block gets an owner (joint observability); agents may own more, or nothing;
    # an agent observes at most own_cap states (see scenarios(): conditioning of the local gains)
    size = [edges[b + 1] - edges[b] for b in range(nb)]
    owned = [set() for _ in range(m)]
    load = [0] * m
    for b in range(nb):
        i = draw(st.sampled_from([k for k in range(m) if load[k] + size[b] <= own_cap]))
        owned[i].add(b)
        load[i] += size[b]
    for i in range(m):
        for b in draw(st.lists(st.integers(0, nb - 1), max_size=nb, unique=True)):
            if b not in owned[i] and load[i] + size[b] <= own_cap:
                owned[i].add(b)
                load[i] += size[b]
    cs = []
    for i in range(m):
        rows = 2 if near_dependent else draw(st.integers(1, 2))
        c = np.zeros((rows, n))
        # the first row touches every owned block; a second row touches a subset of them, or is a
        # multiple of the first (rank-deficient C_i), or (near_dependent) nearly so: two sensors of
        # the same thing, whose weakly determined difference must not leak into the rank decisions
        for b in sorted(owned[i]):
            c[0, edges[b]:edges[b + 1]] = draw(_coefficient(edges[b + 1] - edges[b]))
        if rows == 2 and owned[i]:
            kind = "nearly" if near_dependent else draw(st.sampled_from(["subset", "multiple"]))
            use = sorted(draw(st.sets(st.sampled_from(sorted(owned[i])), max_size=nb))) if kind == "subset" \
                else sorted(owned[i])
            for b in use:
                c[1, edges[b]:edges[b + 1]] = draw(_coefficient(edges[b + 1] - edges[b]))
            if kind != "subset":
                f = draw(st.floats(0.1, 2.0)) * draw(st.sampled_from([-1.0, 1.0]))
                delta = 0.0 if kind == "multiple" else draw(st.sampled_from([1e-4, 1e-7, 1e-8, 1e-10]))
                c[1] = f * c[0] + delta * c[1]
            sv = np.linalg.svd(c, compute_uv=False)
            if not near_dependent and len(sv) == 2 and 0 < sv[1] < 1e-3 * sv[0]:
                # a subset row at almost the angle of the first (one shared 2x2 block): every result
                # of the design then carries round-off amplified by sv[0] / sv[1] (K ~ 1 / sv[1]);
                # keep the main properties on well-conditioned C_i
                c[1] = c[0]
        cs.append(c)
    if draw(st.booleans()):
        seed = draw(st.integers(0, 2**32 - 1))
        T, R = np.linalg.qr(np.random.default_rng(seed).normal(size=(n, n)))
        T = T * np.sign(np.diag(R))
    else:
        T = np.eye(n)
    A = T @ D @ T.T
    Cs = [c @ T.T for c in cs]
    return A, Cs, T, edges, tuple(frozenset(o) for o in owned)


@st.composite
def _arcs(draw, m: int) -> tuple:
    """Arcs ``(j, i)`` (0-based) of a strongly connected graph, and whether it is undirected."""
    if m == 1:
        return [], True
    order = draw(st.permutations(range(m)))
    arcs = {(order[k], order[(k + 1) % m]) for k in range(m)}
    extra = draw(st.lists(st.tuples(st.integers(0, m - 1), st.integers(1, m - 1)), max_size=2 * m))
    arcs |= {(j, (j + d) % m) for j, d in extra}
    undirected = draw(st.booleans())
    if undirected:
        arcs |= {(i, j) for j, i in arcs}
    return sorted(arcs), undirected


@st.composite
def scenarios(draw, *, time: str | None = None, q_method: str | None = None, m_max: int = 8,
              n_max: int = 10, graphs: int | None = None, near_dependent: bool = False,
              rank_tol: float | str = 1e-12) -> Drawn:
    """A valid scenario (see the module docstring); ``None`` arguments are drawn.

    ``near_dependent``: every observing agent has two output rows that differ by 1e-4..1e-10 of
    their size (valid, but ill-conditioned: for rank-decision tests of the local decomposition).
    """
    time = time or draw(st.sampled_from(["discrete", "continuous"]))
    m = draw(_sizes_m().filter(lambda k: k <= m_max))
    ids = sorted(draw(st.lists(st.integers(1, 40), min_size=m, max_size=m, unique=True)))
    rate = draw(st.floats(0.3, 0.95) if time == "discrete" else st.floats(0.2, 2.0))
    gains = draw(st.sampled_from(["place", "riccati"]))
    margins = [0.5, 0.5, 0.2, 1.0, 2.0]
    # Numerical conditioning of the LOCAL gains (gains.py), not an assumption of the paper.  With one
    # output observing many states, both gain methods degrade as the shift grows:
    # * continuous pole placement needs |K| ~ 1e8..1e9 for 7-9 states at shift rate (1 + margin) > 3
    #   (e.g. 4 oscillators + 1 real mode, C_1 = [1 0 1 0 1 0 1 0 -0.375], rate 2: numpy puts an
    #   eigenvalue of the stored A + K C at -1.88 while its exact spectrum is left of -3), so no
    #   double-precision check of the rate is meaningful;
    # * scipy's CARE/DARE fail ("Failed to find a finite solution") or return an X whose closed loop
    #   misses the rate (e.g. A = diag(-1, -0.8, ..., 0.6), C_1 = -1', rate 2), which design_gain
    #   rejects loudly; discrete placement at rate 0.3 with 10 states misses the rate likewise.
    # Keep <= 6 (continuous) / 8 (discrete) states per agent, continuous shifts <= 3 and discrete
    # Riccati radii rate / (1 + margin) >= 0.2 (CI drew a DARE with no finite solution at radius 0.1532, four
    # slow modes of modulus 1.1 seen by one agent; solved at 0.161: tests/unit/test_observability_gains.py).
    own_cap = 8 if time == "discrete" else 6
    if time == "continuous":
        margins = [x for x in margins if rate * (1 + x) <= 3.0] or [0.2]
    elif gains == "riccati":
        margins = [x for x in margins if rate / (1 + x) >= 0.2] or [0.2]
    A, Cs, T, edges, owned = draw(_system(m, time, n_max, own_cap, near_dependent))
    ngraphs = graphs or draw(st.integers(1, 2))
    gs = [draw(_arcs(m)) for _ in range(ngraphs)]
    names = [f"g{k + 1}" for k in range(ngraphs)]
    data: dict = {
        "name": "drawn",
        "time": time,
        "system": {"A": A.tolist(), "C": {ids[k]: Cs[k].tolist() for k in range(m)}},
        "graphs": {name: {"arcs": [[ids[j], ids[i]] for j, i in arcs]} for name, (arcs, _) in zip(names, gs)},
    }
    if ngraphs == 2:
        if draw(st.booleans()):
            if time == "discrete":
                t1, t2 = draw(st.integers(1, 5)), draw(st.integers(1, 5))
            else:
                t1, t2 = draw(st.floats(0.05, 2.0)), draw(st.floats(0.05, 2.0))
            data["switching"] = {"schedule": [[0, names[0]], [t1, names[1]]], "period": t1 + t2}
        else:
            dwell = draw(st.integers(1, 5)) if time == "discrete" else draw(st.floats(0.05, 2.0))
            data["switching"] = {"random": {"graphs": names, "dwell": dwell, "seed": draw(st.integers(0, 1000))}}
    design: dict = {"rate": rate, "gains": gains, "margin": draw(st.sampled_from(margins)), "rank_tol": rank_tol}
    if design["gains"] == "riccati" and draw(st.booleans()):
        design["riccati"] = {"process_weight": draw(st.floats(0.1, 10.0)),
                             "measurement_weight": draw(st.floats(0.1, 10.0))}
    if time == "discrete":
        design["q_method"] = q_method or draw(st.sampled_from(["spectral", "weighted", "two-norm", "mixed"]))
    if all(u for _, u in gs) and draw(st.booleans()):
        design["weights"] = "metropolis"
    data["design"] = design
    return Drawn(data=data, T=T, edges=edges, owned=owned)


def graph_sequences(k: int, length: int = 10):
    """Random sequences of graph indices ``0..k-1`` (the switching signal of a product test)."""
    return st.lists(st.integers(0, k - 1), min_size=length, max_size=length)
