"""The noise of a system: ``system.process_noise`` and ``system.measurement_noise``, checked, and what they mean.

What a scenario may give (``docs/how-to/scenario.md``):

``process_noise`` (``v`` in ``x+ = A x + v``, or ``x' = A x + v`` in continuous time)
    a number: discrete, the std ``sigma`` of every state's ``v`` (covariance per step ``sigma^2 I``); continuous,
    the intensity ``q`` of white noise (``E[v(t) v(s)'] = q I delta(t - s)``).  A list of ``n`` numbers: the same
    per state (discrete: stds, covariance ``diag(v^2)``; continuous: intensities, intensity matrix ``diag(v)``).
    An ``n x n`` matrix: the covariance per step (discrete) or the intensity matrix (continuous), symmetric
    positive semidefinite.
``measurement_noise`` (``w_i`` in ``y_i = C_i x + w_i``)
    a number: the std of every output's noise sample; a mapping ``{agent id: std or [one std per output]}`` that
    lists every agent: that agent's std for each of its outputs, or one per output (``s_i`` of them).

The scenario keeps what was given (:class:`~splitspec_core.scenarios.specs.System` ``process_noise``,
``measurement_noise``: a float, a read-only array, a dict in agent order) for text and JSON
(:func:`noise_text`, :func:`noise_json`); every computation uses the derived matrices of this module, through
the ``System``'s accessors (``process_covariance``, ``measurement_std``, ``measurement_covariance``, ...).
A scalar stays a scalar all the way to the plant, so its trajectories are those of the scalar-only code, bit for
bit.  Checks raise one line naming the key (``system.measurement_noise.2 has 3 entries, agent 2 has 2 outputs``).
"""

from __future__ import annotations

import math
import numbers
from typing import Any, Mapping, Sequence

import numpy as np

from ..errors import DimensionError, ScenarioError
from .checks import check_agent_id, check_number, describe, ids_text

__all__ = ["parse_process_noise", "parse_measurement_noise", "process_covariance", "measurement_std",
           "process_level", "measurement_level", "noise_text", "noise_json", "PSD_TOLERANCE"]

#: a process-noise matrix is positive semidefinite when its smallest eigenvalue is >= -PSD_TOLERANCE times its
#: largest magnitude (round-off of a matrix written with a dozen digits, never a real negative direction)
PSD_TOLERANCE = 1e-10
#: a process-noise matrix is symmetric when ``|M - M'| <= SYMMETRY_TOLERANCE max|M|`` entry by entry
SYMMETRY_TOLERANCE = 1e-12


def _not_a_name(value: Any, key: str) -> None:
    """A string where a number or a matrix goes names an array of ``system.file``, which resolves it first."""
    if isinstance(value, str):
        name = repr(value) if len(repr(value)) <= 40 else repr(value)[:37] + "..."
        raise ScenarioError(f"{key} is the name {name}, and system.file is not given (or does not "
                            "resolve it): name a .npz or .mat file there to take arrays from, or write the numbers")


def _std(value: Any, key: str) -> float:
    v = check_number(value, key)
    if v < 0:
        raise ScenarioError(f"{key} must be >= 0, got {v:g}")
    return v


def _frozen(a: np.ndarray) -> np.ndarray:
    a = np.array(a, dtype=float)
    a.setflags(write=False)
    return a


