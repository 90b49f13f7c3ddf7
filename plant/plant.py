"""The plant: generates the true state and the measurements, one event time per tick.

On tick ``tau``: if it is a new event time the plant moves ``x -> x(tau)``
(process noise), then draws ``y(tau)`` (measurement noise, every agent) and
publishes ``y(tau)`` on ``y/all`` and ``x(tau)`` on ``truth``; with known inputs (``system.B``) the ``y``
message's vector carries ``u(tau)`` after the stacked outputs, so every agent adds the plant's own ``B u``.  With
``--measurements FILE`` (the file the orchestrator was given, checked by its
sha256) it plays row ``tau`` of the file instead: its ``y``, the agents without
a measurement there, and its truth (an empty ``x`` when the file has none).  The scenario's sensor faults
(the fault kinds whose runtime effect is the plant's: :mod:`splitspec_core.scenarios.faults`) change the
measurements from the step the simulator changes them, as it does.  A re-run of
the same tick (a higher attempt) re-publishes the same values.  The draws are
those of :class:`splitspec_core.simulation.simulator.Plant`, in the same order, so the
truth equals the simulator's.  Agents never see the truth.
"""

from __future__ import annotations

import argparse
import logging

import numpy as np

from splitspec_core.errors import SplitspecError
from splitspec_core.scenarios.measurements import load_measurements
from splitspec_core.model.network import NetworkState, fault_schedule
from splitspec_core.model.plant import Plant, RecordedPlant, output_rows
from splitspec_core.scenarios.faults import PLANT
from splitspec_core.runtime.ticks import Fence
from splitspec_core.runtime.wire import Keys, WireError, decode, encode
from splitspec_core.scenarios.load import parse_scenario_text

log = logging.getLogger("splitspec.plant")


class PlantNode:
    """Plant protocol state; ``on_tick`` returns ``[(key, payload), ...]`` to publish."""

    def __init__(self, config: dict, run_id: str, measurements: str | None = None):
        self.run_id = run_id
        self.keys = Keys(run_id)
        self.sc = parse_scenario_text(config["scenario"], source="config")
        wanted = config.get("measurements")  # {sha256, steps, truth}: the run plays a measurements file
        if (wanted is None) != (measurements is None):
            raise SplitspecError("this run plays the measurements file with sha256 "
                                 f"{wanted['sha256'][:12]}...: start the plant with --measurements FILE"
                                 if wanted else f"--measurements {measurements}: this run simulates its plant "
                                                "(the orchestrator was started without --measurements)")
        self.meas = None
        if measurements is not None:
            self.meas = load_measurements(measurements, self.sc)
            if self.meas.sha256 != wanted["sha256"]:
                raise SplitspecError(f"--measurements {measurements} is not the file the orchestrator plays "
                                     f"(sha256 {self.meas.sha256[:12]}... against {wanted['sha256'][:12]}...)")
            self.plant = RecordedPlant(self.meas, self.sc.n, self.sc)
            self.no_x = np.zeros(0)  # a truth message without x: the file has no truth
        else:
            self.plant = Plant(self.sc, int(config["seed"]))
        # the scenario's sensor faults, applied at the steps the simulator applies them (network.fault_step)
        self.net = NetworkState(self.sc, int(config["seed"]))  # a sensor fault's noise: the seed's own stream
        self.sensor_faults = fault_schedule([f for f in self.sc.faults if f.runtime == PLANT],
                                            self.sc.run.dt if self.sc.time == "continuous" else 1.0)
        self.rows = output_rows(self.sc.system.Cs)
        self.mac_key = config.get("key")
        self.extra_counts = None  # callable -> {reason: count} of drops outside the node (the inbox)
        self.tau = None
        self.y = None
        self.rejected: dict = {}
        self.fence = Fence()  # the highest orchestrator epoch seen (the shell's, shared with its control messages)

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
        if not self.fence.admit(t):  # a superseded orchestrator's (a standby took over): never obeyed
            self.reject("fenced")
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
            if self.meas is not None and tau > self.meas.steps:
                raise RuntimeError(f"event time {tau} is past the measurements file's last row ({self.meas.steps})")
            self.tau = tau
            self.net.apply(self.sensor_faults.get(tau, ()))
            # (y_1, ..., y_m) stacked in agent order; a missing row of the file stays as it is
            self.y = self.net.measured(self.plant.measure(), self.rows, self.plant.missing())
            u = self.plant.input()  # u(tau) (None: no inputs), sent after the outputs
            if u is not None:
                self.y = np.concatenate([np.asarray(self.y, dtype=float), np.asarray(u, dtype=float)])
        x = self.plant.x if self.meas is None or self.meas.x is not None else self.no_x
        out = [(self.keys.truth, encode("truth", self.run_id, mac_key=self.mac_key, tau=tau, attempt=t["attempt"],
                                        x=x, rejected=self.counts()))]
        if not t["final"]:  # one message for every agent: each takes its own rows
            missing = [] if self.meas is None else [a for a, gone in zip(self.sc.agent_ids, self.plant.missing())
                                                    if gone]
            out.append((self.keys.y, encode("y", self.run_id, mac_key=self.mac_key, tau=tau, attempt=t["attempt"],
                                            y=np.asarray(self.y), missing=missing)))
        return out


def build_parser(prog: str = "python -m splitspec_plant") -> argparse.ArgumentParser:
    """The plant process's options (also ``splitspec plant ...``, which hands its arguments here)."""
    from splitspec_core.runtime.cli import ArgumentParser, add_logging_options, add_node_options

    p = ArgumentParser(prog=prog, description="The plant process: fetches the scenario from the orchestrator, publishes "
                       "measurements and the truth each event time.")
    add_node_options(p)
    p.add_argument("--measurements", metavar="FILE", help="play this measurements file (the one the orchestrator was "
                   "given: the same bytes) instead of simulating the plant")
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
        node = PlantNode(shell.fetch_config(wait=args.wait), keys.run_id, measurements=args.measurements)
        node.extra_counts = shell.inbox.take_dropped
        node.fence = shell.fence
        return shell.run(lambda ch, key, p: node.on_tick(p), node.reject, name="plant",
                         subscriptions=[(keys.tick, "tick")])
    finally:
        shell.close()
