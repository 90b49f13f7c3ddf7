"""What `design` says of a lossy network: certified only where the two-norm argument covers every realization."""

from __future__ import annotations

import itertools
import json

import numpy as np
import pytest
import yaml

from splitspec_core.synthesis.designer import design
from splitspec_core.synthesis.loss_certificate import loss_certificate
from splitspec_core.synthesis.spectral import certifies
from splitspec_core.scenarios.load import load_scenario, parse_scenario
from splitspec_orchestrator import cli
from tests.conftest import EXAMPLES


def lossy(example: str, network: dict, **design_keys):
    raw = yaml.safe_load((EXAMPLES / f"{example}.yaml").read_text())
    raw["network"] = network
    raw["design"] = {**raw["design"], **design_keys}
    return design(parse_scenario(raw))


def test_a_lossy_chord_is_certified_with_enough_consensus_and_the_bound_holds_for_every_sequence():
    """The paper's graph a, only the message 1 -> 3 lossy: a sub-round realizes graph a or b.  At q = 9 every
    one of the 2^9 sequences of realized graphs maps the error by at most the certified two-norm bound."""
    des = lossy("paper_discrete", {"arcs": [{"arc": [1, 3], "loss": 0.3}]}, q=9)
    c = loss_certificate(des)
    assert c.certified and c.graphs == 2 and certifies(c.bound, 0.5) and c.text.startswith("rate certified under loss")
    sc = des.scenario
    Vs = [a.V for a in des.agents]
    V = np.zeros((3 * 4, sum(v.shape[1] for v in Vs)))
    c0 = 0
    for k, v in enumerate(Vs):
        V[4 * k:4 * k + 4, c0:c0 + v.shape[1]] = v
        c0 += v.shape[1]
    Atil = V.T @ np.kron(np.eye(3), sc.system.A) @ V  # blockdiag(V_i' A V_i)
    S_a = des.graphs[0].S
    S_b = S_a.copy()
    S_b[2, 0] = 0.0
    S_b[2] /= S_b[2].sum()  # agent 3 averages over itself and agent 2 only
    Bs = [V.T @ np.kron(S, np.eye(4)) @ V for S in (S_a, S_b)]
    worst = 0.0
    for seq in itertools.product(range(2), repeat=9):
        M = Atil
        for s in seq:
            M = M @ Bs[s]
        worst = max(worst, np.linalg.norm(M, 2))
    assert worst <= c.bound * (1 + 1e-12) and worst < 0.5
    # the designed q = 6 is not enough for the bound, and the certificate names the q that is
    c6 = loss_certificate(lossy("paper_discrete", {"arcs": [{"arc": [1, 3], "loss": 0.3}]}))
    assert not c6.certified and c6.q_needed == 9 and "q >= 9 would certify" in c6.text


def test_every_arc_lossy_is_never_certified_and_says_why():
    c = loss_certificate(lossy("ring10", {"loss": 0.1}))
    assert not c.certified and c.max_lost == 1 and c.graphs == 25  # the ring, and it minus each of its 24 arcs
    # P(more than 1 of 24 independent losses of probability 0.1) = 1 - 0.9^24 - 24 0.1 0.9^23
    assert c.p_more == pytest.approx(1 - 0.9 ** 24 - 24 * 0.1 * 0.9 ** 23, rel=1e-12)
    assert "certified only for sub-rounds that lose at most 1 message" in c.text and "probability 0.708" in c.text
    # one lost message that cuts an agent off: nothing to certify
    c = loss_certificate(lossy("paper_discrete", {"loss": 0.1}))
    assert not c.certified and c.max_lost == 0 and "leaves graph a not strongly connected" in c.text
    # with a deadline any message can be late: no bound on how many
    c = loss_certificate(lossy("ring10", {"deadline": 0.02}))
    assert not c.certified and "any number of messages can be late" in c.text
    # continuous time: switching every run.dt
    c = loss_certificate(lossy("paper_continuous", {"loss": 0.1}))
    assert not c.certified and "switches the graph for one step of run.dt" in c.text


def test_partitions_are_named_and_a_perfect_network_has_no_certificate_under_loss():
    c = loss_certificate(design(load_scenario(EXAMPLES / "ring10_partition.yaml")))
    assert "nothing is certified while partitioned (from 5 to 35" in c.text
    assert loss_certificate(design(load_scenario(EXAMPLES / "ring10.yaml"))) is None


def test_design_reports_it(capsys):
    path = EXAMPLES / "ring10_lossy.yaml"
    assert cli.main(["design", str(path), "--json"]) == 0
    out = json.loads(capsys.readouterr().out)["loss_certificate"]
    assert out["certified"] is False and out["max_lost"] == 1 and 0 < out["p_more"] < 1
    assert cli.main(["design", str(path)]) == 0
    text = capsys.readouterr().out
    assert text.count("under loss: ") == 1 and out["text"] in text
    assert cli.main(["design", str(EXAMPLES / "ring10.yaml"), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["loss_certificate"] is None
