"""The agent's and the plant's protocol state machines, without sockets: what they accept and what not."""

import numpy as np
import pytest

from splitspec_agents.agent import AgentNode
from splitspec_plant.plant import PlantNode
from splitspec_core.runtime.wire import encode, new_run_key
from tests.conftest import EXAMPLES

KEY = new_run_key()


def config(key=KEY):
    return {"scenario": (EXAMPLES / "paper_discrete.yaml").read_text(), "seed": 7, "g": None, "q": 6,
            "g_mode": None, "key": key}


def node():
    return AgentNode(2, config(), "r")


def sign(msg_type, run="r", key=KEY, **fields):
    return encode(msg_type, run, mac_key=key, **fields)


ROWS = {"2": [[2, 1, 3], [1 / 3, 1 / 3, 1 / 3]]}


def tick(tau, attempt=0, rows=ROWS, **kw):
    return sign("tick", tau=tau, attempt=attempt, graph=0, final=False, alive=[1, 2, 3], rows=rows,
                incarnation={"2": 0}, **kw)


def z(tau, k, j=1, attempt=0, n=4, run="r", key=KEY, value=0.0):
    return sign("z", run=run, key=key, tau=tau, attempt=attempt, k=k, agent=j, z=np.full(n, value))


def test_z_before_the_first_tick_is_buffered_not_a_crash():
    a = node()
    out = a.on_z("splitspec/r/z/1", z(0, 0))
    assert out == [] and a.rejected == {}
    a.on_z("splitspec/r/z/1", b"\x00\x01")  # garbage before the first tick is counted
    assert a.rejected == {"bad_mac": 1}


def test_round_publishes_q_exchanges_and_the_estimate():
    a = node()
    out = a.on_tick(tick(0))
    assert [k for k, _ in out] == ["splitspec/r/xhat/2", "splitspec/r/z/2"]  # admission, then z(0)
    for k in range(6):
        for j in (1, 3):
            out = a.on_z(f"splitspec/r/z/{j}", z(0, k, j))
    out = a.on_y(sign("y", tau=0, attempt=0, agent=2, y=np.zeros(1)))
    assert [k for k, _ in out] == ["splitspec/r/xhat/2"]
    assert a.candidate[0] == 1


def test_forgeries_without_the_key_change_nothing():
    a = node()
    a.on_tick(tick(0))
    x0 = a.x.copy()
    other = new_run_key()
    # the tick from the far future with empty rows that used to make every agent restart
    assert a.on_tick(encode("tick", "r", mac_key=other, tau=2 ** 62, attempt=0, graph=0, final=False, alive=[],
                            rows={}, incarnation={})) == []
    assert a.on_tick(encode("tick", "r", tau=1, attempt=0, graph=0, final=False, alive=[], rows={},
                            incarnation={})) == []  # unsigned
    assert a.on_y(encode("y", "r", tau=0, attempt=0, agent=2, y=np.array([1e6]))) == []
    assert a.rejected == {"bad_mac": 3} and a.ybuf == {} and np.array_equal(a.x, x0) and a.tick_tag == (0, 0)


@pytest.mark.parametrize("payload,reason", [
    (lambda: z(0, 0, run="other"), "wrong_run"),
    (lambda: z(0, 1, n=5), "bad_shape"),
    (lambda: z(0, 1, value=np.nan), "non_finite"),
    (lambda: z(0, 99), "bad_k"),
    (lambda: z(5, 0), "future"),
    (lambda: z(0, 0, attempt=7), "future"),
    (lambda: sign("z", tau=0, attempt=0, k=0, agent=3, z=np.zeros(4)), "wrong_sender"),
])
def test_signed_but_implausible_z_is_rejected_by_reason(payload, reason):
    a = node()
    a.on_tick(tick(0))
    a.on_z("splitspec/r/z/1", payload())
    assert a.rejected == {reason: 1}


def test_tick_window_and_stale_ticks():
    a = node()
    a.on_tick(tick(0))
    assert a.on_tick(tick(2)) == [] and a.rejected == {"future": 1}  # more than one event time ahead
    assert a.on_tick(tick(0)) == [] and a.rejected == {"future": 1, "stale": 1}
    assert a.on_tick(tick(0, attempt=1)) != []  # a re-run of the same event time is accepted
    assert a.on_tick(tick(1)) != []


def test_buffers_are_bounded_under_a_flood_of_plausible_messages():
    a = node()
    a.on_tick(tick(0))
    for k in range(1000):  # every (tau, attempt, k) slot that is plausible, and more
        a.on_z("splitspec/r/z/1", z(k % 2, k % 6, attempt=k % 3))
        a.on_z("splitspec/r/z/3", z(1, k % 6, j=3, attempt=(k + 1) % 3))
        a.on_y(sign("y", tau=k % 2, attempt=0, agent=2, y=np.zeros(1)))
    assert sum(len(v) for v in a.zbuf.values()) <= a.zbuf_limit == 6 * 6 * 2
    assert len(a.ybuf) <= 2
    assert a.rejected.get("duplicate", 0) > 0


def test_plant_takes_only_signed_ticks_in_order():
    p = PlantNode(config(), "r")
    out = p.on_tick(tick(0))
    assert [k for k, _ in out] == ["splitspec/r/truth", "splitspec/r/y/1", "splitspec/r/y/2", "splitspec/r/y/3"]
    assert p.on_tick(encode("tick", "r", tau=1, attempt=0, graph=0, final=False, alive=[], rows={},
                            incarnation={})) == []
    assert p.on_tick(tick(5)) == [] and p.rejected == {"bad_mac": 1, "future": 1}
