"""Recorded measurements: a user's own ``y_i`` in place of the simulated plant (``--measurements FILE``).

Files (**contract**), one row per event time (discrete) or per step of ``run.dt`` (continuous):

NPZ
    ``t`` (T,) strictly increasing; ``y_<id>`` (T, s_i) for every agent id of the scenario (a single output
    may also be (T,)); optional ``x`` (T, n), the truth when the user has it; optional ``missing_<id>``
    (T,) bool: no measurement of agent ``id`` at that row (the agent then predicts only); optional ``u``
    (T, p): the known inputs at each row (a scenario with ``system.B``, ``p`` its columns).
CSV
    a header row ``t, y<id>.<row>, ..., x.<k>, ..., u.<k>, ...`` (``row`` and ``k`` 1-based, any column order),
    then one row of numbers per event time; an empty ``y`` cell means no measurement of that agent at that row
    (every cell of the agent's row empty). ``x`` columns are all present or all absent, and so are ``u``'s.

A file's ``u`` replaces the scenario's ``system.u`` (the signal); without ``u`` the scenario's signal applies.

Values must be finite (an empty CSV cell is not a value; NaN and infinities are refused), ``t`` strictly
increasing, at least two rows, every agent's ``y`` present with its ``s_i`` columns.  In continuous time the
rows must be ``run.dt`` apart (to 1e-6 relative): the sampled-data estimator steps by ``run.dt``.  The file
drives the run: ``T`` rows are ``T - 1`` steps (``--steps`` may take fewer).  Files larger than
:data:`MAX_FILE_BYTES` are refused before they are read.

Every error is one line naming the file and what is wrong (:class:`~splitspec_core.errors.ScenarioError`).
"""

from __future__ import annotations

import csv
import hashlib
import io
import math
import os
import zipfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import ScenarioError

__all__ = ["Measurements", "load_measurements", "write_measurements", "MAX_FILE_BYTES", "DT_RTOL"]

#: the largest measurements file read (bytes): 1 GiB
MAX_FILE_BYTES = 1 << 30
#: continuous time: how far the rows' spacing may be from run.dt (relative)
DT_RTOL = 1e-6


@dataclass(frozen=True)
class Measurements:
    """A measurements file, checked against a scenario.

    ``y`` (T, sum s_i) stacked in agent order (``C = [C_1; ...; C_m]``, as the plant's ``y``), 0.0 where
    missing; ``missing`` (T, m) bool; ``x`` (T, n) or None (no truth); ``sha256`` of the file's bytes;
    ``u`` (T, p) the known inputs or None (the scenario's ``system.u`` applies).
    """

    path: str
    t: np.ndarray
    y: np.ndarray
    missing: np.ndarray
    x: np.ndarray | None
    sha256: str
    u: np.ndarray | None = None

    @property
    def steps(self) -> int:
        """int: ``T - 1``, the steps the file drives."""
        return len(self.t) - 1

    @property
    def has_truth(self) -> bool:
        """bool: whether the file carries the truth ``x``."""
        return self.x is not None


def _fail(path, what: str) -> ScenarioError:
    return ScenarioError(f"measurements {path}: {what}")


def _read_bytes(path: Path) -> bytes:
    try:
        size = path.stat().st_size
    except OSError as exc:
        raise _fail(path, f"cannot read it ({exc.strerror})") from None
    if size > MAX_FILE_BYTES:
        raise _fail(path, f"is {size / 2**20:.0f} MiB; at most {MAX_FILE_BYTES >> 20} MiB are read")
    try:
        return path.read_bytes()
    except OSError as exc:
        raise _fail(path, f"cannot read it ({exc.strerror})") from None


