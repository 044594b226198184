"""The one registry of estimators: names, where each lives, what each can do.

Every place that lists, checks or labels estimators reads this module: the command line's
``--method`` choices and argument errors, :func:`~vesselid.identify.api.identify`,
:mod:`vesselid.studies.montecarlo`, :mod:`vesselid.studies.reproduce`,
:mod:`vesselid.studies.plots` and the hostile-input checks. An entry is data — a name, a lazy
``"module:Class"`` target with its options and capability flags — so importing this module
loads no estimator (``vesselid identify --method nonsense`` is refused without numba);
:func:`get_estimator` builds an estimator on first use.

Adding an estimator is one module with an :class:`~vesselid.identify.base.Estimator` subclass
and one :func:`register` call (or one line in :data:`_BUILTIN`)::

    register(EstimatorEntry("my-iv", "mypackage.estimators:MyIV", {"order": 2},
                            multi_state=True))
"""

from __future__ import annotations

import importlib
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from vesselid.errors import IdentificationError
from vesselid.identify.defaults import (
    COV_TYPES,
    DEFAULT_COV_TYPE,
    DEFAULT_METHOD,
    DEFAULT_STREAM_METHOD,
)

if TYPE_CHECKING:  # pragma: no cover
    from vesselid.identify.base import Estimator

__all__ = [
    "COV_TYPES",
    "DEFAULT_COV_TYPE",
    "DEFAULT_METHOD",
    "DEFAULT_STREAM_METHOD",
    "ESTIMATORS",
    "METHODS",
    "PAPER_METHODS",
    "STREAM_METHODS",
    "EstimatorEntry",
    "entries",
    "entry",
    "get_estimator",
    "method_labels",
    "names",
    "register",
]


@dataclass(frozen=True)
class EstimatorEntry:
    """One registered estimator: where it lives and what it can do.

    Parameters
    ----------
    name : str
        Registry key (``--method``).
    target : str
        ``"module:Class"`` of the :class:`~vesselid.identify.base.Estimator` subclass,
        imported on first use.
    options : mapping
        Keyword arguments of the class (the configured instance is the estimator).
    streamable : bool
        Works on moment sums of a log larger than memory (``identify --stream``).
    multi_state : bool
        Identifies specs with more than one state equation.
    own_covariance : bool
        Computes its covariance from its own (likelihood) model; ``--cov`` does not apply.
    closed_loop : bool
        Needs a closed-loop log (declared controller, reference and dither columns).
    paper : bool
        One of the three estimators of the paper's Tables 1–2.
    """

    name: str
    target: str
    options: Mapping[str, Any] = field(default_factory=dict)
    streamable: bool = False
    multi_state: bool = True
    own_covariance: bool = False
    closed_loop: bool = False
    paper: bool = False

    def build(self) -> Estimator:
        """A new configured estimator instance."""
        module, _, attr = self.target.partition(":")
        if not attr:
            raise IdentificationError(f"estimator target {self.target!r} is not 'module:Class'")
        cls = getattr(importlib.import_module(module), attr)
        est = cls(**dict(self.options))
        if est.name != self.name:
            raise IdentificationError(
                f"estimator {self.target!r} is named {est.name!r}, registered as {self.name!r}")
        return est


_AUTO_LABEL = ("GMM, simulated + delayed instruments unless the C test or the colour test "
               "rejects the delayed ones (then PEM on one-state logs, else SRIV) or, on "
               "one-state logs, the colour test's p-value falls below its guard (then PEM "
               "with the sensor-noise model)")

#: The package's estimators, in the order of ``--method``'s choices.
_BUILTIN: tuple[EstimatorEntry, ...] = (
    EstimatorEntry("ls", "vesselid.identify.methods:LeastSquares", streamable=True, paper=True),
    EstimatorEntry("iv", "vesselid.identify.methods:RefinedIV", {"zero_mean": False},
                   streamable=True, paper=True),
    EstimatorEntry("iv-zero-mean", "vesselid.identify.methods:RefinedIV", {"zero_mean": True},
                   streamable=True, paper=True),
    EstimatorEntry("lagged-2sls", "vesselid.identify.efficient:LaggedIV"),
    EstimatorEntry("sriv", "vesselid.identify.efficient:InstrumentalGMM", {
        "instruments": "simulated", "noise_order": 4, "refine": 3, "name": "sriv",
        "label": "refined IV with an AR(4) noise-model prefilter (SRIV)", "short": "SRIV"}),
    EstimatorEntry("gmm", "vesselid.identify.efficient:InstrumentalGMM", {
        "instruments": "combined", "refine": 1, "name": "gmm",
        "label": "two-step GMM, simulated + delayed-measurement instruments", "short": "GMM"}),
    EstimatorEntry("auto", "vesselid.identify.efficient:InstrumentalGMM", {
        "instruments": "auto", "noise_order": 4, "refine": 1, "name": "auto",
        "pem_fallback": True, "label": _AUTO_LABEL, "short": "auto"}),
    EstimatorEntry("pem", "vesselid.identify.pem:PredictionError", multi_state=False,
                   own_covariance=True),
    EstimatorEntry("pem-switching", "vesselid.identify.switching:SwitchingCurrent",
                   multi_state=False, own_covariance=True),
    EstimatorEntry("cl-iv", "vesselid.identify.closedloop:ClosedLoopIV", closed_loop=True),
)

