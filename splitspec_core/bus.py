"""The one module that talks to Zenoh (the process shells use it; the math never does).

* :func:`zenoh_config` builds every session's config in one place: mode,
  listen/connect endpoints, multicast scouting off, a short link lease so a
  frozen process is detected within about a second;
* :class:`Inbox` turns subscriber callbacks into one thread-safe queue: the
  callbacks only enqueue ``(channel, key, payload bytes)`` (never block), and
  the process's single event loop takes them off in order.
"""

from __future__ import annotations

import json
import os
import queue
import time
from typing import Any

import zenoh

from .errors import SplitspecError

__all__ = ["zenoh_config", "open_session", "Inbox", "NodeShell", "BusError", "query_all", "LIVELINESS_PUT", "LIVELINESS_DELETE"]

LIVELINESS_PUT = "put"
LIVELINESS_DELETE = "delete"


class BusError(SplitspecError, RuntimeError):
    """The middleware could not be set up (bad endpoint, port in use, no router)."""


def default_lease_ms() -> int:
    """Link lease: ``SPLITSPEC_LEASE_MS`` or 1000 ms: a frozen process is declared gone after it
    (Zenoh's default is 10 s).  Keep-alives go every quarter lease from Zenoh's own threads, so a busy
    Python process is not mistaken for a frozen one; raise it on a machine starved for seconds."""
    try:
        return max(100, int(os.environ.get("SPLITSPEC_LEASE_MS", "1000")))
    except ValueError:
        return 1000


def zenoh_config(mode: str, *, listen: list | None = None, connect: list | None = None,
                 lease_ms: int | None = None, user: str | None = None, password: str | None = None,
                 connect_timeout_ms: int | None = None, extra: dict | None = None) -> zenoh.Config:
    """Zenoh config: ``mode`` is ``router``, ``peer`` or ``client``; multicast scouting is off.

    ``lease_ms`` is the link lease (default :func:`default_lease_ms`): a frozen
    peer is declared gone after it (Zenoh's default is 10 s).
    """
    lease_ms = default_lease_ms() if lease_ms is None else lease_ms
    c = zenoh.Config()
    try:
        c.insert_json5("mode", json.dumps(mode))
        if listen:
            c.insert_json5("listen/endpoints", json.dumps(list(listen)))
        if connect:
            c.insert_json5("connect/endpoints", json.dumps(list(connect)))
            # keep retrying the connection at start-up rather than failing at once
            # (a client refused by a secure router fails after this timeout, not at once)
            timeout = connect_timeout_ms if connect_timeout_ms is not None else (-1 if mode != "client" else 30000)
            c.insert_json5("connect/timeout_ms", str(int(timeout)))
        c.insert_json5("scouting/multicast/enabled", "false")
        c.insert_json5("transport/link/tx/lease", str(int(lease_ms)))
        c.insert_json5("transport/link/tx/keep_alive", "4")
        if user is not None:
            c.insert_json5("transport/auth/usrpwd/user", json.dumps(user))
            c.insert_json5("transport/auth/usrpwd/password", json.dumps(password or ""))
        for k, v in (extra or {}).items():
            c.insert_json5(k, json.dumps(v))
    except Exception as exc:  # noqa: BLE001 - zenoh reports config errors as ZError/ValueError
        raise BusError(f"invalid Zenoh configuration: {exc}") from None
    return c


def open_session(mode: str, **kw) -> zenoh.Session:
    """Open a Zenoh session, turning failures into one-line :class:`BusError`s."""
    cfg = zenoh_config(mode, **kw)
    try:
        return zenoh.open(cfg)
    except Exception as exc:  # noqa: BLE001
        where = kw.get("listen") or kw.get("connect") or ""
        hint = ""
        if mode == "client":
            hint = (" (is the router up? a secure router refuses missing or wrong credentials)" if kw.get("user") is None
                    else " (is the router up? are these the run's credentials?)")
        why = str(exc).split(" at /")[0]  # drop the Rust source location
        raise BusError(f"cannot open a Zenoh {mode} session on {', '.join(where)}: {why}{hint}") from None


class Inbox:
    """One queue fed by many subscribers; keeps every subscriber referenced."""

    def __init__(self, session: zenoh.Session):
        self.session = session
        self.q: queue.SimpleQueue = queue.SimpleQueue()
        self._subs: list = []

    def subscribe(self, key: str, channel: str) -> None:
        q = self.q

        def cb(sample, _c=channel, _q=q):
            _q.put((_c, str(sample.key_expr), sample.payload.to_bytes()))

        self._subs.append(self.session.declare_subscriber(key, cb))

    def watch_liveliness(self, key: str, channel: str, *, history: bool = True) -> None:
        q = self.q

        def cb(sample, _c=channel, _q=q):
            kind = LIVELINESS_DELETE if sample.kind == zenoh.SampleKind.DELETE else LIVELINESS_PUT
            _q.put((_c, str(sample.key_expr), kind))

        self._subs.append(self.session.liveliness().declare_subscriber(key, cb, history=history))

    def serve(self, key: str, reply) -> None:
        """Declare a queryable answering with ``reply(query) -> bytes`` (runs on a Zenoh thread)."""
        def cb(query, _key=key):
            try:
                query.reply(_key, reply(query))
            except Exception:  # noqa: BLE001 - a failing reply must not kill the Zenoh thread
                pass

        self._subs.append(self.session.declare_queryable(key, cb))

    def get(self, timeout: float | None) -> tuple | None:
        """Next ``(channel, key, payload)`` or ``None`` after ``timeout`` seconds."""
        try:
            return self.q.get(timeout=timeout) if timeout is None or timeout > 0 else self.q.get_nowait()
        except queue.Empty:
            return None

    def put(self, item: tuple) -> None:
        """Inject an item (e.g. a signal turned into an event)."""
        self.q.put(item)

    def close(self) -> None:
        for s in self._subs:
            try:
                s.undeclare()
            except Exception:  # noqa: BLE001
                pass
        self._subs.clear()


