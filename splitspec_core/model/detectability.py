"""What no agent sees: the jointly unobservable space ``W``, how fast ``A`` decays on it, and the estimator on the rest.

The paper assumes ``(C, A)`` jointly observable and notes that "generalizing the results that follow to
the case when (C, A) is only detectable is quite straightforward" (Section 2).  Real models need it:
measurement filters, lead-lag blocks whose pole cancels a zero and fast exciter modes are stable modes
no sensor sees.  This module is that generalisation.

The unobserved space and the quotient
-------------------------------------
``W = V_1 ∩ ... ∩ V_m``: the directions no agent sees, as each agent decides (its ``V_i``,
:mod:`splitspec_core.model.observability`, made in balanced coordinates); ``W`` is A-invariant because every
``V_i`` is.  In orthonormal coordinates ``x = U_o a + U_w b`` with ``U_w`` spanning ``W``::

    A = [[A_oo, 0], [A_wo, A_ww]],    C_i = [C_io, 0]        (A W ⊆ W, C_i W = 0)

The quotient ``(C_io, A_oo)`` is jointly observable, and agent i's unobservable space of it is
``V_i ⊖ W`` (``V_i = (V_i ⊖ W) ⊕ W``).  The estimator is the paper's with ``P_i`` the orthogonal
projection on ``V_i ⊖ W`` (:func:`quotient_basis`); ``K_i`` is unchanged (it lies in ``V_i^⊥ ⊆ W^⊥``).
In the coordinates above (eq. split_continuous_observer; the discrete two-rate estimator likewise)::

    a_i' = (A_oo + K_io C_io) a_i - K_io y_i - g P_io (a_i - sum_j w_ij a_j)    the paper's, on the quotient
    b_i' = A_wo a_i + A_ww b_i                                                  open loop: no sensor sees b

so the stacked ``e_a`` follows the paper's error dynamics of the quotient, which q or g certifies at the
rate ``lam`` (every certificate of :mod:`splitspec_core.synthesis.bounds` runs on the cases built from
``V_i ⊖ W``), and ``e_b,i' = A_ww e_b,i + A_wo e_a,i`` decays as fast as the slower of the two.  The
same pure step functions run it (:mod:`splitspec_core.model.steps`: only ``P_i`` changed); the sampled-data
form keeps the split, since ``exp(A dt)`` is block triangular in the same coordinates.

The certificate
---------------
``W`` decays at ``mu_W = -max Re eig(A_ww)`` (continuous) or with radius ``rho_W = max |eig(A_ww)|``
(discrete).  Faster than the rate asked for: the rate stands.  Slower: the errors decay at
``mu_W`` and no faster, and the design certifies the envelope rate :data:`BACKOFF` ``mu_W``
(``rho_W^BACKOFF``): at exactly ``mu_W`` a mode of ``W`` that couples to the quotient or repeats
carries a factor ``t``, and no finite transient constant would hold.  A mode of ``W`` that does not
decay (an integrator or an unstable mode nobody sees) leaves nothing to certify: the design refuses it,
naming the states it lives on, unless ``design.undetectable: exclude`` asks for the estimator of the
quotient alone, whose certificate then covers the error modulo ``W`` only.

After losses the survivors' ``W_S`` (the intersection over the survivors) contains ``W``; the same
argument, with ``W_S`` in place of ``W``, gives their certificate: the quotient by ``W_S``
(:func:`quotient_basis` of the design's ``V_i``) and the decay of ``A`` on ``W_S`` (the consensus still
running on ``W_S ⊖ W`` only speeds that part up: its error map there is ``exp(A_22 t) (x) exp(-g (I - S) t)``).
The design asks it of every single loss at once (:func:`unobserved_without_each`): the m intersections of m - 1
subspaces share their triangular factors, O(m) factorizations in all.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ..scenarios.labels import combination, heaviest, spread
from .modal import Spectrum, rescale
from .observability import ROUND_OFF, split_residual_of, threshold_of
from .subspaces import complement, intersection, intersections_without_each, triangular_without_each
from .subspaces import difference as quotient_basis  # V_i ⊖ W: the estimator's V_i

__all__ = ["BACKOFF", "Unobserved", "UnobservedOf", "unobserved", "unobserved_of", "unobserved_without_each",
           "quotient_basis", "still_text", "envelope_rate", "not_detectable_text", "directions_of"]

#: a W that limits the rate is certified at this fraction of its decay rate (module docstring)
BACKOFF = 0.9
#: A on W "does not decay" when its decay rate is below this fraction of |A_b| (continuous) or its radius within it of 1
STILL = 1e-9
#: W decaying within this fraction of the rate decays at the rate (round-off: a drawn mode at -0.2 computed at
#: 0.20000000000000015 against rate 0.2): a mode at the rate certifies nothing (its errors grow like k r^k)
TIE = 1e-9


@dataclass(frozen=True)
class Unobserved:
    """The directions a set of agents leaves unobserved (module docstring).

    Attributes
    ----------
    W : (n, w) array
        Orthonormal basis of ``W`` in the user's coordinates.
    eigs : (w,) complex array
        Spectrum of ``A`` on ``W`` (``U_w' A U_w``).
    time : str
    residual : float
        How far ``W`` is from an exact unobserved space, in balanced coordinates: ``max(|Q_b A_b W_b| / |A_b - aI|,
        |C_b W_b| / |C_b|)`` (round-off when every direction in it is unseen to round-off; a weakly seen mode left
        to it makes it the size of that margin).
    scale : float
        ``|A_b|_2``, the scale "does not decay" is judged against.
    names : tuple
        The state names, for the texts.
    AW : (n, w) array
        ``A W``, for the modes of :meth:`still_modes`.
    Ww : (n, w) array
        Orthonormal basis of ``W`` in the design's working coordinates (``design.coordinates``: the user's, or
        balanced), where the estimator's ``V_i ⊖ W`` is taken; ``W`` itself when they are the user's.
    """

    W: np.ndarray
    eigs: np.ndarray
    time: str
    residual: float = 0.0
    scale: float = 1.0
    names: tuple = ()
    AW: np.ndarray | None = field(default=None, repr=False, compare=False)
    Ww: np.ndarray | None = field(default=None, repr=False, compare=False)

    @property
    def W_working(self) -> np.ndarray:
        """``W`` in the design's working coordinates (:attr:`Ww`, or ``W``)."""
        return self.W if self.Ww is None else self.Ww

    @property
    def dim(self) -> int:
        """int: ``w``, the dimension of ``W`` (0: every direction is observed by some agent)."""
        return int(self.W.shape[1])

    @property
    def decay(self) -> float:
        """Continuous: ``-max Re eig`` (inf when ``W`` is empty); discrete: ``max |eig|`` (0 when empty)."""
        if self.time == "continuous":
            return math.inf if not self.dim else float(-np.max(self.eigs.real))
        return 0.0 if not self.dim else float(np.max(np.abs(self.eigs)))

    @property
    def decays(self) -> bool:
        """Whether every mode on ``W`` decays (beyond round-off)."""
        if not self.dim:
            return True
        if self.time == "continuous":
            return self.decay > STILL * max(self.scale, 1.0)
        return self.decay < 1.0 - STILL * max(self.scale, 1.0)

    def limits(self, rate: float) -> bool:
        """Whether ``W`` decays no faster than the rate ``lam`` (so the errors cannot decay at ``lam``); within
        :data:`TIE` of it counts as at it.

        Parameters
        ----------
        rate : float
            ``lam``: a decay rate (continuous) or a spectral radius (discrete).

        Returns
        -------
        bool
            False when ``W`` is empty.
        """
        if not self.dim:
            return False
        tie = TIE * max(abs(rate), 1e-300)
        return self.decay <= rate + tie if self.time == "continuous" else self.decay >= rate - tie

    def envelope(self, rate: float) -> float:
        """The rate of the certified envelope: ``lam`` or, when ``W`` limits it, :data:`BACKOFF` of ``W``'s.

        Parameters
        ----------
        rate : float
            ``lam``.

        Returns
        -------
        float
            ``rate``, or ``BACKOFF mu_W`` (continuous) / ``rho_W^BACKOFF`` (discrete).
        """
        if not self.limits(rate):
            return rate
        return BACKOFF * self.decay if self.time == "continuous" else self.decay ** BACKOFF

    def still_modes(self) -> list:
        """``[(eigenvalue, direction (n,) complex)]`` of the modes on ``W`` that do not decay, the slowest first.

        Returns
        -------
        list of (complex, (n,) complex array)
            Empty when every mode decays (or ``W`` is empty).
        """
        if not self.dim:
            return []
        w, X = np.linalg.eig(self.W.T @ self.AW)
        return [(w[k], self.W @ X[:, k]) for k in self._still(w)]

    def _still(self, w: np.ndarray) -> list:
        tol = STILL * max(self.scale, 1.0)
        if self.time == "continuous":
            bad = [k for k in range(len(w)) if -w[k].real <= tol]
            return sorted(bad, key=lambda k: -w[k].real)
        bad = [k for k in range(len(w)) if abs(w[k]) >= 1.0 - tol]
        return sorted(bad, key=lambda k: -abs(w[k]))

    def rate_text(self) -> str:
        """``2.1`` (continuous: ``mu_W``) or ``radius 0.8`` (discrete): how fast W decays.

        Returns
        -------
        str
        """
        return f"{self.decay:.3g}" if self.time == "continuous" else f"radius {self.decay:.3g}"

    def where(self) -> str:
        """The states that carry ``W`` (:func:`splitspec_core.scenarios.labels.spread`).

        Returns
        -------
        str
        """
        return spread(self.W, self.names)

    def summary(self, rate: float) -> str:
        """One line: what goes unobserved, how fast it decays, whether that limits the rate.

        Parameters
        ----------
        rate : float
            ``lam``, the rate asked for.

        Returns
        -------
        str
        """
        if not self.dim:
            return "every direction is observed by some agent"
        one = self.dim == 1
        what = f"{self.dim} direction{'' if one else 's'} no agent sees ({self.where()})"
        if not self.decays:
            return f"{what} {'does not decay' if one else 'do not all decay'}"
        verb = "decays" if one else "decay"
        if self.time == "continuous":
            speed = f"{verb} at {self.decay:.3g}"
            cmp = f"{'<=' if self.limits(rate) else '>'} rate {rate:g}"
        else:
            speed = f"{verb} with radius {self.decay:.3g}"
            cmp = f"{'>=' if self.limits(rate) else '<'} rate {rate:g}"
        if self.limits(rate):
            return f"{what} {speed} {cmp}: {'it limits' if one else 'they limit'} the certified rate to " \
                   f"{self.envelope(rate):.4g}"
        return f"{what} {speed} {cmp}: faster than the rate, {'it does' if one else 'they do'} not limit it"


