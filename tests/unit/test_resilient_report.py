"""The report of a resilient design whose network is certified but whose survivors are not (issue 46, finding 7).

A model of one's own, written here: four rooms in a row, each with a heavy wall mass (8 states, a thermal RC
network per minute), each agent one room's thermometer, a ring, ``design.resilience: 1``, rate 0.9.  The walls are
weakly observable, so the split is approximate and the full error matrices decide: the ring itself is below the
rate, every ring without one agent is not.  The report then:

* says one verdict for the design as a whole, and which case each bound is about (no "certified bound" line
  before a "NOT certified" one);
* proposes in its advice only a rate it designed and certified;
* points ``design.rank_tol`` one way (down: count the weak directions), never also up;
* exits 0 as for any design made (certified or not, nominal or resilient); ``--json``'s ``certified_rate`` says it.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
import yaml

from splitspec_core.scenarios.load import parse_scenario
from splitspec_core.synthesis.advice import advice, fastest_rate
from splitspec_core.synthesis.designer import design
from splitspec_core.synthesis.report import design_text, design_warnings
from splitspec_core.synthesis.verdict import rate_certificate
from splitspec_orchestrator import cli


def building(rate: float = 0.9) -> dict:
    """Four rooms (x1..x4) with wall masses (x5..x8): room capacity 1, wall 20, room-wall conductance 0.03,
    room-room 0.1, outside 0.05; sampled each minute; agent i reads room i (agent 3's thermometer 20x noisier)."""
    n, Cr, Cw, k_rw, k_rr, k_out = 8, 1.0, 20.0, 0.03, 0.1, 0.05
    A = np.zeros((n, n))
    for i in range(4):
        r, w = i, 4 + i
        A[r, r] -= (k_rw + k_out) / Cr
        A[r, w] += k_rw / Cr
        A[w, w] -= (k_rw + k_out) / Cw
        A[w, r] += k_rw / Cw
        for j in (i - 1, i + 1):
            if 0 <= j < 4:
                A[r, r] -= k_rr / Cr
                A[r, j] += k_rr / Cr
    C = {i + 1: [[1.0 if k == i else 0.0 for k in range(n)]] for i in range(4)}
    return {"name": "building", "time": "discrete",
            "system": {"A": A.round(5).tolist(), "C": C, "sample": 1.0, "process_noise": 0.01,
                       "measurement_noise": {1: 0.1, 2: 0.1, 3: 2.0, 4: 0.1}},
            "graphs": {"ring": {"undirected": [[1, 2], [2, 3], [3, 4], [4, 1]]}},
            "design": {"rate": rate, "gains": "place", "resilience": 1}, "run": {"steps": 300, "seed": 1}}


@pytest.fixture(scope="module")
def resilient():
    return design(parse_scenario(building()))


def test_the_network_is_certified_its_survivors_not(resilient):
    full = resilient.full_radius
    assert full["ring"] < 0.9 and all(v >= 0.9 for k, v in full.items() if k != "ring"), full
    assert not rate_certificate(resilient).certified


def test_one_verdict_naming_the_case_each_bound_is_about(resilient):
    text = design_text(resilient)
    assert "certified bound" not in text  # the q line once said "certified bound 0.8863 <= 0.9"
    q_line = next(line for line in text.splitlines() if line.startswith("q = "))
    assert "on the split blocks only" in q_line and "the verdict below is the full error matrices'" in q_line
    verdicts = [line for line in text.splitlines() if line.startswith("rate ")]
    assert len(verdicts) == 1 and verdicts[0].startswith("rate NOT certified: "), verdicts
    worst = max(resilient.full_radius, key=resilient.full_radius.get)
    assert f" on {worst} (the worst of 5 cases" in verdicts[0] and "without losses, ring: " in verdicts[0]
    # every case's full error matrix is listed with its name
    for label in resilient.full_radius:
        assert f"  {label}: spectral radius of the full error matrix = " in text


def test_advice_proposes_only_a_certified_rate(resilient):
    reach = fastest_rate(resilient)
    assert reach is not None
    knobs = [t for t in advice(resilient) if t.knob.startswith("design.rate")]
    assert len(knobs) == 1 and knobs[0].certified is True, knobs
    proposed = float(knobs[0].knob.split(": ")[1])
    # discrete: a slower rate is a larger lam; the proposal is at least as slow as the search's certified bracket
    assert proposed >= reach.rate * (1 - 1e-12) > reach.refused
    slower = parse_scenario({**building(proposed)})
    assert rate_certificate(design(slower)).certified  # designed again from the proposal as a user would write it


def test_rank_tol_is_pointed_one_way(resilient):
    warnings = design_warnings(resilient)
    down = [w for w in warnings if "set design.rank_tol below" in w]
    up = [w for w in warnings if "leaves it to consensus)" in w]
    assert down and not up, warnings
    for t in advice(resilient):
        if t.knob.startswith("design.rank_tol: "):
            weakest = min(a.dec.weak for a in resilient.agents if a.dec.weak > 0)
            assert float(t.knob.split(": ")[1]) < weakest, t.knob


def test_the_exit_status_is_that_of_any_design_and_json_says_it(tmp_path, capsys):
    path = tmp_path / "building.yaml"
    path.write_text(yaml.safe_dump(building()))
    assert cli.main(["design", str(path), "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["certified_rate"] is False and out["certificate"].startswith("q = ")
    assert all(k["certified"] for k in out["advice"] if k["knob"].startswith("design.rate: "))
