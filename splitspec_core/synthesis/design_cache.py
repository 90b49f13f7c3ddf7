"""Designs paid once: the design of a scenario kept, in this process and on disk, keyed by what determines it.

``ss.simulate(sc)``, ``ss.compare(sc)``, ``splitspec simulate``, ``pace`` and ``run`` each design the scenario they
are given; a script that simulates two seeds of a power-system model paid its minutes-long design twice, and
``splitspec run`` designed it in the command (to fail fast) and again in the orchestrator process.  They all call
:func:`cached_design`:

* the key: the SHA-256 of the scenario pickled (every matrix, key and setting it holds) but for what no design
  reads (:data:`NOT_DESIGNED`: the file it came from, the drawing's positions, the run's seed, pace, retention and
  recording: ``pace`` measures a copy of the scenario with ``run.record_every`` set, and designed it again), the
  options that change the result (``compare_q_methods``; not ``workers``: the same numbers either way), the source of
  ``splitspec_core`` itself and the numpy and scipy versions: a design is reused only where it would be computed
  again bit for bit;
* in this process: the last :data:`MEMORY` designs (the same object is returned: its cached analyses with it; for
  a scenario that differs in what no design reads, a copy holding that scenario, the analyses with it);
* on disk: designs that took at least :data:`DISK_MIN_SECONDS` (the cheap ones are not worth a file), written when
  designed and again when this process exits if analyses were computed on them meanwhile (the transient constant,
  the bad-data covariances: on the IEEE 14-bus model these take as long as the design itself), in
  ``$SPLITSPEC_CACHE`` (default ``$XDG_CACHE_HOME/splitspec/designs``, else ``~/.cache/splitspec/designs``), the
  newest :data:`DISK_KEEP` files kept; written atomically (a temporary file, then renamed); a file that does not
  load is removed and the design computed again.  ``SPLITSPEC_CACHE=off`` turns both off (the test suite does,
  but for the tests of this module).

A refusal (an :class:`~splitspec_core.errors.AssumptionError` or :class:`~splitspec_core.errors.DesignError`) is not
kept: it is computed again, and says the same.
"""

from __future__ import annotations

import functools
import hashlib
import os
import pickle
import tempfile
import time
from collections import OrderedDict
from pathlib import Path

__all__ = ["MEMORY", "DISK_MIN_SECONDS", "DISK_KEEP", "NOT_DESIGNED", "cache_dir", "design_key", "cached_design", "clear_memory"]

#: designs kept in this process
MEMORY = 4
#: a design that took less than this (seconds) is not written to disk
DISK_MIN_SECONDS = 1.0
#: design files kept on disk (the newest)
DISK_KEEP = 32

#: the run's keys no design reads (set to their defaults in the key); the scenario's ``source`` and ``positions`` too
NOT_DESIGNED = ("seed", "pace", "show", "until_stopped", "keep_hours", "keep_gigabytes", "keep_recording_hours",
                "record_every", "keep_segment_mb")

_memory: "OrderedDict[str, object]" = OrderedDict()
_on_disk: dict = {}  # key -> (folder, design, analyses it held when written): written again at exit if they grew
_exit_pid: list = []  # the process that registered the exit hook (a forked worker inherits it, and must not write)


def cache_dir() -> Path | None:
    """Where designs are kept on disk (module docstring); None when ``SPLITSPEC_CACHE=off``.

    Returns
    -------
    pathlib.Path or None
    """
    value = os.environ.get("SPLITSPEC_CACHE")
    if value is not None and value.strip().lower() in ("off", "0", "no", "false", ""):
        return None
    if value:
        return Path(value)
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "splitspec" / "designs"


@functools.lru_cache(maxsize=1)
def _code_digest() -> str:
    """The source of ``splitspec_core`` and the numeric libraries' versions, hashed once per process."""
    import numpy
    import scipy

    root = Path(__file__).resolve().parents[1]
    h = hashlib.sha256(f"numpy {numpy.__version__} scipy {scipy.__version__}".encode())
    for path in sorted(root.rglob("*.py")):
        h.update(path.relative_to(root).as_posix().encode())
        h.update(path.read_bytes())
    return h.hexdigest()


def design_key(sc, *, compare_q_methods: bool = False) -> str | None:
    """The key of a scenario's design (module docstring); None when the scenario cannot be pickled (not kept).

    Parameters
    ----------
    sc : Scenario
    compare_q_methods : bool, default False

    Returns
    -------
    str or None
        64 hexadecimal digits.

    Examples
    --------
    >>> import splitspec_core as ss
    >>> a, b = ss.load_scenario("examples/paper_discrete.yaml"), ss.load_scenario("examples/paper_discrete.yaml")
    >>> design_key(a) == design_key(b), design_key(a) == design_key(a, compare_q_methods=True)
    (True, False)
    """
    try:
        body = pickle.dumps(_designed_part(sc), protocol=pickle.HIGHEST_PROTOCOL)
    except (pickle.PicklingError, TypeError, AttributeError):
        return None
    h = hashlib.sha256(_code_digest().encode())
    h.update(b"compare_q_methods=1" if compare_q_methods else b"compare_q_methods=0")
    h.update(body)
    return h.hexdigest()


