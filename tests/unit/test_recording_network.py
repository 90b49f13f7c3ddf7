"""A network that misbehaves, as run.rrd shows it: rounds/lost, dashed arcs, the partition and its marks.

A recorder fed by hand (rows with ``lost=``, topologies with ``partition=``, the ``partition`` and
``healed`` events), its ``run.rrd`` read back the way the viewer queries it (latest-at per event time).
"""

from __future__ import annotations

import numpy as np
import pytest

from splitspec_core.model.impairment import LATE, LOSS, PARTITION
from splitspec_orchestrator.viewer import blueprint as bp
from splitspec_orchestrator.records.recorder import Recorder, RecordingError
from splitspec_orchestrator.viewer.topology_view import dash_dots, lost_arcs, status_text
from tests.rrd_readback import read_rrd, read_rrd_graph, read_rrd_logs, rrd_entities, verify_rrd

IDS = (1, 2, 3, 4)
N, T = 2, 20
RING = [(1, 2), (2, 1), (2, 3), (3, 2), (3, 4), (4, 3), (4, 1), (1, 4)]
GROUPS = [[1, 2], [3, 4]]
CUT = {(2, 3), (3, 2), (4, 1), (1, 4)}
PART_FROM, HEAL_AT, AGENT_LOST_AT = 8, 12, 15
NEVER = 3600.0


def lost_rows(tau: int) -> tuple:
    """The consensus messages of event time ``tau`` that did not count (tau, k, j, i, cause)."""
    if tau == 2:  # 1 -> 2 lost twice, 3 -> 4 once too late
        return ((2, 1, 1, 2, LOSS), (2, 2, 1, 2, LOSS), (2, 1, 3, 4, LATE))
    if tau == 4:
        return ((4, 3, 2, 3, LOSS),)
    if PART_FROM <= tau < HEAL_AT:  # every message across the cut, in both sub-rounds
        return tuple((tau, k, j, i, PARTITION) for k in (1, 2) for j, i in sorted(CUT))
    if tau in (14, 15, 16):  # 4 -> 3 and 1 -> 2 lost: agent 4 is lost at 15, noticed after 16 was logged
        return ((tau, 1, 4, 3, LOSS), (tau, 1, 1, 2, LOSS))
    return ()


def record(out, *, flush_seconds: float) -> None:
    rng = np.random.default_rng(5)
    rec = Recorder(out, agent_ids=IDS, n=N, steps=T - 1, time_mode="discrete", dt=1.0, graph_names=("ring",),
                   run_id="lossy", scenario_name="lossy", flush_seconds=flush_seconds, envelope_rate=0.8)
    rec.topology(0, "ring", IDS, RING)
    alive = np.ones(len(IDS), dtype=bool)
    for tau in range(T):
        if tau == PART_FROM:
            rec.event("partition", float(tau), groups=GROUPS, tau=tau)
            rec.topology(tau, "ring", IDS, RING, partition=GROUPS)
        if tau == HEAL_AT:
            rec.event("healed", float(tau), tau=tau)
            rec.topology(tau, "ring", IDS, RING)
        if tau == AGENT_LOST_AT + 2:  # rows 15 and 16 are in run.rrd already (flush_seconds=0)
            alive[3] = False
            rec.mark_lost(AGENT_LOST_AT, 4)
            rec.event("agent_lost", float(AGENT_LOST_AT), id=4, tau=AGENT_LOST_AT)
            rec.topology(AGENT_LOST_AT, "ring", (1, 2, 3), RING)
        x = rng.normal(size=N)
        xhat = x + rng.normal(size=(len(IDS), N)) * 0.9 ** tau
        lost = tuple(r for r in lost_rows(tau) if alive[3] or 4 not in r[2:4])
        rec.row(tau, x, xhat, alive.copy(), 0, attempts=1, rejected=0, wall_ms=1.0, lost=lost)
    rec.close()


@pytest.fixture(scope="module", params=[0.0, NEVER], ids=["write-through", "one-flush"])
def recorded(request, tmp_path_factory):
    out = tmp_path_factory.mktemp("lossy")
    record(out, flush_seconds=request.param)
    return out / "run.rrd"


def test_rounds_lost_counts_each_event_time(recorded):
    ok, msg = verify_rrd(recorded)
    assert ok, msg
    got = dict(read_rrd(recorded)["rounds/lost"])
    assert sorted(got) == list(range(T))
    want = {tau: len(lost_rows(tau)) for tau in range(T)}
    want[AGENT_LOST_AT] = want[AGENT_LOST_AT + 1] = 1  # agent 4's messages are forgotten with it ...
    assert got == {**want, 14: 2}  # ... from its loss on, not before


