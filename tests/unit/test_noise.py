"""Noise per state, per agent and per output (``splitspec_core/scenarios/noise.py``) and everything that uses it.

A number means what it always did, down to the bit: the trajectories of a scalar-noise scenario are those of the
scalar-only formulas (``x+ = A x + (sigma_p I) v``, ``y = C x + sigma_m w``, the Van Loan ``Qd`` of ``q I`` and
its Cholesky factor), written out here independently of the plant, and ``{agent: that number}`` or ``[that
number] * n`` give the same trajectories as the number.  Per-output and matrix noise are what the plant draws
(empirical stds and covariances over long runs, within sampling error), what the centralized Kalman filter of
``compare`` predicts (against a Monte Carlo of its baseline) and what the design's predicted steady-state error
says (against a Monte Carlo of the estimator).

Tolerances: quantities computed along the same path are compared exactly (``np.array_equal``); the same quantity
along different float paths to 1e-12 relative; empirical statistics to a few standard errors of the estimate
(stated at each assertion).
"""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest
import scipy.linalg as sla

import splitspec_core as ss
from splitspec_core.errors import DimensionError, ScenarioError
from splitspec_core.model import local_design
from splitspec_core.model.plant import Plant, initial_state, measured, psd_sqrt, sampled_model
from splitspec_core.model.streams import stream
from splitspec_core.scenarios.noise import noise_json, noise_text
from splitspec_core.scenarios.sampling import sampled_data_matrices
from splitspec_core.scenarios.specs import System
from splitspec_core.simulation.montecarlo import simulate_seeds
from splitspec_core.studies import baselines
from splitspec_core.studies.baselines import baseline_seeds, kalman_predictor
from splitspec_core.synthesis.error_matrix import predicted_rms
from tests.conftest import EXAMPLES

A4 = [[0, 1, 0, 0], [-1, 0, 0, 0], [0, 0, 0, 1], [0, 0, -2, 0]]
#: agent 2 has two outputs, so a per-output std means something
C3 = {1: [[1, 0, 0, 0]], 2: [[0, 1, 0, 0], [0, 0, 1, 0]], 3: [[0, 0, 0, 1]]}
GRAPH = {"a": {"undirected": [[1, 2], [2, 3], [1, 3]]}}


def _scenario(*, time="discrete", process_noise=0.0, measurement_noise=0.0, gains="place", steps=40, **kw):
    """A small scenario: the paper's two oscillators (sampled with 0.3 s in discrete time: stable, |eig| = 1)."""
    extra = {"sample": 0.3} if time == "discrete" else {"dt": 0.02, "g": "auto"}
    return ss.scenario(A=A4, C=C3, graphs=GRAPH, time=time, rate=0.8 if time == "discrete" else 1.0, gains=gains,
                       process_noise=process_noise, measurement_noise=measurement_noise, steps=steps, seed=5,
                       **extra, **kw)


# --------------------------------------------------------------------------
# parsing: what the keys hold, and what they mean
# --------------------------------------------------------------------------


def test_a_number_means_what_it_always_did():
    sc = _scenario(process_noise=0.1, measurement_noise=0.05)
    s = sc.system
    assert s.process_noise == 0.1 and s.measurement_noise == 0.05 and isinstance(s.measurement_noise, float)
    np.testing.assert_array_equal(s.process_covariance, 0.1 ** 2 * np.eye(4))
    np.testing.assert_array_equal(s.measurement_std, np.full(4, 0.05))
    np.testing.assert_array_equal(s.measurement_covariance, 0.05 ** 2 * np.eye(4))
    assert [R.shape for R in s.measurement_covariances] == [(1, 1), (2, 2), (1, 1)]
    assert s.has_noise and s.process_noise_present and s.measurement_noise_present
    assert s.process_noise_level == 0.1 and s.measurement_noise_level == 0.05
    c = _scenario(time="continuous", process_noise=0.25).system
    np.testing.assert_array_equal(c.process_covariance, 0.25 * np.eye(4))  # an intensity, not squared
    assert c.process_noise_present and not c.measurement_noise_present
    quiet = _scenario().system
    assert not quiet.has_noise and not quiet.process_noise_present and not quiet.measurement_noise_present


