"""The layout docs/explanation/architecture.md describes, checked on the source: who imports whom.

That page's table of layers ("What may import what") is the one place the import rules are stated:
:func:`layers` reads it and :func:`test_imports_follow_the_layers` enforces it on every module.
"""

from __future__ import annotations

import ast
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

from tests.conftest import ROOT

FOLDERS = {"splitspec_core": "splitspec_core", "splitspec_agents": "agents", "splitspec_plant": "plant",
           "splitspec_orchestrator": "orchestrator"}
LONG = 420  # lines of code (docstrings not counted); a longer module says why in its docstring ("Why one module: ...")


def modules(package: str) -> dict[str, Path]:
    """``{dotted module name: path}`` of an installed package, from its repository folder."""
    folder = ROOT / FOLDERS[package]
    out = {}
    for path in sorted(folder.rglob("*.py")):
        rel = path.relative_to(folder).with_suffix("")
        parts = [package, *rel.parts]
        if parts[-1] == "__init__":
            parts.pop()
        out[".".join(parts)] = path
    return out


def imports(name: str, path: Path) -> set[str]:
    """Absolute names of every module ``path`` imports (relative imports resolved, lazy ones included)."""
    return _imports_of(name, path, ast.parse(path.read_text(), str(path)))


def _imports_of(name: str, path: Path, tree: ast.AST) -> set[str]:
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]

    def absolute(level: int, module: str | None) -> str:
        if not level:
            return module or ""
        base = package.split(".")[: len(package.split(".")) - level + 1]
        return ".".join(base + ([module] if module else []))

    found = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            found |= {a.name for a in node.names}
        elif isinstance(node, ast.ImportFrom):
            mod = absolute(node.level, node.module)
            found.add(mod)
            found |= {f"{mod}.{a.name}" for a in node.names}
        elif _is_import_module(node) and node.args and isinstance(node.args[0], ast.Constant):
            target = node.args[0].value  # importlib.import_module("a.b") or (".b", __package__): an import too
            dots = len(target) - len(target.lstrip("."))
            found.add(absolute(dots, target.lstrip(".") or None) if dots else target)
        elif (isinstance(node, ast.Assign) and any(isinstance(t, ast.Name) and t.id == "_PUBLIC" for t in node.targets)
              and isinstance(node.value, ast.Dict)):
            # splitspec_core/__init__.py: the public names load their modules on first use (PEP 562)
            found |= {f"{name}.{v.value}" for v in node.value.values if isinstance(v, ast.Constant)}
    return found


def _is_import_module(node: ast.AST) -> bool:
    """A call of ``importlib.import_module`` or ``__import__`` (however it was imported)."""
    if not isinstance(node, ast.Call):
        return False
    f = node.func
    return (isinstance(f, ast.Attribute) and f.attr == "import_module") or \
        (isinstance(f, ast.Name) and f.id in ("import_module", "__import__"))


def _under(name: str, prefix: str) -> bool:
    return name == prefix or name.startswith(prefix + ".")


ARCHITECTURE = ROOT / "docs" / "explanation" / "architecture.md"
LAYER_COLUMNS = ["layer", "packages/modules", "may import", "never imports"]


def _cells(line: str) -> list[str]:
    return [c.strip() for c in line.strip().strip("|").split("|")]


def layers() -> dict[str, dict]:
    """The layers table of :data:`ARCHITECTURE`: ``{layer: {"prefixes", "may", "never"}}``.

    Its header is :data:`LAYER_COLUMNS`; ``packages/modules`` and ``never imports`` hold backticked
    module names, ``may import`` comma-separated layer names.
    """
    lines = ARCHITECTURE.read_text(encoding="utf-8").splitlines()
    heads = [k for k, line in enumerate(lines) if line.startswith("|") and _cells(line) == LAYER_COLUMNS]
    assert len(heads) == 1, f"{ARCHITECTURE} must hold one table with the columns {LAYER_COLUMNS}"
    out = {}
    for line in lines[heads[0] + 2:]:
        if not line.startswith("|"):
            break
        layer, mods, may, never = _cells(line)
        out[layer] = {"prefixes": re.findall(r"`([^`]+)`", mods),
                      "may": {m.strip() for m in may.split(",") if m.strip()},
                      "never": re.findall(r"`([^`]+)`", never)}
    return out


