"""Resilience analysis (paper, Section resilience; Automatica22, Section 5).

A network is *redundantly strongly connected* when every graph stays
strongly connected after any one agent is lost, and *redundantly jointly
observable* when the survivors of any single loss still jointly observe
``(C, A)``; *redundantly jointly detectable* when what the survivors leave
unobserved (``W_S``, :mod:`splitspec_core.model.detectability`) still decays.  The
split-spectrum estimators keep working after such a loss provided g or q also
covers the survivors' graphs (``design.resilience: 1``), on the quotient by ``W_S``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from typing import Callable

from ..model.detectability import Unobserved, UnobservedOf, still_text
from ..model.graphs import arc_positions, find_unreachable

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
    unobserved : Unobserved
        What no survivor sees (``W_S``), its spectrum and whether it decays.
    """

    strongly_connected: dict
    unreachable: dict
    unobserved: Unobserved

    @property
    def jointly_observable(self) -> bool:
        """The survivors observe the whole state: nothing is left unobserved (bool)."""
        return self.unobserved.dim == 0

    @property
    def detectable(self) -> bool:
        """What no survivor sees decays (so a rate can still be certified)."""
        return self.unobserved.decays

    @property
    def unobservable_direction(self) -> str | None:
        """The modes no survivor sees that do not decay (named), when not jointly detectable; else None."""
        return None if self.detectable else still_text(self.unobserved)

    @property
    def ok(self) -> bool:
        """The loss is survivable (bool): what the survivors leave unobserved decays and every graph restricted to
        them is strongly connected."""
        return self.detectable and all(self.strongly_connected.values())


def network_verdict(unobserved_of: Callable, alive, graphs: dict, *, connected: dict | None = None,
                    unobserved: Unobserved | None = None) -> LossReport:
    """Strong connectivity of each graph restricted to ``alive`` and what ``alive`` leaves unobserved.

    ``unobserved_of(alive)``: the :class:`~splitspec_core.model.detectability.Unobserved` of a set of agents (the design's
    :meth:`~splitspec_core.synthesis.design_data.Design.unobserved_of`), unless ``unobserved`` gives it already.
    ``graphs`` maps a name to its arcs ``(j, i)`` between agent ids.  ``connected``: ``{name: bool}`` already
    known (:func:`analyse_agent_losses` decides it for every loss at once); a pair that cannot reach is then
    searched only for a graph that splits.

    Parameters
    ----------
    unobserved_of : callable
        ``alive -> Unobserved``; not called when ``unobserved`` is given.
    alive : iterable of int
        The surviving agents' ids.
    graphs : dict
        ``{graph name: arcs (j, i)}`` (arcs to or from lost agents are ignored).
    connected : dict, optional
        ``{graph name: bool}``, strong connectivity already decided.
    unobserved : Unobserved, optional
        What ``alive`` leaves unobserved, already computed.

    Returns
    -------
    LossReport
        Per graph whether it stays strongly connected (False when nobody is alive) and, when not, a pair that
        cannot reach; what the survivors leave unobserved.
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
    return LossReport(strongly_connected=sc, unreachable=unreach,
                      unobserved=unobserved_of(alive) if unobserved is None else unobserved)


def _components(m: int, rows: np.ndarray, cols: np.ndarray, keep: np.ndarray | None = None) -> int:
    """Strongly connected components of the digraph on m vertices with the arcs ``rows[k] -> cols[k]`` kept."""
    import scipy.sparse as sp
    from scipy.sparse.csgraph import connected_components

    if keep is not None:
        rows, cols = rows[keep], cols[keep]
    G = sp.csr_matrix((np.ones(len(rows)), (rows, cols)), shape=(m, m))
    return int(connected_components(G, directed=True, connection="strong", return_labels=False))


def analyse_agent_losses(unobserved_of: UnobservedOf, ids, graphs: dict) -> dict:
    """``{lost agent id: LossReport}`` for every single agent loss: :func:`network_verdict` of each survivor set,
    with strong connectivity decided for all of them in O(m (m + arcs)) compiled steps by scipy's strongly
    connected components (the survivors are strongly connected iff the graph with the lost agent's arcs removed
    has 2 components, the lost agent alone and the rest), and what each survivor set leaves unobserved by
    :meth:`UnobservedOf.without_each` (O(m) factorizations for all m losses, not m intersections of m - 1
    subspaces each).

    Parameters
    ----------
    unobserved_of : UnobservedOf
        What a set of the scenario's agents leaves unobserved (its ``without_each`` gives every single loss).
    ids : iterable of int
        Every agent's id.
    graphs : dict
        ``{graph name: arcs (j, i)}``.

    Returns
    -------
    dict
        ``{lost agent id: LossReport}``, in the order of the sorted ids.

    Examples
    --------
    >>> import splitspec_core as ss
    >>> from splitspec_core.synthesis.designer import design
    >>> des = design(ss.scenario(A=[[0, 1, 0, 0], [-1, 0, 0, 0], [0, 0, 0, 1], [0, 0, -2, 0]],
    ...                          C={1: [[1, 0, 0, 0]], 2: [[0, 1, 0, 0]], 3: [[0, 0, 1, 0]]},
    ...                          graphs={"a": [(1, 2), (2, 1), (2, 3), (3, 2), (1, 3)]}, rate=0.5, gains="place"))
    >>> losses = des.agent_losses  # this function's result, computed by the design
    >>> losses[2].strongly_connected, losses[2].unreachable, losses[3].detectable
    ({'a': False}, {'a': (3, 1)}, False)
    """
    ids = tuple(sorted(ids))
    m = len(ids)
    arrays = {name: arc_positions(ids, arcs) for name, arcs in graphs.items()}
    unobserved = unobserved_of.without_each(ids)
    out = {}
    for k, a in enumerate(ids):
        connected = {name: m == 2 or _components(m, rows, cols, (rows != k) & (cols != k)) == 2
                     for name, (rows, cols) in arrays.items()}
        out[a] = network_verdict(unobserved_of, ids[:k] + ids[k + 1:], graphs, connected=connected,
                                 unobserved=unobserved[a])
    return out


def analyse_arc_losses(ids, graphs: dict) -> dict:
    """``{graph name: {(j, i): still strongly connected}}`` for every single arc loss (strongly connected
    components of the graph without that arc, scipy's compiled search: O(arcs (m + arcs)) compiled steps).

    Parameters
    ----------
    ids : sequence of int
        Every agent's id.
    graphs : dict
        ``{graph name: arcs (j, i)}``.

    Returns
    -------
    dict
        ``{graph name: {(j, i): bool}}``, False for an arc whose loss breaks strong connectivity.

    Examples
    --------
    >>> analyse_arc_losses((1, 2, 3), {"a": [(1, 2), (2, 3), (3, 1), (2, 1)]})
    {'a': {(1, 2): False, (2, 3): False, (3, 1): False, (2, 1): True}}
    """
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