def _designed_part(sc):
    """``sc`` with what no design reads set to its defaults (:data:`NOT_DESIGNED`)."""
    import dataclasses

    from ..scenarios.specs import RunSpec

    default = RunSpec()
    run = dataclasses.replace(sc.run, **{k: getattr(default, k) for k in NOT_DESIGNED})
    return dataclasses.replace(sc, run=run, source="<scenario>", positions=None)


def _for(sc, des):
    """``des`` for ``sc``: itself when it was designed from this scenario, else a copy holding ``sc`` (the same key:
    they differ only in what no design reads), its analyses shared."""
    import dataclasses

    if des.scenario is sc or pickle.dumps(des.scenario, protocol=pickle.HIGHEST_PROTOCOL) == pickle.dumps(
            sc, protocol=pickle.HIGHEST_PROTOCOL):
        return des
    out = dataclasses.replace(des, scenario=sc)
    out._analyses.update(des._analyses)
    return out


def clear_memory() -> None:
    """Forget the designs kept in this process (the disk's stay, and are not written again at exit).

    Returns
    -------
    None
    """
    _memory.clear()
    _on_disk.clear()


def _remember(key: str, des) -> None:
    _memory[key] = des
    _memory.move_to_end(key)
    while len(_memory) > MEMORY:
        _memory.popitem(last=False)


def _load(path: Path):
    try:
        with open(path, "rb") as fh:
            return pickle.load(fh)
    except FileNotFoundError:
        return None
    except Exception:  # noqa: BLE001 - a torn or foreign file: removed, and the design computed again
        path.unlink(missing_ok=True)
        return None


def _store(folder: Path, key: str, des) -> None:
    tmp = None
    try:
        folder.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=folder, prefix=".design-", suffix=".tmp")
        with os.fdopen(fd, "wb") as fh:
            pickle.dump(des, fh, protocol=pickle.HIGHEST_PROTOCOL)
        os.replace(tmp, folder / f"{key}.pickle")
        tmp = None
        files = sorted(folder.glob("*.pickle"), key=lambda p: p.stat().st_mtime, reverse=True)
        for old in files[DISK_KEEP:]:
            old.unlink(missing_ok=True)
    except (OSError, pickle.PicklingError, TypeError, AttributeError):
        pass  # a read-only home, a full disk, a design that cannot be pickled: nothing kept, nothing lost
    finally:
        if tmp is not None:
            Path(tmp).unlink(missing_ok=True)


def _write_back() -> None:
    """At exit: the designs whose analyses grew since they were written, written again."""
    if not _exit_pid or _exit_pid[0] != os.getpid():
        return
    for key, (folder, des, count) in list(_on_disk.items()):
        if len(getattr(des, "_analyses", {})) > count:
            _store(folder, key, des)


def _kept_on_disk(folder: Path, key: str, des) -> None:
    if not _exit_pid:
        import atexit

        _exit_pid.append(os.getpid())
        atexit.register(_write_back)
    _on_disk[key] = (folder, des, len(getattr(des, "_analyses", {})))


def cached_design(sc, *, compare_q_methods: bool = False, workers: int | None = None):
    """:func:`~splitspec_core.synthesis.designer.design`, computed once per scenario (module docstring).

    Parameters
    ----------
    sc : Scenario
    compare_q_methods : bool, default False
        As :func:`~splitspec_core.synthesis.designer.design`.
    workers : int or None, optional
        As :func:`~splitspec_core.synthesis.designer.design` (not part of the key: the same numbers either way).

    Returns
    -------
    Design
        The kept design, or a new one (then kept).

    Raises
    ------
    AssumptionError, DesignError
        As :func:`~splitspec_core.synthesis.designer.design` (refusals are not kept).
    """
    from .designer import design

    folder = cache_dir()
    key = None if folder is None else design_key(sc, compare_q_methods=compare_q_methods)
    if key is None:
        return design(sc, compare_q_methods=compare_q_methods, workers=workers)
    if key in _memory:
        _memory.move_to_end(key)
        return _for(sc, _memory[key])
    des = _load(folder / f"{key}.pickle")
    if des is not None:
        _remember(key, des)
        _kept_on_disk(folder, key, des)
        return _for(sc, des)
    t0 = time.perf_counter()
    des = design(sc, compare_q_methods=compare_q_methods, workers=workers)
    _remember(key, des)
    if time.perf_counter() - t0 >= DISK_MIN_SECONDS:
        _store(folder, key, des)
        _kept_on_disk(folder, key, des)
    return des
