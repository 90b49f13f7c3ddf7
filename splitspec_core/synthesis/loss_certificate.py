"""What the theory says about a lossy network: the design's rate under lost messages, certified or not, and why.

With losses the realized graph changes every sub-round (:mod:`splitspec_core.model.impairment`): one event
time maps the unobservable part of the error by ``Atil B_q ... B_1`` with ``B_k = V' Sbar_k V``, ``S_k``
the row-stochastic matrix of sub-round k's realized graph (eq. split_discrete_ench with a product in
place of ``B^q``).  The paper's discrete results assume the graph constant within an event time; what
still holds is the argument of its two-norm certificate (Appendix B, "Weighted Two-Norm" b): if every
event time's map has ``|Atil B_q ... B_1|_2 <= lam``, the error decays as ``lam^tau`` whatever the
sequence.  Submultiplicativity gives ``|Atil B_q ... B_1|_2 <= |Atil|_2 beta^q`` with
``beta = max |B|_2`` over every graph a sub-round can realize.  So:

* the family: every graph the scenario uses (each held constant) minus at most ``L`` of its *droppable*
  arcs (those with a loss probability above 0; every arc when a deadline can make a message late), ``L``
  the largest number (at most 2) for which every such graph stays strongly connected (the paper's
  standing assumption); ``L = 0`` when one lost message can cut an agent off: then nothing is certified;
* certified under loss when ``beta < 1``, ``|Atil|_2 beta^q <= lam`` and the family is every graph a
  sub-round can realize (at most ``L`` arcs can drop at all, and no deadline: lateness has no bound in
  number); when it covers only the sub-rounds that lose at most ``L`` messages it says so, and gives the
  probability that a sub-round loses more (independent losses, exactly): not certified; with
  ``beta < 1`` but q too small, the q that would certify is reported;
* ``beta >= 1``: no bound of this kind (nor any other the paper gives) covers a graph switching within an
  event time, and the certificate says so;
* continuous time: a lost message switches the graph for one step of ``run.dt``; no certificate of the
  paper covers switching that fast (the dwell-time bound grows without limit as the dwell shrinks);
* a partition cuts the graph into pieces that are not strongly connected: nothing is certified while
  it is in force.

Never more than that: a certificate here is a sufficient condition, often pessimistic; the measured
behaviour under loss is what ``splitspec compare --sweep-loss`` shows.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass

import numpy as np

from .design_data import Design, cached_analysis
from ..model.graphs import build_graph, find_unreachable
from .spectral import certifies

__all__ = ["LossCertificate", "loss_certificate", "MAX_LOST_CHECKED"]

#: the largest number of lost messages per sub-round the certificate enumerates
MAX_LOST_CHECKED = 2
#: enumeration budget: realized graphs, and nbar^3 * graphs of two-norms
_MAX_GRAPHS = 5000
_MAX_WORK = 5e9


@dataclass(frozen=True)
class LossCertificate:
    """The design's rate under the scenario's ``network:`` and partitions (see the module docstring)."""

    certified: bool
    text: str
    max_lost: int | None = None  # L
    beta: float | None = None  # max over the family of |V' Sbar_k V|_2
    bound: float | None = None  # |Atil|_2 beta^q
    q_needed: int | None = None  # the smallest q with |Atil|_2 beta^q <= lam (beta < 1)
    p_more: float | None = None  # probability that a sub-round loses more than L messages
    graphs: int = 0  # realized graphs checked


def _p_more_than(probs, L: int) -> float:
    """P(more than L of independent events with probabilities ``probs``) (Poisson binomial, exactly)."""
    dist = np.zeros(L + 2)
    dist[0] = 1.0
    for p in probs:
        nxt = dist * (1 - p)
        nxt[1:] += dist[:-1] * p
        nxt[-1] += dist[-1] * p  # "more than L" absorbs
        dist = nxt
    return float(max(0.0, 1.0 - dist[:L + 1].sum()))


def _realized_S(base, lost: set, ids, weights: str) -> np.ndarray:
    """``S`` of a sub-round that lost ``lost`` (arcs (j, i)), by impairment.realized_row's rule."""
    pos = {a: k for k, a in enumerate(ids)}
    S = base.copy()
    for j, i in lost:
        r, c = pos[i], pos[j]
        if weights == "metropolis":
            S[r, r] += S[r, c]
            S[r, c] = 0.0
        else:
            S[r, c] = 0.0
    if weights != "metropolis":
        S = (S != 0) / np.maximum((S != 0).sum(axis=1, keepdims=True), 1)
    return S


