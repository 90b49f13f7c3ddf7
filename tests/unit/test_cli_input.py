"""Bad command-line input: one line ``splitspec: error: ...``, exit 2, no traceback, nothing started.

Every case runs the real CLI in a subprocess (``python -m splitspec_orchestrator``)
with a timeout, so a case that would block (a FIFO as scenario file) or read
without end (``/dev/zero``) fails the test instead of hanging it.  All of them
are refused while the arguments are parsed or the scenario is loaded: none
gets as far as designing, simulating or starting a process.
"""

from __future__ import annotations

import os
import resource
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from splitspec_orchestrator import cli
from splitspec_core.scenarios import load as scenario_module
from splitspec_core.errors import ScenarioError
from splitspec_core.scenarios.load import MAX_FILE_BYTES, load_scenario, parse_scenario_text
from splitspec_core.scenarios.specs import MAX_SEED
from splitspec_core.simulation.simulator import check_trajectory_memory

ROOT = Path(__file__).resolve().parents[2]
EXAMPLES = ROOT / "examples"
DISCRETE = EXAMPLES / "paper_discrete.yaml"
NOISY = EXAMPLES / "paper_discrete_noise.yaml"
PREFIX = "splitspec: error: "
HUGE_STEPS = 10**12  # (T, m, n) float64 of 3 agents, n = 4: about 87 TiB, more than any test machine has


def _limit_memory() -> None:
    """In the child: at most 2 GiB of address space, so a regression that reads /dev/zero fails fast."""
    resource.setrlimit(resource.RLIMIT_AS, (2 * 2**30, 2 * 2**30))


def run_cli(*argv, timeout: float = 60) -> subprocess.CompletedProcess:
    """The real CLI in a child with a timeout and a memory limit: nothing here can hang or exhaust the machine."""
    env = {k: v for k, v in os.environ.items() if k != "SPLITSPEC_DEBUG"}
    env["RERUN_ANALYTICS"] = "0"
    return subprocess.run([sys.executable, "-m", "splitspec_orchestrator", *map(str, argv)], cwd=ROOT, env=env,
                          capture_output=True, text=True, timeout=timeout, stdin=subprocess.DEVNULL,
                          preexec_fn=_limit_memory)


def assert_one_line_error(r: subprocess.CompletedProcess, *fragments: str) -> str:
    err = r.stderr
    assert "Traceback" not in err, err
    assert r.returncode == 2, (r.returncode, err)
    lines = err.splitlines()
    assert len(lines) == 1 and err.endswith("\n"), f"expected exactly one line on stderr, got {err!r}"
    assert lines[0].startswith(PREFIX) and lines[0][len(PREFIX):].strip(), err
    assert "usage:" not in err
    for fragment in fragments:
        assert fragment in lines[0], f"{fragment!r} not in {lines[0]!r}"
    return lines[0]


def _scenario_file(tmp_path: Path, base: Path, **run) -> Path:
    data = yaml.safe_load(base.read_text(encoding="utf-8"))
    data.setdefault("run", {}).update(run)
    p = tmp_path / "scenario.yaml"
    p.write_text(yaml.safe_dump(data, sort_keys=False), encoding="utf-8")
    return p


# --------------------------------------------------------------------------
# numbers on the command line
# --------------------------------------------------------------------------

SECONDS = ["nan", "0", "-1", "inf", "-inf", "1e300", "soon"]

