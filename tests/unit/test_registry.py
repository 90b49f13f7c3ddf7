"""The run registry and `splitspec kill`: unique run ids, choosing the run, signalling only this user's processes.

Real dummy processes stand in for a run: a `python -c` sleeper whose argv names splitspec (as every
splitspec process's does) is the orchestrator or an agent; the registry lives in a private
SPLITSPEC_RUNTIME_DIR.
"""

import json
import os
import re
import signal
import subprocess
import sys
import time

import pytest

from splitspec_orchestrator import registry
from splitspec_orchestrator.cli import main
from splitspec_core.errors import SplitspecError
from splitspec_core.runtime.wire import Keys

SLEEPER = "import time; time.sleep(60)"


@pytest.fixture
def rt(tmp_path, monkeypatch):
    d = tmp_path / "rt"
    d.mkdir(mode=0o700)
    monkeypatch.setenv("SPLITSPEC_RUNTIME_DIR", str(d))
    return d


@pytest.fixture
def procs():
    started = []

    def spawn(*argv, **kw):
        p = subprocess.Popen(list(argv), **kw)
        started.append(p)
        return p

    yield spawn
    for p in started:
        if p.poll() is None:
            p.kill()
        p.wait()


def dummy(procs, role="agent"):
    """A live process that looks like a splitspec process (its argv contains 'splitspec')."""
    return procs(sys.executable, "-c", SLEEPER, f"splitspec-dummy-{role}")


def write_entry(rt, run_id, orch_pid, agents=(), **extra):
    path = rt / f"{run_id}.{orch_pid}.json"
    path.write_text(json.dumps({"run_id": run_id, "orchestrator": {"pid": orch_pid}, "out": f"/tmp/out-{run_id}",
                                "host": os.uname().nodename, "started": time.time(), "written": registry.now_mark(),
                                "agents": {str(i): {"pid": pid, "host": os.uname().nodename}
                                           for i, pid in agents}, **extra}))
    return path


def alive(p) -> bool:
    return p.poll() is None


def test_new_run_ids_are_unique_short_and_valid_keys():
    ids = {registry.new_run_id() for _ in range(2000)}
    # 32 random bits: 2000 draws collide once with probability about 2000**2 / 2**33 = 5e-4 (CI met one), three
    # times with about 2e-11; a constant or a counter-free clock would collide at once
    assert len(ids) >= 1998
    for rid in list(ids)[:50]:
        assert re.fullmatch(r"r[0-9a-f]{8}", rid)
        assert Keys(rid).prefix == f"splitspec/{rid}" and registry.check_run_id(rid) == rid
    # the registry's (import-light) check refuses exactly what wire.Keys refuses
    for bad in ("", "a/b", "a*", "x$", "q?", "h#"):
        with pytest.raises(SplitspecError):
            Keys(bad)
        with pytest.raises(SplitspecError, match="--run-id"):
            registry.check_run_id(bad)


