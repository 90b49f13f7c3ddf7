"""Jointly detectable systems (splitspec_core/model/detectability.py): what no agent sees, its rate, its certificate.

The systems are the paper's discrete example with one more state nobody measures, a filter of the first
oscillator's position ``f(tau+1) = a f + (1 - a) x1``: W = span(e_f) exactly, and A on W is ``a``.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import yaml

from splitspec_core.synthesis.conditioning import conditioning, transient_constant
from splitspec_core.synthesis.designer import design
from splitspec_core.model.detectability import BACKOFF
from splitspec_core.errors import AssumptionError
from splitspec_core.synthesis.error_matrix import case_parts as _case_parts, full_error_matrix, modulo
from splitspec_core.synthesis.report import design_json
from splitspec_core.synthesis.verdict import rate_certificate
from splitspec_core.scenarios.load import load_scenario, parse_scenario
from splitspec_core.simulation.simulator import simulate
from splitspec_core.synthesis.survivors import certify_network
from splitspec_orchestrator import cli
from tests.conftest import EXAMPLES


def filtered(a: float, *, undetectable: str | None = None, **design_keys) -> dict:
    """The paper's discrete example (rate 0.5, its gains) with f(tau+1) = a f + (1 - a) x1 that nobody measures.

    ``x(0) = 0``: the plant grows like 2^(tau/2), so the round-off of ``xhat - x`` would grow with it; from 0 the
    error is the estimates themselves, and decays far below any floor."""
    raw = yaml.safe_load((EXAMPLES / "paper_discrete_filter.yaml").read_text())
    raw["system"]["A"][4] = [1 - a, 0, 0, 0, a]
    raw["system"]["x0"] = [0.0] * 5
    if undetectable:
        raw["design"]["undetectable"] = undetectable
    raw["design"].update(design_keys)
    return raw


def stacked_errors(tr) -> np.ndarray:
    """``|e(tau)|`` of every agent's error stacked, (T,)."""
    e = tr.xhat - tr.x[:, None, :]
    return np.linalg.norm(e.reshape(e.shape[0], -1), axis=1)


def test_a_filter_nobody_sees_leaves_the_paper_design_on_the_rest():
    """W = span(e_f); the estimator's P_i never touch f; the quotient is the paper's system, so q and the certified
    radius are the paper's; W decays (0.4) faster than the rate (0.5): the rate stands."""
    des = design(load_scenario(EXAMPLES / "paper_discrete_filter.yaml"))
    paper = design(load_scenario(EXAMPLES / "paper_discrete.yaml"))
    e5 = np.eye(5)[:, 4:]
    un = des.unobserved
    assert un.dim == 1 and np.allclose(un.W @ un.W.T, e5 @ e5.T, atol=1e-12)
    assert un.decays and not un.limits(0.5) and un.decay == pytest.approx(0.4, rel=1e-12)
    for a in des.agents:
        assert np.allclose(a.P[:, 4], 0.0, atol=1e-12) and np.allclose(a.P[4, :], 0.0, atol=1e-12)
        assert a.dec.unobserved == 1 and a.dec.n_unobservable == 2
    # the quotient is the paper's system: the same q, the same radius (different operations: a tolerance)
    assert des.q == paper.q == 6
    assert des.q_result.bound == pytest.approx(paper.q_result.bound, rel=1e-9)
    cert = rate_certificate(des)
    assert cert.certified and cert.rate == des.envelope_rate == 0.5
    assert "1 direction no agent sees (f) decays with radius 0.4 < rate 0.5" in cert.text
    out = design_json(des)
    assert out["checks"]["jointly_observable"] is False and out["checks"]["jointly_detectable"] is True
    assert out["unobserved"]["states"] == ["f"] and out["unobserved"]["limits_rate"] is False
    assert out["states"] == ["x1", "x2", "x3", "x4", "f"] and out["envelope_rate"] == 0.5


