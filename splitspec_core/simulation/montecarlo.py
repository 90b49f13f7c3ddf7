"""Monte Carlo: many seeds of one design as one batched computation.

A seed fixes a run's initial state, initial estimates and noise (the named streams of
:mod:`splitspec_core.model.streams`); N seeds of the same design share everything else (the matrices,
the switching signal when it does not depend on the seed, the faults).  So the estimates of all N
runs can be stepped together: the state is ``X`` (m, n, N), seeds on the trailing axis, and every
product of :class:`~splitspec_core.simulation.simulator.BatchEstimator` becomes one product over all seeds
(a sparse ``S @ Z`` with ``n N`` columns, batched ``P_i``, ``A + K_i C_i``, ``K_i`` products).

Per seed the numbers drawn are exactly those of a single-seed :func:`~splitspec_core.simulation.simulator.simulate`
(each seed's streams are opened and drawn in the same order; a stream's ``normal(size=(T, n))`` is
its ``T`` successive ``normal(size=n)`` draws), so a batched run equals ``simulate(des, seed=s)`` for
every seed to round-off, not bit for bit: the batched matrix products sum in another order, and the
discrete sub-rounds run as ``z_i <- z_i + P_i (sum_j w_ij z_j - z_i)`` (eq. split-discrete-p2 as
:func:`~splitspec_core.model.steps.consensus_subround` writes it) where the single-seed lossless path runs
them in unobservable-space coordinates (``w <- c + B w``).  Known inputs (``system.B``,
:mod:`splitspec_core.scenarios.inputs`) are left out of plant and estimators alike: both add the same ``B u``, so the
errors, all that is kept here, do not depend on them (to round-off).

What is batched and what falls back
-----------------------------------
Batched: discrete and continuous time (fixed or adaptive g), noise or not, faults (kill, freeze,
restart, drop_arc, restore_arc, partition, heal, corrupt, repair: they strike every seed at the same step; a
sensor fault's ``noise`` draws each seed's own ``sensor_noise`` stream, as ``simulate`` does), and
switching that does not depend on the seed (constant, periodic, dwell, or random with its own
``switching.seed``).  Per-seed loop over :func:`~splitspec_core.simulation.simulator.simulate` (the same
results, one seed after another), with the reason in :attr:`MonteCarloRuns.fallback`: random
switching drawn from the run's seed, a lossy or late network (``network:``: its losses are drawn per
seed), a replay of recorded losses, measurements from a file (one realisation anyway: only the initial
estimates change with the seed), and the exact ODE.

Memory
------
Nothing of size ``N x T x m x n`` is kept unless trajectories are asked for: per seed and step only
the squared error summed over the alive agents and their number (``2 N T`` floats), from which the
Monte Carlo statistics of :func:`splitspec_core.simulation.metrics.monte_carlo_stats` follow.  Seeds run in
chunks of :data:`CHUNK` (default); a chunk holds its noise draws for the whole run,
``chunk x T x (n + sum s_i)`` float64 (32 seeds x 500 steps x 210 values = 27 MB for m = 200, n = 10),
and a few ``m x n x chunk`` state arrays.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from .metrics import rms_stats, steady_rms
from ..synthesis.design_data import Design
from ..errors import ScenarioError
from ..model.network import NetworkState, make_plan
from ..model.plant import advanced, initial_estimate, measured, seed_draws
from ..model.rows import REPORTED, empty
from .kinds import consensus_matrix, kind_of
from .loop import run_steps
from .simulator import (BatchEstimator, NetworkWeights, Trajectory, realized_step, check_trajectory_memory,
                        simulate, round_columns)

__all__ = ["CHUNK", "MonteCarloRuns", "SeedBatchEstimator", "fallback_reason", "simulate_seeds"]

CHUNK = 32  # seeds per batch: a chunk's state (m n CHUNK float64, 0.5 MB at m = 200, n = 10) stays in cache


@dataclass(frozen=True)
class MonteCarloRuns:
    """The runs of one design over many seeds (``ss.simulate(..., seeds=...)``).

    Attributes
    ----------
    seeds : tuple of int
        The seeds, in the order of every seed axis.
    t : (T,) float
        Event index (discrete) or time (continuous).
    sq_error : (N, T) float
        Per seed and step, ``sum_i |x_i - x|_2^2`` over the alive agents.
    alive_count : (N, T) int
        How many agents were alive (the same for every seed: faults do not depend on it).
    batched : bool
        True when the seeds ran as one batched computation, False for the per-seed loop.
    fallback : str or None
        Why the per-seed loop ran (None when batched).
    trajectories : tuple of Trajectory or None
        Every seed's full trajectory, only when asked for (``trajectories=True``).
    """

    seeds: tuple
    t: np.ndarray
    sq_error: np.ndarray
    alive_count: np.ndarray
    batched: bool
    fallback: str | None = None
    trajectories: tuple | None = None

    def rms(self) -> np.ndarray:
        """RMS error over the alive agents, (N, T): ``sqrt(sq_error / alive_count)``, NaN where none is alive.

        Returns
        -------
        (N, T) ndarray
            The RMS error over the alive agents, per seed and step.
        """
        with np.errstate(invalid="ignore", divide="ignore"):
            return np.where(self.alive_count > 0, np.sqrt(self.sq_error / np.maximum(self.alive_count, 1)), np.nan)

    def steady_rms(self, *, start: int | None = None) -> np.ndarray:
        """Per seed, RMS over agents and steps from ``start`` (default: the last half, as ``compare``), (N,):
        :func:`splitspec_core.simulation.metrics.steady_rms` of ``sq_error`` and ``alive_count``.

        Parameters
        ----------
        start : int or None, optional
            The first step counted; None (default): the last half of the run.

        Returns
        -------
        (N,) ndarray
            The steady-state RMS error of each seed (NaN where no agent is counted).
        """
        return steady_rms(sq_error=self.sq_error, count=self.alive_count, start=start)

    def stats(self, *, tail: float = 0.2) -> dict:
        """The Monte Carlo statistics of :func:`splitspec_core.simulation.metrics.monte_carlo_stats` (same keys, same numbers
        to round-off): per-step mean, std, 10 % and 90 % of the RMS error over seeds, and the steady-state (last
        ``tail`` of the run) and final RMS error, mean and std over seeds.

        Parameters
        ----------
        tail : float, optional
            The fraction of the run, at its end, that the steady-state statistics cover (default 0.2).

        Returns
        -------
        dict
            ``seeds``; ``mean``, ``std``, ``p10``, ``p90`` (T,) arrays; ``steady_rms_mean``,
            ``steady_rms_std``, ``final_rms_mean``, ``final_rms_std`` floats.
        """
        return rms_stats(self.rms(), tail=tail)


def fallback_reason(des: Design, *, lost=None, measurements=None, exact: bool = False) -> str | None:
    """Why N seeds of ``des`` cannot run as one batch (see the module docstring), or None.

    Parameters
    ----------
    des : Design
        The design.
    lost : optional
        Recorded losses to replay (any value but None falls back).
    measurements : optional
        Recorded measurements (any value but None falls back).
    exact : bool, optional
        The exact ODE asked for (default False).

    Returns
    -------
    str or None
        The reason the per-seed loop runs, in words; None when the seeds can run as one batch.
    """
    sc = des.scenario
    if exact:
        return "the exact ODE integrates one seed at a time"
    if measurements is not None:
        return "measurements from a file are one realisation"
    if lost is not None:
        return "a replay of recorded losses"
    if sc.network.impaired:
        return "network: losses and delays are drawn per seed"
    if sc.switching.kind == "random" and sc.switching.seed is None:
        return "random switching drawn from each run's seed"
    from ..synthesis.bad_data import bad_data

    if bad_data(des) is not None:
        return "design.bad_data: each agent's test decides, per seed, which measurements it uses"
    return kind_of(des).seeds_refusal


class SeedBatchEstimator(BatchEstimator):
    """:class:`~splitspec_core.simulation.simulator.BatchEstimator` with a trailing seed axis: state ``X`` (m, n, N)
    (each kind's seeds form, :meth:`.kinds.Kind.seeds_step`).

    Discrete sub-rounds run as eq. (split-discrete-p2) in full coordinates,
    ``Z <- Z + P (S Z - Z)`` (one sparse product with ``n N`` columns, one batched ``P_i`` product); the update
    is eq. (split-discrete-est1).  Continuous time is the sampled-data step of
    :func:`~splitspec_core.model.steps.sampled_step`; the adaptive gains ``g`` are (m, N), one per agent and seed.
    """

    def __init__(self, des: Design, seeds: int):
        super().__init__(des)
        self.N = int(seeds)
        self.kind.for_seeds(self.N)

    def weights(self, rows: dict) -> sp.csr_matrix:
        """``S`` (m x m, sparse): row i holds agent i's weights on its alive neighbours.

        Parameters
        ----------
        rows : dict
            ``{i: (neighbour ids, weights)}`` of the alive agents.

        Returns
        -------
        scipy.sparse.csr_matrix
            ``S`` restricted to the alive agents, in both times and every kind that batches seeds.
        """
        return consensus_matrix(self.sc, rows)

    def step(self, X: np.ndarray, y: np.ndarray, W, alive: np.ndarray, missing=None) -> np.ndarray:
        """One step of every seed; ``W`` one ``S`` for every exchange (lossless).

        Parameters
        ----------
        X : (m, n, N) ndarray
            The estimates, seeds on the trailing axis.
        y : (sum s_i, N) ndarray
            The stacked measurements of every seed.
        W : scipy.sparse.csr_matrix
            :meth:`weights` of the step's network.
        alive : (m,) bool ndarray
            The agents taking part (the same in every seed).
        missing : optional
            Ignored: every agent measures every step here (measurements files fall back to the per-seed loop).

        Returns
        -------
        (m, n, N) ndarray
            The estimates ``x_i(k+1)`` of every seed, zero for the dead agents.
        """
        return self.step_realized(X, y, [W] * self.kind.exchanges, alive)

    def step_realized(self, X: np.ndarray, y: np.ndarray, Ws: list, alive: np.ndarray, missing=None) -> np.ndarray:
        """One step of every seed with one ``S_k`` per exchange (sparse or realized, the same for every seed: a
        partition, never a drawn loss).

        Parameters
        ----------
        X : (m, n, N) ndarray
            The estimates, seeds on the trailing axis.
        y : (sum s_i, N) ndarray
            The stacked measurements of every seed.
        Ws : list
            ``S_k`` per exchange (``q``; one in continuous time), sparse or realized.
        alive : (m,) bool ndarray
            The agents taking part.
        missing : optional
            Ignored (as in :meth:`step`).

        Returns
        -------
        (m, n, N) ndarray
            The estimates ``x_i(k+1)`` of every seed, zero for the dead agents.  With the adaptive gain this
            also advances ``g`` (m, N).
        """
        return self.kind.seeds_step(X, self.kind.Y(y), Ws, alive)


def simulate_seeds(des: Design, seeds, *, steps: int | None = None, noise: bool = True,
                   trajectories: bool = False, chunk: int = CHUNK, lost=None, measurements=None,
                   exact: bool = False, force_loop: bool = False) -> MonteCarloRuns:
    """Run every seed of ``seeds`` on ``des``: one batched computation, or the per-seed loop where a seed changes
    more than the noise and initial values (:func:`fallback_reason`).

    Parameters
    ----------
    des : Design
        The design (:attr:`splitspec_core.api.DesignResult.detail`).
    seeds : iterable of int
        The seeds, at least one.
    steps : int, optional
        Defaults to ``run.steps`` (or the measurements' length).
    noise : bool
        False zeroes process and measurement noise (the draws still happen).
    trajectories : bool
        Also keep every seed's :class:`~splitspec_core.simulation.simulator.Trajectory` (``N`` trajectories in memory:
        checked against this machine's memory first).
    chunk : int
        Seeds per batch.
    lost : (N, 4) int array, or ``(lost, lost_cause)``, optional
        Replay these consensus losses (as :func:`~splitspec_core.simulation.simulator.simulate`); the seeds run
        one after another.
    measurements : Measurements, optional
        Recorded measurements instead of the plant (as :func:`~splitspec_core.simulation.simulator.simulate`);
        the seeds run one after another.
    exact : bool
        Integrate the exact ODE (:func:`~splitspec_core.simulation.simulator.simulate_exact`, noise-free); the
        seeds run one after another.
    force_loop : bool
        Run the per-seed loop even where the batch applies (the reference the batch is tested against).

    Returns
    -------
    MonteCarloRuns
        Per seed and step the squared error over the alive agents; ``sq_error[k]`` equals
        ``nansum(simulate(des, seed=seeds[k]).errors() ** 2, axis=1)`` to round-off.

    Raises
    ------
    ScenarioError
        No seed, ``chunk < 1``, or trajectories that cannot fit in memory.

    Examples
    --------
    >>> import splitspec_core as ss
    >>> des = ss.design(ss.load_scenario("examples/paper_discrete.yaml")).detail
    >>> runs = simulate_seeds(des, range(4), steps=20)
    >>> runs.batched, runs.sq_error.shape
    (True, (4, 21))
    >>> bool(runs.stats()["final_rms_mean"] < 1e-4)
    True
    """
    seeds = tuple(int(s) for s in seeds)
    if not seeds:
        raise ScenarioError("seeds is empty: give at least one seed")
    if chunk < 1:
        raise ScenarioError(f"chunk must be >= 1, got {chunk}")
    sc = des.scenario
    if trajectories and measurements is None:
        check_trajectory_memory(sc, steps, copies=len(seeds), key="steps" if steps is not None else None)
    reason = fallback_reason(des, lost=lost, measurements=measurements, exact=exact)
    if force_loop and reason is None:
        reason = "per-seed loop asked for"
    if reason is not None:
        return _loop(des, seeds, steps=steps, noise=noise, trajectories=trajectories, lost=lost,
                     measurements=measurements, exact=exact, reason=reason)
    parts = [_batch(des, seeds[a:a + chunk], steps=steps, noise=noise, trajectories=trajectories)
             for a in range(0, len(seeds), chunk)]
    trajs = tuple(tr for p in parts for tr in p[3]) if trajectories else None
    return MonteCarloRuns(seeds=seeds, t=parts[0][0], sq_error=np.concatenate([p[1] for p in parts]),
                          alive_count=np.concatenate([p[2] for p in parts]), batched=True, trajectories=trajs)


def _loop(des: Design, seeds: tuple, *, steps, noise, trajectories, lost, measurements, exact, reason):
    """The per-seed loop: :func:`~splitspec_core.simulation.simulator.simulate` (or ``simulate_exact``) once per seed."""
    from .simulator import simulate_exact

    sq, count, kept = [], [], []
    tr = None
    for s in seeds:
        if exact:
            tr = simulate_exact(des, seed=s, steps=steps)
        else:
            tr = simulate(des, seed=s, steps=steps, noise=noise, lost=lost, measurements=measurements)
        e2 = np.linalg.norm(tr.xhat - tr.x[:, None, :], axis=2) ** 2
        sq.append(np.where(tr.alive, e2, 0.0).sum(axis=1))  # NaN stays where the truth is unknown (measurements)
        count.append(tr.alive.sum(axis=1))
        if trajectories:
            kept.append(tr)
    return MonteCarloRuns(seeds=seeds, t=tr.t, sq_error=np.stack(sq), alive_count=np.stack(count), batched=False,
                          fallback=reason, trajectories=tuple(kept) if trajectories else None)


def _batch(des: Design, seeds: tuple, *, steps, noise, trajectories) -> tuple:
    """``(t, sq_error (N, T), alive_count (N, T), trajectories)`` of one chunk of seeds, stepped together.

    The loop of :func:`~splitspec_core.simulation.simulator.simulate` (:func:`~splitspec_core.simulation.loop.run_steps`:
    faults, record, measure, update, advance), with every seed's plant and estimates on a trailing axis.
    """
    sc = des.scenario
    N = len(seeds)
    plan = make_plan(sc, seeds[0], steps)  # the same for every seed here (fallback_reason)
    est = SeedBatchEstimator(des, N)
    m, n, T = sc.m, sc.n, plan.steps + 1
    # x (n, N), v (T-1, n, N), w (T-1, sum s_i, N): each seed's Plant, bit for bit
    plant, x, v, w = seed_draws(sc, seeds, T - 1, noise=noise)
    F, L, C, sigma_m = plant.F, plant.L, plant.C, plant.sigma_m
    X = np.stack([np.stack([initial_estimate(n, s, i) for s in seeds], axis=1) for i in range(m)])  # (m, n, N)
    net = NetworkState(sc, seeds)  # a sensor fault's noise: each seed's own stream, as simulate draws it
    alive = net.alive
    sq = np.zeros((N, T))
    count = np.zeros((N, T), dtype=np.int64)
    if trajectories:
        xs = np.zeros((N, T, n))
        xh = np.full((N, T, m, n), np.nan)
        al = np.zeros((T, m), dtype=bool)
        g = np.full((N, T, m), np.nan)  # g_i(t) per seed (the row schema's g)
        rounds = {c.name: empty(c, T, m, n) for c in REPORTED if c.reported == "round"}  # the same for every seed
        lost_rows: list = []
    impaired = any(f.drops_messages for f in sc.faults)  # the only losses that are the same for every seed
    exchanges = est.kind.exchanges
    weights = NetworkWeights(est, sc)

    def restart(killed, rejoined):
        for i in killed:
            X[i] = 0.0
        for i, inc in rejoined:
            X[i] = np.stack([initial_estimate(n, s, i, inc) for s in seeds], axis=1)
            est.kind.restart(i)

    def record(k):
        e2 = np.einsum("ijs,ijs->is", X - x[None], X - x[None])  # (m, N)
        sq[:, k] = e2[alive].sum(axis=0)
        count[:, k] = int(alive.sum())
        if trajectories:
            xs[:, k] = x.T
            xh[:, k, alive] = X[alive].transpose(2, 0, 1)
            al[k] = alive
            gains = est.kind.gains()
            if gains is not None:
                g[:, k, alive] = gains[alive].T

    def update(k, y):
        nonlocal X
        W = weights(net, plan.graph_seq[k])
        before = len(lost_rows) if trajectories else 0
        Ws = realized_step(est, sc, W, k, exchanges, None, None, net.groups,
                           lost_rows if trajectories else []) if impaired else None
        if trajectories:
            for name, values in round_columns(sc, W[1], exchanges, lost_rows[before:]).items():
                rounds[name][k] = values
        X = est.step(X, y, W[0], alive) if Ws is None else est.step_realized(X, y, Ws, alive)

    def advance(k):
        nonlocal x
        x = advanced(F, L, x, v[k])

    # the plant's formulas, on every seed's state
    run_steps(plan, net, plant.rows, restart=restart, record=record, measure=lambda k: measured(C, sigma_m, x, w[k]),
              update=update, advance=advance)
    t = plan.times()
    trajs = ()
    if trajectories:
        from .trajectory_file import lost_arrays

        lost_a, cause_a = lost_arrays(lost_rows)
        trajs = tuple(Trajectory(t=t, x=xs[s], xhat=xh[s], alive=al.copy(), graph=plan.graph_seq.copy(),
                                 agent_ids=np.array(sc.agent_ids),
                                 columns={"g": g[s], **{k: v.copy() for k, v in rounds.items()}}, lost=lost_a.copy(),
                                 lost_cause=cause_a.copy(), states=sc.state_names) for s in range(N))
    return t, sq, count, trajs
