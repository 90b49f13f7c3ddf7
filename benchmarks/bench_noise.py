"""Certified estimates under noise (issue 35): every estimator against the centralized Kalman filter and the
centralized Kalman filter designed for A/rate (rate-shifted, certified at the same rate, not the optimum under it),
predicted and measured, and the highest certifiable rate.

    .venv/bin/python benchmarks/bench_noise.py [--only NAME] [--seeds 4] [--label before|after] [--json PATH]
    .venv/bin/python benchmarks/bench_noise.py --report --json PATH     # the tables of a saved run, no work
    .venv/bin/python benchmarks/bench_noise.py --only ROW --stages compare --json PATH   # one stage again, merged

The rows (:data:`ROWS`): the paper's noisy examples (``paper_discrete_noise``, ``paper_continuous``),
``ring10_noise``, ``ieee14_pmu`` as shipped (continuous, rate 0.3 /s, ``run.dt`` 0.02, process 1e-4, measurement
1e-3, gains riccati), the same PMU ring built here from ``examples/models/*.npz`` for ``kundur_full`` (rate 0.3)
and ``ieee39_damped`` (rate 0.2) as ``benchmarks/bench_real.py::scenario`` builds them (one agent per generator,
``C_pmu_<k>``, a ring both directions, named states; gains riccati, noise 1e-4 / 1e-3, ``run.dt`` 0.02),
``platoon``, and the 0.5 /s targets: IEEE 14-bus and Kundur at 0.5 /s (continuous) and both sampled at 20 ms
(``time: discrete``, ``system.sample: 0.02``, rate 0.99 per step = 0.503 /s; process noise std 1e-3 per step,
measurement 1e-2 (IEEE 14) or 1e-3 (Kundur); gains riccati).  One extra row, ``ieee39_damped_pmu_m0.1``:
the 39-bus ring with ``design.margin: 0.1``, the settings of ``bench_real.py``'s certified noise row, whose
``compare`` the issue saw run past 10 minutes.

Per row, four stages, each in its own process with a time limit (a stage that runs out is a result: "did not
finish in X min"):

``design``  the scenario's own design (``ss.design``): certified (``rate_certificate``) and its line, wall time,
            or the design's one-line error; its predicted steady RMS (``predicted_rms``: RMS over agents); the two
            references on the per-step model ``(F, Q, R) = sampled_model(sc)``:

            * ``KF``: the centralized steady-state Kalman predictor (``kalman_predictor``), ``sqrt(trace P)``;
            * ``ref@rate``: the centralized Kalman filter designed for A/rate (rate-shifted, not the optimum under
              it), certified at the per-step rate ``lam_s`` (discrete:
              ``design.rate``; continuous: ``exp(-rate run.dt)``): the KF itself when ``rho(F - L C) < lam_s``, else
              the Riccati design of ``F`` shifted by the rate (the prescribed degree of stability design:
              ``X = solve_discrete_are(F' / lam_s, C' / c, Q, R)``, ``c`` either ``1`` or ``lam_s``, the better of the
              two whose ``rho(F - L C) < lam_s``), its RMS from ``solve_discrete_lyapunov(F - L C, Q + L R L')``.

            The ratio ``pred/ref`` is the design's predicted RMS over the larger of the two references.
``compare`` ``ss.compare(sc, seeds=range(N), steps=...)``: every estimator row it returns, whatever its name, with
            its own figures (``rms_mean``: per seed the RMS over agents and the steps of the run's last half, mean
            over seeds; ``ratio_to_centralized``; ``predicted_rms``) and its wall time.  Beside them, from
            ``res.curves[name]`` (RMS over agents, mean over seeds), ``sqrt(mean curve^2)`` over the last third and
            the last half: equal when the transient is over.  (The curves average ``|e|`` over seeds before squaring,
            which under-reads the RMS of one estimate, the KF's, by up to 17 % on the paper's 4-state example; so
            the headline figures are measured as below, not from the curves.)
``measure`` the headline measurement, the same code before and after: the scenario's own design by
            ``ss.simulate(design, seeds=range(N), steps=...)`` (its squared errors per seed and step), the
            centralized KF and the KCF by ``studies.baselines.baseline_seeds`` (guarded; the KCF with as many
            exchanges per event time as the design's q) on the same realisations; per seed the RMS over agents and
            the steps of the **last third**, then mean (and spread) over seeds.  Also where ``compare`` refuses
            (its ``place`` variant fails on models it cannot place): the design's figure is still measured.
            The horizon: 20 time constants of the slowest of the rate, the KF (``rho(F - L C)``) and the design's
            own error map (``rho(M)``, when it decays), clamped per row (the power-system rows: 6000 steps = 120 s;
            an initial error 50 times the steady one is then below 1 % of the mean square over the window).
``maxrate`` the highest certifiable rate of the scenario's design settings: bracket, then bisection (log scale;
            discrete: on ``-ln(rate per step)``) for the fastest ``design.rate`` at which ``ss.design`` succeeds
            and ``rate_certificate`` certifies it (its envelope at least that fast; a design that raises is not
            certified), at most ``--bisect-steps`` designs after the bracket and ``--maxrate-minutes`` per row.

Only the public API (``splitspec_core`` as ``ss``, ``rate_certificate``, ``predicted_rms``, ``sampled_model``,
``kalman_predictor``; ``error_dynamics`` and ``baseline_seeds`` guarded), so the same script measures the code
before issue 35 and after it.  Wall times depend much on the load of the machine (the same ``compare`` took 35 s
at load 0.3 and 292 s at load 3 to 6 on a shared 2-core machine): every stage records the load before and after.
"""

from __future__ import annotations

import argparse
import dataclasses
import datetime
import json
import math
import os
import platform
import signal
import subprocess
import sys
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np
import scipy.linalg as sla

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
EXAMPLES = ROOT / "examples"
MODELS = EXAMPLES / "models"
sys.path.insert(0, str(HERE))
from _common import loadavg  # noqa: E402

import splitspec_core as ss  # noqa: E402
from splitspec_core.synthesis.error_matrix import predicted_rms  # noqa: E402
from splitspec_core.synthesis.verdict import rate_certificate  # noqa: E402

try:  # where the plant's per-step model lives (the brief's path; older trees re-export it from the baselines)
    from splitspec_core.model.plant import sampled_model  # noqa: E402
