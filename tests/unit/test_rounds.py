"""The orchestrator's rules without I/O (orchestrator.rounds.RoundMachine), case by case.

Every test drives the machine by hand: hellos, tokens, truths, estimates and the clock go in; the actions
that come out are what the Zenoh shell would execute.  The last test plays the whole protocol in-process
(the real AgentNode and PlantNode, messages delivered by a loop instead of Zenoh) and checks the trajectory
against `simulate`.
"""

import signal

import numpy as np
import pytest

from splitspec_core.model.rows import REPORTED, report
from splitspec_orchestrator.rounds import machine as R
from splitspec_core.synthesis.designer import design
from splitspec_core.scenarios.load import parse_scenario
from tests.conftest import EXAMPLES

HOST = "here"


def machine(example="paper_discrete", *, wait=60.0, round_timeout=10.0, spawned=False, changes=None, now=0.0):
    import yaml

    raw = yaml.safe_load((EXAMPLES / f"{example}.yaml").read_text())
    for section, values in (changes or {}).items():
        if isinstance(values, dict):
            raw.setdefault(section, {}).update(values)
        else:
            raw[section] = values
    sc = parse_scenario(raw, source=example)
    return R.RoundMachine(sc, design(sc), host=HOST, wait=wait, round_timeout=round_timeout, spawned=spawned,
                          now=now)


def hello(role, ident, nonce, pid, host=HOST):
    return {"role": role, "id": ident, "pid": pid, "host": host, "nonce": nonce}


def of(actions, kind):
    return [a for a in actions if isinstance(a, kind)]


def events(actions, name=None):
    return [a for a in actions if isinstance(a, R.Event) and (name is None or a.name == name)]


def start(m, now=1.0):
    """Grant and show every participant; returns the actions (the first tick among them)."""
    out = m.start(now)
    out += m.on_hello("q-plant", hello("plant", 0, "p0", 100), now)
    out += m.on_token("plant", 0, "p0", True, now)
    for k, a in enumerate(m.sc.agent_ids):
        out += m.on_hello(f"q{a}", hello("agent", a, f"n{a}", 200 + k), now)
        out += m.on_token("agent", a, f"n{a}", True, now)
    return out


def advance(m, t0, t1, step=0.1, answered=None, plant=True):
    """The shell's polling: on_timer every ``step`` seconds from t0 to t1; status queries are answered by
    ``answered`` (default: every alive agent) and counted.  Returns the actions."""
    out, t = [], t0
    while t < t1:
        t = min(t + step, t1)
        acts = m.on_timer(t)
        out += acts
        while of(acts, R.QueryStatus):
            acts = m.on_status(set(m.alive) if answered is None else set(answered), t, plant=plant)
            out += acts
    return out


def finish_round(m, now, *, skip=()):
    """Feed truth and every alive agent's estimates of the round in flight."""
    x = np.zeros(m.sc.n)
    out = m.on_truth(m.tau, m.attempt, x, {}, now)
    for a in sorted(m.alive):
        if a in skip:
            continue
        if a not in m.est.get(m.tau, {}):  # admission: the fresh estimate x_i(tau) first
            out += m.on_xhat(a, m.tau, m.attempt, m.incarnation(a), x, report(), {}, now)
        out += m.on_xhat(a, m.tau + 1, m.attempt, m.incarnation(a), x, report(), {}, now)
    return out


# ---------------------------------------------------------------------- identity


def test_start_needs_every_participant_then_ticks():
    m = machine()
    out = m.start(0.0)
    assert out == []  # not spawned: processes are started by hand
    out = m.on_hello("q", hello("plant", 0, "p0", 100), 0.1)
    assert of(out, R.ReplyConfig) and events(out, "process_started") and of(out, R.RegistryUpdate)
    out = m.on_token("plant", 0, "p0", True, 0.2)
    assert not of(out, R.Tick)
    out = start(m, 0.3)
    ticks = of(out, R.Tick)
    assert len(ticks) == 1 and (ticks[0].tau, ticks[0].attempt) == (0, 0) and ticks[0].alive == (1, 2, 3)
    assert events(out, "run_started")


