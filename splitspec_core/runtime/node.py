"""The process shell of a plant or agent: session, identity claim, configuration, publishing, the loop.

The node itself (``AgentNode``, ``PlantNode``) is I/O-free: messages in, messages out.  This shell
opens the Zenoh sessions (:mod:`.bus`), claims the process's identity with the orchestrator, fetches
the scenario and the run's key, hands each message to the node on Zenoh's network thread (one at a
time, under a lock) and publishes what the node returns.  Two sessions, two links to the router: the
data session carries the protocol, control and the liveliness token (one link, so the token is seen
only after the subscriptions are in place); the health session only answers the orchestrator's
``status`` queries, so a flood on the data link, which the network thread works through in order,
never makes a busy process look frozen (chaos flood case: with one session, every agent was declared
frozen).
"""

from __future__ import annotations

import os
import threading
import time

import zenoh

from .bus import (CHILD_ENV, LIVELINESS_DELETE, IdentityRefused, Inbox, lease_ms_for, open_session,
                  query_bytes)

__all__ = ["NodeShell"]


class NodeShell:
    """The Zenoh side of a plant or agent process: session, identity claim, config, publishing, the event loop.

    The process claims its identity (``role``, ``ident``) with a random nonce in its ``hello``; the
    orchestrator answers with the configuration (and the run's MAC key) or refuses, naming the live
    process that holds the identity (:class:`IdentityRefused`).  The loop ends on a ``stop`` from the
    orchestrator, when the orchestrator's liveliness token disappears (so no process outlives a crashed
    orchestrator), or on SIGINT/SIGTERM.  Every other message goes to the node's
    ``dispatch(channel, key, payload) -> [(key, payload), ...]``; a handler error is counted with
    ``on_error(reason)`` and never ends the process.
    """

    def __init__(self, connect: str, keys, *, log, role: str, ident: int, credentials: str | None = None,
                 wait: float = 30.0):
        import signal

        from .wire import new_nonce

        self.keys, self.log = keys, log
        self.role, self.ident = role, int(ident)
        self.nonce = new_nonce()
        self.mac_key: bytes | None = None
        kw = {}
        if credentials:
            from .security import read_credentials

            kw["user"], kw["password"] = read_credentials(credentials)
        opts = dict(connect=[connect], connect_timeout_ms=int(max(wait, 1.0) * 1000), lease_ms=lease_ms_for(role), **kw)
        self.session = open_session("client", **opts)
        # the status queryable's own session (its own link): protocol messages are handled on the data
        # link's network thread, so a flood there must not queue the orchestrator's status queries behind it
        self.health = open_session("client", **opts)
        self.inbox = Inbox(self.session)
        self.health_inbox = Inbox(self.health)
        self.pubs: dict = {}
        self._looping = False
        self._closing = False

        def on_signal(signum, _frame):
            if not self._looping:  # still starting (fetching the config): leave at once
                raise SystemExit(128 + signum)
            self.inbox.put(("signal", "", b""))

        for sig in (signal.SIGINT, signal.SIGTERM):
            signal.signal(sig, on_signal)
        # watch the orchestrator first: if it dies we must exit by ourselves
        self.inbox.watch_liveliness(keys.alive("orchestrator"), "orchestrator")

    @property
    def who(self) -> str:
        return "the plant" if self.role == "plant" else f"{self.role} {self.ident}"

    def fetch_config(self, *, wait: float) -> dict:
        """Claim the identity and fetch the scenario, the centralised design and the run's key.

        Then declares this process's ``status`` queryable: it answers with the same hello from a
        Zenoh thread, so the orchestrator can tell a frozen process (no answer) from one that is
        only waiting for a frozen neighbour.
        """
        import socket

        from .wire import WireError, decode, encode

        hello = encode("hello", self.keys.run_id, role=self.role, id=self.ident, pid=os.getpid(),
                       host=socket.gethostname(), nonce=self.nonce)
        raw = query_bytes(self.session, self.keys.config, timeout=2.0, payload=hello,
                          retry_until=time.monotonic() + wait)
        if raw is None:
            raise TimeoutError(f"no orchestrator answered on {self.keys.config} within {wait:g} s")
        try:
            refusal = decode(raw, self.keys.run_id, "refused")
        except WireError:
            refusal = None
        if refusal is not None:
            raise IdentityRefused(f"{self.who} of run {self.keys.run_id!r} refused: {refusal['reason']}")
        cfg = decode(raw, self.keys.run_id, "config")
        self.mac_key = self.inbox.mac_key = cfg["key"]
        self.health_inbox.serve(self.keys.status(self.role, self.ident, self.nonce), lambda _q: hello)
        return cfg

    def publish(self, items) -> None:
        for key, payload in items:
            pub = self.pubs.get(key)
            if pub is None:
                # BLOCK: a protocol message is never dropped by congestion control (a flood on the same
                # links may be; the round must not be)
                pub = self.pubs[key] = self.session.declare_publisher(
                    key, congestion_control=zenoh.CongestionControl.BLOCK)
            pub.put(payload)

    def run(self, dispatch, on_error, *, name: str, subscriptions=()) -> int:
        """Subscribe, declare the liveliness token, then handle messages until told to stop.

        ``subscriptions`` (``(key, channel)`` pairs) are handled where they arrive, on the Zenoh
        thread, one at a time under a lock: ``dispatch(channel, key, payload)`` and the publication
        of what it returns (no queue, no thread hand-off).  Control messages, the orchestrator's
        presence and signals go through the event loop below.
        """
        import signal

        from .wire import WireError, decode

        me = f"{self.role}/{self.ident}"  # the target name in fault commands
        code = 0
        lock = threading.Lock()

        def handle(channel: str, key: str, payload: bytes) -> None:
            with lock:
                if self._closing:  # the loop has ended: nothing more is handled or sent
                    return
                try:
                    self.publish(dispatch(channel, key, payload))
                except (ValueError, TypeError, KeyError, IndexError) as exc:
                    # a message that passed validation but still broke the node: drop it, count it, go on
                    on_error("handler_error")
                    self.log.warning("%s: dropped a %s message on %s: %s", name, channel, key, exc)
                except zenoh.ZError as exc:  # the session is closing under us (the orchestrator was lost)
                    self.log.info("%s: not sent (%s)", name, str(exc).split(" at ")[0])

        for key, channel in subscriptions:
            self.inbox.subscribe(key, channel, direct=handle)
        self.inbox.subscribe(self.keys.control, "control")
        token = self.session.liveliness().declare_token(self.keys.alive(self.role, self.ident, self.nonce))
        self._looping = True
        self.log.info("%s ready (pid %d)", name, os.getpid())
        while True:
            item = self.inbox.get(timeout=1.0)
            if item is None:
                continue
            channel, key, payload = item
            if channel == "control":
                try:
                    cmd = decode(payload, self.keys.run_id, "control", mac_key=self.mac_key)["cmd"]
                except WireError as e:
                    on_error(e.reason)
                    continue
                if cmd == "stop":
                    self.log.info("%s: stop from the orchestrator", name)
                    break
                action, _, target = cmd.partition(" ")
                if action in ("kill", "hang") and target == me:
                    # a scenario fault for a process the orchestrator cannot signal (another host)
                    self.log.warning("%s: %s requested by the orchestrator", name, action)
                    os.kill(os.getpid(), signal.SIGKILL if action == "kill" else signal.SIGSTOP)
            elif channel == "orchestrator":
                if payload == LIVELINESS_DELETE:
                    import sys

                    msg = (f"{self.who}: the orchestrator of run {self.keys.run_id!r} was lost (its liveliness "
                           "token disappeared); exiting")
                    if os.environ.get(CHILD_ENV):  # the orchestrator's own child: `splitspec run` says it once
                        self.log.info("%s", msg)
                    else:
                        print(f"splitspec: error: {msg}", file=sys.stderr)
                    code = 1
                    break
            elif channel == "signal":
                self.log.info("%s: interrupted", name)
                break
            else:  # subscribed before run() without a direct handler: handled here, in order
                handle(channel, key, payload)
        with lock:
            self._closing = True
        token.undeclare()
        return code

    def close(self) -> None:
        self.inbox.close()
        self.health_inbox.close()
        for session in (self.session, self.health):
            try:
                session.close()
            except Exception as exc:  # noqa: BLE001 - leaving anyway
                self.log.warning("closing the Zenoh session: %s", str(exc).split(" at ")[0])
