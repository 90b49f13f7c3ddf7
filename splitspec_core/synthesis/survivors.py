"""The runtime's verdict on what is left after losses: does the designed g or q still certify the rate?

The orchestrator asks it at every loss, rejoin and link change of a run (``certify_network``): the survivors'
strong connectivity, what they leave unobserved (:mod:`splitspec_core.model.detectability`: ``W_S``, the intersection of
their own unobservable spaces, and whether it decays), then the design's own certificate recomputed on the
survivors' graphs, on the quotient by ``W_S`` (:func:`splitspec_core.synthesis.verdict.survivors_certificate`:
the verdict and its line are the verdict module's).  Cheap enough for every event of a run: no bisection, no search.
"""

from __future__ import annotations

from .design_data import Design
from .verdict import survivors_certificate

__all__ = ["certify_network"]


def certify_network(des: Design, alive_ids, dropped=frozenset()) -> dict:
    """Does the designed g or q still certify the rate on what is left after losses?

    The survivors ``alive_ids`` on every graph the switching signal uses,
    minus the ``dropped`` arcs: strong connectivity, joint observability and
    detectability (:func:`resilience.network_verdict`), then, when every graph
    is strongly connected and what the survivors leave unobserved decays (or
    was excluded by the design), the design's own certificate recomputed on
    the survivors' graphs
    (:func:`splitspec_core.synthesis.verdict.survivors_certificate`: ``q``
    with the design's q method, ``g`` against eq. (g) or the exact spectrum,
    and the sampled-data form with ``run.dt``).  Cheap enough to call at
    every loss during a run (no bisection).

    Parameters
    ----------
    des : Design
        The design the run uses.
    alive_ids : iterable of int
        The agents still alive (ids not in the scenario are ignored).
    dropped : set of (int, int)
        Arcs ``(j, i)`` that are down.

    Returns
    -------
    dict
        JSON-ready: ``alive``, ``dropped_arcs``, ``strongly_connected`` (per graph), ``unreachable`` (per graph, a
        pair ``[j, i]``), ``jointly_observable``, ``detectable``, ``unobservable_direction``, ``rate_certified``
        (bool, or None for the adaptive gain), ``certificate`` (one line), ``ok``; ``envelope_rate`` when certified
        at a slower envelope (directions the survivors leave unobserved).

    Examples
    --------
    >>> import splitspec_core as ss
    >>> from splitspec_core.synthesis.designer import design
    >>> des = design(ss.scenario(A=[[0, 1, 0, 0], [-1, 0, 0, 0], [0, 0, 0, 1], [0, 0, -2, 0]],
    ...                          C={1: [[1, 0, 0, 0]], 2: [[0, 1, 0, 0]], 3: [[0, 0, 1, 0]]},
    ...                          graphs={"a": [(1, 2), (2, 1), (2, 3), (3, 2), (1, 3), (3, 1)]}, rate=0.5,
    ...                          gains="place"))
    >>> v = certify_network(des, [1, 3])
    >>> v["rate_certified"], v["certificate"]
    (True, 'q = 3: spectral bound 0.1768 < rate 0.5')
    >>> v = certify_network(des, [1, 2])  # nobody sees x3, x4 any more
    >>> v["ok"], v["jointly_observable"], v["certificate"]
    (False, False, 'no rate: the survivors leave a mode unobserved that does not decay')
    """
    from ..model.network import active_arcs
    from .resilience import network_verdict

    sc = des.scenario
    alive = tuple(a for a in sc.agent_ids if a in set(alive_ids))
    used = sc.switching.graph_names(sc.graph_names)
    arcs = {name: active_arcs(sc, sc.graph_names.index(name), dropped) for name in used}
    v = network_verdict(des.unobserved_of, alive, arcs)
    un_S = v.unobserved
    out = {"alive": list(alive), "dropped_arcs": sorted([list(a) for a in dropped]),
           "strongly_connected": dict(v.strongly_connected),
           "unreachable": {k: list(p) for k, p in v.unreachable.items()},
           "jointly_observable": v.jointly_observable, "detectable": v.detectable,
           "unobservable_direction": v.unobservable_direction}
    excluded = des.excluded and un_S.dim == des.unobserved.dim  # nothing more unobserved than the design excluded
    cert = survivors_certificate(des, alive, arcs, v, excluded=excluded)
    if cert.certified and un_S.dim and not excluded:
        out["envelope_rate"] = cert.rate
    out.update(rate_certified=cert.certified, certificate=cert.text,
               ok=bool(cert.certified is not False and all(v.strongly_connected.values())
                       and (v.detectable or excluded)))
    return out