# (id, argv after the subcommand's scenario (or none), fragments)
OPTION_CASES = [
    *[(f"run-round-timeout-{v}", ["run", DISCRETE, "--out", "{out}", f"--round-timeout={v}"],
       ["--round-timeout must be a number in (0, 1e+06]", repr(v)]) for v in SECONDS],
    *[(f"run-wait-{v}", ["run", DISCRETE, "--out", "{out}", f"--wait={v}"],
       ["--wait must be a number in (0, 1e+06]", repr(v)]) for v in SECONDS],
    ("orchestrator-round-timeout-0", ["orchestrator", DISCRETE, "--out", "{out}", "--listen", "tcp/127.0.0.1:1",
                                      "--round-timeout", "0"], ["--round-timeout must be a number in (0"]),
    ("plant-wait-nan", ["plant", "--connect", "tcp/127.0.0.1:1", "--wait", "nan"], ["--wait must be a number"]),
    ("agent-wait-0", ["agent", "--id", "1", "--connect", "tcp/127.0.0.1:1", "--wait", "0"],
     ["--wait must be a number"]),
    ("simulate-seed-2**70", ["simulate", DISCRETE, "--out", "{out}", "--seed", str(2**70)],
     ["--seed must be <= 9223372036854775807", str(2**70)]),
    ("simulate-seed-2**63", ["simulate", DISCRETE, "--out", "{out}", "--seed", str(2**63)], ["--seed must be <="]),
    ("simulate-seed-negative", ["simulate", DISCRETE, "--out", "{out}", "--seed", "-1"], ["--seed must be >= 0"]),
    ("simulate-seed-float", ["simulate", DISCRETE, "--out", "{out}", "--seed", "1.5"],
     ["--seed must be an integer", "'1.5'"]),
    ("simulate-steps-0", ["simulate", DISCRETE, "--out", "{out}", "--steps", "0"], ["--steps must be >= 1"]),
    ("simulate-steps-text", ["simulate", DISCRETE, "--out", "{out}", "--steps", "many"],
     ["--steps must be an integer"]),
    ("simulate-steps-huge", ["simulate", DISCRETE, "--out", "{out}", "--steps", str(HUGE_STEPS)],
     [f"--steps = {HUGE_STEPS} needs", "GiB for the trajectory (T x m x n float64); this machine has"]),
    ("simulate-monte-carlo-0", ["simulate", DISCRETE, "--out", "{out}", "--monte-carlo", "0"],
     ["--monte-carlo must be >= 1"]),
    ("simulate-monte-carlo-memory", ["simulate", DISCRETE, "--out", "{out}", "--steps", "10000000000",
                                     "--monte-carlo", "7"],
     ["--steps = 10000000000 needs", "GiB for the trajectory (T x m x n float64)"]),  # the seeds keep none
    ("simulate-monte-carlo-seed-range", ["simulate", DISCRETE, "--out", "{out}", "--seed", str(MAX_SEED),
                                         "--monte-carlo", "2"], ["--monte-carlo", "exceeds 2**63 - 1"]),
    ("compare-seed-2**70", ["compare", NOISY, "--out", "{out}", "--seed", str(2**70)], ["--seed must be <="]),
    ("compare-seeds-0", ["compare", NOISY, "--out", "{out}", "--seeds", "0"], ["--seeds must be >= 1"]),
    ("compare-seeds-range", ["compare", NOISY, "--out", "{out}", "--seed", str(MAX_SEED - 3), "--seeds", "5"],
     ["--seeds: the last seed", "exceeds 2**63 - 1"]),
    ("compare-steps-3", ["compare", NOISY, "--out", "{out}", "--steps", "3"], ["--steps must be >= 4"]),
    ("compare-steps-huge", ["compare", NOISY, "--out", "{out}", "--steps", str(HUGE_STEPS)],
     [f"--steps = {HUGE_STEPS} needs", "this machine has"]),
    *[(f"compare-kcf-eps-{v}", ["compare", NOISY, "--out", "{out}", f"--kcf-eps={v}"],
       ["--kcf-eps must be a number in (0, 1e+12]"]) for v in ("0", "-1", "nan", "inf")],
    ("unknown-command", ["frobnicate"], ["invalid choice: 'frobnicate'"]),
    ("no-command", [], ["the following arguments are required: COMMAND"]),
    ("missing-out", ["simulate", DISCRETE], ["the following arguments are required: --out"]),
    ("unknown-option", ["design", DISCRETE, "--fast"], ["unrecognized arguments: --fast"]),
]


@pytest.mark.parametrize("argv, fragments", [pytest.param(a, f, id=i) for i, a, f in OPTION_CASES])
def test_bad_option_is_one_line_exit_2(argv, fragments, tmp_path):
    out = tmp_path / "out"
    r = run_cli(*[str(a).replace("{out}", str(out)) for a in argv])
    assert_one_line_error(r, *fragments)
    assert not out.exists(), "refused before anything was written"


# --------------------------------------------------------------------------
# run.steps: allowed by the loader, refused where memory is preallocated
# --------------------------------------------------------------------------


@pytest.mark.parametrize("command, base", [("simulate", DISCRETE), ("compare", NOISY)])
def test_huge_run_steps_are_refused_by_simulate_and_compare(command, base, tmp_path):
    path = _scenario_file(tmp_path, base, steps=HUGE_STEPS)
    r = run_cli(command, path, "--out", tmp_path / "out", "--no-plots")
    line = assert_one_line_error(r, f"run.steps = {HUGE_STEPS} needs", "GiB for the trajectory (T x m x n float64)",
                                 "this machine has")
    have = os.sysconf("SC_PHYS_PAGES") * os.sysconf("SC_PAGE_SIZE") / 2**30
    assert line.endswith(f"this machine has {have:.1f} GiB")


