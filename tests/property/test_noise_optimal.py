"""Property tests of the noise-optimal design (``design.gains: optimal``: synthesis/whole_state.py, the designer's
choice between the whole state and the split) on drawn jointly detectable systems with heterogeneous noise.

* the chosen design's certificate holds: from random initial estimates, the noise-free error stays under the
  certified envelope ``c r^k |e(0)|`` (``c`` the transient constant of the full error matrix, ``r`` the rate);
* its predicted steady RMS is what a Monte Carlo measures, within sampling error (four standard errors).

The systems are :mod:`.test_detectable`'s (an observable part, a stable block nobody sees, mixed and scaled), the
noise drawn per agent and output and per state (``system.measurement_noise: {agent: [stds]}``,
``system.process_noise: [one per state]``), each kind asked for by name (``design.consensus``: ``split``, ``whole``,
``fusion`` and ``relay`` (the envelope only: their steady states are ``test_fusion_properties.py``'s and
``test_relay_properties.py``'s), or ``auto``'s choice).

A draw that is not checked (the designer refuses it in one line, its rate is not certified, its plant is unstable
for the steady state, its transient too long to wait out) is counted by its reason, never silently dropped: each test
prints the tally and fails when none, or (ten draws or more) fewer than half its draws, were checked.
"""

from __future__ import annotations

import copy
import math

import numpy as np
import pytest
from collections import Counter

from hypothesis import event, example, given, settings
from hypothesis import strategies as st

from splitspec_core.errors import SplitspecError
from splitspec_core.scenarios.load import parse_scenario
from splitspec_core.simulation.montecarlo import simulate_seeds
from splitspec_core.synthesis.conditioning import conditioning
from splitspec_core.synthesis.designer import design
from splitspec_core.synthesis.error_matrix import predicted_rms
from splitspec_core.synthesis.verdict import rate_certificate

from .test_design_properties import COMMON, examples
from .test_detectable import assert_under_the_envelope, detectable

pytestmark = pytest.mark.filterwarnings("ignore:Convergence was not reached:UserWarning")


@st.composite
def noisy(draw, stable: bool = False, kinds: tuple = ("auto", "split", "whole")):
    """A detectable drawn system with noise per agent and output, and per state, and gains left to the noise.

    ``stable``: the plant made stable without changing what the agents see (discrete: ``A`` divided by its spectral
    radius and a little more; continuous: shifted left of the imaginary axis; the eigenvectors, hence the
    observable and unobservable directions and detectability, unchanged), so that a test of the steady state needs
    no filter that discards most drawn systems (Hypothesis's filter_too_much health check failed under one
    OpenBLAS kernel)."""
    data, _, _ = draw(detectable())
    sys_ = data["system"]
    n = len(sys_["A"])
    if stable:
        A = np.asarray(sys_["A"], dtype=float)
        ev = np.linalg.eigvals(A)
        if data.get("time", "discrete") == "discrete":
            radius = float(np.max(np.abs(ev)))
            A = A / (radius * 1.05) if radius >= 0.99 else A
        else:
            top = float(np.max(ev.real))
            A = A - (top + 0.05) * np.eye(n) if top >= -0.01 else A
        sys_["A"] = A.tolist()
    meas = {}
    for aid, C in sys_["C"].items():
        meas[aid] = [draw(st.sampled_from([0.01, 0.05, 0.2, 1.0])) for _ in C]
    sys_["measurement_noise"] = meas
    process = [draw(st.sampled_from([0.0, 0.01, 0.1])) for _ in range(n)]
    process[draw(st.integers(0, n - 1))] = draw(st.sampled_from([0.01, 0.1]))  # some process noise, not filtered
    sys_["process_noise"] = process
    # the design under noise is the subject, not the bad-data test the stated noise turns on by default (issue 46):
    # it sets a sensor aside on a large transient (the envelope then is the fallback's) and runs Monte Carlo seed by
    # seed (567 s for this file's Monte Carlo test, against seconds as one batch)
    data["design"] = {"rate": data["design"]["rate"], "consensus": draw(st.sampled_from(list(kinds))),
                      "bad_data": "off"}
    return data


def _design(data, tally: Counter):
    """The design, or None with the refusal counted."""
    try:
        return design(parse_scenario(data))
    except SplitspecError as exc:
        # the split's local gains can be out of numerical reach on a drawn system (strategies.py), and a rate the
        # consensus cannot keep up with is refused in one line naming the fastest it can: both are verdicts
        assert "\n" not in str(exc)
        tally[f"refused ({data['design']['consensus']})"] += 1
        return None


