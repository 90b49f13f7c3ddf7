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

from .graphs import arc_positions, find_unreachable
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
                    rank_tol: float | None = None, connected: dict | None = None) -> LossReport:
    """Strong connectivity of each graph restricted to ``alive`` and joint observability of ``alive``.

    ``graphs`` maps a name to its arcs ``(j, i)`` between agent ids.  ``connected``: ``{name: bool}`` already
    known (:func:`analyse_agent_losses` decides it for every loss at once); a pair that cannot reach is then
    searched only for a graph that splits.
    """
    alive = tuple(sorted(alive))
    sc, unreach = {}, {}
    for name, arcs in graphs.items():
        bad = None
        if alive and (connected is None or not connected[name]):
            bad = find_unreachable(len(alive), list(zip(*arc_positions(alive, arcs))))
        sc[name] = bad is None and bool(alive) and (connected is None or connected[name])
        if bad is not None:
            unreach[name] = (alive[bad[0]], alive[bad[1]])
    if alive:
        D = unobservable_directions(A, [Cs_by_id[a] for a in alive], rank_tol=rank_tol)
    else:
        D = np.eye(A.shape[0])
    jo = D.shape[1] == 0
    return LossReport(strongly_connected=sc, unreachable=unreach, jointly_observable=jo,
                      unobservable_direction=None if jo else _direction_text(D[:, 0]))


def _components(m: int, rows: np.ndarray, cols: np.ndarray, keep: np.ndarray | None = None) -> int:
    """Strongly connected components of the digraph on m vertices with the arcs ``rows[k] -> cols[k]`` kept."""
    import scipy.sparse as sp
    from scipy.sparse.csgraph import connected_components

    if keep is not None:
        rows, cols = rows[keep], cols[keep]
    G = sp.csr_matrix((np.ones(len(rows)), (rows, cols)), shape=(m, m))
    return int(connected_components(G, directed=True, connection="strong", return_labels=False))


def analyse_agent_losses(A, Cs_by_id: dict, graphs: dict, *, rank_tol: float | None = None) -> dict:
    """``{lost agent id: LossReport}`` for every single agent loss: :func:`network_verdict` of each survivor set,
    with strong connectivity decided for all of them in O(m (m + arcs)) compiled steps by scipy's strongly
    connected components (the survivors are strongly connected iff the graph with the lost agent's arcs removed
    has 2 components, the lost agent alone and the rest)."""
    ids = tuple(sorted(Cs_by_id))
    m = len(ids)
    arrays = {name: arc_positions(ids, arcs) for name, arcs in graphs.items()}
    out = {}
    for k, a in enumerate(ids):
        connected = {name: m == 2 or _components(m, rows, cols, (rows != k) & (cols != k)) == 2
                     for name, (rows, cols) in arrays.items()}
        out[a] = network_verdict(A, Cs_by_id, ids[:k] + ids[k + 1:], graphs, rank_tol=rank_tol, connected=connected)
    return out


def analyse_arc_losses(ids, graphs: dict) -> dict:
    """``{graph name: {(j, i): still strongly connected}}`` for every single arc loss (strongly connected
    components of the graph without that arc, scipy's compiled search: O(arcs (m + arcs)) compiled steps)."""
    m = len(ids)
    out = {}
    for name, arcs in graphs.items():
        rows, cols = arc_positions(ids, arcs)
        keep = np.ones(len(rows), dtype=bool)
        res = {}
        for k, drop in enumerate(arcs):
            keep[k] = False
            res[drop] = m <= 1 or _components(m, rows, cols, keep) == 1
            keep[k] = True
        out[name] = res
    return out
