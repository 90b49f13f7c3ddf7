"""The true system and the initial values, shared by the simulator, the plant process and the agents.

Everything here draws from the named seed streams of :mod:`splitspec_core.model.streams`, so the
batch simulator (:mod:`splitspec_core.simulation.simulator`), the plant process and every agent process
produce the same numbers for the same scenario and seed:

- ``x(0)`` (n,): :func:`initial_state`, the scenario's ``x0`` or the ``initial_state`` stream;
- ``x_i(0)`` (n,): :func:`initial_estimate`, agent i's initial estimate (per incarnation);
- ``x(k+1) = A x(k) + B u(k) + v(k)``, ``y_i(k) = C_i x(k) + w_i(k)``: :class:`Plant` (continuous time: the
  system sampled with ``dt``, ``u`` held over the step, noise of the exact sampled covariance); ``u(k)``
  (:func:`input_of`) is what every agent adds too (:mod:`splitspec_core.scenarios.inputs`).
"""

from __future__ import annotations

import numpy as np

from . import steps as st
from ..scenarios.inputs import input_at, input_time
from ..scenarios.specs import Scenario
from .streams import stream

__all__ = ["Plant", "advanced", "initial_estimate", "initial_state", "input_matrix", "input_of", "input_period",
           "input_sequence", "measured",
           "output_rows", "psd_sqrt", "sampled_model", "seed_draws"]


def input_period(sc: Scenario) -> float | None:
    """Seconds per step for the input signal's time (``run.dt``, or ``system.sample``), None: event times.

    Parameters
    ----------
    sc : Scenario
        The scenario.

    Returns
    -------
    float or None
        ``run.dt`` (continuous time), else ``system.sample`` (None when the discrete system has no
        sampling period).
    """
    return sc.run.dt if sc.time == "continuous" else sc.system.sample


def input_matrix(sc: Scenario) -> np.ndarray | None:
    """``G`` of the plant's step ``x+ = F x + G u``: ``B`` (discrete), ``int_0^dt exp(A s) ds B`` (continuous, ``u``
    held over the step); None without inputs.

    Parameters
    ----------
    sc : Scenario
        The scenario (its ``system.A``, ``system.B``, ``time`` and ``run.dt``).

    Returns
    -------
    (n, r) ndarray or None
        ``G``; None when ``system.B`` is None.
    """
    if sc.system.B is None:
        return None
    if sc.time == "continuous":
        _, D, _ = st.sampled_data_matrices(sc.system.A, sc.run.dt)
        return D @ np.asarray(sc.system.B)
    return np.array(sc.system.B)


def input_sequence(sc: Scenario, steps: int, u: np.ndarray | None = None) -> np.ndarray | None:
    """``G u(k)`` for ``k = 0 .. steps - 1`` (steps, n): a recorded ``u`` (rows per step) or the scenario's signal;
    None without inputs.  What the baselines' and the reference's predictions add, as the plant does.

    Parameters
    ----------
    sc : Scenario
        The scenario.
    steps : int
        The number of steps.
    u : (steps, r) array_like or None, optional
        Recorded inputs, one row per step (only the first ``steps`` rows are used); None (default):
        the scenario's signal :func:`input_of`.

    Returns
    -------
    (steps, n) ndarray or None
        Row k is ``G u(k)``; None when the scenario has no inputs.
    """
    G = input_matrix(sc)
    if G is None:
        return None
    us = np.asarray(u, dtype=float)[:steps] if u is not None else np.array([input_of(sc, k) for k in range(steps)])
    return us.reshape(steps, -1) @ G.T


