"""Property tests of the design engine against the paper, on the FULL error matrices.

Every check recomputes its quantity from the dense ``mn x mn`` objects of the
paper (``Abar = blockdiag(A + K_i C_i)``, ``P = blockdiag(P_i)``,
``Sbar = S (x) I_n``, ``V = blockdiag(V_i)``) rather than from the reduced
quantities the library works with (``bounds.Case``: Gram-matrix ``B``,
``A_un``, ``h``), so a slip in the library's reductions shows up here.

Eigenvalues of these non-normal matrices can be ill-conditioned (agents that
see nothing on a directed path make ``S`` restricted to them a Jordan block),
so spectral radii and abscissae are compared as round-off intervals
(:func:`radius_interval`), never with a fixed tolerance.

Scenarios come from :mod:`.strategies` (valid by construction: jointly
observable, strongly connected).  Environment:

* ``HYPOTHESIS_PROFILE=ci``: the same examples on every run (derandomized; the
  profile is registered in ``tests/conftest.py``); the default profile draws new ones each run;
* ``SPLITSPEC_PROPERTY_SCALE=10``: ten times the examples (a longer hunt
  than the ~35 s default budget).
"""

from __future__ import annotations

import dataclasses
import math
import os

import numpy as np
import pytest
import scipy.linalg as sla
from hypothesis import HealthCheck, assume, event, example, given, settings
from hypothesis import strategies as st

from splitspec_core.synthesis.designer import design
from splitspec_core.errors import AssumptionError, DesignError
from splitspec_core.synthesis.error_matrix import block_diagonal
from splitspec_core.synthesis.spectral import CERTIFY_MARGIN, certifies
from splitspec_core.model.observability import decompose, threshold_of
from splitspec_core.scenarios.load import parse_scenario

from .strategies import Drawn, graph_sequences, scenarios

SCALE = float(os.environ.get("SPLITSPEC_PROPERTY_SCALE", "1"))
COMMON = dict(deadline=None, suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])

# scipy.signal.place_poles (method YT, multi-output C_i) warns when its robustness iteration stops
# early; the poles are still placed and design_gain checks them against the rate.
pytestmark = pytest.mark.filterwarnings("ignore:Convergence was not reached:UserWarning")


def examples(n: int) -> int:
    """``n`` examples times ``SPLITSPEC_PROPERTY_SCALE``."""
    return max(1, int(n * SCALE))


# --------------------------------------------------------------------------
# dense objects of the paper
# --------------------------------------------------------------------------


def complement(V: np.ndarray) -> np.ndarray:
    """``Q_i'``: orthonormal basis of the orthogonal complement of ``span V_i``."""
    return np.eye(V.shape[0]) if V.shape[1] == 0 else sla.null_space(V.T, rcond=1e-12)


def _eig_errors(M: np.ndarray, form: float = 0.0) -> tuple:
    """Eigenvalues and their first-order error scales ``kappa_j eps |M|_2`` (``kappa_j = 1/|y_j' x_j|``).

    Round-off moves a simple eigenvalue by about ``kappa eps |M|``; near a Jordan block (e.g. agents
    that see nothing on a directed path: ``S`` restricted to them is ``(I + N)/2``) the computed
    eigenvalues split by ``eps^(1/k)`` and the computed ``kappa`` grows to match, so the same
    formula gives the right scale.  ``form`` adds the round-off of FORMING ``M`` (e.g. a matrix
    power whose factors are much larger than the product, see :func:`power_scale`), which matters
    when ``M`` is compared with the library's own formation of the same matrix.
    """
    w, yl, xr = sla.eig(M, left=True, right=True)
    with np.errstate(divide="ignore"):
        kappa = 1.0 / np.abs(np.sum(yl.conj() * xr, axis=0))
    return w, 10.0 * kappa * np.finfo(float).eps * (norm2(M) + form) + 1e-12


def radius_interval(M: np.ndarray, form: float = 0.0) -> tuple:
    """``(lo, rho, hi)``: computed spectral radius with its round-off interval."""
    if not M.size:
        return 0.0, 0.0, 0.0
    w, err = _eig_errors(M, form)
    r = np.abs(w)
    return float(np.max(r - err)), float(np.max(r)), float(np.max(r + err))


def abscissa_interval(M: np.ndarray, form: float = 0.0) -> tuple:
    """``(lo, alpha, hi)``: computed spectral abscissa with its round-off interval."""
    if not M.size:
        return -math.inf, -math.inf, -math.inf
    w, err = _eig_errors(M, form)
    return float(np.max(w.real - err)), float(np.max(w.real)), float(np.max(w.real + err))


def power_scale(B: np.ndarray, q: int, h: np.ndarray) -> float:
    """First-order round-off scale of forming ``B^q`` (per unit eps): ``q |B| max_k |B^k|^2``.

    ``max_k |B^k|_2 <= sqrt(max h / min h) max_k |B^k|_R <= sqrt(max h / min h)`` because
    ``|B|_R < 1`` (eq. ino, checked in the certificate test) with ``R = diag(h)``.
    """
    return q * norm2(B) * float(h.max() / h.min()) if B.size else 0.0


def top(*intervals) -> tuple:
    """Interval of the largest of several quantities given as intervals."""
    return tuple(max(iv[k] for iv in intervals) for k in range(3))


