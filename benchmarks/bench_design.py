"""Design time for growing networks (issue: design engine; "Speed at scale", item 6).

Two tables, no timing assertions anywhere (the machine is shared):

* random jointly observable systems (n = 10, every agent sees part of the
  state) on random strongly connected graphs (a ring plus 2m random arcs),
  discrete (spectral q) and continuous (g_bound + exact g_min), place gains;
* design at scale: the undirected ring of :func:`splitspec_core.scenarios.generate.ring_scenario`
  (every oscillator block seen by two agents or more, so any single loss leaves a
  jointly observable, strongly connected network), discrete, spectral q, designed
  plain and with ``design.resilience: 1`` (q certified on the m + 1 cases: the ring
  and the ring without each agent).  Plain and resilient runs alternate, the table
  gives their medians, the ratio resilient / plain and /proc/loadavg beside them.
  ``--cli`` times the text report ``splitspec design FILE`` (a fresh process, as a user
  runs it) instead of the in-process ``design()``;
* how the cost grows with m (``--only scale``): the ring with one random chord per agent
  (:func:`splitspec_core.scenarios.generate.chord_arcs`: a ring of 1000 mixes too slowly to be useful), n = 6,
  one output per agent, rate 0.9, ``q: auto``, designed plain and resilient, each design in a fresh
  process: wall seconds (median of ``--scale-repeat``), CPU seconds of the design and its workers (what it costs
  whatever else loads the machine), the peak resident memory of that process (``wait4``), q, and how the spectral
  radii were computed (``dense``/``iterative``, :mod:`splitspec_core.synthesis.spectral`).  Resilient designs run with one
  process and with every core (:mod:`splitspec_core.parallel`: the loss cases on worker processes); plain and
  resilient alternate per size; the 1-minute load average after each run is printed beside them.

    .venv/bin/python benchmarks/bench_design.py [--sizes 5 20 50 100] [--repeat 1]
    .venv/bin/python benchmarks/bench_design.py --only ring [--ring-sizes 50 100] [--ring-n 4] [--ring-repeat 3] [--cli]
        [--ring-rate 0.5] [--eigenvalues auto|dense|iterative]
    .venv/bin/python benchmarks/bench_design.py --only scale [--scale-sizes 100 300 1000 3000]
        [--scale-resilient-max 1000] [--scale-serial-max 1000] [--scale-repeat 1]

* the fusion kind's design (``--only fusion``, :mod:`splitspec_core.synthesis.fusion`) on Rego's ring and the power
  models of ``bench_comm.py`` at each q, certified at the scenario's rate: wall seconds with the machine as it is and
  with one other busy process (a child spinning on a core), alternating, medians of ``--fusion-repeat``, the load
  average beside each.

    .venv/bin/python benchmarks/bench_design.py --only fusion [--fusion-models rego ieee14_pmu] [--fusion-q 1 2 3]

* the relay kind's design (``--only relay``, :mod:`splitspec_core.synthesis.relay`): the product's whole design and
  its report (``design`` and ``design_json`` of the scenario with ``design.consensus: relay``, ``design.q: q``) on
  Rego's ring and the IEEE 39-bus PMU ring, quiet and with one other busy process, alternating, medians of
  ``--relay-repeat``, the load average beside each:

    .venv/bin/python benchmarks/bench_design.py --only relay [--relay-models rego ieee39_pmu] [--relay-q 1 3]

* ``splitspec compare`` of Rego's ring from a cold start (``--only compare``, no kept design), quiet and beside one
  busy process:

    .venv/bin/python benchmarks/bench_design.py --only compare [--compare-repeat 2]

On a loaded machine OpenBLAS threads can dominate the figures; ``OPENBLAS_NUM_THREADS=1``
in the environment takes them out (the header says which setting ran).
"""

from __future__ import annotations

import argparse
import json
import os
import re
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import yaml

from splitspec_core.synthesis.designer import design
from splitspec_core.scenarios.generate import random_strongly_connected_arcs, random_system, ring_scenario
from splitspec_core.scenarios.load import parse_scenario

from _common import loadavg


