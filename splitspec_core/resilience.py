"""Resilience analysis (paper, Section resilience; Automatica22, Section 5).

A network is *redundantly strongly connected* when every graph stays
strongly connected after any one agent is lost, and *redundantly jointly
observable* when the survivors of any single loss still jointly observe
``(C, A)``.  The split-spectrum estimators keep working after such a loss
provided g or q also covers the survivors' graphs (``design.resilience: 1``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .graphs import find_unreachable
from .observability import _direction_text, unobservable_directions

__all__ = ["LossReport", "network_verdict", "analyse_agent_losses", "analyse_arc_losses"]


@dataclass(frozen=True)
class LossReport:
    """What is left after a loss.

    Attributes
    ----------
    strongly_connected : dict
        ``{graph name: bool}`` for the graphs restricted to the survivors.
    unreachable : dict
        ``{graph name: (j, i)}``: a survivor j that cannot reach survivor i.
    jointly_observable : bool
    unobservable_direction : str or None
        A direction no survivor observes, when not jointly observable.
    """

    strongly_connected: dict
    unreachable: dict
    jointly_observable: bool
    unobservable_direction: str | None

    @property
    def ok(self) -> bool:
        return self.jointly_observable and all(self.strongly_connected.values())


def network_verdict(A: np.ndarray, Cs_by_id: dict, alive, graphs: dict, *,
                    rank_tol: float | None = None) -> LossReport:
    """Strong connectivity of each graph restricted to ``alive`` and joint observability of ``alive``.

    ``graphs`` maps a name to its arcs ``(j, i)`` between agent ids.
    """
    alive = tuple(sorted(alive))
    pos = {a: k for k, a in enumerate(alive)}
    sc, unreach = {}, {}
    for name, arcs in graphs.items():
        idx = [(pos[j], pos[i]) for j, i in arcs if j in pos and i in pos]
        bad = find_unreachable(len(alive), idx) if alive else None
        sc[name] = bad is None and bool(alive)
        if bad is not None:
            unreach[name] = (alive[bad[0]], alive[bad[1]])
    if alive:
        D = unobservable_directions(A, [Cs_by_id[a] for a in alive], rank_tol=rank_tol)
    else:
        D = np.eye(A.shape[0])
    jo = D.shape[1] == 0
    return LossReport(strongly_connected=sc, unreachable=unreach, jointly_observable=jo,
                      unobservable_direction=None if jo else _direction_text(D[:, 0]))


def analyse_agent_losses(A, Cs_by_id: dict, graphs: dict, *, rank_tol: float | None = None) -> dict:
    """``{lost agent id: LossReport}`` for every single agent loss."""
    ids = tuple(sorted(Cs_by_id))
    return {a: network_verdict(A, Cs_by_id, [b for b in ids if b != a], graphs, rank_tol=rank_tol) for a in ids}


def analyse_arc_losses(ids, graphs: dict) -> dict:
    """``{graph name: {(j, i): still strongly connected}}`` for every single arc loss."""
    pos = {a: k for k, a in enumerate(ids)}
    out = {}
    for name, arcs in graphs.items():
        res = {}
        for drop in arcs:
            idx = [(pos[j], pos[i]) for j, i in arcs if (j, i) != drop]
            res[drop] = find_unreachable(len(ids), idx) is None
        out[name] = res
    return out