def test_arcs_that_lost_a_message_are_dashed_for_that_event_time_only(recorded):
    edges = {tau: set(read_rrd_graph(recorded, bp.TOPOLOGY, tau)["edges"]) for tau in range(T)}
    dots = {tau: read_rrd_graph(recorded, bp.TOPOLOGY_LOST, tau) for tau in range(T)}
    status = {tau: read_rrd_graph(recorded, bp.TOPOLOGY_STATUS, tau).get("labels", []) for tau in range(T)}
    # before any loss: the whole ring, nothing dashed, no status
    assert edges[0] == edges[1] == set(RING) and not dots[1] and not status[1]
    # event time 2: 1 -> 2 (lost) and 3 -> 4 (late) are not solid but dashed, red and orange
    assert edges[2] == set(RING) - {(1, 2), (3, 4)}
    arcs = {}
    for node, color in zip(dots[2]["node_ids"], dots[2]["colors"]):
        arcs.setdefault(node.split(":")[0], set()).add(color)
    assert arcs == {"1>2": {bp.LOST_COLOR}, "3>4": {bp.LATE_COLOR}}
    assert status[2] == ["3 messages did not count (2 loss, 1 late); 2 arcs dashed"]
    # event time 3 loses nothing: everything back, the dots and the status cleared
    assert edges[3] == set(RING) and dots[3]["node_ids"] == [] and status[3] == []
    assert edges[4] == set(RING) - {(2, 3)} and {n.split(":")[0] for n in dots[4]["node_ids"]} == {"2>3"}
    assert edges[5] == set(RING) and dots[5]["node_ids"] == []


def test_partition_cut_is_dashed_named_and_healed(recorded):
    for tau in range(PART_FROM, HEAL_AT):
        g = read_rrd_graph(recorded, bp.TOPOLOGY, tau)
        assert set(g["edges"]) == set(RING) - CUT, tau  # no cut arc drawn solid ...
        cut = read_rrd_graph(recorded, bp.TOPOLOGY_PARTITION, tau)
        assert {n.split(":")[0] for n in cut["node_ids"]} == {f"{j}>{i}" for j, i in CUT}  # ... but dashed
        assert set(cut["colors"]) == {bp.CUT_COLOR}
        assert read_rrd_graph(recorded, bp.TOPOLOGY_GRAPH, tau)["labels"] == ["graph: ring\npartition 1 2 | 3 4"]
        # partition losses are the cut's: no arc of topology/lost, the count on topology/status
        assert read_rrd_graph(recorded, bp.TOPOLOGY_LOST, tau)["node_ids"] == []
        assert read_rrd_graph(recorded, bp.TOPOLOGY_STATUS, tau)["labels"] == [
            "8 messages did not count (8 partition)"]
    healed = read_rrd_graph(recorded, bp.TOPOLOGY_PARTITION, HEAL_AT)
    assert healed["node_ids"] == [] and set(read_rrd_graph(recorded, bp.TOPOLOGY, HEAL_AT)["edges"]) == set(RING)
    assert read_rrd_graph(recorded, bp.TOPOLOGY_GRAPH, HEAL_AT)["labels"] == ["graph: ring"]
    assert read_rrd_graph(recorded, bp.TOPOLOGY_STATUS, HEAL_AT)["labels"] == []


def test_partition_and_heal_are_marked_on_the_error_plot(recorded):
    series = read_rrd(recorded)
    lmax = dict(series["errors_log10/max"])
    assert [tau for tau, _ in series["marks/partition"]] == [PART_FROM]
    assert [tau for tau, _ in series["marks/healed"]] == [HEAL_AT]
    assert series["marks/partition"][0][1] == pytest.approx(lmax[PART_FROM], abs=1e-12)  # on the max error
    assert series["marks/healed"][0][1] == pytest.approx(lmax[HEAL_AT], abs=1e-12)
    texts = [text for _, _, text in read_rrd_logs(recorded)["events"]]
    assert "partition 1 2 | 3 4: no consensus message crosses between the groups" in texts
    assert "partition healed" in texts


