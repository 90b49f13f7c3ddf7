"""Networks that misbehave: the draws, the realized weights, the agent's sub-round rule, and simulate with losses."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import yaml

from splitspec_core.synthesis.designer import design
from splitspec_core.model.impairment import (LATE, LOSS, PARTITION, Impairment, crosses, group_of, realized_row, sub_round,
                                       u_array, u_scalar)
from splitspec_core.scenarios.load import load_scenario, parse_scenario
from splitspec_core.scenarios.specs import NetworkSpec
from splitspec_core.simulation.simulator import simulate
from tests.conftest import EXAMPLES
from tests.numerics import assert_close


def raw(name: str = "ring10", **top) -> dict:
    data = yaml.safe_load((EXAMPLES / f"{name}.yaml").read_text())
    data.update(top)
    return data


# --------------------------------------------------------------------------
# draws
# --------------------------------------------------------------------------


def test_scalar_and_vectorised_draws_are_the_same_numbers():
    """Agents draw one message at a time, the simulator a sub-round at once: the same u, bit for bit (the same
    integer operations modulo 2^64, then one exact conversion)."""
    rng = np.random.default_rng(0)
    for key in (0, 1, 2 ** 63 - 1, int(rng.integers(0, 2 ** 63))):
        for tau in (0, 1, 17, 2 ** 40):
            j, i = rng.integers(1, 10 ** 6, size=50), rng.integers(1, 10 ** 6, size=50)
            got = u_array(key, tau, 3, j, i)
            assert got.tolist() == [u_scalar(key, tau, 3, int(a), int(b)) for a, b in zip(j, i)]
            assert ((got >= 0) & (got < 1)).all()


def test_every_sub_round_at_once_draws_the_same_numbers():
    """The simulator draws an event time's q sub-rounds in one call: the same numbers and causes as one sub-round
    at a time (the same integer operations per element), per-arc overrides included."""
    net = NetworkSpec(loss=0.3, delay_mean=0.002, delay_jitter=0.002, deadline=0.003,
                      arcs={(2, 1): {"loss": 0.9}, (3, 4): {"delay_mean": 0.01}})
    imp = Impairment(net, seed=11)
    js, is_ = np.array([2, 3, 1, 4, 5]), np.array([1, 4, 2, 3, 1])
    for tau in (0, 5, 99):
        ks = np.arange(1, 7)[:, None]
        assert u_array(imp.loss_key, tau, ks, js, is_).tolist() == [
            u_array(imp.loss_key, tau, int(k), js, is_).tolist() for k in range(1, 7)]
        both = imp.dropped(tau, ks, js, is_)
        assert both.shape == (6, 5)
        assert both.tolist() == [imp.dropped(tau, int(k), js, is_).tolist() for k in range(1, 7)]
    arc34 = imp.dropped(0, np.arange(1, 200)[:, None], js, is_)[:, 1]
    assert set(arc34.tolist()) == {LOSS, LATE}  # held 8-12 ms against a 3 ms deadline: it never counts


def test_draws_are_uniform_and_independent_of_the_indices_order():
    j = np.repeat(np.arange(1, 101), 100)
    i = np.tile(np.arange(1, 101), 100)
    u = u_array(12345, 7, 2, j, i)
    # 10,000 draws: mean 0.5 +- 0.003 (sd 0.0029), every decile near 1,000 (sd 30)
    assert abs(u.mean() - 0.5) < 0.012
    assert np.all(np.abs(np.bincount((u * 10).astype(int), minlength=10) - 1000) < 150)
    # (j, i) and (i, j) are different messages; so are two sub-rounds and two event times
    assert u_scalar(5, 1, 1, 2, 3) != u_scalar(5, 1, 1, 3, 2)
    assert u_scalar(5, 1, 1, 2, 3) != u_scalar(5, 1, 2, 2, 3) != u_scalar(5, 2, 1, 2, 3)


def test_loss_rate_and_delays_follow_the_spec():
    net = NetworkSpec(loss=0.2, delay_mean=0.002, delay_jitter=0.001, deadline=0.0025, arcs={(1, 2): {"loss": 0.0}})
    imp = Impairment(net, seed=3)
    lost = [imp.lost(tau, 1, 3, 4) for tau in range(5000)]
    assert 0.18 < np.mean(lost) < 0.22  # 5000 draws: sd 0.006
    assert not any(imp.lost(tau, 1, 1, 2) for tau in range(500))  # the arc's override: never lost
    d = np.array([imp.delay(tau, 1, 3, 4) for tau in range(5000)])
    assert d.min() >= 0.001 - 1e-12 and d.max() <= 0.003 + 1e-12 and abs(d.mean() - 0.002) < 5e-5
    # simulate's emulation: a message is late exactly when its drawn delay exceeds the deadline
    js, is_ = np.full(5000, 3), np.full(5000, 4)
    causes = np.array([imp.dropped(tau, 1, js[:1], is_[:1])[0] for tau in range(5000)])
    lost_a = np.array(lost)
    assert ((causes == LOSS) == lost_a).all()
    assert ((causes == LATE) == (~lost_a & (d > 0.0025))).all()


def test_the_named_stream_fixes_the_draws():
    net = NetworkSpec(loss=0.5)
    a, b, c = Impairment(net, 1), Impairment(net, 1), Impairment(net, 2)
    draws = [[imp.lost(t, 1, 1, 2) for t in range(64)] for imp in (a, b, c)]
    assert draws[0] == draws[1] != draws[2]


# --------------------------------------------------------------------------
# realized weights
# --------------------------------------------------------------------------


def test_realized_rows_are_row_stochastic():
    nbs, ws = (4, 1, 2, 7), (0.25, 0.25, 0.25, 0.25)
    assert realized_row(nbs, ws, {1, 2, 7}, "uniform") == (nbs, ws)  # nothing lost: the row as it was
    got_nbs, got_ws = realized_row(nbs, ws, {2}, "uniform")
    assert got_nbs == (4, 2) and got_ws == (0.5, 0.5)  # row 4 of the realized graph 2 -> 4
    assert realized_row(nbs, ws, set(), "uniform") == ((4,), (1.0,))
    # Metropolis: the missing weight goes to the receiver itself
    m_nbs, m_ws = realized_row((4, 1, 2), (0.5, 0.25, 0.25), {1}, "metropolis")
    assert m_nbs == (4, 1) and m_ws == pytest.approx((0.75, 0.25), abs=0, rel=1e-15)
    for counted in ({1}, {2}, set(), {1, 2}):
        _, w = realized_row((4, 1, 2), (0.5, 0.25, 0.25), counted, "metropolis")
        assert min(w) > 0 and sum(w) == pytest.approx(1.0, rel=1e-15)


def test_partition_groups():
    g = group_of(((1, 2), (5,)), (1, 2, 3, 4, 5))
    assert g == {1: 0, 2: 0, 5: 1, 3: 2, 4: 2}  # the unnamed agents form one more group
    assert crosses(g, 1, 5) and crosses(g, 3, 2) and not crosses(g, 3, 4) and not crosses(g, 1, 2)
    assert group_of(None, (1, 2)) == {} and not crosses({}, 1, 2)


# --------------------------------------------------------------------------
# the agent's rule (one sub-round)
# --------------------------------------------------------------------------


def test_sub_round_waits_then_goes_on_at_the_deadline():
    net = NetworkSpec(deadline=0.02)
    imp = Impairment(net, 0)
    kw = dict(tau=3, k=1, me=2, nbs=(2, 1, 3), ws=(1 / 3,) * 3, groups={}, opened=10.0)
    assert sub_round(imp, "uniform", have={1: 0}, now=10.01, **kw) == ("wait", pytest.approx(10.02))
    go = sub_round(imp, "uniform", have={1: 0}, now=10.02, **kw)
    assert go == ("go", (2, 1), (0.5, 0.5), [(1, 3, LATE)])
    assert sub_round(imp, "uniform", have={1: 0, 3: 0}, now=10.0, **kw) == ("go", (2, 1, 3), (1 / 3,) * 3, [])


def test_sub_round_drawn_losses_and_partitions_are_not_waited_for():
    imp = Impairment(NetworkSpec(loss=0.5), 9)
    groups = group_of(((1, 2),), (1, 2, 3, 4))
    for tau in range(40):
        got = sub_round(imp, "uniform", tau=tau, k=2, me=2, nbs=(2, 1, 3), ws=(1 / 3,) * 3, have={}, groups=groups)
        if imp.lost(tau, 2, 1, 2):  # 1's message is lost and 3 is on the other side: nothing to wait for
            assert got[0] == "go" and got[1:3] == ((2,), (1.0,))
            assert {j: c for _, j, c in got[-1]} == {1: LOSS, 3: PARTITION}
        else:
            assert got == ("wait", None)  # 1's message is due (no deadline): wait for it, never for 3's


def test_sub_round_holds_a_message_for_its_delay():
    imp = Impairment(NetworkSpec(delay_mean=0.005, delay_jitter=0.0, deadline=0.02), 0)
    kw = dict(tau=0, k=1, me=2, nbs=(2, 1), ws=(0.5, 0.5), have={1: 0}, groups={}, opened=0.0, arrived={1: 0.001})
    assert sub_round(imp, "uniform", now=0.002, **kw) == ("wait", pytest.approx(0.006))
    assert sub_round(imp, "uniform", now=0.006, **kw)[:3] == ("go", (2, 1), (0.5, 0.5))
    kw["arrived"] = {1: 0.018}  # released at 0.023, after the deadline at 0.02: late
    assert sub_round(imp, "uniform", now=0.02, **kw) == ("go", (2,), (1.0,), [(1, 1, LATE)])


# --------------------------------------------------------------------------
# simulate
# --------------------------------------------------------------------------


def test_a_perfect_network_section_changes_nothing():
    """network: with no loss is today's estimator: the same operations, so the same trajectory (exact)."""
    base = simulate(design(parse_scenario(raw())))
    same = simulate(design(parse_scenario(raw(network={"loss": 0.0}))))
    assert np.array_equal(base.xhat, same.xhat, equal_nan=True) and same.lost.shape == (0, 4)


