"""The kinds of scenario fault, declared once: one small registered class per kind.

A fault is a frozen dataclass, a subclass of :class:`Fault`, registered under its ``action`` (the scenario's
key: ``{at: T, kill: 3}``).  Each kind holds everything about itself:

* its parsing (:meth:`Fault.parse`: the value of its key and its options, one-line errors naming the key);
* its effect in the simulator (:meth:`Fault.apply` on :class:`splitspec_core.model.network.NetworkState`, and
  :meth:`Fault.measure` on the measurements of a sensor it holds, the identity for most kinds);
* its effect in the runtime, a declarative answer the orchestrator dispatches on (:attr:`Fault.runtime`:
  :data:`SIGNAL` the agent's process, :data:`RESTART` it, change the agents' :data:`NETWORK`, or a
  :data:`PLANT` effect the plant process applies itself from the scenario, at the same step);
* its event in ``events.jsonl`` (:attr:`Fault.event`, :meth:`Fault.payload`, :meth:`Fault.text`) and how a
  replay reads it back (:meth:`Fault.from_event`); its mark on the Rerun timeline (:attr:`Fault.mark`) and on
  the plots (:meth:`Fault.plot_mark`, :attr:`Fault.loss_word`).

A kind with an end (:attr:`Fault.ends_with`) takes a generic duration: ``{at: 10, kill: 3, for: 5}`` is a
kill at 10 and a restart at 15, expanded when parsed.  An action nobody registered cannot be built: the
parser refuses it with one line naming the registered kinds, and so does :func:`make_fault`.  Adding a kind
is one class here (with :func:`register`), its test and its line in ``docs/how-to/faults.md``.

Why one module: it is the declaration of every kind, the one place a newcomer adds one; split per kind, each
addition would touch a new module and the list that imports it.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from ..errors import ScenarioError
from .checks import check_arc, check_keys, check_known_agent, check_number, describe, ids_text, require_map
from .network_section import check_heals, parse_groups

__all__ = ["Fault", "FaultContext", "KINDS", "FAULT_ACTIONS", "FAULT_ALIASES", "SIGNAL", "RESTART", "NETWORK",
           "PLANT", "ORCHESTRATOR", "register", "make_fault", "parse_faults", "kind_of_event", "fault_event_text", "fault_marks"]

SIGNAL = "signal"  #: the runtime signals the agent's process (SIGKILL, SIGSTOP); it is lost from that step
RESTART = "restart"  #: the runtime spawns the agent's process again; it rejoins with a fresh estimate
NETWORK = "network"  #: the runtime changes the agents' network as the simulator does (the ticks carry it)
PLANT = "plant"  #: the plant process applies it to the measurements, from the scenario, at the same step
ORCHESTRATOR = "orchestrator"  #: the runtime's active orchestrator kills itself (a standby takes over); no effect

KINDS: dict = {}  #: ``{action: kind}`` in registration order
_WORDS: dict = {}  #: every word a scenario may use for an action (aliases too) -> the kind
_EVENTS: dict = {}  #: event word -> the kind a replay makes of it (the first registered with that event)


@dataclass(frozen=True)
class FaultContext:
    """What a kind's parser may check its values against: the agents' ids and each agent's number of outputs."""

    ids: tuple
    outputs: dict | None = None  # {agent id: s_i}; None: not known (no per-output check)


