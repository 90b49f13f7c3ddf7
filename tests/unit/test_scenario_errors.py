"""Bad scenario input through ``splitspec design FILE``: one clear line, exit 2, no traceback.

Contract (``../shared/DESIGN.md``, "Scenario file"): bad input gets one line on
stderr naming the key and the reason, a non-zero exit, never a traceback.

Every case runs through ``splitspec_orchestrator.cli.main`` in-process (fast; an escaping
exception fails the test with its traceback); a handful also run the real CLI
in a subprocess (``python -m splitspec_orchestrator design FILE``).
"""

from __future__ import annotations

import copy
import json
import math
import os
import resource
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from splitspec_orchestrator import cli
from splitspec_core.scenarios.checks import GAIN_METHODS
from splitspec_core.synthesis.spectral import certifies

ROOT = Path(__file__).resolve().parents[2]
EXAMPLE = ROOT / "examples" / "paper_discrete.yaml"
PREFIX = "splitspec: error: "

A4 = [[0, 1, 0, 0], [-1, 0, 0, 0], [0, 0, 0, 1], [0, 0, -2, 0]]

# Paper, Section 5: two oscillators, three agents (as examples/paper_discrete.yaml).
DISCRETE = {
    "name": "bad-input",
    "time": "discrete",
    "system": {
        "A": A4,
        "C": {1: [[1, 0, 0, 0]], 2: [[0, 1, 0, 0]], 3: [[0, 0, 1, 0]]},
    },
    "graphs": {
        "a": {"arcs": [[1, 2], [2, 1], [2, 3], [3, 2], [1, 3]]},
        "b": {"undirected": [[1, 2], [2, 3]]},
    },
    "design": {
        "rate": 0.5,
        "gains": "explicit",
        "K": {1: [[0.5], [0.94], [0], [0]], 2: [[-0.94], [0.5], [0], [0]], 3: [[0], [0], [0.5], [1.94]]},
        "q": "auto",
        "q_method": "spectral",
    },
    "run": {"steps": 40, "seed": 7},
}

# Paper, Section 5 (continuous dynamics), as examples/paper_continuous.yaml.
CONTINUOUS = {
    "name": "bad-input-continuous",
    "time": "continuous",
    "system": copy.deepcopy(DISCRETE["system"]),
    "graphs": copy.deepcopy(DISCRETE["graphs"]),
    "design": {
        "rate": 1.0,
        "gains": "explicit",
        "K": {1: [[-5], [-5], [0], [0]], 2: [[5], [-5], [0], [0]], 3: [[0], [0], [-5], [-4]]},
        "g": 10,
    },
    "run": {"steps": 100, "dt": 0.01, "seed": 7},
}

DELETE = object()


def _key(part: str):
    return int(part) if part.isdigit() else part


def scenario(patch: dict | None = None, *, time: str = "discrete") -> str:
    """YAML text of the base scenario with ``patch`` applied.

    ``patch`` maps dotted keys (``"system.C.3"``, ``"design.rate"``) to a new
    value or ``DELETE``; digit parts are agent ids (integer keys).
    """
    data = copy.deepcopy(CONTINUOUS if time == "continuous" else DISCRETE)
    for dotted, value in (patch or {}).items():
        *parents, last = dotted.split(".")
        node = data
        for part in parents:
            node = node[_key(part)]
        if value is DELETE:
            del node[_key(last)]
        else:
            node[_key(last)] = value
    return yaml.safe_dump(data, sort_keys=False, default_flow_style=None)


def _missing_file(tmp_path: Path) -> Path:
    return tmp_path / "no-such-scenario.yaml"


def _directory(tmp_path: Path) -> Path:
    d = tmp_path / "scenario-dir.yaml"
    d.mkdir()
    return d


def _binary_file(tmp_path: Path) -> Path:
    p = tmp_path / "binary.yaml"
    p.write_bytes(b"\xff\xfe\x00\x81garbage\x00\xc3\x28")
    return p


def _fifo(tmp_path: Path) -> Path:
    """A FIFO nobody writes to: opening it for reading would block forever."""
    p = tmp_path / "scenario.fifo"
    os.mkfifo(p)
    return p


def _large_file(tmp_path: Path) -> Path:
    """A 17.3 MB scenario (a comment, then a valid scenario): refused by size before it is read."""
    p = tmp_path / "big.yaml"
    with open(p, "w", encoding="utf-8") as f:
        f.write(scenario())
        f.write("#" * 80 + "\n")
        f.truncate(17_300_000)
    return p


