"""Live sensors, the pure parts: payload decoding, the one-slot sampler (injected clock), the scenario's
``sources:`` section, the secure run's sensor users, and the example chain the scenario models."""

from __future__ import annotations

import importlib.util
import json

import numpy as np
import pytest
import yaml

from splitspec_agents.measure import YBuffer
from splitspec_agents.sensor import FLOOD_BURST, FLOOD_RATE, LiveSampler, SensorReject, decode_payload, payload_cap
from splitspec_core.errors import ScenarioError
from splitspec_core.runtime.security import acl_config, generate
from splitspec_core.runtime.wire import Keys
from splitspec_core.scenarios.load import load_scenario, parse_scenario_text
from tests.conftest import ROOT

CHAIN = ROOT / "examples" / "sensors" / "chain.yaml"


class Clock:
    def __init__(self, t: float = 100.0):
        self.t = t

    def __call__(self) -> float:
        return self.t


# ------------------------------------------------------------------ payloads


def test_json_and_raw_payloads_decode_to_the_same_vector():
    y = np.array([0.25, -1.5e-3])
    got, t = decode_payload(json.dumps({"y": y.tolist(), "t": 12.5}).encode(), 2)
    assert np.array_equal(got, y) and t == 12.5
    got, t = decode_payload(y.astype("<f8").tobytes(), 2)
    assert np.array_equal(got, y) and t is None
    got, t = decode_payload(b' {"y": [1, 2]} ', 2)  # integers and whitespace are fine; t is optional
    assert got.dtype == float and list(got) == [1.0, 2.0] and t is None


@pytest.mark.parametrize("payload, reason", [
    (b"\x00\x01garbage", "garbage"),
    (b"{not json", "garbage"),
    (b"", "garbage"),
    (b"[1.0, 2.0]", "not_object"),
    (b"3.5", "not_object"),
    (b'{"t": 1}', "bad_y"),
    (b'{"y": "1 2"}', "bad_y"),
    (b'{"y": [1, true]}', "bad_y"),
    (b'{"y": [1.0]}', "bad_length"),
    (b'{"y": [1.0, 2.0, 3.0]}', "bad_length"),
    (b'{"y": [NaN, 1.0]}', "non_finite"),
    (b'{"y": [Infinity, 1.0]}', "non_finite"),
    (np.array([np.nan, 1.0]).tobytes(), "non_finite"),
    (np.array([1.0, 2.0, 3.0]).tobytes(), "garbage"),  # 24 bytes: not 8 * s_i
    (b'{"y": [1.0, 2.0], "t": "noon"}', "bad_t"),
    (b'{"y": [1.0, 2.0], "t": NaN}', "bad_t"),
    (b"{" + b" " * 2000 + b"}", "too_big"),
    (b"[" * 1200, "too_big"),
    (b"[" * 1000, "garbage"),  # nested too deep for the JSON parser: refused, not a crash
    (b'{"y": [1' + b"0" * 400 + b', 1.0]}', "non_finite"),  # a JSON integer beyond float: OverflowError before
    (b'{"y": [1.0, 2.0], "t": 1' + b"0" * 400 + b"}", "bad_t"),
])
def test_a_bad_payload_is_refused_with_its_reason(payload, reason):
    with pytest.raises(SensorReject) as e:
        decode_payload(payload, 2)
    assert e.value.reason == reason


def test_the_cap_grows_with_the_output_size():
    assert payload_cap(1) < payload_cap(100)
    big = json.dumps({"y": [1.0 / 3.0] * 100}).encode()  # 100 values written at full precision fit
    assert len(big) <= payload_cap(100) and len(decode_payload(big, 100)[0]) == 100


# ------------------------------------------------------------------ the sampler


def test_the_newest_value_is_taken_while_it_is_at_most_max_age_old():
    clock = Clock()
    s = LiveSampler(2, 0.5, clock=clock)  # times in binary fractions: the boundary is exact
    assert s.take() is None  # nothing yet: predict
    assert s.offer(json.dumps({"y": [1, 2]}).encode())
    clock.t += 0.25
    assert s.offer(json.dumps({"y": [3, 4]}).encode())  # newer: replaces the slot
    clock.t += 0.5  # exactly max_age after the last arrival: still used
    assert list(s.take()) == [3.0, 4.0]
    assert list(s.take()) == [3.0, 4.0]  # taking does not consume it (a slower sensor: used while fresh)
    clock.t += 2 ** -20
    assert s.take() is None  # older than max_age: no measurement
    assert s.counts() == {} and s.accepted == 2


def test_the_taken_value_is_a_copy():
    s = LiveSampler(2, 1.0, clock=Clock())
    s.offer(np.array([1.0, 2.0]).tobytes())
    y = s.take()
    y[0] = 99.0
    assert s.take()[0] == 1.0