def layer_of(name: str, table: dict[str, dict]) -> str | None:
    """The layer of module ``name``: the one whose package is the longest prefix of it (None: no layer)."""
    best = max(((len(p), layer) for layer, row in table.items() for p in row["prefixes"] if _under(name, p)),
               default=None)
    return best and best[1]


CORE_LAYERS = ["base", "scenarios", "model", "synthesis", "simulation", "studies"]
NODE_MAY = {"base", "scenarios", "model", "runtime"}  # what an agent or the plant process may import


def test_the_layers_table_is_whole():
    """Every layer a row may import is a row; every module of every package is in a layer."""
    table = layers()
    assert {*CORE_LAYERS, "api", "runtime", "agents", "plant", "rounds", "records", "viewer", "orchestrator",
            "entry"} <= set(table), sorted(table)
    unknown = {m for row in table.values() for m in row["may"]} - set(table)
    assert not unknown, unknown
    orphans = [name for package in FOLDERS for name in modules(package) if layer_of(name, table) is None]
    assert not orphans, orphans


def test_the_layers_table_keeps_the_rules():
    """The rules the layout stands on, so that loosening the table is a visible decision: the math's layers
    import only the layers below them and neither the runtime nor Zenoh, msgpack, Rerun; agents and plant
    import only scenarios, model and the runtime (never the design stack); the round rules are I/O-free; the
    orchestrator imports neither agents nor plant (it starts them) but for the ``splitspec`` entry point."""
    table = layers()
    for k, layer in enumerate(CORE_LAYERS):
        row = table[layer]
        assert row["may"] <= {"base", *CORE_LAYERS[1: k + 1]}, (layer, row["may"])
        assert {"zenoh", "msgpack", "rerun", "matplotlib"} <= set(row["never"]), (layer, row["never"])
    assert table["api"]["may"] <= {*CORE_LAYERS, "api", "widget"}, table["api"]
    for node in ("agents", "plant"):
        assert table[node]["may"] <= NODE_MAY | {node}, table[node]
        assert "scipy" in table[node]["never"], table[node]
    assert {"zenoh", "rerun"} <= set(table["rounds"]["never"]), table["rounds"]
    assert "records" not in table["viewer"]["may"], table["viewer"]
    for layer in ("orchestrator", "rounds", "records", "viewer"):
        assert not {"agents", "plant"} & table[layer]["may"], table[layer]
    assert layer_of("splitspec_core.runtime.bus", table) == "runtime"
    assert layer_of("splitspec_core.model.steps", table) == "model"
    assert layer_of("splitspec_core.errors", table) == "base"
    assert layer_of("splitspec_orchestrator.cli", table) == "entry"


def test_imports_follow_the_layers():
    """Every import of every module (lazy ones included) obeys its layer's row of the table in
    docs/explanation/architecture.md: modules of the project only from the layers it may import,
    no third-party package it never imports."""
    table = layers()
    bad = []
    for package in FOLDERS:
        for name, path in modules(package).items():
            row = table[layer_of(name, table)]
            for imp in sorted(imports(name, path)):
                if imp.split(".")[0] in FOLDERS:
                    target = layer_of(imp, table)
                    if target not in row["may"]:
                        bad.append((name, imp, f"{layer_of(name, table)} may not import {target}"))
                elif any(_under(imp, n) for n in row["never"]):
                    bad.append((name, imp, f"{layer_of(name, table)} never imports it"))
    assert not bad, bad


def import_graph(package: str) -> dict[str, set[str]]:
    """``{module: the modules of the same package it imports}``, lazy (function-level) imports, ``import_module``
    strings and the imports under ``if TYPE_CHECKING:`` included (an annotation's import is a dependency too:
    a module that needs another's type to be read sits above it)."""
    mods = modules(package)
    return {name: {imp for imp in imports(name, path) if imp in mods and imp != name} for name, path in mods.items()}


