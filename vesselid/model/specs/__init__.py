"""Model specs and ingest configurations shipped with the package.

``kvlcc2.toml``
    A 3-DOF manoeuvring model of the KVLCC2 tanker for free-running model tests (surge
    about the approach speed, sway, yaw; rudder forces linear in δ with a speed correction;
    the constant-rpm propeller balance absorbed in the surge equilibrium). Documented in
    the file itself and in the user guide ("Your real vessel").
``kvlcc2_u2delta.toml``
    The same with the rudder forces in ``u²δ`` and ``u²δ²`` as derived inputs computed from
    the measured speed (outside the IV consistency results: :mod:`vesselid.model.derived`).
``kvlcc2_vr.toml``
    ``kvlcc2.toml`` with the cross term ``v*|r|`` (``N_v|r|``) in the yaw moment, chosen by
    leave-one-run-out cross-validation on the training zig-zags (``scripts/kvlcc2_study.py``):
    closer second overshoot angles, free-run fit as good.
``kvlcc2_hsva_ingest.toml``
    The ``[tank]`` table (:mod:`vesselid.data.ingest.tank`) that reads the HSVA free-running
    KVLCC2 zig-zag tables of SIMMAN 2008 (whitespace ``.dat``, four header lines, angles in
    degrees, earth-fixed velocities, model scale 1:45.7).

>>> from vesselid.model.specs import load_spec, path   # doctest: +SKIP
>>> spec = load_spec("kvlcc2")
>>> path("kvlcc2_hsva_ingest")                    # pass it to ``vesselid ingest --config``
>>> from vesselid.data.ingest.tank import ingest_tank, load_tank_format
>>> log = ingest_tank(files, spec.dt, load_tank_format(path("kvlcc2_hsva_ingest")))
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

__all__ = ["available", "load_spec", "path"]

_HERE = Path(__file__).parent


def available() -> list[str]:
    """Names of the shipped files (without ``.toml``)."""
    return sorted(p.stem for p in _HERE.glob("*.toml"))


def path(name: str) -> Path:
    """Path of a shipped TOML file.

    Raises
    ------
    ModelSpecError
        Unknown name (the message lists the available ones).
    """
    p = _HERE / f"{name}.toml"
    if not p.is_file():
        from vesselid.errors import ModelSpecError

        raise ModelSpecError(f"no shipped spec {name!r}; available: {available()}")
    return p


def load_spec(name: str) -> Any:
    """The shipped model spec ``name`` as a :class:`~vesselid.model.spec.ModelSpec`."""
    from vesselid.model.spec import ModelSpec

    return ModelSpec.load(path(name))
