"""The gain methods' table (scenarios/gain_methods.py) and the registry of their functions (model/gains.py): every
declared local word has one function with one signature, nothing undeclared can be registered or asked for, and
every method designs a scenario whose rate is certified and met by a noise-free simulation."""

from __future__ import annotations

import dataclasses
import inspect

import numpy as np
import pytest

from splitspec_core.errors import DesignError, ScenarioError
from splitspec_core.model import gains
from splitspec_core.model.gain_registry import LOCAL_METHODS, GainRequest, local_method
from splitspec_core.model.observability import decompose
from splitspec_core.scenarios import gain_methods
from splitspec_core.scenarios.checks import DESIGN_CHOICES, GAIN_METHODS
from tests.conftest import EXAMPLES, ROOT


def test_every_local_word_has_one_function_with_one_signature():
    assert set(LOCAL_METHODS) == set(gain_methods.names_where(local=True))
    for name, fn in LOCAL_METHODS.items():
        params = list(inspect.signature(fn).parameters)
        assert params == ["dec", "request"], (name, params)
    # the scenario's words are the table's
    assert GAIN_METHODS == gain_methods.NAMES and DESIGN_CHOICES["gains"] == (gain_methods.NAMES, gain_methods.DEFAULT)
    assert gain_methods.NOISY_DEFAULT in gain_methods.NAMES


def test_a_central_method_names_local_methods_for_its_split():
    for g in gain_methods.METHODS.values():
        assert g.doc and g.doc == g.doc.strip(), g.name
        assert g.whole in (None, "given", "shifted", "search"), g.name
        if not g.local:
            assert g.split and all(gain_methods.METHODS[m].local for m in g.split), g.name


def test_an_undeclared_word_is_refused_where_it_enters():
    with pytest.raises(DesignError, match="'nonsense' is not declared"):
        local_method("nonsense")
    with pytest.raises(DesignError, match="'optimal' is not declared as a local method"):
        local_method("optimal")  # a central method has no per-agent function
    with pytest.raises(ScenarioError, match=r"^design.gains must be one of place, riccati, .*got 'nonsense'$"):
        gain_methods.method("nonsense")
    dec = decompose(np.array([[0.9]]), np.array([[1.0]]))
    with pytest.raises(DesignError, match=r"^agent 1: unknown local gain method 'optimal' \(the local methods: place"):
        gains.design_gain(dec, GainRequest(method="optimal", time="discrete", rate=0.5, label="agent 1"))


def test_the_scenario_page_has_a_line_for_every_method():
    page = (ROOT / "docs/how-to/scenario.md").read_text(encoding="utf-8")
    for name in gain_methods.NAMES:
        assert f"* `{name}`" in page, name


def test_the_request_is_built_once_from_the_scenario():
    """gain_request: the method, the rate and the noise the designer and each agent process hand to the method; the
    process covariance and the user's K in the working coordinates (x = D x_w: K_w = D^-1 K, Q_w = D^-1 Q D^-1)."""
    import splitspec_core as ss
    from splitspec_core.model.local_design import gain_request

    sc = ss.load_scenario(EXAMPLES / "paper_discrete.yaml")
    sc = dataclasses.replace(sc, system=dataclasses.replace(sc.system, process_noise=[0.1, 0.2, 0.3, 0.4],
                                                            measurement_noise={1: 0.5, 2: 0.25, 3: 0.125}))
    scale = np.array([1.0, 2.0, 4.0, 8.0])
    req = gain_request(sc, 2, scale)
    assert req.method == "explicit" and req.label == "design.K.2" and req.rate == sc.design.rate
    np.testing.assert_allclose(scale[:, None] * req.K, sc.design.K[1], rtol=1e-15)
    np.testing.assert_allclose(req.process_covariance * np.outer(scale, scale), np.diag([0.01, 0.04, 0.09, 0.16]),
                               rtol=1e-12)
    np.testing.assert_allclose(req.measurement_covariance, [[0.25 ** 2]], rtol=1e-15)
    assert gain_request(sc, 3, None, method="place").label == "agent 3"


