"""`splitspec run --measurements FILE` read back from run.rrd: without the truth no error and no truth is logged,
only what can be known (residuals, disagreement, the centralized Kalman filter and the distance to it), equal to
trajectory.npz's arrays; with the truth, both.

Tolerances: the recording's residuals and disagreement are computed per flush (a batch of rows) by the same
functions (:mod:`splitspec_core.studies.no_truth`) that compute trajectory.npz's over all rows at once; the matrix
product ``x_i C_i'`` of a batch of L rows may be blocked differently by BLAS than that of T rows, so the two can
differ by a few ulp (CI runs under several OpenBLAS kernels): rtol 1e-12 (and 1e-12 absolute on the log10s);
measured here, 0.  The filter and the distances to it are the
very arrays the last trajectory.npz got, logged after the run: equal exactly.
"""

from __future__ import annotations

import signal
import urllib.request
from pathlib import Path

import numpy as np
import pytest
import yaml

from splitspec_core.scenarios.measurements import load_measurements, write_measurements
from tests.integration.runtime_helpers import dump, events, run
from tests.integration.test_measurements_run import hidden
from tests.rrd_readback import read_blueprint, read_rrd, read_rrd_clears, rrd_entities, verify_rrd

pytestmark = pytest.mark.slow

IDS = [1, 2, 3, 4, 5]
N = 6
KILLED, KILL_AT = 4, 18  # agent 4 is killed at event time 18
GAP = slice(5, 10)  # agent 2 has no measurement at event times 5..9
RTOL = 1e-12


def _with_kill(path):
    raw = yaml.safe_load(path.read_text())
    raw["faults"] = [{"at": KILL_AT, "kill": KILLED}]
    path.write_text(yaml.safe_dump(raw))
    return path


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("meas_rec")
    scen, sc = hidden(tmp, seed=6)
    r = run("simulate", scen, "--out", tmp / "sim0", "--no-plots", "--write-measurements", tmp / "full.npz")
    assert r.returncode == 0, r.stderr
    full = load_measurements(tmp / "full.npz", sc)
    missing = full.missing.copy()
    missing[GAP, 1] = True
    blind = tmp / "blind.csv"  # no x: no truth
    write_measurements(blind, t=full.t, y=full.y, agent_ids=sc.agent_ids,
                       sizes=[np.shape(C)[0] for C in sc.system.Cs], missing=missing)
    return tmp, _with_kill(scen), sc, blind, tmp / "full.npz"


def _run_on(files, name: str, measurements) -> Path:
    tmp, scen = files[0], files[1]
    out = tmp / name
    r = run("run", scen, "--out", out, "--measurements", measurements)
    assert r.returncode == 0, r.stdout + r.stderr
    return out


@pytest.fixture(scope="module")
def no_truth(files):
    return _run_on(files, "no_truth", files[3])


@pytest.fixture(scope="module")
def with_truth(files):
    return _run_on(files, "with_truth", files[4])


def reference_entities():
    ents = {"disagreement", "disagreement_log10"} | {f"state/{k}/kf" for k in range(1, N + 1)}
    for a in IDS:
        ents |= {f"{p}/agent_{a}" for p in ("residual", "residual_log10", "kf_distance", "kf_distance_log10")}
    return ents


def assert_series_equal(series: dict, entity: str, values: np.ndarray, *, log: bool = False, exact: bool = False):
    """The entity holds ``values`` (log10 of them with ``log``) at exactly the event times where they are known."""
    v = np.log10(values) if log else values
    with np.errstate(invalid="ignore"):
        known = [k for k in range(len(v)) if np.isfinite(v[k])]
    got = dict(series.get(entity, []))
    assert sorted(got) == known, (entity, sorted(set(got) ^ set(known)))
    have = np.array([got[k] for k in known])
    if exact:
        assert np.array_equal(have, v[known]), entity
    elif log:
        np.testing.assert_allclose(have, v[known], rtol=0, atol=RTOL, err_msg=entity)
    else:
        np.testing.assert_allclose(have, v[known], rtol=RTOL, atol=0, err_msg=entity)


