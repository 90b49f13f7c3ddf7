"""A standby's takeover without I/O: the follower (orchestrator.rounds.follower), a new round machine adopting its
view, the fencing of a superseded orchestrator, the scenario's `kill: orchestrator`.

The in-process protocol of test_rounds (the real AgentNode and PlantNode, messages delivered by a loop) is played
with a follower beside the machine; the machine dies as it ticks an event time, with its last rows unwritten, and
a new machine of the next epoch adopts the follower's view: the rows must be those of `simulate`, each event time
once."""

import os
import time
from pathlib import Path

import numpy as np
import pytest

from splitspec_core.model.rows import report
from splitspec_core.runtime.ticks import Fence, TickEncoder
from splitspec_core.runtime.wire import decode, new_run_key
from splitspec_orchestrator.rounds import machine as R
from splitspec_orchestrator.rounds.follower import Follower
from tests.unit.test_rounds import finish_round, machine, of, play, start


@pytest.mark.parametrize("example,changes,at", [
    ("paper_discrete", {"run": {"steps": 30}}, 12),
    ("ring10_partition", {"run": {"steps": 40}}, 25),  # during the partition: the network faults replayed
    ("paper_continuous_switching", {"run": {"steps": 30}}, 7),
])
def test_a_takeover_in_flight_gives_the_rows_of_simulate(example, changes, at):
    from splitspec_core.simulation.simulator import simulate

    m, rows = play(example, changes=changes, takeover_at=at)
    assert m.epoch == 2
    steps = changes["run"]["steps"]
    assert [r.tau for r in rows] == list(range(steps + 1))  # every event time once
    tr = simulate(m.des, seed=m.sc.run.seed, steps=steps)
    xhat = np.array([r.xhat for r in rows])
    # other operations than the simulator's (the agents' per-agent steps): to round-off
    assert np.max(np.abs(xhat - tr.xhat)) <= 1e-12 * max(1.0, np.abs(tr.xhat).max())
    assert np.array_equal(np.array([r.alive for r in rows]), tr.alive)


def _tick(enc, key, **kw):
    base = dict(attempt=0, graph=0, final=False, fresh=False, prev_attempt=0, alive=[1, 2], partition=(),
                rows={1: ((1, 2), (0.5, 0.5)), 2: ((2, 1), (0.5, 0.5))}, incarnation={1: 0, 2: 0})
    return decode(enc.encode(**{**base, **kw}), "r", "tick", mac_key=key)


def test_the_follower_records_a_round_when_the_next_tick_names_its_attempt():
    m = machine("paper_discrete")
    f = Follower(m.sc)
    key = new_run_key()
    enc = TickEncoder("r", mac_key=key, epoch=1)
    ids = m.sc.agent_ids
    rows = {a: ((a,), (1.0,)) for a in ids}
    kw = dict(alive=list(ids), rows=rows, incarnation={a: 0 for a in ids})
    f.on_tick(_tick(enc, key, tau=0, fresh=True, **kw))
    x = np.ones(m.sc.n)
    f.on_truth(0, 0, x)
    for a in ids:
        f.on_xhat(a, 0, 0, 0, x, report(), lost=())
        f.on_xhat(a, 1, 0, 0, 2 * x, report(), lost=())
    f.on_tick(_tick(enc, key, tau=0, attempt=1, **kw))  # re-run: its estimates of 1 no longer count
    assert 1 not in f.collected.est and not f.rows
    for a in ids:
        f.on_xhat(a, 1, 1, 0, 3 * x, report(), lost=())
    f.on_truth(0, 1, x)
    f.on_tick(_tick(enc, key, tau=1, prev_attempt=1, **kw))
    (row,) = f.rows
    assert row.tau == 0 and row.attempts == 2 and np.array_equal(row.xhat, np.ones((len(ids), m.sc.n)))
    assert not f.ready  # no state yet
    f.on_state({"epoch": 1, "procs": {}, "t_run_wall": None, "tau": 1, "pid": 7, "host": "h", "kept": 0})
    assert f.ready and f.first == 0
    f.on_state({"epoch": 0, "procs": {"plant": {}}, "t_run_wall": None, "tau": 1, "pid": 8, "host": "h",
                "kept": 0})  # a superseded orchestrator's state is ignored
    assert f.pid == 7 and f.procs == {}


