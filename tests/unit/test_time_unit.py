"""system.time_unit (issue 46, finding 9): the model's time printed in its own unit, not always seconds.

A user's model in minutes, sampled every minute (``system.sample: 1.0``), read ``system.sample = 1 s``: the unit was
stated nowhere.  The key is declared once (scenarios/keys.py, default ``s``); every line printing a time of the model
or a rate per it uses it; the run's wall clock stays in seconds.
"""

from __future__ import annotations

import numpy as np
import pytest

import splitspec_core as ss
from splitspec_core.errors import ScenarioError
from splitspec_core.synthesis.report import design_json, model_lines
from splitspec_orchestrator.commands.deploy import default_steps_line


def building(**keys):
    """Two rooms with wall masses, a continuous model in minutes sampled every minute, two thermometers."""
    A = [[-0.02, 0.01, 0.01, 0.0], [0.005, -0.005, 0.0, 0.0], [0.01, 0.0, -0.03, 0.01], [0.0, 0.0, 0.004, -0.004]]
    return ss.scenario(A=A, C={1: [[1, 0, 0, 0]], 2: [[0, 0, 1, 0]]}, graphs={"g": [(1, 2), (2, 1)]}, rate=0.999,
                       sample=1.0, **keys)


def test_the_sampled_model_is_printed_in_the_scenarios_time_unit():
    (line,) = model_lines(building(time_unit="min"))
    assert "system.sample = 1 min (zero-order hold)" in line and " per min, " in line and line.endswith("t in min")
    assert " s " not in line and "second" not in line, line
    # the default: seconds, as before
    (line,) = model_lines(building())
    assert "system.sample = 1 s (zero-order hold)" in line and " per second, " in line


def test_the_design_json_states_the_unit():
    assert design_json(ss.design(building(time_unit="h")).detail)["time_unit"] == "h"


def test_run_dt_of_a_continuous_scenario_is_printed_in_its_unit():
    sc = ss.scenario(A=np.diag([-1.0, -2.0]), C={1: [[1, 0]], 2: [[0, 1]]}, graphs={"g": [(1, 2), (2, 1)]},
                     rate=0.5, time="continuous", time_unit="ms")
    assert sc.system.time_unit == "ms" and sc.system.per_time == "per ms"
    assert "of run.dt 0.01 ms" in default_steps_line(sc)


@pytest.mark.parametrize("unit", ["2 min", "", "minutes-and-more", 3])
def test_a_time_unit_that_is_not_a_short_word_is_one_line(unit):
    with pytest.raises(ScenarioError) as e:
        building(time_unit=unit)
    assert str(e.value).startswith("system.time_unit must be a short word of letters") and "\n" not in str(e.value)
