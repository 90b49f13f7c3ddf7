"""The action vocabulary of the round rules: what :class:`~splitspec_orchestrator.rounds.machine.RoundMachine`
returns for its shell to carry out.

Each action is a small frozen dataclass: publish a tick (:class:`Tick`), record a row (:class:`Record`) or the
network (:class:`Topology`), log an event (:class:`Event`) or a line (:class:`Log`), signal (:class:`Signal`) or
spawn (:class:`Spawn`) a process, broadcast a command (:class:`Control`), query statuses (:class:`QueryStatus`),
answer a claim (:class:`ReplyConfig`, :class:`ReplyRefused`), stop (:class:`Stop`) or finish (:class:`Finished`).
The shell (:mod:`splitspec_orchestrator.driver`) executes them; nothing here does I/O.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

__all__ = ["Tick", "Record", "Topology", "MarkLost", "Event", "Log", "Signal", "Control", "Spawn", "QueryStatus",
           "ReplyConfig", "ReplyRefused", "RegistryUpdate", "Stop", "Finished", "KillSelf"]

@dataclass(frozen=True)
class Tick:
    tau: int
    attempt: int
    graph: int
    final: bool
    alive: tuple
    rows: dict
    incarnation: dict
    fresh: bool = True  # someone starts this round with a fresh estimate: every agent sends its z_i(0)
    prev_attempt: int = 0  # the attempt of round tau - 1 whose estimates x_i(tau) are this round's z_i(0)
    partition: tuple = ()  # groups of agent ids of a partition in force (splitspec_core.model.impairment), or ()


@dataclass(frozen=True)
class Record:
    tau: int
    x: np.ndarray
    xhat: np.ndarray
    alive: np.ndarray
    graph: int
    columns: dict  # the agents' reported row columns (splitspec_core.model.rows.REPORTED): name -> (m,)
    attempts: int = 1  # attempts of the round (1 = not re-run)
    rejected: int = 0  # messages rejected since the previous record
    started: float = math.nan  # `now` of the round's first tick (driver clock)
    lost: tuple = ()  # (tau, k, j, i, cause) of every consensus message of the round that did not count
    y: tuple = ()  # live sensors: (agent id, y_i(tau) used or None) of the agents alive
    late: float = math.nan  # seconds the round started behind run.pace (NaN: unpaced)
    u: tuple = ()  # live known inputs: (agent id, u(tau) it used) of the agents alive that reported one

    @property
    def max_error(self) -> float:
        """``max_i |x_i - x|`` over the alive agents (NaN when none is alive)."""
        errs = np.linalg.norm(self.xhat - self.x, axis=1)
        return float(np.nanmax(errs)) if np.isfinite(errs).any() else math.nan  # none alive, or no truth


@dataclass(frozen=True)
class Topology:
    tau: int
    graph_name: str
    alive: tuple
    arcs: tuple
    partition: tuple = ()  # groups of agent ids of a partition in force, or ()


@dataclass(frozen=True)
class MarkLost:
    tau: int
    agent: int


@dataclass(frozen=True)
class Event:
    name: str
    t: float
    fields: dict = field(default_factory=dict)
    level: str | None = None  # None: the recorder's rule (WARN when the name says lost/rejected/error/failed)


@dataclass(frozen=True)
class Log:
    level: str  # "info" | "warning"
    message: str


@dataclass(frozen=True)
class Signal:
    """Send ``sig`` to a process on this host (the shell checks it is still a splitspec process)."""
    pid: int
    sig: int


@dataclass(frozen=True)
class Control:
    """Broadcast a control command (``stop``, ``kill agent/<i>``, ``freeze agent/<i>``)."""
    cmd: str


@dataclass(frozen=True)
class Spawn:
    """Start a process on this host; the shell answers with :meth:`RoundMachine.on_spawned`."""
    role: str
    ident: int


@dataclass(frozen=True)
class QueryStatus:
    """Query every process's status for ``timeout`` seconds; the shell answers with :meth:`RoundMachine.on_status`."""
    timeout: float = 1.0


@dataclass(frozen=True)
class ReplyConfig:
    ref: object
    role: str = "agent"  # who asked: its configuration may hold what is its own (an agent's central gain)
    ident: int = 0


@dataclass(frozen=True)
class ReplyRefused:
    ref: object
    reason: str
    holder_pid: int
    holder_host: str


@dataclass(frozen=True)
class RegistryUpdate:
    """The process table changed (``RoundMachine.procs``)."""


@dataclass(frozen=True)
class Stop:
    """The run cannot go on: ``message`` is the one line for the user; ``code`` the exit status."""
    code: int
    message: str


@dataclass(frozen=True)
class Finished:
    rounds: int


@dataclass(frozen=True)
class KillSelf:
    """The scenario kills the active orchestrator (``kill: orchestrator``): the shell SIGKILLs its own process."""

    tau: int
