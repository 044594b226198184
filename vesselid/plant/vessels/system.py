"""A hull as a catalogue :class:`~vesselid.plant.systems.System` (``vesselid simulate``).

The catalogue entry of a vessel has no current (a ``System``'s disturbances are
state-wise; for the earth-fixed current, wind and sensors use
:func:`~vesselid.plant.vessels.kernel.simulate_vessel`), additive bounded Gauss–Markov process
noise ``w`` (unmodelled forces), Gaussian measurement noise, and random-width pulses on
static offsets per input (paper §6 / A10).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

from vesselid.plant.disturbances import Gaussian, GaussMarkov
from vesselid.plant.signals import RandomPulses
from vesselid.plant.systems import System
from vesselid.plant.vessels.hull import Hull

__all__ = ["pulse_system"]

Levels = tuple[float, float]


def pulse_system(
    hull: Hull,
    levels: Mapping[str, Levels | Sequence[Levels]],
    *,
    dt: float,
    process_noise_std: Sequence[float],
    process_noise_time_constant: float,
    sensor_noise_std: Sequence[float],
    x0: Sequence[float],
    width: tuple[float, float] = (20.0, 60.0),
    merges: Sequence[tuple[str, str, float]] = (),
    description: str = "",
    **_: Any,
) -> System:
    """``hull`` driven by random pulses on ``levels`` (per input ``(low, high)``, or one
    pair per experiment, cycled) with process and sensor noise.

    ``width`` is the pulse-width range (s); ``merges`` are ``ModelSpec.merge_terms``
    arguments giving the identified structure (terms collinear on such data).
    """
    spec = hull.spec(dt)
    states = spec.states
    w = {s: GaussMarkov(0.0, float(sd), process_noise_time_constant, dt, 3.0 * float(sd))
         for s, sd in zip(states, process_noise_std, strict=True) if sd > 0}
    e = {s: Gaussian(0.0, float(sd)) for s, sd in zip(states, sensor_noise_std, strict=True)}
    lo, hi = (max(1, round(t / dt)) for t in width)

    def pulses(level):
        if isinstance(level[0], Sequence):
            return tuple(RandomPulses(a, b, lo, hi) for a, b in level)
        return RandomPulses(level[0], level[1], lo, hi)

    model = spec
    for keep, drop, factor in merges:
        model = model.merge_terms(keep, drop, factor)
    return System(
        spec=spec, inputs={k: pulses(v) for k, v in levels.items()}, process_noise=w,
        sensor_noise=e, model=model if merges else None,
        x0=dict(zip(states, (float(x) for x in x0), strict=True)), description=description,
    )
