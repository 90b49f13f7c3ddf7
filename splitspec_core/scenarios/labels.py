"""Names of states and outputs, and directions and subspaces written with them.

A scenario may name its states (``system.states``) and each agent's outputs (``system.outputs``);
unnamed ones are ``x1 .. xn`` and ``y<i>`` (one output) or ``y<i>_1 .. y<i>_<s_i>``.  Every message,
report line and record that speaks of a direction of the state space goes through this module, so a
52-state model's direction reads ``LL_x_EXDC2_1 - 0.42 LL_x_EXDC2_3 (+ 9 smaller)`` instead of 52
numbers.
"""

from __future__ import annotations

import re

import numpy as np

__all__ = ["NAME_PATTERN", "SHOW_ALL", "default_state_names", "default_output_names", "combination", "heaviest",
           "shown_states", "spread"]

#: what a state or output name may be: it becomes part of a Rerun entity path and of a file's column name
NAME_PATTERN = re.compile(r"[A-Za-z_][A-Za-z0-9_.\-]{0,63}")
#: components shown of a direction or subspace, the largest first
SHOWN = 5
#: components smaller than this fraction of the largest are not named
NEGLIGIBLE = 5e-4
#: components within this fraction of the largest of each other are equal (round-off): named in the states' order
TIE = 1e-9


#: a model of at most this many states shows every one in the default views (run.rrd's states tab, states.png);
#: a larger one shows what ``run.show`` picks, by default at most :data:`SHOW_MEASURED` of the states its agents
#: measure
SHOW_ALL = 8
SHOW_MEASURED = 12


def shown_states(names, show, Cs) -> tuple:
    """Indices of the states the default views show: those ``show`` names or matches (``fnmatch`` patterns, in the
    states' order), else every state of a model of at most :data:`SHOW_ALL`, else the state each output row
    weighs most (agent order, each once), at most :data:`SHOW_MEASURED` (the first :data:`SHOW_ALL` when no row
    picks any).

    Parameters
    ----------
    names : sequence of str
        The state names.
    show : sequence of str or None
        ``run.show``: names or ``fnmatch`` patterns (empty or None: the default choice).
    Cs : iterable of array_like
        Each agent's ``C_i``.

    Returns
    -------
    tuple of int
        0-based state indices, ascending.

    Examples
    --------
    >>> shown_states([f"x{k}" for k in range(1, 11)], ["x1*"], [])
    (0, 9)
    """
    import fnmatch

    n = len(names)
    if show:
        return tuple(k for k, name in enumerate(names) if any(fnmatch.fnmatchcase(name, p) for p in show))
    if n <= SHOW_ALL:
        return tuple(range(n))
    picked: list = []
    for C in Cs:
        for row in np.atleast_2d(np.asarray(C, dtype=float)):
            k = int(np.argmax(np.abs(row)))
            if row[k] != 0 and k not in picked:
                picked.append(k)
    return tuple(sorted(picked[:SHOW_MEASURED])) or tuple(range(SHOW_ALL))


def default_state_names(n: int) -> tuple:
    """``("x1", ..., "xn")``.

    Parameters
    ----------
    n : int
        Number of states.

    Returns
    -------
    tuple of str
    """
    return tuple(f"x{k + 1}" for k in range(n))


def default_output_names(agent_id: int, s: int) -> tuple:
    """``("y<i>",)`` for one output, ``("y<i>_1", ..., "y<i>_<s>")`` for several.

    Parameters
    ----------
    agent_id : int
        The agent's id ``i``.
    s : int
        Its number of outputs.

    Returns
    -------
    tuple of str
    """
    return (f"y{agent_id}",) if s == 1 else tuple(f"y{agent_id}_{k + 1}" for k in range(s))


def _largest_first(values: np.ndarray) -> list:
    """Indices of the non-negligible ``values`` (at least :data:`NEGLIGIBLE` of the largest), the largest first;
    values equal to within :data:`TIE` of the largest (a run of them, each that close to the next) in index order,
    so the order does not depend on the round-off of the path that computed them."""
    top = float(values.max())
    order = [int(k) for k in np.argsort(-values, kind="stable") if values[k] >= NEGLIGIBLE * top]
    out, run = [], []
    for k in order:
        if run and values[run[-1]] - values[k] > TIE * top:
            out += sorted(run)
            run = []
        run.append(k)
    return out + sorted(run)


