"""An agent's measurements ``y_i(tau)``: what it updates with, or that it has none (it then predicts only).

The plant publishes one ``y`` message per event time for every agent (``y/all``: the stacked
``(y_1, ..., y_m)``, then ``u(tau)`` when the scenario has known inputs, and the ids of the agents without a
measurement at that event time, a recorded gap in a measurements file).  :class:`YBuffer` keeps agent i's rows of it per event time: at most two event times
before the first tick, none older than the last tick's, none more than one event time ahead of it; anything
else is dropped and counted (``stale``, ``future``, ``buffer_full``, ``bad_shape``).
"""

from __future__ import annotations

import numpy as np

from splitspec_core.model.steps import known_input

__all__ = ["YBuffer"]


class YBuffer:
    """``y_i(tau)`` per event time (None: no measurement at ``tau``); :meth:`ready` before :meth:`get`."""

    def __init__(self, agent_id: int, rows: slice, size: int, limit: int = 2, B: np.ndarray | None = None):
        self.id, self.rows, self.limit = agent_id, rows, limit
        self.B = None if B is None else np.asarray(B)  # the scenario's known inputs: x+ = A x + B u
        self.outputs, self.inputs = size, 0 if B is None else int(np.shape(B)[1])
        self.size = size + self.inputs  # the message's vector: the stacked y, then u(tau) (the scenario's known inputs)
        self.buf: dict = {}
        self.ubuf: dict = {}
        self.held = np.zeros(self.inputs)  # live inputs (put_input): the last u taken, zero before the first

    def put_message(self, m: dict, *, last_tau, tick_tau, reject) -> bool:
        """Keep agent i's part of a decoded ``y`` message; False (and ``reject(reason)``) if it is dropped."""
        if m["y"].shape != (self.size,):
            reject("bad_shape")
            return False
        tau = m["tau"]
        if (last_tau is not None and tau < last_tau) or (tick_tau is not None and tau < tick_tau):
            reject("stale")
            return False
        if tick_tau is not None and tau > tick_tau + 1:
            reject("future")
            return False
        if tau not in self.buf and len(self.buf) >= self.limit:  # before the first tick: keep the newest two
            oldest = min(self.buf)
            if tau < oldest:
                reject("buffer_full")
                return False
            del self.buf[oldest]
        self.buf[tau] = None if self.id in m["missing"] else np.asarray(m["y"][self.rows])
        if self.inputs:
            self.ubuf[tau] = np.asarray(m["y"][self.outputs:])
        return True

    def put_sample(self, tau: int, y: np.ndarray | None, u: np.ndarray | None = None) -> None:
        """A live sensor's sample at event time ``tau`` (:mod:`splitspec_agents.sensor`); the first one counts.
        With known inputs, ``u`` is the live inputs' sample (:meth:`put_input`)."""
        self.buf.setdefault(tau, y)
        if self.inputs:
            self.put_input(tau, u)

    def put_input(self, tau: int, u: np.ndarray | None) -> None:
        """The live known inputs' sample at ``tau`` (``sources.inputs``); None (none fresh): the last one taken is
        held, zero before the first.  The first one of an event time counts."""
        if u is not None:
            self.held = np.asarray(u, dtype=float)
        self.ubuf.setdefault(tau, self.held)

    def ready(self, tau: int) -> bool:
        """Whether ``y_i(tau)`` (or the word that there is none) has arrived."""
        return tau in self.buf

    def get(self, tau: int) -> np.ndarray | None:
        return self.buf[tau]

    def bu(self, tau: int) -> np.ndarray | None:
        """``B u(tau)``, ``u`` as the plant sent it (the simulator adds ``B @ u`` too); None: no inputs."""
        return known_input(self.B, self.ubuf[tau] if self.inputs else None)

    def prune(self, tau: int) -> None:
        """Forget event times before ``tau``."""
        self.buf = {k: v for k, v in self.buf.items() if k >= tau}
        self.ubuf = {k: v for k, v in self.ubuf.items() if k >= tau}
