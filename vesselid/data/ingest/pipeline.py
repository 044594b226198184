"""Raw inputs → trial log: clock alignment, resampling, frames, experiments, quality.

:func:`ingest` reads every source (NMEA 0183 files, ROS 2 bags, mapped CSV files), picks
one stream per channel (NMEA: GGA before RMC for position, RMC before VTG for velocity,
HDT before THS; bags: IMU gyro before odometry twist for yaw rate), and then

1. converts latitude/longitude to local NED (``pymap3d.geodetic2ned``) around the
   configured origin or the first fix,
2. lays the grid ``t_k = k·dt`` (UNIX seconds, so 10 Hz GNSS epochs fall on grid points),
   keeps the grid points where *every* channel has data without a gap longer than
   ``max(max_gap, 3 periods)``, and splits experiments where that fails (a pause between
   runs, or one sensor missing for minutes); stretches shorter than ``min_duration`` are
   dropped and reported,
3. resamples each channel (:func:`vesselid.data.ingest.streams.resample`: anti-aliased
   decimation, interpolation, or zero-order hold for commands; heading unwrapped),
4. subtracts the heading sensor's mounting offset (``heading_offset``) from the heading,
   rotates earth-frame velocity into body-frame surge/sway with the heading,
   ``u = cos ψ v_N + sin ψ v_E``, ``v = −sin ψ v_N + cos ψ v_E``, and takes the yaw rate
   from the rate-of-turn sensor/gyro, or differentiates the unwrapped heading when there
   is none,
5. moves GNSS position and velocity from the antenna to the reference point
   (``lever_arm = [x, y]``, body axes): ``n_ref = n − (cos ψ x − sin ψ y)``,
   ``e_ref = e − (sin ψ x + cos ψ y)``, ``u_ref = u + r y``, ``v_ref = v − r x``,
6. writes a quality report (per source and per column) into ``metadata["quality"]``.

Model-test tables (a ``[tank]`` table in the configuration) take the one-clock path of
:mod:`vesselid.data.ingest.tank` instead: one experiment per file, no grid alignment.
"""

from __future__ import annotations

import glob
import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from vesselid.data.ingest.config import IngestConfig, IngestError, load_config
from vesselid.data.ingest.streams import Stream, coverage, resample, stream_quality
from vesselid.errors import VesselidError

__all__ = ["NMEA_SUFFIXES", "ingest"]

NMEA_SUFFIXES = (".nmea", ".txt", ".log", ".0183", ".n0183")
BAG_SUFFIXES = (".db3", ".mcap", ".bag")
#: Optional packages per input kind: (import name, extra).
_NEEDS = {"nmea": (("pynmea2", "raw"), ("pymap3d", "raw")), "bag": (("rosbags", "ros"),),
          "position": (("pymap3d", "raw"),)}
CONFIG_NAME = "ingest.toml"
#: Grid points beyond which ingest refuses (a clock error making the span absurd).
MAX_GRID = 50_000_000

#: Columns first in the output, in this order (when present).
_ORDER = ("u", "v", "r", "psi", "north", "east", "u_log", "v_log", "wind_speed", "wind_angle")


def _collect(paths: Sequence[str | Path], config_path: str | Path | None):
    files: list[Path] = []
    bags: list[Path] = []
    tomls: list[Path] = []
    config_file = Path(config_path) if config_path is not None else None
    for p in paths:
        p = Path(p)
        if not p.exists():
            raise IngestError(f"input {p} does not exist")
        if p.is_dir():
            if (p / "metadata.yaml").is_file():
                bags.append(p)
                continue
            if config_file is None and (p / CONFIG_NAME).is_file():
                config_file = p / CONFIG_NAME
            for child in sorted(p.iterdir()):
                if child.is_dir() and (child / "metadata.yaml").is_file():
                    bags.append(child)
                elif child.is_file():
                    files.append(child)
        else:
            files.append(p)
    config = load_config(config_file) if config_file is not None else IngestConfig()
    nmea, csv, other = [], [], []
    for f in files:
        suffix = f.suffix.lower()
        if f.name == CONFIG_NAME or (config_file is not None and f == config_file):
            continue
        if suffix in NMEA_SUFFIXES:
            nmea.append(f)
        elif suffix in BAG_SUFFIXES:
            bags.append(f)
        elif suffix == ".csv":
            csv.append(f)
        elif suffix == ".toml":
            tomls.append(f)
        else:
            other.append(f)
    return config, config_file, nmea, bags, csv, tomls, other