def test_second_claimant_is_refused_and_the_holder_kept():
    m = machine()
    start(m)
    out = m.on_hello("q-imp", hello("agent", 3, "impostor", 999, "elsewhere"), 2.0)
    (ref,) = of(out, R.ReplyRefused)
    assert "held by pid 202 on host here" in ref.reason and (ref.holder_pid, ref.holder_host) == (202, HOST)
    (dup,) = events(out, "duplicate_refused")
    assert dup.fields["pid"] == 999 and dup.fields["holder_pid"] == 202
    assert m.procs[3] == {"pid": 202, "host": HOST} and not of(out, R.RegistryUpdate)
    # the impostor's token neither counts nor hides the holder's death
    assert m.on_token("agent", 3, "impostor", True, 2.1) == []
    assert m.on_token("agent", 3, "impostor", False, 2.2) == []
    assert 3 in m.alive and not m.pending_loss
    out = m.on_token("agent", 3, "n3", False, 2.3)
    (lost,) = events(out, "agent_lost")
    assert lost.fields["id"] == 3 and lost.fields["pid"] == 202
    assert [(t.tau, t.attempt) for t in of(out, R.Tick)] == [(0, 1)]  # the round re-run without it


def test_same_process_asking_again_gets_the_config_again():
    m = machine()
    m.on_hello("q1", hello("agent", 1, "a", 10), 0.0)
    out = m.on_hello("q2", hello("agent", 1, "a", 10), 0.5)
    assert of(out, R.ReplyConfig) and not events(out)


def test_unknown_identity_is_refused():
    m = machine()
    out = m.on_hello("q", hello("agent", 7, "x", 10), 0.0)
    (ref,) = of(out, R.ReplyRefused)
    assert "agent 7 is not part of this run (agents: 1, 2, 3)" == ref.reason


def test_claim_without_token_lapses_after_wait():
    m = machine(wait=5.0)
    m.on_hello("q", hello("agent", 1, "a", 10), 0.0)
    assert of(m.on_hello("q2", hello("agent", 1, "b", 11), 1.0), R.ReplyRefused)
    for k in range(1, 11):
        m.on_timer(1.0 + 0.5 * k)  # the shell polls every 0.5 s
    assert of(m.on_hello("q3", hello("agent", 1, "b", 11), 6.1), R.ReplyConfig)


def test_claimant_after_a_loss_is_a_rejoin():
    m = machine()
    start(m)
    m.on_token("agent", 2, "n2", False, 2.0)  # agent 2 dies during round 0
    out = finish_round(m, 2.1)
    assert of(out, R.Record) and m.tau == 1
    out = m.on_hello("q", hello("agent", 2, "fresh", 300), 2.2)
    assert of(out, R.ReplyConfig) and m.procs[2]["pid"] == 300
    m.on_token("agent", 2, "fresh", True, 2.3)
    out = finish_round(m, 2.4)
    (back,) = events(out, "agent_rejoined")
    assert back.fields["id"] == 2 and back.fields["incarnation"] == 1 and back.fields["tau"] == 2
    assert of(out, R.Tick)[-1].alive == (1, 2, 3) and of(out, R.Tick)[-1].incarnation[2] == 1


def test_old_token_of_a_lost_agent_never_readmits_it():
    m = machine()
    start(m)
    out = m.on_status(set(), 1.0)  # not in the status phase: ignored
    assert out == []
    m.pending_loss[1] = "test"
    out = m.on_timer(1.1)
    assert events(out, "agent_lost") and 1 not in m.alive
    m.on_token("agent", 1, "n1", True, 1.2)  # its old process's token shows again
    finish_round(m, 1.3)
    assert 1 not in m.alive and not m.joinable


# ---------------------------------------------------------------------- start-up failures


def test_child_exiting_during_startup_stops_at_once_with_its_status():
    m = machine(spawned=True)
    out = m.start(0.0)
    assert [(s.role, s.ident) for s in of(out, R.Spawn)] == [("plant", 0), ("agent", 1), ("agent", 2), ("agent", 3)]
    m.on_spawned("plant", 0, 50, 0.0)
    m.on_hello("q", hello("plant", 0, "p", 50), 0.2)
    out = m.on_child_exit(50, 1, 0.4)
    (stop,) = of(out, R.Stop)
    assert stop.code == 1
    assert stop.message == "the plant (pid 50) exited during start-up (exit status 1); see its output above"
    assert m.finished


def test_startup_times_out_naming_who_is_missing():
    m = machine(wait=3.0)
    m.start(0.0)
    m.on_hello("q", hello("plant", 0, "p", 5), 0.1)
    m.on_token("plant", 0, "p", True, 0.2)
    assert not of(advance(m, 0.2, 2.9), R.Stop)
    (stop,) = of(m.on_timer(3.05), R.Stop)
    assert stop.message == "waited 3 s for agent 1, agent 2, agent 3 to connect"


