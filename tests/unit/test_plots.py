"""simulate's plots and summary: events marked, legends outside the data, envelope restarted, adaptive gain honest."""

import json

import matplotlib.pyplot as plt
import numpy as np
import pytest
import yaml

from splitspec_orchestrator import cli, plots
from splitspec_core.simulation.metrics import NO_CERTIFIED_RATE, Mark, event_marks, max_error, summarize
from splitspec_core.synthesis.designer import design
from splitspec_core.scenarios.load import load_scenario
from splitspec_core.scenarios.faults import make_fault
from splitspec_core.simulation.simulator import simulate
from tests.conftest import EXAMPLES


def test_event_marks_hand_worked():
    alive = np.ones((8, 3), dtype=bool)
    alive[2:5, 1] = False  # agent 20 killed at 2, back at 5
    alive[4:, 2] = False  # agent 30 lost at 4 (no fault names it)
    graph = np.array([0, 0, 0, 1, 1, 1, 1, 0])
    faults = (make_fault("kill", 2, agent=20), make_fault("drop_arc", 3, arc=(10, 20)),
              make_fault("restore_arc", 6, arc=(10, 20)), make_fault("kill", 99, agent=10))
    marks = event_marks(np.arange(8.0), alive, graph, agent_ids=[10, 20, 30], faults=faults,
                        graph_names=("a", "b"))
    assert marks == (Mark(2, 2.0, "loss", "20 killed"), Mark(3, 3.0, "switch", "graph b"),
                     Mark(3, 3.0, "arc", "arc 10-20 down"), Mark(4, 4.0, "loss", "30 lost"),
                     Mark(5, 5.0, "rejoin", "20 rejoins"), Mark(6, 6.0, "arc", "arc 10-20 up"),
                     Mark(7, 7.0, "switch", "graph a"))


def test_event_marks_continuous_time_uses_the_fault_step():
    t = np.arange(5) * 0.1
    marks = event_marks(t, np.ones((5, 2), dtype=bool), np.zeros(5, dtype=int), agent_ids=[1, 2],
                        faults=(make_fault("drop_arc", 0.25, arc=(1, 2)),), dt=0.1)
    assert [(m.step, m.kind) for m in marks] == [(3, "arc")]  # ceil(0.25 / 0.1) = 3, as the simulator applies it


@pytest.fixture(scope="module")
def ring10_faults():
    sc = load_scenario(EXAMPLES / "ring10_faults.yaml")
    traj = simulate(design(sc), seed=sc.run.seed)
    marks = event_marks(traj.t, traj.alive, traj.graph, agent_ids=traj.agent_ids, faults=sc.faults,
                        graph_names=sc.graph_names)
    fig = plots.errors_figure(traj, time=sc.time, rate=sc.design.rate, title=sc.name, marks=marks)
    fig.canvas.draw()  # lay out (constrained) before measuring
    yield sc, traj, marks, fig
    plt.close(fig)


def _lines(ax, gid):
    return [ln for ln in ax.get_lines() if ln.get_gid() == gid]


def test_ring10_faults_errors_marks_losses_rejoins_and_arcs(ring10_faults):
    _, _, _, fig = ring10_faults
    ax = fig.axes[0]
    at = {kind: sorted(float(ln.get_xdata()[0]) for ln in _lines(ax, f"mark:{kind}"))
          for kind in ("loss", "rejoin", "arc", "switch")}
    # examples/ring10_faults.yaml: kill 3 at 10, freeze 5 at 20, restarts at 30 and 35, arc 1-6 down 15 / up 40
    assert at == {"loss": [10.0, 20.0], "rejoin": [30.0, 35.0], "arc": [15.0, 40.0], "switch": []}
    styles = {kind: (_lines(ax, f"mark:{kind}")[0].get_linestyle(), _lines(ax, f"mark:{kind}")[0].get_color())
              for kind in ("loss", "rejoin", "arc")}
    assert len(set(styles.values())) == 3  # one style per kind
    labels = sorted(tx.get_text().strip() for tx in ax.texts)
    assert labels == ["3 killed", "3 rejoins", "5 frozen", "5 rejoins", "arc 1-6 down", "arc 1-6 up"]