def _holds_envelope(des, seeds=range(5)) -> float:
    """The largest ``|e(tau)| / (c r^tau |e(0)|)`` over noise-free runs from random initial states (must be <= 1)."""
    c = conditioning(des).transient_constant
    r = des.envelope_rate
    worst = 0.0
    for seed in seeds:
        tr = simulate(des, seed=seed, steps=60, noise=False)
        e = stacked_errors(tr)
        worst = max(worst, float(np.max(e / (c * r ** tr.t * e[0]))))
    return worst


@pytest.mark.parametrize("a", [0.4, 0.8])
def test_the_error_stays_under_the_certified_envelope(a):
    """From random initial states the stacked error stays under ``c r^tau |e(0)|`` with the design's transient
    constant and envelope rate (0.5 when the filter is faster, 0.8^BACKOFF when it is slower)."""
    des = design(parse_scenario(filtered(a)))
    assert des.envelope_rate == pytest.approx(0.5 if a < 0.5 else a ** BACKOFF, rel=1e-12)
    assert math.isfinite(conditioning(des).transient_constant)
    assert _holds_envelope(des) <= 1.0 + 1e-9


def test_a_slow_filter_limits_the_rate_and_the_run_shows_it():
    """f decays with radius 0.8 > rate 0.5: the certified rate is 0.8^BACKOFF, said in one line; the simulated error
    does decay at 0.8 (the filter's), not at the rate asked for."""
    from splitspec_core.simulation.metrics import fit_decay, max_error

    des = design(parse_scenario(filtered(0.8)))
    cert = rate_certificate(des)
    assert cert.certified and cert.rate == pytest.approx(0.8 ** BACKOFF, rel=1e-12)
    assert f"decays with radius 0.8 >= rate 0.5: it limits the certified rate to {0.8 ** BACKOFF:.4g}" in cert.text
    tr = simulate(des, seed=3, steps=200, noise=False)
    assert fit_decay(tr.t, max_error(tr), time="discrete", floor_rel=1e-250) == pytest.approx(0.8, rel=0.02)


def test_a_mode_nobody_sees_that_does_not_decay_is_refused_naming_it(tmp_path, capsys):
    """f integrates x1 (a = 1): refused in one line naming f and what would fix it, exit 2."""
    with pytest.raises(AssumptionError) as err:
        design(parse_scenario(filtered(1.0)))
    text = str(err.value)
    assert text == ("(C, A) is not jointly detectable: no agent sees f (eigenvalue 1), which does not decay; "
                    "measure one of f, or set design.undetectable: exclude to estimate the rest")
    path = tmp_path / "integrator.yaml"
    path.write_text(yaml.safe_dump(filtered(1.0)))
    assert cli.main(["design", str(path)]) == 2
    stderr = capsys.readouterr().err
    assert stderr.count("\n") == 1 and "no agent sees f (eigenvalue 1)" in stderr