def test_plant_lost_during_the_run_stops_it_truthfully():
    m = machine()
    start(m)
    finish_round(m, 1.5)
    (stop,) = of(m.on_token("plant", 0, "p0", False, 1.6), R.Stop)
    assert stop.message.startswith("the plant (pid 100) was lost at event time 1: liveliness lost")


# ---------------------------------------------------------------------- time, timeouts, retries


def test_orchestrator_stall_moves_deadlines_and_blames_nobody():
    m = machine(round_timeout=2.0)
    start(m, 1.0)
    out = m.on_timer(7.0)  # the orchestrator was frozen 6 s with the round in flight
    assert events(out, "orchestrator_stalled") and not of(out, R.QueryStatus) and not of(out, R.Stop)
    assert m.deadline == pytest.approx(9.0)
    out = finish_round(m, 7.1)
    assert of(out, R.Record) and not events(out, "agent_lost")


def test_time_spent_starting_its_own_processes_is_no_stall():
    """m = 100 on a busy machine: 101 spawns of 0.1 s each (10 s in all, no call in between); then the hellos.
    Before the fix the first hello saw a 10 s gap and warned "frozen or starved" about the orchestrator's own
    start-up; a real freeze before a spawn is still one."""
    m = machine(spawned=True)
    out = m.start(1.0)
    spawns = of(out, R.Spawn)
    assert len(spawns) == 1 + m.sc.m
    t = 1.0
    for k, s in enumerate(spawns):
        out += m.on_spawned(s.role, s.ident, 100 + k, t + 0.1, began=t)
        t += 0.1
    t += 0.05
    out += m.on_hello("q-plant", hello("plant", 0, "p0", 100), t) + m.on_token("plant", 0, "p0", True, t)
    for k, a in enumerate(m.sc.agent_ids):
        out += m.on_hello(f"q{a}", hello("agent", a, f"n{a}", 101 + k), t)
        out += m.on_token("agent", a, f"n{a}", True, t)
    assert not events(out, "orchestrator_stalled") and not [a for a in out if isinstance(a, R.Log)
                                                            and "frozen or starved" in a.message]
    assert m.started and of(out, R.Tick)
    m = machine(spawned=True)
    (first, *_) = of(m.start(1.0), R.Spawn)
    stalled = m.on_spawned(first.role, first.ident, 100, 5.1, began=5.0)  # frozen 4 s before it spawned
    assert [e.fields["seconds"] for e in events(stalled, "orchestrator_stalled")] == [4.0]


def test_round_timeout_queries_status_then_retries_once_then_loses_the_late():
    m = machine(round_timeout=2.0)
    start(m, 1.0)
    x = np.zeros(m.sc.n)
    m.on_truth(0, 0, x, {}, 1.1)
    for a in (1, 2):
        m.on_xhat(a, 1, 0, 0, x, report(), {}, 1.2)
    out = advance(m, 1.2, 2.9)  # no news of agent 3: probes every 0.3 s, all answer, nobody is blamed
    assert len(of(out, R.QueryStatus)) >= 4 and not events(out, "agent_lost") and not events(out, "round_retried")
    assert of(m.on_timer(3.1), R.QueryStatus) and not m.probing  # the round timeout's own query
    out = m.on_status({1, 2, 3}, 3.2)  # all answer: re-run once
    assert events(out, "round_retried")[0].fields["late"] == [3]
    assert [(t.tau, t.attempt) for t in of(out, R.Tick)] == [(0, 1)]
    m.on_truth(0, 1, x, {}, 3.3)
    for a in (1, 2):  # they answer the re-run; agent 3 stays silent
        m.on_xhat(a, 1, 1, 0, x, report(), {}, 3.4)
    advance(m, 3.4, 5.15)
    assert of(m.on_timer(5.3), R.QueryStatus) and not m.probing
    out = m.on_status({1, 2, 3}, 5.5)
    (lost,) = events(out, "agent_lost")
    assert lost.fields["id"] == 3 and "without its estimate" in lost.fields["reason"]


