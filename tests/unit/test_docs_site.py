"""The documentation site's sources (docs/): what ``make docs`` builds (CI builds it, warnings as errors) is
complete: every public name is in the API reference, every tutorial in the tutorials' table of contents."""

from __future__ import annotations

import re

import splitspec_core
from tests.conftest import ROOT

DOCS = ROOT / "docs"


def test_every_public_name_is_in_the_api_reference():
    text = (DOCS / "reference" / "api.rst").read_text()
    documented = set(re.findall(r"^\.\. auto(?:function|class|exception):: splitspec_core\.(\w+)", text, re.M))
    assert documented == set(splitspec_core.__all__), (sorted(set(splitspec_core.__all__) - documented),
                                                       sorted(documented - set(splitspec_core.__all__)))


def test_every_tutorial_is_listed_and_every_listed_tutorial_exists():
    notebooks = {p.stem for p in (DOCS / "tutorials").glob("*.py")}
    listed = set(re.findall(r"^\.\./_generated/tutorials/(\w+)$", (DOCS / "tutorials" / "index.md").read_text(), re.M))
    assert notebooks and listed == notebooks, (sorted(notebooks - listed), sorted(listed - notebooks))


def test_every_tutorial_is_a_jupytext_percent_notebook():
    """A header jupytext reads, then cells; the first a Markdown cell with the page's title."""
    for path in sorted((DOCS / "tutorials").glob("*.py")):
        text = path.read_text()
        assert "format_name: percent" in text.split("# ---")[1], path.name
        first = text.split("# %%", 1)[1]
        assert first.startswith(" [markdown]\n# # "), path.name


def test_the_readmes_links_lead_somewhere():
    """The README is read on GitHub as well as built into nothing: Sphinx does not check its links, this does."""
    text = (ROOT / "README.md").read_text()
    links = re.findall(r"\]\(([^)#\s]+)(?:#[^)]*)?\)", text)
    local = [link for link in links if not re.match(r"[a-z]+://", link)]
    assert len(local) >= 15
    missing = [link for link in local if not (ROOT / link).exists()]
    assert not missing, missing


def test_the_readme_is_a_front_page():
    """At most ~150 lines, the two quickstart commands before anything else runnable."""
    text = (ROOT / "README.md").read_text()
    assert len(text.splitlines()) <= 150
    first = text.split("```sh", 1)[1].split("```", 1)[0].strip().splitlines()
    assert [line.split()[:2] for line in first] == [["make", "demo"], ["make", "test"]]
