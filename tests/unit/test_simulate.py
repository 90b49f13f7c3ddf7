"""Batch simulator vs per-agent step functions, exact ODE, faults, reproducibility."""

import dataclasses

import numpy as np
import pytest

from splitspec_core.simulation.metrics import fit_decay, max_error
from splitspec_core.synthesis.designer import design
from splitspec_core.scenarios.generate import random_strongly_connected_arcs, random_system
from splitspec_core.scenarios.load import load_scenario, parse_scenario
from splitspec_core.simulation.simulator import Trajectory, simulate, simulate_exact
from tests.conftest import EXAMPLES
from tests.numerics import assert_close, max_rel_diff


def random_scenario(seed: int, *, time: str, m: int = 5, n: int = 6, g="auto", noise=0.05, faults=(), bad_data=None):
    rng = np.random.default_rng(seed)
    A, Cs = random_system(rng, m, n, time=time)
    arcs_a = random_strongly_connected_arcs(rng, m, extra=m)
    arcs_b = random_strongly_connected_arcs(rng, m, extra=2)
    d = {"rate": 0.8, "gains": "place", "q": "auto"} if time == "discrete" else {"rate": 0.5, "gains": "riccati",
                                                                                   "g": g}
    if bad_data is not None:  # else the default: on under the measurement noise where the design calibrates it
        d["bad_data"] = bad_data
    return parse_scenario({
        "name": f"rand{seed}", "time": time,
        "system": {"A": A.tolist(), "C": {i + 1: C.tolist() for i, C in enumerate(Cs)},
                   "process_noise": noise, "measurement_noise": noise},
        "graphs": {"a": {"arcs": [[j + 1, i + 1] for j, i in arcs_a]},
                   "b": {"arcs": [[j + 1, i + 1] for j, i in arcs_b]}},
        "switching": {"random": {"graphs": ["a", "b"], "dwell": 3 if time == "discrete" else 0.05}},
        "design": d,
        "faults": list(faults),
        "run": {"steps": 300, "seed": seed, **({"dt": 0.01} if time == "continuous" else {})},
    })


@pytest.mark.parametrize("time,g", [("discrete", None), ("continuous", "auto"), ("continuous", "adaptive")])
@pytest.mark.parametrize("seed", [1, 2])
def test_batch_equals_per_agent_step_functions(time, g, seed):
    faults = [{"at": 100 if time == "discrete" else 1.0, "kill": 2},
              {"at": 200 if time == "discrete" else 2.0, "restart": 2}]
    sc = random_scenario(seed, time=time, g=g or "auto", faults=faults)
    des = design(sc)
    a = simulate(des, estimator="batch")
    b = simulate(des, estimator="loop")
    assert a.xhat.shape == (301, 5, 6)
    # vectorised against per-agent loops: other summation orders; 300 steps of a contracting recursion with
    # entries of order one, so 1e-12 of the larger norm leaves room for the round-off of each step
    assert_close(a.xhat, b.xhat, rtol=1e-12, equal_nan=True, what="xhat")  # NaN where dead, in both
    assert np.array_equal(a.x, b.x)  # exact: one Plant class draws and steps the truth, whatever the estimator
    assert len(set(a.graph.tolist())) == 2  # it really switched
    if g == "adaptive":
        assert_close(a.g, b.g, rtol=1e-12, equal_nan=True, what="adaptive g_i")
        assert np.all(np.diff(a.g[:100], axis=0) >= 0)  # eq. (adaptive): g_i is non-decreasing


def test_same_seed_same_trajectory_and_different_seed_differs():
    des = design(load_scenario(EXAMPLES / "paper_discrete_switching.yaml"))
    a, b, c = simulate(des, seed=3), simulate(des, seed=3), simulate(des, seed=4)
    # exact: the same function on the same input, twice (reproducibility is this test's subject)
    assert np.array_equal(a.xhat, b.xhat) and np.array_equal(a.x, b.x)
    assert not np.allclose(a.x, c.x)


