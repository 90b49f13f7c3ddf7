"""Named random streams derived from the scenario seed.

A scenario plus a seed fixes the whole trajectory, in ``simulate`` and in the
multi-process ``run`` alike.  Every stream is addressed by a key, not by draw
order across processes: ``SeedSequence(seed, spawn_key=(stream, *key))``.
Each process opens exactly the streams it owns and draws from them in the
same order as the simulator:

==================  =================================  ==========================
stream              key                                draws (per step)
==================  =================================  ==========================
``initial_state``   ()                                 ``n`` normals once (if no x0)
``process``         ()                                 ``n`` normals per step
``measurement``     ()                                 ``sum s_i`` normals per step
                                                       (all agents, dead or alive)
``estimate``        (agent index, incarnation)         ``n`` normals once
``switching``       ()                                 random switching signal
``network``         ()                                 two 64-bit keys once: the counter-based
                                                       loss and delay draws of every consensus
                                                       message (:mod:`splitspec_core.model.impairment`)
``sensor_noise``    (agent index, sensor fault)        ``s_i`` normals per step while a sensor fault
                                                       with ``noise:`` is in force on agent i (the
                                                       fault: 0 for the first put on that agent, +1
                                                       for each later; :mod:`splitspec_core.scenarios.faults`)
==================  =================================  ==========================
"""

from __future__ import annotations

import numpy as np

__all__ = ["stream", "STREAMS"]

STREAMS = {"initial_state": 0, "process": 1, "measurement": 2, "estimate": 3, "switching": 4, "network": 5, "sensor_noise": 6}


def stream(seed: int, name: str, *key: int) -> np.random.Generator:
    """The generator of stream ``name`` with integer ``key`` (see the module table).

    Parameters
    ----------
    seed : int
        The run's seed (``run.seed``).
    name : str
        A stream of :data:`STREAMS` (``"process"``, ``"estimate"``, ...).
    *key : int
        The stream's key, e.g. ``(agent index, incarnation)`` for ``estimate``.

    Returns
    -------
    numpy.random.Generator
        ``default_rng(SeedSequence(seed, spawn_key=(STREAMS[name], *key)))``: the same numbers in every process.

    Examples
    --------
    >>> a = stream(7, "estimate", 0, 1).standard_normal(2)
    >>> b = stream(7, "estimate", 0, 1).standard_normal(2)
    >>> bool((a == b).all()), bool((a == stream(7, "estimate", 1, 1).standard_normal(2)).all())
    (True, False)
    """
    return np.random.default_rng(np.random.SeedSequence(int(seed), spawn_key=(STREAMS[name], *map(int, key))))
