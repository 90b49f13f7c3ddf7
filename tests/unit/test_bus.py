"""The Zenoh configuration every process's session gets (splitspec_core.runtime.bus.zenoh_config), and the socket
check that tells an endpoint nobody listens on from a router that refused (unreachable_reason)."""

import json
import socket

import pytest

from splitspec_core.runtime.bus import socket_address, unreachable_reason, zenoh_config
from splitspec_core.runtime.security import acl_config
from splitspec_core.runtime.wire import ORCHESTRATORS, Keys


@pytest.mark.parametrize("mode,kw", [("router", {"listen": ["tcp/127.0.0.1:7447"]}),
                                     ("client", {"connect": ["tcp/127.0.0.1:7447"]}),
                                     ("peer", {"listen": ["tcp/127.0.0.1:7447"]})])
def test_no_shared_memory(mode, kw):
    """A message of 3 KB or more (a config reply from m = 16 agents on) would go through the sender's 16 MB
    shared-memory pool, and every receiving process would map all of it."""
    assert json.loads(zenoh_config(mode, **kw).get_json("transport/shared_memory/enabled")) is False


def test_a_router_without_peers_opens_without_the_scouting_delay():
    """The orchestrator's embedded router: nothing to scout (multicast off, no connect), so no 500 ms sleep."""
    c = zenoh_config("router", listen=["tcp/127.0.0.1:7447"])
    assert json.loads(c.get_json("scouting/delay")) == 0
    # a router that connects to others keeps Zenoh's default: the delay lets it hear of them
    c = zenoh_config("router", listen=["tcp/127.0.0.1:7447"], connect=["tcp/127.0.0.1:7448"])
    assert json.loads(c.get_json("scouting/delay")) != 0


@pytest.mark.parametrize("endpoint,expected", [
    ("tcp/127.0.0.1:7447", ("tcp", ("127.0.0.1", 7447))),
    ("tcp/[::1]:7447", ("tcp", ("::1", 7447))),
    ("tls/router.example:7447?iface=eth0#lease=1", ("tcp", ("router.example", 7447))),
    ("ws/host:80", ("tcp", ("host", 80))),
    ("unixsock-stream//tmp/z.sock", ("unix", "/tmp/z.sock")),
    ("udp/127.0.0.1:7447", None), ("quic/host:7447", None),  # not checkable with a TCP socket
    ("tcp/127.0.0.1", None), ("tcp/:7447", None), ("garbage", None),
])
def test_socket_address(endpoint, expected):
    assert socket_address(endpoint) == expected


def test_unreachable_reason_tells_a_listener_from_nobody(tmp_path):
    with socket.socket() as srv:
        srv.bind(("127.0.0.1", 0))
        srv.listen()
        port = srv.getsockname()[1]
        assert unreachable_reason(f"tcp/127.0.0.1:{port}") is None
    assert unreachable_reason(f"tcp/127.0.0.1:{port}") == "connection refused"  # closed now
    assert unreachable_reason(f"unixsock-stream/{tmp_path / 'none.sock'}") == "no such file or directory"
    assert unreachable_reason("tcp/no-such-host.invalid:7447").startswith("cannot resolve 'no-such-host.invalid'")
    assert unreachable_reason("udp/127.0.0.1:1") is None  # cannot tell


def test_every_authenticated_process_may_ask_which_runs_a_secure_router_hosts():
    acl = acl_config("r1", [1, 2])
    (rule,) = [r for r in acl["rules"] if r["id"] == "discover-runs"]
    assert rule["messages"] == ["liveliness_query"] and rule["flows"] == ["ingress"]
    assert rule["key_exprs"] == [ORCHESTRATORS] == ["splitspec/*/alive/orchestrator/*"]
    (everyone,) = [p for p in acl["policies"] if p["id"] == "everyone"]
    assert "discover-runs" in everyone["rules"]
    # the reply is the orchestrator's own token, which every authenticated process may already see
    assert Keys.run_of(Keys("r1").alive("orchestrator")) == "r1"
    assert Keys.run_of("splitspec") is None and Keys.run_of("other/r1/alive") is None


def test_a_direct_handler_keeps_its_thread_state_from_one_message_to_the_next():
    """zenoh-python runs a direct handler on Zenoh's own thread through PyGILState_Ensure/Release: without
    Inbox's kept thread state each message got a new Python thread state (and a new frame stack: mmap, page
    faults, munmap), visible here as a ``threading.local`` that forgets between messages.  Real sessions: a
    router and a client on a loopback port."""
    import threading
    import time

    from splitspec_core.runtime.bus import Inbox, open_session

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        endpoint = f"tcp/127.0.0.1:{s.getsockname()[1]}"
    router = open_session("router", listen=[endpoint])
    client = open_session("client", connect=[endpoint])
    try:
        local, seen, done = threading.local(), [], threading.Event()

        def handler(channel, key, payload):
            local.count = getattr(local, "count", 0) + 1  # the same thread state: the count goes on
            seen.append((threading.get_ident(), local.count))
            if len(seen) == 20:
                done.set()

        inbox = Inbox(client)
        inbox.subscribe("test/direct", "t", signed=False, direct=handler)
        pub = router.declare_publisher("test/direct")
        deadline = time.monotonic() + 10
        while not done.is_set() and time.monotonic() < deadline:
            pub.put(b"x")
            time.sleep(0.02)
        assert done.is_set(), f"{len(seen)} of 20 messages arrived"
        per_thread: dict = {}
        for ident, count in seen:  # Zenoh may hand messages to either of its network threads: per thread
            per_thread.setdefault(ident, []).append(count)
        assert all(counts == list(range(1, len(counts) + 1)) for counts in per_thread.values()), per_thread
        assert max(len(c) for c in per_thread.values()) > 1
        inbox.close()
    finally:
        client.close()
        router.close()