def test_ring10_faults_legend_outside_the_axes(ring10_faults):
    _, _, _, fig = ring10_faults
    ax = fig.axes[0]
    renderer = fig.canvas.get_renderer()
    leg, box = ax.get_legend().get_window_extent(renderer), ax.get_window_extent(renderer)
    assert leg.x0 >= box.x1  # entirely to the right of the data
    fig_box = fig.bbox
    assert leg.x1 <= fig_box.x1 + 1 and leg.y0 >= fig_box.y0 - 1  # and still on the canvas
    names = [t.get_text() for t in ax.get_legend().get_texts()]
    assert [f"agent {i}" for i in range(1, 11)] == names[:10]
    assert {"agent lost", "agent rejoins (fresh estimate)", "arc dropped / restored"} <= set(names)


def test_ring10_faults_envelope_restarts_at_the_rejoins(ring10_faults):
    sc, traj, _, fig = ring10_faults
    env_line, = _lines(fig.axes[0], "envelope")
    env = np.asarray(env_line.get_ydata(), dtype=float)
    assert "from each restart (rejoin)" in env_line.get_label()
    # it jumps up with the fresh estimates (from about 1e-2 to the error's size), no 1e15 constant
    assert env[30] > 10 * env[29] and env[35] > env[34]
    assert env.max() < 100 * np.nanmax(max_error(traj))
    # between restarts it decays at the designed rate
    assert np.allclose(env[1:30] / env[:29], sc.design.rate) and np.allclose(env[36:] / env[35:-1], sc.design.rate)
    # and stays above the errors (above the round-off floor)
    err, floor = max_error(traj), 1e-9 * np.linalg.norm(traj.x, axis=1)
    ok = err > floor
    assert np.all(env[ok] >= err[ok] * (1 - 1e-12))


def test_summary_pieces_instead_of_one_constant(ring10_faults):
    sc, traj, _, _ = ring10_faults
    s = summarize(traj, time=sc.time, rate=sc.design.rate)
    assert s["envelope_c"] is None  # no single constant over a run with rejoins
    assert [p[0] for p in s["envelope_pieces"]] == [0.0, 30.0, 35.0]
    assert all(c is not None and c < 100 for _, c in s["envelope_pieces"])
    assert s["certified_rate"] is True and s["rate_note"] is None


def test_adaptive_gain_has_no_certified_rate_nor_envelope(tmp_path, capsys):
    raw = yaml.safe_load((EXAMPLES / "paper_continuous.yaml").read_text())
    raw["design"]["g"] = "adaptive"
    raw["name"] = "paper-continuous-adaptive"
    path = tmp_path / "adaptive.yaml"
    path.write_text(yaml.safe_dump(raw))
    out = tmp_path / "out"
    assert cli.main(["simulate", str(path), "--out", str(out), "--steps", "300"]) == 0
    text = capsys.readouterr().out
    summary = json.loads((out / "summary.json").read_text())
    assert summary["certified_rate"] is False
    assert summary.get("envelope_c") is None and not summary.get("envelope_pieces")
    assert summary["measured_meets_design"] is None and summary["rate_note"] == NO_CERTIFIED_RATE
    assert NO_CERTIFIED_RATE in text and "does NOT meet" not in text and "meets the design" not in text
    assert "measured rate" in text  # still reported, as information
    # the figure: no envelope line, the note in the title
    sc = load_scenario(path)
    traj = simulate(design(sc), seed=sc.run.seed, steps=300, noise=False)
    fig = plots.errors_figure(traj, time=sc.time, rate=sc.design.rate, title=sc.name, adaptive=True)
    try:
        ax = fig.axes[0]
        assert not _lines(ax, "envelope")
        assert NO_CERTIFIED_RATE in ax.get_title()
        assert not any("designed" in t.get_text() for t in ax.get_legend().get_texts())
    finally:
        plt.close(fig)


def test_dense_switching_envelope_is_one_constant_and_switches_are_ticks():
    sc = load_scenario(EXAMPLES / "paper_discrete_switching.yaml")
    traj = simulate(design(sc), seed=sc.run.seed, noise=False)
    marks = event_marks(traj.t, traj.alive, traj.graph, agent_ids=traj.agent_ids, graph_names=sc.graph_names)
    n_switch = int(np.count_nonzero(np.diff(traj.graph)))
    assert n_switch > plots.MAX_LABELLED_SWITCHES and sum(m.kind == "switch" for m in marks) == n_switch
    fig = plots.errors_figure(traj, time=sc.time, rate=sc.design.rate, title=sc.name, marks=marks)
    try:
        ax = fig.axes[0]
        env_line, = _lines(ax, "envelope")
        env = np.asarray(env_line.get_ydata(), dtype=float)
        assert np.allclose(env[1:] / env[:-1], sc.design.rate)  # no restart at every switch
        assert f"across {n_switch} switches" in env_line.get_label()
        ticks = _lines(ax, "mark:switch")
        assert len(ticks) == n_switch and all(np.allclose(t.get_ydata(), [1 - plots.SWITCH_TICK, 1.0]) for t in ticks)
        assert not ax.texts  # no label per switch
    finally:
        plt.close(fig)