@pytest.mark.parametrize("weights,time", [("uniform", "discrete"), ("metropolis", "discrete"),
                                          ("uniform", "continuous")])
def test_batch_equals_the_agents_rule_under_loss(weights, time):
    """The vectorised realized weights equal the agents' realized_row (the per-agent loop), to round-off."""
    if time == "continuous":
        data = raw("paper_continuous", network={"loss": 0.3})
        data["run"] = {**data.get("run", {}), "steps": 300}
    else:
        data = raw(network={"loss": 0.3, "arcs": [{"arc": [1, 6], "loss": 0.9}]})
        if weights == "metropolis":
            data["design"] = {**data["design"], "weights": "metropolis"}
    des = design(parse_scenario(data))
    a, b = simulate(des), simulate(des, estimator="loop")
    assert len(a.lost) > 100 and np.array_equal(a.lost, b.lost) and np.array_equal(a.lost_cause, b.lost_cause)
    assert_close(a.xhat, b.xhat, rtol=1e-12, equal_nan=True, what="xhat")  # other summation orders
    # rows sorted by (tau, k, j, i); every lost message is an arc of the graph
    assert np.array_equal(a.lost, a.lost[np.lexsort(a.lost.T[::-1])])
    arcs = {tuple(x) for g in des.scenario.graphs for x in g.arcs}
    assert all((j, i) in arcs for _, _, j, i in a.lost.tolist())


