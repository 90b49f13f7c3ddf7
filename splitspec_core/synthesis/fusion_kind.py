"""The fusion kind in a design (``design.consensus: fusion``): the gains of :mod:`.fusion` on every graph of the
scenario, the budget ``q``, what certifies it, and what each agent process is sent.

Each agent measures, fuses its neighbours' estimates ``q`` times with matrix weights, and predicts
(:mod:`splitspec_core.model.steps`: ``local_update``, ``matrix_fusion``, ``prediction_update``); one estimate of ``n``
numbers per exchange, as the whole state.  The gains are designed per graph held constant (:func:`.fusion.design_fusion`:
the noise's best steady-state gains, shifted by the rate when those are too slow) and certified by the spectral
radius of the full error map of that graph below the rate per event time.

``design.q`` is the budget.  Given, the design is made at that ``q``; when no gains within it certify the rate, the
noise's gains are kept, the design says it is not certified, the fewest exchanges that would certify (looked for up
to the graph's diameter plus :data:`LOOK_FURTHER`) and the fastest rate those gains keep.  ``auto``: the smallest ``q``
whose protocol limit (:mod:`.exchange_limit`) is within :data:`AUTO_GAP` of the centralized Kalman predictor, raised
until the rate is certified.

An agent that is lost, or a message that does not count (a loss, a deadline, a partition), has its weight folded
into the receiving agent's own (:func:`~splitspec_core.model.steps.fold_weights`: the weights still sum to ``I``);
the runtime's verdict on the survivors is the spectral radius of their error map with the weights so folded
(:func:`survivors_radius`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ..errors import DesignError
from ..model.steps import fold_weights
from ..scenarios.specs import Scenario
from .exchange_limit import hop_distances, network_model, scenario_limit
from .fusion import design_fusion, neighbour_positions
from .kalman import per_step_rate, spectral_radius
from .spectral import certifies

__all__ = ["FusionKind", "design_fusion_kind", "fusion_matrix", "fusion_noise", "agent_fusion", "survivors_radius"]

#: ``design.q: auto``: the smallest q whose protocol limit is within this fraction of the Kalman predictor
AUTO_GAP = 0.01
#: a q that does not certify (and ``design.q: auto``): the fewest that would is looked for up to the diameter plus
#: this many
LOOK_FURTHER = 2


@dataclass(frozen=True)
class FusionKind:
    """What the fusion design chose (the report's and ``--json``'s ``fusion``).

    Attributes
    ----------
    q : int
        Exchanges per event time (per ``run.dt`` in continuous time).
    designs : tuple of FusionDesign
        The gains per scenario graph, in the scenario's order.
    lam_step : float
        The rate per event time.
    limit : float
        The protocol's limit at ``q`` on the first graph, over the Kalman predictor's RMS.
    fewest : int or None
        Not certified: the fewest exchanges that certify the rate (None: none up to the search's end, or certified).
    searched : int
        Not certified: the largest q tried for :attr:`fewest`.
    """

    q: int
    designs: tuple = field(repr=False)
    lam_step: float
    limit: float
    fewest: int | None = None
    searched: int = 0

    @property
    def radius(self) -> float:
        """The largest spectral radius of the full error map over the graphs."""
        return max(d.radius for d in self.designs)

    @property
    def certified(self) -> bool:
        """Every graph's error map below the rate (the one rule, :func:`.spectral.certifies`)."""
        return certifies(self.radius, self.lam_step)

    @property
    def kf_rms(self) -> float:
        """The centralized Kalman predictor's RMS of the error vector (``sqrt(trace P)``)."""
        d = self.designs[0]
        return d.kf_rms * math.sqrt(d.n)

    @property
    def alpha(self) -> float:
        """The smallest shift used over the graphs (1: the noise's gains as they are)."""
        return min(d.alpha for d in self.designs)


def _diameter(sc: Scenario) -> int:
    worst = 1
    for g in range(len(sc.graph_names)):
        arcs = network_model(sc, g)[5]
        d = hop_distances(sc.m, arcs)
        worst = max(worst, int(d[np.isfinite(d)].max()))
    return worst


def _designs(sc: Scenario, q: int, lam: float | None) -> tuple | None:
    """The gains on every graph at ``q`` certified at ``lam`` (None: unshifted), or None when a graph refuses."""
    out = []
    for g in range(len(sc.graph_names)):
        F, Q, _, Cs, Rs, arcs = network_model(sc, g)
        try:
            out.append(design_fusion(F, Cs, Q, Rs, neighbour_positions(sc.m, arcs), q, rate=lam))
        except DesignError:
            return None
    return tuple(out)


def design_fusion_kind(sc: Scenario, rate: float, warnings: list) -> FusionKind:
    """The fusion design of ``sc`` at ``rate`` (module docstring).

    Parameters
    ----------
    sc : Scenario
        With measurement noise on every output (``design.consensus: fusion``); ``design.q`` the budget or ``auto``.
    rate : float
        ``lam`` in the scenario's units (the envelope's when directions no agent sees limit it).
    warnings : list
        The design's warnings; a budget that does not certify appends its line.

    Returns
    -------
    FusionKind

    Raises
    ------
    DesignError
        ``design.q: auto`` and no q up to the diameter + :data:`LOOK_FURTHER` (at most ``design.q_max``) certifies
        the rate.

    Examples
    --------
    >>> import splitspec_core as ss
    >>> sc = ss.scenario(A=[[0.9, 0.2], [0, 0.8]], C={1: [[1, 0]], 2: [[0, 1]]}, graphs={"a": [(1, 2), (2, 1)]},
    ...                  rate=0.5, process_noise=0.1, measurement_noise=0.1, consensus="fusion", q=1)
    >>> kind = design_fusion_kind(sc, 0.5, [])
    >>> kind.q, kind.certified, round(kind.radius, 4), round(kind.designs[0].ratio, 4)
    (1, True, 0.3478, 1.0)
    """
    d = sc.design
    lam = per_step_rate(sc, rate)
    if d.q != "auto":
        q = int(d.q)
        got = _designs(sc, q, lam)
        limit = scenario_limit(sc, q).ratio
        if got is not None:
            return FusionKind(q=q, designs=got, lam_step=lam, limit=limit)
        free = _designs(sc, q, None)
        if free is None:  # pragma: no cover - the unshifted design does not refuse
            raise DesignError(f"design.consensus: fusion found no gains at q = {q}")
        end = min(d.q_max, _diameter(sc) + LOOK_FURTHER)
        fewest = next((k for k in range(q + 1, end + 1) if _designs(sc, k, lam) is not None), None)
        kind = FusionKind(q=q, designs=free, lam_step=lam, limit=limit, fewest=fewest, searched=end)
        warnings.append(budget_text(sc, kind))
        return kind
    diameter = _diameter(sc)
    start = next((k for k in range(1, diameter + 1) if scenario_limit(sc, k).ratio <= 1 + AUTO_GAP), diameter)
    # as the budget's fewest: up to the diameter and LOOK_FURTHER more (every sensor is heard within the event time
    # from the diameter on; each q beyond costs a shift search, minutes on a drawn system no q certifies)
    end = min(d.q_max, max(start, diameter + LOOK_FURTHER))
    for q in range(start, end + 1):
        got = _designs(sc, q, lam)
        if got is not None:
            return FusionKind(q=q, designs=got, lam_step=lam, limit=scenario_limit(sc, q).ratio)
    raise DesignError(f"design.consensus: fusion certifies rate {d.rate:g} with no q up to {end} (the network's "
                      f"diameter {diameter} + {LOOK_FURTHER}; the gains cannot outrun the plant's slowest mode the "
                      "sensors cannot speed up): lower design.rate")


def budget_text(sc: Scenario, kind: FusionKind) -> str:
    """One line: the budget does not certify the rate, the fewest exchanges that would, the fastest rate it keeps.

    Parameters
    ----------
    sc : Scenario
    kind : FusionKind
        Not certified.

    Returns
    -------
    str
    """
    r = kind.radius
    fastest = f"{r:.6g} per event time" if sc.time == "discrete" else \
        f"{-math.log(r) / sc.run.dt:.4g} {sc.system.per_time}" if 0 < r < 1 else "none: its error map is unstable"
    fewest = f"q = {kind.fewest}" if kind.fewest is not None else f"none up to q = {kind.searched}"
    return (f"design.q = {kind.q} does NOT certify rate {sc.design.rate:g} with the fusion kind: the fewest exchanges "
            f"that do: {fewest}; the noise's gains at q = {kind.q} keep rate {fastest} (spectral radius {r:.6g})")


def fusion_matrix(des, graph_index: int) -> np.ndarray:
    """The full error map of one event time on the scenario's graph ``graph_index`` held constant.

    Parameters
    ----------
    des : Design
        A fusion design.
    graph_index : int

    Returns
    -------
    (m n, m n) array
    """
    return des.whole.designs[graph_index].M


def fusion_noise(des, graph_index: int) -> np.ndarray:
    """The covariance of the noise entering the error per event time on graph ``graph_index``:
    ``P blkdiag(L_i R_i L_i') P' + 1 1' (x) Q`` (:func:`.fusion.error_map`).

    Parameters
    ----------
    des : Design
    graph_index : int

    Returns
    -------
    (m n, m n) array
    """
    from .fusion import error_map
    from scipy.linalg import block_diag

    sc = des.scenario
    fd = des.whole.designs[graph_index]
    F, Q, _, Cs, Rs, _ = network_model(sc, graph_index)
    _, P = error_map(fd.F, fd.Cs, fd.Ls, fd.weights, fd.neighbours)
    G = P @ block_diag(*fd.Ls)
    one = np.kron(np.ones((sc.m, 1)), np.eye(sc.n))
    N = G @ block_diag(*Rs) @ G.T + one @ Q @ one.T
    return 0.5 * (N + N.T)


def agent_fusion(des, agent_id: int) -> dict:
    """What agent ``agent_id``'s process is sent: per scenario graph its ``L_i`` and its weights per sub-round keyed
    by neighbour (``{graph name: [{j: W_ij(k) nested list}] for k = 1..q}``), the floats the simulator holds.

    Parameters
    ----------
    des : Design
        A fusion design.
    agent_id : int

    Returns
    -------
    dict
        ``{"consensus": "fusion", "F": the per-step model, "L": {graph name: L_i}, "weights": {...}}`` (nested lists).
    """
    sc = des.scenario
    i = sc.agent_ids.index(agent_id)
    graphs = {}
    for name, fd in zip(sc.graph_names, des.whole.designs):
        ids = [sc.agent_ids[j] for j in fd.neighbours[i]]
        graphs[name] = [{str(j): blocks[i][:, a * sc.n:(a + 1) * sc.n].tolist() for a, j in enumerate(ids)}
                        for blocks in fd.weights]
    return {"consensus": "fusion", "F": np.asarray(des.whole.designs[0].F).tolist(),
            "L": {name: np.asarray(fd.Ls[i]).tolist() for name, fd in zip(sc.graph_names, des.whole.designs)},
            "weights": graphs}


def weight_blocks(des, graph_index: int, i: int) -> list:
    """Agent ``i``'s (position) weights on one graph: per sub-round ``{neighbour id: W_ij(k)}``.

    Parameters
    ----------
    des : Design
    graph_index, i : int

    Returns
    -------
    list of dict
    """
    sc = des.scenario
    fd = des.whole.designs[graph_index]
    ids = [sc.agent_ids[j] for j in fd.neighbours[i]]
    n = sc.n
    return [{j: blocks[i][:, a * n:(a + 1) * n] for a, j in enumerate(ids)} for blocks in fd.weights]


def survivors_radius(des, alive: tuple, arcs: dict) -> float:
    """The largest spectral radius over ``arcs``' graphs of the survivors' error map: every survivor keeps its gains,
    the weights of the agents lost and the arcs down folded into its own.

    Parameters
    ----------
    des : Design
        A fusion design.
    alive : tuple of int
        The survivors' ids.
    arcs : dict
        ``{graph name: arcs (j, i) still up}``.

    Returns
    -------
    float
    """
    sc = des.scenario
    n = sc.n
    pos = {a: k for k, a in enumerate(alive)}
    worst = 0.0
    for name, up in arcs.items():
        g = sc.graph_names.index(name)
        fd = des.whole.designs[g]
        M = np.eye(len(alive) * n)
        hears = {i: {j for j, k in up if k == i and j in pos} for i in alive}
        for k in range(fd.q):
            Wk = np.zeros_like(M)
            for i in alive:
                blocks = weight_blocks(des, g, sc.agent_ids.index(i))[k]
                counted = [i] + sorted(hears[i] & set(blocks) - {i})
                folded = fold_weights(blocks, i, counted)
                for a, j in enumerate(counted):
                    Wk[pos[i] * n:(pos[i] + 1) * n, pos[j] * n:(pos[j] + 1) * n] = folded[:, a * n:(a + 1) * n]
            M = Wk @ M
        T = np.zeros_like(M)
        for i in alive:
            a = sc.agent_ids.index(i)
            T[pos[i] * n:(pos[i] + 1) * n, pos[i] * n:(pos[i] + 1) * n] = np.eye(n) - fd.Ls[a] @ fd.Cs[a]
        Fb = np.kron(np.eye(len(alive)), fd.F)
        worst = max(worst, spectral_radius(Fb @ M @ T))
    return worst
