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
           "partition": {"partition": [[1, 2, 3]]}, "heal": {"heal": True}}


def test_every_registered_kind_has_an_example_here():
    assert set(EXAMPLE) <= set(fk.KINDS)
    assert fk.FAULT_ACTIONS == tuple(fk.KINDS) and fk.FAULT_ALIASES == {"hang": "freeze"}


@pytest.mark.parametrize("action", list(EXAMPLE))
def test_each_kind_parses_to_its_class_and_its_event_reads_back(ring, action):
    """Parsed, logged (its payload under its event word) and read back by a replay: the same fault again."""
    raw = ([{"at": 1, "partition": [[1, 2, 3]]}] if action == "heal" else []) + [{"at": 4, **EXAMPLE[action]}]
    f = parse(raw)[-1]
    assert type(f) is fk.KINDS[action] and f.action == action and f.at == 4.0
    assert f.runtime in (fk.SIGNAL, fk.RESTART, fk.NETWORK, fk.PLANT) and f.event is not None
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
    from splitspec_orchestrator.recording import blueprint as bp
    from splitspec_orchestrator.records.events import event_text

    for cls in fk.KINDS.values():
        if cls.mark is not None:
            assert bp.MARK_OF_EVENT[cls.event] == cls.mark and cls.mark in bp.MARK_KINDS
    assert event_text("arc_dropped", {"arc": [1, 6], "tau": 15}) == "arc 1 -> 6 dropped"
    assert event_text("healed", {"tau": 3}) == "partition healed"