def import_cycles(package: str) -> dict[frozenset, list[str]]:
    """The import cycles of ``package``: ``{modules that import each other, one cycle through them}``."""
    graph = import_graph(package)

    def path(src: str, dst: str) -> list[str]:  # shortest import path src -> ... -> dst (breadth first)
        prev, todo = {src: None}, [src]
        for name in todo:
            for nxt in sorted(graph[name]):
                if nxt not in prev:
                    prev[nxt] = name
                    todo.append(nxt)
        out, at = [dst], prev.get(dst)
        while at is not None:
            out.append(at)
            at = prev[at]
        return out[::-1] if out[-1] == src else []

    found = {}
    for name in sorted(graph):
        for nxt in sorted(graph[name]):
            back = path(nxt, name)
            if back:
                loop = [name, *back]
                group = frozenset(n for n in graph if path(n, name) and path(name, n)) | {name}
                found.setdefault(group, loop)
    return found


#: import cycles still allowed, each named with the imports that close it (none: issue 21 broke the last ones,
#: api <-> runs and designer <-> conditioning/full_matrix/baselines; issue 29 the type-checking ones, designer <->
#: conditioning/error_matrix and observability <-> gains); a listed cycle that is gone fails the test
KNOWN_CYCLES: set = set()


@pytest.mark.parametrize("package", list(FOLDERS))
def test_no_import_cycle(package):
    """No module imports, even lazily inside a function or for annotations only, a module that imports it back
    (directly or through others), but for the cycles listed in ``KNOWN_CYCLES``; the failure shows the cycle."""
    cycles = import_cycles(package)
    known = {c for c in KNOWN_CYCLES if next(iter(c)).split(".")[0] == package}
    new = [" -> ".join(loop) for group, loop in cycles.items() if group not in known]
    assert not new, new
    gone = [sorted(c) for c in known if c not in cycles]
    assert not gone, f"no longer a cycle, delete it from KNOWN_CYCLES: {gone}"


def test_every_dynamic_import_is_seen():
    """``importlib.import_module`` / ``__import__`` only with a constant module name (the layers test reads it as an
    import); the one computed name is ``splitspec_core``'s lazy public names, read from its ``_PUBLIC`` table."""
    bad = []
    for package in FOLDERS:
        for name, path in modules(package).items():
            for node in ast.walk(ast.parse(path.read_text(), str(path))):
                if _is_import_module(node) and not (node.args and isinstance(node.args[0], ast.Constant)):
                    if name != "splitspec_core":
                        bad.append((name, node.lineno))
    assert not bad, bad


CLASS_LINES = 450  # a class longer than this carries more than one idea (issue 29)


def test_no_class_is_a_house():
    """No class of the packages over :data:`CLASS_LINES` lines."""
    big = []
    for package in FOLDERS:
        for name, path in modules(package).items():
            for node in ast.walk(ast.parse(path.read_text(), str(path))):
                if isinstance(node, ast.ClassDef) and node.end_lineno - node.lineno + 1 > CLASS_LINES:
                    big.append((f"{name}.{node.name}", node.end_lineno - node.lineno + 1))
    assert not big, big


def test_no_generic_top_level_import_names():
    """Nothing imports the bare folder names (``agents`` is another package's import name)."""
    bad = []
    for root in [*FOLDERS.values(), "tests", "benchmarks", "examples", "docs"]:
        for path in (ROOT / root).rglob("*.py"):
            for imp in imports("x.y", path):
                if imp.split(".")[0] in ("agents", "plant", "orchestrator"):
                    bad.append((str(path.relative_to(ROOT)), imp))
    assert not bad, bad


def test_every_package_says_what_it_holds():
    """Each package's and subpackage's docstring says what it holds (a room that says what it is)."""
    bad = []
    for package, folder in FOLDERS.items():
        for init in sorted((ROOT / folder).rglob("__init__.py")):
            doc = ast.get_docstring(ast.parse(init.read_text())) or ""
            if len(doc.split()) < 8 or "placeholder" in doc.lower():
                bad.append((str(init.relative_to(ROOT)), doc[:40]))
    assert not bad, bad


SUBPACKAGES = ["splitspec_core.scenarios", "splitspec_core.model", "splitspec_core.synthesis",
               "splitspec_core.simulation", "splitspec_core.studies", "splitspec_orchestrator.rounds",
               "splitspec_orchestrator.records", "splitspec_orchestrator.viewer"]