def test_vectors_matrices_and_per_agent_noise():
    Q = [[0.04, 0.01, 0, 0], [0.01, 0.09, 0, 0], [0, 0, 0.01, 0], [0, 0, 0, 0]]  # singular: fine
    sc = _scenario(process_noise=Q, measurement_noise={3: 0.2, 1: 0.05, 2: [0.1, 0.0]})
    s = sc.system
    assert list(s.measurement_noise) == [1, 2, 3]  # agent order, whatever order it was given in
    assert s.measurement_noise == {1: 0.05, 2: (0.1, 0.0), 3: 0.2}
    np.testing.assert_array_equal(s.measurement_std, [0.05, 0.1, 0.0, 0.2])
    np.testing.assert_array_equal(s.measurement_covariance, np.diag([0.05 ** 2, 0.1 ** 2, 0.0, 0.2 ** 2]))
    Rs = s.measurement_covariances
    np.testing.assert_array_equal(Rs[1], np.diag([0.1 ** 2, 0.0]))
    np.testing.assert_array_equal(s.process_covariance, Q)
    assert not s.process_noise.flags.writeable
    v = _scenario(process_noise=[0.1, 0.2, 0.0, 0.3]).system
    np.testing.assert_array_equal(v.process_covariance, np.diag(np.square([0.1, 0.2, 0.0, 0.3])))  # stds, squared
    vc = _scenario(time="continuous", process_noise=[0.1, 0.2, 0.0, 0.3]).system
    np.testing.assert_array_equal(vc.process_covariance, np.diag([0.1, 0.2, 0.0, 0.3]))  # intensities
    # one number where a scalar is needed: the root mean variance (discrete), the mean intensity (continuous)
    assert v.process_noise_level == pytest.approx(np.sqrt(np.mean(np.square([0.1, 0.2, 0.0, 0.3]))), rel=1e-15)
    assert vc.process_noise_level == pytest.approx(0.15, rel=1e-15)
    assert s.measurement_noise_level == pytest.approx(np.sqrt(np.mean([0.05 ** 2, 0.01, 0, 0.04])), rel=1e-15)
    # equal entries stand as the number they repeat, exactly
    assert _scenario(process_noise=[0.1] * 4).system.process_noise_level == 0.1
    assert _scenario(measurement_noise={1: 0.1, 2: [0.1, 0.1], 3: 0.1}).system.measurement_noise_level == 0.1


def test_numpy_arrays_from_python_and_arrays_of_a_model_file(tmp_path):
    Q = np.diag([0.1, 0.2, 0.3, 0.4])
    sc = _scenario(process_noise=Q, measurement_noise={1: np.float64(0.1), 2: np.array([0.1, 0.2]), 3: np.int64(0)})
    np.testing.assert_array_equal(sc.system.process_noise, Q)
    assert sc.system.measurement_noise == {1: 0.1, 2: (0.1, 0.2), 3: 0.0}
    np.savez(tmp_path / "model.npz", A=np.array(A4, float), Q=Q, q=np.array([0.1, 0.2, 0.3, 0.4]),
             r2=np.array([[0.1, 0.2]]), one=np.array(0.3))
    text = (f"time: discrete\nsystem:\n  file: model.npz\n  A: A\n  sample: 0.3\n"
            f"  C: {json.dumps({str(k): v for k, v in C3.items()})}\n  process_noise: {{}}\n  measurement_noise: {{}}\n"
            f"graphs: {{a: {{undirected: [[1, 2], [2, 3], [1, 3]]}}}}\ndesign: {{rate: 0.8}}\n")
    for pn, mn, want_p, want_m in (("Q", "{1: one, 2: r2, 3: 0.1}", Q, {1: 0.3, 2: (0.1, 0.2), 3: 0.1}),
                                   ("q", "one", [0.1, 0.2, 0.3, 0.4], 0.3)):
        path = tmp_path / "s.yaml"
        path.write_text(text.replace("process_noise: {}", f"process_noise: {pn}")
                        .replace("measurement_noise: {}", f"measurement_noise: {mn}"))
        s = ss.load_scenario(path).system
        np.testing.assert_array_equal(s.process_noise, want_p)
        assert s.measurement_noise == want_m
    path.write_text(text.replace("process_noise: {}", "process_noise: nope").replace("measurement_noise: {}",
                                                                                      "measurement_noise: 0"))
    with pytest.raises(ScenarioError, match="system.process_noise names array 'nope', which system.file"):
        ss.load_scenario(path)


