"""Environment settings: defaults merged with the given ones, numbers, ranges and triples
(domain errors), and the ``## Arguments`` text shared by a single and a vector class."""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np

from vesselid.errors import VesselidError

__all__ = ["document", "finite", "merged", "pair", "triple"]


def finite(name: str, value: Any, *, nonneg: bool = False, positive: bool = False) -> float:
    """``float(value)``, finite (and non-negative / positive when asked)."""
    try:
        v = float(value)
    except (TypeError, ValueError) as exc:
        raise VesselidError(f"{name} must be a number, got {value!r}") from exc
    if not math.isfinite(v) or (nonneg and v < 0) or (positive and v <= 0):
        what = "positive" if positive else "non-negative" if nonneg else "finite"
        raise VesselidError(f"{name} must be {what}, got {value!r}")
    return v


def pair(name: str, value: Any, *, strict: bool = True) -> tuple[float, float]:
    """A finite range ``(low, high)`` with ``low < high`` (``<=`` unless ``strict``)."""
    try:
        lo, hi = (float(v) for v in value)
    except (TypeError, ValueError) as exc:
        raise VesselidError(f"{name} must be a pair (low, high), got {value!r}") from exc
    if not (math.isfinite(lo) and math.isfinite(hi)) or (hi <= lo if strict else hi < lo):
        raise VesselidError(f"{name} must be finite with low < high, got {value!r}")
    return lo, hi


def triple(name: str, value: Any) -> tuple[float, float, float]:
    """Three finite numbers (a scalar is repeated)."""
    arr = np.broadcast_to(np.asarray(value, dtype=float), (3,))
    if not np.all(np.isfinite(arr)):
        raise VesselidError(f"{name} must be finite, got {value!r}")
    return (float(arr[0]), float(arr[1]), float(arr[2]))


def merged(settings: Mapping[str, Any], defaults: Mapping[str, Any]) -> dict[str, Any]:
    """``defaults`` updated by ``settings``; an unknown setting is a domain error."""
    unknown = sorted(set(settings) - set(defaults))
    if unknown:
        raise VesselidError(f"unknown settings {unknown}; known: {sorted(defaults)}")
    return {**defaults, **settings}


def document(arguments: str, *classes: type) -> None:
    """Put the ``arguments`` text in place of ``{arguments}`` in each class docstring."""
    for cls in classes:
        cls.__doc__ = (cls.__doc__ or "").replace("{arguments}", arguments.strip())
