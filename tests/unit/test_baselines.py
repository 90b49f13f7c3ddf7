"""Baselines: centralized steady-state Kalman predictor and Olfati-Saber's Kalman-consensus filter."""

import numpy as np
import pytest
import scipy.linalg as sla
import yaml

from splitspec_core.studies.baselines import (KalmanConsensusFilter, SeedBatchKCF, baseline_seeds, baseline_trajectories,
                                      default_eps, kalman_predictor, run_predictor, sampled_model)
from splitspec_core.synthesis.designer import design
from splitspec_core.errors import DesignError
from splitspec_core.model.plant import Plant, output_rows
from splitspec_core.scenarios.load import load_scenario, parse_scenario
from splitspec_core.simulation.simulator import simulate
from tests.conftest import EXAMPLES
from tests.numerics import assert_close


def random_model(seed: int, *, radius: float, n: int = 3, p: int = 2):
    """Random ``(F, C, Q, R)`` with spectral radius ``radius``, generic (hence observable) C, SPD Q and R."""
    rng = np.random.default_rng(seed)
    F = rng.normal(size=(n, n))
    F *= radius / np.max(np.abs(np.linalg.eigvals(F)))
    C = rng.normal(size=(p, n))
    B = rng.normal(size=(n, n))
    Q = 0.1 * B @ B.T + 0.01 * np.eye(n)
    D = rng.normal(size=(p, p))
    R = 0.2 * D @ D.T + 0.05 * np.eye(p)
    return F, C, Q, R


# --------------------------------------------------------------------------
# centralized predictor
# --------------------------------------------------------------------------


@pytest.mark.parametrize("radius", [0.8, 1.3])
def test_steady_state_covariance_and_gain_match_the_riccati_recursion(radius):
    F, C, Q, R = random_model(11, radius=radius)
    kp = kalman_predictor(F, C, Q, R)
    P, L = kp.P, kp.L
    assert P.shape == (3, 3) and L.shape == (3, 2)
    S = C @ P @ C.T + R
    residual = F @ P @ F.T - F @ P @ C.T @ np.linalg.solve(S, C @ P @ F.T) + Q - P
    assert np.max(np.abs(residual)) <= 1e-10 * np.max(np.abs(P))
    assert np.allclose(P, P.T, atol=1e-12)
    assert np.linalg.eigvalsh(P)[0] > 0
    assert np.max(np.abs(np.linalg.eigvals(F - L @ C))) < 1  # stabilising solution
    # time-varying Riccati recursion of the one-step predictor, from P = I
    Pk = np.eye(3)
    for _ in range(2000):
        Sk = C @ Pk @ C.T + R
        Pk = F @ Pk @ F.T - F @ Pk @ C.T @ np.linalg.solve(Sk, C @ Pk @ F.T) + Q
    Lk = F @ Pk @ C.T @ np.linalg.inv(C @ Pk @ C.T + R)
    assert np.allclose(Pk, P, rtol=1e-8, atol=1e-12)
    assert np.allclose(Lk, L, rtol=1e-8, atol=1e-12)


def test_undetectable_pair_raises_and_singular_noise_is_regularised():
    F = np.diag([2.0, 0.5])
    with pytest.raises(DesignError):
        kalman_predictor(F, np.array([[0.0, 1.0]]), np.eye(2), np.eye(1))  # unstable mode 2 unobserved
    # noise-free measurements and no process noise: regularised, still a stabilising predictor
    F = np.array([[1.0, 1.0], [0.0, 1.0]])
    C = np.array([[1.0, 0.0]])
    kp = kalman_predictor(F, C, np.zeros((2, 2)), np.zeros((1, 1)))
    assert np.all(np.isfinite(kp.L)) and np.all(np.isfinite(kp.P))
    assert np.max(np.abs(np.linalg.eigvals(F - kp.L @ C))) < 1
    assert np.max(np.abs(kp.P)) < 1e-6  # nothing left to estimate in the small-noise limit


