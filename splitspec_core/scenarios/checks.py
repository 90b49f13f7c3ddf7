"""The value checkers of scenarios: every number, matrix, id and key is checked here, by name.

One path for files and Python: :func:`splitspec_core.scenario` builds the mapping a file holds,
:func:`plain` turns numpy arrays and tuples into the YAML data model, and the section parsers of
:mod:`splitspec_core.scenarios.sections` call these checkers, whose one-line messages name the key
(``system.C.3 has 5 columns, system.A is 4x4``).  The limits are here, each with its reason.
"""

from __future__ import annotations

import math
import numbers
from typing import Any, Mapping

import numpy as np

from ..errors import DimensionError, ScenarioError
from . import gain_methods, keys

#: the words of design.gains: declared once, with what each needs, in gain_methods.py
GAIN_METHODS = gain_methods.NAMES
#: the word-valued design keys: ``{key: (the words, the default)}``, from their declaration (keys.py).  The design
#: section parses them from here (one line naming the key and the words), ``DesignSpec``'s defaults are these (a
#: test), and docs/how-to/scenario.md lists every word on the key's line (a test).  ``gains`` defaults to
#: ``optimal`` when the scenario states noise (design_section.py).
DESIGN_CHOICES = keys.choices(keys.DESIGN)
# design.consensus: what each agent takes from its neighbours (synthesis/whole_state.py): the paper's split (its
# unobservable subspace), the whole state, or auto (the noise decides: design.gains optimal)
CONSENSUS = DESIGN_CHOICES["consensus"][0]
Q_METHODS = DESIGN_CHOICES["q_method"][0]
WEIGHTINGS = DESIGN_CHOICES["weights"][0]

# the keys each section accepts, from their declaration (keys.py)
TOP_KEYS = keys.names(keys.TOP)
NETWORK_KEYS = keys.names(keys.NETWORK)
DELAY_KEYS = keys.names(keys.DELAY)
NETWORK_ARC_KEYS = keys.names(keys.NETWORK_ARC)
SYSTEM_KEYS = keys.names(keys.SYSTEM)
GRAPH_KEYS = keys.names(keys.GRAPH)
SWITCHING_KEYS = keys.names(keys.SWITCHING)
RANDOM_KEYS = keys.names(keys.RANDOM)
DESIGN_KEYS = keys.names(keys.DESIGN)
RICCATI_KEYS = keys.names(keys.RICCATI)
BAD_DATA_KEYS = keys.names(keys.BAD_DATA)
RUN_KEYS = keys.names(keys.RUN)
KEEP_KEYS = keys.names(keys.KEEP)

# Limits, each with the key(s) it bounds and why (docs/how-to/scenario.md, "Files and limits").
# Every number (matrix entries, x0, noise levels, rate, g, g0, margin, times, dt, dwell, pace,
# riccati weights): |x| <= 1e12, so squares and products of a few of them stay far below the
# float limit 1.8e308 (system.process_noise: 1e308 overflowed in process_noise**2, the Riccati weight).
MAX_MAGNITUDE = 1e12
# run.dt >= 1e-9: the sampled model integrates exp(A s) over [0, dt]; at dt = 1e-300 it underflows and the SVD fails.
MIN_DT = 1e-9
# run.pace >= 1e-6 event times per second: the orchestrator sleeps 1/pace s per event time.
MIN_PACE = 1e-6
# design.riccati.*_weight >= 1e-12: the Riccati equations are solved with these as covariances.
MIN_RICCATI_WEIGHT = 1e-12
# switching.random.dwell and switching.period >= 1e-3 sample steps (dt, or 1 event time): the switching
# signal is built piece by piece (memory ~ horizon / dwell), and switching within a step is not seen.
MIN_SWITCH_STEPS = 1e-3
# network.delay (mean + jitter) and network.deadline <= 60 s: a consensus sub-round that waits longer is no
# longer a network impairment but a stalled run (the orchestrator's round timeout is 10 s by default).
MAX_NETWORK_SECONDS = 60.0
# design.q_max <= 1e6: q is the number of consensus exchanges per event time.
MAX_Q = 1_000_000
# run.seed, switching.random.seed <= 2**63 - 1: seeds travel to the processes as msgpack 64-bit integers.
MAX_SEED = 2**63 - 1
# scenario files: regular files of at most 16 MB (16,000,000 bytes), read with a bounded read; a scenario
# is a few kB, and the checks below cost about 0.6 s per MB with libyaml's C loader.
MAX_FILE_BYTES = 16_000_000


