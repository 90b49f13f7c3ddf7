"""Models from where users keep them: ``system.file`` (.npz, MATLAB .mat v5 written by scipy), a python-control
``StateSpace`` (``ss.scenario(plant=..., agents=...)``), a continuous model sampled for the discrete estimator
(``system.sample``), and known inputs (``system.B``, ``system.u``, a measurements file's ``u`` columns)."""

from __future__ import annotations

import math
import os
from pathlib import Path

import numpy as np
import pytest
import scipy.io
import scipy.linalg as sla
import yaml

import splitspec_core as ss
from splitspec_core.scenarios.inputs import input_at, parse_input
from splitspec_core.synthesis.conditioning import conditioning
from splitspec_core.scenarios.measurements import load_measurements, write_measurements
from splitspec_core.model.plant import input_of
from splitspec_core.scenarios.load import load_scenario, resolved_scenario_text
from splitspec_core.simulation.simulator import simulate as simulate_design
from splitspec_orchestrator import cli
from tests.numerics import assert_close

ROOT = Path(__file__).resolve().parents[2]
KUNDUR = ROOT / "examples" / "models" / "kundur_full.npz"

# two oscillators, three agents (the paper's Section 5 system, discrete)
A4 = np.array([[0.9, 0.2, 0, 0], [-0.2, 0.9, 0, 0], [0, 0, 0.8, 0.3], [0, 0, -0.3, 0.8]])
CS = {1: np.array([[1.0, 0, 0, 0]]), 2: np.array([[0, 1.0, 0, 0]]), 3: np.array([[0, 0, 1.0, 0], [0, 0, 0, 1.0]])}
RING = {"a": {"undirected": [[1, 2], [2, 3], [3, 1]]}}
NAMES = ["p1", "v1", "p2", "v2"]


def base(**system) -> dict:
    return {"name": "files", "time": "discrete", "system": system, "graphs": RING, "design": {"rate": 0.5},
            "run": {"steps": 40, "seed": 5}}


def write(path: Path, data: dict) -> Path:
    path.write_text(yaml.safe_dump(data, sort_keys=False), encoding="utf-8")
    return path


def cli_error(path: Path, capsys) -> str:
    code = cli.main(["design", str(path)])
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1 and "Traceback" not in err, (code, err)
    return err


# --------------------------------------------------------------------------
# system.file
# --------------------------------------------------------------------------


def test_a_model_in_an_npz_beside_the_scenario_is_the_inline_model(tmp_path, monkeypatch):
    folder = tmp_path / "case"
    folder.mkdir()
    np.savez(folder / "model.npz", A=A4, C1=CS[1], C2=CS[2], C3=CS[3], names=np.array(NAMES), x0=np.ones(4))
    path = write(folder / "s.yaml", base(file="model.npz", A="A", C={1: "C1", 2: "C2", 3: "C3"}, states="names",
                                         x0="x0"))
    monkeypatch.chdir(tmp_path)  # the file is found beside the scenario, not in the working directory
    sc = load_scenario(path)
    inline = ss.scenario(A=A4, C=CS, states=NAMES, x0=np.ones(4), graphs=RING, rate=0.5, steps=40, seed=5)
    assert np.array_equal(sc.system.A, inline.system.A) and sc.state_names == tuple(NAMES)
    assert all(np.array_equal(a, b) for a, b in zip(sc.system.Cs, inline.system.Cs))
    # what the processes get: the arrays written in, the same numbers bit for bit (floats as repr)
    text = resolved_scenario_text(path, path.read_text())
    assert "file" not in yaml.safe_load(text)["system"]
    again = ss.scenario(**{k: v for k, v in yaml.safe_load(text).items() if k not in ("system",)},
                        system=yaml.safe_load(text)["system"])
    assert np.array_equal(again.system.A, sc.system.A)
    # ss.scenario's file= is relative to the working directory
    monkeypatch.chdir(folder)
    kw = ss.scenario(file="model.npz", A="A", C={1: "C1", 2: "C2", 3: "C3"}, graphs=RING, rate=0.5)
    assert np.array_equal(kw.system.A, A4)


def test_a_mat_file_written_by_scipy_with_a_cell_array_of_names(tmp_path):
    names = np.empty((1, 4), dtype=object)
    names[0, :] = NAMES
    scipy.io.savemat(tmp_path / "model.mat", {"A": A4, "C1": CS[1], "C2": CS[2], "C3": CS[3], "names": names,
                                              "x0": np.ones((4, 1)), "outs": np.array(["pos", "vel"])})
    path = write(tmp_path / "s.yaml", base(file="model.mat", A="A", C={1: "C1", 2: "C2", 3: "C3"}, states="names",
                                           x0="x0", outputs={3: "outs"}))
    sc = load_scenario(path)
    assert np.array_equal(sc.system.A, A4) and sc.state_names == tuple(NAMES)
    assert np.array_equal(sc.system.x0, np.ones(4)) and sc.output_names(3) == ("pos", "vel")