def same(x: tuple, y: tuple, tol: float = 0.0) -> bool:
    """Whether two round-off intervals ``(lo, value, hi)`` overlap (up to ``tol``)."""
    return x[0] <= y[2] + tol and y[0] <= x[2] + tol


def norm2(M: np.ndarray) -> float:
    return float(np.linalg.norm(M, 2)) if M.size else 0.0


def mixed_norm(M: np.ndarray, rows, cols) -> float:
    """eq. (split_mmn): ``|| <M> ||_inf`` with ``<M>_ij = |M_ij|_2`` (empty blocks count 0)."""
    re, ce = np.concatenate([[0], np.cumsum(rows)]), np.concatenate([[0], np.cumsum(cols)])
    sums = [sum(norm2(M[re[i]:re[i + 1], ce[j]:ce[j + 1]]) for j in range(len(cols)))
            for i in range(len(rows))]
    return max(sums, default=0.0)


def perron(S: np.ndarray) -> np.ndarray:
    """``pi > 0`` with ``S' pi = pi``, ``sum pi = 1`` (from the eigenvector of ``S'`` at 1)."""
    w, X = np.linalg.eig(S.T)
    k = int(np.argmin(np.abs(w - 1.0)))
    pi = np.real(X[:, k])
    return pi / pi.sum()


def working(dsg) -> tuple:
    """``(A, Cs, Ks, Ps, Vs)`` of a design in its working coordinates (``design.coordinates``: the user's own, or
    balanced), where ``V_i`` is orthonormal and ``P_i = V_i V_i'``: the paper's objects."""
    s = dsg.scale
    Cs = [np.asarray(C) if s is None else np.asarray(C) * s[None, :] for C in dsg.scenario.system.Cs]
    return (dsg.A_working, Cs, [a.gain.K for a in dsg.agents], [a.dec.P for a in dsg.agents],
            [a.dec.V for a in dsg.agents])


class Full:
    """The dense matrices of a design (paper Sections 2-3), built independently of ``bounds``, in the design's working
    coordinates (the user's own unless ``design.coordinates`` balanced them)."""

    def __init__(self, dsg):
        sc = dsg.scenario
        self.dsg, self.sc = dsg, sc
        self.n, self.m, self.rate = sc.n, sc.m, sc.design.rate
        A, Cs, Ks, Ps, Vs = working(dsg)
        self.Abar = block_diagonal([A + K @ C for K, C in zip(Ks, Cs)])
        self.P = block_diagonal(Ps)
        self.V = block_diagonal(Vs)  # mn x nbar
        self.Q = block_diagonal([complement(V).T for V in Vs])  # (mn - nbar) x mn
        self.sizes = [V.shape[1] for V in Vs]
        # bounds.make_case takes A_i = V_i'A V_i (eq. QA2 with C_i V_i = 0); ours carries V_i'K_i C_i V_i,
        # round-off of size |K_i| |C_i| eps: part of the formation scale in cross-checks
        self.kc = max(norm2(K) * norm2(C) for K, C in zip(Ks, Cs))
        self.nbar = sum(self.sizes)
        # eq. (split_AV): Abar V = V Atil ; eq. (split_QA): Q Abar = Abar_V Q
        self.Atil = self.V.T @ self.Abar @ self.V
        self.AbarV = self.Q @ self.Abar @ self.Q.T
        # |Q Abar V|: how far span V is from Abar-invariant (0 up to round-off unless a weak direction was left out)
        self.leak = norm2(self.Q @ self.Abar @ self.V) if self.nbar and self.Q.shape[0] else 0.0
        self.I = np.eye(self.m * self.n)

    def Sbar(self, S: np.ndarray) -> np.ndarray:
        return np.kron(S, np.eye(self.n))

    def B(self, S: np.ndarray) -> np.ndarray:
        """``B = V' Sbar V`` (eq. split_discrete_ench)."""
        return self.V.T @ self.Sbar(S) @ self.V

    def discrete_error(self, S: np.ndarray, q: int) -> np.ndarray:
        """eq. (split-discrete-error): ``Abar (I - P(I - Sbar))^q``."""
        return self.Abar @ np.linalg.matrix_power(self.I - self.P @ (self.I - self.Sbar(S)), q)

    def continuous_error(self, S: np.ndarray, g: float) -> np.ndarray:
        """eq. (split_continuous_em): ``Abar - g P (I - Sbar)``."""
        return self.Abar - g * self.P @ (self.I - self.Sbar(S))

    def g_bound(self, S: np.ndarray) -> float:
        """eq. (g) with ``H = blockdiag(pi_i I_{n_i})`` and ``L = 2 Pi - Pi S - S' Pi``."""
        pi = perron(S)
        H = np.diag(np.repeat(pi, self.sizes))
        Pi = np.diag(pi)
        L = 2 * Pi - Pi @ S - S.T @ Pi
        M = self.rate * np.eye(self.nbar) + self.Atil
        num = np.linalg.eigvalsh(H @ M + M.T @ H)[-1]
        den = np.linalg.eigvalsh(self.V.T @ np.kron(L, np.eye(self.n)) @ self.V)[0]
        assert den > 0, "V'(L (x) I)V must be positive definite (prop. split_continuous_stable)"
        return max(num, 0.0) / den