def test_simulated_error_covariance_matches_the_predicted_one():
    F, C, Q, R = random_model(5, radius=0.95)
    kp = kalman_predictor(F, C, Q, R)
    rng = np.random.default_rng(2024)
    N, burn = 20000, 200
    LQ, LR = np.linalg.cholesky(Q), np.linalg.cholesky(R)
    x = np.zeros(3)
    xs = np.zeros((N, 3))
    ys = np.zeros((N - 1, 2))
    for k in range(N):
        xs[k] = x
        if k == N - 1:
            break
        ys[k] = C @ x + LR @ rng.normal(size=2)
        x = F @ x + LQ @ rng.normal(size=3)
    xhat = run_predictor(F, C, kp.L, ys, np.zeros(3))
    assert xhat.shape == (N, 3) and np.array_equal(xhat[0], np.zeros(3))  # exact: the initial estimate, copied
    e = (xs - xhat)[burn:]
    measured = np.mean(np.sum(e ** 2, axis=1))
    predicted = np.trace(kp.P)
    # Tolerance from the sample size: e(k+1) = (F - L C) e(k) + v - L w is stationary Gaussian with
    # cov(e(k+h), e(k)) = G_h = (F - L C)^h P, so (Isserlis) cov(|e(k+h)|^2, |e(k)|^2) = 2 tr(G_h G_h')
    # and the variance of the sample mean of |e|^2 is (2 tr(P^2) + 4 sum_{h>=1} tr(G_h G_h')) / N.
    # Allow 4 standard deviations (about 3% here; the 200-step transient is negligible).
    Ae = F - kp.L @ C
    G, acc = kp.P, 2 * np.trace(kp.P @ kp.P)
    for _ in range(400):
        G = Ae @ G
        acc += 4 * np.trace(G @ G.T)
    tol = 4 * np.sqrt(acc / len(e)) / predicted
    assert tol < 0.1
    assert abs(measured / predicted - 1) < tol


# --------------------------------------------------------------------------
# Kalman-consensus filter
# --------------------------------------------------------------------------


def two_agent_kcf(exchanges: int) -> KalmanConsensusFilter:
    one = np.array([[1.0]])
    return KalmanConsensusFilter(one, [one, one], np.array([[0.5]]), [one, one], {0: [1], 1: [0]}, eps=0.5,
                                 exchanges=exchanges, P0=np.eye(1))


def test_kcf_step_worked_by_hand():
    kcf = two_agent_kcf(1)
    nxt = kcf.step(np.array([[1.0], [3.0]]), [np.array([2.0]), np.array([2.0])])
    # each agent fuses both measurements: U_i = 1 + 1 = 2, u_i = 2 + 2 = 4
    # M_i = (1/P_i + U_i)^-1 = 1 / (1 + 2) = 1/3;  gamma = 0.5 / (1 + |M_i|_F) = 0.5 / (4/3) = 0.375
    # xhat_1 = 1 + (1/3)(4 - 2*1) + 0.375 (1/3)(3 - 1) = 1 + 2/3 + 1/4 = 23/12
    # xhat_2 = 3 + (1/3)(4 - 2*3) + 0.375 (1/3)(1 - 3) = 3 - 2/3 - 1/4 = 25/12
    # F = 1: next priors = xhat;  P_i = F M_i F' + Q = 1/3 + 1/2 = 5/6
    assert np.allclose(nxt, [[23 / 12], [25 / 12]], rtol=0, atol=1e-14)
    assert np.allclose(kcf.P, 5 / 6, rtol=0, atol=1e-14)
    # second event time, y = [0, 6]: M_i = (6/5 + 2)^-1 = 5/16, gamma = 0.5 / (21/16) = 8/21,
    # gamma M_i = 5/42; u_i = 0 + 6 = 6:
    # xbar_1 = 23/12 + (5/16)(6 - 2*23/12) + (5/42)(25/12 - 23/12) = 23/12 + (5/16)(13/6) + 5/252
    #        = 23/12 + 65/96 + 5/252
    nxt2 = kcf.step(nxt, [np.array([0.0]), np.array([6.0])])
    assert np.isclose(nxt2[0, 0], 23 / 12 + 65 / 96 + 5 / 252, rtol=0, atol=1e-14)
    # xbar_2 = 25/12 + (5/16)(6 - 2*25/12) + (5/42)(23/12 - 25/12) = 25/12 + (5/16)(11/6) - 5/252
    #        = 25/12 + 55/96 - 5/252
    assert np.isclose(nxt2[1, 0], 25 / 12 + 55 / 96 - 5 / 252, rtol=0, atol=1e-14)
    assert np.allclose(kcf.P, 5 / 16 + 1 / 2, rtol=0, atol=1e-14)


