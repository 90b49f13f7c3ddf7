"""Exceptions of splitspec.

Every error the package raises on purpose derives from :class:`SplitspecError`
and also from the matching builtin, so callers can catch either.  Messages are
one line, name the offending key or matrix, and say what was expected.
"""

from __future__ import annotations


class SplitspecError(Exception):
    """Base class of every error splitspec raises on purpose."""


class ScenarioError(SplitspecError, ValueError):
    """A scenario file (or dictionary) is malformed: the message names the key."""


class DimensionError(ScenarioError):
    """Matrix shapes do not agree (e.g. ``system.C.3`` vs ``system.A``)."""


class AssumptionError(SplitspecError, ValueError):
    """A mathematical precondition of the paper does not hold.

    Examples: a graph that is not strongly connected, a system that is not
    jointly observable, explicit gains that do not meet the rate.
    """


class DesignError(SplitspecError, RuntimeError):
    """The design could not be completed (e.g. no q found below ``q_max``)."""


class NetworkError(SplitspecError, RuntimeError):
    """A process's command line was well formed, but the deployment around it is not what it names.

    No router answers at the endpoint, the router refused the process (no credentials, a wrong
    password), the router hosts no run of that id, or the router went away while the process waited.
    The command-line boundary exits with status 1 (a failure), not 2 (bad input): the same command
    may succeed once the run is up.
    """
