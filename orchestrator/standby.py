"""``splitspec standby``: a second orchestrator that follows a run and takes it over when the active one dies.

``splitspec standby --run-id ID --connect ENDPOINT --out DIR [--credentials FILE]`` (``splitspec run`` starts one
itself for a scenario with ``run.standby: true``; ``compose.yaml`` has it as a service).  The standby

* says hello as ``standby`` and receives the run's scenario, key and the active orchestrator's epoch (the active
  one resends the network in its next tick and publishes its state: a follower needs both);
* holds its own liveliness token (``alive/standby/0/<nonce>``): while it is up, the plant and the agents wait for
  a takeover when the active orchestrator's token goes (:data:`splitspec_core.runtime.node.TAKEOVER_WAIT`)
  instead of exiting;
* follows the run (:class:`~splitspec_orchestrator.rounds.follower.Follower`): ticks, truth, estimates, state;
* when the active orchestrator's token goes (its process died, or its host was cut off and its link's lease ran
  out) and no other orchestrator's token is up, takes the run over as an
  :class:`~splitspec_orchestrator.driver.Orchestrator` of the next epoch (:mod:`splitspec_orchestrator.takeover`),
  on the same Zenoh session, in the same output folder.  Of several standbys, the one with the lowest nonce takes
  over; the others follow the new active one.

It exits 0 when the run ends (the active orchestrator's ``stop``), 1 in one line when it cannot follow (no
orchestrator answers, the run's records are not in ``--out``) or cannot take over (the active one died before
the standby had followed a round), and as the run it took over exits otherwise.
"""

from __future__ import annotations

import logging
import os
import signal
import socket
import sys
import time
from pathlib import Path

from splitspec_core.errors import SplitspecError

log = logging.getLogger("splitspec.standby")

__all__ = ["Standby", "main"]

HOST = socket.gethostname()
#: seconds a standby waits, with no orchestrator's token up and no tick, before it takes the run over (it has
#: followed it) or leaves in one line (it has not): the token's DELETE came before the standby watched
ALONE_SECONDS = 5.0