@dataclass(frozen=True)
class Fault:
    """One scheduled fault at time ``at``: the base of the registered kinds (it cannot be built itself)."""

    at: float

    action: ClassVar[str] = ""
    aliases: ClassVar[tuple] = ()  # older spellings of the action, read as it
    options: ClassVar[tuple] = ()  # keys besides ``at``, the action and ``for``
    ends_with: ClassVar[str | None] = None  # the action that ends it: ``for: S`` adds one at ``at + S``
    runtime: ClassVar[str] = NETWORK
    event: ClassVar[str | None] = None  # the event the runtime logs for it (a replay reads it back)
    mark: ClassVar[str | None] = None  # its event's mark on the Rerun timeline (``marks/<mark>``)
    mark_style: ClassVar[tuple | None] = None  # (legend, marker, colour) of a mark kind of its own
    loss_word: ClassVar[str | None] = None  # why the agent is lost, on the plots (``3 killed``)
    verdict: ClassVar[bool] = False  # the runtime says the survivors' verdict after it
    #: it stops consensus messages the same way for every seed (the simulator then steps message by message)
    drops_messages: ClassVar[bool] = False
    #: a sensor fault that holds the agent's last measurement (the network state then keeps every agent's)
    holds_last: ClassVar[bool] = False
    #: a ``SIGNAL`` kind's OS signal (``SIGKILL``), and whether the process stays (stopped) after it
    signal: ClassVar[str | None] = None
    keeps_process: ClassVar[bool] = False

    def __post_init__(self):
        if KINDS.get(self.action) is not type(self):
            raise ScenarioError(f"fault kind {type(self).__name__} is not registered (the kinds: "
                                f"{', '.join(KINDS)})")

    @classmethod
    def parse(cls, value: Any, fmap: dict, key: str, ctx: FaultContext) -> dict:
        """The fields of the kind from the value of its key (``faults[k].<action>``) and its options.

        Parameters
        ----------
        value : Any
            The value of the action's key as the scenario gives it (``3`` for ``kill: 3``).
        fmap : dict
            The whole fault entry, the action's value also under the kind's own ``action`` (an alias
            read as it), for the kind's options (``bias``, ``scale``).
        key : str
            The entry's name in errors (``faults[2]``).
        ctx : FaultContext
            The agents' ids and outputs the values are checked against.

        Returns
        -------
        dict
            The kind's fields besides ``at`` (``{"agent": 3}``).

        Raises
        ------
        ScenarioError
            One line naming ``key`` and what is wrong with the value or an option.
        """
        raise NotImplementedError

    @classmethod
    def from_event(cls, e: dict, where: str, ids: tuple) -> dict:
        """The fields of the kind from its recorded event ``e`` (``where`` names it in an error).

        Parameters
        ----------
        e : dict
            The event, as :func:`splitspec_core.scenarios.replay.load_events` reads it.
        where : str
            The event's description in errors (file and event number).
        ids : tuple of int
            The scenario's agent ids, which the event's agents must be among.

        Returns
        -------
        dict
            The kind's fields besides ``at``; the base returns ``{}`` (a kind without fields).

        Raises
        ------
        ScenarioError
            The event lacks a field the kind needs, or names an agent that is not in ``ids``.
        """
        return {}

    def apply(self, net) -> tuple:
        """Its effect on the simulator's network state: ``(lost positions, [(position, incarnation)])``.

        The base changes nothing and returns ``([], [])``.

        Parameters
        ----------
        net : NetworkState
            The simulator's network state (:class:`splitspec_core.model.network.NetworkState`), changed in
            place.

        Returns
        -------
        lost : list of int
            The positions that stopped taking part at this step.
        rejoined : list of (int, int)
            ``(position, incarnation)`` of the agents that rejoin with a fresh estimate.
        """
        return [], []

    def measure(self, y: np.ndarray, memo: dict) -> np.ndarray:
        """A sensor it holds (:meth:`apply` puts it in ``net.sensors``): agent i's measurement ``y_i`` (outputs on
        axis 0, seeds after) as the estimator is given it; ``memo`` is the sensor's own memory.

        Parameters
        ----------
        y : (s_i,) or (s_i, N) ndarray
            Agent i's true measurement (outputs on axis 0, seeds after).
        memo : dict
            The sensor fault's own memory, kept from step to step while it is in force; at its first
            measurement the network state puts in it ``before`` (the last measurement the agent was given
            before the fault) and ``draws`` (its own noise stream,
            :class:`splitspec_core.model.network.SensorDraws`).

        Returns
        -------
        ndarray
            The measurement the estimator is given, shaped as ``y``; the base returns ``y`` itself.
        """
        return y

    def payload(self, tau: int) -> dict:
        """The fields of its event in ``events.jsonl``, at event time ``tau``.

        Parameters
        ----------
        tau : int
            The event time from which the fault holds.

        Returns
        -------
        dict
            The event's fields (JSON values): ``{"tau": tau}`` and the kind's own (``id``, ``arc``,
            ``groups``, ...).
        """
        return {"tau": tau}

    @staticmethod
    def text(fields: dict) -> str:
        """The one-sentence text of its event (the ``events`` TextLog).

        Parameters
        ----------
        fields : dict
            The event's fields (:meth:`payload`, or as read back from ``events.jsonl``).

        Returns
        -------
        str
            The sentence.
        """
        raise NotImplementedError

    def log_line(self, tau: int) -> tuple | None:
        """``(level, message)`` the runtime logs when it applies the fault (None: the event says it).

        Parameters
        ----------
        tau : int
            The event time the fault applies at.

        Returns
        -------
        tuple of (str, str) or None
            ``(level, message)`` with ``level`` a logging level name (``"warning"``, ``"info"``); the base
            returns None.
        """
        return None

    def plot_mark(self) -> tuple | None:
        """``(plot mark kind, words)`` on the error plots (:func:`splitspec_core.simulation.metrics.event_marks`).

        Returns
        -------
        tuple of (str, str) or None
            ``(mark kind, words)``, e.g. ``("arc", "1-3 down")``; the base returns None (no mark of its own).
        """
        return None

    def end(self, at: float) -> "Fault":
        """The fault that ends this one at ``at`` (the kind :attr:`ends_with`, on the same agent or arc).

        Parameters
        ----------
        at : float
            The end's time.

        Returns
        -------
        Fault
            A fault of the kind ``ends_with`` names, with this fault's fields that kind has (the agent or
            the arc).

        Examples
        --------
        >>> make_fault("drop_arc", 2.0, arc=(1, 3)).end(5.0)
        RestoreArc(at=5.0, arc=(1, 3))
        """
        cls = KINDS[self.ends_with]
        return cls(at=at, **{f.name: getattr(self, f.name) for f in dataclasses.fields(cls) if f.name != "at"})


