"""The one registry of estimators: ``--method`` names, labels, Monte Carlo, plots.

Everything that lists or labels estimators (the CLI choices, ``identify``,
:mod:`vesselid.studies.montecarlo`, :mod:`vesselid.studies.reproduce`, :mod:`vesselid.studies.plots`)
reads :data:`ESTIMATORS`. Adding an estimator is one subclass of
:class:`~vesselid.identify.base.Estimator` and one :func:`register` call.
"""

from __future__ import annotations

from vesselid.errors import IdentificationError
from vesselid.identify.base import Estimator
from vesselid.identify.closedloop import ClosedLoopIV
from vesselid.identify.efficient import InstrumentalGMM, LaggedIV
from vesselid.identify.methods import LeastSquares, RefinedIV
from vesselid.identify.pem import PredictionError

__all__ = [
    "DEFAULT_METHOD",
    "ESTIMATORS",
    "PAPER_METHODS",
    "get_estimator",
    "method_labels",
    "register",
]

#: name -> estimator object (a configured instance).
ESTIMATORS: dict[str, Estimator] = {}


def register(estimator: Estimator) -> Estimator:
    """Add ``estimator`` under ``estimator.name`` (replacing an earlier entry)."""
    ESTIMATORS[estimator.name] = estimator
    return estimator


for _est in (
    LeastSquares(),
    RefinedIV(zero_mean=False),
    RefinedIV(zero_mean=True),
    LaggedIV(),
    InstrumentalGMM("simulated", noise_order=4, refine=3, name="sriv",
                    label="refined IV with an AR(4) noise-model prefilter (SRIV)",
                    short="SRIV"),
    InstrumentalGMM("combined", refine=1, name="gmm",
                    label="two-step GMM, simulated + delayed-measurement instruments",
                    short="GMM"),
    InstrumentalGMM("auto", noise_order=4, refine=1, name="auto", pem_fallback=True,
                    label="GMM, simulated + delayed instruments unless the C test or the "
                          "colour test rejects the delayed ones (then PEM on one-state "
                          "logs, else SRIV)",
                    short="auto"),
    PredictionError(),
    ClosedLoopIV(),
):
    register(_est)

#: The three estimators of the paper's Tables 1–2, in the paper's order.
PAPER_METHODS: tuple[str, ...] = ("ls", "iv", "iv-zero-mean")

#: The package default (``identify`` and ``vesselid identify`` without ``--method``),
#: chosen from ``scripts/estimator_study.py`` (docs/guide/choosing-an-estimator.md): on
#: white disturbances it matches 2SLS with delayed instruments, under a coloured
#: current it falls back to the simulated instruments the paper proves valid.
DEFAULT_METHOD = "auto"


def get_estimator(method: str | Estimator) -> Estimator:
    """The registered estimator ``method`` (an :class:`Estimator` passes through)."""
    if isinstance(method, Estimator):
        return method
    try:
        return ESTIMATORS[method]
    except (KeyError, TypeError):
        raise IdentificationError(
            f"unknown method {method!r}; choose from {list(ESTIMATORS)}") from None


def method_labels(kind: str = "short") -> dict[str, str]:
    """name -> label (``kind``: ``"short"`` table rows, ``"plot"``, ``"long"``)."""
    attr = {"short": "short", "plot": "plot_label", "long": "label"}[kind]
    return {name: getattr(est, attr) for name, est in ESTIMATORS.items()}
