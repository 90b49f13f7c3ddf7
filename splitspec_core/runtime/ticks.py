"""The orchestrator's ticks with the network only when it changed, and one agent's view of that network.

Every agent decodes every tick.  The network a tick announces (who is alive, each agent's neighbours and
weights, the incarnations, a partition in force) is O(m) to decode, in every agent and every event time: at
m = 100 about a tenth of an agent's CPU per event time, in all of them.  So a tick carries it only when it
changed, with ``topology``, the number of changes so far (``wire`` schema 6): :class:`TickEncoder` on the
orchestrator's side, :class:`TickNetwork` in each agent, which keeps what the last tick with a network said
of it.  A tick naming a network the agent never received (it cannot happen on Zenoh's reliable links; it
would take a lost tick) leaves the agent out of that round, counted as ``unknown_topology``: the orchestrator
then sees it as lost, and its rejoin changes the network, which the next tick carries.
"""

from __future__ import annotations

from ..model.impairment import group_of
from .wire import encode

__all__ = ["TickEncoder", "TickNetwork", "Fence"]


class Fence:
    """The highest orchestrator epoch a process has seen in a tick or a control (fencing).

    Every orchestrator that holds a run's rounds has an epoch: the first 1, each standby that takes over one
    more.  A tick or a control of a lower epoch than the highest seen comes from an orchestrator that was
    superseded (cut off, then back): it is refused (``fenced``), so two orchestrators never hold the rounds at
    once.  A message without an epoch counts as epoch 0.

    Examples
    --------
    >>> f = Fence()
    >>> f.admit({"epoch": 1}), f.admit({"epoch": 2}), f.admit({"epoch": 1}), f.epoch
    (True, True, False, 2)
    """

    def __init__(self):
        self.epoch = 0

    def admit(self, msg: dict) -> bool:
        """Whether the decoded tick or control ``msg`` may be obeyed (its epoch is not below the highest seen).

        Parameters
        ----------
        msg : dict
            A decoded ``tick`` or ``control`` message.

        Returns
        -------
        bool
            True (and the highest epoch raised to the message's) unless the message's epoch is lower.
        """
        epoch = int(msg.get("epoch", 0))
        if epoch < self.epoch:
            return False
        self.epoch = epoch
        return True


class TickEncoder:
    """The ticks of one run (signed with ``mac_key``), the network in those where it changed."""

    def __init__(self, run_id: str, *, mac_key: bytes | None, epoch: int = 0, topology: int = 0):
        self.run_id, self.mac_key = run_id, mac_key
        self.epoch = int(epoch)  # the orchestrator's (fencing: Fence); 0: none sent
        self.topology = int(topology)  # a standby that takes over counts on from the last tick's
        self._last = None

    def encode(self, *, tau: int, attempt: int, graph: int, final: bool, fresh: bool, prev_attempt: int,
               alive, rows: dict, incarnation: dict, partition) -> bytes:
        """The tick of one round, with the network only when it differs from the last tick's (``topology``: changes).

        Parameters
        ----------
        tau, attempt : int
            Event time and attempt of the round.
        graph : int
            Index of the active graph in the scenario's graph names.
        final : bool
            The last tick of the run (no round follows).
        fresh : bool
            Some agent starts this round with a fresh estimate: every agent sends its ``z_i(0)``.
        prev_attempt : int
            The attempt of round ``tau - 1`` whose estimates ``x_i(tau)`` are this round's ``z_i(0)``.
        alive : iterable of int
            Agent ids alive.
        rows : dict
            ``{agent id: (neighbours, weights)}``.
        incarnation : dict
            ``{agent id: int}``.
        partition : iterable of iterables of int
            Groups of a partition in force (empty: none).

        Returns
        -------
        bytes
            The encoded (and, with ``mac_key``, signed) ``tick`` message.

        Examples
        --------
        >>> from splitspec_core.runtime.wire import decode
        >>> enc = TickEncoder("r1", mac_key=None)
        >>> kw = dict(attempt=0, graph=0, final=False, fresh=True, prev_attempt=0, alive=[1, 2], partition=(),
        ...           rows={1: ((1, 2), (0.5, 0.5)), 2: ((2, 1), (0.5, 0.5))}, incarnation={1: 0, 2: 0})
        >>> first, second = (decode(enc.encode(tau=t, **kw), "r1", "tick") for t in (0, 1))
        >>> first["topology"], "rows" in first, second["topology"], "rows" in second
        (1, True, 1, False)
        >>> net = TickNetwork(2, [1, 2])
        >>> net.update(first), net.row, net.update(second)
        (True, ([2, 1], [0.5, 0.5]), True)
        """
        net = (tuple(alive), rows, dict(incarnation), tuple(tuple(g) for g in partition))
        last = self._last
        # rows is the round machine's cached dict while the network stands: identity first, O(1)
        same = (last is not None and (last[1] is rows or last[1] == rows)
                and (last[0], last[2], last[3]) == (net[0], net[2], net[3]))
        fields = dict(tau=tau, attempt=attempt, graph=graph, final=final, fresh=fresh, prev_attempt=prev_attempt)
        if not same:
            self.topology += 1
            self._last = net
            fields.update(alive=list(net[0]), rows={str(i): [list(nb), list(w)] for i, (nb, w) in rows.items()},
                          incarnation={str(i): int(v) for i, v in net[2].items()},
                          partition=[list(g) for g in net[3]])
        if self.epoch:
            fields["epoch"] = self.epoch
        return encode("tick", self.run_id, mac_key=self.mac_key, topology=self.topology, **fields)

    def resend_network(self) -> None:
        """Carry the network in the next tick (a standby that starts following learns it there)."""
        self._last = None


class TickNetwork:
    """Agent ``agent_id``'s view of the network the ticks announce, from the last tick that carried one: its row
    (neighbours as ints, weights as floats; None when it takes no part), whether it is alive, its incarnation,
    every agent's (``incarnations``, ``{agent id: incarnation}``: a higher one is a rejoin), and the partition in
    force as ``{agent id: group}`` (:func:`splitspec_core.model.impairment.group_of`; {} for none)."""

    def __init__(self, agent_id: int, ids):
        self.id, self.key, self.ids = agent_id, str(agent_id), tuple(ids)
        self.topology = None
        self.row = None
        self.alive = False
        self.incarnation = 0
        self.incarnations: dict = {}
        self.groups: dict = {}

    def update(self, t: dict) -> bool:
        """Take the network of the decoded tick ``t`` if it has one; False if ``t`` names a network this agent
        never received.

        Parameters
        ----------
        t : dict
            A decoded ``tick`` message.

        Returns
        -------
        bool
            Whether the agent's view is the network ``t`` names (its ``topology``).
        """
        if "rows" in t:
            self.topology = t["topology"]
            row = t["rows"].get(self.key)
            self.row = None if row is None else ([int(j) for j in row[0]], [float(w) for w in row[1]])
            self.alive = self.id in t["alive"]
            self.incarnation = int(t["incarnation"].get(self.key, 0))
            self.incarnations = {int(k): int(v) for k, v in t["incarnation"].items()}
            self.groups = group_of(t["partition"], self.ids)
        return self.topology == t["topology"]