def register(cls: type) -> type:
    """Register a kind under its ``action`` and aliases (a class decorator).

    Parameters
    ----------
    cls : type
        A frozen dataclass, subclass of :class:`Fault`, with its own ``action``.

    Returns
    -------
    type
        ``cls``, now buildable (:meth:`Fault.__post_init__` refuses a kind nobody registered).
    """
    if cls.runtime not in (SIGNAL, RESTART, NETWORK, PLANT, ORCHESTRATOR):
        raise ValueError(f"fault kind {cls.__name__}: runtime {cls.runtime!r} is none of {SIGNAL}, {RESTART}, "
                         f"{NETWORK}, {PLANT}, {ORCHESTRATOR}")
    if cls.event is None or (cls.runtime in (SIGNAL, RESTART) and "agent" not in cls.__dataclass_fields__):
        raise ValueError(f"fault kind {cls.__name__} needs an event, and an agent when the runtime signals or "
                         "restarts it")
    if cls.runtime == SIGNAL and cls.signal not in ("SIGKILL", "SIGSTOP"):
        raise ValueError(f"fault kind {cls.__name__} signals its agent: its signal must be SIGKILL or SIGSTOP")
    for word in (cls.action, *cls.aliases):
        if word in _WORDS:
            raise ValueError(f"fault action {word!r} is registered twice")
        _WORDS[word] = cls
    KINDS[cls.action] = cls
    if cls.event is not None:
        _EVENTS.setdefault(cls.event, cls)
    return cls


def make_fault(action: str, at: float, **fields) -> Fault:
    """A fault of a registered kind, built directly (the parser builds them from the scenario's mapping).

    Parameters
    ----------
    action : str
        The kind's action or one of its aliases (``kill``, ``hang``, ``drop_arc``, ...).
    at : float
        The fault's time.
    **fields
        The kind's fields (``agent=3``, ``arc=(1, 2)``, ``groups=((1, 2),)``, ...).

    Returns
    -------
    Fault
        An instance of the registered kind.

    Raises
    ------
    ScenarioError
        ``unknown fault action 'x' (the kinds: kill, restart, ...)``.

    Examples
    --------
    >>> make_fault("hang", 3, agent=2)
    Freeze(at=3.0, agent=2)
    """
    cls = _WORDS.get(action)
    if cls is None:
        raise ScenarioError(f"unknown fault action {action!r} (the kinds: {', '.join(KINDS)})")
    return cls(at=float(at), **fields)