def parse_process_noise(value: Any, n: int, key: str = "system.process_noise") -> float | np.ndarray:
    """``system.process_noise`` as given: a float >= 0, a read-only (n,) array of entries >= 0 or a read-only
    (n, n) symmetric positive semidefinite array.

    Parameters
    ----------
    value : number, list or array
        The YAML data model (numbers, lists); an array is taken as its list.
    n : int
        Number of states.
    key : str, default "system.process_noise"
        The key named in messages.

    Returns
    -------
    float or read-only array
        The value as given, checked (a matrix as written, not symmetrised).

    Raises
    ------
    ScenarioError
        One line naming ``key``: not a number, a list or a matrix; a wrong size (:class:`DimensionError`); a
        negative or non-finite entry; a matrix that is not symmetric or not positive semidefinite (with its smallest
        eigenvalue).

    Examples
    --------
    >>> parse_process_noise(0.1, 2)
    0.1
    >>> parse_process_noise([0.1, 0.2], 2)
    array([0.1, 0.2])
    >>> parse_process_noise([[1, 2], [2, 1]], 2)  # doctest: +ELLIPSIS
    Traceback (most recent call last):
        ...
    splitspec_core.errors.ScenarioError: system.process_noise is not symmetric positive semidefinite (smallest ...
    """
    if isinstance(value, np.ndarray):
        value = value.tolist()
    _not_a_name(value, key)
    if not isinstance(value, list):
        if isinstance(value, bool) or not isinstance(value, numbers.Real):
            raise ScenarioError(f"{key} must be a number, a list of {n} (one per state) or a {n}x{n} matrix, "
                                f"got {describe(value)}")
        return _std(value, key)
    if not value:
        raise ScenarioError(f"{key} is an empty list: give a number, {n} numbers (one per state) or a {n}x{n} matrix")
    if all(not isinstance(v, list) for v in value):  # a vector: one per state
        if len(value) != n:
            raise DimensionError(f"{key} has {len(value)} entries, system.A is {n}x{n} (one per state)")
        return _frozen([_std(v, f"{key}[{k + 1}]") for k, v in enumerate(value)])
    if len(value) != n or any(not isinstance(r, list) or len(r) != n for r in value):
        rows = [len(r) if isinstance(r, list) else 1 for r in value]
        widths = ", ".join(map(str, rows))
        shape = f"{len(value)}x{rows[0]}" if len(set(rows)) == 1 else f"{len(value)} rows of {widths}"
        raise DimensionError(f"{key} is {shape}, system.A is {n}x{n} (a matrix must be {n}x{n})")
    M = np.array([[check_number(x, f"{key}[{r + 1}][{c + 1}]") for c, x in enumerate(row)]
                  for r, row in enumerate(value)], dtype=float)
    scale = float(np.max(np.abs(M)))
    asym = np.abs(M - M.T)
    if float(asym.max()) > SYMMETRY_TOLERANCE * scale:
        r, c = np.unravel_index(int(np.argmax(asym)), asym.shape)
        raise ScenarioError(f"{key} is not symmetric: [{r + 1}][{c + 1}] is {M[r, c]:g}, [{c + 1}][{r + 1}] is "
                            f"{M[c, r]:g} (a covariance or intensity matrix is symmetric positive semidefinite)")
    smallest = float(np.linalg.eigvalsh(0.5 * (M + M.T))[0])
    if smallest < -PSD_TOLERANCE * scale:
        raise ScenarioError(f"{key} is not symmetric positive semidefinite (smallest eigenvalue {smallest:.3g})")
    return _frozen(M)


