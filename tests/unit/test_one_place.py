"""One place per idea (issue 36): the code dispatches on a gain method's or a fault kind's declaration, never on
its word.  A comparison such as ``sc.design.gains == "riccati"`` or ``f.action == "kill"`` outside the declaring
modules is an if/elif a newcomer would have to find when adding a method or a kind; the flags of
:mod:`splitspec_core.scenarios.gain_methods` and the hooks of :mod:`splitspec_core.scenarios.faults` say it
instead.  Allowed: the partition's own mathematics (its certificate and its groups' checks), which are about that
kind and no other.
"""

from __future__ import annotations

import ast

import pytest

from splitspec_core import design, load_scenario
from splitspec_core.scenarios import faults, gain_methods
from splitspec_core.simulation import kinds
from tests.conftest import ROOT

FOLDERS = ("splitspec_core", "orchestrator", "agents", "plant")
DECLARATIONS = {"splitspec_core/scenarios/faults.py", "splitspec_core/scenarios/gain_methods.py",
                "splitspec_core/model/gains.py"}
# the partition's own mathematics: which groups, until which heal (a partition is the one loss every seed shares)
PARTITION_MATH = {"splitspec_core/synthesis/loss_certificate.py", "splitspec_core/scenarios/network_section.py"}


def _word_comparisons(tree: ast.AST, words: set, names: tuple) -> list:
    """``(line, word)`` of every comparison of one of ``words`` with an expression whose last name is in
    ``names`` (``x.action``, ``gains``, ``d.gains``, ``request.method``), ``==``, ``!=``, ``in`` or ``not in``."""
    def named(node) -> bool:
        last = node.attr if isinstance(node, ast.Attribute) else node.id if isinstance(node, ast.Name) else None
        return last in names

    def constants(node) -> list:
        if isinstance(node, ast.Constant) and isinstance(node.value, str):
            return [node.value]
        if isinstance(node, (ast.Tuple, ast.List, ast.Set)):
            return [c for e in node.elts for c in constants(e)]
        return []

    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Compare):
            sides = [node.left, *node.comparators]
            if any(named(s) for s in sides):
                found += [(node.lineno, w) for s in sides for w in constants(s) if w in words]
    return found


def _scan(words: set, names: tuple, allowed: set) -> list:
    bad = []
    for folder in FOLDERS:
        for path in sorted((ROOT / folder).rglob("*.py")):
            rel = path.relative_to(ROOT).as_posix()
            if rel in DECLARATIONS or rel in allowed:
                continue
            bad += [f"{rel}:{line}: {w!r}" for line, w in _word_comparisons(ast.parse(path.read_text()), words, names)]
    return bad


def test_no_code_dispatches_on_a_fault_word():
    assert not _scan(set(faults.KINDS) | set(faults.FAULT_ALIASES), ("action",), PARTITION_MATH)


def test_no_code_dispatches_on_a_gain_method_word():
    assert not _scan(set(gain_methods.NAMES), ("gains", "method"), set())


def test_the_scan_sees_a_dispatch_on_a_word():
    tree = ast.parse('if f.action == "kill" or sc.design.gains in ("place", "riccati"): pass\nif x == "kill": pass')
    assert _word_comparisons(tree, {"kill"}, ("action",)) == [(1, "kill")]
    assert _word_comparisons(tree, {"place", "riccati"}, ("gains",)) == [(1, "place"), (1, "riccati")]


#: what names a design's kind: the words and the attributes a branch on the kind would read
KIND_WORDS = {"whole", "fusion", "split", "continuous", "discrete", "adaptive"}
KIND_ATTRIBUTES = {"whole", "fusion", "continuous", "adaptive", "consensus", "g_mode", "time"}
#: the step paths (issue 44: the simulator walked eight near-parallel step paths, 18 branches on whole/continuous)
STEP_PATHS = ("splitspec_core/simulation/simulator.py", "splitspec_core/simulation/montecarlo.py")


def _kind_branches(tree: ast.AST) -> list:
    """``(line, what)`` of every branch (if, conditional expression, boolean operation, comparison) whose test reads
    a kind's attribute or word, or asks ``isinstance`` of a kind class."""
    found = []
    for node in ast.walk(tree):
        test = node.test if isinstance(node, (ast.If, ast.IfExp, ast.While, ast.Assert)) else None
        if test is None:
            continue
        for sub in ast.walk(test):
            if isinstance(sub, ast.Attribute) and sub.attr in KIND_ATTRIBUTES:
                found.append((sub.lineno, sub.attr))
            elif isinstance(sub, ast.Constant) and sub.value in KIND_WORDS:
                found.append((sub.lineno, sub.value))
            elif isinstance(sub, ast.Call) and getattr(sub.func, "id", None) == "isinstance" and any(
                    getattr(a, "id", "") in {k.__name__ for k in kinds.KINDS.values()} for a in sub.args):
                found.append((sub.lineno, "isinstance"))
    return found


def test_the_simulator_enters_every_kind_through_one_step_path():
    """The simulator's driver, its estimators and the Monte Carlo batch branch on the design's kind nowhere: each
    kind is one class of ``simulation/kinds.py`` holding its batch, per-agent and per-seed forms, chosen once
    (:func:`~splitspec_core.simulation.kinds.kind_of`); a kind is added there and nowhere else."""
    counted = {rel: _kind_branches(ast.parse((ROOT / rel).read_text())) for rel in STEP_PATHS}
    assert counted == {rel: [] for rel in STEP_PATHS}
    # in kinds.py the kind is read in one place: kind_of (and the exact ODE's refusal, which names the kind it refuses)
    tree = ast.parse((ROOT / "splitspec_core/simulation/kinds.py").read_text())
    readers = sorted({f.name for f in ast.walk(tree) if isinstance(f, ast.FunctionDef)
                      for sub in ast.walk(f) if isinstance(sub, ast.Attribute) and sub.attr == "consensus"})
    assert readers == ["kind_of"]
    assert set(kinds.KINDS.values()) == {c for c in vars(kinds).values()
                                         if isinstance(c, type) and issubclass(c, kinds.Kind) and c is not kinds.Kind}


def test_the_kind_scan_sees_a_branch_on_the_kind():
    tree = ast.parse('if est.whole: pass\nx = 1 if sc.time == "continuous" else q\nif isinstance(k, Fusion): pass\n'
                     'if est.screen is not None: pass')
    assert sorted(_kind_branches(tree)) == [(1, "whole"), (2, "continuous"), (2, "time"), (3, "isinstance")]


@pytest.mark.parametrize("example, kind", [("paper_discrete.yaml", "SplitDiscrete"),
                                           ("paper_continuous.yaml", "SplitSampled")])
def test_kind_of_picks_the_kind_of_a_design(example, kind):
    sc = load_scenario(ROOT / "examples" / example)
    assert kinds.kind_of(design(sc).detail).__name__ == kind
