"""Make linearised small-signal power-system models (x' = A x) from ANDES test cases.

For each bundled ANDES case this script solves the power flow, runs ANDES's
eigenvalue routine (``EIG``: the state matrix ``As`` after eliminating the
algebraic variables and zero-time-constant states) and writes one ``.npz``:

* ``A``          n x n float64, ``ss.EIG.As`` as ANDES computes it
* ``states``     n state names, ANDES's "<var> <model> <idx>" sanitised, e.g. ``omega_GENROU_1``
* ``eigs``       the eigenvalues ANDES reports (``ss.EIG.mu``), complex
* ``generators`` generator names, in the order of ``C_pmu_k`` / ``C_more_k`` (k is 1-based)
* ``C_pmu_k``    2 x n: rotor angle ``delta`` and speed ``omega`` of generator k (a PMU at its bus)
* ``C_more_k``   the PMU rows plus one output state of generator k's exciter and one of its
                 governor (see ``EXC_OUT`` / ``GOV_OUT``; the rows are listed in ``meta``)
* ``meta``       JSON string: versions, case, date, models, n, devices per generator, ...

Files load with ``np.load(path, allow_pickle=False)``.

Besides the unmodified cases (``CASES``, file ``<case stem>.npz``) the script writes variants
(``VARIANTS``, file ``<variant name>.npz``): an ANDES case loaded with ``andes.load(..., setup=False)``,
with some model parameters overridden for all devices of that model before ``System.setup``, then
the same power flow / EIG / ``build`` / ``check`` path. A variant's ``meta`` has, in addition,
``variant`` (its name), ``parameter_changes`` (model, parameter, new value, original values, devices)
and a ``note`` explaining the change. The one variant so far:

* ``ieee39_damped``: ``ieee39/ieee39_full.xlsx`` with the degenerate input filters of its 10
  IEEEST stabilisers regularised, A1 = 0.001 s and A3 = 0.002 s (A2, A4, A5, A6 stay 0; the case
  has all six 0). In ``ieee39_full`` the filter F1 = 1/(1 + A1 s + A2 s^2) with A1 = A2 = 0 gives
  the index-2 pair 0 = u - y, y' = x, which produces 6 spurious eigenvalues near +1 and 4 extra
  zero eigenvalues (all-zero rows F2_x2 of IEEEST 1, 2, 9, 10); F2 = (1 + A5 s + A6 s^2) /
  (1 + A3 s + A4 s^2) with A3 = A4 = 0 is degenerate in the same way (its bypass y = u is exact,
  but its internal state x2 gets an all-zero row). With A1 = 0.001, F1 is the 1 ms lag
  1/(1 + 0.001 s); with A3 = 0.002, F2 is still the exact bypass y = u and its internal x2 is a
  decoupled stable lag (mode -1/A3 = -500, unobservable, distinct from F1's modes near -1000 so
  that no near-defective double eigenvalue arises). The linearisation then has no positive
  eigenvalues, one zero eigenvalue (the rotor-angle reference) and no all-zero rows; n = 170.
  (A1 = A2 = 0.001 instead would make F1 a resonant filter, natural frequency 31.6 rad/s, damping
  ratio 0.016, and leaves F2's all-zero rows.)

ANDES is NOT a dependency of splitspec. Run this in a throwaway virtual environment::

    python3 -m venv /tmp/andes-venv && /tmp/andes-venv/bin/pip install andes
    /tmp/andes-venv/bin/python examples/models/make_power_models.py        # all cases and variants
    /tmp/andes-venv/bin/python examples/models/make_power_models.py --variants ieee39_damped  # only it

``--cases`` / ``--variants`` restrict the run to the named cases / variants (given alone without
names: all cases / all variants); without either option everything is regenerated.
"""
import argparse
import datetime
import json
import platform
import re
import warnings
from pathlib import Path

import andes
import numpy as np
import scipy
from scipy.optimize import linear_sum_assignment

CASES = ["kundur/kundur_full.xlsx", "kundur/kundur_ieeest.xlsx",
         "ieee14/ieee14_full.xlsx", "ieee39/ieee39_full.xlsx"]
