"""The public API (``import splitspec_core as ss``): one validation path with files, the CLI's results, frozen results."""

from __future__ import annotations

import dataclasses
import os
import subprocess
import sys

import numpy as np
import pytest
import yaml

import splitspec_core as ss
from splitspec_core.scenarios.checks import DESIGN_KEYS, RUN_KEYS, SYSTEM_KEYS
from splitspec_core.scenarios.specs import DesignSpec, System
from splitspec_orchestrator import cli
from tests.conftest import ROOT
from tests.numerics import assert_close
from tests.unit import test_scenario_errors as errors_suite

EXAMPLES = ROOT / "examples"
SECTIONS = {"system": SYSTEM_KEYS, "design": DESIGN_KEYS, "run": RUN_KEYS}


def as_keywords(data: dict) -> dict:
    """The keywords of ``ss.scenario`` for a scenario mapping: each section's known keys lifted to their own
    names (what a notebook user writes), anything else (unknown keys, a section that is not a mapping) as is."""
    kw = {}
    for key, value in data.items():
        if key in SECTIONS and isinstance(value, dict):
            rest = {k: v for k, v in value.items() if k not in SECTIONS[key]}
            kw.update({k: v for k, v in value.items() if k in SECTIONS[key] and v is not None})
            if rest or not value:
                kw[key] = rest
        else:
            kw[key] = value
    return kw


def cli_error(path, capsys) -> str:
    code = cli.main(["design", str(path)])
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1, err
    return err.removeprefix("splitspec: error: ").rstrip("\n")


def _mapping(text: str):
    try:
        return yaml.safe_load(text)
    except yaml.YAMLError:  # the YAML syntax cases: nothing a Python caller could write
        return None


YAML_CASES = [pytest.param(text, id=case_id) for case_id, text, _ in errors_suite.CASES
              if isinstance(text, str) and isinstance(_mapping(text), dict)]


@pytest.mark.parametrize("text", YAML_CASES)
def test_every_scenario_file_error_has_the_same_message_through_ss_scenario(text, tmp_path, capsys, monkeypatch):
    monkeypatch.delenv("SPLITSPEC_DEBUG", raising=False)
    path = tmp_path / "scenario.yaml"
    path.write_text(text)
    expected = cli_error(path, capsys)
    kw = as_keywords(yaml.safe_load(text))
    with pytest.raises(ss.SplitspecError) as info:
        ss.design(ss.scenario(**kw))
    assert str(info.value) == expected


def test_the_error_cases_cover_most_of_the_file_errors():
    assert len(YAML_CASES) >= 80, len(YAML_CASES)


@pytest.mark.parametrize("name", ["paper_discrete", "paper_continuous_switching", "ring10_faults_switching",
                                  "paper_discrete_noise"])
def test_ss_simulate_equals_splitspec_simulate(name, tmp_path, capsys):
    path = EXAMPLES / f"{name}.yaml"
    assert cli.main(["simulate", str(path), "--out", str(tmp_path), "--no-plots", "--seed", "3"]) == 0
    capsys.readouterr()
    cli_traj = ss.Trajectory.load(tmp_path / "trajectory.npz")
    tr = ss.simulate(ss.load_scenario(path), seed=3)
    for f in ("t", "alive", "graph", "agent_ids"):  # times, flags and indices: the same numbers by construction
        np.testing.assert_array_equal(getattr(tr, f), getattr(cli_traj, f), err_msg=f)
    assert set(tr.columns) == set(cli_traj.columns)  # every per-agent row column of the schema, in both
    for f, a, b in [("x", tr.x, cli_traj.x), ("xhat", tr.xhat, cli_traj.xhat),
                    *((k, v, cli_traj.columns[k]) for k, v in tr.columns.items())]:
        # the same simulator on the same design; compared to round-off all the same (relative 1e-12): the CLI
        # path builds the scenario and the design anew, and equality of the bits is not what is tested here
        assert_close(np.asarray(a, float), np.asarray(b, float), rtol=1e-12, equal_nan=True, what=f)


def test_numpy_arrays_and_lists_give_the_same_scenario_and_design():
    sc_file = ss.load_scenario(EXAMPLES / "paper_discrete.yaml")
    s, d = sc_file.system, sc_file.design
    sc_np = ss.scenario(name=sc_file.name, A=np.array(s.A), C={i: np.array(C) for i, C in zip(sc_file.agent_ids, s.Cs)},
                        graphs={g.name: [tuple(a) for a in g.arcs] for g in sc_file.graphs}, time="discrete",
                        rate=np.float64(d.rate), gains=d.gains, K={i: np.array(K) for i, K in zip(sc_file.agent_ids, d.K)},
                        steps=np.int64(sc_file.run.steps), seed=sc_file.run.seed)
    a, b = ss.design(sc_np), ss.design(sc_file)
    assert a.q == b.q and a.checks.certificate == b.checks.certificate
    for i in sc_file.agent_ids:
        # exact: explicit gains, the scenario's own numbers, whether they came as lists or arrays
        np.testing.assert_array_equal(a.agents[i].K, b.agents[i].K)
        np.testing.assert_allclose(a.agents[i].poles, b.agents[i].poles)
    # the same simulator on equal designs: exact on one machine, compared to 1e-12 (relative) as any two
    # designs built separately (their V_i come out of separate QR factorisations)
    assert_close(ss.simulate(a).xhat, ss.simulate(b).xhat, rtol=1e-12, what="xhat")