NOT_OBSERVABLE = scenario({"system.C.3": [[1, 0, 0, 0]], "design.gains": "place", "design.K": DELETE})

# (id, source, fragments): source is YAML text or a function tmp_path -> path;
# every fragment must appear in the one-line message.
CASES = [
    # --- missing matrices ------------------------------------------------------------------------
    ("A-missing", scenario({"system.A": DELETE}), ["system.A is missing"]),
    ("C-missing", scenario({"system.C": DELETE}), ["system.C is missing"]),
    ("system-missing", scenario({"system": DELETE}), ["system is missing"]),
    ("C-empty", scenario({"system.C": {}}), ["system.C has no agents"]),
    # --- non-numeric, NaN, inf entries -----------------------------------------------------------
    ("A-non-numeric", scenario({"system.A": [[0, 1, 0, 0], [-1, 0, "x", 0], [0, 0, 0, 1], [0, 0, -2, 0]]}),
     ["system.A[2][3]", "must be a number", "'x'"]),
    ("C-non-numeric", scenario({"system.C.2": [[0, "x", 0, 0]]}), ["system.C.2[1][2]", "must be a number", "'x'"]),
    ("A-nan", scenario({"system.A": [[math.nan, 1, 0, 0], [-1, 0, 0, 0], [0, 0, 0, 1], [0, 0, -2, 0]]}),
     ["system.A[1][1]", "must be finite", "nan"]),
    ("A-inf", scenario({"system.A": [[0, 1, 0, 0], [-1, 0, 0, 0], [0, 0, 0, 1], [0, 0, -math.inf, 0]]}),
     ["system.A[4][3]", "must be finite", "-inf"]),
    ("A-int-too-large", scenario({"system.A": [[0, 10**400, 0, 0], [-1, 0, 0, 0], [0, 0, 0, 1], [0, 0, -2, 0]]}),
     ["system.A[1][2]", "must be finite"]),
    ("C-nan", scenario({"system.C.1": [[1, 0, math.nan, 0]]}), ["system.C.1[1][3]", "must be finite", "nan"]),
    ("C-inf", scenario({"system.C.3": [[0, 0, math.inf, 0]]}), ["system.C.3[1][3]", "must be finite", "inf"]),
    ("x0-nan", scenario({"system.x0": [1, 2, math.nan, 4]}), ["system.x0[3]", "must be finite", "nan"]),
    ("x0-inf", scenario({"system.x0": [math.inf, 2, 3, 4]}), ["system.x0[1]", "must be finite", "inf"]),
    ("x0-non-numeric", scenario({"system.x0": [1, 2, 3, "four"]}), ["system.x0[4]", "must be a number"]),
    ("K-nan", scenario({"design.K.2": [[math.nan], [0.5], [0], [0]]}), ["design.K.2[1][1]", "must be finite"]),
    # --- dimensions ------------------------------------------------------------------------------
    ("A-not-square", scenario({"system.A": A4[:3]}), ["system.A must be square, got 3x4"]),
    ("A-ragged", scenario({"system.A": [[0, 1, 0, 0], [-1, 0, 0], [0, 0, 0, 1], [0, 0, -2, 0]]}),
     ["system.A row 2 has 3 entries, row 1 has 4"]),
    ("C-ragged", scenario({"system.C.1": [[1, 0, 0, 0], [0, 1]]}), ["system.C.1 row 2 has 2 entries, row 1 has 4"]),
    ("C-wrong-columns", scenario({"system.C.3": [[0, 0, 1, 0, 0]]}), ["system.C.3 has 5 columns, system.A is 4x4"]),
    ("K-wrong-rows", scenario({"design.K.2": [[-0.94], [0.5], [0]]}), ["design.K.2 is 3x1, expected 4x1"]),
    ("K-wrong-columns", scenario({"design.K.1": [[0.5, 0], [0.94, 0], [0, 0], [0, 0]]}),
     ["design.K.1 is 4x2, expected 4x1"]),
    ("x0-wrong-length", scenario({"system.x0": [1, 2, 3]}), ["system.x0 has 3 entries, system.A is 4x4"]),
    # --- unknown agent ids -----------------------------------------------------------------------
    ("arcs-unknown-agent", scenario({"graphs.a.arcs": [[1, 2], [2, 1], [2, 3], [3, 2], [1, 7]]}),
     ["graphs.a.arcs[5]", "agent 7", "not in system.C", "agents: 1, 2, 3"]),
    ("arcs-bad-agent-id", scenario({"graphs.a.arcs": [[0, 1], [1, 2], [2, 3], [3, 1]]}),
     ["graphs.a.arcs[1]", "agent ids must be positive integers"]),
    ("undirected-unknown-agent", scenario({"graphs.b.undirected": [[1, 2], [2, 3], [3, 4]]}),
     ["graphs.b.undirected[3]", "agent 4", "not in system.C"]),
    ("K-unknown-agent", scenario({"design.K.9": [[0], [0], [0], [0]]}), ["design.K", "agent 9", "not in system.C"]),
    ("K-agent-without-gain", scenario({"design.K.3": DELETE}), ["design.K has no gain for agent(s) 3"]),
    ("faults-kill-unknown-agent", scenario({"faults": [{"at": 5, "kill": 9}]}),
     ["faults[1].kill", "agent 9", "not in system.C"]),
    ("faults-arc-unknown-agent", scenario({"faults": [{"at": 5, "kill": 2}, {"at": 9, "drop_arc": [1, 5]}]}),
     ["faults[2].drop_arc", "agent 5", "not in system.C"]),
    # --- rate ------------------------------------------------------------------------------------
    ("continuous-rate-zero", scenario({"design.rate": 0}, time="continuous"),
     ["design.rate must be > 0 for continuous time, got 0"]),
    ("continuous-rate-negative", scenario({"design.rate": -1.5}, time="continuous"),
     ["design.rate must be > 0 for continuous time, got -1.5"]),
    ("discrete-rate-zero", scenario({"design.rate": 0}), ["design.rate must be in (0, 1) for discrete time, got 0"]),
    ("discrete-rate-negative", scenario({"design.rate": -0.5}),
     ["design.rate must be in (0, 1) for discrete time, got -0.5"]),
    ("discrete-rate-one", scenario({"design.rate": 1}), ["design.rate must be in (0, 1) for discrete time, got 1"]),
    ("discrete-rate-above-one", scenario({"design.rate": 1.5}),
     ["design.rate must be in (0, 1) for discrete time, got 1.5"]),
    ("rate-non-numeric", scenario({"design.rate": "fast"}), ["design.rate must be a number", "'fast'"]),
    ("rate-nan", scenario({"design.rate": math.nan}), ["design.rate must be finite"]),
    ("rate-int-too-large", scenario({"design.rate": 10**400}, time="continuous"), ["design.rate must be finite"]),
    ("rate-missing", scenario({"design.rate": DELETE}), ["design.rate is missing"]),
    ("design-missing", scenario({"design": DELETE}), ["design is missing"]),
    # --- names of states and outputs, and what no agent sees ----------------------------------------
    ("states-count", scenario({"system.states": ["a", "b"]}), ["system.states has 2 names, expected 4"]),
    ("states-not-a-list", scenario({"system.states": "x1 x2 x3 x4"}),
     ["system.states must be a list of 4 names", "the string"]),
    ("states-duplicate", scenario({"system.states": ["p", "v", "p", "w"]}),
     ["system.states[3] = 'p' is also system.states[1]: names must differ"]),
    ("states-bad-name", scenario({"system.states": ["p", "v w", "q", "r"]}),
     ["system.states[2] = 'v w' is not a name", "letters, digits"]),
    ("states-not-a-string", scenario({"system.states": ["p", 3, "q", "r"]}), ["system.states[2] = 3 is not a name"]),
    ("outputs-count", scenario({"system.outputs": {1: ["a", "b"]}}),
     ["system.outputs.1 has 2 names, expected 1 (one per row of system.C.1)"]),
    ("outputs-unknown-agent", scenario({"system.outputs": {9: ["a"]}}), ["system.outputs names agent 9"]),
    ("outputs-not-a-map", scenario({"system.outputs": ["a"]}), ["system.outputs must be a mapping"]),
    ("undetectable-bad", scenario({"design.undetectable": "maybe"}),
     ["design.undetectable must be refuse or exclude, got 'maybe'"]),
    ("coordinates-bad", scenario({"design.coordinates": "polar"}),
     ["design.coordinates must be one of auto, given, balanced, got 'polar'"]),
    # --- files -----------------------------------------------------------------------------------
    ("yaml-syntax-error", "name: broken\nsystem:\n  A: [[0, 1], [1, 0]\n  C: {1: [[1, 0]]}\n",
     ["YAML syntax error", "line 4"]),
    ("yaml-bad-indentation", "name: broken\n  time: discrete\n", ["YAML syntax error", "line 2"]),
    ("yaml-tab", "system:\n\tA: [[1]]\n", ["YAML syntax error", "line 2"]),
    ("empty-file", "", ["is empty"]),
    ("comments-only", "# a scenario\n\n   # nothing here yet\n\n", ["is empty"]),
    ("whitespace-only", "  \n\n\t\n   ", ["is empty"]),
    ("file-missing", _missing_file, ["no-such-scenario.yaml", "does not exist"]),
    ("directory", _directory, ["scenario-dir.yaml", "is a directory"]),
    ("not-utf8", _binary_file, ["cannot read scenario file", "binary.yaml"]),
    ("top-level-list", "- system\n- design\n", ["the scenario must be a mapping"]),
    # --- unknown keys ----------------------------------------------------------------------------
    ("top-unknown-key", scenario({"solver": "fast"}), ["unknown key solver"]),
    ("system-unknown-key", scenario({"system.D": [[1], [0], [0], [0]]}), ["unknown key system.D"]),
    # --- known inputs and sampling (system.B, system.u, system.sample) ------------------------------
    ("B-rows", scenario({"system.B": [[1], [0]]}), ["system.B is 2x1, system.A is 4x4"]),
    # issue 46's walk: one input's column written as a flat list (B: [0, 0, 0, 1]) is one row, and says so
    ("B-flat", scenario({"system.B": [0, 0, 0, 1]}),
     ["system.B is 1x4, system.A is 4x4", "a flat list is one row: write one input's column as [[a], [b], ...]"]),
    ("u-without-B", scenario({"system.u": [1.0]}), ["system.u needs system.B"]),
    ("u-width", scenario({"system.B": [[1], [0], [0], [0]], "system.u": [1.0, 2.0]}),
     ["system.u has 2 entries; system.B has 1 columns"]),
    ("u-steps-width", scenario({"system.B": [[1], [0], [0], [0]], "system.u": {"steps": [[0, [1.0]], [3, [1, 2]]]}}),
     ["system.u.steps[2] has 2 entries"]),
    ("u-steps-order", scenario({"system.B": [[1], [0], [0], [0]], "system.u": {"steps": [[5, [1.0]], [3, [2.0]]]}}),
     ["system.u.steps[2]: times must increase"]),
    ("u-sine-period", scenario({"system.B": [[1], [0], [0], [0]],
                                "system.u": {"sine": [{"amplitude": [1.0], "period": 0}]}}),
     ["system.u.sine[1].period must be > 0"]),
    ("u-unknown-part", scenario({"system.B": [[1], [0], [0], [0]], "system.u": {"ramp": [1.0]}}),
     ["unknown key system.u.ramp"]),
    ("sample-continuous", scenario({"system.sample": 0.1}, time="continuous"),
     ["system.sample samples a continuous model for time: discrete"]),
    ("sample-negative", scenario({"system.sample": -0.1}), ["system.sample must be >= 1e-09"]),
    ("sample-overflow", scenario({"system.sample": 1e4, "system.A": [[1000, 0, 0, 0], [0, 0, 0, 0], [0, 0, 0, 0],
                                                                      [0, 0, 0, 0]]}), ["exp(A dt) overflows"]),
    ("A-name-without-file", scenario({"system.A": "A"}), ["system.A is the name 'A', and system.file is not given"]),
    ("design-unknown-key-q_methd", scenario({"design.q_methd": "mixed"}), ["unknown key design.q_methd"]),
    ("run-unknown-key", scenario({"run.stepz": 10}), ["unknown key run.stepz"]),
    ("graph-unknown-key", scenario({"graphs.a.arc": [[1, 2]]}), ["unknown key graphs.a.arc"]),
    ("switching-unknown-key", scenario({"switching": {"schedul": [[0, "a"]]}}), ["unknown key switching.schedul"]),
    # --- assumptions of the paper ----------------------------------------------------------------
    ("graph-not-strongly-connected", scenario({"graphs.b": {"arcs": [[1, 2], [2, 3]]}}),
     ["graph b is not strongly connected: agent 2 cannot reach agent 1"]),
    ("not-jointly-observable", NOT_OBSERVABLE,
     ["(C, A) is not jointly detectable: no agent sees x4, x3 (0.71) (eigenvalue 0 +- 1.41j), which does not decay",
      "measure one of x4, x3", "design.undetectable: exclude"]),
    ("explicit-gain-misses-rate", scenario({"design.K.1": [[0], [0], [0], [0]]}),
     ["design.K.1", "do not meet rate 0.5", "need moduli < 0.5"]),
    ("explicit-gain-misses-rate-continuous", scenario({"design.K.3": [[0], [0], [-1], [-1]]}, time="continuous"),
     ["design.K.3", "do not meet rate 1", "need real parts < -1"]),
    # --- switching and design options ------------------------------------------------------------
    ("schedule-unknown-graph", scenario({"switching": {"schedule": [[0, "a"], [10, "c"]]}}),
     ["switching.schedule[2]", "graph 'c'", "not in graphs (a, b)"]),
    ("random-unknown-graph", scenario({"switching": {"random": {"graphs": ["a", "z"], "dwell": 5}}}),
     ["switching.random.graphs[2]", "graph 'z'", "not in graphs"]),
    ("schedule-not-at-zero", scenario({"switching": {"schedule": [[5, "a"], [10, "b"]]}}),
     ["switching.schedule must start at time 0, starts at 5"]),
    ("schedule-not-increasing", scenario({"switching": {"schedule": [[0, "a"], [10, "b"], [10, "a"]]}}),
     ["switching.schedule[3] time 10 is not after the previous piece"]),
    ("bad-q_method", scenario({"design.q_method": "fastest"}),
     ["design.q_method must be one of spectral, weighted, two-norm, mixed", "'fastest'"]),
    ("bad-gains", scenario({"design.gains": "magic"}),
     ["design.gains must be one of " + ", ".join(GAIN_METHODS), "'magic'"]),  # the words: scenarios/gain_methods.py
    ("bad-q", scenario({"design.q": "many"}), ["design.q must be an integer", "'many'"]),
    ("q-for-continuous", scenario({"design.q": 5}, time="continuous"), ["design.q is for discrete time"]),
    ("g-for-discrete", scenario({"design.g": 10}), ["design.g is for continuous time"]),
    ("dt-for-discrete", scenario({"run.dt": 0.01}), ["run.dt is only for continuous time"]),
    ("bad-time", scenario({"time": "hybrid"}), ["time must be discrete or continuous", "'hybrid'"]),
    # --- numbers that would overflow later arithmetic (bounds in splitspec_core/scenarios/specs.py) -----
    ("process-noise-1e308", scenario({"system.process_noise": 1e308}),
     ["system.process_noise = 1e+308 is out of range", "within +-1e+12"]),
    ("measurement-noise-huge", scenario({"system.measurement_noise": 1e13}),
     ["system.measurement_noise = 1e+13 is out of range"]),
    ("A-entry-huge", scenario({"system.A": [[0, 1e300, 0, 0], [-1, 0, 0, 0], [0, 0, 0, 1], [0, 0, -2, 0]]}),
     ["system.A[1][2] = 1e+300 is out of range"]),
    ("C-entry-huge", scenario({"system.C.2": [[0, -1e200, 0, 0]]}), ["system.C.2[1][2] = -1e+200 is out of range"]),
    ("K-entry-huge", scenario({"design.K.3": [[0], [0], [1e20], [1.94]]}), ["design.K.3[3][1] = 1e+20 is out of range"]),
    ("x0-entry-huge", scenario({"system.x0": [1, 2, 3, 1e13]}), ["system.x0[4] = 1e+13 is out of range"]),
    ("continuous-rate-huge", scenario({"design.rate": 1e300}, time="continuous"),
     ["design.rate = 1e+300 is out of range"]),
    ("g-huge", scenario({"design.g": 1e300}, time="continuous"), ["design.g = 1e+300 is out of range"]),
    ("dt-huge", scenario({"run.dt": 1e300}, time="continuous"), ["run.dt = 1e+300 is out of range"]),
    ("dt-tiny", scenario({"run.dt": 1e-300}, time="continuous"), ["run.dt must be >= 1e-09", "1e-300"]),
    ("pace-huge", scenario({"run.pace": 1e308}), ["run.pace = 1e+308 is out of range"]),
    ("pace-tiny", scenario({"run.pace": 1e-308}), ["run.pace must be >= 1e-06"]),
    ("design-dwell-huge", scenario({"design.dwell": 1e300}, time="continuous"),
     ["design.dwell = 1e+300 is out of range"]),
    ("random-dwell-tiny", scenario({"switching": {"random": {"graphs": ["a", "b"], "dwell": 1e-300}}},
                                   time="continuous"),
     ["switching.random.dwell = 1e-300 is below 0.001 sample steps", "run.dt = 0.01"]),
    ("period-tiny", scenario({"switching": {"schedule": [[0, "a"], [1e-300, "b"]], "period": 2e-300}}),
     ["switching.period = 2e-300 is below 0.001 sample steps", "one event time"]),
    ("schedule-time-huge", scenario({"switching": {"schedule": [[0, "a"], [1e300, "b"]]}}),
     ["switching.schedule[2] time = 1e+300 is out of range"]),
    ("fault-at-huge", scenario({"faults": [{"at": 1e300, "kill": 1}]}), ["faults[1].at = 1e+300 is out of range"]),
    ("riccati-weight-tiny", scenario({"design.gains": "riccati", "design.K": DELETE,
                                      "design.riccati": {"measurement_weight": 1e-300}}),
     ["design.riccati.measurement_weight must be >= 1e-12"]),
    ("riccati-weight-huge", scenario({"design.gains": "riccati", "design.K": DELETE,
                                      "design.riccati": {"process_weight": 1e300}}),
     ["design.riccati.process_weight = 1e+300 is out of range"]),
    ("q_max-huge", scenario({"design.q_max": 10**12}), ["design.q_max must be <= 1000000", "1000000000000"]),
    # --- seeds: what a process can carry (msgpack, 64-bit) ---------------------------------------
    ("run-seed-2**70", scenario({"run.seed": 2**70}), ["run.seed must be <= 2**63 - 1", str(2**70)]),
    ("run-seed-2**63", scenario({"run.seed": 2**63}), ["run.seed must be <= 2**63 - 1", str(2**63)]),
    ("random-seed-2**70", scenario({"switching": {"random": {"graphs": ["a", "b"], "dwell": 2, "seed": 2**70}}}),
     ["switching.random.seed must be <= 2**63 - 1", str(2**70)]),
    # --- faults on self-arcs (implicit) ----------------------------------------------------------
    ("drop-self-arc", scenario({"faults": [{"at": 5, "drop_arc": [3, 3]}]}),
     ["faults[1].drop_arc [3, 3] is a self-arc", "implicit"]),
    ("restore-self-arc", scenario({"faults": [{"at": 5, "drop_arc": [1, 3]}, {"at": 9, "restore_arc": [2, 2]}]}),
     ["faults[2].restore_arc [2, 2] is a self-arc"]),
    # --- a gain column written as a flat row is not transposed -----------------------------------
    ("K-flat-row", scenario({"design.K.1": [0.5, 0.94, 0, 0]}),
     ["design.K.1 is 1x4, expected 4x1", "write a column as [[a], [b], ...]"]),
    ("K-row-of-rows", scenario({"design.K.1": [[0.5, 0.94, 0, 0]]}), ["design.K.1 is 1x4, expected 4x1"]),
    # --- noise per state, per agent, per output: bad shapes (splitspec_core/scenarios/noise.py) -----
    ("measurement-noise-missing-agent", scenario({"system.measurement_noise": {1: 0.1, 2: 0.1}}),
     ["system.measurement_noise has no entry for agent 3 (it lists 1, 2)"]),
    ("measurement-noise-negative-output", scenario({"system.measurement_noise": {1: 0.1, 2: [-1], 3: 0}}),
     ["system.measurement_noise.2[1] must be >= 0, got -1"]),
    ("measurement-noise-wrong-length", scenario({"system.measurement_noise": {1: 0.1, 2: [0.1, 0.2, 0.3], 3: 0}}),
     ["system.measurement_noise.2 has 3 entries, agent 2 has 1 output"]),
    ("measurement-noise-unknown-agent", scenario({"system.measurement_noise": {1: 0.1, 2: 0.1, 3: 0.1, 7: 0.1}}),
     ["system.measurement_noise names agent 7, which is not in system.C (agents: 1, 2, 3)"]),
    ("measurement-noise-nan", scenario({"system.measurement_noise": {1: 0.1, 2: float("nan"), 3: 0.1}}),
     ["system.measurement_noise.2 must be finite, got nan"]),
    ("measurement-noise-list", scenario({"system.measurement_noise": [0.1, 0.2, 0.3]}),
     ["system.measurement_noise must be a number or a mapping", "a list of 3 items"]),
    ("measurement-noise-negative", scenario({"system.measurement_noise": -1}),
     ["system.measurement_noise must be >= 0, got -1"]),
    ("process-noise-vector-length", scenario({"system.process_noise": [0.1, 0.2]}),
     ["system.process_noise has 2 entries, system.A is 4x4"]),
    ("process-noise-vector-negative", scenario({"system.process_noise": [0.1, 0.2, -0.5, 0]}),
     ["system.process_noise[3] must be >= 0, got -0.5"]),
    ("process-noise-matrix-shape", scenario({"system.process_noise": [[1, 0], [0, 1]]}),
     ["system.process_noise is 2x2, system.A is 4x4"]),
    ("process-noise-not-psd", scenario({"system.process_noise": [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0],
                                                                  [0, 0, 0, -0.3]]}),
     ["system.process_noise is not symmetric positive semidefinite (smallest eigenvalue -0.3)"]),
    ("process-noise-not-psd-continuous", scenario({"system.process_noise": [[1, 2, 0, 0], [2, 1, 0, 0], [0, 0, 1, 0],
                                                                             [0, 0, 0, 1]]}, time="continuous"),
     ["system.process_noise is not symmetric positive semidefinite (smallest eigenvalue -1)"]),
    ("process-noise-not-symmetric", scenario({"system.process_noise": [[1, 0.5, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0],
                                                                        [0, 0, 0, 1]]}),
     ["system.process_noise is not symmetric: [1][2] is 0.5, [2][1] is 0"]),
    ("process-noise-name-without-file", scenario({"system.process_noise": "Q"}),
     ["system.process_noise is the name 'Q', and system.file is not given"]),
    ("process-noise-mapping", scenario({"system.process_noise": {1: 0.1}}),
     ["system.process_noise must be a number, a list of 4 (one per state) or a 4x4 matrix", "a mapping"]),
    # --- files: regular files only, at most 16 MB ------------------------------------------------
    ("dev-zero", lambda tmp_path: Path("/dev/zero"), ["scenario file /dev/zero is a character device",
                                                      "not a regular file"]),
    ("fifo", _fifo, ["scenario.fifo is a FIFO, not a regular file"]),
    ("too-large", _large_file, ["big.yaml is 17.3 MB; the limit is 16 MB"]),
]

