"""The fault kinds' registry (splitspec_core/scenarios/faults.py): parsing, ``for:``, refusals, events read back,
and each kind's effect where the simulator, the runtime, the replay and the timeline ask for it."""

import dataclasses

import numpy as np
import pytest

import splitspec_core as ss
from splitspec_core.errors import ScenarioError
from splitspec_core.model.network import NetworkState
from splitspec_core.scenarios import faults as fk
from splitspec_core.scenarios.load import load_scenario
from splitspec_core.scenarios.replay import faults_from_events
from tests.conftest import EXAMPLES

IDS = tuple(range(1, 11))  # ring10's agents


@pytest.fixture(scope="module")
def ring():
    return load_scenario(EXAMPLES / "ring10.yaml")


def parse(raw, ids=IDS, outputs=None):
    return fk.parse_faults(raw, ids, outputs=outputs)


# one entry of every registered kind (the test of a new kind adds its own line here)
EXAMPLE = {"kill": {"kill": 3}, "restart": {"restart": 3}, "freeze": {"freeze": 3},
           "drop_arc": {"drop_arc": [1, 2]}, "restore_arc": {"restore_arc": [1, 2]},
           "partition": {"partition": [[1, 2, 3]]}, "heal": {"heal": True},
           "corrupt": {"corrupt": 3, "bias": [0.5], "scale": 2.0}, "repair": {"repair": 3},
           "kill_orchestrator": {"kill": "orchestrator"}}


def test_every_registered_kind_has_an_example_here():
    assert set(EXAMPLE) == set(fk.KINDS)
    assert all(cls.ends_with in fk.KINDS for cls in fk.KINDS.values() if cls.ends_with is not None)


def test_a_kind_the_runtime_could_not_dispatch_is_refused_at_registration():
    """No event (nothing to log or replay), or an agent-less kind the runtime would signal: refused when declared,
    never a TypeError in the middle of a run."""
    @dataclasses.dataclass(frozen=True)
    class Silent(fk.Fault):
        action = "silent"

    with pytest.raises(ValueError, match="fault kind Silent needs an event"):
        fk.register(Silent)

    @dataclasses.dataclass(frozen=True)
    class Zap(fk.Fault):
        action, runtime, event = "zap", fk.SIGNAL, "zapped"

    with pytest.raises(ValueError, match="fault kind Zap needs an event, and an agent when the runtime signals"):
        fk.register(Zap)

    @dataclasses.dataclass(frozen=True)
    class Odd(fk.Fault):
        action, runtime, event = "odd", "teleport", "odd"

    with pytest.raises(ValueError, match="runtime 'teleport' is none of signal, restart, network, plant"):
        fk.register(Odd)
    assert not {"silent", "zap", "odd"} & set(fk.KINDS)
    assert fk.FAULT_ACTIONS == tuple(fk.KINDS) and fk.FAULT_ALIASES == {"hang": "freeze"}


@pytest.mark.parametrize("action", list(EXAMPLE))
def test_each_kind_parses_to_its_class_and_its_event_reads_back(ring, action):
    """Parsed, logged (its payload under its event word) and read back by a replay: the same fault again."""
    raw = ([{"at": 1, "partition": [[1, 2, 3]]}] if action == "heal" else []) + [{"at": 4, **EXAMPLE[action]}]
    f = parse(raw)[-1]
    assert type(f) is fk.KINDS[action] and f.action == action and f.at == 4.0
    assert f.runtime in (fk.SIGNAL, fk.RESTART, fk.NETWORK, fk.PLANT, fk.ORCHESTRATOR) and f.event is not None
    event = {"event": f.event, **f.payload(4)}
    if f.runtime in (fk.SIGNAL, fk.RESTART):  # the runtime logs agent_lost / agent_rejoined itself
        event = {"event": f.event, "id": f.agent, "tau": 4}
    (back,) = faults_from_events([event], ring)
    # kill and freeze both log agent_lost: a replay reads a loss as a kill (the simulator treats them alike)
    want = dataclasses.replace(f) if action != "freeze" else fk.make_fault("kill", 4, agent=3)
    assert back == want


