"""The errors of the statics (``controller.core.statics`` and the modules it is built from).

Pure module, no imports: one place for the classes, so the solver's pieces can raise them.
"""

from __future__ import annotations

__all__ = ["SingularConfiguration", "SolverUnavailable", "StaticsError", "StaticsInputError"]


class StaticsError(ValueError):
    """Base class of the errors of the statics."""


class StaticsInputError(StaticsError):
    """Bad input: wrong shape, non-finite number, non-positive mass, inverted limits."""


class SingularConfiguration(StaticsError):
    """No tension distribution exists or is defined at this pose (see the statics module)."""


class SolverUnavailable(StaticsError):
    """A degenerate pose of more than four cables needs scipy's linear-programming solver,
    which is not installed."""
