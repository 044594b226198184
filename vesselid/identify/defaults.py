"""The package's default choices, named once (read by the registry and the estimators).

Plain constants with no imports, so that the estimators' own modules can use them without
importing the registry that names those modules.
"""

from __future__ import annotations

__all__ = ["COV_TYPES", "DEFAULT_COV_TYPE", "DEFAULT_METHOD", "DEFAULT_STREAM_METHOD"]

#: The package default estimator (``identify`` and ``vesselid identify`` without
#: ``--method``), chosen from ``scripts/estimator_study.py``
#: (docs/guide/choosing-an-estimator.md).
DEFAULT_METHOD = "auto"

#: The default of ``identify --stream`` (a consistent estimator among the streamable ones).
DEFAULT_STREAM_METHOD = "iv-zero-mean"

#: ``--cov`` names (:data:`vesselid.identify.covariance.COVARIANCE_ESTIMATORS`) and the
#: package default (chosen from the calibration study, ``scripts/calibration.py``).
COV_TYPES: tuple[str, ...] = ("unadjusted", "hac", "cluster")
DEFAULT_COV_TYPE = "hac"
