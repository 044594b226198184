"""The catalogue of simulated systems: one registry, filled by string entry points.

Each line names a catalogue entry and the module (and factory) that builds it; nothing
is imported until an entry is asked for, and no model module imports this one's
consumers, so imports run one way (model modules → plant → model spec). A vessel data
module (``vesselid.plant.vessels.<name>``) provides ``HULL`` (a
:class:`~vesselid.plant.vessels.hull.Hull`)
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

__all__ = ["SYSTEMS", "VESSELS", "get_hull", "get_system", "names", "register_system",
           "register_vessel", "vessel_module", "vessel_names"]

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


def register_vessel(name: str, module: str) -> None:
    """Add a vessel: ``module`` is the import path of its data module (``HULL``, ``system``)."""
    _check_new(name, module)
    VESSELS[name] = module


def register_system(name: str, target: str) -> None:
    """Add a system: ``target`` is ``"module:factory"`` (``factory(**options) -> System``)."""
    _check_new(name, target)
    if ":" not in target:
        raise VesselidError(f"system target {target!r} is not 'module:factory'")
    SYSTEMS[name] = target


def _check_new(name: str, target: str) -> None:
    if not name or not isinstance(name, str) or not isinstance(target, str) or not target:
        raise VesselidError(f"a catalogue entry needs a name and a target, got {name!r}, "
                            f"{target!r}")


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
