"""What every benchmark script prints beside its figures (imported as ``_common``: the scripts' own folder is
on ``sys.path`` when they run)."""

from __future__ import annotations

from pathlib import Path


def loadavg(fields: int = 3) -> str:
    """The first ``fields`` load averages of /proc/loadavg (1, 5, 15 minutes), or ``n/a``."""
    try:
        return " ".join(Path("/proc/loadavg").read_text().split()[:fields])
    except OSError:
        return "n/a"
