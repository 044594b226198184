"""Input designs: random-width pulses, static offset plus perturbation, PRBS, multisine.

Each design draws from a caller-supplied :class:`numpy.random.Generator`
(``sample(rng, n)``), so one seed controls every experiment.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any, ClassVar

import numpy as np

from vesselid.errors import VesselidError
from vesselid.plant.disturbances import Process, Sampled, process_from_dict

__all__ = [
    "PRBS",
    "ConstantInput",
    "InputSignal",
    "Multisine",
    "RandomPulses",
    "StaticOffset",
    "input_from_dict",
]


class InputSignal(Sampled):
    """A known input design ``u(k)``."""


def _check_range(name: str, lo: float, hi: float) -> tuple[float, float]:
    lo, hi = float(lo), float(hi)
    if not (math.isfinite(lo) and math.isfinite(hi)) or hi < lo:
        raise VesselidError(f"{name} range must be finite with low <= high, got ({lo}, {hi})")
    return lo, hi


@dataclass(frozen=True)
class _Pulses(InputSignal):
    """Piecewise-constant levels between ``low`` and ``high`` held for random widths."""

    kind: ClassVar[str] = ""
    low: float = 0.1
    high: float = 0.3
    min_width: int = 1
    max_width: int = 20

    def __post_init__(self) -> None:
        _check_range("amplitude", self.low, self.high)
        if not (1 <= int(self.min_width) <= int(self.max_width)):
            raise VesselidError(
                f"pulse widths need 1 <= min_width <= max_width, got {self.min_width}, "
                f"{self.max_width}"
            )

    def to_dict(self) -> dict[str, Any]:
        return {"kind": self.kind, "low": self.low, "high": self.high,
                "min_width": int(self.min_width), "max_width": int(self.max_width)}


@dataclass(frozen=True)
class RandomPulses(_Pulses):
    """Piecewise-constant pulses of random amplitude and random width (paper §6).

    Levels are uniform on ``[low, high]``; each is held for a width drawn uniformly
    from the integers ``min_width ... max_width`` samples.
    """

    kind: ClassVar[str] = "pulses"
    min_width: int = 10
    max_width: int = 100

    def sample(self, rng: np.random.Generator, n: int) -> np.ndarray:
        # Enough pulses to cover n samples for certain (every width >= min_width).
        n_pulses = n // int(self.min_width) + 1
        widths = rng.integers(int(self.min_width), int(self.max_width) + 1, n_pulses)
        levels = rng.uniform(self.low, self.high, n_pulses)
        return np.repeat(levels, widths)[:n]


@dataclass(frozen=True)
class AlternatingPulses(_Pulses):
    """Pulses switching between two levels, each held for a random width.

    The input alternates ``low, high, low, ...`` (starting level drawn at random);
    every level is held for a width drawn uniformly from the integers
    ``min_width ... max_width`` samples. With ``low=0.1, high=0.3`` and widths
    1–20 this is the input design that best reproduces the spreads of the paper's
    Tables 1–2 (§6: "a set of pulses with amplitudes between 0.1 and 0.3 ... of
    varying width"); see :mod:`vesselid.studies.reproduce`.
    """

    kind: ClassVar[str] = "alternating_pulses"  # the defaults of _Pulses: 0.1–0.3, 1–20

    def sample(self, rng: np.random.Generator, n: int) -> np.ndarray:
        # Draw order: the starting level, then widths in blocks of about 1.1 n / mean
        # width until they cover n samples (deterministic for a given generator).
        lo, hi = int(self.min_width), int(self.max_width)
        first = int(rng.integers(0, 2))
        block = int(1.1 * n / (0.5 * (lo + hi))) + 16
        parts = [rng.integers(lo, hi + 1, block)]
        total = int(parts[0].sum())
        while total < n:
            parts.append(rng.integers(lo, hi + 1, block))
            total += int(parts[-1].sum())
        widths = np.concatenate(parts) if len(parts) > 1 else parts[0]
        levels = np.where((np.arange(widths.size) + first) % 2 == 0, self.low, self.high)
        return np.repeat(levels, widths)[:n]


@dataclass(frozen=True)
class StaticOffset(InputSignal):
    """Static offset plus a perturbation process (Ljungberg & Enqvist 2019; paper §5).

    ``u(k) = offset + p(k)``; the offset keeps the states away from zero (A10/A15)
    while the perturbation excites the dynamics.
    """

    offset: float
    perturbation: Process = field(default=None)  # type: ignore[assignment]

    def sample(self, rng: np.random.Generator, n: int) -> np.ndarray:
        base = np.full(n, float(self.offset))
        if self.perturbation is not None:
            base += self.perturbation.sample(rng, n)
        return base

    def to_dict(self) -> dict[str, Any]:
        d: dict[str, Any] = {"kind": "static_offset", "offset": float(self.offset)}
        if self.perturbation is not None:
            d["perturbation"] = self.perturbation.to_dict()
        return d


@dataclass(frozen=True)
class ConstantInput(InputSignal):
    """A constant input."""

    value: float = 0.0

    def sample(self, rng: np.random.Generator, n: int) -> np.ndarray:
        return np.full(n, float(self.value))

    def to_dict(self) -> dict[str, Any]:
        return {"kind": "constant", "value": float(self.value)}


@dataclass(frozen=True)
class PRBS(InputSignal):
    """Pseudo-random binary sequence between ``low`` and ``high``.

    A maximum-length sequence (``scipy.signal.max_len_seq``) of ``nbits`` bits with a
    random non-zero start state, each bit held for ``hold`` samples.
    """

    low: float = -1.0
    high: float = 1.0
    nbits: int = 10
    hold: int = 1

    def __post_init__(self) -> None:
        _check_range("PRBS level", self.low, self.high)
        if not (2 <= int(self.nbits) <= 32) or int(self.hold) < 1:
            raise VesselidError("PRBS needs 2 <= nbits <= 32 and hold >= 1")

    def sample(self, rng: np.random.Generator, n: int) -> np.ndarray:
        nbits = int(self.nbits)
        state = rng.integers(0, 2, nbits)
        if not state.any():
            state[0] = 1
        n_bits_needed = -(-n // int(self.hold))
        period = 2**nbits - 1
        from scipy.signal import max_len_seq  # lazily (scipy.signal: ~1 s of process start)

        seq, _ = max_len_seq(nbits, state=state, length=min(n_bits_needed, period))
        if n_bits_needed > period:
            seq = np.resize(seq, n_bits_needed)
        bits = np.repeat(seq, int(self.hold))[:n]
        return np.where(bits == 1, self.high, self.low).astype(float)

    def to_dict(self) -> dict[str, Any]:
        return {"kind": "prbs", "low": self.low, "high": self.high, "nbits": int(self.nbits),
                "hold": int(self.hold)}


@dataclass(frozen=True)
class Multisine(InputSignal):
    """Sum of sinusoids with random phases plus an offset.

    Parameters
    ----------
    frequencies : sequence of float
        Frequencies in cycles per sample, each in ``(0, 0.5)``.
    amplitudes : float or sequence of float
        Amplitude of each sinusoid.
    offset : float
        Constant offset.
    """

    frequencies: Sequence[float] = (0.01, 0.02, 0.05)
    amplitudes: float | Sequence[float] = 0.1
    offset: float = 0.0

    def __post_init__(self) -> None:
        f = np.asarray(self.frequencies, dtype=float)
        if f.ndim != 1 or f.size == 0 or np.any((f <= 0) | (f >= 0.5)):
            raise VesselidError("multisine frequencies must be in (0, 0.5) cycles/sample")
        a = np.broadcast_to(np.asarray(self.amplitudes, dtype=float), f.shape)
        if not np.all(np.isfinite(a)):
            raise VesselidError("multisine amplitudes must be finite")

    def sample(self, rng: np.random.Generator, n: int) -> np.ndarray:
        f = np.asarray(self.frequencies, dtype=float)
        a = np.broadcast_to(np.asarray(self.amplitudes, dtype=float), f.shape)
        phases = rng.uniform(0, 2 * np.pi, f.size)
        k = np.arange(n)[:, None]
        return self.offset + (a * np.sin(2 * np.pi * f * k + phases)).sum(axis=1)

    def to_dict(self) -> dict[str, Any]:
        return {"kind": "multisine", "frequencies": [float(x) for x in self.frequencies],
                "amplitudes": np.broadcast_to(np.asarray(self.amplitudes, dtype=float),
                                              (len(self.frequencies),)).tolist(),
                "offset": float(self.offset)}


def input_from_dict(data: dict[str, Any]) -> InputSignal:
    """Rebuild an input design from :meth:`InputSignal.to_dict` output."""
    kind = data.get("kind") if isinstance(data, dict) else None
    if kind == "pulses":
        return RandomPulses(data["low"], data["high"], data["min_width"], data["max_width"])
    if kind == "alternating_pulses":
        return AlternatingPulses(data["low"], data["high"], data["min_width"], data["max_width"])
    if kind == "static_offset":
        pert = data.get("perturbation")
        return StaticOffset(data["offset"], process_from_dict(pert) if pert else None)
    if kind == "constant":
        return ConstantInput(data["value"])
    if kind == "prbs":
        return PRBS(data["low"], data["high"], data["nbits"], data["hold"])
    if kind == "multisine":
        return Multisine(tuple(data["frequencies"]), tuple(data["amplitudes"]), data["offset"])
    raise VesselidError(f"unknown input design {kind!r}")