def test_loss_draws_depend_only_on_the_seed():
    des = design(parse_scenario(raw(network={"loss": 0.2})))
    a, b, c = simulate(des, seed=4), simulate(des, seed=4), simulate(des, seed=5)
    assert np.array_equal(a.lost, b.lost) and not np.array_equal(a.lost, c.lost)
    # about 20% of the messages: 60 event times x 6 sub-rounds x 24 arcs
    assert 0.15 < len(a.lost) / (60 * des.q * 24) < 0.25


def test_a_replay_drops_exactly_the_recorded_messages():
    des = design(parse_scenario(raw(network={"loss": 0.2})))
    tr = simulate(des)
    again = simulate(des, lost=(tr.lost, tr.lost_cause))
    assert np.array_equal(again.lost, tr.lost) and np.array_equal(again.xhat, tr.xhat, equal_nan=True)  # same ops
    fewer = simulate(des, lost=(tr.lost[:10], tr.lost_cause[:10]))  # a different record: a different trajectory
    assert len(fewer.lost) == 10 and not np.allclose(fewer.xhat[1:4], tr.xhat[1:4], equal_nan=True)


def test_partition_splits_and_heals():
    """ring10_partition: the side without x7, x8 stops converging while cut, both sides reconverge after the heal."""
    sc = load_scenario(EXAMPLES / "ring10_partition.yaml")
    tr = simulate(design(sc))
    e = tr.errors()
    side_a = [sc.agent_ids.index(a) for a in (1, 2, 3, 9, 10)]
    side_b = [sc.agent_ids.index(a) for a in (4, 5, 6, 7, 8)]
    assert e[34, side_a].min() > 1e3 * e[34, side_b].max()  # cut: side a cannot see x7, x8
    assert np.ptp(e[20:35, side_a]) < 1e-2 * e[34, side_a].max()  # ... and does not converge (rotations: it stays)
    assert np.nanmax(e[-1]) < 1e-6 * np.nanmax(e[34])  # healed: everyone reconverges
    cut = {(j, i) for _, _, j, i in tr.lost.tolist()}
    assert set(np.unique(tr.lost_cause)) == {PARTITION}
    assert cut == {(3, 4), (4, 3), (8, 9), (9, 8), (1, 6), (6, 1), (3, 8), (8, 3)}
    taus = np.unique(tr.lost[:, 0])
    assert taus.min() == 5 and taus.max() == 34