@pytest.mark.parametrize("subpackage", SUBPACKAGES)
def test_a_subpackage_names_each_of_its_modules(subpackage):
    """The docstring of each subpackage by role names every module in it (``name.py``), so that reading it says
    where a change goes."""
    package = subpackage.split(".")[0]
    mods = modules(package)
    doc = ast.get_docstring(ast.parse(mods[subpackage].read_text())) or ""
    missing = [name for name in mods if name.rpartition(".")[0] == subpackage
               and f"{name.rpartition('.')[2]}.py" not in doc]
    assert not missing, missing


def _named_in(doc: str, package: str, folder: Path) -> list[tuple[str, Path | None]]:
    """What a package docstring names: ``name.py`` files of its folder and :mod:`.x` / :mod:`pkg.x.y` modules,
    each with the file or folder it must be (None: a name outside splitspec's packages, not checked)."""
    out = [(m, folder / m) for m in re.findall(r"``([a-z_0-9]+\.py)``", doc)]
    for ref in re.findall(r":mod:`~?([.\w]+)`", doc):
        if ref.startswith("."):
            parts, base = ref[1:].split("."), folder
        else:
            top, *parts = ref.split(".")
            if top not in FOLDERS:
                out.append((ref, None))
                continue
            base = ROOT / FOLDERS[top]
        out.append((ref, base.joinpath(*parts)))
    return out


def test_package_docstrings_name_only_modules_that_exist():
    """Every module a package's docstring names (``name.py`` or :mod:`...`) exists: a docstring that still names
    modules that have moved sends a newcomer to files that are not there."""
    bad = []
    for package, folder in FOLDERS.items():
        for init in sorted((ROOT / folder).rglob("__init__.py")):
            doc = ast.get_docstring(ast.parse(init.read_text())) or ""
            for name, path in _named_in(doc, package, init.parent):
                if path is not None and not (path.with_suffix(".py").is_file() or (path / "__init__.py").is_file()
                                             or path.is_file()):
                    bad.append((str(init.relative_to(ROOT)), name))
    assert not bad, bad


def test_the_docstring_check_sees_a_moved_module(tmp_path):
    """The check above on a docstring naming one module that exists and two that do not."""
    (tmp_path / "here.py").write_text("")
    doc = "``here.py`` the one; ``gone.py`` moved; :mod:`.away` too; :mod:`numpy.linalg` not ours"
    missing = [n for n, p in _named_in(doc, "splitspec_core", tmp_path)
               if p is not None and not (p.with_suffix(".py").is_file() or p.is_file())]
    assert missing == ["gone.py", ".away"]


def code_lines(tree: ast.Module, text: str) -> int:
    """Lines of ``text`` outside its docstrings (module, class and function): the numpydoc sections of every public
    function (issue 36) describe the code, they do not add ideas to the module."""
    doc_lines = set()
    for node in ast.walk(tree):
        if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)) and node.body:
            first = node.body[0]
            if isinstance(first, ast.Expr) and isinstance(first.value, ast.Constant) and \
                    isinstance(first.value.value, str):
                doc_lines |= set(range(first.lineno, first.end_lineno + 1))
    return len(text.splitlines()) - len(doc_lines)


def test_long_modules_say_why():
    long = []
    for package in FOLDERS:
        for name, path in modules(package).items():
            tree = ast.parse(path.read_text())
            n = code_lines(tree, path.read_text())
            doc = ast.get_docstring(tree) or ""
            if n > LONG and "Why one module:" not in doc:
                long.append((name, n))
    assert not long, long


