"""The catalogue of simulated systems: one registry, filled by string entry points.

Each line names a catalogue entry and the module (and factory) that builds it; nothing
is imported until an entry is asked for, and no model module imports this one's
consumers, so imports run one way (model modules → plant → model spec). A vessel data
module (``vesselid.plant.vessels.<name>``) provides ``HULL`` (a :class:`~vesselid.plant.vessels.hull.Hull`)
and ``system(**options)``; adding a vessel is its module plus one line in :data:`VESSELS`.
"""

from __future__ import annotations

import importlib
from types import ModuleType
from typing import TYPE_CHECKING, Any

from vesselid.errors import VesselidError

if TYPE_CHECKING:  # pragma: no cover
    from vesselid.plant.systems import System
    from vesselid.plant.vessels.hull import Hull

__all__ = ["SYSTEMS", "VESSELS", "get_hull", "get_system", "names", "vessel_module",
           "vessel_names"]

#: Systems of the paper: name -> "module:factory".
SYSTEMS: dict[str, str] = {
    "heave": "vesselid.plant.systems:heave",
    "siso": "vesselid.plant.systems:siso_example",
}

#: Vessels: name -> data module (with ``HULL`` and ``system``).
VESSELS: dict[str, str] = {
    "cybership2": "vesselid.plant.vessels.cybership2",
    "viknes830": "vesselid.plant.vessels.viknes830",
}


def names() -> list[str]:
    """Every catalogue name (systems, then vessels)."""
    return [*SYSTEMS, *VESSELS]


def vessel_names() -> list[str]:
    """Names of the catalogue vessels."""
    return list(VESSELS)


def vessel_module(name: str) -> ModuleType:
    """The data module of a catalogue vessel.

    Raises
    ------
    VesselidError
        For an unknown name (the message lists the known ones).
    """
    if name not in VESSELS:
        raise VesselidError(f"unknown vessel {name!r}; known: {vessel_names()}")
    return importlib.import_module(VESSELS[name])


def get_hull(name: str) -> Hull:
    """The hull of a catalogue vessel (its data module's ``HULL``)."""
    return vessel_module(name).HULL


def get_system(name: str, **options: Any) -> System:
    """Build a catalogue system by name (:func:`names`) with its options."""
    if name in VESSELS:
        return vessel_module(name).system(**options)
    if name not in SYSTEMS:
        raise VesselidError(f"unknown system {name!r}; known: {names()}")
    module, factory = SYSTEMS[name].split(":")
    return getattr(importlib.import_module(module), factory)(**options)