def expected_S(sc, graph) -> np.ndarray:
    """``S`` from the scenario's arcs, by hand (agent i hears j: arc ``(j, i)``; self-arcs implicit).

    Uniform: row i averages i and its in-neighbours, ``S = D^-1 Adj'``.  Metropolis (undirected):
    ``S_ij = 1 / (1 + max(d_i, d_j))`` for neighbours, ``S_ii = 1 - sum_j S_ij``.
    """
    pos = {a: k for k, a in enumerate(sc.agent_ids)}
    hears = [{i} for i in range(sc.m)]
    for j, i in sc.graph(graph.name).arcs:
        hears[pos[i]].add(pos[j])
    S = np.zeros((sc.m, sc.m))
    for i in range(sc.m):
        if sc.design.weights == "metropolis":
            for j in hears[i] - {i}:
                S[i, j] = 1.0 / (1 + max(len(hears[i]), len(hears[j])) - 1)
            S[i, i] = 1.0 - S[i].sum()
        else:
            S[i, sorted(hears[i])] = 1.0 / len(hears[i])
    return S


def _bucket(k: int) -> str:
    return "0" if k == 0 else "1" if k == 1 else "2-9" if k < 10 else "10-99" if k < 100 else "100+"


def designed(drawn, **kw):
    """Design the drawn scenario; record its shape for ``--hypothesis-show-statistics``."""
    sc = parse_scenario(drawn.data)
    try:
        dsg = design(sc, **kw)
    except AssumptionError as exc:
        # a rank_tol far below the default counts directions seen with a margin of 1e-12 as observable; pole
        # placement on such a part is not accurate, and the design refuses it in one line (CI's test-kernels drew
        # one: poles at 0.39 asked inside 0.34 / 2).  Not a certificate to check: another example
        reject = "do not meet rate" in str(exc) and isinstance(sc.design.rank_tol, float) and sc.design.rank_tol < 1e-6
        if not reject:
            raise
        event("refused: placement inaccurate on a weakly observable part (rank_tol < 1e-6)")
        assume(False)
    nbar = sum(V.shape[1] for V in dsg.Vs)
    event(f"m={sc.m}")
    event(f"n={sc.n}")
    event(f"nbar={_bucket(nbar)}")
    event(f"gains={sc.design.gains}, graphs={len(sc.graphs)}, weights={sc.design.weights}")
    if sc.time == "discrete":
        event(f"q_method={sc.design.q_method}, q={_bucket(dsg.q)}")
    else:
        event(f"g certified by {dsg.g_certified_by}")
    return dsg


# --------------------------------------------------------------------------
# 1. local decomposition and gains
# --------------------------------------------------------------------------


@settings(max_examples=examples(140), **COMMON)
@given(scenarios())
def test_local_decomposition_and_gains(drawn):
    """V_i orthonormal and exactly the constructed unobservable space, C_i V_i = 0, eq. (QA2), rates, S."""
    dsg = designed(drawn)
    sc = dsg.scenario
    n = sc.n
    A, Cs, Ks, Ps, Vs = working(dsg)
    for k, (agent, C, K, P, V) in enumerate(zip(dsg.agents, Cs, Ks, Ps, Vs)):
        # the construction fixes the unobservable space: span of T's unowned-block columns (the user's coordinates;
        # in the working ones that is its image D^-1 W)
        W = drawn.expected_V_basis(k)
        assert np.allclose(agent.V_user @ agent.V_user.T, W @ W.T, atol=1e-8)
        W = W if dsg.scale is None else np.linalg.qr(W / dsg.scale[:, None])[0]
        assert V.shape == (n, W.shape[1])
        assert np.allclose(V.T @ V, np.eye(V.shape[1]), atol=1e-9)
        assert np.allclose(P, W @ W.T, atol=1e-8)
        # C_i V_i = 0 ; P_i = V_i V_i' symmetric idempotent
        assert np.allclose(C @ V, 0, atol=1e-9 * max(1.0, np.linalg.norm(C, 2)))
        assert np.allclose(P, V @ V.T, atol=1e-12)
        assert np.allclose(P, P.T, atol=1e-12) and np.allclose(P @ P, P, atol=1e-9)
        # eq. (QA2): (A + K_i C_i) V_i = V_i A_i, i.e. (I - P_i)(A + K_i C_i) V_i = 0
        F = A + K @ C
        scale = 1.0 + np.linalg.norm(A, 2) + np.linalg.norm(K, 2) * np.linalg.norm(C, 2)
        assert np.allclose((np.eye(n) - P) @ F @ V, 0, atol=1e-9 * scale)
        # the observable part Q_i (A + K_i C_i) Q_i' meets the rate (gains.py, meets_rate)
        Qt = complement(V)
        if Qt.shape[1]:
            F_obs = Qt.T @ F @ Qt
            iv = abscissa_interval(F_obs) if sc.time == "continuous" else radius_interval(F_obs)
            bound = -sc.design.rate if sc.time == "continuous" else sc.design.rate
            assert iv[1] < bound + (iv[2] - iv[1]), (iv, bound)
    # S of every graph as the paper defines it
    for graph in dsg.graphs:
        assert np.allclose(graph.S, expected_S(sc, graph), rtol=0, atol=1e-15)


# --------------------------------------------------------------------------
# 2. discrete: the full error matrix and the chosen q's certificate
# --------------------------------------------------------------------------