def test_a_frozen_agent_is_found_by_the_probe_and_lost():
    m = machine(round_timeout=10.0)
    start(m, 1.0)
    m.on_truth(0, 0, np.zeros(m.sc.n), {}, 1.1)
    assert not of(m.on_timer(1.35), R.QueryStatus)
    assert of(m.on_timer(1.45), R.QueryStatus) and m.probing  # 0.3 s without news of the round
    out = m.on_status({1, 3}, 2.45)  # agent 2 does not answer within the second
    (lost,) = events(out, "agent_lost")
    assert lost.fields["id"] == 2 and "frozen" in lost.fields["reason"] and 201 in m.stopped
    assert [(t.tau, t.attempt) for t in of(out, R.Tick)] == [(0, 1)]


def test_a_silent_plant_stops_the_run():
    m = machine()
    start(m, 1.0)
    out = advance(m, 1.0, 1.5, plant=False)
    (stop,) = of(out, R.Stop)
    assert stop.message.startswith("the plant (pid 100) was lost at event time 0: it does not answer a status query")


def test_rejections_are_summarised_per_second_not_per_message():
    m = machine()
    start(m, 1.0)
    x = np.zeros(m.sc.n)
    out = []
    for k in range(5000):  # a flood of well-formed future and stale estimates
        out += m.on_xhat(1, 50 + k, 0, 0, x, report(), {}, 1.0 + k * 1e-4)
        out += m.on_truth(-1, 0, x, {}, 1.0 + k * 1e-4)
    out += m.on_timer(2.6)
    summary = events(out, "message_rejected")
    assert len(summary) <= 4  # at most one line per reason per second, not 10000
    totals = {}
    for e in summary:
        totals[e.fields["reason"]] = totals.get(e.fields["reason"], 0) + e.fields["count"]
    assert totals == {"future": 5000, "stale": 5000}
    assert len(m.est) == 0 and len(m.truth) == 0  # nothing buffered
    # remote totals are turned into increments
    m.remote_counts("agent 2", {"bad_mac": 7})
    m.remote_counts("agent 2", {"bad_mac": 9})
    out = advance(m, 2.6, 4.0)
    assert [(e.fields["by"], e.fields["count"]) for e in events(out, "message_rejected")] == [("agent 2", 9)]
    # a restarted agent (incarnation 1) counts from 0 again: its first 3 are new; the old one's late totals are not
    m.remote_counts("agent 2", {"bad_mac": 3}, incarnation=1)
    m.remote_counts("agent 2", {"bad_mac": 12}, incarnation=0)
    out = advance(m, 4.0, 5.5)
    assert [(e.fields["by"], e.fields["count"]) for e in events(out, "message_rejected")] == [("agent 2", 3)]


# ---------------------------------------------------------------------- faults between rounds


def test_scenario_faults_kill_hang_restart_and_arcs():
    m = machine("ring10_faults", changes={"run": {"steps": 40}})
    start(m, 1.0)
    t = 1.0
    acts = []
    while m.tau < 10:
        t += 0.01
        acts = finish_round(m, t)
    kill = of(acts, R.Signal)
    pid3 = m.procs[3]["pid"]
    assert kill == [R.Signal(pid3, int(signal.SIGKILL))] and events(acts, "agent_lost")[0].fields["id"] == 3
    while m.tau < 30:
        t += 0.01
        acts = finish_round(m, t)
        if m.tau == 20:
            assert R.Signal(m.procs[5]["pid"], int(signal.SIGSTOP)) in of(acts, R.Signal)
            assert m.procs[5]["pid"] in m.stopped
    assert m.phase == "restarting" and of(acts, R.Spawn) == [R.Spawn("agent", 3)]
    assert not of(acts, R.Tick)  # the run waits for the restarted agent
    m.on_spawned("agent", 3, 777, t)
    m.on_hello("q", hello("agent", 3, "new3", 777), t + 0.1)
    out = m.on_token("agent", 3, "new3", True, t + 0.2)
    assert events(out, "agent_rejoined")[0].fields["reason"] == "restarted by the scenario"
    assert of(out, R.Tick)[0].tau == 30


def test_restart_that_dies_is_reported_and_the_run_goes_on():
    m = machine("ring10_faults", changes={"run": {"steps": 40}})
    start(m, 1.0)
    t = 1.0
    while m.phase != "restarting":
        t += 0.01
        finish_round(m, t)
    m.on_spawned("agent", 3, 778, t)
    out = m.on_child_exit(778, -9, t + 0.1)
    (failed,) = events(out, "restart_failed")
    assert failed.fields["reason"] == "the new process exited (killed by SIGKILL)"
    assert of(out, R.Tick) and 3 not in of(out, R.Tick)[0].alive