def test_installed_names_work_outside_the_repository(tmp_path):
    """From another directory (the checkout not on sys.path): the installed import names and ``-m`` entry points."""
    env = {**os.environ, "PYTHONPATH": "", "RERUN_ANALYTICS": "0"}
    code = ("import sys, splitspec_core, splitspec_orchestrator.cli, splitspec_agents.agent, splitspec_plant.plant\n"
            "assert not {'agents', 'plant', 'orchestrator'} & set(sys.modules), sorted(sys.modules)\n"
            "assert 'splitspec_core.runtime.bus' not in sys.modules  # nothing above needs Zenoh at import\n"
            "print(splitspec_core.__file__)")
    r = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, env=env, capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    assert Path(r.stdout.strip()).parent == ROOT / "splitspec_core"
    for pkg, words in (("splitspec_agents", "--id ID --connect ENDPOINT"), ("splitspec_plant", "--connect ENDPOINT"),
                       ("splitspec_orchestrator", "design")):
        r = subprocess.run([sys.executable, "-m", pkg, "--help"], cwd=tmp_path, env=env, capture_output=True,
                           text=True)
        assert r.returncode == 0 and words in " ".join(r.stdout.split()), (pkg, r.stdout, r.stderr)


@pytest.mark.parametrize("pkg", ["splitspec_agents", "splitspec_plant"])
def test_node_bad_argument_is_one_line(tmp_path, pkg):
    r = subprocess.run([sys.executable, "-m", pkg, "--connect", "tcp/127.0.0.1:1", "--run-id", "x", "--wait", "-1"],
                       cwd=tmp_path, capture_output=True, text=True, env={**os.environ, "RERUN_ANALYTICS": "0"})
    assert r.returncode == 2 and r.stderr.count("\n") == 1, r.stderr
    assert r.stderr.startswith("splitspec: error: ") and "--wait must be a number" in r.stderr, r.stderr


#: what no plant or agent process of a discrete-time scenario with pole placement or explicit gains loads
#: (scipy: about 30 MB of RSS per process; the plotting, recording and simulation modules: the orchestrator's)
NODE_NEVER = ("scipy", "matplotlib", "rerun", "pyarrow", "splitspec_orchestrator", "splitspec_core.synthesis",
              "splitspec_core.simulation", "splitspec_core.studies", "splitspec_core.api")


@pytest.mark.parametrize("example", ["ring10.yaml", "paper_discrete.yaml"])
def test_a_node_imports_only_what_it_uses(tmp_path, example):
    """A fresh interpreter with everything an agent and the plant load up to their first round: their entry
    modules and shell, the scenario and the local design from the config, the first tick (``yaml`` stays:
    the config carries the scenario's text, parsed once)."""
    code = f"""
import sys
from pathlib import Path
from splitspec_agents.agent import AgentNode, cli_main
from splitspec_plant.plant import PlantNode, cli_main as plant_main
from splitspec_core.runtime.node import NodeShell
from splitspec_core.runtime.wire import encode, new_run_key
key = new_run_key()
cfg = {{"scenario": Path({str(ROOT / "examples" / example)!r}).read_text(), "seed": 7, "g": None, "q": 3,
        "g_mode": None, "key": key}}
agent, plant = AgentNode(1, cfg, "r"), PlantNode(cfg, "r")
ids = agent.sc.agent_ids
tick = encode("tick", "r", mac_key=key, tau=0, attempt=0, graph=0, final=False, alive=ids,
              rows={{str(i): [[i], [1.0]] for i in ids}}, incarnation={{str(i): 0 for i in ids}}, fresh=True,
              prev_attempt=0, partition=[], topology=1)
assert agent.on_tick(tick)
y = dict(plant.on_tick(tick))[agent.keys.y]
assert any("xhat" in k for k, _ in agent.on_y(y))  # a whole round: the step functions ran
never = {NODE_NEVER!r}
print(sorted(m for m in sys.modules if any(m == n or m.startswith(n + ".") for n in never)))
"""
    r = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, capture_output=True, text=True,
                       env={**os.environ, "RERUN_ANALYTICS": "0"})
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip() == "[]", r.stdout


def test_no_module_of_the_math_is_named_after_an_api_name():
    """``import splitspec_core.X`` binds ``X`` on the package: a module named like a public name (as
    ``network_sweep.py`` was) would replace ``ss.X`` once anything imported the module."""
    import splitspec_core

    names = {name.rpartition(".")[2] for name in modules("splitspec_core")}
    assert not names & set(splitspec_core.__all__), sorted(names & set(splitspec_core.__all__))


