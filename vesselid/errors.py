"""Domain errors and warnings: the one error hierarchy of the package.

Every domain error subclasses :class:`ValueError` (through :class:`VesselidError`)
so callers can catch bad input uniformly, following python-control's convention::

    VesselidError (ValueError)
    ├── ModelSpecError           invalid model structure / TOML spec
    ├── LogValidationError       trial log: missing column, NaN/inf, bad time
    ├── SimulationError          bad simulation input (shapes, θ)
    │   └── SimulationDivergedError
    ├── IdentificationError      identification cannot proceed
    │   ├── RankDeficientError   collinear regressors (names the terms)
    │   ├── CovarianceError      unknown covariance estimator / bad configuration
    │   └── EstimationFailedError the estimator ran but gave no finite estimate
    │       └── NoUsableModelError no estimator of the fallback chain gave a usable
    │                            model (the chain tried is attached)
    ├── SeaTrialError            bad sea-trial settings
    ├── ControlError             bad controller settings
    └── CLIError                 bad command-line input

The command line maps these (and ``OSError``) to exit code 2 with a one-line reason;
any other exception is a bug and shows as one (traceback, exit code 1). Raise a
subclass here for bad input, never a plain ``ValueError``.
"""

from __future__ import annotations

__all__ = [
    "CLIError",
    "ControlError",
    "ConvergenceWarning",
    "CovarianceError",
    "DerivedInputWarning",
    "EstimationFailedError",
    "ExperimentDesignWarning",
    "FallbackWarning",
    "IdentifiabilityWarning",
    "IdentificationError",
    "InvalidActionError",
    "LogValidationError",
    "MisspecificationWarning",
    "ModelSpecError",
    "NoUsableModelError",
    "ParameterDriftWarning",
    "RankDeficientError",
    "ResourceLimitError",
    "SeaTrialError",
    "SimulationDivergedError",
    "SimulationError",
    "UnstableModelWarning",
    "VesselidError",
    "WeakInstrumentWarning",
]


class VesselidError(ValueError):
    """Base class of all vesselid domain errors (a ``ValueError``)."""


class ModelSpecError(VesselidError):
    """A model structure or TOML spec is invalid (unknown signal, bad term, ...)."""


class LogValidationError(VesselidError):
    """A trial log is missing columns, holds NaN/inf, or has non-increasing time."""


class SimulationError(VesselidError):
    """Bad simulation input: inputs, disturbances or θ of the wrong shape, non-finite θ."""


class SimulationDivergedError(SimulationError):
    """A simulated state became non-finite or exceeded the divergence limit."""


class IdentificationError(VesselidError):
    """Identification cannot proceed (too few samples, diverging auxiliary model, ...)."""


class RankDeficientError(IdentificationError):
    """Regressors are (near) collinear; the message names the collinear terms."""


class CovarianceError(IdentificationError):
    """Unknown covariance estimator or invalid configuration of one."""


class EstimationFailedError(IdentificationError):
    """The estimator ran on valid input but gave no finite estimate (singular instrument
    equations, an auxiliary model that diverges from every start, a likelihood that could
    not be maximised). The default estimator's fallback chain catches this one; input
    errors (other :class:`IdentificationError` subclasses) are raised at once."""


class NoUsableModelError(EstimationFailedError):
    """No estimator of the fallback chain gave a finite estimate.

    Attributes
    ----------
    chain : list of dict
        One entry per estimator tried: ``method``, ``outcome``, ``reason``.
    """

    def __init__(self, message: str, chain: list | None = None) -> None:
        super().__init__(message)
        self.chain = list(chain or [])


class SeaTrialError(VesselidError):
    """Bad sea-trial settings (unknown aggregate, too few samples, violated margins...)."""


class ControlError(VesselidError):
    """Bad controller settings (unknown terms, zero input gain, ...)."""


class CLIError(VesselidError):
    """Bad command-line input (exit code 2)."""


class WeakInstrumentWarning(UserWarning):
    """ZᵀΦ is ill-conditioned: the instruments are weakly correlated with the regressors."""


class ConvergenceWarning(UserWarning):
    """The refined instrumental-variable iteration did not converge."""


class ClosedLoopWarning(UserWarning):
    """An open-loop estimator was used on a log recorded in (or looking like) closed loop."""


class UnstableModelWarning(UserWarning):
    """The identified model is unstable on the log: its free-run simulation on the log's
    own inputs diverges or leaves the measured range by far."""


class FallbackWarning(UserWarning):
    """The default estimator failed on this log; the result is a fallback estimator's
    (``diagnostics["fallback_chain"]`` says which were tried and why)."""


class ExperimentDesignWarning(UserWarning):
    """A state comes too close to zero for the modulus to be treated as smooth (A10/A15)."""


class DerivedInputWarning(UserWarning):
    """A derived input is computed from measured states: not exogenous (vesselid.model.derived)."""


class IdentifiabilityWarning(UserWarning):
    """The data identify a combination of parameters, not each one (e.g. a current's mean
    inside the modulus without a disturbance sensor)."""


class MisspecificationWarning(UserWarning):
    """Two estimators that are consistent under a correct model structure disagree
    significantly: the structure is misspecified on this log
    (:mod:`vesselid.identify.misspecification`)."""


class ParameterDriftWarning(UserWarning):
    """The parameters differ between parts of the log (split-sample stability test)."""


class ResourceLimitError(VesselidError):
    """A request would need more memory, disk or time than this machine allows."""


class InvalidActionError(VesselidError):
    """An environment action is not finite or does not have the action space's shape."""