class Standby:
    """A standby orchestrator of run ``run_id`` on the router at ``connect``, recording to ``out`` once it takes
    over (see the module docstring)."""

    def __init__(self, *, run_id: str, connect: str, out: Path, credentials: str | None = None,
                 secure_dir: str | None = None, wait: float = 60.0, round_timeout: float = 10.0,
                 viewer: str | None = None, spawn_local: bool = False):
        from splitspec_core.runtime.wire import Keys, new_nonce

        self.keys = Keys(run_id)
        self.connect, self.out = connect, Path(out)
        self.credentials, self.secure_dir = credentials, secure_dir
        self.wait, self.round_timeout, self.viewer = float(wait), float(round_timeout), viewer
        self.spawn_local = spawn_local
        self.nonce = new_nonce()
        self.stop = False

    def _session(self):
        from splitspec_core.runtime.bus import Inbox, lease_ms_for, open_session

        kw: dict = {"lease_ms": lease_ms_for("orchestrator")}
        creds = self.credentials
        if creds is None and self.secure_dir is not None:
            creds = str(Path(self.secure_dir) / "orchestrator.cred")
        if creds is not None:
            from splitspec_core.runtime.security import read_credentials

            kw["user"], kw["password"] = read_credentials(creds)
        self.session = open_session("client", connect=[self.connect], **kw)
        self.inbox = Inbox(self.session)

    def _config(self) -> dict:
        from splitspec_core.runtime.bus import query_bytes
        from splitspec_core.runtime.wire import WireError, decode, encode

        hello = encode("hello", self.keys.run_id, role="standby", id=0, pid=os.getpid(), host=HOST, nonce=self.nonce)
        raw = query_bytes(self.session, self.keys.config, timeout=2.0, payload=hello,
                          retry_until=time.monotonic() + self.wait)
        if raw is None:
            raise SplitspecError(f"standby: no orchestrator of run {self.keys.run_id!r} answered on {self.connect} "
                                 f"within {self.wait:g} s")
        try:
            return decode(raw, self.keys.run_id, "config")
        except WireError:
            try:
                reason = decode(raw, self.keys.run_id, "refused")["reason"]
            except WireError:
                reason = "an answer that is not this run's configuration"
            raise SplitspecError(f"standby: the orchestrator of run {self.keys.run_id!r} refused it: {reason}") from None

    def run(self) -> int:
        """Follow the run, take it over if its orchestrator dies; the process's exit status."""
        from splitspec_core.runtime.ticks import TickEncoder

        from .driver import Orchestrator
        from .rounds.follower import Follower

        self._session()
        try:
            cfg = self._config()
            if not (self.out / "scenario.yaml").exists():
                raise SplitspecError(f"standby: {self.out} holds no records of a run (no scenario.yaml): give --out "
                                     "the run's output folder (a standby on another host needs it on a shared disk)")
            security = None
            if self.secure_dir is not None:
                from splitspec_core.runtime.security import Credentials

                security = Credentials.load(self.secure_dir)
            # the orchestrator it may become, designed now (a takeover must not wait for a design)
            orch = Orchestrator(None, scenario_text=cfg["scenario"], out=self.out, run_id=self.keys.run_id,
                                listen=None, connect=self.connect, wait=self.wait, round_timeout=self.round_timeout,
                                viewer=self.viewer, security=security, spawn_local=self.spawn_local, standby=True)
            orch.key = self.inbox.mac_key = cfg["key"]
            from .takeover import warm

            warm()
            follower = Follower(orch.sc)
            follower.epoch = int(cfg.get("epoch", 1))
            return self._follow(orch, follower, TickEncoder)
        finally:
            if getattr(self, "orch_took_over", False) is False:
                self.inbox.close()
                try:
                    self.session.close()
                except Exception:  # noqa: BLE001 - leaving anyway
                    pass

    def _follow(self, orch, follower, TickEncoder) -> int:
        from splitspec_core.model.rows import REPORTED
        from splitspec_core.runtime.bus import LIVELINESS_DELETE
        from splitspec_core.runtime.wire import WireError, decode
        from splitspec_core.runtime.node import settle_heap

        keys = self.keys
        inbox = self.inbox
        inbox.watch_liveliness(keys.alive_all, "alive")
        # queued from Zenoh's network thread (direct): in the order they arrive on the router's link, so that a
        # truth comes before the next tick as it did at the active one (a subscriber's own Python thread would
        # interleave the keys); the loop below verifies and decodes them
        for key, channel in ((keys.tick, "tick"), (keys.truth, "truth"), (f"{keys.prefix}/xhat/*", "xhat"),
                             (keys.state, "state"), (keys.control, "control")):
            inbox.subscribe(key, channel, direct=lambda c, k, p: inbox.offer((c, k, p)))
        token = self.session.liveliness().declare_token(keys.alive("standby", 0, self.nonce))
        self.following = True
        log.warning("standby orchestrator (pid %d) follows run %r on %s", os.getpid(), keys.run_id, self.connect)
        present: set = set()  # (role, id, nonce) of the plant's and agents' tokens up
        orchestrators: set = set()
        standbys: set = set()
        last_tick = started = time.monotonic()
        ready = None  # its second token, declared once the follower is ready (the active one says standby_ready)
        while not self.stop:
            item = inbox.get(timeout=0.5)
            if item is None and not orchestrators and time.monotonic() - max(started, last_tick) > ALONE_SECONDS:
                # no orchestrator's token was ever seen or has been for a while, and no tick: its DELETE came
                # before this standby watched (it died, or the run ended, as the standby started)
                if follower.round is not None and follower.network is not None and follower.procs is not None:
                    return self._take_over(orch, follower, present, (token, ready), last_tick, TickEncoder)
                print(f"splitspec: error: standby: no orchestrator of run {keys.run_id!r} is up on {self.connect} "
                      "(the run ended, or its orchestrator died before this standby followed it); exiting",
                      file=sys.stderr)
                return 1
            if ready is None and follower.ready:
                settle_heap()  # its start-up and the records taken on: never visited again (it may hold the rounds)
                ready = self.session.liveliness().declare_token(keys.alive("standby", 1, self.nonce))
                log.info("standby: ready to take over run %r (records on disk to event time %d)", keys.run_id,
                         follower.kept - 1)
            if item is None:
                continue
            channel, key, payload = item
            try:
                if channel == "tick":
                    follower.on_tick(decode(payload, keys.run_id, "tick", mac_key=orch.key))
                    last_tick = time.monotonic()
                elif channel == "truth":
                    msg = decode(payload, keys.run_id, "truth", mac_key=orch.key)
                    follower.on_truth(msg["tau"], msg["attempt"], msg["x"])
                elif channel == "xhat":
                    msg = decode(payload, keys.run_id, "xhat", mac_key=orch.key)
                    follower.on_xhat(msg["agent"], msg["tau"], msg["attempt"], msg["incarnation"], msg["x"],
                                     {c.name: msg[c.name] for c in REPORTED}, lost=msg["lost"], y=msg["y"],
                                     u=msg["u"])
                elif channel == "state":
                    follower.on_state(decode(payload, keys.run_id, "state", mac_key=orch.key))
                elif channel == "control":
                    msg = decode(payload, keys.run_id, "control", mac_key=orch.key)
                    if msg["cmd"] == "stop" and int(msg.get("epoch", 0)) >= follower.epoch:
                        log.info("standby: the run ended; exiting")
                        return 0
            except WireError:
                continue  # not trusted, not followed (the active one counts what it rejects)
            if channel == "signal":
                return 0
            if channel != "alive":
                continue
            member = keys.parse_member(key)
            if member is None:
                continue
            role, ident, nonce = member
            up = payload != LIVELINESS_DELETE
            if role == "orchestrator":
                (orchestrators.add if up else orchestrators.discard)(ident)
                if up or orchestrators:
                    continue
                if any(n < self.nonce for n in standbys):  # another standby takes over; this one follows it
                    continue
                return self._take_over(orch, follower, present, (token, ready), last_tick, TickEncoder)
            if role == "standby" and nonce != self.nonce:
                (standbys.add if up else standbys.discard)(nonce)
            elif role in ("plant", "agent"):
                (present.add if up else present.discard)((role, ident, nonce))
        return 0

    def _take_over(self, orch, follower, present: set, tokens, last_tick: float, TickEncoder) -> int:
        if follower.round is None or follower.network is None or follower.procs is None:
            missing = [what for what, have in (("a tick", follower.round), ("the network", follower.network),
                                               ("its state", follower.procs)) if have is None]
            print(f"splitspec: error: standby: the orchestrator of run {self.keys.run_id!r} was lost before this "
                  f"standby had followed the run (it had not seen {' or '.join(missing)}); cannot take over",
                  file=sys.stderr)
            return 1
        orch.epoch = follower.epoch + 1
        orch.ticks = TickEncoder(self.keys.run_id, mac_key=orch.key, epoch=orch.epoch,
                                 topology=follower.round.topology)
        orch.session, orch.inbox = self.session, self.inbox
        orch.takeover = (follower, {"pid": follower.pid, "host": follower.host, "present": set(present),
                                    "last_tick": last_tick})
        for token in tokens:  # no longer a standby: the processes wait for the next one only if another is up
            if token is not None:
                token.undeclare()
        self.orch_took_over = True
        self.taken = orch
        log.warning("standby: the orchestrator (pid %s on %s) of run %r was lost at event time %d; taking over as "
                    "epoch %d", follower.pid, follower.host, self.keys.run_id, follower.round.tau, orch.epoch)
        return orch.run()