def _npz_arrays(path: Path, data: bytes) -> dict:
    if not data.startswith(b"PK"):  # numpy would guess a pickle and say so
        raise _fail(path, "is not an NPZ file (a zip archive of .npy arrays, as numpy.savez writes)")
    try:
        with zipfile.ZipFile(io.BytesIO(data)) as z:  # compressed members: bound what they expand to before
            expanded = sum(i.file_size for i in z.infolist())  # anything is inflated (zipfile reads no more)
        if expanded > 4 * MAX_FILE_BYTES:
            raise _fail(path, f"expands to {expanded / 2**20:.0f} MiB; at most {4 * MAX_FILE_BYTES >> 20} MiB")
        with np.load(io.BytesIO(data), allow_pickle=False) as f:
            return {k: f[k] for k in f.files}
    except ScenarioError:
        raise
    except (ValueError, OSError, zipfile.BadZipFile, EOFError) as exc:
        raise _fail(path, f"is not a readable NPZ file ({str(exc).splitlines()[0] if str(exc) else type(exc).__name__})") \
            from None


def _numeric(path: Path, key: str, a: np.ndarray) -> np.ndarray:
    if a.dtype.kind not in "fiub":
        raise _fail(path, f"{key} holds {a.dtype} values, not numbers")
    a = np.asarray(a, dtype=float)
    bad = ~np.isfinite(a)
    if bad.any():
        idx = tuple(int(v) for v in np.argwhere(bad)[0])
        raise _fail(path, f"{key}{list(idx)} is {a[idx]}: values must be finite (mark a missing measurement "
                          "with missing_<id> in NPZ, an empty cell in CSV)")
    return a


def _check_inputs(path: Path, u: np.ndarray | None, p: int, T: int, what: str) -> None:
    if u is None:
        return
    if p == 0:
        raise _fail(path, f"has {what}, known inputs, and the scenario has no system.B (x+ = A x + B u)")
    if u.shape != (T, p):
        raise _fail(path, f"{what} has {u.shape[1] if u.ndim == 2 else u.shape} column(s); system.B has {p} "
                          f"(one per input): expected ({T}, {p})")


def _from_npz(path: Path, data: bytes, ids, sizes, n, p: int = 0) -> tuple:
    arrays = _npz_arrays(path, data)
    if "t" not in arrays:
        raise _fail(path, "has no array t (event times, shape (T,))")
    t = _numeric(path, "t", arrays["t"])
    if t.ndim != 1:
        raise _fail(path, f"t has shape {t.shape}; expected (T,)")
    T = len(t)
    known = {"t", "x", "u"} | {f"y_{i}" for i in ids} | {f"missing_{i}" for i in ids}
    extra = sorted(set(arrays) - known)
    if extra:
        raise _fail(path, f"has {extra[0]}, which names no agent of the scenario (agents {', '.join(map(str, ids))}; "
                          "arrays t, y_<id>, missing_<id>, x, u)")
    ys, miss = [], np.zeros((T, len(ids)), dtype=bool)
    for k, (i, s) in enumerate(zip(ids, sizes)):
        key = f"y_{i}"
        if key not in arrays:
            raise _fail(path, f"has no {key}: agent {i}'s measurements, shape ({T}, {s})")
        if f"missing_{i}" in arrays:
            m = arrays[f"missing_{i}"]
            if m.dtype != bool or m.shape != (T,):
                raise _fail(path, f"missing_{i} must be a bool array of shape ({T},), got {m.dtype} {m.shape}")
            miss[:, k] = m
        y = arrays[key]
        flat = y.ndim == 1 and s == 1
        if (y.shape[0], 1) != (T, s) if flat else y.shape != (T, s):
            raise _fail(path, f"{key} has shape {y.shape}; agent {i} has {s} output(s) and t has {T} rows: "
                              f"expected ({T}, {s})")
        if y.dtype.kind == "f":  # a row marked missing may hold anything (NaN, as a logger writes it)
            y = np.where(miss[:, k] if flat else miss[:, k:k + 1], 0.0, y)
        y = _numeric(path, key, y)
        ys.append(y[:, None] if flat else y)
    x = None
    if "x" in arrays:
        x = _numeric(path, "x", arrays["x"])
        if x.shape != (T, n):
            raise _fail(path, f"x has shape {x.shape}; expected ({T}, {n}) (the truth, n = {n} states)")
    u = None
    if "u" in arrays:
        u = _numeric(path, "u", arrays["u"])
        if u.ndim == 1 and p == 1:
            u = u[:, None]
        _check_inputs(path, u, p, T, "u")
    return t, np.hstack(ys) if ys else np.zeros((T, 0)), miss, x, u


