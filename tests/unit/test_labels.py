"""Directions and subspaces named with the states (splitspec_core/scenarios/labels.py): the largest first, and
components equal to round-off named in the states' order, whatever path computed them."""

from __future__ import annotations

import numpy as np

from splitspec_core.scenarios.labels import combination, heaviest, spread

NAMES = ("p1", "p2", "p3", "p4")


def test_equal_components_are_named_in_the_states_order_whatever_their_round_off():
    """p2, p3, p4 carry the direction equally; two computations of it differ in the last bits (1e-16), one way or
    the other: the text is the same."""
    for eps in (0.0, 2e-16, -2e-16):
        v = np.array([0.0, 1.0, 1.0 + eps, 1.0 - eps]) / np.sqrt(3.0)
        assert combination(v, NAMES) == "p2 + p3 + p4"
        assert combination(-v, NAMES) == "p2 + p3 + p4"  # the sign of an eigenvector is arbitrary
        W = np.zeros((4, 2))
        W[1, 0] = W[2, 1] = 1.0
        W[:, 0] += eps
        assert heaviest(W, NAMES) == ["p2", "p3"]
        assert spread(np.eye(4)[:, [3, 0]], NAMES) == "p1, p4"


def test_distinct_components_stay_largest_first():
    """A component larger beyond round-off (1e-6 here) comes first, as before."""
    v = np.array([0.0, 1.0, 1.0 + 1e-6, 0.5])
    assert combination(v, NAMES) == "p3 + p2 + 0.5 p4"
    W = np.array([[0.1], [0.2], [0.9], [0.0]])
    assert heaviest(W / np.linalg.norm(W), NAMES) == ["p3", "p2", "p1"]


def test_negligible_components_are_counted_not_named():
    v = np.array([1.0, -0.42, 1e-5, 0.0])
    assert combination(v, NAMES) == "p1 - 0.42 p2"