def input_of(sc: Scenario, k: int) -> np.ndarray | None:
    """``u(k)`` of the scenario's signal (zero without ``system.u``), None without inputs (no ``system.B``).

    Parameters
    ----------
    sc : Scenario
        The scenario.
    k : int
        The step (its time is ``k`` times :func:`input_period`).

    Returns
    -------
    (r,) ndarray or None
        ``u(k)``; zeros when ``system.u`` is None; None when ``system.B`` is None.
    """
    if sc.system.B is None:
        return None
    if sc.system.u is None:
        return np.zeros(sc.system.inputs)
    return input_at(sc.system.u, input_time(k, input_period(sc)))


def output_rows(Cs) -> list:
    """``[slice of y_i in the stacked y = (y_1, ..., y_m)]`` in agent order (``C = [C_1; ...; C_m]``).

    Parameters
    ----------
    Cs : sequence of (s_i, n) array_like
        The agents' output matrices ``C_i``, in agent order.

    Returns
    -------
    list of slice
        Agent i's rows of the stacked ``y``.

    Examples
    --------
    >>> import numpy as np
    >>> output_rows([np.ones((1, 3)), np.ones((2, 3))])
    [slice(0, 1, None), slice(1, 3, None)]
    """
    offsets = np.cumsum([0] + [np.shape(C)[0] for C in Cs])
    return [slice(int(a), int(b)) for a, b in zip(offsets[:-1], offsets[1:])]


def initial_state(sc: Scenario, seed: int) -> np.ndarray:
    """``x(0)``: the scenario's ``x0`` or ``n`` standard normals from the ``initial_state`` stream.

    Parameters
    ----------
    sc : Scenario
        The scenario (its ``system.x0`` and ``n``).
    seed : int
        The run's seed.

    Returns
    -------
    (n,) ndarray
        ``x(0)``.
    """
    if sc.system.x0 is not None:
        return np.array(sc.system.x0, dtype=float)
    return stream(seed, "initial_state").normal(size=sc.n)


def initial_estimate(n: int, seed: int, agent_index: int, incarnation: int = 0) -> np.ndarray:
    """``x_i(0)`` of an agent's given incarnation (0 at start, +1 per restart): ``n`` standard normals.

    Parameters
    ----------
    n : int
        The state dimension.
    seed : int
        The run's seed.
    agent_index : int
        The agent's index in agent order (0-based).
    incarnation : int, optional
        The agent's incarnation (default 0: the first start).

    Returns
    -------
    (n,) ndarray
        ``x_i(0)``, from the ``estimate`` stream of ``(seed, agent_index, incarnation)``.
    """
    return stream(seed, "estimate", agent_index, incarnation).normal(size=n)



def measured(C: np.ndarray, sigma_m: float | np.ndarray, x: np.ndarray, w: np.ndarray) -> np.ndarray:
    """``y = C x + sigma_m w``: the stacked outputs of state ``x`` (n,) or of a batch of states (n, N).

    ``sigma_m``: one std for every output (a float: exactly ``C @ x + sigma_m * w``), or one per output (p,)
    (``System.measurement_std``), applied to each row of ``w`` (p,) or (p, N).

    Parameters
    ----------
    C : (p, n) ndarray
        The stacked output matrix ``C = [C_1; ...; C_m]``.
    sigma_m : float or (p,) ndarray
        The measurement noise std, one for all outputs or one per output.
    x : (n,) or (n, N) ndarray
        The state, or N states as columns.
    w : (p,) or (p, N) ndarray
        Standard normal draws, shaped like ``C @ x``.

    Returns
    -------
    (p,) or (p, N) ndarray
        ``y``.

    Examples
    --------
    >>> import numpy as np
    >>> measured(np.array([[1.0, 0.0], [0.0, 2.0]]), np.array([0.1, 1.0]), np.array([1.0, 1.0]), np.ones(2))
    array([1.1, 3. ])
    """
    if np.ndim(sigma_m) == 0:
        return C @ x + sigma_m * w
    return C @ x + (sigma_m if np.ndim(w) == 1 else sigma_m[:, None]) * w


