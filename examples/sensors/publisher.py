"""A live sensor for every agent of examples/sensors/chain.yaml: a mass-spring chain simulated in real time.

Three unit masses between two walls, joined by four springs (stiffness ``K_SPRING``) with light damping
(``DAMPING``); the state is ``x = (p_1, p_2, p_3, v_1, v_2, v_3)``.  Every ``1 / --rate`` seconds (plus a
random ``--jitter``) the chain moves by the exact solution of its ODE over the time that really passed
(``expm(A_c dt)``, plus process noise of the scenario's level), and each agent's sensor publishes
``y_i = C_i x + noise`` on its source key (``splitspec/<run>/sensors/<key>``, the scenario's ``sources:``)
as the JSON object ``{"y": [...], "t": <wall-clock seconds, time.time()>}``; with probability ``--dropout``
a sensor skips a sample.

``--bias B --bias-agent I --bias-from K --bias-samples N`` makes agent I's sensor lie: ``y_i + B`` (every output)
for N samples from sample K (0-based; default: to the end), for trying ``design.bad_data``; the truth is untouched.

``--record FILE.csv`` writes what was published in the measurements format ``splitspec simulate
--measurements`` reads: ``t, y<id>.<row>..., x.<k>...`` (1-based; ``t`` the wall clock; an empty cell: that
sensor dropped the sample), one row per sample: at ``--rate`` = ``run.pace`` a row is an event time.

This is the user's side of the contract: plain Zenoh (one client session per sensor, so a secure run's
``sensor-<id>.cred`` gives each exactly its own key), no splitspec import.  ``main(args)`` takes the parsed
arguments, so a test can call it.

    python examples/sensors/publisher.py examples/sensors/chain.yaml --connect tcp/127.0.0.1:7447 \\
        --run-id RUN [--credentials DIR|FILE] [--agents 1 2] [--rate 20] [--dropout 0.05] [--record log.csv]
    python examples/sensors/publisher.py examples/sensors/chain.yaml --from-run out/chain   # beside splitspec run
"""

from __future__ import annotations

import argparse
import csv
import json
import logging
import signal
import sys
import time
from pathlib import Path

import numpy as np
import yaml
import zenoh
from scipy.linalg import expm

log = logging.getLogger("sensors")

MASSES = 3
K_SPRING = 16.0  # N/m, every spring
DAMPING = 0.3  # N s/m, every mass to ground
X0 = [0.5, 0.0, -0.3, 0.0, 0.2, 0.0]


def chain_matrix() -> np.ndarray:
    """A_c of the chain: d/dt (p, v) = (v, -(L p + c v)) with L the walls-to-walls stiffness matrix."""
    L = K_SPRING * (2 * np.eye(MASSES) - np.eye(MASSES, k=1) - np.eye(MASSES, k=-1))
    return np.block([[np.zeros((MASSES, MASSES)), np.eye(MASSES)], [-L, -DAMPING * np.eye(MASSES)]])


