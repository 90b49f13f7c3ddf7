"""Networks that misbehave: which consensus messages count, and how a receiver averages without the others.

Messages
--------
In discrete time, sub-round ``k`` (``1..q``) of event time ``tau`` has agent ``i`` average its
in-neighbours' ``z_j(k-1)`` (eq. split-discrete-p2; ``z_j(0) = x_j(tau)``, eq. split-discrete-p1).
*Message* ``(tau, k, j, i)`` is ``z_j(k-1)`` as agent ``i`` uses it in sub-round ``k``.  In continuous
time there is one exchange per step: message ``(tau, 1, j, i)`` is ``x_j(tau)`` in step ``tau``.

A message does not count in its sub-round when

* ``loss``: it is lost, with probability ``network.loss`` (or the arc's override), independently of
  every other message;
* ``partition``: a ``partition`` fault in force puts ``j`` and ``i`` in different groups;
* ``late`` (``run`` only, with ``network.deadline``): it was not there ``deadline`` seconds after agent
  ``i`` opened the sub-round (``i`` opens sub-round ``k`` once it has ``z_i(k-1)``).  Every message is
  held ``delay`` seconds (``network.delay``: uniform in ``mean +- jitter``, never negative) after it
  arrives before it counts: real waiting, on top of the network's own latency.  ``simulate`` has no
  clock: it emulates the deadline by dropping the messages whose drawn delay exceeds it, and a replay
  (``simulate --faults-from RUN``) drops exactly the messages the run recorded.

Without a deadline every sub-round waits for every message that is not lost (today's behaviour when
nothing is lost either).

What the estimator does without them
------------------------------------
The message removes arc ``j -> i`` for that sub-round only: agent ``i`` averages over what it has,
itself always included.  With uniform weights that is the average over the counted neighbours and
itself, ``1 / (1 + #counted)`` each: row ``i`` of ``S`` of the *realized* graph (the active graph
without the arcs that did not count), ``S_k = D_k^-1 Adj_k'``.  With Metropolis weights each agent
keeps the weights it has and moves the missing ones to itself (``w_ii += sum of the lost w_ij``).
Either way row ``i`` is non-negative, sums to one and keeps a positive diagonal: ``S_k`` is
row-stochastic, and eq. (split-discrete-p2) becomes ``z(k) = (I - P (I - Sbar_k)) z(k-1)``.  By
eq. (split_discrete_pr2), sub-round by sub-round, ``(I - P (I - Sbar_k)) V = V B_k`` with
``B_k = V' Sbar_k V``, so one event time maps the error by ``Abar (prod_k (I - P (I - Sbar_k)))`` whose
unobservable part is ``A_V(tau) = Atil B_q ... B_1`` (eq. split_discrete_ench with a product in place of
``B^q``): the graph now switches *within* an event time, which the paper's discrete results assume it
does not (Section 4: neighbours do not change between event times), and every certificate is about
the realized graphs (:mod:`splitspec_core.synthesis.loss_certificate`).

Draws
-----
Whether a message is lost and its delay are counter-based: ``u(key, tau, k, j, i)``, a splitmix64 hash
of a 64-bit key from the scenario seed's named stream ``network`` and the message's indices, mapped to
``[0, 1)``.  No draw depends on the order messages arrive or on a round's attempt, so ``simulate``
(vectorised, :func:`u_array`) and every agent process (one message at a time, :func:`u_scalar`) draw the
same numbers and lose the same messages.
"""

from __future__ import annotations

import numpy as np

from .streams import stream

__all__ = ["CAUSES", "LOSS", "LATE", "PARTITION", "Impairment", "u_scalar", "u_array", "realized_row",
           "group_of", "crosses", "sub_round"]

LOSS, LATE, PARTITION = 0, 1, 2
CAUSES = ("loss", "late", "partition")

