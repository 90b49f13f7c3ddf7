"""Forged and malformed input on the key space is dropped and counted; the trajectory is unchanged.

The deployment is started by hand (orchestrator with --listen, plant and agents with --connect, no
--secure), as a user would on several machines; a rogue Zenoh session that was never admitted joins the
same router and injects garbage, well-formed forgeries (a tick far in the future with empty rows, a
measurement for the current event time) and malformed messages during the run.  None carries the run's
MAC, so every receiver drops them in its Zenoh callback (``bad_mac``), before decoding or buffering.
What an *admitted* process could send badly (wrong run, shape, NaN, stale, future, bad k...) is checked
message by message in tests/unit/test_agent_node.py.
"""

import os
import threading
import time
from contextlib import contextmanager

import msgpack
import numpy as np
import pytest

from splitspec_core.runtime.bus import open_session
from splitspec_core.runtime.wire import MAC_BYTES, SCHEMA_VERSION, Keys, WireError, decode, encode
from tests.integration.runtime_helpers import (assert_all_gone, compare_with_simulate, dump, events, free_port,
                                               scenario_file, start, started_pids, wait_for_event, wait_for_listener)

pytestmark = pytest.mark.slow


def rogue(endpoint: str, run_id: str, stop: threading.Event, sent: dict, *, credentials=None, only=None) -> None:
    """Inject every kind of bad message, keyed to the live event time read from the ticks.

    ``credentials``: (user, password) for a secure router; ``only``: inject only on these keys.
    """
    keys = Keys(run_id)
    user, password = credentials or (None, None)
    s = open_session("client", connect=[endpoint], user=user, password=password, connect_timeout_ms=5000)
    taus = []

    def on_tick(smp):
        try:
            # the MAC authenticates, it does not hide: anyone on the router can read the body
            taus.append(decode(smp.payload.to_bytes()[:-MAC_BYTES], run_id, "tick"))
        except WireError:  # our own garbage tick
            pass

    sub = s.declare_subscriber(keys.tick, on_tick)
    pubs = {k: s.declare_publisher(k) for k in (keys.z(1), keys.z(2), keys.y, keys.xhat(2), keys.truth,
                                                keys.tick)}
    n = 4
    try:
        while not stop.is_set():
            if not taus:
                time.sleep(0.01)
                continue
            t = taus[-1]
            tau, att = t["tau"], t["attempt"]
            bad = {
                "garbage": (keys.z(1), os.urandom(37)),
                "wrong_run": (keys.z(2), encode("z", "another-run", tau=tau, attempt=att, k=0, agent=2, z=np.zeros(n))),
                "bad_shape": (keys.z(1), encode("z", run_id, tau=tau, attempt=att, k=1, agent=1, z=np.zeros(n + 1))),
                "non_finite": (keys.z(2), encode("z", run_id, tau=tau, attempt=att, k=1, agent=2,
                                                 z=np.array([np.nan, 0, 0, 0]))),
                "stale": (keys.z(1), encode("z", run_id, tau=tau - 1, attempt=att, k=0, agent=1, z=np.ones(n))),
                "future": (keys.z(2), encode("z", run_id, tau=tau + 3, attempt=att, k=0, agent=2, z=np.ones(n))),
                "bad_k": (keys.z(1), encode("z", run_id, tau=tau, attempt=att, k=99, agent=1, z=np.ones(n))),
                "y_shape": (keys.y, encode("y", run_id, tau=tau, attempt=att, y=np.zeros(5))),
                "xhat_garbage": (keys.xhat(2), msgpack.packb({"v": SCHEMA_VERSION, "run": run_id, "type": "xhat"})),
                "truth_nan": (keys.truth, encode("truth", run_id, tau=tau, attempt=att, x=np.full(n, np.inf),
                                                 rejected={})),
                "tick_garbage": (keys.tick, b"\xff\x00tick"),
                # well-formed forgeries: a tick from the far future with no rows (used to make every agent
                # restart) and a measurement for the current event time (used to shift the trajectory)
                "tick_future": (keys.tick, encode("tick", run_id, tau=2 ** 62, attempt=0, graph=0, alive=[], rows={},
                                                  final=False, incarnation={}, fresh=False, prev_attempt=0,
                                                  partition=[])),
                "y_forged": (keys.y, encode("y", run_id, tau=tau, attempt=att, y=np.full(3, 1e6))),
            }
            for name, (key, payload) in bad.items():
                if only is not None and key not in only:
                    continue
                pubs[key].put(payload)
                sent[name] = sent.get(name, 0) + 1
            time.sleep(0.02)
    finally:
        sub.undeclare()
        s.close()


