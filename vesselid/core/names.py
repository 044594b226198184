"""Static names of the estimators and covariance estimators, for checking arguments.

The registries (:data:`vesselid.identify.registry.ESTIMATORS`,
:data:`vesselid.identify.covariance.COVARIANCE_ESTIMATORS`) load the compiled
kernels; the command line checks ``--method``/``--cov`` against these plain tuples
instead, so that an argument error never loads numba.
``tests/test_lazy_imports.py`` checks that they equal the registries.
"""

from __future__ import annotations

__all__ = ["COV_TYPES", "DEFAULT_COV_TYPE", "DEFAULT_METHOD", "DEFAULT_STREAM_METHOD",
           "METHODS", "STREAM_METHODS"]

#: ``--method`` names, in the registry's order (:data:`~vesselid.identify.ESTIMATORS`).
METHODS: tuple[str, ...] = ("ls", "iv", "iv-zero-mean", "lagged-2sls", "sriv", "gmm", "auto",
                            "pem", "cl-iv")
#: The package default estimator (:data:`~vesselid.identify.DEFAULT_METHOD`).
DEFAULT_METHOD = "auto"
#: ``identify --stream`` methods (:data:`vesselid.identify.streaming.STREAM_METHODS`) and default.
STREAM_METHODS: tuple[str, ...] = ("ls", "iv", "iv-zero-mean")
DEFAULT_STREAM_METHOD = "iv-zero-mean"
#: ``--cov`` names (:func:`vesselid.identify.covariance_api.available`) and the default.
COV_TYPES: tuple[str, ...] = ("unadjusted", "hac", "cluster")
DEFAULT_COV_TYPE = "hac"