@settings(max_examples=examples(170), **COMMON)
@given(scenarios(time="discrete"))
def test_discrete_error_matrix_meets_rate(drawn):
    """The full error matrix of eq. (split-discrete-error) splits (eq. split_discrete_as) and meets the rate."""
    dsg = designed(drawn)
    full, res, q = Full(dsg), dsg.q_result, dsg.q
    assert res.certified, f"auto q = {q} is not certified by {res.method} (bound {res.bound})"
    # the gains put the observable part strictly inside the rate: rho(blockdiag(Abar_i + Kbar_i Cbar_i))
    rho_obs = radius_interval(full.AbarV)
    assert rho_obs[0] < full.rate
    rho_V = {}
    for graph in dsg.graphs:
        M = full.discrete_error(graph.S, q)
        tol = 1e-9 * (1.0 + norm2(M))
        # eqs. (split_discrete_xpr1), (split_discrete_xpr2): V is invariant, Q M = Abar_V Q
        AV = full.V.T @ M @ full.V
        exact = full.leak <= tol
        if exact:  # else a weak direction was left to consensus: see test_continuous_g_meets_rate
            assert np.allclose(M @ full.V, full.V @ AV, atol=tol)
            assert np.allclose(full.Q @ M, full.AbarV @ full.Q, atol=tol)
            # eq. (split_discrete_ench): A_V = Atil B^q
            assert np.allclose(AV, full.Atil @ np.linalg.matrix_power(full.B(graph.S), q), atol=tol)
        else:
            event("split inexact (a weak direction left to consensus)")
        # eq. (split_discrete_as): spec(M) = spec(Abar_V) U spec(A_V)
        B = full.B(graph.S)
        h = np.repeat(perron(graph.S), full.sizes)
        rho_V[graph.name] = radius_interval(AV, (norm2(full.Atil) + full.kc) * power_scale(B, q, h))
        rho_M = radius_interval(M)
        split = top(rho_obs, radius_interval(AV))
        if exact:
            assert same(rho_M, split, 1e-9 * (1 + norm2(M))), (rho_M, split)
        # the certificate bounds (or is) the spectral radius, for each graph held constant
        assert rho_M[1] < full.rate + (rho_M[2] - rho_M[1])
        # the library's radius of A_V = Atil B^q (formed from its Gram matrices)
        lib = dsg.error_radius[graph.name]
        assert same((lib, lib, lib), rho_V[graph.name], 1e-12), (lib, rho_V[graph.name])
    worst = top(*rho_V.values())
    if res.method == "spectral":
        assert same((res.bound,) * 3, worst, 1e-12), (res.bound, worst)
        # q is the smallest that works for every graph
        if q > 1:
            before = top(*(radius_interval(full.Atil @ np.linalg.matrix_power(full.B(g.S), q - 1))
                           for g in dsg.graphs))
            assert before[2] >= full.rate, before
    else:
        assert worst[0] <= res.bound * (1 + 1e-9) + 1e-12


# --------------------------------------------------------------------------
# 4. discrete: every q method's certificate, recomputed; switching products
# --------------------------------------------------------------------------


def _product_check(full, dsg, q: int, seq, *, reduced_bound):
    """Products of switching error matrices decay at the certified rate (eq. split-discrete-phi).

    ``reduced_bound(tau)`` bounds ``|Psi(tau)|_2`` for the product ``Psi`` of ``A_V(s)``.  On the
    full product ``Phi = M_tau ... M_1`` (block triangular in ``T = [Q', V]``, orthogonal) the triangle
    inequality gives ``|Phi|_2 <= c rate^tau`` with ``c`` from ``|Abar_V^j|`` and the coupling blocks.
    """
    lam = full.rate
    Ms = [full.discrete_error(dsg.graphs[k].S, q) for k in seq]
    Phi = np.eye(full.m * full.n)
    Psi = np.eye(full.nbar)
    # forward round-off of the products: sum_k |M_tau..M_(k+1)| |M_k| |Phi(k-1)| (a leak out of V at
    # step k is carried by the later factors, which can be large before they contract)
    norms_before, err = [], []
    for tau, M in enumerate(Ms, start=1):
        norms_before.append(norm2(M) * norm2(Phi))
        Phi = M @ Phi
        Psi = (full.V.T @ M @ full.V) @ Psi
        tail = np.eye(full.m * full.n)
        scale = norms_before[-1]
        for k in range(tau - 1, 0, -1):
            tail = tail @ Ms[k]
            scale += norm2(tail) * norms_before[k - 1]
        err.append(1e-12 * (1 + scale))
        # Phi V = V Psi: the product never leaves V (eq. split_discrete_xpr2 for every step)
        assert np.allclose(Phi @ full.V, full.V @ Psi, atol=err[-1])
        assert norm2(Psi) <= reduced_bound(tau) * (1 + 1e-8) + err[-1]
    # full product: |Phi(tau)| <= |Abar_V^tau| + |Psi(tau)| + sum_k |Psi(tau..k+1)| |C_k| |Abar_V^(k-1)|
    a = [norm2(np.linalg.matrix_power(full.AbarV, j)) for j in range(len(Ms) + 1)]
    coup = max(norm2(full.V.T @ M @ full.Q.T) for M in Ms)
    Phi = np.eye(full.m * full.n)
    for tau, M in enumerate(Ms, start=1):
        Phi = M @ Phi
        c = (a[tau] / lam**tau + reduced_bound(tau) / lam**tau
             + sum(reduced_bound(tau - k) / lam ** (tau - k) * coup * a[k - 1] / lam**k for k in range(1, tau + 1)))
        assert norm2(Phi) <= c * lam**tau * (1 + 1e-8) + err[tau - 1]


