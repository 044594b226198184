"""Strict JSON: every document vesselid writes is valid JSON (RFC 8259).

Python's :mod:`json` writes ``NaN``/``Infinity`` by default, which strict parsers
reject. :func:`strict` converts non-finite floats to ``None`` (``null``), numpy
scalars and arrays to Python values, and mapping keys to strings; :func:`dumps`
then serialises with ``allow_nan=False`` so a stray non-finite value is an error,
never an invalid file.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable, Mapping
from typing import Any

import numpy as np

__all__ = ["dumps", "strict"]


def strict(obj: Any, default: Callable[[Any], Any] | None = None) -> Any:
    """``obj`` with non-finite floats as ``None`` and numpy values as Python values.

    ``default`` converts other unknown objects (as in :func:`json.dumps`).
    """
    if isinstance(obj, Mapping):
        return {str(k): strict(v, default) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [strict(v, default) for v in obj]
    if isinstance(obj, np.ndarray):
        return strict(obj.tolist(), default)
    if isinstance(obj, np.generic):
        obj = obj.item()
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if obj is None or isinstance(obj, str | int | bool):
        return obj
    if default is not None:
        return strict(default(obj), None)
    return obj


def dumps(obj: Any, **kwargs: Any) -> str:
    """:func:`json.dumps` of :func:`strict` ``(obj)`` with ``allow_nan=False``."""
    default = kwargs.pop("default", None)
    return json.dumps(strict(obj, default), allow_nan=False, **kwargs)
