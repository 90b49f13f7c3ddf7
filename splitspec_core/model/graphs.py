"""Neighbour graphs, their stochastic matrices, and switching signals.

Conventions (paper, Section 2):

* an arc ``(j, i)`` means agent j is a neighbour of agent i (i hears j);
  every agent is its own neighbour (self-arcs are implicit);
* ``Adj[j, i] = 1`` for every arc ``j -> i`` (self-arcs included);
* ``S = D^-1 Adj'`` with ``D`` the in-degrees, so row i of ``S`` averages
  over i's in-neighbours and itself: ``(S z)_i = (1/m_i) sum_{j in N_i} z_j``;
* Metropolis weights (undirected graphs only) give a symmetric, doubly
  stochastic ``S`` as Theorem ``thm:arb`` needs:
  ``S_ij = 1 / (1 + max(d_i, d_j))`` for neighbours, ``S_ii = 1 - sum``.

Indices here are 0-based positions in the scenario's ``agent_ids``.
"""

from __future__ import annotations

import itertools
from collections import deque
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from ..errors import AssumptionError, ScenarioError

__all__ = [
    "Graph",
    "adjacency",
    "stochastic_matrix",
    "metropolis_matrix",
    "find_unreachable",
    "is_strongly_connected",
    "perron_vector",
    "is_doubly_stochastic",
    "build_graph",
    "graph_sequence",
    "SwitchingSignal",
    "switch_times",
    "enumerate_strongly_connected",
    "neighbour_lists",
    "arc_positions",
    "positions_in",
]


@dataclass(frozen=True)
class Graph:
    """A neighbour graph over a set of agents with its stochastic matrix.

    Attributes
    ----------
    name : str
        Graph name (scenario key, or a derived label such as ``a-minus-3``).
    ids : tuple of int
        Agent ids of the vertices, in order.
    arcs : tuple of (int, int)
        Arcs ``(j, i)`` between agent ids, without self-arcs.
    S : (k, k) array
        Row-stochastic matrix ``S = D^-1 Adj'`` (or Metropolis weights); formed on first use (the m + 1 cases
        of a resilient design of 1000 agents would hold 8 GB of them; their spectral radii need only
        ``entries``).
    entries : (rows, cols, values)
        The nonzero entries of ``S`` (0-based positions), the same values, without forming ``S``.
    """

    name: str
    ids: tuple
    arcs: tuple
    weights: str = "uniform"

    @property
    def m(self) -> int:
        """int: the number of agents (vertices), ``len(ids)``."""
        return len(self.ids)

    @property
    def strongly_connected(self) -> bool:
        """Every agent reaches every other along the arcs (computed from them, each time: a breadth-first search)."""
        return is_strongly_connected(self.m, zip(*(a.tolist() for a in arc_positions(self.ids, self.arcs))))

    @property
    def _idx(self) -> tuple:
        # computed on each use (vectorised, well under a millisecond for thousands of arcs): the m + 1 graphs of a
        # resilient design of 1000 agents would otherwise keep 180 MB of these arrays and of ``entries``
        return arc_positions(self.ids, self.arcs)  # senders j, receivers i

    @cached_property
    def S(self) -> np.ndarray:
        """Read-only ``(m, m)`` row-stochastic ``S = D^-1 Adj'`` (or Metropolis weights), formed on first use."""
        adj = adjacency(self.m, zip(*self._idx))
        S = metropolis_matrix(adj) if self.weights == "metropolis" else stochastic_matrix(adj)
        S.setflags(write=False)
        return S

    @property
    def entries(self) -> tuple:
        """``(rows, cols, values)``: the nonzero entries of ``S`` (three arrays, 0-based), without forming ``S``."""
        if self.weights == "metropolis" or "S" in self.__dict__:
            rows, cols = np.nonzero(self.S)
            return rows, cols, self.S[rows, cols]
        j, i = self._idx
        diag = np.arange(self.m)
        rows, cols = np.concatenate([i, diag]), np.concatenate([j, diag])
        count = np.bincount(rows, minlength=self.m).astype(float)  # in-neighbours and itself
        return rows, cols, 1.0 / count[rows]  # S = D^-1 Adj': each row averages its in-neighbours and itself