def _label_boxes(fig, ax, labels):
    """The boxes in pixels of the texts ``labels`` on ``ax``, as drawn (a PNG written at simulate's dpi, then drawn
    again)."""
    import io

    fig.savefig(io.BytesIO(), dpi=110)
    fig.canvas.draw()
    renderer = fig.canvas.get_renderer()
    return [(t.get_text().strip(), t.get_window_extent(renderer)) for t in ax.texts if t.get_text().strip() in labels]


@pytest.mark.parametrize("figure", ["errors", "states"])
def test_labels_of_events_close_in_time_do_not_overlap(ring10_faults, figure):
    """Issue 46, finding 8: two events at the same or the next event time had their labels on top of one another."""
    sc, traj, _, _ = ring10_faults
    marks = (Mark(30, 30.0, "loss", "3 killed"), Mark(30, 30.0, "fault", "sensor 2 corrupted"),
             Mark(31, 31.0, "rejoin", "5 rejoins"), Mark(32, 32.0, "sensor", "2 suspect"),
             Mark(59, 59.0, "sensor", "2 restored"), Mark(60, 60.0, "fault", "sensor 2 repaired"))
    if figure == "errors":
        fig = plots.errors_figure(traj, time=sc.time, rate=sc.design.rate, title=sc.name, marks=marks)
    else:
        fig = plots.states_figure(traj, time=sc.time, title=sc.name, marks=marks)
    ax = fig.axes[0]  # the labels: at the bottom of the errors, above the first state
    try:
        boxes = _label_boxes(fig, ax, {m.label for m in marks})
        assert sorted(text for text, _ in boxes) == sorted(m.label for m in marks)
        for k, (a, ba) in enumerate(boxes):
            for b, bb in boxes[k + 1:]:
                assert not ba.overlaps(bb), (a, ba, b, bb)
        frame = ax.get_window_extent(fig.canvas.get_renderer())
        px = frame.width / np.ptp(ax.get_xlim())  # pixels per event time
        width = max(bb.width for _, bb in boxes)
        for (text, bb), m in zip(boxes, marks):  # near its own line: within the labels of its cluster
            assert frame.x0 - 1 <= bb.x0 and bb.x1 <= frame.x1 + 1, text
            anchor = frame.x0 + (m.t - ax.get_xlim()[0]) * px
            assert abs((bb.x0 + bb.x1) / 2 - anchor) < 4 * width, (text, bb, anchor)
    finally:
        plt.close(fig)


@pytest.mark.parametrize("name, label", [("platoon", "event time tau (one is 0.1 min)"),
                                         ("ieee14_pmu", "time t (min)"),
                                         ("ring10", "event time tau")])
def test_the_time_axis_says_the_models_unit(tmp_path, name, label):
    """Issue 46's walk: a model in minutes (``system.time_unit: min``) was plotted against a bare ``time t``.  A
    continuous model's axis is in its unit, a sampled one's event time is ``system.sample`` of it, a discrete
    model's event time is a step."""
    from splitspec_core.scenarios.files import resolve_model_file
    from splitspec_core.scenarios.sections import parse_scenario

    data = dict(resolve_model_file(yaml.safe_load((EXAMPLES / f"{name}.yaml").read_text()), EXAMPLES))
    if name != "ring10":
        data["system"] = dict(data["system"], time_unit="min")
    sc = parse_scenario(data)
    unit = plots.time_unit(sc.system)
    traj = simulate(design(sc), seed=0, steps=20)
    for fig in (plots.errors_figure(traj, time=sc.time, rate=sc.design.rate, title=sc.name, unit=unit),
                plots.states_figure(traj, time=sc.time, title=sc.name, unit=unit)):
        assert fig.axes[-1].get_xlabel() == label or any(ax.get_xlabel() == label for ax in fig.axes), label
        plt.close(fig)
