"""What `splitspec run`'s terminal tells (issue 46, finding 8): ``--log-level events`` shows the run's events at INFO
too (a rejoin, a sensor repaired or restored) beside every warning, and no other INFO line."""

import subprocess
import sys

import pytest

from splitspec_core.runtime.cli import EVENTS_LOGGER

CODE = f"""
import logging
from splitspec_core.runtime.cli import ArgumentParser, add_logging_options, setup_logging
p = ArgumentParser(prog="t")
add_logging_options(p)
setup_logging(p.parse_args(__import__("sys").argv[1:]))
logging.getLogger({EVENTS_LOGGER!r}).info("agent 4 rejoins at event time 40")
logging.getLogger({EVENTS_LOGGER!r}).warning("agent 4 lost from event time 30")
logging.getLogger("splitspec.orchestrator").info("wall time 3.4 s")
logging.getLogger("splitspec.orchestrator").warning("live sensors: publish y_i on ...")
"""


@pytest.mark.parametrize("level, shown", [
    ("events", ["agent 4 rejoins", "agent 4 lost", "live sensors"]),
    ("warning", ["agent 4 lost", "live sensors"]),
    ("info", ["agent 4 rejoins", "agent 4 lost", "wall time", "live sensors"]),
    ("error", []),
])
def test_log_level_events_shows_the_run_s_events_and_the_warnings(level, shown):
    r = subprocess.run([sys.executable, "-c", CODE, "--log-level", level], capture_output=True, text=True,
                       timeout=60)
    assert r.returncode == 0, r.stderr
    said = [w for w in ("agent 4 rejoins", "agent 4 lost", "wall time", "live sensors") if w in r.stderr]
    assert said == shown, r.stderr