except ImportError:  # pragma: no cover
    from splitspec_core.studies.baselines import sampled_model  # noqa: E402
from splitspec_core.studies.baselines import kalman_predictor  # noqa: E402

#: the noise of the PMU rows built here (process intensity, measurement std), as examples/ieee14_pmu.yaml
PMU_NOISE = (1e-4, 1e-3)
#: ``--label after``: every row's design is the default under noise (``design.gains: optimal``: the noise-optimal
#: design of issue 35, the scenario's explicit gains and K dropped, ``design.consensus: auto``); ``before``: the rows
#: as shipped at 2dd269a (the PMU rows with gains riccati)
DEFAULT_DESIGN = False


# --------------------------------------------------------------------------
# the rows
# --------------------------------------------------------------------------


def pmu_ring(model: str, *, time_: str, rate: float, noise: tuple, dt: float = 0.02, steps: int = 1500,
             gains: str = "riccati", **design) -> "ss.Scenario":
    """One agent per generator with its PMU (``C_pmu_<k>``), a ring both directions, named states (as
    ``bench_real.py::scenario``); continuous with ``run.dt`` = dt, or discrete sampled at dt (``system.sample``)."""
    d = np.load(MODELS / f"{model}.npz", allow_pickle=False)
    m = len(d["generators"])
    ring = [(k, k % m + 1) for k in range(1, m + 1)] + [(k % m + 1, k) for k in range(1, m + 1)]
    timing = {"dt": dt} if time_ == "continuous" else {"sample": dt}
    sc = ss.scenario(name=f"{model}-pmu-{time_}-{rate:g}", time=time_, A=d["A"],
                     states=[str(s) for s in d["states"]], C={k: d[f"C_pmu_{k}"] for k in range(1, m + 1)},
                     graphs={"ring": ring}, steps=steps, seed=1, process_noise=noise[0],
                     measurement_noise=noise[1], rate=rate, gains=gains, **timing, **design)
    return default_design(sc) if DEFAULT_DESIGN else sc


def example(name: str, *, rate: float | None = None) -> "ss.Scenario":
    sc = ss.load_scenario(EXAMPLES / f"{name}.yaml")
    sc = sc if rate is None else with_rate(sc, rate)
    return default_design(sc) if DEFAULT_DESIGN else sc


def default_design(sc) -> "ss.Scenario":
    """The scenario with the design a noisy scenario gets by default (``--label after``): ``gains: optimal``,
    ``consensus: auto``, no explicit K, q and g left to the design."""
    d = dataclasses.replace(sc.design, gains="optimal", K=None, consensus="auto", q="auto", g="auto")
    return dataclasses.replace(sc, design=d)


def with_rate(sc, rate: float):
    """The scenario with ``design.rate`` replaced (``DesignSpec`` is frozen: ``dataclasses.replace``)."""
    return dataclasses.replace(sc, design=dataclasses.replace(sc.design, rate=float(rate)))


@dataclasses.dataclass(frozen=True)
class Row:
    """One benchmark row: how to build its scenario, and the clamp of its horizon (event times)."""

    name: str
    build: object  # () -> Scenario
    note: str
    min_steps: int
    max_steps: int
    seeds: int | None = None  # at least this many seeds (a short, noisy row), else --seeds


ROWS = [
    Row("paper_discrete_noise", lambda: example("paper_discrete_noise"),
        "examples/paper_discrete_noise.yaml as shipped (unstable plant: round-off past ~100 steps; 80 steps, "
        "at least 20 seeds as docs/how-to/compare.md)", 80, 80, 20),
    Row("paper_continuous", lambda: example("paper_continuous"),
        "examples/paper_continuous.yaml as shipped (explicit gains, g 10, dt 0.01; 100 s: 4 seeds of 20 s read "
        "the KF 14 % low)", 10000, 10000),
    Row("ring10_noise", lambda: example("ring10_noise"), "examples/ring10_noise.yaml as shipped", 400, 2000),
    Row("ieee14_pmu", lambda: example("ieee14_pmu"),
        "examples/ieee14_pmu.yaml as shipped (continuous, rate 0.3, dt 0.02, noise 1e-4/1e-3, riccati)", 6000, 6000),
    Row("kundur_pmu", lambda: pmu_ring("kundur_full", time_="continuous", rate=0.3, noise=PMU_NOISE),
        "kundur_full PMU ring, continuous, rate 0.3, dt 0.02, noise 1e-4/1e-3, riccati", 6000, 6000),
    Row("ieee39_damped_pmu", lambda: pmu_ring("ieee39_damped", time_="continuous", rate=0.2, noise=PMU_NOISE),
        "ieee39_damped PMU ring, continuous, rate 0.2, dt 0.02, noise 1e-4/1e-3, riccati", 6000, 6000),
    Row("ieee39_damped_pmu_m0.1",
        lambda: pmu_ring("ieee39_damped", time_="continuous", rate=0.2, noise=PMU_NOISE, margin=0.1),
        "extra: ieee39_damped PMU ring as bench_real's certified noise row (riccati, design.margin 0.1), rate 0.2, "
        "dt 0.02: the compare the issue saw run past 10 min", 6000, 6000),
    Row("platoon", lambda: example("platoon"), "examples/platoon.yaml as shipped (discrete, 0.1 s, rate 0.7)",
        300, 1500),
    Row("ieee14_pmu_0.5", lambda: example("ieee14_pmu", rate=0.5),
        "examples/ieee14_pmu.yaml at rate 0.5 /s (continuous)", 6000, 6000),
    Row("kundur_pmu_0.5", lambda: pmu_ring("kundur_full", time_="continuous", rate=0.5, noise=PMU_NOISE),
        "kundur_full PMU ring at rate 0.5 /s (continuous)", 6000, 6000),
    Row("ieee14_pmu_20ms", lambda: pmu_ring("ieee14_full", time_="discrete", rate=0.99, noise=(1e-3, 1e-2)),
        "ieee14_full PMU ring sampled at 20 ms, rate 0.99 per step, noise 1e-3/1e-2 (std per step), riccati",
        6000, 6000),
    Row("kundur_pmu_20ms", lambda: pmu_ring("kundur_full", time_="discrete", rate=0.99, noise=(1e-3, 1e-3)),
        "kundur_full PMU ring sampled at 20 ms, rate 0.99 per step, noise 1e-3/1e-3 (std per step), riccati",
        6000, 6000),
]
ROW = {r.name: r for r in ROWS}