@cached_analysis  # once per design, on first use (the realized graphs' two-norms)
def loss_certificate(des: Design) -> LossCertificate | None:
    """The certificate under loss of a design whose scenario has ``network:`` impairments or partitions (else None).

    Computed once per design (:func:`~splitspec_core.synthesis.design_data.cached_analysis`).

    Parameters
    ----------
    des : Design
        The design; its scenario's ``network:`` and ``faults:`` (partitions) decide what is checked.

    Returns
    -------
    LossCertificate or None
        ``certified`` and the one-line ``text`` saying why (module docstring), with ``max_lost`` (``L``), ``beta``,
        ``bound``, ``q_needed``, ``p_more``, ``graphs`` where computed; None without impairments or partitions.

    Examples
    --------
    >>> import splitspec_core as ss
    >>> from splitspec_core.synthesis.designer import design
    >>> lc = loss_certificate(design(ss.load_scenario("examples/ring10_lossy.yaml")))
    >>> lc.certified, lc.max_lost, lc.q_needed, lc.graphs
    (False, 1, 6, 25)
    >>> loss_certificate(design(ss.load_scenario("examples/ring10.yaml"))) is None
    True
    """
    sc = des.scenario
    net = sc.network
    partitions = [f for f in sc.faults if f.action == "partition"]
    if not net.impaired and not partitions:
        return None
    cut = ""
    if partitions:
        heals = [f.at for f in sc.faults if f.action == "heal"]
        cut = (f"; nothing is certified while partitioned (from {partitions[0].at:g}"
               + (f" to {heals[0]:g}" if heals else "") + ": the graph is not strongly connected)")
    if not net.impaired:
        return LossCertificate(True, f"under loss: no message is lost outside the partitions{cut}")
    if des.consensus == "fusion":
        return LossCertificate(False, "not certified under loss: the fusion kind's certificate holds the graph "
                                      "constant within an event time; a lost message folds its weight into the "
                                      "receiver's own, another error map (what loss costs is measured by splitspec "
                                      f"compare --sweep-loss){cut}")
    if des.consensus == "relay":
        return LossCertificate(False, "not certified under loss: the relay kind's certificate holds every sample "
                                      "arriving as the graph's hops say; a lost message leaves its samples out of "
                                      "the walk, the base running on fewer rows (what loss costs is measured by "
                                      f"splitspec compare --sweep-loss){cut}")
    if des.consensus == "whole":
        return LossCertificate(False, "not certified under loss: the whole-state design's certificates (the full error "
                                      "matrix, the mixing bound) hold the graph constant within an event time and its "
                                      "weights doubly stochastic; a lost message changes both within a sub-round and "
                                      "moves the consensus average (what loss costs is measured by splitspec compare "
                                      f"--sweep-loss){cut}")
    if sc.time == "continuous":
        return LossCertificate(False, "not certified under loss: in continuous time a lost message switches the graph "
                                      f"for one step of run.dt = {sc.run.dt:g}, and no certificate of the paper covers "
                                      "switching that fast (the dwell-time bound grows without limit as the dwell "
                                      f"shrinks){cut}")
    used = sc.switching.graph_names(sc.graph_names)
    ids = sc.agent_ids
    ad = {a.id: a for a in des.agents}
    Vs = [ad[i].V for i in ids]
    sizes = [V.shape[1] for V in Vs]
    nbar = sum(sizes)
    if nbar == 0:
        return LossCertificate(True, f"rate certified under loss: every agent sees the whole state, consensus plays no "
                                     f"part and losses change nothing{cut}")
    Vcat = np.hstack(Vs)
    G = Vcat.T @ Vcat
    edges = np.concatenate([[0], np.cumsum(sizes)])

    def B_of(S):
        return np.repeat(np.repeat(S, sizes, axis=0), sizes, axis=1) * G  # V' (S (x) I) V

    Atil = np.zeros((nbar, nbar))
    for k, i in enumerate(ids):
        Atil[edges[k]:edges[k + 1], edges[k]:edges[k + 1]] = ad[i].dec.A_un
    norm_a = float(np.linalg.norm(Atil, 2))
    pos = {a: k for k, a in enumerate(ids)}
    family, L, probs = [], MAX_LOST_CHECKED, []
    for name in used:
        g = build_graph(name, ids, sc.graph(name).arcs, weights=sc.design.weights)
        arcs = [a for a in g.arcs if a[0] != a[1]]
        droppable = arcs if net.deadline is not None else [a for a in arcs if net.loss_of(a) > 0]
        probs.append([net.loss_of(a) for a in droppable])
        for size in range(1, MAX_LOST_CHECKED + 1):
            if math.comb(len(droppable), size) > _MAX_GRAPHS:
                L = min(L, size - 1)
                break
            for gone in itertools.combinations(droppable, size):
                keep = [(pos[j], pos[i]) for j, i in arcs if (j, i) not in gone]
                bad = find_unreachable(len(ids), keep)
                if bad is not None:
                    if size == 1:
                        j, i = gone[0]
                        return LossCertificate(False, f"not certified under loss: losing the message {j} -> {i} "
                                                      f"leaves graph {name} not strongly connected (agent "
                                                      f"{ids[bad[0]]} cannot reach agent {ids[bad[1]]}), which the "
                                                      f"paper's results exclude{cut}", max_lost=0)
                    L = min(L, size - 1)
                    break
            if L < size:
                break
        family.append((g, droppable))
    L = min(L, max(len(d) for _, d in family))
    graphs = []
    for g, droppable in family:
        for size in range(0, L + 1):
            graphs += [(g, set(gone)) for gone in itertools.combinations(droppable, size)]
    if len(graphs) * nbar ** 3 > _MAX_WORK:
        return LossCertificate(False, f"not certified under loss: checking the {len(graphs)} graphs a sub-round can "
                                      f"realize (nbar = {nbar}) is beyond this tool's budget{cut}", max_lost=L,
                               graphs=len(graphs))
    beta = max(float(np.linalg.norm(B_of(_realized_S(g.S, gone, ids, sc.design.weights)), 2)) for g, gone in graphs)
    p_more = max(_p_more_than(p, L) for p in probs) if net.lossy else None
    # every realization covered: at most L arcs can drop at all (no deadline: lateness has no bound in number)
    covers = net.deadline is None and all(len(d) <= L for _, d in family)
    if net.deadline is not None:
        beyond = "; with a deadline any number of messages can be late"
    else:
        beyond = "" if covers else f"; a sub-round loses more with probability {p_more:.3g}"
    late = " (lost or late)" if net.deadline is not None else ""
    scope = f"sub-rounds that lose at most {L} message{'s' if L != 1 else ''}{late}"
    q, rate = des.q, sc.design.rate
    if beta >= 1.0:
        return LossCertificate(False, f"not certified under loss: a graph a sub-round can realize has |V' S_k V|_2 = "
                                      f"{beta:.4g} >= 1, so no two-norm bound covers a graph that changes within an "
                                      f"event time (the paper's certificates assume it does not){cut}",
                               max_lost=L, beta=beta, p_more=p_more, graphs=len(graphs))
    bound = norm_a * beta ** q
    q_needed = max(1, math.ceil(math.log(rate / norm_a) / math.log(beta))) if norm_a > rate else 1
    fields = dict(max_lost=L, beta=beta, bound=bound, q_needed=q_needed, p_more=p_more, graphs=len(graphs))
    what = f"|Atil|_2 max_k |V' S_k V|_2^q = {norm_a:.4g} x {beta:.4g}^{q} = {bound:.4g}"
    if certifies(bound, rate) and covers:
        return LossCertificate(True, f"rate certified under loss: {what} < rate {rate:g} over every graph a "
                                     f"sub-round can realize ({len(graphs)}){cut}", **fields)
    if certifies(bound, rate):
        return LossCertificate(False, f"not certified under loss: certified only for {scope} ({what} < rate "
                                      f"{rate:g} over the {len(graphs)} graphs they realize){beyond}{cut}", **fields)
    return LossCertificate(False, f"not certified under loss: q = {q} gives {what} >= rate {rate:g}; q >= {q_needed} "
                                  f"would certify {scope} (two-norm over the {len(graphs)} graphs they realize)"
                                  f"{beyond}{cut}", **fields)