def test_network_bad_input_is_one_line():
    from splitspec_core.errors import ScenarioError

    cases = [
        ({"network": {"loss": 1.0}}, "network.loss must be in [0, 1)"),
        ({"network": {"loss": -0.1}}, "network.loss must be in [0, 1)"),
        ({"network": {"delay": {"mean": -0.001}}}, "network.delay.mean must be >= 0 seconds"),
        ({"network": {"delay": {"jitter": float("inf")}}}, "network.delay.jitter must be finite"),
        ({"network": {"deadline": 0}}, "network.deadline must be > 0 seconds"),
        ({"network": {"deadline": -1}}, "network.deadline must be > 0 seconds"),
        ({"network": {"arcs": [{"arc": [1, 99], "loss": 0.1}]}}, "network.arcs[1].arc names agent 99"),
        ({"network": {"arcs": [{"arc": [1, 5], "loss": 0.1}]}}, "is not an arc of any graph"),
        ({"network": {"arcs": [{"loss": 0.1}]}}, "network.arcs[1].arc is missing"),
        ({"network": {"los": 0.1}}, "unknown key network.los"),
        ({"faults": [{"at": 3, "heal": True}]}, "the heal at 3 has no partition before it"),
        ({"faults": [{"at": 3, "partition": [[1, 2], [2, 3]]}]}, "do not overlap"),
        ({"faults": [{"at": 3, "partition": [[1, 99]]}]}, "names agent 99"),
        ({"faults": [{"at": 3, "partition": [list(range(1, 11))]}]}, "nothing is cut"),
    ]
    for extra, message in cases:
        with pytest.raises(ScenarioError) as err:
            parse_scenario(raw(**extra))
        assert message in str(err.value) and "\n" not in str(err.value), (extra, str(err.value))


def test_exact_ode_refuses_a_lossy_network():
    from splitspec_core.errors import ScenarioError
    from splitspec_core.simulation.simulator import simulate_exact

    sc = load_scenario(EXAMPLES / "paper_continuous.yaml")
    sc = dataclasses.replace(sc, network=NetworkSpec(loss=0.1))
    with pytest.raises(ScenarioError, match="exact ODE has no messages to lose"):
        simulate_exact(design(sc), steps=5)
