"""Noise-free property: the simulated error decays at least at the designed rate (tail fit).

The truth starts at x(0) = 0, so the error is the estimates themselves and can
decay far below the usual round-off floor (which is relative to |x|); the tail
fit then sees the asymptotic rate even when repeated eigenvalues across agents
add polynomial factors t^k lam^t to the transient.
"""

import numpy as np
import pytest
from hypothesis import HealthCheck, assume, event, example, given, settings
from hypothesis import strategies as st

from splitspec_core.errors import AssumptionError

from splitspec_core.simulation.metrics import fit_decay, max_error
from splitspec_core.synthesis.designer import design
from splitspec_core.scenarios.generate import random_strongly_connected_arcs, random_system
from splitspec_core.scenarios.load import parse_scenario
from splitspec_core.simulation.simulator import simulate
from splitspec_core.synthesis.verdict import rate_certificate
from tests.property.test_design_properties import examples
from tests.property.test_detectable import assert_under_the_envelope


def _scenario(seed, m, n, time, rate, gains, extra, dt=0.005, rank_tol=None):
    rng = np.random.default_rng(seed)
    A, Cs = random_system(rng, m, n, time=time)
    arcs = random_strongly_connected_arcs(rng, m, extra=extra)
    d = {"rate": rate, "gains": gains, **({} if rank_tol is None else {"rank_tol": rank_tol})}
    # discrete: long enough for the designed envelope to fall by e^-200 (polynomial factors fade)
    if time == "discrete":
        run = {"steps": int(np.ceil(200 / -np.log(rate))), "seed": seed}
    else:
        run = {"steps": int(np.ceil(25 / (rate * dt))), "dt": dt, "seed": seed}
    return parse_scenario({
        "time": time,
        "system": {"A": A.tolist(), "C": {i + 1: C.tolist() for i, C in enumerate(Cs)}, "x0": [0.0] * n},
        "graphs": {"g": {"arcs": [[j + 1, i + 1] for j, i in arcs]}},
        "design": d, "run": run,
    })


def _designed(*drawn, **kw):
    """The design of the drawn scenario; a draw whose blocks one agent sees only within design.rank_tol is another
    example.  random_system keeps its oscillators' frequencies only 0.01 apart: an agent with one output row seeing
    two of them close together sees the pair with a margin near that gap, which the design refuses in one line
    (test_a_pair_of_close_oscillators_seen_within_rank_tol_is_refused_and_the_advice_designs checks the refusal)."""
    try:
        return design(_scenario(*drawn, **kw))
    except AssumptionError as exc:
        if "only weakly (margin" not in str(exc):
            raise
        event("refused: seen within design.rank_tol")
        assume(False)


@settings(max_examples=examples(15), deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 10_000), m=st.integers(2, 6), n=st.integers(2, 8),
       rate=st.floats(0.3, 0.9), gains=st.sampled_from(["place", "riccati"]), extra=st.integers(0, 6))
def test_discrete_error_decays_at_designed_rate(seed, m, n, rate, gains, extra):
    des = _designed(seed, m, n, "discrete", rate, gains, extra)
    tr = simulate(des)
    measured = fit_decay(tr.t, max_error(tr), time="discrete", floor_rel=1e-250)
    if measured is None:  # converged to round-off within a few steps
        assert np.nanmax(tr.errors()[-1]) <= 1e-200
        return
    assert measured <= rate * 1.02, (measured, rate, des.q)


@pytest.mark.long
@settings(max_examples=examples(10), deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 10_000), m=st.integers(2, 5), n=st.integers(2, 6),
       rate=st.floats(0.2, 1.5), gains=st.sampled_from(["place", "riccati"]), extra=st.integers(0, 4))
