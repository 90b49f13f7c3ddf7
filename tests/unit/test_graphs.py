import numpy as np
import pytest

from splitspec_core.errors import AssumptionError
from splitspec_core.model.graphs import (adjacency, build_graph, enumerate_strongly_connected, find_unreachable,
                                   graph_sequence, is_doubly_stochastic, metropolis_matrix, neighbour_lists,
                                   perron_vector, stochastic_matrix, switch_times)
from splitspec_core.scenarios.specs import Switching


def test_stochastic_matrix_averages_in_neighbours():
    # arcs (j, i): 0 -> 1, 1 -> 2, 2 -> 0 ; agent 1 hears 0 and itself
    S = stochastic_matrix(adjacency(3, [(0, 1), (1, 2), (2, 0)]))
    assert np.allclose(S, [[0.5, 0, 0.5], [0.5, 0.5, 0], [0, 0.5, 0.5]])
    assert np.allclose(S.sum(axis=1), 1)


def test_unreachable_pair_is_named():
    # path 0 -> 1 -> 2: nothing reaches 0
    j, i = find_unreachable(3, [(0, 1), (1, 2)])
    assert i == 0 and j in (1, 2)
    with pytest.raises(AssumptionError, match="graph g is not strongly connected: agent [23] cannot reach agent 1"):
        build_graph("g", (1, 2, 3), [(1, 2), (2, 3)])
    assert find_unreachable(3, [(0, 1), (1, 2), (2, 0)]) is None


def test_perron_vector():
    S = build_graph("a", (1, 2, 3), [(1, 2), (2, 1), (2, 3), (3, 2), (1, 3)]).S
    pi = perron_vector(S)
    assert np.all(pi > 0) and pi.sum() == pytest.approx(1)
    assert np.allclose(S.T @ pi, pi)


def test_metropolis_is_doubly_stochastic_and_needs_undirected():
    adj = adjacency(4, [(0, 1), (1, 0), (1, 2), (2, 1), (2, 3), (3, 2), (0, 2), (2, 0)])
    W = metropolis_matrix(adj)
    assert np.allclose(W, W.T) and is_doubly_stochastic(W) and np.all(W >= 0)
    assert not is_doubly_stochastic(stochastic_matrix(adj))
    with pytest.raises(AssumptionError, match="undirected"):
        metropolis_matrix(adjacency(3, [(0, 1), (1, 2), (2, 0)]))


def test_neighbour_lists_include_self_first():
    g = build_graph("a", (1, 2, 3), [(1, 2), (2, 1), (2, 3), (3, 2), (1, 3)])
    assert neighbour_lists(g) == {1: (1, 2), 2: (2, 1, 3), 3: (3, 1, 2)}


def test_schedule_with_period_and_sequence():
    sw = Switching(kind="schedule", schedule=((0.0, "a"), (2.0, "b")), period=5.0)
    pieces = switch_times(sw, ("a", "b"), 12)
    seq = graph_sequence(pieces, 12)
    assert seq.tolist() == [0, 0, 1, 1, 1, 0, 0, 1, 1, 1, 0, 0]


def test_random_switching_is_seeded_and_has_the_average_dwell():
    sw = Switching(kind="random", graphs=("a", "b"), dwell=0.5)
    p1 = switch_times(sw, ("a", "b"), 2000.0, np.random.default_rng(1))
    p2 = switch_times(sw, ("a", "b"), 2000.0, np.random.default_rng(1))
    assert p1 == p2  # exact: the same function, the same seed
    mean_dwell = 2000.0 / len(p1)
    assert mean_dwell == pytest.approx(0.5, rel=0.1)
    # always a switch to the other graph
    assert all(x[1] != y[1] for x, y in zip(p1, p1[1:]))


def test_enumerate_strongly_connected_small():
    assert len(enumerate_strongly_connected(2)) == 1
    assert len(enumerate_strongly_connected(3)) == 18  # known count of strongly connected digraphs on 3 labelled vertices


@pytest.mark.parametrize("switching", [
    {"kind": "constant"},
    {"kind": "schedule", "schedule": ((0.0, "a"), (3.0, "b"))},
    {"kind": "schedule", "schedule": ((0.0, "a"), (2.5, "b")), "period": 4.0},
    {"kind": "random", "graphs": ("a", "b", "c"), "dwell": 0.7},
])
@pytest.mark.parametrize("dt", [1.0, 0.05])
def test_lazy_switching_signal_equals_the_sequence(switching, dt):
    """The runtime's O(1)-memory signal draws exactly what the simulator's array holds."""
    from splitspec_core.model.graphs import SwitchingSignal, graph_sequence, switch_times
    from splitspec_core.scenarios.specs import Switching

    sw = Switching(**switching)
    names = ("a", "b", "c")
    steps = 400
    pieces = switch_times(sw, names, steps * dt, np.random.default_rng(5) if sw.kind == "random" else None)
    seq = graph_sequence(pieces, steps, dt=dt)
    sig = SwitchingSignal(sw, names, dt=dt, rng=np.random.default_rng(5) if sw.kind == "random" else None)
    assert [sig.at(k) for k in range(steps)] == seq.tolist()
    assert len(set(seq.tolist())) == (1 if sw.kind == "constant" else len(set(g for _, g in pieces)))
    with pytest.raises(ValueError, match="forward only"):
        sig.at(3)
