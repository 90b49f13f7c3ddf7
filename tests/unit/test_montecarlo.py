"""Monte Carlo as one batch (splitspec_core.simulation.montecarlo): every seed equals its single-seed simulation.

Why not bit for bit: the batch steps all seeds with one product each (``(m, n, n) @ (m, n, N)``, a sparse
``S @ Z`` with ``n N`` columns, ``(n, n) @ (n, N)`` for the plant), where a single-seed run multiplies
vectors; BLAS sums those in another order, and the discrete sub-rounds run as
``z_i <- (I - P_i) x_i + P_i sum_j w_ij z_j`` where the single-seed lossless path runs them in
unobservable-space coordinates.  Both are the same recursion, so they differ by round-off: 1e-9 of the
larger max-norm over a whole trajectory (``tests/numerics.py``); measured about 1e-15 on these scenarios.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

import splitspec_core as ss
from splitspec_core.simulation.metrics import monte_carlo_stats
from splitspec_core.simulation.metrics import steady_rms
from splitspec_core.synthesis.designer import design
from splitspec_core.errors import ScenarioError
from splitspec_core.simulation.montecarlo import fallback_reason, simulate_seeds
from splitspec_core.scenarios.load import load_scenario
from splitspec_core.simulation.simulator import simulate
from splitspec_core.model.streams import stream
from splitspec_orchestrator import cli
from tests.conftest import EXAMPLES
from tests.numerics import assert_close, max_rel_diff
from tests.unit.test_simulate import random_scenario

SEEDS = (3, 4, 5, 6, 7)


def assert_stats_close(got: dict, want: dict, keys) -> None:
    """Every statistic within 1e-9 of the largest mean RMS error (the run's error scale): a noise-free run's
    steady-state error is itself round-off (1e-16 of that scale), so a relative test of it would compare noise."""
    scale = float(np.max(want["mean"]))
    for k in keys:
        diff = np.max(np.abs(np.asarray(got[k], dtype=float) - np.asarray(want[k], dtype=float)))
        assert diff <= 1e-9 * scale, f"{k}: differs by {diff:.3g}, {diff / scale:.3g} of the error scale {scale:.3g}"


def _seeded_switching(sc):
    """The scenario with its random switching drawn from a fixed ``switching.seed`` (the same for every run)."""
    return dataclasses.replace(sc, switching=dataclasses.replace(sc.switching, seed=11))


def _faults(time: str) -> list:
    at = (lambda k: k) if time == "discrete" else (lambda k: k / 100)
    return [{"at": at(60), "kill": 2}, {"at": at(90), "drop_arc": [1, 2]}, {"at": at(120), "restart": 2},
            {"at": at(150), "restore_arc": [1, 2]}]


CASES = {
    "paper_discrete_noise": lambda: load_scenario(EXAMPLES / "paper_discrete_noise.yaml"),
    "paper_discrete_switching": lambda: load_scenario(EXAMPLES / "paper_discrete_switching.yaml"),
    "paper_continuous": lambda: load_scenario(EXAMPLES / "paper_continuous.yaml"),
    "ring10_faults_switching": lambda: load_scenario(EXAMPLES / "ring10_faults_switching.yaml"),
    "ring10_partition": lambda: load_scenario(EXAMPLES / "ring10_partition.yaml"),
    # design.bad_data: off: the default test (on under measurement noise) runs per seed (test_what_falls_back_and_why)
    "random discrete, faults, switching": lambda: _seeded_switching(
        random_scenario(1, time="discrete", faults=_faults("discrete"), bad_data="off")),
    "random continuous, faults, switching": lambda: _seeded_switching(
        random_scenario(2, time="continuous", faults=_faults("continuous"))),
    "random adaptive g, faults, switching": lambda: _seeded_switching(
        random_scenario(3, time="continuous", g="adaptive", faults=_faults("continuous"))),
    # a seed changes more than the noise here: the per-seed loop, with the same results
    "ring10_lossy (loss drawn per seed)": lambda: load_scenario(EXAMPLES / "ring10_lossy.yaml"),
    "random switching drawn per seed": lambda: random_scenario(4, time="discrete", faults=_faults("discrete")),
}
FALLS_BACK = {"ring10_lossy (loss drawn per seed)", "random switching drawn per seed"}


@pytest.mark.parametrize("name", list(CASES))
def test_batched_seeds_equal_single_seed_simulations(name):
    des = design(CASES[name]())
    steps = 200
    runs = simulate_seeds(des, SEEDS, steps=steps, trajectories=True, chunk=3)  # two chunks: 3 + 2 seeds
    assert runs.batched == (name not in FALLS_BACK), runs.fallback
    assert runs.seeds == SEEDS and runs.sq_error.shape == (len(SEEDS), steps + 1)
    for s, tr in zip(SEEDS, runs.trajectories):
        ref = simulate(des, seed=s, steps=steps)
        # flags, indices and losses: the same by construction (faults and partitions strike every seed alike)
        for f in ("t", "alive", "graph", "agent_ids", "lost", "lost_cause"):
            np.testing.assert_array_equal(getattr(tr, f), getattr(ref, f), err_msg=f"{f}, seed {s}")
        assert_close(tr.x, ref.x, rtol=1e-9, what=f"x, seed {s}")
        assert_close(tr.xhat, ref.xhat, rtol=1e-9, equal_nan=True, what=f"xhat, seed {s}")  # NaN where dead
        assert_close(tr.g, ref.g, rtol=1e-9, equal_nan=True, what=f"g_i, seed {s}")
        # every other per-agent row column (rows.py): what the network decides, the same integers in both
        assert set(tr.columns) == set(ref.columns), (sorted(tr.columns), sorted(ref.columns))
        for k in set(ref.columns) - {"g"}:
            np.testing.assert_array_equal(tr.columns[k], ref.columns[k], err_msg=f"{k}, seed {s}")
    if "switching" in name:
        assert len(set(runs.trajectories[0].graph.tolist())) == 2  # it really switched
    if "faults" in name:
        assert not runs.trajectories[0].alive.all()  # an agent really died


@pytest.mark.parametrize("name", ["paper_discrete_noise", "ring10_faults_switching",
                                  "random adaptive g, faults, switching"])
def test_statistics_without_trajectories_equal_monte_carlo_stats_of_the_loop(name):
    des = design(CASES[name]())
    runs = simulate_seeds(des, SEEDS, steps=150)
    assert runs.trajectories is None and runs.batched
    trajs = [simulate(des, seed=s, steps=150) for s in SEEDS]
    want, got = monte_carlo_stats(trajs), runs.stats()
    assert got.keys() == want.keys() and got["seeds"] == len(SEEDS)
    assert_stats_close(got, want, ("mean", "std", "p10", "p90", "steady_rms_mean", "steady_rms_std", "final_rms_mean",
                                   "final_rms_std"))
    e = [tr.errors() for tr in trajs]
    assert_close(runs.rms(), [np.sqrt(np.nanmean(x ** 2, axis=1)) for x in e], rtol=1e-9, what="rms")
    assert_stats_close({"s": runs.steady_rms()}, {"s": [steady_rms(x) for x in e], "mean": want["mean"]}, ["s"])


def test_the_loop_and_the_batch_give_the_same_errors_and_chunks_do_not_matter():
    des = design(CASES["random discrete, faults, switching"]())
    seeds = range(10, 17)
    batch = simulate_seeds(des, seeds, steps=120)
    loop = simulate_seeds(des, seeds, steps=120, force_loop=True)
    one = simulate_seeds(des, seeds, steps=120, chunk=1)
    assert batch.batched and not loop.batched and loop.fallback == "per-seed loop asked for"
    np.testing.assert_array_equal(batch.alive_count, loop.alive_count)  # integers: faults alike per seed
    assert max_rel_diff(batch.sq_error, loop.sq_error) <= 1e-9
    assert max_rel_diff(batch.sq_error, one.sq_error) <= 1e-9  # other chunk sizes: other BLAS shapes only


def test_a_stream_drawn_whole_equals_its_draws_one_step_at_a_time():
    """The batch draws each seed's noise for the whole run at once; it must be the same numbers."""
    a, b = stream(7, "process"), stream(7, "process")
    np.testing.assert_array_equal(np.stack([a.normal(size=5) for _ in range(40)]), b.normal(size=(40, 5)))


def test_what_falls_back_and_why():
    assert fallback_reason(design(load_scenario(EXAMPLES / "ring10_faults_switching.yaml"))) is None
    assert "network" in fallback_reason(design(load_scenario(EXAMPLES / "ring10_lossy.yaml")))
    des = design(load_scenario(EXAMPLES / "ring10.yaml"))
    assert "replay" in fallback_reason(des, lost=np.zeros((0, 4), dtype=np.int64))
    assert "measurements" in fallback_reason(des, measurements=object())
    assert "switching" in fallback_reason(design(random_scenario(4, time="discrete")))
    noisy = _seeded_switching(random_scenario(1, time="discrete"))  # the bad-data test on by default (issue 46)
    assert fallback_reason(design(noisy)).startswith("design.bad_data: each agent's test decides, per seed")


def test_ss_simulate_with_seeds():
    sc = load_scenario(EXAMPLES / "ring10_noise.yaml")
    runs = ss.simulate(sc, seeds=iter([1, 2, 3]), steps=30)  # any iterable
    assert isinstance(runs, ss.MonteCarloRuns) and runs.seeds == (1, 2, 3) and runs.t.shape == (31,)
    with pytest.raises(ScenarioError, match="not both"):
        ss.simulate(sc, seed=1, seeds=[1, 2], steps=5)
    with pytest.raises(ScenarioError, match="seeds is empty"):
        ss.simulate(sc, seeds=[], steps=5)
    with pytest.raises(ScenarioError, match="give seeds"):
        ss.simulate(sc, trajectories=True, steps=5)
    with pytest.raises(ScenarioError, match="keep_y"):
        ss.simulate(sc, seeds=[1], keep_y=True, steps=5)
    exact = ss.simulate(load_scenario(EXAMPLES / "paper_continuous.yaml"), seeds=[1, 2], steps=20, exact=True)
    assert not exact.batched and "exact" in exact.fallback


@pytest.mark.parametrize("name", ["paper_discrete_noise", "ring10_faults_switching", "paper_continuous"])
def test_cli_monte_carlo_figures_equal_the_looped_version(name, tmp_path, capsys):
    """``splitspec simulate --monte-carlo N``'s summary.json: the numbers the per-seed loop gave before."""
    import json

    path = EXAMPLES / f"{name}.yaml"
    assert cli.main(["simulate", str(path), "--out", str(tmp_path), "--no-plots", "--seed", "3", "--steps", "120",
                     "--monte-carlo", "4"]) == 0
    capsys.readouterr()
    got = json.loads((tmp_path / "summary.json").read_text())["monte_carlo"]
    des = design(load_scenario(path))
    want = monte_carlo_stats([simulate(des, seed=s, steps=120) for s in range(3, 7)])  # the loop it replaced
    assert got.keys() == {k for k, v in want.items() if not hasattr(v, "shape")}
    assert got["seeds"] == 4
    assert_stats_close(got, want, [k for k in got if k != "seeds"])


def test_seeds_over_a_measurements_file_run_one_after_another(tmp_path):
    """One realisation of y: only the initial estimates change with the seed; the loop, the same numbers."""
    from splitspec_core.scenarios.measurements import write_measurements

    sc = load_scenario(EXAMPLES / "ring10_noise.yaml")
    tr = ss.simulate(sc, seed=1, steps=40, keep_y=True)
    write_measurements(tmp_path / "m.npz", t=tr.t, y=tr.y, agent_ids=sc.agent_ids,
                       sizes=[np.shape(C)[0] for C in sc.system.Cs], x=tr.x)
    runs = ss.simulate(sc, seeds=[1, 2], measurements=tmp_path / "m.npz")
    assert not runs.batched and "measurements" in runs.fallback
    for k, s in enumerate((1, 2)):
        ref = ss.simulate(sc, seed=s, measurements=tmp_path / "m.npz")
        # the loop calls this very simulate: the same operations, so the same numbers
        np.testing.assert_array_equal(runs.sq_error[k], np.nansum(ref.errors() ** 2, axis=1))