_M64 = (1 << 64) - 1
_GAMMA = (0x9E3779B97F4A7C15, 0xC2B2AE3D27D4EB4F, 0x165667B19E3779F9, 0xD6E8FEB86659FD93)
_MUL1, _MUL2 = 0xBF58476D1CE4E5B9, 0x94D049BB133111EB
_TO_UNIT = 2.0 ** -53


def _mix(z: int) -> int:
    z = ((z ^ (z >> 30)) * _MUL1) & _M64
    z = ((z ^ (z >> 27)) * _MUL2) & _M64
    return z ^ (z >> 31)


def u_scalar(key: int, tau: int, k: int, j: int, i: int) -> float:
    """The uniform draw of message ``(tau, k, j, i)`` under ``key``, in ``[0, 1)`` (one message).

    Parameters
    ----------
    key : int
        64-bit key (:class:`Impairment`'s ``loss_key`` or ``delay_key``).
    tau, k, j, i : int
        Event time, sub-round, sender id and receiver id.

    Returns
    -------
    float
        The splitmix64 hash of the key and indices, mapped to ``[0, 1)`` (53 bits).

    Examples
    --------
    >>> import numpy as np
    >>> u = u_scalar(12345, 3, 1, 2, 5)
    >>> 0.0 <= u < 1.0, bool(u_array(12345, 3, 1, np.array([2]), np.array([5]))[0] == u)
    (True, True)
    """
    z = key & _M64
    for v, g in zip((tau, k, j, i), _GAMMA):
        z = _mix(z ^ ((int(v) * g) & _M64))
    return (z >> 11) * _TO_UNIT


def _mix_array(z: np.ndarray) -> np.ndarray:
    z = (z ^ (z >> np.uint64(30))) * np.uint64(_MUL1)
    z = (z ^ (z >> np.uint64(27))) * np.uint64(_MUL2)
    return z ^ (z >> np.uint64(31))


def u_array(key: int, tau: int, k, j: np.ndarray, i: np.ndarray) -> np.ndarray:
    """:func:`u_scalar` for many messages (``k``, ``j``, ``i`` arrays, broadcast; ``k`` may be one sub-round):
    the same numbers.

    Parameters
    ----------
    key : int
        64-bit key.
    tau : int
        Event time.
    k : int or int array
        Sub-round(s).
    j, i : int arrays
        Sender and receiver ids.

    Returns
    -------
    float array
        The broadcast shape of ``k``, ``j``, ``i``; values in ``[0, 1)``.
    """
    k = np.asarray(k, dtype=np.uint64)
    j = np.asarray(j, dtype=np.uint64)
    i = np.asarray(i, dtype=np.uint64)
    with np.errstate(over="ignore"):  # uint64 arithmetic wraps modulo 2^64, as the scalar version masks
        z = np.uint64(key & _M64) ^ np.uint64((int(tau) * _GAMMA[0]) & _M64)
        z = _mix_array(np.asarray(z, dtype=np.uint64))
        z = _mix_array(z ^ (k * np.uint64(_GAMMA[1])))
        z = _mix_array(z ^ (j * np.uint64(_GAMMA[2])))
        z = _mix_array(z ^ (i * np.uint64(_GAMMA[3])))
    return (z >> np.uint64(11)).astype(np.float64) * _TO_UNIT


