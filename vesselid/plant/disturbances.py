"""Seeded disturbance processes: currents, process noise, sensor noise, wind gusts.

Every process draws from a :class:`numpy.random.Generator` passed in by the caller
(scientific-python SPEC 7): no global random state. Processes add with ``+``.

The paper's assumptions A2/A9/A11 ask for bounded noise; use
:class:`TruncatedGaussian` or :class:`Uniform` for that, :class:`Gaussian` to
reproduce §6 (which deliberately used unbounded Gaussian noise).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from vesselid.errors import VesselidError

__all__ = [
    "Constant",
    "GaussMarkov",
    "Gaussian",
    "Process",
    "Sampled",
    "Sum",
    "TruncatedGaussian",
    "Uniform",
    "Zero",
    "gauss_markov_rows",
    "process_from_dict",
    "register_process",
]


class Sampled:
    """Drawn on a uniform grid from the caller's generator and recorded in log metadata:
    a disturbance :class:`Process` or an input design
    (:class:`vesselid.plant.signals.InputSignal`)."""

    def sample(self, rng: np.random.Generator, n: int) -> np.ndarray:  # pragma: no cover
        """Draw ``n`` consecutive samples."""
        raise NotImplementedError

    def to_dict(self) -> dict[str, Any]:  # pragma: no cover
        """``kind`` and parameters (``process_from_dict`` / ``input_from_dict`` rebuild it)."""
        raise NotImplementedError


class Process(Sampled):
    """A stationary scalar random process sampled on a uniform grid."""

    #: The stationary mean of most processes (their field; others override :attr:`mean`).
    mean_: float

    @property
    def mean(self) -> float:
        """Stationary mean."""
        return self.mean_

    @property
    def std(self) -> float:  # pragma: no cover
        """Stationary standard deviation."""
        raise NotImplementedError

    @property
    def bound(self) -> float:
        """Bound on ``|sample - mean|`` (``inf`` when unbounded)."""
        return math.inf

    @property
    def is_zero(self) -> bool:
        """Identically zero: zero mean and no spread."""
        return self.mean == 0 and self.std == 0

    def __add__(self, other: Process) -> Process:
        if not isinstance(other, Process):
            return NotImplemented
        parts = (self.parts if isinstance(self, Sum) else (self,)) + (
            other.parts if isinstance(other, Sum) else (other,)
        )
        return Sum(tuple(p for p in parts if not p.is_zero) or (Zero(),))


def _check(name: str, value: float, *, positive: bool = False, nonneg: bool = False) -> float:
    value = float(value)
    if not math.isfinite(value):
        raise VesselidError(f"{name} must be finite, got {value}")
    if positive and value <= 0:
        raise VesselidError(f"{name} must be positive, got {value}")
    if nonneg and value < 0:
        raise VesselidError(f"{name} must be non-negative, got {value}")
    return value


@dataclass(frozen=True)
class Zero(Process):
    """No disturbance."""

    def sample(self, rng: np.random.Generator, n: int) -> np.ndarray:
        return np.zeros(n)

    mean = 0.0  # type: ignore[assignment]
    std = 0.0  # type: ignore[assignment]

    @property
    def bound(self) -> float:
        return 0.0

    def to_dict(self) -> dict[str, Any]:
        return {"kind": "zero"}


@dataclass(frozen=True)
class Constant(Process):
    """A constant offset (e.g. a steady current)."""

    value: float

    def __post_init__(self) -> None:
        object.__setattr__(self, "value", _check("value", self.value))

    def sample(self, rng: np.random.Generator, n: int) -> np.ndarray:
        return np.full(n, self.value)

    @property
    def mean(self) -> float:
        return self.value

    @property
    def std(self) -> float:
        return 0.0

    @property
    def bound(self) -> float:
        return 0.0

    def to_dict(self) -> dict[str, Any]:
        return {"kind": "constant", "value": self.value}


@dataclass(frozen=True)
class Gaussian(Process):
    """White Gaussian noise ``N(mean, std²)``.

    The paper states variances: ``N(0, 0.01)`` is ``Gaussian(0, std=0.1)``, or
    ``Gaussian.from_variance(0, 0.01)``.
    """

    mean_: float = 0.0
    std_: float = 1.0

    def __init__(self, mean: float = 0.0, std: float = 1.0) -> None:
        object.__setattr__(self, "mean_", _check("mean", mean))
        object.__setattr__(self, "std_", _check("std", std, nonneg=True))

    @classmethod
    def from_variance(cls, mean: float, variance: float) -> Gaussian:
        return cls(mean, math.sqrt(_check("variance", variance, nonneg=True)))

    def sample(self, rng: np.random.Generator, n: int) -> np.ndarray:
        return rng.normal(self.mean_, self.std_, n) if self.std_ > 0 else np.full(n, self.mean_)

    @property
    def std(self) -> float:
        return self.std_

    @property
    def bound(self) -> float:
        return 0.0 if self.std_ == 0 else math.inf

    def to_dict(self) -> dict[str, Any]:
        return {"kind": "gaussian", "mean": self.mean_, "std": self.std_}


@dataclass(frozen=True)
class Uniform(Process):
    """White noise uniform on ``(mean - half_width, mean + half_width)`` (paper §5)."""

    mean_: float = 0.0
    half_width: float = 1.0

    def __init__(self, mean: float = 0.0, half_width: float = 1.0) -> None:
        object.__setattr__(self, "mean_", _check("mean", mean))
        object.__setattr__(self, "half_width", _check("half_width", half_width, nonneg=True))

    def sample(self, rng: np.random.Generator, n: int) -> np.ndarray:
        return rng.uniform(self.mean_ - self.half_width, self.mean_ + self.half_width, n)

    @property
    def std(self) -> float:
        return self.half_width / math.sqrt(3.0)

    @property
    def bound(self) -> float:
        return self.half_width

    def to_dict(self) -> dict[str, Any]:
        return {"kind": "uniform", "mean": self.mean_, "half_width": self.half_width}


@dataclass(frozen=True)
class TruncatedGaussian(Process):
    """White Gaussian noise truncated to ``|x - mean| < bound`` (bounded, as A2/A9 assume).

    ``std`` is the standard deviation of the parent Gaussian before truncation.
    """

    mean_: float = 0.0
    sigma: float = 1.0
    bound_: float = 3.0

    def __init__(self, mean: float = 0.0, std: float = 1.0, bound: float = 3.0) -> None:
        object.__setattr__(self, "mean_", _check("mean", mean))
        object.__setattr__(self, "sigma", _check("std", std, positive=True))
        object.__setattr__(self, "bound_", _check("bound", bound, positive=True))

    @property
    def _dist(self):
        from scipy import stats  # lazily: importing scipy.stats costs ~1 s of process start

        b = self.bound_ / self.sigma
        return stats.truncnorm(-b, b, loc=self.mean_, scale=self.sigma)

    def sample(self, rng: np.random.Generator, n: int) -> np.ndarray:
        return self._dist.rvs(size=n, random_state=rng)

    @property
    def std(self) -> float:
        return float(self._dist.std())

    @property
    def bound(self) -> float:
        return self.bound_

    @property
    def is_zero(self) -> bool:
        return False  # std > 0 (and its std needs scipy.stats)

    def to_dict(self) -> dict[str, Any]:
        return {"kind": "truncated_gaussian", "mean": self.mean_, "std": self.sigma,
                "bound": self.bound_}


@dataclass(frozen=True)
class GaussMarkov(Process):
    """First-order Gauss–Markov (coloured) process, optionally bounded.

    ``x(k+1) = mean + a (x(k) - mean) + sqrt(1 - a²) std ε(k)`` with
    ``a = exp(-dt / time_constant)``, started in its stationary distribution, so the
    stationary standard deviation is ``std`` for any time constant. With ``bound``
    the process is passed through the smooth saturation ``b·tanh(g/b)``, so
    ``|x - mean| < bound`` always holds while the colour is kept (a bounded
    first-order process, used for slowly varying currents); :attr:`std` then
    reports the exact stationary standard deviation after saturation.
    """

    mean_: float = 0.0
    std_: float = 1.0
    time_constant: float = 100.0
    dt: float = 1.0
    bound_: float = math.inf

    def __init__(
        self,
        mean: float = 0.0,
        std: float = 1.0,
        time_constant: float = 100.0,
        dt: float = 1.0,
        bound: float = math.inf,
    ) -> None:
        object.__setattr__(self, "mean_", _check("mean", mean))
        object.__setattr__(self, "std_", _check("std", std, nonneg=True))
        object.__setattr__(self, "time_constant", _check("time_constant", time_constant,
                                                         positive=True))
        object.__setattr__(self, "dt", _check("dt", dt, positive=True))
        bound = float(bound)
        if not bound > 0:
            raise VesselidError(f"bound must be positive, got {bound}")
        object.__setattr__(self, "bound_", bound)

    @property
    def pole(self) -> float:
        return math.exp(-self.dt / self.time_constant)

    def sample(self, rng: np.random.Generator, n: int) -> np.ndarray:
        if self.std_ == 0:
            return np.full(n, self.mean_)
        g = gauss_markov_rows(rng, np.array([self.std_]), self.pole, n)[0]
        if math.isfinite(self.bound_):
            g = self.bound_ * np.tanh(g / self.bound_)
        return g + self.mean_

    @property
    def std(self) -> float:
        if not math.isfinite(self.bound_) or self.std_ == 0:
            return self.std_
        # E[b² tanh²(g/b)], g ~ N(0, σ²), by Gauss–Hermite quadrature
        t, wts = np.polynomial.hermite_e.hermegauss(80)
        val = self.bound_ * np.tanh(self.std_ * t / self.bound_)
        return float(math.sqrt(np.sum(wts * val**2) / math.sqrt(2 * math.pi)))

    @property
    def bound(self) -> float:
        return self.bound_

    def to_dict(self) -> dict[str, Any]:
        d = {"kind": "gauss_markov", "mean": self.mean_, "std": self.std_,
             "time_constant": self.time_constant, "dt": self.dt}
        if math.isfinite(self.bound_):
            d["bound"] = self.bound_
        return d


@dataclass(frozen=True)
class Sum(Process):
    """Sum of independent processes (e.g. ``Constant(0.1) + GaussMarkov(...)``)."""

    parts: tuple[Process, ...]

    def sample(self, rng: np.random.Generator, n: int) -> np.ndarray:
        out = np.zeros(n)
        for p in self.parts:
            out += p.sample(rng, n)
        return out

    @property
    def mean(self) -> float:
        return float(sum(p.mean for p in self.parts))

    @property
    def std(self) -> float:
        return math.sqrt(sum(p.std**2 for p in self.parts))

    @property
    def bound(self) -> float:
        return float(sum(p.bound for p in self.parts))

    @property
    def is_zero(self) -> bool:
        return all(p.is_zero for p in self.parts)

    def to_dict(self) -> dict[str, Any]:
        return {"kind": "sum", "parts": [p.to_dict() for p in self.parts]}


def gauss_markov_rows(rng: np.random.Generator, std: np.ndarray, pole: float,
                      n: int) -> np.ndarray:
    """``m`` independent zero-mean Gaussian Gauss–Markov processes with one pole, ``(m, n)``.

    ``g(k) = a g(k−1) + √(1 − a²) σ ε(k)`` started in the stationary distribution
    ``g(0) ~ N(0, σ²)``. Draws ``m × n`` standard normals (the innovations, row by row;
    column 0 is replaced) and then ``m`` for the start: the one Gauss–Markov draw of
    :class:`GaussMarkov` (``m = 1``) and of the plant's disturbed paths
    (:meth:`vesselid.plant.vessels.kernel.VesselModel.disturbed_paths`).
    """
    # lazily; the compiled filter is scipy.signal.lfilter's recursion without its
    # ~1.5 s import
    from vesselid.core.filters import ar1_filter

    std = np.asarray(std, dtype=float)
    a = float(pole)
    e = rng.standard_normal((std.size, int(n))) * (std * math.sqrt(1 - a * a))[:, None]
    e[:, 0] = rng.standard_normal(std.size) * std
    return ar1_filter(e, a, np.zeros(std.size))


_KINDS = {
    "zero": lambda d: Zero(),
    "constant": lambda d: Constant(d["value"]),
    "gaussian": lambda d: Gaussian(d.get("mean", 0.0), d.get("std", 1.0)),
    "uniform": lambda d: Uniform(d.get("mean", 0.0), d.get("half_width", 1.0)),
    "truncated_gaussian": lambda d: TruncatedGaussian(d.get("mean", 0.0), d.get("std", 1.0),
                                                      d.get("bound", 3.0)),
    "gauss_markov": lambda d: GaussMarkov(d.get("mean", 0.0), d.get("std", 1.0),
                                          d.get("time_constant", 100.0), d.get("dt", 1.0),
                                          d.get("bound", math.inf)),
    "sum": lambda d: Sum(tuple(process_from_dict(p) for p in d["parts"])),
}


def register_process(kind: str, factory: Callable[[dict[str, Any]], Process]) -> None:
    """Make a new process kind rebuildable from log metadata (:func:`process_from_dict`).

    ``factory`` maps the process's :meth:`~Sampled.to_dict` output (``{"kind": kind, ...}``)
    back to the process; a new disturbance is its :class:`Process` subclass plus this line.
    """
    if not kind or not isinstance(kind, str):
        raise VesselidError(f"a process kind must be a non-empty string, got {kind!r}")
    _KINDS[kind] = factory


def process_from_dict(data: dict[str, Any]) -> Process:
    """Rebuild a process from :meth:`Process.to_dict` output (log metadata)."""
    kind = data.get("kind") if isinstance(data, dict) else None
    if kind not in _KINDS:
        raise VesselidError(f"unknown disturbance kind {kind!r}; known {sorted(_KINDS)}")
    return _KINDS[kind](data)