def _from_csv(path: Path, data: bytes, ids, sizes, n, p: int = 0) -> tuple:
    try:
        text = data.decode("utf-8-sig")
    except UnicodeDecodeError:
        raise _fail(path, "is not UTF-8 text (a CSV file, or an .npz)") from None
    rows = list(csv.reader(io.StringIO(text)))
    rows = [r for r in rows if any(c.strip() for c in r)]
    if not rows:
        raise _fail(path, "is empty: expected a header row t, y<id>.<row>, ..., x.<k>, ...")
    header = [c.strip() for c in rows[0]]
    col: dict = {}
    for c, name in enumerate(header):
        if name in col:
            raise _fail(path, f"header names column {name!r} twice")
        col[name] = c
    if "t" not in col:
        raise _fail(path, "header has no column t")
    wanted = {f"y{i}.{r + 1}" for i, s in zip(ids, sizes) for r in range(s)}
    xcols = {f"x.{k + 1}" for k in range(n)}
    ucols = [h for h in header if h.startswith("u.")]
    unknown = [h for h in header if h != "t" and h not in wanted and h not in xcols and h not in ucols]
    if unknown:
        raise _fail(path, f"header column {unknown[0]!r} is not t, y<id>.<row> (agents {', '.join(map(str, ids))}, "
                          f"rows from 1), x.<k> (k = 1..{n}) or u.<k> (known inputs)")
    if ucols:
        if p == 0:
            raise _fail(path, f"has column {ucols[0]}, a known input, and the scenario has no system.B "
                              "(x+ = A x + B u)")
        expected = [f"u.{k + 1}" for k in range(p)]
        if set(ucols) != set(expected):
            extra = sorted(set(ucols) - set(expected)) or sorted(set(expected) - set(ucols))
            raise _fail(path, f"has u columns {', '.join(sorted(ucols))}; system.B has {p} column(s): expected "
                              f"{', '.join(expected)} (not {extra[0]})")
    for i, s in zip(ids, sizes):
        for r in range(s):
            if f"y{i}.{r + 1}" not in col:
                raise _fail(path, f"header has no column y{i}.{r + 1} (agent {i} has {s} output(s))")
    has_x = any(h in col for h in xcols)
    if has_x and not xcols <= set(col):
        missing = sorted(xcols - set(col), key=lambda h: int(h[2:]))[0]
        raise _fail(path, f"header has some x columns but not {missing}: give all {n} or none")
    body = rows[1:]
    T = len(body)
    t = np.zeros(T)
    y = np.zeros((T, sum(sizes)))
    miss = np.zeros((T, len(ids)), dtype=bool)
    x = np.zeros((T, n)) if has_x else None
    u = np.zeros((T, p)) if ucols else None
    offsets = np.cumsum([0] + list(sizes))

    def number(line: int, name: str, cell: str) -> float:
        try:
            v = float(cell)
        except ValueError:
            raise _fail(path, f"line {line}, column {name}: {cell!r} is not a number") from None
        if not math.isfinite(v):
            raise _fail(path, f"line {line}, column {name}: {cell.strip()} is not finite (leave the agent's cells "
                              "empty for a missing measurement)")
        return v

    for r, row in enumerate(body):
        line = r + 2
        if len(row) != len(header):
            raise _fail(path, f"line {line} has {len(row)} cells; the header has {len(header)}")
        t[r] = number(line, "t", row[col["t"]])
        for k, (i, s) in enumerate(zip(ids, sizes)):
            cells = [row[col[f"y{i}.{q + 1}"]].strip() for q in range(s)]
            if all(c == "" for c in cells):
                miss[r, k] = True
                continue
            for q, c in enumerate(cells):
                name = f"y{i}.{q + 1}"
                if c == "":
                    raise _fail(path, f"line {line}, column {name} is empty but agent {i}'s other outputs are not: "
                                      "leave all of them empty for a missing measurement")
                y[r, offsets[k] + q] = number(line, name, c)
        if x is not None:
            for q in range(n):
                x[r, q] = number(line, f"x.{q + 1}", row[col[f"x.{q + 1}"]])
        if u is not None:
            for q in range(p):
                u[r, q] = number(line, f"u.{q + 1}", row[col[f"u.{q + 1}"]])
    return t, y, miss, x, u