def positions_in(ids, values) -> tuple:
    """Find agent ids in ``ids``; vectorised, a sorted lookup (no Python loop over a thousand-agent network).

    Parameters
    ----------
    ids, values : sequence of int
        The agent ids to look in, and the ids to look up.

    Returns
    -------
    pos : (len(values),) int array
        Position of each of ``values`` in ``ids`` (0 where it is not there).
    found : (len(values),) bool array
        Whether it is there.
    """
    ids = np.asarray(ids, dtype=np.int64)
    values = np.asarray(values, dtype=np.int64)
    if not len(ids):
        return np.zeros(len(values), dtype=np.int64), np.zeros(len(values), dtype=bool)
    order = np.argsort(ids, kind="stable")
    k = np.minimum(np.searchsorted(ids[order], values), len(ids) - 1)
    return order[k], ids[order][k] == values


def _positions(ids, arcs) -> tuple:
    """``(senders, receivers, kept)``: the positions in ``ids`` of each arc's ends and whether both are in ``ids``."""
    arcs = np.asarray(arcs, dtype=np.int64).reshape(-1, 2)
    (j, found_j), (i, found_i) = positions_in(ids, arcs[:, 0]), positions_in(ids, arcs[:, 1])
    return j, i, found_j & found_i


def arc_positions(ids, arcs) -> tuple:
    """The positions in ``ids`` of the arcs ``(j, i)`` between agents of ``ids`` (arcs touching another agent dropped).

    Parameters
    ----------
    ids : sequence of int
        Agent ids of the vertices, in order.
    arcs : sequence of (int, int)
        Arcs ``(j, i)`` between agent ids.

    Returns
    -------
    senders, receivers : int array
        Positions of each kept arc's ``j`` and ``i``.
    """
    j, i, kept = _positions(ids, arcs)
    return j[kept], i[kept]


def adjacency(m: int, arcs) -> np.ndarray:
    """Adjacency matrix with self-arcs: ``Adj[j, i] = 1`` for each arc ``(j, i)`` (0-based).

    Parameters
    ----------
    m : int
        Number of agents.
    arcs : iterable of (int, int)
        Arcs ``(j, i)`` between 0-based positions.

    Returns
    -------
    (m, m) float array
        ``Adj``, ones on the diagonal.
    """
    adj = np.eye(m)
    for j, i in arcs:
        adj[j, i] = 1.0
    return adj


def stochastic_matrix(adj: np.ndarray) -> np.ndarray:
    """``S = D^-1 Adj'`` (paper, after eq. split_continuous_em): rows average in-neighbours.

    Parameters
    ----------
    adj : (m, m) array
        Adjacency matrix with self-arcs, as :func:`adjacency` builds it.

    Returns
    -------
    (m, m) float array
        Row-stochastic ``S``.
    """
    at = adj.T
    return at / at.sum(axis=1, keepdims=True)


def metropolis_matrix(adj: np.ndarray) -> np.ndarray:
    """Metropolis weights for an undirected graph: symmetric and doubly stochastic.

    Parameters
    ----------
    adj : (m, m) array
        Symmetric adjacency matrix with self-arcs.

    Returns
    -------
    (m, m) float array
        ``S_ij = 1 / (1 + max(d_i, d_j))`` for neighbours, ``S_ii = 1 - sum_j S_ij``.

    Raises
    ------
    AssumptionError
        If the graph is not undirected (``adj`` not symmetric).
    """
    if not np.array_equal(adj, adj.T):
        raise AssumptionError("Metropolis weights need an undirected graph (every arc in both directions)")
    m = adj.shape[0]
    deg = adj.sum(axis=0) - 1.0  # neighbours other than self
    S = np.zeros((m, m))
    for i in range(m):
        for j in range(m):
            if i != j and adj[j, i]:
                S[i, j] = 1.0 / (1.0 + max(deg[i], deg[j]))
        S[i, i] = 1.0 - S[i].sum()
    return S