@contextmanager
def rogue_during_hand_started_run(tmp_path, scen, out, run_id, *, creds=None, **rogue_kw):
    """Orchestrator (--listen), plant and agents 1..3 started by hand, and a rogue session injecting once the run
    has started. Yields ``(endpoint, procs, sent)``; on exit every process must have ended with 0 and be gone."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    logs = [tmp_path / f"{name}.log" for name in ("orch", "plant", "a1", "a2", "a3")]

    def secure(user):
        return ["--credentials", creds / f"{user}.cred"] if creds else []

    procs = [start("orchestrator", scen, "--listen", endpoint, "--out", out, "--run-id", run_id,
                   *(["--secure", creds] if creds else []), log=logs[0])]
    wait_for_listener(endpoint)  # processes started by hand give the router 2.5 s
    procs.append(start("plant", "--connect", endpoint, "--run-id", run_id, *secure("plant"), log=logs[1]))
    procs += [start("agent", "--id", i, "--connect", endpoint, "--run-id", run_id, *secure(f"agent-{i}"),
                    log=logs[1 + i]) for i in (1, 2, 3)]
    stop = threading.Event()
    sent: dict = {}
    th = threading.Thread(target=rogue, args=(endpoint, run_id, stop, sent), kwargs=rogue_kw, daemon=True)
    try:
        wait_for_event(out, "run_started", timeout=60)
        th.start()
        yield endpoint, procs, sent
        # the rogue stops with the run: what it sends while the processes shut down is never counted (on a starved
        # machine that once was most of it)
        deadline = time.monotonic() + 120
        while (procs[0].poll() is None and time.monotonic() < deadline
               and not any(e["event"] == "run_finished" for e in events(out))):
            time.sleep(0.05)
        stop.set()
        th.join(timeout=10)
        assert procs[0].wait(timeout=120) == 0, dump(*logs)
    finally:
        stop.set()
        th.join(timeout=10)
        for p in procs:
            if p.poll() is None:
                p.kill()
    for p in procs[1:]:
        assert p.wait(timeout=15) == 0, dump(*logs)
    assert_all_gone(started_pids(out).values())


def test_rogue_messages_are_dropped_and_counted(tmp_path):
    # 6 s of rounds: the rogue's session, started once the run has, has most of them to send in
    scen = scenario_file(tmp_path, "paper_discrete", run={"steps": 150, "pace": 25})
    out = tmp_path / "out"
    with rogue_during_hand_started_run(tmp_path, scen, out, "rogue-test") as (_, _, sent):
        pass
    assert sum(sent.values()) > 100
    rej, lines = {}, 0
    for e in events(out):
        if e["event"] == "message_rejected":
            lines += 1
            rej.setdefault(e["reason"], 0)
            rej[e["reason"]] += e["count"]
    # every forged message was refused for want of the run's key (the orchestrator's own and the agents' and
    # plant's counts), summarised once per second per process and reason, not one line per message
    assert set(rej) == {"bad_mac"} and rej["bad_mac"] >= sum(sent.values()) // 2, rej
    seconds = next(e for e in events(out) if e["event"] == "run_finished")["seconds"]
    assert lines <= 5 * (seconds + 2), (lines, seconds)  # at most one per process (5) and reason per second
    # and none of it changed the estimates: the run still equals the simulator
    compare_with_simulate(out, scen, tmp_path)