@settings(max_examples=examples(120), **COMMON)
@given(scenarios(time="discrete"), st.data())
def test_discrete_q_certificates_from_full_matrices(drawn, data):
    """Each q method's certificate (spectral, eq. rnorm, two-norm, eqs. rajit*) holds; switching products decay."""
    dsg = designed(drawn, compare_q_methods=True)
    full = Full(dsg)
    lam, m, sizes = full.rate, full.m, full.sizes
    Bs = {g.name: full.B(g.S) for g in dsg.graphs}
    for method, res in dsg.q_methods.items():
        assert not isinstance(res, str), f"{method}: {res}"
        assert res.certified and certifies(res.bound, lam), f"{method}: q = {res.q} not certified (bound {res.bound})"
        # below: each bound recomputed independently is below the rate too (strictly: the one rule's margin, 1e-6
        # relative, exceeds the two paths' round-off)
        q = res.q
        if method == "two-norm":
            # max over graphs |Atil B^q|_2 < rate bounds every switching product
            vals = [norm2(full.Atil @ np.linalg.matrix_power(B, q)) for B in Bs.values()]
            assert max(vals, default=0.0) == pytest.approx(res.bound, rel=1e-7, abs=1e-12)
            assert max(vals, default=0.0) < lam
            assert res.p * res.pbar == q
        elif method == "mixed":
            # eqs. (rajit), (rajit2), (rajit3): q = p pbar, ||B^p|| < 1, ||Atil|| ||B^p||^pbar < rate
            assert res.p * res.pbar == q and res.p >= 1
            na = mixed_norm(full.Atil, sizes, sizes)
            for B in Bs.values():
                if not full.nbar:
                    continue
                nbp = mixed_norm(np.linalg.matrix_power(B, res.p), sizes, sizes)
                assert nbp < 1.0
                assert na * nbp**res.pbar < lam
                assert mixed_norm(full.Atil @ np.linalg.matrix_power(B, q), sizes, sizes) < lam
        elif method == "weighted":
            # eq. (rnorm) with R = V'(Pi (x) I)V = block_diagonal(pi_i I_{n_i}), pi the Perron vector of S
            for g in dsg.graphs:
                pi = perron(g.S)
                assert np.all(pi > 0)
                # lem. split_discrete_brian: Pi - S' Pi S >= 0
                assert np.linalg.eigvalsh(np.diag(pi) - g.S.T @ np.diag(pi) @ g.S)[0] >= -1e-12
                if not full.nbar:
                    continue
                r = np.sqrt(np.repeat(pi, sizes))
                wnorm = lambda X: norm2(r[:, None] * X / r[None, :])  # noqa: E731
                nb = wnorm(Bs[g.name])
                assert nb < 1.0  # eq. (ino)
                assert wnorm(full.Atil) * nb**q < lam
        else:  # spectral
            for B in Bs.values():
                iv = radius_interval(full.Atil @ np.linalg.matrix_power(B, q))
                assert iv[1] < lam + 1e-9 + (iv[2] - iv[1]), (iv, lam)
    if not full.nbar or full.leak > 1e-9 * (1 + norm2(full.Abar)):
        return  # (an inexact split, a weak direction left to consensus: the products' bounds assume V invariant)
    # switching products over random graph sequences (two-norm and mixed certify arbitrary switching)
    seq = data.draw(graph_sequences(len(dsg.graphs)), label="graph sequence")
    two, mixed = dsg.q_methods["two-norm"], dsg.q_methods["mixed"]
    _product_check(full, dsg, two.q, seq, reduced_bound=lambda tau: lam**tau)
    # |X|_2 <= |<X>|_2 <= sqrt(|<X>|_1 |<X>|_inf) <= sqrt(m) ||X|| (mixed norm, submultiplicative)
    _product_check(full, dsg, mixed.q, seq, reduced_bound=lambda tau: (math.sqrt(m) if tau else 1.0) * lam**tau)


# --------------------------------------------------------------------------
# 3, 5. continuous: g, g_min, g_bound on the full error matrix
# --------------------------------------------------------------------------


def mode_at_the_rate_seen_once() -> Drawn:
    """CI's draw (make test): ``A = -0.2`` at rate 0.2 seen by agent 1 of a ring of seven (rank_tol 1e-12, place):
    the others' error decays at exactly the rate when g = 0, and faster for every g > 0."""
    arcs = [[k, k % 7 + 1] for k in range(1, 8)] + [[k % 7 + 1, k] for k in range(1, 8)]
    data = {"name": "drawn", "time": "continuous",
            "system": {"A": [[-0.2]], "C": {k: [[-1.0 if k == 1 else 0.0]] for k in range(1, 8)}},
            "graphs": {"g1": {"arcs": arcs}},
            "design": {"rate": 0.2, "gains": "place", "margin": 0.5, "rank_tol": 1e-12}}
    return Drawn(data=data, T=np.eye(1), edges=(0, 1), owned=(frozenset({0}),) + (frozenset(),) * 6)


