"""One rate certificate, reported alike by `splitspec design`, `simulate` and `compare`.

* continuous time: a g certified for the ODE whose sampled-data form with
  ``run.dt`` misses the rate is not certified (design, simulate);
* the adaptive gain (thm. split_continuous_adaptive) is asymptotic
  convergence with no certified rate, everywhere: no verdict against a
  design, no designed envelope.
"""

import json
import math

import numpy as np
import pytest
import scipy.linalg as sla
import yaml

from splitspec_core.synthesis.designer import design
from splitspec_core.synthesis.survivors import certify_network
from splitspec_core.synthesis.report import design_json, design_text
from splitspec_core.synthesis.verdict import rate_certificate
from splitspec_core.synthesis.verdict import NO_CERTIFIED_RATE
from splitspec_core.scenarios.load import load_scenario
from splitspec_orchestrator import cli
from tests.conftest import EXAMPLES

# words that claim a rate (or judge a run against one); none may describe the adaptive gain
CLAIMS = ("designed envelope", "does NOT meet", "meets the design", "rate certified", "certified by",
          "errors decay as")


def _scenario_file(tmp_path, name: str, **changes) -> tuple:
    """paper_continuous.yaml with ``design``/``run`` keys changed; (path, raw dict)."""
    raw = yaml.safe_load((EXAMPLES / "paper_continuous.yaml").read_text())
    for key, value in changes.items():
        section, field = key.split("__")
        raw[section][field] = value
    raw["name"] = name
    path = tmp_path / f"{name}.yaml"
    path.write_text(yaml.safe_dump(raw))
    return path, raw


def sampled_error_map(des) -> np.ndarray:
    """The full (mn x mn) sampled-data error map of steps.py's formula, built from the full matrices:
    ``e_i+ = (E + D K_i C_i) e_i - g D P_i (e_i - sum_j s_ij e_j)``, ``E = exp(A dt)``, ``D = int_0^dt exp(A s) ds``."""
    sc = des.scenario
    A, dt, n, m = np.asarray(sc.system.A), sc.run.dt, sc.n, sc.m
    F = sla.expm(np.block([[A, np.eye(n)], [np.zeros((n, 2 * n))]]) * dt)
    E, D = F[:n, :n], F[:n, n:]
    S = des.graphs[0].S
    return (sla.block_diag(*[E + D @ K @ C for K, C in zip(des.Ks, sc.system.Cs)])
            - des.g * sla.block_diag(*[D @ P for P in des.Ps]) @ (np.eye(m * n) - np.kron(S, np.eye(n))))


def _sampled_decay(des) -> float:
    """``-ln rho(M) / dt`` of the full sampled-data error map."""
    return -math.log(np.max(np.abs(np.linalg.eigvals(sampled_error_map(des))))) / des.scenario.run.dt