@pytest.mark.parametrize("changes, message", [
    ({"measurement_noise": {1: 0.1, 2: 0.1}}, "system.measurement_noise has no entry for agent 3 (it lists 1, 2)"),
    ({"measurement_noise": {1: 0.1, 2: [0.1, -1], 3: 0}}, "system.measurement_noise.2[2] must be >= 0, got -1"),
    ({"measurement_noise": {1: 0.1, 2: [0.1, 0.2, 0.3], 3: 0}},
     "system.measurement_noise.2 has 3 entries, agent 2 has 2 outputs"),
    ({"measurement_noise": {1: 0.1, 2: np.inf, 3: 0}}, "system.measurement_noise.2 must be finite, got inf"),
    ({"measurement_noise": {1: 0.1, 2: "r", 3: 0}}, "system.measurement_noise.2 is the name 'r'"),
    ({"measurement_noise": np.array([0.1, 0.2])}, "system.measurement_noise must be a number or a mapping"),
    ({"process_noise": np.ones(3)}, "system.process_noise has 3 entries, system.A is 4x4"),
    ({"process_noise": -np.eye(4)}, "system.process_noise is not symmetric positive semidefinite (smallest "
                                    "eigenvalue -1)"),
    ({"process_noise": np.eye(4) + np.triu(np.ones((4, 4)), 1)}, "system.process_noise is not symmetric"),
    ({"process_noise": np.eye(3)}, "system.process_noise is 3x3, system.A is 4x4"),
    ({"process_noise": [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, float("nan")]]},
     "system.process_noise[4][4] must be finite, got nan"),
])
def test_bad_shapes_are_one_line_naming_the_key(changes, message):
    with pytest.raises(ScenarioError) as err:
        _scenario(**changes)
    assert message in str(err.value) and "\n" not in str(err.value)


def test_a_system_built_directly_meets_the_same_checks():
    Cs = tuple(np.array(C, dtype=float) for C in C3.values())
    s = System(A=np.array(A4, float), Cs=Cs, x0=None, process_noise=np.array([0.1, 0.2, 0.3, 0.4]),
               measurement_noise={1: 0.1, 2: np.array([0.1, 0.2]), 3: 0.0})
    assert s.measurement_noise == {1: 0.1, 2: (0.1, 0.2), 3: 0.0} and not s.process_noise.flags.writeable
    with pytest.raises(DimensionError, match="system.measurement_noise lists 2 agents, system.Cs holds 3"):
        System(A=np.array(A4, float), Cs=Cs, x0=None, measurement_noise={1: 0.1, 2: 0.1})
    with pytest.raises(ScenarioError, match="system.process_noise is not symmetric positive semidefinite"):
        System(A=np.array(A4, float), Cs=Cs, x0=None, process_noise=-np.eye(4))
    sc = _scenario(measurement_noise={1: 0.1, 2: 0.2, 3: 0.3})
    renamed = dataclasses.replace(sc.system, measurement_noise={1: 0.1, 2: 0.2, 4: 0.3})
    with pytest.raises(ScenarioError, match="lists agents 1, 2, 4, the scenario's agents are 1, 2, 3"):
        dataclasses.replace(sc, system=renamed)
    with pytest.raises(ScenarioError, match="system.time is 'discrete', the scenario's time is 'continuous'"):
        dataclasses.replace(sc, time="continuous")