# State taken as "the output" of an exciter (field voltage) / governor (valve position).
EXC_OUT = {"EXDC2": "vp", "IEEEX1": "vp", "EXST1": "LR_y", "ESST3A": "LAW2_y", "SEXS": "LA_y"}
GOV_OUT = {"TGOV1": "LAG_y", "TGOV1N": "LAG_y", "IEEEG1": "L4_y"}
# Variants: name -> (ANDES case, {(model, parameter): value for all devices of that model}).
# ieee39_damped: see the module docstring and NOTES["ieee39_damped"].
VARIANTS = {
    "ieee39_damped": ("ieee39/ieee39_full.xlsx", {("IEEEST", "A1"): 0.001, ("IEEEST", "A3"): 0.002}),
}
ZERO_TOL = -1e-6   # real part >= this counts as a zero/unstable mode
NOTES = {
    "ieee39_full": (
        "Caveat: ANDES (2.0.0, and 1.10.1 alike) reports 6 real eigenvalues near +1.0 and 4 extra "
        "zero eigenvalues (A has all-zero rows for F2_x2 of IEEEST 1, 2, 9, 10). They come from the "
        "IEEEST input filter F1 with A1 = A2 = 0 (a degenerate second-order lag that makes the DAE "
        "higher-index); setting A1 = 0.001 removes the positive ones. A perturbed nonlinear ANDES "
        "time-domain simulation stays bounded, so they are linearisation artefacts, not a physical "
        "instability."),
    "ieee39_damped": (
        "Variant of ieee39/ieee39_full.xlsx (see ieee39_full): the IEEEST input filter parameters, "
        "all 0 in the case, are changed to A1 = 0.001 s and A3 = 0.002 s for all 10 IEEEST (A2, A4, "
        "A5, A6 stay 0). With A1 = A2 = 0 the filter F1 = 1/(1 + A1 s + A2 s^2) is the degenerate "
        "(index-2) pair 0 = u - y, y' = x that gives 6 spurious eigenvalues near +1 and extra zero "
        "eigenvalues; with A1 = 0.001 it is the 1 ms lag 1/(1 + 0.001 s), nearly transparent in the "
        "electromechanical band. F2 = (1 + A5 s + A6 s^2)/(1 + A3 s + A4 s^2) with A3 = A4 = 0 is "
        "degenerate likewise (all-zero rows for F2_x2); with A4 = 0 ANDES keeps its exact bypass "
        "y = u, and A3 = 0.002 only turns its internal state x2 into a decoupled, unobservable stable "
        "lag x2' = (u - x2)/A3 (mode -500, kept apart from F1's modes near -1000 to avoid a "
        "near-defective double eigenvalue). Result: no positive eigenvalues, one zero eigenvalue "
        "(rotor-angle reference), no all-zero rows. A1 = A2 = 0.001 was not used: it makes F1 a "
        "resonant filter (31.6 rad/s, damping ratio 0.016) and leaves F2's all-zero rows."),
    "kundur_ieeest": (
        "The single IEEEST (on generator 1) has placeholder parameters (all 1, speed input), so its "
        "filters cancel pole-zero and the BusFreq block feeds nothing: those modes are unobservable."),
}


def sanitise(name):
    return re.sub(r"_+", "_", re.sub(r"[^A-Za-z0-9_]", "_", str(name))).strip("_")


def dev_name(model, idx):
    s = sanitise(idx)
    return s if s.startswith(model) else f"{model}_{s}"


def group_devices(ss, group):
    """(model, idx, {state var: dae index}, model object, position) for each device of a group."""
    out = []
    for mdl in ss.groups[group].models.values():
        for i, idx in enumerate(mdl.idx.v):
            out.append((mdl.class_name, idx, {v: int(var.a[i]) for v, var in mdl.states.items()}, mdl, i))
    return out


