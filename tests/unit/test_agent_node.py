"""The agent's and the plant's protocol state machines, without sockets: what they accept and what not."""

import itertools

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


TOPOLOGIES = itertools.count(1)  # a new network number for every tick that does not name one


def tick(tau, attempt=0, rows=ROWS, fresh=True, prev_attempt=0, topology=None, **kw):
    """A tick with its network (a new ``topology`` number each time, unless given)."""
    return sign("tick", tau=tau, attempt=attempt, graph=0, final=False, alive=[1, 2, 3], rows=rows,
                incarnation={"2": 0}, fresh=fresh, prev_attempt=prev_attempt,
                topology=next(TOPOLOGIES) if topology is None else topology, **{"partition": [], **kw})


def y(tau, attempt=0, value=0.0, key=KEY):
    return encode("y", "r", mac_key=key, tau=tau, attempt=attempt, y=np.full(3, value))  # y_1, y_2, y_3 stacked


def xhat(tau, j, attempt=0, value=0.0, n=4):
    return sign("xhat", tau=tau, attempt=attempt, agent=j, incarnation=0, x=np.full(n, value), g=0.0, rejected={},
                lost=[])


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
    out = a.on_y(y(0))
    assert [k for k, _ in out] == ["splitspec/r/xhat/2"]
    assert a.candidate.tau == 1


def run_round(a, tau, *, z0_from_x: bool):
    """Neighbours 1 and 3 play round tau with agent 2: their z(k) for k >= 1 (and z(0) or their x)."""
    for j in (1, 3):
        if z0_from_x:
            a.on_x(f"splitspec/r/xhat/{j}", xhat(tau, j, value=float(j)))
        else:
            a.on_z(f"splitspec/r/z/{j}", z(tau, 0, j, value=float(j)))
    for k in range(1, 6):
        for j in (1, 3):
            a.on_z(f"splitspec/r/z/{j}", z(tau, k, j))
    return a.on_y(y(tau))


def test_a_steady_round_takes_z0_from_the_neighbours_estimates_and_sends_no_z0():
    """x_j(tau) published in round tau - 1 is z_j(0) of round tau (eq. split-discrete-p1): bit for bit the
    same round as with explicit z(0) messages, one publish fewer per agent."""
    a, b = node(), node()
    for n in (a, b):
        n.on_tick(tick(0))
        run_round(n, 0, z0_from_x=False)
    explicit = b.on_tick(tick(1, fresh=True))
    steady = a.on_tick(tick(1, fresh=False, prev_attempt=0))
    assert [k for k, _ in explicit] == ["splitspec/r/z/2"] and steady == []  # no z(0) in a steady round
    run_round(b, 1, z0_from_x=False)
    run_round(a, 1, z0_from_x=True)
    # exact: the same step functions on the same float64 values (z_j(0) from x_j's message or from z_j's: the
    # same bytes decoded), in the same order
    assert a.candidate.tau == b.candidate.tau == 2 and np.array_equal(a.candidate.x, b.candidate.x)


def test_a_neighbour_a_round_ahead_is_kept_with_one_exchange():
    """q = 1: round tau + 1 needs nothing new from agent 2 (z_2(0) is x_2(tau + 1), already sent), so a neighbour
    may finish it, x_j(tau + 2), before agent 2 has read tick tau + 1; rejecting that as "future" stalled the
    run until the round timeout (measured: 10 s at tau 203 of a continuous run on measurements)."""
    a = AgentNode(2, {**config(), "q": 1}, "r")
    a.on_tick(tick(0))
    for j in (1, 3):
        a.on_z(f"splitspec/r/z/{j}", z(0, 0, j, value=float(j)))
    a.on_y(y(0))
    for j in (1, 3):
        a.on_x(f"splitspec/r/xhat/{j}", xhat(1, j, value=float(j)))  # their x_j(1): round 1's z_j(0)
        a.on_x(f"splitspec/r/xhat/{j}", xhat(2, j, value=float(j)))  # round 1 done before our tick 1
    a.on_x("splitspec/r/xhat/1", xhat(3, 1))  # two rounds ahead: nobody honest is there
    assert a.rejected == {"future": 1} and a.tick_tag == (0, 0)
    a.on_tick(tick(1, fresh=False, prev_attempt=0))
    assert [k for k, _ in a.on_y(y(1))] == ["splitspec/r/xhat/2"]
    a.on_tick(tick(2, fresh=False, prev_attempt=0))  # z_j(0) = x_j(2), kept above: no new message needed
    assert [k for k, _ in a.on_y(y(2))] == ["splitspec/r/xhat/2"] and a.candidate.tau == 3


