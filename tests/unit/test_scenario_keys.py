"""The scenario's keys are declared once (scenarios/keys.py): the parser's accepted keys, defaults and one-line
messages, ``ss.scenario``'s keywords and the scenario page's reference table all follow the declaration."""

from __future__ import annotations

import dataclasses
import inspect
import re

import pytest

import splitspec_core as ss
from splitspec_core.errors import ScenarioError
from splitspec_core.scenarios import checks, keys
from splitspec_core.scenarios.load import parse_scenario
from splitspec_core.scenarios.specs import DesignSpec
from tests.conftest import ROOT

PAGE = ROOT / "docs/how-to/scenario.md"
BEGIN = "<!-- keys: generated from splitspec_core/scenarios/keys.py (reference_table) -->\n"
END = "<!-- keys: end -->"
KINDS = {"number", "integer", "word", "boolean", "number|word", "integer|word", "matrix", "per agent", "names", "noise", "signal",
         "path", "map", "map|word", "list", "text"}


def _minimal(**design):
    return {"time": "discrete", "system": {"A": [[0.5]], "C": {1: [[1]]}}, "graphs": {"g": {"arcs": []}},
            "design": {"rate": 0.9, **design}}


def test_every_key_has_a_kind_and_a_doc_line():
    for section, declared in keys.SECTIONS.items():
        assert len(set(keys.names(declared))) == len(declared), section
        for k in declared:
            assert k.kind in KINDS, (section, k.name, k.kind)
            # one markdown line, nothing a page would read as an HTML tag
            assert k.doc.strip() and "\n" not in k.doc and not re.search(r"<[A-Za-z/]", k.doc), (section, k.name)
            assert (k.kind == "word") <= bool(k.words), (section, k.name)
            if k.kind == "word":
                assert k.default in k.words, (section, k.name)


def test_the_sections_accept_exactly_the_declared_keys():
    assert checks.TOP_KEYS == keys.names(keys.TOP)
    assert (checks.GRAPH_KEYS, checks.SWITCHING_KEYS, checks.RANDOM_KEYS) == tuple(
        keys.names(d) for d in (keys.GRAPH, keys.SWITCHING, keys.RANDOM))
    assert (checks.NETWORK_KEYS, checks.DELAY_KEYS, checks.NETWORK_ARC_KEYS) == tuple(
        keys.names(d) for d in (keys.NETWORK, keys.DELAY, keys.NETWORK_ARC))
    assert checks.SYSTEM_KEYS == keys.names(keys.SYSTEM)
    assert checks.DESIGN_KEYS == keys.names(keys.DESIGN)
    assert checks.RICCATI_KEYS == keys.names(keys.RICCATI)
    assert checks.RUN_KEYS == keys.names(keys.RUN)
    with pytest.raises(ScenarioError, match=r"^unknown key design\.nonsense \(expected one of: rate, gains, "):
        parse_scenario(_minimal(nonsense=1))


def test_the_scenario_page_lists_every_key_as_declared():
    """The page's table is the declaration's (a key added without its doc line on the page fails here)."""
    page = PAGE.read_text(encoding="utf-8")
    assert page.count(BEGIN) == 1 and page.count(END) == 1
    table = page[page.index(BEGIN) + len(BEGIN):page.index(END)]
    assert table == keys.reference_table(), (
        "docs/how-to/scenario.md's key table differs from the declaration: put "
        "splitspec_core.scenarios.keys.reference_table() between its markers")
    for section, declared in keys.SECTIONS.items():
        for k in declared:
            assert f"| `{keys.dotted(section, k.name)}` |" in table and k.doc in table, (section, k.name)


def test_ss_scenario_takes_every_key_by_its_name():
    params = inspect.signature(ss.scenario).parameters
    doc = inspect.getdoc(ss.scenario)
    for name in keys.names(keys.TOP):  # a section by its name, or each of its keys (below)
        assert name in params and params[name].kind is inspect.Parameter.KEYWORD_ONLY, name
        assert name in doc, name
    for section in ("system", "design", "run"):
        for name in keys.names(keys.SECTIONS[section]):
            assert name in params and params[name].kind is inspect.Parameter.KEYWORD_ONLY, (section, name)
            assert name in doc, (section, name)
    sc = ss.scenario(A=[[0.5]], C={1: [[1]]}, graphs={"g": []}, rate=0.9, margin=0.25, q_max=7, steps=3, seed=4)
    assert (sc.design.margin, sc.design.q_max, sc.run.steps, sc.run.seed) == (0.25, 7, 3, 4)


def test_absent_keys_take_their_declared_defaults():
    sc = parse_scenario(_minimal())
    spec = {f.name: getattr(sc.design, f.name) for f in dataclasses.fields(DesignSpec)}
    for k in keys.DESIGN:
        if k.kind in ("word", "number", "integer") and k.default is not keys.REQUIRED and k.name in spec:
            assert spec[k.name] == k.default, k.name
    assert sc.design.q == "auto" and sc.design.g == "auto" and sc.design.rank_tol is None  # auto: the default tol
    run = {k.name: k.default for k in keys.RUN}
    assert (sc.run.steps, sc.run.seed, sc.run.pace) == (run["steps"], run["seed"], run["pace"])


@pytest.mark.parametrize("section,key", [(s, k.name) for s in ("design", "run") for k in keys.SECTIONS[s]
                                         if k.kind in ("number", "integer", "number|word", "integer|word")
                                         and k.name != "dt"])
def test_a_value_of_the_wrong_kind_is_one_line_naming_the_key(section, key):
    decl = next(k for k in keys.SECTIONS[section] if k.name == key)
    raw = _minimal()
    raw.setdefault(section, {})[key] = [1, 2]  # neither a number nor a word
    want = "a number" if decl.kind.startswith("number") else "an integer"
    with pytest.raises(ScenarioError, match=rf"^{section}\.{key} must be {want}, got .*$"):
        parse_scenario(raw)


def test_a_key_written_null_is_absent_in_every_section(tmp_path):
    """``key: null`` is the key left out, wherever it is: the name, a time-dependent design key, a run key, a
    sub-section's key (the cases that were refused or read as the text 'None')."""
    plain = parse_scenario(_minimal(), source="nulls.yaml")
    raw = _minimal(g=None, q=None)
    raw.update(name=None, run={"dt": None, "steps": None})
    raw["switching"] = None
    sc = parse_scenario(raw, source="nulls.yaml")
    assert sc.name == plain.name == "nulls"
    assert sc.design == plain.design and sc.run == plain.run
    two = {"time": "discrete", "system": {"A": [[0.5]], "C": {1: [[1]], 2: [[1]]}},
           "graphs": {"a": {"arcs": [[1, 2]]}, "b": {"arcs": [[2, 1]]}}, "design": {"rate": 0.9},
           "switching": {"random": {"dwell": 2, "graphs": None, "seed": 3}}}
    assert parse_scenario(two).switching == parse_scenario(
        {**two, "switching": {"random": {"dwell": 2, "seed": 3}}}).switching
