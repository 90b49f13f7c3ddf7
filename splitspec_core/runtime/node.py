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

A process started by hand (not by an orchestrator: no ``SPLITSPEC_CHILD`` in its environment) fails
fast and says why, each as one line and exit status 1 (:class:`~splitspec_core.errors.NetworkError`):
nothing accepts a connection at the endpoint within :data:`CONNECT_BUDGET` of its start; the router refuses it
(no ``--credentials`` for a secure run, a wrong password, another run's credentials); the router
hosts other runs but not ``--run-id`` (for :data:`RUN_GRACE`); the router goes away while it waits
(for :data:`LINK_GRACE`: the run ended).  A router that hosts no run at all is waited on for
``--wait`` (a deployment whose orchestrator starts last, as in ``compose.yaml``), and the process
logs once what it waits for.  The processes an orchestrator starts itself keep the patient start:
their router is their parent's, already up, and under heavy load a short budget would be a false
failure.
"""

from __future__ import annotations

import os
import threading
import time

import zenoh

from ..errors import NetworkError
from ..scenarios.faults import KINDS, SIGNAL
from .bus import (CHILD_ENV, LIVELINESS_DELETE, IdentityRefused, Inbox, hosted_runs, lease_ms_for, open_session,
                  query_bytes, socket_address, unreachable_reason, zenoh_config)

__all__ = ["NodeShell", "CONNECT_BUDGET", "RUN_GRACE", "LINK_GRACE", "TAKEOVER_WAIT", "process_age", "settle_heap"]

#: seconds after its start a hand-started process gives the router to accept its connection (retried while
#: nothing listens); counted from the process's start, so a slow start on a loaded machine does not add to it
CONNECT_BUDGET = 2.5
#: seconds a router hosting other runs may take to show this process's run before the process gives up
RUN_GRACE = 1.0
#: seconds a hand-started process waiting for its configuration tolerates having no router link
LINK_GRACE = 1.0
#: Zenoh's runtimes in a plant or agent process (RON, read by Zenoh from ``ZENOH_RUNTIME`` when the process opens
#: its first session; a value already in the environment is kept): the application and transmission tasks run on
#: the reception threads.  A node handles each message on the reception thread that delivered it and publishes
#: from there; by default the publication woke a transmission thread, and timers an application thread, about
#: 11 thread switches per agent and event time more (q = 4).  Ring of 100 agents (q = 4), two runs each,
#: alternating: the agents' CPU per event time 110 ms against 122-125 ms, 70-71 against 77-79 ms/event
NODE_ZENOH_RUNTIME = "(app: (handover: rx), tx: (handover: rx))"
ZENOH_RUNTIME_ENV = "ZENOH_RUNTIME"
#: seconds a plant or agent waits for a standby orchestrator to take over once the active one's token is gone
#: (``SPLITSPEC_TAKEOVER_WAIT``); without a standby's token up it exits at once, as it always did
def _takeover_wait() -> float:
    try:
        return max(0.1, float(os.environ.get("SPLITSPEC_TAKEOVER_WAIT", "10")))
    except ValueError:
        return 10.0


TAKEOVER_WAIT = _takeover_wait()
#: a refused handshake is tried this many times (POLL apart) before the process reports it
REFUSALS = 2
POLL = 0.1


def settle_heap(*, collect: bool = True) -> int:
    """Exclude what a process has built so far (its imports, its design, its configuration) from Python's cyclic
    garbage collector (:func:`gc.freeze`); the number of objects it moved.

    A full collection visits every tracked object: an orchestrator's ~108,000 after its imports (numpy, scipy,
    Zenoh, Rerun) and the design took 124 ms on a busy 2-core machine, an event time's pace several times over,
    and Python starts one by itself whenever the long-lived objects grow by a quarter.  Frozen, they are never
    visited again: a collection sees only what the rounds create.  Called by every process of a run once it is set
    up and before its rounds start: agents and the plant in :meth:`NodeShell.run`, the orchestrator once its
    records are open, a standby once it is ready to take over and again as it takes over (without the collection).

    Parameters
    ----------
    collect : bool, default True
        Collect first (the garbage of the start-up is then freed, not kept for good); False where a pause
        must not happen (the first round, a takeover): freezing alone takes microseconds.

    Returns
    -------
    int
        Objects moved to the permanent generation by this call.

    Examples
    --------
    >>> settle_heap(collect=False) >= 0
    True
    """
    import gc

    before = gc.get_freeze_count()
    if collect:
        gc.collect()
    gc.freeze()
    return gc.get_freeze_count() - before


def process_age() -> float:
    """Seconds since this process started (Linux ``/proc/self/stat``); 0 where that cannot be read.

    Returns
    -------
    float
        Seconds, non-negative (the boot-time clock minus the process's start time).
    """
    try:
        with open("/proc/self/stat", encoding="ascii") as f:
            start_ticks = int(f.read().rsplit(")", 1)[1].split()[19])  # field 22, starttime, in clock ticks
        return max(0.0, time.clock_gettime(time.CLOCK_BOOTTIME) - start_ticks / os.sysconf("SC_CLK_TCK"))
    except (OSError, ValueError, IndexError, AttributeError):
        return 0.0


class NodeShell:
    """The Zenoh side of a plant or agent process: session, identity claim, config, publishing, the event loop.

    The process claims its identity (``role``, ``ident``) with a random nonce in its ``hello``; the
    orchestrator answers with the configuration (and the run's MAC key) or refuses, naming the live
    process that holds the identity (:class:`IdentityRefused`).  The loop ends on a ``stop`` from the
    orchestrator, when the orchestrator's liveliness token disappears and no standby orchestrator follows the run
    (so no process outlives a crashed orchestrator; with a standby up it waits :data:`TAKEOVER_WAIT` seconds for
    the takeover, then exits), or on SIGINT/SIGTERM.  A tick or control of an orchestrator epoch below the
    highest seen is refused (``fenced``: :class:`~splitspec_core.runtime.ticks.Fence`).  Every other message goes to the node's
    ``dispatch(channel, key, payload) -> [(key, payload), ...]``; a handler error is counted with
    ``on_error(reason)`` and never ends the process.
    """

    def __init__(self, connect: str, keys, *, log, role: str, ident: int, credentials: str | None = None,
                 wait: float = 30.0):
        import signal

        from .wire import new_nonce

        self.keys, self.log = keys, log
        self.role, self.ident = role, int(ident)
        self.endpoint, self.credentials = connect, credentials
        # before the first session: Zenoh builds its runtimes then, from this variable (a user's own wins)
        os.environ.setdefault(ZENOH_RUNTIME_ENV, NODE_ZENOH_RUNTIME)
        self.nonce = new_nonce()
        self.mac_key: bytes | None = None
        #: not started by an orchestrator: fail fast with the reason (see the module docstring)
        self.hand_started = not os.environ.get(CHILD_ENV)
        kw = {}
        if credentials:
            from .security import read_credentials

            kw["user"], kw["password"] = read_credentials(credentials)
        opts = dict(connect=[connect], connect_timeout_ms=int(max(wait, 1.0) * 1000), lease_ms=lease_ms_for(role), **kw)
        if self.hand_started:
            # one connection attempt per open (a refused handshake fails at once instead of being retried
            # until the timeout); _open_promptly retries while nothing listens
            opts["connect_timeout_ms"] = 0
            self.session = self._open_promptly(opts)
            try:
                self.health = self._open_promptly(opts)
            except NetworkError:
                self.session.close()
                raise
        else:
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
        from .ticks import Fence

        self.fence = Fence()  # the highest orchestrator epoch seen in a tick or a control (the node shares it)
        # watch the orchestrators first: if the last one dies and no standby takes over, we must exit by ourselves
        self.orchestrators: set = set()  # the epochs of the orchestrator tokens up
        self.standbys: set = set()  # the standby orchestrators' token keys up
        self.takeover_by: float | None = None  # the orchestrator is gone: wait for a standby's takeover until then
        self.expect_standby = False  # the config says a standby follows the run (its token may reach us late)
        self.inbox.watch_liveliness(keys.orchestrators, "orchestrator")
        self.inbox.watch_liveliness(keys.standbys, "standby")

    @property
    def who(self) -> str:
        """The process as log lines name it (str): ``the plant``, or ``<role> <id>`` (``agent 3``)."""
        return "the plant" if self.role == "plant" else f"{self.role} {self.ident}"

    def _open_promptly(self, opts: dict) -> zenoh.Session:
        """A client session of a hand-started process, or a one-line :class:`NetworkError` saying why not.

        Retried every :data:`POLL` seconds until :data:`CONNECT_BUDGET` seconds after the process
        started while nothing accepts a connection at the endpoint (a router still starting); a router
        that accepts the connection but not the Zenoh handshake refused this process (:data:`REFUSALS`
        attempts): that is reported at once, naming the credentials it came with.  An endpoint a
        socket cannot check (``udp/``, ``quic/``...) is retried for the whole budget.
        """
        config = zenoh_config("client", **opts)
        checkable = socket_address(self.endpoint) is not None
        started = time.monotonic() - process_age()
        deadline = started + CONNECT_BUDGET
        refusals = 0
        while True:
            try:
                return zenoh.open(config)
            except zenoh.ZError:
                pass  # zenoh gives no reason ("Unable to connect to any of [...]"): a socket tells
            why = unreachable_reason(self.endpoint, timeout=max(0.1, min(1.0, deadline - time.monotonic())))
            refusals = refusals + 1 if checkable and why is None else 0
            if refusals >= REFUSALS or time.monotonic() >= deadline:
                raise NetworkError(self._not_admitted(why, time.monotonic() - started, checked=checkable))
            time.sleep(POLL)

    def _not_admitted(self, unreachable: str | None, tried: float, *, checked: bool = True) -> str:
        """The one line saying why this process has no session.

        ``unreachable``: the socket's reason, if nothing accepted a connection; ``checked``: False if
        a socket cannot tell (the line then names both causes).
        """
        ep = self.endpoint
        if unreachable is not None:
            return (f"cannot reach a Zenoh router at {ep} ({unreachable}, for {tried:.1f} s): is the run (or its "
                    "router) up, and is this its endpoint?")
        if not checked:
            return (f"cannot connect to a Zenoh router at {ep} (for {tried:.1f} s): nothing answers there, or the "
                    f"router refused {self.who} ({'with' if self.credentials else 'without'} --credentials)")
        get_them = ("`splitspec credentials SCENARIO --out DIR` writes them, for an orchestrator started with "
                    "--secure DIR")
        if not self.credentials:
            return (f"the Zenoh router at {ep} refused {self.who}, which has no credentials: a secure run (the "
                    f"default) admits only processes started with --credentials FILE ({get_them}; or start the "
                    "run with --insecure)")
        from .security import read_credentials, user_of

        user = read_credentials(self.credentials)[0]
        mismatch = "" if user == user_of(self.role, self.ident) else f", which is not {self.who}'s user"
        return (f"the Zenoh router at {ep} refused user {user!r} of {self.credentials}{mismatch}: a wrong "
                f"password, or another run's credentials (use this run's; {get_them})")

    def fetch_config(self, *, wait: float) -> dict:
        """Claim the identity and fetch the scenario, the centralised design and the run's key.

        Then declares this process's ``status`` queryable: it answers with the same hello from a
        Zenoh thread, so the orchestrator can tell a frozen process (no answer) from one that is
        only waiting for a frozen neighbour.

        Parameters
        ----------
        wait : float
            Seconds to wait for the orchestrator's answer.

        Returns
        -------
        dict
            The decoded ``config`` message (:data:`~splitspec_core.runtime.wire.MESSAGE_FIELDS`: ``scenario``,
            ``seed``, ``g``, ``q``, ``g_mode``, ``key`` and the optional fields present); its ``key`` is also
            kept as the shell's ``mac_key``.

        Raises
        ------
        TimeoutError
            No orchestrator answered within ``wait`` seconds.
        IdentityRefused
            The orchestrator refused the identity (another live process holds it).
        NetworkError
            A hand-started process: the router hosts other runs but not this one, or the router link was
            lost (see the module docstring).
        WireError
            The answer is neither a refusal nor a valid ``config`` of this run.
        """
        import socket

        from .wire import WireError, decode, encode

        hello = encode("hello", self.keys.run_id, role=self.role, id=self.ident, pid=os.getpid(),
                       host=socket.gethostname(), nonce=self.nonce)
        if self.hand_started:
            raw = self._await_config(hello, wait=wait)
        else:
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
        self.expect_standby = bool(cfg.get("standby", False))  # a standby follows the run: wait for its takeover
        self.health_inbox.serve(self.keys.status(self.role, self.ident, self.nonce), lambda _q: hello)
        return cfg

    def _await_config(self, hello: bytes, *, wait: float) -> bytes | None:
        """The orchestrator's answer to ``hello`` (None after ``wait`` s) for a hand-started process.

        Between attempts it looks at what the router hosts (:func:`hosted_runs`): other runs but not
        this one for :data:`RUN_GRACE` -> :class:`NetworkError` (a wrong ``--run-id``); no router link
        for :data:`LINK_GRACE` -> :class:`NetworkError` (the run ended, the router stopped); no run at
        all -> it waits, and says once what for.
        """
        run_id, ep = self.keys.run_id, self.endpoint
        deadline = time.monotonic() + wait
        others_since = lost_since = None
        told = False
        while True:
            now = time.monotonic()
            if not self.session.info.routers_zid():
                lost_since = now if lost_since is None else lost_since
                if now - lost_since >= LINK_GRACE:
                    raise NetworkError(f"lost the Zenoh router at {ep} while {self.who} waited for the orchestrator "
                                       f"of run {run_id!r} (the run ended, or the router stopped)")
            else:
                lost_since = None
                # on the health session: a liveliness get on the data session right after its liveliness
                # subscriber (the orchestrator watch, with history) often comes back empty (Zenoh 1.10)
                runs = hosted_runs(self.health)
                if runs and run_id not in runs:
                    others_since = now if others_since is None else others_since
                    if now - others_since >= RUN_GRACE:
                        hosted = ", ".join(map(repr, runs))
                        raise NetworkError(f"no run {run_id!r} on {ep}: this router hosts run{'s' * (len(runs) > 1)} "
                                           f"{hosted} (check --run-id)")
                else:
                    others_since = None
                    if not runs and not told:
                        self.log.info("%s: waiting up to %g s for the orchestrator of run %r on %s (no run is "
                                      "visible on this router yet)", self.who, wait, run_id, ep)
                        told = True
                    raw = query_bytes(self.session, self.keys.config, timeout=2.0, payload=hello)
                    if raw is not None:
                        return raw
            if time.monotonic() > deadline:
                return None
            time.sleep(POLL)

    def publish(self, items) -> None:
        """Publish every ``(key, payload)`` (a publisher declared once per key, congestion control BLOCK).

        Parameters
        ----------
        items : iterable of (str, bytes)
            The key expressions and payloads, published in order.
        """
        for key, payload in items:
            pub = self.pubs.get(key)
            if pub is None:
                # BLOCK: a protocol message is never dropped by congestion control (a flood on the same
                # links may be; the round must not be)
                pub = self.pubs[key] = self.session.declare_publisher(
                    key, congestion_control=zenoh.CongestionControl.BLOCK)
            pub.put(payload)

    def run(self, dispatch, on_error, *, name: str, subscriptions=(), timer=None) -> int:
        """Subscribe, declare the liveliness token, then handle messages until told to stop.

        ``subscriptions`` (``(key, channel)`` pairs) are handled where they arrive, on the Zenoh
        thread, one at a time under a lock: ``dispatch(channel, key, payload)`` and the publication
        of what it returns (no queue, no thread hand-off).  Control messages, the orchestrator's
        presence and signals go through the event loop below.

        ``timer``: ``(next_wakeup, on_timer)`` of a node with deadlines (an agent on a network with
        ``network.deadline`` or delays): after every message the shell asks ``next_wakeup()`` (a monotonic
        time or None) and the event loop calls ``on_timer()`` once the clock reaches it, under the same
        lock, and publishes what it returns.  The event loop's alarm is never later than ``next_wakeup()``:
        a message that brings the wake-up before the alarm moves the alarm and wakes the loop (through the
        inbox); one that moves it later (the next sub-round's deadline, almost every message of a run whose
        messages arrive in time) leaves the loop asleep, and an alarm that rings early only re-arms it.
        So a deadline run wakes the event loop about once per deadline, not once per round.

        Parameters
        ----------
        dispatch : callable
            ``dispatch(channel, key, payload) -> [(key, payload), ...]``: the node's handler; what it
            returns is published.
        on_error : callable
            ``on_error(reason)``: counts a rejected or failed message (a :class:`WireError` reason, or
            ``handler_error``).
        name : str
            The process's name in log lines.
        subscriptions : iterable of (str, str), optional
            ``(key, channel)`` pairs handled directly on the Zenoh thread (default: none).
        timer : tuple of (callable, callable) or None, optional
            ``(next_wakeup, on_timer)`` of a node with deadlines; None (default): no timer.

        Returns
        -------
        int
            The process's exit status: 0 after a ``stop`` or a signal, 1 when the orchestrator was lost.
        """
        import signal

        from .wire import WireError, decode

        me = f"{self.role}/{self.ident}"  # the target name in fault commands
        code = 0
        lock = threading.Lock()

        alarm = [None]  # when the event loop wakes up next, never after next_wakeup() (guarded by lock)

        def guarded(call, what: str) -> None:
            try:
                self.publish(call())
            except (ValueError, TypeError, KeyError, IndexError) as exc:
                # a message that passed validation but still broke the node: drop it, count it, go on
                on_error("handler_error")
                self.log.warning("%s: dropped %s: %s", name, what, exc)
            except zenoh.ZError as exc:  # the session is closing under us (the orchestrator was lost)
                self.log.info("%s: not sent (%s)", name, str(exc).split(" at ")[0])
            if timer is not None:
                w = timer[0]()
                if w is not None and (alarm[0] is None or w < alarm[0]):
                    alarm[0] = w
                    self.inbox.put(("timer", "", b""))  # the event loop re-arms for the earlier wake-up

        def handle(channel: str, key: str, payload: bytes) -> None:
            with lock:
                if self._closing:  # the loop has ended: nothing more is handled or sent
                    return
                guarded(lambda: dispatch(channel, key, payload), f"a {channel} message on {key}")

        for key, channel in subscriptions:
            self.inbox.subscribe(key, channel, direct=handle)
        self.inbox.subscribe(self.keys.control, "control")
        settle_heap()  # set up: what is built so far is never visited by a collection again (a paced round's pause)
        token = self.session.liveliness().declare_token(self.keys.alive(self.role, self.ident, self.nonce))
        self._looping = True
        self.log.info("%s ready (pid %d)", name, os.getpid())
        while True:
            due = alarm[0]
            if self.takeover_by is not None:
                if time.monotonic() >= self.takeover_by:
                    code = self._no_takeover()
                    break
                due = self.takeover_by if due is None else min(due, self.takeover_by)
            item = self.inbox.get(timeout=1.0 if due is None else min(1.0, max(0.0, due - time.monotonic())))
            if timer is not None:
                with lock:
                    if not self._closing:
                        w = timer[0]()
                        if w is not None and time.monotonic() >= w:
                            guarded(timer[1], "a deadline")
                        alarm[0] = timer[0]()  # early (the wake-up moved later, or there is none): re-armed
            if item is None or item[0] == "timer":
                continue
            channel, key, payload = item
            if channel == "control":
                try:
                    msg = decode(payload, self.keys.run_id, "control", mac_key=self.mac_key)
                    cmd = msg["cmd"]
                except WireError as e:
                    on_error(e.reason)
                    continue
                if not self.fence.admit(msg):  # a superseded orchestrator's: never obeyed
                    on_error("fenced")
                    continue
                if cmd == "stop":
                    self.log.info("%s: stop from the orchestrator", name)
                    break
                word, _, target = cmd.partition(" ")
                kind = KINDS.get(word)
                if kind is not None and kind.runtime == SIGNAL and target == me:
                    # a scenario fault for a process the orchestrator cannot signal (another host): its kind says
                    # which signal
                    self.log.warning("%s: %s requested by the orchestrator", name, word)
                    os.kill(os.getpid(), getattr(signal, kind.signal))
            elif channel == "orchestrator":
                if self._orchestrator_token(key, payload):
                    code = 1
                    break
            elif channel == "standby":
                (self.standbys.add if payload != LIVELINESS_DELETE else self.standbys.discard)(str(key))
            elif channel == "signal":
                self.log.info("%s: interrupted", name)
                break
            else:  # subscribed before run() without a direct handler: handled here, in order
                handle(channel, key, payload)
        with lock:
            self._closing = True
        token.undeclare()
        return code

    def _orchestrator_token(self, key: str, payload) -> bool:
        """An orchestrator's token appeared or went (its id is its epoch); True: exit now (the last one went and no
        standby follows the run).  With a standby up (or the run's config saying one follows it: its token may reach
        this process late), wait :data:`TAKEOVER_WAIT` seconds for its takeover."""
        epoch = self.keys.last(key)
        if payload != LIVELINESS_DELETE:
            self.orchestrators.add(epoch)
            if self.takeover_by is not None:
                self.takeover_by = None
                self.log.info("%s: orchestrator epoch %s took over run %r; going on", self.who, epoch,
                              self.keys.run_id)
            return False
        self.orchestrators.discard(epoch)
        if self.orchestrators or self.takeover_by is not None:
            return False
        if self.standbys or self.expect_standby:
            self.takeover_by = time.monotonic() + TAKEOVER_WAIT
            self.log.warning("%s: the orchestrator (epoch %s) of run %r was lost; waiting up to %g s for its standby "
                             "to take over", self.who, epoch, self.keys.run_id, TAKEOVER_WAIT)
            return False
        self._say(f"{self.who}: the orchestrator of run {self.keys.run_id!r} was lost (its liveliness token "
                  "disappeared); exiting")
        return True

    def _no_takeover(self) -> int:
        self._say(f"{self.who}: the orchestrator of run {self.keys.run_id!r} was lost and no standby took over "
                  f"within {TAKEOVER_WAIT:g} s (SPLITSPEC_TAKEOVER_WAIT); exiting")
        return 1

    def _say(self, msg: str) -> None:
        """The one line of an exit for want of an orchestrator (the log only for a process `splitspec run` started:
        it says it once)."""
        import sys

        if os.environ.get(CHILD_ENV):
            self.log.info("%s", msg)
        else:
            print(f"splitspec: error: {msg}", file=sys.stderr)

    def close(self) -> None:
        """Close both inboxes and both Zenoh sessions (an error closing a session is logged, not raised)."""
        self.inbox.close()
        self.health_inbox.close()
        for session in (self.session, self.health):
            try:
                session.close()
            except Exception as exc:  # noqa: BLE001 - leaving anyway
                self.log.warning("closing the Zenoh session: %s", str(exc).split(" at ")[0])
