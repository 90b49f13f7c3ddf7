"""The local part of the design: what every agent process computes from the scenario (``V_i, P_i, K_i``).

The paper's design is distributed but for g or q: each agent decides its own unobservable space ``V_i`` and
local gain ``K_i`` from ``(A, C_i)`` and the rate (proof of prop. error).  Here that takes the skeleton of
``A`` (:mod:`splitspec_core.model.modal`, the same in every process), the design's working coordinates
(``design.coordinates``) and, when the design found directions no agent sees, ``W`` (sent with the
configuration; :mod:`splitspec_core.model.detectability`).  The designer builds every agent's with the same
functions, so a run's agents and ``simulate`` hold the same matrices.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

from .detectability import directions_of
from .gain_target import beyond_target
from .gains import GainRequest, LocalGain, design_gain
from .modal import Spectrum, rescale, spectrum
from .observability import Decomposition, decompose
from ..scenarios import gain_methods
from ..scenarios.specs import Scenario

__all__ = ["AgentDesign", "AUTO_COORDINATES", "central_part", "design_agent", "directions_of", "gain_request",
           "noise_weights", "scenario_agent",
           "scenario_spectrum", "whole_placeholder", "with_gain", "working_scale"]


@dataclass(frozen=True)
class AgentDesign:
    """One agent's local design: decomposition and gain, in the design's working coordinates ``x = diag(scale) x_w``
    (``design.coordinates``; ``scale`` None: the user's own).

    The certificates use ``V`` (orthonormal there) and ``dec``; the estimator runs in the user's coordinates with
    ``K`` and ``P``, the working coordinates' ``K_w`` and ``P_w = V V'`` seen from the user's: ``K = D K_w``,
    ``P = D P_w D^-1`` (an orthogonal projection in the working coordinates, oblique in the user's when they differ).
    """

    id: int
    dec: Decomposition
    gain: LocalGain
    scale: np.ndarray | None = field(default=None, repr=False, compare=False)
    #: what the agent takes from its neighbours: ``split`` (the paper's: its unobservable space, ``P_i = V_i V_i'``)
    #: or ``whole`` (every state, ``P_i = I``: :mod:`splitspec_core.synthesis.whole_state`)
    consensus: str = "split"

    @property
    def V(self) -> np.ndarray:
        """``V_i`` of the certificates, an (n, k) array (orthonormal in the working coordinates; ``k = n - r_i``, less
        the directions no agent sees when the design found some)."""
        return self.dec.V

    @cached_property
    def K(self) -> np.ndarray:
        """``K_i`` in the user's coordinates (what runs), an (n, s_i) array."""
        return self.gain.K if self.scale is None else self.scale[:, None] * self.gain.K

    @cached_property
    def P(self) -> np.ndarray:
        """``P_i`` in the user's coordinates (what runs), an (n, n) array: the projection on the unobservable space
        (minus what no agent sees) along the working coordinates' orthogonal complement; the identity when the agent
        takes the whole state from its neighbours (``consensus == "whole"``)."""
        if self.consensus == "whole":
            return np.eye(self.dec.P.shape[0])
        return self.dec.P if self.scale is None else self.scale[:, None] * self.dec.P / self.scale[None, :]

    @cached_property
    def V_user(self) -> np.ndarray:
        """The same subspace as ``V``, an (n, k) array orthonormal in the user's coordinates (reports, the API)."""
        return self.dec.V if self.scale is None else rescale(self.dec.V, self.scale, None)

    @cached_property
    def V_adaptive(self) -> np.ndarray:
        """``R_i = D^-1 V_i``, an (n, k) array: the working coordinates of the unobservable space seen from the user's,
        ``V_i' x_w = R_i' x`` (eq. adaptive's projection of the disagreement; ``P = L_i R_i'``)."""
        return self.dec.V if self.scale is None else self.dec.V / self.scale[:, None]

    @cached_property
    def V_lift(self) -> np.ndarray:
        """``L_i = D V_i``, an (n, k) array: the unobservable space's basis in the user's coordinates, ``x = L_i w`` for
        ``w`` in the working ones (``P = L_i R_i'``, ``R_i' L_i = I``)."""
        return self.dec.V if self.scale is None else self.scale[:, None] * self.dec.V



def design_agent(A: np.ndarray, C: np.ndarray, request: GainRequest, *, agent_id: int = 0,
                 rank_tol: float | None = None, spectrum: Spectrum | None = None,
                 unobserved: np.ndarray | None = None, dec: Decomposition | None = None,
                 scale: np.ndarray | None = None) -> AgentDesign:
    """The local, fully distributed part of the design for one agent (``V_i, P_i, K_i``).

    Parameters
    ----------
    A, C : arrays
        ``A`` (n x n) and the agent's ``C_i`` (s_i x n), the user's coordinates.
    request : GainRequest
        What the gain is asked (:func:`gain_request` builds it from the scenario; its ``K`` and process covariance
        already in the working coordinates).
    agent_id : int
        The agent's id (its messages name it).
    rank_tol : float, optional
        ``design.rank_tol`` (None: auto), when ``dec`` is not given.
    spectrum : Spectrum, optional
        The skeleton of ``A`` (:func:`scenario_spectrum`; the designer and every agent process compute the same one).
    unobserved : (n, w) array, optional
        ``W`` in the working coordinates, the directions no agent sees (the design's, sent to the agents with their
        configuration): ``P_i`` then projects on ``V_i ⊖ W``.
    dec : Decomposition, optional
        The decomposition already computed (the designer's).
    scale : (n,) array, optional
        The working coordinates ``x = diag(scale) x_w`` (:func:`working_scale`; None: the user's).

    Returns
    -------
    AgentDesign
        The agent's decomposition and its gain, which meets ``request.rate`` on its observable part.

    Raises
    ------
    DesignError
        The gain method's numerical step failed (:func:`~splitspec_core.model.gains.design_gain`).
    AssumptionError
        The gain does not meet the rate.

    Examples
    --------
    Agent 1 of the paper's discrete example sees the first oscillator; the second is its unobservable space:

    >>> A = np.array([[0, 1, 0, 0], [-1, 0, 0, 0], [0, 0, 0, 1], [0, 0, -2, 0]], dtype=float)
    >>> agent = design_agent(A, np.array([[1.0, 0, 0, 0]]), GainRequest(method="place", time="discrete", rate=0.5),
    ...                      agent_id=1)
    >>> agent.V.shape, (agent.P.round(6) + 0.0).diagonal().tolist(), agent.consensus
    ((4, 2), [0.0, 0.0, 1.0, 1.0], 'split')
    """
    dec = dec if dec is not None else decompose(A, C, rank_tol=rank_tol, spectrum=spectrum,
                                                free=beyond_target(request.time, request.rate, request.margin),
                                                scale=scale)
    gain = design_gain(dec, request)
    if unobserved is not None and unobserved.shape[1]:
        A_w = np.asarray(A, dtype=float) if scale is None else np.asarray(A) * scale[None, :] / scale[:, None]
        dec = dec.without(unobserved, A_w)
    return AgentDesign(id=agent_id, dec=dec, gain=gain, scale=scale)


def gain_request(sc: Scenario, agent_id: int, scale: np.ndarray | None, *, method: str | None = None) -> GainRequest:
    """What agent ``agent_id``'s gain is asked, from the scenario: the one construction the designer and every agent
    process share.

    Parameters
    ----------
    sc : Scenario
        The scenario.
    agent_id : int
        The agent.
    scale : (n,) array or None
        The working coordinates ``x = diag(scale) x_w`` (:func:`working_scale`).
    method : str, optional
        The local method (default ``design.gains``; a central method's split names one of its ``split`` methods).

    Returns
    -------
    GainRequest
        The method, the rate, the margin, the user's ``K_i`` and the process covariance in the working coordinates
        (``K_w = D^-1 K``, ``Q_w = D^-1 Q D^-1``), the noise weights (:func:`noise_weights`), ``R_i``.
    """
    d, s = sc.design, sc.system
    k = sc.index_of(agent_id)
    method = method or d.gains
    K = None if d.K is None else np.asarray(d.K[k], dtype=float)
    Qp = s.process_covariance
    if scale is not None:
        K = None if K is None else K / scale[:, None]
        Qp = Qp / np.outer(scale, scale)
    offsets = np.cumsum((0,) + s.output_sizes)
    R = np.diag(s.measurement_std[offsets[k]:offsets[k + 1]] ** 2)
    pw, mw = noise_weights(sc)
    label = f"design.K.{agent_id}" if gain_methods.method(method).needs_K else f"agent {agent_id}"
    return GainRequest(method=method, time=sc.time, rate=d.rate, margin=d.margin, K=K, process_weight=pw,
                       measurement_weight=mw, process_covariance=Qp, measurement_covariance=R, label=label)


def whole_placeholder(A: np.ndarray, dec: Decomposition, agent_id: int, unobserved: np.ndarray | None,
                      scale: np.ndarray | None) -> AgentDesign:
    """Agent ``agent_id`` of a whole-state design before its gain is chosen (:func:`with_gain`): its decomposition
    (what it sees, for the reports and the loss analysis; minus ``unobserved``, W, as :func:`design_agent` does), no
    gain, ``P_i = I``.

    Parameters
    ----------
    A : (n, n) array
        ``A`` in the user's coordinates.
    dec : Decomposition
        The agent's decomposition (working coordinates).
    agent_id : int
        The agent.
    unobserved : (n, w) array or None
        ``W`` in the working coordinates, the directions no agent sees (None or no columns: none).
    scale : (n,) array or None
        The working coordinates ``x = diag(scale) x_w`` (None: the user's).

    Returns
    -------
    AgentDesign
        ``consensus`` ``whole``; a zero ``K_i`` (n x s_i), no poles, method ``whole``.
    """
    if unobserved is not None and unobserved.shape[1]:
        A_w = np.asarray(A, dtype=float) if scale is None else np.asarray(A) * scale[None, :] / scale[:, None]
        dec = dec.without(unobserved, A_w)
    s = dec.Cbar.shape[0]
    zero = LocalGain(K=np.zeros((dec.P.shape[0], s)), Kbar=np.zeros((dec.n_observable, s)),
                     poles=np.zeros(0, complex), method="whole")
    return AgentDesign(id=agent_id, dec=dec, gain=zero, scale=scale, consensus="whole")


def with_gain(agent: AgentDesign, K: np.ndarray, method: str) -> AgentDesign:
    """``agent`` with the gain ``K`` (the user's coordinates) a design chose centrally (the whole-state design's
    ``K_i``, :mod:`splitspec_core.synthesis.whole_state`); ``poles`` empty: no pole of its own is assigned.

    Parameters
    ----------
    agent : AgentDesign
        The agent (:func:`whole_placeholder`); its decomposition, scale and consensus are kept.
    K : (n, s_i) array_like
        ``K_i`` in the user's coordinates (stored as ``K_w = D^-1 K``).
    method : str
        The word of ``design.gains`` that chose it.

    Returns
    -------
    AgentDesign
        A new agent design; ``agent.K`` then equals ``K``.
    """
    K = np.asarray(K, dtype=float)
    K_w = K if agent.scale is None else K / agent.scale[:, None]  # K = D K_w
    gain = LocalGain(K=K_w, Kbar=agent.dec.Q @ K_w, poles=np.zeros(0, complex), method=method)
    return AgentDesign(id=agent.id, dec=agent.dec, gain=gain, scale=agent.scale, consensus=agent.consensus)


def central_part(gain: dict, n: int, s: int) -> tuple:
    """``(K_i, P_i, R_i)`` of an agent from the configuration's ``gain``, sent when the design chose its gain centrally
    (:func:`splitspec_core.synthesis.whole_state.agent_gain`): ``K`` (n x s_i), the consensus ``whole``
    (``P_i = I``) or ``split`` with its ``P`` (n x n); no ``R_i`` (no adaptive gain).

    Parameters
    ----------
    gain : dict
        ``{"K": nested list, "consensus": "whole" or "split", "P": nested list}`` (``P`` only for ``split``).
    n : int
        The number of states.
    s : int
        The agent's number of outputs ``s_i``.

    Returns
    -------
    tuple of arrays
        ``(K_i, P_i, R_i)``: ``(n, s)``, ``(n, n)``, and an empty ``(n, 0)`` ``R_i``.

    Examples
    --------
    >>> K, P, R = central_part({"K": [[0.5], [0.0]], "consensus": "whole"}, 2, 1)
    >>> K.shape, P.tolist(), R.shape
    ((2, 1), [[1.0, 0.0], [0.0, 1.0]], (2, 0))
    """
    K = np.asarray(gain["K"], dtype=float).reshape(n, s)
    P = np.eye(n) if gain["consensus"] == "whole" else np.asarray(gain["P"], dtype=float).reshape(n, n)
    return K, P, np.zeros((n, 0))


def scenario_agent(sc: Scenario, agent_id: int, *, unobserved: np.ndarray | None = None,
                   spectrum: Spectrum | None = None) -> AgentDesign:
    """Agent ``agent_id``'s local design from the scenario alone (what its process computes; the designer computes
    the same): :func:`design_agent` with the scenario's options, its skeleton and working coordinates, and
    ``unobserved`` (W in the working coordinates, as the design sends it).

    Parameters
    ----------
    sc : Scenario
        The scenario.
    agent_id : int
        The agent.
    unobserved : (n, w) array, optional
        ``W`` in the working coordinates (None: none).
    spectrum : Spectrum, optional
        The skeleton of ``A`` already computed (None: :func:`scenario_spectrum`).

    Returns
    -------
    AgentDesign
        The agent's local design (``split`` consensus, the scenario's ``design.gains``).

    Raises
    ------
    DesignError, AssumptionError
        As :func:`design_agent`.

    Examples
    --------
    >>> import splitspec_core as ss
    >>> agent = scenario_agent(ss.load_scenario("examples/paper_discrete.yaml"), 1)
    >>> (agent.K.round(4) + 0.0).ravel().tolist(), sorted(agent.gain.poles.real.round(4).tolist())
    ([0.5, 0.94, 0.0, 0.0], [0.2, 0.3])
    """
    sp = spectrum if spectrum is not None else scenario_spectrum(sc)
    scale = working_scale(sc, sp)
    return design_agent(sc.system.A, sc.system.Cs[sc.index_of(agent_id)], gain_request(sc, agent_id, scale),
                        agent_id=agent_id, rank_tol=sc.design.rank_tol, spectrum=sp, scale=scale,
                        unobserved=unobserved)


def scenario_spectrum(sc: Scenario) -> Spectrum:
    """The skeleton of the scenario's ``A`` (every agent's rows for its decoupled states): what the designer and every
    agent process decide in (:mod:`splitspec_core.model.modal`).

    Parameters
    ----------
    sc : Scenario
        The scenario (its ``A`` and every ``C_i``).

    Returns
    -------
    Spectrum
        The skeleton of ``A`` with the stacked outputs ``C``.
    """
    return spectrum(sc.system.A, np.vstack(sc.system.Cs))


#: ``design.coordinates: auto`` works in balanced coordinates when balancing scales states this much apart
AUTO_COORDINATES = 100.0


def working_scale(sc: Scenario, sp: Spectrum) -> np.ndarray | None:
    """The working coordinates of the design (``design.coordinates``): None for the user's own (``given``), the
    balancing ``d`` of :mod:`splitspec_core.model.modal` for ``balanced``; ``auto``: balanced when the balancing scales
    two states more than :data:`AUTO_COORDINATES` apart (the user's units are not comparable: orthogonal projections
    in them mix meters with millimeters), else the user's (the paper's examples: their numbers are the paper's).

    Parameters
    ----------
    sc : Scenario
        The scenario (its ``design.coordinates``).
    sp : Spectrum
        The skeleton of its ``A`` (:func:`scenario_spectrum`), holding the balancing scales ``d``.

    Returns
    -------
    (n,) array or None
        The scales ``diag(D)`` of ``x = D x_w``, normalised to geometric mean 1; None: the user's coordinates.
    """
    mode = sc.design.coordinates
    if mode == "given" or (mode == "auto" and float(sp.d.max() / sp.d.min()) <= AUTO_COORDINATES):
        return None
    return sp.d / np.exp(np.mean(np.log(sp.d)))  # a common factor changes nothing: the geometric mean at 1


def noise_weights(sc: Scenario) -> tuple:
    """``(process weight, measurement weight)``, the identity multiples of a weighted method's Riccati equation
    (``riccati``; :mod:`splitspec_core.scenarios.gain_methods`): explicit
    ``design.riccati``, else the square of the scenario's noise level, else 1.

    The level is one number (``System.process_noise_level``, ``System.measurement_noise_level``): a scalar noise
    is itself (``process_noise ** 2``, ``measurement_noise ** 2``); a vector or matrix process noise stands as
    its root mean variance (discrete) or mean intensity (continuous), per-agent or per-output measurement noise
    as the root mean square of every output's std, so equal entries weigh as the scalar they repeat.  Only the
    ratio of the two shapes the gain; the weights stay scalar, as every agent computes its gain alike.

    Parameters
    ----------
    sc : Scenario
        The scenario (its ``design.riccati`` and its noise).

    Returns
    -------
    tuple of float
        ``(process weight, measurement weight)``, each positive.
    """
    d, s = sc.design, sc.system
    p_level, m_level = s.process_noise_level, s.measurement_noise_level
    pw = d.process_weight or (p_level**2 if p_level > 0 else 1.0)
    mw = d.measurement_weight or (m_level**2 if m_level > 0 else 1.0)
    return pw, mw
