"""Live sensors (scenario ``sources:``): the newest ``y_i`` from the user's own process, one slot, no queue.

The user's sensor publishes agent i's measurement on ``splitspec/<run>/sensors/<key>``
(:meth:`~splitspec_core.runtime.wire.Keys.sensor`) whenever it has one.  The payload (the contract):

* a JSON object ``{"y": [y_1, ..., y_s], "t": <seconds, optional>}`` (UTF-8), or
* raw little-endian float64, exactly ``8 * s_i`` bytes (no ``t``).

A payload that parses as a JSON object is JSON; otherwise one of exactly ``8 * s_i`` bytes is raw.  ``t`` is the sensor's own clock: the agent's clock and
the sensor's are not synchronised, so ``t`` only orders values (a value whose ``t`` is not after the kept
one's is dropped, ``out_of_order``, while the kept one is fresh: a sensor back after ``max_age`` with its
clock restarted is taken at once); the **age** of a value is measured on the agent's clock from its
arrival.

:class:`LiveSampler` keeps only the newest valid value and its arrival time (one slot: a flood only
overwrites it).  At every event time (the tick's arrival: the run is paced, so that is the event time's
wall-clock instant) the agent takes the value if its age is at most ``max_age``, else it has no
measurement and predicts (:func:`splitspec_core.model.steps.prediction_update`).  What is refused is counted
per reason and reaches the orchestrator in the agent's ``xhat`` (``rejected``): ``too_big`` (more than
:func:`payload_cap` bytes: never decoded), ``garbage`` (neither a JSON object nor ``8 * s_i`` bytes),
``not_object`` (JSON, not an object), ``bad_y`` (no list of numbers), ``bad_length`` (not s_i values),
``non_finite`` (NaN or inf), ``bad_t``, ``out_of_order``, ``flood`` (beyond :data:`FLOOD_RATE` messages a
second, in bursts of at most :data:`FLOOD_BURST`: the rest are dropped undecoded).

Nothing here blocks: :meth:`LiveSampler.offer` runs on Zenoh's thread and holds a lock only to swap the
slot and bump a counter.
"""

from __future__ import annotations

import json
import math
import threading
import time

import numpy as np

__all__ = ["LiveSampler", "SensorReject", "decode_payload", "payload_cap", "FLOOD_RATE", "FLOOD_BURST", "attach",
           "attach_inputs"]

_NOT_JSON = object()

#: messages a second a sensor may send (a token bucket holding at most FLOOD_BURST); the rest are counted
#: (``flood``) and dropped undecoded: a sensor far faster than any event rate only costs its counter
FLOOD_RATE = 500.0
FLOOD_BURST = 50


class SensorReject(ValueError):
    """A sensor payload that is not a measurement; ``reason`` is the counter's name."""

    def __init__(self, reason: str):
        super().__init__(reason)
        self.reason = reason


def payload_cap(size: int) -> int:
    """The largest payload decoded for an s_i = ``size`` sensor: 64 bytes per value and 1 KiB of slack."""
    return 1024 + 64 * size


def decode_payload(payload: bytes, size: int, field: str = "y") -> tuple:
    """``(y, t)`` from a sensor payload (module docstring: the contract); :class:`SensorReject` otherwise.
    ``field``: the JSON object's key of the values (``u`` for the live known inputs, ``sources.inputs``)."""
    if len(payload) > payload_cap(size):
        raise SensorReject("too_big")
    try:
        obj = json.loads(payload)
    except (UnicodeDecodeError, ValueError, RecursionError):
        obj = _NOT_JSON
    if isinstance(obj, dict):
        return _from_object(obj, size, field)
    if len(payload) != 8 * size:  # neither a JSON object nor s_i raw float64
        raise SensorReject("garbage" if obj is _NOT_JSON else "not_object")
    y = np.frombuffer(payload, dtype="<f8").astype(float)
    if not np.isfinite(y).all():
        raise SensorReject("non_finite")
    return y, None


def _from_object(obj, size: int, field: str = "y") -> tuple:
    if not isinstance(obj, dict):
        raise SensorReject("not_object")
    ys = obj.get(field)
    if not isinstance(ys, list) or not all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in ys):
        raise SensorReject(f"bad_{field}")
    if len(ys) != size:
        raise SensorReject("bad_length")
    try:  # JSON integers have no size limit: 400 digits overflow a float
        y = np.array(ys, dtype=float)
    except OverflowError:
        raise SensorReject("non_finite") from None
    if not np.isfinite(y).all():
        raise SensorReject("non_finite")
    t = obj.get("t")
    if t is None:
        return y, None
    if isinstance(t, bool) or not isinstance(t, (int, float)):
        raise SensorReject("bad_t")
    try:
        t = float(t)
    except OverflowError:
        raise SensorReject("bad_t") from None
    if not math.isfinite(t):
        raise SensorReject("bad_t")
    return y, t