_ENTRIES: dict[str, EstimatorEntry] = {e.name: e for e in _BUILTIN}
_BUILT: dict[str, Estimator] = {}

#: The three estimators of the paper's Tables 1–2, in the paper's order.
PAPER_METHODS: tuple[str, ...] = tuple(e.name for e in _BUILTIN if e.paper)


def register(item: EstimatorEntry | Estimator) -> EstimatorEntry | Estimator:
    """Add an estimator under its name, replacing an earlier entry of that name.

    ``item`` is an :class:`EstimatorEntry` (lazy) or a configured estimator instance
    (registered as it is, capabilities from its class: ``multi_experiment``,
    ``open_loop``).
    """
    if isinstance(item, EstimatorEntry):
        _ENTRIES[item.name] = item
        _BUILT.pop(item.name, None)
        return item
    name = getattr(item, "name", "")
    if not name:
        raise IdentificationError(f"{item!r} has no registry name")
    cls = type(item)
    _ENTRIES[name] = EstimatorEntry(
        name, f"{cls.__module__}:{cls.__qualname__}",
        closed_loop=not getattr(item, "open_loop", True))
    _BUILT[name] = item
    return item


def names() -> tuple[str, ...]:
    """Every registered name, in registration order."""
    return tuple(_ENTRIES)


def entries() -> tuple[EstimatorEntry, ...]:
    """Every registered entry, in registration order."""
    return tuple(_ENTRIES.values())


def entry(method: str) -> EstimatorEntry:
    """The entry ``method`` (one-line error naming the choices for an unknown one)."""
    try:
        return _ENTRIES[method]
    except (KeyError, TypeError):
        raise IdentificationError(
            f"unknown method {method!r}; choose from {list(_ENTRIES)}") from None


def get_estimator(method: str | Estimator) -> Estimator:
    """The registered estimator ``method`` (an estimator object passes through)."""
    if not isinstance(method, str):
        if hasattr(method, "fit") and hasattr(method, "name"):
            return method
        raise IdentificationError(
            f"unknown method {method!r}; choose from {list(_ENTRIES)}")
    if method not in _BUILT:
        _BUILT[method] = entry(method).build()
    return _BUILT[method]


class _Estimators(Mapping[str, "Estimator"]):
    """name -> estimator instance, built on first access (:func:`get_estimator`)."""

    def __getitem__(self, name: str) -> Estimator:
        if name not in _ENTRIES:
            raise KeyError(name)
        return get_estimator(name)

    def __iter__(self) -> Iterator[str]:
        return iter(tuple(_ENTRIES))

    def __len__(self) -> int:
        return len(_ENTRIES)

    def __contains__(self, name: object) -> bool:
        return name in _ENTRIES

    def __repr__(self) -> str:
        return f"ESTIMATORS({list(_ENTRIES)})"


#: name -> estimator instance (lazy; iterating lists the names without building any).
ESTIMATORS: Mapping[str, Estimator] = _Estimators()

#: The built-in names (``--method`` choices), in the registry's order.
METHODS: tuple[str, ...] = tuple(_ENTRIES)

#: The streamable built-in names (``identify --stream``).
STREAM_METHODS: tuple[str, ...] = tuple(e.name for e in _BUILTIN if e.streamable)


def method_labels(kind: str = "short") -> dict[str, str]:
    """name -> label (``kind``: ``"short"`` table rows, ``"plot"``, ``"long"``)."""
    attr = {"short": "short", "plot": "plot_label", "long": "label"}[kind]
    return {name: getattr(get_estimator(name), attr) for name in _ENTRIES}
