"""Readable recordings of large models: the default views show the states ``run.show`` picks (by default, of a
model over :data:`~splitspec_core.scenarios.labels.SHOW_ALL` states, those its agents measure), and the rest stays in the
recording.  A real Recorder writes a real run.rrd, read back."""

from __future__ import annotations

import numpy as np
import pytest

import splitspec_core as ss
from splitspec_core.scenarios.labels import SHOW_ALL, shown_states
from splitspec_orchestrator.viewer import blueprint as bp
from splitspec_orchestrator.plots import states_figure
from splitspec_orchestrator.records.recorder import Recorder
from splitspec_orchestrator.records.recover import _blueprint
from tests.rrd_readback import rrd_entities, verify_rrd

N = 20
NAMES = tuple([f"delta_{k}" for k in range(1, 5)] + [f"omega_{k}" for k in range(1, 5)]
              + [f"e_{k}" for k in range(1, 13)])


def state_views(blueprint) -> list[str]:
    tabs = blueprint.root_container.contents[0]
    grid = next(t for t in tabs.contents if t.name == "states")
    return [str(v.origin) for v in grid.contents]


def test_which_states_the_default_views_show():
    Cs = [np.eye(N)[[k, 4 + k]] for k in range(4)]  # agent k+1 measures delta_k and omega_k (a PMU)
    shown = shown_states(NAMES, None, Cs)
    assert [NAMES[k] for k in shown] == [f"delta_{k}" for k in range(1, 5)] + [f"omega_{k}" for k in range(1, 5)]
    assert shown_states(NAMES, ("omega_*", "e_1?"), Cs) == tuple(range(4, 8)) + tuple(range(17, 20))
    assert shown_states(NAMES[:SHOW_ALL], None, [C[:, :SHOW_ALL] for C in Cs]) == tuple(range(SHOW_ALL))
    # a scenario's run.show: names or patterns, each matching a state, else one line
    A = -np.eye(N)
    sc = ss.scenario(A=A, C={k + 1: C for k, C in enumerate(Cs)}, states=NAMES, rate=0.5, time="continuous",
                     graphs={"r": [(1, 2), (2, 3), (3, 4), (4, 1)]}, show=["e_3", "omega_1"])
    assert sc.shown_states == (4, 10)
    with pytest.raises(ss.ScenarioError, match=r"run.show\[2\] = 'zeta\*' matches no state"):
        ss.scenario(A=A, C={k + 1: C for k, C in enumerate(Cs)}, states=NAMES, rate=0.5, time="continuous",
                    graphs={"r": [(1, 2), (2, 3), (3, 4), (4, 1)]}, show=["e_3", "zeta*"])


def test_the_recording_keeps_every_state_and_its_blueprint_shows_the_picked_ones(tmp_path):
    shown = (0, 4, 17)
    blue = bp.default_blueprint("discrete", n=N, states=NAMES, shown=shown)
    assert state_views(blue) == [f"state/{NAMES[k]}" for k in shown]
    assert len(state_views(bp.default_blueprint("discrete", n=N, states=NAMES))) == N  # shown None: all
    ids = (1, 2, 3, 4)
    rec = Recorder(tmp_path, agent_ids=ids, n=N, steps=5, time_mode="discrete", dt=1.0, graph_names=("r",),
                   run_id="large", scenario_name="large", states=NAMES, shown=shown)
    rec.topology(0, "r", ids, [(1, 2), (2, 3), (3, 4), (4, 1)])
    rng = np.random.default_rng(1)
    for tau in range(6):
        rec.row(tau, rng.normal(size=N), rng.normal(size=(4, N)), np.ones(4, dtype=bool), 0)
    rec.close()
    rrd = tmp_path / "run.rrd"
    verify_rrd(rrd)
    entities = rrd_entities(rrd)
    assert all(f"state/{name}/agents" in entities and f"state/{name}/truth" in entities for name in NAMES)
    # the blueprint `splitspec view` rebuilds from the recording's properties shows the same picked states
    assert state_views(_blueprint(rrd)) == [f"state/{NAMES[k]}" for k in shown]


def test_states_png_draws_the_picked_states():
    sc = ss.scenario(A=0.9 * np.eye(N), C={1: np.eye(N)[:10], 2: np.eye(N)[10:]}, states=NAMES, rate=0.95,
                     graphs={"a": [(1, 2), (2, 1)]}, steps=5, show=["omega_*"])
    tr = ss.simulate(sc)
    fig = states_figure(tr, time="discrete", title="t", shown=sc.shown_states)
    try:
        labels = [ax.get_ylabel() for ax in fig.axes]
        assert labels == [f"omega_{k}" for k in range(1, 5)], labels
    finally:
        import matplotlib.pyplot as plt

        plt.close(fig)
