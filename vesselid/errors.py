"""Domain errors and warnings.

Every domain error subclasses :class:`ValueError` (through :class:`VesselidError`)
so callers can catch bad input uniformly, following python-control's convention.
"""

from __future__ import annotations

__all__ = [
    "ConvergenceWarning",
    "ExperimentDesignWarning",
    "IdentificationError",
    "InvalidActionError",
    "LogValidationError",
    "ModelSpecError",
    "RankDeficientError",
    "ResourceLimitError",
    "SimulationDivergedError",
    "VesselidError",
    "WeakInstrumentWarning",
]


class VesselidError(ValueError):
    """Base class of all vesselid domain errors (a ``ValueError``)."""


class ModelSpecError(VesselidError):
    """A model structure or TOML spec is invalid (unknown signal, bad term, ...)."""


class LogValidationError(VesselidError):
    """A trial log is missing columns, holds NaN/inf, or has non-increasing time."""


class SimulationDivergedError(VesselidError):
    """A simulated state became non-finite or exceeded the divergence limit."""


class RankDeficientError(VesselidError):
    """Regressors are (near) collinear; the message names the collinear terms."""


class IdentificationError(VesselidError):
    """Identification cannot proceed (too few samples, diverging auxiliary model, ...)."""


class WeakInstrumentWarning(UserWarning):
    """ZᵀΦ is ill-conditioned: the instruments are weakly correlated with the regressors."""


class ConvergenceWarning(UserWarning):
    """The refined instrumental-variable iteration did not converge."""


class ExperimentDesignWarning(UserWarning):
    """A state comes too close to zero for the modulus to be treated as smooth (A10/A15)."""


class ResourceLimitError(VesselidError):
    """A request would need more memory, disk or time than this machine allows."""


class InvalidActionError(VesselidError):
    """An environment action is not finite or does not have the action space's shape."""
