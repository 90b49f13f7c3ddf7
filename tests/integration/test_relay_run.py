"""The relay kind (``design.consensus: relay``, issue 44) as real processes: every agent its own OS process over real
Zenoh sessions on loopback, passing the sensors' samples on in ``r`` messages, through a kill and a restart (the lost
agent's samples left out, the restarted one walking from its fresh estimate) and a lossy network (a lost message's
samples left out of the receiver's walk), against ``simulate`` to round-off."""

import copy

import numpy as np
import pytest
import yaml

from tests.integration.runtime_helpers import compare_with_simulate, events, run
from tests.integration.test_runtime import NOISY_CONTINUOUS, NOISY_DISCRETE

pytestmark = pytest.mark.slow


def _relay(raw: dict, q: int, **extra) -> dict:
    out = copy.deepcopy(raw)
    out["name"] = raw["name"].replace("whole", "relay")
    out["design"] = {"rate": raw["design"]["rate"], "consensus": "relay", "q": q}
    out.update(extra)
    return out


# the discrete ring runs lossy (its kill and restart kept): the lossless round is the same path with every message in,
# and the deployments' tests are make test's long pole (one worker, one after another)
@pytest.mark.parametrize("raw", [_relay(NOISY_DISCRETE, 1, network={"loss": 0.2}), _relay(NOISY_CONTINUOUS, 1)],
                         ids=["discrete-lossy", "continuous"])
def test_run_equals_simulate_for_the_relay_kind(tmp_path, raw):
    import splitspec_core as ss

    scen = tmp_path / f"{raw['name']}.yaml"
    scen.write_text(yaml.safe_dump(raw))
    des = ss.design(ss.load_scenario(scen))
    assert des.detail.consensus == "relay" and des.detail.q == 1 and des.checks.rate_certified
    if raw["time"] == "discrete":  # the ring of 4 at one exchange: the far sensor one event time late
        assert des.detail.whole.D == 1
    out = tmp_path / "out"
    r = run("run", scen, "--out", out)
    assert r.returncode == 0, r.stdout + r.stderr
    compare_with_simulate(out, scen, tmp_path)
    traj = np.load(out / "trajectory.npz")
    k = 3 if raw["time"] == "discrete" else 2
    alive = traj["alive"][:, k - 1]
    assert not alive.all() and alive[-1]  # killed, then back
    if "network" in raw:  # messages were lost, their samples left out: the comparison above covered them
        assert traj["lost"].shape[0] > 0
    names = {e["event"] for e in events(out)}
    assert "run_finished" in names