# --------------------------------------------------------------------------
# small helpers
# --------------------------------------------------------------------------


def one_line(exc: BaseException) -> str:
    text = " ".join(str(exc).split())
    return f"{type(exc).__name__}: {text}" if text else type(exc).__name__


def detail(des):
    """The full design of an ``ss.design`` result (what ``rate_certificate`` and ``predicted_rms`` take)."""
    return getattr(des, "detail", des)


def step_rate(sc) -> float:
    """The rate per event time: discrete ``design.rate``; continuous ``exp(-rate run.dt)``."""
    return float(sc.design.rate) if sc.time == "discrete" else math.exp(-float(sc.design.rate) * float(sc.run.dt))


def step_seconds(sc) -> float | None:
    """Seconds per event time (continuous: run.dt; discrete sampled: system.sample; else None)."""
    if sc.time == "continuous":
        return float(sc.run.dt)
    s = getattr(sc.system, "sample", None)
    return float(s) if s else None


def spectral_radius(M: np.ndarray) -> float:
    return float(np.max(np.abs(np.linalg.eigvals(M)), initial=0.0))


def time_constant(rho: float | None) -> float | None:
    """Event times per e-fold of a decay ``rho`` per event time (None: none, or not decaying)."""
    if rho is None or not (0.0 < rho < 1.0):
        return None if rho is None or rho >= 1.0 else 0.0
    return -1.0 / math.log(rho)


def regularised(M: np.ndarray) -> np.ndarray:
    """``M`` made positive definite when (numerically) singular, as the baselines do (noise-free measurements)."""
    try:
        from splitspec_core.studies.baselines import regularise
        return regularise(M)
    except ImportError:  # pragma: no cover
        M = 0.5 * (M + M.T)
        scale = max(1.0, float(np.linalg.norm(M, 2))) if M.size else 1.0
        return M + 1e-9 * scale * np.eye(M.shape[0]) if M.size and np.linalg.eigvalsh(M)[0] <= 1e-12 * scale else M


def stacked_C(sc) -> np.ndarray:
    return np.vstack([np.atleast_2d(np.asarray(c, dtype=float)) for c in sc.system.Cs])


# --------------------------------------------------------------------------
# the references: the centralized KF and the centralized KF designed for A/rate (rate-shifted, not the optimum)
# --------------------------------------------------------------------------


def references(sc) -> dict:
    """The centralized KF and the rate-certified centralized design on the per-step model (module docstring)."""
    F, Q, R = sampled_model(sc)
    C = stacked_C(sc)
    lam = step_rate(sc)
    out = {"lam_step": lam}
    t0 = time.perf_counter()
    try:
        kp = kalman_predictor(F, C, Q, R)
        rho_kf = spectral_radius(F - kp.L @ C)
        out["kf"] = {"rms": float(math.sqrt(max(np.trace(kp.P), 0.0))), "rho": rho_kf,
                     "faster_than_rate": bool(rho_kf < lam)}
    except Exception as exc:  # a result: the KF of this model does not exist
        out["kf"] = {"error": one_line(exc)}
        kp = None
    Qr, Rr = regularised(Q), regularised(R)
    if kp is not None and out["kf"]["faster_than_rate"]:
        out["ref"] = {"rms": out["kf"]["rms"], "rho": out["kf"]["rho"], "how": "the KF (faster than the rate)"}
    else:
        best, errors = None, []
        for c_scale, how in ((1.0, "shifted Riccati: F/lam, C"), (lam, "shifted Riccati: F/lam, C/lam")):
            try:
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")
                    X = sla.solve_discrete_are(F.T / lam, C.T / c_scale, Qr, Rr)
                X = 0.5 * (X + X.T)
                # gain of the shifted pair (F/lam, C/c), mapped back: rho(F/lam - L_s C/c) < 1 -> L = L_s lam / c
                S = (C @ X @ C.T) / c_scale ** 2 + Rr
                L_s = np.linalg.solve(S, (C / c_scale) @ X @ (F.T / lam)).T
                L = L_s * lam / c_scale
                Fc = F - L @ C
                rho = spectral_radius(Fc)
                if not rho < lam * (1 - 1e-12):
                    errors.append(f"{how}: rho(F - L C) = {rho:.6g} >= {lam:.6g}")
                    continue
                Sig = sla.solve_discrete_lyapunov(Fc, Q + L @ R @ L.T)
                rms = float(math.sqrt(max(np.trace(Sig), 0.0)))
                if best is None or rms < best["rms"]:
                    best = {"rms": rms, "rho": rho, "how": how}
            except Exception as exc:
                errors.append(f"{how}: {one_line(exc)}")
        out["ref"] = best if best is not None else {"error": "; ".join(errors)}
        if best is not None and errors:
            out["ref"]["other"] = "; ".join(errors)
    out["wall"] = time.perf_counter() - t0
    return out


# --------------------------------------------------------------------------
# stage workers (each runs in its own process, with a time limit set by the parent)
# --------------------------------------------------------------------------


def certificate_of(des) -> dict:
    cert = rate_certificate(detail(des))
    return {"certified": bool(cert.certified), "text": " ".join(str(cert.text).split()),
            "rate": getattr(cert, "rate", None), "by": getattr(cert, "by", None)}


