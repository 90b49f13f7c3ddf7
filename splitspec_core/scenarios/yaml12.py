"""Numbers in scenario YAML as YAML 1.2 reads them (its core schema), for loading and for writing.

PyYAML follows YAML 1.1, where a float needs a dot: ``rank_tol: 1e-3`` was the string ``'1e-3'``, and ``017`` was
octal 15, ``1:20`` the sexagesimal 80, ``1_000`` the integer 1000.  Scenario files are read with the 1.2 core
schema's numbers instead: integers ``[-+]?[0-9]+``, ``0o17``, ``0x1F``; floats with or without a dot or an exponent
(``1e-3``, ``.5``, ``1.``), ``.inf``, ``-.inf``, ``.nan``.  Everything else is PyYAML's safe schema as before
(``true``/``false``; ``yes``/``no``/``on``/``off`` are still booleans, as in YAML 1.1).  The dumper that writes a
scenario for the processes resolves plain scalars the same way, so a string that reads as a number here (a state
named ``1e3``) is written quoted and read back as the same string.
"""

from __future__ import annotations

import math
import re

import yaml

__all__ = ["INT_TAG", "FLOAT_TAG", "loader_for", "dumper"]

INT_TAG = "tag:yaml.org,2002:int"
FLOAT_TAG = "tag:yaml.org,2002:float"

#: YAML 1.2 core schema, section 10.3.2 (tag resolution)
INT_RE = re.compile(r"^(?:[-+]?[0-9]+|0o[0-7]+|0x[0-9a-fA-F]+)$")
FLOAT_RE = re.compile(r"^(?:[-+]?(?:\.[0-9]+|[0-9]+(?:\.[0-9]*)?)(?:[eE][-+]?[0-9]+)?"
                      r"|[-+]?\.(?:inf|Inf|INF)|\.(?:nan|NaN|NAN))$")


def _construct_int(loader, node) -> int:
    text = loader.construct_scalar(node)
    if text.startswith("0o"):
        return int(text[2:], 8)
    if text.startswith("0x"):
        return int(text[2:], 16)
    return int(text)  # decimal, leading zeros included: 017 is 17


def _construct_float(loader, node) -> float:
    text = loader.construct_scalar(node).lower()
    if text.endswith(".inf"):
        return -math.inf if text.startswith("-") else math.inf
    if text == ".nan":
        return math.nan
    return float(text)


def _numbers_12(cls: type) -> type:
    """``cls`` with YAML 1.1's int and float resolvers replaced by YAML 1.2's (int first: ``17`` is both)."""
    cls.yaml_implicit_resolvers = {first: [(tag, rx) for tag, rx in pairs if tag not in (INT_TAG, FLOAT_TAG)]
                                   for first, pairs in cls.yaml_implicit_resolvers.items()}
    cls.add_implicit_resolver(INT_TAG, INT_RE, list("-+0123456789"))
    cls.add_implicit_resolver(FLOAT_TAG, FLOAT_RE, list("-+0123456789."))
    return cls


_LOADERS: dict = {}


def loader_for(base: type) -> type:
    """A subclass of the safe loader ``base`` (``yaml.CSafeLoader`` or ``yaml.SafeLoader``) reading numbers as YAML
    1.2 does; one class per base.

    Parameters
    ----------
    base : type
        ``yaml.CSafeLoader`` or ``yaml.SafeLoader``.

    Returns
    -------
    type
        The loader class (made once per base, then reused).

    Examples
    --------
    >>> import yaml
    >>> yaml.load("[1e-3, 017, 0x1F, 1_000, .inf]", Loader=loader_for(yaml.SafeLoader))
    [0.001, 17, 31, '1_000', inf]
    """
    if base not in _LOADERS:
        cls = _numbers_12(type(f"Scenario{base.__name__}", (base,), {}))
        cls.add_constructor(INT_TAG, _construct_int)
        cls.add_constructor(FLOAT_TAG, _construct_float)
        _LOADERS[base] = cls
    return _LOADERS[base]


def _list(dumper_, data):
    """A list of scalars on one line (``[0, 0.001, 0]``: a matrix a row per line, as people write it), others in
    block style: a 5 x 5 ``A`` written by ``design --tune rms --write`` took 30 lines, one number each."""
    flat = all(x is None or isinstance(x, (bool, int, float, str)) for x in data)
    return dumper_.represent_sequence("tag:yaml.org,2002:seq", data, flow_style=flat and bool(data))


#: the safe dumper whose plain scalars resolve as :func:`loader_for`'s do (strings that read as numbers are quoted)
dumper = _numbers_12(type("ScenarioDumper", (yaml.SafeDumper,), {}))
dumper.add_representer(list, _list)