def _csv_jobs(config: IngestConfig, csv_files: list[Path]):
    jobs = []
    used: set[Path] = set()
    for m in config.csv:
        pattern = str(config.base / m.file)
        hits = sorted(Path(x) for x in glob.glob(pattern))
        hits += [f for f in csv_files if f.name == Path(m.file).name and f not in hits]
        if not hits:
            raise IngestError(f"the ingest configuration maps {m.file!r}, which is not there")
        for h in hits:
            jobs.append((h, m))
            used.add(h.resolve())
    unmapped = [str(f) for f in csv_files if f.resolve() not in used]
    return jobs, unmapped


def require(kind: str, what: str) -> None:
    """Refuse with one line naming the extra to install when an optional package is missing.

    Parameters
    ----------
    kind : {"nmea", "bag", "position"}
    what : str
        What needs it, for the message (e.g. ``"reading NMEA 0183 (nav.nmea)"``).

    Raises
    ------
    IngestError
        ``<what> needs the optional package 'pynmea2': pip install 'vesselid[raw]'``.
    """
    import importlib

    for module, extra in _NEEDS[kind]:
        try:
            importlib.import_module(module)
        except ImportError:
            raise IngestError(f"{what} needs the optional package {module!r}: "
                              f"pip install 'vesselid[{extra}]'") from None


def _find_spec(tomls: list[Path]):
    from vesselid.model.spec import ModelSpec

    for t in tomls:
        try:
            return ModelSpec.load(t), t
        except (VesselidError, ValueError, OSError, KeyError, TypeError):
            continue
    return None, None


def _choose(streams: list[Stream]) -> tuple[dict[str, Stream], dict[str, list[str]]]:
    chosen: dict[str, Stream] = {}
    unused: dict[str, list[str]] = {}
    for s in sorted(streams, key=lambda s: (s.priority, -s.t.size)):
        if s.t.size == 0:
            unused.setdefault(s.name, []).append(f"{s.source} (no valid samples)")
            continue
        if s.name in chosen:
            unused.setdefault(s.name, []).append(s.source)
        else:
            chosen[s.name] = s
    return chosen, unused


def _ned(chosen: dict[str, Stream], config: IngestConfig, notes: dict) -> tuple | None:
    if "lat" not in chosen or "lon" not in chosen:
        return None
    require("position", "converting GNSS latitude/longitude to local north/east")
    import pymap3d

    lat, lon = chosen.pop("lat"), chosen.pop("lon")
    alt = chosen.pop("alt", None)
    t, ia, ib = np.intersect1d(lat.t, lon.t, return_indices=True)
    la, lo = lat.values[ia], lon.values[ib]
    if config.origin is not None:
        origin = config.origin
    else:
        h0 = float(np.interp(t[0], alt.t, alt.values)) if alt is not None and alt.t.size else 0.0
        origin = (float(la[0]), float(lo[0]), h0)
    n, e, _d = pymap3d.geodetic2ned(la, lo, np.full(la.size, origin[2]), *origin)
    chosen["north"] = Stream("north", t, np.asarray(n, float), source=lat.source,
                             notes=dict(lat.notes)).clean()
    chosen["east"] = Stream("east", t, np.asarray(e, float), source=lat.source).clean()
    notes["origin"] = [float(x) for x in origin]
    notes["origin_source"] = "configuration" if config.origin is not None else "first fix"
    return origin


