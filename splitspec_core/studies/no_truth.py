"""When there is no truth: what can be known about the estimates of a run on the user's own measurements.

Without ``x`` the error ``|x_i - x|`` cannot be shown, and nothing shows a made-up one.  Instead
(:func:`no_truth_arrays`, written to ``trajectory.npz`` and shown by the plots and the recording):

``residual`` (T, m)
    ``|y_i(tau) - C_i x_i(tau)|_2``: how far agent i's estimate is from explaining its own measurement
    (the innovation of eq. split-discrete-est1 / the sampled-data step); NaN where the agent is dead or
    has no measurement.  With noise it settles at the measurement noise's level, not at zero.
``disagreement`` (T,)
    ``max_ij |x_i(tau) - x_j(tau)|_2`` over the alive agents: consensus, which must go to zero
    (to the noise level) for every agent to hold the whole state.
``kf`` (T, n) and ``kf_distance`` (T, m)
    the centralized Kalman filter on the same measurements (every agent's ``y_i`` at once: the best any
    estimator can do with them, a one-step predictor like the agents' ``x_i(tau)``), and
    ``|x_i(tau) - kf(tau)|_2``: the distance to that reference instead of the error to the truth.
    Time-varying (rows without a measurement are left out of that step's update), started at the
    scenario's ``x0`` (covariance 0) or at 0 with covariance ``I`` (the prior the simulator draws
    ``x(0)`` from); ``Q``, ``R`` from the scenario's noise levels (:func:`baselines.sampled_model`),
    regularised when zero (:func:`baselines.regularise`).
"""

from __future__ import annotations

import numpy as np

from .baselines import regularise, sampled_model
from ..model.plant import input_sequence, output_rows

__all__ = ["no_truth_arrays", "residuals", "disagreement", "kalman_reference", "held_inputs"]


def residuals(xhat: np.ndarray, y: np.ndarray, missing: np.ndarray, Cs) -> np.ndarray:
    """``|y_i - C_i x_i|`` per step and agent, (T, m); NaN where dead (NaN estimate) or missing.

    Parameters
    ----------
    xhat : (T, m, n) array
        Every agent's estimate (NaN rows: dead).
    y : (T, sum s_i) array
        The stacked measurements, agents in the order of ``Cs``.
    missing : (T, m) bool array
        True where agent i had no measurement.
    Cs : sequence of (s_i, n) arrays
        The agents' output matrices.

    Returns
    -------
    (T, m) array
        The residual norms.

    Examples
    --------
    >>> xhat = np.array([[[0.0, 0.0], [1.0, 0.0]], [[1.0, 1.0], [np.nan, np.nan]]])
    >>> residuals(xhat, np.array([[0.5, 0.0], [1.0, 1.0]]), np.array([[False, False], [False, True]]),
    ...           [np.array([[1.0, 0.0]]), np.array([[0.0, 1.0]])]).tolist()
    [[0.5, 0.0], [0.0, nan]]
    """
    T, m, _ = xhat.shape
    out = np.full((T, m), np.nan)
    for k, (C, r) in enumerate(zip(Cs, output_rows(Cs))):
        pred = xhat[:, k, :] @ np.asarray(C).T
        out[:, k] = np.linalg.norm(y[:, r] - pred, axis=1)
    out[missing] = np.nan
    return out