def test_for_expands_into_the_end_of_each_kind_with_an_end():
    got = parse([{"at": 2, "kill": 3, "for": 5}, {"at": 3, "drop_arc": [1, 2], "for": 1.5},
                 {"at": 1, "partition": [[1, 2]], "for": 2}, {"at": 4, "hang": 7, "for": 1}])
    # sorted by time, ties in the order written (each end right after its fault): the drop at 3 before the heal
    assert got == (fk.make_fault("partition", 1, groups=((1, 2),)), fk.make_fault("kill", 2, agent=3),
                   fk.make_fault("drop_arc", 3, arc=(1, 2)), fk.make_fault("heal", 3),
                   fk.make_fault("freeze", 4, agent=7), fk.make_fault("restore_arc", 4.5, arc=(1, 2)),
                   fk.make_fault("restart", 5, agent=7), fk.make_fault("restart", 7, agent=3))


def test_for_in_the_simulator_is_the_pair_of_faults(ring):
    """``for: 4`` is exactly the kill and the restart written out: the same operations in the same order."""
    a = ss.simulate(ring, faults=[{"at": 5, "kill": 3, "for": 4}])
    b = ss.simulate(ring, faults=[{"at": 5, "kill": 3}, {"at": 9, "restart": 3}])
    np.testing.assert_array_equal(a.alive, b.alive)
    np.testing.assert_array_equal(a.xhat, b.xhat)
    k = IDS.index(3)
    assert not a.alive[5:9, k].any() and a.alive[9:, k].all() and a.alive[:5, k].all()


@pytest.mark.parametrize("raw, words", [
    ([{"at": 1, "explode": 3}], ["unknown key faults[1].explode", "kill, restart, freeze"]),
    ([{"at": 1}], ["faults[1] needs exactly one of kill, restart, freeze, drop_arc"]),
    ([{"at": 1, "kill": 3, "freeze": 4}], ["faults[1] needs exactly one of"]),
    ([{"at": 1, "restart": 3, "for": 2}], ["faults[1].for: a restart has no end", "kill, freeze, drop_arc"]),
    ([{"at": 1, "heal": True, "for": 2}], ["faults[1].for: a heal has no end"]),
    ([{"at": 1, "kill": 3, "for": 0}], ["faults[1].for must be > 0", "restart"]),
    ([{"at": 1, "kill": 3, "for": "long"}], ["faults[1].for must be a number"]),
    ([{"at": 1, "kill": 11}], ["faults[1].kill names agent 11"]),
    ([{"at": 1, "heal": True}], ["the heal at 1 has no partition before it"]),
    ([{"at": 1, "partition": [[1, 2]], "for": 3}, {"at": 2, "heal": True}], ["the heal at 4 has no partition"]),
])
def test_bad_faults_are_one_line_naming_the_key(raw, words):
    with pytest.raises(ScenarioError) as e:
        parse(raw)
    msg = str(e.value)
    assert "\n" not in msg and all(w in msg for w in words), msg


def test_an_action_nobody_registered_cannot_be_built():
    with pytest.raises(ScenarioError, match=r"unknown fault action 'explode' \(the kinds: kill, restart"):
        fk.make_fault("explode", 1.0, agent=3)
    with pytest.raises(ScenarioError, match="fault kind Fault is not registered"):
        fk.Fault(at=1.0)

    @dataclasses.dataclass(frozen=True)
    class Unregistered(fk.Fault):
        action = "unregistered"

    with pytest.raises(ScenarioError, match="fault kind Unregistered is not registered"):
        Unregistered(at=1.0)


def test_a_recorded_event_with_a_bad_target_is_one_line(ring):
    with pytest.raises(ScenarioError, match=r"event 1 \(agent_lost\) names agent 42, which is not in the scenario"):
        faults_from_events([{"event": "agent_lost", "id": 42, "tau": 3}], ring, source="e")
    with pytest.raises(ScenarioError, match=r"event 1 \(partition\) has bad 'groups'"):
        faults_from_events([{"event": "partition", "groups": [[42]], "tau": 3}], ring, source="e")