def _frozen(a: np.ndarray) -> np.ndarray:
    a = np.array(a, dtype=float)
    a.setflags(write=False)
    return a


def require_map(value: Any, key: str) -> Mapping:
    """``value``'s keys but those set to null, if it is a mapping (a YAML section), else a one-line error naming
    ``key``: a key written ``null`` (``design: {g: null}``) is absent, in every section alike.

    Parameters
    ----------
    value : Any
        The value the file (or :func:`plain`) holds at ``key``.
    key : str
        Its dotted name for the message (``design.riccati``).

    Returns
    -------
    dict
        ``value`` without its null-valued keys (a new dict; the file's own mapping is left alone).

    Raises
    ------
    ScenarioError
        ``value`` is not a mapping (``design must be a mapping, got a list of 3 items``).
    """
    if not isinstance(value, Mapping):
        raise ScenarioError(f"{key} must be a mapping, got {describe(value)}")
    return {k: v for k, v in value.items() if v is not None}


def describe(value: Any) -> str:
    """How an error message names a value it refuses: its kind and, for a scalar, a short ``repr`` (one line).

    Parameters
    ----------
    value : Any
        Any value of the YAML data model (or a numpy array).

    Returns
    -------
    str
        ``nothing (null)``, ``the string 'x'``, ``the boolean True``, ``a list of 3 items``, ``a mapping``, ``an array
        of shape (2, 2)``, else the type's name and the ``repr`` cut to 60 characters.

    Examples
    --------
    >>> describe(None), describe([1, 2]), describe(True), describe(2.5)
    ('nothing (null)', 'a list of 2 items', 'the boolean True', 'float 2.5')
    """
    if value is None:
        return "nothing (null)"
    if isinstance(value, str):
        return f"the string {_short(repr(value))}"
    if isinstance(value, bool):
        return f"the boolean {value}"
    if isinstance(value, list):
        return f"a list of {len(value)} items"
    if isinstance(value, Mapping):
        return "a mapping"
    if isinstance(value, np.ndarray):
        return f"an array of shape {value.shape}"
    return f"{type(value).__name__} {_short(repr(value))}"


def _short(text: str, limit: int = 60) -> str:
    """One line of at most ``limit`` characters (error messages are one line)."""
    text = " ".join(text.split())
    return text if len(text) <= limit else text[: limit - 3] + "..."


def plain(value: Any, depth: int = 0) -> Any:
    """The YAML data model of a value built in Python: arrays and tuples as lists, numpy scalars as
    Python numbers, mappings as dicts.  Applied to every scenario before validation, so a file and
    :func:`splitspec_core.scenario` (numpy arrays welcome) meet the same checks with the same messages.

    Parameters
    ----------
    value : Any
        A value built in Python: numpy arrays and scalars, tuples, lists, mappings, anything else.
    depth : int
        The nesting depth reached (callers leave it at 0); a value nested deeper than 8 levels (deeper than any
        scenario key) is returned as is, for the checks to refuse.

    Returns
    -------
    Any
        ``value`` in the YAML data model: arrays and tuples as (nested) lists, numpy scalars as Python numbers,
        mappings as dicts (keys converted too); anything else unchanged.

    Examples
    --------
    >>> plain({"A": np.eye(2), "rate": np.float64(0.5), "arc": (1, 2)})
    {'A': [[1.0, 0.0], [0.0, 1.0]], 'rate': 0.5, 'arc': [1, 2]}
    """
    if depth > 8:  # deeper than any scenario key: left for the checks to refuse
        return value
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, (list, tuple)):
        return [plain(v, depth + 1) for v in value]
    if isinstance(value, Mapping):
        return {plain(k, depth + 1): plain(v, depth + 1) for k, v in value.items()}
    return value


