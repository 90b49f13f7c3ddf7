"""The loss and deadline sweeps (`splitspec compare --sweep-loss / --sweep-deadline`): each figure is what
`simulate` of that network gives, and bad requests are refused in one line."""

import dataclasses
import json

import numpy as np
import pytest

from splitspec_core.simulation.metrics import fit_decay, max_error
from splitspec_core.simulation.metrics import steady_rms
from splitspec_core.synthesis.designer import design
from splitspec_core.errors import DesignError
from splitspec_core.model.impairment import LATE, LOSS
from splitspec_core.scenarios.load import load_scenario
from splitspec_core.scenarios.specs import NetworkSpec
from splitspec_core.studies.sweeps import network_sweep, sweep_table
from splitspec_core.simulation.simulator import simulate
from tests.conftest import EXAMPLES
from tests.integration.runtime_helpers import run


def _with_network(sc, net):
    return design(dataclasses.replace(sc, network=net))


def test_each_level_is_the_simulation_of_that_network():
    """A row's figures are recomputed here from `simulate` of the scenario with that loss on every arc (the
    per-arc override included) and the same seeds; the lossless reference from a perfect network."""
    sc = load_scenario(EXAMPLES / "ring10_noise.yaml")
    seeds = [3, 4, 5]
    sw = network_sweep(sc, "loss", [0.0, 0.3], seeds=seeds, steps=60, progress=False)
    assert [r["value"] for r in sw["rows"]] == [0.0, 0.3] and sw["noisy"] and sw["q"] == design(sc).q
    for row, net in ((sw["lossless"], NetworkSpec()), (sw["rows"][1], NetworkSpec(loss=0.3))):
        des = _with_network(sc, net)
        rates, rms, lost = [], [], 0
        for s in seeds:
            clean = simulate(des, seed=s, steps=60, noise=False)
            rates.append(fit_decay(clean.t, max_error(clean), time="discrete", scale=np.linalg.norm(clean.x, axis=1)))
            rms.append(steady_rms(simulate(des, seed=s, steps=60).errors()))
            lost += len(clean.lost)
        # the same functions on the same trajectories, in the same order: equal (up to the mean's summation)
        assert row["rates"] == pytest.approx(rates, rel=1e-12)
        assert row["rms_mean"] == pytest.approx(np.mean(rms), rel=1e-12)
        assert row["lost_per_event"] == pytest.approx(lost / len(seeds) / 60, rel=1e-12)
    assert sw["lossless"]["lost_fraction"] == 0.0 and sw["rows"][0]["lost_fraction"] == 0.0
    # 3 seeds x 60 event times x q x 24 arcs messages, each lost with probability 0.3: the fraction within 4 sd
    n_msgs = 3 * 60 * sw["q"] * 24
    assert abs(sw["rows"][1]["lost_fraction"] - 0.3) < 4 * np.sqrt(0.3 * 0.7 / n_msgs)


def test_a_loss_level_replaces_every_arcs_loss_and_more_loss_slows_the_decay():
    sc = load_scenario(EXAMPLES / "ring10_lossy.yaml")  # loss 0.1, arc 1 -> 6 with 0.3, deadline 20 ms
    assert sc.network.arcs[(1, 6)]["loss"] == 0.3
    sw = network_sweep(sc, "loss", [0.0, 0.6], seeds=range(6), steps=80, progress=False)
    lossless, zero, heavy = sw["lossless"], sw["rows"][0], sw["rows"][1]
    assert zero["lost_per_event"] == 0.0  # the override too is 0: delays of 1-3 ms never pass the 20 ms deadline
    assert zero["rates"] == pytest.approx(lossless["rates"], rel=1e-12)  # nothing lost: the lossless run
    # losing 60% of the messages slows consensus: every seed decays slower than without loss (lam^tau: larger)
    assert all(h > z for h, z in zip(heavy["rates"], zero["rates"]))
    assert not sw["rows"][1]["certified"] and "not certified under loss" in sw["rows"][1]["certificate"]
    lines = sweep_table(sw)
    assert len(lines) == 3 + 2 and "lossless: measured rate" in lines[1] and lines[-1].strip().startswith("0.6")


