"""``splitspec compare --sweep-rate`` end to end: the CLI as a user runs it, on a model written here."""

import json

import numpy as np
import pytest
import scipy.linalg as sla
import yaml

from tests.integration.runtime_helpers import run

A = [[0.9, 0.2, 0.0], [0.0, 0.8, 0.3], [0.0, 0.0, 0.7]]
SIGMA_P, SIGMA_M = 0.1, {1: 0.1, 2: 0.1, 3: 0.5}
RATES = [0.8, 0.4, 0.1, 0.02]


def _refuse(constant):
    """``json.loads(..., parse_constant=_refuse)``: strict JSON, no NaN or Infinity."""
    raise ValueError(f"not JSON: {constant}")


def test_compare_sweep_rate_end_to_end(tmp_path):
    """Three agents on a triangle, one sensor 5x noisier; four rates from slower than the Kalman filter to far
    faster.  The command writes strict JSON and a figure; the centralized Kalman filter's RMS is the DARE's (solved
    here), the same at every rate; no estimator is predicted below it; the best centralized estimator certified at a
    rate pays more as the rate gets faster; the table has a line per rate."""
    src = tmp_path / "triangle.yaml"
    src.write_text(yaml.safe_dump({
        "name": "triangle", "time": "discrete",
        "system": {"A": A, "C": {1: [[1, 0, 0]], 2: [[0, 1, 0]], 3: [[0, 0, 1]]}, "process_noise": SIGMA_P,
                   "measurement_noise": SIGMA_M},
        "graphs": {"ring": {"undirected": [[1, 2], [2, 3], [3, 1]]}},
        "design": {"rate": 0.5}, "run": {"steps": 200, "seed": 3}}))
    out = tmp_path / "rates"
    r = run("compare", src, "--out", out, "--sweep-rate", *RATES, "--seeds", 2)
    assert r.returncode == 0, r.stderr
    data = json.loads((out / "rate_sweep.json").read_text(), parse_constant=_refuse)
    png = (out / "rate_sweep.png").read_bytes()
    assert png[:8] == b"\x89PNG\r\n\x1a\n" and len(png) > 10_000
    assert data["rates"] == RATES and data["seeds"] == [3, 4] and [row["rate"] for row in data["rows"]] == RATES
    # the centralized Kalman predictor's steady error: sqrt(trace P), P the DARE's solution
    P = sla.solve_discrete_are(np.array(A).T, np.eye(3), SIGMA_P ** 2 * np.eye(3),
                               np.diag([s ** 2 for s in SIGMA_M.values()]))
    kalman = float(np.sqrt(np.trace(P)))
    for row in data["rows"]:
        assert row["kalman"] == pytest.approx(kalman, rel=1e-9), row
        for est in ("whole", "split"):  # predicted exactly (Lyapunov): never below the centralized filter
            assert row[est]["error"] is None and row[est]["rms"] >= kalman * (1 - 1e-9), (est, row)
        assert row["reference"] >= kalman * (1 - 1e-9)
        assert row["kcf"] >= 0.8 * kalman  # measured over 2 seeds x 100 steps: sampling error only below it
    references = [row["reference"] for row in data["rows"]]  # the rates get faster down the list
    assert all(b >= a * (1 - 1e-9) for a, b in zip(references, references[1:])), references
    assert references[-1] > 1.5 * kalman  # 0.02 per step costs the centralized estimator too
    lines = r.stdout.splitlines()
    for rate in RATES:
        assert sum(1 for ln in lines if ln.split() and ln.split()[0] == f"{rate:g}") == 1, r.stdout
    assert lines[-1] == f"wrote {out}/rate_sweep.json, rate_sweep.png"
