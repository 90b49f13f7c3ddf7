"""Chaos suite: real `splitspec run`s under duplicate identities, floods, freezes, load, deaths, full disks.

The cases live in tests/chaos/cases.py (shared with benchmarks/bench_faults.py --chaos); each one asserts the
exit code, the one-line message, no orphans, consistent records and run == simulate / replay where the run
completes.  Their figures are printed (pytest -s, or -rP) for the report.
"""

import pytest

from tests.chaos import cases as C

pytestmark = pytest.mark.slow


def _show(name, case, *args):
    """Run a case (it asserts), print its figures; a case that needs a tmpfs is skipped where none can be mounted."""
    try:
        figures = case(*args)
    except C.MountUnavailable as exc:
        pytest.skip(str(exc))
    print(f"\n{name}: " + ", ".join(f"{k} {v}" for k, v in figures.items()))


@pytest.mark.long
def test_duplicate_id_is_refused_and_the_holder_kept(tmp_path):
    _show("duplicate id", C.case_duplicate_id, tmp_path)


def test_flood_of_unsigned_future_messages_and_forgeries(tmp_path):
    _show("flood", C.case_flood, tmp_path)


def test_frozen_orchestrator_is_waited_for(tmp_path):
    _show("frozen orchestrator", C.case_frozen_orchestrator, tmp_path)


def test_loaded_machine_loses_nobody(tmp_path):
    _show("loaded machine", C.case_loaded_machine, tmp_path)


@pytest.mark.parametrize("who", ["plant", "agent"])
def test_death_during_start_up_stops_the_run_at_once(tmp_path, who):
    f = C.case_plant_dies_at_startup if who == "plant" else C.case_agent_dies_at_startup
    _show(f"{who} death at start-up", f, tmp_path)


def test_plant_death_mid_run(tmp_path):
    _show("plant death mid-run", C.case_plant_dies_mid_run, tmp_path)


def test_orchestrator_sigkill_mid_run(tmp_path):
    _show("orchestrator SIGKILL", C.case_orchestrator_killed, tmp_path)


@pytest.mark.long
def test_orchestrator_takeovers_at_a_switch_a_roll_and_of_the_standby(tmp_path):
    _show("orchestrator takeovers", C.case_orchestrator_takeovers, tmp_path)


def _need_mount():
    if not C.can_mount():
        pytest.skip("needs root to mount a tmpfs")


def test_full_disk(tmp_path):
    _need_mount()
    _show("full disk", C.case_full_disk, tmp_path)


def test_read_only_out(tmp_path):
    _need_mount()
    _show("read-only --out", C.case_read_only_out, tmp_path)


@pytest.mark.long
def test_agent_sigstop_then_sigcont(tmp_path):
    _show("agent SIGSTOP/SIGCONT", C.case_agent_frozen, tmp_path)


@pytest.mark.parametrize("seed", [1, 5])  # 2 and 3 victims
def test_random_multi_kills(tmp_path, seed):
    _show(f"random kills seed {seed}", C.case_random_kills, tmp_path, seed)


@pytest.mark.long
def test_kill_and_restart_storm(tmp_path):
    _show("kill-and-restart storm", C.case_restart_storm, tmp_path)