def test_kcf_two_exchanges_worked_by_hand():
    kcf = two_agent_kcf(2)
    nxt = kcf.step(np.array([[1.0], [3.0]]), [np.array([2.0]), np.array([2.0])])
    # first exchange as in Algorithm 1: xhat = (23/12, 25/12); the second one with gamma M_i = 0.375/3 = 1/8:
    # xhat_1 = 23/12 + (1/8)(25/12 - 23/12) = 23/12 + 1/48 = 93/48
    # xhat_2 = 25/12 + (1/8)(23/12 - 25/12) = 25/12 - 1/48 = 99/48
    assert np.allclose(nxt, [[93 / 48], [99 / 48]], rtol=0, atol=1e-14)
    assert np.allclose(kcf.P, 5 / 6, rtol=0, atol=1e-14)  # P does not depend on the exchanges


def test_kcf_step_equals_algorithm_1_in_information_form():
    rng = np.random.default_rng(3)
    n, m = 3, 3
    F = rng.normal(size=(n, n))
    Cs = [rng.normal(size=(s, n)) for s in (1, 2, 1)]
    Rs = [np.diag(rng.uniform(0.5, 2.0, size=C.shape[0])) for C in Cs]
    Q = 0.1 * np.eye(n)
    nbs = [[1], [0, 2], [0]]
    eps = 0.4
    kcf = KalmanConsensusFilter(F, Cs, Q, Rs, nbs, eps=eps)
    Ps = [np.eye(n) + 0.1 * k * np.ones((n, n)) for k in range(m)]
    kcf.P = np.stack(Ps)
    xbar = rng.normal(size=(m, n))
    ys = [rng.normal(size=C.shape[0]) for C in Cs]
    got = kcf.step(xbar, ys)
    for i in range(m):  # Algorithm 1 written out literally
        J = [i] + nbs[i]
        u = sum(Cs[j].T @ np.linalg.solve(Rs[j], ys[j]) for j in J)
        U = sum(Cs[j].T @ np.linalg.solve(Rs[j], Cs[j]) for j in J)
        M = np.linalg.inv(np.linalg.inv(Ps[i]) + U)
        gamma = eps / (1 + np.sqrt(np.trace(M.T @ M)))
        xhat = xbar[i] + M @ (u - U @ xbar[i]) + gamma * M @ sum(xbar[j] - xbar[i] for j in nbs[i])
        assert np.allclose(got[i], F @ xhat, rtol=1e-10, atol=1e-12)
        assert np.allclose(kcf.P[i], F @ M @ F.T + Q, rtol=1e-10, atol=1e-12)


def test_kcf_default_eps_converges_on_a_path_graph():
    # 3-agent path 0 - 1 - 2, unstable plant; no agent's neighbourhood sees the whole state
    rot = lambda a, r: r * np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])  # noqa: E731
    F = sla.block_diag(rot(0.3, 1.05), rot(0.7, 0.98))
    Cs = [np.array([[1.0, 0, 0, 0]]), np.array([[0, 0, 1.0, 0]]), np.array([[0, 0, 0, 1.0]])]
    nbs = {0: [1], 1: [0, 2], 2: [1]}
    assert default_eps(nbs) == pytest.approx(1 / 3)
    rng = np.random.default_rng(0)
    T = 200
    xs = np.zeros((T, 4))
    xs[0] = rng.normal(size=4)
    for k in range(T - 1):
        xs[k + 1] = F @ xs[k]
    ys = xs[:-1] @ np.vstack(Cs).T
    X0 = rng.normal(size=(3, 4))
    kcf = KalmanConsensusFilter(F, Cs, 0.01 * np.eye(4), [0.01 * np.eye(1)] * 3, nbs)
    out = kcf.run(ys, X0, output_rows([[[1]], [[1]], [[1]]]))  # three single-row agents
    assert out.shape == (T, 3, 4) and np.array_equal(out[0], X0)  # exact: the initial estimates, copied
    e = np.linalg.norm(out - xs[:, None, :], axis=2).max(axis=1)
    assert e[-1] < 1e-6 * e[0]