class Impairment:
    """The drawn part of a scenario's ``network:`` for one seed: losses and delays of every message."""

    def __init__(self, network, seed: int):
        self.network = network
        keys = stream(seed, "network").integers(0, 2 ** 63, size=2)
        self.loss_key, self.delay_key = int(keys[0]), int(keys[1])
        self._params: dict = {}  # the per-arc parameters of a sub-round's messages, by (senders, receivers)

    def lost(self, tau: int, k: int, j: int, i: int) -> bool:
        """Message ``(tau, k, j, i)`` is lost (an injected loss).

        Parameters
        ----------
        tau, k, j, i : int
            Event time, sub-round, sender id and receiver id.

        Returns
        -------
        bool
            ``u < p`` with ``p`` the arc's loss probability (False when it is 0).
        """
        p = self.network.loss_of((j, i))
        return p > 0 and u_scalar(self.loss_key, tau, k, j, i) < p

    def delay(self, tau: int, k: int, j: int, i: int) -> float:
        """Seconds message ``(tau, k, j, i)`` is held before it counts (``mean + jitter (2u - 1)``, at least 0).

        Parameters
        ----------
        tau, k, j, i : int
            Event time, sub-round, sender id and receiver id.

        Returns
        -------
        float
            The delay in seconds (0.0 when the arc has neither mean nor jitter).
        """
        mean, jitter = self.network.delay_of((j, i))
        if mean == 0 and jitter == 0:
            return 0.0
        return max(0.0, mean + jitter * (2.0 * u_scalar(self.delay_key, tau, k, j, i) - 1.0))

    def _arc_params(self, js: np.ndarray, is_: np.ndarray) -> tuple:
        """Loss probability, delay mean and jitter per message (arrays, or scalars without per-arc overrides)."""
        net = self.network
        if not net.arcs:
            return net.loss, net.delay_mean, net.delay_jitter
        key = (js.tobytes(), is_.tobytes())
        got = self._params.get(key)
        if got is None:
            arcs = list(zip(js.tolist(), is_.tolist()))
            mj = np.array([net.delay_of(a) for a in arcs], dtype=float).reshape(-1, 2)
            got = self._params[key] = (np.array([net.loss_of(a) for a in arcs], dtype=float), mj[:, 0], mj[:, 1])
        return got

    def dropped(self, tau: int, k, js: np.ndarray, is_: np.ndarray) -> np.ndarray:
        """Per message of sub-round ``k`` (arrays of sender and receiver ids): -1 if it counts, else its cause
        (``simulate``'s emulation: a delay beyond the deadline is ``late``).  ``k`` an array of sub-rounds: one
        row per sub-round, the same numbers.

        Parameters
        ----------
        tau : int
            Event time.
        k : int or int array
            Sub-round(s).
        js, is_ : int arrays
            Sender and receiver ids, one per message.

        Returns
        -------
        int64 array
            Broadcast shape of ``k`` and ``js``: -1, :data:`LOSS` or :data:`LATE` (partitions are not drawn here).
        """
        shape = np.broadcast_shapes(np.shape(k), np.shape(js))
        out = np.full(shape, -1, dtype=np.int64)
        if not len(js):
            return out
        net = self.network
        p, mean, jitter = self._arc_params(js, is_)
        if net.lossy:
            out[u_array(self.loss_key, tau, k, js, is_) < p] = LOSS
        if net.deadline is not None and net.delayed:
            d = np.maximum(0.0, mean + jitter * (2.0 * u_array(self.delay_key, tau, k, js, is_) - 1.0))
            out[(out < 0) & (d > net.deadline)] = LATE
        return out


def group_of(groups, ids) -> dict:
    """Agent id -> group index under a partition; the unnamed agents form one more group.

    Parameters
    ----------
    groups : sequence of sequences of int, or None
        The partition's groups of agent ids (None or empty: no partition).
    ids : iterable of int
        Every agent id.

    Returns
    -------
    dict of int to int
        Empty when there is no partition.
    """
    if not groups:
        return {}
    out = {a: g for g, members in enumerate(groups) for a in members}
    rest = len(groups)
    return {a: out.get(a, rest) for a in ids}


def crosses(groups_map: dict, j: int, i: int) -> bool:
    """Arc ``j -> i`` crosses between the groups of a partition in force.

    Parameters
    ----------
    groups_map : dict
        :func:`group_of`'s map (empty: no partition).
    j, i : int
        Sender and receiver ids.

    Returns
    -------
    bool
    """
    return bool(groups_map) and groups_map[j] != groups_map[i]