def stage_design(row: Row) -> dict:
    sc = row.build()
    out = {"name": row.name, "note": row.note, "scenario": sc.name, "time": sc.time, "n": int(sc.n), "m": int(sc.m),
           "rate": float(sc.design.rate), "gains": sc.design.gains, "step_seconds": step_seconds(sc),
           "process_noise": float(sc.system.process_noise), "measurement_noise": float(sc.system.measurement_noise)}
    out["references"] = references(sc)
    t0 = time.perf_counter()
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            des = ss.design(sc)
    except Exception as exc:  # the design's own error line is the figure
        out["design"] = {"ok": False, "error": one_line(exc), "wall": time.perf_counter() - t0}
        return out
    wall = time.perf_counter() - t0
    out["design"] = {"ok": True, "wall": wall, "q": getattr(des, "q", None), "g": getattr(des, "g", None),
                     **{"certificate": certificate_of(des)}}
    t0 = time.perf_counter()
    try:
        r = np.asarray(predicted_rms(detail(des)), dtype=float)
        out["predicted"] = {"rms": float(np.sqrt(np.mean(r ** 2))), "per_agent": [float(v) for v in r],
                            "wall": time.perf_counter() - t0}
    except Exception as exc:
        out["predicted"] = {"error": one_line(exc), "wall": time.perf_counter() - t0}
    try:  # the design's own error map (not public API: guarded), for the horizon
        from splitspec_core.synthesis.error_matrix import error_dynamics
        M, _ = error_dynamics(detail(des))
        out["predicted"]["rho_error_map"] = spectral_radius(M)
    except Exception as exc:
        out["predicted"]["rho_error_map_error"] = one_line(exc)
    return out


def horizon(row: Row, rec: dict) -> dict:
    """The horizon: 20 time constants of the slowest of the rate, the KF and the design's error map, clamped."""
    refs = rec["references"]
    taus = {"rate": time_constant(refs["lam_step"])}
    if "rho" in refs.get("kf", {}):
        taus["KF"] = time_constant(refs["kf"]["rho"])
    rho_m = rec.get("predicted", {}).get("rho_error_map")
    if rho_m is not None:
        taus["design"] = time_constant(rho_m)  # None when the error map does not decay
    known = {k: v for k, v in taus.items() if v is not None}
    slowest = max(known.values()) if known else None
    want = int(math.ceil(20 * slowest)) if slowest else row.max_steps
    steps = min(max(want, row.min_steps), row.max_steps)
    return {"steps": steps, "time_constants_steps": taus, "slowest": slowest, "wanted_steps": want,
            "window": "last third", "window_start_time_constants": (2 / 3) * steps / slowest if slowest else None,
            "clamped": steps != want}


def window_rms(curve: np.ndarray, frac: float) -> float:
    c = np.asarray(curve, dtype=float)
    k0 = int(math.floor((1.0 - frac) * len(c)))
    tail = c[k0:]
    tail = tail[np.isfinite(tail)]
    return float(math.sqrt(np.mean(tail ** 2))) if tail.size else float("nan")


def stage_compare(row: Row, seeds: int, steps: int) -> dict:
    sc = row.build()
    t0 = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = ss.compare(sc, seeds=range(seeds), steps=steps)
    wall = time.perf_counter() - t0
    names = list(res.estimators)
    kf = "centralized KF" if "centralized KF" in names else next((k for k in names if k.startswith("centralized")),
                                                                  None)
    est = {}
    for name, e in res.estimators.items():
        curve = res.curves.get(name)
        fig = {f: getattr(e, f) for f in getattr(e, "__dataclass_fields__", {})}
        fig = {k: (v if isinstance(v, (int, float, str, bool, type(None))) else str(v)) for k, v in fig.items()}
        if curve is not None:
            fig["rms_last_third"] = window_rms(curve, 1 / 3)
            fig["rms_last_half"] = window_rms(curve, 1 / 2)
        est[name] = fig
    if kf is not None and "rms_last_third" in est.get(kf, {}):
        base = est[kf]["rms_last_third"]
        for fig in est.values():
            if "rms_last_third" in fig:
                fig["ratio_kf_last_third"] = fig["rms_last_third"] / base if base > 0 else None
    return {"ok": True, "wall": wall, "seeds": list(range(seeds)), "steps": int(res.steps), "kf_name": kf,
            "estimators": est}


def tail_rms(sq_error: np.ndarray, count: np.ndarray, frac: float) -> np.ndarray:
    """Per seed: the RMS over agents and the steps of the last ``frac`` of the run, (N,)."""
    sq, cnt = np.atleast_2d(np.asarray(sq_error, dtype=float)), np.atleast_2d(np.asarray(count, dtype=float))
    k0 = int(math.floor((1.0 - frac) * sq.shape[1]))
    with np.errstate(invalid="ignore", over="ignore"):
        return np.sqrt(np.sum(sq[:, k0:], axis=1) / np.maximum(np.sum(cnt[:, k0:], axis=1), 1))


def figures(sq_error, count) -> dict:
    out = {}
    for key, frac in (("third", 1 / 3), ("half", 1 / 2)):
        r = tail_rms(sq_error, count, frac)
        out[f"rms_last_{key}"] = float(np.mean(r)) if np.all(np.isfinite(r)) else float("inf")
        out[f"rms_last_{key}_std"] = float(np.std(r, ddof=1)) if len(r) > 1 and np.all(np.isfinite(r)) else None
    return out


def stage_measure(row: Row, seeds: int, steps: int) -> dict:
    """The scenario's design, the centralized KF and the KCF on the same realisations, measured on the last third."""
    sc = row.build()
    seeds_ = list(range(seeds))
    out = {"ok": True, "seeds": seeds_, "steps": steps, "estimators": {}}
    exchanges = 1
    t0 = time.perf_counter()
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            des = ss.design(sc)
            if sc.time == "discrete" and getattr(des, "q", None):
                exchanges = int(des.q)
            runs = ss.simulate(des, seeds=seeds_, steps=steps)
        out["estimators"]["split (scenario design)"] = {**figures(runs.sq_error, runs.alive_count),
                                                        "wall": time.perf_counter() - t0}
    except Exception as exc:
        out["estimators"]["split (scenario design)"] = {"error": one_line(exc), "wall": time.perf_counter() - t0}
    t0 = time.perf_counter()
    try:
        from splitspec_core.studies.baselines import baseline_seeds
    except ImportError as exc:  # pragma: no cover - the after code may move it
        out["baselines_error"] = one_line(exc)
        return out
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            b = baseline_seeds(sc, seeds_, exchanges=exchanges, steps=steps)
        wall = time.perf_counter() - t0
        out["estimators"]["centralized KF"] = {**figures(b["centralized"].sq_error, b["centralized"].alive_count),
                                               "wall": wall}
        out["estimators"]["KCF"] = {**figures(b["kcf"].sq_error, b["kcf"].alive_count), "wall": wall,
                                    "exchanges": exchanges}
    except Exception as exc:
        out["baselines_error"] = one_line(exc)
    kf = out["estimators"].get("centralized KF", {}).get("rms_last_third")
    for fig in out["estimators"].values():
        if kf and "rms_last_third" in fig:
            fig["ratio_kf"] = fig["rms_last_third"] / kf
    return out


