"""The orchestrator's terminal progress line: the max error with the truth, else the consensus disagreement
(a run on live sensors or on measurements without truth never shows an error it cannot know)."""

import numpy as np

from splitspec_orchestrator.driver import Progress


def line(capsys, max_err, xhat, alive):
    p = Progress(10, 2)
    p.enabled = True  # as on a terminal
    p.update(3, max_err, int(alive.sum()), force=True, xhat=xhat, alive_mask=alive)
    return capsys.readouterr().err


def test_without_truth_the_line_shows_the_disagreement(capsys):
    xhat = np.array([[0.0, 0.0], [3.0, 4.0]])
    both = np.array([True, True])
    assert "disagreement 5.000e+00" in line(capsys, float("nan"), xhat, both)
    assert "max error 2.500e-01" in line(capsys, 0.25, xhat, both)
    assert "disagreement 0.000e+00" in line(capsys, float("nan"), xhat, np.array([True, False]))  # one alive