def load_measurements(path, sc, *, steps: int | None = None) -> Measurements:
    """Read and check a measurements file against scenario ``sc`` (module docstring); one-line errors.

    Parameters
    ----------
    path : str or path-like
        An ``.npz`` or ``.csv`` file.
    sc : Scenario
        The scenario (agent ids, ``s_i``, ``n``, ``system.B``'s columns, time and ``run.dt``).
    steps : int, optional
        Use only the first ``steps + 1`` rows (at most the file's).

    Returns
    -------
    Measurements

    Raises
    ------
    ScenarioError
        One line naming the file: another suffix, too large, unreadable, a missing or unknown array or column, a
        wrong shape, a value that is not a finite number, fewer than 2 rows, ``t`` not strictly increasing, rows
        not ``run.dt`` apart (continuous time), ``steps`` beyond the file.

    Examples
    --------
    >>> import os, tempfile
    >>> import numpy as np
    >>> from splitspec_core.scenarios.load import load_scenario
    >>> sc = load_scenario("examples/paper_discrete.yaml")  # agents 1, 2, 3 with one output each
    >>> path = os.path.join(tempfile.mkdtemp(), "y.csv")
    >>> gap = np.array([[0, 0, 0], [0, 1, 0], [0, 0, 0]], dtype=bool)
    >>> write_measurements(path, t=np.arange(3.0), y=np.arange(9.0).reshape(3, 3), agent_ids=sc.agent_ids,
    ...                    sizes=[1, 1, 1], missing=gap)
    >>> print(open(path).read().strip())
    t,y1.1,y2.1,y3.1
    0.0,0.0,1.0,2.0
    1.0,3.0,,5.0
    2.0,6.0,7.0,8.0
    >>> m = load_measurements(path, sc)
    >>> m.steps, m.has_truth, m.missing[1].tolist(), m.y[1].tolist()
    (2, False, [False, True, False], [3.0, 0.0, 5.0])
    >>> import shutil; shutil.rmtree(os.path.dirname(path))
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in (".npz", ".csv"):
        raise _fail(path, "must be an .npz or a .csv file")
    data = _read_bytes(path)
    ids = list(sc.agent_ids)
    sizes = [int(np.shape(C)[0]) for C in sc.system.Cs]
    reader = _from_npz if suffix == ".npz" else _from_csv
    t, y, miss, x, u = reader(path, data, ids, sizes, sc.n, sc.system.inputs)
    T = len(t)
    if T < 2:
        raise _fail(path, f"has {T} row(s); at least 2 event times are needed")
    dt = np.diff(t)
    if np.any(dt <= 0):
        k = int(np.argmax(dt <= 0))
        raise _fail(path, f"t is not strictly increasing: row {k + 2} has t = {t[k + 1]:g} after {t[k]:g}")
    if sc.time == "continuous":
        bad = np.abs(dt - sc.run.dt) > DT_RTOL * sc.run.dt
        if bad.any():
            k = int(np.argmax(bad))
            raise _fail(path, f"rows {k + 1} and {k + 2} are {dt[k]:g} {sc.system.time_unit} apart; run.dt is "
                              f"{sc.run.dt:g}: the sampled-data estimator steps by run.dt (resample the log, or set "
                              "run.dt)")
    if steps is not None:
        if steps > T - 1:
            raise _fail(path, f"has {T} rows ({T - 1} steps); --steps {steps} asks for more")
        t, y, miss = t[:steps + 1], y[:steps + 1], miss[:steps + 1]
        x = None if x is None else x[:steps + 1]
        u = None if u is None else u[:steps + 1]
    return Measurements(str(path), t, y, miss, x, hashlib.sha256(data).hexdigest(), u)


def write_measurements(path, *, t: np.ndarray, y: np.ndarray, agent_ids, sizes, x: np.ndarray | None = None,
                       missing: np.ndarray | None = None, u: np.ndarray | None = None) -> None:
    """Write a measurements file (``.npz`` or ``.csv`` by suffix) that :func:`load_measurements` reads back exactly.

    CSV numbers are written with 17 significant digits (``repr``), which read back to the same float64.  The file
    is written to a temporary name beside it, then renamed.

    Parameters
    ----------
    path : str or path-like
        The ``.npz`` or ``.csv`` file (replaced).
    t : (T,) array
        Event times (or seconds).
    y : (T, sum s_i) array
        The measurements stacked in agent order.
    agent_ids : sequence of int
        The agents, in order.
    sizes : sequence of int
        Their ``s_i``.
    x : (T, n) array, optional
        The truth.
    missing : (T, m) bool array, optional
        No measurement of that agent at that row (CSV: empty cells; NPZ: ``missing_<id>`` when any).
    u : (T, p) array, optional
        The known inputs.

    Raises
    ------
    ScenarioError
        If the suffix is neither ``.npz`` nor ``.csv``.
    """
    path = Path(path)
    offsets = np.cumsum([0] + list(sizes))
    T = len(t)
    miss = np.zeros((T, len(agent_ids)), dtype=bool) if missing is None else np.asarray(missing, dtype=bool)
    if path.suffix.lower() == ".npz":
        arrays = {"t": np.asarray(t, dtype=float)}
        for k, i in enumerate(agent_ids):
            arrays[f"y_{i}"] = np.asarray(y[:, offsets[k]:offsets[k + 1]], dtype=float)
            if miss[:, k].any():
                arrays[f"missing_{i}"] = miss[:, k].copy()
        if x is not None:
            arrays["x"] = np.asarray(x, dtype=float)
        if u is not None:
            arrays["u"] = np.asarray(u, dtype=float)
        tmp = path.with_name(f".{path.name}.tmp")
        with open(tmp, "wb") as f:
            np.savez(f, **arrays)
        os.replace(tmp, path)
        return
    if path.suffix.lower() != ".csv":
        raise ScenarioError(f"measurements {path}: must be an .npz or a .csv file")
    header = ["t"] + [f"y{i}.{r + 1}" for i, s in zip(agent_ids, sizes) for r in range(s)]
    if x is not None:
        header += [f"x.{k + 1}" for k in range(np.shape(x)[1])]
    if u is not None:
        header += [f"u.{k + 1}" for k in range(np.shape(u)[1])]
    out = io.StringIO()
    w = csv.writer(out, lineterminator="\n")
    w.writerow(header)
    for r in range(T):
        cells = [repr(float(t[r]))]
        for k, s in enumerate(sizes):
            cells += ["" if miss[r, k] else repr(float(v)) for v in y[r, offsets[k]:offsets[k + 1]]]
        if x is not None:
            cells += [repr(float(v)) for v in x[r]]
        if u is not None:
            cells += [repr(float(v)) for v in u[r]]
        w.writerow(cells)
    tmp = path.with_name(f".{path.name}.tmp")
    tmp.write_text(out.getvalue(), encoding="utf-8")
    os.replace(tmp, path)