def certified_at(sc, rate: float) -> tuple:
    """(certified at ``rate``, one line): ``ss.design`` succeeds and the certificate's envelope is that fast."""
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            des = ss.design(with_rate(sc, rate))
        c = certificate_of(des)
    except Exception as exc:
        return False, one_line(exc)
    if not c["certified"]:
        return False, c["text"]
    env = c["rate"]
    if env is not None:
        slower = env > rate * (1 + 1e-9) if sc.time == "discrete" else env < rate * (1 - 1e-9)
        if slower:
            return False, f"certified only at the envelope's {env:.6g}: {c['text']}"
    return True, c["text"]


def stage_maxrate(row: Row, steps: int, progress: Path) -> dict:
    """Bracket, then bisect (log scale on the decay per unit: continuous the rate, discrete -ln(rate per step))."""
    sc = row.build()
    discrete = sc.time == "discrete"
    to_rate = (lambda d: math.exp(-d)) if discrete else (lambda d: d)
    to_decay = (lambda r: -math.log(r)) if discrete else (lambda r: r)
    probes = []

    def probe(d: float) -> bool:
        r = to_rate(d)
        t0 = time.perf_counter()
        ok, text = certified_at(sc, r)
        p = {"rate": r, "certified": ok, "text": text, "wall": time.perf_counter() - t0}
        probes.append(p)
        with open(progress, "a") as f:
            f.write(json.dumps(p) + "\n")
        return ok

    d0 = to_decay(float(sc.design.rate))
    lo = hi = None  # lo: certified decay, hi: failed decay
    if probe(d0):
        lo, d = d0, d0
        for _ in range(8):
            d *= 2
            if discrete and to_rate(d) <= 1e-6:
                break
            if probe(d):
                lo = d
            else:
                hi = d
                break
    else:
        hi, d = d0, d0
        for _ in range(8):
            d /= 2
            if probe(d):
                lo = d
                break
            hi = d
    n = 0
    while lo is not None and hi is not None and n < steps and hi / lo > 1.005:
        mid = math.sqrt(lo * hi)
        if probe(mid):
            lo = mid
        else:
            hi = mid
        n += 1
    return {"probes": probes, "fastest_certified": None if lo is None else to_rate(lo),
            "slowest_failed": None if hi is None else to_rate(hi), "bisection_steps": n}


# --------------------------------------------------------------------------
# the parent: stages in subprocesses with time limits, records, tables
# --------------------------------------------------------------------------


def run_stage(stage: str, row: Row, args, *, minutes: float, extra: list | None = None) -> dict:
    """Run one stage of one row in its own process group, killed after ``minutes``."""
    with tempfile.TemporaryDirectory(prefix="bench-noise-") as tmp:
        out = Path(tmp) / "out.json"
        progress = Path(tmp) / "progress.jsonl"
        cmd = [sys.executable, str(Path(__file__).resolve()), "--worker", stage, "--only", row.name,
               "--seeds", str(max(args.seeds, row.seeds or 0)), "--worker-out", str(out), "--worker-progress", str(progress),
               "--bisect-steps", str(args.bisect_steps), "--label", args.label] + (extra or [])
        t0 = time.perf_counter()
        proc = subprocess.Popen(cmd, start_new_session=True, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                text=True)
        try:
            so, se = proc.communicate(timeout=minutes * 60)
            timed_out = False
        except subprocess.TimeoutExpired:
            timed_out = True
            os.killpg(proc.pid, signal.SIGTERM)
            try:
                so, se = proc.communicate(timeout=20)
            except subprocess.TimeoutExpired:
                os.killpg(proc.pid, signal.SIGKILL)
                so, se = proc.communicate()
        wall = time.perf_counter() - t0
        if out.exists() and not timed_out:
            rec = json.loads(out.read_text())
        else:
            rec = {"ok": False}
            if timed_out:
                rec["error"] = f"did not finish in {minutes:g} min"
                rec["timed_out"] = True
            else:
                last = [ln for ln in (se or "").strip().splitlines() if ln.strip()]
                rec["error"] = last[-1] if last else f"worker exited {proc.returncode}"
        if progress.exists():
            rec.setdefault("probes", [json.loads(ln) for ln in progress.read_text().splitlines() if ln.strip()])
        rec["stage_wall"] = wall
        return rec


def bracket_of(probes: list, discrete: bool) -> tuple:
    ok = [p["rate"] for p in probes if p["certified"]]
    bad = [p["rate"] for p in probes if not p["certified"]]
    if discrete:
        best = min(ok) if ok else None
        fail = [r for r in bad if best is None or r < best]
        return best, (max(fail) if fail else None)
    best = max(ok) if ok else None
    fail = [r for r in bad if best is None or r > best]
    return best, (min(fail) if fail else None)


STAGES = ("design", "compare", "measure", "maxrate")


def do_row(row: Row, args, old: dict | None = None) -> dict:
    """The row's stages (``--stages``); a stage not run keeps its figures from ``old`` (the record being updated),
    each stage saying when and under which load it ran."""
    stages = set(args.stages.split(","))
    old = old or {}
    if "design" in stages or "references" not in old:
        rec = {"label": args.label, "started": datetime.datetime.now().isoformat(timespec="seconds"),
               "load_start": loadavg()}
        d = run_stage("design", row, args, minutes=args.design_minutes)
        rec.update({k: v for k, v in d.items() if k not in ("ok",)} if "references" in d else {"design_stage": d})
        if "references" not in d:  # the stage itself failed (timeout, crash): a horizon from the row's clamp only
            rec["horizon"] = {"steps": row.max_steps, "window": "last third", "note": "design stage failed"}
        else:
            rec["horizon"] = horizon(row, d)
        print(f"# {row.name}: design stage {d['stage_wall']:.1f} s; load {loadavg()}", flush=True)
    else:
        rec = {k: v for k, v in old.items() if k not in ("compare", "measure", "maxrate")}
    for stage in ("compare", "measure", "maxrate"):
        if stage not in stages or getattr(args, f"no_{stage}"):
            if stage in old:
                rec[stage] = old[stage]
            continue
        t = {"started": datetime.datetime.now().isoformat(timespec="seconds"), "load_start": loadavg()}
        if stage == "compare" and args.skip_compare_over and rec.get("n", 0) > args.skip_compare_over:
            rec[stage] = {"ok": False, "error": f"skipped: n = {rec['n']} > --skip-compare-over"}
            continue
        minutes = getattr(args, f"{stage}_minutes")
        extra = [] if stage == "maxrate" else ["--steps", str(rec["horizon"]["steps"])]
        r = run_stage(stage, row, args, minutes=minutes, extra=extra)
        r.update(t)
        r["load_end"] = loadavg()
        r["limit_minutes"] = minutes
        if stage == "maxrate":
            r["bracket"] = list(bracket_of(r.get("probes", []), rec.get("time") == "discrete"))
        rec[stage] = r
        print(f"# {row.name}: {stage} stage {r['stage_wall']:.1f} s; load {loadavg()}", flush=True)
    rec["load_end"] = loadavg()
    return rec


