"""Where a local gain moves the observable part's slow modes: :class:`GainTarget` and :func:`beyond_target`.

Its own module because two others read it one way: :mod:`.gains` places the poles past it (the modes already
there are left alone: "Only the slow modes move" in its docstring), and :mod:`.observability` decides the clusters
already past it at round-off and measures the others against the distance the gain moves them.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["GainTarget", "beyond_target"]


@dataclass(frozen=True)
class GainTarget:
    """Where a local gain moves the observable part's slow modes (:func:`beyond_target` makes it): past
    ``-(1 + margin) rate`` (continuous) or inside ``rate / (1 + margin)`` (discrete).  Called on an array of
    eigenvalues: true where a mode is already there, so the gain leaves it alone."""

    time: str
    rate: float
    margin: float

    def __call__(self, z) -> np.ndarray:
        if self.time == "continuous":
            return np.real(z) < -(1.0 + self.margin) * self.rate
        return np.abs(z) < self.rate / (1.0 + self.margin)

    def shift(self, z) -> np.ndarray:
        """How far each eigenvalue is from the target region (0 inside it): the least the gain moves it.

        Parameters
        ----------
        z : array_like of complex
            Eigenvalues.

        Returns
        -------
        float array, shaped as ``z``
            ``max(0, Re z + (1 + margin) lam)`` (continuous) or ``max(0, |z| - lam / (1 + margin))`` (discrete).
        """
        if self.time == "continuous":
            return np.maximum(0.0, np.real(z) + (1.0 + self.margin) * self.rate)
        return np.maximum(0.0, np.abs(z) - self.rate / (1.0 + self.margin))


def beyond_target(time: str, rate: float, margin: float) -> GainTarget:
    """Where the gain moves the slow modes (:class:`GainTarget`): called on an array of
    eigenvalues, true where a mode already decays faster than the gain's target (real part below ``-(1 + margin)
    lam`` in continuous time, modulus below ``lam / (1 + margin)`` in discrete time).  The gain leaves such modes
    where they are (:mod:`splitspec_core.model.gains`); the observability decisions count them at round-off and
    measure the other clusters' dynamics against the distance the gain moves them
    (:func:`splitspec_core.model.observability.decompose`).

    Parameters
    ----------
    time : {"continuous", "discrete"}
        The scenario's time.
    rate : float
        The rate ``lam``: a decay rate (continuous) or a spectral radius (discrete).
    margin : float
        Relative margin past ``lam``.

    Returns
    -------
    GainTarget

    Examples
    --------
    >>> import numpy as np
    >>> t = beyond_target("continuous", 1.0, 0.5)
    >>> t(np.array([-2.0, -1.0])).tolist(), t.shift(np.array([-2.0, -1.0])).tolist()
    ([True, False], [0.0, 0.5])
    """
    return GainTarget(time, float(rate), float(margin))
