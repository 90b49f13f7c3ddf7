"""pyproject.toml's dependencies tell the truth: what is installed satisfies them, and every import is declared.

* The installed distributions satisfy the bounds (``make test`` checks the newest allowed versions,
  ``make test-lowest`` the oldest).
* Every third-party module imported by the packages (``splitspec_core``, ``agents``, ``plant``,
  ``orchestrator``) comes from a declared dependency, and every declared dependency is imported;
  the tests may also use the ``dev`` extra, ``docs/`` the ``docs`` and ``screenshots`` extras.
"""

from __future__ import annotations

import ast
import functools
import re
import sys
import tomllib
from importlib import metadata

import pytest

from tests.conftest import ROOT

PYPROJECT = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))
PROJECT = PYPROJECT["project"]
EXTRAS = PROJECT.get("optional-dependencies", {})
PACKAGE_FOLDERS = ["splitspec_core", "agents", "plant", "orchestrator"]
# import name -> distribution, for when the distribution is not installed (packages_distributions() knows
# only installed ones) or to pin the expected answer
KNOWN = {"zenoh": "eclipse-zenoh", "yaml": "pyyaml", "rerun": "rerun-sdk", "PIL": "pillow",
         "playwright": "playwright", "msgpack": "msgpack", "numpy": "numpy", "scipy": "scipy",
         "matplotlib": "matplotlib", "pyarrow": "pyarrow", "pytest": "pytest", "hypothesis": "hypothesis"}


def canonical(name: str) -> str:
    """PEP 503 normalised distribution name."""
    return re.sub(r"[-_.]+", "-", name).lower()


# --------------------------------------------------------------------------
# requirements: packaging when available, else the simple forms pyproject uses
# --------------------------------------------------------------------------

_REQ = re.compile(r"^\s*([A-Za-z0-9][A-Za-z0-9._-]*)\s*(?:\[[^\]]*\])?\s*([^;]*?)\s*(?:;.*)?$")


def _release(version: str) -> tuple:
    """Numeric release of a version string (``2.0.0rc1`` -> (2, 0, 0)), zero-padded when compared."""
    parts = []
    for piece in version.split("."):
        m = re.match(r"\d+", piece)
        if not m:
            break
        parts.append(int(m.group()))
        if m.end() != len(piece):  # a pre/post/dev suffix ends the release part
            break
    return tuple(parts)


def _cmp(a: str, b: str) -> int:
    ra, rb = _release(a), _release(b)
    n = max(len(ra), len(rb))
    ra, rb = ra + (0,) * (n - len(ra)), rb + (0,) * (n - len(rb))
    return (ra > rb) - (ra < rb)


_OPS = {">=": lambda c: c >= 0, "<=": lambda c: c <= 0, ">": lambda c: c > 0, "<": lambda c: c < 0,
        "==": lambda c: c == 0, "!=": lambda c: c != 0}


def parse(requirement: str) -> tuple[str, list[tuple[str, str]]]:
    """``(canonical name, [(operator, version), ...])`` of a requirement string."""
    m = _REQ.match(requirement)
    assert m, f"cannot parse requirement {requirement!r}"
    specs = re.findall(r"(>=|<=|==|!=|~=|>|<)\s*([^,\s]+)", m.group(2))
    return canonical(m.group(1)), specs


def satisfies(version: str, requirement: str) -> bool:
    try:
        from packaging.requirements import Requirement
        from packaging.version import Version
    except ImportError:  # pragma: no cover - packaging is usually there (matplotlib needs it)
        _, specs = parse(requirement)
        ok = True
        for op, bound in specs:
            if op == "~=":  # ~=X.Y: >=X.Y, ==X.*
                head = _release(bound)[:-1]
                ok &= _cmp(version, bound) >= 0 and _release(version)[:len(head)] == head
            else:
                ok &= _OPS[op](_cmp(version, bound))
        return ok
    return Requirement(requirement).specifier.contains(Version(version), prereleases=True)


def installed(name: str) -> str | None:
    try:
        return metadata.version(name)
    except metadata.PackageNotFoundError:
        return None


# --------------------------------------------------------------------------
# imports
# --------------------------------------------------------------------------

def _optional_imports(tree: ast.AST) -> set:
    """Import nodes inside ``try:`` blocks that catch ImportError (an optional module with a fallback)."""
    out = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Try) and any(
                isinstance(h.type, ast.Name) and h.type.id in ("ImportError", "ModuleNotFoundError")
                or isinstance(h.type, ast.Tuple) and any(getattr(e, "id", "") in ("ImportError", "ModuleNotFoundError")
                                                         for e in h.type.elts)
                for h in node.handlers):
            out.update(n for stmt in node.body for n in ast.walk(stmt) if isinstance(n, (ast.Import, ast.ImportFrom)))
    return out


def top_level_imports(folder: str) -> dict[str, set]:
    """``{top-level module: {files importing it}}`` for the absolute, non-optional imports under ``folder``."""
    found: dict[str, set] = {}
    for path in sorted((ROOT / folder).rglob("*.py")):
        tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
        optional = _optional_imports(tree)
        for node in ast.walk(tree):
            if node in optional:
                continue
            if isinstance(node, ast.Import):
                names = [alias.name for alias in node.names]
            elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                names = [node.module]
            else:
                continue
            for name in names:
                found.setdefault(name.split(".")[0], set()).add(str(path.relative_to(ROOT)))
    return found


