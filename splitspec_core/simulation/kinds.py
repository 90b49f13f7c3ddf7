"""The estimator kinds, one class each: a kind's event time in the simulator's three forms.

A design's kind (:func:`kind_of`, the one place that reads ``design.consensus`` and the scenario's time for the
step) is one of

* :class:`SplitDiscrete` - the paper's discrete split estimator: ``q`` consensus sub-rounds projected by ``P_i``
  (eq. split-discrete-p2), then the update (eq. split-discrete-est1);
* :class:`SplitSampled` - the paper's continuous estimator in its sampled-data form with the gain ``g`` (fixed, or
  adaptive by eq. adaptive), one exchange per ``run.dt`` (:func:`~splitspec_core.model.steps.sampled_step`);
* :class:`WholeState` - :mod:`splitspec_core.synthesis.whole_state`: the update on the per-step model, then ``q``
  plain averages of the whole estimate;
* :class:`Fusion` - :mod:`splitspec_core.synthesis.fusion_kind`: measure, fuse ``q`` times with matrix weights,
  predict;
* :class:`Relay` - :mod:`splitspec_core.synthesis.relay`: measure, pass the samples on ``q`` times, walk each
  agent's base estimate over the samples it holds.

Each class holds the kind's matrices and runs its event time in every form the simulator has: ``step`` /
``step_realized`` for :class:`~splitspec_core.simulation.simulator.BatchEstimator` (the agents stacked, ``X`` (m, n)),
``loop`` for :class:`~splitspec_core.simulation.simulator.AgentLoopEstimator` (agent by agent with the step functions
of :mod:`splitspec_core.model.steps`, as the agent processes call them) and ``seeds_step`` for
:class:`~splitspec_core.simulation.montecarlo.SeedBatchEstimator` (``X`` (m, n, N)).  The estimators dispatch once,
when they are made; a kind is added here, as one class (``docs/how-to/extend.md``), and nowhere in the simulator's
loop or the Monte Carlo batch.

Why one module: the kinds share the sparse kernels and the realized consensus matrix below, and the forms of one
kind must be read side by side (each is checked against the others to round-off).
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from ..model import steps as st
from ..model.impairment import realized_row
from ..synthesis.design_data import Design

__all__ = ["Kind", "SplitDiscrete", "SplitSampled", "WholeState", "Fusion", "Relay", "KINDS", "kind_of", "RealizedS",
           "realized_rows", "weight_entries", "consensus_matrix", "spmv", "spmm", "bmv", "exact_refusal",
           "EXACT_NEEDS_FIXED_G"]


# --------------------------------------------------------------------------
# kernels
# --------------------------------------------------------------------------


try:  # the CSR kernels without scipy's per-call dispatch (about 10 us a call at this size)
    from scipy.sparse._sparsetools import csr_matvec as _csr_matvec, csr_matvecs as _csr_matvecs
except ImportError:  # pragma: no cover - private API moved: fall back to the public product
    _csr_matvec = _csr_matvecs = None


def spmv(A: sp.csr_matrix, x: np.ndarray) -> np.ndarray:
    """``A @ x`` for a CSR matrix and a float64 vector.

    Parameters
    ----------
    A : scipy.sparse.csr_matrix
        The matrix.
    x : (A.shape[1],) float64 ndarray
        The vector.

    Returns
    -------
    (A.shape[0],) ndarray
    """
    if _csr_matvec is None:
        return A @ x
    y = np.zeros(A.shape[0])
    _csr_matvec(A.shape[0], A.shape[1], A.indptr, A.indices, A.data, x, y)
    return y


def spmm(S: sp.csr_matrix, Z: np.ndarray, out: np.ndarray) -> np.ndarray:
    """``out = S @ Z`` for a CSR matrix and a C-contiguous float64 matrix; each row sums in entry order.

    Parameters
    ----------
    S : scipy.sparse.csr_matrix
        The matrix.
    Z : (S.shape[1], k) float64 ndarray
        C-contiguous.
    out : (S.shape[0], k) float64 ndarray
        Written (no temporary of the product's size).

    Returns
    -------
    ndarray
        ``out``.
    """
    if _csr_matvecs is None:
        out[...] = S @ Z
        return out
    out.fill(0.0)
    _csr_matvecs(S.shape[0], S.shape[1], Z.shape[1], S.indptr, S.indices, S.data, Z.ravel(), out.ravel())
    return out


def bmv(M: np.ndarray, X: np.ndarray) -> np.ndarray:
    """Batched matrix-vector product: row i is ``M[i] @ X[i]``.

    Parameters
    ----------
    M : (m, a, b) ndarray
    X : (m, b) ndarray

    Returns
    -------
    (m, a) ndarray
    """
    return np.matmul(M, X[:, :, None])[:, :, 0]


def weight_entries(sc, rows: dict) -> tuple:
    """``(row, col, weight, off-diagonal)`` arrays (agent positions) of ``rows``, sorted by row, in its order within.

    Parameters
    ----------
    sc : Scenario
        The scenario (its agent order).
    rows : dict
        ``{i: (neighbour ids, weights)}`` (:func:`splitspec_core.model.network.consensus_rows`).

    Returns
    -------
    row : (E,) int64 ndarray
        The receiver's position of each entry.
    col : (E,) int64 ndarray
        The sender's position.
    weight : (E,) float ndarray
        ``w_ij``.
    off : (E,) bool ndarray
        True for the off-diagonal entries (the messages between agents).
    """
    pos = {a: k for k, a in enumerate(sc.agent_ids)}
    ri = np.array([pos[i] for i, (nbs, _) in rows.items() for _ in nbs], dtype=np.int64)
    ci = np.array([pos[j] for _, (nbs, _) in rows.items() for j in nbs], dtype=np.int64)
    w = np.array([x for _, (_, ws) in rows.items() for x in ws], dtype=float)
    order = np.argsort(ri, kind="stable")  # by receiver, each row's own order kept (a realized S sums rows)
    ri, ci, w = ri[order], ci[order], w[order]
    return ri, ci, w, ri != ci


def consensus_matrix(sc, rows: dict) -> sp.csr_matrix:
    """``S`` (m x m, sparse) of ``rows``: row i holds agent i's weights on its alive neighbours.

    Parameters
    ----------
    sc : Scenario
        The scenario (its agent order).
    rows : dict
        ``{i: (neighbour ids, weights)}`` of the alive agents.

    Returns
    -------
    scipy.sparse.csr_matrix
    """
    pos = {a: k for k, a in enumerate(sc.agent_ids)}
    ri = [pos[i] for i, (nbs, _) in rows.items() for _ in nbs]
    ci = [pos[j] for _, (nbs, _) in rows.items() for j in nbs]
    w = [x for _, (_, ws) in rows.items() for x in ws]
    return sp.csr_matrix((w, (ri, ci)), shape=(sc.m, sc.m))


class RealizedS:
    """A realized consensus matrix ``S`` (m x m) as entries sorted by row, every present row non-empty (its own
    weight): ``S @ Z`` sums each row's ``w_ij z_j`` in entry order, as a CSR product does."""

    __slots__ = ("m", "cols", "w", "starts", "present")

    def __init__(self, m: int, rows: np.ndarray, cols: np.ndarray, w: np.ndarray):
        self.m, self.cols, self.w = m, cols, w
        new_row = np.ones(len(rows), dtype=bool)
        new_row[1:] = rows[1:] != rows[:-1]
        self.starts = np.flatnonzero(new_row)
        self.present = rows[self.starts]

    def __matmul__(self, Z: np.ndarray) -> np.ndarray:
        out = np.zeros((self.m,) + Z.shape[1:])
        if len(self.cols):
            out[self.present] = np.add.reduceat(self.w.reshape((-1,) + (1,) * (Z.ndim - 1)) * Z[self.cols],
                                                self.starts, axis=0)
        return out


def _realized_matrices(sc, entries: tuple, counts: list) -> list:
    """``S_k`` of each exchange's realized graph (:func:`impairment.realized_row`, vectorised), a
    :class:`RealizedS` each (a segmented sum: building a scipy matrix per sub-round cost more than the whole step)."""
    ri, ci, w, off = entries
    offi = np.flatnonzero(off)
    out = []
    for ok in counts:
        keep = ~off
        keep[offi[ok]] = True
        rk = ri[keep]
        if sc.design.weights == "metropolis":  # the missing weights go to the receiver itself
            wk = w.copy()
            kept = keep & off
            wk[~off] = (1.0 - np.bincount(ri[kept], weights=w[kept], minlength=sc.m))[ri[~off]]
            wk = wk[keep]
        else:  # 1 / (1 + #counted): row i of the realized graph's S
            wk = 1.0 / np.bincount(rk, minlength=sc.m)[rk]
        out.append(RealizedS(sc.m, rk, ci[keep], wk))
    return out


def realized_rows(sc, rows: dict, entries: tuple, counts: list) -> list:
    """Each exchange's realized rows ``{i: (nbs, ws)}``, by the agents' own :func:`impairment.realized_row`.

    Parameters
    ----------
    sc : Scenario
        Its agent order and ``design.weights``.
    rows : dict
        ``{i: (neighbour ids, weights)}`` of the step's network.
    entries : tuple
        :func:`weight_entries` of ``rows``.
    counts : list of (E_off,) bool ndarray
        One per exchange, True where an off-diagonal entry's message counts.

    Returns
    -------
    list of dict
        Per exchange, ``{i: (neighbour ids, weights)}`` of the messages that count.
    """
    ri, ci, _, off = entries
    ids = sc.agent_ids
    offi = np.flatnonzero(off)
    out = []
    for ok in counts:
        counted: dict = {}
        for e in offi[ok]:
            counted.setdefault(ids[ri[e]], set()).add(ids[ci[e]])
        out.append({i: realized_row(nbs, ws, counted.get(i, ()), sc.design.weights) for i, (nbs, ws) in rows.items()})
    return out


# --------------------------------------------------------------------------
# the kinds
# --------------------------------------------------------------------------


class Kind:
    """One estimator kind of a design, for one estimator ``est`` (its screen, its projections, its form).

    The base holds what the stacked forms share: ``Kp`` (m, n, s_max) the gains the update applies to ``y_i``
    (zero-padded), the index that spreads the stacked ``y`` into it, ``Pst`` (m, n, n) the projections.
    """

    #: the kind in words (messages)
    label = "estimator"
    #: why N seeds of the kind cannot step as one batch (None: they can; :func:`.montecarlo.fallback_reason`)
    seeds_refusal: str | None = None
    #: a rejoiner's fresh estimate reaches the others' measured directions (their bad-data tests warm up afresh:
    #: :meth:`~splitspec_core.model.screening.Screen.rejoined`); the split's consensus leaves them alone (C_i P_i = 0)
    spreads_rejoins: bool = False

    def __init__(self, est, Ks: list):
        self.est, self.sc, self.m, self.n = est, est.sc, est.m, est.n
        self.Ks = Ks  # what the update applies to y_i (the whole state: the per-step model's K_s,i)
        s_max = max(C.shape[0] for C in est.Cs)
        self.Kp = np.zeros((self.m, self.n, s_max))
        rows, cols = [], []
        for i, (K, C) in enumerate(zip(Ks, est.Cs)):
            self.Kp[i, :, : K.shape[1]] = K
            rows += [i] * C.shape[0]
            cols += list(range(C.shape[0]))
        self.yidx = (np.array(rows), np.array(cols))
        self.Pst = np.stack(est.Ps)

    @property
    def exchanges(self) -> int:
        """The consensus exchanges of an event time (``q``; one per ``run.dt`` in the sampled-data form)."""
        return int(self.est.des.q)

    def gains(self) -> np.ndarray | None:
        """The gains ``g_i`` reported per row (the sampled-data form's), or None.

        Returns
        -------
        ndarray or None
            (m,) or (m, N) with seeds; None for a kind without a consensus gain.
        """
        return None

    def restart(self, i: int) -> None:
        """Agent ``i`` starts again: the kind's own state of it (the adaptive gain) from its initial value.

        Parameters
        ----------
        i : int
            The agent's position.
        """

    def for_seeds(self, N: int) -> None:
        """Hold the kind's own state once per seed (``N`` seeds on a trailing axis).

        Parameters
        ----------
        N : int
            The seeds.
        """

    def Y(self, y: np.ndarray) -> np.ndarray:
        """The stacked ``y`` (sum s_i[, N]) per agent, zero-padded: (m, s_max[, N]).

        Parameters
        ----------
        y : (sum s_i,) or (sum s_i, N) ndarray
            The stacked measurement(s).

        Returns
        -------
        ndarray
        """
        Y = np.zeros((self.m, self.Kp.shape[2]) + y.shape[1:])
        Y[self.yidx] = y
        return Y

    # the batch form (BatchEstimator): X (m, n)

    def weights(self, rows: dict):
        """The batch form's weights of a network (computed once per network, :class:`.simulator.NetworkWeights`).

        Parameters
        ----------
        rows : dict
            ``{i: (neighbour ids, weights)}`` of the alive agents (:func:`splitspec_core.model.network.consensus_rows`).

        Returns
        -------
        object
            What :meth:`step` takes: ``S`` sparse (m x m) unless the kind says otherwise.
        """
        return consensus_matrix(self.sc, rows)

    def realized(self, rows: dict, entries: tuple, counts: list) -> list:
        """``S_k`` (m x m) of each exchange's realized graph: :func:`impairment.realized_row`, vectorised.

        Parameters
        ----------
        rows : dict
            ``{i: (neighbour ids, weights)}`` of the step's network.
        entries : tuple
            :func:`weight_entries` of ``rows``.
        counts : list of (E_off,) bool ndarray
            One per exchange, True where an off-diagonal entry's message counts.

        Returns
        -------
        list
            What :meth:`step_realized` takes per exchange: a :class:`RealizedS` (a receiver's missing messages'
            weight goes to itself (Metropolis), or its row is re-weighted ``1 / (1 + counted)`` (uniform)).
        """
        return _realized_matrices(self.sc, entries, counts)

    def step(self, X: np.ndarray, y: np.ndarray, W, alive: np.ndarray, missing, bu) -> np.ndarray:
        """One event time, every message counting (:meth:`.simulator.BatchEstimator.step`).

        Parameters
        ----------
        X : (m, n) ndarray
            The estimates ``x_i(k)``.
        y : (sum s_i,) ndarray
            The stacked measurement ``y(k)``.
        W : object
            :meth:`weights` of the step's network.
        alive : (m,) bool ndarray
            The agents taking part.
        missing : (m,) bool ndarray or None
            Agents without a measurement this step.
        bu : (n,) ndarray or None
            The known input's ``B u(k)``.

        Returns
        -------
        (m, n) ndarray
            ``x_i(k+1)``, zero rows for the dead agents.
        """
        return self.step_realized(X, y, [W] * self.exchanges, alive, missing, bu)

    def step_realized(self, X: np.ndarray, y: np.ndarray, Ws: list, alive: np.ndarray, missing, bu) -> np.ndarray:
        """One event time with each exchange's realized weights (:meth:`.simulator.BatchEstimator.step_realized`).

        Parameters
        ----------
        X : (m, n) ndarray
            The estimates ``x_i(k)``.
        y : (sum s_i,) ndarray
            The stacked measurement ``y(k)``.
        Ws : list
            :meth:`realized` of the step, one per exchange.
        alive : (m,) bool ndarray
            The agents taking part.
        missing : (m,) bool ndarray or None
            Agents without a measurement this step.
        bu : (n,) ndarray or None
            The known input's ``B u(k)``.

        Returns
        -------
        (m, n) ndarray
            ``x_i(k+1)``, zero rows for the dead agents.
        """
        raise NotImplementedError

    # the loop form (AgentLoopEstimator): agent by agent with model/steps.py

    def loop(self, X: np.ndarray, y: np.ndarray, rounds: list, alive: np.ndarray, missing, bu) -> np.ndarray:
        """One event time agent by agent with the step functions of :mod:`splitspec_core.model.steps`.

        Parameters
        ----------
        X : (m, n) ndarray
            The estimates ``x_i(k)``.
        y : (sum s_i,) ndarray
            The stacked measurement ``y(k)``.
        rounds : list of dict
            Per exchange, ``{i: (neighbour ids, weights)}`` of the messages that count (the first: the agents
            taking part).
        alive : (m,) bool ndarray
            The agents taking part (those of ``rounds[0]``).
        missing : (m,) bool ndarray or None
            Agents without a measurement this step.
        bu : (n,) ndarray or None
            The known input's ``B u(k)``.

        Returns
        -------
        (m, n) ndarray
            ``x_i(k+1)``, zero rows for the agents not in ``rounds[0]``.
        """
        raise NotImplementedError

    def ys(self, y: np.ndarray, missing) -> list:
        """Each agent's ``y_i``, None where it has no measurement this step.

        Parameters
        ----------
        y : (sum s_i,) ndarray
            The stacked measurement.
        missing : (m,) bool ndarray or None
            Agents without one.

        Returns
        -------
        list
        """
        return [None if missing is not None and missing[k] else y[r] for k, r in enumerate(self.est.rows_y)]

    # the seeds form (SeedBatchEstimator): X (m, n, N)

    def seeds_step(self, X: np.ndarray, Y: np.ndarray, Ws: list, alive: np.ndarray) -> np.ndarray:
        """One event time of every seed with one ``S_k`` per exchange (sparse or :class:`RealizedS`).

        Parameters
        ----------
        X : (m, n, N) ndarray
            The estimates, seeds on the trailing axis.
        Y : (m, s_max, N) ndarray
            :meth:`Y` of the stacked measurements.
        Ws : list
            ``S_k`` per exchange.
        alive : (m,) bool ndarray
            The agents taking part (the same in every seed).

        Returns
        -------
        (m, n, N) ndarray
            ``x_i(k+1)`` of every seed, zero for the dead agents.
        """
        raise NotImplementedError(self.seeds_refusal)


class SplitDiscrete(Kind):
    """The paper's discrete split estimator: ``q`` sub-rounds ``z_i <- z_i + P_i (sum_j w_ij z_j - z_i)``
    (eq. split-discrete-p2), then ``x_i <- (A + K_i C_i) z_i(q) - K_i y_i`` (eq. split-discrete-est1).

    The batch form runs the lossless sub-rounds in unobservable-space coordinates: from eq. (split-discrete-p2),
    ``(I - P_i) z_i(k) = (I - P_i) x_i(tau)`` for every k, and ``w = V'z`` obeys ``w(k) = c + B w(k-1)`` with
    ``B = V' Sbar V`` (eq. split_discrete_pr2) and ``c = V' Sbar (I - P) x(tau)``.  With balanced working coordinates
    (``design.coordinates``) ``P_i = L_i R_i'`` is oblique in the user's: ``w = R'z``, ``B = R' Sbar L``,
    ``c = R' Sbar (I - P) x``, ``z = (I - P) x + L w``.  ``B`` is block sparse (one ``n_i x n_j`` block per arc), so a
    sub-round costs one sparse product with about ``sum_arcs n_i n_j`` non-zeros.
    """

    label = "discrete split estimator"

    def __init__(self, est):
        super().__init__(est, est.Ks)
        self.A = est.A
        self.F = [est.A + K @ C for K, C in zip(est.Ks, est.Cs)]
        self.Fst = np.stack(self.F)
        self.Vbig = sp.block_diag([sp.csr_matrix(L) for L in est.Ls], format="csr")  # (mn, nbar): L
        self.VT = sp.block_diag([sp.csr_matrix(R.T) for R in est.Vs], format="csr")  # (nbar, mn): R transposed

    def weights(self, rows: dict):
        """``(B, G, S)``: ``B = V'(W (x) I)V`` and ``G = V'(W (x) I)`` (sparse), and, with the bad-data test,
        ``S`` itself as a :class:`RealizedS` (a suspect sensor's ``P_i = I`` runs the sub-rounds on ``S``)."""
        W = consensus_matrix(self.sc, rows)
        G = (self.VT @ sp.kron(W, sp.identity(self.n), format="csr")).tocsr()
        S = None
        if self.est.screen is not None:
            entries = weight_entries(self.sc, rows)
            S = self.realized(rows, entries, [np.ones(int(entries[3].sum()), dtype=bool)])[0]
        return (G @ self.Vbig).tocsr(), G, S

    def step(self, X, y, W, alive, missing, bu):
        B, G, S = W
        if self.est.screen is not None and self.est.screen.suspect.any():  # a suspect's P_i = I: the sub-rounds on S
            return self.step_realized(X, y, [S] * self.exchanges, alive, missing, bu)
        U = X - bmv(self.Pst, X)  # (I - P_i) x_i, fixed through the sub-rounds
        w = spmv(self.VT, X.ravel())  # w_i = R_i' x_i (V_i' x_i), z_i = U_i + L_i w_i
        c = spmv(G, U.ravel())
        for _ in range(self.exchanges):
            # eq. split-discrete-p2 in V coordinates: w_i <- V_i' sum_j w_ij z_j
            w = c + spmv(B, w)
        Z = U + spmv(self.Vbig, w).reshape(self.m, self.n)
        Xn = self._update(Z, self.Y(y), self.est.screen_of(Z, y, missing, alive), bu)
        Xn[~alive] = 0.0
        return Xn

    def step_realized(self, X, y, Ws, alive, missing, bu):
        Z = X.copy()
        Pst = self.Pst if self.est.screen is None else np.stack(self.est.projections())
        for Wk in Ws:
            Z = Z + bmv(Pst, Wk @ Z - Z)
        Xn = self._update(Z, self.Y(y), self.est.screen_of(Z, y, missing, alive), bu)
        Xn[~alive] = 0.0
        return Xn

    def _update(self, Z: np.ndarray, Y: np.ndarray, missing, bu) -> np.ndarray:
        """Eq. split-discrete-est1; an agent without a measurement predicts, ``A z_i(q)`` (steps.prediction_update);
        the known input's ``B u`` added when there is one."""
        Xn = bmv(self.Fst, Z) - bmv(self.Kp, Y)
        if missing is not None and missing.any():
            Xn[missing] = Z[missing] @ self.A.T
        return Xn if bu is None else Xn + bu

    def loop(self, X, y, rounds, alive, missing, bu):
        est, pos = self.est, self.est.pos
        Ps = est.projections()  # before the test: the watch at the start of the step
        Xn = np.zeros_like(X)
        Z = X.copy()
        for rows in rounds:
            Zn = np.zeros_like(Z)
            for i_id, (nbs, ws) in rows.items():
                i = pos[i_id]
                Zn[i] = st.consensus_subround(Z[i], Ps[i], [Z[pos[j]] for j in nbs], ws)
            Z = Zn
        ys = self.ys(y, est.screen_of(Z, y, missing, alive))
        for i_id in rounds[0]:
            i = pos[i_id]
            Xn[i] = (st.prediction_update(Z[i], self.A, bu) if ys[i] is None
                     else st.measurement_update(Z[i], self.F[i], self.Ks[i], ys[i], bu))
        return Xn

    def seeds_step(self, X, Y, Ws, alive):
        m, n, N = X.shape
        if all(isinstance(S, sp.csr_matrix) for S in Ws):
            # eq. split-discrete-p2: (I - P_i) z_i(k) = (I - P_i) z_i(tau) for every k, so
            # z_i <- (I - P_i) x_i + P_i sum_j w_ij z_j, in place (no temporary of the state's size)
            U = X - np.matmul(self.Pst, X)
            Z = X.copy()
            SZ = np.empty((m, n * N))
            for S in Ws:
                spmm(S, Z.reshape(m, n * N), SZ)
                np.matmul(self.Pst, SZ.reshape(m, n, N), out=Z)
                Z += U
        else:  # realized graphs of a partition (a RealizedS per exchange)
            Z = X
            for S in Ws:
                # eq. split-discrete-p2: z_i <- z_i + P_i (sum_j w_ij z_j - z_i)
                Z = Z + np.matmul(self.Pst, (S @ Z.reshape(m, n * N)).reshape(m, n, N) - Z)
        # eq. split-discrete-est1: x_i <- (A + K_i C_i) z_i(q) - K_i y_i
        Xn = np.matmul(self.Fst, Z) - np.matmul(self.Kp, Y)
        Xn[~alive] = 0.0
        return Xn


class SplitSampled(Kind):
    """The paper's continuous estimator, sampled: per ``run.dt`` one exchange and
    ``x_i <- E x_i + D [K_i (C_i x_i - y_i) - g_i P_i (x_i - sum_j w_ij x_j) + B u]``
    (:func:`~splitspec_core.model.steps.sampled_step`); with ``design.g: adaptive`` each ``g_i`` grows by eq. (adaptive)
    (its Euler step)."""

    label = "sampled split estimator"

    def __init__(self, est):
        super().__init__(est, est.Ks)
        sc, des = est.sc, est.des
        self.E, self.D, _ = st.sampled_data_matrices(est.A, sc.run.dt)
        self.dt = sc.run.dt
        self.adaptive = des.g_mode == "adaptive"
        self.g = np.full(self.m, sc.design.g0 if self.adaptive else float(des.g))
        self.KC = np.stack([K @ C for K, C in zip(est.Ks, est.Cs)])
        self.Rgram = np.stack([R @ R.T for R in est.Vs])  # eq. (adaptive): |R_i' d|^2 = d' R_i R_i' d

    @property
    def exchanges(self) -> int:
        return 1

    def gains(self):
        return self.g

    def restart(self, i):
        if self.adaptive:
            self.g[i] = self.sc.design.g0

    def for_seeds(self, N):
        self.g = np.repeat(self.g[:, None], N, axis=1)

    def step(self, X, y, W, alive, missing, bu):
        Y = self.Y(y)
        Pst = np.stack(self.est.projections())  # before the test: the watch at the start of the step
        missing = self.est.screen_of(X, y, missing, alive)
        diff = X - W @ X
        innov = bmv(self.KC, X) - bmv(self.Kp, Y)
        if missing is not None and missing.any():
            innov[missing] = 0.0  # steps.sampled_step with y_i None
        corr = innov - self.g[:, None] * bmv(Pst, diff)
        if bu is not None:
            corr = corr + bu  # steps.sampled_step: B u(k) held over the step
        Xn = X @ self.E.T + corr @ self.D.T
        if self.adaptive:
            # eq. (adaptive): |V_i'(avg_i - x_i)|^2 = diff' R_i R_i' diff (diff' P_i diff for orthogonal P_i)
            rate = np.einsum("mi,mi->m", diff, bmv(self.Rgram, diff))
            self.g = np.where(alive, self.g + self.dt * rate, self.g)
        Xn[~alive] = 0.0
        return Xn

    def step_realized(self, X, y, Ws, alive, missing, bu):
        return self.step(X, y, Ws[0], alive, missing, bu)

    def loop(self, X, y, rounds, alive, missing, bu):
        est, pos, rows = self.est, self.est.pos, rounds[0]
        Ps = est.projections()  # before the test: the watch at the start of the step
        ys = self.ys(y, est.screen_of(X, y, missing, alive))
        Xn = np.zeros_like(X)
        g_next = self.g.copy()
        for i_id, (nbs, ws) in rows.items():
            i = pos[i_id]
            states = [X[pos[j]] for j in nbs]
            Xn[i] = st.sampled_step(X[i], self.E, self.D, self.Ks[i], est.Cs[i], ys[i], Ps[i], self.g[i], states, ws,
                                    bu)
            if self.adaptive:
                g_next[i] = st.adaptive_gain_step(self.g[i], st.adaptive_gain_rate(est.Vs[i], X[i], states, ws),
                                                  self.dt)
        self.g = g_next
        return Xn

    def seeds_step(self, X, Y, Ws, alive):
        m, n, N = X.shape
        S = Ws[0]
        diff = X - (S @ X.reshape(m, n * N)).reshape(m, n, N)
        PD = np.matmul(self.Pst, diff)
        # steps.sampled_step: x_i <- E x_i + D [K_i (C_i x_i - y_i) - g_i P_i (x_i - sum_j w_ij x_j)]
        corr = np.matmul(self.KC, X) - np.matmul(self.Kp, Y) - self.g[:, None, :] * PD
        Xn = np.matmul(self.E, X) + np.matmul(self.D, corr)
        if self.adaptive:
            # eq. (adaptive): |V_i'(avg_i - x_i)|^2 = diff' R_i R_i' diff (diff' P_i diff for orthogonal P_i)
            rate = np.einsum("ijs,ijs->is", diff, np.matmul(self.Rgram, diff))
            self.g = np.where(alive[:, None], self.g + self.dt * rate, self.g)
        Xn[~alive] = 0.0
        return Xn


class WholeState(Kind):
    """The whole-state design (:mod:`splitspec_core.synthesis.whole_state`): every agent updates on the per-step model
    (:func:`~splitspec_core.model.steps.step_matrices`: ``A_s``, ``F_i``, ``K_s,i``, the input ``G B u``), then
    averages the whole estimate with its neighbours ``q`` times, ``z_i <- sum_j w_ij z_j`` (eq. split-discrete-p2 with
    ``P_i = I``); in continuous time on the sampled model, ``q`` exchanges per ``run.dt``."""

    label = "whole-state design"
    spreads_rejoins = True  # the average takes the whole estimate, measured directions included

    def __init__(self, est):
        sc = est.sc
        dt = sc.run.dt if sc.time == "continuous" else None
        ED = None if dt is None else st.sampled_data_matrices(est.A, dt)[:2]
        mats = [st.step_matrices(est.A, K, C, dt=dt, sampled=ED) for K, C in zip(est.Ks, est.Cs)]
        super().__init__(est, [mt[2] for mt in mats])  # K_s,i = K_i, or D K_i: what the step applies to y_i
        self.A_step, self.G = mats[0][0], mats[0][3]
        self.F = [mt[1] for mt in mats]
        self.Fst = np.stack(self.F)

    def step_realized(self, X, y, Ws, alive, missing, bu):
        Y = self.Y(y)
        missing = self.est.screen_of(X, y, missing, alive)
        Xn = bmv(self.Fst, X) - bmv(self.Kp, Y)
        if missing is not None and missing.any():
            Xn[missing] = X[missing] @ self.A_step.T
        bu = st.step_input(self.G, bu)
        Z = Xn if bu is None else Xn + bu
        for Wk in Ws:  # then average q times (whole_state.py): z_i <- sum_j w_ij z_j
            Z = Wk @ Z
        Z[~alive] = 0.0
        return Z

    def loop(self, X, y, rounds, alive, missing, bu):
        est, pos = self.est, self.est.pos
        ys = self.ys(y, est.screen_of(X, y, missing, alive))
        bu = st.step_input(self.G, bu)
        Z = np.zeros_like(X)
        for i_id in rounds[0]:
            i = pos[i_id]
            Z[i] = (st.prediction_update(X[i], self.A_step, bu) if ys[i] is None
                    else st.measurement_update(X[i], self.F[i], self.Ks[i], ys[i], bu))
        for rows in rounds:
            Zn = np.zeros_like(Z)
            for i_id, (nbs, ws) in rows.items():
                Zn[pos[i_id]] = st.weighted_average([Z[pos[j]] for j in nbs], ws)  # eq. split-discrete-p2, P_i = I
            Z = Zn
        return Z

    def seeds_step(self, X, Y, Ws, alive):
        m, n, N = X.shape
        Z = np.matmul(self.Fst, X) - np.matmul(self.Kp, Y)  # z_i(0) = F_i x_i - K_s,i y_i
        for S in Ws:
            Z = (S @ Z.reshape(m, n * N)).reshape(m, n, N)
        Z[~alive] = 0.0
        return Z


class Fusion(Kind):
    """The fusion kind (:mod:`splitspec_core.synthesis.fusion_kind`), agent by agent with the step functions of
    :mod:`splitspec_core.model.steps` in the order an agent process calls them: ``local_update``, then per exchange
    ``fold_weights`` and ``matrix_fusion`` over the neighbours that count, then ``prediction_update``.  The batch and
    the loop forms run the same steps (the same floats); the seeds do not batch."""

    label = "fusion kind"

    seeds_refusal = "the fusion kind runs its agents' steps one seed at a time (kinds.Fusion)"

    def __init__(self, est):
        from ..synthesis.fusion_kind import weight_blocks

        super().__init__(est, est.Ks)
        sc, des = est.sc, est.des
        kind = des.whole
        self.C = [np.asarray(C, dtype=float) for C in sc.system.Cs]
        self.F = np.asarray(kind.designs[0].F)  # the per-step model: A, or exp(A run.dt) (the agents are sent it)
        dt = sc.run.dt if sc.time == "continuous" else None
        # the known input's map per step: B u itself, or D B u on the sampled model (steps.step_matrices's G)
        self.G = None if dt is None else st.sampled_data_matrices(np.asarray(sc.system.A), dt)[1]
        self.L = [d.Ls for d in kind.designs]
        self.blocks = [[weight_blocks(des, g, i) for i in range(sc.m)] for g in range(len(kind.designs))]

    def weights(self, rows):
        """The rows themselves: each agent folds its neighbours' weights."""
        return rows

    def realized(self, rows, entries, counts):
        return realized_rows(self.sc, rows, entries, counts)

    def step_realized(self, X, y, Ws, alive, missing, bu):
        return self.loop(X, y, Ws, alive, missing, bu)

    def loop(self, X, y, rounds, alive, missing, bu):
        ys = self.ys(y, missing)
        pos, L, blocks = self.est.pos, self.L[self.est.graph], self.blocks[self.est.graph]
        Z = np.zeros_like(X)
        for i_id in rounds[0]:
            i = pos[i_id]
            Z[i] = st.local_update(X[i], L[i], self.C[i], ys[i])
        for k, rows in enumerate(rounds):
            Zn = np.zeros_like(Z)
            for i_id, (nbs, _) in rows.items():
                i = pos[i_id]
                Zn[i] = st.matrix_fusion([Z[pos[j]] for j in nbs], st.fold_weights(blocks[i][k], i_id, nbs))
            Z = Zn
        Xn = np.zeros_like(X)
        bu = st.step_input(self.G, bu)
        for i_id in rounds[0]:
            Xn[pos[i_id]] = st.prediction_update(Z[pos[i_id]], self.F, bu)
        return Xn


class Relay(Kind):
    """The relay kind (:mod:`splitspec_core.synthesis.relay`), agent by agent with the step functions of
    :mod:`splitspec_core.model.steps` in the order an agent process calls them: its own sample held, per exchange
    ``relay_forward`` to the neighbours whose messages count, then ``relay_walk`` over the samples held.  Each agent's
    base, its base's event time and the samples it holds and has sent are the kind's own state (a start or a restart
    takes the initial estimate as the base, nothing held); the batch and the loop forms run the same steps, the seeds
    do not batch."""

    label = "relay kind"

    seeds_refusal = "the relay kind runs its agents' steps one seed at a time (kinds.Relay)"

    def __init__(self, est):
        from ..synthesis.relay import gain_table

        super().__init__(est, est.Ks)
        sc, r = est.sc, est.des.whole
        self.F = np.asarray(r.F)
        self.C = np.vstack([np.asarray(C, dtype=float) for C in sc.system.Cs])
        dt = sc.run.dt if sc.time == "continuous" else None
        self.G = None if dt is None else st.sampled_data_matrices(np.asarray(sc.system.A), dt)[1]
        self.D = r.D
        self.table = [gain_table(r, i) for i in range(self.m)]
        self.sensor_rows = [np.arange(s.start, s.stop, dtype=np.int64) for s in est.rows_y]
        self.base = np.zeros((self.m, self.n))
        self.t_base = np.zeros(self.m, dtype=np.int64)
        self.fresh = set(range(self.m))
        self.held = [{} for _ in range(self.m)]  # per agent {(sensor, t): y_j(t)}
        self.sent = [set() for _ in range(self.m)]
        self.bus: dict = {}  # t -> B u(t) (continuous: the sampled model's)

    def restart(self, i):
        self.fresh.add(i)

    def weights(self, rows):
        """The rows themselves: the samples go to the neighbours whose messages count."""
        return rows

    def realized(self, rows, entries, counts):
        return realized_rows(self.sc, rows, entries, counts)

    def step_realized(self, X, y, Ws, alive, missing, bu):
        return self.loop(X, y, Ws, alive, missing, bu)

    def loop(self, X, y, rounds, alive, missing, bu):
        tau, pos = int(self.est.tau), self.est.pos
        members = [pos[i] for i in rounds[0]]
        for i in members:
            if i in self.fresh:  # a start: the initial estimate is the base at tau, nothing held
                self.base[i], self.t_base[i] = X[i], tau
                self.held[i], self.sent[i] = {}, set()
                self.fresh.discard(i)
        ys = self.ys(y, missing)
        bu = st.step_input(self.G, bu)
        if bu is not None:
            self.bus[tau] = bu
        for i in members:
            if ys[i] is not None:
                self.held[i][(i, tau)] = ys[i]
        for rows in rounds:  # each exchange: every member sends what it has not sent; the counted ones arrive
            out = {pos[j]: st.relay_forward(self.held[pos[j]], self.sent[pos[j]]) for j in rows}
            for j, s in out.items():
                self.sent[j] |= set(s)
            for i_id, (nbs, _) in rows.items():
                i = pos[i_id]
                for j_id in nbs:
                    if j_id != i_id:
                        self.held[i].update(out[pos[j_id]])
        Xn = np.zeros_like(X)
        for i in members:
            samples = st.relay_samples(self.held[i], self.sensor_rows, int(self.t_base[i]), tau)
            self.base[i], self.t_base[i], Xn[i] = st.relay_walk(self.base[i], int(self.t_base[i]), tau,
                                                                 self.table[i], self.F, self.C, samples,
                                                                 self.bus if self.bus else None)
        cut = tau - self.D + 1  # no agent's walk starts before: older samples are no longer sent or held
        for i in range(self.m):
            self.held[i] = st.relay_prune(self.held[i], cut)
            self.sent[i] = {h for h in self.sent[i] if h[1] >= cut}
        for t in [t for t in self.bus if t < cut]:
            del self.bus[t]
        return Xn


#: the kinds by the name a design gives (``Design.consensus``, and ``split`` by the scenario's time)
KINDS = {"split": SplitDiscrete, "sampled": SplitSampled, "whole": WholeState, "fusion": Fusion, "relay": Relay}


def kind_of(des: Design) -> type:
    """The kind class of a design: the one place the simulator reads which estimator a design is.

    Parameters
    ----------
    des : Design
        The design.

    Returns
    -------
    type
        A :class:`Kind` subclass of :data:`KINDS`.

    Examples
    --------
    >>> import splitspec_core as ss
    >>> kind_of(ss.design(ss.load_scenario("examples/paper_discrete.yaml")).detail).__name__
    'SplitDiscrete'
    """
    name = des.consensus if des.consensus in KINDS else "split"
    if name == "split" and des.scenario.time == "continuous":
        name = "sampled"
    return KINDS[name]


# eq. (adaptive) makes each g_i(t) a state of its own: the ODE is no longer linear, so no matrix exponential
EXACT_NEEDS_FIXED_G = ("the exact ODE needs one fixed g, and design.g is adaptive (each agent's g_i(t), eq. adaptive): "
                       "give design.g a number or auto")


def exact_refusal(des: Design) -> str | None:
    """Why the exact ODE of eq. (split_continuous_observer) cannot integrate this design's kind, or None.

    Parameters
    ----------
    des : Design
        The design.

    Returns
    -------
    str or None
        One line: a discrete scenario, a kind other than the sampled split, or the adaptive gain.
    """
    kind = kind_of(des)
    if des.scenario.time != "continuous":
        return "the exact ODE is continuous time; this scenario is discrete (time: discrete)"
    if kind is not SplitSampled:
        return ("the exact ODE is the split's continuous estimator (eq. split_continuous_observer); the "
                f"{kind.label} runs on the sampled model, q exchanges per run.dt: simulate without --exact")
    if des.g_mode == "adaptive":
        return EXACT_NEEDS_FIXED_G
    return None