def test_huge_run_steps_still_load_and_design(tmp_path):
    """The multi-process run grows its rows: the loader itself does not forbid many steps."""
    path = _scenario_file(tmp_path, DISCRETE, steps=HUGE_STEPS)
    assert load_scenario(path).run.steps == HUGE_STEPS
    r = run_cli("design", path)
    assert r.returncode == 0, r.stderr


def test_trajectory_memory_check_in_the_core(tmp_path, monkeypatch):
    """simulate, simulate_exact and the baselines refuse before preallocating; the bound is T x m x n x 8 bytes."""
    sc = load_scenario(DISCRETE)  # m = 3, n = 4: 96 bytes per event time
    monkeypatch.setattr("splitspec_core.simulation.simulator.physical_memory", lambda: 96 * 1001)
    check_trajectory_memory(sc, 1000)  # exactly fits
    with pytest.raises(ScenarioError, match=r"^steps = 1001 needs 0\.0 GiB for the trajectory"):
        check_trajectory_memory(sc, 1001)
    with pytest.raises(ScenarioError, match=r"^--steps = 500 needs .* for 2 trajectories"):
        check_trajectory_memory(sc, 500, key="--steps", copies=2)
    from splitspec_core.studies.baselines import baseline_trajectories
    from splitspec_core.synthesis.designer import design
    from splitspec_core.simulation.simulator import simulate

    des = design(sc)
    with pytest.raises(ScenarioError, match="needs"):
        simulate(des, steps=2000)
    with pytest.raises(ScenarioError, match="needs"):
        baseline_trajectories(sc, 0, exchanges=1, steps=2000)
    assert simulate(des, steps=40).xhat.shape == (41, 3, 4)


# --------------------------------------------------------------------------
# scenario files: regular files only, at most 16 MB
# --------------------------------------------------------------------------


def test_dev_zero_is_refused(tmp_path):
    assert_one_line_error(run_cli("design", "/dev/zero", timeout=30), "/dev/zero is a character device",
                          "not a regular file")


@pytest.mark.parametrize("command", ["design", "simulate", "compare", "run"])
def test_fifo_is_refused_without_blocking(command, tmp_path):
    fifo = tmp_path / "scenario.yaml"
    os.mkfifo(fifo)
    argv = [command, fifo] + ([] if command == "design" else ["--out", tmp_path / "out"])
    assert_one_line_error(run_cli(*argv, timeout=30), f"{fifo} is a FIFO, not a regular file")


def test_directory_is_refused(tmp_path):
    assert_one_line_error(run_cli("design", tmp_path), f"scenario file {tmp_path} is a directory")


def test_file_over_16_mb_is_refused(tmp_path):
    big = tmp_path / "big.yaml"
    big.write_bytes(DISCRETE.read_bytes() + b"# padding\n" + b"#" * (17 * 10**6))
    size = big.stat().st_size / 1e6
    assert_one_line_error(run_cli("design", big), f"scenario file {big} is {size:.1f} MB; the limit is 16 MB")


def test_file_of_exactly_16_mb_is_read(tmp_path):
    """The limit is inclusive: a valid scenario padded with a comment to exactly 16 MB loads."""
    text = DISCRETE.read_text(encoding="utf-8") + "#"
    big = tmp_path / "limit.yaml"
    big.write_text(text + "x" * (MAX_FILE_BYTES - len(text.encode()) - 1) + "\n", encoding="utf-8")
    assert big.stat().st_size == MAX_FILE_BYTES
    assert load_scenario(big).name == "paper-discrete"


# --------------------------------------------------------------------------
# one YAML helper, libyaml's C loader when present
# --------------------------------------------------------------------------


def test_yaml_loader_is_the_c_loader_when_libyaml_is_there(monkeypatch):
    expected = yaml.CSafeLoader if yaml.__with_libyaml__ else yaml.SafeLoader
    assert issubclass(scenario_module.yaml_loader(), expected)
    monkeypatch.setattr(yaml, "__with_libyaml__", False)
    assert issubclass(scenario_module.yaml_loader(), yaml.SafeLoader)
    assert not issubclass(scenario_module.yaml_loader(), yaml.CSafeLoader)