def test_text_and_json_say_the_noise_as_given():
    assert noise_text(0.05) == "0.05" and noise_json(0.05) == 0.05 and isinstance(noise_json(0.05), float)
    assert noise_text({1: 0.1, 2: (0.1, 0.2)}) == "{1: 0.1, 2: [0.1, 0.2]}"
    assert noise_json({1: 0.1, 2: (0.1, 0.2)}) == {"1": 0.1, "2": [0.1, 0.2]}
    assert noise_text(np.array([0.1, 0.2])) == "[0.1, 0.2]"
    assert noise_text(np.eye(2)) == "[[1, 0], [0, 1]]" and noise_json(np.eye(2)) == [[1.0, 0.0], [0.0, 1.0]]
    assert noise_text(np.linspace(1, 2, 160)) == "per state: 160 values, 1 to 2"
    assert noise_text(np.eye(20)) == "a 20x20 matrix, diagonal 1 to 1"
    assert noise_text({i: 0.1 * i for i in range(1, 21)}) == "per agent: 20 agents, 0.1 to 2"


# --------------------------------------------------------------------------
# byte compatibility: a number is the scalar-only code, bit for bit
# --------------------------------------------------------------------------


def _scalar_only_trajectory(sc, seed: int, steps: int) -> tuple:
    """``(x, y)`` by the scalar-only formulas, written out: ``y = C x + sigma_m w``, ``x+ = A x + (sigma_p I) v``,
    each from its named stream, ``y`` drawn before ``x`` advances."""
    n = sc.n
    C = np.vstack([np.asarray(c) for c in sc.system.Cs])
    A, L = np.array(sc.system.A), sc.system.process_noise * np.eye(n)
    proc, meas = stream(seed, "process"), stream(seed, "measurement")
    x = initial_state(sc, seed)
    xs, ys = [x], []
    for _ in range(steps):
        ys.append(C @ x + sc.system.measurement_noise * meas.normal(size=C.shape[0]))
        x = A @ x + L @ proc.normal(size=n)
        xs.append(x)
    return np.array(xs), np.array(ys)


def _scalar_only_sampling(A: np.ndarray, dt: float, q: float) -> tuple:
    """The sampled-data matrices and the plant's noise input before per-state noise: Van Loan with ``q I``, then
    Cholesky."""
    n = A.shape[0]
    M = np.zeros((2 * n, 2 * n))
    M[:n, :n], M[:n, n:] = A, np.eye(n)
    F = sla.expm(M * dt)
    VL = np.zeros((2 * n, 2 * n))
    VL[:n, :n], VL[:n, n:], VL[n:, n:] = -A, q * np.eye(n), A.T
    G = sla.expm(VL * dt)
    Qd = G[n:, n:].T @ G[:n, n:]
    Qd = 0.5 * (Qd + Qd.T)
    return F[:n, :n], F[:n, n:], Qd, np.linalg.cholesky(Qd)


@pytest.mark.parametrize("gains", ["place", "riccati"])
def test_scalar_noise_is_the_scalar_only_code_bit_for_bit(gains):
    sc = _scenario(process_noise=0.1, measurement_noise=0.05, gains=gains, steps=60)
    tr = ss.simulate(ss.design(sc), keep_y=True)
    x, y = _scalar_only_trajectory(sc, sc.run.seed, 60)
    assert np.array_equal(tr.x, x) and np.array_equal(tr.y[:-1], y)


def test_scalar_continuous_sampling_is_unchanged_bit_for_bit():
    sc = _scenario(time="continuous", process_noise=0.25)
    A, dt = np.array(sc.system.A), sc.run.dt
    E, D, Qd, L = _scalar_only_sampling(A, dt, 0.25)
    E2, D2, Qd2 = sampled_data_matrices(A, dt, noise_intensity=0.25)
    assert np.array_equal(E, E2) and np.array_equal(D, D2) and np.array_equal(Qd, Qd2)
    plant = Plant(sc, 0)
    assert np.array_equal(plant.F, E) and np.array_equal(plant.L, L)
    assert measured(np.eye(2), 0.5, np.ones(2), np.ones(2)).tolist() == [1.5, 1.5]