def check_keys(mapping: Mapping, allowed: tuple, key: str) -> None:
    """Refuse the first key of ``mapping`` not in ``allowed``: one line naming it, the allowed keys, and where it
    belongs when it is (close to) a key of another section (``did you mean design.q_method?``).

    Parameters
    ----------
    mapping : Mapping
        A section as the file holds it.
    allowed : tuple of str
        The section's keys (``DESIGN_KEYS``, ...: from :mod:`~splitspec_core.scenarios.keys`).
    key : str
        The section's dotted name (``""``: the file's top level).

    Raises
    ------
    ScenarioError
        ``mapping`` holds a key outside ``allowed``.

    Examples
    --------
    >>> check_keys({"rate": 0.5, "qmethod": "spectral"}, DESIGN_KEYS, "design")  # doctest: +ELLIPSIS
    Traceback (most recent call last):
    ...
    splitspec_core.errors.ScenarioError: unknown key design.qmethod (expected one of: ...); did you mean design.q_method?
    """
    for k in mapping:
        if k not in allowed:
            where = f"{key}.{k}" if key else str(k)
            raise ScenarioError(f"unknown key {where} (expected one of: {', '.join(allowed)}){_did_you_mean(k)}")


# every key of the file by its dotted place, for "did you mean" hints
_ALL_KEYS = (
    *TOP_KEYS, *(f"system.{k}" for k in SYSTEM_KEYS), *(f"design.{k}" for k in DESIGN_KEYS),
    *(f"run.{k}" for k in RUN_KEYS), *(f"run.keep.{k}" for k in KEEP_KEYS), *(f"switching.{k}" for k in SWITCHING_KEYS),
    *(f"design.riccati.{k}" for k in RICCATI_KEYS), *(f"design.bad_data.{k}" for k in BAD_DATA_KEYS),
    *(f"network.{k}" for k in NETWORK_KEYS),
    *(f"network.delay.{k}" for k in DELAY_KEYS),
)


def _did_you_mean(key: Any) -> str:
    """``; did you mean design.q_method?`` when ``key`` is (close to) a key that belongs elsewhere."""
    import difflib

    word = str(key)
    places = {k: k.rpartition(".")[2] for k in _ALL_KEYS}
    exact = [k for k, last in places.items() if last == word]
    close = exact or [k for k in _ALL_KEYS if places[k] in difflib.get_close_matches(word, places.values(), n=1)]
    return f"; did you mean {close[0]}?" if close else ""


def _float(value: numbers.Real) -> float:
    """``float(value)``, with integers too large for a float (YAML ``1000...0``) as +-inf."""
    try:
        return float(value)
    except OverflowError:
        return math.inf if value > 0 else -math.inf


def _bounded(x: float, key: str) -> float:
    """``x`` if ``|x| <= MAX_MAGNITUDE``, else a one-line :class:`ScenarioError` naming ``key``."""
    if not math.isfinite(x):
        raise ScenarioError(f"{key} must be finite, got {x}")
    if abs(x) > MAX_MAGNITUDE:
        raise ScenarioError(f"{key} = {x:g} is out of range: numbers must be within +-{MAX_MAGNITUDE:g} "
                            "(larger ones overflow later arithmetic)")
    return x


def check_number(value: Any, key: str) -> float:
    """A finite number within ``+-MAX_MAGNITUDE`` (booleans refused), naming ``key`` on failure.

    Parameters
    ----------
    value : Any
        The value the file holds (an int, a float; an integer too large for a float counts as infinite).
    key : str
        Its dotted name for the message.

    Returns
    -------
    float
        ``value`` as a float.

    Raises
    ------
    ScenarioError
        Not a number, not finite, or ``|value| > MAX_MAGNITUDE`` (1e12).
    """
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise ScenarioError(f"{key} must be a number, got {describe(value)}")
    return _bounded(_float(value), key)


def check_seed(value: Any, key: str) -> int:
    """A seed: an integer in ``0 .. MAX_SEED`` (``2**63 - 1``, what msgpack carries), naming ``key`` on failure.

    Parameters
    ----------
    value : Any
        The value the file holds (an integral float such as ``7.0`` counts as the integer).
    key : str
        Its dotted name for the message (``run.seed``).

    Returns
    -------
    int
        The seed.

    Raises
    ------
    ScenarioError
        Not an integer, negative, or above ``MAX_SEED``.
    """
    v = check_integer(value, key, minimum=0)
    if v > MAX_SEED:
        raise ScenarioError(f"{key} must be <= 2**63 - 1 = {MAX_SEED} (seeds travel to the processes as "
                            f"64-bit integers), got {v}")
    return v


