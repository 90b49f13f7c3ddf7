"""launcher.spawn: the processes of a run die with the process that started them (PR_SET_PDEATHSIG, asked for by
the child itself, so that spawning can vfork)."""

import os
import signal
import subprocess
import sys
import time

from splitspec_orchestrator.registry import pid_running, process_state
from splitspec_core.runtime.cli import PARENT_ENV

CHILD = "from splitspec_core.runtime.cli import die_with_parent; die_with_parent(); import time; time.sleep(60)"


def test_a_spawned_process_dies_with_its_parent_even_a_sigkilled_one(tmp_path):
    ready = tmp_path / "ready"
    # the child says when it has asked for the signal; only then is the parent killed (before it, the child's
    # own check of its parent would stop it, and the test could not tell the signal from that check)
    child = ("import sys; from splitspec_core.runtime.cli import die_with_parent; die_with_parent(); "
             "open(sys.argv[1], 'w').close(); import time; time.sleep(60)")
    parent = ("import os, signal, sys, time\n"
              "from pathlib import Path\n"
              "from splitspec_orchestrator.launcher import spawn\n"
              f"p = spawn([sys.executable, '-c', {child!r}, {str(ready)!r}])\n"
              "print(p.pid, flush=True)\n"
              f"while not Path({str(ready)!r}).exists():\n"
              "    time.sleep(0.01)\n"
              "os.kill(os.getpid(), signal.SIGKILL)\n")
    r = subprocess.run([sys.executable, "-c", parent], capture_output=True, text=True, timeout=60)
    assert r.returncode == -signal.SIGKILL, r.stderr
    child = int(r.stdout.split()[0])
    deadline = time.monotonic() + 10
    while pid_running(child) and time.monotonic() < deadline:
        time.sleep(0.05)
    assert not pid_running(child)


def test_a_process_whose_parent_is_already_gone_stops_at_once():
    """The parent died while the child's interpreter was starting: the pid it left is no longer the child's parent."""
    # pid 0 is nobody's parent (1 would be, for a child reparented to init or a test run as pid 1)
    p = subprocess.Popen([sys.executable, "-c", CHILD], env={**os.environ, PARENT_ENV: "0"})
    assert p.wait(timeout=60) == -signal.SIGTERM


def test_a_spawned_process_keeps_running_and_its_own_children_do_not_inherit_the_parent():
    code = ("import os, sys\n"
            "from splitspec_core.runtime.cli import PARENT_ENV, die_with_parent\n"
            "assert os.environ[PARENT_ENV] == str(os.getppid())\n"
            "die_with_parent()\n"
            "print(os.environ.get(PARENT_ENV))\n")
    r = subprocess.run([sys.executable, "-c", f"import subprocess, sys; from splitspec_orchestrator.launcher import spawn; "
                        f"p = spawn([sys.executable, '-c', {code!r}]); sys.exit(p.wait())"],
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == 0 and r.stdout.strip() == "None", (r.stdout, r.stderr)


def test_a_starting_standby_is_idle_class_and_every_thread_it_started_leaves_it():
    """launcher.idle_class / normal_class: a process put in the idle class starts threads (as a standby's Zenoh
    session does); taken out, every thread is back in the normal class."""
    import pytest

    from splitspec_orchestrator.launcher import idle_class, normal_class

    if not hasattr(os, "SCHED_IDLE"):
        pytest.skip("no SCHED_IDLE here")
    code = ("import sys, threading, time\n"
            "sys.stdin.readline()\n"  # told: it is in the idle class now
            "for _ in range(3):\n"
            "    threading.Thread(target=time.sleep, args=(60,), daemon=True).start()\n"
            "print('threads', flush=True)\n"
            "time.sleep(60)\n")
    p = subprocess.Popen([sys.executable, "-c", code], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    try:
        if not idle_class(p.pid):
            pytest.skip("may not leave the idle class again here (not root, RLIMIT_NICE < 20)")
        assert os.sched_getscheduler(p.pid) == os.SCHED_IDLE
        p.stdin.write("go\n")
        p.stdin.flush()
        assert p.stdout.readline().strip() == "threads"
        tasks = [int(t) for t in os.listdir(f"/proc/{p.pid}/task")]
        assert len(tasks) == 4 and {os.sched_getscheduler(t) for t in tasks} == {os.SCHED_IDLE}
        normal_class(p.pid)
        assert {os.sched_getscheduler(t) for t in tasks} == {os.SCHED_OTHER}
    finally:
        p.kill()
        p.wait()


def test_process_state_tells_a_stopped_process_from_a_starved_one():
    """The orchestrator asks a process on its host that missed a status query once more unless ``/proc`` says it is
    stopped (SIGSTOP: ``T``), a zombie or gone: a starved process is slow, not frozen."""
    p = subprocess.Popen(["sleep", "30"])
    try:
        deadline = time.monotonic() + 10
        while process_state(p.pid) != "S" and time.monotonic() < deadline:  # exec'd and asleep
            time.sleep(0.01)
        assert process_state(p.pid) == "S"
        os.kill(p.pid, signal.SIGSTOP)
        while process_state(p.pid) != "T" and time.monotonic() < deadline:
            time.sleep(0.01)
        assert process_state(p.pid) == "T" and pid_running(p.pid)  # stopped, not dead
        os.kill(p.pid, signal.SIGCONT)
        while process_state(p.pid) == "T" and time.monotonic() < deadline:
            time.sleep(0.01)
        assert process_state(p.pid) in ("R", "S")
        p.kill()
        while process_state(p.pid) != "Z" and time.monotonic() < deadline:  # dead, not yet reaped
            time.sleep(0.01)
        assert process_state(p.pid) == "Z" and not pid_running(p.pid)
    finally:
        p.kill()
        p.wait()
    assert process_state(p.pid) is None and process_state(-1) is None