@pytest.fixture(scope="module")
def paper_noise():
    sc = load_scenario(EXAMPLES / "paper_discrete_noise.yaml")
    return sc, design(sc).q


def test_kcf_noise_free_converges_on_the_paper_example(paper_noise):
    # The plant has eigenvalues +-i sqrt(2): |x(k)| grows like 2^(k/2) (about 1e30 at k = 200), so round-off
    # alone leaves errors of about 1e-16 |x(k)|.  Absolute errors must fall below 1e-3 of the initial ones
    # while |x| is moderate (k = 40, the scenario's run length); at k = 200 the error relative to |x| must
    # be at round-off level.
    sc, q = paper_noise
    b = baseline_trajectories(sc, 7, exchanges=q, steps=200, noise=False)
    e = np.linalg.norm(b["kcf"] - b["x"][:, None, :], axis=2).max(axis=1)
    ec = np.linalg.norm(b["centralized"] - b["x"], axis=1)
    xn = np.linalg.norm(b["x"], axis=1)
    assert e[40] < 1e-3 * e[0] and ec[40] < 1e-3 * ec[0]
    assert e[-1] < 1e-12 * xn[-1] and ec[-1] < 1e-12 * xn[-1]
    assert xn[-1] > 1e20  # the plant really is unstable: absolute errors say nothing at k = 200


def test_kcf_noisy_rms_is_finite_and_no_better_than_centralized(paper_noise):
    # Monte Carlo over seeds instead of one long run: with |x(k)| ~ 2^(k/2), round-off (~1e-16 |x|) would
    # swamp the noise (std 0.1) after about 100 steps (at 2000 steps |x| ~ 1e301).  60 steps per seed
    # (round-off ~1e-7 at the end), the last half of each, 40 seeds: 1200 samples per agent.
    sc, q = paper_noise
    F, Q, R = sampled_model(sc)
    kp = kalman_predictor(F, np.vstack(sc.system.Cs), Q, R)
    sq_kcf, sq_c = [], []
    for seed in range(40):
        b = baseline_trajectories(sc, seed, exchanges=q, steps=60)
        sq_kcf.append(np.sum((b["kcf"] - b["x"][:, None, :])[30:] ** 2, axis=2))
        sq_c.append(np.sum((b["centralized"] - b["x"])[30:] ** 2, axis=1))
    rms_kcf = np.sqrt(np.mean(np.concatenate(sq_kcf), axis=0))
    rms_c = np.sqrt(np.mean(np.concatenate(sq_c)))
    assert rms_kcf.shape == (sc.m,) and np.all(np.isfinite(rms_kcf))
    assert np.all(rms_c <= 1.05 * rms_kcf)  # the centralized predictor is optimal
    # the centralized predictor's error is the predicted one (std of the estimate: about 2%)
    assert rms_c == pytest.approx(np.sqrt(np.trace(kp.P)), rel=0.1)


