"""vesselid: consistent identification of second-order modulus vessel models.

Simulate marine vessels under current, wind and sensor noise, and identify their
physical models with the consistent instrumental-variable estimators of
Ljungberg & Enqvist ("Consistent Parameter Estimators for Second-order Modulus
Systems with Non-additive Disturbances").
"""

from __future__ import annotations

__version__ = "0.1.0"

from vesselid.errors import (
    ConvergenceWarning,
    ExperimentDesignWarning,
    IdentificationError,
    LogValidationError,
    ModelSpecError,
    RankDeficientError,
    SimulationDivergedError,
    VesselidError,
    WeakInstrumentWarning,
)
from vesselid.model import Aggregate, ModelSpec
from vesselid.terms import Term

__all__ = [
    "Aggregate",
    "ConvergenceWarning",
    "ExperimentDesignWarning",
    "IdentificationError",
    "LogValidationError",
    "ModelSpec",
    "ModelSpecError",
    "RankDeficientError",
    "SimulationDivergedError",
    "Term",
    "VesselidError",
    "WeakInstrumentWarning",
    "__version__",
]

try:  # register the gymnasium environments (vesselid/Heave-v0, ...) when gymnasium is there
    from vesselid.envs import register_envs as _reg

    _reg()
except ImportError:
    pass