def step_matrix(dt: float) -> np.ndarray:
    """The chain's exact motion over ``dt`` seconds; chain.yaml's system.A is this at dt = 1 / run.pace."""
    return expm(chain_matrix() * dt)


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(description="Publish a simulated mass-spring chain's sensors for a splitspec run.")
    p.add_argument("scenario", help="the run's scenario (its sources:, system.C, noise levels, run.pace)")
    p.add_argument("--from-run", metavar="OUT", help="take the endpoint, run id and credentials from the sensors "
                   "event of a run writing into OUT (splitspec run --out OUT), waiting up to --wait s for it, and "
                   "stop when that run has finished")
    p.add_argument("--wait", type=float, default=60.0, help="with --from-run: seconds to wait for the run (default 60)")
    p.add_argument("--connect", metavar="ENDPOINT", help="the run's Zenoh router, e.g. tcp/127.0.0.1:7447")
    p.add_argument("--run-id", help="the run's id (keys live under splitspec/<run-id>/sensors/)")
    p.add_argument("--credentials", metavar="DIR|FILE", help="a secure run's credentials: the directory holding "
                   "sensor-<id>.cred, or one .cred file used for every sensor started here")
    p.add_argument("--agents", type=int, nargs="+", help="publish only these agents' sensors (default: all)")
    p.add_argument("--rate", type=float, help="samples per second (default: the scenario's run.pace)")
    p.add_argument("--jitter", type=float, default=0.1, help="random extra delay of a sample, as a fraction of the "
                   "period (default 0.1)")
    p.add_argument("--dropout", type=float, default=0.0, help="probability that a sensor skips a sample")
    p.add_argument("--seed", type=int, default=0, help="random seed (noise, jitter, dropouts)")
    p.add_argument("--duration", type=float, default=float("inf"), help="stop after this many seconds")
    p.add_argument("--samples", type=int, help="stop after this many samples")
    p.add_argument("--record", metavar="FILE.csv", help="also write the samples and the truth as a measurements CSV")
    p.add_argument("--bias", type=float, default=0.0, help="a sensor that lies: add B to every output of "
                   "--bias-agent's sensor (what is published and recorded; the truth is untouched)")
    p.add_argument("--bias-agent", type=int, help="the agent whose sensor lies (with --bias)")
    p.add_argument("--bias-from", type=int, default=0, metavar="K", help="the first biased sample (0-based)")
    p.add_argument("--bias-samples", type=int, metavar="N", help="biased samples (default: to the end)")
    return p


def _session(endpoint: str, cred: Path | None) -> zenoh.Session:
    c = zenoh.Config()
    c.insert_json5("mode", '"client"')
    c.insert_json5("connect/endpoints", json.dumps([endpoint]))
    c.insert_json5("scouting/multicast/enabled", "false")
    if cred is not None:
        user, _, password = cred.read_text().strip().partition(":")
        c.insert_json5("transport/auth/usrpwd/user", json.dumps(user))
        c.insert_json5("transport/auth/usrpwd/password", json.dumps(password))
    return zenoh.open(c)


def _events(out: Path) -> list:
    try:
        lines = (out / "events.jsonl").read_text().splitlines()
    except OSError:
        return []
    events = []
    for line in lines:
        try:
            events.append(json.loads(line))
        except ValueError:  # a line being written
            pass
    return events


def _finished(events: list) -> bool:
    return any(e.get("event") in ("run_finished", "recording_closed") for e in events)


def from_run(args: argparse.Namespace) -> None:
    """Fill --connect, --run-id, --credentials from the ``sensors`` event of the run writing into --from-run.

    An events.jsonl whose run has finished is an earlier run's: wait for the new run to rewrite it."""
    out, deadline = Path(args.from_run), time.monotonic() + args.wait
    log.info("waiting for the run in %s", out)
    while True:
        events = _events(out)
        found = [e for e in events if e.get("event") == "sensors"]
        if found and not _finished(events):
            e = found[-1]
            args.connect, args.run_id = e["endpoint"], e["run_id"]
            if args.credentials is None and e.get("credentials"):
                args.credentials = e["credentials"]
            return
        if time.monotonic() > deadline:
            raise SystemExit(f"publisher: error: --from-run {out}: no running splitspec run with sources wrote "
                             f"its sensors event there within {args.wait:g} s")
        time.sleep(0.2)