@settings(max_examples=examples(110), **COMMON)
@given(scenarios(time="continuous"))
@example(mode_at_the_rate_seen_once())
def test_continuous_g_meets_rate(drawn):
    """The full matrix of eq. (split_continuous_em) meets the rate at g; eq. (g) is sufficient; g_min is tight."""
    dsg = designed(drawn)
    full, lam, g = Full(dsg), dsg.rate, dsg.g
    assert dsg.g_mode == "auto" and g is not None and g >= 0
    a_obs = abscissa_interval(full.AbarV)
    assert a_obs[0] < -lam
    for graph in dsg.graphs:
        S = graph.S
        Sbar = full.Sbar(S)

        def AV(gain):
            # eq. (split_continuous_split): A_V = Atil - g V'(I - Sbar)V, from the full matrix
            return full.V.T @ full.continuous_error(S, gain) @ full.V

        # 3. the full error matrix at the design's g decays at the rate, for each graph held constant
        M = full.continuous_error(S, g)
        tol = 1e-9 * (1.0 + norm2(M))
        assert np.allclose(AV(g), full.Atil - g * full.V.T @ (full.I - Sbar) @ full.V, atol=tol)
        a_M, a_V = abscissa_interval(M), abscissa_interval(AV(g))
        if full.leak <= tol:
            # the split is exact to round-off: M is block triangular in (V, Q') and its spectrum is that of the blocks
            assert np.allclose(M @ full.V, full.V @ AV(g), atol=tol)
            assert np.allclose(full.Q @ M, full.AbarV @ full.Q, atol=tol)
            assert same(a_M, top(a_obs, a_V), 1e-9 * (1 + norm2(M))), (a_M, a_obs, a_V)
        else:
            # a direction seen above round-off but below rank_tol was left to consensus (Decomposition.weak): V_i is
            # only nearly A-invariant and the identities hold up to the leak; the design's guarantee is then the
            # full error matrix's rate, checked below (CI's test-kernels drew one: rank_tol 1e-12, margin 4.5e-10,
            # leak 1.9e-6)
            event("split inexact (a weak direction left to consensus)")
        assert a_M[1] <= -lam + 1e-7 + (a_M[2] - a_M[1]), (a_M, -lam)
        if full.nbar:
            lib = dsg.error_radius[graph.name]
            formed = abscissa_interval(AV(g), norm2(full.Atil) + full.kc + g * (1 + norm2(full.B(S))))
            assert same((lib,) * 3, formed, 1e-12), (lib, formed)
        # 5. eq. (g) is what the paper says, and sufficient (it can be tight: then A_V(g_bound)
        # sits on the boundary and only round-off separates it from -rate)
        gb = full.g_bound(S) if full.nbar else 0.0
        assert dsg.g_bounds[graph.name] == pytest.approx(gb, rel=1e-7, abs=1e-12)
        if full.nbar:
            at_gb = abscissa_interval(AV(gb))
            assert at_gb[1] <= -lam + 1e-9 + (at_gb[2] - at_gb[1]), (at_gb, -lam)
            at_gb = abscissa_interval(full.continuous_error(S, gb))
            assert at_gb[1] <= -lam + 1e-7 + (at_gb[2] - at_gb[1]), (at_gb, -lam)
        # 3. the exact smallest g (bisection, rtol 1e-6) sits on the boundary
        gm = dsg.g_mins[graph.name]
        assert gm >= 0
        if gm > gb * (1 + 2e-6) + 1e-9:
            # the strict rule (spectral.certifies): at eq. (g)'s bound the error decays only at the rate (a part no
            # gain moves, decaying exactly at it), which certifies nothing: the smallest g is a hair above the bound
            at_gb = abscissa_interval(AV(gb))
            assert at_gb[2] >= -lam * (1 + 1e-5) and gm <= gb + 1e-4 * (1 + lam), (gm, gb, at_gb, -lam)
        at_gm = abscissa_interval(AV(gm))
        if gm == 0:
            assert at_gm[0] <= -lam
        else:
            assert same(at_gm, (-lam,) * 3, 1e-4 * (1 + gm)), (at_gm, -lam)
        # ... and is the smallest: no g on a grid below it meets the rate (bisection assumes one crossing)
        if gm > 0 and full.nbar:
            for x in np.linspace(0.0, gm * (1 - 1e-3), 41):
                below = abscissa_interval(AV(x))
                # by the one rule the bisection used (spectral.certifies, a margin of 1e-6 |lam|): a g below gm may
                # meet the rate by less than the margin (CI drew A = -0.2 at rate 0.2 seen by one agent of seven:
                # every g > 0 beats the rate, at g = 7.6e-8 by 5e-9; gm = 3e-6 is the first g to beat it by the margin)
                assert below[2] >= -lam * (1 + CERTIFY_MARGIN) - 1e-9, (x, gm, below, -lam)