def test_the_network_state_applies_each_kind(ring):
    net = NetworkState(ring)
    (kill, drop, part, restart, heal, restore) = parse(
        [{"at": 1, "kill": 3}, {"at": 2, "drop_arc": [1, 2]}, {"at": 3, "partition": [[1, 2]]},
         {"at": 4, "restart": 3}, {"at": 5, "heal": True}, {"at": 6, "restore_arc": [1, 2]}])
    assert net.apply([kill]) == ([2], []) and net.apply([kill]) == ([], [])  # a second kill: nobody more
    assert net.apply([drop]) == ([], []) and net.dropped == {(1, 2)}
    net.apply([part])
    assert net.groups == ((1, 2),)
    assert net.apply([restart]) == ([], [(2, 1)])  # position 2, incarnation 1
    net.apply([heal, restore])
    assert net.groups is None and net.dropped == set() and net.alive.all()
    y = np.arange(10.0)
    assert net.measured(y, [slice(k, k + 1) for k in range(10)]) is y  # no sensor fault: y itself


def test_timeline_marks_and_texts_come_from_the_kinds():
    from splitspec_orchestrator.viewer import blueprint as bp
    from splitspec_orchestrator.records.events import event_text

    for cls in fk.KINDS.values():
        if cls.mark is not None:
            assert bp.MARK_OF_EVENT[cls.event] == cls.mark and cls.mark in bp.MARK_KINDS
    assert event_text("arc_dropped", {"arc": [1, 6], "tau": 15}) == "arc 1 -> 6 dropped"
    assert event_text("healed", {"tau": 3}) == "partition healed"


# ------------------------------------------------------------------------------------------------ corrupt


def test_corrupt_parses_bias_per_output_and_scale():
    (c, r) = parse([{"at": 2, "corrupt": 3, "for": 1.5, "bias": [0.5, -1]}], outputs={3: 2})
    assert (c.agent, c.bias, c.scale, type(r), r.agent, r.at) == (3, (0.5, -1.0), None, fk.KINDS["repair"], 3, 3.5)
    (c,) = parse([{"at": 2, "corrupt": 3, "scale": 0}])
    assert (c.bias, c.scale) == (None, 0.0) and c.runtime == fk.PLANT


@pytest.mark.parametrize("raw, outputs, words", [
    ([{"at": 1, "corrupt": 3}], None, ["faults[1].corrupt needs bias: b", "scale: k"]),
    ([{"at": 1, "corrupt": 3, "bias": [1, 2]}], {3: 1}, ["faults[1].bias has 2 values; the agent has 1 output"]),
    ([{"at": 1, "corrupt": 3, "bias": "big"}], None, ["faults[1].bias must be a number"]),
    ([{"at": 1, "corrupt": 3, "scale": [2]}], None, ["faults[1].scale must be a number"]),
    ([{"at": 1, "kill": 3, "bias": 1}], None, ["faults[1].bias does not go with kill"]),
    ([{"at": 1, "corrupt": 12, "bias": 1}], None, ["faults[1].corrupt names agent 12"]),
    ([{"at": 1, "repair": 3, "for": 1}], None, ["faults[1].for: a repair has no end"]),
])
def test_bad_corrupt_faults_are_one_line(raw, outputs, words):
    with pytest.raises(ScenarioError) as e:
        parse(raw, outputs=outputs)
    msg = str(e.value)
    assert "\n" not in msg and all(w in msg for w in words), msg


def test_corrupt_changes_exactly_the_agents_measurements_in_its_window(ring):
    """Agent 2 is given y_2 + 0.5 during [10, 16) and nothing else changes in y; its error grows there, then
    decays again once the sensor is repaired."""
    clean = ss.simulate(ring, keep_y=True)
    hit = ss.simulate(ring, keep_y=True, faults=[{"at": 10, "corrupt": 2, "for": 6, "bias": 0.5}])
    # the plant does not depend on the estimates: the same x and noise, and the corrupted row is y + 0.5, the
    # same operation the simulator runs (exact)
    np.testing.assert_array_equal(hit.x, clean.x)
    rows = np.zeros(clean.y.shape[1], dtype=bool)
    rows[IDS.index(2)] = True  # ring10: one output per agent, in agent order
    np.testing.assert_array_equal(hit.y[10:16, rows], clean.y[10:16, rows] + 0.5)
    np.testing.assert_array_equal(hit.y[:10], clean.y[:10])
    np.testing.assert_array_equal(hit.y[16:], clean.y[16:])
    np.testing.assert_array_equal(hit.y[:, ~rows], clean.y[:, ~rows])
    e_hit, e_clean = hit.errors()[:, IDS.index(2)], clean.errors()[:, IDS.index(2)]
    np.testing.assert_array_equal(e_hit[:11], e_clean[:11])  # the estimates use y(10) from step 11 on
    assert e_hit[16] > 10 * e_clean[16] and e_hit[16] > e_hit[10]
    assert e_hit[-1] < 1e-3 * e_hit[16]  # repaired: it converges again


