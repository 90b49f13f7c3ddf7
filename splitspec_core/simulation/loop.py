"""The one simulation loop: at each step, faults, record, measure, update, advance.

:func:`~splitspec_core.simulation.simulator.simulate`, :func:`~splitspec_core.simulation.simulator.simulate_exact`
and the batched Monte Carlo (:mod:`splitspec_core.simulation.montecarlo`) run their steps through
:func:`run_steps`, each supplying only what differs (its estimator, its plant, what it records).  The order is
the contract ``splitspec run`` reproduces: at step k (time ``t_k``) the faults due at k apply
(:meth:`splitspec_core.model.network.NetworkState.apply`); ``x(k), x_i(k)`` are recorded; the plant measures
``y_i(k)``, which the sensor faults in force change (:meth:`~splitspec_core.model.network.NetworkState.measured`);
every alive agent updates to ``x_i(k+1)``; the plant moves to ``x(k+1)``.  The last step records only.
"""

from __future__ import annotations

from typing import Callable

from ..model.network import NetworkState, Plan

__all__ = ["run_steps"]


def run_steps(plan: Plan, net: NetworkState, rows: list, *, restart: Callable, record: Callable, update: Callable,
              measure: Callable | None = None, advance: Callable | None = None, last: Callable | None = None,
              missing: Callable | None = None) -> None:
    """Run steps ``0 .. plan.steps``: faults, record, measure, update, advance.

    Parameters
    ----------
    plan : Plan
        The run's steps and its faults by step (:func:`splitspec_core.model.network.make_plan`).
    net : NetworkState
        The network the faults change (alive agents, arcs, partition, sensors).
    rows : list of slice
        Each agent's rows of the stacked measurement (:func:`splitspec_core.model.plant.output_rows`).
    restart : callable
        ``restart(killed, rejoined)``: the positions lost and the ``(position, incarnation)`` that rejoin at this
        step (:meth:`~splitspec_core.model.network.NetworkState.apply`), for the caller's estimates.
    record : callable
        ``record(k)``: keep ``x(k)`` and ``x_i(k)``.
    update : callable
        ``update(k, y)``: every alive agent to ``x_i(k+1)`` from the measurement ``y(k)`` (None without ``measure``).
    measure : callable, optional
        ``measure(k)``: the plant's stacked ``y(k)`` (outputs on axis 0); None: no measurement (the exact ODE).
    advance : callable, optional
        ``advance(k)``: the plant to ``x(k+1)`` (None: ``update`` moves it too).
    last : callable, optional
        ``last(k)``: after the last step's record.
    missing : callable, optional
        ``missing(k)``: the agents without a measurement at step k ((m,) bool, or None: none), whose rows the
        sensor faults leave as they are; None: every agent has one.

    Examples
    --------
    >>> import splitspec_core as ss
    >>> from splitspec_core.model.network import NetworkState, make_plan
    >>> sc = ss.load_scenario("examples/paper_discrete.yaml")
    >>> seen = []
    >>> run_steps(make_plan(sc, 0, 3), NetworkState(sc), [], restart=lambda killed, rejoined: None,
    ...           record=lambda k: seen.append(("record", k)), update=lambda k, y: seen.append(("update", k)))
    >>> seen
    [('record', 0), ('update', 0), ('record', 1), ('update', 1), ('record', 2), ('update', 2), ('record', 3)]
    """
    for k in range(plan.steps + 1):
        restart(*net.apply(plan.faults.get(k, ())))
        record(k)
        if k == plan.steps:
            if last is not None:
                last(k)
            return
        y = (None if measure is None else  # as the sensor faults in force give it
             net.measured(measure(k), rows, None if missing is None else missing(k)))
        update(k, y)
        if advance is not None:
            advance(k)