def test_an_agent_lost_late_takes_its_arcs_out_of_the_overlays_logged_after_it(recorded):
    """Rows 15 and 16 were logged with agent 4's arcs; its loss at 15 (noticed at 17) redraws them without."""
    assert set(read_rrd_graph(recorded, bp.TOPOLOGY, 14)["edges"]) == set(RING) - {(4, 3), (1, 2)}
    for tau in (AGENT_LOST_AT, AGENT_LOST_AT + 1):
        g = read_rrd_graph(recorded, bp.TOPOLOGY, tau)
        assert set(g["edges"]) == {(1, 2), (2, 1), (2, 3), (3, 2)} - {(1, 2)}, tau
        assert {n.split(":")[0] for n in read_rrd_graph(recorded, bp.TOPOLOGY_LOST, tau)["node_ids"]} == {"1>2"}
        assert "agent 4 (lost)" in g["labels"]
    assert set(read_rrd_graph(recorded, bp.TOPOLOGY, AGENT_LOST_AT + 2)["edges"]) == {(1, 2), (2, 1), (2, 3), (3, 2)}


def test_a_network_that_loses_nothing_logs_no_overlay(tmp_path):
    rec = Recorder(tmp_path, agent_ids=IDS, n=N, steps=4, time_mode="discrete", dt=1.0, graph_names=("ring",),
                   run_id="clean", scenario_name="clean", flush_seconds=0.0)
    rec.topology(0, "ring", IDS, RING)
    for tau in range(5):
        rec.row(tau, np.zeros(N), np.ones((len(IDS), N)), np.ones(len(IDS), dtype=bool), 0, lost=())
    rec.close()
    ents = rrd_entities(tmp_path / "run.rrd")
    assert {bp.TOPOLOGY, bp.TOPOLOGY_GRAPH} <= ents
    assert not {bp.TOPOLOGY_LOST, bp.TOPOLOGY_PARTITION, bp.TOPOLOGY_STATUS} & ents
    assert [v for _, v in read_rrd(tmp_path / "run.rrd")["rounds/lost"]] == [0.0] * 5


def test_partition_of_unknown_agents_is_refused(tmp_path):
    rec = Recorder(tmp_path, agent_ids=IDS, n=N, steps=4, time_mode="discrete", dt=1.0, graph_names=("ring",),
                   run_id="bad", scenario_name="bad", flush_seconds=0.0)
    with pytest.raises(RecordingError, match=r"partition names \[9\]"):
        rec.topology(0, "ring", IDS, RING, partition=[[1, 2], [3, 9]])
    rec.close()


# ---------------------------------------------------------------------- the drawing itself


def test_lost_arcs_and_status_text():
    rows = ((0, 1, 1, 2, LATE), (0, 2, 1, 2, LOSS), (0, 1, 3, 4, LATE), (0, 1, 2, 3, PARTITION))
    arcs = lost_arcs(rows)
    assert arcs == {(1, 2): LOSS, (3, 4): LATE}  # any loss makes the arc red; partition is the cut's
    assert status_text(rows, arcs) == "4 messages did not count (1 loss, 2 late, 1 partition); 2 arcs dashed"
    assert status_text((), {}) == ""
    assert status_text(((0, 1, 1, 2, LOSS),), {(1, 2): LOSS}) == "1 message did not count (1 loss); 1 arc dashed"


def test_dashes_run_between_the_label_boxes_right_of_travel_and_grow_towards_the_receiver():
    pos = {1: (0.0, 0.0), 2: (200.0, 0.0)}
    labels = {1: "agent 1", 2: "agent 2"}
    ids, xy, radii, which = dash_dots([(1, 2), (2, 1)], pos, labels)
    fwd = [p for p, w in zip(xy, which) if w == 0]
    back = [p for p, w in zip(xy, which) if w == 1]
    half_box = (6.3 * len("agent 1") + 6.0) / 2
    assert all(half_box < x < 200 - half_box for x, _ in fwd + back)  # outside both label boxes
    assert {y for _, y in fwd} == {3.0} and {y for _, y in back} == {-3.0}  # side by side, not on each other
    assert [x for x, _ in fwd] == sorted(x for x, _ in fwd) and len(fwd) >= 2
    r_fwd = [r for r, w in zip(radii, which) if w == 0]
    assert r_fwd == sorted(r_fwd) and r_fwd[0] < r_fwd[-1]  # bigger towards agent 2, the receiver
    assert len(set(ids)) == len(ids) and ids[0].startswith("1>2:")
    # two boxes that touch: still two dots, around the middle
    ids, xy, _, _ = dash_dots([(1, 2)], {1: (0.0, 0.0), 2: (30.0, 0.0)}, labels)
    assert len(ids) == 2 and all(0 < x < 30 for x, _ in xy)


def test_default_blueprint_opens_on_a_tab_by_name():
    """docs/make_screenshots.py shows the rounds panel through the default blueprint opened on its tab."""
    bp.default_blueprint("discrete", n=2, active_tab="rounds")
    with pytest.raises(ValueError, match="'nope' is not a tab"):
        bp.default_blueprint("discrete", n=2, active_tab="nope")