def test_a_follower_that_joins_mid_run_records_nothing_it_did_not_see_and_is_ready_once_on_disk():
    m = machine("paper_discrete")
    f = Follower(m.sc)
    key = new_run_key()
    enc = TickEncoder("r", mac_key=key, epoch=1)
    ids = m.sc.agent_ids
    kw = dict(alive=list(ids), rows={a: ((a,), (1.0,)) for a in ids}, incarnation={a: 0 for a in ids})
    f.on_tick({**_tick(enc, key, tau=5, **kw), **{}})  # the first tick it hears carries the network (resent)
    enc2 = TickEncoder("r", mac_key=key, epoch=1)
    t6 = _tick(enc2, key, tau=6, **kw)
    t7 = _tick(enc2, key, tau=7, **kw)
    for k in ("alive", "rows", "incarnation", "partition"):
        t7.pop(k, None)
    f.on_tick(t6)
    f.on_state({"epoch": 1, "procs": {}, "t_run_wall": None, "tau": 6, "pid": 7, "host": "h", "kept": 4})
    assert f.first == 5 and not f.ready  # rows 4 (on disk: 0..3) and 5: round 5 was not heard whole
    f.on_state({"epoch": 1, "procs": {}, "t_run_wall": None, "tau": 7, "pid": 7, "host": "h", "kept": 6})
    assert f.ready


def test_a_superseded_orchestrator_is_fenced_off():
    from splitspec_agents.agent import AgentNode
    from tests.conftest import EXAMPLES

    key = new_run_key()
    m = machine("paper_discrete")
    cfg = {"scenario": (EXAMPLES / "paper_discrete.yaml").read_text(), "seed": m.sc.run.seed, "g": m.des.g,
           "q": m.des.q, "g_mode": m.des.g_mode, "key": key}
    node = AgentNode(m.sc.agent_ids[0], cfg, "inproc")
    ids = m.sc.agent_ids
    base = dict(graph=0, final=False, fresh=True, prev_attempt=0, alive=list(ids), partition=(),
                rows={a: ((a,), (1.0,)) for a in ids}, incarnation={a: 0 for a in ids})
    old, new = TickEncoder("inproc", mac_key=key, epoch=1), TickEncoder("inproc", mac_key=key, epoch=2)
    assert node.on_tick(new.encode(tau=0, attempt=1, **base))  # the new epoch's tick is obeyed
    assert node.on_tick(old.encode(tau=0, attempt=5, **base)) == []  # the old one's, however new its attempt, not
    assert node.counts().get("fenced") == 1
    f = Fence()
    assert f.admit({}) and f.admit({"epoch": 3}) and not f.admit({"epoch": 2}) and not f.admit({})


def test_the_kth_orchestrator_kill_is_epoch_ks_and_a_successor_replaying_the_step_goes_on():
    changes = {"run": {"steps": 10}, "faults": [{"at": 3, "kill": "orchestrator"}, {"at": 6, "kill": "orchestrator"}]}
    for epoch, killed_at in ((1, 3), (2, 6), (3, None)):
        m = machine("paper_discrete", changes=changes)
        m.epoch = epoch
        out = start(m, 1.0)
        t = 1.0
        kills, said = [], []
        while not m.finished and t < 100:
            t += 0.01
            out = finish_round(m, t)
            kills += [a.tau for a in of(out, R.KillSelf)]
            said += [a.fields["tau"] for a in of(out, R.Event) if a.name == "orchestrator_killed"]
            if kills:
                break
        assert kills == ([] if killed_at is None else [killed_at]), (epoch, kills)
        assert said == kills  # a successor replaying an earlier kill's step says nothing of it
        if killed_at is None:
            assert m.finished


# ---------------------------------------------------------------------- the records a standby takes over


def _recorder(out, *, continuous=None, resume=None):
    from splitspec_orchestrator.records.recorder import Recorder

    return Recorder(out, agent_ids=(1, 2, 5), n=4, steps=50, time_mode="discrete", dt=1.0, graph_names=("g",),
                    run_id="takeover", scenario_name="takeover", flush_seconds=0.0, continuous=continuous,
                    resume=resume)


