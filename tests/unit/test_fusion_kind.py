"""The fusion kind in a design (``design.consensus: fusion``, issue 44): the budget q, its certificate, the report and
``--json``, what each agent is sent, the survivors' verdict, the simulator's one step path, the scenario's refusals."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

import splitspec_core as ss
from splitspec_orchestrator import cli
from splitspec_core.errors import ScenarioError
from splitspec_core.model import steps as st
from splitspec_core.simulation.simulator import simulate
from splitspec_core.synthesis.designer import design
from splitspec_core.synthesis.exchange_limit import scenario_limit
from splitspec_core.synthesis.fusion import scenario_fusion
from splitspec_core.synthesis.fusion_kind import (AUTO_GAP, FusionKind, agent_fusion, budget_text, survivors_radius)
from splitspec_core.synthesis.report import design_json, design_text
from splitspec_core.synthesis.survivors import certify_network
from splitspec_core.synthesis.error_matrix import predicted_rms
from splitspec_core.synthesis.verdict import rate_certificate
from tests.conftest import EXAMPLES


def ring(q=2, **keys):
    sc = ss.load_scenario(EXAMPLES / "ring10_noise.yaml")
    d = dict(consensus="fusion", gains="optimal", q=q, resilience=0, K=None)
    d.update(keys)
    return dataclasses.replace(sc, design=dataclasses.replace(sc.design, **d))


def test_the_design_is_the_fusion_gains_certified_by_the_full_error_map():
    sc = ring(q=2)
    des = design(sc)
    alone = scenario_fusion(sc, 2, rate=des.whole.lam_step)
    assert des.consensus == "fusion" and des.q == 2 and des.two_rate
    assert des.whole.radius == pytest.approx(alone.radius, rel=1e-12)
    assert des.whole.radius == pytest.approx(max(abs(np.linalg.eigvals(des.whole.designs[0].M))), rel=1e-9)
    cert = rate_certificate(des)
    assert cert.certified and cert.by == "full error matrix" and "fusion" in cert.text
    # the predicted noise (the design's Lyapunov equation of M and N) is the fusion design's own covariance
    j = design_json(des)
    n = sc.n
    assert j["predicted_rms"]["all"] == pytest.approx(alone.rms * np.sqrt(n), rel=1e-6)
    assert j["predicted_rms"]["ratio_to_kalman"] == pytest.approx(alone.ratio, rel=1e-6)
    assert j["fusion"]["q"] == 2 and j["fusion"]["certified"] and j["consensus"] == "fusion"
    assert j["fusion"]["limit"] == pytest.approx(scenario_limit(sc, 2).ratio, rel=1e-12)
    assert j["exchanges"]["messages"] == 2 and j["exchanges"]["numbers"] == 2 * n and j["whole_state"] is None
    text = design_text(des)
    assert "consensus on the whole state, fused with matrix weights (fusion)" in text
    assert f"q = 2 exchanges per event time  (fusion; design.q: the budget given)" in text
    assert "rate certified: q = 2: spectral radius of the full error map" in text


def test_auto_takes_the_fewest_exchanges_whose_limit_is_the_kalman_filters():
    sc = ring(q="auto")
    des = design(sc)
    want = next(q for q in range(1, 10) if scenario_limit(sc, q).ratio <= 1 + AUTO_GAP)
    assert des.q == want and des.whole.certified
    assert scenario_limit(sc, des.q - 1).ratio > 1 + AUTO_GAP


def test_a_budget_that_does_not_certify_says_the_fewest_that_would_and_the_fastest_rate_it_keeps():
    sc = ring(q=1)
    free = scenario_fusion(sc, 1)
    kind = FusionKind(q=1, designs=(free,), lam_step=0.5 * free.radius, limit=1.2, fewest=None, searched=4)
    text = budget_text(sc, kind)
    assert not kind.certified
    assert text.startswith("design.q = 1 does NOT certify rate 0.8 with the fusion kind")
    assert "none up to q = 4" in text and f"keep rate {free.radius:.6g} per event time" in text
    assert "q = 3" in budget_text(sc, dataclasses.replace(kind, fewest=3))


def test_each_agent_is_sent_its_gains_and_weights_per_graph_and_they_sum_to_the_identity():
    sc = ring(q=2)
    des = design(sc)
    sent = agent_fusion(des, 4)
    assert sent["consensus"] == "fusion" and set(sent["L"]) == set(sc.graph_names)
    per_k = sent["weights"][sc.graph_names[0]]
    assert len(per_k) == 2
    for blocks in per_k:
        total = sum(np.asarray(W) for W in blocks.values())
        assert np.allclose(total, np.eye(sc.n), atol=1e-9)
        assert set(blocks) == {"3", "4", "5"}  # itself and its two ring neighbours
    assert json.loads(json.dumps(sent)) == sent  # what the wire carries, as is


def test_a_lost_neighbour_s_weight_is_folded_into_the_agent_s_own():
    blocks = {1: np.array([[0.5]]), 2: np.array([[0.3]]), 3: np.array([[0.2]])}
    W = st.fold_weights(blocks, 1, [1, 2])
    assert W.tolist() == [[0.7, 0.3]]
    assert st.fold_weights(blocks, 1, [1, 2, 3]).tolist() == [[0.5, 0.3, 0.2]]


def test_the_survivors_verdict_keeps_the_gains_and_folds_the_lost():
    sc = ring(q=2)
    des = design(sc)
    arcs = {g.name: g.arcs for g in sc.graphs}
    # nobody lost: the survivors' map is the design's
    assert survivors_radius(des, sc.agent_ids, arcs) == pytest.approx(des.whole.radius, rel=1e-9)
    v = certify_network(des, sc.agent_ids)
    assert v["rate_certified"] and "folded" in v["certificate"]


def test_the_simulator_runs_one_step_path_for_the_kind_batched_or_looped():
    """Both estimators run kinds.Fusion: the same floats, with a kill and a restart (ring10_faults' faults)."""
    faults = ss.load_scenario(EXAMPLES / "ring10_faults.yaml").faults
    sc = dataclasses.replace(ring(q=1), faults=faults)
    des = design(sc)
    a = simulate(des, steps=60, estimator="batch")
    b = simulate(des, steps=60, estimator="loop")
    assert not a.alive.all()  # someone was killed
    assert np.array_equal(a.xhat, b.xhat, equal_nan=True)  # the same code in the same order: exactly


@pytest.mark.parametrize("changes,says", [
    ({"system": {"measurement_noise": 0.0}}, "set system.measurement_noise above 0 on every output"),
    ({"design": {"gains": "place"}}, "leave design.gains out"),
    ({"design": {"bad_data": {"false_alarm": 0.01, "suspect_after": 3}}}, "design.bad_data is not offered"),
    ({"design": {"resilience": 1}}, "design.resilience is not offered"),
])
def test_what_the_kind_does_not_offer_is_refused_in_one_line(tmp_path, capsys, changes, says):
    import yaml

    raw = yaml.safe_load((EXAMPLES / "ring10_noise.yaml").read_text())
    raw["design"] = {"rate": 0.8, "consensus": "fusion", "q": 1}
    for key, sub in changes.items():
        raw[key].update(sub)
    path = tmp_path / "s.yaml"
    path.write_text(yaml.safe_dump(raw))
    with pytest.raises(ScenarioError, match=says.replace(".", r"\.")):
        ss.load_scenario(path)
    assert cli.main(["design", str(path)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and says in err[0], err


def test_a_budget_too_small_for_the_split_says_the_fewest_exchanges_that_certify(capsys):
    """Item 1 of issue 44 for every kind: design.q given and not certified, one line names the fewest that are."""
    sc = ss.load_scenario(EXAMPLES / "paper_discrete.yaml")
    auto = design(sc)
    short = design(dataclasses.replace(sc, design=dataclasses.replace(sc.design, q=int(auto.q) - 1)))
    assert not rate_certificate(short).certified
    assert design_json(short)["fewest_certified_q"] == auto.q
    assert (f"the fewest exchanges that certify rate {sc.design.rate:g} with these design keys: q = {auto.q} per event "
            f"time (design.q: auto), against the budget design.q = {int(auto.q) - 1}") in design_text(short)
    assert design_json(auto)["fewest_certified_q"] is None  # certified: nothing to say


def test_a_given_q_is_a_budget_auto_keeps_the_most_accurate_certified_kind_within_it():
    """design.consensus: auto with design.q given: the relay and fusion kinds are designed at that q too, and the
    most accurate certified one kept (ring10_noise at q = 1: the split is not certified there; the relay is the
    protocol's limit, the fusion kind a hair above it)."""
    sc = ring(q=1, consensus="auto")
    des = design(sc)
    fused, relay = design(ring(q=1)), design(ring(q=1, consensus="relay"))
    assert rate_certificate(fused).certified and rate_certificate(relay).certified
    assert relay.whole.ratio < fused.whole.designs[0].ratio  # the limit itself, against the fusion kind's
    assert des.consensus == "relay" and des.q == 1 and rate_certificate(des).certified
    assert des.chosen.startswith("design.consensus: auto chose relay at the budget design.q = 1")
    assert "rate NOT certified" in des.chosen  # what it was preferred to
    assert des.whole.radius == pytest.approx(relay.whole.radius, rel=1e-12)  # the same gains as asked for by name
    assert design(ring(q="auto", consensus="auto")).consensus not in ("fusion", "relay")  # no budget: as before


def test_beside_a_shifted_relay_the_fusion_kind_is_designed_and_the_more_accurate_kept():
    """The platoon is slower than its rate: the relay's gain is shifted, so the fusion kind is designed beside it
    (m n = 48) and the certified one of smaller predicted RMS kept."""
    base = ss.load_scenario(EXAMPLES / "platoon.yaml")
    sc = dataclasses.replace(base, design=dataclasses.replace(base.design, consensus="auto", gains="optimal", q=1,
                                                               resilience=0, K=None))
    des = design(sc)
    by = {k: design(dataclasses.replace(sc, design=dataclasses.replace(sc.design, consensus=k)))
          for k in ("relay", "fusion")}
    assert by["relay"].whole.alpha < 1.0
    rms = {k: float(np.sqrt(np.mean(predicted_rms(d) ** 2))) for k, d in by.items() if rate_certificate(d).certified}
    assert len(rms) == 2
    best = min(rms, key=rms.get)
    assert des.consensus == best and des.chosen.startswith(f"design.consensus: auto chose {best}")
    other = next(k for k in rms if k != best)
    assert f"{other}: predicted steady RMS {rms[other]:.4g}" in des.chosen
