"""Action and call-order checks shared by every vesselid environment (single and vector).

An action must hold finite numbers in exactly the shape of the action space (a bare
number is accepted when the space holds one value); anything else raises
:class:`~vesselid.errors.InvalidActionError` (a ``ValueError``) naming the problem, so
a NaN never turns into NaN observations and a wrong shape is never truncated or
broadcast. ``step`` before ``reset`` raises :class:`gymnasium.error.ResetNeeded` in
every environment.
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np

from vesselid.errors import InvalidActionError

__all__ = ["check_action", "require_reset"]

_NUMPY = (np.ndarray, np.generic)


def check_action(action: Any, shape: tuple[int, ...], *, name: str = "action") -> np.ndarray:
    """``action`` as a float64 array of ``shape``, or a clear error.

    Parameters
    ----------
    action : array_like
        The action passed to ``step``.
    shape : tuple of int
        Shape of the action space (``(num_envs, k)`` for a vector environment).
    name : str
        Word used in the message (``"action"``, ``"actions"``).

    Raises
    ------
    InvalidActionError
        Not real numbers, wrong shape, or NaN/±inf (the message gives the first index).
    """
    try:
        if isinstance(action, _NUMPY) and action.dtype.kind == "c":
            raise TypeError("complex")  # numpy would drop the imaginary part
        arr = np.asarray(action, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise InvalidActionError(
            f"{name} must be numbers of shape {shape}, got {type(action).__name__} "
            f"{action!r:.60}") from exc
    if arr.shape != tuple(shape):
        if arr.ndim == 0 and int(np.prod(shape)) == 1:
            arr = arr.reshape(shape)
        else:
            raise InvalidActionError(
                f"{name} must have shape {tuple(shape)}, got {arr.shape}")
    bad = ~np.isfinite(arr)
    if bad.any():
        idx = tuple(int(i) for i in np.argwhere(bad)[0])
        raise InvalidActionError(
            f"{name} must be finite, got {float(arr[idx])!r} at index {idx}")
    return arr


def require_reset(ready: bool) -> None:
    """Raise :class:`gymnasium.error.ResetNeeded` unless the environment was reset."""
    if not ready:
        raise gym.error.ResetNeeded("call reset() before step()")