# A handful also go through the real console entry point in a subprocess.
SUBPROCESS_IDS = (
    "C-wrong-columns", "A-nan", "yaml-syntax-error", "file-missing",
    "design-unknown-key-q_methd", "graph-not-strongly-connected",
    "process-noise-1e308", "run-seed-2**70", "drop-self-arc", "K-flat-row", "dev-zero", "fifo", "too-large",
    "measurement-noise-missing-agent", "process-noise-not-psd",
)

_BY_ID = {case_id: (source, fragments) for case_id, source, fragments in CASES}
assert len(_BY_ID) == len(CASES), "duplicate case ids"


def _path_for(source, tmp_path: Path) -> Path:
    if callable(source):
        return source(tmp_path)
    p = tmp_path / "scenario.yaml"
    p.write_text(source, encoding="utf-8")
    return p


def _run_in_process(argv: list, capsys, monkeypatch) -> tuple:
    """``cli.main(argv)`` -> (exit code, stdout, stderr); an escaping exception fails the test."""
    monkeypatch.delenv("SPLITSPEC_DEBUG", raising=False)
    try:
        code = cli.main(argv)
    except SystemExit as exc:  # argparse
        code = exc.code
    out, err = capsys.readouterr()
    return code, out, err


def _limit_memory() -> None:
    """In the child: at most 2 GiB of address space, so a regression that reads /dev/zero fails fast."""
    resource.setrlimit(resource.RLIMIT_AS, (2 * 2**30, 2 * 2**30))


