"""The gain design methods, declared once: the words of ``design.gains``, what each one needs and how the design
uses it.

A :class:`GainMethod` is the scenario's side of a method: its word, its doc line (the scenario page's and
``--help``'s), and the flags the parsers and the design stack ask instead of spelling method names:

``local``
    each agent designs its own ``K_i`` from ``(A, C_i)``, the rate and the scenario's noise (paper, proof of prop.
    error): one function registered under the same word in :mod:`splitspec_core.model.gains`
    (``@local_method("word")``; a word declared here with no function there fails a test, a function registered
    under a word not declared here fails at import);
``needs_K``
    the user's ``K_i`` (``design.K``, one n x s_i matrix per agent);
``needs_noise``
    refused unless the scenario states noise (``system.process_noise`` or ``system.measurement_noise``);
``margin``
    moves the slow modes of the observable part to a target set by ``design.margin``;
``weighted``
    takes ``design.riccati``'s process and measurement weights (identity multiples);
``whole``
    what ``design.consensus: whole`` does with it (:mod:`splitspec_core.synthesis.whole_state`): ``given`` the
    user's ``K_i``, ``shifted`` the centralized Riccati design of the scenario's noise shifted by the rate,
    ``search`` the noise-optimal search; None: refused with the whole state;
``split``
    a central method (``local`` False): the local methods its split tries, the first its default.

Adding a method: its entry here, its function in ``model/gains.py``, its test, its line in
``docs/how-to/scenario.md``.
"""

from __future__ import annotations

from dataclasses import dataclass

from ..errors import ScenarioError

__all__ = ["GainMethod", "METHODS", "NAMES", "DEFAULT", "NOISY_DEFAULT", "method", "names_where", "listed"]


@dataclass(frozen=True)
class GainMethod:
    """One word of ``design.gains`` and what it needs (module docstring)."""

    name: str
    doc: str
    local: bool = True
    needs_K: bool = False
    needs_noise: bool = False
    margin: bool = False
    weighted: bool = False
    whole: str | None = None
    split: tuple = ()


#: every gain method, in the order the scenario page and the messages list them
METHODS = {g.name: g for g in (
    GainMethod("place", "pole placement: distinct real poles beyond the rate by design.margin", margin=True),
    GainMethod("riccati", "steady-state Kalman gain of identity-multiple weights (design.riccati, else the noise "
                          "levels), shifted so its poles beat the rate by design.margin", margin=True, weighted=True,
               whole="shifted"),
    GainMethod("kalman", "steady-state Kalman gain of the agent's own noise (the process noise on its slow observable "
                         "modes, its R_i), shifted so its poles beat the rate by design.margin", needs_noise=True,
               margin=True, whole="shifted"),
    GainMethod("explicit", "the user's K_i (design.K), checked against the rate", needs_K=True, whole="given"),
    GainMethod("optimal", "gains, consensus subspace and q chosen for the scenario's noise under the rate's "
                          "certificate", local=False, needs_noise=True, whole="search", split=("riccati", "place")),
)}
NAMES = tuple(METHODS)
#: ``design.gains`` when the scenario does not say: ``DEFAULT``, or ``NOISY_DEFAULT`` when it states noise
DEFAULT = "place"
NOISY_DEFAULT = "optimal"


def method(name: str) -> GainMethod:
    """The declaration of the gain method ``name``.

    Parameters
    ----------
    name : str
        A word of ``design.gains``.

    Returns
    -------
    GainMethod
        Its declaration.

    Raises
    ------
    ScenarioError
        ``name`` is not declared (one line listing the declared words).

    Examples
    --------
    >>> method("kalman").needs_noise, method("kalman").whole
    (True, 'shifted')
    >>> method("lqr")  # doctest: +ELLIPSIS
    Traceback (most recent call last):
    ...
    splitspec_core.errors.ScenarioError: design.gains must be one of place, riccati, ..., got 'lqr'
    """
    try:
        return METHODS[name]
    except (KeyError, TypeError):
        raise ScenarioError(f"design.gains must be one of {', '.join(NAMES)}, got {name!r}") from None


def names_where(**flags) -> tuple:
    """The words of the methods whose flags have the given values (``names_where(local=True)``), in table order.

    Parameters
    ----------
    **flags : Any
        :class:`GainMethod` fields and the value each must have (none: every method).

    Returns
    -------
    tuple of str
        The matching words.

    Examples
    --------
    >>> names_where(local=True, needs_K=False)
    ('place', 'riccati', 'kalman')
    """
    return tuple(g.name for g in METHODS.values() if all(getattr(g, k) == v for k, v in flags.items()))



def listed(names: tuple) -> str:
    """Words as a message says them: ``place, riccati or kalman``.

    Parameters
    ----------
    names : tuple of str
        Words of ``design.gains`` (:func:`names_where`).

    Returns
    -------
    str
        The words, the last two joined by ``or``, the others by commas.

    Examples
    --------
    >>> listed(("place", "riccati", "kalman")), listed(("place",))
    ('place, riccati or kalman', 'place')
    """
    return " or ".join(names) if len(names) < 3 else ", ".join(names[:-1]) + " or " + names[-1]