def build(ss, case, variant=None, changes=None):
    """Arrays and meta of the .npz; variant (its name) and changes only for a variant (see solve)."""
    eig = ss.EIG
    A = np.ascontiguousarray(np.array(eig.As, dtype=float))
    n = A.shape[0]
    full_names = list(ss.dae.x_name)
    pos = {full_names.index(name): j for j, name in enumerate(eig.x_name)}  # dae index -> row of A
    states = np.array([sanitise(s) for s in eig.x_name])
    assert len(set(states)) == n, "state names are not unique"
    row = pos.get

    exc = {m.syn.v[i]: (name, idx, st) for name, idx, st, m, i in group_devices(ss, "Exciter")}
    gov = {m.syn.v[i]: (name, idx, st) for name, idx, st, m, i in group_devices(ss, "TurbineGov")}
    pss = {m.syn.v[i]: (name, idx) for name, idx, st, m, i in group_devices(ss, "PSS")}
    gens, out, devices = [], {}, {}
    for name, idx, st, mdl, i in group_devices(ss, "SynGen"):
        k = len(gens) + 1
        gname = dev_name(name, idx)
        gens.append(gname)
        rows = [row(st["delta"]), row(st["omega"])]
        assert None not in rows, f"{gname}: delta/omega eliminated"
        more, info = list(rows), {"bus": str(mdl.bus.v[i])}
        for key, table, devs in (("exciter", EXC_OUT, exc), ("governor", GOV_OUT, gov)):
            if idx not in devs:
                continue
            dname, didx, dst = devs[idx]
            kept = [v for v in dst if row(dst[v]) is not None]
            var = table.get(dname) if table.get(dname) in kept else kept[0]
            more.append(row(dst[var]))
            info[key] = dev_name(dname, didx)
        if idx in pss:
            info["pss"] = dev_name(*pss[idx])
        for tag, r in (("pmu", rows), ("more", more)):
            C = np.zeros((len(r), n))
            C[np.arange(len(r)), r] = 1.0
            out[f"C_{tag}_{k}"] = C
        info["C_more_rows"] = [str(states[r]) for r in more]
        devices[gname] = info

    models = sorted({s.split()[1] for s in full_names})
    removed = [sanitise(s) for j, s in enumerate(full_names) if j not in pos]
    meta = {
        "andes": andes.__version__, "numpy": np.__version__, "scipy": scipy.__version__,
        "python": platform.python_version(), "case": case,
        "date": datetime.datetime.now(datetime.timezone.utc).date().isoformat(),
        "models": models, "n": n, "n_generators": len(gens), "generator_devices": devices,
        "states_eliminated_by_andes": removed,
        "andes_eig_stats": {"positive": int(eig.n_positive), "zero": int(eig.n_zeros),
                            "negative": int(eig.n_negative), "tol": eig.config.tol},
        "note": NOTES.get(variant or Path(case).stem, ""),
        "description": (
            f"Linearised small-signal model of the ANDES test case '{case}' around its power-flow "
            "operating point: A is ANDES's EIG state matrix As = T^-1 (fx - fy gy^-1 gx), with "
            "algebraic variables and zero-time-constant states eliminated (listed in "
            "states_eliminated_by_andes). Per-unit quantities, time in seconds; delta in rad, "
            "omega in pu. C_pmu_k selects delta and omega of generator k; C_more_k adds one output "
            "state of its exciter (field voltage: EXDC2/IEEEX1 vp, EXST1 LR_y, ESST3A LAW2_y) and "
            "of its governor (valve position: TGOV1/TGOV1N LAG_y), as listed in generator_devices."),
    }
    if variant is not None:  # record what was changed (keys absent for the plain cases)
        meta["variant"] = variant
        meta["parameter_changes"] = changes
        meta["description"] = meta["description"].replace(
            f"ANDES test case '{case}'",
            f"ANDES test case '{case}' with modified parameters (parameter_changes, note)", 1)
    return A, states, np.asarray(eig.mu, dtype=complex), np.array(gens), out, meta


def apply_changes(ss, changes):
    """Set (model, parameter) -> value for all devices of the model on a not yet set-up System."""
    done = []
    for (model, param), value in changes.items():
        mdl = ss.models[model]
        idx = list(mdl.idx.v)
        old = [float(v) for v in getattr(mdl, param).v]
        mdl.set(param, idx, [float(value)] * len(idx))
        done.append({"model": model, "param": param, "value": float(value), "original": old,
                     "devices": [str(i) for i in idx]})
    return done


def solve(case, changes=None):
    """Power flow and EIG of an ANDES case (parameters changed first if given); (ss, record) or None."""
    if not changes:
        ss, record = andes.run(andes.get_case(case), no_output=True, default_config=True), None
    else:
        ss = andes.load(andes.get_case(case), setup=False, no_output=True, default_config=True)
        record = apply_changes(ss, changes)
        ss.setup()
        for ch in record:  # the values must survive setup (no per-unit conversion of these)
            v = getattr(ss.models[ch["model"]], ch["param"]).v
            assert np.all(v == ch["value"]), (ch, v)
        ss.PFlow.run()
    if not ss.PFlow.converged:
        print(f"!! {case}: power flow did not converge, skipped")
        return None
    with warnings.catch_warnings():  # ill-conditioned eigenvectors in the participation factors
        warnings.simplefilter("ignore")
        if not ss.EIG.run():
            print(f"!! {case}: eigenvalue analysis failed, skipped")
            return None
    return ss, record