def advanced(F: np.ndarray, L: np.ndarray, x: np.ndarray, v: np.ndarray, gu: np.ndarray | None = None) -> np.ndarray:
    """``x+ = F x + L v [+ G u]``: one step of the plant from ``x`` (n,) or a batch of states (n, N); ``gu`` the
    known input's ``G u`` (``B u``, or ``D B u`` sampled), None without inputs.

    Parameters
    ----------
    F : (n, n) ndarray
        The step's state matrix (``A`` or ``exp(A dt)``).
    L : (n, n) ndarray
        The noise input, ``L L'`` the process-noise covariance per step.
    x : (n,) or (n, N) ndarray
        The state, or N states as columns.
    v : (n,) or (n, N) ndarray
        Standard normal draws, shaped like ``x``.
    gu : (n,) ndarray or None, optional
        The known input's ``G u``; None (default): no inputs.

    Returns
    -------
    (n,) or (n, N) ndarray
        ``x+``.
    """
    x = F @ x + L @ v
    return x if gu is None else x + gu

class Plant:
    """The true system and its measurements, drawing noise from the named streams.

    ``x(k+1) = F x(k) + L v`` with ``v`` standard normal (n,) and ``L L'`` the covariance per step: discrete,
    ``F = A`` and ``L = sigma_p I`` (``process_noise`` a number, the std ``sigma_p``), ``diag(v)`` (a vector of
    stds) or :func:`psd_sqrt` of the covariance matrix; continuous (sampled with ``dt``), ``F = exp(A dt)`` and
    ``L`` a square root of ``Qd``, the exact covariance over a step of white noise of intensity ``process_noise``
    (``q I``, ``diag(v)`` or the matrix: ``E[v(t) v(s)'] = Qc delta(t - s)``), by Cholesky for a number as always,
    by :func:`psd_sqrt` otherwise.  Measurements ``y = C x(k) + sigma_m w`` (``sigma_m`` a number, or one std
    per output: ``System.measurement_std``) are drawn for every agent every step, stacked in agent order
    (``C = [C_1; ...; C_m]``).
    """

    def __init__(self, sc: Scenario, seed: int, *, noise: bool = True):
        self.Cs = [np.asarray(C) for C in sc.system.Cs]
        self.C = np.vstack(self.Cs)
        self.rows = output_rows(self.Cs)
        s = sc.system
        scalar_m = not isinstance(s.measurement_noise, dict)
        self.sigma_m = (s.measurement_noise if scalar_m else s.measurement_std) if noise else 0.0
        sigma_p = s.process_noise if noise else 0.0
        scalar_p = np.ndim(sigma_p) == 0
        if sc.time == "continuous":
            E, _, Qd = st.sampled_data_matrices(s.A, sc.run.dt,
                                                noise_intensity=sigma_p if scalar_p else s.process_covariance)
            self.F = E
            self.L = _psd_sqrt(Qd) if scalar_p else psd_sqrt(Qd)
        else:
            self.F = np.array(s.A)
            if scalar_p:
                self.L = sigma_p * np.eye(sc.n)
            elif np.ndim(sigma_p) == 1:
                self.L = np.diag(np.asarray(sigma_p, dtype=float))  # the stds: L L' = diag(v^2)
            else:
                self.L = psd_sqrt(s.process_covariance)
        self.G = input_matrix(sc)  # x+ = F x + G u (u held over a continuous step: zero-order hold)
        self.sc = sc
        self.k = 0
        self.proc = stream(seed, "process")
        self.meas = stream(seed, "measurement")
        self.x = initial_state(sc, seed)

    def input(self) -> np.ndarray | None:
        """``u(k)`` at the current step (None: the scenario has no inputs).

        Returns
        -------
        (r,) ndarray or None
            ``u(k)`` of :func:`input_of` at the plant's step ``k``.
        """
        return input_of(self.sc, self.k)

    def measure(self) -> np.ndarray:
        """Stacked ``y(k) = (y_1(k), ..., y_m(k))`` (one noise draw of ``sum s_i`` normals).

        Returns
        -------
        (p,) ndarray
            ``y(k) = C x(k) + sigma_m w``, ``p = sum s_i``.
        """
        return measured(self.C, self.sigma_m, self.x, self.meas.normal(size=self.C.shape[0]))

    def split(self, y: np.ndarray) -> list:
        """``[y_1, ..., y_m]`` from the stacked vector.

        Parameters
        ----------
        y : (p,) ndarray
            The stacked measurement.

        Returns
        -------
        list of ndarray
            ``y_i`` (s_i,) per agent, in agent order.
        """
        return [y[r] for r in self.rows]

    def advance(self) -> np.ndarray:
        """One step of the plant: ``x(k+1) = F x(k) + L v(k) [+ G u(k)]`` (one draw of ``n`` normals); ``k`` += 1.

        Returns
        -------
        (n,) ndarray
            The new state ``x(k+1)`` (also ``self.x``).
        """
        u = self.input()
        self.x = advanced(self.F, self.L, self.x, self.proc.normal(size=self.x.shape[0]),
                          None if u is None else self.G @ u)
        self.k += 1
        return self.x

    def missing(self) -> None:
        """Every agent measures every step."""
        return None