def test_corrupt_scale_in_the_batched_monte_carlo_equals_the_loop(ring):
    faults = [{"at": 5, "corrupt": 4, "for": 8, "scale": 1.5, "bias": -0.2}, {"at": 9, "kill": 7}]
    batch = ss.simulate(ring, seeds=[1, 2, 3], faults=faults)
    loop = [ss.simulate(ring, seed=s, faults=faults) for s in (1, 2, 3)]
    assert batch.batched
    # round-off: the batch sums its products in another order (montecarlo.py)
    np.testing.assert_allclose(batch.sq_error, [np.nansum(tr.errors() ** 2, axis=1) for tr in loop], rtol=1e-9,
                               atol=1e-12)


def test_the_exact_ode_refuses_a_sensor_fault():
    sc = load_scenario(EXAMPLES / "paper_continuous.yaml")
    with pytest.raises(ScenarioError, match="the exact ODE measures every output exactly: it cannot model corrupt"):
        ss.simulate(sc, exact=True, faults=[{"at": 0.1, "corrupt": 1, "bias": 1.0}])


def test_corrupt_marks_the_timeline_and_the_plots(ring):
    from splitspec_orchestrator.viewer import blueprint as bp
    from splitspec_orchestrator.records.events import event_text
    from splitspec_core.simulation.metrics import event_marks

    assert bp.MARK_OF_EVENT["sensor_corrupted"] == bp.MARK_OF_EVENT["sensor_repaired"] == "sensor"
    assert bp.MARK_KINDS["sensor"][0] == "sensor fault"
    assert event_text("sensor_corrupted", {"id": 2, "tau": 10, "bias": 0.5}) == \
        "agent 2's measurements corrupted (bias 0.5)"
    faults = parse([{"at": 10, "corrupt": 2, "for": 6, "bias": 0.5}])
    tr = ss.simulate(ring, faults=[{"at": 10, "corrupt": 2, "for": 6, "bias": 0.5}])
    marks = event_marks(tr.t, tr.alive, tr.graph, agent_ids=tr.agent_ids, faults=faults)
    assert [(m.step, m.kind, m.label) for m in marks] == [(10, "fault", "sensor 2 corrupted"),
                                                          (16, "fault", "sensor 2 repaired")]


def test_the_exact_ode_refuses_known_inputs():
    """It integrates x' = A x without B u: a scenario with inputs is refused in one line, not simulated wrong."""
    from splitspec_core.scenarios.load import load_yaml, parse_scenario

    raw = load_yaml((EXAMPLES / "paper_continuous.yaml").read_text())
    n = len(raw["system"]["A"])
    raw["system"].update(B=[[1.0]] + [[0.0]] * (n - 1), u=[0.5])
    sc = parse_scenario(raw)
    assert np.isfinite(ss.simulate(sc, steps=5).xhat).all()  # the scenario itself is fine without exact
    with pytest.raises(ScenarioError, match="^the exact ODE has no known input: it cannot model system.B"):
        ss.simulate(sc, exact=True)


# ------------------------------------------------------------------------------------- stuck and noisy sensors


def test_corrupt_parses_stuck_and_noise_and_what_combines():
    (c,) = parse([{"at": 2, "corrupt": 3, "stuck": True}])
    assert (c.stuck, c.bias, c.scale, c.noise, c.holds_last) == (True, None, None, None, True)
    (c,) = parse([{"at": 2, "corrupt": 3, "stuck": True, "noise": [0.1, 0]}], outputs={3: 2})
    assert (c.stuck, c.noise) == (True, (0.1, 0.0))
    (c,) = parse([{"at": 2, "corrupt": 3, "noise": 0.3, "bias": 1, "scale": 2}])
    assert (c.stuck, c.noise, c.bias, c.scale, c.holds_last) == (False, 0.3, 1.0, 2.0, False)


