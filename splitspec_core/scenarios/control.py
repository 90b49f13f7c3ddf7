"""A python-control ``StateSpace`` as a scenario's system: ``ss.scenario(plant=sys, agents={id: outputs})``.

``plant``'s ``A`` is the system matrix, each agent's ``C_i`` the rows of ``plant.C`` of the outputs it is given
(by label or by index), ``plant.B`` the known inputs' matrix (when the plant has inputs); its state and output
labels become the scenario's ``system.states`` and ``system.outputs`` (python-control's ``x[0]`` as ``x_0``:
a name must be usable as a Rerun entity and a file's column); ``plant.dt`` decides the time (0: continuous,
``True`` or a period: discrete).  python-control is an optional extra (``pip install splitspec[control]``);
nothing here imports it unless ``plant=`` is given.
"""

from __future__ import annotations

import re
from typing import Any, Mapping

import numpy as np

from ..errors import ScenarioError

__all__ = ["from_statespace", "label_name", "plant_keywords"]


#: the names python-control gives a system nobody named (``sys[3]``, ``sys[3]$sampled``): not a scenario's name
GENERIC_NAME = re.compile(r"sys\[\d+\](\$\w+)*")


def label_name(label: str, fallback: str) -> str:
    """A python-control label as a scenario name: ``x[3]`` -> ``x_3``, other characters a name cannot hold -> ``_``.

    Parameters
    ----------
    label : str
        The label.
    fallback : str
        The name when nothing usable is left.

    Returns
    -------
    str
        A name matching :data:`~splitspec_core.scenarios.labels.NAME_PATTERN` (at most 64 characters; one that
        does not start with a letter or ``_`` gets a ``_`` in front).

    Examples
    --------
    >>> label_name("x[3]", "x1"), label_name("3 phase", "y1")
    ('x_3', '_3_phase')
    """
    from .labels import NAME_PATTERN

    name = re.sub(r"\[(\d+)\]", r"_\1", str(label))
    name = re.sub(r"[^A-Za-z0-9_.\-]", "_", name).strip("_") or fallback
    if not re.match(r"[A-Za-z_]", name):
        name = "_" + name
    name = name[:64]
    return name if NAME_PATTERN.fullmatch(name) else fallback


def _distinct(names: list, fallback: str) -> list:
    """``names`` made distinct (a repeat gets ``_2``, ``_3`` ...)."""
    seen: dict = {}
    out = []
    for k, name in enumerate(names):
        base = name
        while name in seen:
            seen[base] += 1
            name = f"{base}_{seen[base]}"[:64]
        seen.setdefault(name, 1)
        out.append(name if name else f"{fallback}{k + 1}")
    return out


def _rows(plant: Any, aid: Any, wanted: Any) -> list:
    labels = list(plant.output_labels)
    items = wanted if isinstance(wanted, (list, tuple)) else [wanted]
    if not items:
        raise ScenarioError(f"agents.{aid} lists no outputs (labels or indices of the plant's outputs)")
    rows = []
    for w in items:
        if isinstance(w, (int, np.integer)) and not isinstance(w, bool):
            if not 0 <= int(w) < len(labels):
                raise ScenarioError(f"agents.{aid}: output index {int(w)} is out of range (the plant has "
                                    f"{len(labels)} outputs, 0 .. {len(labels) - 1})")
            rows.append(int(w))
        elif isinstance(w, str):
            if w not in labels:
                shown = ", ".join(labels[:8]) + (" ..." if len(labels) > 8 else "")
                raise ScenarioError(f"agents.{aid}: {w!r} is not an output of the plant (its outputs: {shown})")
            rows.append(labels.index(w))
        else:
            raise ScenarioError(f"agents.{aid}: {w!r} is neither an output label nor an output index")
    if len(set(rows)) != len(rows):
        raise ScenarioError(f"agents.{aid} names an output twice")
    return rows


