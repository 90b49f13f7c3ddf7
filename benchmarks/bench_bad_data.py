"""Sensors that lie (issue 37): one agent's sensor corrupted for 60 event times, with and without the bad-data test,
against the Kalman consensus filter on the same measurements.

    .venv/bin/python benchmarks/bench_bad_data.py [--only ring10_noise] [--seeds 4] [--json PATH]

Per system (:data:`SYSTEMS`), all with ``design.bad_data: {false_alarm: 1e-5, suspect_after: 3}`` unless said:

``clean``   ``--seeds`` runs of the system's clean steps without a fault: the false alarms (measurements set
            aside per 10,000 agent-event times after the transient, the system's warm-up) and each agent's
            clean steady RMS error ``sqrt(mean |x_i - x|^2)`` over the same window, the same for the KCF (the
            Kalman consensus filter of ``studies.baselines.baseline_trajectories``, as many exchanges per event time
            as the design's q) and for the design without the test.
``faults``  the faulty agent's sensor corrupted from the end of the warm-up for 60 event times, one kind at
            a time, each of a size comparable to 20 standard deviations of the agent's clean signal ``sigma_y`` (its
            measurement's std over the clean runs, per output): ``bias`` ``20 sigma_y``; ``scale`` ``21`` (``21 y``
            is ``y`` plus ``20 y``); ``stuck`` (the last value held); ``noise`` ``20 sigma_y``.  Per kind and seed:
            the detection delay (the first event time >= T0 whose measurement is set aside, minus T0); per agent
            the mean error ``|x_i - x|`` over the 60 event times, over its clean steady RMS (the issue's measure:
            within 2x for every other agent, 3x for the faulty one), with the test, without it, and for the KCF.

Writes a JSON record (``--json``) and prints the tables with the load average before and after.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import splitspec_core as ss  # noqa: E402
from splitspec_core.scenarios.load import load_yaml, parse_scenario  # noqa: E402
from splitspec_core.studies.baselines import baseline_trajectories  # noqa: E402

#: name -> (scenario file, the faulty agent, its design's extra keys, event times of warm-up (the fault's start),
#: event times of the clean runs)
SYSTEMS = {
    "ring10_noise": ("examples/ring10_noise.yaml", 3, {}, 100, 2600),
    # the IEEE 14-bus PMU ring (continuous, run.dt 0.02 s, rate 0.3 /s: its envelope falls 1000x in 23 s)
    "ieee14_pmu": ("examples/ieee14_pmu.yaml", 3, {}, 1500, 4000),
}
WINDOW = 60  # event times of the fault
KINDS = ("bias", "scale", "stuck", "noise")


def loadavg() -> str:
    return " ".join(Path("/proc/loadavg").read_text().split()[:3])


def scenario(path: str, *, bad_data, steps: int, extra: dict):
    raw = load_yaml((ROOT / path).read_text(), source=path)
    raw.setdefault("design", {}).update(extra)
    raw["design"]["bad_data"] = bad_data
    raw.setdefault("run", {})["steps"] = steps
    raw.pop("faults", None)
    return parse_scenario(raw, source=path, base=(ROOT / path).parent)


def agent_errors(xhat: np.ndarray, x: np.ndarray) -> np.ndarray:
    """(T, m) |x_i - x|."""
    return np.linalg.norm(xhat - x[:, None, :], axis=2)


def fault_of(kind: str, agent: int, t0: float, dt: float, sigma: np.ndarray) -> dict:
    """The fault at ``t0`` (the scenario's time: event times, or seconds in continuous time) for WINDOW event times."""
    size = [float(s) for s in 20.0 * sigma]
    how = {"bias": {"bias": size}, "scale": {"scale": 21.0}, "stuck": {"stuck": True}, "noise": {"noise": size}}[kind]
    return {"at": t0, "corrupt": agent, "for": round(WINDOW * dt, 9), **how}


def run_system(name: str, seeds: list, kinds=KINDS) -> dict:
    path, agent, extra, warmup, clean_steps = SYSTEMS[name]
    on = {"false_alarm": 1e-5, "suspect_after": 3}
    sc_on = scenario(path, bad_data=on, steps=clean_steps, extra=extra)
    sc_off = scenario(path, bad_data="off", steps=clean_steps, extra=extra)
    t_design = time.perf_counter()
    des_on, des_off = ss.design(sc_on), ss.design(sc_off)
    t_design = time.perf_counter() - t_design
    q = int(des_on.q) if des_on.q is not None else 1
    ids = list(sc_on.agent_ids)
    ai = ids.index(agent)
    m = len(ids)
    out = {"system": name, "agent": agent, "m": m, "n": sc_on.n, "q": q, "seeds": len(seeds), "design_s": t_design,
           "report_bad_data": [ln for ln in des_on.report().splitlines() if "bad" in ln.lower() or "sensor" in
                               ln.lower()]}
    # clean runs: false alarms, clean steady RMS per agent (with the test, without it, KCF), the faulty agent's
    # signal's std per output
    sq = {"on": [], "off": [], "kcf": []}
    rejected, looked, ys = 0, 0, []
    for s in seeds:
        tr = ss.simulate(des_on, seed=s, keep_y=True)
        e_on = agent_errors(tr.xhat, tr.x)[warmup:]
        rej = np.asarray(tr.columns["y_rejected"])[warmup:-1]  # the last row has no round
        rejected += int(rej.sum())
        looked += int(rej.size)
        tr_off = ss.simulate(des_off, seed=s)
        b = baseline_trajectories(sc_on, s, exchanges=q)
        sq["on"].append(e_on ** 2)
        sq["off"].append(agent_errors(tr_off.xhat, tr_off.x)[warmup:] ** 2)
        sq["kcf"].append(agent_errors(b["kcf"], b["x"])[warmup:] ** 2)
        ys.append(np.asarray(tr.y)[warmup:, _rows_of(sc_on, ai)])  # the faulty agent's measurement
    clean = {k: np.sqrt(np.mean(np.concatenate(v), axis=0)) for k, v in sq.items()}  # (m,) each
    sigma = np.std(np.concatenate(ys), axis=0)  # its signal's std per output (noise included)
    out["clean"] = {"false_alarms_per_10000": 1e4 * rejected / max(looked, 1), "agent_event_times": looked,
                    "steady_rms": {k: v.tolist() for k, v in clean.items()}, "sigma_y": sigma.tolist()}
    # faults
    steps = warmup + WINDOW + 40
    out["faults"] = {}
    for kind in kinds:
        dt = float(sc_on.run.dt) if sc_on.time == "continuous" else 1.0
        f = fault_of(kind, agent, round(warmup * dt, 9), dt, sigma)
        delays, means = [], {"on": [], "off": [], "kcf": []}
        for s in seeds:
            tr = ss.simulate(des_on, seed=s, steps=steps, faults=[f])
            rej = np.asarray(tr.columns["y_rejected"])[warmup:warmup + WINDOW, ai]
            hit = np.flatnonzero(rej)
            delays.append(int(hit[0]) if hit.size else None)
            means["on"].append(agent_errors(tr.xhat, tr.x)[warmup:warmup + WINDOW].mean(axis=0))
            tr_off = ss.simulate(des_off, seed=s, steps=steps, faults=[f])
            means["off"].append(agent_errors(tr_off.xhat, tr_off.x)[warmup:warmup + WINDOW].mean(axis=0))
            sc_f = _with_faults(scenario(path, bad_data="off", steps=steps, extra=extra), [f])
            b = baseline_trajectories(sc_f, s, exchanges=q, steps=steps)
            means["kcf"].append(agent_errors(b["kcf"], b["x"])[warmup:warmup + WINDOW].mean(axis=0))
        ratio = {k: (np.mean(v, axis=0) / clean[k]) for k, v in means.items()}
        others = [i for i in range(m) if i != ai]
        out["faults"][kind] = {
            "fault": f, "delays": delays,
            "ratio": {k: v.tolist() for k, v in ratio.items()},
            "faulty_ratio": {k: float(v[ai]) for k, v in ratio.items()},
            "others_max_ratio": {k: float(np.max(v[others])) for k, v in ratio.items()},
        }
    return out


def _rows_of(sc, ai: int) -> list:
    start = sum(np.shape(C)[0] for C in sc.system.Cs[:ai])
    return list(range(start, start + np.shape(sc.system.Cs[ai])[0]))


def _with_faults(sc, faults: list):
    from splitspec_core.api import _with_faults as wf

    return wf(sc, faults)


def table(rec: dict) -> str:
    lines = [f"{rec['system']}: m {rec['m']}, n {rec['n']}, q {rec['q']}, {rec['seeds']} seeds, faulty agent "
             f"{rec['agent']} (sigma_y {', '.join(f'{s:.3g}' for s in rec['clean']['sigma_y'])}); design "
             f"{rec['design_s']:.1f} s",
             f"  clean: {rec['clean']['false_alarms_per_10000']:.2f} measurements set aside per 10,000 agent-event "
             f"times ({rec['clean']['agent_event_times']} looked at); steady RMS (mean over agents) with the test "
             f"{np.mean(rec['clean']['steady_rms']['on']):.4g}, without {np.mean(rec['clean']['steady_rms']['off']):.4g}"
             f", KCF {np.mean(rec['clean']['steady_rms']['kcf']):.4g}",
             "  fault   delay (event times, per seed)   faulty agent x clean: test / no test / KCF   "
             "worst other agent x clean: test / no test / KCF"]
    for kind, r in rec["faults"].items():
        d = ", ".join("-" if v is None else str(v) for v in r["delays"])
        fr, ot = r["faulty_ratio"], r["others_max_ratio"]
        lines.append(f"  {kind:<7} {d:<33} {fr['on']:7.2f} / {fr['off']:8.2f} / {fr['kcf']:8.2f}"
                     f"              {ot['on']:7.2f} / {ot['off']:8.2f} / {ot['kcf']:8.2f}")
    return "\n".join(lines)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--only", choices=sorted(SYSTEMS), action="append")
    p.add_argument("--seeds", type=int, default=4)
    p.add_argument("--kinds", default=",".join(KINDS), help="comma-separated fault kinds (default: all)")
    p.add_argument("--json", type=Path)
    a = p.parse_args(argv)
    before = loadavg()
    t0 = time.perf_counter()
    kinds = tuple(k for k in a.kinds.split(",") if k)
    recs = [run_system(name, list(range(a.seeds)), kinds) for name in (a.only or SYSTEMS)]
    meta = {"load_before": before, "load_after": loadavg(), "wall_s": time.perf_counter() - t0,
            "threads": os.environ.get("OPENBLAS_NUM_THREADS"), "numpy": np.__version__}
    print(f"bench_bad_data: load average before {before}, after {meta['load_after']}; {meta['wall_s']:.0f} s")
    for rec in recs:
        print(table(rec))
    if a.json:
        a.json.write_text(json.dumps({"meta": meta, "systems": recs}, indent=1, default=float))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
