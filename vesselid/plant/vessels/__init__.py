"""Surface vessels (surge, sway, yaw) as data on one generic kernel.

* :mod:`vesselid.plant.vessels.hull` — :class:`Hull`, a vessel as data (mass matrix, force table
  of second-order modulus terms, limits) and its discrete-time spec;
* :mod:`vesselid.plant.vessels.kernel` — the compiled kernel, :func:`simulate_vessel`,
  :class:`VesselSimulation` and :class:`VesselBatch` (the environments' plant);
* :mod:`vesselid.plant.vessels.environment` — current, wind, unmodelled forces, sensors and the
  plug-in :class:`DisturbanceComponent`;
* :mod:`vesselid.plant.vessels.wind` — Blendermann wind loads;
* data modules, one per vessel (:mod:`vesselid.plant.vessels.cybership2`, ...),
  each listed once in :mod:`vesselid.plant.catalogue`.
"""

from __future__ import annotations

from vesselid.plant.vessels.cybership2 import (
    CYBERSHIP2,
    CyberShip2Coefficients,
    cybership2_hull,
    cybership2_spec,
    cybership2_system,
    simulate_cybership2,
)
from vesselid.plant.vessels.environment import (
    SENSOR_CHANNELS,
    SENSOR_GROUPS,
    ComponentDraw,
    DisturbanceComponent,
    ProcessForce,
    VesselDisturbances,
    VesselSensors,
)
from vesselid.plant.vessels.hull import Hull
from vesselid.plant.vessels.kernel import (
    LAYOUT,
    VesselBatch,
    VesselModel,
    VesselSimulation,
    log_columns,
    simulate_vessel,
    wrap,
)
from vesselid.plant.vessels.wind import BLENDERMANN94, BlendermannWind, blendermann_wind_force

__all__ = [
    "BLENDERMANN94",
    "CYBERSHIP2",
    "LAYOUT",
    "SENSOR_CHANNELS",
    "SENSOR_GROUPS",
    "BlendermannWind",
    "ComponentDraw",
    "CyberShip2Coefficients",
    "DisturbanceComponent",
    "Hull",
    "ProcessForce",
    "VesselBatch",
    "VesselDisturbances",
    "VesselModel",
    "VesselSensors",
    "VesselSimulation",
    "blendermann_wind_force",
    "cybership2_hull",
    "cybership2_spec",
    "cybership2_system",
    "log_columns",
    "simulate_cybership2",
    "simulate_vessel",
    "wrap",
]
