"""What an agent and the plant process load: a git revision ("before") against this checkout ("after").

Each sample is a fresh interpreter that imports the node's module (``splitspec_agents.agent`` or
``splitspec_plant.plant``), then builds the node from a scenario and runs its first round as
tests/unit/test_architecture.py does (the scenario parsed, the agent's local design, one tick and one
measurement). Printed per (revision, node): the import's wall time, the RSS after the import and after the
first round (``ru_maxrss``), and how many ``splitspec_core`` and ``scipy`` modules are loaded then. The two
revisions alternate (A B A B ...) and medians are reported beside the load average.

The "before" revision is extracted with ``git archive`` into a temporary folder whose package names
(``splitspec_core``, ``splitspec_agents``, ...) are put first on ``sys.path``, so the installed checkout is
not what it imports.

    .venv/bin/python benchmarks/bench_node_import.py [--before 3a1209a] [--repeat 7] [--example ring10.yaml]
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
FOLDERS = {"splitspec_core": "splitspec_core", "splitspec_agents": "agents", "splitspec_plant": "plant",
           "splitspec_orchestrator": "orchestrator"}

WORKER = r"""
import json, resource, sys, time
if sys.argv[1]:  # the "before" revision's packages first
    sys.path.insert(0, sys.argv[1])
node, example = sys.argv[2], sys.argv[3]
t0 = time.perf_counter()
if node == "agent":
    from splitspec_agents.agent import AgentNode
else:
    from splitspec_plant.plant import PlantNode
t_import = time.perf_counter() - t0
rss_import = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
import splitspec_core
assert splitspec_core.__file__.startswith(sys.argv[4]), splitspec_core.__file__
from pathlib import Path
from splitspec_core.runtime.wire import encode, new_run_key
from splitspec_agents.agent import AgentNode
from splitspec_plant.plant import PlantNode
key = new_run_key()
cfg = {"scenario": Path(example).read_text(), "seed": 7, "g": None, "q": 3, "g_mode": None, "key": key}
agent, plant = AgentNode(1, cfg, "r"), PlantNode(cfg, "r")
ids = agent.sc.agent_ids
tick = encode("tick", "r", mac_key=key, tau=0, attempt=0, graph=0, final=False, alive=ids,
              rows={str(i): [[i], [1.0]] for i in ids}, incarnation={str(i): 0 for i in ids}, fresh=True,
              prev_attempt=0, partition=[], topology=1)
assert agent.on_tick(tick)
y = dict(plant.on_tick(tick))[agent.keys.y]
assert any("xhat" in k for k, _ in agent.on_y(y))
rss_round = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
mods = sorted(sys.modules)
print(json.dumps({"import_ms": 1e3 * t_import, "rss_import_mb": rss_import, "rss_round_mb": rss_round,
                  "core_modules": sum(m.startswith("splitspec_core") for m in mods),
                  "scipy_modules": sum(m == "scipy" or m.startswith("scipy.") for m in mods)}))
"""


def extract(rev: str, into: Path) -> Path:
    """``rev``'s packages under their installed names in ``into``."""
    archive = subprocess.run(["git", "-C", str(ROOT), "archive", rev, *FOLDERS.values()], capture_output=True,
                             check=True).stdout
    subprocess.run(["tar", "-x", "-C", str(into)], input=archive, check=True)
    for name, folder in FOLDERS.items():
        if name != folder:
            (into / folder).rename(into / name)
    return into


def sample(path: str, node: str, example: Path, root: Path) -> dict:
    env = {**os.environ, "RERUN_ANALYTICS": "0", "PYTHONPATH": ""}
    r = subprocess.run([sys.executable, "-c", WORKER, path, node, str(example), str(root)], capture_output=True,
                       text=True, env=env, cwd=tempfile.gettempdir())
    if r.returncode:
        raise SystemExit(f"bench_node_import: the {node} worker failed: {r.stderr.strip().splitlines()[-1]}")
    return json.loads(r.stdout)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--before", default="3a1209a", help="git revision of the 'before' layout (default: 3a1209a)")
    ap.add_argument("--repeat", type=int, default=7)
    ap.add_argument("--example", default="ring10.yaml", help="a scenario of examples/ (discrete time)")
    args = ap.parse_args()
    example = ROOT / "examples" / args.example
    with tempfile.TemporaryDirectory(prefix="bench-node-import.") as tmp:
        before = extract(args.before, Path(tmp))
        print(f"before = {args.before}, after = this checkout; {args.example}; {args.repeat} fresh interpreters "
              f"each, alternating; load average at start {open('/proc/loadavg').read().split()[:3]}")
        got: dict = {}
        for _ in range(args.repeat):
            for node in ("agent", "plant"):
                for label, path, root in (("before", str(before), str(before)), ("after", "", str(ROOT))):
                    got.setdefault((node, label), []).append(sample(path, node, example, Path(root)))
        print(f"{'node':6} {'layout':7} {'import ms':>10} {'RSS import MB':>14} {'RSS 1st round MB':>17} "
              f"{'core modules':>13} {'scipy modules':>14}")
        for (node, label), rows in got.items():
            med = {k: statistics.median(r[k] for r in rows) for k in rows[0]}
            print(f"{node:6} {label:7} {med['import_ms']:10.0f} {med['rss_import_mb']:14.1f} "
                  f"{med['rss_round_mb']:17.1f} {med['core_modules']:13.0f} {med['scipy_modules']:14.0f}")
        print(f"load average at end {open('/proc/loadavg').read().split()[:3]}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