def unobserved(sp: Spectrum, A: np.ndarray, C: np.ndarray, Vs, *, time: str, names,
               rank_tol: float | None = None, coords: np.ndarray | None = None) -> Unobserved:
    """The unobserved space of the agents whose unobservable spaces are ``Vs``, with ``C`` their rows stacked (for
    the residual) and ``sp`` the skeleton of ``A`` (:mod:`splitspec_core.model.modal`).

    A direction counts as unobserved when it is within the decisions' own threshold (``design.rank_tol``) of every
    agent's ``V_i``, in balanced coordinates: an agent that left a weakly seen direction out has a ``V_i`` tilted
    by up to about that much, and consensus could recover a direction that every ``V_i`` holds only that closely
    only with a gain of order one over its square (the split is then approximate: ``residual``).

    Parameters
    ----------
    sp : Spectrum
        The skeleton of ``A``.
    A : (n, n) array_like
        State matrix.
    C : (p, n) array_like
        The agents' rows ``C_i`` stacked.
    Vs : iterable of (n, n_i) arrays
        The agents' ``V_i``, in the coordinates ``x = diag(coords) x_w``.
    time : {"continuous", "discrete"}
        The scenario's time.
    names : sequence of str
        State names, for the texts.
    rank_tol : float, optional
        ``design.rank_tol`` (None: auto).
    coords : (n,) array, optional
        The design's working coordinates (None: the user's).

    Returns
    -------
    Unobserved

    Examples
    --------
    >>> import numpy as np
    >>> from splitspec_core.model.modal import spectrum
    >>> from splitspec_core.model.observability import decompose
    >>> A, Cs = np.diag([-1.0, -2.0, -3.0]), [np.array([[1.0, 0, 0]]), np.array([[0, 1.0, 0]])]
    >>> sp = spectrum(A, np.vstack(Cs))
    >>> un = unobserved(sp, A, np.vstack(Cs), [decompose(A, C, spectrum=sp).V for C in Cs],
    ...                 time="continuous", names=("x1", "x2", "x3"))
    >>> un.dim, un.where(), round(un.decay, 6)
    (1, 'x3', 3.0)
    >>> un.summary(5.0)
    '1 direction no agent sees (x3) decays at 3 <= rate 5: it limits the certified rate to 2.7'
    """
    A = np.asarray(A, dtype=float)
    Wb = intersection([rescale(V, coords, sp.d) for V in Vs], A.shape[0], tol=threshold_of(rank_tol))
    return _unobserved_in(sp, A, np.asarray(C, dtype=float) * sp.d[None, :], Wb, time=time, names=names,
                          coords=coords)