SCANNED = PACKAGE_FOLDERS + ["tests", "benchmarks", "docs", "examples"]


@functools.cache
def local_modules() -> frozenset:
    """The project's own import names, and the modules and packages of the scanned folders."""
    own = set(PYPROJECT["tool"]["setuptools"]["packages"]) | set(PYPROJECT["tool"]["setuptools"]["package-dir"])
    for folder in SCANNED:
        for path in (ROOT / folder).rglob("*.py"):
            rel = path.relative_to(ROOT)
            own.add(path.stem)
            own.update(rel.parts[:-1])
    return frozenset(name.split(".")[0] for name in own)


@functools.cache
def _packages_distributions() -> dict:
    return metadata.packages_distributions()


def distribution_of(module: str) -> str:
    dists = _packages_distributions().get(module)
    if dists:
        return canonical(dists[0])
    return canonical(KNOWN.get(module, module))


def third_party(folders) -> dict[str, set]:
    """``{distribution: {files}}`` of the third-party imports under ``folders``."""
    skip = set(sys.stdlib_module_names) | local_modules()
    out: dict[str, set] = {}
    for folder in folders:
        for module, files in top_level_imports(folder).items():
            if module not in skip:
                out.setdefault(distribution_of(module), set()).update(files)
    return out


def declared(*extras: str) -> set:
    reqs = list(PROJECT["dependencies"]) + [r for e in extras for r in EXTRAS[e]]
    return {parse(r)[0] for r in reqs}


# --------------------------------------------------------------------------
# tests
# --------------------------------------------------------------------------

def test_the_requirement_parser_reads_the_forms_used():
    assert parse("rerun-sdk>=0.41,<0.42") == ("rerun-sdk", [(">=", "0.41"), ("<", "0.42")])
    assert parse("PyYAML >= 6.0 ; python_version>'3'") == ("pyyaml", [(">=", "6.0")])
    assert satisfies("0.41.0", "rerun-sdk>=0.41,<0.42") and not satisfies("0.42.0", "rerun-sdk>=0.41,<0.42")
    assert satisfies("2.0.0", "numpy>=2.0,<3") and not satisfies("1.26.4", "numpy>=2.0,<3")
    assert _cmp("2.0", "2.0.0") == 0 and _cmp("1.10.2", "1.3.0") > 0 and _cmp("1.0.5", "1.0.10") < 0


def test_python_satisfies_requires_python():
    here = ".".join(map(str, sys.version_info[:3]))
    assert satisfies(here, f"python{PROJECT['requires-python']}"), (here, PROJECT["requires-python"])


@pytest.mark.parametrize("group", ["dependencies", *EXTRAS])
def test_installed_versions_satisfy_the_bounds(group):
    """Runtime and ``dev`` dependencies must be installed (``make setup`` installs them) and within bounds;
    other extras (``docs``) only when installed."""
    reqs = PROJECT["dependencies"] if group == "dependencies" else EXTRAS[group]
    missing, outside = [], []
    for req in reqs:
        name = parse(req)[0]
        version = installed(name)
        if version is None:
            if group in ("dependencies", "dev"):
                missing.append(req)
        elif not satisfies(version, req):
            outside.append(f"{name} {version} (pyproject: {req})")
    assert not missing, f"not installed: {missing}"
    assert not outside, f"installed versions outside pyproject.toml's bounds: {outside}"


def test_every_bound_has_a_floor_and_a_reason():
    """Each dependency has a lower bound, and a comment above it in pyproject.toml says why."""
    text = (ROOT / "pyproject.toml").read_text(encoding="utf-8")
    block = text.split("\ndependencies = [", 1)[1].split("\n]", 1)[0].splitlines()
    for req in PROJECT["dependencies"]:
        assert any(op in (">=", "==", "~=") for op, _ in parse(req)[1]), f"{req}: no lower bound"
        at = next(i for i, line in enumerate(block) if line.strip().startswith(f'"{req}"'))
        assert at > 0 and block[at - 1].strip().startswith("#"), f"{req}: no comment saying why"


def test_every_third_party_import_of_the_packages_is_declared():
    used = third_party(PACKAGE_FOLDERS)
    undeclared = {dist: sorted(files) for dist, files in used.items() if dist not in declared()}
    assert not undeclared, f"imported but not in [project] dependencies: {undeclared}"


def test_every_declared_dependency_is_imported_by_the_packages():
    used = third_party(PACKAGE_FOLDERS)
    unused = sorted(declared() - set(used))
    assert not unused, f"in [project] dependencies but imported nowhere in {PACKAGE_FOLDERS}: {unused}"


@pytest.mark.parametrize("folders, extras", [(["tests", "benchmarks"], ("dev",)), (["docs"], ("docs", "screenshots"))])
def test_tests_and_docs_import_only_declared_dependencies(folders, extras):
    used = third_party(folders)
    undeclared = {dist: sorted(files) for dist, files in used.items() if dist not in declared(*extras)}
    assert not undeclared, f"imported under {folders} but not in dependencies or {extras}: {undeclared}"


def test_import_names_map_to_the_declared_distributions():
    """The names that differ between import and distribution resolve as pyproject spells them."""
    for module, dist in [("zenoh", "eclipse-zenoh"), ("yaml", "pyyaml"), ("rerun", "rerun-sdk")]:
        assert distribution_of(module) == dist
        assert dist in declared()
