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
    """Seconds per step for the input signal's time (``run.dt``, or ``system.sample``), None: event times."""
    return sc.run.dt if sc.time == "continuous" else sc.system.sample


def input_matrix(sc: Scenario) -> np.ndarray | None:
    """``G`` of the plant's step ``x+ = F x + G u``: ``B`` (discrete), ``int_0^dt exp(A s) ds B`` (continuous, ``u``
    held over the step); None without inputs."""
    if sc.system.B is None:
        return None
    if sc.time == "continuous":
        _, D, _ = st.sampled_data_matrices(sc.system.A, sc.run.dt)
        return D @ np.asarray(sc.system.B)
    return np.array(sc.system.B)


def input_sequence(sc: Scenario, steps: int, u: np.ndarray | None = None) -> np.ndarray | None:
    """``G u(k)`` for ``k = 0 .. steps - 1`` (steps, n): a recorded ``u`` (rows per step) or the scenario's signal;
    None without inputs.  What the baselines' and the reference's predictions add, as the plant does."""
    G = input_matrix(sc)
    if G is None:
        return None
    us = np.asarray(u, dtype=float)[:steps] if u is not None else np.array([input_of(sc, k) for k in range(steps)])
    return us.reshape(steps, -1) @ G.T


def input_of(sc: Scenario, k: int) -> np.ndarray | None:
    """``u(k)`` of the scenario's signal (zero without ``system.u``), None without inputs (no ``system.B``)."""
    if sc.system.B is None:
        return None
    if sc.system.u is None:
        return np.zeros(sc.system.inputs)
    return input_at(sc.system.u, input_time(k, input_period(sc)))


def output_rows(Cs) -> list:
    """``[slice of y_i in the stacked y = (y_1, ..., y_m)]`` in agent order (``C = [C_1; ...; C_m]``)."""
    offsets = np.cumsum([0] + [np.shape(C)[0] for C in Cs])
    return [slice(int(a), int(b)) for a, b in zip(offsets[:-1], offsets[1:])]


def initial_state(sc: Scenario, seed: int) -> np.ndarray:
    """``x(0)``: the scenario's ``x0`` or ``n`` standard normals from the ``initial_state`` stream."""
    if sc.system.x0 is not None:
        return np.array(sc.system.x0, dtype=float)
    return stream(seed, "initial_state").normal(size=sc.n)


def initial_estimate(n: int, seed: int, agent_index: int, incarnation: int = 0) -> np.ndarray:
    """``x_i(0)`` of an agent's given incarnation (0 at start, +1 per restart): ``n`` standard normals."""
    return stream(seed, "estimate", agent_index, incarnation).normal(size=n)



def measured(C: np.ndarray, sigma_m: float | np.ndarray, x: np.ndarray, w: np.ndarray) -> np.ndarray:
    """``y = C x + sigma_m w``: the stacked outputs of state ``x`` (n,) or of a batch of states (n, N).

    ``sigma_m``: one std for every output (a float: exactly ``C @ x + sigma_m * w``), or one per output (p,)
    (``System.measurement_std``), applied to each row of ``w`` (p,) or (p, N)."""
    if np.ndim(sigma_m) == 0:
        return C @ x + sigma_m * w
    return C @ x + (sigma_m if np.ndim(w) == 1 else sigma_m[:, None]) * w


def advanced(F: np.ndarray, L: np.ndarray, x: np.ndarray, v: np.ndarray, gu: np.ndarray | None = None) -> np.ndarray:
    """``x+ = F x + L v [+ G u]``: one step of the plant from ``x`` (n,) or a batch of states (n, N); ``gu`` the
    known input's ``G u`` (``B u``, or ``D B u`` sampled), None without inputs."""
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
        """``u(k)`` at the current step (None: the scenario has no inputs)."""
        return input_of(self.sc, self.k)

    def measure(self) -> np.ndarray:
        """Stacked ``y(k) = (y_1(k), ..., y_m(k))`` (one noise draw of ``sum s_i`` normals)."""
        return measured(self.C, self.sigma_m, self.x, self.meas.normal(size=self.C.shape[0]))

    def split(self, y: np.ndarray) -> list:
        """``[y_1, ..., y_m]`` from the stacked vector."""
        return [y[r] for r in self.rows]

    def advance(self) -> np.ndarray:
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
    the plant process of a discrete scenario loads no scipy)."""
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
        """The file's ``u`` row when it has ``u`` columns, else the scenario's signal (None: no inputs)."""
        if self.meas.u is not None:
            return self.meas.u[self.k]
        return None if self.sc is None else input_of(self.sc, self.k)

    @property
    def x(self) -> np.ndarray:
        return self.meas.x[self.k] if self.meas.x is not None else self._nan

    def measure(self) -> np.ndarray:
        return self.meas.y[self.k]

    def missing(self) -> np.ndarray:
        return self.meas.missing[self.k]

    def advance(self) -> np.ndarray:
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