def unobserved_without_each(sp: Spectrum, A: np.ndarray, Cs, Vs, *, time: str, names,
                            rank_tol: float | None = None, coords: np.ndarray | None = None) -> list:
    """``[unobserved(...) of every agent but k for k]``: the survivors' ``W_S`` of every single loss, equal to
    :func:`unobserved` of the survivors to round-off (the same test on the same singular values; a basis of
    ``W_S`` may be another rotation of it), in O(m) factorizations of at most ``2n`` rows
    (:func:`~splitspec_core.model.subspaces.triangular_without_each`) instead of m of ``(m - 1) n`` rows.  The
    residual's ``|C_b W_b|`` and ``|C_b|`` (2-norms) are those of the survivors' rows' triangular factor,
    computed only when some ``W_S`` is not empty.

    Parameters
    ----------
    sp : Spectrum
        The skeleton of ``A``.
    A : (n, n) array_like
        State matrix.
    Cs, Vs : sequences
        Each agent's ``C_i`` and ``V_i`` (in the coordinates ``coords``), in one order.
    time, names, rank_tol, coords
        As for :func:`unobserved`.

    Returns
    -------
    list of Unobserved
        Entry k: what the agents other than the k-th leave unobserved.
    """
    A = np.asarray(A, dtype=float)
    n = A.shape[0]
    Wbs = intersections_without_each([rescale(V, coords, sp.d) for V in Vs], n, tol=threshold_of(rank_tol))
    if any(Wb.shape[1] for Wb in Wbs):
        Rs = triangular_without_each([np.asarray(C, dtype=float) * sp.d[None, :] for C in Cs], n)
    else:
        Rs = [np.zeros((0, n))] * len(Wbs)  # the residual of an empty W_S is 0: no rows read
    return [_unobserved_in(sp, A, R, Wb, time=time, names=names, coords=coords) for R, Wb in zip(Rs, Wbs)]


