"""The Zenoh session and message intake of every process (the shells use it; the math never does).

* :func:`zenoh_config` builds every session's config in one place: mode,
  listen/connect endpoints, multicast scouting off, and the link lease the
  process announces (:func:`lease_ms_for`, 10 s): a link stays open through
  an orchestrator (and its router) frozen or starved for seconds and through
  any load; a killed process closes its sockets and is seen at once; a
  frozen one is found by the orchestrator's status probe, not by the lease.
  Keep-alives come from Zenoh's own threads, so a busy Python process is
  never mistaken for a frozen one;
* :class:`Inbox` holds every subscriber and checks each queued message's MAC
  trailer in its callback (half a microsecond; forged messages are dropped
  there and counted).  A message goes either straight to a handler on
  Zenoh's network thread, which verifies it as it decodes (the plant's and
  the agents' protocol messages, see
  :class:`splitspec_core.runtime.node.NodeShell`) or into one bounded,
  thread-safe queue that a single event loop empties in order (the
  orchestrator; control and presence everywhere).  The queue holds at most
  :data:`INBOX_LIMIT` messages; beyond that a message is dropped and counted
  (``inbox_full``), so a flood can cost CPU but never unbounded memory.
"""

from __future__ import annotations

import json
import os
import queue
import socket
import threading
import time
from typing import Any, Callable

import zenoh

from ..errors import SplitspecError
from .wire import ORCHESTRATORS, Keys, WireError, verify

__all__ = ["zenoh_config", "open_session", "Inbox", "BusError", "IdentityRefused", "query_all",
           "lease_ms_for", "LIVELINESS_PUT", "LIVELINESS_DELETE", "INBOX_LIMIT", "socket_address",
           "unreachable_reason", "hosted_runs"]

CHILD_ENV = "SPLITSPEC_CHILD"  #: set in the environment of the processes an orchestrator starts itself
LIVELINESS_PUT = "put"
LIVELINESS_DELETE = "delete"
INBOX_LIMIT = 10_000
_kept_thread_states = threading.local()  # .done on a Zenoh thread whose Python thread state is kept


def _keep_thread_state() -> None:
    """Keep this (Zenoh network) thread's Python thread state from one callback to the next.

    zenoh-python runs a direct callback (``indirect=False``) on Zenoh's own thread through
    ``PyGILState_Ensure``/``Release``; on a thread Python did not start, the release at the end of each
    callback deletes the thread state the ensure created, so every message paid for a new one and for the
    memory of its frame stack (mmap, page faults, munmap: about a quarter of an agent's CPU per round at
    m = 16).  One ``PyGILState_Ensure`` never released keeps the count above zero: later callbacks find the
    thread state and only take the GIL.  The thread state lives as long as the thread (the session's).
    """
    import ctypes

    ctypes.pythonapi.PyGILState_Ensure()
    _kept_thread_states.done = True


class BusError(SplitspecError, RuntimeError):
    """The middleware could not be set up (bad endpoint, port in use, no router)."""


class IdentityRefused(SplitspecError, RuntimeError):
    """The orchestrator refused this process's identity (another live process holds it)."""


def _env_ms(name: str, default: int) -> int:
    try:
        return max(100, int(os.environ.get(name, str(default))))
    except ValueError:
        return default


def lease_ms_for(role: str) -> int:
    """The link lease a process of ``role`` announces: how long the others wait for it when it goes silent.

    Every role: ``SPLITSPEC_LEASE_MS`` or 10000 ms.  A router that is itself frozen (the
    orchestrator's embedded one, with the orchestrator) judges its clients by *their* lease when it
    wakes up, so a short client lease would close every link after an orchestrator freeze of a
    second; with 10 s an orchestrator frozen or starved for up to ~9 s is waited for, and a loaded
    machine never closes a link.  A killed process closes its sockets and is seen at once; a frozen
    agent is found by the orchestrator's status probe (:mod:`splitspec_orchestrator.rounds.machine`) in about 1.1 s.

    Parameters
    ----------
    role : str
        The process's role (``"agent"``, ``"plant"``, ``"orchestrator"``); every role gets the same lease today.

    Returns
    -------
    int
        Milliseconds, at least 100 (an unparsable ``SPLITSPEC_LEASE_MS`` gives 10000).
    """
    return _env_ms("SPLITSPEC_LEASE_MS", 10_000)


