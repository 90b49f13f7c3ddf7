"""The :class:`Design` result: the data a design produces, and the per-design cache of what is computed from it.

``Design`` holds the design (agents, graphs, cases, g or q and their bounds, the losses analysed, the warnings)
with its cheap derived properties; the analyses of a design are functions of it, elsewhere: the verdict
(:mod:`.verdict`), its conditioning (:mod:`.conditioning`), its certificate under loss (:mod:`.loss_certificate`).
They are costly (the full error matrices cost more than the design itself at scale), so each is computed once
per design, on first use (:func:`cached_analysis`).  :mod:`.designer` builds it.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from . import bounds
from ..model.detectability import Unobserved, quotient_basis, unobserved_of
from ..model.modal import Spectrum
from ..scenarios.specs import Scenario

__all__ = ["Design", "cached_analysis", "SPLIT_EXACT"]

#: a split residual below this is round-off: the split is exact
SPLIT_EXACT = 1e-9


@dataclass(frozen=True)
class Design:
    """A complete design with diagnostics (see ``design_json`` for the contract).

    ``g`` is ``None`` for discrete time and for the adaptive estimator;
    ``q`` is ``None`` for continuous time.  ``g_certified_by`` names what
    certifies g for the ODE (None: nothing, or the adaptive gain); the verdict
    for the estimator as run is :func:`splitspec_core.synthesis.verdict.rate_certificate`.

    It holds data: what is computed from it (the verdict, :func:`~splitspec_core.synthesis.conditioning.conditioning`,
    :func:`~splitspec_core.synthesis.loss_certificate.loss_certificate`) are functions of it, cached per design by
    :func:`cached_analysis` (a design changed with ``dataclasses.replace`` starts with none).
    """

    scenario: Scenario
    agents: tuple
    graphs: tuple  # Graph per scenario graph, scenario order
    cases: tuple  # bounds.Case covered by g or q
    g: float | None = None
    g_mode: str | None = None  # auto | given | adaptive
    g_bounds: dict = field(default_factory=dict)  # case label -> eq. (g)
    g_mins: dict = field(default_factory=dict)  # case label -> exact smallest g
    g_dwell: float | None = None
    dwell: float | None = None
    g_arbitrary: float | None = None
    g_certified_by: str | None = None
    q: int | None = None
    q_result: bounds.QResult | None = None
    q_methods: dict = field(default_factory=dict)  # the q method's result; every method's with compare_q_methods
    error_radius: dict = field(default_factory=dict)  # case label -> spectral radius / abscissa of A_V
    sampled_rate: dict = field(default_factory=dict)  # continuous: case label -> decay rate of the sampled-data form
    agent_losses: dict = field(default_factory=dict)
    arc_losses: dict = field(default_factory=dict)
    warnings: tuple = ()
    # max over agents of Decomposition.split_residual (and W's); above round-off, full_radius: approximate.check_full
    split_residual: float = 0.0
    full_radius: dict = field(default_factory=dict)
    # what no agent sees (detectability.py): W, its spectrum, whether it decays; None only for a design built by hand
    unobserved: Unobserved | None = None
    spectrum: Spectrum | None = field(default=None, repr=False, compare=False)  # modal.py: A balanced, its clusters
    # what each agent takes from its neighbours: split (the paper's) or whole (P_i = I: whole_state.py), and what the
    # whole-state design chose (whole_state.WholeState; None for the split)
    consensus: str = "split"
    whole: Any = field(default=None, repr=False, compare=False)
    # design.gains: optimal that chose the split: why (None otherwise); design.consensus: auto's verdict in one line
    chosen: str | None = None
    # the analyses computed from it so far (cached_analysis); not an argument, so a replaced design starts empty
    _analyses: dict = field(default_factory=dict, init=False, repr=False, compare=False)

    @property
    def time(self) -> str:
        """The scenario's time, ``"discrete"`` or ``"continuous"`` (str)."""
        return self.scenario.time

    @property
    def adaptive(self) -> bool:
        """The adaptive gain (eq. adaptive): no fixed g, no steady state, no certified rate."""
        return self.g_mode == "adaptive"

    @property
    def two_rate(self) -> bool:
        """q consensus exchanges per event time: discrete time, or the whole-state design in continuous time (one
        event time per ``run.dt``)."""
        return self.time == "discrete" or self.consensus in ("whole", "fusion", "relay")

    @property
    def rate(self) -> float:
        """The decay rate asked for, ``design.rate`` (float): ``lam`` per event time or per unit time."""
        return self.scenario.design.rate

    @property
    def Ks(self) -> list:
        """Every ``K_i`` the estimator runs (the user's coordinates)."""
        return [a.K for a in self.agents]

    @property
    def Ps(self) -> list:
        """Every ``P_i`` the estimator runs (the user's coordinates)."""
        return [a.P for a in self.agents]

    @property
    def Vs(self) -> list:
        """Every ``R_i`` eq. (adaptive) projects with, in the user's coordinates (:attr:`AgentDesign.V_adaptive`;
        ``V_i`` itself in the user's own working coordinates)."""
        return [a.V_adaptive for a in self.agents]

    @property
    def Ls(self) -> list:
        """Every ``L_i`` (:attr:`AgentDesign.V_lift`): ``P_i = L_i R_i'`` with ``R_i`` of :attr:`Vs`."""
        return [a.V_lift for a in self.agents]

    @property
    def scale(self) -> np.ndarray | None:
        """The working coordinates ``x = diag(scale) x_w`` (``design.coordinates``; None: the user's)."""
        return self.agents[0].scale if self.agents else None

    @property
    def redundantly_strongly_connected(self) -> bool:
        """Every graph stays strongly connected after the loss of any one agent (bool; True when no losses were
        analysed)."""
        return all(all(r.strongly_connected.values()) for r in self.agent_losses.values())

    @property
    def redundantly_jointly_observable(self) -> bool:
        """The survivors of any one agent loss still observe the whole state (bool; True when no losses were
        analysed)."""
        return all(r.jointly_observable for r in self.agent_losses.values())

    @property
    def redundantly_jointly_detectable(self) -> bool:
        """What the survivors of any one agent loss leave unobserved decays (bool; True when no losses were
        analysed)."""
        return all(r.detectable for r in self.agent_losses.values())

    @property
    def excluded(self) -> bool:
        """``design.undetectable: exclude`` took effect: directions no agent sees do not decay, and the certificate
        covers the error modulo them only."""
        return self.unobserved is not None and not self.unobserved.decays

    @property
    def envelope_rate(self) -> float:
        """The rate of the certified envelope: ``lam``, or slower when the unobserved directions limit it
        (:meth:`splitspec_core.model.detectability.Unobserved.envelope`); with :attr:`excluded`, ``lam`` (modulo them)."""
        un = self.unobserved
        return self.rate if un is None or self.excluded else un.envelope(self.rate)

    @property
    def A_working(self) -> np.ndarray:
        """``A`` in the working coordinates (``D^-1 A D``)."""
        A = np.asarray(self.scenario.system.A, dtype=float)
        return A if self.scale is None else A * self.scale[None, :] / self.scale[:, None]

    def unobserved_of(self, alive) -> Unobserved:
        """What the agents ``alive`` leave unobserved (``W_S ⊇ W``, :mod:`splitspec_core.model.detectability`).

        Parameters
        ----------
        alive : iterable of int
            The ids of the agents left.

        Returns
        -------
        Unobserved
            ``W_S`` (``W``: an orthonormal basis, user's coordinates), its eigenvalues and whether it decays.

        Examples
        --------
        >>> import splitspec_core as ss
        >>> from splitspec_core.synthesis.designer import design
        >>> des = design(ss.scenario(A=[[0, 1, 0, 0], [-1, 0, 0, 0], [0, 0, 0, 1], [0, 0, -2, 0]],
        ...                          C={1: [[1, 0, 0, 0]], 2: [[0, 1, 0, 0]], 3: [[0, 0, 1, 0]]},
        ...                          graphs={"a": [(1, 2), (2, 1), (2, 3), (3, 2), (1, 3)]}, rate=0.5, gains="place"))
        >>> des.unobserved_of((1, 2, 3)).dim, des.unobserved_of((1, 2)).dim  # x3, x4 are agent 3's alone
        (0, 2)
        """
        return unobserved_of(self.scenario, self.spectrum, {a.id: self.unobservable_space(a.id)
                                                            for a in self.agents}, self.scale)(alive)

    def survivor_case(self, label: str, graph, un: Unobserved) -> bounds.Case:
        """The certificate's case of the agents of ``graph`` when they leave ``un.W`` unobserved: ``V_i ⊖ W_S``.

        Parameters
        ----------
        label : str
            The case's label (``a without agent 3``).
        graph : Graph
            The surviving agents (``graph.ids``) and their graph.
        un : Unobserved
            What they leave unobserved (:meth:`unobserved_of`).

        Returns
        -------
        bounds.Case
            With the agents' own ``V_i`` and ``A_i`` when ``un`` is the design's own ``W``; otherwise with
            ``V_i ⊖ W_S`` (quotient bases) and ``A_i = V_i' A V_i`` in the working coordinates.
        """
        ad = {a.id: a for a in self.agents}
        if self.unobserved is None or un.dim == self.unobserved.dim:
            return bounds.make_case(label, graph, [ad[i].V for i in graph.ids], [ad[i].dec.A_un for i in graph.ids])
        A = self.A_working
        Vs = [quotient_basis(self.unobservable_space(i), un.W_working) for i in graph.ids]
        return bounds.make_case(label, graph, Vs, [V.T @ A @ V for V in Vs])

    def unobservable_space(self, agent_id: int) -> np.ndarray:
        """Agent ``agent_id``'s own unobservable space in the working coordinates: ``[V_i ⊖ W, W]`` (orthonormal: the
        two are orthogonal there).

        Parameters
        ----------
        agent_id : int
            An agent of the design.

        Returns
        -------
        (n, n - r_i) array
            ``[V_i ⊖ W, W]``, orthonormal columns.
        """
        a = next(a for a in self.agents if a.id == agent_id)
        W = self.unobserved.W_working if self.unobserved is not None else np.zeros((a.V.shape[0], 0))
        return np.hstack([a.V, W])

    @property
    def split_exact(self) -> bool:
        """Every V_i an unobservable space to round-off: the split of prop. error holds, the certificates apply."""
        return self.split_residual <= SPLIT_EXACT


def cached_analysis(fn):
    """``fn(des, **options)`` computed once per design and options, on first use (kept in the design's own cache:
    the design is frozen, and a design made from it by ``dataclasses.replace`` starts with an empty one).
    ``cached.remember(des, value, **options)`` keeps a value the design computed on its way instead.

    Parameters
    ----------
    fn : callable
        ``fn(des, **options)``, a pure analysis of a :class:`Design` (options hashable).

    Returns
    -------
    callable
        ``cached(des, **options)`` with the same result, computed once per design and options, and its
        ``remember`` attribute.
    """
    name = f"{fn.__module__}.{fn.__qualname__}"

    @functools.wraps(fn)
    def cached(des: Design, **options):
        key = (name, *sorted(options.items()))
        if key not in des._analyses:
            des._analyses[key] = fn(des, **options)
        return des._analyses[key]

    def remember(des: Design, value, **options) -> None:
        des._analyses[(name, *sorted(options.items()))] = value

    cached.remember = remember
    return cached