def _run_subprocess(argv: list) -> tuple:
    """The real CLI in a child with a timeout and a memory limit: a blocked or unbounded read cannot hang the test."""
    env = {k: v for k, v in os.environ.items() if k != "SPLITSPEC_DEBUG"}
    env["RERUN_ANALYTICS"] = "0"
    proc = subprocess.run([sys.executable, "-m", "splitspec_orchestrator", *argv], cwd=ROOT, env=env,
                          capture_output=True, text=True, timeout=60, stdin=subprocess.DEVNULL,
                          preexec_fn=_limit_memory)
    return proc.returncode, proc.stdout, proc.stderr


def _assert_one_line_error(code, out: str, err: str, fragments: list) -> None:
    assert "Traceback" not in err, err
    assert code == cli.EXIT_BAD_INPUT == 2, (code, err)
    assert out == "", out
    assert err.endswith("\n") and err.count("\n") == 1, f"expected exactly one line on stderr, got {err!r}"
    assert err.startswith(PREFIX), err
    message = err[len(PREFIX):].strip()
    assert message, err
    for fragment in fragments:
        assert fragment in message, f"{fragment!r} not in {message!r}"


# Files that would block (a FIFO) or read without end (/dev/zero) if the checks regressed: only in a subprocess.
NOT_IN_PROCESS = ("dev-zero", "fifo")


