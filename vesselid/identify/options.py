"""The options of :meth:`vesselid.identify.base.Estimator.fit` as one typed object.

:class:`FitOptions` holds every keyword :func:`vesselid.identify.identify` passes to an
estimator (``combine``, ``target``, ``cov_type``, ``max_iter``, ``noise_order``, ...) and
validates them in one place, when it is built: a bad value is an
:class:`~vesselid.errors.IdentificationError` (a ``ValueError``) with a one-line reason,
an unknown name a ``TypeError``. What depends on the estimator (the ``combine`` modes it
supports, the covariance estimators it can honour, the shape of user instruments
against its regressors) is checked by the estimator in ``fit``.

>>> from vesselid.identify.options import FitOptions
>>> FitOptions(max_iter=50).max_iter
50
>>> FitOptions.of(FitOptions(tol=1e-6), max_iter=20).tol
1e-06
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from dataclasses import dataclass
from numbers import Integral, Real
from typing import Any

import numpy as np

from vesselid.errors import IdentificationError

__all__ = ["COMBINE_MODES", "DEFAULT_COMBINE", "NOISE_ORDER_RANGE", "TARGETS", "FitOptions",
           "FitOptionsError"]

#: Multi-experiment forms (``combine``): the per-experiment normal equations summed
#: (``"pooled"``) or the ``p N_E`` equations (6)/(10) stacked.
COMBINE_MODES = ("pooled", "stacked")
#: Default way to combine experiments (see docs/method-notes.md).
DEFAULT_COMBINE = "pooled"
#: Regression targets (the left-hand side of (4)/(10)); see
#: :func:`vesselid.identify.base._target_rule`.
TARGETS = ("measured", "aggregated")
#: Smallest and largest AR order of the noise-model prefilter (``noise_order``).
NOISE_ORDER_RANGE = (1, 50)


class FitOptionsError(IdentificationError):
    """A fit option with a value outside its domain (one-line reason)."""


def _integer(val: Any) -> bool:
    return isinstance(val, Integral | np.integer) and not isinstance(val, bool | np.bool_)


def _real(val: Any) -> bool:
    return isinstance(val, Real | np.floating | np.integer) and not isinstance(
        val, bool | np.bool_)


@dataclass(frozen=True)
class FitOptions:
    """Options of one estimation (:meth:`~vesselid.identify.base.Estimator.fit`).

    Parameters
    ----------
    combine : {"pooled", "stacked"}
        Multi-experiment form (see :func:`vesselid.identify.identify`).
    target : {"measured", "aggregated"}
        Regression target with an ``[aggregate]`` relation.
    cov_type : str, optional
        Covariance estimator; default the package default.
    cov_config : mapping, optional
        Options of the covariance estimator.
    instruments : ndarray (T, P), optional
        User-supplied instruments (methods ``iv`` and ``iv-zero-mean``).
    theta_start : array-like or mapping, optional
        Start of the refined iteration instead of the LS estimate.
    max_iter : int
        Largest number of refined-iteration steps (positive).
    tol : float
        Relative fixed-point residual at which the iteration stops (positive).
    eta : mapping state -> float, optional
        Known noise bounds of the A10/A15 design check (finite, non-negative).
    design_threshold : float
        Largest share of samples within ``η`` of zero before warning (in ``[0, 1]``).
    weak_instrument_cond : float
        Warn when the equilibrated ``ZᵀΦ`` has a larger condition number (positive;
        ``inf``: never).
    min_samples : int, optional
        Minimum samples per experiment (positive; default parameters per equation + 2).
    sensor_noise : mapping state -> float, or bool, optional
        Std of the white sensor noise on each regressor signal (``False``: none;
        ``None``: the log's ``metadata["sensor_noise_std"]``).
    noise_order : int, optional
        AR order of the noise-model prefilter of the estimators that use one
        (``sriv``, ``auto``'s fallback) instead of their default (an integer in
        :data:`NOISE_ORDER_RANGE`).
    """

    combine: str = DEFAULT_COMBINE
    target: str = "measured"
    cov_type: str | None = None
    cov_config: Mapping[str, Any] | None = None
    instruments: Any | None = None
    theta_start: Any | None = None
    max_iter: int = 100
    tol: float = 1e-9
    eta: Mapping[str, float] | None = None
    design_threshold: float = 0.01
    weak_instrument_cond: float = 1e6
    min_samples: int | None = None
    sensor_noise: Mapping[str, float] | bool | None = None
    noise_order: int | None = None

    def __post_init__(self) -> None:
        for name, check in _CHECKS:
            val = getattr(self, name)
            if val is not None or name in _REQUIRED:
                reason = check(val)
                if reason:
                    raise FitOptionsError(reason.format(name=name, val=val))

    @classmethod
    def of(cls, options: FitOptions | Mapping[str, Any] | None = None,
           **overrides: Any) -> FitOptions:
        """``options`` (an object, a mapping of keywords, or None: the defaults) with
        ``overrides`` replaced; an unknown name is a ``TypeError``."""
        if options is None:
            return cls(**overrides)
        if isinstance(options, FitOptions):
            return dataclasses.replace(options, **overrides) if overrides else options
        if isinstance(options, Mapping):
            return cls(**{**options, **overrides})
        raise TypeError(f"options must be FitOptions or a mapping, got "
                        f"{type(options).__name__}")

    def as_dict(self) -> dict[str, Any]:
        """The options as keywords (for code that passes them on by name)."""
        return {f.name: getattr(self, f.name) for f in dataclasses.fields(self)}


def _choice(choices: tuple[str, ...]):
    def check(val: Any) -> str:
        ok = isinstance(val, str) and val in choices
        return "" if ok else "unknown {name} {val!r}; choose from " + str(list(choices))
    return check


def _positive_integer(val: Any) -> str:
    return "" if _integer(val) and val >= 1 else "{name} must be a positive integer, got {val!r}"


def _positive_number(val: Any) -> str:
    ok = _real(val) and math.isfinite(val) and val > 0
    return "" if ok else "{name} must be a positive number, got {val!r}"


def _share(val: Any) -> str:
    ok = _real(val) and 0.0 <= val <= 1.0
    return "" if ok else "{name} must be a number in [0, 1], got {val!r}"


def _condition_bound(val: Any) -> str:
    ok = _real(val) and val > 0
    return "" if ok else "{name} must be a positive number (inf: never warn), got {val!r}"


def _name(val: Any) -> str:
    return "" if isinstance(val, str) else "{name} must be a covariance estimator name, got {val!r}"


def _mapping(val: Any) -> str:
    ok = _is_mapping(val)
    return "" if ok else "{name} must be a mapping of option names to values, got {val!r}"


def _bounds(val: Any) -> str:
    ok = _is_mapping(val) and all(
        _real(v) and math.isfinite(v) and v >= 0 for _, v in val.items())
    return "" if ok else "{name} must map states to finite non-negative noise bounds, got {val!r}"


def _sensor_noise(val: Any) -> str:
    ok = isinstance(val, bool) or _is_mapping(val)
    return "" if ok else ("{name} must map states to noise stds, or be False (no "
                          "correction), got {val!r}")


def _noise_order(val: Any) -> str:
    lo, hi = NOISE_ORDER_RANGE
    ok = _integer(val) and lo <= val <= hi
    return "" if ok else "{name} must be an integer in " + f"{lo}..{hi}" + ", got {val!r}"


def _is_mapping(val: Any) -> bool:
    """A mapping, or a mapping-like object with ``get`` and ``items`` (a Series)."""
    return isinstance(val, Mapping) or (hasattr(val, "get") and hasattr(val, "items"))


def _instruments(val: Any) -> str:
    ok = isinstance(val, np.ndarray | list | tuple)
    return "" if ok else "{name} must be a (T, P) array, got {val!r}"


#: options that may not be None
_REQUIRED = frozenset({"combine", "target", "max_iter", "tol", "design_threshold",
                       "weak_instrument_cond"})
#: (field, check -> "" or the message template of its failure), in checking order
_CHECKS = (
    ("combine", _choice(COMBINE_MODES)),
    ("target", _choice(TARGETS)),
    ("cov_type", _name),
    ("cov_config", _mapping),
    ("instruments", _instruments),
    ("max_iter", _positive_integer),
    ("tol", _positive_number),
    ("eta", _bounds),
    ("design_threshold", _share),
    ("weak_instrument_cond", _condition_bound),
    ("min_samples", _positive_integer),
    ("sensor_noise", _sensor_noise),
    ("noise_order", _noise_order),
)