def test_sampled_data_converges_to_exact_ode_as_dt_shrinks():
    sc = load_scenario(EXAMPLES / "paper_continuous.yaml")
    errs = []
    for dt in (0.01, 0.005):
        s2 = dataclasses.replace(sc, run=dataclasses.replace(sc.run, dt=dt, steps=int(round(2.0 / dt))),
                                 system=dataclasses.replace(sc.system, process_noise=0.0))
        des = design(s2)
        sampled, exact = simulate(des), simulate_exact(des)
        assert np.allclose(sampled.x, exact.x, atol=1e-12)  # same plant, same initial conditions
        errs.append(np.nanmax(np.abs(sampled.xhat - exact.xhat)))
    ratio = errs[0] / errs[1]
    # first-order discretisation: halving dt halves the gap to the ODE
    assert 1.7 < ratio < 2.4, (errs, ratio)
    assert errs[1] < 0.05


def test_exact_ode_meets_designed_rate():
    sc = load_scenario(EXAMPLES / "paper_continuous_switching.yaml")
    des = design(sc)
    tr = simulate_exact(des, steps=600)
    rate = fit_decay(tr.t, max_error(tr), time="continuous", scale=np.linalg.norm(tr.x, axis=1))
    assert rate >= 1.0


def test_kill_makes_row_nan_and_survivors_converge():
    sc = load_scenario(EXAMPLES / "ring10.yaml")
    sc = dataclasses.replace(sc, faults=parse_scenario(
        {**_raw(EXAMPLES / "ring10.yaml"), "faults": [{"at": 10, "kill": 3}]}).faults)
    des = design(sc)
    assert des.redundantly_jointly_observable and des.redundantly_strongly_connected
    tr = simulate(des, steps=80)
    k = 2  # agent 3
    assert np.all(np.isnan(tr.xhat[10:, k])) and np.all(np.isfinite(tr.xhat[:10, k]))
    assert not tr.alive[10:, k].any() and tr.alive[:10, k].all()
    e = tr.errors()
    survivors = [i for i in range(10) if i != k]
    assert np.max(e[-1, survivors]) < 1e-8 * np.max(e[0, survivors])
    # the survivors keep the designed rate after the loss (resilience: 1)
    rate = fit_decay(tr.t[10:], np.nanmax(e[10:, survivors], axis=1), time="discrete",
                     scale=np.linalg.norm(tr.x[10:], axis=1))
    assert rate <= 0.8


def test_restart_rejoins_with_fresh_estimate_and_converges():
    raw = _raw(EXAMPLES / "ring10.yaml")
    sc = parse_scenario({**raw, "faults": [{"at": 10, "kill": 5}, {"at": 30, "restart": 5}]})
    des = design(sc)
    tr = simulate(des, steps=90)
    k = 4
    assert np.all(np.isnan(tr.xhat[10:30, k]))
    assert np.all(np.isfinite(tr.xhat[30:, k]))
    e = tr.errors()
    assert e[30, k] > 1e-3  # fresh estimate, far from the truth
    assert e[-1, k] < 1e-8 * e[30, k]


def test_drop_arc_changes_weights_but_keeps_convergence():
    raw = _raw(EXAMPLES / "paper_discrete.yaml")
    sc = parse_scenario({**raw, "faults": [{"at": 5, "drop_arc": [1, 3]}, {"at": 15, "restore_arc": [1, 3]}]})
    des = design(sc)
    tr = simulate(des)
    base = simulate(design(parse_scenario(raw)))
    # step 5 uses the reduced graph, x(6) differs; before it, the same estimator on the same graph (to round-off:
    # the fault splits the run into other batches of steps)
    assert_close(tr.xhat[:6], base.xhat[:6], rtol=1e-12, what="xhat before the fault")
    assert max_rel_diff(tr.xhat[6], base.xhat[6]) > 1e-6  # far beyond round-off
    assert np.nanmax(tr.errors()[-1]) < 1e-6


def test_trajectory_roundtrip(tmp_path):
    des = design(load_scenario(EXAMPLES / "paper_discrete.yaml"))
    tr = simulate(des)
    tr.save(tmp_path / "t.npz")
    back = Trajectory.load(tmp_path / "t.npz")
    for f in ("t", "x", "xhat", "alive", "graph", "agent_ids"):  # exact: a save/load round trip copies the bytes
        assert np.array_equal(getattr(tr, f), getattr(back, f), equal_nan=f == "xhat")


def _raw(path):
    import yaml
    return yaml.safe_load(open(path))