def test_the_shipped_power_model_loads_by_name(tmp_path):
    data = base(file=str(KUNDUR), A="A", C={i: f"C_pmu_{i}" for i in (1, 2, 3, 4)}, states="states")
    data["graphs"] = {"ring": {"undirected": [[1, 2], [2, 3], [3, 4], [4, 1]]}}
    data["time"] = "continuous"
    data["run"] = {"steps": 10, "dt": 0.01}
    sc = load_scenario(write(tmp_path / "k.yaml", data))
    z = np.load(KUNDUR)
    assert sc.n == z["A"].shape[0] == 52 and sc.state_names == tuple(str(s) for s in z["states"])


@pytest.mark.parametrize("case, change, fragments", [
    ("missing-file", {"file": "absent.npz"}, ["system.file", "absent.npz does not exist"]),
    ("suffix", {"file": "model.txt"}, ["neither .npz nor .mat"]),
    ("missing-array", {"C": {1: "C1", 2: "C2", 3: "C9"}}, ["system.C.3 names array 'C9'", "does not hold",
                                                           "it has: A, C1, C2, C3"]),
    ("wrong-shape", {"C": {1: "C1", 2: "C2", 3: "bad"}}, ["system.C.3 has 3 columns, system.A is 4x4"]),
    ("names-count", {"states": "three"}, ["system.states has 3 names, expected 4"]),
    ("single-name-for-C", {"C": "C1"}, ["system.C must map agent ids to arrays"]),
    ("v7.3", {"file": "new.mat"}, ["MATLAB v7.3 (HDF5)", "save(file, ..., '-v7')"]),
    ("not-npz", {"file": "text.npz"}, ["text.npz is not an .npz file"]),
    ("not-mat", {"file": "text.mat"}, ["cannot read", "text.mat as a .mat file"]),
])
def test_a_bad_model_file_is_one_line_naming_the_key(tmp_path, capsys, case, change, fragments):
    np.savez(tmp_path / "model.npz", A=A4, C1=CS[1], C2=CS[2], C3=CS[3], three=np.array(["a", "b", "c"]),
             bad=np.ones((1, 3)))
    (tmp_path / "model.txt").write_text("A = 1\n")
    (tmp_path / "text.npz").write_text("A = 1\n")
    (tmp_path / "text.mat").write_text("A = 1\n")
    # a v7.3 file is HDF5 behind MATLAB's 128-byte text header
    (tmp_path / "new.mat").write_bytes(b"MATLAB 7.3 MAT-file, Platform: GLNXA64".ljust(128, b" ") + b"\x89HDF\r\n")
    system = {"file": "model.npz", "A": "A", "C": {1: "C1", 2: "C2", 3: "C3"}, **change}
    err = cli_error(write(tmp_path / f"{case}.yaml", base(**system)), capsys)
    assert all(f in err for f in fragments), err


def test_tune_write_keeps_a_relative_model_file_found(tmp_path, capsys):
    np.savez(tmp_path / "model.npz", A=A4, C1=CS[1], C2=CS[2], C3=CS[3])
    data = base(file="model.npz", A="A", C={1: "C1", 2: "C2", 3: "C3"}, process_noise=0.1, measurement_noise=0.1)
    path = write(tmp_path / "s.yaml", data)
    (tmp_path / "elsewhere").mkdir()
    target = tmp_path / "elsewhere" / "tuned.yaml"
    assert cli.main(["design", str(path), "--tune", "rms", "--write", str(target)]) == 0, capsys.readouterr().err
    written = yaml.safe_load(target.read_text())
    assert written["system"]["file"] == os.path.join("..", "model.npz")
    assert np.array_equal(load_scenario(target).system.A, A4)


# --------------------------------------------------------------------------
# python-control
# --------------------------------------------------------------------------


