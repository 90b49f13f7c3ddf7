"""The agent's protocol state machine, without sockets."""

import numpy as np

from agents.agent import AgentNode
from splitspec_core.wire import encode
from tests.conftest import EXAMPLES


def node():
    cfg = {"scenario": (EXAMPLES / "paper_discrete.yaml").read_text(), "seed": 7, "g": None, "q": 6,
           "g_mode": None}
    return AgentNode(2, cfg, "r")


def test_z_before_the_first_tick_is_buffered_not_a_crash():
    a = node()
    out = a.on_z("splitspec/r/z/1", encode("z", "r", tau=0, attempt=0, k=0, agent=1, z=np.ones(4)))
    assert out == [] and a.rejected == {}
    # garbage before the first tick is counted
    a.on_z("splitspec/r/z/1", b"\x00\x01")
    assert a.rejected == {"garbage": 1}


def test_round_publishes_q_exchanges_and_the_estimate():
    a = node()
    rows = {"2": [[2, 1, 3], [1 / 3, 1 / 3, 1 / 3]]}
    out = a.on_tick(encode("tick", "r", tau=0, attempt=0, graph=0, final=False, alive=[1, 2, 3], rows=rows,
                           incarnation={"2": 0}))
    assert [k for k, _ in out] == ["splitspec/r/xhat/2", "splitspec/r/z/2"]  # admission, then z(0)
    for k in range(6):
        for j in (1, 3):
            out = a.on_z(f"splitspec/r/z/{j}", encode("z", "r", tau=0, attempt=0, k=k, agent=j, z=np.zeros(4)))
    out = a.on_y(encode("y", "r", tau=0, attempt=0, agent=2, y=np.zeros(1)))
    assert [k for k, _ in out] == ["splitspec/r/xhat/2"]
    assert a.candidate[0] == 1
