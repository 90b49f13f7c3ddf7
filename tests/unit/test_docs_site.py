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