def scenario(m: int, n: int, time_mode: str, seed: int) -> dict:
    rng = np.random.default_rng(seed)
    A, Cs = random_system(rng, m, n, time=time_mode)
    arcs = random_strongly_connected_arcs(rng, m, extra=2 * m)
    d = {"rate": 0.9, "gains": "place", "q_method": "spectral"} if time_mode == "discrete" else \
        {"rate": 0.5, "gains": "place", "g": "auto"}
    return {
        "name": f"bench-{m}", "time": time_mode,
        "system": {"A": A.tolist(), "C": {i + 1: C.tolist() for i, C in enumerate(Cs)}},
        "graphs": {"g": {"arcs": [[j + 1, i + 1] for j, i in arcs]}},
        "design": d,
    }


def random_table(args) -> None:
    print(f"{'m':>5} {'n':>3} {'time':>10} {'nbar':>6} {'result':>22} {'seconds':>9}")
    for m in args.sizes:
        for mode in ("discrete", "continuous"):
            sc = parse_scenario(scenario(m, args.n, mode, seed=m))
            best = np.inf
            for _ in range(args.repeat):
                t0 = time.perf_counter()
                des = design(sc)
                best = min(best, time.perf_counter() - t0)
            nbar = des.cases[0].nbar
            res = f"q = {des.q}" if mode == "discrete" else f"g = {des.g:.4g} (min {max(des.g_mins.values()):.3g})"
            print(f"{m:>5} {args.n:>3} {mode:>10} {nbar:>6} {res:>22} {best:>9.3f}", flush=True)


def _timer(raw: dict, cli: bool, tmp: Path):
    """A function timing one design of ``raw`` (in-process, or ``splitspec design --json`` in a fresh process)."""
    if not cli:
        sc = parse_scenario(raw)

        def run() -> tuple:
            t0 = time.perf_counter()
            des = design(sc)
            return time.perf_counter() - t0, des.q, des.cases[0].nbar
        return run
    path = tmp / f"{raw['name']}-r{raw['design']['resilience']}.yaml"
    path.write_text(yaml.safe_dump(raw, sort_keys=False))
    cmd = [sys.executable, "-m", "splitspec_orchestrator", "design", str(path)]

    def run_cli() -> tuple:
        t0 = time.perf_counter()
        out = subprocess.run(cmd, check=True, capture_output=True, text=True).stdout
        t = time.perf_counter() - t0
        q = int(re.search(r"^q = (\d+)", out, re.M).group(1))
        return t, q, sum(int(k) for k in re.findall(r"^  agent \d+: .*n_i = (\d+),", out, re.M))
    return run_cli


def _child(m: int, resilience: int, rate: float, n: int, workers: int) -> None:
    """One design in this (fresh) process: prints its JSON line (the parent measures its memory)."""
    sc = parse_scenario(ring_scenario(m, n, resilience=resilience, rate=rate, chords=True), source="<bench>")
    c0 = _cpu_seconds()
    t0 = time.perf_counter()
    des = design(sc, workers=workers or None)
    t = time.perf_counter() - t0
    print(json.dumps({"seconds": t, "cpu": _cpu_seconds() - c0, "q": des.q, "nbar": des.cases[0].nbar,
                      "cases": len(des.cases), "eig": des.q_result.eig}))


def _cpu_seconds() -> float:
    """User + system CPU seconds of this process and of its workers that have ended (a design's pool is shut down,
    its workers waited for, before it returns): what a design costs whatever else loads the machine."""
    import resource

    own, ended = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + ended.ru_utime + ended.ru_stime


def _pss_mb(pid: int) -> float:
    """Proportional set size of ``pid`` and its children (MB): each page shared copy-on-write between a process
    and its forked workers counted once in all (``/proc/PID/smaps_rollup``); 0 for a process that is gone."""
    total = 0.0
    pids = [pid]
    try:
        for task in os.listdir(f"/proc/{pid}/task"):
            pids += [int(c) for c in Path(f"/proc/{pid}/task/{task}/children").read_text().split()]
    except OSError:
        pass
    for p in pids:
        try:
            for line in Path(f"/proc/{p}/smaps_rollup").read_text().splitlines():
                if line.startswith("Pss:"):
                    total += int(line.split()[1]) / 1024
        except OSError:
            pass
    return total