def test_a_python_control_statespace_as_the_plant():
    control = pytest.importorskip("control")  # the [control] extra: installed by `make setup`, so CI runs this
    Ac = np.array([[0, 1, 0, 0], [-2, -0.1, 1, 0], [0, 0, 0, 1], [1, 0, -3, -0.2]])
    Bc = np.array([[0], [1], [0], [0]])
    C = np.eye(4)
    plant = control.ss(Ac, Bc, C, 0, states=["th1", "om1", "th2", "om2"], outputs=["PMU1", "w1", "PMU2", "w2"])
    sc = ss.scenario(plant=plant, agents={1: ["PMU1", "w1"], 2: [2]}, graphs={"a": [(1, 2), (2, 1)]}, rate=0.3,
                     dt=0.05, steps=20)
    assert sc.time == "continuous" and sc.state_names == ("th1", "om1", "th2", "om2")
    assert np.array_equal(sc.system.Cs[0], C[:2]) and np.array_equal(sc.system.Cs[1], C[2:3])
    assert sc.output_names(1) == ("PMU1", "w1") and sc.output_names(2) == ("PMU2",)
    assert np.array_equal(sc.system.B, Bc)
    # python-control's default labels x[0] become names a recording can use; dt > 0 is discrete time
    d = control.ss(A4, np.zeros((4, 1)), np.eye(4), 0, dt=0.1)
    sd = ss.scenario(plant=d, agents={1: [0, 1], 2: ["y[2]", "y[3]"]}, graphs={"a": [(1, 2), (2, 1)]}, rate=0.5)
    assert sd.time == "discrete" and sd.state_names == ("x_0", "x_1", "x_2", "x_3") and sd.system.B is None
    assert sd.output_names(2) == ("y_2", "y_3")
    ss.design(sd)  # and it designs
    # the plant's own name is the scenario's, unless python-control made it up or name= is given
    assert sc.name == "scenario" and plant.name.startswith("sys[")
    named = control.ss(Ac, Bc, C, 0, name="two-area")
    kw = {"agents": {1: [0, 1], 2: [2]}, "graphs": {"a": [(1, 2), (2, 1)]}, "rate": 0.3}
    assert ss.scenario(plant=named, **kw).name == "two-area"
    assert ss.scenario(plant=named, name="mine", **kw).name == "mine"
    assert ss.scenario(plant=plant.sample(0.05), **kw).name == "scenario"  # sys[N]$sampled


@pytest.mark.parametrize("plant, agents, extra, fragment", [
    ("tf", {1: [0]}, {}, "plant= must be a python-control StateSpace, got TransferFunction (control.ss(sys)"),
    ("list", {1: [0]}, {}, "plant= must be a python-control StateSpace, got list"),
    ("ss", {1: ["P9"]}, {}, "agents.1: 'P9' is not an output of the plant (its outputs: y[0], y[1])"),
    ("ss", {1: [5]}, {}, "agents.1: output index 5 is out of range"),
    ("ss", None, {}, "plant= needs agents={id: [outputs]}"),
    ("ss", {1: [0]}, {"A": [[1.0]]}, "plant= gives the system: A= cannot be given with it"),
    ("ss", {1: [0]}, {"time": "discrete"}, "time='discrete', and plant= is continuous time"),
    ("feed", {1: [0]}, {}, "agents.1: the plant feeds its inputs through to these outputs (D != 0)"),
])
def test_a_bad_plant_is_one_line(plant, agents, extra, fragment):
    control = pytest.importorskip("control")
    plants = {"tf": control.tf([1], [1, 1]), "list": [[1.0]],
              "ss": control.ss([[-1, 0], [0, -2]], [[1], [0]], np.eye(2), 0),
              "feed": control.ss([[-1, 0], [0, -2]], [[1], [0]], np.eye(2), [[1], [0]])}
    with pytest.raises(ss.ScenarioError) as err:
        ss.scenario(plant=plants[plant], agents=agents, graphs={"a": [(1, 1)]}, rate=0.5, **extra)
    assert fragment in str(err.value) and "\n" not in str(err.value), str(err.value)


# --------------------------------------------------------------------------
# system.sample
# --------------------------------------------------------------------------