@pytest.mark.parametrize("source, fragments",
                         [pytest.param(s, f, id=i) for i, s, f in CASES if i not in NOT_IN_PROCESS])
def test_bad_scenario_gives_one_line_and_exit_2(source, fragments, tmp_path, capsys, monkeypatch):
    path = _path_for(source, tmp_path)
    code, out, err = _run_in_process(["design", str(path)], capsys, monkeypatch)
    _assert_one_line_error(code, out, err, fragments)


@pytest.mark.parametrize("case_id", SUBPROCESS_IDS)
def test_bad_scenario_through_real_cli(case_id, tmp_path):
    source, fragments = _BY_ID[case_id]
    path = _path_for(source, tmp_path)
    code, out, err = _run_subprocess(["design", str(path)])
    _assert_one_line_error(code, out, err, fragments)


@pytest.mark.parametrize("time", ["discrete", "continuous"])
def test_base_scenarios_are_valid(time, tmp_path, capsys, monkeypatch):
    """The unpatched bases design cleanly, so each error case fails only because of its patch."""
    path = _path_for(scenario(time=time), tmp_path)
    code, out, err = _run_in_process(["design", str(path)], capsys, monkeypatch)
    assert code == 0, err
    assert err == ""
    assert "splitspec design: bad-input" in out