@settings(max_examples=examples(80), **COMMON)
@given(scenarios(time="continuous", graphs=2), st.data())
def test_continuous_switching_certificates(drawn, data):
    """thm:arb (doubly stochastic S) and eq. (split_continuous_g) (average dwell time), from full matrices."""
    dsg = designed(drawn)
    full, lam, g, by = Full(dsg), dsg.rate, dsg.g, dsg.g_certified_by
    cases = {c.label for c in dsg.cases}
    graphs = [gr for gr in dsg.graphs if gr.name in cases]
    if not full.nbar:
        return
    I = np.eye(full.nbar)
    Ms = {gr.name: I - full.B(gr.S) for gr in graphs}  # V'(I - Sbar)V
    norm_a = norm2(full.Atil)
    sym = lambda X: X + X.T  # noqa: E731
    # thm:arb: g >= lam_max((lam I + Atil) + (.)') / min lam_min(V'((2I - S - S') (x) I)V)
    if all(np.allclose(gr.S.sum(axis=0), 1.0, atol=1e-12) for gr in graphs):
        num = max(np.linalg.eigvalsh(sym(lam * I + full.Atil))[-1], 0.0)
        den = min(np.linalg.eigvalsh(full.V.T @ np.kron(2 * np.eye(full.m) - gr.S - gr.S.T, np.eye(full.n)) @ full.V)[0]
                  for gr in graphs)
        assert dsg.g_arbitrary == pytest.approx(num / den, rel=1e-7, abs=1e-12)
    else:
        assert dsg.g_arbitrary is None
    # eq. (split_continuous_g): |exp(-V'(I - Sbar)V t)| <= c exp(-lam_star t) from the H-Lyapunov function
    # (H = block_diagonal(pi_i I_{n_i}) (eq. H): agents with n_i = 0 carry no weight)
    c, lam_star = 1.0, math.inf
    for gr in graphs:
        pi = perron(gr.S)
        h = np.repeat(pi, full.sizes)
        c = max(c, math.sqrt(h.max() / h.min()))
        Pi = np.diag(pi)
        VLV = full.V.T @ np.kron(2 * Pi - Pi @ gr.S - gr.S.T @ Pi, np.eye(full.n)) @ full.V
        lam_star = min(lam_star, np.linalg.eigvalsh(VLV)[0] / (2 * h.max()))
    for gr in graphs:
        for t in (0.01, 0.1, 0.5, 1.0, 3.0):
            assert norm2(sla.expm(-Ms[gr.name] * t)) <= c * math.exp(-lam_star * t) * (1 + 1e-9) + 1e-12
    tau_d = dsg.dwell
    if tau_d is not None:
        g_dw = (math.log(c) + (lam + norm_a * c) * tau_d) / (lam_star * tau_d)
        assert dsg.g_dwell == pytest.approx(g_dw, rel=1e-7)
    # the auto g covers the certificate it names
    assert by in ("thm:arb", "eq:split_continuous_g", None)
    if by is None:
        assert any("not certified for switching" in w for w in dsg.warnings)
        return
    cert = dsg.g_arbitrary if by == "thm:arb" else dsg.g_dwell
    assert g >= cert
    # switching products of exp(A_V(g) t) over random signals decay like exp(-lam T)
    k = len(graphs)
    pieces = data.draw(st.lists(st.tuples(st.integers(0, k - 1), st.floats(1.0, 3.0)), min_size=1, max_size=8),
                       label="switching signal (graph, duration / dwell)")
    scale = tau_d if by == "eq:split_continuous_g" else data.draw(st.floats(0.01, 1.0), label="time unit")
    Psi, T = I, 0.0
    for idx, f in pieces:
        AV = full.Atil - g * Ms[graphs[idx].name]
        if by == "thm:arb":
            # common Lyapunov function |z|^2: (lam I + A_V) + (lam I + A_V)' <= 0 for every graph
            assert np.linalg.eigvalsh(sym(lam * I + AV))[-1] <= 1e-9 * (1 + g)
        Psi = sla.expm(AV * f * scale) @ Psi
        T += f * scale
        assert norm2(Psi) <= math.exp(-lam * T) * (1 + 1e-6) + 1e-12


def test_weighted_q_is_certified_at_a_round_off_tie():
    """Regression (found by test_discrete_q_certificates_from_full_matrices).

    ``||Atil||_R = 1`` (rotations) and ``||B||_R = 1/2`` at rate 1/2 make eq. (rnorm) an exact tie at
    q = 1; evaluated, the ratio came out 1 + 6e-16, the ``- 1e-12`` in the ceiling kept q = 1, and
    ``||Atil||_R ||B||_R = 0.5000000000000002 > 0.5`` left the auto q uncertified (with a "does NOT
    meet rate" warning).  q_weighted and q_mixed now step up until their bound holds as evaluated.
    """
    w1, w2, w3 = 0.25, 0.45, 0.65
    rot = [[[math.cos(w), math.sin(w)], [-math.sin(w), math.cos(w)]] for w in (w1, w2, w3)]
    A = sla.block_diag(*rot, np.diag([-0.9, -0.7]))
    data = {
        "time": "discrete",
        "system": {"A": A.tolist(), "C": {1: [[1, 0, 1, 0, 1, 0, -1, -1]], 2: [[1, 0, 1, 0, 0, 0, 0, 0]],
                                          3: [[0, 0, 0, 0, 1, 0, -1, -1]]}},
        "graphs": {"g1": {"arcs": [[1, 2], [2, 3], [3, 1]]}},
        "design": {"rate": 0.5, "gains": "place", "q_method": "weighted"},
    }
    dsg = design(parse_scenario(data), compare_q_methods=True)
    for method, res in dsg.q_methods.items():
        assert res.certified and certifies(res.bound, 0.5), (method, res)
    assert not dsg.warnings