def test_a_continuous_model_sampled_for_the_discrete_estimator(capsys, tmp_path):
    Ac = np.array([[0, 1, 0, 0], [-1, -0.1, 0, 0], [0, 0, 0, 1], [0, 0, -4, -0.2]])
    Bc = np.array([[0], [1], [0], [1]])
    dt = 0.1
    sc = ss.scenario(A=Ac, B=Bc, sample=dt, C=CS, graphs=RING, rate=0.8, steps=60)
    # zero-order hold: A_d = exp(A dt), B_d = int_0^dt exp(A s) ds B, from the block exponential of [[A, B], [0, 0]]
    M = np.zeros((5, 5))
    M[:4, :4], M[:4, 4:] = Ac, Bc
    F = sla.expm(M * dt)
    assert_close(sc.system.A, F[:4, :4], rtol=1e-12, what="A_d")
    assert_close(sc.system.B, F[:4, 4:], rtol=1e-12, what="B_d")
    assert np.array_equal(sc.system.A_continuous, Ac) and sc.time == "discrete"
    # the report says what rate per second the per-step certificate means
    path = write(tmp_path / "s.yaml", {"name": "sampled", "time": "discrete",
                                       "system": {"A": Ac.tolist(), "sample": dt, "C": {k: v.tolist() for k, v in
                                                                                         CS.items()}},
                                       "graphs": RING, "design": {"rate": 0.8}})
    assert cli.main(["design", str(path), "--json"]) == 0
    import json

    out = json.loads(capsys.readouterr().out)
    assert out["sample"] == dt and out["continuous_rate"] == pytest.approx(-math.log(0.8) / dt)
    assert cli.main(["design", str(path)]) == 0
    text = capsys.readouterr().out
    assert f"lam^(1/dt) = {0.8 ** (1 / dt):.4g} per second" in text and f"exp(-{-math.log(0.8) / dt:.4g} t)" in text
    # and the estimator's error decays at least as the certificate says, in seconds
    tr = ss.simulate(sc)
    err = np.nanmax(np.abs(tr.xhat - tr.x[:, None, :]), axis=(1, 2))
    const = conditioning(ss.design(sc).detail).transient_constant
    assert err[-1] <= err[0] * 0.8 ** 60 * const * math.sqrt(4 * 3), (err[-1], err[0], const)


# --------------------------------------------------------------------------
# known inputs
# --------------------------------------------------------------------------


def test_an_input_signal_is_the_sum_of_its_parts():
    sig = parse_input({"constant": [1.0, 0.0], "steps": [[2, [0.0, 5.0]], [4, [1.0, 1.0]]],
                       "sine": [{"amplitude": [2.0, 0.0], "period": 8.0, "phase": 0.5}]}, 2)
    for t in (0.0, 1.9, 2.0, 3.0, 4.0, 10.0):
        step = [0.0, 0.0] if t < 2 else [0.0, 5.0] if t < 4 else [1.0, 1.0]
        want = np.array([1.0, 0.0]) + step + np.array([2.0, 0.0]) * math.sin(2 * math.pi * t / 8 + 0.5)
        assert np.allclose(input_at(sig, t), want, rtol=0, atol=1e-15), t
    assert np.array_equal(input_at(parse_input([3.0], 1), 7.0), [3.0])


@pytest.mark.parametrize("time, extra", [("discrete", {}), ("continuous", {"dt": 0.05}), ("discrete", {"sample": 0.1})])
def test_known_inputs_move_the_state_and_cancel_from_the_errors(time, extra):
    A = A4 if time == "discrete" and "sample" not in extra else np.array(
        [[0, 1, 0, 0], [-1, -0.1, 0, 0], [0, 0, 0, 1], [0, 0, -4, -0.2]])
    B = np.array([[0, 1], [1, 0], [0, 0], [1, 0]])
    u = {"constant": [1.0, -0.5], "steps": [[1.0, [2.0, 0.0]]], "sine": [{"amplitude": [0.0, 3.0], "period": 2.0}]}
    kw = dict(C=CS, graphs=RING, rate=0.5, time=time, steps=60, seed=2, process_noise=0.01, measurement_noise=0.01)
    with_u = ss.scenario(A=A, B=B, u=u, **kw, **extra)
    without = ss.scenario(A=A, **kw, **extra)
    a, b = ss.simulate(with_u), ss.simulate(without)
    assert np.abs(a.x - b.x).max() > 1.0  # the input moves the plant
    ea, eb = a.xhat - a.x[:, None, :], b.xhat - b.x[:, None, :]
    # the same noise draws, and B u added by the plant and by every agent: the errors agree to round-off of |x|
    # (another path: the plant's x carries the input, so its round-off is that of |x|, ~1e-16 |x| per step)
    assert np.abs(ea - eb).max() <= 1e-11 * max(1.0, np.abs(a.x).max()), np.abs(ea - eb).max()
    # the per-agent step functions (the agents' own path) agree with the batched simulator
    loop = simulate_design(ss.design(with_u).detail, estimator="loop")
    assert_close(loop.xhat, a.xhat, rtol=1e-12, what="loop against batch with inputs")
    # the baselines add G u too: their errors do not depend on the inputs either
    from splitspec_core.studies.baselines import baseline_trajectories

    ba, bb = (baseline_trajectories(s, 2, exchanges=3) for s in (with_u, without))
    scale = max(1.0, np.abs(ba["x"]).max())
    assert np.abs((ba["centralized"] - ba["x"]) - (bb["centralized"] - bb["x"])).max() <= 1e-11 * scale
    assert np.abs((ba["kcf"] - ba["x"][:, None]) - (bb["kcf"] - bb["x"][:, None])).max() <= 1e-11 * scale