def _fresh(m: int, resilience: int, rate: float, n: int, workers: int = 0) -> dict:
    """``_child`` in a fresh process; its JSON plus its peak resident memory (MB) from ``wait4`` and the peak of
    its and its workers' proportional set size, sampled every 0.1 s (``workers`` 0: the design's default, every
    core)."""
    import threading

    cmd = [sys.executable, __file__, "--child", str(m), str(resilience), str(rate), str(n), str(workers)]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, text=True)
    peak_pss = [0.0]
    done = threading.Event()

    def sample():
        while not done.wait(0.1):
            peak_pss[0] = max(peak_pss[0], _pss_mb(proc.pid))

    sampler = threading.Thread(target=sample, daemon=True)
    sampler.start()
    out = proc.stdout.read()
    done.set()
    sampler.join()
    _, status, usage = os.wait4(proc.pid, 0)
    proc.returncode = os.waitstatus_to_exitcode(status)
    if proc.returncode != 0:
        raise SystemExit(f"bench_design: the design of m = {m} (resilience {resilience}) failed")
    res = json.loads(out.strip().splitlines()[-1])
    # wait4's maxrss is the largest of the process and its waited-for workers (the process's own, at least what
    # it held before forking them); the sampled PSS counts the pages the workers share with it once
    return {**res, "peak_mb": usage.ru_maxrss / 1024, "pss_mb": peak_pss[0]}


def _eig(e: dict | None) -> str:
    return "-" if not e or not e.get("methods") else ", ".join(f"{k} {v}" for k, v in e["methods"].items())


def scale_table(args) -> None:
    from splitspec_core.parallel import available_workers

    cores = available_workers()
    print(f"ring + one random chord per agent, n = 6, one output each, rate 0.9, q auto, spectral; each design in a "
          f"fresh process; OPENBLAS_NUM_THREADS={os.environ.get('OPENBLAS_NUM_THREADS', 'unset')}; "
          f"resilient designs with 1 process and with every core ({cores} workers); memory: the process's peak "
          f"RSS, and the peak proportional set size of the process and its workers together (sampled every 0.1 s)")
    print(f"{'m':>5} {'nbar':>6} {'design':>14} {'cases':>6} {'q':>3} {'seconds':>9} {'CPU s':>8} {'peak MB':>8} "
          f"{'PSS MB':>8}  {'spectral radii':<28} loadavg (after each run)")
    for m in args.scale_sizes:
        kinds = [("plain", 0, 1)]
        if m <= args.scale_resilient_max:
            kinds += [("resilient, 1", 1, 1)] if cores > 1 and m <= args.scale_serial_max else []
            kinds += [(f"resilient, {cores}", 1, 0)]
        rows: dict = {k: [] for k in kinds}
        for _ in range(args.scale_repeat):
            for k in kinds:  # interleaved: plain, resilient serial, resilient parallel, plain, ...
                rows[k].append((_fresh(m, k[1], 0.9, 6, k[2]), loadavg()))
        for k in kinds:
            res = [r for r, _ in rows[k]]
            r = res[0]
            secs = statistics.median(x["seconds"] for x in res)
            cpu = statistics.median(x["cpu"] for x in res)
            peak = max(x["peak_mb"] for x in res)
            total = max(x["pss_mb"] for x in res)
            loads = "; ".join(load.split()[0] for _, load in rows[k])
            print(f"{m:>5} {r['nbar']:>6} {k[0]:>14} {r['cases']:>6} {r['q']:>3} {secs:>9.2f} {cpu:>8.2f} {peak:>8.0f} "
                  f"{total:>8.0f}  {_eig(r['eig']):<28} {loads}", flush=True)
        secs = {k[0]: statistics.median(x["seconds"] for x, _ in rows[k]) for k in kinds}
        for k in kinds[1:]:
            print(f"{'':>5} {k[0]} / plain: {secs[k[0]] / secs['plain']:.2f}", flush=True)