def test_sampled_model_follows_the_plant():
    sc = load_scenario(EXAMPLES / "paper_continuous.yaml")
    F, Q, R = sampled_model(sc)
    A, dt, w = np.array(sc.system.A), sc.run.dt, sc.system.process_noise
    assert np.allclose(F, sla.expm(A * dt), rtol=1e-12, atol=1e-14)
    # Qd = w int_0^dt e^(As) e^(A's) ds, by a fine trapezoid rule
    s = np.linspace(0, dt, 401)
    vals = np.stack([sla.expm(A * t) @ sla.expm(A * t).T for t in s])
    assert np.allclose(Q, w * np.trapezoid(vals, s, axis=0), rtol=1e-6, atol=1e-12)
    assert np.array_equal(R, np.zeros((3, 3)))  # exact: no measurement noise is a zero matrix
    sc = load_scenario(EXAMPLES / "paper_discrete_noise.yaml")
    F, Q, R = sampled_model(sc)
    # exact: in discrete time F is A itself (a copy); Q = 0.1^2 I to an ulp
    assert np.array_equal(F, np.array(sc.system.A)) and np.allclose(Q, 0.01 * np.eye(4), rtol=1e-15, atol=0)


@pytest.mark.parametrize("name,steps", [("paper_discrete_noise.yaml", None), ("paper_continuous.yaml", 50)])
def test_baseline_truth_is_the_simulators(name, steps):
    sc = load_scenario(EXAMPLES / name)
    tr = simulate(design(sc), seed=3, steps=steps)
    b = baseline_trajectories(sc, 3, exchanges=2, steps=steps)
    assert np.array_equal(b["x"], tr.x)  # exact: the same Plant class, seed streams and steps as the simulator
    assert np.allclose(b["t"], tr.t, rtol=0, atol=1e-12)
    T = tr.x.shape[0]
    assert b["centralized"].shape == (T, sc.n) and b["kcf"].shape == (T, sc.m, sc.n)
    # exact: the same initial_estimate(n, seed, i) draws as the simulator's agents
    assert np.array_equal(b["kcf"][0], tr.xhat[0])
    # their mean (numpy's mean of the same rows, in both): to 1e-15 of their size all the same
    assert_close(b["centralized"][0], tr.xhat[0].mean(axis=0), rtol=1e-15, what="centralized initial estimate")


# --------------------------------------------------------------------------
# many seeds as one batch
# --------------------------------------------------------------------------


def two_output_scenario():
    """The paper's discrete example with measurement noise and agent 1 seeing two outputs: neighbourhoods ``J_i``
    of 2, 3 and 4 rows (agent 3 hears 1 and 2, the others one agent), so the batch's padding is exercised."""
    data = yaml.safe_load((EXAMPLES / "paper_discrete_noise.yaml").read_text())
    data["system"]["C"][1] = [[1, 0, 0, 0], [0, 0, 0, 1]]
    data["system"]["measurement_noise"] = 0.05
    data["design"] = {"rate": 0.5, "gains": "place", "q": "auto"}
    return parse_scenario(data)


def ring_with_sensor_faults():
    """ring10 with noise and its sensors lying: agent 2 stuck then noisy, agent 5 biased and scaled."""
    data = yaml.safe_load((EXAMPLES / "ring10_noise.yaml").read_text())
    data["faults"] = [{"at": 5, "corrupt": 2, "for": 10, "stuck": True, "noise": 0.3},
                      {"at": 20, "corrupt": 2, "noise": 0.5}, {"at": 8, "corrupt": 5, "bias": 1.0, "scale": 1.5}]
    return parse_scenario(data)


BATCH_CASES = {
    "two outputs": (two_output_scenario, 3, 60, True),
    "sensor faults": (ring_with_sensor_faults, 2, 40, True),
    "ring, 3 exchanges": (lambda: load_scenario(EXAMPLES / "ring10_noise.yaml"), 3, 60, True),
    "continuous": (lambda: load_scenario(EXAMPLES / "paper_continuous.yaml"), 1, 50, True),
    "noise-free": (two_output_scenario, 2, 40, False),
}


