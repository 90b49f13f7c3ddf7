"""settle_heap: what a run's process built while it started is kept out of every later garbage collection.

Checked in a fresh interpreter (freezing this test process's heap would outlive the test): after the imports and a
design, a full collection visits only what was created after the freeze.
"""

import subprocess
import sys
import textwrap

from tests.integration.runtime_helpers import EXAMPLES, ROOT

PROBE = textwrap.dedent("""
    import gc, sys, time
    import numpy, scipy.linalg, zenoh, rerun
    from splitspec_core.scenarios.load import load_scenario
    from splitspec_core.synthesis.designer import design
    from splitspec_core.runtime.node import settle_heap

    des = design(load_scenario(sys.argv[1]))
    tracked = len(gc.get_objects())
    moved = settle_heap()
    left = len(gc.get_objects())  # the generations a collection visits (the permanent one is not among them)
    again = settle_heap(collect=False)
    print(tracked, moved, left, again)
""")


def test_a_settled_heap_leaves_a_collection_only_what_came_after():
    r = subprocess.run([sys.executable, "-c", PROBE, str(EXAMPLES / "ring10.yaml")], capture_output=True,
                       text=True, cwd=ROOT, timeout=300)
    assert r.returncode == 0, r.stderr[-2000:]
    tracked, moved, left, again = map(int, r.stdout.split())
    assert tracked > 20_000, tracked  # the imports and the design: what a collection visited before
    assert moved >= 0.9 * tracked - 1_000, (moved, tracked)  # (the collection first frees the start-up's garbage)
    assert left < 0.01 * moved, (left, moved)
    assert again <= left + 100, (again, left)  # a second call moves only what came since