def parse_measurement_noise(value: Any, outputs: Mapping[int, int],
                            key: str = "system.measurement_noise") -> float | dict:
    """``system.measurement_noise`` as given: a float >= 0, or ``{agent id: float or tuple of s_i floats}`` in
    the order of ``outputs``, every agent listed.

    Parameters
    ----------
    value : number or mapping
        The YAML data model.
    outputs : mapping of int to int
        ``{agent id: s_i}``, in agent order.
    key : str, default "system.measurement_noise"
        The key named in messages.

    Returns
    -------
    float or dict

    Raises
    ------
    ScenarioError
        One line naming the key: not a number or a mapping; an agent not in ``outputs``, listed twice or
        missing; a list of the wrong length (``system.measurement_noise.2 has 3 entries, agent 2 has 2 outputs``);
        a negative or non-finite std (``system.measurement_noise.2[1] must be >= 0, got -1``).

    Examples
    --------
    >>> parse_measurement_noise({2: [0.1, 0.2], 1: 0.5}, {1: 1, 2: 2})
    {1: 0.5, 2: (0.1, 0.2)}
    """
    if isinstance(value, np.ndarray) and value.ndim == 0:
        value = value.item()
    _not_a_name(value, key)
    if not isinstance(value, Mapping):
        if isinstance(value, bool) or not isinstance(value, numbers.Real):
            raise ScenarioError(f"{key} must be a number or a mapping {{agent id: std or [one std per output]}}, "
                                f"got {describe(value)}")
        return _std(value, key)
    ids = tuple(outputs)
    given: dict = {}
    for k, v in value.items():
        aid = check_agent_id(k, key)
        if aid not in outputs:
            raise ScenarioError(f"{key} names agent {aid}, which is not in system.C (agents: {ids_text(ids)})")
        if aid in given:
            raise ScenarioError(f"{key}.{aid} is given twice")
        where = f"{key}.{aid}"
        if isinstance(v, np.ndarray):
            v = v.tolist()
        _not_a_name(v, where)
        if isinstance(v, (list, tuple)):
            if len(v) != outputs[aid]:
                what = "output" if outputs[aid] == 1 else "outputs"
                raise DimensionError(f"{where} has {len(v)} entries, agent {aid} has {outputs[aid]} {what}")
            given[aid] = tuple(_std(x, f"{where}[{c + 1}]") for c, x in enumerate(v))
        elif isinstance(v, bool) or not isinstance(v, numbers.Real):
            raise ScenarioError(f"{where} must be a number or a list of {outputs[aid]} (one std per output), got "
                                f"{describe(v)}")
        else:
            given[aid] = _std(v, where)
    missing = [a for a in ids if a not in given]
    if missing:
        lists = ids_text(tuple(sorted(given))) or "none"
        raise ScenarioError(f"{key} has no entry for agent {missing[0]} (it lists {lists}): give every agent's std")
    return {a: given[a] for a in ids}


def process_covariance(value: float | np.ndarray, n: int, time: str) -> np.ndarray:
    """The covariance per step of ``v`` (discrete) or its intensity matrix (continuous) of ``process_noise``
    ``value`` (the module docstring).

    Parameters
    ----------
    value : float or array
        What :func:`parse_process_noise` returned.
    n : int
        Number of states.
    time : {"continuous", "discrete"}
        The scenario's time.

    Returns
    -------
    (n, n) float array
        Discrete: ``sigma^2 I``, ``diag(v^2)`` or the matrix; continuous: ``q I``, ``diag(v)`` or the matrix
        (a matrix symmetrised).

    Examples
    --------
    >>> process_covariance([0.1, 0.2], 2, "discrete").round(6).tolist()
    [[0.01, 0.0], [0.0, 0.04]]
    """
    if np.ndim(value) == 0:
        v = float(value)
        return (v ** 2 if time == "discrete" else v) * np.eye(n)
    a = np.asarray(value, dtype=float)
    if a.ndim == 1:
        return np.diag(a ** 2 if time == "discrete" else a)
    return 0.5 * (a + a.T)


def measurement_std(value: float | Mapping, sizes: Sequence[int]) -> np.ndarray:
    """Every output's noise std, stacked in agent order.

    Parameters
    ----------
    value : float or mapping
        What :func:`parse_measurement_noise` returned.
    sizes : sequence of int
        The ``s_i``, in agent order.

    Returns
    -------
    (p,) float array
        ``p = sum s_i``.
    """
    if not isinstance(value, Mapping):
        return np.full(int(sum(sizes)), float(value))
    parts = [np.full(s, float(v)) if np.ndim(v) == 0 else np.asarray(v, dtype=float)
             for s, v in zip(sizes, value.values())]
    return np.concatenate(parts) if parts else np.zeros(0)


def _common(values: np.ndarray) -> float | None:
    """The one value of ``values`` when they are all equal (None otherwise)."""
    return float(values[0]) if values.size and bool(np.all(values == values[0])) else None


