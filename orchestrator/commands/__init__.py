"""The ``splitspec`` commands, one module per group; :mod:`splitspec_orchestrator.cli` parses and dispatches.

- :mod:`.study`: ``design``, ``simulate``, ``compare`` (the public API, then files and plots);
- :mod:`.deploy`: ``run``, ``orchestrator``, ``router``, ``credentials``;
- :mod:`.pace`: ``pace`` (can this machine keep a scenario's pace? measured on a short real run);
- :mod:`.operate`: ``kill``, ``recover``, ``view``.

``splitspec plant`` and ``splitspec agent`` hand their arguments to the process packages
(``splitspec_plant``, ``splitspec_agents``) from :mod:`splitspec_orchestrator.cli`, the one module that imports
them (the "entry" layer of docs/explanation/architecture.md); the commands here never do.
"""

from __future__ import annotations


def out_dir(path):
    """``--out`` as a Path: created if missing and proven writable, or one clear line (exit 2)."""
    from ..records.outdir import check_output_dir

    return check_output_dir(path)
