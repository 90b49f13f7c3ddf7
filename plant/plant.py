"""The plant: generates the true state and the measurements, one event time per tick.

On tick ``tau``: if it is a new event time the plant moves ``x -> x(tau)``
(process noise), then draws ``y(tau)`` (measurement noise, every agent) and
publishes ``y_i(tau)`` on ``y/<i>`` and ``x(tau)`` on ``truth``.  A re-run of
the same tick (a higher attempt) re-publishes the same values.  The draws are
those of :class:`splitspec_core.simulator.Plant`, in the same order, so the
truth equals the simulator's.  Agents never see the truth.
"""

from __future__ import annotations

import argparse
import logging

import numpy as np

from splitspec_core.scenario_model import parse_scenario_text
from splitspec_core.plant_model import Plant
from splitspec_core.runtime.wire import Keys, WireError, decode, encode

log = logging.getLogger("splitspec.plant")


class PlantNode:
    """Plant protocol state; ``on_tick`` returns ``[(key, payload), ...]`` to publish."""

    def __init__(self, config: dict, run_id: str):
        self.run_id = run_id
        self.keys = Keys(run_id)
        self.sc = parse_scenario_text(config["scenario"], source="config")
        self.plant = Plant(self.sc, int(config["seed"]))
        self.mac_key = config.get("key")
        self.extra_counts = None  # callable -> {reason: count} of drops outside the node (the inbox)
        self.tau = None
        self.y = None
        self.rejected: dict = {}

    def reject(self, reason: str) -> None:
        self.rejected[reason] = self.rejected.get(reason, 0) + 1

    def counts(self) -> dict:
        """Running totals of rejected messages per reason (the node's and the inbox's)."""
        out = dict(self.rejected)
        for reason, c in (self.extra_counts() if self.extra_counts else {}).items():
            out[reason] = out.get(reason, 0) + c
        return out

    def on_tick(self, payload: bytes) -> list:
        try:
            t = decode(payload, self.run_id, "tick", mac_key=self.mac_key)
        except WireError as e:
            self.reject(e.reason)
            return []
        tau = t["tau"]
        if self.tau is None:
            if tau != 0:
                raise RuntimeError(f"the plant joined at event time {tau}: it must be present from event time 0")
        elif tau == self.tau + 1:
            self.plant.advance()
        elif tau != self.tau:
            self.reject("stale" if tau < self.tau else "future")
            return []
        if tau != self.tau:
            self.tau = tau
            self.y = self.plant.measure()  # (y_1, ..., y_m) stacked in agent order
        out = [(self.keys.truth, encode("truth", self.run_id, mac_key=self.mac_key, tau=tau, attempt=t["attempt"],
                                        x=self.plant.x, rejected=self.counts()))]
        if not t["final"]:  # one message for every agent: each takes its own rows
            out.append((self.keys.y, encode("y", self.run_id, mac_key=self.mac_key, tau=tau, attempt=t["attempt"],
                                            y=np.asarray(self.y))))
        return out


def build_parser(prog: str = "python -m splitspec_plant") -> argparse.ArgumentParser:
    """The plant process's options (also ``splitspec plant ...``, which hands its arguments here)."""
    from splitspec_core.runtime.cli import ArgumentParser, add_logging_options, add_node_options

    p = ArgumentParser(prog=prog, description="The plant process: fetches the scenario from the orchestrator, publishes "
                       "measurements and the truth each event time.")
    add_node_options(p)
    add_logging_options(p)
    return p


def cli_main(argv: list | None = None, *, prog: str = "python -m splitspec_plant") -> int:
    """Parse ``argv`` and run the plant inside the shared error boundary; the exit status."""
    from splitspec_core.runtime.cli import node_cli

    return node_cli(build_parser, main, argv, prog)


def main(args: argparse.Namespace) -> int:
    """``splitspec plant --connect ENDPOINT [--run-id ID] [--credentials FILE]``."""
    from splitspec_core.runtime.node import NodeShell

    keys = Keys(args.run_id)  # required on the command line
    shell = NodeShell(args.connect, keys, log=log, role="plant", ident=0, credentials=args.credentials,
                      wait=args.wait)
    try:
        node = PlantNode(shell.fetch_config(wait=args.wait), keys.run_id)
        node.extra_counts = shell.inbox.take_dropped
        return shell.run(lambda ch, key, p: node.on_tick(p), node.reject, name="plant",
                         subscriptions=[(keys.tick, "tick")])
    finally:
        shell.close()
