"""Sampling a continuous model: the zero-order hold of ``system.sample`` and of the sampled-data estimator.

``exp(A dt)``, ``int_0^dt exp(A s) ds`` and the sampled process-noise covariance, by one block exponential
(Van Loan). The scenario uses it to sample ``(A, B)``; the pure steps (:mod:`splitspec_core.model.steps`), the
plant and the certificates use the same function, so every path samples alike.
"""

from __future__ import annotations

import numpy as np

__all__ = ["sampled_data_matrices"]


def sampled_data_matrices(A: np.ndarray, dt: float, *, noise_intensity: float | np.ndarray = 0.0) -> tuple:
    """``(E, D, Qd)`` for step ``dt``: ``E = exp(A dt)``, ``D = int_0^dt exp(A s) ds`` and the process-noise
    covariance per step ``Qd = int_0^dt exp(A s) Qc exp(A s)' ds`` of white noise of intensity ``Qc``
    (``E[v(t) v(s)'] = Qc delta(t - s)``): ``noise_intensity`` a number ``q`` (``Qc = q I``), a vector
    (``diag``) or an ``n x n`` matrix (Van Loan: ``Qd = G22' G12`` of ``exp([[-A, Qc], [0, A']] dt)``).

    Parameters
    ----------
    A : (n, n) ndarray
        The continuous-time system matrix ``A``.
    dt : float
        The step, in seconds.
    noise_intensity : float, (n,) array_like or (n, n) array_like, optional
        The intensity ``Qc`` of the process noise: a number ``q`` (``Qc = q I``), the diagonal, or the
        matrix.  0 (default) or all zeros: no noise, ``Qd`` is zero (a negative number counts as none).

    Returns
    -------
    E : (n, n) ndarray
        ``exp(A dt)``.
    D : (n, n) ndarray
        ``int_0^dt exp(A s) ds``.
    Qd : (n, n) ndarray
        The process-noise covariance per step, symmetrised.

    Examples
    --------
    >>> import numpy as np
    >>> E, D, Qd = sampled_data_matrices(np.array([[0.0, 1.0], [0.0, 0.0]]), 0.5, noise_intensity=1.0)
    >>> E
    array([[1. , 0.5],
           [0. , 1. ]])
    >>> D.round(6)
    array([[0.5  , 0.125],
           [0.   , 0.5  ]])
    >>> Qd.round(6)
    array([[0.541667, 0.125   ],
           [0.125   , 0.5     ]])
    """
    import scipy.linalg as sla  # here only: a discrete-time agent imports no scipy

    n = A.shape[0]
    M = np.zeros((2 * n, 2 * n))
    M[:n, :n] = A
    M[:n, n:] = np.eye(n)
    F = sla.expm(M * dt)
    E, D = F[:n, :n], F[:n, n:]
    scalar = np.ndim(noise_intensity) == 0
    if noise_intensity > 0 if scalar else np.any(noise_intensity):
        VL = np.zeros((2 * n, 2 * n))
        VL[:n, :n] = -A
        if scalar:
            VL[:n, n:] = noise_intensity * np.eye(n)
        else:
            Qc = np.asarray(noise_intensity, dtype=float)
            VL[:n, n:] = np.diag(Qc) if Qc.ndim == 1 else Qc
        VL[n:, n:] = A.T
        G = sla.expm(VL * dt)
        Qd = G[n:, n:].T @ G[:n, n:]
        Qd = 0.5 * (Qd + Qd.T)
    else:
        Qd = np.zeros((n, n))
    return E, D, Qd
