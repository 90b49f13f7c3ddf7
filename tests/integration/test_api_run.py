"""``ss.run``, ``ss.load_run``, ``ss.view``: the multi-process run from Python, read back as the simulator's
``Trajectory`` (real processes over real Zenoh on loopback, started by the API as ``splitspec run`` would be)."""

from __future__ import annotations

import dataclasses
import signal
import time
import urllib.request

import numpy as np
import pytest

import splitspec_core as ss
from tests.integration.runtime_helpers import EXAMPLES, free_port
from tests.numerics import assert_close

pytestmark = pytest.mark.slow


def test_a_run_from_python_reads_back_as_the_simulation_with_its_kill_and_rejoin(tmp_path):
    sc = ss.load_scenario(EXAMPLES / "ring10_faults.yaml")
    rec = ss.run(sc, out=tmp_path / "run")
    sim = ss.simulate(sc)
    tr = rec.trajectory
    assert isinstance(tr, ss.Trajectory) and tr.xhat.shape == sim.xhat.shape
    assert np.array_equal(tr.alive, sim.alive)  # the same deaths and rejoins at the same event times
    # another path than the simulator's (per-agent steps in their own processes, vectorised in-process): the
    # estimates are O(1) to O(10), so round-off is ~1e-15 of them; 1e-12 of the largest leaves room for any kernel
    assert_close(tr.xhat, sim.xhat, rtol=1e-12, equal_nan=True, what="run xhat against simulate")
    assert_close(tr.x, sim.x, rtol=1e-12, what="the plant's x")
    assert rec.named("agent_lost") and rec.named("agent_rejoined")
    assert rec.design().q == ss.design(sc).q
    again = ss.load_run(tmp_path / "run")  # any run's directory, read again: the same file, the same arrays
    assert np.array_equal(again.trajectory.xhat, tr.xhat, equal_nan=True) and again.events == rec.events


def test_a_python_scenario_with_faults_given_to_run(tmp_path):
    sc = ss.scenario(A=[[0.9, 0.2], [-0.2, 0.9]], C={1: [[1, 0]], 2: [[0, 1]], 3: [[1, 1]]},
                     graphs={"a": [(1, 2), (2, 1), (2, 3), (3, 2), (3, 1), (1, 3)]}, time="discrete", rate=0.5,
                     gains="place", steps=20, seed=3)
    faults = [{"at": 5, "kill": 3}]
    rec = ss.run(sc, out=tmp_path / "run", faults=faults)
    assert [e["id"] for e in rec.named("agent_lost")] == [3] and not rec.trajectory.alive[6:, 2].any()
    # the run played the scenario with those faults: its scenario.yaml simulates to the same trajectory
    assert_close(rec.trajectory.xhat, ss.simulate(rec.scenario).xhat, rtol=1e-12, equal_nan=True)


def test_bad_input_to_the_api_is_one_line(tmp_path):
    with pytest.raises(ss.ScenarioError, match="has no trajectory.npz or chunks/: not a run's output directory"):
        ss.load_run(tmp_path)
    with pytest.raises(ss.ScenarioError, match="is not a directory"):
        ss.load_run(tmp_path / "absent")
    sc = ss.load_scenario(EXAMPLES / "paper_discrete.yaml")
    with pytest.raises(ss.ScenarioError, match="was not made by ss.scenario or ss.load_scenario"):
        ss.run(dataclasses.replace(sc, name="changed"), out=tmp_path / "x")
    with pytest.raises(ss.RunError) as err:  # the command's own one-line error, and its status
        ss.run(sc, out=tmp_path / "y", measurements=tmp_path / "absent.csv")
    assert err.value.status == 2 and "absent.csv" in str(err.value) and "\n" not in str(err.value)
    with pytest.raises(ss.ScenarioError, match="absent.yaml"):  # a file that is not there: one line, no OSError
        ss.run(tmp_path / "absent.yaml", out=tmp_path / "z")
    with pytest.raises(ss.ScenarioError, match="has no run.rrd"):
        ss.view(tmp_path)


def test_view_serves_a_run_from_python(tmp_path):
    sc = ss.load_scenario(EXAMPLES / "paper_discrete.yaml")
    ss.run(sc, out=tmp_path / "run")
    port = free_port()
    proc = ss.view(tmp_path / "run", port=port)
    try:
        deadline, page = time.monotonic() + 30, None
        while page is None and time.monotonic() < deadline and proc.poll() is None:
            try:
                page = urllib.request.urlopen(f"http://127.0.0.1:{port}/", timeout=2).read()
            except OSError:
                time.sleep(0.3)
        assert page and b"<html" in page.lower(), proc.poll()
    finally:
        proc.send_signal(signal.SIGINT)
        assert proc.wait(timeout=20) in (0, 130, -2)


def test_the_notebook_tutorial_executes(tmp_path):
    """docs/tutorials/notebook_workflow.py (a jupytext notebook) as a script: design, simulate, run with a kill
    and a restart, the comparison it asserts itself, the plot."""
    import os
    import subprocess
    import sys

    from tests.integration.runtime_helpers import ENV, ROOT

    r = subprocess.run([sys.executable, str(ROOT / "docs" / "tutorials" / "notebook_workflow.py")], cwd=tmp_path,
                       env={**ENV, "SPLITSPEC_OUT": str(tmp_path / "nb"), "MPLBACKEND": "Agg"},
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stdout + r.stderr
    assert "('agent_lost', 10), ('agent_rejoined', 20)" in r.stdout
    assert (tmp_path / "nb" / "errors.png").stat().st_size > 10_000 and (tmp_path / "nb" / "run.rrd").is_file()
    assert os.path.isfile(tmp_path / "nb" / "trajectory.npz")


def test_view_inline_hands_the_whole_recording_to_the_notebook_widget(tmp_path):
    """``ss.view(out, inline=True)``: Rerun's notebook widget, fed run.rrd by Rerun's own loader.  Outside a
    notebook nothing displays it, so the widget queues what it was sent until a front end says it is ready:
    that queue is read back (the widget's private ``_event_queue``: the only place the data is visible without a
    browser) and decoded as a recording with every entity of run.rrd."""
    pytest.importorskip("rerun_notebook")  # in the dev extra: installed by make test
    from rerun.chunk import RrdReader

    ss.run(ss.load_scenario(EXAMPLES / "paper_discrete.yaml"), out=tmp_path / "run")
    viewer = ss.view(tmp_path / "run", inline=True)
    assert type(viewer).__module__ == "rerun.notebook"
    sent = [bytes(b) for event, buffers in viewer._viewer._event_queue if event == {"type": "rrd"}
            for b in buffers or []]
    assert sent and all(b.startswith(b"RRF2") for b in sent)  # each message is a whole RRD stream
    for k, b in enumerate(sent):
        (tmp_path / f"sent{k}.rrd").write_bytes(b)

    def entities(*paths):
        found = set()
        for path in paths:
            try:
                chunks = list(RrdReader(path).stream())
            except ValueError as exc:  # a message may carry only the stream's start, no data yet
                assert "No recording store" in str(exc)
                continue
            found |= {c.entity_path for c in chunks if not c.entity_path.startswith("/__")}  # Rerun's own
        return found

    want = entities(tmp_path / "run" / "run.rrd")
    assert "/errors/agent_1" in want
    assert entities(*(tmp_path / f"sent{k}.rrd" for k in range(len(sent)))) == want
