"""A run's recording inline in a Jupyter notebook (``ss.view(out, inline=True)``), with Rerun's notebook widget.

The widget is ``rerun.notebook.Viewer`` (the ``rerun-notebook`` package, the same web viewer as
``splitspec view --web``, shipped as a Jupyter widget). A fresh recording stream is wired to the widget and the
run's ``run.rrd`` is loaded into it with ``log_file_from_path`` (Rerun's own .rrd loader: every entity, every
timeline, the blueprint the recorder wrote), so nothing is served and no port is opened. The widget shows the
data once the notebook displays it (return it from the cell); until then it holds what it was sent.
"""

from __future__ import annotations

import uuid
from pathlib import Path

from splitspec_core.errors import ScenarioError

RECORDING_NAME = "run.rrd"
INSTALL = "pip install 'rerun-notebook==0.41.*'"


def notebook_viewer(out: str | Path, *, width: int | str = "auto", height: int | str = 640):
    """The notebook widget showing ``out/run.rrd``; one-line errors for a missing recording or widget."""
    rrd = Path(out) / RECORDING_NAME
    if not rrd.is_file():
        raise ScenarioError(f"{out} has no {RECORDING_NAME}: not a run's output directory")
    import rerun as rr
    from rerun import notebook

    if not notebook.HAS_NOTEBOOK:
        raise ScenarioError(f"inline viewing needs Rerun's notebook widget: {INSTALL} (or ss.view(out) without "
                            "inline: the native or the web viewer)")
    rec = rr.RecordingStream("splitspec_view", recording_id=f"view-{uuid.uuid4().hex[:12]}")
    viewer = notebook.Viewer(recording=rec, width=width, height=height)
    rec.log_file_from_path(rrd)
    rec.flush()
    return viewer