@pytest.mark.parametrize("raw, outputs, words", [
    ([{"at": 1, "corrupt": 3, "stuck": False}], None, ["faults[1].stuck must be true", "got the boolean False"]),
    ([{"at": 1, "corrupt": 3, "stuck": 1}], None, ["faults[1].stuck must be true"]),
    ([{"at": 1, "corrupt": 3, "stuck": True, "bias": 1}], None, ["faults[1].stuck does not go with bias or scale"]),
    ([{"at": 1, "corrupt": 3, "stuck": True, "scale": 2}], None, ["faults[1].stuck does not go with bias or scale"]),
    ([{"at": 1, "corrupt": 3, "noise": -1}], None, ["faults[1].noise must be a std > 0"]),
    ([{"at": 1, "corrupt": 3, "noise": 0}], None, ["faults[1].noise must be a std > 0"]),
    ([{"at": 1, "corrupt": 3, "noise": [0, 0]}], {3: 2}, ["faults[1].noise must be a std > 0"]),
    ([{"at": 1, "corrupt": 3, "noise": [0.1, -0.1]}], {3: 2}, ["faults[1].noise must be a std > 0"]),
    ([{"at": 1, "corrupt": 3, "noise": [1, 2]}], {3: 1}, ["faults[1].noise has 2 values; the agent has 1 output"]),
    ([{"at": 1, "corrupt": 3, "noise": "loud"}], None, ["faults[1].noise must be a number"]),
    ([{"at": 1, "kill": 3, "stuck": True}], None, ["faults[1].stuck does not go with kill"]),
    ([{"at": 1, "corrupt": 3}], None, ["stuck: true", "noise: s"]),
])
def test_bad_stuck_and_noise_are_one_line(raw, outputs, words):
    with pytest.raises(ScenarioError) as e:
        parse(raw, outputs=outputs)
    msg = str(e.value)
    assert "\n" not in msg and all(w in msg for w in words), msg


@pytest.mark.parametrize("entry, text", [
    ({"stuck": True}, "agent 3's measurements corrupted (stuck)"),
    ({"stuck": True, "noise": 0.25}, "agent 3's measurements corrupted (stuck, noise 0.25)"),
    ({"noise": [0.5, 0.0], "bias": [1, 2], "scale": 3}, "agent 3's measurements corrupted (scale 3.0, bias [1.0, "
                                                        "2.0], noise [0.5, 0.0])"),
])
def test_stuck_and_noise_events_read_back_as_the_same_fault(ring, entry, text):
    import json

    (c,) = parse([{"at": 4, "corrupt": 3, **entry}], outputs={3: 2})
    event = json.loads(json.dumps({"event": c.event, **c.payload(4)}))  # as events.jsonl holds it
    assert c.text(event) == text
    (back,) = faults_from_events([event], ring)
    assert back == c


def test_a_stuck_sensor_holds_the_last_measurement_before_the_fault(ring):
    """From step 10 to 15 agent 2 is given y_2(9), the last measurement it was given before; nothing else changes;
    at step 0 there is none before: it holds y_2(0)."""
    clean = ss.simulate(ring, keep_y=True)
    k = IDS.index(2)
    hit = ss.simulate(ring, keep_y=True, faults=[{"at": 10, "corrupt": 2, "for": 6, "stuck": True}])
    np.testing.assert_array_equal(hit.x, clean.x)
    assert clean.y[9, k] != clean.y[10, k]
    np.testing.assert_array_equal(hit.y[10:16, k], np.full(6, clean.y[9, k]))  # held exactly
    rest = np.ones(clean.y.shape, dtype=bool)
    rest[10:16, k] = False
    np.testing.assert_array_equal(hit.y[rest], clean.y[rest])
    assert hit.errors()[16, k] > 2 * clean.errors()[16, k]
    first = ss.simulate(ring, keep_y=True, steps=8, faults=[{"at": 0, "corrupt": 2, "stuck": True}])
    np.testing.assert_array_equal(first.y[:, k], np.full(9, clean.y[0, k]))