def machine() -> dict:
    cpu = "n/a"
    try:
        for ln in Path("/proc/cpuinfo").read_text().splitlines():
            if ln.startswith("model name"):
                cpu = ln.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    try:
        head = subprocess.run(["git", "rev-parse", "HEAD"], cwd=ROOT, capture_output=True, text=True).stdout.strip()
    except OSError:
        head = "n/a"
    return {"nproc": os.cpu_count(), "affinity": len(os.sched_getaffinity(0)), "cpu": cpu, "git_head": head,
            "python": platform.python_version(), "numpy": np.__version__,
            "scipy": __import__("scipy").__version__}


# ---- tables


def f3(v, fmt=".3g", none="-"):
    if v is None:
        return none
    if isinstance(v, float) and not math.isfinite(v):
        return "inf" if v > 0 else "nan"
    return format(v, fmt)


def split_name(rec: dict) -> str | None:
    """The compare row of the scenario's own design: ``split (scenario)`` when there, else ``split <gains>``."""
    est = rec.get("compare", {}).get("estimators", {})
    for k in ("split (scenario)", f"split {rec.get('gains')}"):
        if k in est:
            return k
    return None


def rate_text(rec: dict, r) -> str:
    if r is None:
        return "-"
    if rec.get("time") == "discrete":
        s = rec.get("step_seconds")
        return f"{r:.6g}/step" + (f" ({-math.log(r) / s:.3g}/s)" if s and 0 < r < 1 else "")
    return f"{r:.4g}/s"


def larger_reference(rec: dict):
    refs = rec.get("references", {})
    return max([v for v in (refs.get("kf", {}).get("rms"), refs.get("ref", {}).get("rms")) if v is not None],
               default=None)


def ratio(a, b):
    if a is None or b is None or not b:
        return None
    return a / b