def ring_table(args) -> None:
    what = "splitspec design FILE (fresh process)" if args.cli else "design() in-process"
    print(f"undirected ring, n = {args.ring_n}, rate {args.ring_rate}, discrete, spectral q (eigenvalues "
          f"{args.eigenvalues}); {what}; median of {args.ring_repeat} "
          f"interleaved runs; OPENBLAS_NUM_THREADS={os.environ.get('OPENBLAS_NUM_THREADS', 'unset')}")
    print(f"{'m':>5} {'nbar':>6} {'q plain':>8} {'q resil.':>8} {'plain s':>9} {'resilient s':>12} {'ratio':>7}"
          f"   loadavg (before -> after)")
    with tempfile.TemporaryDirectory() as tmp:
        for m in args.ring_sizes:
            raws = [ring_scenario(m, args.ring_n, resilience=r, rate=args.ring_rate) for r in (0, 1)]
            for raw in raws:
                raw["design"]["eigenvalues"] = args.eigenvalues
            plain = _timer(raws[0], args.cli, Path(tmp))
            resil = _timer(raws[1], args.cli, Path(tmp))
            load0 = loadavg()
            tp, tr = [], []
            for _ in range(args.ring_repeat):  # interleaved, so both see the same load
                t, qp, nbar = plain()
                tp.append(t)
                t, qr, _ = resil()
                tr.append(t)
            mp, mr = statistics.median(tp), statistics.median(tr)
            print(f"{m:>5} {nbar:>6} {qp:>8} {qr:>8} {mp:>9.3f} {mr:>12.3f} {mr / mp:>7.2f}   {load0} -> {loadavg()}",
                  flush=True)


def _spin() -> None:  # pragma: no cover - the busy process of the fusion table
    while True:
        pass


def fusion_table(args) -> None:
    """The fusion design's wall time, quiet and beside one busy process (module docstring)."""
    import multiprocessing

    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from bench_comm import MODELS, _parts
    from splitspec_core.synthesis.fusion import design_fusion, neighbour_positions
    from splitspec_core.synthesis.kalman import per_step_rate

    print(f"fusion design (one BLAS thread inside; load {loadavg()})")
    print(f"{'model':<14}{'q':>3}{'quiet s':>10}{'busy s':>10}{'ratio':>8}{'radius':>11}{'rate':>11}  load after")
    for key in args.fusion_models:
        sc = MODELS[key]()
        F, Q, R, Cs, Rs, arcs = _parts(sc)
        nbs = neighbour_positions(sc.m, arcs)
        lam = per_step_rate(sc, sc.design.rate)
        for q in args.fusion_q:
            quiet, busy, des = [], [], None
            for _ in range(args.fusion_repeat):
                for loaded in (False, True):
                    spinner = multiprocessing.Process(target=_spin, daemon=True) if loaded else None
                    if spinner:
                        spinner.start()
                    try:
                        t0 = time.perf_counter()
                        des = design_fusion(F, Cs, Q, Rs, nbs, q, rate=lam)
                        (busy if loaded else quiet).append(time.perf_counter() - t0)
                    finally:
                        if spinner:
                            spinner.terminate()
                            spinner.join()
            print(f"{key:<14}{q:>3}{statistics.median(quiet):>10.1f}{statistics.median(busy):>10.1f}"
                  f"{des.ratio:>8.4f}{des.radius:>11.6g}{lam:>11.6g}  {loadavg(1)}", flush=True)


def relay_table(args) -> None:
    """The relay kind's design and report, quiet and beside one busy process (module docstring)."""
    import dataclasses
    import multiprocessing

    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from bench_comm import MODELS
    from splitspec_core.synthesis.report import design_json

    print(f"relay design and its report (load {loadavg()})")
    print(f"{'model':<14}{'q':>3}{'quiet s':>10}{'busy s':>10}{'ratio':>8}{'radius':>11}{'rate':>11}  load after")
    for key in args.relay_models:
        base = MODELS[key]()
        for q in args.relay_q:
            sc = dataclasses.replace(base, design=dataclasses.replace(base.design, consensus="relay", q=q, gains="optimal",
                                                                      resilience=0, K=None))
            quiet, busy, des = [], [], None
            for _ in range(args.relay_repeat):
                for loaded in (False, True):
                    spinner = multiprocessing.Process(target=_spin, daemon=True) if loaded else None
                    if spinner:
                        spinner.start()
                    try:
                        t0 = time.perf_counter()
                        des = design(sc)
                        design_json(des)
                        (busy if loaded else quiet).append(time.perf_counter() - t0)
                    finally:
                        if spinner:
                            spinner.terminate()
                            spinner.join()
            k = des.whole
            print(f"{key:<14}{q:>3}{statistics.median(quiet):>10.1f}{statistics.median(busy):>10.1f}"
                  f"{k.ratio:>8.4f}{k.radius:>11.6g}{k.lam_step:>11.6g}  {loadavg(1)}", flush=True)