@pytest.mark.parametrize("time", ["discrete", "continuous"])
@pytest.mark.parametrize("gains", ["place", "riccati"])
def test_the_same_number_per_agent_or_per_state_is_the_number(time, gains):
    """``{agent: s}`` and ``[p] * n`` give the trajectories, Monte Carlo errors and baselines of ``s`` and ``p``."""
    kw = dict(time=time, gains=gains, steps=50)
    scalar = _scenario(process_noise=0.1, measurement_noise=0.05, **kw)
    per_agent = _scenario(process_noise=[0.1] * 4, measurement_noise={1: 0.05, 2: [0.05, 0.05], 3: 0.05}, **kw)
    if time == "continuous":  # a vector takes the general root of Qd: the same covariance, not the same bits
        per_agent = _scenario(process_noise=0.1, measurement_noise={1: 0.05, 2: [0.05, 0.05], 3: 0.05}, **kw)
    d1, d2 = ss.design(scalar), ss.design(per_agent)
    for a in scalar.agent_ids:
        assert np.array_equal(d1.agents[a].K, d2.agents[a].K)
    t1, t2 = ss.simulate(d1), ss.simulate(d2)
    assert np.array_equal(t1.x, t2.x) and np.array_equal(t1.xhat, t2.xhat, equal_nan=True)
    m1, m2 = simulate_seeds(d1.detail, range(3), steps=20), simulate_seeds(d2.detail, range(3), steps=20)
    assert np.array_equal(m1.sq_error, m2.sq_error)
    b1, b2 = (baseline_seeds(s, range(3), exchanges=2, steps=20) for s in (scalar, per_agent))
    assert all(np.array_equal(b1[k].sq_error, b2[k].sq_error) for k in b1)


# --------------------------------------------------------------------------
# per-output and matrix noise are what the plant draws
# --------------------------------------------------------------------------


def test_per_output_measurement_noise_is_drawn():
    """The empirical std of ``y - C x`` per output over 20000 steps is the given std: the relative standard error
    of a std from N normal samples is 1 / sqrt(2 N) = 0.5%, the test allows 5 of them (2.5%)."""
    stds = [0.05, 0.1, 0.0, 0.3]
    sc = _scenario(process_noise=0.01, measurement_noise={1: 0.05, 2: [0.1, 0.0], 3: 0.3}, steps=20000)
    tr = ss.simulate(ss.design(sc), keep_y=True)
    C = np.vstack([np.asarray(c) for c in sc.system.Cs])
    resid = tr.y - tr.x @ C.T
    assert np.all(resid[:, 2] == 0.0)  # a zero std: no noise at all on that output
    np.testing.assert_allclose(resid[:, [0, 1, 3]].std(axis=0), [0.05, 0.1, 0.3], rtol=5 / np.sqrt(2 * 20000))


def test_matrix_process_noise_is_drawn_discrete():
    """The empirical covariance of ``x(k+1) - A x(k)`` over 20000 steps is the given matrix: entry (i, j) has a
    standard error of ``sqrt((Q_ii Q_jj + Q_ij^2) / N)``; the test allows 5 of them."""
    Q = np.array([[0.04, 0.015, 0, 0.01], [0.015, 0.09, 0, 0], [0, 0, 0, 0], [0.01, 0, 0, 0.01]])  # singular
    sc = _scenario(process_noise=Q, measurement_noise=0.01, steps=20000)
    tr = ss.simulate(ss.design(sc))
    v = tr.x[1:] - tr.x[:-1] @ np.asarray(sc.system.A).T
    # a direction with no noise gets none (the PSD root of a singular matrix): x(k+1) - A x(k) there is round-off
    assert np.all(np.abs(v[:, 2]) <= 1e-13 * np.abs(tr.x).max())
    emp = v.T @ v / len(v)
    se = np.sqrt((np.outer(np.diag(Q), np.diag(Q)) + Q ** 2) / len(v))
    assert np.all(np.abs(emp - Q) <= 5 * se + 1e-15), (emp, Q)
    L = Plant(sc, 0).L
    np.testing.assert_allclose(L @ L.T, Q, rtol=0, atol=1e-15)  # the plant's input: exactly this covariance