def test_valid_example_exits_0():
    code, out, err = _run_subprocess(["design", str(EXAMPLE)])
    assert code == 0, err
    assert "Traceback" not in err and "error" not in err
    assert "paper-discrete" in out and "q = " in out


def test_design_json_contract():
    code, out, err = _run_subprocess(["design", "--json", str(EXAMPLE)])
    assert code == 0, err
    assert "Traceback" not in err
    data = json.loads(out)
    for key in ("time", "rate", "m", "n", "agents", "q", "q_method", "q_bound", "checks"):
        assert key in data, key
    assert data["time"] == "discrete"
    assert data["rate"] == 0.5
    assert (data["m"], data["n"]) == (3, 4)
    assert isinstance(data["q"], int) and data["q"] >= 1
    assert data["q_method"] == "spectral"
    assert certifies(data["q_bound"], data["rate"])  # the one rule (synthesis/spectral.py)
    assert [a["id"] for a in data["agents"]] == [1, 2, 3]
    for agent in data["agents"]:
        for key in ("id", "K", "V", "P", "poles"):
            assert key in agent, (agent.get("id"), key)
        assert len(agent["K"]) == 4 and all(len(row) == 1 for row in agent["K"])
        assert len(agent["P"]) == 4 and all(len(row) == 4 for row in agent["P"])
        assert all(len(row) == 2 for row in agent["poles"])  # [re, im]
    checks = data["checks"]
    assert checks["jointly_observable"] is True
    assert checks["strongly_connected"] == {"a": True, "b": True}