def find_unreachable(m: int, arcs) -> tuple | None:
    """Return ``(j, i)`` (0-based) such that j cannot reach i, or ``None`` if strongly connected.

    Reaching follows arcs ``j -> i`` (the direction information flows).

    Parameters
    ----------
    m : int
        Number of agents.
    arcs : iterable of (int, int)
        Arcs ``(j, i)`` between 0-based positions.

    Returns
    -------
    (int, int) or None
        A pair through agent 0 that is not connected, or ``None``.
    """
    if m <= 1:
        return None
    out_nb = [[] for _ in range(m)]
    in_nb = [[] for _ in range(m)]
    for j, i in arcs:
        out_nb[j].append(i)
        in_nb[i].append(j)

    def reach(start: int, nbrs) -> list:
        seen = [False] * m
        seen[start] = True
        todo = deque([start])
        while todo:
            v = todo.popleft()
            for w in nbrs[v]:
                if not seen[w]:
                    seen[w] = True
                    todo.append(w)
        return seen

    fwd = reach(0, out_nb)
    for v in range(m):
        if not fwd[v]:
            return (0, v)
    bwd = reach(0, in_nb)
    for v in range(m):
        if not bwd[v]:
            return (v, 0)
    return None


def is_strongly_connected(m: int, arcs) -> bool:
    """Whether every agent reaches every other along the arcs ``j -> i``.

    Parameters
    ----------
    m : int
        Number of agents.
    arcs : iterable of (int, int)
        Arcs ``(j, i)`` between 0-based positions.

    Returns
    -------
    bool
        ``find_unreachable(m, arcs) is None``.

    Examples
    --------
    >>> is_strongly_connected(3, [(0, 1), (1, 2), (2, 0)]), is_strongly_connected(3, [(0, 1), (1, 2)])
    (True, False)
    """
    return find_unreachable(m, arcs) is None


def perron_vector(S: np.ndarray) -> np.ndarray:
    """Perron vector ``pi > 0``, ``S' pi = pi``, ``sum(pi) = 1`` (proof of prop. split_continuous_stable).

    Unique when the graph of ``S'`` is strongly connected.

    Parameters
    ----------
    S : (m, m) array
        Row-stochastic matrix.

    Returns
    -------
    (m,) float array
        ``pi``, the least-squares solution of ``S' pi = pi``, ``sum(pi) = 1``.
    """
    m = S.shape[0]
    M = np.vstack([S.T - np.eye(m), np.ones((1, m))])
    rhs = np.zeros(m + 1)
    rhs[-1] = 1.0
    pi, *_ = np.linalg.lstsq(M, rhs, rcond=None)
    return pi


def is_doubly_stochastic(S: np.ndarray, *, tol: float = 1e-12) -> bool:
    """True when the column sums of the (row-)stochastic ``S`` are all one.

    Parameters
    ----------
    S : (m, m) array
        Row-stochastic matrix.
    tol : float, default 1e-12
        Tolerance per agent: column sums within ``tol * m`` of one count.

    Returns
    -------
    bool
    """
    return bool(np.all(np.abs(S.sum(axis=0) - 1.0) <= tol * S.shape[0]))