def query_all(session: zenoh.Session, key: str, *, timeout: float) -> list:
    """``[(key, payload bytes), ...]`` of every reply to ``get(key)`` from every matching queryable."""
    out = []
    try:
        for reply in session.get(key, target=zenoh.QueryTarget.ALL, consolidation=zenoh.ConsolidationMode.NONE,
                                 timeout=timeout):
            if reply.ok is not None:
                out.append((str(reply.ok.key_expr), reply.ok.payload.to_bytes()))
    except Exception:  # noqa: BLE001 - an unreachable network simply gives no replies
        pass
    return out


def query_bytes(session: zenoh.Session, key: str, *, timeout: float, payload: bytes | None = None,
                retry_until: float | None = None) -> bytes | None:
    """First reply's payload of ``get(key)``; retried until ``retry_until`` (monotonic) if given."""
    while True:
        try:
            kw: dict[str, Any] = {"timeout": timeout}
            if payload is not None:
                kw["payload"] = payload
            for reply in session.get(key, **kw):
                if reply.ok is not None:
                    return reply.ok.payload.to_bytes()
        except Exception:  # noqa: BLE001 - the router may not be reachable yet
            pass
        if retry_until is None or time.monotonic() > retry_until:
            return None
        time.sleep(0.1)


class NodeShell:
    """The Zenoh side of a plant or agent process: session, config fetch, publishing, the event loop.

    The loop ends on a ``stop`` from the orchestrator, when the orchestrator's
    liveliness token disappears (so no process outlives a crashed
    orchestrator), or on SIGINT/SIGTERM.  Every other message goes to the
    node's ``dispatch(channel, key, payload) -> [(key, payload), ...]``; a
    handler error is counted with ``on_error(reason)`` and never ends the process.
    """

    def __init__(self, connect: str, keys, *, log, credentials: str | None = None, wait: float = 30.0):
        import signal

        self.keys, self.log = keys, log
        kw = {}
        if credentials:
            from .security import read_credentials

            kw["user"], kw["password"] = read_credentials(credentials)
        self.session = open_session("client", connect=[connect], connect_timeout_ms=int(max(wait, 1.0) * 1000), **kw)
        self.inbox = Inbox(self.session)
        self.pubs: dict = {}
        for sig in (signal.SIGINT, signal.SIGTERM):
            signal.signal(sig, lambda *_: self.inbox.put(("signal", "", b"")))
        # watch the orchestrator first: if it dies we must exit by ourselves
        self.inbox.watch_liveliness(keys.alive("orchestrator"), "orchestrator")

    def fetch_config(self, *, role: str, ident: int, wait: float) -> dict:
        """Ask the orchestrator's queryable for the scenario and the centralised design (with a hello).

        Also declares this process's ``status`` queryable: it answers with the same hello from a
        Zenoh thread, so the orchestrator can tell a frozen process (no answer) from one that is
        only waiting for a frozen neighbour.
        """
        import socket

        from .wire import decode, encode

        hello = encode("hello", self.keys.run_id, role=role, id=int(ident), pid=os.getpid(),
                       host=socket.gethostname())
        self.inbox.serve(self.keys.status(role, ident), lambda _q: hello)
        raw = query_bytes(self.session, self.keys.config, timeout=2.0, payload=hello,
                          retry_until=time.monotonic() + wait)
        if raw is None:
            raise TimeoutError(f"no orchestrator answered on {self.keys.config} within {wait:g} s")
        return decode(raw, self.keys.run_id, "config")

    def publish(self, items) -> None:
        for key, payload in items:
            pub = self.pubs.get(key)
            if pub is None:
                pub = self.pubs[key] = self.session.declare_publisher(key)
            pub.put(payload)

    def run(self, token_key: str, dispatch, on_error, *, name: str) -> int:
        """Declare the liveliness token, then handle messages until told to stop."""
        from .wire import WireError, decode

        import signal

        me = "/".join(token_key.split("/")[-2:])  # "agent/3": the target name in fault commands
        self.inbox.subscribe(self.keys.control, "control")
        token = self.session.liveliness().declare_token(token_key)
        self.log.info("%s ready (pid %d)", name, os.getpid())
        while True:
            item = self.inbox.get(timeout=1.0)
            if item is None:
                continue
            channel, key, payload = item
            if channel == "control":
                try:
                    cmd = decode(payload, self.keys.run_id, "control")["cmd"]
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
                    self.log.warning("%s: orchestrator lost, exiting", name)
                    break
            elif channel == "signal":
                self.log.info("%s: interrupted", name)
                break
            else:
                try:
                    self.publish(dispatch(channel, key, payload))
                except (ValueError, TypeError, KeyError, IndexError) as exc:
                    # a message that passed validation but still broke the node: drop it, count it, go on
                    on_error("handler_error")
                    self.log.warning("%s: dropped a %s message on %s: %s", name, channel, key, exc)
        token.undeclare()
        return 0

    def close(self) -> None:
        self.inbox.close()
        try:
            self.session.close()
        except Exception as exc:  # noqa: BLE001 - leaving anyway
            self.log.warning("closing the Zenoh session: %s", str(exc).split(" at ")[0])
