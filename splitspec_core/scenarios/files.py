"""Models kept in files: ``system.file`` (a ``.npz`` or a MATLAB ``.mat``) and the arrays it names.

A scenario may keep its matrices in a file beside it instead of as YAML literals (a 160-state ``A`` is a
160 x 160 literal)::

    system:
      file: kundur.npz          # relative to the scenario file's folder (ss.scenario: the working directory)
      A: A                      # a string where a matrix goes names an array of the file
      C: {1: C_G1, 2: C_G2}
      B: B
      states: state_names       # an array of strings (npz), a char matrix or a cell array (mat)
      process_noise: Q          # a number (one value), a vector (1 x n, n x 1 or flat) or an n x n matrix
      measurement_noise: {1: r1, 2: 0.1}   # per agent: an array (one value, or one per output) or a number

:func:`resolve_model_file` replaces each such name by the array, as a nested list, before the scenario's own
checks run, so an array of the wrong shape gets the same one-line message as a literal of the wrong shape (and
a missing file, a missing array, a MATLAB v7.3 file get their own line naming the key).  The processes of a
run receive the scenario with the arrays written in
(:func:`splitspec_core.scenarios.load.resolved_scenario_text`), so an agent on another
machine needs no copy of the file, and ``scenario.yaml`` in a run's records is self-contained.

The file is read with ``numpy.load(allow_pickle=False)`` (``.npz``) or ``scipy.io.loadmat`` (``.mat``, v4 to
v7); nothing in it is executed.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Mapping

import numpy as np

from ..errors import ScenarioError

__all__ = ["read_model_file", "resolve_model_file"]

#: a MATLAB v7.3 file is HDF5: its 128-byte header starts with this text
_V73 = b"MATLAB 7.3 MAT-file"


def read_model_file(path: Path, key: str = "system.file") -> dict:
    """The arrays of a ``.npz`` or ``.mat`` file by name (``.mat``: MATLAB's own ``__header__`` etc. left out).

    Parameters
    ----------
    path : Path
        The file.
    key : str, default "system.file"
        The key named in messages.

    Returns
    -------
    dict of str to numpy.ndarray

    Raises
    ------
    ScenarioError
        One line naming ``key`` and the file: missing, not a file, another suffix, unreadable, a v7.3 ``.mat``,
        an ``.npz`` holding object arrays.
    """
    if not path.exists():
        raise ScenarioError(f"{key}: {path} does not exist")
    if not path.is_file():
        raise ScenarioError(f"{key}: {path} is not a regular file")
    suffix = path.suffix.lower()
    if suffix not in (".npz", ".mat"):
        raise ScenarioError(f"{key}: {path} is neither .npz nor .mat (numpy.savez or scipy.io.savemat / MATLAB save)")
    try:
        with open(path, "rb") as f:
            head = f.read(128)
    except OSError as exc:
        raise ScenarioError(f"{key}: cannot read {path}: {exc.strerror or exc}") from None
    if suffix == ".npz":
        if not head.startswith(b"PK"):  # numpy would take it for a pickle and say so
            raise ScenarioError(f"{key}: {path} is not an .npz file (a zip archive of .npy arrays, as numpy.savez "
                                "writes)")
        try:
            with np.load(path, allow_pickle=False) as z:
                return {name: z[name] for name in z.files}
        except ValueError as exc:  # an object array (it would need pickle)
            raise ScenarioError(f"{key}: {path} holds an array of Python objects ({exc}); save plain numeric "
                                "or string arrays (numpy.savez)") from None
        except Exception as exc:  # noqa: BLE001 - a damaged archive (BadZipFile, EOFError, OSError...): one line
            raise ScenarioError(f"{key}: cannot read {path} as .npz: {type(exc).__name__}: {exc}") from None
    if suffix == ".mat":
        if head.startswith(_V73):
            raise ScenarioError(f"{key}: {path} is a MATLAB v7.3 (HDF5) file, which splitspec does not read: save "
                                "it as v7 (MATLAB: save(file, ..., '-v7'); Python: scipy.io.savemat)")
        import scipy.io  # here only: most scenarios have no file

        try:
            data = scipy.io.loadmat(str(path))
        except Exception as exc:  # noqa: BLE001 - MatReadError, ValueError, ...: not a .mat it can read, one line
            raise ScenarioError(f"{key}: cannot read {path} as a .mat file: {type(exc).__name__}: {exc}") from None
        return {k: v for k, v in data.items() if not k.startswith("__")}
    raise AssertionError(suffix)  # unreachable: the suffix was checked above


def _names_of(a: np.ndarray) -> list:
    """Names from an array of strings (npz), a char matrix (one name per row, blank-padded) or a cell array."""
    if a.dtype.kind == "U":
        return [str(s).strip() for s in a.reshape(-1)]
    if a.dtype.kind == "O":  # a MATLAB cell array: each cell an array holding one string
        return [str(np.asarray(c).reshape(-1)[0]).strip() if np.asarray(c).size else "" for c in a.reshape(-1)]
    return a.tolist()  # not strings: the names' check says so


def _value(arrays: dict, name: str, key: str, source: str, *, names: bool = False, vector: bool = False,
           noise: bool = False) -> Any:
    if name not in arrays:
        have = ", ".join(sorted(arrays)[:12]) + (" ..." if len(arrays) > 12 else "")
        raise ScenarioError(f"{key} names array {name!r}, which {source} does not hold (it has: {have or 'nothing'})")
    a = np.asarray(arrays[name])
    if names:
        return _names_of(a)
    if a.dtype.kind not in "biuf":
        raise ScenarioError(f"{key}: array {name!r} of {source} is not numeric (dtype {a.dtype})")
    if noise:  # a number, a vector or a matrix: a single value (MATLAB's 1 x 1) is a number, a 1 x k or k x 1 a vector
        if a.size == 1:
            return float(a.reshape(-1)[0])
        vector = a.ndim == 1 or (a.ndim == 2 and 1 in a.shape)
    if vector:
        if a.ndim == 2 and 1 in a.shape:  # MATLAB keeps every vector as a matrix
            a = a.reshape(-1)
        return a.astype(float).tolist()
    if a.ndim == 1:  # one output row, or a 1 x 1 model's A
        a = a.reshape(1, -1)
    if a.ndim != 2:
        raise ScenarioError(f"{key}: array {name!r} of {source} has {a.ndim} dimensions {a.shape}, expected a matrix")
    return a.astype(float).tolist()


def resolve_model_file(data: Any, base: Path | None) -> Any:
    """``data`` (a scenario's mapping) with ``system.file``'s named arrays written in and ``system.file`` gone.

    A mapping without ``system.file`` is returned as it is.  Anything not a string is left for the scenario's
    checks.  ``A``, ``B``, ``C`` and ``outputs`` (per agent), ``x0``, ``states``, ``process_noise`` and
    ``measurement_noise`` (whole or per agent) may name arrays.

    Parameters
    ----------
    data : object
        A scenario's mapping (the YAML data model).
    base : Path or None
        The folder a relative ``system.file`` is taken from (None: the working directory).

    Returns
    -------
    object
        ``data`` itself, or a new mapping with a new ``system`` (``data`` is not changed); arrays as nested lists.

    Raises
    ------
    ScenarioError
        ``system.file`` not a path, as :func:`read_model_file`, a name the file does not hold, an array that is
        not numeric or not a matrix, ``C`` or ``outputs`` given as one name.

    Examples
    --------
    >>> import tempfile
    >>> from pathlib import Path
    >>> import numpy as np
    >>> folder = Path(tempfile.mkdtemp())
    >>> np.savez(folder / "model.npz", A=np.eye(2), C1=np.array([1.0, 0.0]))
    >>> resolve_model_file({"system": {"file": "model.npz", "A": "A", "C": {1: "C1"}}}, folder)
    {'system': {'A': [[1.0, 0.0], [0.0, 1.0]], 'C': {1: [[1.0, 0.0]]}}}
    >>> import shutil; shutil.rmtree(folder)
    """
    if not isinstance(data, Mapping) or not isinstance(data.get("system"), Mapping) or "file" not in data["system"]:
        return data
    system = dict(data["system"])
    raw = system.pop("file")
    if not isinstance(raw, str) or not raw.strip():
        raise ScenarioError(f"system.file must be the path of a .npz or .mat file, got {raw!r}")
    path = Path(raw).expanduser()
    if not path.is_absolute() and base is not None:
        path = base / path
    arrays = read_model_file(path)
    source = f"system.file {raw}"
    for key in ("A", "B"):
        if isinstance(system.get(key), str):
            system[key] = _value(arrays, system[key], f"system.{key}", source)
    if isinstance(system.get("x0"), str):
        system["x0"] = _value(arrays, system["x0"], "system.x0", source, vector=True)
    if isinstance(system.get("states"), str):
        system["states"] = _value(arrays, system["states"], "system.states", source, names=True)
    if isinstance(system.get("process_noise"), str):
        system["process_noise"] = _value(arrays, system["process_noise"], "system.process_noise", source, noise=True)
    noise = system.get("measurement_noise")
    if isinstance(noise, str):
        system["measurement_noise"] = _value(arrays, noise, "system.measurement_noise", source, noise=True)
    elif isinstance(noise, Mapping):
        system["measurement_noise"] = {aid: (_value(arrays, v, f"system.measurement_noise.{aid}", source, noise=True)
                                             if isinstance(v, str) else v) for aid, v in noise.items()}
    for key, names in (("C", False), ("outputs", True)):
        part = system.get(key)
        if isinstance(part, Mapping):
            system[key] = {aid: (_value(arrays, v, f"system.{key}.{aid}", source, names=names)
                                 if isinstance(v, str) else v) for aid, v in part.items()}
        elif isinstance(part, str):
            raise ScenarioError(f"system.{key} must map agent ids to arrays of {source} (e.g. {key}: {{1: "
                                f"{part}}}), got the single name {part!r}")
    out = dict(data)
    out["system"] = system
    return out
