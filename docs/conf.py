"""Sphinx configuration of the splitspec documentation site (``make docs`` -> docs/_build/html).

Why Sphinx with MyST (and not MkDocs): the API reference comes from the numpydoc docstrings through
autodoc + napoleon, the CLI reference from the argparse parser itself (docs/_ext/splitspec_docs.py), the
pages are Markdown (MyST) with the paper's equations as LaTeX, rendered by a MathJax copy shipped with
the site (sphinx-mathjax-offline: the site reads offline too), and ``-W`` turns every warning (a broken
cross-reference, a malformed docstring, a tutorial that fails) into a failed build.  python-control,
scipy and numpy document themselves the same way.  Nothing here touches the network.
"""

from __future__ import annotations

import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE / "_ext"))

project = "splitspec"
author = "the splitspec authors"
copyright = "2026, the splitspec authors"  # noqa: A001 - Sphinx's name

extensions = [
    "myst_parser",
    "sphinx.ext.autodoc",
    "sphinx.ext.napoleon",
    "sphinx.ext.mathjax",
    "sphinx-mathjax-offline",
    "splitspec_docs",
]

source_suffix = {".md": "markdown", ".rst": "restructuredtext"}
root_doc = "index"
exclude_patterns = ["_build", "_ext", "Thumbs.db", ".DS_Store"]

myst_enable_extensions = ["dollarmath", "amsmath", "deflist", "colon_fence"]
myst_heading_anchors = 3

# the API reference: numpydoc sections, signatures as written, members in source order
autodoc_member_order = "bysource"
autodoc_typehints = "signature"
autodoc_default_options = {"members": True, "undoc-members": False}
napoleon_google_docstring = False
napoleon_numpy_docstring = True
napoleon_use_rtype = False
napoleon_use_ivar = True  # "Attributes" as fields of the class, not a second description of each member

html_theme = "furo"
html_title = "splitspec"
html_static_path: list = []
html_show_sourcelink = False