def process_level(value: float | np.ndarray, n: int, time: str) -> float:
    """One number standing for the process noise, in the units of a scalar ``process_noise`` (a scalar is itself):
    for a vector or a matrix, discrete the root mean variance (``sqrt`` of the covariance's mean diagonal; a vector
    of equal stds, that std), continuous the mean intensity (the intensity matrix's mean diagonal); equal diagonal
    entries give their common value exactly.  What the Riccati weights and the noise tuning, which take one
    number, use (as ``level ** 2``, the scalar's ``process_noise ** 2``).

    Parameters
    ----------
    value : float or array
        What :func:`parse_process_noise` returned.
    n : int
        Number of states (not read).
    time : {"continuous", "discrete"}
        The scenario's time.

    Returns
    -------
    float
    """
    if np.ndim(value) == 0:
        return float(value)
    a = np.asarray(value, dtype=float)
    if a.ndim == 1 and time == "discrete":  # stds
        c = _common(a)
        return c if c is not None else math.sqrt(float(np.mean(a ** 2)))
    d = a if a.ndim == 1 else np.diag(a)  # intensities, or a covariance / intensity matrix's diagonal
    c = _common(d)
    mean = c if c is not None else float(np.mean(d))
    return math.sqrt(mean) if time == "discrete" else mean


def measurement_level(value: float | Mapping, sizes: Sequence[int]) -> float:
    """One number standing for the measurement noise: the std itself, or the root mean square of every output's
    std (their common value exactly when they are all equal).

    Parameters
    ----------
    value : float or mapping
        What :func:`parse_measurement_noise` returned.
    sizes : sequence of int
        The ``s_i``, in agent order.

    Returns
    -------
    float
    """
    if not isinstance(value, Mapping):
        return float(value)
    s = measurement_std(value, sizes)
    c = _common(s)
    return c if c is not None else float(np.sqrt(np.mean(s ** 2)))


def noise_json(value: float | np.ndarray | Mapping) -> Any:
    """The JSON form of a noise value as given: a number, a list (of lists), ``{"agent id": number or list}``.

    Parameters
    ----------
    value : float, array or mapping
        A parsed noise value.

    Returns
    -------
    float, list or dict
    """
    if isinstance(value, Mapping):
        return {str(a): (float(v) if np.ndim(v) == 0 else [float(x) for x in v]) for a, v in value.items()}
    if np.ndim(value) == 0:
        return float(value)
    return np.asarray(value, dtype=float).tolist()


#: the most numbers a noise text writes out in full (beyond: a summary)
TEXT_ENTRIES = 12


def noise_text(value: float | np.ndarray | Mapping) -> str:
    """A noise value as given, for one line of text: ``0.05``, ``[0.1, 0.2]``, ``{1: 0.1, 2: [0.1, 0.2]}``; a
    long one summarised (``per state: 160 values, 0.001 to 0.01``, ``a 160x160 matrix, diagonal 0.001 to 0.01``,
    ``per agent: 100 agents, 0.01 to 0.1``).

    Parameters
    ----------
    value : float, array or mapping
        A parsed noise value.

    Returns
    -------
    str

    Examples
    --------
    >>> noise_text({1: 0.1, 2: (0.1, 0.2)})
    '{1: 0.1, 2: [0.1, 0.2]}'
    """
    if isinstance(value, Mapping):
        if sum(1 if np.ndim(v) == 0 else len(v) for v in value.values()) <= TEXT_ENTRIES:
            return "{" + ", ".join(f"{a}: {noise_text(v if np.ndim(v) == 0 else np.asarray(v))}"
                                   for a, v in value.items()) + "}"
        flat = np.concatenate([np.ravel(np.asarray(v, dtype=float)) for v in value.values()])
        return f"per agent: {len(value)} agents, {flat.min():g} to {flat.max():g}"
    if np.ndim(value) == 0:
        return f"{float(value):g}"
    a = np.asarray(value, dtype=float)
    if a.size <= TEXT_ENTRIES:
        rows = a if a.ndim == 2 else [a]
        text = ", ".join("[" + ", ".join(f"{x:g}" for x in r) + "]" for r in rows)
        return f"[{text}]" if a.ndim == 2 else text
    if a.ndim == 1:
        return f"per state: {a.size} values, {a.min():g} to {a.max():g}"
    d = np.diag(a)
    return f"a {a.shape[0]}x{a.shape[1]} matrix, diagonal {d.min():g} to {d.max():g}"