class LiveSampler:
    """Agent i's sensor slot: :meth:`offer` (Zenoh thread) keeps the newest value, :meth:`take` samples it.

    ``size``: s_i; ``max_age``: seconds; ``clock``: a monotonic clock (injected in tests).
    """

    def __init__(self, size: int, max_age: float, *, clock=time.monotonic, field: str = "y"):
        self.size, self.max_age, self.clock, self.field = int(size), float(max_age), clock, field
        self._lock = threading.Lock()
        self._slot = None  # (y, t, arrived)
        self._tokens, self._filled = float(FLOOD_BURST), clock()
        self._counts: dict = {}
        self.accepted = 0

    def _count(self, reason: str) -> None:
        with self._lock:
            self._counts[reason] = self._counts.get(reason, 0) + 1

    def offer(self, payload: bytes) -> bool:
        """A sensor message: kept (True) or counted and dropped (False)."""
        with self._lock:  # the arrival time under the lock: the bucket never refills by a negative amount
            now = self.clock()
            self._tokens = min(float(FLOOD_BURST), self._tokens + max(0.0, now - self._filled) * FLOOD_RATE)
            self._filled = max(self._filled, now)
            if self._tokens < 1.0:
                self._counts["flood"] = self._counts.get("flood", 0) + 1
                return False
            self._tokens -= 1.0
        try:
            y, t = decode_payload(payload, self.size, self.field)
        except SensorReject as e:
            self._count(e.reason)
            return False
        except Exception:  # noqa: BLE001 - a payload must never raise on Zenoh's thread; counted instead
            self._count("garbage")
            return False
        with self._lock:
            old = self._slot
            if old is not None and old[2] > now:  # a newer arrival got the slot first
                self._counts["out_of_order"] = self._counts.get("out_of_order", 0) + 1
                return False
            # t orders the values of one sensor's run of fresh values only: once the kept value is older than
            # max_age the sensor may have restarted with its clock (a new t below the old one is its return)
            fresh = old is not None and now - old[2] <= self.max_age
            if t is not None and fresh and old[1] is not None and t <= old[1]:
                self._counts["out_of_order"] = self._counts.get("out_of_order", 0) + 1
                return False
            self._slot = (y, t, now)
            self.accepted += 1
        return True

    def take(self) -> np.ndarray | None:
        """The newest value if it arrived at most ``max_age`` ago, else None (no measurement: predict)."""
        now = self.clock()
        with self._lock:
            slot = self._slot
        if slot is None or now - slot[2] > self.max_age:
            return None
        return slot[0].copy()

    def counts(self) -> dict:
        """Running totals of refused sensor messages per reason."""
        with self._lock:
            return dict(self._counts)


def attach(node, shell, keys) -> list:
    """Give an agent with a live sensor its :class:`LiveSampler` and subscribe it (and the live known inputs',
    :func:`attach_inputs`, when the scenario has ``sources.inputs``); the extra subscriptions.

    The sensor's messages are handled on Zenoh's thread by :meth:`LiveSampler.offer` alone (not under the
    node's lock), so a flooding sensor never holds up the protocol.
    """
    src = node.sc.sources[node.id]
    node.sampler = LiveSampler(node.s, src.max_age)
    sub = _subscribe(node, shell, keys.sensor(src.key), node.sampler, "sensor")
    return [sub] + (attach_inputs(node, shell, keys) if node.sc.input_source is not None else [])


def attach_inputs(node, shell, keys) -> list:
    """Give an agent the live known inputs' :class:`LiveSampler` (``sources.inputs``: ``{"u": [...], "t": ...}``
    or ``8 p`` raw bytes) and subscribe it; refusals are counted as ``inputs_<reason>``."""
    src = node.sc.input_source
    node.input_sampler = LiveSampler(node.sc.system.inputs, src.max_age, field="u")
    return [_subscribe(node, shell, keys.sensor(src.key), node.input_sampler, "inputs")]


def _subscribe(node, shell, key: str, sampler: LiveSampler, what: str):
    """Subscribe ``sampler`` to ``key`` (its refusals in the node's counts as ``<what>_<reason>``); the subscriber."""
    import zenoh

    inbox_counts = node.extra_counts

    def counts() -> dict:
        out = dict(inbox_counts() if inbox_counts else {})
        for reason, c in sampler.counts().items():
            out[f"{what}_{reason}"] = out.get(f"{what}_{reason}", 0) + c
        return out

    node.extra_counts = counts
    cap = payload_cap(sampler.size)

    def cb(sample):
        if len(sample.payload) > cap:  # never copied, never decoded
            sampler._count("too_big")
            return
        sampler.offer(sample.payload.to_bytes())

    sub = shell.session.declare_subscriber(key, zenoh.handlers.Callback(cb, None, indirect=False))
    shell.log.info("agent %d: live %s on %s (max_age %g s)", node.id, what, key, sampler.max_age)
    return sub