def _kalman_scenario(time: str, process_noise, measurement_noise) -> dict:
    """The paper's example of ``time`` with ``design.gains: kalman`` and the noise given (no K, the default g)."""
    import yaml

    raw = yaml.safe_load((EXAMPLES / f"paper_{time}.yaml").read_text())
    for key in ("K", "g"):
        raw["design"].pop(key, None)
    raw["design"]["gains"] = "kalman"
    raw["system"].update(process_noise=process_noise, measurement_noise=measurement_noise)
    return raw


@pytest.mark.parametrize("time", ["discrete", "continuous"])
def test_kalman_gains_are_certified_and_a_noise_free_run_stays_under_the_envelope(time):
    """design.gains: kalman (the agent's own noise as the Riccati weights): every agent's poles meet the rate, the
    report certifies it, and from a random initial state the stacked noise-free error stays under the certified
    envelope ``c r^tau |e(0)|`` (continuous: ``c exp(-r t) |e(0)|``)."""
    from splitspec_core.scenarios.load import parse_scenario
    from splitspec_core.simulation.simulator import simulate
    from splitspec_core.synthesis.conditioning import conditioning
    from splitspec_core.synthesis.designer import design
    from splitspec_core.synthesis.report import design_json
    from splitspec_core.synthesis.verdict import rate_certificate

    from splitspec_core.model.local_design import scenario_agent

    des = design(parse_scenario(_kalman_scenario(time, [0.05, 0.2, 0.1, 0.4], {1: 0.3, 2: 0.05, 3: 0.1})))
    assert [a.gain.method for a in des.agents] == ["kalman"] * 3 and des.consensus == "split"
    for a in des.agents:
        assert gains.meets_rate(a.gain.poles, time, des.rate)
        # what the agent's own process computes from the scenario: the same floats (one construction of the request)
        assert np.array_equal(scenario_agent(des.scenario, a.id, unobserved=des.unobserved.W_working).K, a.K)
    cert = rate_certificate(des)
    assert cert.certified and cert.rate == des.envelope_rate == des.rate
    assert design_json(des)["agents"][0]["K"] == np.asarray(des.agents[0].K).tolist()
    c, r = conditioning(des).transient_constant, des.envelope_rate
    # 30 event times: the paper's discrete plant grows as sqrt(2)^tau, and past ~45 the error meets round-off of x
    tr = simulate(des, seed=3, steps=30 if time == "discrete" else 1000, noise=False)
    e = tr.xhat - tr.x[:, None, :]
    e = np.linalg.norm(e.reshape(e.shape[0], -1), axis=1)
    envelope = c * (r ** tr.t if time == "discrete" else np.exp(-r * tr.t)) * e[0]
    assert np.all(e <= envelope * (1 + 1e-9)), float(np.max(e / envelope))
    assert e[-1] < 1e-3 * e[0]  # it did converge, not only stay bounded


def test_kalman_is_riccati_with_the_noise_levels_on_isotropic_noise():
    """Scalar noise and unit output rows (the paper's C_i): the agent's own weights are the noise levels squared,
    riccati's defaults, so the two gains agree (different operations: a tolerance); per-state noise moves them."""
    from splitspec_core.scenarios.load import parse_scenario
    from splitspec_core.synthesis.designer import design

    def gains_of(method, process_noise, measurement_noise):
        raw = _kalman_scenario("discrete", process_noise, measurement_noise)
        raw["design"]["gains"] = method
        return [np.asarray(a.K) for a in design(parse_scenario(raw)).agents]

    for K, R in zip(gains_of("kalman", 0.2, 0.1), gains_of("riccati", 0.2, 0.1)):
        np.testing.assert_allclose(K, R, rtol=1e-9, atol=1e-12)
    moved = [np.linalg.norm(K - R) for K, R in zip(gains_of("kalman", [0.05, 0.2, 0.1, 0.4], 0.1),
                                                   gains_of("riccati", [0.05, 0.2, 0.1, 0.4], 0.1))]
    assert max(moved) > 1e-3, moved


def test_kalman_needs_the_scenario_to_state_noise():
    from splitspec_core.scenarios.load import parse_scenario

    with pytest.raises(ScenarioError, match=r"^design.gains: kalman minimizes the error under noise: set "):
        parse_scenario(_kalman_scenario("discrete", 0.0, 0.0))