def _feed(rec, start, stop):
    for tau in range(start, stop):
        rng = np.random.default_rng(tau)
        rec.row(tau, rng.normal(size=4), rng.normal(size=(3, 4)), np.ones(3, dtype=bool), 0, wall_ms=1.0,
                attempts=1, rejected=0, lost=[], late_ms=0.0)


def test_records_resumed_after_a_kill_hold_every_row_once(tmp_path):
    from splitspec_orchestrator.takeover import resume_records
    from splitspec_orchestrator.viewer.rrd_file import rrd_segments, verify_rrd

    out = tmp_path / "run"
    dead = _recorder(out)
    _feed(dead, 0, 120)
    dead.abandon()  # killed: nothing more written, run.rrd without its footer, trajectory.npz as of its last rewrite
    with open(out / "events.jsonl", "ab") as f:
        f.write(b'{"event": "torn')  # a line the kill cut short
    with open(out / "run.rrd", "ab") as f:
        f.write(bytes(37))  # and a message
    rows, segment, torn = resume_records(out)
    assert (rows, segment, torn) == (120, 1, out / "run.rrd")
    rec = _recorder(out, resume=(rows, segment))
    assert rec.finish_beside(torn).wait(timeout=120) == 0
    _feed(rec, 120, 200)
    rec.close()
    z = np.load(out / "trajectory.npz")  # rebuilt from every chunk at the close
    assert np.array_equal(z["t"], np.arange(200))
    for tau in (0, 119, 120, 199):  # exact: the values given, copied
        assert np.array_equal(z["x"][tau], np.random.default_rng(tau).normal(size=4))
    assert [p.name for p in rrd_segments(out / "run.rrd")] == ["run.rrd", "run-0001.rrd"]
    assert all(verify_rrd(p)[0] for p in rrd_segments(out / "run.rrd"))
    lines = (out / "events.jsonl").read_text().splitlines()
    assert all(line.startswith("{") and line.endswith("}") for line in lines)  # the torn line cut, then appended


def _blocked_on_a_lock(pid: int) -> bool:
    """Whether process ``pid`` waits for a file lock (``/proc/locks``: a waiter's line has ``->``)."""
    rows = [line.split() for line in Path("/proc/locks").read_text().splitlines()]
    return any(len(r) > 5 and r[1] == "->" and r[5] == str(pid) for r in rows)


@pytest.mark.skipif(not Path("/proc/locks").exists(), reason="reads /proc/locks (Linux)")
def test_a_second_finisher_of_a_segment_waits_for_the_first_and_leaves_its_work(tmp_path):
    """A segment rolled as its orchestrator was killed (before the next segment's first write) is finished twice: by
    the child its roll started, which the kill does not stop, and by the successor's ``finish_beside`` (no footer
    yet).  The second waits for the first (the test holds the segment's lock as the first does) and then finds the
    footer and leaves the file alone.  (Without it the chaos suite's takeover at a roll left a segment with a torn
    message header, 1 run in 4: the second one cut the first one's finished file at its end-of-stream message.)"""
    import fcntl
    import shutil

    from splitspec_orchestrator.viewer.rrd_file import finish_in_child, has_footer, optimize_rrd, verify_rrd

    out = tmp_path / "run"
    dead = _recorder(out)
    _feed(dead, 0, 100)
    args = dead.layout_args()
    dead.abandon()
    seg, done = out / "run-0001.rrd", tmp_path / "done.rrd"
    shutil.copy(out / "run.rrd", seg)
    shutil.copy(out / "run.rrd", done)
    assert optimize_rrd(done) and has_footer(done)  # what the first finisher leaves
    with open(seg, "rb") as first:
        fcntl.flock(first, fcntl.LOCK_EX)  # the first finisher at work
        second = finish_in_child(seg, args)
        deadline = time.monotonic() + 60
        while second.poll() is None and not _blocked_on_a_lock(second.pid) and time.monotonic() < deadline:
            time.sleep(0.01)
        assert second.poll() is None, "the second finisher went on while the first held the segment"
        os.replace(shutil.copy(done, out / ".first.tmp"), seg)  # the first one's finished file, moved in
    assert second.wait(timeout=60) == 0, second.stderr.read()
    assert seg.read_bytes() == done.read_bytes()  # left as the first one finished it
    assert verify_rrd(seg)[0]
    assert not list(out.glob(".*.tmp"))


