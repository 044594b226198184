"""Identification of second-order modulus models from trial logs.

>>> from vesselid.identify import identify
>>> result = identify(log, spec)                          # doctest: +SKIP
>>> print(result.summary())                               # doctest: +SKIP

Estimators live in one registry, :data:`ESTIMATORS` (``--method`` on the command
line); :data:`DEFAULT_METHOD` is the package default. The paper's three:
``"ls"`` (16), ``"iv"`` (refined instrumental variables, (4) and (6)),
``"iv-zero-mean"`` (the paper's IV_{E{ζ}=0}, consistent under Lemma 3.1, and with
an ``[aggregate]`` relation in the spec under Lemma 4.1 via the predictor (9)).
"""

from __future__ import annotations

from vesselid.core.lazy import lazy_attributes

__all__ = [
    "COMBINE_MODES",
    "DEFAULT_COMBINE",
    "DEFAULT_METHOD",
    "ESTIMATORS",
    "METHODS",
    "PAPER_METHODS",
    "TARGETS",
    "EquationDesign",
    "Estimator",
    "EstimatorEntry",
    "FitOptions",
    "IdentificationResult",
    "RegressionData",
    "asymptotic_covariance",
    "estimate",
    "from_arrays",
    "from_log",
    "get_estimator",
    "identify",
    "method_labels",
    "register",
]

# Imported on first use (PEP 562): ``vesselid.identify.registry`` (the estimator names and
# capabilities the command line checks) loads without the compiled estimators.
_LAZY = {
    "COMBINE_MODES": "vesselid.identify.options",
    "estimate": "vesselid.identify.estimators",
    "DEFAULT_COMBINE": "vesselid.identify.api",
    "asymptotic_covariance": "vesselid.identify.api",
    "identify": "vesselid.identify.api",
    "DEFAULT_METHOD": "vesselid.identify.registry",
    "ESTIMATORS": "vesselid.identify.registry",
    "METHODS": "vesselid.identify.registry",
    "PAPER_METHODS": "vesselid.identify.registry",
    "EstimatorEntry": "vesselid.identify.registry",
    "get_estimator": "vesselid.identify.registry",
    "method_labels": "vesselid.identify.registry",
    "register": "vesselid.identify.registry",
    "TARGETS": "vesselid.identify.options",
    "FitOptions": "vesselid.identify.options",
    "EquationDesign": "vesselid.identify.base",
    "Estimator": "vesselid.identify.base",
    "IdentificationResult": "vesselid.identify.results",
    "RegressionData": "vesselid.identify.data",
    "from_arrays": "vesselid.identify.data",
    "from_log": "vesselid.identify.data",
}

__getattr__, __dir__ = lazy_attributes(__name__, _LAZY, __all__)
