"""Typed records of an identification result's diagnostics (after linearmodels' results).

Each record is a frozen dataclass read from one entry of
:attr:`IdentificationResult.diagnostics <vesselid.identify.results.IdentificationResult>`
(the JSON-ready mapping that ``vesselid identify --json`` writes). A record keeps the keys
of its entry in their order, and :meth:`Record.to_dict` gives the entry back exactly, so
the typed view and the JSON are one thing read two ways. Keys a record does not name
(written by a newer estimator) are kept in :attr:`Record.extra`.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, fields
from types import MappingProxyType
from typing import Any, ClassVar, TypeVar

__all__ = ["EquationSpecification", "ExcitationReport", "FallbackAttempt", "FeedbackTest",
           "FirstStage", "InputExcitation", "MeanCurrentTest", "ParameterStabilityTest",
           "Record", "SmoothnessReport", "SpectralRadius", "StabilityReport", "StallAverage",
           "TestStatistic", "frozen_mapping", "plain", "records"]

R = TypeVar("R", bound="Record")


def frozen_mapping(value: Mapping[str, Any], convert: Callable[[Any], Any] | None = None
                   ) -> Mapping[str, Any]:
    """A read-only copy of ``value`` (values passed through ``convert`` when given)."""
    return MappingProxyType({k: (v if convert is None else convert(v))
                             for k, v in value.items()})


def plain(value: Any) -> Any:
    """The JSON-ready form of a record, tuple or mapping of them (lists and dicts)."""
    if isinstance(value, Record):
        return value.to_dict()
    if isinstance(value, tuple | list):
        return [plain(v) for v in value]
    if isinstance(value, Mapping):
        return {k: plain(v) for k, v in value.items()}
    return value


def _seq(value: Any) -> tuple[Any, ...]:
    return tuple(value)


@dataclass(frozen=True)
class Record:
    """Base of the typed diagnostic records (module docstring).

    Attributes
    ----------
    extra : Mapping
        Keys of the entry that the record does not name, with their values.
    """

    #: Field name → key in the diagnostics entry, where the two differ.
    KEYS: ClassVar[Mapping[str, str]] = {}
    #: Field name → converter of the entry's value (lists to tuples, nested records).
    CONVERT: ClassVar[Mapping[str, Callable[[Any], Any]]] = {}

    extra: Mapping[str, Any] = field(default_factory=dict, kw_only=True, repr=False)
    _order: tuple[str, ...] = field(default=(), kw_only=True, repr=False, compare=False)

    @classmethod
    def from_dict(cls: type[R], entry: Mapping[str, Any]) -> R:
        """The record of one diagnostics entry (missing keys: the field's default)."""
        names = {cls.KEYS.get(f.name, f.name): f.name for f in fields(cls)
                 if f.name not in ("extra", "_order")}
        kwargs: dict[str, Any] = {}
        extra: dict[str, Any] = {}
        for key, value in entry.items():
            name = names.get(key)
            if name is None:
                extra[key] = value
                continue
            convert = cls.CONVERT.get(name)
            kwargs[name] = value if convert is None or value is None else convert(value)
        return cls(**kwargs, extra=MappingProxyType(extra), _order=tuple(entry))

    def to_dict(self) -> dict[str, Any]:
        """The diagnostics entry this record was read from (same keys, same order)."""
        out: dict[str, Any] = {}
        by_key = {self.KEYS.get(f.name, f.name): f.name for f in fields(self)
                  if f.name not in ("extra", "_order")}
        order = self._order or tuple(by_key)
        for key in order:
            if key in by_key:
                out[key] = plain(getattr(self, by_key[key]))
            elif key in self.extra:
                out[key] = plain(self.extra[key])
        return out


@dataclass(frozen=True)
class TestStatistic(Record):
    """A test statistic with its null distribution (linearmodels' ``WaldTestStatistic``).

    Attributes
    ----------
    stat : float
        The statistic (χ² distributed under the null unless :attr:`distribution` says
        otherwise).
    df : int
        Degrees of freedom.
    pvalue : float
        Upper-tail probability of :attr:`stat` under the null.
    name, distribution, null, sentence : str or None
        The test's name, ``"chi2"`` or ``"F"``, the null hypothesis in words and one
        plain sentence (None where the entry does not carry them).
    """

    __test__ = False  # not a pytest test class

    stat: float | None = None
    df: int | None = None
    pvalue: float | None = None
    name: str | None = None
    distribution: str | None = None
    null: str | None = None
    sentence: str | None = None

    @property
    def pval(self) -> float:
        """:attr:`pvalue` under linearmodels' name."""
        return self.pvalue


@dataclass(frozen=True)
class FeedbackTest(Record):
    """Test of feedback from the outputs to the input (an open-loop log has none).

    Attributes
    ----------
    declared_closed_loop : bool
        Whether the log's metadata declares a closed loop.
    stat : float
        Wald statistic of the lagged outputs in a regression of the input on its own past
        and the outputs' past (entry key ``statistic``); χ²(``df``) under no feedback.
    df : int
    pvalue : float
    lags : int
        Lags of the outputs in that regression.
    alpha : float
        Level of the test.
    rejects : bool
        Whether no feedback is rejected at ``alpha``.
    """

    KEYS: ClassVar[Mapping[str, str]] = {"stat": "statistic"}

    declared_closed_loop: bool | None = None
    stat: float | None = None
    df: int | None = None
    pvalue: float | None = None
    lags: int | None = None
    alpha: float | None = None
    rejects: bool | None = None


@dataclass(frozen=True)
class ParameterStabilityTest(Record):
    """Split-sample (Chow-type) Wald test of constant parameters.

    Attributes
    ----------
    stat : float
        ``dᵀ (V₁ + V₂)⁻¹ d`` with ``d`` the difference of the two halves' IV_E{ζ}=0
        estimates and ``V`` their HAC covariances (entry key ``statistic``); χ²(``df``)
        under constant parameters.
    df : int
        Number of parameters.
    pvalue : float
    level : float
        Level of the test.
    rejected : bool
    first_half, second_half : Mapping[str, float]
        The halves' estimates, keyed ``"state: term"``.
    sentence : str
    """

    KEYS: ClassVar[Mapping[str, str]] = {"stat": "statistic"}
    CONVERT: ClassVar[Mapping[str, Callable[[Any], Any]]] = {
        "first_half": frozen_mapping, "second_half": frozen_mapping}

    stat: float | None = None
    df: int | None = None
    pvalue: float | None = None
    level: float | None = None
    rejected: bool | None = None
    first_half: Mapping[str, float] | None = None
    second_half: Mapping[str, float] | None = None
    sentence: str | None = None


@dataclass(frozen=True)
class MeanCurrentTest(Record):
    """Test of a mean current inside the modulus (the coefficient of ``|w|``).

    Attributes
    ----------
    stat : float
        z statistic of the ``|w|`` coefficient (entry key ``statistic``).
    pvalue, level : float
    warned : bool
        Whether the mean current was found (and warned about).
    abs_coefficient, abs_coefficient_se : float
        The ``|w|`` coefficient and its standard error.
    identified : str
        What the coefficient identifies (``-2·n·v̄``).
    estimate, std_error : float
        The mean current ``v̄`` it implies and its standard error (the state's units).
    sentence : str
    """

    KEYS: ClassVar[Mapping[str, str]] = {"stat": "statistic"}

    stat: float | None = None
    pvalue: float | None = None
    level: float | None = None
    warned: bool | None = None
    abs_coefficient: float | None = None
    abs_coefficient_se: float | None = None
    identified: str | None = None
    estimate: float | None = None
    std_error: float | None = None
    sentence: str | None = None


@dataclass(frozen=True)
class SpectralRadius(Record):
    """Spectral radius of the identified model's Jacobian along the log.

    Attributes
    ----------
    operating_point : float
        At the log's mean operating point.
    median, max : float
        Over the log's samples.
    share_above_one : float
        Share of samples (0–1) where it exceeds one (locally unstable).
    """

    operating_point: float | None = None
    median: float | None = None
    max: float | None = None
    share_above_one: float | None = None


@dataclass(frozen=True)
class StabilityReport(Record):
    """Stability of the identified model on the log (free run and linearisation).

    Attributes
    ----------
    stable : bool
        Whether the free run on the log's own inputs stays bounded (``status`` is
        ``"unstable"`` otherwise).
    free_run_bounded : bool
    unbounded_experiments : tuple
        Experiments whose free run leaves ``bound_factor`` times the measured range.
    bound_factor : float
    worst_excursion : float
        Largest free-run excursion as a multiple of the measured range.
    spectral_radius : SpectralRadius
    sentence : str
    """

    CONVERT: ClassVar[Mapping[str, Callable[[Any], Any]]] = {
        "unbounded_experiments": _seq,
        "spectral_radius": lambda v: SpectralRadius.from_dict(v)}

    stable: bool | None = None
    free_run_bounded: bool | None = None
    unbounded_experiments: tuple[Any, ...] = ()
    bound_factor: float | None = None
    worst_excursion: float | None = None
    spectral_radius: SpectralRadius | None = None
    sentence: str | None = None


@dataclass(frozen=True)
class FallbackAttempt(Record):
    """One estimator tried by the default path.

    Attributes
    ----------
    method : str
    outcome : str
        ``"accepted"`` or why the result was passed over.
    reason : str
    """

    method: str | None = None
    outcome: str | None = None
    reason: str | None = None


@dataclass(frozen=True)
class SmoothnessReport(Record):
    """Non-smoothness of the modulus at zero crossings of one state (A10/A15).

    Attributes
    ----------
    share_within_eta : float
        Share (0–1) of samples whose state lies within ``eta`` of zero.
    worst_experiment : int
    worst_share_within_eta : float
    eta : float
        Margin around zero, the state's units.
    sigma : float
        Sensor-noise level used (the state's units).
    sigma_source : str
    bias_se : float
        Bound of the bias the non-smoothness causes, in standard errors.
    threshold_se : float
        Bias in standard errors above which it matters.
    matters : bool
    sentence : str
    """

    share_within_eta: float | None = None
    worst_experiment: int | None = None
    worst_share_within_eta: float | None = None
    eta: float | None = None
    sigma: float | None = None
    sigma_source: str | None = None
    bias_se: float | None = None
    threshold_se: float | None = None
    matters: bool | None = None
    sentence: str | None = None


@dataclass(frozen=True)
class InputExcitation(Record):
    """Excitation of one input.

    Attributes
    ----------
    excited : bool
    range_within_experiments : float
        Range of the input within experiments (the input's units).
    magnitude : float
        Typical magnitude of the input (the input's units).
    """

    excited: bool | None = None
    range_within_experiments: float | None = None
    magnitude: float | None = None


@dataclass(frozen=True)
class ExcitationReport(Record):
    """Whether the inputs excite the model's terms.

    Attributes
    ----------
    inputs : Mapping[str, InputExcitation]
    not_excited : tuple of str
    unidentifiable : Mapping
        Terms the log cannot identify, with why.
    sentences : tuple of str
    """

    CONVERT: ClassVar[Mapping[str, Callable[[Any], Any]]] = {
        "inputs": lambda v: frozen_mapping(v, InputExcitation.from_dict),
        "not_excited": _seq, "unidentifiable": frozen_mapping, "sentences": _seq}

    inputs: Mapping[str, InputExcitation] | None = None
    not_excited: tuple[str, ...] = ()
    unidentifiable: Mapping[str, Any] | None = None
    sentences: tuple[str, ...] = ()


@dataclass(frozen=True)
class FirstStage(Record):
    """First-stage regressions of one equation's endogenous regressors on the instruments.

    Attributes
    ----------
    partial_f : Mapping[str, float]
        Partial F statistic of the excluded instruments, per endogenous regressor.
    partial_r2 : Mapping[str, float]
        Partial R² (0–1), per endogenous regressor.
    endogenous : tuple of str
    df : tuple of int
        Numerator and denominator degrees of freedom of the partial F.
    cragg_donald : float
        Cragg–Donald minimum-eigenvalue statistic (weak-instrument test).
    """

    CONVERT: ClassVar[Mapping[str, Callable[[Any], Any]]] = {
        "partial_f": frozen_mapping, "partial_r2": frozen_mapping, "endogenous": _seq,
        "df": _seq}

    partial_f: Mapping[str, float] | None = None
    partial_r2: Mapping[str, float] | None = None
    endogenous: tuple[str, ...] = ()
    df: tuple[int, ...] = ()
    cragg_donald: float | None = None


@dataclass(frozen=True)
class EquationSpecification(Record):
    """Instrument and specification tests of one equation (linearmodels' ``first_stage``,
    ``wu_hausman``/``durbin`` and ``sargan``/``j_stat``).

    Attributes
    ----------
    first_stage : FirstStage
    endogeneity : TestStatistic
        Durbin–Wu–Hausman test of LS consistency (null: the regressors are exogenous).
    hansen_j : TestStatistic
        Hansen J test of the over-identifying restrictions (null: all instruments are
        uncorrelated with the equation error).
    """

    CONVERT: ClassVar[Mapping[str, Callable[[Any], Any]]] = {
        "first_stage": lambda v: FirstStage.from_dict(v),
        "endogeneity": lambda v: TestStatistic.from_dict(v),
        "hansen_j": lambda v: TestStatistic.from_dict(v)}

    first_stage: FirstStage | None = None
    endogeneity: TestStatistic | None = None
    hansen_j: TestStatistic | None = None


@dataclass(frozen=True)
class StallAverage(Record):
    """The averaged steps of a stalled refined-IV iteration.

    Attributes
    ----------
    evaluations : int
        Further undamped steps averaged.
    mean_step_se : float
        Mean step, in standard errors of the parameters.
    location_se : float
        Standard error of that mean, in standard errors of the parameters.
    """

    evaluations: int | None = None
    mean_step_se: float | None = None
    location_se: float | None = None


def records(convert: Callable[[Any], R]) -> Callable[[Sequence[Any]], tuple[R, ...]]:
    """A converter of a list of entries into a tuple of records."""
    return lambda entries: tuple(convert(e) for e in entries)