def tables(data: dict) -> str:
    lines = []
    rows = [data["rows"][r.name] for r in ROWS if r.name in data["rows"]]
    lines.append("## A. The scenario's design: certificate, predicted steady RMS, the two references")
    lines.append("   KF: the centralized Kalman predictor, sqrt(trace P); ref@rate: the centralized KF designed for "
                 "A/rate, "
                 "certified at the rate per step lam_s (the KF when rho KF < lam_s, else the shifted Riccati design); "
                 "pred/ref: predicted over the larger of the two")
    hdr = (f"{'row':<24} {'n':>4} {'m':>3} {'rate':>20} {'cert':>5} {'design s':>9} {'pred split':>10} "
           f"{'KF':>8} {'rho KF':>8} {'lam_s':>8} {'ref@rate':>9} {'ref/KF':>7} {'pred/KF':>8} {'pred/ref':>8}")
    lines += [hdr, "-" * len(hdr)]
    for rec in rows:
        refs = rec.get("references", {})
        kf, ref = refs.get("kf", {}), refs.get("ref", {})
        des = rec.get("design", {})
        cert = "-" if not des.get("ok") else ("yes" if des["certificate"]["certified"] else "no")
        pred = rec.get("predicted", {}).get("rms")
        lines.append(
            f"{rec['name']:<24} {rec.get('n', '-'):>4} {rec.get('m', '-'):>3} {rate_text(rec, rec.get('rate')):>20} "
            f"{cert:>5} {f3(des.get('wall'), '.2f'):>9} {f3(pred):>10} {f3(kf.get('rms')):>8} "
            f"{f3(kf.get('rho'), '.5f'):>8} {f3(refs.get('lam_step'), '.5f'):>8} {f3(ref.get('rms')):>9} "
            f"{f3(ratio(ref.get('rms'), kf.get('rms'))):>7} {f3(ratio(pred, kf.get('rms'))):>8} "
            f"{f3(ratio(pred, larger_reference(rec))):>8}")
    lines.append("")
    lines.append("   certificates (or the design's error), references:")
    for rec in rows:
        des = rec.get("design", {})
        if des.get("ok"):
            lines.append(f"   {rec['name']}: {'certified' if des['certificate']['certified'] else 'NOT certified'}: "
                         f"{des['certificate']['text']}" + (f"  [q {des['q']}]" if des.get("q") else "")
                         + (f"  [g {des['g']:.4g}]" if isinstance(des.get("g"), float) else ""))
        elif des:
            lines.append(f"   {rec['name']}: design failed: {des.get('error')}")
        else:
            lines.append(f"   {rec['name']}: design stage failed: {rec.get('design_stage', {}).get('error')}")
        refs = rec.get("references", {})
        if "error" in refs.get("kf", {}):
            lines.append(f"      KF: {refs['kf']['error']}")
        ref = refs.get("ref", {})
        if ref:
            lines.append("      ref@rate: " + (ref.get("how", "") if "error" not in ref else f"none: {ref['error']}")
                         + (f" (rho {ref['rho']:.6g})" if "rho" in ref else ""))
        if "error" in rec.get("predicted", {}):
            lines.append(f"      predicted: {rec['predicted']['error']}")

    lines.append("")
    lines.append("## B. Measured, the headline: per seed the RMS over agents and the steps of the LAST THIRD of the "
                 "horizon, mean +- std over seeds (ss.simulate of the scenario's design; baseline_seeds: the "
                 "centralized KF and the KCF, same realisations)")
    hdr = (f"{'row':<24} {'horizon':>16} {'win@tc':>6} {'split (design)':>20} {'KF':>18} {'KCF':>18} "
           f"{'split/KF':>9} {'KCF/KF':>7} {'split/ref':>9} {'pred split/KF':>13} {'measure s':>9}")
    lines += [hdr, "-" * len(hdr)]

    def pm(fig):
        if not fig:
            return "-"
        if "error" in fig:
            return "error"
        v, sd = fig.get("rms_last_third"), fig.get("rms_last_third_std")
        return f3(v) + (f" +- {sd:.2g}" if sd is not None else "")

    for rec in rows:
        meas = rec.get("measure", {})
        hz = rec.get("horizon", {})
        sec = rec.get("step_seconds")
        hor = f"{hz.get('steps')}" + (f" ({hz['steps'] * sec:g} s)" if sec and hz.get("steps") else "")
        if "estimators" not in meas:
            lines.append(f"{rec['name']:<24} {hor:>16} measure: {meas.get('error', 'not run')}")
            continue
        est = meas["estimators"]
        sp, kf, kcf = est.get("split (scenario design)", {}), est.get("centralized KF", {}), est.get("KCF", {})
        refs = rec.get("references", {})
        lines.append(
            f"{rec['name']:<24} {hor:>16} {f3(hz.get('window_start_time_constants'), '.1f'):>6} {pm(sp):>20} "
            f"{pm(kf):>18} {pm(kcf):>18} {f3(sp.get('ratio_kf')):>9} {f3(kcf.get('ratio_kf')):>7} "
            f"{f3(ratio(sp.get('rms_last_third'), larger_reference(rec))):>9} "
            f"{f3(ratio(rec.get('predicted', {}).get('rms'), refs.get('kf', {}).get('rms'))):>13} "
            f"{f3(meas.get('stage_wall'), '.1f'):>9}")
    errs = []
    for rec in rows:
        for name, fig in rec.get("measure", {}).get("estimators", {}).items():
            if "error" in fig:
                errs.append(f"   {rec['name']}: {name}: {fig['error']}")
        if rec.get("measure", {}).get("baselines_error"):
            errs.append(f"   {rec['name']}: baselines: {rec['measure']['baselines_error']}")
    if errs:
        lines.append("")
        lines.append("   not measured:")
        lines += errs
    lines.append("   (win@tc: where the window starts, in time constants of the slowest of the rate, the KF and the "
                 "design's error map; split/ref: over the larger of the KF's and ref@rate's predicted RMS)")

    lines.append("")
    lines.append("## C. ss.compare, every estimator it returns: its own figures (rms_mean: last half per seed, mean "
                 "over seeds; ratio_to_centralized; predicted), and sqrt(mean curve^2) of res.curves over the last "
                 "third / last half (the transient check: equal when it is over)")
    hdr = (f"{'row':<24} {'estimator':<18} {'cert':>5} {'pred':>9} {'rms_mean':>9} {'+-':>8} {'/KF':>9} "
           f"{'pred/KF':>9} {'curve 1/3':>9} {'curve 1/2':>9} {'msg/ev':>6}")
    lines += [hdr, "-" * len(hdr)]
    for rec in rows:
        cmp = rec.get("compare")
        if not cmp:
            continue
        if "estimators" not in cmp:
            lines.append(f"{rec['name']:<24} compare: {cmp.get('error')}  (after {cmp.get('stage_wall', 0):.0f} s)")
            continue
        kfp = rec.get("references", {}).get("kf", {}).get("rms")
        for name, e in cmp["estimators"].items():
            cert = {True: "yes", False: "no", None: "-"}.get(e.get("certified_rate"), str(e.get("certified_rate")))
            pr = e.get("predicted_rms")
            lines.append(f"{rec['name']:<24} {name:<18} {cert:>5} {f3(pr):>9} {f3(e.get('rms_mean')):>9} "
                         f"{f3(e.get('rms_std'), '.2g'):>8} {f3(e.get('ratio_to_centralized')):>9} "
                         f"{f3(ratio(pr, kfp)):>9} {f3(e.get('rms_last_third')):>9} {f3(e.get('rms_last_half')):>9} "
                         f"{e.get('messages_per_event', '-'):>6}")
        lines.append(f"{'':<24} compare: {cmp['wall']:.1f} s for {len(cmp['seeds'])} seeds x {cmp['steps']} steps"
                     f" (load {cmp.get('load_start', rec.get('load_start'))} before, {cmp.get('load_end')} after)")

    lines.append("")
    lines.append("## D. Summary: the scenario's design against the references (measured: B), compare's wall time, the "
                 "highest certifiable rate of the scenario's design settings (bisection bracket)")
    hdr = (f"{'row':<24} {'cert':>5} {'pred/ref':>9} {'split/KF':>9} {'split/ref':>9} {'KCF/KF':>7} "
           f"{'compare':>22} {'fastest certified':>24} {'next tried, failed':>24} {'designs':>7} {'bisect s':>8}")
    lines += [hdr, "-" * len(hdr)]
    for rec in rows:
        des = rec.get("design", {})
        cert = "-" if not des.get("ok") else ("yes" if des["certificate"]["certified"] else "no")
        est = rec.get("measure", {}).get("estimators", {})
        sp, kcf = est.get("split (scenario design)", {}), est.get("KCF", {})
        cmp = rec.get("compare", {})
        if "estimators" in cmp:
            ctime = f"{cmp['wall']:.1f} s"
        elif cmp.get("timed_out"):
            ctime = cmp["error"]
        elif cmp:
            ctime = "refused (error)"
        else:
            ctime = "-"
        mr = rec.get("maxrate", {})
        b = mr.get("bracket", [None, None])
        best = rate_text(rec, b[0]) if b[0] is not None else "none"
        lines.append(f"{rec['name']:<24} {cert:>5} {f3(ratio(rec.get('predicted', {}).get('rms'), larger_reference(rec))):>9} "
                     f"{f3(sp.get('ratio_kf')):>9} {f3(ratio(sp.get('rms_last_third'), larger_reference(rec))):>9} "
                     f"{f3(kcf.get('ratio_kf')):>7} {ctime:>22} {best:>24} {rate_text(rec, b[1]):>24} "
                     f"{len(mr.get('probes', [])):>7} {f3(mr.get('stage_wall'), '.0f'):>8}")
    notes = []
    for rec in rows:
        cmp = rec.get("compare", {})
        if cmp and "estimators" not in cmp and not cmp.get("timed_out"):
            notes.append(f"   {rec['name']}: compare: {cmp.get('error')}")
    if notes:
        lines.append("")
        lines.append("   compare's errors:")
        lines += notes
    notes = []
    for rec in rows:
        mr = rec.get("maxrate", {})
        if mr.get("error"):
            notes.append(f"   {rec['name']}: bisection stage: {mr['error']}")
        b = mr.get("bracket", [None, None])
        at = [p for p in mr.get("probes", []) if not p["certified"] and p["rate"] == b[1]]
        if at:
            notes.append(f"   {rec['name']}: at {rate_text(rec, at[0]['rate'])}: {at[0]['text']}")
        elif b[0] is not None and b[1] is None:
            notes.append(f"   {rec['name']}: no failure found up to {rate_text(rec, b[0])} (the search's end)")
    if notes:
        lines.append("")
        lines.append("   why the next rate failed (the failing end of each bracket):")
        lines += notes
    return "\n".join(lines)