def test_results_are_frozen():
    d = ss.design(ss.load_scenario(EXAMPLES / "paper_continuous.yaml"))
    with pytest.raises(dataclasses.FrozenInstanceError):
        d.g = 1.0
    with pytest.raises(TypeError):
        d.agents[1] = None
    with pytest.raises(ValueError):
        d.agents[1].K[0, 0] = 1.0  # read-only array
    assert d.g is not None and d.q is None and d.checks.rate_certified is True
    cmp = ss.compare(ss.load_scenario(EXAMPLES / "paper_discrete_noise.yaml"), seeds=2, steps=60)
    assert dataclasses.is_dataclass(cmp) and not any(k.startswith("_") for k in cmp.to_json())
    assert cmp.seeds == (cmp.seeds[0], cmp.seeds[0] + 1) and cmp.t.shape == (61,)
    kf, kcf = cmp.estimators["centralized KF"], cmp.estimators["KCF"]
    assert kcf.ratio_to_centralized == pytest.approx(kcf.rms_mean / kf.rms_mean, rel=1e-12)
    assert kf.rms_mean == pytest.approx(kf.predicted_rms, rel=0.3)  # measured (2 seeds x 58 steps) vs the DARE's
    with pytest.raises(dataclasses.FrozenInstanceError):
        cmp.estimators["KCF"].rms_mean = 0.0


def test_checks_are_computed_from_the_design():
    """``jointly_observable`` is False for a detectable but unobservable system (``design`` goes on), and
    ``strongly_connected`` says what each graph of the design handed to ``Checks.of`` is (``design`` itself refuses a
    scenario graph that is not, so a design with the survivors' graph after two losses shows the False)."""
    from splitspec_core.model.graphs import build_graph

    d = ss.design(ss.load_scenario(EXAMPLES / "paper_discrete_filter.yaml"))
    assert d.checks.jointly_observable is False and d.checks.jointly_detectable is True and d.checks.unobserved
    d = ss.design(ss.load_scenario(EXAMPLES / "ring10.yaml"))
    assert d.checks.jointly_observable is True and dict(d.checks.strongly_connected) == {"ring": True}
    assert ss.Checks.of(d.detail) == d.checks
    ring = d.detail.graphs[0]
    cut = build_graph("ring without 3, 6", tuple(i for i in ring.ids if i not in (3, 6)), ring.arcs, check=False)
    checks = ss.Checks.of(dataclasses.replace(d.detail, graphs=(ring, cut)))
    assert dict(checks.strongly_connected) == {"ring": True, "ring without 3, 6": False}


def test_a_scenario_built_from_its_dataclasses_is_checked_too():
    sc = ss.load_scenario(EXAMPLES / "paper_discrete.yaml")
    bad = dataclasses.replace(sc.system, Cs=(np.ones((1, 5)), *sc.system.Cs[1:]))
    with pytest.raises(ss.DimensionError, match=r"^system\.C\.1 has 5 columns, system\.A is 4x4$"):
        dataclasses.replace(sc, system=bad)
    flat = dataclasses.replace(sc.design, K=(np.ones((1, 4)), *sc.design.K[1:]))
    with pytest.raises(ss.DimensionError, match=r"^design\.K\.1 is 1x4, expected 4x1"):
        dataclasses.replace(sc, design=flat)
    assert isinstance(sc.system, System) and isinstance(sc.design, DesignSpec)


def test_unknown_keyword_names_the_key_and_suggests_one():
    with pytest.raises(ss.ScenarioError, match=r"unknown key q_methd .*did you mean design\.q_method\?$"):
        ss.scenario(A=np.eye(2), C={1: np.eye(2)}, graphs={"a": [(1, 1)]}, rate=0.5, q_methd="spectral")
    with pytest.raises(ss.ScenarioError, match=r"^design\.rate is given twice: as rate= and in design=$"):
        ss.scenario(A=np.eye(2), C={1: np.eye(2)}, graphs={"a": []}, rate=0.5, design={"rate": 0.4})


def test_api_tour_runs(tmp_path):
    env = {**os.environ, "RERUN_ANALYTICS": "0", "MPLBACKEND": "Agg"}
    png = tmp_path / "tour.png"
    r = subprocess.run([sys.executable, str(EXAMPLES / "api_tour.py"), "--plot", str(png)], cwd=tmp_path, env=env,
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    out = r.stdout
    assert "design: q = 6 consensus exchanges" in out  # the paper's q (Section 5) for rate 0.5
    for word in ("simulate:", "faults: agent 1 dead for event times 10..24", "compare", "centralized KF",
                 "x 1.00 of centralized"):
        assert word in out, (word, out)
    assert png.stat().st_size > 10_000


def test_readme_python_example_runs(monkeypatch):
    """The README's Python API block, executed as written (from the repository root)."""
    readme = (ROOT / "README.md").read_text()
    block = readme.split("## Python API")[1].split("```python")[1].split("```")[0]
    monkeypatch.chdir(ROOT)
    scope: dict = {}
    exec(compile(block, "README.md", "exec"), scope)  # noqa: S102 - our own documentation
    assert scope["d"].q == 6 and scope["tr"].xhat.shape == (41, 3, 4)
    assert scope["cmp"].estimators["KCF"].rms_mean > 0