def test_t_only_orders_values_and_bad_ones_never_replace_a_good_one():
    clock = Clock()
    s = LiveSampler(2, 10.0, clock=clock)
    assert s.offer(b'{"y": [1, 1], "t": 5.0}')
    assert not s.offer(b'{"y": [2, 2], "t": 5.0}')  # not after the kept one
    assert not s.offer(b'{"y": [2, 2], "t": 4.0}')
    assert not s.offer(b'{"y": [NaN, 2]}')
    assert not s.offer(b"junk")
    assert s.offer(b'{"y": [3, 3], "t": 6.0}')
    assert s.offer(b'{"y": [4, 4]}')  # without t: by arrival
    assert list(s.take()) == [4.0, 4.0]
    assert s.counts() == {"out_of_order": 2, "non_finite": 1, "garbage": 1}


def test_a_sensor_back_with_its_clock_restarted_is_picked_up():
    """t orders one run of fresh values only: a sensor restarted (its clock back at 0) after its last value went
    stale is used again at once; before that, an earlier t is out of order."""
    clock = Clock()
    s = LiveSampler(1, 0.5, clock=clock)
    assert s.offer(b'{"y": [1], "t": 1000.0}')
    clock.t += 0.25
    assert not s.offer(b'{"y": [2], "t": 0.5}')  # the kept value is fresh: 0.5 is out of order
    clock.t += 60.0  # the sensor was gone a minute
    assert s.take() is None
    assert s.offer(b'{"y": [3], "t": 0.5}')  # back, its clock restarted
    assert list(s.take()) == [3.0] and s.counts() == {"out_of_order": 1}


def test_an_arrival_that_lost_the_race_to_the_slot_does_not_replace_a_newer_one():
    clock = Clock()
    s = LiveSampler(1, 10.0, clock=clock)
    clock.t = 5.0
    assert s.offer(b'{"y": [1]}')
    clock.t = 4.0  # an offer whose arrival time was read before the kept one's (two callbacks at once)
    assert not s.offer(b'{"y": [2]}')
    clock.t = 5.0
    assert list(s.take()) == [1.0] and s.counts() == {"out_of_order": 1}


def test_a_flood_is_counted_and_dropped_undecoded_and_the_slot_stays_one():
    clock = Clock()
    s = LiveSampler(1, 1.0, clock=clock)
    for k in range(10_000):  # in no time at all: the bucket allows its burst, then nothing
        s.offer(json.dumps({"y": [float(k)]}).encode())
    assert s.accepted == FLOOD_BURST and s.counts() == {"flood": 10_000 - FLOOD_BURST}
    assert list(s.take()) == [float(FLOOD_BURST - 1)]  # the newest decoded one
    clock.t += 10.5 / FLOOD_RATE  # the bucket refills at FLOOD_RATE a second: 10 (and a half) tokens
    for k in range(20):
        s.offer(b"[1]")  # decoded again (and refused as not_object): 10 tokens, then flood
    assert s.counts() == {"flood": 10_000 - FLOOD_BURST + 10, "not_object": 10}
    # one slot, nothing that grows with the messages: the object's attributes are scalars, the slot and the counters
    assert isinstance(s._slot, tuple) and all(
        isinstance(v, (int, float, str, tuple)) or v in (s.clock, s._lock, s._counts) for v in vars(s).values())


def test_a_live_sample_enters_the_y_buffer_once_per_event_time():
    b = YBuffer(1, slice(0, 2), 4)
    b.put_sample(3, np.array([1.0, 2.0]))
    b.put_sample(3, None)  # a re-run of the same event time keeps the first sample
    assert b.ready(3) and list(b.get(3)) == [1.0, 2.0]
    b.put_sample(4, None)
    assert b.ready(4) and b.get(4) is None  # no measurement: the agent predicts


# ------------------------------------------------------------------ the scenario


def _chain(**sources_and_run) -> str:
    raw = yaml.safe_load(CHAIN.read_text())
    for k, v in sources_and_run.items():
        raw[k] = v
    return yaml.safe_dump(raw)


def test_the_example_parses_with_its_defaults():
    sc = load_scenario(CHAIN)
    assert sorted(sc.sources) == [1, 2, 3]
    assert sc.sources[1].key == "chain/1" and sc.sources[1].max_age == pytest.approx(2 / sc.run.pace)
    assert sc.sources[3].max_age == 0.2
    assert Keys("r1").sensor(sc.sources[2].key) == "splitspec/r1/sensors/chain/2"


