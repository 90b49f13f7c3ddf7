"""A run's recording inline in a Jupyter notebook (``ss.view(out, inline=True)``), with Rerun's notebook widget.

The widget is ``rerun.notebook.Viewer`` (the ``rerun-notebook`` package, the same web viewer as
``splitspec view --web``, shipped as a Jupyter widget). A fresh recording stream is wired to the widget and the
run's ``run.rrd`` is loaded into it with ``log_file_from_path`` (Rerun's own .rrd loader: every entity, every
timeline, the blueprint the recorder wrote), and after it, in order, the segments a run until stopped rolled it
into (``run-0001.rrd`` ...: :func:`recording_files`), so nothing is served and no port is opened. The widget shows the
data once the notebook displays it (return it from the cell); until then it holds what it was sent.
"""

from __future__ import annotations

import re
import uuid
from pathlib import Path

from splitspec_core.errors import ScenarioError

RECORDING_NAME = "run.rrd"
INSTALL = "pip install 'rerun-notebook==0.41.*'"


def recording_files(out: str | Path) -> list[Path]:
    """The files of ``out``'s recording, in order: ``run.rrd`` and the segments it rolled into (one recording).

    The segments are named as :func:`splitspec_orchestrator.viewer.rrd_file.segment_path` names them
    (``run-0001.rrd`` ...; this module may import no other of the orchestrator's: the tests check that both
    list the same files); those that exist, also after the oldest were deleted.
    """
    first = Path(out) / RECORDING_NAME
    pattern = re.compile(rf"{re.escape(first.stem)}-(\d{{4,}}){re.escape(first.suffix)}")
    rolled = sorted((int(m.group(1)), p) for p in first.parent.iterdir() if (m := pattern.fullmatch(p.name))) \
        if first.parent.is_dir() else []
    if not first.is_file() and not rolled:
        raise ScenarioError(f"{out} has no {RECORDING_NAME}: not a run's output directory")
    # run.keep may have removed run.rrd (the oldest segment) and kept the later ones
    return ([first] if first.is_file() else []) + [p for _, p in rolled]


def notebook_viewer(out: str | Path, *, width: int | str = "auto", height: int | str = 640):
    """The notebook widget showing ``out/run.rrd`` and its rolled segments; one-line errors for a missing recording
    or widget."""
    files = recording_files(out)
    import rerun as rr
    from rerun import notebook

    if not notebook.HAS_NOTEBOOK:
        raise ScenarioError(f"inline viewing needs Rerun's notebook widget: {INSTALL} (or ss.view(out) without "
                            "inline: the native or the web viewer)")
    rec = rr.RecordingStream("splitspec_view", recording_id=f"view-{uuid.uuid4().hex[:12]}")
    viewer = notebook.Viewer(recording=rec, width=width, height=height)
    for path in files:
        rec.log_file_from_path(path)
    rec.flush()
    return viewer