def test_without_truth_no_error_and_no_truth_is_recorded(no_truth):
    rrd = no_truth / "run.rrd"
    ok, msg = verify_rrd(rrd)
    assert ok, msg
    ents = rrd_entities(rrd)
    assert not [e for e in ents if e.startswith("errors")], sorted(ents)
    assert not [e for e in ents if e.startswith("state/") and e.endswith("/truth")], sorted(ents)
    assert reference_entities() <= ents, sorted(reference_entities() - ents)
    assert {f"state/{k}/agents" for k in range(1, N + 1)} <= ents
    series = read_rrd(rrd)
    with np.load(no_truth / "trajectory.npz") as f:
        dis = f["disagreement"]
    # the kill is marked at its event time, on the log10 disagreement's axis (no max error to stand on)
    [(tau, y)] = series["marks/lost"]
    assert tau == KILL_AT and y == pytest.approx(np.log10(dis[KILL_AT]), abs=RTOL)
    # the layout that travels in the file: reference views, no error view
    views = {name: origin for _, name, origin in read_blueprint(rrd)["views"]}
    assert views["log10 residuals |y_i - C_i x_i|"] == "residual_log10"
    assert views["log10 distance to the centralized KF |x_i - x_KF| (after the run)"] == "kf_distance_log10"
    assert views["x1: centralized KF (after the run) and estimates"] == "state/1"
    assert not [v for v in views if "|x_i - x|" in v], sorted(views)


def test_without_truth_the_recording_equals_the_trajectory(no_truth):
    series = read_rrd(no_truth / "run.rrd")
    with np.load(no_truth / "trajectory.npz") as f:
        res, dis, kf, dist, alive = f["residual"], f["disagreement"], f["kf"], f["kf_distance"], f["alive"]
        xhat = f["xhat"]
    assert not alive[KILL_AT:, IDS.index(KILLED)].any() and np.isnan(res[GAP, 1]).all()
    for i, a in enumerate(IDS):
        assert_series_equal(series, f"residual/agent_{a}", res[:, i])
        assert_series_equal(series, f"residual_log10/agent_{a}", res[:, i], log=True)
        assert_series_equal(series, f"kf_distance/agent_{a}", dist[:, i], exact=True)
        assert_series_equal(series, f"kf_distance_log10/agent_{a}", dist[:, i], log=True)
    assert_series_equal(series, "disagreement", dis)
    assert_series_equal(series, "disagreement_log10", dis, log=True)
    for k in range(N):
        assert_series_equal(series, f"state/{k + 1}/kf", kf[:, k], exact=True)
    # the states of every agent are still there (its estimates are known, only its error is not)
    from tests.rrd_readback import read_rrd_state

    state = read_rrd_state(no_truth / "run.rrd")
    got = dict(state[f"state/1/agent_{IDS[0]}"])
    np.testing.assert_array_equal([got[k] for k in sorted(got)], xhat[sorted(got), 0, 0])
    # a gap in the measurements and a dead agent: a Clear breaks the line (never a NaN value)
    clears = read_rrd_clears(no_truth / "run.rrd")
    assert set(range(GAP.start, GAP.stop)) <= set(clears["residual/agent_2"])
    assert set(range(KILL_AT, len(dis))) <= set(clears[f"residual/agent_{KILLED}"])
    assert set(range(KILL_AT, len(dis))) <= set(clears[f"kf_distance/agent_{KILLED}"])
    assert any(e["event"] == "agent_lost" and e["id"] == KILLED for e in events(no_truth))


def test_with_truth_both_errors_and_reference(with_truth):
    rrd = with_truth / "run.rrd"
    ok, msg = verify_rrd(rrd)
    assert ok, msg
    ents = rrd_entities(rrd)
    want = reference_entities() | {"errors/max", "errors_log10/max", "errors_log10/envelope"}
    want |= {f"errors_log10/agent_{a}" for a in IDS} | {f"state/{k}/truth" for k in range(1, N + 1)}
    assert want <= ents, sorted(want - ents)
    series = read_rrd(rrd)
    with np.load(with_truth / "trajectory.npz") as f:
        err = np.linalg.norm(f["xhat"] - f["x"][:, None, :], axis=2)  # NaN where dead
        res, kf = f["residual"], f["kf"]
    for i, a in enumerate(IDS):
        assert_series_equal(series, f"errors_log10/agent_{a}", err[:, i], log=True)
        assert_series_equal(series, f"residual/agent_{a}", res[:, i])
    for k in range(N):
        assert_series_equal(series, f"state/{k + 1}/kf", kf[:, k], exact=True)
    views = {name for _, name, _ in read_blueprint(rrd)["views"]}
    assert {"log10 |x_i - x|, designed envelope, marks", "log10 residuals |y_i - C_i x_i|",
            "x1: truth, centralized KF and estimates"} <= views


def test_view_serves_a_run_without_truth(no_truth, tmp_path):
    from tests.integration.test_view import start_view, wait_for_url

    log = tmp_path / "view.log"
    proc = start_view(no_truth, log=log)
    try:
        url = wait_for_url(proc, log)
        with urllib.request.urlopen(url, timeout=10) as resp:
            assert resp.status == 200 and "re_viewer.js" in resp.read().decode()
        proc.send_signal(signal.SIGINT)
        assert proc.wait(timeout=15) == 0, dump(log)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