def kind_of_event(event: str) -> type | None:
    """The kind a replay makes of a recorded event.

    Parameters
    ----------
    event : str
        The event word of ``events.jsonl`` (``agent_lost``, ``arc_dropped``, ...).

    Returns
    -------
    type or None
        The first registered kind that logs it (``agent_lost``: ``kill``), None when no kind does.
    """
    return _EVENTS.get(event)


def fault_event_text(event: str, fields: dict) -> str | None:
    """The text of a fault kind's own event in the ``events`` TextLog.

    Parameters
    ----------
    event : str
        The event word.
    fields : dict
        The event's fields (the kind's :meth:`Fault.payload`).

    Returns
    -------
    str or None
        The kind's :meth:`Fault.text`; None when no kind the runtime records logs this event.
    """
    for cls in KINDS.values():
        if cls.event == event and cls.runtime in (NETWORK, PLANT):
            return cls.text(fields)
    return None


def fault_marks() -> tuple:
    """The timeline marks the kinds declare (``orchestrator/viewer/blueprint.py`` builds its tables from them).

    Returns
    -------
    tuple of dict
        ``({event: mark kind}, {mark kind: (legend, marker, colour)})``: the second holds the mark kinds of the
        kinds' own (``sensor``); the others are the blueprint's (``lost``, ``fault``, ``partition``, ...).
    """
    of_event = {cls.event: cls.mark for cls in KINDS.values() if cls.event is not None and cls.mark is not None}
    styles = {cls.mark: cls.mark_style for cls in KINDS.values() if cls.mark_style is not None}
    return of_event, styles


# ---------------------------------------------------------------------------------------------------- the kinds


def _event_agent(e: dict, where: str, ids: tuple) -> int:
    aid = e.get("id")
    if aid not in ids:
        raise ScenarioError(f"{where} names agent {aid!r}, which is not in the scenario (agents {ids_text(ids)}): "
                            "wrong scenario?")
    return aid


@dataclass(frozen=True)
class _AgentFault(Fault):
    """A fault on one agent (``{at: T, <action>: I}``)."""

    agent: int = 0

    @classmethod
    def parse(cls, value, fmap, key, ctx):
        return {"agent": check_known_agent(value, f"{key}.{cls.action}", ctx.ids)}

    @classmethod
    def from_event(cls, e, where, ids):
        return {"agent": _event_agent(e, where, ids)}

    def payload(self, tau):
        return {"id": self.agent, "tau": tau}


@register
@dataclass(frozen=True)
class Kill(_AgentFault):
    """``kill: I``: agent I takes no part from the step on; the runtime sends SIGKILL to its process."""

    action = "kill"
    ends_with, runtime, event, mark, loss_word = "restart", SIGNAL, "agent_lost", "lost", "killed"
    signal = "SIGKILL"

    def apply(self, net):
        """Agent ``agent`` is lost (no change if it already is)."""
        i = net.ids.index(self.agent)
        return ([i] if net.lose(i) else []), []


@register
@dataclass(frozen=True)
class Restart(_AgentFault):
    """``restart: I``: a lost agent rejoins with a fresh estimate (its next incarnation); ignored if alive."""

    action, runtime, event, mark = "restart", RESTART, "agent_rejoined", "rejoined"

    def apply(self, net):
        """Agent ``agent`` rejoins with its next incarnation (no change if it is alive)."""
        i = net.ids.index(self.agent)
        inc = net.rejoin(i)
        return [], ([] if inc is None else [(i, inc)])


@register
@dataclass(frozen=True)
class Freeze(Kill):
    """``freeze: I`` (``hang``, its older spelling): as a kill in the simulator; the runtime sends SIGSTOP."""

    action, aliases, loss_word = "freeze", ("hang",), "frozen"
    signal, keeps_process = "SIGSTOP", True