def realized_row(nbs, ws, counted, weights: str) -> tuple:
    """Agent i's neighbours and weights in a sub-round where only ``counted`` neighbours' messages count.

    Uniform weights: ``1 / (1 + #counted)`` each (row i of the realized graph's ``S``); Metropolis: the missing
    weights go to i itself.  Row-stochastic either way (see the module docstring).

    Parameters
    ----------
    nbs, ws : sequence
        The row of the active graph, agent i first (:func:`splitspec_core.model.network.consensus_rows`).
    counted : container of int
        The neighbour ids whose message counts (i itself always does).
    weights : {"uniform", "metropolis"}
        The design's consensus weights.

    Returns
    -------
    nbs, ws : tuple
        The realized row (the given row itself when every message counts).

    Examples
    --------
    >>> realized_row((1, 2, 3), (1 / 3, 1 / 3, 1 / 3), [3], "uniform")
    ((1, 3), (0.5, 0.5))
    >>> realized_row((1, 2, 3), (0.5, 0.25, 0.25), [3], "metropolis")
    ((1, 3), (0.75, 0.25))
    """
    me = nbs[0]
    keep = [me] + [j for j in nbs[1:] if j in counted]
    if len(keep) == len(nbs):
        return tuple(nbs), tuple(ws)
    if weights == "metropolis":
        kept_w = [w for j, w in zip(nbs[1:], ws[1:]) if j in counted]
        return tuple(keep), tuple([1.0 - sum(kept_w)] + kept_w)
    w = 1.0 / len(keep)
    return tuple(keep), (w,) * len(keep)


def sub_round(imp: Impairment | None, weights: str, *, tau: int, k: int, me: int, nbs, ws, have: dict, groups: dict,
              now: float = 0.0, opened: float = 0.0, arrived: dict | None = None):
    """Agent ``me``'s decision for sub-round ``k`` of event time ``tau`` (the agent process's rule, one message at a time).

    Parameters
    ----------
    imp : Impairment or None
        The run's drawn losses and delays (None: a network without them).
    weights : {"uniform", "metropolis"}
        The design's consensus weights.
    tau, k : int
        Event time and sub-round.
    me : int
        The agent's id.
    nbs, ws : sequence
        Its row of the active graph, itself first.
    have : dict
        Neighbour id -> its message for this sub-round, as far as arrived.
    groups : dict
        A partition in force (:func:`group_of`; empty: none).
    now, opened : float, default 0.0
        The current time and when the sub-round opened, on one clock (seconds).
    arrived : dict, optional
        Neighbour id -> when its message arrived (with delays: each is held its drawn delay).

    Returns
    -------
    tuple
        ``("wait", wake)`` (wake: when to look again, or None to wait for a message) or ``("go", nbs, ws, lost)``:
        the realized row (:func:`realized_row`) and the ``(k, j, cause)`` of every neighbour whose message does not
        count.
    """
    net = imp.network if imp is not None else None
    lost, missing, wake = [], [], []
    for j in nbs[1:]:
        if crosses(groups, j, me):
            lost.append((k, j, PARTITION))
        elif imp is not None and imp.lost(tau, k, j, me):
            lost.append((k, j, LOSS))
        elif j not in have:
            missing.append(j)
        elif arrived is not None:
            release = arrived.get(j, now) + imp.delay(tau, k, j, me)
            if release > now:
                missing.append(j)
                wake.append(release)
    deadline = net.deadline if net is not None else None
    if missing:
        if deadline is None or now < opened + deadline:
            if deadline is not None:
                wake.append(opened + deadline)
            return "wait", (min(wake) if wake else None)
        lost += [(k, j, LATE) for j in missing]
    gone = {j for _, j, _ in lost}
    row_nbs, row_ws = realized_row(nbs, ws, [j for j in nbs[1:] if j not in gone], weights)
    return "go", row_nbs, row_ws, lost