def check_integer(value: Any, key: str, *, minimum: int | None = None) -> int:
    """An integer (an integral float such as ``3.0`` counts; booleans refused), at least ``minimum``, naming ``key``
    on failure.

    Parameters
    ----------
    value : Any
        The value the file holds.
    key : str
        Its dotted name for the message.
    minimum : int, optional
        The smallest value allowed (None: no lower limit).

    Returns
    -------
    int
        ``value`` as an int.

    Raises
    ------
    ScenarioError
        Not an integer, or below ``minimum``.
    """
    if isinstance(value, bool) or not isinstance(value, numbers.Integral):
        if isinstance(value, float) and value.is_integer():
            value = int(value)
        else:
            raise ScenarioError(f"{key} must be an integer, got {describe(value)}")
    v = int(value)
    if minimum is not None and v < minimum:
        raise ScenarioError(f"{key} must be >= {minimum}, got {v}")
    return v


def read(mapping: Mapping, section: str, name: str, *, default: Any = None) -> Any:
    """``section.name`` from ``mapping`` as its declaration says (:mod:`~splitspec_core.scenarios.keys`): absent or
    null, its declared default (or ``default``); a word of its words as is; else a number or an integer as its kind
    says, checked here with the one-line message naming the key.

    Parameters
    ----------
    mapping : Mapping
        The section as the file holds it.
    section, name : str
        ``design`` and ``margin``, for ``design.margin`` (``""``: the file's top level).
    default : optional
        Overrides the declared default (``design.gains`` under noise).

    Returns
    -------
    Any
        The value: a float, an int, one of the key's words, or None (absent, no default).

    Raises
    ------
    ScenarioError
        A word outside the key's words, a value of the wrong kind, or below the key's minimum; a required key absent.
    """
    decl = next(k for k in keys.SECTIONS[section] if k.name == name)
    where = keys.dotted(section, name)
    value = mapping.get(name)
    if value is None:
        value = decl.default if default is None else default
    if value is keys.REQUIRED:
        raise ScenarioError(f"{where} is missing ({decl.doc})")
    if value is None or (decl.words and isinstance(value, str) and value in decl.words):
        return value
    if decl.kind == "word":
        words = decl.words
        listed = " or ".join(words) if len(words) == 2 else "one of " + ", ".join(words)
        raise ScenarioError(f"{where} must be {listed}, got {value!r}")
    if decl.kind.startswith("number"):
        return check_number(value, where)
    if decl.kind.startswith("integer"):
        return check_integer(value, where, minimum=decl.minimum)
    if decl.kind == "boolean" and not isinstance(value, bool):
        raise ScenarioError(f"{where} must be true or false, got {value!r}")
    return value


