"""The public API's docstrings (``ss.*`` functions): numpydoc Parameters, Returns and Examples sections, and every
example runs as written (from the repository's root, as the docs say: ``examples/...`` paths)."""

from __future__ import annotations

import doctest
import inspect

import pytest

import splitspec_core as ss
from tests.conftest import ROOT

FUNCTIONS = [name for name in ss.__all__ if inspect.isfunction(getattr(ss, name))]


def test_the_api_has_functions():
    assert {"scenario", "load_scenario", "design", "simulate", "compare", "network_sweep", "run", "load_run",
            "view"} <= set(FUNCTIONS)


@pytest.mark.parametrize("name", FUNCTIONS)
def test_every_api_function_has_parameters_returns_and_examples(name):
    doc = inspect.getdoc(getattr(ss, name)) or ""
    for section in ("Parameters", "Returns", "Examples"):
        assert f"\n{section}\n{'-' * len(section)}\n" in doc, (name, section)


@pytest.mark.parametrize("name", FUNCTIONS)
def test_every_api_example_runs(name, monkeypatch):
    monkeypatch.chdir(ROOT)
    fn = getattr(ss, name)
    finder = doctest.DocTestFinder(recurse=False)
    runner = doctest.DocTestRunner(optionflags=doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE)
    tests = finder.find(fn, name, globs={})
    assert tests and tests[0].examples, name
    for test in tests:
        runner.run(test)
    assert runner.failures == 0, name