def main(args: argparse.Namespace) -> int:
    if args.from_run:
        from_run(args)
    elif not (args.connect and args.run_id):
        raise SystemExit("publisher: error: give --from-run OUT, or both --connect and --run-id")
    try:
        raw = yaml.safe_load(Path(args.scenario).read_text())
        sources = {int(k): (v if isinstance(v, str) else v["key"]) for k, v in raw["sources"].items()}
        Cs = {int(k): np.atleast_2d(np.array(v, dtype=float)) for k, v in raw["system"]["C"].items()}
    except (OSError, yaml.YAMLError, KeyError, TypeError, ValueError, AttributeError) as exc:
        raise SystemExit(f"publisher: error: {args.scenario}: not a scenario with sources: and system.C "
                         f"({type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else ''})") from None
    ids = sorted(Cs)
    mine = args.agents or ids
    unknown = sorted(set(mine) - set(sources))
    if unknown:
        raise SystemExit(f"publisher: error: --agents {unknown[0]}: the scenario's sources are for agents "
                         f"{', '.join(map(str, sorted(sources)))}")
    if args.bias and args.bias_agent not in ids:
        raise SystemExit(f"publisher: error: --bias needs --bias-agent, one of {', '.join(map(str, ids))}")
    rate = args.rate or float(raw["run"]["pace"])
    pnoise = float(raw["system"].get("process_noise", 0.0))
    mnoise = float(raw["system"].get("measurement_noise", 0.0))
    rng = np.random.default_rng(args.seed)
    creds = None if args.credentials is None else Path(args.credentials)
    sessions, pubs = [], {}
    for i in mine:
        cred = None if creds is None else (creds / f"sensor-{i}.cred" if creds.is_dir() else creds)
        for attempt in range(20):  # the router may be a moment from accepting (measured once in 5 starts)
            try:
                s = _session(args.connect, cred)
                break
            except zenoh.ZError:
                if attempt == 19:
                    raise
                time.sleep(0.5)
        sessions.append(s)
        pubs[i] = s.declare_publisher(f"splitspec/{args.run_id}/sensors/{sources[i]}")
    # a plain flag, not a threading.Event: the handler runs in this thread, and Event.set inside Event.wait's own
    # lock (a signal arriving there) deadlocks (a test's SIGINT left this publisher running, once in a suite)
    stop: list = []
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.append(True))
    writer = f = None
    if args.record:
        f = open(args.record, "w", newline="")
        writer = csv.writer(f)
        writer.writerow(["t"] + [f"y{i}.{r + 1}" for i in ids for r in range(Cs[i].shape[0])]
                        + [f"x.{k + 1}" for k in range(2 * MASSES)])
    x = np.array(X0, dtype=float)
    t0 = last = time.monotonic()
    k = 0
    period = 1.0 / rate
    log.info("publishing agents %s at %g samples/s on %s", mine, rate, args.connect)
    try:
        while not stop and (args.samples is None or k < args.samples):
            due = t0 + k * period + rng.uniform(0, args.jitter) * period
            while not stop and time.monotonic() < due:
                time.sleep(min(0.05, max(0.0, due - time.monotonic())))  # a signal: seen within 50 ms
            if stop:
                break
            now = time.monotonic()
            if now - t0 > args.duration:
                break
            if args.from_run and k % max(1, int(rate)) == 0 and _finished(_events(Path(args.from_run))):
                log.info("the run has finished")
                break
            x = step_matrix(now - last) @ x + pnoise * np.sqrt((now - last) / period) * rng.standard_normal(x.size)
            last = now
            stamp = time.time()  # the sensor's own clock: wall-clock seconds (the agents only order by it)
            cells = []
            lying = args.bias_from <= k and (args.bias_samples is None or k < args.bias_from + args.bias_samples)
            for i in ids:
                y = Cs[i] @ x + mnoise * rng.standard_normal(Cs[i].shape[0])
                if lying and i == args.bias_agent:
                    y = y + args.bias
                sent = i in pubs and rng.uniform() >= args.dropout
                if sent:
                    pubs[i].put(json.dumps({"y": y.tolist(), "t": stamp}))
                cells += [repr(float(v)) if sent else "" for v in y]
            if writer is not None:
                writer.writerow([repr(stamp)] + cells + [repr(float(v)) for v in x])
            k += 1
    finally:
        if f is not None:
            f.close()
        for s in sessions:
            s.close()
    log.info("published %d samples", k)
    return 0


if __name__ == "__main__":
    logging.basicConfig(level=logging.INFO, format="%(name)s: %(message)s")
    try:
        sys.exit(main(build_parser().parse_args()))
    except zenoh.ZError as exc:
        print(f"publisher: error: {str(exc).split(' at /')[0]}", file=sys.stderr)
        sys.exit(1)
