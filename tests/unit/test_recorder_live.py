"""The recorder with live sensors: the y_i the agents used (from their xhat) become trajectory.npz's y and
y_missing, and at the close what is known without truth (the centralized Kalman filter on those y)."""

import dataclasses
import os

import numpy as np

from splitspec_core.studies.no_truth import kalman_reference
from splitspec_core.scenarios.load import load_scenario
from splitspec_orchestrator.records.recorder import Recorder
from tests.conftest import EXAMPLES

os.environ.setdefault("RERUN_ANALYTICS", "0")


def test_the_y_used_is_recorded_with_its_gaps_and_the_kf_runs_on_it(tmp_path):
    sc = load_scenario(EXAMPLES / "sensors" / "chain.yaml")
    sc = dataclasses.replace(sc, run=dataclasses.replace(sc.run, steps=5))
    rec = Recorder(tmp_path, agent_ids=sc.agent_ids, n=sc.n, steps=5, time_mode="discrete", dt=1.0,
                   graph_names=sc.graph_names, run_id="live", scenario_name=sc.name, flush_seconds=1e9)
    rec.set_live_sources(sc)
    rng = np.random.default_rng(2)
    xhat = rng.normal(size=(6, 3, sc.n))
    alive = np.ones(3, dtype=bool)
    for tau in range(6):
        used = [(1, [tau, -tau]), (2, None if tau == 2 else [1.0, 2.0])] + ([(3, [0.5, 0.25])] if tau else [])
        rec.live_y(tau, used)  # agent 3 not alive at 0 (not listed): missing
        rec.row(tau, np.full(sc.n, np.nan), xhat[tau], alive, 0)
    rec.close()
    with np.load(tmp_path / "trajectory.npz") as z:
        y, miss = z["y"], z["y_missing"]
        assert y.shape == (6, 6) and miss.shape == (6, 3)
        assert miss[2, 1] and miss[0, 2] and miss.sum() == 2
        assert np.array_equal(y[4], [4.0, -4.0, 1.0, 2.0, 0.5, 0.25]) and np.isnan(y[2, 2:4]).all()
        # the reference, computed on the recorded y: the same function, the same input, so to the last bit
        assert np.array_equal(z["kf"], kalman_reference(sc, y, miss))
        assert np.isnan(z["x"]).all() and np.isfinite(z["kf_distance"]).all()