@dataclass(frozen=True)
class _ArcFault(Fault):
    """A fault on one arc ``[j, i]`` of every graph (with Metropolis weights, the link in both directions)."""

    arc: tuple = ()
    verdict: ClassVar[bool] = True
    mark: ClassVar[str] = "fault"

    @classmethod
    def parse(cls, value, fmap, key, ctx):
        arc = check_arc(value, f"{key}.{cls.action}", ctx.ids)
        if arc[0] == arc[1]:
            raise ScenarioError(f"{key}.{cls.action} [{arc[0]}, {arc[1]}] is a self-arc: self-arcs are implicit "
                                "and cannot be dropped or restored")
        return {"arc": arc}

    @classmethod
    def from_event(cls, e, where, ids):
        arc = e.get("arc")
        if not (isinstance(arc, list) and len(arc) == 2 and all(a in ids for a in arc)):
            raise ScenarioError(f"{where} has a bad 'arc' {arc!r}")
        return {"arc": (arc[0], arc[1])}

    def payload(self, tau):
        return {"arc": list(self.arc), "tau": tau}

    def plot_mark(self):
        return "arc", f"{self.arc[0]}-{self.arc[1]} {'down' if self.action == 'drop_arc' else 'up'}"


@register
@dataclass(frozen=True)
class DropArc(_ArcFault):
    """``drop_arc: [j, i]``: the arc is removed from every graph."""

    action, ends_with, event = "drop_arc", "restore_arc", "arc_dropped"

    def apply(self, net):
        """Add ``arc`` to the dropped arcs."""
        net.dropped.add(self.arc)
        return [], []

    @staticmethod
    def text(fields):
        """``arc j -> i dropped``."""
        j, i = fields.get("arc", ("?", "?"))
        return f"arc {j} -> {i} dropped"


@register
@dataclass(frozen=True)
class RestoreArc(_ArcFault):
    """``restore_arc: [j, i]``: the arc comes back."""

    action, event = "restore_arc", "arc_restored"

    def apply(self, net):
        """Remove ``arc`` from the dropped arcs."""
        net.dropped.discard(self.arc)
        return [], []

    @staticmethod
    def text(fields):
        """``arc j -> i restored``."""
        j, i = fields.get("arc", ("?", "?"))
        return f"arc {j} -> {i} restored"


@register
@dataclass(frozen=True)
class Partition(Fault):
    """``partition: [[ids], [ids]]``: no consensus message crosses between the groups (agents named in no group
    form one more group) until a ``heal``."""

    groups: tuple = ()
    action, ends_with, event, mark = "partition", "heal", "partition", "partition"
    drops_messages = True

    @classmethod
    def parse(cls, value, fmap, key, ctx):
        """``groups`` from the list of lists of agent ids."""
        return {"groups": parse_groups(value, f"{key}.partition", ctx.ids)}

    @classmethod
    def from_event(cls, e, where, ids):
        """``groups`` from the event's ``groups`` (a non-empty list of lists of known ids)."""
        groups = e.get("groups")
        if not (isinstance(groups, list) and groups and all(isinstance(g, list) and all(a in ids for a in g)
                                                            for g in groups)):
            raise ScenarioError(f"{where} has bad 'groups' {groups!r}")
        return {"groups": tuple(tuple(g) for g in groups)}

    def apply(self, net):
        """Set the network's partition groups to ``groups``."""
        net.groups = self.groups
        return [], []

    def payload(self, tau):
        """``{"groups": [[ids], ...], "tau": tau}``."""
        return {"groups": [list(g) for g in self.groups], "tau": tau}

    @staticmethod
    def text(fields):
        """``partition 1 2 | 3: ...``, the groups separated by bars."""
        return ("partition " + " | ".join(" ".join(str(a) for a in g) for g in fields["groups"])
                + ": no consensus message crosses between the groups")

    def log_line(self, tau):
        """A warning naming the groups."""
        return "warning", (f"event time {tau}: partition {[list(g) for g in self.groups]}: no consensus message "
                           "crosses between the groups until a heal")


@register
@dataclass(frozen=True)
class Heal(Fault):
    """``heal: true``: the partition in force ends."""

    action, event, mark = "heal", "healed", "healed"

    @classmethod
    def parse(cls, value, fmap, key, ctx):
        """No fields; the value must be ``true``."""
        if value is not True:
            raise ScenarioError(f"{key}.heal must be true (it ends every partition), got {describe(value)}")
        return {}

    def apply(self, net):
        """End the partition in force (the network's groups become None)."""
        net.groups = None
        return [], []

    @staticmethod
    def text(fields):
        """``partition healed``."""
        return "partition healed"

    def log_line(self, tau):
        """An info line: the partition is healed."""
        return "info", f"event time {tau}: the partition is healed"


