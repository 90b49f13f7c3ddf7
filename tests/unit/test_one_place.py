"""One place per idea (issue 36): the code dispatches on a gain method's or a fault kind's declaration, never on
its word.  A comparison such as ``sc.design.gains == "riccati"`` or ``f.action == "kill"`` outside the declaring
modules is an if/elif a newcomer would have to find when adding a method or a kind; the flags of
:mod:`splitspec_core.scenarios.gain_methods` and the hooks of :mod:`splitspec_core.scenarios.faults` say it
instead.  Allowed: the partition's own mathematics (its certificate and its groups' checks), which are about that
kind and no other.
"""

from __future__ import annotations

import ast

from splitspec_core.scenarios import faults, gain_methods
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