def zenoh_config(mode: str, *, listen: list | None = None, connect: list | None = None,
                 lease_ms: int | None = None, user: str | None = None, password: str | None = None,
                 connect_timeout_ms: int | None = None, extra: dict | None = None) -> zenoh.Config:
    """Zenoh config: ``mode`` is ``router``, ``peer`` or ``client``; multicast scouting is off.

    Parameters
    ----------
    mode : {"router", "peer", "client"}
        The session's mode.
    listen, connect : list of str, optional
        Endpoints to listen on and to connect to (``tcp/host:port``, ...).
    lease_ms : int, optional
        The link lease (default :func:`lease_ms_for`): a frozen peer is declared gone after it.
    user, password : str, optional
        Credentials for a ``--secure`` router.
    connect_timeout_ms : int, optional
        With ``connect``: how long to keep retrying it at start-up (default: for ever, ``-1``; a client: 30000).
    extra : dict, optional
        More ``{config path: value}`` entries (JSON-encoded into the config).

    Returns
    -------
    zenoh.Config

    Raises
    ------
    BusError
        If Zenoh rejects a value.
    """
    lease_ms = lease_ms_for("agent") if lease_ms is None else lease_ms
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
        if mode == "router" and not connect:
            # a router sleeps scouting/delay (500 ms) in open() to hear of peers; with multicast scouting off
            # and none to connect to there is nothing to hear, and the run's processes start only after it
            c.insert_json5("scouting/delay", "0")
        # no shared memory: Zenoh would otherwise put every message >= 3 KB between processes of one
        # host (a config reply from m = 16 agents on) into the sender's 16 MB pool, and every receiver
        # maps the whole pool (16 MB more RSS per agent); the messages here are a few KB at most
        c.insert_json5("transport/shared_memory/enabled", "false")
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
    """Open a Zenoh session, turning failures into one-line :class:`BusError`s.

    Parameters
    ----------
    mode : {"router", "peer", "client"}
        The session's mode.
    **kw
        The options of :func:`zenoh_config`.

    Returns
    -------
    zenoh.Session

    Raises
    ------
    BusError
        If the config is invalid or the session cannot be opened (names the endpoints, with a hint for a client).
    """
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


#: Zenoh link protocols that run over TCP: :func:`unreachable_reason` can check them with a plain socket
TCP_PROTOCOLS = ("tcp", "tls", "ws")


def socket_address(endpoint: str) -> tuple | None:
    """``("tcp", (host, port))`` or ``("unix", path)``: what a plain socket can connect to for ``endpoint``, or None.

    TCP-based locators (``tcp/HOST:PORT``, ``tls/``, ``ws/``; ``[v6]`` addresses, host names) and
    ``unixsock-stream/PATH``; None for the others (``udp/``, ``quic/``, ``serial/``...), which a
    socket cannot check.  Zenoh's locator metadata and config (``?...``, ``#...``) are ignored.

    Parameters
    ----------
    endpoint : str
        A Zenoh locator.

    Returns
    -------
    tuple or None

    Examples
    --------
    >>> socket_address("tcp/[::1]:7447"), socket_address("unixsock-stream/tmp/r.sock"), socket_address("udp/h:1")
    (('tcp', ('::1', 7447)), ('unix', 'tmp/r.sock'), None)
    """
    proto, sep, address = str(endpoint).partition("/")
    address = address.split("?", 1)[0].split("#", 1)[0]
    if not sep or not address:
        return None
    if proto in TCP_PROTOCOLS:
        host, sep, port = address.rpartition(":")
        if not sep or not host or not port.isdigit():
            return None
        return "tcp", (host.removeprefix("[").removesuffix("]"), int(port))
    if proto == "unixsock-stream":
        return "unix", address
    return None


def unreachable_reason(endpoint: str, *, timeout: float = 1.0) -> str | None:
    """Why nothing accepts a connection at ``endpoint`` (``"connection refused"``, ...), or None if something does.

    Zenoh reports a client it could not connect the same way whether nobody listens at the endpoint
    or the router there refused the handshake (no credentials, a wrong password): "Unable to connect
    to any of [...]".  A plain socket tells the two apart: None means something accepted the
    connection (closed again at once, before any Zenoh handshake).  Only for the endpoints
    :func:`socket_address` knows; None for the others.

    Parameters
    ----------
    endpoint : str
        A Zenoh locator.
    timeout : float, default 1.0
        Seconds to wait for the connection.

    Returns
    -------
    str or None
        The reason, lower case (resolution failure, no answer within the timeout, the OS error).
    """
    target = socket_address(endpoint)
    if target is None:
        return None
    kind, address = target
    try:
        if kind == "unix":
            with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as sock:
                sock.settimeout(timeout)
                sock.connect(address)
        else:  # any address (IPv4, IPv6) the host name resolves to
            with socket.create_connection(address, timeout=timeout):
                pass
    except socket.gaierror as exc:
        return f"cannot resolve {address[0]!r}: {exc.strerror}"
    except TimeoutError:
        return f"no answer within {timeout:g} s"
    except OSError as exc:
        return (exc.strerror or str(exc)).lower()
    return None