def _unobserved_in(sp: Spectrum, A: np.ndarray, Cb: np.ndarray, Wb: np.ndarray, *, time: str, names,
                   coords: np.ndarray | None) -> Unobserved:
    """The :class:`Unobserved` of ``W_b`` (orthonormal, balanced coordinates); ``C_b``: the agents' rows in balanced
    coordinates, or any matrix with their 2-norms on every subspace (their triangular factor)."""
    W = sp.to_user(Wb)
    Ww = None if coords is None else rescale(Wb, sp.d, coords)
    residual = split_residual_of(sp.A_b, Cb, complement(Wb).T, Wb) if Wb.shape[1] else 0.0
    eigs = np.linalg.eigvals(W.T @ A @ W) if W.shape[1] else np.zeros(0, complex)
    return Unobserved(W=W, eigs=eigs, time=time, residual=residual, scale=float(np.linalg.norm(sp.A_b, 2)),
                      names=tuple(names), AW=A @ W, Ww=Ww)


def still_text(un: Unobserved) -> str:
    """The modes of ``W`` that do not decay, named: ``x3 + x4 (eigenvalue +-1j)``, the slowest first (at most 3).

    Parameters
    ----------
    un : Unobserved

    Returns
    -------
    str
        ``"; "``-joined, a complex pair once; empty when every mode decays.
    """
    parts = []
    for lam, v in un.still_modes()[:3]:
        if abs(lam.imag) > 1e-12 * max(1.0, abs(lam)):
            if lam.imag < 0:
                continue  # its conjugate is listed
            ev = f"{lam.real:.3g} +- {abs(lam.imag):.3g}j"
        else:
            ev = f"{lam.real:.3g}"
        parts.append(f"{combination(v, un.names)} (eigenvalue {ev})")
    return "; ".join(parts)


def envelope_rate(rate: float, un: Unobserved | None) -> float:
    """``lam``, or the rate :attr:`Unobserved.envelope` certifies when ``W`` limits it.

    Parameters
    ----------
    rate : float
        ``lam``.
    un : Unobserved or None
        None: nothing goes unobserved.

    Returns
    -------
    float
    """
    return rate if un is None else un.envelope(rate)


