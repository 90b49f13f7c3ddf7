"""The row schema of a run's records, declared once: every column of the row of an event time.

A run's records hold one row per event time ``tau``: the true state, every agent's estimate, who was alive, the
active graph, and the per-agent quantities each agent reports with its estimate.  :data:`COLUMNS` declares each
column once -- its one name, shape kind, dtype, fill value (what stands where there is no value: a dead agent, a
quantity this run does not have), unit and meaning -- and every layer derives its part from it:

* the wire: an agent's ``xhat`` message carries one scalar field per :data:`REPORTED` column
  (:data:`splitspec_core.runtime.wire.BINARY_LAYOUT`); the agent fills them with :func:`report`;
* the orchestrator: :class:`splitspec_orchestrator.rounds.collected.Collected` keeps each agent's report and
  hands the row to the recorder (``Record.columns``), whose row store, flushes and checks loop over the columns;
* the files: the chunks' Arrow schema (:mod:`splitspec_core.simulation.trajectory_chunks`), the arrays of
  ``trajectory.npz`` (:mod:`splitspec_core.simulation.trajectory_file`) and
  :class:`~splitspec_core.simulation.simulator.Trajectory` (``columns``, keyed by name);
* Rerun: one series per agent for each reported column the run shows (``<entity>/agent_<id>``), in the
  ``per agent`` tab (:mod:`splitspec_orchestrator.viewer.sink`).

So a new per-agent quantity is one line here (``reported="state"`` or ``"round"``) plus its computation where
it is computed: by the agent process (:mod:`splitspec_agents.agent`, which reports it with :func:`report`) and by
the simulator (:mod:`splitspec_core.simulation.simulator`, which puts it in ``Trajectory.columns``).

Shape kinds (T rows; m agents; n states): ``row`` (T,), ``state`` (T, n), ``agent`` (T, m), ``agent_state``
(T, m, n), ``round`` (T, len(:data:`ROUND_FIELDS`)).  Beside the columns, not in them: the consensus messages
that did not count (``lost``, ``lost_cause``: any number per row), on measurements or live sensors ``y`` and
``y_missing``, and with known inputs ``u`` (:mod:`splitspec_core.simulation.trajectory_file`).

A reported column is of the agent's *state* (``reported="state"``: its value at ``tau`` comes with ``x_i(tau)``,
as ``g_i(tau)`` does; an admission report carries the initial value) or of the *round* (``reported="round"``: the
round of ``tau`` computes it and reports it with ``x_i(tau + 1)``; it belongs to row ``tau``; an admission report
and the last row, which has no round, carry the fill).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["Column", "COLUMNS", "REPORTED", "ROUND_FIELDS", "column", "report", "run_columns", "shape_of", "empty",
           "present"]

#: the ``round`` column's fields, in order: what the orchestrator measured of each round
ROUND_FIELDS = ("wall_ms", "attempts", "rejected", "lost", "late_ms")

_SHAPES = ("row", "state", "agent", "agent_state", "round")


@dataclass(frozen=True)
class Column:
    """One column of the row schema (see the module docstring).

    Attributes
    ----------
    name : str
        The one name of the quantity: ``trajectory.npz`` key, chunk column, ``xhat`` field, ``Trajectory.columns``
        key, recorder keyword.
    shape : str
        ``row``, ``state``, ``agent``, ``agent_state`` or ``round``.
    dtype : str
        The numpy dtype of its values.
    fill : object
        The value where there is none (a dead agent, a quantity this run does not have).
    unit : str
        Its unit ("" for none).
    doc : str
        What it is, one line.
    npz : bool
        It is an array of ``trajectory.npz`` (``tau``, ``wall``, ``round`` are in the chunks only).
    reported : str or None
        ``state`` or ``round``: each agent reports it with its estimate (a per-agent scalar); None otherwise.
    entity : str or None
        The Rerun entity prefix of a reported column's series (``<entity>/agent_<id>``; default: the name).
    label : str
        The name of its Rerun view (default: the name).
    only_with_g : bool
        A run has it only when its design has a gain g (continuous time, the split design); else it is all fill
        and the recording shows no series of it.
    only_with_bad_data : bool
        A run has it only when its design tests the measurements (``design.bad_data``,
        :mod:`splitspec_core.synthesis.bad_data`); else it is all fill and the recording shows no series of it.
    """

    name: str
    shape: str
    dtype: str
    fill: object
    unit: str
    doc: str
    npz: bool = True
    reported: str | None = None
    entity: str | None = None
    label: str | None = None
    only_with_g: bool = False
    only_with_bad_data: bool = False

    def __post_init__(self):
        if self.shape not in _SHAPES:
            raise ValueError(f"column {self.name}: shape {self.shape!r} is not one of {', '.join(_SHAPES)}")
        if self.reported not in (None, "state", "round") or (self.reported and self.shape != "agent"):
            raise ValueError(f"column {self.name}: a reported column is a per-agent scalar of the state or the round")

    @property
    def path(self) -> str:
        """The Rerun entity prefix of its per-agent series."""
        return self.entity or self.name


NAN = math.nan

#: every column of a row, in the chunks' order
COLUMNS = (
    Column("tau", "row", "int64", 0, "", "event index", npz=False),
    Column("t", "row", "float64", 0.0, "s (continuous) or event", "event index (discrete) or time tau * dt"),
    Column("x", "state", "float64", 0.0, "state", "true state x(tau); NaN where unknown (measurements)"),
    Column("xhat", "agent_state", "float64", NAN, "state", "agent estimates x_i(tau), NaN where dead"),
    Column("alive", "agent", "bool", False, "", "the agent ran at tau"),
    Column("graph", "row", "int64", 0, "", "index of the active graph (scenario order)"),
    Column("g", "agent", "float64", NAN, "1/s", "consensus gain g_i(tau) (eq. adaptive, or the fixed g); "
           "continuous time only", reported="state", entity="gains",
           label="adaptive gains g_i", only_with_g=True),
    Column("messages_used", "agent", "int64", -1, "messages", "the neighbours' consensus messages agent i counted in "
           "the round of tau, over its exchanges; -1 where dead and in the last row (no round)", reported="round",
           label="consensus messages used per agent"),
    Column("y_rejected", "agent", "bool", False, "", "agent i's measurement y_i(tau) was set aside by its bad-data "
           "test (failed, or its sensor suspect) and not used; False where used, dead, in the last row, or without "
           "design.bad_data", reported="round", label="measurements set aside (bad data)"),
    Column("y_statistic", "agent", "float64", -1.0, "", "agent i's bad-data statistic d_i = r_i' S_i^-1 r_i of the "
           "round of tau; -2 for a measurement repeating the last one exactly (a stuck sensor); -1 where nothing was "
           "tested (no measurement, its warm-up, dead, the last row, or without design.bad_data)",
           reported="round", label="bad-data statistic d_i", only_with_bad_data=True),
    Column("wall", "row", "int64", 0, "ns", "time.time_ns() of the row's arrival (run only)", npz=False),
    Column("round", "round", "float64", NAN, "", "the round's " + ", ".join(ROUND_FIELDS) + " (run only)",
           npz=False),
)

#: the per-agent scalars each agent reports with its estimate, in ``xhat``'s order
REPORTED = tuple(c for c in COLUMNS if c.reported)
_BY_NAME = {c.name: c for c in COLUMNS}


def column(name: str) -> Column:
    """The column called ``name``.

    Parameters
    ----------
    name : str

    Returns
    -------
    Column

    Raises
    ------
    KeyError
        Naming the columns, if none is called ``name``.
    """
    try:
        return _BY_NAME[name]
    except KeyError:
        raise KeyError(f"no row column {name!r}; the columns are {', '.join(_BY_NAME)}") from None


def report(**values) -> dict:
    """An agent's report of its :data:`REPORTED` columns: ``values`` where given, the fill elsewhere.

    Parameters
    ----------
    **values
        Reported column name -> this agent's value.

    Returns
    -------
    dict
        Every reported column's name -> a plain Python value of its dtype.

    Raises
    ------
    KeyError
        A name that is not a reported column.

    Examples
    --------
    >>> report(g=0.5)
    {'g': 0.5, 'messages_used': -1, 'y_rejected': False, 'y_statistic': -1.0}
    """
    unknown = set(values) - {c.name for c in REPORTED}
    if unknown:
        raise KeyError(f"not reported columns: {sorted(unknown)}; they are {', '.join(c.name for c in REPORTED)}")
    return {c.name: np.dtype(c.dtype).type(values.get(c.name, c.fill)).item() for c in REPORTED}


def run_columns(*, has_g: bool, bad_data: bool = False) -> tuple:
    """The names of the reported columns a run has (:attr:`Column.only_with_g`, :attr:`Column.only_with_bad_data`).

    Parameters
    ----------
    has_g : bool
        The design has a gain g (continuous time, the split design; not ``Design.two_rate``).
    bad_data : bool, optional
        The design tests the measurements (``design.bad_data``); default False.

    Returns
    -------
    tuple of str
        In :data:`REPORTED`'s order.
    """
    return tuple(c.name for c in REPORTED if (has_g or not c.only_with_g) and (bad_data or not c.only_with_bad_data))


def shape_of(c: Column, m: int, n: int) -> tuple:
    """The shape of one row of ``c``.

    Parameters
    ----------
    c : Column
    m, n : int
        Agents, states.

    Returns
    -------
    tuple of int
        ``()``, ``(n,)``, ``(m,)``, ``(m, n)`` or ``(len(ROUND_FIELDS),)`` by its shape kind.
    """
    return {"row": (), "state": (n,), "agent": (m,), "agent_state": (m, n), "round": (len(ROUND_FIELDS),)}[c.shape]


def empty(c: Column, rows: int, m: int, n: int) -> np.ndarray:
    """``rows`` rows of ``c``, all its fill.

    Parameters
    ----------
    c : Column
    rows, m, n : int
        Rows, agents, states.

    Returns
    -------
    numpy.ndarray
        Shape ``(rows,) + shape_of(c, m, n)``, dtype ``c.dtype``.
    """
    return np.full((int(rows),) + shape_of(c, m, n), c.fill, dtype=c.dtype)


def present(c: Column, values: np.ndarray) -> np.ndarray:
    """Where ``values`` of column ``c`` hold a value.

    Parameters
    ----------
    c : Column
    values : array_like
        Values of ``c``, any shape.

    Returns
    -------
    numpy.ndarray of bool
        True where a value is not the fill (NaN is no value either), same shape as ``values``.

    Examples
    --------
    >>> import numpy as np
    >>> present(column("messages_used"), np.array([2, -1, 0]))
    array([ True, False,  True])
    """
    values = np.asarray(values)
    if values.dtype.kind == "f":
        return np.isfinite(values) if isinstance(c.fill, float) and math.isnan(c.fill) else \
            np.isfinite(values) & (values != c.fill)
    return values != c.fill