def test_fault_for_an_agent_on_another_host_is_a_control_message():
    m = machine("paper_discrete", changes={"faults": [{"at": 1, "kill": 2}]})
    start(m, 1.0)
    m.procs[2] = {"pid": 5, "host": "far"}
    out = finish_round(m, 1.1)
    assert of(out, R.Control) == [R.Control("kill agent/2")] and not of(out, R.Signal)


# ---------------------------------------------------------------------- the whole protocol in-process


def play(example, changes=None, events=None, takeover_at=None, unflushed=3):
    """Orchestrator machine + PlantNode + AgentNodes with messages delivered in order (no Zenoh); the machine's
    events go to ``events`` when given.  ``takeover_at``: a standby's follower hears everything, and the machine
    dies as it ticks that event time (its last ``unflushed`` rows never reach the disk); a new machine of epoch 2
    adopts the follower's view (rounds.follower.adopt) and carries the run on.  The rows: the dead machine's on
    disk, the follower's after them, the new machine's."""
    from splitspec_agents.agent import AgentNode
    from splitspec_orchestrator.rounds.follower import Follower, adopt
    from splitspec_plant.plant import PlantNode
    from splitspec_core.runtime.ticks import TickEncoder
    from splitspec_core.runtime.wire import Keys, decode, encode, new_run_key

    m = machine(example, changes=changes)
    follower = Follower(m.sc) if takeover_at is not None else None
    key = new_run_key()
    ticks = TickEncoder("inproc", mac_key=key, epoch=m.epoch)
    text = (EXAMPLES / f"{example}.yaml").read_text()
    if changes:
        import yaml

        raw = yaml.safe_load(text)
        for section, values in changes.items():
            raw.setdefault(section, {}).update(values) if isinstance(values, dict) else raw.__setitem__(section, values)
        text = yaml.safe_dump(raw)
    cfg = {"scenario": text, "seed": m.sc.run.seed, "g": m.des.g, "q": m.des.q, "g_mode": m.des.g_mode, "key": key}
    keys = Keys("inproc")
    plant = PlantNode(cfg, "inproc")
    nodes = {a: AgentNode(a, cfg, "inproc") for a in m.sc.agent_ids}
    rows = []
    t = 1.0
    queue = list(start(m, t))
    while queue:
        a = queue.pop(0)
        t += 1e-4
        if isinstance(a, R.Tick):  # as the driver encodes it: the network only when it changed
            payload = ticks.encode(tau=a.tau, attempt=a.attempt, graph=a.graph, final=a.final, fresh=a.fresh,
                                   prev_attempt=a.prev_attempt, alive=a.alive, rows=a.rows,
                                   incarnation=a.incarnation, partition=a.partition)
            if follower is not None:
                follower.on_tick(decode(payload, "inproc", "tick", mac_key=key))
                follower.on_state({"epoch": m.epoch, "procs": m.identity.state(), "t_run_wall": None,
                                   "tau": m.tau, "pid": 1, "host": HOST, "kept": len(rows)})
                if a.tau == takeover_at and m.epoch == 1:  # it dies here: a new machine adopts the follower's view
                    kept = max(0, len(rows) - unflushed)
                    assert follower.ready and follower.rows_from(kept)[0].tau == kept
                    rows = rows[:kept] + follower.rows_from(kept)
                    present = {(r, i, n) for (r, i), c in m.claims.items() if c.present and not c.released
                               for n in (c.nonce,)}
                    m = machine(example, changes=changes)
                    m.epoch = 2
                    ticks = TickEncoder("inproc", mac_key=key, epoch=2, topology=follower.round.topology)
                    queue = adopt(m, follower, present, t)
            msgs = plant.on_tick(payload)
            for n in nodes.values():
                msgs += n.on_tick(payload)
            while msgs:  # deliver every message to whoever subscribes to its key
                k, p = msgs.pop(0)
                if k == keys.truth:
                    d = decode(p, "inproc", "truth", mac_key=key)
                    queue += m.on_truth(d["tau"], d["attempt"], d["x"], d["rejected"], t)
                    if follower is not None:
                        follower.on_truth(d["tau"], d["attempt"], d["x"])
                elif k.startswith(keys.prefix + "/xhat/"):
                    d = decode(p, "inproc", "xhat", mac_key=key)
                    queue += m.on_xhat(d["agent"], d["tau"], d["attempt"], d["incarnation"], d["x"],
                                       {c.name: d[c.name] for c in REPORTED},
                                       d["rejected"], t, lost=d["lost"])
                    if follower is not None:
                        follower.on_xhat(d["agent"], d["tau"], d["attempt"], d["incarnation"], d["x"],
                                         {c.name: d[c.name] for c in REPORTED}, lost=d["lost"])
                    for n in nodes.values():  # x_j(tau + 1) is also the neighbours' next z_j(0)
                        if d["agent"] in n.in_neighbours:
                            msgs += n.on_x(k, p)
                elif k == keys.y:
                    for n in nodes.values():
                        msgs += n.on_y(p)
                elif k.startswith(keys.prefix + "/z/"):
                    for n in nodes.values():
                        if int(k.rsplit("/", 1)[1]) in n.in_neighbours:
                            msgs += n.on_z(k, p)
        elif isinstance(a, R.Record):
            rows.append(a)
        elif isinstance(a, R.Event) and events is not None:
            events.append(a)
        elif isinstance(a, (R.Stop,)):
            raise AssertionError(a.message)
    assert m.finished
    return m, rows


