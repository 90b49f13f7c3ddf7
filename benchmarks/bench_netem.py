"""Real link impairment under a deadline: what TCP makes of lost frames (issue item 4).

``paper_discrete`` (3 agents, q = 6: 30 consensus messages per event time) across network namespaces,
each process on its own host, the agents' links impaired as ``tc netem delay D J loss P`` would (netem
where the kernel has it, else the user-space emulator: ``tests/integration/netns.py``), through the
multi-host test's own :func:`tests.integration.test_multihost.impaired_run`.  Per setting: ms per event time
(the orchestrator's ``run_finished``: first tick to last record), the consensus messages recorded late
(``lost_cause`` 1) and the frames the links dropped.  Loss starts once every process is in.

Settings: plain links (the bridge alone); perfect links (through the emulator, if it is the backend), with and without a deadline; delay and jitter; loss alone; delay, jitter and loss;
each without a deadline (every sub-round waits for every message: a lost frame is only a slower round, as
TCP retransmits it) and with one (a retransmitted message comes after the deadline: ``late``).

    sudo .venv/bin/python benchmarks/bench_netem.py [--steps 40] [--repeat 2] [--deadline 0.006]

Measured (2 shared cores, load average 4.2 -> 7.5, user-space emulator: the kernel has no netem; medians of 3
runs of 40 event times, 1200 consensus messages each; frames dropped over the three agents' links, both ways):

    link                 deadline   ms/event   late   frames dropped
    plain (no emulator)  none              4      0        0
    perfect (emulator)   none / 6 ms    6 / 7  0 / 0        0
    delay 4 +- 3 ms      none / 6 ms  65 / 42  0 / 806      0
    loss 1.5 %           none / 6 ms  22 / 16  0 / 12      42 / 39
    delay + loss         none / 6 ms  85 / 54  0 / 800     50 / 41

Loss alone makes few messages late: with data flowing, SACK/RACK retransmit a lost frame within about a
round-trip (well under a millisecond here); only a tail loss (nothing sent after it on that link) waits for the
loss probe or the retransmission timeout (at least ~200 ms on Linux), and stalls everything behind it.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from _common import loadavg  # noqa: E402

from tests.integration import netns  # noqa: E402
from tests.integration.test_multihost import LINK, impaired_run  # noqa: E402

DELAY = {"delay": LINK["delay"], "jitter": LINK["jitter"]}
LOSS = {"loss": LINK["loss"]}


def settings(deadline: float) -> list:
    net = {"deadline": deadline}
    return [("plain (no emulator)", None, None), ("perfect", {}, None), ("perfect", {}, net),
            ("delay+jitter", DELAY, None), ("delay+jitter", DELAY, net),
            ("loss", LOSS, None), ("loss", LOSS, net),
            ("delay+jitter+loss", LINK, None), ("delay+jitter+loss", LINK, net)]


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--steps", type=int, default=40)
    p.add_argument("--repeat", type=int, default=2)
    p.add_argument("--deadline", type=float, default=0.006)
    args = p.parse_args()
    if netns.available() is not None:
        print(f"bench_netem: {netns.available()}")
        return 1
    messages = args.steps * 6 * 5
    print(f"load average at start: {loadavg()}; links: delay {DELAY['delay'] * 1e3:g} +- "
          f"{DELAY['jitter'] * 1e3:g} ms, loss {LOSS['loss'] * 100:g} % per frame each way; "
          f"{args.steps} event times, {messages} consensus messages per run")
    print(f"{'link':<19} {'deadline':>9} {'ms/event (runs)':>24} {'late (runs)':>22} {'frames dropped':>15} backend")
    for name, link, network in settings(args.deadline):
        runs = []
        for _ in range(args.repeat):
            with tempfile.TemporaryDirectory() as tmp:
                runs.append(impaired_run(Path(tmp), link=link, network=network, steps=args.steps))
        ms = [r["ms_per_event_time"] for r in runs]
        late = [r["late"] for r in runs]
        dropped = [sum(w["dropped"] for h in r["frames"].values() for w in h.values()) for r in runs]
        dl = "none" if network is None else f"{network['deadline'] * 1e3:g} ms"
        print(f"{name:<19} {dl:>9} {statistics.median(ms):>7.0f} ({', '.join(f'{v:.0f}' for v in ms)})"
              f"{statistics.median(late):>9.0f} ({', '.join(map(str, late))}) {statistics.median(dropped):>9.0f}"
              f"       {runs[0]['backend'] or 'bridge'}", flush=True)
    print(f"load average at end: {loadavg()}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