def test_estimates_of_an_aborted_attempt_are_not_taken_as_z0():
    a = node()
    a.on_tick(tick(0))
    run_round(a, 0, z0_from_x=False)
    # the kept attempt's estimate arrives first, the aborted one last: arrival order cannot decide
    a.on_x("splitspec/r/xhat/1", xhat(1, 1, attempt=1, value=1.0))  # round 0, attempt 1: the one kept
    a.on_x("splitspec/r/xhat/3", xhat(1, 3, attempt=1, value=3.0))
    a.on_x("splitspec/r/xhat/1", xhat(1, 1, attempt=0, value=9.0))  # round 0, attempt 0: re-run later
    a.on_tick(tick(1, fresh=False, prev_attempt=1))
    # rows [2, 1, 3]: agent 1's z(0) is its attempt-1 estimate (1.0 exactly: the value sent, decoded)
    assert a._neighbour_states(0)[2][1][0] == 1.0


def test_a_rerun_round_sends_z0_again():
    a = node()
    a.on_tick(tick(0))
    run_round(a, 0, z0_from_x=False)
    a.on_tick(tick(1, fresh=False))
    out = a.on_tick(tick(1, attempt=1, fresh=False))
    assert [k for k, _ in out] == ["splitspec/r/z/2"]


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
    assert a.on_y(encode("y", "r", tau=0, attempt=0, y=np.full(3, 1e6))) == []
    # exact: the estimate was not touched (x0 is its copy)
    assert a.rejected == {"bad_mac": 3} and a.ys.buf == {} and np.array_equal(a.x, x0) and a.tick_tag == (0, 0)


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
        a.on_y(y(k % 2))
        a.on_x("splitspec/r/xhat/1", xhat(k % 2, 1, attempt=k % 3))
    assert sum(len(v) for v in a.zbuf.values()) <= a.zbuf_limit == 6 * 6 * 2
    assert sum(len(v) for v in a.xbuf.values()) <= a.zbuf_limit
    assert len(a.ys.buf) <= 2
    assert a.rejected.get("duplicate", 0) > 0


def test_plant_takes_only_signed_ticks_in_order():
    p = PlantNode(config(), "r")
    out = p.on_tick(tick(0))
    assert [k for k, _ in out] == ["splitspec/r/truth", "splitspec/r/y/all"]  # one y message for every agent
    assert p.on_tick(encode("tick", "r", tau=1, attempt=0, graph=0, final=False, alive=[], rows={},
                            incarnation={}, fresh=False, prev_attempt=0, partition=[])) == []
    assert p.on_tick(tick(5)) == [] and p.rejected == {"bad_mac": 1, "future": 1}


def lossy_node(network: dict):
    import yaml

    from splitspec_core.runtime.wire import decode

    raw = yaml.safe_load((EXAMPLES / "paper_discrete.yaml").read_text())
    raw["network"] = network
    cfg = {**config(), "scenario": yaml.safe_dump(raw)}
    a = AgentNode(2, cfg, "r")
    now = [100.0]
    a.clock = lambda: now[0]  # the node reads no other clock
    return a, now, lambda payload: decode(payload, "r", "xhat", mac_key=KEY)