def build_graph(name: str, ids: tuple, arcs, *, weights: str = "uniform", check: bool = True) -> Graph:
    """Build a :class:`Graph` over agents ``ids`` from arcs between agent ids.

    Arcs touching agents outside ``ids`` are dropped (the graph restricted to
    ``ids``, e.g. the survivors of a fault), and so are self-arcs.

    Parameters
    ----------
    name : str
        The graph's name.
    ids : tuple of int
        Agent ids of the vertices, in order.
    arcs : iterable of (int, int)
        Arcs ``(j, i)`` between agent ids (j is heard by i).
    weights : {"uniform", "metropolis"}, default "uniform"
        ``S = D^-1 Adj'``, or Metropolis weights (formed at once: a directed graph is refused).
    check : bool, default True
        Refuse a graph that is not strongly connected.

    Returns
    -------
    Graph

    Raises
    ------
    AssumptionError
        If ``check`` and the graph is not strongly connected (the message
        names an agent that cannot reach another), or Metropolis weights on a directed graph.

    Examples
    --------
    >>> g = build_graph("ring", (1, 2, 3), [(1, 2), (2, 3), (3, 1), (3, 9)])
    >>> g.arcs, g.m
    (((1, 2), (2, 3), (3, 1)), 3)
    >>> g.S
    array([[0.5, 0. , 0.5],
           [0.5, 0.5, 0. ],
           [0. , 0.5, 0.5]])
    """
    arcs = arcs if isinstance(arcs, (tuple, list)) else list(arcs)
    flat = np.fromiter(itertools.chain.from_iterable(arcs), dtype=np.int64, count=2 * len(arcs))
    j, i, keep = _positions(ids, flat.reshape(-1, 2))
    keep &= j != i
    # the given pairs themselves where they are tuples (tuple(t) is t): the m + 1 graphs of a resilient design
    # of 1000 agents share the network's arc tuples instead of holding 450 MB of copies
    kept = tuple(tuple(a) for a in itertools.compress(arcs, keep.tolist()))
    m = len(ids)
    if check:
        bad = find_unreachable(m, zip(j[keep].tolist(), i[keep].tolist()))
        if bad is not None:
            raise AssumptionError(
                f"graph {name} is not strongly connected: agent {ids[bad[0]]} cannot reach agent {ids[bad[1]]}")
    g = Graph(name=name, ids=tuple(ids), arcs=kept, weights=weights)
    if weights == "metropolis":
        g.S  # noqa: B018 - formed now: metropolis_matrix refuses a directed graph, at build time
    return g


def neighbour_lists(graph: Graph) -> dict:
    """``{i: (j, ...)}``: agent ids each agent hears, itself first, then ascending.

    Parameters
    ----------
    graph : Graph

    Returns
    -------
    dict of int to tuple of int
    """
    nb = {i: [i] for i in graph.ids}
    for j, i in graph.arcs:
        nb[i].append(j)
    return {i: (i,) + tuple(sorted(v[1:])) for i, v in nb.items()}


# --------------------------------------------------------------------------
# switching signals
# --------------------------------------------------------------------------


def switch_times(switching, names: tuple, horizon: float, rng: np.random.Generator | None = None) -> list:
    """Pieces ``[(start, graph_index), ...]`` of the switching signal on ``[0, horizon)``.

    ``graph_index`` indexes ``names`` (the scenario's graph order).  Random
    switching draws exponential dwell times with mean ``switching.dwell`` and
    jumps to a different graph of ``switching.graphs`` chosen uniformly, so
    the average dwell time is ``dwell`` (the paper's tau_D, chatter bound in
    probability).

    Parameters
    ----------
    switching : SwitchingSpec
        The scenario's switching (``kind`` constant, schedule or random).
    names : tuple of str
        The scenario's graph names.
    horizon : float
        End of the signal (time units); a periodic schedule is repeated up to it.
    rng : numpy.random.Generator, optional
        Needed for random switching.

    Returns
    -------
    list of (float, int)
        Switch times, ascending, with the graph index in force from then on.

    Raises
    ------
    ScenarioError
        Random switching without ``rng``.
    """
    kind = switching.kind
    if kind == "constant":
        return [(0.0, 0)]
    if kind == "schedule":
        base = [(t, names.index(g)) for t, g in switching.schedule]
        if switching.period is None:
            return base
        pieces = []
        for k in itertools.count():
            offset = k * switching.period
            if offset >= horizon:
                break
            pieces.extend((offset + t, g) for t, g in base if offset + t < horizon)
        return pieces
    if rng is None:
        raise ScenarioError("random switching needs a random generator (seed)")
    choices = [names.index(g) for g in switching.graphs]
    current = choices[int(rng.integers(len(choices)))]
    pieces = [(0.0, current)]
    t = 0.0
    while True:
        t += float(rng.exponential(switching.dwell))
        if t >= horizon:
            break
        others = [c for c in choices if c != current]
        current = others[int(rng.integers(len(others)))]
        pieces.append((t, current))
    return pieces