@pytest.mark.parametrize("case", list(BATCH_CASES))
def test_batched_baselines_are_the_per_seed_ones(case):
    """``baseline_seeds`` on 5 seeds in chunks of 2 (a chunk boundary inside the seeds, a last chunk of one):
    per seed the squared errors of ``baseline_trajectories``.  Other summation orders (the padded solve, the
    adjacency product, ``(gamma M) d``) move an estimate by round-off of the state's size, and the paper's plant
    grows like 2^(k/2) (|x| ~ 1e9 at k = 60) while the errors stay ~0.1: so the error norms are compared to
    1e-12 of ``1 + |x(k)|`` (measured: 1e-15), far below any difference of method (one exchange more or less
    changes the KCF's errors by percents)."""
    make, exchanges, steps, noise = BATCH_CASES[case]
    sc = make()
    seeds = (4, 0, 11, 7, 2)
    b = baseline_seeds(sc, seeds, exchanges=exchanges, steps=steps, noise=noise, chunk=2)
    assert b["centralized"].sq_error.shape == b["kcf"].sq_error.shape == (5, steps + 1)
    assert b["kcf"].seeds == seeds and np.all(b["centralized"].alive_count == 1) and np.all(b["kcf"].alive_count == sc.m)
    for k, s in enumerate(seeds):
        r = baseline_trajectories(sc, s, exchanges=exchanges, steps=steps, noise=noise)
        assert np.array_equal(b["kcf"].t, r["t"])  # exact: the same plan's times, the same arange times dt
        scale = 1.0 + np.linalg.norm(r["x"], axis=1)
        central = np.linalg.norm(r["centralized"] - r["x"], axis=1)
        kcf = np.linalg.norm(r["kcf"] - r["x"][:, None, :], axis=2)  # (T, m)
        assert np.max(np.abs(np.sqrt(b["centralized"].sq_error[k]) - central) / scale) < 1e-12, s
        # sum_i |e_i|^2 against the same sum of the reference's: 1e-12 of m (1 + |x|)^2 apart
        assert np.max(np.abs(b["kcf"].sq_error[k] - np.sum(kcf ** 2, axis=1)) / (sc.m * scale ** 2)) < 1e-12, s
        assert np.max(b["kcf"].sq_error[k]) > 1e-3  # the errors compared are not round-off themselves


def test_the_batched_kcf_shares_the_per_seed_gains():
    """``SeedBatchKCF``'s ``P_i`` after 30 event times are :class:`KalmanConsensusFilter`'s (the recursion never
    sees a measurement; padded solves in another order: 1e-12 relative), and one seed stepped alone equals the
    batch's column of it."""
    sc = two_output_scenario()
    plant = Plant(sc, 0)
    F, Q, R = sampled_model(sc)
    nbs = {0: [1], 1: [0, 2], 2: [0, 1]}
    Rs = [0.05 ** 2 * np.eye(C.shape[0]) for C in plant.Cs]
    ref = KalmanConsensusFilter(F, plant.Cs, Q, Rs, nbs, exchanges=2)
    batch = SeedBatchKCF(KalmanConsensusFilter(F, plant.Cs, Q, Rs, nbs, exchanges=2))
    rng = np.random.default_rng(5)
    X = rng.normal(size=(3, 4, 6))
    Xr = X[:, :, 2].copy()
    for _ in range(30):
        y = rng.normal(size=(plant.C.shape[0], 6))
        X = batch.step(X, y)
        Xr = ref.step(Xr, [y[r, 2] for r in plant.rows])
    assert_close(batch.P, ref.P, rtol=1e-12, what="P_i")
    assert_close(X[:, :, 2], Xr, rtol=1e-9, what="seed 2's priors")
    batch.reset()
    assert np.array_equal(batch.P, np.tile(np.eye(4), (3, 1, 1)))  # exact: copies of P0