def test_a_sub_round_goes_on_without_a_late_neighbour_at_the_deadline():
    """Deadline 20 ms: agent 3's z never comes; at the deadline agent 2 averages with agent 1 alone (1/2, 1/2),
    and its estimate reports (k, 3, late) for every sub-round."""
    a, now, xhat_of = lossy_node({"deadline": 0.02})
    a.on_tick(tick(0))
    out = a.on_z("splitspec/r/z/1", z(0, 0, j=1, value=1.0))
    assert out == [] and a.next_wakeup() == pytest.approx(100.02)  # waits for agent 3 until the deadline
    now[0] = 100.019
    assert a.on_timer() == [] and a.round.k == 0
    for k in range(6):
        now[0] += 0.02  # each sub-round's deadline passes (they open one after the other)
        out = a.on_timer()
        assert a.round is None or a.round.k == k + 1
        if k < 5:
            a.on_z("splitspec/r/z/1", z(0, k + 1, j=1, value=1.0))
    out = a.on_y(y(0))
    (key, payload), = [o for o in out if "xhat" in o[0]]
    lost = xhat_of(payload)["lost"]
    assert lost == [v for k in range(1, 7) for v in (k, 3, 1)]  # (k, j = 3, late) for k = 1..6


def test_drawn_losses_are_not_waited_for_and_are_reported():
    from splitspec_core.model.impairment import Impairment
    from splitspec_core.scenarios.specs import NetworkSpec

    a, now, xhat_of = lossy_node({"loss": 0.5})
    imp = Impairment(NetworkSpec(loss=0.5), 7)  # the scenario's seed
    a.on_tick(tick(0))
    for k in range(6):
        for j in (1, 3):
            if not imp.lost(0, k + 1, j, 2):
                a.on_z(f"splitspec/r/z/{j}", z(0, k, j=j, value=float(j)))
    out = a.on_y(y(0))
    (_, payload), = [o for o in out if "xhat" in o[0]]  # no deadline, yet it never waited for a lost message
    lost = xhat_of(payload)["lost"]
    expected = [(k, j, 0) for k in range(1, 7) for j in (1, 3) if imp.lost(0, k, j, 2)]
    assert expected and list(zip(lost[0::3], lost[1::3], lost[2::3])) == expected


def test_on_time_a_deadline_changes_nothing():
    """Every message in time: a node with a deadline (and no loss or delay) publishes exactly what a node on a
    perfect network publishes (the same operations in the same order: exact), loses nothing and wants no timer
    once the event time is done; a message arriving past the deadline is the only thing it would drop."""
    from splitspec_core.runtime.wire import decode

    plain = node()
    timed, now, xhat_of = lossy_node({"deadline": 0.02})
    outs = []
    for a in (plain, timed):
        a.on_tick(tick(0))
        got = []
        for k in range(6):
            got += a.on_z("splitspec/r/z/1", z(0, k, j=1, value=1.0 + k))
            got += a.on_z("splitspec/r/z/3", z(0, k, j=3, value=-2.0 + k))
            now[0] += 0.001  # well within each sub-round's deadline
        got += a.on_y(y(0))
        outs.append([decode(p, "r", "xhat", mac_key=KEY) for key, p in got if "xhat" in key])
    assert len(outs[0]) == len(outs[1]) == 1
    assert np.array_equal(outs[0][0]["x"], outs[1][0]["x"])
    assert outs[1][0]["lost"] == [] and timed.next_wakeup() is None


def one_round(a, y_msg):
    """A full round 0 of agent 2 (neighbours' z all 1.0), then its y message: what it publishes last."""
    from splitspec_core.runtime.wire import decode

    a.on_tick(tick(0))
    for k in range(6):
        a.on_z("splitspec/r/z/1", z(0, k, j=1, value=1.0))
        a.on_z("splitspec/r/z/3", z(0, k, j=3, value=1.0))
    out = a.on_y(y_msg)
    (_, payload), = [o for o in out if "xhat" in o[0]]
    return decode(payload, "r", "xhat", mac_key=KEY)