@pytest.mark.parametrize("dt", [0.01, 0.2])
def test_sampled_data_form_decides_the_certificate(tmp_path, capsys, dt):
    """g = 10 is certified by eq. (g) for the ODE; at run.dt = 0.2 its sampled-data form is unstable."""
    path, _ = _scenario_file(tmp_path, f"dt{dt}", run__dt=dt)
    des = design(load_scenario(path))
    assert des.g_certified_by == "eq:g"  # the ODE certificate does not depend on dt
    decay = _sampled_decay(des)
    expected = decay >= des.rate
    cert = rate_certificate(des)
    assert cert.certified is expected
    assert rate_certificate(des, sampled=False).certified  # the exact ODE is certified either way
    if dt == 0.2:
        assert decay < 0 and "UNSTABLE" in cert.text and "run.dt = 0.2" in cert.text  # the case under test
    # the runtime verdict on the (here: all) surviving agents agrees
    verdict = certify_network(des, des.scenario.agent_ids)
    assert verdict["rate_certified"] is expected and verdict["ok"] is expected
    assert ("UNSTABLE" in verdict["certificate"]) is (dt == 0.2)
    # design --json and the text report say the same
    assert cli.main(["design", str(path), "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["certified_rate"] is expected and out["certificate"] == cert.text and out["rate_note"] is None
    assert cli.main(["design", str(path)]) == 0
    text = capsys.readouterr().out
    assert f"rate {'certified' if expected else 'NOT certified'}: {cert.text}" in text
    # so does simulate: summary.json and the printed summary
    sim = tmp_path / f"sim{dt}"
    assert cli.main(["simulate", str(path), "--out", str(sim), "--steps", "200", "--no-plots"]) == 0
    text = capsys.readouterr().out
    summary = json.loads((sim / "summary.json").read_text())
    assert summary["certified_rate"] is expected and summary["certificate"] == cert.text
    assert ("NOT certified by the design" in text) is (not expected)
    if not expected:
        assert summary["measured_rate"] < 0  # the sampled-data run does diverge


@pytest.fixture
def adaptive(tmp_path):
    path, raw = _scenario_file(tmp_path, "adaptive", design__g="adaptive")
    return path, raw


def test_adaptive_design_claims_no_rate(adaptive, capsys):
    path, _ = adaptive
    des = design(load_scenario(path))
    assert des.g is None and des.g_certified_by is None
    cert = rate_certificate(des)
    assert cert.certified is False and NO_CERTIFIED_RATE in cert.text
    out = design_json(des)
    assert out["certified_rate"] is False and out["rate_note"] == NO_CERTIFIED_RATE
    assert out["g_certified_by"] is None and out["g"] is None
    verdict = certify_network(des, des.scenario.agent_ids)
    assert verdict["rate_certified"] is None and NO_CERTIFIED_RATE in verdict["certificate"]
    text = design_text(des)
    assert NO_CERTIFIED_RATE in text
    for claim in CLAIMS:
        assert claim not in text, claim
    # the CLI prints exactly these
    assert cli.main(["design", str(path), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["certificate"] == cert.text
    assert cli.main(["design", str(path)]) == 0
    assert capsys.readouterr().out.strip() == text.strip()


def test_adaptive_simulate_claims_no_rate(adaptive, tmp_path, capsys):
    path, _ = adaptive
    out = tmp_path / "sim"
    assert cli.main(["simulate", str(path), "--out", str(out), "--steps", "300", "--no-plots"]) == 0
    text = capsys.readouterr().out
    summary = json.loads((out / "summary.json").read_text())
    assert summary["certified_rate"] is False and summary["rate_note"] == NO_CERTIFIED_RATE
    assert NO_CERTIFIED_RATE in summary["certificate"]
    assert summary["designed_rate"] is None and summary["measured_meets_design"] is None
    assert summary["envelope_c"] is None and not summary["envelope_pieces"]
    for claim in CLAIMS:
        assert claim not in text, claim


def test_adaptive_compare_claims_no_rate(adaptive, tmp_path, capsys):
    """compare runs the adaptive estimator (no predicted steady state) and says it has no certified rate."""
    path, _ = adaptive
    out = tmp_path / "cmp"
    assert cli.main(["compare", str(path), "--out", str(out), "--seeds", "2", "--steps", "100", "--sweep"]) == 0
    text = capsys.readouterr().out
    res = json.loads((out / "compare.json").read_text())
    split = {k: v for k, v in res["estimators"].items() if k.startswith("split")}
    assert split and "split tuned" not in split  # the adaptive gain has no steady state to tune
    for name, r in split.items():
        assert r["certified_rate"] is False and r["rate_note"] == NO_CERTIFIED_RATE, name
        assert r["predicted_rms"] is None and r["g"] is None
        assert f"{name}: adaptive gain: {NO_CERTIFIED_RATE}" in text
    for r in (res["estimators"]["centralized KF"], res["estimators"]["KCF"]):
        assert "certified_rate" not in r  # no split-spectrum certificate for the baselines
    assert (out / "sweep.png").stat().st_size > 1000  # drawn without a designed g
    sw = json.loads((out / "sweep.json").read_text())
    assert sw["designed"] is None and NO_CERTIFIED_RATE in sw["designed_note"]
    assert NO_CERTIFIED_RATE in text.splitlines()[-2]  # the sweep line: its values are fixed g, for comparison
    for line in text.splitlines():
        if line.strip().startswith("split"):
            for claim in CLAIMS:
                assert claim not in line, (claim, line)