def ingest(
    paths: str | Path | Sequence[str | Path],
    dt: float,
    *,
    config: str | Path | None = None,
    origin: Sequence[float] | None = None,
    max_gap: float | None = None,
    min_duration: float | None = None,
    sample_rate: float | None = None,
) -> Any:
    """Turn raw sensor files into a :class:`~vesselid.data.logs.TrialLog`.

    Parameters
    ----------
    paths : path or sequence of paths
        Directories (every NMEA file ``*.nmea|*.txt|*.log``, mapped CSV, ROS 2 bag and
        spec TOML in them; ``ingest.toml`` is the configuration) and/or files.
    dt : float
        Sample time of the output grid (s).
    config : path, optional
        Ingest configuration TOML (:mod:`vesselid.data.ingest.config`); default ``ingest.toml``
        in the first directory that has one.
    origin : (lat, lon[, h]), optional
        Local NED origin, overriding the configuration.
    max_gap, min_duration : float, optional
        Override the configuration (s).
    sample_rate : float, optional
        The logger's sample rate (Hz) of every mapped table: a time column with
        duplicated (quantised) timestamps is rebuilt from it; without it such a table
        is refused.

    Returns
    -------
    TrialLog
        Columns ``experiment, time`` (s from the first sample), ``u, v, r`` (body frame),
        ``psi`` (unwrapped heading, rad), ``north, east`` (m), speed log and wind columns when
        measured, and every mapped CSV/bag channel (inputs). ``metadata["quality"]`` holds the
        quality report; a spec TOML found among the inputs is attached when its columns are
        all present.

    Raises
    ------
    IngestError
        Nothing usable, a required channel missing (the reason names the channel and
        why), no stretch of data long enough, a quantised time column without a stated
        sample rate, an optional package missing (the extra to install).
    """
    if isinstance(paths, str | Path):
        paths = [paths]
    if not paths:
        raise IngestError("no input files given")
    dt = float(dt)
    if not (math.isfinite(dt) and dt > 0):
        raise IngestError(f"--dt must be a positive number of seconds, got {dt}")
    cfg, cfg_file, nmea_files, bags, csv_files, tomls, other = _collect(paths, config)
    if cfg.tank is not None:  # model-test tables: one clock per file, one experiment each
        from vesselid.data.ingest.tank import ingest_tank, tank_format_from_dict

        fmt = tank_format_from_dict(cfg.tank, base=cfg.base)
        log = ingest_tank([*nmea_files, *csv_files, *other], dt, fmt, cfg_file)
        _attach_spec(log, tomls)
        return log
    if origin is not None or max_gap is not None or min_duration is not None:
        from dataclasses import replace

        org = cfg.origin
        if origin is not None:
            o = [float(x) for x in origin]
            if len(o) not in (2, 3):
                raise IngestError(f"--origin needs LAT,LON[,H], got {origin!r}")
            if not (all(math.isfinite(x) for x in o) and -90 < o[0] < 90
                    and -180 <= o[1] <= 180):
                raise IngestError(f"--origin latitude/longitude out of range or not finite: "
                                  f"{origin!r} (need -90 < lat < 90, -180 <= lon <= 180)")
            org = (o[0], o[1], o[2] if len(o) == 3 else 0.0)
        cfg = replace(cfg, origin=org,
                      max_gap=cfg.max_gap if max_gap is None else float(max_gap),
                      min_duration=cfg.min_duration if min_duration is None
                      else float(min_duration))
        if not (math.isfinite(cfg.max_gap) and cfg.max_gap > 0):
            raise IngestError(f"--max-gap must be a positive number of seconds, got "
                              f"{cfg.max_gap}")
        if not (math.isfinite(cfg.min_duration) and cfg.min_duration >= 0):
            raise IngestError(f"--min-duration must be a non-negative number of seconds, got "
                              f"{cfg.min_duration}")
    if sample_rate is not None:
        sample_rate = float(sample_rate)
        if not (math.isfinite(sample_rate) and sample_rate > 0):
            raise IngestError(f"--sample-rate must be a positive rate in Hz, got {sample_rate}")
    _check_sizes([*nmea_files, *csv_files])
    if nmea_files:
        require("nmea", f"reading NMEA 0183 ({nmea_files[0].name})")
    if bags:
        require("bag", f"reading ROS bags ({bags[0].name})")
    streams: list[Stream] = []
    sources: list[dict[str, Any]] = []
    for f in nmea_files:
        from vesselid.data.ingest.nmea import read_nmea

        s, q = read_nmea(f, relative_latency=cfg.relative_latency,
                         epoch_tolerance=cfg.epoch_tolerance, options=cfg.nmea)
        streams += s
        sources.append({"type": "nmea0183", **q})
    jobs, unmapped = _csv_jobs(cfg, csv_files)
    for f, m in jobs:
        from vesselid.data.ingest.tables import read_csv_streams

        if sample_rate is not None:
            from dataclasses import replace

            m = replace(m, sample_rate=sample_rate)
        s, q = read_csv_streams(f, m)
        streams += s
        sources.append({"type": "csv", "kind": m.kind, **q})
    for b in bags:
        from vesselid.data.ingest.rosbag import read_bag

        s, q = read_bag(b, cfg.ros)
        streams += s
        sources.append({"type": q.get("format", "ros2bag"), **q})
    if not streams:
        what = "no NMEA 0183 file, ROS bag or mapped CSV file"
        extra = f" (unmapped CSV files: {unmapped}; add a [[csv]] table)" if unmapped else ""
        raise IngestError(f"{what} among the inputs{extra}")
    notes: dict[str, Any] = {}
    chosen, unused = _choose(streams)
    gnss_position = "lat" in chosen and "lon" in chosen
    _ned(chosen, cfg, notes)
    chosen.pop("alt", None)
    body_direct = "u" in chosen and "v" in chosen
    if not body_direct:
        if "vel_north" not in chosen:
            raise IngestError(
                "no velocity: need speed/course over ground (RMC/VTG), odometry twist or mapped "
                "'u'/'v' columns; " + _why_missing(("RMC", "VTG"), sources, chosen, unused,
                                                   ("vel_north",)))
        if "psi" not in chosen:
            raise IngestError(
                "no heading (HDT/THS, HDG/HDM with a magnetic variation, odometry orientation "
                "or a mapped 'psi' column): earth-frame velocities cannot be rotated into "
                "body-frame surge/sway; " + _why_missing(("HDT", "THS", "HDG", "HDM"), sources,
                                                         chosen, unused, ("psi",)))
    if "psi" in chosen and cfg.heading_offset:
        p = chosen["psi"]
        chosen["psi"] = Stream(p.name, p.t, p.values - math.radians(cfg.heading_offset),
                               kind=p.kind, source=p.source, priority=p.priority,
                               notes={**p.notes, "heading_offset_deg": cfg.heading_offset})
        notes["heading_offset_deg"] = cfg.heading_offset
    used = dict(chosen)
    if body_direct:
        for c in ("vel_north", "vel_east"):
            used.pop(c, None)
    grid_info = _grid(used, dt, cfg)
    segments = grid_info["segments"]
    if not segments:
        raise IngestError(grid_info["reason"])
    t0 = segments[0][0] * dt
    cols: dict[str, list[np.ndarray]] = {}
    info: dict[str, dict[str, Any]] = {name: {"bridged": 0} for name in used}
    exp_col, time_col = [], []
    for e, (k0, k1) in enumerate(segments):
        ks = np.arange(k0, k1 + 1)
        grid = ks * dt
        exp_col.append(np.full(grid.size, e, dtype=np.int64))
        time_col.append((ks - segments[0][0]) * dt)
        for name, s in used.items():
            vals, inf = resample(s, grid, dt)
            cols.setdefault(name, []).append(vals)
            info[name]["bridged"] += inf["bridged"]
            info[name]["method"] = inf["method"]
    data: dict[str, np.ndarray] = {"experiment": np.concatenate(exp_col),
                                   "time": np.concatenate(time_col)}
    arrays = {k: np.concatenate(v) for k, v in cols.items()}
    derived: dict[str, str] = {}
    if not body_direct:
        psi = arrays["psi"]
        vn, ve = arrays.pop("vel_north"), arrays.pop("vel_east")
        c, s_ = np.cos(psi), np.sin(psi)
        arrays["u"] = c * vn + s_ * ve
        arrays["v"] = -s_ * vn + c * ve
        derived["u"] = derived["v"] = "earth-frame velocity over ground rotated by the heading"
    if "r" not in arrays and "psi" in arrays:
        r = np.empty_like(arrays["psi"])
        for e in range(len(segments)):
            m = data["experiment"] == e
            r[m] = np.gradient(arrays["psi"][m], dt) if m.sum() > 1 else 0.0
        arrays["r"] = r
        derived["r"] = "derivative of the unwrapped heading (no rate-of-turn sensor or gyro)"
    if any(cfg.lever_arm[:2]):
        x, y = cfg.lever_arm[0], cfg.lever_arm[1]
        moved = []
        if "psi" not in arrays:
            raise IngestError("lever_arm needs a heading (psi) to move the antenna's position "
                              "and velocity to the reference point")
        psi = arrays["psi"]
        if gnss_position and "north" in arrays:
            arrays["north"] = arrays["north"] - (np.cos(psi) * x - np.sin(psi) * y)
            arrays["east"] = arrays["east"] - (np.sin(psi) * x + np.cos(psi) * y)
            moved.append("north/east")
        if not body_direct:
            arrays["u"] = arrays["u"] + arrays["r"] * y
            arrays["v"] = arrays["v"] - arrays["r"] * x
            moved.append("u/v")
            derived["u"] = derived["v"] = (derived["u"] + ", moved from the antenna to the "
                                           "reference point (lever arm)")
        notes["lever_arm_m"] = list(cfg.lever_arm)
        notes["lever_arm_applied_to"] = moved
    if "wind_angle" in arrays:
        arrays["wind_angle"] = np.mod(arrays["wind_angle"] + math.pi, 2 * math.pi) - math.pi
    order = [c for c in _ORDER if c in arrays] + sorted(c for c in arrays if c not in _ORDER)
    for c in order:
        data[c] = arrays[c]
    frame = pd.DataFrame(data)
    n_rows = len(frame)
    columns_q: dict[str, Any] = {}
    for name, s in used.items():
        q = stream_quality(s)
        q["resampling"] = info[name].get("method")
        q["interpolated_fraction"] = info[name]["bridged"] / n_rows if n_rows else 0.0
        columns_q[name] = q
    for c, why in derived.items():
        columns_q[c] = {"derived": why}
    quality = {
        "dt": dt,
        "rows": n_rows,
        "experiments": [{"experiment": e, "start_utc": _iso(k0 * dt), "rows": int(k1 - k0 + 1)}
                        for e, (k0, k1) in enumerate(segments)],
        "dropped_segments": grid_info["dropped"],
        "grid_coverage": grid_info["coverage"],
        "input_span_s": float(max(v.t[-1] for v in used.values())
                              - min(v.t[0] for v in used.values())),
        "kept_s": float(sum((k1 - k0) * dt for k0, k1 in segments)),
        "columns": columns_q,
        "sources": sources,
        "unused_sources": unused,
        "unmapped_files": unmapped + [str(o) for o in other],
        **notes,
    }
    from vesselid import __version__
    from vesselid.data.logs import TrialLog

    meta: dict[str, Any] = {
        "source": "vesselid ingest",
        "inputs": [str(p) for p in paths],
        "config": str(cfg_file) if cfg_file is not None else None,
        "dt": dt,
        "time_origin_utc": _iso(t0),
        "time_origin_unix": t0,
        "quality": quality,
        "vesselid_version": __version__,
    }
    log = TrialLog(frame, _jsonable(meta))
    _attach_spec(log, tomls)
    return log