def _enough(name: str, tally: Counter) -> None:
    """Print the tally; fail when no draw was checked, or (ten draws or more) fewer than half (refusals must not empty
    the test; a handful of draws, as the lowest-versions gate runs, may hold one unlucky)."""
    checked = sum(v for k, v in tally.items() if k.startswith("checked"))
    total = sum(tally.values())
    print(f"{name}: {checked} of {total} draws checked; " + ", ".join(f"{k}: {v}" for k, v in sorted(tally.items())))
    assert checked >= (total / 2 if total >= 10 else 1), \
        f"{name}: only {checked} of {total} draws checked ({dict(tally)})"


def test_the_noise_optimal_designs_error_stays_under_its_certified_envelope():
    tally: Counter = Counter()

    @settings(max_examples=examples(25), **COMMON)
    @given(noisy(kinds=("auto", "split", "whole", "fusion", "relay")))  # their steady states: test_*_properties.py
    def check(data):
        des = _design(data, tally)
        if des is None:
            return
        cert = rate_certificate(des)
        if not cert.certified:
            tally[f"not certified ({des.consensus})"] += 1
            return
        event(f"consensus {des.consensus}")
        assert_under_the_envelope(des, cert)
        tally[f"checked ({des.consensus})"] += 1

    check()
    _enough("the certified envelope", tally)


#: a draw kept (session 4 of issue 44): the mode no agent sees at -0.2, computed at 0.20000000000000015, was called
#: faster than rate 0.2 and the design certified with an infinite transient constant (detectability.TIE)
MODE_AT_THE_RATE = {
    "name": "detectable", "time": "continuous",
    "system": {"A": [[-0.9923955727172279, 0.00526953755006427], [1.1434996818354888, -0.20760442728277206]],
               "C": {1: [[0.0, 0.0]], 2: [[-0.04055202746344281, 0.0002696764580815072]],
                     3: [[-0.04055202746344281, 0.0002696764580815072]]},
               "x0": [0.0, 0.0], "measurement_noise": {1: [0.01], 2: [0.01], 3: [0.01]}, "process_noise": [0.01, 0.0]},
    "graphs": {"ring": {"arcs": [[1, 2], [2, 3], [3, 1], [2, 1], [3, 2], [1, 3]]}},
    "design": {"rate": 0.2, "consensus": "auto", "bad_data": "off"}, "run": {"steps": 600, "seed": 0, "dt": 0.01}}


def test_the_predicted_steady_rms_is_what_a_monte_carlo_measures():
    tally: Counter = Counter()

    @settings(max_examples=examples(15), **COMMON)
    @given(noisy(stable=True))
    @example(copy.deepcopy(MODE_AT_THE_RATE))
    def check(data):
        des = _design(data, tally)
        if des is None:
            return
        if not rate_certificate(des).certified:
            tally[f"not certified ({des.consensus})"] += 1
            return
        sc = des.scenario
        # an unstable plant's state grows without bound, and the estimates' round-off with it (1e-16 of |x|): over
        # the thousands of steps a steady state takes, that is no longer the noise the prediction is about
        ev = np.linalg.eigvals(np.asarray(sc.system.A))
        if not (np.max(np.abs(ev)) <= 1.0 if sc.time == "discrete" else np.max(ev.real) <= 0.0):
            tally["unstable plant"] += 1
            return
        event(f"consensus {des.consensus}")
        pred = predicted_rms(des)
        if not np.all(np.isfinite(pred)):
            tally[f"no finite prediction ({des.consensus})"] += 1
            return
        # long enough for the transient (the certified envelope) to be a thousandth of the noise, then the steady state
        c = conditioning(des).transient_constant
        r = des.envelope_rate if sc.time == "discrete" else math.exp(-des.envelope_rate * sc.run.dt)
        start = int(math.ceil(math.log(1e-3 / max(c, 1.0)) / math.log(r))) + 1
        if start > 4000:
            tally[f"transient longer than 4000 steps ({des.consensus})"] += 1
            return
        runs = simulate_seeds(des, range(200), steps=start + 400)
        ms = (runs.sq_error[:, start:] / runs.alive_count[:, start:]).mean(axis=1)  # per seed: mean square over agents
        mean, se = ms.mean(), ms.std(ddof=1) / math.sqrt(len(ms))
        expected = float(np.mean(pred ** 2))
        # the initial transient's thousandth of e(0)^2 is far below the noise floor for these scales; sampling error
        assert abs(mean - expected) <= 4 * se + 1e-3 * expected, (mean, expected, se)
        tally[f"checked ({des.consensus})"] += 1

    check()
    _enough("the predicted steady RMS", tally)
