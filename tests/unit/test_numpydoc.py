"""Every public function of ``splitspec_core`` says what it takes and what it gives (numpydoc ``Parameters`` and
``Returns`` sections, issue 36), and every docstring example in the package runs as written.

Public: a module-level function or a method of a module-level class whose names do not start with ``_``; a
property needs no sections (its one paragraph says what it returns); a function with no parameters besides
``self``/``cls`` needs no ``Parameters``, one that returns nothing needs no ``Returns``.
"""

from __future__ import annotations

import ast
import doctest
import importlib

import pytest

from tests.conftest import ROOT

PACKAGE = ROOT / "splitspec_core"
MODULES = sorted(p for p in PACKAGE.rglob("*.py"))


def _returns_value(fn: ast.FunctionDef) -> bool:
    if fn.returns is not None:
        return not (isinstance(fn.returns, ast.Constant) and fn.returns.value is None)
    for node in ast.walk(fn):
        if isinstance(node, (ast.FunctionDef, ast.Lambda)) and node is not fn:
            continue
        if isinstance(node, ast.Return) and node.value is not None and not (
                isinstance(node.value, ast.Constant) and node.value.value is None):
            return True
    return False


def _is_generator(fn: ast.FunctionDef) -> bool:
    return any(isinstance(n, (ast.Yield, ast.YieldFrom)) for n in ast.walk(fn))


def _inherited(cls: ast.ClassDef, name: str, classes: dict) -> ast.FunctionDef | None:
    """The documented method ``name`` of a base class of ``cls`` defined in the same module (bases followed in
    order; an undocumented override on the way is skipped)."""
    for base in cls.bases:
        parent = classes.get(base.id) if isinstance(base, ast.Name) else None
        if parent is None:
            continue
        for item in parent.body:
            if isinstance(item, ast.FunctionDef) and item.name == name and ast.get_docstring(item):
                return item
        found = _inherited(parent, name, classes)
        if found is not None:
            return found
    return None


def _public_functions():
    """``(module path, name, the function to check)``: a method overriding one of a base class in the same module
    is checked by the base's docstring (numpydoc: an override inherits its base's sections)."""
    for path in MODULES:
        tree = ast.parse(path.read_text())
        rel = path.relative_to(ROOT).as_posix()
        classes = {c.name: c for c in tree.body if isinstance(c, ast.ClassDef)}
        for node in tree.body:
            if isinstance(node, ast.FunctionDef) and not node.name.startswith("_"):
                yield rel, node.name, node
            if isinstance(node, ast.ClassDef) and not node.name.startswith("_"):
                for item in node.body:
                    if isinstance(item, ast.FunctionDef) and not item.name.startswith("_"):
                        yield rel, f"{node.name}.{item.name}", _inherited(node, item.name, classes) or item


def _missing(fn: ast.FunctionDef) -> list[str]:
    decorators = {d.id if isinstance(d, ast.Name) else getattr(d, "attr", "") for d in fn.decorator_list}
    if decorators & {"property", "cached_property", "setter", "overload"}:
        return []
    doc = ast.get_docstring(fn) or ""
    need = []
    args = [a.arg for a in fn.args.posonlyargs + fn.args.args + fn.args.kwonlyargs if a.arg not in ("self", "cls")]
    if args or fn.args.vararg or fn.args.kwarg:
        need.append("Parameters")
    if _is_generator(fn):
        need.append("Yields")
    elif _returns_value(fn):
        need.append("Returns")
    return [s for s in need if f"\n{s}\n{'-' * len(s)}\n" not in "\n" + doc + "\n"]


FUNCTIONS = list(_public_functions())


def test_the_package_has_public_functions():
    assert len(FUNCTIONS) > 300


def test_every_public_function_has_numpydoc_sections():
    missing = [f"{rel}: {name} lacks {', '.join(m)}" for rel, name, fn in FUNCTIONS if (m := _missing(fn))]
    assert not missing, f"{len(missing)} of {len(FUNCTIONS)}:\n" + "\n".join(missing)


EXAMPLED = [p for p in MODULES if ">>>" in p.read_text()]
#: modules whose examples need an optional extra (pyproject's ``control``), skipped where it is not installed
#: (``make test-lowest``'s environment has only the required dependencies)
OPTIONAL = {"splitspec_core/scenarios/control.py": "control"}


@pytest.mark.parametrize("path", EXAMPLED, ids=lambda p: p.relative_to(ROOT).as_posix())
def test_every_docstring_example_runs(path, monkeypatch):
    if path.relative_to(ROOT).as_posix() in OPTIONAL:
        pytest.importorskip(OPTIONAL[path.relative_to(ROOT).as_posix()])
    monkeypatch.chdir(ROOT)  # the examples name files as the docs do: examples/... from the repository's root
    name = ".".join(path.relative_to(ROOT).with_suffix("").parts).removesuffix(".__init__")
    module = importlib.import_module(name)
    finder = doctest.DocTestFinder()
    runner = doctest.DocTestRunner(optionflags=doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE)
    tests = [t for t in finder.find(module, name) if t.examples]
    assert tests, name
    for test in tests:
        runner.run(test)
    assert runner.failures == 0, name