def test_deadline_sweep_loses_what_arrives_late():
    sc = load_scenario(EXAMPLES / "ring10_lossy.yaml")
    sc = dataclasses.replace(sc, network=dataclasses.replace(sc.network, loss=0.0, arcs={}))
    sw = network_sweep(sc, "deadline", [0.0015, 0.0025, 0.004], seeds=[1, 2], steps=40, progress=False)
    fr = [r["lost_fraction"] for r in sw["rows"]]
    # delays uniform in 1..3 ms: late with probability 3/4, 1/4 and 0
    assert fr[0] > fr[1] > fr[2] == 0.0
    assert abs(fr[0] - 0.75) < 0.05 and abs(fr[1] - 0.25) < 0.05
    tr = simulate(_with_network(sc, dataclasses.replace(sc.network, deadline=0.0015)), seed=1, steps=40)
    assert set(tr.lost_cause.tolist()) == {LATE} and LOSS not in tr.lost_cause


def test_refusals():
    sc = load_scenario(EXAMPLES / "ring10.yaml")
    with pytest.raises(DesignError, match="--sweep-deadline needs a delay distribution"):
        network_sweep(sc, "deadline", [0.01], seeds=[1])
    with pytest.raises(DesignError, match="give 1 to 50 levels"):
        network_sweep(sc, "loss", [0.1] * 51, seeds=[1])


def test_sweep_cli(tmp_path):
    out = tmp_path / "s"
    r = run("compare", EXAMPLES / "ring10_lossy.yaml", "--out", out, "--seeds", 2, "--steps", 30,
            "--sweep-loss", 0, 0.2, "--sweep-deadline", 0.002, 0.004)
    assert r.returncode == 0, r.stderr
    for f in ("loss_sweep.json", "loss_sweep.png", "deadline_sweep.json", "deadline_sweep.png"):
        assert (out / f).stat().st_size > 500
    loss = json.loads((out / "loss_sweep.json").read_text())
    assert loss["seeds"] == [1, 2] and [r["value"] for r in loss["rows"]] == [0.0, 0.2]  # run.seed = 1
    assert "loss sweep" in r.stdout and "deadline sweep" in r.stdout and "measured rate" in r.stdout
    # bad input: one line on stderr, exit 2, nothing written
    for args, msg in ((["--sweep-loss", "1"], "loss probability in [0, 1)"),
                      (["--sweep-loss", "nan"], "loss probability in [0, 1)"),
                      (["--sweep-deadline", "0"], "must be a number in (0, 60]"),
                      (["--sweep-deadline", "-0.001"], "must be a number in (0, 60]"),
                      (["--sweep", "--sweep-loss", "0.1"], "separate studies")):
        bad = tmp_path / "bad"
        r = run("compare", EXAMPLES / "ring10_lossy.yaml", "--out", bad, *args)
        assert r.returncode == 2 and msg in r.stderr and r.stderr.count("\n") == 1, (args, r.stderr)
        assert not bad.exists()
    r = run("compare", EXAMPLES / "ring10.yaml", "--out", tmp_path / "nodelay", "--sweep-deadline", 0.01)
    assert r.returncode == 2 and "needs a delay distribution" in r.stderr and r.stderr.count("\n") == 1
    assert not (tmp_path / "nodelay").exists()


def test_an_unknown_sweep_parameter_is_a_scenario_error():
    """The public API's one error family (SplitspecError), not a bare ValueError: the CLI and callers catch it."""
    from splitspec_core.errors import ScenarioError

    with pytest.raises(ScenarioError, match="^parameter must be one of"):
        network_sweep(load_scenario(EXAMPLES / "ring10_lossy.yaml"), "delay", [0.1], seeds=range(1))