def seed_draws(sc: Scenario, seeds, steps: int, *, noise: bool = True) -> tuple:
    """Every seed's plant for a run of ``steps`` steps at once, for the batched Monte Carlo paths.

    Returns ``(plant, x0, v, w)``: ``plant`` the first seed's :class:`Plant` (its ``F``, ``L``, ``C``,
    ``sigma_m`` (a number, or one std per output) and ``rows`` are every seed's), ``x0`` (n, N) the initial
    states, ``v`` (steps, n, N) and
    ``w`` (steps, sum s_i, N) the process and measurement draws, so that step k is ``y = measured(C, sigma_m,
    x, w[k])`` then ``x = advanced(F, L, x, v[k])``, as :class:`Plant` runs it.  Each stream's draws for the
    whole run at once are the same numbers as one step at a time (a stream's ``normal(size=(T, n))`` is its
    ``T`` successive ``normal(size=n)`` draws), so every seed's realisation is :class:`Plant`'s, bit for bit.

    Parameters
    ----------
    sc : Scenario
        The scenario.
    seeds : sequence of int
        The N seeds.
    steps : int
        The number of steps drawn.
    noise : bool, optional
        Draw noise scaled by the scenario's stds (default True); False: the plants' ``L`` and
        ``sigma_m`` are zero (the draws are still made).

    Returns
    -------
    plant : Plant
        The first seed's plant.
    x0 : (n, N) ndarray
        The initial states.
    v : (steps, n, N) ndarray
        The process draws.
    w : (steps, p, N) ndarray
        The measurement draws, ``p = sum s_i``.
    """
    plants = [Plant(sc, s, noise=noise) for s in seeds]
    n, p = sc.n, plants[0].C.shape[0]
    x0 = np.stack([pl.x for pl in plants], axis=1)
    v = np.stack([pl.proc.normal(size=(steps, n)) for pl in plants], axis=2)
    w = np.stack([pl.meas.normal(size=(steps, p)) for pl in plants], axis=2)
    return plants[0], x0, v, w


def psd_sqrt(Q: np.ndarray) -> np.ndarray:
    """A square root ``L`` (``L L' = Q``) of a symmetric positive semidefinite ``Q`` (n, n), singular ones included:
    the symmetric root ``U diag(sqrt(max(w, 0))) U'`` of the eigendecomposition ``Q = U diag(w) U'`` (numpy only:
    the plant process of a discrete scenario loads no scipy).

    Parameters
    ----------
    Q : (n, n) ndarray
        A symmetric positive semidefinite matrix (its symmetric part is used; negative eigenvalues
        are clipped to zero).

    Returns
    -------
    (n, n) ndarray
        The symmetric square root ``L``.

    Examples
    --------
    >>> import numpy as np
    >>> psd_sqrt(np.diag([4.0, 0.0]))
    array([[2., 0.],
           [0., 0.]])
    """
    w, U = np.linalg.eigh(0.5 * (Q + Q.T))
    return (U * np.sqrt(np.clip(w, 0.0, None))) @ U.T


