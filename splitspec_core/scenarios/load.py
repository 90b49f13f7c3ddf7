"""Scenario entry points: a scenario from a file, from YAML text, or from a parsed mapping.

:func:`load_scenario` turns a YAML file into a :class:`~splitspec_core.scenarios.specs.Scenario`
of frozen dataclasses or raises a :class:`~splitspec_core.errors.ScenarioError` whose one-line
message names the offending key, e.g. ``system.C.3 has 5 columns, system.A is 4x4``;
:func:`parse_scenario_text` does the same for YAML text (the agent and plant processes receive the
scenario's text), :func:`parse_scenario` (:mod:`splitspec_core.scenarios.sections`) for a parsed mapping.

Unknown keys are rejected (a typo such as ``q_methd`` would otherwise silently
fall back to a default).  Numbers are bounded (the limits, with their reasons, are in
:mod:`splitspec_core.scenarios.checks`) so that nothing accepted here can overflow later
arithmetic, and scenario files are read only if they are regular files of at most
:data:`MAX_FILE_BYTES`.  Every YAML parse of a scenario goes through :func:`load_yaml`
(libyaml's C loader when present).

The import order of the scenario modules: :mod:`splitspec_core.scenarios.checks` <-
:mod:`splitspec_core.scenarios.specs` <- :mod:`splitspec_core.scenarios.sections` <- this module.
"""

from __future__ import annotations

import os
import stat
from pathlib import Path
from typing import Any

import yaml

from ..errors import ScenarioError
from .checks import MAX_FILE_BYTES, plain
from .files import resolve_model_file
from .specs import Scenario
from .yaml12 import dumper, loader_for
from .sections import parse_scenario

__all__ = ["dump_yaml", "load_scenario", "load_yaml", "parse_scenario", "parse_scenario_text", "read_scenario_text",
           "resolved_scenario_text", "yaml_loader", "MAX_FILE_BYTES"]

#: how :func:`splitspec_core.scenario` / :func:`splitspec_core.load_scenario` remember where a scenario came
#: from (its mapping, or its file), so that :func:`splitspec_core.run` can hand it to the processes as YAML
ORIGIN = "_splitspec_origin"


def yaml_loader() -> type:
    """The YAML loader for scenarios: libyaml's ``CSafeLoader`` when PyYAML has it, else ``SafeLoader``, reading
    numbers as YAML 1.2 does (``1e-3`` is a float; :mod:`splitspec_core.scenarios.yaml12`).

    The C loader parses a 10 MB scenario several times faster than the pure-Python one.

    Returns
    -------
    type
        A loader class for ``yaml.load(text, Loader=...)``.
    """
    return loader_for(yaml.CSafeLoader if getattr(yaml, "__with_libyaml__", False) else yaml.SafeLoader)


def dump_yaml(data: Any) -> str:
    r"""Scenario data (plain Python: :func:`~splitspec_core.scenarios.checks.plain`) as YAML text that
    :func:`load_yaml` reads back to the same values (block style, keys in order).

    Parameters
    ----------
    data : object
        Plain data: dicts, lists, strings, numbers, booleans, None.

    Returns
    -------
    str

    Examples
    --------
    >>> dump_yaml({"name": "1e3", "rank_tol": 1e-3})
    "name: '1e3'\nrank_tol: 0.001\n"
    """
    return yaml.dump(data, Dumper=dumper, sort_keys=False)


def load_yaml(text: str, *, source: str = "<scenario>") -> Any:
    r"""Parse scenario YAML text (safe loader); a syntax error is one line with its line and column.

    Every YAML parse of a scenario goes through here: :func:`load_scenario`,
    the ``--tune --write`` of the CLI, and the agent and plant processes
    (which receive the scenario text from the orchestrator).

    Parameters
    ----------
    text : str
        YAML text.
    source : str, default "<scenario>"
        What the text is, for messages (a file name).

    Returns
    -------
    object
        The YAML data model (None for an empty document).

    Raises
    ------
    ScenarioError
        ``<source>: YAML syntax error at line L, column C: <problem>``.

    Examples
    --------
    >>> load_yaml("rank_tol: 1e-3\nsteps: 017")
    {'rank_tol': 0.001, 'steps': 17}
    """
    try:
        return yaml.load(text, Loader=yaml_loader())  # noqa: S506 - a safe loader
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        problem = getattr(exc, "problem", None) or str(exc).splitlines()[0]
        where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark is not None else ""
        raise ScenarioError(f"{source}: YAML syntax error{where}: {problem}") from None