def _per_output(value: Any, key: str, n: int | None, *, std: bool = False) -> float | tuple:
    """``bias`` or ``noise`` (``std``: each >= 0, not all 0): one number for every output, or a list of one per
    output (``n`` of them, when known)."""
    if isinstance(value, list):
        if n is not None and len(value) != n:
            raise ScenarioError(f"{key} has {len(value)} values; the agent has {n} output{'s' if n != 1 else ''} "
                                "(give one number for all, or one per output)")
        out = tuple(check_number(v, f"{key}[{k + 1}]") for k, v in enumerate(value))
    else:
        out = check_number(value, key)
    if std:
        values = out if isinstance(out, tuple) else (out,)
        if any(v < 0 for v in values) or not any(v > 0 for v in values):
            raise ScenarioError(f"{key} must be a std > 0 (or one per output, each >= 0, not all 0), got "
                                f"{describe(value)}")
    return out


def _per_row(v, y: np.ndarray) -> np.ndarray:
    """``v`` (a number, or one per output) shaped to multiply or add to ``y`` (outputs on axis 0, seeds after)."""
    v = np.asarray(v, dtype=float)
    return v if v.ndim == 0 else v.reshape((-1,) + (1,) * (np.ndim(y) - 1))


@register
@dataclass(frozen=True)
class Corrupt(_AgentFault):
    """``corrupt: I`` with ``bias: b`` (a number, or a list of one per output of agent I) and/or ``scale: k``, or
    ``stuck: true``, and/or ``noise: s`` (a std, or one per output): from the step on, agent I is given
    ``k y_i + b + s w`` (stuck: ``y_i^held + s w``) instead of its measurement ``y_i``, until a ``repair``
    (``for: S`` writes it).  ``y_i^held`` is the last measurement agent I was given before the fault (its
    first, for a fault at the first step); ``w`` standard normals of the ``sensor_noise`` stream
    (:class:`splitspec_core.model.network.SensorDraws`).  A stuck sensor refuses ``bias`` and ``scale`` (a held value
    shifted or scaled is just another held value).  The plant process applies it in ``run``, as the simulator
    does."""

    bias: float | tuple | None = None
    scale: float | None = None
    stuck: bool = False
    noise: float | tuple | None = None
    action, options, ends_with, runtime = "corrupt", ("bias", "scale", "stuck", "noise"), "repair", PLANT
    event, mark, mark_style = "sensor_corrupted", "sensor", ("sensor fault", "Square", (227, 119, 194))

    @property
    def holds_last(self) -> bool:
        """bool: a stuck sensor holds the agent's last measurement."""
        return self.stuck

    @classmethod
    def _fields(cls, fmap: dict, key: str, n: int | None, dot: str) -> dict:
        """``bias``, ``scale``, ``stuck`` and ``noise`` of a scenario entry or an event (``dot``: ``key.`` or "")."""
        if "stuck" in fmap and fmap["stuck"] is not True:
            raise ScenarioError(f"{dot}stuck must be true (the sensor holds its last value), got "
                                f"{describe(fmap['stuck'])}")
        if "stuck" in fmap and ("bias" in fmap or "scale" in fmap):
            raise ScenarioError(f"{dot}stuck does not go with bias or scale (a stuck sensor gives its held value; "
                                "noise: s may be added to it)")
        return {"bias": None if fmap.get("bias") is None else _per_output(fmap["bias"], f"{dot}bias", n),
                "scale": None if fmap.get("scale") is None else check_number(fmap["scale"], f"{dot}scale"),
                "stuck": "stuck" in fmap,
                "noise": None if fmap.get("noise") is None else _per_output(fmap["noise"], f"{dot}noise", n,
                                                                            std=True)}

    @classmethod
    def parse(cls, value, fmap, key, ctx):
        """``agent``, ``bias`` and ``noise`` (checked against the agent's number of outputs), ``scale`` and
        ``stuck``; one of them needed, ``stuck`` without ``bias`` or ``scale``."""
        agent = check_known_agent(value, f"{key}.corrupt", ctx.ids)
        if not any(o in fmap for o in cls.options):
            raise ScenarioError(f"{key}.corrupt needs bias: b (added to agent {agent}'s outputs), scale: k "
                                "(multiplying them), stuck: true (holding the last value) or noise: s (an extra "
                                "noise std)")
        n = None if ctx.outputs is None else ctx.outputs.get(agent)
        return {"agent": agent, **cls._fields(fmap, key, n, f"{key}.")}

    @classmethod
    def from_event(cls, e, where, ids):
        """``agent``, ``bias``, ``scale``, ``stuck`` and ``noise`` from the event (absent ones None, not stuck)."""
        try:
            return {"agent": _event_agent(e, where, ids),
                    **cls._fields({k: e[k] for k in cls.options if e.get(k) is not None}, "", None, "")}
        except ScenarioError as exc:
            raise ScenarioError(f"{where}: {exc}") from None

    def apply(self, net):
        """Put the agent's sensor under this fault (a fresh memory), replacing a fault in force on it."""
        net.put_sensor(net.ids.index(self.agent), self)
        return [], []

    def measure(self, y, memo):
        # y_i -> k y_i + b + s w, or y_i^held + s w (b and s one number, or one per output: outputs on axis 0,
        # any seeds after)
        """``k y_i + b + s w`` (no scaling when ``scale`` is None, no bias when ``bias`` is None, no noise when
        ``noise`` is None), stuck: ``memo["before"] + s w``; ``w`` from ``memo["draws"]``, every step."""
        if self.stuck:
            out = np.array(memo["before"], dtype=float)
        else:
            out = y if self.scale is None else y * self.scale
            out = out if self.bias is None else out + _per_row(self.bias, y)
        if self.noise is None:
            return out
        return out + _per_row(self.noise, y) * memo["draws"].normal(np.shape(y)[0])

    def payload(self, tau):
        """``{"id", "tau"}`` and the ``bias`` and ``noise`` (a list per output), ``scale`` and ``stuck`` that are
        set."""
        how = {"stuck": True if self.stuck else None, "scale": self.scale,
               **{k: list(v) if isinstance(v, tuple) else v for k, v in (("bias", self.bias), ("noise", self.noise))}}
        return {"id": self.agent, "tau": tau, **{k: v for k, v in how.items() if v is not None}}

    @staticmethod
    def text(fields):
        """``agent I's measurements corrupted (stuck, scale k, bias b, noise s)``, the options set."""
        how = (["stuck"] if fields.get("stuck") else []) + [f"{k} {fields[k]}" for k in ("scale", "bias", "noise")
                                                           if fields.get(k) is not None]
        return f"agent {fields.get('id', '?')}'s measurements corrupted ({', '.join(how)})"

    def log_line(self, tau):
        """A warning with the event's text."""
        return "warning", f"event time {tau}: {self.text(self.payload(tau))} by the scenario"

    def plot_mark(self):
        """``("fault", "sensor I corrupted")``."""
        return "fault", f"sensor {self.agent} corrupted"