def step_seconds_rec(rec: dict):
    return rec.get("step_seconds")


# ---- main


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--only", default=None, help="only this row (exact name; comma-separated for several)")
    ap.add_argument("--seeds", type=int, default=4, help="compare's seeds (default 4: seeds 0..3)")
    ap.add_argument("--label", default="before", help="before | after (recorded)")
    ap.add_argument("--json", default=None, help="the record; with --only, merged into an existing one")
    ap.add_argument("--report", action="store_true", help="print the tables of --json and stop")
    ap.add_argument("--bisect-steps", type=int, default=10, help="designs after the bracket (default 10)")
    ap.add_argument("--design-minutes", type=float, default=15.0)
    ap.add_argument("--compare-minutes", type=float, default=15.0)
    ap.add_argument("--maxrate-minutes", type=float, default=20.0)
    ap.add_argument("--skip-compare-over", type=int, default=0, help="skip compare above this many states (0: never)")
    ap.add_argument("--stages", default=",".join(STAGES),
                    help="the stages to run (default all); with --json, the others keep the saved figures")
    ap.add_argument("--no-compare", action="store_true")
    ap.add_argument("--no-maxrate", action="store_true")
    ap.add_argument("--no-measure", action="store_true")
    ap.add_argument("--measure-minutes", type=float, default=15.0)
    ap.add_argument("--list", action="store_true", help="list the rows")
    # the stage workers (internal)
    ap.add_argument("--worker", choices=("design", "compare", "measure", "maxrate"), help=argparse.SUPPRESS)
    ap.add_argument("--worker-out", help=argparse.SUPPRESS)
    ap.add_argument("--worker-progress", help=argparse.SUPPRESS)
    ap.add_argument("--steps", type=int, help=argparse.SUPPRESS)
    args = ap.parse_args()
    global DEFAULT_DESIGN
    DEFAULT_DESIGN = args.label == "after"

    if args.list:
        for r in ROWS:
            print(f"{r.name:<22} {r.note}")
        return
    if args.worker:
        row = ROW[args.only]
        if args.worker == "design":
            out = stage_design(row)
        elif args.worker == "compare":
            out = stage_compare(row, args.seeds, args.steps)
        elif args.worker == "measure":
            out = stage_measure(row, args.seeds, args.steps)
        else:
            out = stage_maxrate(row, args.bisect_steps, Path(args.worker_progress))
        Path(args.worker_out).write_text(json.dumps(out, default=str))
        return
    path = Path(args.json) if args.json else None
    data = json.loads(path.read_text()) if path and path.exists() else {"rows": {}}
    if args.report:
        for meta in data.get("runs", []):
            print(f"# run ({meta.get('label')}) {meta.get('date')} -> {meta.get('finished', '?')}; git "
                  f"{meta.get('git_head')}; {meta.get('nproc')} cores, {meta.get('cpu')}; numpy {meta.get('numpy')}, "
                  f"scipy {meta.get('scipy')}; load {meta.get('load_start')} -> {meta.get('load_end', '?')}; "
                  f"args: {' '.join(meta.get('argv', [])) or '(all rows, all stages)'}")
        print()
        print(tables(data))
        return
    names = [r.name for r in ROWS] if not args.only else args.only.split(",")
    unknown = [n for n in names if n not in ROW]
    if unknown:
        sys.exit(f"unknown row {unknown[0]!r}; rows: {', '.join(ROW)}")
    meta = {"label": args.label, "date": datetime.datetime.now().isoformat(timespec="seconds"), **machine(),
            "seeds": args.seeds, "load_start": loadavg(), "rows": names, "stages": args.stages,
            "argv": sys.argv[1:],
            "limits_min": {"design": args.design_minutes, "compare": args.compare_minutes,
                           "measure": args.measure_minutes, "maxrate": args.maxrate_minutes}}
    print(f"# bench_noise ({args.label}) {meta['date']}; git {meta['git_head']}; {meta['nproc']} cores "
          f"({meta['affinity']} usable), {meta['cpu']}; numpy {meta['numpy']}, scipy {meta['scipy']}; "
          f"load {meta['load_start']}", flush=True)
    data.setdefault("runs", []).append(meta)
    data["label"] = args.label
    for name in names:
        row = ROW[name]
        print(f"# {name}: {row.note}; load {loadavg()}", flush=True)
        data["rows"][name] = do_row(row, args, data["rows"].get(name))
        if path:
            path.parent.mkdir(parents=True, exist_ok=True)
            path.write_text(json.dumps(data, indent=1, default=str))
    meta["load_end"] = loadavg()
    meta["finished"] = datetime.datetime.now().isoformat(timespec="seconds")
    if path:
        path.write_text(json.dumps(data, indent=1, default=str))
    print()
    print(tables({"rows": {n: data["rows"][n] for n in names}}))
    print(f"\n# finished {meta['finished']}; load {meta['load_end']}", flush=True)


if __name__ == "__main__":
    main()
