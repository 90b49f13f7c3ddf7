"""Output directory of a run: checked before any process starts, and a disk-space reserve while recording.

:func:`check_output_dir` turns ``--out`` into a directory that is known to be
writable (it creates, writes, fsyncs and removes a probe file), or raises
:class:`OutputDirError` with one line.  :class:`Reserve` is the recorder's
emergency space: a small preallocated file in the output directory, released
when a write fails for lack of space so that the final, consistent records can
still be written (as databases keep a reserve for their last log records).
"""

from __future__ import annotations

import errno
import logging
import os
from pathlib import Path

from splitspec_core.errors import ScenarioError

__all__ = ["OutputDirError", "Reserve", "check_output_dir", "RESERVE_FILE"]

log = logging.getLogger(__name__)

RESERVE_FILE = ".splitspec-reserve"
_PROBE_FILE = ".splitspec-probe"


class OutputDirError(ScenarioError):
    """``--out`` cannot hold a run (empty, not a directory, not writable); the message says why.

    A :class:`ScenarioError` (bad CLI input, also a ``ValueError``): the CLI prints one line and exits 2.
    """


def check_output_dir(path: str | os.PathLike) -> Path:
    """The output directory ``path``, created if missing and proven writable.

    The probe creates, writes, fsyncs and removes ``.splitspec-probe`` in it,
    so a read-only mount, a full disk with no block left, or missing
    permissions are found before any process starts.

    Raises
    ------
    OutputDirError
        ``--out must name a directory`` for ``''``; ``cannot write to output
        directory X: <strerror>`` otherwise (``Not a directory`` for an
        existing non-directory).
    """
    if str(path).strip() == "":
        raise OutputDirError("--out must name a directory")
    out = Path(path)
    if out.exists() and not out.is_dir():
        raise OutputDirError(f"cannot write to output directory {out}: {os.strerror(errno.ENOTDIR)}")
    probe = out / _PROBE_FILE
    try:
        out.mkdir(parents=True, exist_ok=True)
        fd = os.open(probe, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
        try:
            os.write(fd, b"splitspec\n")
            os.fsync(fd)
        finally:
            os.close(fd)
        probe.unlink()
    except OSError as exc:
        try:
            probe.unlink(missing_ok=True)
        except OSError:
            pass
        raise OutputDirError(f"cannot write to output directory {out}: {exc.strerror or exc}") from None
    return out


class Reserve:
    """A preallocated file of about ``size`` bytes in ``out_dir`` (at most 1/8 of the free space).

    :meth:`release` removes it (at close, or to make room after ENOSPC); it
    never raises.  Creating it never fails a run: without space or
    ``posix_fallocate`` there is simply no reserve.
    """

    def __init__(self, out_dir: Path, size: int):
        self.path = Path(out_dir) / RESERVE_FILE
        self.size = 0
        if size <= 0:
            return
        try:
            st = os.statvfs(out_dir)
            size = min(int(size), st.f_bavail * st.f_frsize // 8)
            if size <= 0:
                return
            fd = os.open(self.path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
            try:
                os.posix_fallocate(fd, 0, size)
            finally:
                os.close(fd)
            self.size = size
        except (OSError, AttributeError) as exc:  # AttributeError: no posix_fallocate on this platform
            log.debug("no disk space reserve in %s (%s)", out_dir, exc)
            self.release()

    def release(self) -> bool:
        """Remove the reserve file; True if it was there and is gone."""
        try:
            self.path.unlink()
        except FileNotFoundError:
            return False
        except OSError as exc:  # e.g. read-only by now: nothing to gain
            log.debug("could not release %s (%s)", self.path, exc)
            return False
        finally:
            self.size = 0
        return True
