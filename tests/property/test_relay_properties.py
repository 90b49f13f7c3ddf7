"""The relay kind on drawn systems (issue 44): at a fixed q, what it certifies holds, and what it predicts is measured.

The draws of ``test_fusion_properties`` (2 to 4 agents on a random strongly connected graph, 2 to 5 states, one or
two random outputs per agent, random noise levels, ``q`` in {1, 2}); the rate drawn between 0.85 and 1.05 times the
Kalman predictor's radius (above it: the base is the Kalman predictor; below: shifted, with ``design.lag: auto``).
Checked on every design the designer accepts:

* the certificate: ``|e(tau)| <= c rate^tau |e(0)|`` along noise-free runs from random initial errors (every agent
  its own initial estimate, its base), ``c`` its transient constant;
* the prediction: the steady RMS of a long noisy run against the predicted one, within sampling error;
* the limit: the predicted RMS never below the protocol's limit at the same q, and equal to it unshifted.

A draw the designer does not certify is counted, never silently dropped; the test fails if those leave fewer than
half the draws.  ``SPLITSPEC_PROPERTY_SCALE`` scales the number of draws.
"""

from __future__ import annotations

import numpy as np
import pytest

from splitspec_core.studies.few_exchanges import run_relay, simulate_measurements
from splitspec_core.synthesis.exchange_limit import hop_distances
from splitspec_core.synthesis.kalman import kalman_predictor
from splitspec_core.synthesis.relay import design_relay
from splitspec_core.synthesis.spectral import certifies
from tests.property.test_fusion_properties import DRAWS, _draw


def _check(seed: int) -> str:
    A, Cs, Q, Rs, arcs, q, rng = _draw(seed)
    m, n = len(Cs), A.shape[0]
    dist = hop_distances(m, arcs)
    import scipy.linalg as sla

    kf = kalman_predictor(A, np.vstack(Cs), Q, sla.block_diag(*Rs))
    rate = float(rng.uniform(0.85, 1.05) * kf.radius)
    if rate >= 1.0:
        rate = 0.5 * (1.0 + kf.radius)
    des = design_relay(A, Cs, Q, Rs, dist, q, rate)
    if not des.certified:
        return "refused"
    assert certifies(des.radius, rate) and (des.alpha < 1.0) == (kf.radius >= rate)
    c = des.transient_constant
    assert np.isfinite(c) and c >= 1.0
    T = 60
    for _ in range(3):
        x = np.zeros((T, n))
        x[0] = rng.standard_normal(n)
        for k in range(T - 1):
            x[k + 1] = A @ x[k]
        y = x[:-1] @ np.vstack(Cs).T
        X0 = x[0] + rng.standard_normal((m, n))
        e = run_relay(des, Cs, y, X0) - x[:, None]
        norms = np.linalg.norm(e, axis=2)  # each agent's envelope: c_i <= c
        assert np.all(norms <= c * rate ** np.arange(T)[:, None] * norms[0] * (1 + 1e-9) + 1e-12 * norms[0])
    steps = 4000
    x, y = simulate_measurements(A, Cs, Q, Rs, steps, rng)
    xs = run_relay(des, Cs, y, np.zeros((m, n)))
    burn = int(np.ceil(np.log(1e-8) / np.log(max(des.radius, kf.radius, 1e-3)))) + 10 + des.D
    measured = np.sqrt(np.mean(np.sum((xs[burn:] - x[burn:, None]) ** 2, axis=2)))
    predicted = np.sqrt(np.mean(des.agent_rms ** 2))
    corr = 1.0 / (1.0 - max(des.radius, kf.radius) ** 2)
    tol = 5 * 0.5 * np.sqrt(2 * corr / (steps - burn))
    assert measured == pytest.approx(predicted, rel=max(tol, 0.01))
    assert des.ratio >= des.limit * (1 - 1e-9)
    if des.alpha == 1.0:
        assert des.ratio == pytest.approx(des.limit, rel=1e-6)
    return "accepted"


def test_relay_certificates_and_predictions_hold_on_drawn_systems():
    outcomes = [_check(seed) for seed in range(DRAWS)]
    refused = outcomes.count("refused")
    print(f"relay on {DRAWS} drawn systems: {DRAWS - refused} accepted and checked, {refused} not certified")
    assert DRAWS - refused >= DRAWS / 2, f"{refused} of {DRAWS} draws not certified"
