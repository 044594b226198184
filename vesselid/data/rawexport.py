"""Raw sensor streams from a simulated trial: what a real vessel's sensors would have sent.

:func:`write_raw_streams` turns a simulated surface-vessel :class:`~vesselid.data.logs.TrialLog`
(columns ``u, v, r`` and the spec's inputs; ground truth ``true_*`` when present) into the
files a data logger on a real vessel produces, so that ``vesselid ingest`` can be tested
end to end:

``nav.nmea``
    NMEA 0183 sentences from one serial logger, each line prefixed by a TAG block with the
    logger's receive time (``\\c:<unix ms>*hh\\``), interleaved in receive order:

    ========  ==========  ================================================================
    sentence  rate (Hz)   content
    ========  ==========  ================================================================
    GNGGA     5           position (GNSS noise around the configured origin), UTC of fix
    GNRMC     10          speed and course over ground, UTC date and time of fix
    HEHDT     20          true heading (GNSS compass)
    HEROT     10          rate of turn (deg/min), the log's gyro reading
    VWVBW     10          dual-axis speed through water (when the log has a Doppler log)
    VWVHW     2           longitudinal speed through water (otherwise)
    WIMWV     1           apparent wind angle and speed
    ========  ==========  ================================================================

    The GNSS compass (GGA, RMC, HDT, ROT) shares one latency; the speed log and the
    anemometer have their own. Receive times add a uniform jitter and a constant logger
    clock offset; sentences drop out at random.
``actuators.csv``
    The actuator commands (the spec's inputs) with the control computer's UTC timestamps.
``ingest.toml``
    The installation data ``vesselid ingest`` uses: local NED origin, latencies of the
    untimed sentences relative to the GNSS time of validity, the CSV column mapping.
``<spec name>.toml``
    The model spec with θ0.
``streams.json``
    Provenance: settings, seed, the experiment time windows.

What is *measured* in the log (``u, v`` from GNSS, ``r`` from the gyro, the speed log and
anemometer columns) is encoded as the sentence that sensor sends — the log's readings are
the sensor's readings, so the same seed gives the same measurement noise on both paths —
while what the ideal log abstracts away is added: positions, heading, timing, rates,
quantisation, dropouts. Positions and heading come from ``true_north, true_east, true_psi``
when the log has them, otherwise from the kinematics ``η̇ = R(ψ) ν`` integrated with the
true velocities (explicit Euler at the log's ``dt``, as the vessel simulator does) from a
random initial heading. Earth-frame GNSS velocity is the measured body velocity rotated by
the true heading.
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from vesselid.core.fileio import atomic_path, atomic_write_text
from vesselid.data import nmea0183 as nmea
from vesselid.errors import VesselidError

__all__ = ["RawStreamConfig", "RawStreamError", "write_raw_streams"]

#: Spawn key separating the raw-stream noise from the simulation's streams of the same seed.
RAW_SPAWN_KEY = 0x52415753  # "RAWS"


class RawStreamError(VesselidError):
    """The log cannot be turned into raw sensor streams (not a surface vessel, bad settings)."""


@dataclass(frozen=True)
class RawStreamConfig:
    """Sensor installation and logger behaviour of :func:`write_raw_streams`.

    Parameters
    ----------
    origin : (lat, lon, height)
        Geodetic origin (deg, deg, m, WGS84) of the local NED frame the vessel moves in.
    start_utc : str
        UTC time of the first sample (ISO 8601).
    experiment_gap : float
        Pause between experiments (s); nothing is logged during it.
    rates : dict sentence -> Hz
        Output rates (``GGA, RMC, HDT, ROT, VBW, VHW, MWV``).
    latency : dict device -> s
        Time from validity to reception at the logger: ``gnss`` (GGA, RMC, HDT, ROT: one
        GNSS compass), ``speed_log`` (VBW/VHW), ``anemometer`` (MWV).
    jitter : float
        Receive-time jitter, uniform on ``[0, jitter)`` s.
    logger_clock_offset : float
        Logger clock minus UTC (s).
    controller_jitter : float
        Timestamp jitter of the actuator log, uniform on ``±controller_jitter/2`` s.
    dropout : float
        Probability that a sentence is lost.
    position_noise : float
        GNSS horizontal position noise std (m; RTK-like default).
    heading_noise : float
        Compass noise std (deg).
    speed_log_noise, wind_noise : float
        Noise std of the speed log (m/s) and of the wind speed (m/s) and angle (deg) when
        the log has no such sensor and they are synthesised from the truth.
    talkers : dict sentence -> talker id
    """

    origin: tuple[float, float, float] = (63.4389, 10.3986, 0.0)
    start_utc: str = "2026-06-01T10:00:00Z"
    experiment_gap: float = 120.0
    rates: dict[str, float] = field(default_factory=lambda: {
        "GGA": 5.0, "RMC": 10.0, "HDT": 20.0, "ROT": 10.0, "VBW": 10.0, "VHW": 2.0, "MWV": 1.0})
    latency: dict[str, float] = field(default_factory=lambda: {
        "gnss": 0.06, "speed_log": 0.12, "anemometer": 0.2})
    jitter: float = 0.01
    logger_clock_offset: float = 0.35
    controller_jitter: float = 0.001
    dropout: float = 0.002
    position_noise: float = 0.02
    heading_noise: float = 0.05
    speed_log_noise: float = 0.005
    wind_noise: float = 0.05
    talkers: dict[str, str] = field(default_factory=lambda: {
        "GGA": "GN", "RMC": "GN", "HDT": "HE", "ROT": "HE", "VBW": "VW", "VHW": "VW",
        "MWV": "WI"})

    def __post_init__(self) -> None:
        lat, lon, _h = (float(x) for x in self.origin)
        if not (-90 < lat < 90 and -180 <= lon <= 180):
            raise RawStreamError(f"origin must be (lat, lon, height) in degrees, got {self.origin}")
        for k, v in self.rates.items():
            if not (math.isfinite(v) and v > 0):
                raise RawStreamError(f"rate of {k} must be positive, got {v}")
        for name in ("jitter", "dropout", "position_noise", "heading_noise", "experiment_gap",
                     "controller_jitter", "speed_log_noise", "wind_noise"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v >= 0):
                raise RawStreamError(f"{name} must be a non-negative number, got {v}")
        if self.dropout >= 1:
            raise RawStreamError("dropout must be below 1")
        _parse_utc(self.start_utc)


def _parse_utc(text: str) -> float:
    try:
        ts = pd.Timestamp(text)
    except (ValueError, TypeError) as exc:
        raise RawStreamError(f"start_utc {text!r} is not an ISO 8601 time") from exc
    if ts.tzinfo is None:
        ts = ts.tz_localize("UTC")
    return ts.tz_convert("UTC").value / 1e9


def _col(frame: pd.DataFrame, *names: str) -> np.ndarray | None:
    for n in names:
        if n in frame.columns:
            return frame[n].to_numpy(dtype=float)
    return None


@dataclass
class _Experiment:
    t0: float                    # absolute UTC of the first sample
    time: np.ndarray             # s from t0
    u: np.ndarray                # measured body velocity (GNSS)
    v: np.ndarray
    r: np.ndarray                # gyro
    north: np.ndarray            # true kinematics
    east: np.ndarray
    psi: np.ndarray
    u_log: np.ndarray | None     # speed through water (measured or synthesised)
    v_log: np.ndarray | None
    wind_speed: np.ndarray | None
    wind_angle: np.ndarray | None
    inputs: np.ndarray


def _kinematics(frame: pd.DataFrame, dt: float, rng: np.random.Generator):
    north, east, psi = (_col(frame, f"true_{c}") for c in ("north", "east", "psi"))
    if north is not None and east is not None and psi is not None:
        return north, east, psi
    tu = _col(frame, "true_u", "u")
    tv = _col(frame, "true_v", "v")
    tr = _col(frame, "true_r", "r")
    psi0 = rng.uniform(0.0, 2.0 * math.pi)
    psi = psi0 + dt * np.concatenate([[0.0], np.cumsum(tr[:-1])])
    c, s = np.cos(psi), np.sin(psi)
    vn = c * tu - s * tv
    ve = s * tu + c * tv
    north = dt * np.concatenate([[0.0], np.cumsum(vn[:-1])])
    east = dt * np.concatenate([[0.0], np.cumsum(ve[:-1])])
    return north, east, psi


def _experiments(log: Any, config: RawStreamConfig, rng: np.random.Generator, dt: float):
    spec = log.spec
    out = []
    t0 = _parse_utc(config.start_utc)
    for _eid, frame in log.experiments():
        n = len(frame)
        time = _col(frame, "time")
        time = np.arange(n) * dt if time is None else time - time[0]
        north, east, psi = _kinematics(frame, dt, rng)
        u_log = _col(frame, "u_log")
        v_log = _col(frame, "v_log")
        if u_log is None:
            base = _col(frame, "true_u_r", "true_u", "u")
            u_log = base + rng.normal(0.0, config.speed_log_noise, n)
        ws, wa = _col(frame, "wind_speed"), _col(frame, "wind_angle")
        if ws is None or wa is None:
            # still air: the apparent wind is the vessel's own motion, from ahead when u > 0
            tu, tv = _col(frame, "true_u", "u"), _col(frame, "true_v", "v")
            ws = np.hypot(tu, tv) + rng.normal(0.0, config.wind_noise, n)
            wa = -np.arctan2(tv, tu) + rng.normal(0.0, math.radians(config.wind_noise), n)
        out.append(_Experiment(
            t0=t0, time=time, u=_col(frame, "u"), v=_col(frame, "v"), r=_col(frame, "r"),
            north=north, east=east, psi=psi, u_log=u_log, v_log=v_log,
            wind_speed=np.abs(ws), wind_angle=wa,
            # actuator commands (a sea-trial log with the wind load as a known input
            # keeps the commands in X_cmd, ...)
            inputs=frame[[f"{c}_cmd" if f"{c}_cmd" in frame else c
                          for c in spec.inputs]].to_numpy(dtype=float)))
        duration = float(time[-1]) + dt
        t0 = t0 + math.ceil((duration + config.experiment_gap) / dt) * dt
    return out


def _times(exp: _Experiment, rate: float) -> np.ndarray:
    """Sample times (s from the experiment start) of a sensor at ``rate``."""
    n = math.floor(exp.time[-1] * rate + 1e-9) + 1
    return np.arange(n) / rate


def _interp(exp: _Experiment, t: np.ndarray, values: np.ndarray) -> np.ndarray:
    return np.interp(t, exp.time, values)


class _Sentences:
    """Accumulates the sentences of every stream as byte matrices with their receive times."""

    def __init__(self, config: RawStreamConfig, rng: np.random.Generator) -> None:
        self.config = config
        self.rng = rng
        self.rx: list[np.ndarray] = []
        self.rows: list[np.ndarray] = []
        self.counts: dict[str, int] = {}

    def add(self, kind: str, device: str, t_valid: np.ndarray, fields: list) -> None:
        """Sentences of one stream; ``fields`` are byte matrices or constant strings."""
        cfg = self.config
        n = t_valid.size
        keep = self.rng.random(n) >= cfg.dropout
        jit = self.rng.uniform(0.0, cfg.jitter, n) if cfg.jitter > 0 else np.zeros(n)
        rx = t_valid + cfg.latency.get(device, 0.0) + jit + cfg.logger_clock_offset
        idx = np.flatnonzero(keep)
        cols = [nmea.const_field(f, idx.size) if isinstance(f, str) else f[idx] for f in fields]
        rows = nmea.sentence_rows(cfg.talkers.get(kind, "GP"), kind, cols, rx[idx])
        self.rx.append(rx[idx])
        self.rows.append(rows)
        self.counts[kind] = self.counts.get(kind, 0) + rows.shape[0]

    def write(self, stream: Any) -> None:
        """Every sentence in receive order, CRLF-terminated, to a binary ``stream``."""
        rx = np.concatenate(self.rx) if self.rx else np.zeros(0)
        nmea.write_rows(self.rows, np.argsort(rx, kind="stable"), stream)


def _geodetic(north: np.ndarray, east: np.ndarray, down: np.ndarray, origin) -> tuple:
    import pymap3d

    lat, lon, h = pymap3d.ned2geodetic(north, east, down, *origin)
    return np.asarray(lat), np.asarray(lon), np.asarray(h)


def _emit(exp: _Experiment, out: _Sentences, dt: float) -> None:
    cfg = out.config
    rng = out.rng
    rates = cfg.rates
    fixed = nmea.fixed_field
    # GGA: position with GNSS noise
    t = _times(exp, rates["GGA"])
    n = t.size
    north = _interp(exp, t, exp.north) + rng.normal(0.0, cfg.position_noise, n)
    east = _interp(exp, t, exp.east) + rng.normal(0.0, cfg.position_noise, n)
    down = rng.normal(0.0, 2.0 * cfg.position_noise, n)
    lat, lon, h = _geodetic(north, east, down, cfg.origin)
    la, lad = nmea.latitude_fields(lat)
    lo, lod = nmea.longitude_fields(lon)
    tabs = exp.t0 + t
    out.add("GGA", "gnss", tabs, [
        nmea.utc_time_field(tabs), la, lad, lo, lod, "4", "14", "0.7", fixed(h, 3), "M",
        "39.5", "M", "1.0", "0000"])
    # RMC: measured body velocity rotated by the true heading
    t = _times(exp, rates["RMC"])
    n = t.size
    u, v = _interp(exp, t, exp.u), _interp(exp, t, exp.v)
    psi = _interp(exp, t, exp.psi)
    c, s = np.cos(psi), np.sin(psi)
    vn, ve = c * u - s * v, s * u + c * v
    sog = np.hypot(vn, ve) / nmea.KNOT
    cog = np.degrees(np.arctan2(ve, vn)) % 360.0
    north, east = _interp(exp, t, exp.north), _interp(exp, t, exp.east)
    lat, lon, _ = _geodetic(north, east, np.zeros(n), cfg.origin)
    la, lad = nmea.latitude_fields(lat)
    lo, lod = nmea.longitude_fields(lon)
    tabs = exp.t0 + t
    out.add("RMC", "gnss", tabs, [
        nmea.utc_time_field(tabs), "A", la, lad, lo, lod, fixed(sog, 4), fixed(cog, 3),
        nmea.utc_date_field(tabs), "", "", "R"])
    # HDT: true heading with compass noise
    t = _times(exp, rates["HDT"])
    n = t.size
    hdg = (np.degrees(_interp(exp, t, exp.psi)) + rng.normal(0.0, cfg.heading_noise, n)) % 360.0
    out.add("HDT", "gnss", exp.t0 + t, [fixed(hdg, 2), "T"])
    # ROT: the gyro reading, deg/min (negative: bow turns to port)
    t = _times(exp, rates["ROT"])
    rot = np.degrees(_interp(exp, t, exp.r)) * 60.0
    out.add("ROT", "gnss", exp.t0 + t, [fixed(rot, 2), "A"])
    # speed through water
    if exp.v_log is not None:
        t = _times(exp, rates["VBW"])
        ul, vl = _interp(exp, t, exp.u_log), _interp(exp, t, exp.v_log)
        out.add("VBW", "speed_log", exp.t0 + t, [
            fixed(ul / nmea.KNOT, 4), fixed(vl / nmea.KNOT, 4), "A", "", "", "V"])
    else:
        t = _times(exp, rates["VHW"])
        ul = _interp(exp, t, exp.u_log) / nmea.KNOT
        hdg = np.degrees(_interp(exp, t, exp.psi)) % 360.0
        out.add("VHW", "speed_log", exp.t0 + t, [
            fixed(hdg, 1), "T", "", "M", fixed(ul, 3), "N", fixed(ul * nmea.KNOT * 3.6, 3), "K"])
    # MWV: apparent wind, angle clockwise from the bow (wind from starboard: 0..180)
    t = _times(exp, rates["MWV"])
    ang = (-np.degrees(_interp(exp, t, exp.wind_angle))) % 360.0
    spd = _interp(exp, t, exp.wind_speed)
    out.add("MWV", "anemometer", exp.t0 + t, [fixed(ang, 1), "R", fixed(spd, 2), "M", "A"])


def write_raw_streams(
    log: Any,
    directory: str | Path,
    *,
    seed: int | None = None,
    config: RawStreamConfig | None = None,
) -> dict[str, Any]:
    """Write the raw sensor streams of a simulated surface-vessel trial into ``directory``.

    Parameters
    ----------
    log : TrialLog
        Simulated log with a spec in its metadata, columns ``u, v, r`` (measured body
        velocities and yaw rate) and the spec's inputs; ``true_*`` columns when present.
    directory : str or Path
        Output directory (created; existing files of the same names are replaced atomically).
    seed : int, optional
        Seed of the raw-stream noise (dropouts, jitter, GNSS and compass noise, initial
        heading); default the log's ``metadata["seed"]``. Drawn from
        ``SeedSequence(seed, spawn_key=(RAW_SPAWN_KEY,))``, independent of the simulation's
        own streams.
    config : RawStreamConfig, optional

    Returns
    -------
    dict
        The manifest also written to ``streams.json`` (files, sentence counts, settings).

    Raises
    ------
    RawStreamError
        No spec, missing ``u, v, r`` or input columns, unknown ``dt``.
    """
    config = config or RawStreamConfig()
    spec = log.spec
    if spec is None:
        raise RawStreamError("raw sensor streams need a log with a model spec in its metadata")
    missing = [c for c in ("u", "v", "r", *spec.inputs) if c not in log.data.columns]
    if missing:
        raise RawStreamError(
            f"raw NMEA streams need a surface-vessel log (surge u, sway v, yaw rate r and the "
            f"inputs); missing columns {missing}")
    dt = spec.dt
    if dt is None and "time" in log.data.columns:
        dt = float(np.median(np.diff(log.data["time"].to_numpy()[:2])))
    if dt is None or not dt > 0:
        raise RawStreamError("the spec has no sample time dt")
    if seed is None:
        seed = log.metadata.get("seed")
    rng = np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(RAW_SPAWN_KEY,)))
    exps = _experiments(log, config, rng, dt)
    out = _Sentences(config, rng)
    for exp in exps:
        _emit(exp, out, dt)
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    with atomic_path(directory / "nav.nmea") as tmp, open(tmp, "wb") as stream:
        out.write(stream)
    # actuator commands with the control computer's UTC timestamps: time to 0.1 ms, the
    # commands as the shortest decimal that reads back to the same float64
    blocks = []
    for exp in exps:
        n = exp.time.size
        jit = rng.uniform(-0.5, 0.5, n) * config.controller_jitter
        cols = [nmea.fixed_field(exp.t0 + exp.time + jit, 4)]
        for j in range(exp.inputs.shape[1]):
            text = np.ascontiguousarray(exp.inputs[:, j]).astype("S32")
            cols += [nmea.const_field(",", n), text.view(np.uint8).reshape(n, 32)]
        blocks.append(np.hstack([*cols, nmea.const_field("\n", n)]))
    header = ",".join(["time", *(f"{c}_cmd" for c in spec.inputs)]) + "\n"
    with atomic_path(directory / "actuators.csv") as tmp, open(tmp, "wb") as stream:
        stream.write(header.encode("ascii"))
        nmea.write_rows(blocks, np.arange(sum(b.shape[0] for b in blocks)), stream)
    gnss_lat = config.latency.get("gnss", 0.0)
    ingest_cfg = {
        "origin": [float(x) for x in config.origin],
        "relative_latency": {
            "VBW": config.latency.get("speed_log", 0.0) - gnss_lat,
            "VHW": config.latency.get("speed_log", 0.0) - gnss_lat,
            "MWV": config.latency.get("anemometer", 0.0) - gnss_lat,
        },
        "csv": [{"file": "actuators.csv", "time": "time", "kind": "command",
                 "columns": {c: f"{c}_cmd" for c in spec.inputs}}],
    }
    import tomli_w

    atomic_write_text(
        directory / "ingest.toml",
        "# vesselid ingest configuration (installation data) written by the raw-stream "
        "generator\n" + tomli_w.dumps(ingest_cfg))
    spec_path = directory / f"{spec.name}.toml"
    spec.save(spec_path)
    manifest = {
        "files": ["nav.nmea", "actuators.csv", "ingest.toml", spec_path.name],
        "sentences": out.counts,
        "seed": seed,
        "dt": dt,
        "experiments": [{"start_utc": e.t0, "samples": int(e.time.size)} for e in exps],
        "config": asdict(config),
    }
    atomic_write_text(directory / "streams.json", json.dumps(manifest, indent=2) + "\n")
    return manifest