def test_a_taken_over_run_ends_with_every_segment_finished(tmp_path):
    """The dead orchestrator's last rolled segment, whose finishing child never got to it, is finished at the run's
    end (takeover.finish_left_segments); a finished one is left as it is."""
    import shutil

    from splitspec_orchestrator.takeover import finish_left_segments
    from splitspec_orchestrator.viewer.rrd_file import has_footer, optimize_rrd, rrd_segments, verify_rrd

    out = tmp_path / "run"
    dead = _recorder(out)
    _feed(dead, 0, 60)
    args = dead.layout_args()
    dead.abandon()
    shutil.copy(out / "run.rrd", out / "run-0001.rrd")
    assert optimize_rrd(out / "run-0001.rrd")
    finished = (out / "run-0001.rrd").read_bytes()
    assert not has_footer(out / "run.rrd")
    finish_left_segments(out, args)
    assert [has_footer(p) and verify_rrd(p)[0] for p in rrd_segments(out / "run.rrd")] == [True, True]
    assert (out / "run-0001.rrd").read_bytes() == finished


def test_run_keep_removes_the_dead_orchestrators_segments_too(tmp_path):
    from splitspec_core.simulation.trajectory_chunks import chunk_segments, read_chunks
    from splitspec_orchestrator.records.files import Continuous
    from splitspec_orchestrator.takeover import resume_records

    out = tmp_path / "run"
    dead = _recorder(out, continuous=Continuous(window_rows=16, chunk_bytes=20_000, rrd_bytes=1 << 30))
    _feed(dead, 0, 300)
    dead.abandon()
    before = [p for _, p in chunk_segments(out)]
    assert len(before) >= 3
    rows, segment, torn = resume_records(out)
    rec = _recorder(out, continuous=Continuous(window_rows=16, chunk_bytes=20_000, rrd_bytes=1 << 30,
                                               keep_hours=1e-9), resume=(rows, segment))
    rec.finish_beside(torn).wait(timeout=120)
    rec._w.retention.every = 0.0  # a sweep at every flush
    _feed(rec, rows, 400)
    rec.close()
    assert not any(p.exists() for p in before)  # the dead one's closed segments went by the same rule
    assert not (out / "run.rrd").exists()
    gone = [e for e in map(__import__("json").loads, (out / "events.jsonl").read_text().splitlines())
            if e["event"] == "records_removed"]
    assert {e["kind"] for e in gone} == {"chunks", "recording"} and min(e["first_tau"] or 0 for e in gone) == 0
    left = read_chunks(out)["tau"]
    assert left.tolist() == list(range(int(left[0]), 400))  # nothing lost at the cut, every row once


def test_the_follower_records_a_round_whose_messages_come_after_the_next_tick():
    """The router forwards each sender's messages on its own: a truth may come before its tick, an estimate after
    the next one; the round is still recorded, once, with what the machine would have recorded."""
    m = machine("paper_discrete")
    f = Follower(m.sc)
    key = new_run_key()
    enc = TickEncoder("r", mac_key=key, epoch=1)
    ids = m.sc.agent_ids
    kw = dict(alive=list(ids), rows={a: ((a,), (1.0,)) for a in ids}, incarnation={a: 0 for a in ids})
    x = np.ones(m.sc.n)
    f.on_truth(0, 0, x)  # before its tick
    f.on_tick(_tick(enc, key, tau=0, fresh=True, **kw))
    for a in ids:
        f.on_xhat(a, 0, 0, 0, x, report(), lost=())
    f.on_tick(_tick(enc, key, tau=1, prev_attempt=0, **kw))  # round 0 committed, but x_i(1) has not come yet
    assert not f.rows and len(f.owed) == 1
    for a in ids:
        f.on_xhat(a, 1, 0, 0, 2 * x, report(), lost=())
    (row,) = f.rows
    assert row.tau == 0 and np.array_equal(row.x, x) and not f.owed
    f.on_truth(1, 0, 3 * x)
    c = f.collected  # round 1 in flight: its truth and x_i(1), as the machine would hold them
    assert np.array_equal(c.truth[1], 3 * x) and set(c.est[1]) == set(ids)