def test_psd_root_of_a_singular_matrix():
    rng = np.random.default_rng(3)
    B = rng.normal(size=(5, 2))
    Q = B @ B.T  # rank 2
    L = psd_sqrt(Q)
    np.testing.assert_allclose(L @ L.T, Q, rtol=0, atol=1e-12 * np.abs(Q).max())


def test_continuous_matrix_intensity_is_sampled_exactly():
    """``Qd = int_0^dt exp(A s) Qc exp(A s)' ds`` (Van Loan) against a 4000-panel Simpson rule (error ~1e-14), the
    vector form is the diagonal matrix's, and the plant's ``L L'`` is ``Qd``."""
    Qc = np.array([[0.3, 0.1, 0, 0], [0.1, 0.2, 0, 0], [0, 0, 0.25, 0], [0, 0, 0, 0.0]])
    sc = _scenario(time="continuous", process_noise=Qc)
    A, dt = np.array(sc.system.A), sc.run.dt
    _, _, Qd = sampled_data_matrices(A, dt, noise_intensity=Qc)
    s = np.linspace(0, dt, 4001)
    f = np.array([sla.expm(A * t) @ Qc @ sla.expm(A * t).T for t in s])
    w = np.ones(len(s))
    w[1:-1:2], w[2:-1:2] = 4, 2
    simpson = np.tensordot(w, f, axes=1) * (s[1] - s[0]) / 3
    np.testing.assert_allclose(Qd, simpson, rtol=0, atol=1e-12 * np.abs(simpson).max())
    _, _, Qv = sampled_data_matrices(A, dt, noise_intensity=np.array([0.1, 0.2, 0.0, 0.3]))
    _, _, Qm = sampled_data_matrices(A, dt, noise_intensity=np.diag([0.1, 0.2, 0.0, 0.3]))
    assert np.array_equal(Qv, Qm)
    _, _, Qs = sampled_data_matrices(A, dt, noise_intensity=0.25)
    _, _, Qsm = sampled_data_matrices(A, dt, noise_intensity=0.25 * np.eye(4))
    np.testing.assert_allclose(Qs, Qsm, rtol=1e-12, atol=0)
    L = Plant(sc, 0).L
    np.testing.assert_allclose(L @ L.T, Qd, rtol=0, atol=1e-13 * np.abs(Qd).max())
    _, Q, R = sampled_model(sc)
    np.testing.assert_allclose(Q, Qd, rtol=0, atol=1e-13 * np.abs(Qd).max())


# --------------------------------------------------------------------------
# the consumers: the baselines, compare, the design's prediction, the Riccati weights
# --------------------------------------------------------------------------

#: strongly unequal noise per agent and per output, so that a scalar in place of it would show
UNEQUAL = dict(process_noise=[0.05, 0.02, 0.1, 0.0], measurement_noise={1: 0.5, 2: [0.01, 0.2], 3: 0.05})


def test_the_kalman_filters_take_each_agents_noise(monkeypatch):
    sc = _scenario(**UNEQUAL)
    F, Q, R = sampled_model(sc)
    np.testing.assert_array_equal(R, np.diag(np.square([0.5, 0.01, 0.2, 0.05])))
    np.testing.assert_array_equal(Q, np.diag(np.square(UNEQUAL["process_noise"])))
    seen = {}
    real = baselines.KalmanConsensusFilter

    def spy(F, Cs, Q, Rs, *args, **kw):
        seen["Rs"] = Rs
        return real(F, Cs, Q, Rs, *args, **kw)

    monkeypatch.setattr(baselines, "KalmanConsensusFilter", spy)
    baseline_seeds(sc, range(2), exchanges=1, steps=5)
    for got, want in zip(seen["Rs"], ([[0.5 ** 2]], np.diag(np.square([0.01, 0.2])), [[0.05 ** 2]])):
        np.testing.assert_array_equal(got, want)