@pytest.mark.parametrize("sources, run, fragment", [
    ({1: "a", 2: "b", 3: "c/*"}, None, "sources.3.key must be a key like"),
    ({1: "a", 2: "b", 3: "/c"}, None, "sources.3.key must be a key like"),
    ({1: "a", 2: "b", 3: "c//d"}, None, "sources.3.key must be a key like"),
    ({1: "a", 2: "b", 3: {"max_age": 1}}, None, "sources.3.key must be a key like"),
    ({1: "a", 2: "b", 3: {"key": "c", "maxage": 1}}, None, "unknown key sources.3.maxage"),
    ({1: "a", 2: "b", 9: "c"}, None, "sources names agent 9"),
    ({1: "a", 2: "b"}, None, "sources has no key for agent 3"),
    ({1: "a", 2: "a", 3: "c"}, None, "sources.2.key 'a' is also agent 1's source"),
    ({1: "a", 2: "b", 3: {"key": "c", "max_age": -1}}, None, "sources.3.max_age must be > 0"),
    ({1: "a", 2: "b", 3: {"key": "c", "max_age": 7200}}, None, "sources.3.max_age must be > 0 and <= 3600"),
    ([1, 2], None, "sources must be a mapping"),
    ({1: "a", 2: "b", 3: "c"}, {"steps": 10}, "sources needs run.pace"),
])
def test_bad_sources_name_the_key(sources, run, fragment):
    changes = {"sources": sources} if run is None else {"sources": sources, "run": run}
    with pytest.raises(ScenarioError) as e:
        parse_scenario_text(_chain(**changes))
    assert fragment in str(e.value) and "\n" not in str(e.value)


def test_the_chain_is_the_publishers_physics_and_its_design_is_certified():
    """chain.yaml's A is the publisher's exact motion over one event period; the middle agent never sees the
    antisymmetric mode (p1 - p3, v1 - v3), and gets it by consensus."""
    from splitspec_core.synthesis.designer import design

    spec = importlib.util.spec_from_file_location("publisher", ROOT / "examples" / "sensors" / "publisher.py")
    pub = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(pub)
    sc = load_scenario(CHAIN)
    assert np.max(np.abs(np.asarray(sc.system.A) - pub.step_matrix(1 / sc.run.pace))) < 1e-15
    d = design(sc)
    assert d.q is not None and d.unobserved.dim == 0
    V2 = d.agents[1].dec.V
    anti = np.array([[1, 0, -1, 0, 0, 0], [0, 0, 0, 1, 0, -1]]).T / np.sqrt(2)
    assert V2.shape[1] == 2 and np.allclose(V2 @ V2.T, anti @ anti.T, atol=1e-9)
    assert d.agents[0].dec.V.shape[1] == d.agents[2].dec.V.shape[1] == 0  # the end masses see the whole chain


# ------------------------------------------------------------------ secure mode


def test_each_sensor_user_may_publish_on_its_own_key_only(tmp_path):
    acl = acl_config("r1", [1, 2], {1: "chain/1", 2: "chain/2"})
    rules = {r["id"]: r for r in acl["rules"]}
    assert rules["sensor-1-publish"]["key_exprs"] == ["splitspec/r1/sensors/chain/1"]
    assert rules["sensor-1-publish"]["messages"] == ["put"]
    policy = next(p for p in acl["policies"] if p["id"] == "sensor-1")
    assert policy["rules"] == ["sensor-1-publish", "sensor-1-interest"]
    everyone = next(s for s in acl["subjects"] if s["id"] == "everyone")
    assert "sensor-1" not in everyone["usernames"]  # nothing else: no subscribing, no config, no liveliness
    cred = generate(tmp_path / "c", [1, 2], (1, 2))
    assert "sensor-2" in cred.users and (tmp_path / "c" / "sensor-2.cred").read_text().startswith("sensor-2:")
    cred.check_agents([1, 2], {1: "chain/1", 2: "chain/2"})
    old = generate(tmp_path / "old", [1, 2])
    with pytest.raises(ScenarioError, match="no credentials for sensor-1, sensor-2"):
        old.check_agents([1, 2], {1: "chain/1", 2: "chain/2"})


def test_splitspec_credentials_writes_the_sensors_too(tmp_path, capsys):
    """For an orchestrator started by hand (--secure DIR): `splitspec credentials` gives every sensor its file."""
    from splitspec_orchestrator import cli

    assert cli.main(["credentials", str(CHAIN), "--out", str(tmp_path / "c")]) == 0
    said = capsys.readouterr().out
    assert f"agent i's sensor: {tmp_path / 'c'}/sensor-i.cred" in said
    for i in (1, 2, 3):
        assert (tmp_path / "c" / f"sensor-{i}.cred").read_text().startswith(f"sensor-{i}:")
    assert "sensor-3:" in (tmp_path / "c" / "users.txt").read_text()