def disagreement(xhat: np.ndarray) -> np.ndarray:
    """``max_ij |x_i - x_j|`` over the agents alive (finite estimates) at each step, (T,); NaN with none alive.

    Parameters
    ----------
    xhat : (T, m, n) array
        Every agent's estimate (NaN rows: dead).

    Returns
    -------
    (T,) array
        The largest pairwise distance per step (0 with one agent alive).

    Examples
    --------
    >>> disagreement(np.array([[[0.0, 0.0], [1.0, 0.0]], [[1.0, 1.0], [np.nan, np.nan]]])).tolist()
    [1.0, 0.0]
    """
    T = xhat.shape[0]
    out = np.full(T, np.nan)
    for k in range(T):
        X = xhat[k][np.isfinite(xhat[k]).all(axis=1)]
        if len(X) == 0:
            continue
        # differences, not the Gram matrix (|a|^2 + |b|^2 - 2ab cancels: 1e-8 where the estimates agree to 1e-15)
        chunk = max(1, int(1e6 // max(1, X.size)))
        best = 0.0
        for a in range(0, len(X), chunk):
            best = max(best, float(np.max(np.linalg.norm(X[a:a + chunk, None, :] - X[None, :, :], axis=2))))
        out[k] = best
    return out


def kalman_reference(sc, y: np.ndarray, missing: np.ndarray, u: np.ndarray | None = None) -> np.ndarray:
    """The centralized time-varying Kalman predictor on ``y`` (module docstring), (T, n); with known inputs it adds
    ``G u(k)`` (``u``: the recorded inputs per row, else the scenario's signal).

    Parameters
    ----------
    sc : Scenario
        The scenario (model, noise levels, ``system.x0``).
    y : (T, sum s_i) array
        The stacked measurements.
    missing : (T, m) bool array
        True where agent i had no measurement (its rows are left out of that step's update).
    u : (T, inputs) array, optional
        The recorded known inputs.

    Returns
    -------
    (T, n) array
        The one-step predictions ``kf(tau)`` of ``x(tau)``, before ``y(tau)`` is used.
    """
    F, Q, R = sampled_model(sc)
    gus = input_sequence(sc, len(y), u)
    Q = regularise(Q)
    R = regularise(R)
    C = np.vstack([np.asarray(c) for c in sc.system.Cs])
    rows = output_rows(sc.system.Cs)
    n = sc.n
    if sc.system.x0 is not None:
        x, P = np.asarray(sc.system.x0, dtype=float), regularise(np.zeros((n, n)))
    else:
        x, P = np.zeros(n), np.eye(n)
    T = len(y)
    out = np.zeros((T, n))
    for k in range(T):
        out[k] = x
        use = np.concatenate([np.arange(r.start, r.stop) for r, miss in zip(rows, missing[k]) if not miss] or
                             [np.zeros(0, dtype=int)])
        if use.size:
            Ca = C[use]
            S = Ca @ P @ Ca.T + R[np.ix_(use, use)]
            L = np.linalg.solve(S, Ca @ P @ F.T).T  # F P Ca' S^-1
            x = F @ x + L @ (y[k, use] - Ca @ x)
            P = F @ P @ F.T + Q - L @ S @ L.T
        else:
            x = F @ x
            P = F @ P @ F.T + Q
        if gus is not None:
            x = x + gus[k]
        P = 0.5 * (P + P.T)
    return out


def held_inputs(u: np.ndarray) -> np.ndarray:
    """``u`` (T, p) with every row that is not finite (no agent used one: none alive, a run's last row) holding
    the last finite row before it, zero before the first: what an agent holds when it takes no new ``u``.

    Parameters
    ----------
    u : (T, p) array_like
        Recorded known inputs (a run's ``u``), NaN where none was taken.

    Returns
    -------
    (T, p) ndarray
        A new array, finite everywhere; its finite rows are those of ``u``.

    Examples
    --------
    >>> held_inputs(np.array([[np.nan], [2.0], [np.nan], [3.0]])).ravel().tolist()
    [0.0, 2.0, 2.0, 3.0]
    """
    u = np.array(u, dtype=float)
    last = np.zeros(u.shape[1:])
    for k in range(len(u)):
        if np.isfinite(u[k]).all():
            last = u[k]
        else:
            u[k] = last
    return u


def no_truth_arrays(traj, sc, u: np.ndarray | None = None) -> dict:
    """``residual``, ``disagreement``, ``kf`` and ``kf_distance`` of a trajectory that holds its measurements
    (``u``: the inputs the estimators used, a run's recorded ``u`` or a measurements file's, NaN rows held
    (:func:`held_inputs`); None: the scenario's signal applies).

    Parameters
    ----------
    traj : Trajectory
        A run's or simulation's trajectory with ``y`` (and ``y_missing``, ``alive``, ``xhat``).
    sc : Scenario
        Its scenario.
    u : (T, inputs) array, optional
        The recorded known inputs.

    Returns
    -------
    dict
        ``residual`` (T, m), ``disagreement`` (T,), ``kf`` (T, n; NaN with live known inputs and no recorded
        ``u``, as in a run recorded before runs recorded it) and ``kf_distance`` (T, m).

    Raises
    ------
    ValueError
        The trajectory holds no measurements (``traj.y`` is None).
    """
    if traj.y is None:
        raise ValueError("no_truth_arrays needs the measurements the estimators were given (trajectory y)")
    missing = traj.y_missing if traj.y_missing is not None else np.zeros(traj.alive.shape, dtype=bool)
    if u is None and sc.input_source is not None:
        # live known inputs without the u the agents took: the filter is not shown (NaN) rather than run with a u
        # it did not have
        kf = np.full((len(traj.y), sc.n), np.nan)
    else:
        kf = kalman_reference(sc, traj.y, missing, None if u is None else held_inputs(u))
    return {"residual": residuals(traj.xhat, traj.y, missing, sc.system.Cs),
            "disagreement": disagreement(traj.xhat),
            "kf": kf,
            "kf_distance": np.linalg.norm(traj.xhat - kf[:, None, :], axis=2)}
