"""The scenario's keys, declared once: for each key of the file's top level, ``system:``, ``graphs:``,
``switching:``, ``design:`` (and ``design.riccati:``), ``run:`` and ``network:``, its kind, default, allowed words
and doc line (a fault's keys are its kind's: :mod:`splitspec_core.scenarios.faults` where it exists).

Everything else is derived from these tables: the keys each section accepts (``checks.TOP_KEYS``,
``SYSTEM_KEYS``, ``DESIGN_KEYS``, ``RUN_KEYS``, ...: an unknown key is one line naming it), the words of the word-valued keys and their
defaults (``checks.DESIGN_CHOICES``), the reading of a plain number, integer or word with its default and its
one-line message (:func:`splitspec_core.scenarios.checks.read`), the keywords ``ss.scenario`` routes to each section
(a test checks its signature against them) and the reference table of ``docs/how-to/scenario.md``
(:func:`reference_table`; a test fails when the page differs, so a key added here without its doc line on the page
fails).  Rules that join several keys or depend on ``time`` (``design.rate`` in (0, 1) for discrete time) stay in
the section parsers, each with its reason.

Kinds: ``number`` (a finite float), ``integer``, ``word`` (one of ``words``), ``number|word`` and ``integer|word``
(a number, or one of ``words``), ``map|word`` (a map, or one of ``words``), ``matrix``, ``per agent`` (``{agent id: ...}``), ``names``, ``noise``,
``signal``, ``path``, ``map``, ``list``, ``text``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from . import gain_methods

__all__ = ["Key", "REQUIRED", "TOP", "SYSTEM", "GRAPH", "SWITCHING", "RANDOM", "DESIGN", "RICCATI", "BAD_DATA", "RUN", "KEEP", "NETWORK",
           "DELAY", "NETWORK_ARC", "SECTIONS", "dotted", "names", "choices", "reference_table"]


class _Required:
    """The default of a key that has none: the section refuses to go without it."""

    def __repr__(self) -> str:
        return "required"


REQUIRED = _Required()


@dataclass(frozen=True)
class Key:
    """One scenario key: its ``name`` in its section, ``kind`` (module docstring), ``default`` (None: absent, the
    parser decides; :data:`REQUIRED`: it must be given), the ``words`` it may take, its ``minimum`` (integers) and its
    one-line ``doc``."""

    name: str
    kind: str
    default: Any
    doc: str
    words: tuple = ()
    minimum: int | None = None


TOP = (
    Key("name", "text", None, "the scenario's name (default: the file name)"),
    Key("time", "word", "discrete", "discrete (x+ = A x + v) or continuous (x' = A x + v)",
        words=("discrete", "continuous")),
    Key("system", "map", REQUIRED, "the plant and each agent's outputs (system.*)"),
    Key("graphs", "map", REQUIRED, "named neighbour graphs, each {arcs, undirected}; self-arcs are implicit"),
    Key("switching", "map", None, "which graph when (switching.*); default: the first graph forever"),
    Key("design", "map", REQUIRED, "the rate, the gains and the consensus's certificate (design.*)"),
    Key("faults", "list", None, "scheduled faults [{at: T, kind: operand}], for simulate and run alike"),
    Key("run", "map", None, "the run's length, step, seed and pace (run.*)"),
    Key("positions", "per agent", None, "where run.rrd draws each agent in the topology view: [x, y] per agent"),
    Key("network", "map", None, "what happens to consensus messages (network.*); default: a perfect network"),
    Key("sources", "per agent", None, "run only: live sensors instead of a simulated plant (needs run.pace)"),
)

SYSTEM = (
    Key("file", "path", None, "a .npz or .mat beside the scenario file; a string where a matrix goes names an array "
                              "of it"),
    Key("A", "matrix", REQUIRED, "n x n, finite numbers"),
    Key("B", "matrix", None, "n x p: known inputs (x+ = A x + B u, x' = A x + B u)"),
    Key("u", "signal", None, "the input signal: a constant, or {constant, steps, sine}"),
    Key("sample", "number", None, "time: discrete only: A (and B) are a continuous model sampled with this period "
                                  "(zero-order hold)"),
    Key("C", "per agent", REQUIRED, "one s_i x n matrix per agent, keyed by agent id (positive integers)"),
    Key("x0", "matrix", None, "the initial state (n numbers); default: drawn from the seed"),
    Key("process_noise", "noise", 0.0, "std of v (discrete) or its intensity (continuous); or n of them, or the "
                                       "n x n matrix"),
    Key("measurement_noise", "noise", 0.0, "std of each measurement noise sample; or {agent id: std or [one per "
                                           "output]}"),
    Key("states", "names", None, "n state names, in every message, report, plot and record"),
    Key("outputs", "per agent", None, "names of agent i's outputs (s_i names per agent listed)"),
    Key("time_unit", "text", "s", "the unit of the model's time (system.sample, run.dt, a continuous rate per it): "
                                  "printed after every such time and as 1/unit after rates; a short word (s, min, "
                                  "h, ms); the run's wall clock stays in seconds"),
)

GRAPH = (
    Key("arcs", "list", None, "[j, i]: agent i hears agent j"),
    Key("undirected", "list", None, "[i, j]: shorthand for both arcs"),
)

SWITCHING = (
    Key("schedule", "list", None, "pieces [start, graph], the first at 0 (exactly one of schedule or random)"),
    Key("period", "number", None, "repeat the schedule every period"),
    Key("random", "map", None, "Poisson switching among graphs with a mean dwell (switching.random.*)"),
)

RANDOM = (
    Key("graphs", "list", None, "the graphs it switches among (default: every graph)"),
    Key("dwell", "number", REQUIRED, "the mean dwell time"),
    Key("seed", "integer", None, "its own seed (default: a stream of run.seed)"),
)

DESIGN = (
    Key("rate", "number", REQUIRED, "lambda: continuous > 0 (exp(-lambda t)); discrete in (0, 1) (lambda^tau)"),
    Key("gains", "word", gain_methods.DEFAULT, "the gain method (default: optimal when the system states noise, "
                                               "else place)", words=gain_methods.NAMES),
    Key("K", "per agent", None, "gains that take the user's K_i (explicit): one n x s_i matrix per agent"),
    Key("g", "number|word", "auto", "continuous: the consensus gain", words=("auto", "adaptive")),
    Key("g0", "number", 0.0, "adaptive: the initial g_i"),
    Key("q", "integer|word", "auto", "discrete, and the whole-state design in continuous time: exchanges per event "
                                     "time (per run.dt)", words=("auto",), minimum=1),
    Key("q_method", "word", "spectral", "the certificate q is chosen by",
        words=("spectral", "weighted", "two-norm", "mixed")),
    Key("q_max", "integer", 100_000, "search limit for q", minimum=1),
    Key("resilience", "integer", 0, "1: g or q also certified after any single agent loss", minimum=0),
    Key("weights", "word", "uniform", "consensus weights: uniform (S = D^-1 Adj') or metropolis (undirected graphs, "
                                      "doubly stochastic)", words=("uniform", "metropolis")),
    Key("margin", "number", 0.5, "how far beyond the rate the margin-using gains aim"),
    Key("rank_tol", "number|word", "auto", "smallest observability margin an agent counts as seen (auto: 1e-3)",
        words=("auto",)),
    Key("graph_set", "word", "scenario", "the graphs certified: the scenario's, or every strongly connected graph on "
                                         "m <= 4 vertices", words=("scenario", "all")),
    Key("dwell", "number", None, "average dwell time for the continuous switching bound (default: from switching)"),
    Key("riccati", "map", None, "{process_weight, measurement_weight}: the Riccati weights (default: the noise levels "
                                "squared, else 1)"),
    Key("eigenvalues", "word", "auto", "spectral q's radii (iterative: matrix-free ARPACK; auto above 300 unknowns)",
        words=("auto", "dense", "iterative")),
    Key("undetectable", "word", "refuse", "a mode no agent sees that does not decay: refused, or left out of the "
                                          "certificate", words=("refuse", "exclude")),
    Key("coordinates", "word", "auto", "the coordinates the gains are computed in (auto: balanced when the balancing "
                                       "scales span more than 100x)", words=("auto", "given", "balanced")),
    Key("consensus", "word", "auto", "what each agent takes from its neighbours (auto: the split, but for gains: "
                                     "optimal, which keeps the certified one with the smaller noise; fusion: "
                                     "estimates fused with matrix weights chosen for the noise; relay: the sensors' "
                                     "samples passed on, each agent the Kalman predictor of what it holds)",
        words=("auto", "split", "whole", "fusion", "relay")),
    Key("lag", "integer|word", "auto", "the relay kind: event times its base stays behind beyond the network's delay "
                                       "(its walk's Kalman steps recover the accuracy the rate's shift costs, at a "
                                       "larger transient constant; auto: where that stops paying)", words=("auto",),
        minimum=0),
    Key("bad_data", "map|word", None, "each agent tests its measurement against its prediction and sets a failing one "
                                      "aside: off (or false), on (or true: the defaults below), or {false_alarm, "
                                      "suspect_after} (design.bad_data.*; needs measurement noise); default: on when "
                                      "the scenario states measurement noise, else off", words=("off", "on")),
)

BAD_DATA = (
    Key("false_alarm", "number", 1e-5, "the test's false-alarm probability per agent and event time, in (0, 0.5)"),
    Key("suspect_after", "integer", 3, "tests failed in a row that make a sensor suspect (its agent then estimates "
                                       "from its neighbours alone), and clean ones that restore it", minimum=1),
)

RICCATI = (
    Key("process_weight", "number", None, "the process weight, an identity multiple (>= 1e-12)"),
    Key("measurement_weight", "number", None, "the measurement weight, an identity multiple (>= 1e-12)"),
)

RUN = (
    Key("steps", "integer", 60, "event times (discrete) or number of dt steps (continuous)", minimum=1),
    Key("dt", "number", 0.01, "continuous only: the step"),
    Key("seed", "integer", 0, "every random draw's seed (0 .. 2**63 - 1)"),
    Key("pace", "number", None, "run only: event times per second (default unpaced)"),
    Key("show", "names", None, "the states the default views show: names or patterns"),
    Key("keep", "map", None, "run until stopped only: {hours, gigabytes}, the records kept on disk; the oldest closed "
                             "segments are removed as the run goes (run.keep.*); default: everything"),
    Key("record_every", "integer", None, "run only: the Rerun recording's state panels every this many event times "
                                         "(errors, events and marks every one); default 1, a run until stopped at "
                                         "a pace over 10: the event times of 0.1 s", minimum=1),
    Key("standby", "boolean", False, "run only: a standby orchestrator follows the run and takes over when the "
                                     "active one dies (a router of its own; agents and plant outlive it)"),
)

KEEP = (
    Key("hours", "number", None, "remove a closed segment this many hours (wall time) after it closed"),
    Key("gigabytes", "number", None, "remove the oldest closed segments while the records take more (10^9 bytes)"),
    Key("recording_hours", "number", None, "the Rerun recording's segments (run*.rrd) this many hours instead of "
                                           "hours: a longer review, thinned by run.record_every"),
    Key("segment_mb", "number", None, "MiB past which a segment closes, row chunks and recording alike (default 64 "
                                      "and 256): only closed segments are removed, so a short run removes nothing "
                                      "unless its segments are small"),
)

NETWORK = (
    Key("loss", "number", 0.0, "probability that one consensus message does not count, in [0, 1)"),
    Key("delay", "map", None, "{mean, jitter}: seconds each message is held in run (network.delay.*)"),
    Key("deadline", "number", None, "seconds a sub-round waits for its neighbours, then goes on without the missing "
                                    "ones"),
    Key("arcs", "list", None, "per-arc overrides [{arc: [j, i], loss, delay}] (network.arcs[k].*)"),
)

DELAY = (
    Key("mean", "number", 0.0, "seconds added to every message"),
    Key("jitter", "number", 0.0, "uniform spread around the mean (never negative in total)"),
)

NETWORK_ARC = (
    Key("arc", "list", REQUIRED, "[j, i], an arc of some graph"),
    Key("loss", "number", None, "this arc's loss probability"),
    Key("delay", "map", None, "this arc's {mean, jitter}"),
)

#: ``{section: its keys}``: the sections whose keys are declared here ("" the file's top level)
SECTIONS = {"": TOP, "system": SYSTEM, "graphs.<name>": GRAPH, "switching": SWITCHING, "switching.random": RANDOM,
            "design": DESIGN, "design.riccati": RICCATI, "design.bad_data": BAD_DATA, "run": RUN, "run.keep": KEEP, "network": NETWORK, "network.delay": DELAY,
            "network.arcs[k]": NETWORK_ARC}


def dotted(section: str, name: str) -> str:
    """``design.rate``; a top-level key by its name alone.

    Parameters
    ----------
    section, name : str
        A key of :data:`SECTIONS`, and the key's name in it.

    Returns
    -------
    str
        The key's dotted name, as every message names it.

    Examples
    --------
    >>> dotted("design", "rate"), dotted("", "time")
    ('design.rate', 'time')
    """
    return f"{section}.{name}" if section else name


def names(keys: tuple) -> tuple:
    """The names of ``keys``, in declaration order.

    Parameters
    ----------
    keys : tuple of Key
        A section's declaration.

    Returns
    -------
    tuple of str
        The keys the section accepts.

    Examples
    --------
    >>> names(RUN)
    ('steps', 'dt', 'seed', 'pace', 'show', 'keep', 'record_every', 'standby')
    """
    return tuple(k.name for k in keys)


def choices(keys: tuple) -> dict:
    """``{name: (words, default)}`` of the word-valued keys of ``keys``.

    Parameters
    ----------
    keys : tuple of Key
        A section's declaration.

    Returns
    -------
    dict
        ``{name: (words, default)}`` of the keys of kind ``word`` only (a ``number|word`` key such as ``design.g`` is
        not among them).

    Examples
    --------
    >>> choices(DESIGN)["weights"]
    (('uniform', 'metropolis'), 'uniform')
    """
    return {k.name: (k.words, k.default) for k in keys if k.kind == "word"}


def reference_table() -> str:
    """The reference table of every declared key (``docs/how-to/scenario.md``, "Every key"): one row per key with its
    kind, default, words and doc line, and one per gain method with its doc line.

    Returns
    -------
    str
        Markdown, one line per row, ending with a newline.
    """
    rows = ["| key | kind | default | values | what |", "|---|---|---|---|---|"]
    for section, keys in SECTIONS.items():
        for k in keys:
            default = "" if k.default is None else f"`{k.default!r}`".replace("'", "")
            words = " \\| ".join(f"`{w}`" for w in k.words)
            rows.append(f"| `{dotted(section, k.name)}` | {k.kind.replace('|', ' or ')} | {default} | {words} | "
                        f"{k.doc} |")
            if section == "design" and k.name == "gains":  # each method's own line (scenarios/gain_methods.py)
                rows += [f"| `design.gains: {g.name}` | | | | {g.doc} |" for g in gain_methods.METHODS.values()]
    return "\n".join(rows) + "\n"