@register
@dataclass(frozen=True)
class Repair(_AgentFault):
    """``repair: I``: agent I's sensor fault ends; it is given its true measurement again."""

    action, runtime, event, mark = "repair", PLANT, "sensor_repaired", "sensor"

    def apply(self, net):
        """Take the agent's sensor fault out of force (no change if none is)."""
        net.sensors.pop(net.ids.index(self.agent), None)
        return [], []

    @staticmethod
    def text(fields):
        """``agent I's sensor repaired``."""
        return f"agent {fields.get('id', '?')}'s sensor repaired"

    def log_line(self, tau):
        """An info line with the event's text."""
        return "info", f"event time {tau}: {self.text(self.payload(tau))}"

    def plot_mark(self):
        """``("fault", "sensor I repaired")``."""
        return "fault", f"sensor {self.agent} repaired"


# ---------------------------------------------------------------------------------------------------- parsing


@register
@dataclass(frozen=True)
class KillOrchestrator(Fault):
    """``kill: orchestrator`` (also ``kill_orchestrator: true``): the run's active orchestrator is SIGKILLed at the
    step; with ``run.standby: true`` its standby takes over, else the run ends there.  No effect on the estimates
    (the simulator ignores it).  The k-th of a scenario's orchestrator kills is the orchestrator of epoch k's: a
    standby that takes over does not kill itself again at a step it replays."""

    action, runtime, event, mark = "kill_orchestrator", ORCHESTRATOR, "orchestrator_killed", "takeover"
    mark_style = ("orchestrator killed, taken over", "Right", (127, 127, 127))

    @classmethod
    def parse(cls, value, fmap, key, ctx):
        if value not in (True, "orchestrator"):
            raise ScenarioError(f"{key}.{cls.action} must be true (or write kill: orchestrator), got {value!r}")
        return {}

    @staticmethod
    def text(fields):
        return f"the orchestrator killed by the scenario at event time {fields['tau']}"