def test_given_q_above_q_max_is_rejected(tmp_path, capsys):
    from splitspec_orchestrator.cli import main

    p = tmp_path / "s.yaml"
    p.write_text("time: discrete\nsystem: {A: [[1]], C: {1: [[1]]}}\ngraphs: {a: {arcs: []}}\n"
                 "design: {rate: 0.5, q: 1000000000}\n")
    assert main(["design", str(p)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "design.q = 1000000000 exceeds design.q_max = 100000" in err


def test_the_design_words_are_declared_once_and_documented():
    """DESIGN_CHOICES is the one list of each design key's words: DesignSpec's defaults are its defaults, the
    scenario page lists every word on the key's line, and a word outside it is one line naming the key."""
    import dataclasses

    from splitspec_core.errors import ScenarioError
    from splitspec_core.scenarios.checks import DESIGN_CHOICES, DESIGN_KEYS
    from splitspec_core.scenarios.load import parse_scenario
    from splitspec_core.scenarios.specs import DesignSpec

    defaults = {f.name: f.default for f in dataclasses.fields(DesignSpec)}
    page = (ROOT / "docs/how-to/scenario.md").read_text(encoding="utf-8").splitlines()
    for key, (words, default) in DESIGN_CHOICES.items():
        assert key in DESIGN_KEYS and default in words and defaults[key] == default, key
        line = next(x for x in page if x.startswith(f"  {key}: "))
        assert all(w in line for w in words), (key, line)
        raw = {"time": "discrete", "system": {"A": [[0.5]], "C": {1: [[1]]}}, "graphs": {"g": {"arcs": []}},
               "design": {"rate": 0.9, key: "nonsense"}}
        with pytest.raises(ScenarioError, match=rf"^design\.{key} must be .*got 'nonsense'$"):
            parse_scenario(raw)