def private_imports() -> list[tuple[str, str]]:
    """``(module, name)`` for every ``from <project module> import _name``: one module reaching into another's
    private names (a name others need is public, or the two are one module)."""
    out = []
    for package in FOLDERS:
        for name, path in modules(package).items():
            for node in ast.walk(ast.parse(path.read_text(), str(path))):
                if isinstance(node, ast.ImportFrom):
                    mod = min(_imports_of(name, path, ast.Module(body=[node], type_ignores=[])), key=len)
                    if mod.split(".")[0] in FOLDERS:
                        out += [(name, f"{mod}.{a.name}") for a in node.names
                                if a.name.startswith("_") and not a.name.startswith("__")]
    return out


def test_no_private_name_crosses_a_module():
    """No module imports another module's ``_private`` names."""
    found = private_imports()
    assert not found, found


def test_every_subpackage_is_installed():
    """Every folder of a package is in pyproject's package list: a subpackage left out is missing from ``pip install
    .`` (the image, other hosts) while an editable install still finds it (as ``splitspec_orchestrator.commands``
    was)."""
    import tomllib

    listed = set(tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]["packages"])
    found = {name for package in FOLDERS for name, path in modules(package).items() if path.name == "__init__.py"}
    assert found == listed, (sorted(found - listed), sorted(listed - found))


def test_code_lines_leave_out_docstrings_only():
    text = '"""Module.\n\nMore."""\nX = 1\n\n\ndef f():\n    """One.\n\n    Two.\n    """\n    return "not a docstring"\n'
    assert code_lines(ast.parse(text), text) == len(text.splitlines()) - 3 - 4


# ---------------------------------------------------------------------------------------------- the module tree

TREE_PACKAGES = ("splitspec_core", "agents", "plant", "orchestrator")
_HEADING = re.compile(r"^( *)([a-z_]+)/(?=\s|$)")


def module_tree() -> dict[tuple[str, ...], set[str]]:
    """The architecture page's ``text`` block under "The modules": for each folder (its path of headings, e.g.
    ``("splitspec_core", "synthesis")``) the file names its own lines mention (``commands/{a,b}.py`` expanded)."""
    text = (ROOT / "docs" / "explanation" / "architecture.md").read_text()
    block = text.split("## The modules", 1)[1].split("```text", 1)[1].split("```", 1)[0]
    named: dict[tuple[str, ...], set[str]] = {}
    stack: list[tuple[int, str]] = []  # (indent, folder) of the open headings
    for line in block.splitlines():
        if not line.strip():
            continue
        m = _HEADING.match(line)
        indent = len(line) - len(line.lstrip())
        if m:
            while stack and stack[-1][0] >= indent:
                stack.pop()
            stack.append((indent, m.group(2)))
            line = line[m.end():]
        path = tuple(f for _, f in stack)
        line = re.sub(r"(\w+)/\{([\w,]+)\}\.py",
                      lambda g: " ".join(f"{g[1]}/{n}.py" for n in g[2].split(",")), line)
        for word in re.findall(r"(?:[a-z_]+/)*[a-z_0-9]+\.py", line):
            *sub, name = word.split("/")
            named.setdefault(path + tuple(sub), set()).add(name)
    return named


def test_the_architecture_page_names_every_module_in_its_folder():
    """The module tree of docs/explanation/architecture.md is checked against the code: every module is named
    under its own folder, and every name there is a module of that folder (issue 46: 15 of 121 were missing)."""
    named = module_tree()
    actual: dict[tuple[str, ...], set[str]] = {}
    for pkg in TREE_PACKAGES:
        for f in (ROOT / pkg).rglob("*.py"):
            if f.name != "__init__.py" and "__pycache__" not in f.parts:
                actual.setdefault(f.relative_to(ROOT).parent.parts, set()).add(f.name)
    missing = sorted("/".join(k) + "/" + n for k, names in actual.items() for n in names - named.get(k, set())
                     if n != "__main__.py")
    stale = sorted("/".join(k) + "/" + n for k, names in named.items() for n in names - actual.get(k, set()))
    assert not missing, f"modules the architecture page does not name under their folder: {missing}"
    assert not stale, f"names the architecture page puts in a folder that has no such module: {stale}"
