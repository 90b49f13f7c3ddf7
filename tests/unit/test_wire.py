"""The wire codec: every message type round-trips, and every malformed payload is a WireError with its reason.

The round messages (y, truth, z, xhat) are binary with a fixed layout; the others msgpack maps. Whatever
bytes arrive, decode either returns a validated message or raises WireError: never another exception.
"""

import struct

import msgpack
import numpy as np
import pytest

from splitspec_core.model.rows import report
from splitspec_core.runtime.wire import (BINARY_LAYOUT, MAC_BYTES, ROW_TAG, SCHEMA_VERSION, WireError, decode, encode,
                                         new_run_key)

RUN = "wire-test"
V = np.array([1.5, -2.0, 3.25, 0.0, 1e300, -1e-300])

ROUND = {
    "y": dict(tau=7, attempt=1, y=V[:3], missing=[2]),
    "truth": dict(tau=7, attempt=0, x=V, rejected={"stale": 3, "bad_mac": 1}),
    "z": dict(tau=2 ** 62, attempt=2, k=5, agent=31, z=V),
    "xhat": dict(tau=0, attempt=0, agent=3, incarnation=2, x=V, **report(g=0.125), rejected={},
                 lost=[1, 2, 0, 3, 4, 1], y=[0.5, -1.0], u=[2.0]),  # report: every row column the agents report (rows.py)
}
OTHER = {
    "tick": dict(tau=3, attempt=0, graph=1, alive=[1, 2], rows={"1": [[2], [0.5]]}, final=False,
                 incarnation={"1": 0}, fresh=True, prev_attempt=0, partition=[], topology=4),
    "control": dict(cmd="stop"),
    "hello": dict(role="agent", id=2, pid=123, host="h", nonce="ab"),
}


def same(a, b):
    assert a.keys() == b.keys()
    for k in a:
        if isinstance(a[k], np.ndarray):
            # exact: an encode/decode round trip carries the float64 bytes unchanged
            assert a[k].dtype == float and a[k].shape == np.shape(b[k]) and np.array_equal(a[k], b[k])
        else:
            assert a[k] == b[k] and type(a[k]) is type(b[k])


@pytest.mark.parametrize("msg_type", [*ROUND, *OTHER])
@pytest.mark.parametrize("signed", [False, True])
def test_round_trip(msg_type, signed):
    fields = {**ROUND, **OTHER}[msg_type]
    key = new_run_key() if signed else None
    payload = encode(msg_type, RUN, mac_key=key, **fields)
    assert (payload[0] == 0xB5) == (msg_type in BINARY_LAYOUT)
    same(decode(payload, RUN, msg_type, mac_key=key), fields)


def test_round_messages_are_compact():
    # fixed header + 8 bytes per number (+ the counters' map): a z of n = 6 is 80 bytes before its MAC
    body = encode("z", RUN, **ROUND["z"])
    assert len(body) == struct.calcsize("<BBBxIqiiiI") + 8 * V.size
    as_map = msgpack.packb({"v": SCHEMA_VERSION, "run": RUN, "type": "z", **{k: v for k, v in ROUND["z"].items()
                                                                              if k != "z"},
                            "z": {"shape": [6], "data": V.tobytes()}}, use_bin_type=True)
    assert len(body) < len(as_map)


def reason(payload, msg_type, key=None, run=RUN):
    with pytest.raises(WireError) as e:
        decode(payload, run, msg_type, mac_key=key)
    return e.value.reason


@pytest.mark.parametrize("msg_type", list(ROUND))
def test_every_truncation_and_extension_is_refused(msg_type):
    p = encode(msg_type, RUN, **ROUND[msg_type])
    for cut in range(len(p)):
        assert reason(p[:cut], msg_type) in {"garbage", "bad_shape", "bad_field"}, cut
    for extra in (b"\x00", b"\x80", b"\x00" * 8):
        assert reason(p + extra, msg_type) in {"garbage", "bad_shape"}