def compare_table(args) -> None:
    """``splitspec compare`` of Rego's ring (its fusion design at q = 1, the split beside it, the references, 2 seeds)
    from a cold start (``SPLITSPEC_CACHE=off``), quiet and beside one busy process (module docstring)."""
    import multiprocessing
    import os
    import subprocess
    import tempfile

    root = Path(__file__).resolve().parents[1]
    cmd = [str(root / ".venv" / "bin" / "splitspec"), "compare", str(root / "examples" / "rego_ring.yaml"), "--seeds",
           "2", "--out"]
    print(f"splitspec compare examples/rego_ring.yaml --seeds 2, cold (load {loadavg()})")
    print(f"{'run':>4}{'quiet s':>10}{'busy s':>10}  load after")
    env = {**os.environ, "SPLITSPEC_CACHE": "off", "RERUN_ANALYTICS": "0"}
    for k in range(args.compare_repeat):
        row = []
        for loaded in (False, True):
            spinner = multiprocessing.Process(target=_spin, daemon=True) if loaded else None
            if spinner:
                spinner.start()
            try:
                with tempfile.TemporaryDirectory() as tmp:
                    t0 = time.perf_counter()
                    subprocess.run(cmd + [tmp], env=env, check=True, capture_output=True)
                    row.append(time.perf_counter() - t0)
            finally:
                if spinner:
                    spinner.terminate()
                    spinner.join()
        print(f"{k + 1:>4}{row[0]:>10.1f}{row[1]:>10.1f}  {loadavg(1)}", flush=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--compare-repeat", type=int, default=2)
    ap.add_argument("--only", choices=["random", "ring", "scale", "fusion", "relay", "compare"],
                    help="run one table only")
    ap.add_argument("--relay-models", nargs="+", default=["rego", "ieee39_pmu"])
    ap.add_argument("--relay-q", type=int, nargs="+", default=[1, 3])
    ap.add_argument("--relay-repeat", type=int, default=2)
    ap.add_argument("--fusion-models", nargs="+", default=["rego", "ieee14_pmu"])
    ap.add_argument("--fusion-q", type=int, nargs="+", default=[1, 2, 3])
    ap.add_argument("--fusion-repeat", type=int, default=1)
    ap.add_argument("--sizes", type=int, nargs="+", default=[5, 20, 50, 100])
    ap.add_argument("--n", type=int, default=10)
    ap.add_argument("--repeat", type=int, default=1)
    ap.add_argument("--ring-sizes", type=int, nargs="+", default=[50, 100])
    ap.add_argument("--ring-n", type=int, default=4, help="states of the ring's system")
    ap.add_argument("--ring-repeat", type=int, default=3)
    ap.add_argument("--cli", action="store_true", help="ring table: time `splitspec design FILE` processes")
    ap.add_argument("--ring-rate", type=float, default=0.5)
    ap.add_argument("--eigenvalues", choices=["auto", "dense", "iterative"], default="auto",
                    help="ring table: design.eigenvalues")
    ap.add_argument("--scale-sizes", type=int, nargs="+", default=[100, 300, 1000, 3000])
    ap.add_argument("--scale-resilient-max", type=int, default=1000)
    ap.add_argument("--scale-repeat", type=int, default=1)
    ap.add_argument("--scale-serial-max", type=int, default=1000,
                    help="largest m whose resilient design is also timed with one process")
    ap.add_argument("--child", nargs=5, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child:
        m, r, rate, n, workers = args.child
        return _child(int(m), int(r), float(rate), int(n), int(workers))
    if args.only in (None, "random"):
        random_table(args)
    if args.only in (None, "ring"):
        print() if args.only is None else None
        ring_table(args)
    if args.only in (None, "scale"):
        print() if args.only is None else None
        scale_table(args)
    if args.only in (None, "fusion"):
        print() if args.only is None else None
        fusion_table(args)
    if args.only in (None, "relay"):
        print() if args.only is None else None
        relay_table(args)
    if args.only in (None, "compare"):
        print() if args.only is None else None
        compare_table(args)


if __name__ == "__main__":
    main()