def test_kill_without_run_id_and_no_live_run(rt, capsys):
    assert main(["kill", "--agent", "1"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("splitspec: error: no live run of yours") and err.count("\n") == 1


def test_kill_without_run_id_refuses_with_two_live_runs_and_lists_them(rt, procs, capsys):
    o1, o2, a1, a2 = (dummy(procs) for _ in range(4))
    write_entry(rt, "rone", o1.pid, [(1, a1.pid)])
    write_entry(rt, "rtwo", o2.pid, [(1, a2.pid)])
    assert main(["kill", "--agent", "1"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("splitspec: error: 2 live runs of yours") and "--run-id" in err
    lines = err.splitlines()[1:]
    assert len(lines) == 2
    for line, rid, o in zip(lines, ("rone", "rtwo"), (o1, o2)):
        assert line.split()[0] == rid and f"orchestrator pid {o.pid}" in line and f"/tmp/out-{rid}" in line
        assert re.search(r"started \d{4}-\d\d-\d\d \d\d:\d\d:\d\d", line)
    assert all(alive(p) for p in (o1, o2, a1, a2))  # nothing signalled
    # with --run-id: that run only
    assert main(["kill", "--agent", "1", "--run-id", "rtwo"]) == 0
    assert a2.wait(timeout=10) == -signal.SIGKILL
    assert "of run 'rtwo'" in capsys.readouterr().out
    assert alive(a1) and alive(o1) and alive(o2)


def test_kill_without_run_id_acts_on_the_only_live_run(rt, procs, capsys):
    orch, a1, a2 = dummy(procs, "orchestrator"), dummy(procs), dummy(procs)
    write_entry(rt, "ronly", orch.pid, [(1, a1.pid), (2, a2.pid)])
    assert main(["kill", "--agent", "2", "--signal", "STOP"]) == 0
    assert f"sent SIGSTOP to agent 2 (pid {a2.pid}) of run 'ronly'" in capsys.readouterr().out
    assert main(["kill", "--agent", "2"]) == 0
    assert a2.wait(timeout=10) == -signal.SIGKILL
    assert alive(a1) and alive(orch)
    # the orchestrator dies: its entry is stale, swept, and kill has nothing to act on
    orch.kill()
    orch.wait()
    assert main(["kill", "--agent", "1"]) == 2 and "no live run" in capsys.readouterr().err
    assert list(rt.iterdir()) == [] and alive(a1)


def test_entries_and_directories_of_another_user_are_not_trusted(rt, procs, capsys):
    orch, a1 = dummy(procs), dummy(procs)
    path = write_entry(rt, "rother", orch.pid, [(1, a1.pid)])
    os.chown(path, 4242, -1)
    assert registry.find_runs("*") == [] and path.exists()  # ignored, not removed
    assert main(["kill", "--agent", "1"]) == 2 and "no live run" in capsys.readouterr().err
    assert main(["kill", "--agent", "1", "--run-id", "rother"]) == 2
    assert "no running run with id 'rother'" in capsys.readouterr().err
    os.chown(path, os.getuid(), -1)
    os.chown(rt, 4242, -1)  # a runtime directory someone else made
    assert main(["kill", "--agent", "1"]) == 2 and "is not owned by you" in capsys.readouterr().err
    assert alive(a1)


def test_a_reused_pid_is_never_signalled(rt, procs, capsys):
    orch = dummy(procs)
    plain = procs("sleep", "60")  # not a splitspec process
    # another user's (a shell: that user cannot run this virtualenv's python)
    foreign = procs("sh", "-c", "while :; do sleep 1; done", "splitspec-dummy", user=4242)
    write_entry(rt, "rreuse", orch.pid, [(1, plain.pid), (2, foreign.pid)])
    for aid, p in ((1, plain), (2, foreign)):
        assert main(["kill", "--agent", str(aid)]) == 2
        err = capsys.readouterr().err
        assert f"(pid {p.pid})" in err and "nothing signalled" in err
    time.sleep(0.1)
    assert alive(plain) and alive(foreign) and alive(orch)
    # a splitspec process of this user that started after the entry was written is not the one it names
    late = dummy(procs)
    mark = registry.now_mark()
    assert registry.is_own_splitspec_process(late.pid, started_before=mark)
    tick = os.sysconf("SC_CLK_TCK")
    assert not registry.is_own_splitspec_process(late.pid, started_before={**mark, "ticks": mark["ticks"] - 3 * tick})
    assert not registry.is_own_splitspec_process(late.pid, started_before={**mark, "boot_id": "another boot"})
    assert not registry.is_own_splitspec_process(plain.pid) and not registry.is_own_splitspec_process(foreign.pid)


def test_registry_resolve_and_stale_entries(rt, procs):
    reg = registry.RunRegistry("r1", {"endpoint": "tcp/127.0.0.1:1", "out": "/x", "host": "h"})
    orch, a3 = dummy(procs, "orchestrator"), dummy(procs)
    reg.data["orchestrator"]["pid"] = orch.pid  # this test process stands for nothing
    reg.data["agents"]["3"] = {"pid": a3.pid, "host": "h"}
    reg.update()
    assert (rt.stat().st_mode & 0o777) == 0o700
    pid, host, entry = registry.resolve("r1", "agent", 3)
    assert (pid, host) == (a3.pid, "h") and entry["endpoint"] == "tcp/127.0.0.1:1"
    assert entry["started"] == pytest.approx(time.time(), abs=30)
    assert registry.resolve(None, "agent", 3)[0] == a3.pid
    with pytest.raises(SplitspecError, match="agent 4 has not started"):
        registry.resolve("r1", "agent", 4)
    # an entry whose orchestrator is dead is stale: ignored and removed
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True)
    stale = write_entry(rt, "r2", int(dead.stdout))
    assert registry.find_runs("r2") == [] and not stale.exists()
    reg.remove()
    assert registry.find_runs("r1") == []
