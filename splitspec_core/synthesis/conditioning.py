"""What a certificate does not say: observability margins, gain sizes, transient peaks and noise.

A certificate bounds the *rate* at which the errors decay; it says nothing of their *size* on the way.
With the fixed-graph error dynamics ``e(k+1) = M e(k)`` the whole story is

``||e(k)|| <= c r^k ||e(0)||``,  ``c = sup_k ||M^k||_2 / r^k``

(``r = lam`` per event time in discrete time; ``r = exp(-lam dt)`` per step of the sampled-data form
that ``simulate`` and ``run`` execute in continuous time).  ``c`` (``transient_constant``) is 1 for a
contraction and can be 1e8 for a design whose local gains are huge: that is what a model rounded to a
few decimals used to produce before the rank decisions fit the data (:mod:`splitspec_core.model.observability`).

``M`` is the full error matrix of one step, every agent's error stacked
(:func:`splitspec_core.synthesis.error_matrix.full_error_matrix`), of a graph held constant.

``c`` is computed exactly (up to round-off): ``X_k = (M / r)^k`` is formed until ``||X_N||_2 <= 1``;
every later power is then a product of ``X_N`` and an earlier one, so the supremum is the largest
norm seen before ``N``.  When that takes more than :data:`MAX_WORK` flops the bound of the
Lyapunov function of ``M / r`` is used instead (``c <= sqrt(cond(P))``, ``(M/r)' P (M/r) - P = -I``),
and ``transient_method`` says so.  Above ``mn = MAX_DIM`` nothing is formed (``None``).

The report also carries, when the scenario has noise, the predicted steady-state RMS error of every
agent (:func:`splitspec_core.synthesis.error_matrix.predicted_rms`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .design_data import Design, cached_analysis
from .error_matrix import MAX_DIM, MAX_NOISE_DIM, case_parts, full_error_matrix, modulo, predicted_rms
from .kalman import references
from .approximate import misses_on_full

__all__ = ["AgentConditioning", "Conditioning", "Transient", "conditioning", "transient_constant",
           "time_scale_warning", "MARGIN_WARN", "GAIN_WARN", "TRANSIENT_WARN", "TIME_SCALE_WARN"]

#: a kept direction with a graded margin below this is warned about (10 x the default threshold)
MARGIN_WARN = 1e-2
#: ``||K_i C_i||_2`` above this many times the system's own scale is warned about
GAIN_WARN = 1e3
#: a transient constant above this is warned about
TRANSIENT_WARN = 1e3
#: the work (flops) spent on the exact transient constant before falling back to the Lyapunov bound
MAX_WORK = 1e11
#: and the powers formed at most (a small error map costs Python's overhead per power, not flops: 1e11 flops were
#: 2.3e8 powers of a 6 x 6 map, minutes; this many take about a second)
MAX_POWERS = 200_000


@dataclass(frozen=True)
class Transient:
    """``sup_k ||M^k||_2 / r^k`` (``constant``), the step attaining it, the agent whose error peaks there, how."""

    constant: float | None
    step: int | None
    agent_index: int | None
    method: str


def transient_constant(M: np.ndarray, r: float, *, block: int = 1, max_work: float = MAX_WORK) -> Transient:
    """The transient constant of ``e(k+1) = M e(k)`` at rate ``r`` per step (module docstring).

    ``block``: the size of each agent's block of rows (the agent whose rows peak is reported).  The powers are
    formed once each, with only their Frobenius norms kept (an upper bound of the 2-norm); once one falls below 1 the
    2-norms of the candidates, largest Frobenius norm first, are computed until no remaining one can exceed the
    largest 2-norm found (:func:`_sup_two_norm`).

    Parameters
    ----------
    M : (d, d) array
        The error map of one step.
    r : float
        The rate per step (``lam``, or ``exp(-lam dt)``).
    block : int
        Rows per agent in ``M`` (``d`` a multiple of it).
    max_work : float
        Flops spent on the exact constant before the Lyapunov bound is taken instead.

    Returns
    -------
    Transient
        ``constant`` (1.0 for an empty ``M``; ``inf`` when ``rho(M) >= r``), the step ``k`` attaining it, the index
        of the agent whose rows peak there, and ``method`` (``exact``, the Lyapunov bound and why, or why infinite).

    Examples
    --------
    >>> t = transient_constant(np.array([[0.5, 10.0], [0.0, 0.5]]), 0.9)
    >>> round(t.constant, 3), t.step, t.method
    (12.353, 2, 'exact')
    >>> transient_constant(np.array([[1.5]]), 0.9).method
    'infinite: the spectral radius 1.5 is not below 0.9'
    """
    d = M.shape[0]
    if d == 0:
        return Transient(1.0, 0, None, "exact")
    rho = float(np.max(np.abs(np.linalg.eigvals(M))))
    if not rho < r:
        return Transient(math.inf, None, None, f"infinite: the spectral radius {rho:.4g} is not below {r:.4g}")
    T = M / r
    X = np.eye(d)  # (M / r)^k = exp(logs) X: rescaled now and then, so a huge transient cannot overflow
    logs, logf = 0.0, [0.0]  # log ||T^k||_F (k = 0: the identity counts as 1, its 2-norm)
    steps = int(max(1, min(MAX_POWERS, max_work // max(1.0, 2.0 * d ** 3))))
    # the slowest mode of M / r shrinks by rho(M / r)^steps within the budget: above 1/10 the powers cannot
    # fall below 1 in time unless that mode carries almost nothing, so only a head is formed (a lower bound, the
    # peak it reports) and the Lyapunov bound is taken at once
    hopeless = (rho / r) ** steps > 0.1
    head = max(1, steps // 4) if hopeless else steps
    for k in range(1, head + 1):
        X = T @ X
        f = float(np.linalg.norm(X)) or 1e-300  # 0: nilpotent, nothing after this step
        if not math.isfinite(f):
            return Transient(math.inf, k, None, f"infinite: the power {k} of M / rate overflowed")
        logf.append(math.log(f) + logs)
        # the 2-norm falls below 1 before the Frobenius norm (up to sqrt(d) sooner): looked at every 64 steps
        two = logf[-1] <= 0.5 * math.log(d) and k % 64 == 0 and math.log(float(np.linalg.norm(X, 2))) + logs <= 0.0
        if logf[-1] <= 0.0 or two:
            # ||X_k|| <= 1: any later power is X_k times an earlier one, so the supremum is over the powers so far
            peak, at, rows = _sup_two_norm(T, logf, block)
            return Transient(peak, at, rows, "exact")
        if f > 1e100:
            X /= f
            logs += math.log(f)
    peak, at, rows = _sup_two_norm(T, logf, block)
    import scipy.linalg as sla

    with np.errstate(all="ignore"):
        P = sla.solve_discrete_lyapunov(T.T, np.eye(d))  # T' P T - P = -I
        ev = np.linalg.eigvalsh(0.5 * (P + P.T))
    bound = math.sqrt(ev[-1] / ev[0]) if ev[0] > 0 and np.all(np.isfinite(ev)) else math.inf
    why = (f"the slowest mode decays only {(rho / r) ** -steps:.5g}-fold in the {steps} steps affordable"
           if hopeless else f"the exact peak needed more than {steps} steps")
    return Transient(max(peak, bound), at, rows,
                     f"Lyapunov bound ({why}; the peak of the first {head}: {peak:.3g})")


def _sup_two_norm(T: np.ndarray, logf: list, block: int) -> tuple:
    """``(max_k ||T^k||_2, k, agent index)`` over the powers whose log Frobenius norms are ``logf`` (k = 0, 1, ...).

    The 2-norm is at most the Frobenius norm and at least it over sqrt(d): only the powers whose Frobenius norm
    can beat the largest 2-norm found are looked at, formed again one product at a time as the first pass formed
    them (``T @ X``, rescaled now and then).  Repeated squaring (``matrix_power``) is not used: on a strongly
    non-normal ``T`` its round-off grows with the squares and can overflow where the powers themselves stay
    small.  A power too large to form (its Frobenius norm above 1e300) counts with its Frobenius norm, an upper
    bound."""
    d = T.shape[0]
    lf = np.asarray(logf)
    if lf.max() > 690.0:
        k = int(np.argmax(lf))
        return math.inf, k, None
    floor = float(lf.max()) - 0.5 * math.log(d)  # the largest 2-norm is at least this (log)
    best, at, rows = 1.0, 0, None
    last = int(np.nonzero(lf > max(floor, 0.0))[0].max()) if np.any(lf > max(floor, 0.0)) else -1
    X, logs = np.eye(d), 0.0
    for k in range(0, last + 1):
        if k:
            X = T @ X
        if lf[k] <= math.log(best):
            continue
        with np.errstate(all="ignore"):
            s = float(np.linalg.norm(X, 2)) if np.all(np.isfinite(X)) else math.nan
        if not math.isfinite(s):  # round-off overflowed: the Frobenius norm of the first pass, an upper bound
            return math.exp(lf[k]), k, None
        s *= math.exp(logs)
        if s > best:
            best, at, rows = s, k, np.linalg.norm(X.reshape(d // block, block, d), axis=(1, 2))
        f = float(np.linalg.norm(X))
        if f > 1e100:
            X /= f
            logs += math.log(f)
    return best, at, None if rows is None else int(np.argmax(rows))


# --------------------------------------------------------------------------
# the report
# --------------------------------------------------------------------------


@dataclass(frozen=True)
class AgentConditioning:
    """One agent's local design, sized.

    Attributes
    ----------
    id : agent id
    observability_margin : float or None
        The smallest graded margin of a direction the agent counts as seen (:mod:`splitspec_core.model.observability`);
        None when it sees nothing.
    gain_norm : float
        ``||K_i||_2``.
    gain_ratio : float
        ``||K_i C_i||_2`` over the system's own scale (``max(||A - aI||_2, 1)`` in discrete time,
        ``max(||A - aI||_2, (1 + margin) lam)`` in continuous time): scale-free, warned about above
        :data:`GAIN_WARN`.
    weak : float
        The largest graded margin of a direction left to consensus (0.0 if none).
    split_residual : float
        How far ``V_i`` is from an exact unobservable space (round-off when ``weak`` is 0).
    """

    id: int
    observability_margin: float | None
    gain_norm: float
    gain_ratio: float
    weak: float
    split_residual: float


@dataclass(frozen=True)
class Conditioning:
    """A design sized (module docstring); ``warnings`` are one line each, naming the agent and the knob."""

    agents: tuple
    transient_constant: float | None
    transient_case: str | None
    transient_method: str
    predicted_rms: dict | None  # agent id -> steady-state RMS error (graph ``predicted_graph`` held constant)
    predicted_graph: str | None
    warnings: tuple
    # the references under noise (kalman.references): the centralized Kalman filter's predicted steady RMS, and the
    # rate-shifted one's (kalman.SHIFTED_NAME: certified at the rate, not the best that is; None: no noise, or none)
    kalman_rms: float | None = None
    reference_rms: float | None = None


def _scale(A: np.ndarray) -> float:
    n = A.shape[0]
    return float(np.linalg.norm(A - (np.trace(A) / n) * np.eye(n), 2))


@cached_analysis  # once per design, on first use: the full error matrices cost more than the design at scale
def conditioning(des: Design) -> Conditioning:
    """Margins, gain sizes, the transient constant over the graphs the scenario uses (each held constant),
    and, when the scenario has noise, the predicted steady-state RMS error of the first graph.

    Computed once per design (:func:`~splitspec_core.synthesis.design_data.cached_analysis`).

    Parameters
    ----------
    des : Design
        The design.

    Returns
    -------
    Conditioning
        Per agent its :class:`AgentConditioning`; the largest transient constant over the graphs used (at the
        envelope's rate; None for the adaptive gain or above ``MAX_DIM``), its graph and method; with noise the
        predicted RMS per agent (None above ``MAX_NOISE_DIM`` or adaptive) and the Kalman and reference RMS;
        the warnings.

    Examples
    --------
    >>> import splitspec_core as ss
    >>> from splitspec_core.synthesis.designer import design
    >>> des = design(ss.scenario(A=[[0, 1, 0, 0], [-1, 0, 0, 0], [0, 0, 0, 1], [0, 0, -2, 0]],
    ...                          C={1: [[1, 0, 0, 0]], 2: [[0, 1, 0, 0]], 3: [[0, 0, 1, 0]]},
    ...                          graphs={"a": [(1, 2), (2, 1), (2, 3), (3, 2), (1, 3)]}, rate=0.5, gains="place",
    ...                          process_noise=0.01, measurement_noise=0.1))
    >>> c = conditioning(des)
    >>> round(c.transient_constant, 2), round(c.kalman_rms, 3), c.warnings
    (11.03, 0.25, ())
    """
    sc = des.scenario
    d = sc.design
    # the gain's size against the system's own scale, in the design's working coordinates (the user's, or balanced)
    A = des.A_working
    ref = max(_scale(A), 1.0 if sc.time == "discrete" else (1.0 + d.margin) * d.rate)
    Cs = dict(zip(sc.agent_ids, sc.system.Cs))
    agents = []
    warnings = []
    for a in des.agents:
        C = np.asarray(Cs[a.id]) if des.scale is None else np.asarray(Cs[a.id]) * des.scale[None, :]
        gain_norm = float(np.linalg.norm(a.K, 2)) if a.K.size else 0.0
        ratio = float(np.linalg.norm(a.gain.K @ C, 2)) / ref if a.K.size else 0.0
        ac = AgentConditioning(id=a.id, observability_margin=a.dec.margin, gain_norm=gain_norm, gain_ratio=ratio,
                               weak=a.dec.weak, split_residual=a.dec.split_residual)
        agents.append(ac)
    if des.consensus == "split":  # no local observer in the whole state: margins and local gains are the split's
        warnings += _agent_warnings(agents, more_to_consensus_fails=misses_on_full(des))
    scale_note = time_scale_warning(sc)
    if scale_note:
        warnings.append(scale_note)
    const, case_label, method = _transient(des, warnings)
    rms, graph, kf_rms, ref_rms = None, None, None, None
    s = sc.system
    if s.has_noise:
        if not des.adaptive and (sc.m * sc.n <= MAX_NOISE_DIM or des.consensus == "relay"):  # relay: n x n
            k = sc.graph_names.index(sc.switching.graph_names(sc.graph_names)[0])
            graph = sc.graph_names[k]
            rms = {i: float(v) for i, v in zip(sc.agent_ids, predicted_rms(des, k))}
        kf, ref = references(sc, des.envelope_rate)
        kf_rms, ref_rms = (None if kf is None else kf.rms), (None if ref is None else ref.rms)
    return Conditioning(agents=tuple(agents), transient_constant=const, transient_case=case_label,
                        transient_method=method, predicted_rms=rms, predicted_graph=graph,
                        warnings=tuple(warnings), kalman_rms=kf_rms, reference_rms=ref_rms)


#: a continuous plant whose fastest mode moves less than this fraction per run.dt is told that run.dt is far off
TIME_SCALE_WARN = 1e-4


def _duration(seconds: float) -> str:
    for unit, size in (("h", 3600.0), ("min", 60.0), ("s", 1.0), ("ms", 1e-3)):
        if seconds >= size or unit == "ms":
            return f"{seconds / size:.3g} {unit}"
    return f"{seconds:.3g} s"  # pragma: no cover


def time_scale_warning(sc) -> str | None:
    """A continuous plant whose time constants are far from ``run.dt`` (hours against the default 0.01 s): its
    fastest mode (the largest ``|eig(A)|``) moves less than :data:`TIME_SCALE_WARN` of itself per step, so a run of
    ``run.steps`` steps shows nothing happen; None when they fit (or in discrete time).

    Parameters
    ----------
    sc : Scenario
        Its ``time``, ``system.A``, ``run.dt`` and ``run.steps``.

    Returns
    -------
    str or None
        One line: the time constants against ``run.dt`` and what to set ``run.dt`` near.
    """
    if sc.time != "continuous":
        return None
    ev = np.abs(np.linalg.eigvals(np.asarray(sc.system.A, dtype=float)))
    fastest = float(ev.max()) if ev.size else 0.0
    dt = sc.run.dt
    if fastest == 0.0 or fastest * dt >= TIME_SCALE_WARN:
        return None
    tau = 1.0 / fastest
    slowest = 1.0 / float(ev[ev > 0].min())
    span = _duration(tau) if slowest <= tau * 1.01 else f"{_duration(tau)} to {_duration(slowest)}"
    return (f"the plant's time constants are {span} against run.dt = {_duration(dt)}: a run of {sc.run.steps} steps "
            f"covers {_duration(sc.run.steps * dt)}, {sc.run.steps * dt / tau:.2g} of the fastest; set run.dt near "
            f"a tenth of it ({_duration(tau / 10)}) and design.rate in the plant's units")


def _agents_text(ids) -> str:
    ids = list(ids)
    return f"agent {ids[0]}" if len(ids) == 1 else "agents " + ", ".join(map(str, ids[:-1])) + f" and {ids[-1]}"


def _span(values) -> str:
    lo, hi = min(values), max(values)
    return f"{lo:.2g}" if f"{lo:.2g}" == f"{hi:.2g}" else f"{lo:.2g} to {hi:.2g}"


def _agent_warnings(agents, *, more_to_consensus_fails: bool = False) -> list:
    """One line per kind, naming every agent it concerns (not one line per agent): observability margins below
    :data:`MARGIN_WARN`, gains above :data:`GAIN_WARN` times the system's scale.  What to do about them is the
    report's advice, each knob tried (:mod:`.advice`).  ``more_to_consensus_fails``: the directions already left to
    consensus miss the rate (:func:`.approximate.misses_on_full`); the line then does not point ``design.rank_tol``
    up, the way that leaves more to consensus, against the warning that points it down for those."""
    out = []
    weak = [a for a in agents if a.observability_margin is not None and a.observability_margin < MARGIN_WARN]
    if weak:
        top = max(a.observability_margin for a in weak)
        hint = (f"design.rank_tol above {top:.2g} would leave these directions to consensus too, where the weakest "
                "ones already miss the rate: not a remedy here" if more_to_consensus_fails else
                f"design.rank_tol above {top:.2g} leaves it to consensus")
        out.append(f"{_agents_text(a.id for a in weak)} {'sees a direction' if len(weak) == 1 else 'see directions'} "
                   f"with an observability margin of only {_span([a.observability_margin for a in weak])} "
                   f"(< {MARGIN_WARN:g}): the local gain grows like 1 / margin, and so does its noise; a model less "
                   f"accurate than that does not really show it ({hint})")
    big = [a for a in agents if a.gain_ratio > GAIN_WARN]
    if big:
        out.append(f"{_agents_text(a.id for a in big)}: ||K_i C_i|| is {_span([a.gain_ratio for a in big])} times the "
                   f"system's own scale (> {GAIN_WARN:g}): large local gains amplify each sensor's noise")
    return out


def _transient(des: Design, warnings: list) -> tuple:
    sc = des.scenario
    if des.adaptive:
        return None, None, "not defined for the adaptive gain (g changes with time)"
    if des.consensus == "relay":  # its own constant, from n x n maps (synthesis/relay.py)
        k = des.whole
        label = des.cases[0].label
        if k.transient_constant > TRANSIENT_WARN:
            value = "infinite" if math.isinf(k.transient_constant) else f"{k.transient_constant:.2g}"
            warnings.append(f"errors can grow {value}-fold before they decay (transient_constant, graph {label}; > "
                            f"{TRANSIENT_WARN:g})")
        return k.transient_constant, label, ("max over the agents of the walk's start and ||G_i|| c(F - L C) / "
                                             "rate^D (relay: n x n maps), per event time")
    if sc.m * sc.n > MAX_DIM:
        return None, None, f"not computed: m n = {sc.m * sc.n} > {MAX_DIM}"
    used = set(sc.switching.graph_names(sc.graph_names))
    cases = [c for c in des.cases if c.label in used] or list(des.cases[:1])
    A = np.asarray(sc.system.A)
    # at the envelope's rate: lam, or slower when directions no agent sees limit it (detectability.py)
    rate = des.envelope_rate
    r = rate if sc.time == "discrete" else math.exp(-rate * sc.run.dt)
    block = sc.n - (des.unobserved.dim if des.excluded else 0)
    worst = None
    for case in cases:
        if des.consensus == "fusion":  # its own error map (synthesis/fusion_kind.py), per graph
            from .fusion_kind import fusion_matrix

            M = fusion_matrix(des, sc.graph_names.index(case.graph.name))
        else:
            Cs, Ks, Ps = case_parts(des, case)
            M = full_error_matrix(A, Cs, Ks, Ps, case.graph.S, time=sc.time, q=des.q, g=des.g,
                                  dt=sc.run.dt if sc.time == "continuous" else None, consensus=des.consensus)
        if des.excluded:  # the certificate covers the error modulo W only (design.undetectable: exclude)
            M = modulo(M, des.unobserved.W, sc.m if des.consensus == "fusion" else len(Cs))
        t = transient_constant(M, r, block=block)
        if worst is None or (t.constant or 0.0) > (worst[0].constant or 0.0):
            worst = (t, case)
    t, case = worst
    where = "per event time" if sc.time == "discrete" else f"at the sample times of run.dt = {sc.run.dt:g}"
    what = "the full error matrix" + (" modulo the directions no agent sees" if des.excluded else "")
    at = "" if rate == sc.design.rate else f" (at the envelope's rate {rate:.4g})"
    method = f"sup_k ||M^k|| / rate^k of {what}{at}, {where}, graph {case.label} held constant: " + t.method
    if t.constant is not None and t.constant > TRANSIENT_WARN:
        who = "" if t.agent_index is None else f", agent {case.graph.ids[t.agent_index]}'s error peaking"
        value = "infinite" if math.isinf(t.constant) else f"{t.constant:.2g}"
        warnings.append(f"errors can grow {value}-fold before they decay (transient_constant, graph {case.label}"
                        f"{who}; > {TRANSIENT_WARN:g})")
    return t.constant, case.label, method
