"""`splitspec run` of ring10_partition and ring10_lossy, read back from run.rrd: what a misbehaving network shows.

The rounds panel counts the consensus messages that did not count (``rounds/lost``, the rows of
``trajectory.npz`` ``lost``); the communication graph dashes the arcs that lost one in each event
time and the arcs a partition cuts; the log error plot marks the partition and the heal.
"""

from __future__ import annotations

import re
from collections import Counter

import numpy as np
import pytest

from splitspec_core.model.impairment import PARTITION
from splitspec_orchestrator.viewer import blueprint as bp
from tests.conftest import EXAMPLES
from tests.integration.runtime_helpers import events, run, scenario_file
from tests.rrd_readback import read_blueprint, read_rrd, read_rrd_graph, read_rrd_logs, rrd_entities, verify_rrd

pytestmark = pytest.mark.slow

RING = {(j, i) for a, b in [(1, 2), (2, 3), (3, 4), (4, 5), (5, 6), (6, 7), (7, 8), (8, 9), (9, 10), (10, 1), (1, 6),
                            (3, 8)] for j, i in [(a, b), (b, a)]}
GROUP_A = {1, 2, 3, 9, 10}
CUT = {(j, i) for j, i in RING if (j in GROUP_A) != (i in GROUP_A)}
PART_FROM, HEAL_AT = 5, 35


def _lost_per_tau(out) -> tuple[dict, dict]:
    """From trajectory.npz: event time -> messages that did not count, and -> arcs that lost one to loss/late."""
    with np.load(out / "trajectory.npz") as f:
        lost, cause, T = f["lost"], f["lost_cause"], len(f["t"])
    count = Counter(int(r[0]) for r in lost)
    arcs: dict[int, set] = {}
    for r, c in zip(lost, cause):
        if c != PARTITION:
            arcs.setdefault(int(r[0]), set()).add((int(r[2]), int(r[3])))
    return {tau: count.get(tau, 0) for tau in range(T)}, arcs


@pytest.fixture(scope="module")
def partition(tmp_path_factory):
    out = tmp_path_factory.mktemp("partition") / "out"
    r = run("run", EXAMPLES / "ring10_partition.yaml", "--out", out, timeout=300)
    assert r.returncode == 0, r.stdout + r.stderr
    return out


@pytest.fixture(scope="module")
def lossy(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("lossy")
    out = tmp / "out"
    r = run("run", scenario_file(tmp, "ring10_lossy", run={"steps": 25}), "--out", out, timeout=300)
    assert r.returncode == 0, r.stdout + r.stderr
    return out


@pytest.mark.parametrize("which", ["partition", "lossy"])
def test_recording_verifies_and_rounds_lost_equals_the_trajectory(which, request):
    out = request.getfixturevalue(which)
    rrd = out / "run.rrd"
    ok, msg = verify_rrd(rrd)
    assert ok, msg
    want, _ = _lost_per_tau(out)
    assert dict(read_rrd(rrd)["rounds/lost"]) == want
    assert any(want.values())
    # the rounds panel of the default blueprint shows it
    assert ("TimeSeries", "round lost", "rounds/lost") in read_blueprint(rrd)["views"]
    assert {bp.TOPOLOGY_LOST, bp.TOPOLOGY_STATUS} <= rrd_entities(rrd)


def test_lossy_ring_dashes_the_arcs_that_lost_a_message_in_each_event_time(lossy):
    rrd = lossy / "run.rrd"
    count, arcs = _lost_per_tau(lossy)
    assert bp.TOPOLOGY_PARTITION not in rrd_entities(rrd)
    for tau in range(len(count)):
        dashed = arcs.get(tau, set())
        assert set(read_rrd_graph(rrd, bp.TOPOLOGY, tau)["edges"]) == RING - dashed, tau
        dots = read_rrd_graph(rrd, bp.TOPOLOGY_LOST, tau)
        assert {tuple(int(v) for v in n.split(":")[0].split(">")) for n in dots.get("node_ids", [])} == dashed, tau
        assert set(dots.get("colors", [])) <= {bp.LOST_COLOR, bp.LATE_COLOR}
        status = read_rrd_graph(rrd, bp.TOPOLOGY_STATUS, tau).get("labels", [])
        if count[tau]:
            assert status and status[0].startswith(f"{count[tau]} message"), (tau, status)
        else:
            assert status == []
    texts = [text for _, _, text in read_rrd_logs(rrd)["events"]]
    assert any(re.fullmatch(r"\d+ consensus messages? did not count \(\d+ loss(, \d+ late)?\)", t) for t in texts)


def test_partition_is_dashed_named_and_marked_until_the_heal(partition):
    rrd = partition / "run.rrd"
    assert [(e["event"], e["tau"]) for e in events(partition) if e["event"] in ("partition", "healed")] == \
        [("partition", PART_FROM), ("healed", HEAL_AT)]
    count, arcs = _lost_per_tau(partition)
    for tau in (PART_FROM - 1, PART_FROM, 20, HEAL_AT - 1, HEAL_AT, 50):
        inside = PART_FROM <= tau < HEAL_AT
        edges = set(read_rrd_graph(rrd, bp.TOPOLOGY, tau)["edges"])
        cut = read_rrd_graph(rrd, bp.TOPOLOGY_PARTITION, tau).get("node_ids", [])
        label = read_rrd_graph(rrd, bp.TOPOLOGY_GRAPH, tau)["labels"]
        status = read_rrd_graph(rrd, bp.TOPOLOGY_STATUS, tau).get("labels", [])
        if inside:
            assert edges == RING - CUT, tau
            assert {tuple(int(v) for v in n.split(":")[0].split(">")) for n in cut} == CUT
            assert label == ["graph: ring\npartition 1 2 3 9 10 | 4 5 6 7 8"]
            assert status == [f"{count[tau]} messages did not count ({count[tau]} partition)"]
            assert count[tau] == len(CUT) * 6 and not arcs.get(tau)  # q = 6 sub-rounds, every crossing message
        else:
            assert edges == RING and cut == [] and label == ["graph: ring"] and status == [], tau
    series = read_rrd(rrd)
    lmax = dict(series["errors_log10/max"])
    assert [tau for tau, _ in series["marks/partition"]] == [PART_FROM]
    assert [tau for tau, _ in series["marks/healed"]] == [HEAL_AT]
    assert series["marks/healed"][0][1] == pytest.approx(lmax[HEAL_AT], abs=1e-12)
    texts = [text for _, _, text in read_rrd_logs(rrd)["events"]]
    assert "partition 1 2 3 9 10 | 4 5 6 7 8: no consensus message crosses between the groups" in texts
    assert "partition healed" in texts
