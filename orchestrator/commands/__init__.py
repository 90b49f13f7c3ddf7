"""The ``splitspec`` commands, one module per group; :mod:`splitspec_orchestrator.cli` parses and dispatches.

- :mod:`.study`: ``design``, ``compare`` (the public API, then files and plots);
- :mod:`.simulate`: ``simulate`` (the public API's simulation, then files and plots);
- :mod:`.deploy`: ``run``, ``orchestrator``, ``router``, ``credentials``;
- :mod:`.pace`: ``pace`` (can this machine keep a scenario's pace? measured on a short real run);
- :mod:`.operate`: ``kill``, ``recover``, ``view``.

``splitspec plant`` and ``splitspec agent`` hand their arguments to the process packages
(``splitspec_plant``, ``splitspec_agents``) from :mod:`splitspec_orchestrator.cli`, the one module that imports
them (the "entry" layer of docs/explanation/architecture.md); the commands here never do.
"""

from __future__ import annotations


def seed_range(first: int, count: int, what: str) -> None:
    """Seeds first .. first + count - 1 must all be valid seeds (one line naming ``what`` if not)."""
    from splitspec_core.runtime.cli import MAX_SEED, UsageError

    if first + count - 1 > MAX_SEED:
        raise UsageError(f"{what}: the last seed {first + count - 1} exceeds 2**63 - 1 = {MAX_SEED}")


def out_dir(path):
    """``--out`` as a Path: created if missing and proven writable, or one clear line (exit 2)."""
    from ..records.outdir import check_output_dir

    return check_output_dir(path)
