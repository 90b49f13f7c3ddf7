"""orchestrator.view (display detection, the URL, bad input) and the wire helpers of docs/make_screenshots.py."""

from __future__ import annotations

import importlib.util
import sys
import urllib.parse

import pytest

from splitspec_orchestrator.view import has_display, recording_path, viewer_url
from splitspec_core.errors import ScenarioError
from tests.conftest import ROOT


def _screenshots_module():
    spec = importlib.util.spec_from_file_location("make_screenshots", ROOT / "docs" / "make_screenshots.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # dataclasses look their module up there
    spec.loader.exec_module(module)
    return module


@pytest.mark.parametrize("env, expected", [({}, False), ({"DISPLAY": ""}, False), ({"DISPLAY": ":0"}, True),
                                           ({"WAYLAND_DISPLAY": "wayland-0"}, True)])
def test_has_display(env, expected):
    assert has_display(env) is expected


def test_viewer_url_points_the_page_at_the_grpc_proxy():
    url = viewer_url(9090, 9876)
    parts = urllib.parse.urlsplit(url)
    assert (parts.scheme, parts.hostname, parts.port) == ("http", "127.0.0.1", 9090)
    assert urllib.parse.parse_qs(parts.query) == {"url": ["rerun+http://127.0.0.1:9876/proxy"]}


def test_recording_path(tmp_path):
    (tmp_path / "run.rrd").write_bytes(b"")
    assert recording_path(tmp_path) == tmp_path / "run.rrd"
    for bad, words in [(tmp_path / "nope", "does not exist"), (tmp_path / "run.rrd", "not a directory")]:
        with pytest.raises(ScenarioError, match=words):
            recording_path(bad)
    (tmp_path / "empty").mkdir()
    with pytest.raises(ScenarioError, match="no run.rrd in"):
        recording_path(tmp_path / "empty")


def test_screenshot_wire_helpers_round_trip():
    """A GetViewerStateResponse built with the same field numbers decodes to what was put in."""
    m = _screenshots_module()
    f = m._field
    timeline = f(1, f(1, "event")) + f(2, 1) + f(3, f(2, 60))  # name, sequence type, range [0, 60]
    wall = f(1, f(1, "wall")) + f(2, 3) + f(3, f(1, 1_795_399_708_591_935_065) + f(2, 1_795_399_712_235_859_431))
    cursor = f(1, f(1, "event")) + f(2, 1) + f(3, f(1, 12))
    rec = f(1, "Recording:splitspec:r1") + f(2, timeline) + f(2, wall) + f(3, cursor) + f(5, m.PAUSED)
    state = m.recording_state(f(1, "about:recording") + f(2, "Recording:splitspec:r1") + f(3, rec))
    assert state.store_id == "Recording:splitspec:r1"
    assert state.timelines == {"event": (0, 60), "wall": (1_795_399_708_591_935_065, 1_795_399_712_235_859_431)}
    assert (state.cursor_timeline, state.cursor, state.play_state) == ("event", 12, m.PAUSED)
    # the request: set_time_cursor(6){timeline(2){name(1)}, time(3){sequence(1)}, play_state(5)}
    request = m.set_time_cursor_request("event", 12)
    (kind, body), = m._fields(request)
    assert kind == 6
    assert m._get(m._get(body, 2), 1) == b"event" and m._get(m._get(body, 3), 1) == 12 and m._get(body, 5) == m.PAUSED