def _psd_sqrt(Q: np.ndarray) -> np.ndarray:
    """The plant's root of a scalar intensity's ``Qd`` (Cholesky; eigenvalues when it is singular), as ever."""
    if not np.any(Q):
        return np.zeros_like(Q)
    try:
        return np.linalg.cholesky(Q)
    except np.linalg.LinAlgError:
        w, U = np.linalg.eigh(Q)
        return U * np.sqrt(np.clip(w, 0, None))


class RecordedPlant:
    """The plant of a measurements file (:mod:`splitspec_core.scenarios.measurements`): row ``k`` of ``y`` at step ``k``.

    The same interface as :class:`Plant`: ``x`` is the file's truth at that row (NaN when it has none),
    ``measure()`` the stacked ``y`` row, ``missing()`` which agents have no measurement there.
    """

    def __init__(self, meas, n: int, sc: Scenario | None = None):
        self.meas = meas
        self.sc = sc
        self.k = 0
        self._nan = np.full(n, np.nan)

    def input(self) -> np.ndarray | None:
        """The file's ``u`` row when it has ``u`` columns, else the scenario's signal (None: no inputs).

        Returns
        -------
        (r,) ndarray or None
            The input at the current row ``k``.
        """
        if self.meas.u is not None:
            return self.meas.u[self.k]
        return None if self.sc is None else input_of(self.sc, self.k)

    @property
    def x(self) -> np.ndarray:
        """The file's true state at the current row (n,) ndarray, all NaN when the file has no truth."""
        return self.meas.x[self.k] if self.meas.x is not None else self._nan

    def measure(self) -> np.ndarray:
        """The stacked measurement of the current row.

        Returns
        -------
        (p,) ndarray
            Row ``k`` of the file's stacked ``y`` (0.0 where missing).
        """
        return self.meas.y[self.k]

    def missing(self) -> np.ndarray:
        """Which agents have no measurement at the current row.

        Returns
        -------
        (m,) ndarray of bool
            Row ``k`` of the file's ``missing`` mask, True for an agent without a measurement.
        """
        return self.meas.missing[self.k]

    def advance(self) -> np.ndarray:
        """Move to the next row.

        Returns
        -------
        (n,) ndarray
            The true state of the new row (:attr:`x`).
        """
        self.k += 1
        return self.x


def sampled_model(sc: Scenario) -> tuple:
    """``(F, Q, R)``: the discrete model the plant of the scenario follows, per step.

    Parameters
    ----------
    sc : Scenario

    Returns
    -------
    F : (n, n) array
        ``A`` (discrete) or ``exp(A dt)`` (continuous, sampled with ``run.dt``).
    Q : (n, n) array
        ``L L'`` with ``L`` the plant's noise input, computed by :class:`Plant`
        itself: ``System.process_covariance`` (discrete: ``sigma_p^2 I``, ``diag(v^2)`` or the matrix) or the
        exact ``Qd`` over a step of white noise of intensity ``System.process_covariance`` (continuous).
    R : (p, p) array
        ``System.measurement_covariance``: ``diag`` of every output's variance (``sigma_m^2 I`` for one std),
        ``p = sum s_i``, block diagonal per agent (``System.measurement_covariances``).
    """
    plant = Plant(sc, 0)  # the plant's own F and L: no second copy of its formulas
    F = np.array(plant.F, dtype=float)
    Q = plant.L @ plant.L.T
    Q = 0.5 * (Q + Q.T)
    R = sc.system.measurement_covariance
    return F, Q, R