def check_matrix(value: Any, key: str, *, vector: bool = False) -> np.ndarray:
    """Convert a YAML nested list into a finite float array, naming ``key`` on failure.

    A matrix is a list of rows of equal length; a flat list of numbers is one row (``[1, 0, 0]`` is 1 x 3).  Every
    entry is a number within ``+-MAX_MAGNITUDE``; a message names the entry (``system.A[2][3]``, 1-based).

    Parameters
    ----------
    value : Any
        The nested list the file holds (None: missing).
    key : str
        Its dotted name (``system.C.3``); under ``system.`` a string is taken for an array name with no
        ``system.file`` to hold it.
    vector : bool
        Read a vector (a non-empty flat list, ``system.x0``) instead of a matrix.

    Returns
    -------
    ndarray
        A read-only float array: ``(rows, columns)``, or ``(entries,)`` with ``vector``.

    Raises
    ------
    ScenarioError
        Missing, not a non-empty list (of rows), a non-number entry, an entry out of range, or empty rows.
    DimensionError
        Rows of different lengths.

    Examples
    --------
    >>> check_matrix([[1, 0], [0, 2]], "system.A").tolist()
    [[1.0, 0.0], [0.0, 2.0]]
    >>> check_matrix([1, 0, 0], "system.C.1").shape
    (1, 3)
    >>> check_matrix([[1, 0], [0]], "system.A")
    Traceback (most recent call last):
    ...
    splitspec_core.errors.DimensionError: system.A row 2 has 1 entries, row 1 has 2
    """
    if value is None:
        raise ScenarioError(f"{key} is missing")
    if isinstance(value, str) and key.startswith("system."):
        raise ScenarioError(f"{key} is the name {_short(repr(value))}, and system.file is not given: name a .npz or "
                            ".mat file there to take arrays from, or write the matrix as a list of rows")
    if vector:
        if not isinstance(value, list) or not value:
            raise ScenarioError(f"{key} must be a non-empty list of numbers, got {describe(value)}")
        rows = [value]
    else:
        if not isinstance(value, list) or not value:
            raise ScenarioError(f"{key} must be a non-empty list of rows, got {describe(value)}")
        if all(isinstance(r, numbers.Real) and not isinstance(r, bool) for r in value):
            rows = [value]  # a single row written flat: [1, 0, 0]
        else:
            rows = value
    width = None
    for r, row in enumerate(rows):
        if not isinstance(row, list):
            raise ScenarioError(f"{key} row {r + 1} must be a list of numbers, got {describe(row)}")
        if width is None:
            width = len(row)
        elif len(row) != width:
            raise DimensionError(f"{key} row {r + 1} has {len(row)} entries, row 1 has {width}")
        for c, x in enumerate(row):
            where = f"{key}[{c + 1}]" if vector else f"{key}[{r + 1}][{c + 1}]"
            if isinstance(x, bool) or not isinstance(x, numbers.Real):
                raise ScenarioError(f"{where} must be a number, got {describe(x)}")
            _bounded(_float(x), where)
    if width == 0:
        raise ScenarioError(f"{key} has empty rows")
    arr = np.array(rows, dtype=float)
    return _frozen(arr[0] if vector else arr)


def check_names(value: Any, key: str, count: int, what: str) -> tuple:
    """A list of ``count`` distinct names (:data:`splitspec_core.scenarios.labels.NAME_PATTERN`), naming ``key`` on failure.

    Parameters
    ----------
    value : Any
        The list the file holds.
    key : str
        Its dotted name (``system.states``).
    count : int
        How many names it must hold.
    what : str
        What the names stand for, for the message (``one per state, system.A is 4x4``).

    Returns
    -------
    tuple of str
        The names, in the file's order.

    Raises
    ------
    ScenarioError
        Not a list, an entry that is not a name (letters, digits, ``_ . -``, starting with a letter or ``_``, at
        most 64 characters), or a name given twice.
    DimensionError
        Not ``count`` names.
    """
    from .labels import NAME_PATTERN

    if not isinstance(value, list):
        raise ScenarioError(f"{key} must be a list of {count} names ({what}), got {describe(value)}")
    if len(value) != count:
        raise DimensionError(f"{key} has {len(value)} names, expected {count} ({what})")
    seen: dict = {}
    for k, name in enumerate(value):
        if not isinstance(name, str) or not NAME_PATTERN.fullmatch(name):
            raise ScenarioError(f"{key}[{k + 1}] = {_short(repr(name))} is not a name: letters, digits, _ . - "
                                "(starting with a letter or _), at most 64 characters")
        if name in seen:
            raise ScenarioError(f"{key}[{k + 1}] = {name!r} is also {key}[{seen[name] + 1}]: names must differ")
        seen[name] = k
    return tuple(value)


def check_agent_id(value: Any, key: str) -> int:
    """An agent id: a positive integer (a string of digits, as a YAML or JSON key may be, counts), naming ``key`` on
    failure.

    Parameters
    ----------
    value : Any
        The id as the file holds it.
    key : str
        The dotted name of where it stands (``system.C``).

    Returns
    -------
    int
        The id.

    Raises
    ------
    ScenarioError
        Not a positive integer.
    """
    if isinstance(value, str) and value.strip().isdigit():
        value = int(value)
    if isinstance(value, bool) or not isinstance(value, numbers.Integral) or int(value) < 1:
        raise ScenarioError(f"{key}: agent ids must be positive integers, got {describe(value)}")
    return int(value)


