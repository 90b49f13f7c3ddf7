"""Per-agent step functions: pure, no I/O.  The agent process calls exactly these.

Discrete two-rate estimator (eqs. split-discrete-est1 .. p3)
------------------------------------------------------------
``z_i(0) = x_i(tau)``;  for ``k = 1..q``:
``z_i(k) = (I - P_i) z_i(k-1) + P_i sum_{j in N_i} w_ij z_j(k-1)``
(``w_ij = 1/m_i`` for uniform weights, or the Metropolis weights);
``x_i(tau+1) = (A + K_i C_i) z_i(q) - K_i y_i(tau)``, or, when agent i has no measurement at
``tau`` (a live sensor silent or stale, a recorded gap), the prediction ``x_i(tau+1) = A z_i(q)``
(the same update with the innovation ``C_i z_i(q) - y_i`` taken as zero).  With known inputs
(``x(tau+1) = A x(tau) + B u(tau)``, :mod:`splitspec_core.scenarios.inputs`) every update adds the same ``B u(tau)``
(``bu``) as the plant, so the error recursion, and every certificate, is unchanged.

Continuous time, sampled-data form (one exchange per ``dt``)
-----------------------------------------------------------
The estimator of eq. (split_continuous_observer) is sampled with period
``dt``: the model part is propagated exactly, the correction terms are held
over the step (first order):

``x_i(k+1) = E x_i(k) + D [K_i (C_i x_i(k) - y_i(k)) - g_i P_i (x_i(k) - sum_j w_ij x_j(k)) + B u(k)]``

with ``E = exp(A dt)`` and ``D = int_0^dt exp(A s) ds``.  If every estimate is
exact (``x_j = x``, ``y_i = C_i x``) the update is exactly the plant's
``x(k+1) = E x(k)``, so noise-free errors converge to zero; the error
recursion is ``I + dt (A + K_i C_i - g P_i (I - Sbar)) + O(dt^2)``, so the
trajectory converges to the exact ODE as ``dt -> 0`` (first order); and since
``E``, ``D`` commute with the observability decomposition, the split of the
spectrum (prop. error) holds exactly for every ``dt``.

Whole-state consensus (:mod:`splitspec_core.synthesis.whole_state`)
------------------------------------------------------------------
The same two-rate estimator with ``P_i = I``, each agent's estimate its averaged state (eq. split-discrete-p3):
it updates with its own measurement, then averages ``q`` times,

``z_i(0) = (A + K_i C_i) x_i(tau) - K_i y_i(tau) [+ B u(tau)]`` (:func:`measurement_update` on ``x_i``; without a
measurement :func:`prediction_update`), ``z_i(k) = sum_j w_ij z_j(k-1)`` (:func:`weighted_average`),
``x_i(tau+1) = z_i(q)``.  In continuous time on the sampled model, one event time per ``run.dt``:
``z_i(0) = E x_i + D [K_i (C_i x_i - y_i) + B u]``, the same functions with the matrices of
:func:`step_matrices`.

Fusion (:mod:`splitspec_core.synthesis.fusion`)
-----------------------------------------------
The same protocol with matrix weights, one set per sub-round, chosen for the noise: measure, fuse ``q`` times,
predict,

``z_i(0) = x_i(tau) + L_i (y_i(tau) - C_i x_i(tau))`` (:func:`local_update`; no measurement: ``x_i(tau)``),
``z_i(k) = sum_j W_ij(k) z_j(k-1)`` with ``sum_j W_ij(k) = I`` (:func:`matrix_fusion`),
``x_i(tau+1) = A z_i(q) [+ B u(tau)]`` (:func:`prediction_update`; in continuous time the sampled model's
``E z_i(q) + D B u``).  A neighbour whose estimate does not count (lost, its message lost or late) has its weight
folded into the agent's own (:func:`fold_weights`).  ``design.consensus: fusion``:
:mod:`splitspec_core.synthesis.fusion_kind`.

Relay (:mod:`splitspec_core.synthesis.relay`)
---------------------------------------------
The exchanges carry the sensors' samples (:func:`relay_forward`: each agent passes on once every sample it holds);
each agent keeps a base estimate ``b_i`` of ``x(t_b)`` and walks it forward over the samples it holds
(:func:`relay_walk`, a :func:`relay_step` per event time of the walk), the base moving on once it is ``D`` behind:

``e <- F e + G_l[:, r] (y_r(t) - C_r e) [+ B u(t)]``,  ``t = t_b .. tau``, ``l = tau - t``, ``r`` the rows held,

``x_i(tau + 1) = e``.

Bad data (:mod:`splitspec_core.synthesis.bad_data`)
---------------------------------------------------
Before its update each agent tests its measurement against its prediction (:func:`innovation_test`):
``r_i = y_i - C_i z`` with ``z`` what the update applies ``K_i`` to (``z_i(q)``, or ``x_i(tau)`` for the whole-state
design and the sampled-data form), ``d_i = r_i' S_i^-1 r_i`` against the design's threshold; a failing measurement
is not used (:func:`prediction_update`).  :func:`sensor_watch` counts the failures in a row: ``k`` make the sensor
suspect (its agent then takes ``P_i = I``, no measurement), ``k`` clean tests restore it.

Adaptive gain (eq. adaptive), forward Euler with the same ``dt``:
``g_i(k+1) = g_i(k) + dt |V_i' sum_j w_ij (x_j(k) - x_i(k))|^2``.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from ..scenarios.sampling import sampled_data_matrices

__all__ = [
    "weighted_average",
    "consensus_subround",
    "known_input",
    "local_update",
    "matrix_fusion",
    "fold_weights",
    "measurement_update",
    "prediction_update",
    "flatline",
    "relay_step",
    "relay_walk",
    "relay_forward",
    "relay_samples",
    "relay_prune",
    "sampled_data_matrices",
    "sampled_step",
    "adaptive_gain_rate",
    "adaptive_gain_step",
    "step_matrices",
    "step_input",
    "innovation_test",
    "warmup_step",
    "sensor_watch",
]


def weighted_average(states: Sequence[np.ndarray], weights: Sequence[float]) -> np.ndarray:
    """``sum_j w_ij z_j`` over agent i's neighbours (itself included).

    Parameters
    ----------
    states : sequence of (n,) arrays
        The states ``z_j`` of the neighbours ``j in N_i``, agent i included.
    weights : sequence of float
        The weights ``w_ij``, one per state, in the same order.

    Returns
    -------
    (n,) ndarray
        ``sum_j w_ij z_j`` (float).

    Examples
    --------
    >>> import numpy as np
    >>> weighted_average([np.array([1.0, 0.0]), np.array([3.0, 2.0])], [0.5, 0.5])
    array([2., 1.])
    """
    acc = np.zeros_like(states[0], dtype=float)
    for w, z in zip(weights, states):
        acc = acc + w * z
    return acc


def consensus_subround(z_i: np.ndarray, P_i: np.ndarray, neighbour_states: Sequence[np.ndarray],
                       weights: Sequence[float]) -> np.ndarray:
    """One consensus sub-round (eq. split-discrete-p1..p3, middle line).

    ``z_i(k) = (I - P_i) z_i(k-1) + P_i sum_j w_ij z_j(k-1)``, written as
    ``z_i + P_i (avg - z_i)``.  ``neighbour_states`` and ``weights`` cover
    every ``j in N_i``, agent i included.

    Parameters
    ----------
    z_i : (n,) ndarray
        Agent i's state ``z_i(k-1)`` before the sub-round.
    P_i : (n, n) ndarray
        The projection ``P_i = V_i V_i'`` onto agent i's unobservable space.
    neighbour_states : sequence of (n,) arrays
        The states ``z_j(k-1)`` of every ``j in N_i``, agent i included.
    weights : sequence of float
        The weights ``w_ij``, in the order of ``neighbour_states``.

    Returns
    -------
    (n,) ndarray
        ``z_i(k)``.

    Examples
    --------
    Only the directions of ``P_i`` move towards the average:

    >>> import numpy as np
    >>> P = np.diag([1.0, 0.0])
    >>> consensus_subround(np.array([1.0, 1.0]), P, [np.array([1.0, 1.0]), np.array([3.0, 5.0])], [0.5, 0.5])
    array([2., 1.])
    """
    avg = weighted_average(neighbour_states, weights)
    return z_i + P_i @ (avg - z_i)


def known_input(B: np.ndarray | None, u: np.ndarray | None) -> np.ndarray | None:
    """``B u(tau)``: what every update adds for the known inputs, as the plant does (None: no inputs).

    Parameters
    ----------
    B : (n, r) ndarray or None
        The input matrix ``B``; None when the system has no inputs.
    u : (r,) ndarray or None
        The input ``u(tau)``; None when the system has no inputs.

    Returns
    -------
    (n,) ndarray or None
        ``B u(tau)``; None when ``B`` or ``u`` is None.
    """
    return None if B is None or u is None else B @ u


def measurement_update(z_q: np.ndarray, F_i: np.ndarray, K_i: np.ndarray, y_i: np.ndarray,
                       bu: np.ndarray | None = None) -> np.ndarray:
    """Eq. (split-discrete-est1): ``x_i(tau+1) = (A + K_i C_i) z_i(q) - K_i y_i(tau) [+ B u(tau)]``,
    ``F_i = A + K_i C_i``; ``bu`` the known input's ``B u(tau)`` (None: no inputs).

    Parameters
    ----------
    z_q : (n,) ndarray
        ``z_i(q)``, agent i's state after the ``q`` consensus sub-rounds.
    F_i : (n, n) ndarray
        ``A + K_i C_i``.
    K_i : (n, s_i) ndarray
        Agent i's gain ``K_i``.
    y_i : (s_i,) ndarray
        Agent i's measurement ``y_i(tau)``.
    bu : (n,) ndarray or None, optional
        The known input's ``B u(tau)``; None (default): no inputs, nothing added.

    Returns
    -------
    (n,) ndarray
        ``x_i(tau+1)``.

    Examples
    --------
    >>> import numpy as np
    >>> A, K, C = np.array([[1.0, 1.0], [0.0, 1.0]]), np.array([[-0.5], [-0.25]]), np.array([[1.0, 0.0]])
    >>> measurement_update(np.array([1.0, 2.0]), A + K @ C, K, np.array([2.0]))
    array([3.5 , 2.25])
    """
    x = F_i @ z_q - K_i @ y_i
    return x if bu is None else x + bu


def local_update(x_i: np.ndarray, L_i: np.ndarray, C_i: np.ndarray, y_i: np.ndarray | None) -> np.ndarray:
    """The fusion kind's measurement step: ``z_i(0) = x_i(tau) + L_i (y_i(tau) - C_i x_i(tau))``; ``y_i`` None (no
    measurement at ``tau``): ``x_i(tau)`` itself.

    Parameters
    ----------
    x_i : (n,) ndarray
        Agent i's estimate ``x_i(tau)``.
    L_i : (n, s_i) ndarray
        Its update gain.
    C_i : (s_i, n) ndarray
        Its output matrix.
    y_i : (s_i,) ndarray or None
        Its measurement ``y_i(tau)``; None: none.

    Returns
    -------
    (n,) ndarray
        ``z_i(0)``.

    Examples
    --------
    >>> import numpy as np
    >>> local_update(np.array([1.0, 2.0]), np.array([[0.5], [0.0]]), np.array([[1.0, 0.0]]), np.array([3.0]))
    array([2., 2.])
    """
    if y_i is None:
        return np.array(x_i, dtype=float)
    return x_i + L_i @ (y_i - C_i @ x_i)


def matrix_fusion(states: Sequence[np.ndarray], weights: np.ndarray) -> np.ndarray:
    """One fusion sub-round: ``z_i(k) = sum_j W_ij(k) z_j(k-1)`` over agent i's neighbours (itself included).

    Parameters
    ----------
    states : sequence of (n,) arrays
        ``z_j(k-1)`` of every ``j in N_i``, in the order of the weights.
    weights : (n, |N_i| n) ndarray
        ``[W_ij(k) for j in N_i]`` side by side (their sum is ``I``).

    Returns
    -------
    (n,) ndarray
        ``z_i(k)``.

    Examples
    --------
    >>> import numpy as np
    >>> matrix_fusion([np.array([1.0, 0.0]), np.array([3.0, 2.0])], np.array([[0.5, 0, 0.5, 0], [0, 1, 0, 0]]))
    array([2., 0.])
    """
    return weights @ np.concatenate(states)


def fold_weights(blocks: dict, me, counted: Sequence) -> np.ndarray:
    """Agent ``me``'s fusion weights over the neighbours whose estimates count this sub-round: the weight of every
    other one (lost, its message lost or late, cut by a partition) folded into its own, so they still sum to ``I``.

    Parameters
    ----------
    blocks : dict
        ``{j: W_ij(k)}`` over the graph's ``N_i``, ``me`` included, each ``(n, n)``.
    me : hashable
        Agent i's key in ``blocks``.
    counted : sequence
        The keys whose estimates count, ``me`` included, in the order of the states handed to
        :func:`matrix_fusion`.

    Returns
    -------
    (n, len(counted) n) ndarray
        ``[W'_ij for j in counted]`` side by side, ``W'_ii = W_ii + sum of the others``.

    Examples
    --------
    >>> import numpy as np
    >>> blocks = {1: 0.5 * np.eye(1), 2: 0.3 * np.eye(1), 3: 0.2 * np.eye(1)}
    >>> fold_weights(blocks, 1, [1, 3])
    array([[0.8, 0.2]])
    """
    own = blocks[me]
    for j in sorted(blocks):  # in the order of the keys: the same sum wherever it is folded, however blocks came
        if j not in counted:
            own = own + blocks[j]
    return np.hstack([own if j == me else blocks[j] for j in counted])


def relay_step(e: np.ndarray, F: np.ndarray, G: np.ndarray, C: np.ndarray, y: np.ndarray,
               bu: np.ndarray | None = None) -> np.ndarray:
    """One step of the relay kind's walk, predictor form: ``F e + G (y - C e) [+ B u]``; no rows: ``F e [+ B u]``.

    Parameters
    ----------
    e : (n,) ndarray
        The estimate of ``x(t)``.
    F : (n, n) ndarray
        The per-step model.
    G : (n, r) ndarray
        The gain's columns of the rows held.
    C : (r, n) ndarray
        The rows held of the stacked output matrix.
    y : (r,) ndarray
        Their samples ``y_r(t)``.
    bu : (n,) ndarray or None, optional
        The known input's ``B u(t)`` (None: none).

    Returns
    -------
    (n,) ndarray
        The estimate of ``x(t + 1)``.

    Examples
    --------
    >>> import numpy as np
    >>> relay_step(np.array([1.0]), np.eye(1), np.array([[0.5]]), np.eye(1), np.array([3.0]))
    array([2.])
    """
    x = F @ e
    if len(y):
        x = x + G @ (y - C @ e)
    return x if bu is None else x + bu


def relay_walk(base: np.ndarray, t_base: int, tau: int, gains: Sequence[np.ndarray], F: np.ndarray, C: np.ndarray,
               samples: dict, bus: dict | None = None) -> tuple:
    """The relay kind's event time for one agent: walk the base ``b_i`` (the estimate of ``x(t_base)``) forward over
    the samples held to ``x_i(tau + 1)``; the base moves on one step once it is ``D = len(gains) - 1`` behind.

    Parameters
    ----------
    base : (n,) ndarray
        ``b_i``.
    t_base : int
        The event time ``b_i`` estimates (``tau - D <= t_base <= tau``).
    tau : int
        The event time.
    gains : sequence of (n, p) ndarray
        ``gains[l]``: the walk's gain at lag ``l`` on every stacked row (zero columns for rows not designed),
        ``gains[D]`` the base's.
    F : (n, n) ndarray
        The per-step model.
    C : (p, n) ndarray
        The stacked output matrix.
    samples : dict
        ``{t: (rows, y)}``: the stacked rows (int array, increasing) of ``y(t)`` held and their values.
    bus : dict or None, optional
        ``{t: B u(t)}`` (None: no inputs).

    Returns
    -------
    tuple
        ``(base, t_base, x)``: the base after the event time and ``x_i(tau + 1)``.

    Examples
    --------
    >>> import numpy as np
    >>> gains = [np.array([[0.5]]), np.array([[0.5]])]  # D = 1
    >>> relay_walk(np.zeros(1), 4, 5, gains, np.eye(1), np.eye(1), {4: (np.array([0]), np.array([2.0])),
    ...                                                              5: (np.array([0]), np.array([2.0]))})
    (array([1.]), 5, array([1.5]))
    """
    D = len(gains) - 1
    e, nb, tb = base, base, t_base
    empty = (np.zeros(0, dtype=np.int64), np.zeros(0))
    for t in range(t_base, tau + 1):
        rows, y = samples.get(t, empty)
        lag = tau - t
        e = relay_step(e, F, gains[lag][:, rows], C[rows], y, None if bus is None else bus.get(t))
        if t == t_base and lag == D:  # the base's own step (every sensor in): it moves on
            nb, tb = e, t_base + 1
    return nb, tb, e


def relay_forward(held: dict, sent: set) -> dict:
    """What an agent sends in one exchange of the relay kind: the samples it holds and has not sent yet.

    Parameters
    ----------
    held : dict
        ``{(sensor position, event time): y_j(t)}`` of the samples it holds.
    sent : set of (int, int)
        The keys it sent before.

    Returns
    -------
    dict
        The samples to send, in the order of ``held``.

    Examples
    --------
    >>> relay_forward({(0, 3): 1.5, (1, 3): 2.5}, {(0, 3)})
    {(1, 3): 2.5}
    """
    return {k: v for k, v in held.items() if k not in sent}


def relay_samples(held: dict, sensor_rows: Sequence[np.ndarray], t_base: int, tau: int) -> dict:
    """``{t: (rows, y)}`` of the samples an agent holds for its walk from ``t_base`` to ``tau``
    (:func:`relay_walk`), the sensors in increasing position.

    Parameters
    ----------
    held : dict
        ``{(sensor position, t): y_j(t)}``.
    sensor_rows : sequence of int arrays
        Each sensor's rows of the stacked ``y``.
    t_base, tau : int
        The walk's first and last event times.

    Returns
    -------
    dict

    Examples
    --------
    >>> import numpy as np
    >>> got = relay_samples({(1, 4): np.array([2.0]), (0, 4): np.array([1.0])}, [np.array([0]), np.array([1])], 4, 4)
    >>> got[4][0].tolist(), got[4][1].tolist()
    ([0, 1], [1.0, 2.0])
    """
    by_t: dict = {}
    for j, t in held:  # one pass over what is held, grouped by event time
        if t_base <= t <= tau:
            by_t.setdefault(t, []).append(j)
    out = {}
    for t in sorted(by_t):
        js = sorted(by_t[t])
        out[t] = (np.concatenate([sensor_rows[j] for j in js]), np.concatenate([held[(j, t)] for j in js]))
    return out


def relay_prune(held: dict, cut: int) -> dict:
    """The samples still wanted: those of event times ``cut`` on (no agent's walk starts before ``tau - D + 1``).

    Parameters
    ----------
    held : dict
        ``{(sensor position, t): y_j(t)}``.
    cut : int
        The first event time kept.

    Returns
    -------
    dict

    Examples
    --------
    >>> relay_prune({(0, 3): 1.0, (0, 4): 2.0}, 4)
    {(0, 4): 2.0}
    """
    return {k: v for k, v in held.items() if k[1] >= cut}


def prediction_update(z_q: np.ndarray, A: np.ndarray, bu: np.ndarray | None = None) -> np.ndarray:
    """No measurement at ``tau``: ``x_i(tau+1) = A z_i(q) [+ B u(tau)]`` (eq. split-discrete-est1 without its
    innovation).

    Parameters
    ----------
    z_q : (n,) ndarray
        ``z_i(q)``, agent i's state after the ``q`` consensus sub-rounds.
    A : (n, n) ndarray
        The system matrix ``A`` (``E = exp(A dt)`` on a sampled model).
    bu : (n,) ndarray or None, optional
        The known input's ``B u(tau)``; None (default): no inputs, nothing added.

    Returns
    -------
    (n,) ndarray
        ``x_i(tau+1)``.
    """
    x = A @ z_q
    return x if bu is None else x + bu


def sampled_step(x_i: np.ndarray, E: np.ndarray, D: np.ndarray, K_i: np.ndarray, C_i: np.ndarray,
                 y_i: np.ndarray | None, P_i: np.ndarray, g_i: float, neighbour_states: Sequence[np.ndarray],
                 weights: Sequence[float], bu: np.ndarray | None = None) -> np.ndarray:
    """One sampled-data step of eq. (split_continuous_observer) (see the module docstring); ``y_i`` None: no
    measurement this step, the innovation term ``K_i (C_i x_i - y_i)`` is left out (prediction and consensus);
    ``bu``: the known input's ``B u(k)``, held over the step (None: no inputs).

    Parameters
    ----------
    x_i : (n,) ndarray
        Agent i's estimate ``x_i(k)``.
    E : (n, n) ndarray
        ``exp(A dt)``.
    D : (n, n) ndarray
        ``int_0^dt exp(A s) ds``.
    K_i : (n, s_i) ndarray
        Agent i's gain ``K_i``.
    C_i : (s_i, n) ndarray
        Agent i's output matrix ``C_i``.
    y_i : (s_i,) ndarray or None
        Agent i's measurement ``y_i(k)``; None: no measurement this step.
    P_i : (n, n) ndarray
        The projection ``P_i = V_i V_i'`` onto agent i's unobservable space.
    g_i : float
        Agent i's coupling gain ``g_i``.
    neighbour_states : sequence of (n,) arrays
        The estimates ``x_j(k)`` of every ``j in N_i``, agent i included.
    weights : sequence of float
        The weights ``w_ij``, in the order of ``neighbour_states``.
    bu : (n,) ndarray or None, optional
        The known input's ``B u(k)``; None (default): no inputs.

    Returns
    -------
    (n,) ndarray
        ``x_i(k+1)``.
    """
    avg = weighted_average(neighbour_states, weights)
    corr = -g_i * (P_i @ (x_i - avg))
    if y_i is not None:
        corr = K_i @ (C_i @ x_i - y_i) + corr
    if bu is not None:
        corr = corr + bu
    return E @ x_i + D @ corr


def adaptive_gain_rate(V_i: np.ndarray, x_i: np.ndarray, neighbour_states: Sequence[np.ndarray],
                       weights: Sequence[float]) -> float:
    """Eq. (adaptive): ``dg_i/dt = |V_i' sum_j w_ij (x_j - x_i)|_2^2``.

    Parameters
    ----------
    V_i : (n, n - r_i) ndarray
        Orthonormal basis ``V_i`` of agent i's unobservable space.
    x_i : (n,) ndarray
        Agent i's estimate ``x_i``.
    neighbour_states : sequence of (n,) arrays
        The estimates ``x_j`` of every ``j in N_i``, agent i included.
    weights : sequence of float
        The weights ``w_ij``, in the order of ``neighbour_states``; they sum to 1, so
        ``sum_j w_ij x_j - x_i = sum_j w_ij (x_j - x_i)``.

    Returns
    -------
    float
        ``dg_i/dt`` (non-negative).
    """
    diff = weighted_average(neighbour_states, weights) - x_i
    v = V_i.T @ diff
    return float(v @ v)


def adaptive_gain_step(g_i: float, rate: float, dt: float) -> float:
    """Forward-Euler step of eq. (adaptive).

    Parameters
    ----------
    g_i : float
        Agent i's gain ``g_i(k)``.
    rate : float
        ``dg_i/dt`` at step k (:func:`adaptive_gain_rate`).
    dt : float
        The step, in seconds.

    Returns
    -------
    float
        ``g_i(k+1) = g_i(k) + dt * rate``.
    """
    return g_i + dt * rate


def step_matrices(A: np.ndarray, K_i: np.ndarray, C_i: np.ndarray, *, dt: float | None = None,
                  sampled: tuple | None = None) -> tuple:
    """``(A_s, F_i, K_s, G)``: one event time of the whole-state estimator (module docstring) on the per-step model.

    Discrete (``dt`` None): ``(A, A + K_i C_i, K_i, None)``.  Continuous, sampled with ``dt``:
    ``(E, E + (D K_i) C_i, D K_i, D)`` with ``E = exp(A dt)``, ``D = int_0^dt exp(A s) ds``
    (``sampled``: ``(E, D)`` already computed by :func:`sampled_data_matrices`, the same floats); ``G`` maps the
    known input's ``B u`` to the step's (:func:`step_input`).  The agent processes and the simulator both call this,
    so they hold the same floats.

    Parameters
    ----------
    A : (n, n) array_like
        The system matrix ``A``.
    K_i : (n, s_i) ndarray
        Agent i's gain ``K_i``.
    C_i : (s_i, n) ndarray
        Agent i's output matrix ``C_i``.
    dt : float or None, optional
        The sampling step in seconds; None (default): discrete time.
    sampled : tuple of two (n, n) ndarrays or None, optional
        ``(E, D)`` for ``dt`` already computed; None (default): computed here.

    Returns
    -------
    tuple
        ``(A_s, F_i, K_s, G)``, three (n, n), (n, n), (n, s_i) arrays and ``G`` (n, n) or None (discrete).

    Examples
    --------
    >>> import numpy as np
    >>> A_s, F, K_s, G = step_matrices(np.eye(2), np.array([[-0.5], [0.0]]), np.array([[1.0, 0.0]]))
    >>> F
    array([[0.5, 0. ],
           [0. , 1. ]])
    >>> G is None
    True
    """
    A = np.asarray(A, dtype=float)
    if dt is None:
        return A, A + K_i @ C_i, K_i, None
    E, D = sampled if sampled is not None else sampled_data_matrices(A, dt)[:2]
    K_s = D @ K_i
    return E, E + K_s @ C_i, K_s, D


def step_input(G: np.ndarray | None, bu: np.ndarray | None) -> np.ndarray | None:
    """The known input of one event time of :func:`step_matrices`: ``B u`` itself (discrete), ``D B u`` (continuous:
    ``u`` held over the step); None without inputs.

    Parameters
    ----------
    G : (n, n) ndarray or None
        The ``G`` of :func:`step_matrices` (``D``, continuous; None, discrete).
    bu : (n,) ndarray or None
        The known input's ``B u``; None without inputs.

    Returns
    -------
    (n,) ndarray or None
        ``bu`` (``G`` None), ``G bu`` (continuous), or None when ``bu`` is None.
    """
    return bu if G is None or bu is None else G @ bu


def innovation_test(y_i: np.ndarray, C_i: np.ndarray, z: np.ndarray, S_inv: np.ndarray,
                    threshold: float) -> tuple:
    """The bad-data test of one measurement: ``r_i = y_i - C_i z``, ``d_i = r_i' S_i^-1 r_i``, failed when
    ``d_i > threshold`` (:mod:`splitspec_core.synthesis.bad_data`: ``S_i = C_i Sigma_ii C_i' + R_i``, the threshold
    the chi-square quantile of the false-alarm probability).

    Parameters
    ----------
    y_i : (s_i,) ndarray
        Agent i's measurement ``y_i(tau)``.
    C_i : (s_i, n) ndarray
        Agent i's output matrix.
    z : (n,) ndarray
        The estimate the update applies ``K_i`` to: ``z_i(q)`` (eq. split-discrete-est1; ``C_i z_i(q) = C_i x_i(tau)``),
        or ``x_i(tau)`` (whole-state design, sampled-data form).
    S_inv : (s_i, s_i) ndarray
        ``S_i^-1``, the inverse of the design's innovation covariance.
    threshold : float
        The test's threshold.

    Returns
    -------
    tuple of (float, bool)
        ``(d_i, failed)``.

    Examples
    --------
    >>> import numpy as np
    >>> innovation_test(np.array([3.0]), np.array([[1.0, 0.0]]), np.array([1.0, 5.0]), np.array([[0.25]]), 2.0)
    (1.0, False)
    """
    r = y_i - C_i @ z
    d = float(r @ (S_inv @ r))
    return d, d > threshold


def flatline(y_i: np.ndarray, last: np.ndarray | None) -> bool:
    """A stuck sensor's sign: ``y_i(tau)`` repeats the last measurement the agent was given, bit for bit.

    Under measurement noise with a density (``design.bad_data`` needs ``R_i`` positive definite) two samples are
    equal with probability zero, so the repeat fails the test whatever the chi-square statistic says: a sensor
    holding its last value on a slowly moving signal stays inside the chi-square threshold for many event times
    (issue 37: the IEEE 14-bus PMU angles).

    Parameters
    ----------
    y_i : (s_i,) ndarray
        The measurement of ``tau``.
    last : (s_i,) ndarray or None
        The last measurement given before it (None: none yet in this incarnation).

    Returns
    -------
    bool
        True if ``y_i`` equals ``last`` exactly.

    Examples
    --------
    >>> import numpy as np
    >>> flatline(np.array([1.0, 2.0]), np.array([1.0, 2.0])), flatline(np.array([1.0, 2.0]), None)
    (True, False)
    """
    return last is not None and np.array_equal(y_i, last)


def warmup_step(seen: int, measured: bool, warmup: int) -> tuple:
    """One event time of an agent's warm-up: its first ``warmup`` measurements since its admission are used untested
    (:mod:`splitspec_core.synthesis.bad_data`), counted in measurements, not event times: a sensor that starts late
    (a live sensor started after the run, a recorded file whose first rows are empty) finds its agent's estimate
    unsettled, whatever the clock says.

    Parameters
    ----------
    seen : int
        The agent's measurements since its admission so far (at most ``warmup``).
    measured : bool
        It has a measurement at this event time.
    warmup : int
        ``BadData.warmup``.

    Returns
    -------
    tuple of (int, bool)
        ``(seen, tested)`` after this event time: ``tested``, the measurement is tested.

    Examples
    --------
    >>> warmup_step(0, False, 2), warmup_step(0, True, 2), warmup_step(1, True, 2), warmup_step(2, True, 2)
    ((0, False), (1, False), (2, False), (2, True))
    """
    if not measured:
        return seen, False
    if seen < warmup:
        return seen + 1, False
    return seen, True


def sensor_watch(suspect: bool, run: int, failed: bool | None, k: int) -> tuple:
    """One event time of a sensor's watch: ``k`` failed tests in a row make it suspect, ``k`` clean tests in a row
    (while suspect) restore it; an event time without a measurement (``failed`` None) changes nothing.

    Parameters
    ----------
    suspect : bool
        The sensor is suspect at the start of the event time (its measurement is not used in it).
    run : int
        The failures in a row so far (not suspect), or the clean tests in a row (suspect).
    failed : bool or None
        This event time's test; None: no measurement, no test.
    k : int
        ``design.bad_data.suspect_after``.

    Returns
    -------
    tuple of (bool, int, str or None)
        ``(suspect, run, event)`` after this event time; ``event`` is ``"sensor_suspect"``, ``"sensor_restored"`` or
        None.

    Examples
    --------
    >>> sensor_watch(False, 2, True, 3), sensor_watch(True, 2, False, 3), sensor_watch(False, 2, False, 3)
    ((True, 0, 'sensor_suspect'), (False, 0, 'sensor_restored'), (False, 0, None))
    """
    if failed is None:
        return suspect, run, None
    if not suspect:
        run = run + 1 if failed else 0
        return (True, 0, "sensor_suspect") if run >= k else (False, run, None)
    run = 0 if failed else run + 1
    return (False, 0, "sensor_restored") if run >= k else (True, run, None)