@pytest.mark.parametrize("suffix", [".csv", ".npz"])
def test_a_measurements_file_with_u_columns_drives_the_inputs(tmp_path, suffix):
    B = np.array([[0], [1], [0], [0]])
    kw = dict(A=A4, B=B, C=CS, graphs=RING, rate=0.5, steps=30, seed=4)
    sig = ss.scenario(u={"steps": [[0, [1.0]], [10, [-2.0]]]}, **kw)
    tr = ss.simulate(sig)
    u = np.array([input_of(sig, k) for k in range(31)])
    path = tmp_path / f"m{suffix}"
    full = simulate_design(ss.design(sig).detail, keep_y=True)
    write_measurements(path, t=full.t, y=full.y, agent_ids=sig.agent_ids, sizes=[1, 1, 2], x=full.x, u=u)
    plain = ss.scenario(**kw)  # no signal: the file's u columns are the inputs
    meas = load_measurements(path, plain)
    assert np.array_equal(meas.u, u)
    played = simulate_design(ss.design(plain).detail, measurements=meas)
    # the same operations in the same order (the file holds the signal's own u, written as repr): equal
    assert np.array_equal(played.xhat, tr.xhat)
    # u columns without system.B, or of the wrong width: one line naming the file
    with pytest.raises(ss.ScenarioError, match="the scenario has no system.B"):
        load_measurements(path, ss.scenario(A=A4, C=CS, graphs=RING, rate=0.5))
    two = ss.scenario(A=A4, B=np.hstack([B, B]), C=CS, graphs=RING, rate=0.5)
    with pytest.raises(ss.ScenarioError, match="system.B has 2"):
        load_measurements(path, two)


def test_live_known_inputs_need_their_key_and_known_inputs():
    kw = dict(A=A4, C=CS, graphs=RING, rate=0.5, time="discrete", pace=10)
    with pytest.raises(ss.ScenarioError, match=r"system.B \(known inputs\) with live sensors \(sources:\): give "
                                               "sources.inputs"):
        ss.scenario(B=[[0], [1], [0], [0]], sources={1: "s1", 2: "s2", 3: "s3"}, **kw)
    with pytest.raises(ss.ScenarioError, match="sources.inputs names where u is published, and the scenario has no "
                                               "system.B"):
        ss.scenario(sources={1: "s1", 2: "s2", 3: "s3", "inputs": "u"}, **kw)
    with pytest.raises(ss.ScenarioError, match="sources.inputs.key 's2' is also agent 2's source"):
        ss.scenario(B=[[0], [1], [0], [0]], sources={1: "s1", 2: "s2", 3: "s3", "inputs": "s2"}, **kw)
    sc = ss.scenario(B=[[0], [1], [0], [0]], sources={1: "s1", 2: "s2", 3: "s3", "inputs": {"key": "plant/u",
                                                                                              "max_age": 0.5}}, **kw)
    assert sc.input_source.key == "plant/u" and sc.input_source.max_age == 0.5
    assert sc.sensor_keys == {1: "s1", 2: "s2", 3: "s3", "inputs": "plant/u"}


def test_an_agent_takes_the_live_inputs_and_holds_them_when_none_is_fresh():
    from splitspec_agents.measure import YBuffer
    from splitspec_agents.sensor import LiveSampler

    now = [0.0]
    sampler = LiveSampler(2, 0.15, clock=lambda: now[0], field="u")
    ys = YBuffer(1, slice(0, 1), 3, B=np.ones((4, 2)))
    ys.put_sample(0, np.array([1.0]), sampler.take())  # nothing published yet: zero
    assert np.array_equal(ys.bu(0), np.zeros(4))
    assert sampler.offer(b'{"u": [1.0, 2.0], "t": 1.0}') and not sampler.offer(b'{"y": [1.0, 2.0]}')
    assert sampler.counts() == {"bad_u": 1}
    now[0] = 0.1
    ys.put_sample(1, np.array([1.0]), sampler.take())
    assert np.array_equal(ys.bu(1), np.ones((4, 2)) @ [1.0, 2.0])
    now[0] = 1.0  # the value is stale: the last one taken is held
    ys.put_sample(2, np.array([1.0]), sampler.take())
    assert np.array_equal(ys.bu(2), np.ones((4, 2)) @ [1.0, 2.0])