def _steady(sq: np.ndarray, start: int) -> tuple:
    """``(mean, standard error)`` of the squared error from step ``start`` on: per-seed time averages are
    independent across seeds."""
    per_seed = sq[:, start:].mean(axis=1)
    return float(per_seed.mean()), float(per_seed.std(ddof=1) / np.sqrt(len(per_seed)))


def test_centralized_kf_prediction_matches_a_monte_carlo_of_its_baseline():
    """``trace P`` of the steady-state predictor with per-agent ``R`` is the mean squared error of compare's
    centralized baseline over 400 seeds (within 4 standard errors), and differs from the prediction with one
    averaged std by more than that."""
    sc = _scenario(**UNEQUAL, steps=80)
    F, Q, R = sampled_model(sc)
    C = np.vstack([np.asarray(c) for c in sc.system.Cs])
    predicted = float(np.trace(kalman_predictor(F, C, Q, R).P))
    runs = baseline_seeds(sc, range(400), exchanges=1, steps=80)["centralized"]
    mean, se = _steady(runs.sq_error, 30)
    assert abs(mean - predicted) <= 4 * se, (mean, se, predicted)
    level = sc.system.measurement_noise_level
    averaged = float(np.trace(kalman_predictor(F, C, Q, level ** 2 * np.eye(4)).P))
    assert abs(averaged - predicted) > 8 * se, (averaged, predicted, se)


def test_predicted_rms_with_per_agent_noise_matches_a_monte_carlo():
    """The design's predicted steady-state error (error_dynamics' N from sampled_model's per-output R) is the mean
    squared error of the estimator over 300 seeds, per agent (within 4 standard errors)."""
    sc = _scenario(**UNEQUAL, steps=80)
    des = ss.design(sc).detail
    pred = predicted_rms(des) ** 2
    runs = simulate_seeds(des, range(300), steps=80, trajectories=True)
    err = np.array([np.sum((tr.xhat - tr.x[:, None, :]) ** 2, axis=2) for tr in runs.trajectories])  # (N, T, m)
    for i in range(sc.m):
        mean, se = _steady(err[:, :, i], 30)
        assert abs(mean - pred[i]) <= 4 * se, (i, mean, se, pred[i])


def test_compare_reports_the_noise_as_given(tmp_path):
    res = ss.compare(_scenario(**UNEQUAL, steps=30), seeds=2)
    np.testing.assert_array_equal(res.process_noise, UNEQUAL["process_noise"])
    assert res.measurement_noise == {1: 0.5, 2: (0.01, 0.2), 3: 0.05}
    j = json.loads(json.dumps(res.to_json()))
    assert j["process_noise"] == [0.05, 0.02, 0.1, 0.0]
    assert j["measurement_noise"] == {"1": 0.5, "2": [0.01, 0.2], "3": 0.05}
    scalar = ss.compare(ss.load_scenario(EXAMPLES / "paper_discrete_noise.yaml"), seeds=2, steps=20).to_json()
    assert scalar["process_noise"] == 0.1 and scalar["measurement_noise"] == 0.0  # numbers stay numbers


def test_noise_weights_from_the_noise_levels():
    assert local_design.noise_weights(_scenario(process_noise=0.1, measurement_noise=0.05)) == (0.1 ** 2, 0.05 ** 2)
    assert local_design.noise_weights(_scenario()) == (1.0, 1.0)
    pw, mw = local_design.noise_weights(_scenario(**UNEQUAL))
    assert pw == pytest.approx(np.mean(np.square(UNEQUAL["process_noise"])), rel=1e-15)  # the mean variance
    assert mw == pytest.approx(np.mean(np.square([0.5, 0.01, 0.2, 0.05])), rel=1e-15)
    Qc = np.diag([0.1, 0.2, 0.3, 0.4])
    pw, _ = local_design.noise_weights(_scenario(time="continuous", process_noise=Qc))
    assert pw == pytest.approx(0.25 ** 2, rel=1e-15)  # the mean intensity, squared as a scalar intensity is
