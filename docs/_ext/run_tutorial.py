"""Execute one jupytext notebook cell by cell and write it as a MyST page with its outputs.

    python docs/_ext/run_tutorial.py docs/tutorials/NAME.py docs/_generated/tutorials/NAME.md

Run by ``make docs`` (docs/_ext/splitspec_docs.py) from the repository root, in its own process: the
cells share one namespace, as in a notebook; whatever a cell prints (stdout and stderr) goes under it in a
``text`` block, every matplotlib figure open after it is saved beside the page and shown (then closed).
A cell that raises ends the run with exit 1 and the traceback on stderr.
"""

from __future__ import annotations

import contextlib
import io
import sys
import traceback
from pathlib import Path

MAX_LINES = 60  # of one cell's printed output; the rest is cut with a note


def _text(out: str) -> list[str]:
    lines = out.rstrip().splitlines()
    if len(lines) > MAX_LINES:
        lines = lines[:MAX_LINES] + [f"... ({len(lines) - MAX_LINES} more lines)"]
    return ["```text", *lines, "```", ""] if lines else []


def main(src: Path, dest: Path) -> int:
    import jupytext
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    plt.show = lambda *a, **k: None  # figures are collected after each cell
    nb = jupytext.read(src)
    dest.parent.mkdir(parents=True, exist_ok=True)
    scope: dict = {"__name__": "__main__", "__file__": str(src)}
    page: list[str] = []
    figures = 0
    for k, cell in enumerate(nb.cells, 1):
        if cell.cell_type == "markdown":
            page += [cell.source, ""]
            continue
        if cell.cell_type != "code" or not cell.source.strip():
            continue
        page += ["```python", cell.source.rstrip(), "```", ""]
        buf = io.StringIO()
        try:
            with contextlib.redirect_stdout(buf), contextlib.redirect_stderr(buf):
                exec(compile(cell.source, f"{src} (cell {k})", "exec"), scope)  # noqa: S102 - our tutorial
        except BaseException:  # noqa: BLE001 - reported, then the run fails
            sys.stderr.write(buf.getvalue())
            traceback.print_exc()
            print(f"run_tutorial: {src}: cell {k} raised (above)", file=sys.stderr)
            return 1
        page += _text(buf.getvalue())
        for num in plt.get_fignums():
            figures += 1
            name = f"{src.stem}_{figures}.png"
            plt.figure(num).savefig(dest.parent / name, dpi=110)
            page += [f"![figure {figures} of the tutorial]({name})", ""]
        plt.close("all")
    dest.write_text("\n".join(page))
    return 0


if __name__ == "__main__":
    if len(sys.argv) != 3:
        print("usage: run_tutorial.py NOTEBOOK.py PAGE.md", file=sys.stderr)
        sys.exit(2)
    sys.exit(main(Path(sys.argv[1]), Path(sys.argv[2])))