def _attach_spec(log: Any, tomls: list[Path]) -> None:
    """Attach the first spec TOML among the inputs whose columns the log has."""
    spec, spec_path = _find_spec(tomls)
    if spec is not None:
        if all(c in log.data.columns for c in spec.measured_columns):
            log.metadata["spec"] = spec.to_dict()
            log.metadata["spec_file"] = str(spec_path)


def _why_missing(kinds: tuple[str, ...], sources: list[dict[str, Any]],
                 chosen: dict[str, Stream], unused: dict[str, list[str]],
                 channels: tuple[str, ...]) -> str:
    """Why no stream of ``channels``: the sentences seen and why they gave no samples."""
    reasons = []
    seen: dict[str, int] = {}
    for src in sources:
        for k, why in src.get("unusable", {}).items():
            if k in kinds:
                reasons.append(why)
        for k, tk in src.get("talkers", {}).items():
            seen[k] = seen.get(k, 0) + sum(tk.values())
        for k, c in src.get("unsupported", {}).items():
            seen[k] = seen.get(k, 0) + c
    if not reasons:
        for ch in channels:
            reasons += [f"{s} gave no samples" for s in unused.get(ch, []) if "no valid" in s]
    if not reasons:
        absent = [k for k in kinds if k not in seen]
        reasons.append(f"no {'/'.join(absent) or '/'.join(kinds)} sentences")
    found = ", ".join(f"{c} {k}" for k, c in sorted(seen.items(), key=lambda kv: -kv[1]))
    return ("; ".join(dict.fromkeys(reasons)) + f" (channels found: {sorted(chosen)}"
            + (f"; sentences: {found}" if found else "") + ")")