def test_header_checks():
    p = bytearray(encode("z", RUN, **ROUND["z"]))
    assert reason(bytes(p), "z", run="another-run") == "wrong_run"
    assert reason(bytes(p), "xhat") == "wrong_type"
    assert reason(bytes(p), "tick") == "wrong_type"
    old = bytearray(p)
    old[1] = SCHEMA_VERSION - 1
    assert reason(bytes(old), "z") == "bad_version"
    other_rows = bytearray(p)  # a process built with other reported row columns (rows.py): its xhat would not fit
    other_rows[3] = (ROW_TAG + 1) % 256
    assert reason(bytes(other_rows), "z") == "bad_version"
    unknown = bytearray(p)
    unknown[2] = 99
    assert reason(bytes(unknown), "z") == "wrong_type"
    # a count far beyond the payload (or beyond the limit) is a shape error, never an allocation
    huge = bytearray(p)
    struct.pack_into("<I", huge, struct.calcsize("<BBBxIqiii"), 2 ** 31)
    assert reason(bytes(huge), "z") == "bad_shape"


def test_a_round_message_as_a_map_is_refused():
    as_map = msgpack.packb({"v": SCHEMA_VERSION, "run": RUN, "type": "z", "tau": 1, "attempt": 0, "k": 0,
                            "agent": 1, "z": {"shape": [2], "data": bytes(16)}})
    assert reason(as_map, "z") == "garbage"
    assert reason(msgpack.packb({"v": 2, "run": RUN, "type": "z"}), "z") == "bad_version"


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_non_finite_numbers_are_refused(bad):
    for n in (3, 100):  # both the small-vector and the numpy path
        v = np.zeros(n)
        v[-1] = bad
        assert reason(encode("z", RUN, tau=1, attempt=0, k=0, agent=1, z=v), "z") == "non_finite"
    assert reason(encode("xhat", RUN, **{**ROUND["xhat"], "g": bad}), "xhat") == "bad_field"


@pytest.mark.parametrize("counters", [[1, 2], {"stale": "3"}, {"stale": 1.5}, {"stale": True}, {1: 2}])
def test_counters_must_be_a_map_of_counts(counters):
    # the maps come last, in order: rejected ({}: 0x80), lost ([]: 0x90), y ([]: 0x90), u ([]: 0x90)
    body = encode("xhat", RUN, **{**ROUND["xhat"], "rejected": {}, "lost": [], "y": [], "u": []})[:-4]
    assert reason(body + msgpack.packb(counters) + b"\x90\x90\x90", "xhat") in {"bad_field", "garbage"}


@pytest.mark.parametrize("field,bad", [("y", [1.0, float("nan")]), ("y", [1.0, "2"]), ("y", {"a": 1}),
                                       ("y", [True]), ("u", [1.0, float("inf")]), ("u", ["1"]), ("u", {"a": 1}),
                                       ("missing", [-1]), ("missing", [1.5]), ("missing", "1"),
                                       ("missing", [2 ** 40])])
def test_measurement_fields_are_checked(field, bad):
    msg_type = "xhat" if field in ("y", "u") else "y"
    assert reason(encode(msg_type, RUN, **{**ROUND[msg_type], field: bad}), msg_type) == "bad_field"


def test_measurement_fields_default_and_say_none():
    """Senders that do not record measurements leave them out: ``missing`` [] and ``y`` []; None is "no measurement"."""
    m = decode(encode("y", RUN, tau=1, attempt=0, y=V[:3]), RUN, "y")
    assert m["missing"] == []
    x = decode(encode("xhat", RUN, **{k: v for k, v in ROUND["xhat"].items() if k not in ("y", "u")}), RUN, "xhat")
    assert x["y"] == [] and x["u"] == []
    assert decode(encode("xhat", RUN, **{**ROUND["xhat"], "y": None}), RUN, "xhat")["y"] is None
    assert decode(encode("xhat", RUN, **{**ROUND["xhat"], "u": [0.5, -2.0]}), RUN, "xhat")["u"] == [0.5, -2.0]


def test_signatures():
    key = new_run_key()
    p = encode("xhat", RUN, mac_key=key, **ROUND["xhat"])
    assert reason(p, "xhat", key=new_run_key()) == "bad_mac"
    for i in range(len(p)):
        flipped = bytearray(p)
        flipped[i] ^= 0x01
        assert reason(bytes(flipped), "xhat", key=key) == "bad_mac"
    assert reason(p[:MAC_BYTES], "xhat", key=key) == "bad_mac"