def test_without_a_measurement_the_agent_predicts_and_says_so():
    """The plant's y names agent 2 missing: x_2(1) = A z_2(q) (steps.prediction_update), not the update with
    y_2; with record_y the agent reports the y_i it used (None: none), else [] (not recorded)."""
    from splitspec_core.model import steps as st

    measured = one_round(AgentNode(2, {**config(), "record_y": True}, "r"), y(0, value=0.5))
    a = AgentNode(2, {**config(), "record_y": True}, "r")
    blind = one_round(a, encode("y", "r", mac_key=KEY, tau=0, attempt=0, y=np.full(3, 0.5), missing=[2]))
    b = AgentNode(2, config(), "r")
    b_out = one_round(b, y(0, value=0.5))
    assert measured["y"] == [0.5] and blind["y"] is None and b_out["y"] == []
    # the same z_2(q) both ways (the consensus does not depend on y): the two updates of that z
    z_q = np.linalg.solve(a.F, measured["x"] + a.K @ np.array([0.5]))  # from x = F z - K y
    assert np.allclose(blind["x"], st.prediction_update(z_q, a.A), rtol=1e-12, atol=1e-12)
    assert not np.allclose(blind["x"], measured["x"])
    assert np.array_equal(b_out["x"], measured["x"])  # record_y changes what is reported, not the estimate


def test_the_plant_plays_the_file_the_orchestrator_was_given(tmp_path):
    from splitspec_core.errors import SplitspecError
    from splitspec_core.scenarios.measurements import load_measurements, write_measurements
    from splitspec_core.runtime.wire import decode
    from splitspec_core.scenarios.load import load_scenario

    sc = load_scenario(EXAMPLES / "paper_discrete.yaml")
    t = np.arange(4.0)
    yy = np.arange(12.0).reshape(4, 3)
    miss = np.zeros((4, 3), dtype=bool)
    miss[1, 2] = True
    write_measurements(tmp_path / "m.csv", t=t, y=yy, agent_ids=sc.agent_ids, sizes=[1, 1, 1], missing=miss)
    write_measurements(tmp_path / "other.csv", t=t, y=yy + 1, agent_ids=sc.agent_ids, sizes=[1, 1, 1])
    meas = load_measurements(tmp_path / "m.csv", sc)
    cfg = {**config(), "measurements": {"sha256": meas.sha256, "steps": 3, "truth": False}}
    p = PlantNode(cfg, "r", measurements=str(tmp_path / "m.csv"))
    p.on_tick(tick(0))
    out = p.on_tick(tick(1))
    truth, ymsg = (decode(pl, "r", kind, mac_key=KEY) for (_, pl), kind in zip(out, ("truth", "y")))
    assert truth["x"].shape == (0,)  # no truth in the file: an empty x
    assert ymsg["y"].tolist() == [3.0, 4.0, 0.0] and ymsg["missing"] == [3]  # row 1; agent 3 missing there
    with pytest.raises(SplitspecError, match="is not the file the orchestrator plays"):
        PlantNode(cfg, "r", measurements=str(tmp_path / "other.csv"))
    with pytest.raises(SplitspecError, match="start the plant with --measurements FILE"):
        PlantNode(cfg, "r")
    with pytest.raises(SplitspecError, match="this run simulates its plant"):
        PlantNode(config(), "r", measurements=str(tmp_path / "m.csv"))