def hosted_runs(session: zenoh.Session, *, timeout: float = 1.0) -> list:
    """The run ids whose orchestrator is present on this session's router (its liveliness token), sorted.

    Empty when the router hosts no run yet, or when it does not let this session ask (a secure
    router answers an authenticated client with its own run, see
    :func:`splitspec_core.runtime.security.acl_config`).

    Parameters
    ----------
    session : zenoh.Session
        An open session.
    timeout : float, default 1.0
        Seconds to wait for the liveliness replies.

    Returns
    -------
    list of str
    """
    runs = set()
    try:
        for reply in session.liveliness().get(ORCHESTRATORS, timeout=timeout):
            if reply.ok is not None:
                run_id = Keys.run_of(str(reply.ok.key_expr))
                if run_id:
                    runs.add(run_id)
    except zenoh.ZError:  # the session is closing: nothing to report
        pass
    return sorted(runs)


class Inbox:
    """One bounded queue fed by many subscribers; keeps every subscriber referenced.

    ``dropped`` counts, per reason, what the callbacks refused (``bad_mac``) or could not queue
    (``inbox_full``); the event loop reports it with its own rejections.
    """

    def __init__(self, session: zenoh.Session, *, limit: int = INBOX_LIMIT):
        self.session = session
        self.q: queue.SimpleQueue = queue.SimpleQueue()
        self.limit = int(limit)
        self._subs: list = []
        self.dropped: dict = {}
        self._lock = threading.Lock()
        self.mac_key: bytes | None = None  # set once known: messages on signed channels must carry the trailer

    def _drop(self, reason: str) -> None:
        with self._lock:
            self.dropped[reason] = self.dropped.get(reason, 0) + 1

    def _offer(self, item: tuple) -> None:
        if self.q.qsize() >= self.limit:  # messages only; presence changes and signals always get in
            self._drop("inbox_full")
        else:
            self.q.put(item)

    def subscribe(self, key: str, channel: str, *, signed: bool = True,
                  direct: Callable[[str, str, bytes], None] | None = None) -> None:
        """Deliver every sample on ``key`` as ``(channel, key, payload)``; ``signed``: only with a valid MAC.

        With ``direct`` the callback runs on Zenoh's network thread (``indirect=False``: no hand-off
        to a Python callback thread, ~20% of a round's CPU at m = 16) and calls
        ``direct(channel, key, payload)`` there and then, which verifies the MAC as it decodes;
        messages on one link are then handled in arrival order, and a flood on that link delays
        whatever else arrives on it, which is why a process's ``status`` queryable lives on a
        session of its own (:class:`splitspec_core.runtime.node.NodeShell`).  Otherwise the
        callback runs on the subscriber's own Python thread (zenoh-python's default) and queues
        the item for the event loop (bounded: ``inbox_full``).  A key without wildcards is bound
        once: no string is built per message.

        Parameters
        ----------
        key : str
            Key expression to subscribe to (wildcards allowed).
        channel : str
            The name the items carry.
        signed : bool, default True
            Drop (count ``bad_mac``) a queued message without a valid MAC once :attr:`mac_key` is set.
        direct : callable, optional
            ``direct(channel, key, payload)`` on Zenoh's thread instead of the queue.
        """
        inbox = self
        fixed = None if any(c in key for c in "*$") else key

        def cb(sample, _c=channel, _signed=signed, _fixed=fixed, _direct=direct, _kept=_kept_thread_states):
            if _direct is not None and not getattr(_kept, "done", False):
                _keep_thread_state()
            payload = sample.payload.to_bytes()
            mk = inbox.mac_key
            if _signed and mk is not None and _direct is None:  # a direct handler verifies as it decodes
                try:
                    verify(payload, mk)
                except WireError:
                    inbox._drop("bad_mac")
                    return
            k = _fixed if _fixed is not None else str(sample.key_expr)
            if _direct is not None:
                _direct(_c, k, payload)
            else:
                inbox._offer((_c, k, payload))

        # drop=None given positionally: eclipse-zenoh 1.3 (our lower bound) requires it
        handler = zenoh.handlers.Callback(cb, None, indirect=False) if direct is not None else cb
        self._subs.append(self.session.declare_subscriber(key, handler))

    def serve_deferred(self, key: str, channel: str) -> None:
        """Declare a queryable whose queries are queued as ``(channel, key, query)``; the event loop replies.

        Parameters
        ----------
        key : str
            Key expression of the queryable.
        channel : str
            The name the items carry.
        """
        inbox = self

        def cb(query, _c=channel):
            inbox._offer((_c, str(query.key_expr), query))

        self._subs.append(self.session.declare_queryable(key, cb))

    def watch_liveliness(self, key: str, channel: str, *, history: bool = True) -> None:
        """Queue every liveliness change on ``key`` as ``(channel, key, kind)``, never dropped.

        ``kind`` is :data:`LIVELINESS_PUT` or :data:`LIVELINESS_DELETE`.

        Parameters
        ----------
        key : str
            Liveliness key expression.
        channel : str
            The name the items carry.
        history : bool, default True
            Also deliver the tokens already present.
        """
        q = self.q

        def cb(sample, _c=channel, _q=q):
            kind = LIVELINESS_DELETE if sample.kind == zenoh.SampleKind.DELETE else LIVELINESS_PUT
            _q.put((_c, str(sample.key_expr), kind))  # never dropped: presence changes are few and vital

        self._subs.append(self.session.liveliness().declare_subscriber(key, cb, history=history))

    def serve(self, key: str, reply) -> None:
        """Declare a queryable answering with ``reply(query) -> bytes`` (runs on a Zenoh thread).

        Parameters
        ----------
        key : str
            Key expression of the queryable; replies are sent on it.
        reply : callable
            ``query -> bytes``; an exception in it sends no reply (silently).
        """
        def cb(query, _key=key):
            try:
                query.reply(_key, reply(query))
            except Exception:  # noqa: BLE001 - a failing reply must not kill the Zenoh thread
                pass

        self._subs.append(self.session.declare_queryable(key, cb))

    def get(self, timeout: float | None) -> tuple | None:
        """Next ``(channel, key, payload)`` or ``None`` after ``timeout`` seconds.

        Parameters
        ----------
        timeout : float or None
            Seconds to wait; None: until an item comes; 0 or less: do not wait.

        Returns
        -------
        tuple or None
        """
        try:
            return self.q.get(timeout=timeout) if timeout is None or timeout > 0 else self.q.get_nowait()
        except queue.Empty:
            return None

    def offer(self, item: tuple) -> None:
        """Queue an item as a subscription does: dropped and counted (``inbox_full``) when the inbox is full.

        Parameters
        ----------
        item : tuple
            ``(channel, key, payload)``.
        """
        self._offer(item)

    def put(self, item: tuple) -> None:
        """Inject an item (e.g. a signal turned into an event); never dropped.

        Parameters
        ----------
        item : tuple
            ``(channel, key, payload)``.
        """
        self.q.put(item)

    def take_dropped(self) -> dict:
        """Running totals of dropped messages per reason.

        Returns
        -------
        dict of str to int
            A copy: ``{"bad_mac": n, "inbox_full": n}``, the reasons that occurred.
        """
        with self._lock:
            return dict(self.dropped)

    def close(self) -> None:
        """Undeclare every subscriber and queryable (errors ignored: the session may be closing)."""
        for s in self._subs:
            try:
                s.undeclare()
            except Exception:  # noqa: BLE001
                pass
        self._subs.clear()


def query_all(session: zenoh.Session, key: str, *, timeout: float) -> list:
    """``[(key, payload bytes), ...]`` of every reply to ``get(key)`` from every matching queryable.

    Parameters
    ----------
    session : zenoh.Session
        An open session.
    key : str
        Key expression to query.
    timeout : float
        Seconds to wait for replies.

    Returns
    -------
    list of (str, bytes)
        Empty when nothing answers or the query fails.
    """
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
    """First reply's payload of ``get(key)``; retried until ``retry_until`` (monotonic) if given.

    Parameters
    ----------
    session : zenoh.Session
        An open session.
    key : str
        Key expression to query.
    timeout : float
        Seconds each query waits.
    payload : bytes, optional
        Sent with the query.
    retry_until : float, optional
        ``time.monotonic()`` deadline for retries (every 0.1 s); None: one try.

    Returns
    -------
    bytes or None
        None when no reply came in time.
    """
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
