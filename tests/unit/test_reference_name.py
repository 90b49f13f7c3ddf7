"""The rate-shifted centralized reference is named for what it is (issue 46, finding 11).

:func:`splitspec_core.synthesis.kalman.references` gives, when the Kalman filter decays slower than the rate, the
Riccati design of the model shifted by the rate (the Kalman filter designed for A/rate).  It is certified at the
rate, but it is not the optimum under the rate, so a distributed design can beat it (issue 46 met 0.731x of it).
Every line, table, figure label and doc that shows it uses the one name (``kalman.SHIFTED_NAME``/``SHIFTED_LABEL``)
and never calls it the best.
"""

from __future__ import annotations

import re

import splitspec_core as ss
from splitspec_core.studies.rate_sweep import rate_sweep_table
from splitspec_core.synthesis.designer import design
from splitspec_core.synthesis.kalman import SHIFTED_LABEL, SHIFTED_NAME, references
from splitspec_core.synthesis.report import design_text
from tests.conftest import ROOT


def noisy():
    return ss.scenario(A=[[0.9, 0.2], [0, 0.8]], C={1: [[1, 0]], 2: [[0, 1]]}, graphs={"a": [(1, 2), (2, 1)]},
                       rate=0.2, process_noise=0.1, measurement_noise=0.1, gains="place")


def test_the_design_report_names_the_rate_shifted_reference():
    sc = noisy()
    kf, ref = references(sc, 0.2)
    assert ref is not kf and kf.radius >= 0.2  # the shifted design is the reference shown
    line = next(x for x in design_text(design(sc)).splitlines() if x.startswith("noise: "))
    assert f"x {SHIFTED_NAME} ({ref.rms:.3g}; a rate-shifted Riccati design, not the optimum under the rate)" in line
    assert "best" not in line


def test_the_rate_sweep_table_labels_it():
    res = {"time": "discrete", "rows": [{"rate": 0.5, "whole": {"rms": 1.0, "certified": True, "q": 2},
                                         "split": {"rms": 2.0, "certified": True}, "kalman": 0.5,
                                         "reference": 0.9, "kcf": 1.5}]}
    header = rate_sweep_table(res)[1]
    assert "KF for A/rate" in header and "best" not in header.lower()
    assert "A/rate" in SHIFTED_LABEL and "best" not in SHIFTED_LABEL


def test_no_line_calls_it_the_best():
    """No source, doc or benchmark says "best centralized" (the words once used for it); the one name is used."""
    said = []
    for folder in ("splitspec_core", "orchestrator", "docs", "benchmarks", "examples"):
        for path in (ROOT / folder).rglob("*"):
            if path.suffix in (".py", ".md", ".rst", ".yaml") and path.is_file():
                text = path.read_text(encoding="utf-8", errors="replace")
                said += [f"{path.relative_to(ROOT)}: {m.group(0)}"
                         for m in re.finditer(r"best\s+centrali[sz]ed[^\n]*", text, flags=re.IGNORECASE)]
    assert not said, said