def _sample_std_ok(d, s):
    """The sample std of ``d`` (zero mean) is ``s`` within 5 standard errors (``s / sqrt(2 len)``)."""
    d = np.ravel(d)
    return abs(d.std(ddof=1) - s) < 5 * s / np.sqrt(2 * d.size) and abs(d.mean()) < 5 * s / np.sqrt(d.size)


def test_a_noisy_sensor_gets_extra_noise_of_its_std_from_its_own_stream(ring):
    """noise: 0.3 from step 20 to 619: the difference to the clean measurement is zero outside the window and
    inside has std 0.3 within sampling error; the seed reproduces it exactly, another seed draws other numbers;
    combined with bias and scale it is k y + b + s w."""
    steps, s, k = 640, 0.3, IDS.index(5)
    faults = [{"at": 20, "corrupt": 5, "for": 600, "noise": s}]
    clean = ss.simulate(ring, keep_y=True, steps=steps)
    hit = ss.simulate(ring, keep_y=True, steps=steps, faults=faults)
    d = hit.y - clean.y
    assert not d[:20].any() and not d[620:].any() and not np.delete(d, k, axis=1).any()
    assert _sample_std_ok(d[20:620, k], s), d[20:620, k].std()
    again = ss.simulate(ring, keep_y=True, steps=steps, faults=faults)
    np.testing.assert_array_equal(again.y, hit.y)
    other = ss.simulate(ring, keep_y=True, steps=steps, seed=ring.run.seed + 1, faults=faults)
    d_other = other.y - ss.simulate(ring, keep_y=True, steps=steps, seed=ring.run.seed + 1).y
    assert not np.allclose(d_other[20:620, k], d[20:620, k])
    both = ss.simulate(ring, keep_y=True, steps=steps, faults=[{**faults[0], "bias": 0.5, "scale": 2.0}])
    # the same draws (the same stream: the first sensor fault on agent 5) on top of 2 y + 0.5
    np.testing.assert_allclose(both.y[20:620, k] - (2.0 * clean.y[20:620, k] + 0.5), d[20:620, k], rtol=0,
                               atol=1e-12)


def test_stuck_with_noise_and_each_sensor_fault_its_own_stream(ring):
    """stuck + noise: the held value plus noise of its std; a second noisy fault on the same agent draws from
    its own stream (not the first one's numbers again)."""
    k = IDS.index(3)
    clean = ss.simulate(ring, keep_y=True, steps=500)
    hit = ss.simulate(ring, keep_y=True, steps=500, faults=[
        {"at": 10, "corrupt": 3, "for": 200, "stuck": True, "noise": 0.2},
        {"at": 250, "corrupt": 3, "for": 200, "noise": 0.2}])
    assert _sample_std_ok(hit.y[10:210, k] - clean.y[9, k], 0.2)
    first, second = hit.y[10:210, k] - clean.y[9, k], hit.y[250:450, k] - clean.y[250:450, k]
    assert _sample_std_ok(second, 0.2) and not np.allclose(first, second)


def test_stuck_and_noise_in_the_batched_monte_carlo_equal_the_loop(ring):
    faults = [{"at": 5, "corrupt": 4, "for": 8, "stuck": True, "noise": 0.1},
              {"at": 7, "corrupt": 6, "for": 20, "noise": 0.4, "bias": 0.1}, {"at": 9, "kill": 7}]
    batch = ss.simulate(ring, seeds=[1, 2, 3], steps=60, faults=faults)
    loop = [ss.simulate(ring, seed=s, steps=60, faults=faults) for s in (1, 2, 3)]
    assert batch.batched
    np.testing.assert_allclose(batch.sq_error, [np.nansum(tr.errors() ** 2, axis=1) for tr in loop], rtol=1e-9,
                               atol=1e-12)


