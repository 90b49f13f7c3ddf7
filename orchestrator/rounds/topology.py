"""Topology state: the network the agents of a run form, as the round rules change it.

:class:`TopologyState` keeps who is in the network (``alive``) and who waits to come in at the next event
time (``joinable``), the simulator's own network bookkeeping
(:class:`splitspec_core.model.network.NetworkState`: incarnations, dropped arcs, a partition in force), the
last graph announced and the tick's consensus rows; it announces a changed network (an agent lost or
rejoined, a :class:`Topology` action) and says the survivors' verdict after every change
(:func:`splitspec_core.synthesis.survivors.certify_network`).  I/O-free.
"""

from __future__ import annotations

from splitspec_core.model.network import NetworkState
from splitspec_core.scenarios.faults import NETWORK
from splitspec_core.synthesis.survivors import certify_network

from .actions import Event, Log, MarkLost, Topology

__all__ = ["TopologyState"]


class TopologyState:
    """The agents' network of a run (``sc``, ``des``: the scenario and its design)."""

    def __init__(self, sc, des):
        self.sc, self.des = sc, des
        self.index = {a: k for k, a in enumerate(sc.agent_ids)}
        self.net = NetworkState(sc)
        self.net.alive[:] = False
        self.alive: set = set()
        self.joinable: set = set()  # agents whose token is back: they join at the next event time
        self.last_graph: int | None = None
        self.dirty = True  # the network changed since the last Topology action
        self._rows_cache: tuple | None = None  # (NetworkState.key, rows) of the last tick

    def begin(self) -> None:
        """The run starts: every agent is in."""
        self.net.alive[:] = True
        self.alive = set(self.sc.agent_ids)
        self.joinable.clear()

    def adopt(self, alive, incarnation: dict, faults, *, graph: int) -> None:
        """A takeover: the network of the round in flight (``alive``, ``incarnation``: agent id -> int), the
        network faults applied so far replayed (``faults``), the graph its tick announced."""
        self.net.alive[:] = False
        for a in alive:
            self.net.alive[self.index[a]] = True
        for a, inc in incarnation.items():
            self.net.incarnation[self.index[a]] = int(inc)
        self.net.apply(list(faults))
        self.alive = set(alive)
        self.joinable.clear()
        self.last_graph, self.dirty = graph, True

    def incarnation(self, aid: int) -> int:
        return int(self.net.incarnation[self.index[aid]])

    def lose(self, aid: int, why: str, tau: int, t: float, *, pid=None) -> list:
        """Agent ``aid`` (process ``pid``) leaves the network from event time ``tau`` on: its actions, and the
        survivors' verdict (none: it was not in the network)."""
        if not self.net.lose(self.index[aid]):
            return []
        self.alive.discard(aid)
        self.joinable.discard(aid)
        return [MarkLost(tau, aid),
                Event("agent_lost", t, {"id": aid, "tau": tau, "reason": why, "pid": pid}),
                Log("warning", f"agent {aid} lost from event time {tau}: {why}")
                ] + self.verdict(f"agent {aid} lost", tau, t)

    def rejoin(self, aid: int, why: str, tau: int, t: float, *, pid=None) -> list:
        """Agent ``aid`` (process ``pid``) comes back at event time ``tau`` with a fresh estimate and a new
        incarnation: its actions, and the survivors' verdict (none: it was in the network)."""
        inc = self.net.rejoin(self.index[aid])
        if inc is None:
            return []
        self.alive.add(aid)
        self.joinable.discard(aid)
        return [Event("agent_rejoined", t, {"id": aid, "tau": tau, "incarnation": inc, "reason": why, "pid": pid}),
                Log("info", f"agent {aid} rejoins at event time {tau} with a fresh estimate (incarnation {inc}): "
                            f"{why}")] + self.verdict(f"agent {aid} rejoined", tau, t)

    def change(self, f, tau: int, t: float) -> list:
        """A scenario's fault that the runtime records and the simulator's bookkeeping applies (a kind whose
        ``runtime`` is ``network``: a partition, a heal, a dropped or restored arc; or ``plant``: the plant
        process applies it to the measurements) at event time ``tau``: its event, its log line, and, for the
        kinds that ask for it (an arc), the survivors' verdict."""
        self.net.apply([f])
        self.dirty = self.dirty or f.runtime == NETWORK
        fields = f.payload(tau)
        out = [Event(f.event, t, fields)]
        line = f.log_line(tau)
        if line is not None:
            out.append(Log(*line))
        if f.verdict:
            out += self.verdict(f.text(fields), tau, t)  # after "arc 1 -> 6 dropped"
        return out

    @property
    def groups(self) -> tuple:
        """The groups of agent ids of a partition in force, or ()."""
        return self.net.groups or ()

    def announce(self, tau: int, t: float, graph: int) -> list:
        """The actions that tell the records about a changed network before the tick of ``tau`` on ``graph``."""
        if graph == self.last_graph and not self.dirty:
            return []
        out = []
        name = self.sc.graph_names[graph]
        if self.last_graph is not None and graph != self.last_graph:
            out.append(Event("graph_switched", t, {"graph": name, "previous": self.sc.graph_names[self.last_graph]}))
        out.append(Topology(tau, name, tuple(sorted(self.alive)), tuple(self.net.arcs(self.sc, graph)),
                            partition=tuple(self.groups)))
        self.last_graph, self.dirty = graph, False
        return out

    def rows(self, graph: int) -> dict:
        """The tick's consensus rows of the active network, computed again only when it changed (a graph
        switch, a loss, a rejoin, an arc): building S is O(m) and the network changes rarely."""
        key = self.net.key(graph)
        if self._rows_cache is None or self._rows_cache[0] != key:
            self._rows_cache = (key, self.net.rows(self.sc, graph))
        return self._rows_cache[1]

    def verdict(self, after: str, tau: int, t: float) -> list:
        """The survivors' verdict after a change of the network (``after``, at event time ``tau``): still
        strongly connected, jointly observable, and is the rate still certified by the designed g or q."""
        v = certify_network(self.des, self.alive, frozenset(self.net.dropped))
        survivors = ", ".join(map(str, v["alive"])) or "none"
        if not v["jointly_observable"]:
            msg = (f"agents {survivors} do NOT jointly observe the system (direction {v['unobservable_direction']} "
                   "is seen by none of them): their estimates cannot converge; the run goes on")
        elif not all(v["strongly_connected"].values()):
            bad = ", ".join(f"graph {g} (agent {j} cannot reach agent {i})" for g, (j, i) in v["unreachable"].items())
            msg = f"the network of agents {survivors} is NOT strongly connected: {bad}; the run goes on"
        elif v["rate_certified"] is False:
            msg = (f"agents {survivors} still jointly observe the system over a strongly connected network, but the "
                   f"designed rate is no longer certified ({v['certificate']}); design with `design.resilience: 1` "
                   "to cover single losses")
        else:
            msg = f"agents {survivors}: still strongly connected and jointly observable; {v['certificate']}"
        self.dirty = True
        return [Event("resilience_verdict", t, {"note": f"{after} at event time {tau}: {msg}", "after": after,
                                                "tau": tau, **v}, level="INFO" if v["ok"] else "WARN"),
                Log("info" if v["ok"] else "warning", f"{after} at event time {tau}: {msg}")]