@pytest.mark.parametrize("text, value", [
    ("1e-3", 1e-3), ("1E5", 1e5), ("+1e3", 1e3), ("-2.5e-1", -0.25), (".5", 0.5), ("1.", 1.0), ("6.02e+23", 6.02e23),
    ("017", 17), ("-2", -2), ("+3", 3), ("0o17", 15), ("0x1F", 31), (".inf", float("inf")), ("-.Inf", float("-inf")),
    ("1:20", "1:20"), ("1_000", "1_000"), ("0b101", "0b101"), ("1e", "1e"), ("true", True), ("yes", True),
    ("'1e-3'", "1e-3"), ("~", None),
])
@pytest.mark.parametrize("libyaml", [True, False])
def test_scenario_yaml_reads_numbers_as_yaml_1_2(monkeypatch, text, value, libyaml):
    """YAML 1.2's core schema for numbers (1.1 read 1e-3 as a string, 017 as octal 15, 1:20 as 80); booleans as
    before; the C and the pure-Python loader alike."""
    if libyaml and not yaml.__with_libyaml__:
        pytest.skip("PyYAML without libyaml")
    monkeypatch.setattr(yaml, "__with_libyaml__", libyaml)
    got = scenario_module.load_yaml(f"v: {text}\n")["v"]
    assert got == value and type(got) is type(value)


def test_a_scenario_takes_an_exponent_without_a_dot_and_writes_strings_that_look_like_numbers_quoted():
    text = DISCRETE.read_text(encoding="utf-8").replace("design:", "design:\n  rank_tol: 1e-3", 1)
    assert parse_scenario_text(text, source="s").design.rank_tol == 1e-3
    data = {"name": "1e3", "rate": 1e-05, "q": 17, "label": "017", "inf": float("inf")}
    back = scenario_module.load_yaml(scenario_module.dump_yaml(data))
    assert back == data and type(back["name"]) is str and type(back["label"]) is str


def test_every_scenario_parse_goes_through_the_helper(monkeypatch):
    """load_scenario and parse_scenario_text (agents, plant) parse with yaml_loader()'s loader."""
    used = []

    class Spy(yaml.SafeLoader):
        def __init__(self, stream):
            used.append(type(self))
            super().__init__(stream)

    monkeypatch.setattr(scenario_module, "yaml_loader", lambda: Spy)
    assert load_scenario(DISCRETE).m == 3
    assert parse_scenario_text(DISCRETE.read_text(encoding="utf-8"), source="config").m == 3
    assert used == [Spy, Spy]
    for module in ("agents/agent.py", "plant/plant.py", "orchestrator/cli.py", "orchestrator/driver.py"):
        src = (ROOT / module).read_text(encoding="utf-8")
        assert "yaml.safe_load(" not in src and "yaml.load(" not in src, module


def test_yaml_syntax_error_in_config_text_is_one_line():
    with pytest.raises(ScenarioError) as info:
        parse_scenario_text("system:\n  A: [[0, 1], [1, 0]\n  C: {1: [[1, 0]]}\n", source="config")
    message = str(info.value)
    assert "\n" not in message and message.startswith("config: YAML syntax error at line 3, column")


def test_cli_parser_errors_are_one_line_in_process(capsys):
    with pytest.raises(SystemExit) as info:
        cli.build_parser().parse_args(["simulate", str(DISCRETE), "--out", "x", "--seed", "-5"])
    assert info.value.code == 2
    assert capsys.readouterr().err == "splitspec: error: --seed must be >= 0, got -5\n"


def test_print_of_a_scenario_is_a_summary_not_every_matrix():
    import splitspec_core as ss

    sc = ss.load_scenario(EXAMPLES / "ieee14_pmu.yaml")
    text = repr(sc)
    assert str(sc) == text and len(text.splitlines()) == 8 and len(text) < 1000
    assert "Scenario 'ieee14-pmu' (continuous time" in text and "n = 62 states (delta_GENROU_1" in text
    assert "m = 5" in text and "ring (10 arcs)" in text and "gains optimal" in text and "dt 0.02, 1500 steps" in text
    assert f"{sc.system.A[0, 1]:.6f}" not in text  # no matrix entries
    faulty = ss.load_scenario(EXAMPLES / "ring10_faults.yaml")
    assert "resilience 1" in repr(faulty) and "kill at 10" in repr(faulty)