@pytest.mark.parametrize("example", ["paper_discrete", "paper_continuous_switching"])
def test_in_process_protocol_equals_simulate(example):
    from splitspec_core.simulation.simulator import simulate

    m, rows = play(example, changes={"run": {"steps": 30}})
    tr = simulate(m.des, seed=m.sc.run.seed, steps=30)
    xhat = np.array([r.xhat for r in rows])
    assert xhat.shape == tr.xhat.shape
    assert np.max(np.abs(xhat - tr.xhat)) <= 1e-12 * max(1.0, np.abs(tr.xhat).max())
    assert np.allclose(np.array([r.x for r in rows]), tr.x, rtol=0, atol=1e-12 * max(1.0, np.abs(tr.x).max()))


@pytest.mark.parametrize("example,changes", [
    ("ring10_partition", {"run": {"steps": 40}}),
    ("ring10", {"run": {"steps": 25}, "network": {"loss": 0.2, "arcs": [{"arc": [1, 6], "loss": 0.6}]}}),
    ("paper_continuous", {"run": {"steps": 30}, "network": {"loss": 0.3}}),
])
def test_in_process_protocol_loses_what_simulate_loses(example, changes):
    """Agents drawing their own losses and cutting a partition, the machine collecting what they report: the
    simulator's lost rows and trajectory (the agents' rule is realized_row, the simulator's loop the same)."""
    from splitspec_core.simulation.simulator import simulate

    m, rows = play(example, changes=changes)
    steps = changes["run"]["steps"]
    tr = simulate(m.des, seed=m.sc.run.seed, steps=steps, estimator="loop")
    lost = np.array(sorted(r[:4] for rec in rows for r in rec.lost), dtype=np.int64).reshape(-1, 4)
    causes = np.array([r[4] for r in sorted(r for rec in rows for r in rec.lost)], dtype=np.int8)
    assert len(lost) > 20 and np.array_equal(lost, tr.lost) and np.array_equal(causes, tr.lost_cause)
    xhat = np.array([r.xhat for r in rows])
    assert np.max(np.abs(xhat - tr.xhat)) <= 1e-12 * max(1.0, np.abs(tr.xhat).max())


def test_rounds_summarise_lost_messages_once_per_event_time():
    events: list = []
    m, rows = play("ring10", changes={"run": {"steps": 5}, "network": {"loss": 0.3}}, events=events)
    summaries = [e for e in events if e.name == "messages_lost"]
    per_tau = {r.tau: len(r.lost) for r in rows if r.lost}
    assert per_tau and {e.fields["tau"]: e.fields["count"] for e in summaries} == per_tau  # one line per event time
    assert all(e.fields["count"] == e.fields["loss"] for e in summaries)  # every one drawn lost, none late
    assert all(r[0] == rec.tau for rec in rows for r in rec.lost)