class SwitchingSignal:
    """The switching signal sampled step by step in O(1) memory: what a run of any length needs.

    Draws exactly what :func:`switch_times` draws, in the same order, so
    ``[signal.at(k) for k in range(steps)]`` equals
    ``graph_sequence(switch_times(...), steps, dt=dt)`` (tested); steps must be
    asked for in non-decreasing order.
    """

    def __init__(self, switching, names: tuple, *, dt: float = 1.0, rng: np.random.Generator | None = None):
        if switching.kind == "random" and rng is None:
            raise ScenarioError("random switching needs a random generator (seed)")
        self.tol = 1e-9 * max(dt, 1.0)
        self.dt = dt
        self._it = self._pieces(switching, names, rng)
        self._cur = next(self._it)
        self._next = next(self._it, None)
        self._k = 0

    @staticmethod
    def _pieces(switching, names, rng):
        kind = switching.kind
        if kind == "constant":
            yield (0.0, 0)
            return
        if kind == "schedule":
            base = [(t, names.index(g)) for t, g in switching.schedule]
            if switching.period is None:
                yield from base
                return
            for k in itertools.count():
                offset = k * switching.period
                for t, g in base:
                    yield (offset + t, g)
        choices = [names.index(g) for g in switching.graphs]
        current = choices[int(rng.integers(len(choices)))]
        yield (0.0, current)
        t = 0.0
        while True:
            t += float(rng.exponential(switching.dwell))
            others = [c for c in choices if c != current]
            current = others[int(rng.integers(len(others)))]
            yield (t, current)

    def at(self, k: int) -> int:
        """Graph index in force during step ``k`` (time ``k * dt``).

        Parameters
        ----------
        k : int
            Step, not less than the previous one asked.

        Returns
        -------
        int
            Index into the scenario's graph names.
        """
        if k < self._k:
            raise ValueError(f"the switching signal moves forward only (asked step {k} after {self._k})")
        self._k = k
        t = k * self.dt + self.tol
        while self._next is not None and self._next[0] <= t:
            self._cur, self._next = self._next, next(self._it, None)
        return int(self._cur[1])


def graph_sequence(pieces: list, steps: int, *, dt: float = 1.0) -> np.ndarray:
    """Active graph index at each step ``k = 0..steps-1`` (time ``k * dt``).

    A graph is held constant over a step (the discrete protocol fixes
    neighbours between event times; continuous time is sampled with ``dt``);
    the graph in force at the start of a step is used for the whole step.

    Parameters
    ----------
    pieces : list of (float, int)
        What :func:`switch_times` returns.
    steps : int
        Number of steps.
    dt : float, default 1.0
        Step length (time units).

    Returns
    -------
    (steps,) int array
    """
    starts = np.array([p[0] for p in pieces])
    idx = np.array([p[1] for p in pieces])
    times = np.arange(steps) * dt
    # tolerance so that a switch at t = k*dt is not missed by round-off
    pos = np.searchsorted(starts, times + 1e-9 * max(dt, 1.0), side="right") - 1
    return idx[np.clip(pos, 0, None)]


def enumerate_strongly_connected(m: int) -> list:
    """Every strongly connected directed graph on ``m`` vertices (0-based arcs).

    The paper's switching theorems quantify over this set; it has
    ``2^(m(m-1))`` candidates, so only ``m <= 4`` is allowed.

    Parameters
    ----------
    m : int
        Number of vertices, at most 4.

    Returns
    -------
    list of tuple of (int, int)
        The arc sets, without self-arcs.

    Raises
    ------
    ScenarioError
        If ``m > 4``.
    """
    if m > 4:
        raise ScenarioError(f"design.graph_set: all enumerates 2^(m(m-1)) graphs; m = {m} is too many (at most 4)")
    pairs = [(j, i) for j in range(m) for i in range(m) if i != j]
    out = []
    for mask in range(1 << len(pairs)):
        arcs = [p for b, p in enumerate(pairs) if mask >> b & 1]
        if is_strongly_connected(m, arcs):
            out.append(tuple(arcs))
    return out