class UnobservedOf:
    """``alive -> Unobserved``: what a set of agents of the scenario ``sc`` leaves unobserved, from their own
    unobservable spaces ``full_V`` (agent id -> ``V_i`` in the coordinates ``x = diag(coords) x_w``); and
    :meth:`without_each`, every single loss at once."""

    def __init__(self, sc, sp: Spectrum, full_V: dict, coords: np.ndarray | None = None):
        self._sc, self._sp, self._full_V, self._coords = sc, sp, full_V, coords
        self._Cs = dict(zip(sc.agent_ids, sc.system.Cs))

    def _kw(self) -> dict:
        sc = self._sc
        return dict(time=sc.time, names=sc.state_names, rank_tol=sc.design.rank_tol, coords=self._coords)

    def __call__(self, alive) -> Unobserved:
        sc = self._sc
        alive = set(alive)
        ids = [a for a in sc.agent_ids if a in alive]
        C = np.vstack([self._Cs[a] for a in ids]) if ids else np.zeros((0, sc.n))
        return unobserved(self._sp, sc.system.A, C, [self._full_V[a] for a in ids], **self._kw())

    def without_each(self, ids) -> dict:
        """``{k: self(ids without k) for k in ids}`` to round-off (:func:`unobserved_without_each`: O(m), not
        O(m^2), factorizations).

        Parameters
        ----------
        ids : iterable of int
            The agent ids alive.

        Returns
        -------
        dict of int to Unobserved
            Keyed by the agent lost, in the scenario's agent order.
        """
        chosen = set(ids)
        ids = [a for a in self._sc.agent_ids if a in chosen]
        each = unobserved_without_each(self._sp, self._sc.system.A, [self._Cs[a] for a in ids],
                                       [self._full_V[a] for a in ids], **self._kw())
        return dict(zip(ids, each))


def unobserved_of(sc, sp: Spectrum, full_V: dict, coords: np.ndarray | None = None) -> UnobservedOf:
    """``alive -> Unobserved`` (an :class:`UnobservedOf`): what a set of agents of the scenario ``sc`` leaves
    unobserved, from their own unobservable spaces ``full_V``.

    Parameters
    ----------
    sc : Scenario
        The scenario (agent ids, ``C_i``, time, state names, ``design.rank_tol``).
    sp : Spectrum
        The skeleton of ``A``.
    full_V : dict
        Agent id -> ``V_i`` in the coordinates ``x = diag(coords) x_w``.
    coords : (n,) array, optional
        The design's working coordinates (None: the user's).

    Returns
    -------
    UnobservedOf
    """
    return UnobservedOf(sc, sp, full_V, coords)


def not_detectable_text(un: Unobserved, decs, rank_tol: float | None) -> str:
    """The one line refusing a design whose unobserved directions do not all decay: the modes, named, whether some
    agent sees them weakly (the largest margin an agent left out along them: ``design.rank_tol`` below it would count
    it), what would fix it.

    Parameters
    ----------
    un : Unobserved
        What no agent sees.
    decs : iterable of Decomposition
        The agents' own decompositions.
    rank_tol : float or None
        ``design.rank_tol`` (None: auto).

    Returns
    -------
    str
    """
    modes = un.still_modes()
    weak = 0.0
    for dec in decs:  # a direction an agent left out that lies in W: the margin the threshold would have to go below
        v = dec.weak_direction
        if dec.weak > 0.0 and v is not None and np.linalg.norm(v - un.W @ (un.W.T @ v)) <= 1e-3:
            weak = max(weak, dec.weak)
    plural = sum(1 for lam, _ in modes if lam.imag >= 0) > 1  # a complex pair is one mode
    hint = ""
    if weak > ROUND_OFF:
        source = "design.rank_tol: auto" if rank_tol is None else f"design.rank_tol: {rank_tol:g}"
        hint = (f"; the agents see {'them' if plural else 'it'} only weakly (margin {weak:.2g} < "
                f"{threshold_of(rank_tol):g}, {source}): a model accurate to better than that can set design.rank_tol "
                f"below {weak:.2g}")
    who = heaviest(np.column_stack([np.abs(v) for _, v in modes]) if modes else un.W, un.names, limit=3)
    who = [w for w in who if not w.endswith(" more")]
    return (f"(C, A) is not jointly detectable: no agent sees {still_text(un)}, which does not decay{hint}; "
            f"measure one of {', '.join(who)}, or set design.undetectable: exclude to estimate the rest")


def directions_of(rows, n: int) -> np.ndarray | None:
    """W as a configuration carries it to an agent process (``unobserved``: n rows of w numbers), checked.

    Parameters
    ----------
    rows : list of lists of float, or None
        The configuration's ``unobserved``.
    n : int
        State dimension.

    Returns
    -------
    (n, w) float array or None
        None when the design sent none.

    Raises
    ------
    ValueError
        If ``rows`` are not ``n`` rows of at most ``n`` finite numbers.
    """
    if rows is None:
        return None
    W = np.array(rows, dtype=float)
    if W.ndim != 2 or W.shape[0] != n or W.shape[1] > n or not np.all(np.isfinite(W)):
        raise ValueError(f"the configuration's unobserved directions are not {n} rows of at most {n} finite numbers")
    return W
