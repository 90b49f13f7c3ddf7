"""`splitspec simulate` end to end, as a user runs it (a real subprocess)."""

import json
import subprocess
import sys

import numpy as np
import pytest

from tests.conftest import EXAMPLES, ROOT


def run_cli(*args, timeout=120):
    return subprocess.run([sys.executable, "-m", "splitspec_orchestrator", *map(str, args)], cwd=ROOT,
                          capture_output=True, text=True, timeout=timeout)


@pytest.mark.parametrize("example", ["paper_discrete", "paper_continuous_switching"])
def test_simulate_writes_the_contract(tmp_path, example):
    out = tmp_path / "out"
    r = run_cli("simulate", EXAMPLES / f"{example}.yaml", "--out", out, "--monte-carlo", "3")
    assert r.returncode == 0, r.stderr
    assert "Traceback" not in r.stderr
    with np.load(out / "trajectory.npz") as f:
        T = f["t"].shape[0]
        m, n = 3, 4
        assert f["x"].shape == (T, n)
        assert f["xhat"].shape == (T, m, n)
        assert f["alive"].shape == (T, m) and f["alive"].dtype == bool
        assert f["graph"].shape == (T,)
        assert f["agent_ids"].tolist() == [1, 2, 3]
        assert np.all(np.isfinite(f["xhat"]))
        if example == "paper_continuous_switching":
            assert np.allclose(np.diff(f["t"]), 0.01)
            assert set(np.unique(f["graph"])) == {0, 1}
    summary = json.loads((out / "summary.json").read_text())
    assert summary["measured_meets_design"] is True
    assert set(summary["agents"]) == {"1", "2", "3"}
    assert summary["monte_carlo"]["seeds"] == 3
    for png in ("errors.png", "states.png", "monte_carlo.png"):
        data = (out / png).read_bytes()
        assert data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) > 5000
    assert "measured rate" in r.stdout and "meets the design" in r.stdout


def test_simulate_is_reproducible_and_seed_overrides(tmp_path):
    a, b, c = tmp_path / "a", tmp_path / "b", tmp_path / "c"
    for d, seed in ((a, 5), (b, 5), (c, 6)):
        r = run_cli("simulate", EXAMPLES / "paper_discrete_noise.yaml", "--out", d, "--seed", seed, "--no-plots")
        assert r.returncode == 0, r.stderr
    la, lb, lc = (np.load(d / "trajectory.npz") for d in (a, b, c))
    assert np.array_equal(la["xhat"], lb["xhat"])  # exact: the same command twice (reproducibility is the subject)
    assert not np.allclose(la["xhat"], lc["xhat"])
    assert not (a / "errors.png").exists()


def test_simulate_exact_and_faults(tmp_path):
    r = run_cli("simulate", EXAMPLES / "paper_continuous_switching.yaml", "--out", tmp_path, "--exact",
                "--steps", "300", "--no-plots")
    assert r.returncode == 0, r.stderr
    assert "exact ODE" in (tmp_path / "summary.json").read_text()


def test_exact_with_the_adaptive_gain_is_one_line(tmp_path):
    """--exact cannot integrate eq. (adaptive) (g_i(t) is a state): refused before any output, naming the key."""
    import yaml

    raw = yaml.safe_load((EXAMPLES / "paper_continuous.yaml").read_text())
    raw["design"]["g"] = "adaptive"
    path = tmp_path / "adaptive.yaml"
    path.write_text(yaml.safe_dump(raw))
    out = tmp_path / "o"
    r = run_cli("simulate", path, "--out", out, "--exact")
    assert r.returncode == 2 and r.stdout == ""
    assert r.stderr.count("\n") == 1 and r.stderr.startswith("splitspec: error: --exact")
    assert "design.g is adaptive" in r.stderr
    assert "simulate_exact" not in r.stderr and "Traceback" not in r.stderr
    assert not out.exists()  # refused before the output directory is made
    r = run_cli("simulate", path, "--out", out, "--steps", "20", "--no-plots")  # without --exact it runs
    assert r.returncode == 0, r.stderr


@pytest.mark.parametrize("args,needle", [
    (["--steps", "0"], "--steps must be >= 1"),
    (["--monte-carlo", "0"], "--monte-carlo must be >= 1"),
    (["--exact"], "--exact integrates the continuous-time ODE"),
])
def test_bad_arguments_one_line(tmp_path, args, needle):
    r = run_cli("simulate", EXAMPLES / "paper_discrete.yaml", "--out", tmp_path / "o", *args)
    assert r.returncode == 2
    assert r.stderr.strip().count("\n") == 0 and needle in r.stderr and "Traceback" not in r.stderr


def test_missing_out_is_a_usage_error(tmp_path):
    r = run_cli("simulate", EXAMPLES / "paper_discrete.yaml")
    assert r.returncode == 2 and "--out" in r.stderr


def test_unwritable_out_is_one_line(tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("x")
    r = run_cli("simulate", EXAMPLES / "paper_discrete.yaml", "--out", blocker / "sub")
    assert r.returncode == 2 and "cannot write to output directory" in r.stderr and "Traceback" not in r.stderr


def test_progress_bar_on_a_terminal(tmp_path):
    import os
    import pty

    master, slave = pty.openpty()
    try:
        p = subprocess.run([sys.executable, "-m", "splitspec_orchestrator", "simulate", str(EXAMPLES / "paper_continuous.yaml"),
                            "--out", str(tmp_path), "--steps", "3000", "--no-plots"],
                           cwd=ROOT, stdout=subprocess.PIPE, stderr=slave, timeout=120)
        os.close(slave)
        slave = None
        chunks = []
        while True:
            try:
                data = os.read(master, 4096)
            except OSError:
                break
            if not data:
                break
            chunks.append(data)
    finally:
        if slave is not None:
            os.close(slave)
        os.close(master)
    err = b"".join(chunks).decode(errors="replace")
    assert p.returncode == 0
    assert "simulating [" in err and "100.0%" in err
