"""The Zenoh configuration every process's session gets (splitspec_core.runtime.bus.zenoh_config)."""

import json

import pytest

from splitspec_core.runtime.bus import zenoh_config


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