def test_the_baselines_are_given_the_measurements_the_sensor_faults_give_simulate():
    """The centralized predictor is run_predictor on simulate's given y (with its stuck, noisy and biased sensors)
    and its estimate differs from the one on the clean measurements; compare says the faults were applied to every
    row, and its KF and KCF rows' errors change under them."""
    from splitspec_core.studies.baselines import _filters, run_predictor
    from splitspec_core.model.plant import initial_estimate
    import splitspec_core as ss

    sc = ring_with_sensor_faults()
    clean_sc = parse_scenario({**yaml.safe_load((EXAMPLES / "ring10_noise.yaml").read_text())})
    r = baseline_trajectories(sc, 3, exchanges=2, steps=40)
    tr = simulate(design(sc), seed=3, steps=40, keep_y=True)
    F, C, Lc, _ = _filters(sc, 2, None)
    X0 = np.stack([initial_estimate(sc.n, 3, i) for i in range(sc.m)])
    np.testing.assert_array_equal(r["centralized"], run_predictor(F, C, Lc, tr.y[:40], X0.mean(axis=0)))
    clean = baseline_trajectories(clean_sc, 3, exchanges=2, steps=40)
    np.testing.assert_array_equal(r["x"], clean["x"])
    assert np.array_equal(r["centralized"][:6], clean["centralized"][:6])  # y(5) is the first changed
    assert not np.allclose(r["centralized"][6:], clean["centralized"][6:])
    assert not np.allclose(r["kcf"][6:], clean["kcf"][6:])
    biased = ss.scenario(A=[[0.9, 0.2], [0, 0.8]], C={1: [[1, 0]], 2: [[0, 1]]}, graphs={"a": [(1, 2), (2, 1)]},
                         rate=0.5, process_noise=0.1, measurement_noise=0.1,
                         faults=[{"at": 0, "corrupt": 1, "bias": 2.0}])
    honest = ss.scenario(A=[[0.9, 0.2], [0, 0.8]], C={1: [[1, 0]], 2: [[0, 1]]}, graphs={"a": [(1, 2), (2, 1)]},
                         rate=0.5, process_noise=0.1, measurement_noise=0.1)
    hit, ok = ss.compare(biased, seeds=[0, 1], steps=200), ss.compare(honest, seeds=[0, 1], steps=200)
    for row in ("centralized KF", "KCF"):  # a bias of 2 on x1: the steady error grows well beyond the noise's
        assert hit.estimators[row].rms_mean > 3 * ok.estimators[row].rms_mean, row
    assert ok.note is None and "note" not in ok.to_json()
    assert "sensor faults (agent 1) were applied to the measurements of every row" in hit.note
    assert "KCF included" in hit.note and hit.to_json()["note"] == hit.note


def test_small_stated_process_noise_is_not_regularised_away():
    """Issue 46's walk (a motor and its load through a flexible shaft, sampled at 1 ms): process noise std 1e-6 per
    step on the two angles (variance 1e-12) beside 0.05 on the speeds.  It was taken as singular and given 1e-9 on
    every state, so the centralized Kalman filter's P was another model's (predicted RMS 0.2142 against the DARE's
    0.2125 for the stated noise), and a whole-state design at q = 5 was reported at 0.992x of it: a distributed
    estimator better than the centralized one."""
    from scipy.linalg import solve_discrete_are

    import splitspec_core as ss
    from splitspec_core.scenarios.load import parse_scenario_text
    from tests.unit.test_bad_data import MOTOR

    sc = parse_scenario_text(MOTOR, source="motor")
    F, C = np.asarray(sc.system.A), np.vstack([np.asarray(c, dtype=float) for c in sc.system.Cs])
    Q = np.diag(np.array([1e-6, 0.05, 1e-6, 0.05, 0.01]) ** 2)
    R = np.diag(np.array([5e-4, 5e-3, 0.01]) ** 2)
    exact = np.sqrt(np.trace(solve_discrete_are(F.T, C.T, Q, R)))
    assert kalman_predictor(F, C, Q, R).rms == pytest.approx(exact, rel=1e-6)
    d = ss.design(parse_scenario_text(MOTOR.replace("design: {rate: 0.98}",
                                                    "design: {rate: 0.98, consensus: whole, q: 5}"), source="motor"))
    line, = [ln for ln in d.report().splitlines() if ln.startswith("noise: predicted steady-state RMS error")]
    ratio = float(line.split(" = ")[1].split("x the centralized")[0])
    assert ratio >= 1.0, line