FAULT_ACTIONS = tuple(KINDS)  #: the registered actions (the kinds above), in order
FAULT_ALIASES = {a: cls.action for cls in KINDS.values() for a in cls.aliases}  #: older spellings -> the action


def parse_faults(raw: Any, ids: tuple, *, outputs: dict | None = None) -> tuple:
    """A scenario's ``faults:`` list (or ``ss.run``'s and ``ss.simulate``'s ``faults=``) for agents ``ids``.

    Parameters
    ----------
    raw : list of mapping or None
        ``[{at: T, <action>: value, [for: S], [options]}, ...]``.
    ids : tuple of int
        The scenario's agent ids.
    outputs : dict, optional
        ``{agent id: s_i}``, for the kinds that check a value per output.

    Returns
    -------
    tuple of Fault
        The faults sorted by time (stable), each ``for: S`` expanded into its end at ``at + S``.

    Raises
    ------
    ScenarioError
        One line naming the entry and key that is wrong (an unknown action names the registered kinds).

    Examples
    --------
    >>> for f in parse_faults([{"at": 10, "kill": 3, "for": 5}, {"at": 2, "drop_arc": [1, 2]}], (1, 2, 3)):
    ...     print(f)
    DropArc(at=2.0, arc=(1, 2))
    Kill(at=10.0, agent=3)
    Restart(at=15.0, agent=3)
    """
    if raw is None:
        return ()
    if not isinstance(raw, list):
        raise ScenarioError(f"faults must be a list of {{at: T, <action>: ...}}, got {describe(raw)}")
    ctx = FaultContext(tuple(ids), outputs)
    known = ("at", "for", *_WORDS, *dict.fromkeys(o for cls in KINDS.values() for o in cls.options))
    out = []
    for k, item in enumerate(raw):
        key = f"faults[{k + 1}]"
        fmap = require_map(item, key)
        check_keys(fmap, known, key)
        if "at" not in fmap:
            raise ScenarioError(f"{key}.at is missing (the time of the fault)")
        at = check_number(fmap["at"], f"{key}.at")
        if at < 0:
            raise ScenarioError(f"{key}.at must be >= 0, got {at:g}")
        words = [w for w in _WORDS if w in fmap]
        if len(words) != 1:
            raise ScenarioError(f"{key} needs exactly one of {', '.join(FAULT_ACTIONS)}")
        cls = _WORDS[words[0]]
        if cls is Kill and fmap[words[0]] == "orchestrator":  # kill: orchestrator
            cls = KillOrchestrator
        for o in fmap:
            if o not in ("at", "for", words[0]) and o not in cls.options:
                raise ScenarioError(f"{key}.{o} does not go with {cls.action} (its keys: at, {cls.action}, "
                                    + ", ".join((*cls.options, *(("for",) if cls.ends_with else ()))) + ")")
        fault = cls(at=at, **cls.parse(fmap[words[0]], {**fmap, cls.action: fmap[words[0]]}, key, ctx))
        out.append(fault)
        if "for" in fmap:
            if cls.ends_with is None:
                raise ScenarioError(f"{key}.for: a {cls.action} has no end (for: goes with "
                                    + ", ".join(a for a, c in KINDS.items() if c.ends_with) + ")")
            span = check_number(fmap["for"], f"{key}.for")
            if not span > 0:
                raise ScenarioError(f"{key}.for must be > 0 (the seconds or event times until the "
                                    f"{cls.ends_with}), got {span:g}")
            out.append(fault.end(at + span))
    out = tuple(sorted(out, key=lambda f: f.at))
    check_heals(out)
    return out