def test_exclude_certifies_the_error_modulo_what_nobody_sees(capsys, tmp_path):
    """design.undetectable: exclude: the rest is estimated and certified; the certificate says what it excludes, and
    the error modulo W (every agent's error with its f component dropped) stays under its envelope."""
    des = design(parse_scenario(filtered(1.0, undetectable="exclude")))
    assert des.excluded and des.envelope_rate == 0.5
    cert = rate_certificate(des)
    assert cert.certified and "on the error modulo the 1 direction no agent sees (f)" in cert.text
    assert any("design.undetectable: exclude" in w for w in des.warnings)
    c = conditioning(des).transient_constant
    assert math.isfinite(c) and "modulo the directions no agent sees" in conditioning(des).transient_method
    for seed in range(4):
        tr = simulate(des, seed=seed, steps=60, noise=False)
        e = (tr.xhat - tr.x[:, None, :])[:, :, :4]  # W = span(e_f): the rest is x1..x4
        e = np.linalg.norm(e.reshape(e.shape[0], -1), axis=1)
        assert np.all(e <= c * 0.5 ** tr.t * e[0] * (1 + 1e-9))
        assert not np.all(np.abs(tr.xhat[-1, :, 4] - tr.x[-1, 4]) < 1e-6)  # f itself is not estimated
    path = tmp_path / "excluded.yaml"
    path.write_text(yaml.safe_dump(filtered(1.0, undetectable="exclude")))
    assert cli.main(["design", str(path), "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["unobserved"]["excluded"] is True and out["checks"]["jointly_detectable"] is False


def test_the_full_error_matrix_modulo_w_is_the_quotients():
    """``modulo`` takes the full error map to the quotient's: its spectrum is the full one without A's on W."""
    des = design(parse_scenario(filtered(0.4)))
    sc = des.scenario
    Cs, Ks, Ps = _case_parts(des, des.cases[0])
    M = full_error_matrix(sc.system.A, Cs, Ks, Ps, des.cases[0].graph.S, time="discrete", q=des.q)
    Mq = modulo(M, des.unobserved.W, sc.m)
    full = np.sort(np.abs(np.linalg.eigvals(M)))
    quotient = np.sort(np.abs(np.linalg.eigvals(Mq)))
    w_part = np.full(sc.m, 0.4)  # every agent's f runs open loop with 0.4
    assert np.allclose(full, np.sort(np.concatenate([quotient, w_part])), atol=1e-9)
    assert transient_constant(Mq, 0.5).constant <= transient_constant(M, 0.5).constant * (1 + 1e-9)


def three_agents(d: float) -> dict:
    """An oscillator seen by agents 1 and 2; a mode x3 (x3+ = d x3) seen by agent 3 only; a ring of three."""
    return {"name": "lose-3", "time": "discrete",
            "system": {"A": [[math.cos(0.7), math.sin(0.7), 0], [-math.sin(0.7), math.cos(0.7), 0], [0, 0, d]],
                       "C": {1: [[1, 0, 0]], 2: [[0, 1, 0]], 3: [[1, 0, 1]]}, "states": ["p", "v", "m"]},
            "graphs": {"ring": {"undirected": [[1, 2], [2, 3], [3, 1]]}},
            "design": {"rate": 0.5, "gains": "place", "resilience": 1}}


@pytest.mark.parametrize("d", [0.3, 0.9])
def test_losing_the_only_agent_that_sees_a_decaying_mode(d):
    """Losing agent 3 leaves m unobserved: it decays, so the survivors are still certified (redundantly jointly
    detectable), on the quotient by W_S; when it decays slower than the rate, their envelope is its rate."""
    des = design(parse_scenario(three_agents(d)))
    rep = des.agent_losses[3]
    assert not rep.jointly_observable and rep.detectable and rep.ok
    assert des.redundantly_jointly_detectable and not des.redundantly_jointly_observable
    assert any(c.label == "ring without agent 3" for c in des.cases) and des.q_result.certified
    v = certify_network(des, [1, 2])
    assert v["jointly_observable"] is False and v["detectable"] is True
    assert v["ok"] and v["rate_certified"]
    assert "1 direction no agent sees (m)" in v["certificate"]
    if d < 0.5:
        assert v["envelope_rate"] == 0.5
    else:
        assert v["envelope_rate"] == pytest.approx(0.9 ** BACKOFF, rel=1e-12)
    # the survivors' certificate is their full error map's: radius below the envelope's rate
    from tests.unit.test_resilience_runtime import full_error_radius

    assert full_error_radius(des, [1, 2]) < v["envelope_rate"]


def test_losing_the_only_agent_that_sees_an_oscillator_is_not_detectable():
    des = design(parse_scenario({**three_agents(0.3), "design": {"rate": 0.5, "gains": "place"}}))
    v = certify_network(des, [2, 3])  # agent 1 alone... no: 2 and 3 still see the oscillator
    assert v["ok"]
    raw = three_agents(0.3)
    raw["system"]["C"] = {1: [[1, 0, 0]], 2: [[0, 0, 1]], 3: [[0, 0, 1]]}
    raw["design"] = {"rate": 0.5, "gains": "place"}
    des = design(parse_scenario(raw))
    v = certify_network(des, [2, 3])
    assert v["ok"] is False and v["detectable"] is False and v["rate_certified"] is False
    assert "p, v" in v["unobservable_direction"] or "v, p" in v["unobservable_direction"]