# --------------------------------------------------------------------------
# 1'. rank decisions with nearly dependent outputs (observability.py)
# --------------------------------------------------------------------------


@pytest.mark.parametrize("rank_tol", [1e-9, "auto"])
@settings(max_examples=examples(50), **COMMON)
@given(data=st.data())
def test_nearly_dependent_outputs_keep_the_unobservable_space(rank_tol, data):
    """Two sensors of the same quantity (rows 1e-4..1e-10 apart) do not make the rest observable.

    Regression: with rows 5e-8 apart on one 2x2 block, round-off of the weakly determined second
    direction (~eps / 5e-8) leaked through ``A'`` above ``rank_tol`` and an agent seeing one block
    was declared to see all ten (the design then failed in pole placement).  The construction's
    unobservable space always lies in ``V_i``; ``V_i`` may be larger only by directions whose graded
    margin is too small to tell from round-off or from the threshold, and then ``weak`` or the
    threshold says so (an agent seeing 8 real modes through one row has margins down to ~1e-5).
    """
    drawn = data.draw(scenarios(near_dependent=True, rank_tol=rank_tol), label="scenario")
    sc = parse_scenario(drawn.data)
    d = sc.design
    A = sc.system.A
    for k, C in enumerate(sc.system.Cs):
        dec = decompose(A, C, rank_tol=d.rank_tol)
        W = drawn.expected_V_basis(k)
        assert dec.V.shape[1] >= W.shape[1], (dec.V.shape, W.shape)  # never more observable than it is
        # the subspace is as accurate as C_i's conditioning allows
        sv = np.linalg.svd(C, compute_uv=False)
        kept = sv[sv > threshold_of(d.rank_tol) * sv[0]]
        kappa = kept[0] / kept[-1] if kept.size else 1.0
        tol = min(1e-8 * kappa, 1.0)
        # span W inside span V_i (W may have no column: numpy 2.0's norm refuses an empty matrix)
        assert (np.linalg.norm(W - dec.P @ W, 2) if W.size else 0.0) <= tol
        if dec.V.shape == W.shape:
            assert np.linalg.norm(dec.P - W @ W.T, 2) <= tol
        else:  # the extra directions were seen too weakly to count: the construction's observable space is
            # seen with a margin of the order of the threshold at most (smallest singular value of the scaled
            # observability matrix [C; C S; C S^2; ...] on it, S = (A - aI) / ||A - aI||, C / ||C||)
            Wo = np.linalg.qr(W, mode="complete")[0][:, W.shape[1]:] if W.shape[1] else np.eye(sc.n)
            S = A - np.trace(A) / sc.n * np.eye(sc.n)
            S = S / np.linalg.norm(S, 2)
            R, rows = C / np.linalg.norm(C, 2), []
            for _ in range(sc.n):
                rows.append(R)
                R = R @ S
            smin = np.linalg.svd(np.vstack(rows) @ Wo, compute_uv=False).min()
            assert smin < 3 * max(threshold_of(d.rank_tol), 1e-6), smin
            event("an owned direction left to consensus (weak)")


# --------------------------------------------------------------------------
# the two eigenvalue paths of the spectral q (splitspec_core.synthesis.spectral)
# --------------------------------------------------------------------------


@settings(max_examples=examples(60), **COMMON)
@given(scenarios(time="discrete", q_method="spectral"), st.sampled_from([0, 1]))
def test_spectral_q_is_the_same_on_both_eigenvalue_paths(drawn, resilience):
    """``design.eigenvalues: dense`` and ``iterative`` (ARPACK on the matrix-free operator): the same q, the
    same verdict, every case's radius within the accuracy its computation claims, and the design says which
    path computed what."""
    data = {**drawn.data, "design": {**drawn.data["design"], "resilience": resilience}}
    outs = {}
    for how in ("dense", "iterative"):
        drawn_how = dataclasses.replace(drawn, data={**data, "design": {**data["design"], "eigenvalues": how}})
        try:
            outs[how] = designed(drawn_how)
        except (AssumptionError, DesignError) as exc:  # e.g. a network not redundant enough: the same refusal
            outs[how] = str(exc)
    dense, it = outs["dense"], outs["iterative"]
    if isinstance(dense, str) or isinstance(it, str):
        assert dense == it
        return
    assert it.q == dense.q and it.q_result.certified == dense.q_result.certified
    for case in it.cases:  # each radius within the accuracy ARPACK's answer claims (Radius.tol)
        how = case._how.get(it.q)
        if how is not None:
            d = dense.error_radius[case.label]
            # + 1e-7: the dense value's own error on a double defective eigenvalue, ~sqrt(eps) = 1.5e-8 (a drawn
            # example: dense 0.2500000049, ARPACK 0.2500000013, the exact radius 0.25)
            assert abs(how.value - d) <= (how.tol + 1e-7) * max(d, how.value), (case.label, how, d)
    assert set(dense.q_result.eig["methods"]) <= {"dense"}  # empty when no agent leaves anything to consensus
    assert set(it.q_result.eig["methods"]) <= {"iterative", "dense", "dense (fallback)"}