def pbh(A, C, eigs, tol, k=6):
    """PBH test per distinct eigenvalue: sigma_min([A - lam I; C]), nullity, dominant states."""
    n, res, seen = A.shape[0], [], []
    for lam in eigs:
        if any(abs(lam - m) <= 1e-6 * max(1.0, abs(lam)) for m in seen):
            continue
        seen.append(lam)
        _, s, vh = np.linalg.svd(np.vstack([A - lam * np.eye(n), C]))
        mult = int(np.sum(np.abs(eigs - lam) <= 1e-6 * max(1.0, abs(lam))))
        res.append((s[-1], lam, mult, int(np.sum(s <= tol)), np.argsort(-np.abs(vh[-1]))[:3]))
    res.sort(key=lambda t: t[0])
    return res[:k], sum(r[2] for r in res if r[0] <= tol)


def check(name, A, states, eigs, C):
    ev = np.linalg.eigvals(A)
    r, c = linear_sum_assignment(np.abs(ev[:, None] - eigs[None, :]))
    err = np.abs(ev[r] - eigs[c]).max()
    nA = np.linalg.norm(A, 2)
    print(f"\n== {name}: n={A.shape[0]}, generators={len(C['pmu'])}, ||A||_2={nA:.4g}, "
          f"||A||_F={np.linalg.norm(A):.4g}")
    print(f"   Re(eig) in [{eigs.real.min():.4g}, {eigs.real.max():.4g}], "
          f"|eig| max {np.abs(eigs).max():.4g}; Re>={ZERO_TOL:g}: {np.sum(eigs.real >= ZERO_TOL)} "
          f"{np.round(eigs[eigs.real >= ZERO_TOL], 8).tolist()}")
    ok = err <= 1e-8 * max(1.0, nA)
    print(f"   eigvals(A) vs ANDES eigs (matched): max |diff| = {err:.2e} "
          f"({'OK' if ok else 'MISMATCH'}, tol 1e-8*max(1,||A||_2))")
    zr, zc = np.sum(~A.any(axis=1)), np.sum(~A.any(axis=0))
    print(f"   all-zero rows of A: {zr} {[str(x) for x in states[~A.any(axis=1)]]}, all-zero columns: {zc}")
    tol = 1e-8 * nA
    for tag in ("pmu", "more"):
        Cs = np.vstack(C[tag])
        worst, n_unobs = pbh(A, Cs, eigs, tol)
        print(f"   PBH, all C_{tag} stacked ({Cs.shape[0]} rows): {n_unobs} eigenvalues (with multiplicity) "
              f"have sigma_min <= 1e-8*||A||_2 = {tol:.1e}; smallest sigma_min per distinct eigenvalue:")
        for s, lam, mult, null, top in worst:
            print(f"      {s:.2e}  lam={lam.real:+.5g}{lam.imag:+.5g}j  (x{mult}, null dim {null})  "
                  f"{', '.join(states[top])}")
    return ok


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--out", type=Path, default=Path(__file__).resolve().parent, help="output folder")
    ap.add_argument("--cases", nargs="*", metavar="CASE",
                    help=f"only these ANDES case paths (andes.get_case); no names: all of {CASES}")
    ap.add_argument("--variants", nargs="*", metavar="NAME", choices=list(VARIANTS),
                    help=f"only these variants; no names: all of {list(VARIANTS)}")
    args = ap.parse_args()
    if args.cases is None and args.variants is None:
        args.cases, args.variants = CASES, list(VARIANTS)
    cases = (args.cases or CASES) if args.cases is not None else []
    variants = (args.variants or list(VARIANTS)) if args.variants is not None else []
    jobs = [(Path(c).stem, c, None) for c in cases] + [(v, *VARIANTS[v]) for v in variants]
    andes.config_logger(stream_level=40)
    args.out.mkdir(parents=True, exist_ok=True)
    ok = True
    for name, case, changes in jobs:
        res = solve(case, changes)
        if res is None:
            ok = False
            continue
        ss, record = res
        if changes:
            A, states, eigs, gens, C, meta = build(ss, case, name, record)
        else:
            A, states, eigs, gens, C, meta = build(ss, case)
        path = args.out / (name + ".npz")
        np.savez_compressed(path, A=A, states=states, eigs=eigs, generators=gens,
                            meta=np.array(json.dumps(meta)), **C)
        with np.load(path, allow_pickle=False) as f:
            assert np.array_equal(f["A"], A) and json.loads(str(f["meta"]))["n"] == A.shape[0]
        print(f"wrote {path} ({path.stat().st_size} bytes); models {meta['models']}; "
              f"{len(meta['states_eliminated_by_andes'])} states eliminated by ANDES")
        Cg = {t: [C[f"C_{t}_{k + 1}"] for k in range(len(gens))] for t in ("pmu", "more")}
        ok &= check(name, A, states, eigs, Cg)
    return 0 if ok else 1


if __name__ == "__main__":
    raise SystemExit(main())