def test_random_bytes_and_mutations_only_ever_raise_wire_errors():
    rng = np.random.default_rng(14)
    seeds = [encode(t, RUN, **f) for t, f in {**ROUND, **OTHER}.items()]
    for _ in range(3000):
        p = bytearray(seeds[rng.integers(len(seeds))])
        for _ in range(rng.integers(1, 4)):
            p[rng.integers(len(p))] = rng.integers(256)
        if rng.random() < 0.2:
            p = bytearray(rng.bytes(rng.integers(0, 64)))
        for t in (*ROUND, *OTHER):
            try:
                m = decode(bytes(p), RUN, t)
            except WireError:
                continue
            for v in m.values():  # what passes is well-typed and finite
                if isinstance(v, np.ndarray):
                    assert v.dtype == float and np.isfinite(v).all()


def test_encode_refuses_what_the_layout_does_not_hold():
    with pytest.raises(TypeError, match="takes the fields"):
        encode("z", RUN, tau=1, attempt=0, k=0, z=V)  # no agent
    with pytest.raises(TypeError, match="takes the fields"):
        encode("y", RUN, tau=1, attempt=0, y=V, extra=1)
    with pytest.raises(TypeError, match="g=None"):
        encode("xhat", RUN, **{**ROUND["xhat"], "g": None})
    with pytest.raises(TypeError, match="tau=" + str(2 ** 63)):
        encode("z", RUN, **{**ROUND["z"], "tau": 2 ** 63})
    with pytest.raises(ValueError, match="must be a vector"):
        encode("y", RUN, tau=1, attempt=0, y=np.zeros((2, 3)))


def test_a_tick_carries_its_network_whole_or_not_at_all():
    from splitspec_core.runtime.wire import decode

    full = OTHER["tick"]
    compact = {k: v for k, v in full.items() if k not in ("alive", "rows", "incarnation", "partition")}
    assert "rows" not in decode(encode("tick", RUN, **compact), RUN, "tick")
    assert decode(encode("tick", RUN, **full), RUN, "tick")["rows"] == full["rows"]
    for left_out in ("alive", "rows", "incarnation", "partition"):
        part = {k: v for k, v in full.items() if k != left_out}
        assert reason(encode("tick", RUN, **part), "tick") == "missing_field"


def test_tick_encoder_sends_the_network_when_it_changes():
    """The first tick and every tick after a change carry the network (topology counts the changes); the others
    carry none.  A change is any of: alive, rows, incarnations, partition."""
    from splitspec_core.runtime.ticks import TickEncoder, TickNetwork
    from splitspec_core.runtime.wire import decode

    enc, view = TickEncoder(RUN, mac_key=None), TickNetwork(2, (1, 2, 3))
    rows = {1: ((1, 2), (0.5, 0.5)), 2: ((2, 1, 3), (1 / 3,) * 3), 3: ((3, 2), (0.5, 0.5))}
    base = dict(attempt=0, graph=0, final=False, fresh=False, prev_attempt=0, alive=(1, 2, 3), rows=rows,
                incarnation={1: 0, 2: 0, 3: 0}, partition=())
    changes = [{}, {}, {"alive": (1, 2)}, {"alive": (1, 2)}, {"rows": dict(rows)}, {"incarnation": {1: 0, 2: 1, 3: 0}},
               {"incarnation": {1: 0, 2: 1, 3: 0}}, {"partition": ((1,), (2, 3))}, {"partition": ((1,), (2, 3))}]
    got = []
    for tau, change in enumerate(changes):
        t = decode(enc.encode(tau=tau, **{**base, **change}), RUN, "tick")
        assert view.update(t)
        got.append((t["topology"], "rows" in t))
        base = {**base, **change}
    # an equal copy of the rows is no change (index 4); a new incarnation and a partition are
    assert got == [(1, True), (1, False), (2, True), (2, False), (2, False), (3, True), (3, False), (4, True),
                   (4, False)]
    assert view.row == ([2, 1, 3], [1 / 3] * 3) and view.incarnation == 1 and view.alive
    assert view.groups == {1: 0, 2: 1, 3: 1}