def parse_scenario_text(text: str, *, source: str = "<scenario>") -> Scenario:
    """:func:`load_yaml` then :func:`parse_scenario`: a scenario from its YAML text.

    Parameters
    ----------
    text : str
        The scenario's YAML text.
    source : str, default "<scenario>"
        What the text is, for messages.

    Returns
    -------
    Scenario

    Raises
    ------
    ScenarioError
        If the text is empty, is not valid YAML or fails validation (one line naming the key).
    """
    if not text.strip():
        raise ScenarioError(f"{source} is empty")
    data = load_yaml(text, source=source)
    if data is None:
        raise ScenarioError(f"{source} is empty")
    return parse_scenario(data, source=source)


def _megabytes(size: int) -> str:
    return f"{size / 1e6:.1f}"


def read_scenario_text(path: str | Path) -> str:
    """The text of a scenario file: a regular file of at most :data:`MAX_FILE_BYTES`, UTF-8.

    The file is checked with ``os.stat`` before it is opened (a FIFO would
    block, ``/dev/zero`` never ends) and read with a bounded read.

    Parameters
    ----------
    path : str or Path
        The scenario file.

    Returns
    -------
    str

    Raises
    ------
    ScenarioError
        One line naming the file: missing, a directory or other non-regular
        file, too large, unreadable or not UTF-8.
    """
    p = Path(path)
    try:
        st = os.stat(p)
    except FileNotFoundError:
        raise ScenarioError(f"scenario file {p} does not exist") from None
    except (OSError, ValueError) as exc:
        raise ScenarioError(f"cannot read scenario file {p}: {getattr(exc, 'strerror', None) or exc}") from None
    if stat.S_ISDIR(st.st_mode):
        raise ScenarioError(f"scenario file {p} is a directory")
    if not stat.S_ISREG(st.st_mode):
        kind = ("a FIFO" if stat.S_ISFIFO(st.st_mode) else "a character device" if stat.S_ISCHR(st.st_mode)
                else "a block device" if stat.S_ISBLK(st.st_mode) else "a socket" if stat.S_ISSOCK(st.st_mode)
                else "not a regular file")
        raise ScenarioError(f"scenario file {p} is {kind}, not a regular file")
    limit = f"the limit is {MAX_FILE_BYTES / 1e6:g} MB"
    if st.st_size > MAX_FILE_BYTES:
        raise ScenarioError(f"scenario file {p} is {_megabytes(st.st_size)} MB; {limit}")
    try:
        with open(p, "rb") as f:
            data = f.read(MAX_FILE_BYTES + 1)
    except OSError as exc:
        raise ScenarioError(f"cannot read scenario file {p}: {exc.strerror or exc}") from None
    if len(data) > MAX_FILE_BYTES:  # grew since the stat
        raise ScenarioError(f"scenario file {p} is over {MAX_FILE_BYTES / 1e6:g} MB; {limit}")
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise ScenarioError(f"cannot read scenario file {p}: not UTF-8 text ({exc.reason} at byte {exc.start})") \
            from None


def resolved_scenario_text(path: Path, text: str) -> str:
    """The text the processes of a run receive: ``text`` itself, or, when it names a ``system.file``, the
    scenario with that file's arrays written in (floats as ``repr``: the same numbers, bit for bit;
    :mod:`splitspec_core.scenarios.files`).

    Parameters
    ----------
    path : Path
        The scenario file (``system.file`` is relative to its folder).
    text : str
        Its text.

    Returns
    -------
    str

    Raises
    ------
    ScenarioError
        If the text is not valid YAML or the model file cannot be read or resolved.
    """
    data = load_yaml(text, source=str(path))
    if not isinstance(data, dict) or not isinstance(data.get("system"), dict) or "file" not in data["system"]:
        return text
    return dump_yaml(plain(resolve_model_file(data, Path(path).parent)))


def load_scenario(path: str | Path) -> Scenario:
    """Read and validate a YAML scenario file.

    Parameters
    ----------
    path : str or Path
        The scenario file; a ``system.file`` in it is relative to its folder.

    Returns
    -------
    Scenario

    Raises
    ------
    ScenarioError
        If the file is not a regular file, is too large, cannot be read, is
        empty, is not valid YAML, or fails validation; the message is one line
        naming the file or key.

    Examples
    --------
    >>> sc = load_scenario("examples/paper_discrete.yaml")
    >>> sc.time, sc.n, sc.agent_ids
    ('discrete', 4, (1, 2, 3))
    """
    p = Path(path)
    text = read_scenario_text(p)
    if not text.strip():
        raise ScenarioError(f"scenario file {p} is empty")
    data = load_yaml(text, source=str(p))
    if data is None:
        raise ScenarioError(f"scenario file {p} is empty")
    return parse_scenario(data, source=str(p), base=p.parent)
