"""compose.yaml and the Dockerfile: parsed and checked against the CLI, the scenario, pyproject and the how-to page
docs/how-to/several_machines.md."""

import re
import shlex
import tomllib
from importlib.metadata import version

import pytest
import yaml

from splitspec_agents.agent import build_parser as agent_parser
from splitspec_core.synthesis.designer import design
from splitspec_core.scenarios.load import load_scenario
from splitspec_orchestrator.cli import build_parser
from splitspec_plant.plant import build_parser as plant_parser
from tests.conftest import ROOT


@pytest.fixture(scope="module")
def compose():
    return yaml.safe_load((ROOT / "compose.yaml").read_text())


@pytest.fixture(scope="module")
def dockerfile():
    return (ROOT / "Dockerfile").read_text()


def splitspec_services(compose):
    return {name: s for name, s in compose["services"].items() if s.get("image", "").startswith("splitspec")}


def option(cmd, name):
    return cmd[cmd.index(name) + 1] if name in cmd else None


def test_router_image_matches_the_python_package(compose):
    router = compose["services"]["router"]
    image, tag = router["image"].split(":")
    assert image == "eclipse/zenoh"
    assert tag.split(".")[:2] == version("eclipse-zenoh").split(".")[:2]
    listen = option(router["command"], "-l") or option(router["command"], "--listen")
    assert listen == "tcp/0.0.0.0:7447" and "--no-multicast-scouting" in router["command"]


NODE_PARSERS = {"agent": agent_parser, "plant": plant_parser}


def parse_invocation(cmd: list):
    """``splitspec CMD`` parsed by the real parsers (``agent``/``plant`` hand their arguments to the
    process's own parser); SystemExit, a failed test, on a bad invocation."""
    if cmd[0] in NODE_PARSERS:
        args = NODE_PARSERS[cmd[0]]().parse_args(cmd[1:])
        args.command = cmd[0]
        return args
    return build_parser().parse_args(cmd)


def test_every_command_is_a_valid_invocation(compose):
    services = splitspec_services(compose)
    assert {"orchestrator", "plant"} <= set(services)
    roles = {}
    for name, svc in services.items():
        assert svc.get("build") == "." and svc.get("init") is True, name
        cmd = [str(c) for c in svc["command"]]
        args = parse_invocation(cmd)
        roles[name] = args
        # explicit endpoint to the router service, same run id everywhere
        host = re.fullmatch(r"tcp/([\w.-]+):7447", args.connect).group(1)
        assert host in compose["services"] and "router" in svc.get("depends_on", []), name
        assert args.run_id == "compose"
        # a plant or agent gives the router 2.5 s to listen: one that started too early is started again (bounded);
        # the orchestrator waits for the router by itself and a failed run is not repeated
        assert svc.get("restart") == ("no" if args.command in ("orchestrator", "standby") else "on-failure:3"), name
    assert {a.command for a in roles.values()} == {"orchestrator", "standby", "plant", "agent"}
    # the standby follows the orchestrator's run and writes into its records' folder
    standby = [str(c) for c in services["standby"]["command"]]
    orch = [str(c) for c in services["orchestrator"]["command"]]
    assert option(standby, "--out") == option(orch, "--out")
    assert services["standby"]["volumes"] == services["orchestrator"]["volumes"]


def test_agents_match_the_scenario_and_output_is_a_volume(compose):
    services = splitspec_services(compose)
    orch = [str(c) for c in services["orchestrator"]["command"]]
    scenario = ROOT / orch[1]
    sc = load_scenario(scenario)  # the file the image carries (examples/ is copied in)
    design(sc)  # what the orchestrator does first: the scenario is designable
    agents = sorted(int(option([str(c) for c in s["command"]], "--id")) for n, s in services.items()
                    if s["command"][0] == "agent")
    assert agents == sorted(sc.agent_ids)
    assert {f"agent-{i}" for i in agents} <= set(services)
    out = option(orch, "--out")
    assert any(v.split(":")[1] == out for v in services["orchestrator"]["volumes"])
    # the viewer URL comes from the environment (documented), and the host is reachable from the container
    assert "SPLITSPEC_VIEWER" in services["orchestrator"]["environment"]
    assert "host.docker.internal:host-gateway" in services["orchestrator"]["extra_hosts"]


def test_image_installs_what_the_howto_says(dockerfile):
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())
    setuptools = project["tool"]["setuptools"]
    packages = setuptools["packages"]
    assert "splitspec_core" in packages
    folders = setuptools.get("package-dir", {})
    packages = sorted({folders.get(p.split(".")[0], p.split(".")[0]) for p in packages})  # subpackages: their top
    assert packages == ["agents", "orchestrator", "plant", "splitspec_core"]  # the repository's folders
    copied = {src for line in dockerfile.splitlines() if line.startswith("COPY") for src in line.split()[1:-1]}
    license_files = project["project"]["license-files"]
    for pkg in packages + ["examples", "pyproject.toml", "README.md"] + license_files:  # what the build reads
        assert any(c == pkg or c.startswith(pkg) for c in copied), pkg
    runs = [line[len("RUN "):].strip() for line in dockerfile.splitlines() if line.startswith("RUN ")]
    assert runs == ["python -m pip install ."]
    howto = (ROOT / "docs" / "how-to" / "several_machines.md").read_text()
    assert f"    {runs[0]}" in howto or f"\n{runs[0]}" in howto  # the how-to's install step on other hosts
    assert "docker compose up" in howto
    assert re.search(r'ENTRYPOINT \["splitspec"\]', dockerfile)
    assert project["project"]["scripts"]["splitspec"] == "splitspec_orchestrator.cli:main"


def test_howto_hand_started_commands_parse():
    """The multi-host commands shown in docs/how-to/several_machines.md are valid invocations too."""
    howto = (ROOT / "docs" / "how-to" / "several_machines.md").read_text()
    block = howto.split("## Starting the processes by hand")[1].split("```sh")[1].split("```")[0]
    cmds = [shlex.split(line.split("#")[0]) for line in block.splitlines() if line.strip().startswith("splitspec")]
    assert len(cmds) >= 4
    for cmd in cmds:
        parse_invocation(cmd[1:])
