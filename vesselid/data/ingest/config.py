"""The ingest configuration: installation data and column mappings (a small TOML file).

::

    origin = [63.4389, 10.3986, 0.0]   # local NED origin (lat, lon, h); default: first fix
    max_gap = 1.0                      # s; a longer gap in any channel splits the experiment
    min_duration = 30.0                # s; shorter experiments are dropped (reported)
    epoch_tolerance = 0.02             # s; untimed NMEA sentences this close to a GNSS
                                       # epoch take its time of validity (0: off)

    [relative_latency]                 # s, untimed NMEA sentences, minus the GNSS latency
    MWV = 0.14

    [[csv]]                            # one table per CSV file (multi-rate loggers)
    file = "actuators.csv"             # name or glob, relative to the configuration file
    time = "time"                      # time column
    time_unit = "s"                    # s | ms | us | ns | iso
    clock_offset = 0.0                 # s, subtracted (file clock minus UTC)
    kind = "command"                   # command (zero-order hold) | measurement
    sample_rate = 10.0                 # Hz, optional: the logger's rate, used only to
                                       # rebuild a quantised/duplicated time column
    columns = { X = "X_cmd", psi = { column = "heading_deg", scale = 0.0174533 } }

    heading_offset = 0.0               # deg: heading sensor axis minus the bow, clockwise
                                       # (psi = sensor heading - heading_offset)
    lever_arm = [0.0, 0.0]             # m: GNSS antenna from the reference point, body
                                       # axes (x forward, y starboard[, z down])

    [nmea]                             # NMEA 0183 options
    magnetic_variation = -2.5          # deg, east positive (HDG/HDM without a variation)
    deviation = 0.0                    # deg, east positive (HDG without a deviation)
    channels = { rudder = "delta", shaft_rpm = { name = "n", scale = 0.0166667 } }
    xdr = { RUDDER = "delta", ENGINE0 = { name = "n", scale = 0.0166667 } }

    [tank]                             # model-test tables, one experiment per file
    files = "raw_data/*.dat"           # (vesselid.data.ingest.tank: layout, units, frames, scale)
    columns = { time = "time", psi = "psi", u = "u", v = "v", r = "r", delta = "delta" }

    [ros]                              # ROS 1 / ROS 2 bags (optional extra "ros")
    odometry = "/odom"                 # nav_msgs/msg/Odometry topic (default: by type)
    imu = "/imu"                       # sensor_msgs/msg/Imu
    wrench = "/wrench"                 # geometry_msgs/msg/WrenchStamped
    frame = "enu"                      # ROS REP 103 (ENU world, FLU body) | "ned" (NED/FRD)
    inputs = { X = "force.x", Y = "force.y", N = "torque.z" }

Canonical channel names a mapping may target: ``u, v, r, psi, north, east, lat, lon,
vel_north, vel_east, u_log, v_log, wind_speed, wind_angle`` and any other name (an input or
sensor column, copied as is). ``psi`` and ``wind_angle`` are treated as angles.
NMEA channel names (renamed by ``[nmea] channels``): ``rudder`` (RSA, rad, + to
starboard), ``rudder_port``, ``shaft_rpm`` / ``engine_rpm`` (RPM, rev/min; ``_<n>`` suffix
with several shafts/engines), and the XDR transducer names mapped in ``[nmea] xdr``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from vesselid.errors import VesselidError

__all__ = ["ChannelMap", "CsvMapping", "IngestConfig", "IngestError", "NmeaOptions",
           "load_config"]

ANGLE_CHANNELS = ("psi", "wind_angle")



class IngestError(VesselidError):
    """Raw input that cannot be turned into a trial log (reason in the message)."""


@dataclass(frozen=True)
class ColumnMap:
    column: str
    scale: float = 1.0
    offset: float = 0.0


@dataclass(frozen=True)
class ChannelMap:
    """A renamed (and scaled) channel: ``value = raw * scale + offset``."""

    name: str
    scale: float = 1.0
    offset: float = 0.0


@dataclass(frozen=True)
class NmeaOptions:
    """The ``[nmea]`` table: magnetic corrections and channel names.

    Attributes
    ----------
    magnetic_variation, deviation : float or None
        Degrees, east positive; used where an HDG sentence leaves the field empty and for
        HDM (which has neither). ``None``: not stated.
    channels : dict
        NMEA channel name → :class:`ChannelMap` (rename/scale, e.g. ``rudder`` → ``delta``).
    xdr : dict
        XDR transducer name → :class:`ChannelMap` (unmapped transducers are counted, not
        read).
    """

    magnetic_variation: float | None = None
    deviation: float | None = None
    channels: dict[str, ChannelMap] = field(default_factory=dict)
    xdr: dict[str, ChannelMap] = field(default_factory=dict)


@dataclass(frozen=True)
class CsvMapping:
    file: str
    time: str = "time"
    time_unit: str = "s"
    clock_offset: float = 0.0
    kind: str = "measurement"
    columns: dict[str, ColumnMap] = field(default_factory=dict)
    sample_rate: float | None = None


@dataclass(frozen=True)
class IngestConfig:
    origin: tuple[float, float, float] | None = None
    max_gap: float = 1.0
    min_duration: float = 30.0
    epoch_tolerance: float = 0.02
    relative_latency: dict[str, float] = field(default_factory=dict)
    csv: tuple[CsvMapping, ...] = ()
    ros: dict[str, Any] = field(default_factory=dict)
    base: Path = Path(".")
    heading_offset: float = 0.0
    lever_arm: tuple[float, float, float] = (0.0, 0.0, 0.0)
    nmea: NmeaOptions = field(default_factory=NmeaOptions)
    tank: dict[str, Any] | None = None  # the [tank] table (vesselid.data.ingest.tank)


def _num(value: Any, what: str) -> float:
    try:
        out = float(value)
    except (TypeError, ValueError):
        raise IngestError(f"{what} must be a number, got {value!r}") from None
    if not math.isfinite(out):
        raise IngestError(f"{what} must be finite, got {value!r}")
    return out


def _column_map(name: str, raw: Any, where: str) -> ColumnMap:
    if isinstance(raw, str):
        return ColumnMap(raw)
    if isinstance(raw, dict) and isinstance(raw.get("column"), str):
        return ColumnMap(raw["column"], _num(raw.get("scale", 1.0), f"{where}.{name}.scale"),
                         _num(raw.get("offset", 0.0), f"{where}.{name}.offset"))
    raise IngestError(f"{where}.columns.{name} must be a column name or "
                      f"{{column = ..., scale = ..., offset = ...}}, got {raw!r}")


def _channel_map(raw: Any, where: str) -> ChannelMap:
    if isinstance(raw, str) and raw:
        return ChannelMap(raw)
    if isinstance(raw, dict) and isinstance(raw.get("name"), str) and raw["name"]:
        bad = sorted(set(raw) - {"name", "scale", "offset"})
        if bad:
            raise IngestError(f"{where}: unknown keys {bad} (known: name, scale, offset)")
        return ChannelMap(raw["name"], _num(raw.get("scale", 1.0), f"{where}.scale"),
                          _num(raw.get("offset", 0.0), f"{where}.offset"))
    raise IngestError(f"{where} must be a channel name or {{name = ..., scale = ..., "
                      f"offset = ...}}, got {raw!r}")


def _nmea_options(raw: Any) -> NmeaOptions:
    if not isinstance(raw, dict):
        raise IngestError("[nmea] must be a table")
    known = {"magnetic_variation", "deviation", "channels", "xdr"}
    unknown = sorted(set(raw) - known)
    if unknown:
        raise IngestError(f"unknown [nmea] keys {unknown}; known: {sorted(known)}")
    var = raw.get("magnetic_variation")
    dev = raw.get("deviation")
    var = None if var is None else _num(var, "nmea.magnetic_variation")
    dev = None if dev is None else _num(dev, "nmea.deviation")
    for name, v in (("magnetic_variation", var), ("deviation", dev)):
        if v is not None and abs(v) > 180:
            raise IngestError(f"nmea.{name} must be within ±180 degrees, got {v}")
    maps = {}
    for key in ("channels", "xdr"):
        table = raw.get(key, {})
        if not isinstance(table, dict):
            raise IngestError(f"nmea.{key} must be a table of name = channel")
        maps[key] = {str(k): _channel_map(v, f"nmea.{key}.{k}") for k, v in table.items()}
    return NmeaOptions(var, dev, maps["channels"], maps["xdr"])


def config_from_dict(data: dict[str, Any], base: Path = Path(".")) -> IngestConfig:
    """Validate a parsed configuration (a ``[tank]`` table is checked by
    :func:`vesselid.data.ingest.tank.tank_format_from_dict` where it is used)."""
    known = {"origin", "max_gap", "min_duration", "epoch_tolerance", "relative_latency", "csv",
             "ros", "heading_offset", "lever_arm", "nmea", "tank"}
    unknown = sorted(set(data) - known)
    if unknown:
        raise IngestError(f"unknown ingest configuration keys {unknown}; known: {sorted(known)}")
    origin = data.get("origin")
    if origin is not None:
        if not isinstance(origin, list | tuple) or len(origin) not in (2, 3):
            raise IngestError(f"origin must be [lat, lon] or [lat, lon, h], got {origin!r}")
        vals = [_num(x, "origin") for x in origin]
        if not (-90 < vals[0] < 90 and -180 <= vals[1] <= 180):
            raise IngestError(f"origin latitude/longitude out of range: {origin!r}")
        origin = (vals[0], vals[1], vals[2] if len(vals) == 3 else 0.0)
    max_gap = _num(data.get("max_gap", 1.0), "max_gap")
    min_duration = _num(data.get("min_duration", 30.0), "min_duration")
    epoch_tolerance = _num(data.get("epoch_tolerance", 0.02), "epoch_tolerance")
    if max_gap <= 0 or min_duration < 0 or epoch_tolerance < 0:
        raise IngestError("max_gap must be positive, min_duration and epoch_tolerance "
                          "non-negative")
    rel = data.get("relative_latency", {})
    if not isinstance(rel, dict):
        raise IngestError("[relative_latency] must be a table of sentence = seconds")
    rel = {str(k).upper(): _num(v, f"relative_latency.{k}") for k, v in rel.items()}
    tables = data.get("csv", [])
    if isinstance(tables, dict):
        tables = [tables]
    csv = []
    for i, t in enumerate(tables):
        where = f"csv[{i}]"
        if not isinstance(t, dict) or not isinstance(t.get("file"), str):
            raise IngestError(f"{where} needs file = \"name.csv\"")
        unit = str(t.get("time_unit", "s")).lower()
        if unit not in ("s", "ms", "us", "ns", "iso"):
            raise IngestError(f"{where}.time_unit must be s, ms, us, ns or iso, got {unit!r}")
        kind = str(t.get("kind", "measurement")).lower()
        if kind not in ("command", "measurement"):
            raise IngestError(f"{where}.kind must be 'command' or 'measurement', got {kind!r}")
        cols = t.get("columns", {})
        if not isinstance(cols, dict) or not cols:
            raise IngestError(f"{where}.columns must map channel names to CSV columns")
        rate = t.get("sample_rate")
        if rate is not None:
            rate = _num(rate, f"{where}.sample_rate")
            if rate <= 0:
                raise IngestError(f"{where}.sample_rate must be a positive rate in Hz, got {rate}")
        csv.append(CsvMapping(
            file=t["file"], time=str(t.get("time", "time")), time_unit=unit,
            clock_offset=_num(t.get("clock_offset", 0.0), f"{where}.clock_offset"), kind=kind,
            columns={str(k): _column_map(str(k), v, where) for k, v in cols.items()},
            sample_rate=rate))
    ros = data.get("ros", {})
    if not isinstance(ros, dict):
        raise IngestError("[ros] must be a table")
    heading_offset = _num(data.get("heading_offset", 0.0), "heading_offset")
    if abs(heading_offset) > 360:
        raise IngestError(f"heading_offset must be within ±360 degrees, got {heading_offset}")
    arm = data.get("lever_arm", [0.0, 0.0, 0.0])
    if not isinstance(arm, list | tuple) or len(arm) not in (2, 3):
        raise IngestError(f"lever_arm must be [x, y] or [x, y, z] in metres (body axes: x "
                          f"forward, y starboard, z down), got {arm!r}")
    arm_v = [_num(x, "lever_arm") for x in arm]
    if max(abs(x) for x in arm_v) > 1000:
        raise IngestError(f"lever_arm components must be within ±1000 m, got {arm!r}")
    lever = (arm_v[0], arm_v[1], arm_v[2] if len(arm_v) == 3 else 0.0)
    tank = data.get("tank")
    if tank is not None and not isinstance(tank, dict):
        raise IngestError("[tank] must be a table")
    return IngestConfig(origin=origin, max_gap=max_gap, min_duration=min_duration,
                        epoch_tolerance=epoch_tolerance,
                        relative_latency=rel, csv=tuple(csv), ros=dict(ros), base=base,
                        heading_offset=heading_offset, lever_arm=lever,
                        nmea=_nmea_options(data.get("nmea", {})),
                        tank=tank)


def load_config(path: str | Path) -> IngestConfig:
    """Read an ingest configuration TOML file."""
    try:
        import tomllib
    except ModuleNotFoundError:  # pragma: no cover - Python 3.10
        import tomli as tomllib
    path = Path(path)
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except OSError as exc:
        raise IngestError(f"cannot read ingest configuration {path}: {exc.strerror}") from exc
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise IngestError(f"{path}: invalid TOML: {exc}") from exc
    return config_from_dict(data, base=path.parent)