@example(seed=1, m=2, n=4, rate=0.21875, gains="place", extra=0)  # found by hypothesis: a thin margin at dt = 0.005
@example(seed=1477, m=2, n=6, rate=0.21875, gains="place", extra=0)  # CI's test-kernels: thinner than the budget
@example(seed=256, m=2, n=5, rate=0.203125, gains="place", extra=0)  # CI: the fitted slope 4 % under, the envelope held
def test_continuous_error_decays_at_designed_rate(seed, m, n, rate, gains, extra):
    des = _designed(seed, m, n, "continuous", rate, gains, extra)
    # as the design's warning advises: keep dt small against g and the local gains |K_i C_i|
    # (the sampled-data form is first order in dt) so that it keeps the rate
    stiff = max([des.g] + [np.linalg.norm(K @ C, 2) for K, C in zip(des.Ks, des.scenario.system.Cs)])
    dt = min(0.005, 0.05 / stiff)
    assume(25 / (rate * dt) <= 40_000)  # bounded run length
    if dt < 0.005:
        des = design(_scenario(seed, m, n, "continuous", rate, gains, extra, dt=dt))
    # the sampled-data form tends to the ODE as dt -> 0; where the ODE's margin over the rate is thin
    # (seed 1, m 2, n 4, rate 0.21875: abscissa -0.22) dt = 0.005 decays at 0.208, dt / 2 at 0.220
    while min(des.sampled_rate.values()) < rate * 0.98 and 25 / (rate * dt / 2) <= 100_000:
        dt /= 2
        des = design(_scenario(seed, m, n, "continuous", rate, gains, extra, dt=dt))
    target = rate
    if min(des.sampled_rate.values()) < rate * 0.98:
        # the run-length budget ends the halving first (seed 1477, m 2, n 6, rate 0.21875: abscissa -0.22, decays
        # at 0.185 at dt = 0.0022 and at 0.220 only from dt = 0.00055, 208,000 steps): the design must say so,
        # and the simulation must keep the rate the design reports for this dt
        assert any("reduce run.dt" in w for w in des.warnings), (dt, des.sampled_rate, des.warnings)
        target = min(des.sampled_rate.values())
        assert target > 0, (dt, des.sampled_rate)
    # the guarantee: the noise-free error stays under the certified envelope c e^{-rate t} |e(0)| the whole run
    # (when this dt is certified; else the design said "reduce run.dt" above and the fitted slope is the check)
    cert = rate_certificate(des)
    if cert.rate is not None:
        assert_under_the_envelope(des, cert)
    tr = simulate(des)
    measured = fit_decay(tr.t, max_error(tr), time="continuous", floor_rel=1e-250)
    if measured is None:
        assert np.nanmax(tr.errors()[-1]) <= 1e-200
        return
    # the tail's fitted slope, a sanity bound beside it: undamped oscillators with a near-defective pair decay as
    # t e^{-lam t} over a finite run (seed 256, m 2, n 5, rate 0.203125, place: fitted 0.195 over the second half,
    # 0.157 to 0.232 by window, against 0.205 per the design; the envelope held)
    assert measured >= target * (0.9 if cert.rate is not None else 0.97), (measured, target, rate, des.g)


def test_a_pair_of_close_oscillators_seen_within_rank_tol_is_refused_and_the_advice_designs():
    # drawn by CI's test-kernels (2026-11-30, the same under every kernel): frequencies 0.2204 and 0.2413, one
    # agent sees both with one output row, the other neither; the refusal is one line naming the margin, and
    # design.rank_tol below it, as the line advises, designs an estimator certified at the rate
    drawn = (659, 2, 6, "continuous", 1.5, "place", 0)
    with pytest.raises(AssumptionError) as err:
        design(_scenario(*drawn))
    text = str(err.value)
    assert "\n" not in text and "only weakly (margin 0.00091 < 0.001" in text and "design.rank_tol below 0.00091" in text
    des = design(_scenario(*drawn, rank_tol=1e-4))
    assert rate_certificate(des).certified and min(des.sampled_rate.values()) > 1.5