def from_statespace(plant: Any, agents: Any) -> dict:
    """``{"time": ..., "system": {"A", "C", "states", "outputs", ["B"]}}`` of ``plant`` for ``agents``.

    Parameters
    ----------
    plant : control.StateSpace
        The plant; ``dt`` 0 or None: continuous, else discrete.  ``B`` is kept when it has a nonzero entry.
    agents : mapping
        ``{agent id: output label or index, or a list of them}``: the rows of ``plant.C`` each agent measures.

    Returns
    -------
    dict
        ``system`` holds ``A``, ``C`` (``{agent id: rows}``), ``states`` and ``outputs`` (names from the labels,
        made distinct) and, with inputs, ``B``.

    Raises
    ------
    ScenarioError
        One line: python-control missing, ``plant`` not a ``StateSpace``, ``agents`` missing or naming an output
        the plant does not have, a feedthrough ``D`` on a measured output.

    Examples
    --------
    >>> import control
    >>> plant = control.ss([[0, 1], [-1, 0]], [[0], [1]], [[1, 0], [0, 1]], 0, states=["pos", "vel"],
    ...                    outputs=["p", "v"])
    >>> got = from_statespace(plant, {1: "p", 2: [1]})
    >>> got["time"], got["system"]["C"][2].tolist(), got["system"]["outputs"]
    ('continuous', [[0.0, 1.0]], {1: ['p'], 2: ['v']})
    """
    try:
        import control
    except ImportError:
        raise ScenarioError("plant= takes a python-control StateSpace, and python-control is not installed "
                            "(pip install 'splitspec[control]')") from None
    if not isinstance(plant, control.StateSpace):
        kind = type(plant).__name__
        hint = " (control.ss(sys) converts it)" if isinstance(plant, control.TransferFunction) else ""
        raise ScenarioError(f"plant= must be a python-control StateSpace, got {kind}{hint}")
    if not isinstance(agents, Mapping) or not agents:
        raise ScenarioError("plant= needs agents={id: [outputs]}: which of the plant's outputs each agent measures "
                            "(labels or indices)")
    A = np.asarray(plant.A, dtype=float)
    C = np.asarray(plant.C, dtype=float)
    D = np.asarray(plant.D, dtype=float)
    B = np.asarray(plant.B, dtype=float)
    n = A.shape[0]
    if n == 0:
        raise ScenarioError("plant= has no states")
    out_names = _distinct([label_name(s, f"y{k + 1}") for k, s in enumerate(plant.output_labels)], "y")
    Cs, outputs = {}, {}
    for aid, wanted in agents.items():
        rows = _rows(plant, aid, wanted)
        if D.size and np.any(D[rows] != 0):
            raise ScenarioError(f"agents.{aid}: the plant feeds its inputs through to these outputs (D != 0); "
                                "splitspec's outputs are y_i = C_i x: subtract D u from the measurements first")
        Cs[aid] = C[rows]
        outputs[aid] = [out_names[r] for r in rows]
    states = _distinct([label_name(s, f"x{k + 1}") for k, s in enumerate(plant.state_labels)], "x")
    system: dict = {"A": A, "C": Cs, "states": states, "outputs": outputs}
    if B.size and B.shape[1] and np.any(B != 0):
        system["B"] = B
    dt = plant.dt
    # None: python-control's unspecified timebase, taken as continuous (its default, dt = 0)
    time = "continuous" if dt is None or (not isinstance(dt, bool) and dt == 0) else "discrete"
    return {"time": time, "system": system}


def plant_keywords(given: dict, plant: Any, agents: Any) -> None:
    """``plant=`` and ``agents=`` as the keywords they stand for, in ``given`` (those keywords not given too).

    Sets ``A``, ``C``, ``states``, ``outputs`` (and ``B``), ``time`` and, unless given or made up by
    python-control, ``name``.

    Parameters
    ----------
    given : dict
        :func:`splitspec_core.scenario`'s keywords (``A``, ``B``, ``C``, ``states``, ``outputs``, ``file``,
        ``time`` present, None where not given); updated in place.
    plant : control.StateSpace or None
        The plant.
    agents : mapping
        As for :func:`from_statespace`.

    Raises
    ------
    ScenarioError
        ``agents=`` without ``plant=``, a keyword that ``plant=`` also gives, ``sample=`` on a discrete plant, a
        ``time=`` other than the plant's (or ``"discrete"`` with ``sample=``), and as :func:`from_statespace`.
    """
    if plant is None:
        raise ScenarioError("agents= goes with plant= (a python-control StateSpace); without it give C=")
    clash = [k for k in ("A", "B", "C", "states", "outputs", "file") if given[k] is not None]
    if clash:
        raise ScenarioError(f"plant= gives the system: {', '.join(k + '=' for k in clash)} cannot be given with it")
    if isinstance(given.get("system"), Mapping) and given["system"]:
        raise ScenarioError("plant= gives the system: system= cannot be given with it")
    got = from_statespace(plant, agents)
    own = getattr(plant, "name", None)  # the plant's own name, unless python-control made it up (sys[3], sys[3]$sampled)
    if given.get("name") is None and isinstance(own, str) and own.strip() and not GENERIC_NAME.fullmatch(own):
        given["name"] = own
    if given.get("sample") is not None:  # a continuous plant sampled for the discrete estimator
        if got["time"] != "continuous":
            raise ScenarioError(f"sample= samples a continuous plant, and plant= is discrete (its dt = {plant.dt})")
        if given["time"] not in (None, "discrete"):
            raise ScenarioError("sample= is for time='discrete' (the discrete estimator of the sampled plant)")
        got["time"] = "discrete"
    if given["time"] is not None and given["time"] != got["time"]:
        raise ScenarioError(f"time={given['time']!r}, and plant= is {got['time']} time (its dt = {plant.dt})"
                            + ("; sample=dt samples it for the discrete estimator" if got["time"] == "continuous"
                               else ""))
    given["time"] = got["time"]
    given.update(got["system"])