def _coefficient(c: float, first: bool) -> str:
    mag = abs(c)
    num = "" if abs(mag - 1.0) < 5e-4 else f"{mag:.2g} "
    sign = ("-" if c < 0 else "") if first else (" - " if c < 0 else " + ")
    return f"{sign}{num}"


def combination(v: np.ndarray, names, *, limit: int = SHOWN) -> str:
    """A direction as a combination of named states, scaled so its largest component is 1: ``x3 - 0.42 x4 (+ 2
    smaller)``; an oscillating mode (complex) as the states it moves, with their relative amplitudes:
    ``x4, x3 (0.71)``.

    Parameters
    ----------
    v : (n,) array_like, real or complex
        The direction (a complex one with zero imaginary part is taken as real).
    names : sequence of str
        The state names.
    limit : int, default SHOWN
        Components named, the largest first (components below :data:`NEGLIGIBLE` of the largest never are).

    Returns
    -------
    str
        ``"0"`` for the zero vector.

    Examples
    --------
    >>> import numpy as np
    >>> combination(np.array([0.0, 2.0, -0.84]), ("x1", "x2", "x3"))
    'x2 - 0.42 x3'
    >>> combination(np.array([0.5j, 0.0, 0.7]), ("x1", "x2", "x3"))
    'x3, x1 (0.71)'
    """
    v = np.asarray(v)
    if np.iscomplexobj(v) and np.allclose(v.imag, 0.0, atol=1e-12 * max(float(np.abs(v).max(initial=0.0)), 1e-300)):
        v = v.real
    mags = np.abs(v)
    if not mags.size or mags.max() == 0.0:
        return "0"
    top = mags.max()
    order = _largest_first(mags)
    shown = order[:limit]
    rest = len(order) - len(shown)
    more = f" (+ {rest} smaller)" if rest else ""
    if np.iscomplexobj(v):
        amp = [names[k] + ("" if abs(mags[k] / top - 1.0) < 5e-4 else f" ({mags[k] / top:.2g})") for k in shown]
        return ", ".join(amp) + more
    vals = v / v[order[0]]
    return "".join(_coefficient(float(vals[k]), j == 0) + names[k] for j, k in enumerate(shown)) + more


def heaviest(W: np.ndarray, names, *, limit: int = SHOWN) -> list:
    """The states that carry most of the subspace spanned by the orthonormal columns of ``W`` (the diagonal of the
    projection ``W W'``: how much of each state lies in it), the largest first, at most ``limit``.

    Parameters
    ----------
    W : (n, w) array
        Orthonormal basis of the subspace.
    names : sequence of str
        The state names.
    limit : int, default SHOWN
        States named.

    Returns
    -------
    list of str
        The names, then ``"<k> more"`` when more states carry some of it; empty for an empty subspace.
    """
    weight = np.sum(np.abs(W) ** 2, axis=1)
    if not weight.size or weight.max() == 0.0:
        return []
    order = _largest_first(weight)
    return [names[k] for k in order[:limit]] + ([f"{len(order) - limit} more"] if len(order) > limit else [])


def spread(W: np.ndarray, names, *, limit: int = SHOWN) -> str:
    """:func:`heaviest` as text: ``xf_1, xf_2, xf_3 and 4 more``.

    Parameters
    ----------
    W : (n, w) array
        Orthonormal basis of the subspace.
    names : sequence of str
        The state names.
    limit : int, default SHOWN
        States named.

    Returns
    -------
    str

    Examples
    --------
    >>> import numpy as np
    >>> spread(np.eye(8), tuple("abcdefgh"))
    'a, b, c, d, e and 3 more'
    """
    parts = heaviest(W, names, limit=limit)
    if len(parts) > 1 and parts[-1].endswith(" more"):
        return ", ".join(parts[:-1]) + " and " + parts[-1]
    return ", ".join(parts)
