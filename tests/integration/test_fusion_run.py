"""The fusion kind (``design.consensus: fusion``, issue 44) as real processes: every agent its own OS process over
real Zenoh sessions on loopback, through a kill and a restart (the lost agent's weights folded into its neighbours'
own), a lossy network (each lost message's weight folded the same way) and switching graphs (gains per graph),
against ``simulate`` to round-off."""

import copy

import numpy as np
import pytest
import yaml

from tests.integration.runtime_helpers import compare_with_simulate, events, run
from tests.integration.test_runtime import NOISY_CONTINUOUS, NOISY_DISCRETE

pytestmark = pytest.mark.slow


def _fusion(raw: dict, q: int, **extra) -> dict:
    out = copy.deepcopy(raw)
    out["name"] = raw["name"].replace("whole", "fusion")
    out["design"] = {"rate": raw["design"]["rate"], "consensus": "fusion", "q": q}
    out.update(extra)
    return out


SWITCHING = _fusion(NOISY_DISCRETE, 1, graphs={"ring": {"undirected": [[1, 2], [2, 3], [3, 4], [4, 1]]},
                                               "star": {"undirected": [[1, 2], [1, 3], [1, 4], [2, 3]]}},
                    switching={"schedule": [[0, "ring"], [5, "star"]], "period": 10}, network={"loss": 0.2})


@pytest.mark.parametrize("raw", [_fusion(NOISY_DISCRETE, 2), _fusion(NOISY_CONTINUOUS, 2), SWITCHING],
                         ids=["discrete", "continuous", "switching-lossy"])
def test_run_equals_simulate_for_the_fusion_kind(tmp_path, raw):
    import splitspec_core as ss

    scen = tmp_path / f"{raw['name']}.yaml"
    scen.write_text(yaml.safe_dump(raw))
    des = ss.design(ss.load_scenario(scen))
    assert des.detail.consensus == "fusion" and des.detail.q == raw["design"]["q"]
    out = tmp_path / "out"
    r = run("run", scen, "--out", out)
    assert r.returncode == 0, r.stdout + r.stderr
    compare_with_simulate(out, scen, tmp_path)
    traj = np.load(out / "trajectory.npz")
    k = 3 if raw["time"] == "discrete" else 2
    alive = traj["alive"][:, k - 1]
    assert not alive.all() and alive[-1]  # killed, then back
    if "network" in raw:  # messages were lost, and folded: the comparison above covered them
        assert traj["lost"].shape[0] > 0
        assert len(set(traj["graph"].tolist())) == 2
    names = {e["event"] for e in events(out)}
    assert "run_finished" in names