def check_known_agent(value: Any, key: str, ids: tuple) -> int:
    """An agent id (:func:`check_agent_id`) that is one of the scenario's agents ``ids``.

    Parameters
    ----------
    value : Any
        The id as the file holds it.
    key : str
        The dotted name of where it stands (``design.K``).
    ids : tuple of int
        The scenario's agent ids (the keys of ``system.C``).

    Returns
    -------
    int
        The id.

    Raises
    ------
    ScenarioError
        Not a positive integer, or not in ``ids``.
    """
    aid = check_agent_id(value, key)
    if aid not in ids:
        raise ScenarioError(f"{key} names agent {aid}, which is not in system.C (agents: {ids_text(ids)})")
    return aid


def ids_text(ids: tuple) -> str:
    """Agent ids as a message lists them.

    Parameters
    ----------
    ids : tuple of int
        Agent ids.

    Returns
    -------
    str
        The ids, comma-separated (``1, 2, 3``).
    """
    return ", ".join(str(i) for i in ids)


def check_arc(value: Any, key: str, ids: tuple) -> tuple:
    """An arc ``[j, i]`` (agent i hears agent j) between two of the scenario's agents, naming ``key`` on failure.

    Parameters
    ----------
    value : Any
        The pair as the file holds it.
    key : str
        The dotted name of where it stands (``graphs.a.arcs[2]``).
    ids : tuple of int
        The scenario's agent ids.

    Returns
    -------
    tuple of int
        ``(j, i)``; a self-arc ``(i, i)`` is returned too (the graph parser leaves it out).

    Raises
    ------
    ScenarioError
        Not a pair, or an id that is not a positive integer or not an agent of ``ids``.
    """
    if not isinstance(value, list) or len(value) != 2:
        raise ScenarioError(f"{key} must be a pair [j, i] of agent ids, got {describe(value)}")
    j = check_known_agent(value[0], key, ids)
    i = check_known_agent(value[1], key, ids)
    return (j, i)


def check_shapes(A: Any, Cs: Mapping, x0: Any = None, Ks: Mapping | None = None) -> None:
    """The system's shapes, each mismatch one line naming the matrix: ``A`` square, ``C_i`` with n columns,
    ``x0`` of n entries, ``K_i`` n x s_i.  ``Cs`` and ``Ks`` map agent ids to matrices.  The scenario
    parser and :class:`~splitspec_core.scenarios.specs.Scenario` itself both call it, so a scenario
    built from its dataclasses cannot skip it.

    Parameters
    ----------
    A : array_like
        ``A``, which must be n x n.
    Cs : Mapping
        ``{agent id: C_i}``, each s_i x n (may be empty).
    x0 : array_like, optional
        The initial state, ``(n,)`` (None: not checked).
    Ks : Mapping, optional
        ``{agent id: K_i}``, each n x s_i with s_i the rows of ``Cs[id]`` (None: not checked).

    Raises
    ------
    DimensionError
        The first shape that does not agree, named (``system.C.3 has 5 columns, system.A is 4x4``).

    Examples
    --------
    >>> check_shapes(np.eye(2), {1: [[1, 0]]}, Ks={1: [[1, 0]]})  # doctest: +ELLIPSIS
    Traceback (most recent call last):
    ...
    splitspec_core.errors.DimensionError: design.K.1 is 1x2, expected 2x1 (n x s_i with system.C.1 1x2; ...)
    """
    shape = np.shape(A)
    if len(shape) != 2 or shape[0] != shape[1]:
        raise DimensionError(f"system.A must be square, got {'x'.join(map(str, shape))}")
    n = shape[0]
    for aid, C in Cs.items():
        cs = np.shape(C)
        if len(cs) != 2 or cs[1] != n:
            raise DimensionError(f"system.C.{aid} has {cs[-1] if cs else 0} columns, system.A is {n}x{n}")
    if x0 is not None and np.shape(x0) != (n,):
        raise DimensionError(f"system.x0 has {np.size(x0)} entries, system.A is {n}x{n}")
    for aid, K in (Ks or {}).items():
        s_i, ks = np.shape(Cs[aid])[0], np.shape(K)
        if ks != (n, s_i):
            # no guessing: a flat row [a, b, ...] is 1 x n, not the column n x 1
            hint = "; write a column as [[a], [b], ...]" if s_i == 1 else ""
            raise DimensionError(f"design.K.{aid} is {'x'.join(map(str, ks))}, expected {n}x{s_i} "
                                 f"(n x s_i with system.C.{aid} {s_i}x{n}{hint})")