def main(args) -> int:
    """``splitspec standby --run-id ID --connect ENDPOINT --out DIR [--credentials FILE | --secure DIR]``."""
    os.environ.setdefault("RUST_LOG", "off")
    sb = Standby(run_id=args.run_id, connect=args.connect, out=Path(args.out), credentials=args.credentials,
                 secure_dir=getattr(args, "secure_dir", None), wait=args.wait, round_timeout=args.round_timeout,
                 viewer=args.viewer, spawn_local=getattr(args, "spawn_local", False))

    def on_signal(signum, _frame):
        if not getattr(sb, "following", False):  # still asking for the run (it may have ended): leave at once
            raise SystemExit(0)
        sb.stop = True
        orch = getattr(sb, "taken", None)  # it took the run over: the run stops as any run does
        if orch is not None:
            orch.stop_requested = True
            orch.stop_signal = signal.Signals(signum).name
        if hasattr(sb, "inbox"):
            sb.inbox.put(("signal", "", b""))

    signal.signal(signal.SIGINT, on_signal)
    signal.signal(signal.SIGTERM, on_signal)
    code = 1
    try:
        code = sb.run()
    except SplitspecError as exc:
        print(f"splitspec: error: {exc}", file=sys.stderr)
    except SystemExit as exc:
        code = exc.code if isinstance(exc.code, int) else 0
    except KeyboardInterrupt:
        code = 130
    except BaseException:  # a bug: its traceback, then out (the exit below would swallow it)
        import traceback

        traceback.print_exc()
    finally:
        # its Zenoh callback threads may outlive the closed session and keep the interpreter from exiting: a standby
        # that lingers would hold its token (the processes would wait for it) and `splitspec run` would wait for it
        logging.shutdown()
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(code)