def test_an_admission_estimate_crossing_a_rerun_still_counts():
    """Agent 2 rejoins at tau; agent 3 dies before agent 2's fresh x_2(tau) (sent for attempt 0) arrives."""
    m = machine()
    start(m, 1.0)
    m.on_token("agent", 2, "n2", False, 1.1)  # agent 2 lost during round 0
    finish_round(m, 1.2)
    m.on_hello("q", hello("agent", 2, "fresh", 300), 1.3)
    m.on_token("agent", 2, "fresh", True, 1.4)
    out = finish_round(m, 1.5, skip=(2,))  # round 1 ends; round 2 starts with agent 2 admitted
    assert events(out, "agent_rejoined") and (m.tau, m.attempt) == (2, 0)
    m.on_token("agent", 3, "n3", False, 1.6)  # agent 3 dies: round 2 re-run (attempt 1)
    assert m.attempt == 1
    x = np.zeros(m.sc.n)
    m.on_xhat(2, 2, 0, 1, x, report(), {}, 1.7)  # agent 2's admission estimate, sent at attempt 0, arrives now
    m.on_truth(2, 1, x, {}, 1.8)
    for a in (1, 2):
        out = m.on_xhat(a, 3, 1, m.incarnation(a), x, report(), {}, 1.9)
    assert of(out, R.Record) and m.tau == 3


# ---------------------------------------------------------------------- live sensors (scenario sources:)

SENSORS = {"sources": {1: "s/1", 2: "s/2", 3: "s/3"}, "run": {"pace": 1000.0, "steps": 3}}


def test_with_live_sensors_no_plant_is_spawned_awaited_or_admitted():
    m = machine(changes=SENSORS, spawned=True)
    assert [(s.role, s.ident) for s in of(m.start(0.0), R.Spawn)] == [("agent", 1), ("agent", 2), ("agent", 3)]
    out = m.on_hello("q", hello("plant", 0, "p0", 100), 0.1)
    (refused,) = of(out, R.ReplyRefused)
    assert "live sensors" in refused.reason and not of(out, R.ReplyConfig)
    out = []
    for k, a in enumerate(m.sc.agent_ids):
        out += m.on_hello(f"q{a}", hello("agent", a, f"n{a}", 200 + k), 0.2)
        out += m.on_token("agent", a, f"n{a}", True, 0.2)
    assert events(out, "run_started") and of(out, R.Tick)  # the agents alone start the run


def test_with_live_sensors_rounds_complete_without_truth_and_record_the_y_used():
    m = machine(changes=SENSORS)
    for k, a in enumerate(m.sc.agent_ids):
        m.on_hello(f"q{a}", hello("agent", a, f"n{a}", 200 + k), 0.0)
        m.on_token("agent", a, f"n{a}", True, 0.0)
    x = np.ones(m.sc.n)
    records, t, evs = [], 0.0, []
    for tau in range(4):
        t = max(t, tau / 1000.0) + 0.01
        out = m.on_timer(t)  # the pace's tick
        for a in sorted(m.alive):
            if a not in m.est.get(m.tau, {}):
                out += m.on_xhat(a, m.tau, m.attempt, m.incarnation(a), x, report(), {}, t)
            if m.tau < m.plan.steps:
                used = None if (a, m.tau) == (2, 1) else [float(a), float(m.tau)]  # agent 2 had none at 1
                out += m.on_xhat(a, m.tau + 1, m.attempt, m.incarnation(a), x, report(), {}, t, y=used)
        records += of(out, R.Record)
        evs += [(e.name, e.fields) for e in of(out, R.Event) if e.name.startswith("sensor_")]
    assert [r.tau for r in records] == [0, 1, 2, 3] and m.finished
    # agent 2's sensor, heard at 0, silent at 1, back at 2: one event each (none for the final event time 3)
    assert evs == [("sensor_lost", {"agent": 2, "tau": 1}), ("sensor_back", {"agent": 2, "tau": 2, "silent": 1})]
    assert all(np.isnan(r.x).all() for r in records)  # no truth: x unknown, never waited for
    assert records[1].y == ((1, [1.0, 1.0]), (2, None), (3, [3.0, 1.0]))
    assert records[3].y == ((1, None), (2, None), (3, None))  # the final event time has no round
    # a round timeout is not a lost plant: a status query without a plant answer blames no plant
    m2 = machine(changes=SENSORS)
    for k, a in enumerate(m2.sc.agent_ids):
        m2.on_hello(f"q{a}", hello("agent", a, f"n{a}", 200 + k), 0.0)
        m2.on_token("agent", a, f"n{a}", True, 0.0)
    out = advance(m2, 0.0, 1.5, plant=False)  # silent agents: probed, all answer, nobody (no plant) blamed
    assert of(out, R.QueryStatus) and not of(out, R.Stop) and not m2.finished