def test_envelope_restarts_at_rejoins_and_switches_only():
    from splitspec_core.simulation.metrics import envelope, envelope_restarts

    alive = np.ones((10, 2), dtype=bool)
    alive[3:6, 1] = False  # lost at 3 (no restart), rejoins at 6 (restart)
    graph = np.array([0, 0, 0, 0, 0, 0, 0, 0, 1, 1])  # switch at 8 (restart)
    assert envelope_restarts(alive, graph).tolist() == [0, 6, 8]
    t = np.arange(10.0)
    err = np.array([8.0, 4, 2, 1, 0.5, 0.25, 10, 5, 3, 1.5])
    env = envelope(t, err, [0, 6, 8], time="discrete", rate=0.5)
    # each piece starts at the error it restarts from and halves every event time
    assert np.allclose(env, [8, 4, 2, 1, 0.5, 0.25, 10, 5, 3, 1.5])
    fitted = envelope(t, err * np.array([1, 1, 1, 1, 1, 1, 1, 1.2, 1, 1]), [0, 6, 8], time="discrete", rate=0.5,
                      fit=True)
    assert np.allclose(fitted[6:8], [12, 6])  # the smallest constant above the piece
    cont = envelope(np.linspace(0, 1, 5), np.ones(5), [0], time="continuous", rate=2.0)
    assert np.allclose(cont, np.exp(-2.0 * np.linspace(0, 1, 5)))


def test_exact_refuses_what_it_cannot_integrate():
    """Library callers get the same one line (a ScenarioError naming the key), no function names."""
    from splitspec_core.errors import ScenarioError

    sc = load_scenario(EXAMPLES / "paper_continuous.yaml")
    adaptive = design(dataclasses.replace(sc, design=dataclasses.replace(sc.design, g="adaptive")))
    with pytest.raises(ScenarioError, match="design.g is adaptive") as err:
        simulate_exact(adaptive, steps=5)
    assert "simulate_exact" not in str(err.value)
    with pytest.raises(ScenarioError, match="time: discrete"):
        simulate_exact(design(load_scenario(EXAMPLES / "paper_discrete.yaml")), steps=5)


def test_simulate_takes_faults_as_run_does():
    """``ss.simulate(sc, faults=...)`` is the scenario with that ``faults:`` list: the same trajectory as the file that
    writes it (the same operations in the same order: compared exactly), from a scenario or a design; a wrong entry
    is one line naming it."""
    import dataclasses

    import splitspec_core as ss

    listed = [{"at": 10, "kill": 3}, {"at": 15, "drop_arc": [1, 6]}, {"at": 20, "freeze": 5}, {"at": 30, "restart": 3},
              {"at": 35, "restart": 5}, {"at": 40, "restore_arc": [1, 6]}]
    filed = ss.load_scenario(EXAMPLES / "ring10_faults.yaml")
    assert len(filed.faults) == len(listed)
    bare = dataclasses.replace(filed, faults=())
    want = ss.simulate(filed)
    for source in (bare, ss.design(bare)):
        got = ss.simulate(source, faults=listed)
        np.testing.assert_array_equal(got.alive, want.alive)
        np.testing.assert_array_equal(got.xhat, want.xhat)
    assert not np.array_equal(ss.simulate(bare).alive, want.alive)
    with pytest.raises(ss.ScenarioError, match=r"^faults\[1\]\.kill names agent 99, which is not in system.C"):
        ss.simulate(bare, faults=[{"at": 1, "kill": 99}])


def test_hang_is_read_as_freeze_the_one_word_for_a_frozen_process():
    """Scenario files and recorded runs written before the fault was named ``freeze`` say ``hang``: read as freeze;
    both at once is two actions (refused in one line)."""
    import splitspec_core as ss

    base = ss.load_scenario(EXAMPLES / "ring10_faults.yaml")
    old = [{"at": 20, "hang": 5}, {"at": 35, "restart": 5}]
    new = [{"at": 20, "freeze": 5}, {"at": 35, "restart": 5}]
    a, b = ss.simulate(base, faults=old), ss.simulate(base, faults=new)
    np.testing.assert_array_equal(a.alive, b.alive)  # the same faults: the same operations in the same order
    assert [f.action for f in dataclasses.replace(base, faults=()).faults] == []
    with pytest.raises(ss.ScenarioError, match=r"faults\[1\] needs exactly one of kill, restart, freeze"):
        ss.simulate(base, faults=[{"at": 20, "hang": 5, "freeze": 5}])