def _check_sizes(files: list[Path]) -> None:
    try:
        from vesselid.core import limits
    except ImportError:
        return
    check = getattr(limits, "check_file_size", None)
    if check is None:
        return
    for f in files:
        check(f)


def _grid(used: dict[str, Stream], dt: float, cfg: IngestConfig) -> dict[str, Any]:
    empty = sorted(n for n, s in used.items() if s.t.size == 0)
    if empty:
        return {"segments": [], "dropped": [], "coverage": {},
                "reason": f"no valid samples in channel(s) {empty}"}
    lo = max(s.t[0] for s in used.values())
    hi = min(s.t[-1] for s in used.values())
    names = sorted(used)
    if not hi > lo:
        spans = {n: [_iso(used[n].t[0]), _iso(used[n].t[-1])] for n in names}
        return {"segments": [], "dropped": [], "coverage": {},
                "reason": f"the channels do not overlap in time: {spans}"}
    span = (hi - lo) / dt
    if not math.isfinite(span) or span + 1 > MAX_GRID:
        return {"segments": [], "dropped": [], "coverage": {},
                "reason": f"the common time span ({(hi - lo) / 3600:.1f} h) is too long for "
                          f"dt={dt} (more than {MAX_GRID} samples); check the clocks"}
    k0 = math.floor(lo / dt - 0.5)
    k1 = math.ceil(hi / dt + 0.5)
    if k1 - k0 > MAX_GRID:
        return {"segments": [], "dropped": [], "coverage": {},
                "reason": f"the common time span ({(hi - lo) / 3600:.1f} h) is too long for "
                          f"dt={dt} (more than {MAX_GRID} samples); check the clocks"}
    from vesselid.core import limits

    limits.check_grid("ingest", k1 - k0 + 1, len(names))  # before allocating the grid
    ks = np.arange(k0, k1 + 1)
    grid = ks * dt
    ok = np.ones(ks.size, dtype=bool)
    cov: dict[str, float] = {}
    for n in names:
        c = coverage(used[n], grid, cfg.max_gap)
        cov[n] = float(c.mean())
        ok &= c
    # maximal runs of consecutive good grid points
    d = np.diff(np.concatenate([[0], ok.astype(np.int8), [0]]))
    starts = np.flatnonzero(d == 1)
    ends = np.flatnonzero(d == -1) - 1
    min_n = max(2, math.ceil(cfg.min_duration / dt))
    segments, dropped = [], []
    for a, b in zip(starts, ends, strict=True):
        if b - a + 1 >= min_n:
            segments.append((int(ks[a]), int(ks[b])))
        else:
            dropped.append({"start_utc": _iso(ks[a] * dt), "rows": int(b - a + 1)})
    reason = ""
    if not segments:
        longest = int((ends - starts + 1).max()) if starts.size else 0
        worst = min(cov, key=cov.get) if cov else "?"
        reason = (f"no stretch of at least {cfg.min_duration:g} s where every channel has data "
                  f"(longest {longest * dt:g} s; least covered channel {worst!r}: "
                  f"{100 * cov.get(worst, 0):.0f} % of the common span)")
    return {"segments": segments, "dropped": dropped, "coverage": cov, "reason": reason}


def _iso(unix: float) -> str:
    return pd.Timestamp(unix, unit="s", tz="UTC").isoformat()


def _jsonable(obj: Any) -> Any:
    if isinstance(obj, dict):
        return {str(k): _jsonable(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [_jsonable(v) for v in obj]
    if isinstance(obj, np.generic):
        obj = obj.item()
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    return obj
