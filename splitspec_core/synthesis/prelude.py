"""What both consensus structures of a design share (:mod:`.designer`): the decompositions, what no agent sees, the
graphs, the cases the certificates cover and the losses analysed (steps 1, 2, 4 and 5 of the designer's docstring).

Computed once per design, whether it ends as the paper's split, the whole state (:mod:`.whole_state`) or
``design.consensus: auto``'s choice between them.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from . import bounds
from ..errors import AssumptionError
from ..model.detectability import not_detectable_text, quotient_basis, still_text, unobserved_of
from ..model.gain_target import beyond_target
from ..model.graphs import build_graph, enumerate_strongly_connected
from ..model.local_design import scenario_spectrum, working_scale
from ..model.observability import decompose
from .resilience import analyse_agent_losses, analyse_arc_losses
from ..scenarios.specs import Scenario

__all__ = ["Prelude"]


@dataclasses.dataclass
class Prelude:
    """What both consensus structures share: the decompositions, what no agent sees, the graphs, the cases and the
    losses analysed (steps 1, 2, 4, 5 of the module docstring)."""

    sc: Scenario
    sp: object
    scale: object
    A_w: np.ndarray
    decs: list  # every agent's decomposition (before W is taken out)
    un: object
    warnings: list
    graphs: tuple
    cases: tuple
    agent_losses: dict
    arc_losses: dict
    switching: bool

    @classmethod
    def of(cls, sc: Scenario) -> "Prelude":
        """Compute the shared part of ``sc``'s design.

        Parameters
        ----------
        sc : Scenario
            The scenario to design.

        Returns
        -------
        Prelude
            Every agent's decomposition, what no agent sees (``un``), the graphs, the cases (each graph used; with
            ``design.graph_set: all`` every strongly connected graph; with ``design.resilience: 1`` each graph
            without each agent) and the agent and arc losses analysed.

        Raises
        ------
        AssumptionError
            What no agent sees does not decay (unless ``design.undetectable: exclude``); with
            ``design.resilience: 1``, a single agent loss leaves the network undetectable or a graph not strongly
            connected.

        Examples
        --------
        >>> import splitspec_core as ss
        >>> sc = ss.scenario(A=[[0.9, 0.2], [0, 0.8]], C={1: [[1, 0]], 2: [[0, 1]]}, graphs={"a": [(1, 2), (2, 1)]},
        ...                  rate=0.5, resilience=1)
        >>> p = Prelude.of(sc)  # agent 2 misses x1; without agent 1 nobody sees x1 (W_S), which decays
        >>> [(c.label, c.sizes) for c in p.cases], p.un.dim
        ([('a', (0, 1)), ('a without agent 1', (0,)), ('a without agent 2', (0,))], 0)
        """
        d = sc.design
        A = sc.system.A
        sp = scenario_spectrum(sc)
        free = beyond_target(sc.time, d.rate, d.margin)  # modes the local gains leave alone (gain_target.py)
        scale = working_scale(sc, sp)  # design.coordinates: the user's (None) or balanced
        A_w = A if scale is None else np.asarray(A) * scale[None, :] / scale[:, None]
        decs = [decompose(A, C, rank_tol=d.rank_tol, spectrum=sp, free=free, scale=scale) for C in sc.system.Cs]
        # the standing assumption first ((C, A) of eqs. pre_sys1-pre_sys2 jointly observable, or here detectable):
        # without it no K_i helps, so an explicit K_i that misses the rate on a direction nobody sees is not the error
        of = unobserved_of(sc, sp, {aid: dec.V for aid, dec in zip(sc.agent_ids, decs)}, scale)
        un = of(sc.agent_ids)
        warnings: list = []
        if not un.decays:
            if d.undetectable != "exclude":
                raise AssumptionError(not_detectable_text(un, decs, d.rank_tol))
            warnings.append(f"design.undetectable: exclude: no agent sees {still_text(un)}, which does not decay; "
                            "the certificate covers the error modulo the unobserved directions only")
        # each agent's V_i minus W (what design_agent and whole_placeholder hold): the certificates' cases
        seen = [dec.without(un.W_working, A_w) if un.W_working.shape[1] else dec for dec in decs]
        ad = dict(zip(sc.agent_ids, seen))
        graphs = tuple(build_graph(g.name, sc.agent_ids, g.arcs, weights=d.weights) for g in sc.graphs)
        used = sc.switching.graph_names(sc.graph_names)
        by_name = {g.name: g for g in graphs}
        full_V = {aid: dec.V for aid, dec in zip(sc.agent_ids, decs)}

        def case_for(label, graph, W=None):
            """The case of ``graph``; ``W``: what its agents leave unobserved when it is not the design's (after a
            loss): then ``V_i ⊖ W`` (detectability.py)."""
            if W is None:
                return bounds.make_case(label, graph, [ad[i].V for i in graph.ids], [ad[i].A_un for i in graph.ids])
            Vs = [quotient_basis(full_V[i], W) for i in graph.ids]
            return bounds.make_case(label, graph, Vs, [V.T @ A_w @ V for V in Vs])

        cases = [case_for(name, by_name[name]) for name in used]
        if d.graph_set == "all":
            for k, arcs in enumerate(enumerate_strongly_connected(sc.m)):
                arcs_ids = tuple((sc.agent_ids[j], sc.agent_ids[i]) for j, i in arcs)
                g = build_graph(f"all#{k + 1}", sc.agent_ids, arcs_ids, weights=d.weights)
                cases.append(case_for(g.name, g))
        graph_arcs = {g.name: g.arcs for g in sc.graphs}
        agent_losses = analyse_agent_losses(of, sc.agent_ids, graph_arcs) if sc.m > 1 else {}
        arc_losses = analyse_arc_losses(sc.agent_ids, graph_arcs)
        if d.resilience:
            for lost, rep in agent_losses.items():
                if not rep.detectable:
                    raise AssumptionError(
                        f"design.resilience: 1 needs a redundantly jointly detectable network: without agent {lost}, "
                        f"no agent sees {rep.unobservable_direction}, which does not decay")
                for name in used:
                    if not rep.strongly_connected[name]:
                        j, i = rep.unreachable[name]
                        raise AssumptionError(
                            f"design.resilience: 1 needs a redundantly strongly connected network: without agent "
                            f"{lost}, graph {name} is not strongly connected (agent {j} cannot reach agent {i})")
                survivors = tuple(i for i in sc.agent_ids if i != lost)
                for name in used:  # strongly connected: checked just above (rep.strongly_connected)
                    g = build_graph(f"{name} without agent {lost}", survivors, graph_arcs[name], weights=d.weights,
                                    check=False)
                    W_S = rep.unobserved.W_working
                    cases.append(case_for(g.name, g, None if W_S.shape[1] == un.dim else W_S))
        return cls(sc=sc, sp=sp, scale=scale, A_w=A_w, decs=decs, un=un, warnings=warnings, graphs=graphs,
                   cases=tuple(cases), agent_losses=agent_losses, arc_losses=arc_losses,
                   switching=len(used) > 1 or d.graph_set == "all")