def test_a_live_sensor_is_sampled_at_the_tick_and_equals_the_plants_y():
    """With a LiveSampler (scenario sources:) the round needs no y message: the value the sampler holds at the
    tick is y_i(tau), the same update as the plant's y of that value (bit for bit); a value older than max_age
    is no measurement (prediction only, reported as None)."""
    import json

    from splitspec_agents.sensor import LiveSampler
    from splitspec_core.runtime.wire import decode

    def live_round(age):
        clock = [10.0]
        a = AgentNode(2, {**config(), "record_y": True}, "r")
        a.sampler = LiveSampler(1, 0.25, clock=lambda: clock[0])
        a.sampler.offer(json.dumps({"y": [0.5]}).encode())
        clock[0] += age
        out = a.on_tick(tick(0))
        for k in range(6):
            out += a.on_z("splitspec/r/z/1", z(0, k, j=1, value=1.0))
            out += a.on_z("splitspec/r/z/3", z(0, k, j=3, value=1.0))
        (_, payload), = [o for o in out if "xhat" in o[0] and decode(o[1], "r", "xhat", mac_key=KEY)["tau"] == 1]
        return decode(payload, "r", "xhat", mac_key=KEY)

    plant = one_round(AgentNode(2, {**config(), "record_y": True}, "r"), y(0, value=0.5))
    fresh, stale = live_round(0.25), live_round(0.5)
    assert fresh["y"] == [0.5] and np.array_equal(fresh["x"], plant["x"])
    assert stale["y"] is None and not np.allclose(stale["x"], plant["x"])


def test_a_neighbours_report_one_tick_ahead_is_kept():
    """Without a plant to wait for, a neighbour can finish round tau + 1 before our tick of tau + 1 arrives: its
    x_j(tau + 2) is the next round's z_j(0) and is kept; further ahead is still refused."""
    a = node()
    a.on_tick(tick(0))
    assert a.on_x("splitspec/r/xhat/1", xhat(2, 1)) == [] and a.rejected == {}
    assert (2, 0) in a.xbuf and 1 in a.xbuf[(2, 0)]
    a.on_x("splitspec/r/xhat/1", xhat(3, 1))
    assert a.rejected == {"future": 1}


def compact_tick(tau, topology, attempt=0, fresh=False, prev_attempt=0):
    """A tick without its network (the orchestrator's tick when the network did not change: runtime.ticks)."""
    return sign("tick", tau=tau, attempt=attempt, graph=0, final=False, fresh=fresh, prev_attempt=prev_attempt,
                topology=topology)


def test_a_tick_without_a_network_runs_on_the_last_one():
    """The network rides only on the ticks where it changed: a tick without one takes the last one received,
    and the round is the one a tick with the same network would have given, bit for bit (the same math on the
    same numbers)."""
    a, b = node(), node()
    for n in (a, b):
        n.on_tick(tick(0, topology=7))
        run_round(n, 0, z0_from_x=False)
    full = a.on_tick(tick(1, fresh=False, topology=7))
    compact = b.on_tick(compact_tick(1, topology=7))
    assert full == compact == []  # a steady round: nothing to send before the neighbours' z(1)
    assert b.round.nbs == [2, 1, 3] and "unknown_topology" not in b.rejected
    outs = [run_round(n, 1, z0_from_x=True) for n in (a, b)]
    assert outs[0] == outs[1] and any("xhat/2" in k for k, _ in outs[1])


def test_a_tick_naming_a_network_never_received_leaves_the_agent_out():
    a = node()
    a.on_tick(tick(0, topology=3))
    run_round(a, 0, z0_from_x=False)
    x = a.candidate.x.copy()
    assert a.on_tick(compact_tick(1, topology=4)) == []
    assert a.rejected["unknown_topology"] == 1 and a.round is None
    # x_i(1) was not committed (the agent took no part in round 1), and the estimate it had was kept
    assert a.candidate is None and a.x is not None and not np.array_equal(a.x, x)
    out = a.on_tick(tick(2, topology=4, fresh=True))  # the network comes with the next tick: back in the rounds
    assert a.round is not None and [k for k, _ in out] == ["splitspec/r/xhat/2", "splitspec/r/z/2"]