def test_the_plant_process_gives_the_measurements_simulate_gives(ring):
    """The plant process's own state machine (plant/plant.py), tick by tick: its y is simulate's given y, bit for
    bit, with a stuck and a noisy sensor."""
    import yaml

    from splitspec_plant.plant import PlantNode
    from splitspec_core.runtime.wire import decode, encode, new_run_key

    raw = yaml.safe_load((EXAMPLES / "ring10.yaml").read_text())
    raw["faults"] = [{"at": 3, "corrupt": 2, "for": 5, "stuck": True}, {"at": 4, "corrupt": 9, "noise": 0.5}]
    key = new_run_key()
    node = PlantNode({"scenario": yaml.safe_dump(raw), "seed": 5, "g": None, "q": 1, "g_mode": None, "key": key},
                     "r")
    ys = []
    for tau in range(12):
        out = node.on_tick(encode("tick", "r", mac_key=key, tau=tau, attempt=0, graph=0, final=False, alive=[],
                                  rows={}, incarnation={}, fresh=True, prev_attempt=0, topology=tau, partition=[]))
        ys.append(decode(dict(out)[node.keys.y], "r", "y", mac_key=key)["y"])
    sim = ss.simulate(ring, seed=5, steps=11, keep_y=True, faults=raw["faults"])
    np.testing.assert_array_equal(np.array(ys), sim.y[:12])
    assert len(set(sim.y[3:8, IDS.index(2)])) == 1


def test_a_corrupt_fault_on_a_measurements_file_is_what_the_estimators_were_given(ring, tmp_path):
    """simulate --measurements: the fault changes the file's rows as it changes the simulated plant's (the same
    estimates), the trajectory's y is what the estimators were given, a missing row stays missing and as the file
    has it; the recorder of a run on the file records the same y (network.given_measurements)."""
    from splitspec_core.model.network import given_measurements
    from splitspec_core.scenarios.measurements import load_measurements, write_measurements

    faults = [{"at": 6, "corrupt": 2, "for": 8, "bias": 0.3, "noise": 0.2}, {"at": 10, "corrupt": 4, "stuck": True}]
    steps = 30
    tr = ss.simulate(ring, keep_y=True, steps=steps)
    missing = np.zeros((steps + 1, ring.m), dtype=bool)
    missing[8:11, IDS.index(2)] = missing[9, IDS.index(4)] = True
    path = tmp_path / "m.npz"
    write_measurements(path, t=tr.t, y=tr.y, agent_ids=ring.agent_ids, sizes=[1] * ring.m, missing=missing, x=tr.x)
    meas = load_measurements(path, ring)
    run = ss.simulate(ring, measurements=meas, faults=faults)
    plant_run = ss.simulate(ring, keep_y=True, steps=steps, faults=faults)
    given = np.where(missing, meas.y, plant_run.y)  # one output per agent: a column per agent
    given[10:, IDS.index(4)] = tr.y[8, IDS.index(4)]  # stuck at 10 holds y_4(8): its measurement at 9 is missing
    np.testing.assert_array_equal(run.y, given)
    assert not np.array_equal(run.y, meas.y) and np.array_equal(run.y_missing, missing)
    np.testing.assert_array_equal(run.y[missing], meas.y[missing])
    assert plant_run.y[10, IDS.index(4)] == tr.y[9, IDS.index(4)]  # the simulated plant's: y_4(9)
    np.testing.assert_array_equal(run.xhat[:7], plant_run.xhat[:7])  # y(6) is used from step 7 on
    sc = dataclasses.replace(ring, faults=parse(faults))
    np.testing.assert_array_equal(given_measurements(sc, meas, ring.run.seed).y, run.y)
    assert given_measurements(ring, meas, ring.run.seed) is meas  # no sensor fault: the file as it is


def test_a_run_on_live_sensors_refuses_a_sensor_fault_in_one_line(tmp_path):
    """Live sensors publish to the agents without a plant process: nothing would apply the fault, so `run` refuses
    it in one line before any round."""
    import yaml

    from tests.conftest import ROOT
    from tests.integration.runtime_helpers import run

    raw = yaml.safe_load((ROOT / "examples" / "sensors" / "chain.yaml").read_text())
    raw["faults"] = [{"at": 2, "corrupt": 1, "for": 3, "noise": 0.1}]
    scen = tmp_path / "lying_chain.yaml"
    scen.write_text(yaml.safe_dump(raw))
    r = run("run", scen, "--out", tmp_path / "out", timeout=60)
    err = [line for line in r.stderr.splitlines() if line.startswith("splitspec: error:")]
    assert r.returncode != 0 and len(err) == 1, r.stderr
    assert "corrupt, repair faults are applied by the plant process" in err[0] and "live sensors" in err[0]
    assert "Traceback" not in r.stderr
    assert not (tmp_path / "out" / "trajectory.npz").exists()
