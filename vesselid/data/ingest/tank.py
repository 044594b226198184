"""Model-test (towing tank, free-running model) tables → a trial log, one experiment per file.

A tank or sea-trial table holds every channel of one run on one clock, one row per
sample: whitespace-separated ``.dat`` files with a few header lines (the SIMMAN 2008
KVLCC2/KCS/5415 files of HSVA, MARIN, CEHIPAR, ...) or CSV. The ``[tank]`` table of the
ingest configuration (:mod:`vesselid.data.ingest.config`) says how to read them::

    [tank]
    files = "raw_data/*.dat"          # glob(s) relative to ingest.toml (default: every input)
    delimiter = "whitespace"          # whitespace | comma | semicolon | tab
    header_lines = 4                  # lines before the data (0: a CSV header row)
    encoding = "latin-1"              # text encoding of the header lines
    names = ["time", "x0", "y0", "psi", "u", "v", "r", "p", "delta", "rev", "thrust", "torque"]
    angle_unit = "deg"                # deg | rad: unit of the angle channels below
    angles = ["psi", "r", "delta"]    # channels converted to rad (rad/s); default: the angle
                                      # and rate channels that are mapped
    velocity_frame = "earth"          # earth: (u, v) are north/east velocities, rotated into
                                      # the body frame with the heading; body: as they are
    scale = 45.7                      # model scale λ (optional)
    full_scale = true                 # Froude-scale every channel to full scale (needs scale)
    yaw_rate_tolerance = 0.25         # max ‖r − dψ/dt‖ / ‖dψ/dt‖ before ingest refuses
    sample_time = 0.05                # optional: rebuild the time axis as k·sample_time
                                      # (a quantised or missing time column)

    [tank.columns]                    # channel = column name (or {column, scale, offset, kind})
    time = "time"
    north = "x0"
    east = "y0"
    psi = "psi"
    u = "u"
    v = "v"
    r = "r"
    delta = "delta"
    n = { column = "rev", kind = "rate" }

Every file becomes one experiment, named by the file's stem. The steps, in order:

1. columns mapped, ``x · scale + offset`` per column; angles (``angle_unit = "deg"``)
   converted to radians;
2. the yaw rate checked against the derivative of the unwrapped heading (both mapped):
   a mislabelled column, a wrong unit or a sign error is refused with one line that names
   the column (and the column that would match, if one does);
3. earth-fixed velocities rotated into the body frame,
   ``u = cos ψ v_N + sin ψ v_E``, ``v = −sin ψ v_N + cos ψ v_E``;
4. optional Froude scaling to full scale with ``λ = scale`` (:data:`FROUDE_EXPONENTS`:
   length ``λ``, time ``√λ``, velocity ``√λ``, angular rate and propeller rate ``1/√λ``,
   force ``λ³``, moment ``λ⁴``; angles unchanged; equal water density assumed);
5. resampled onto ``t_k = k·dt`` from the file's first sample when ``dt`` differs from the
   file's own sample time (anti-aliased decimation or interpolation,
   :func:`vesselid.data.ingest.streams.resample`); rows pass unchanged when it agrees.

The quality report (``metadata["quality"]``) records per file the rows, the sample time,
the yaw-rate check and every conversion applied.
"""

from __future__ import annotations

import glob
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from vesselid.data.ingest.config import IngestError
from vesselid.data.ingest.config import _num as config_number

__all__ = ["FROUDE_EXPONENTS", "TankColumn", "TankFormat", "ingest_tank", "load_tank_format",
           "read_tank_file", "tank_format_from_dict"]

#: Exponent ``e`` of the Froude scale factor ``λ^e`` per physical kind of channel.
FROUDE_EXPONENTS: dict[str, float] = {
    "time": 0.5, "length": 1.0, "velocity": 0.5, "rate": -0.5, "angle": 0.0,
    "force": 3.0, "moment": 4.0, "none": 0.0,
}

#: Kind of the canonical channels (a mapped column may state its own ``kind``).
_DEFAULT_KINDS: dict[str, str] = {
    "time": "time", "north": "length", "east": "length", "x": "length", "y": "length",
    "u": "velocity", "v": "velocity", "w": "velocity", "U": "velocity",
    "r": "rate", "p": "rate", "q": "rate", "n": "rate", "rev": "rate", "rps": "rate",
    "psi": "angle", "phi": "angle", "theta": "angle", "delta": "angle", "beta": "angle",
    "X": "force", "Y": "force", "Z": "force", "thrust": "force",
    "N": "moment", "K": "moment", "M": "moment", "torque": "moment",
}
#: Channels taken as angles (or angular rates) when ``angles`` is not given.
_ANGLE_DEFAULT = ("psi", "phi", "theta", "delta", "beta", "r", "p", "q")
_DELIMITERS = {"whitespace": r"\s+", "comma": ",", "semicolon": ";", "tab": "\t"}
_ORDER = ("u", "v", "r", "psi", "north", "east")


@dataclass(frozen=True)
class TankColumn:
    """One mapped column: ``channel = column · scale + offset`` of Froude ``kind``."""

    column: str
    scale: float = 1.0
    offset: float = 0.0
    kind: str | None = None


@dataclass(frozen=True)
class TankFormat:
    """How to read a family of model-test tables (the ``[tank]`` table; module docstring).

    Parameters
    ----------
    columns : dict of channel -> TankColumn
        Must map ``time``; ``psi`` is needed for earth-fixed velocities and the yaw-rate
        check.
    files : tuple of str
        Globs relative to ``base`` (empty: every input file).
    delimiter, header_lines, encoding, names
        Table layout (``names``: column names when the file has no header row).
    angle_unit : {"deg", "rad"}
    angles : tuple of str or None
        Channels in ``angle_unit`` (angles and angular rates); ``None``: the mapped
        channels among ``psi, phi, theta, delta, beta, r, p, q``.
    velocity_frame : {"earth", "body"}
    scale : float or None
        Model scale λ.
    full_scale : bool
        Froude-scale the channels to full scale.
    yaw_rate_tolerance : float
        Largest accepted ``‖r − dψ/dt‖ / ‖dψ/dt‖``.
    sample_time : float or None
        When given, the time axis is rebuilt as ``k · sample_time`` (s, model scale) and a
        mapped time column is only checked for order, never used.
    base : Path
        Directory the globs are relative to.
    """

    columns: dict[str, TankColumn]
    files: tuple[str, ...] = ()
    delimiter: str = "whitespace"
    header_lines: int = 0
    encoding: str = "utf-8"
    names: tuple[str, ...] | None = None
    angle_unit: str = "rad"
    angles: tuple[str, ...] | None = None
    velocity_frame: str = "body"
    scale: float | None = None
    full_scale: bool = False
    yaw_rate_tolerance: float = 0.25
    sample_time: float | None = None
    base: Path = field(default=Path("."))

    def angle_channels(self) -> tuple[str, ...]:
        """Mapped channels converted from ``angle_unit`` to radians."""
        if self.angle_unit == "rad":
            return ()
        if self.angles is not None:
            return tuple(self.angles)
        return tuple(c for c in _ANGLE_DEFAULT if c in self.columns)

    def kind(self, channel: str) -> str | None:
        col = self.columns.get(channel)
        if col is not None and col.kind is not None:
            return col.kind
        return _DEFAULT_KINDS.get(channel)


def _num(value: Any, what: str) -> float:
    if isinstance(value, bool):
        raise IngestError(f"[tank] {what} must be a number, got {value!r}")
    return config_number(value, f"[tank] {what}")


def _names(value: Any, what: str) -> tuple[str, ...]:
    if isinstance(value, str):
        value = [value]
    if not isinstance(value, list | tuple) or not all(isinstance(v, str) for v in value):
        raise IngestError(f"[tank] {what} must be a list of names, got {value!r}")
    return tuple(value)


def tank_format_from_dict(data: dict[str, Any], base: Path = Path(".")) -> TankFormat:
    """Validate a parsed ``[tank]`` table (every bad entry: one line naming the key)."""
    if not isinstance(data, dict):
        raise IngestError("[tank] must be a table")
    known = {"files", "delimiter", "header_lines", "encoding", "names", "angle_unit", "angles",
             "velocity_frame", "scale", "full_scale", "yaw_rate_tolerance", "sample_time",
             "columns"}
    unknown = sorted(set(data) - known)
    if unknown:
        raise IngestError(f"unknown [tank] keys {unknown}; known: {sorted(known)}")
    raw_cols = data.get("columns")
    if not isinstance(raw_cols, dict) or not raw_cols:
        raise IngestError("[tank] needs a [tank.columns] table mapping channels to columns")
    columns: dict[str, TankColumn] = {}
    for name, raw in raw_cols.items():
        if isinstance(raw, str):
            columns[name] = TankColumn(raw)
        elif isinstance(raw, dict) and isinstance(raw.get("column"), str):
            extra = sorted(set(raw) - {"column", "scale", "offset", "kind"})
            if extra:
                raise IngestError(f"[tank.columns] {name}: unknown keys {extra}")
            kind = raw.get("kind")
            if kind is not None and kind not in FROUDE_EXPONENTS:
                raise IngestError(f"[tank.columns] {name}.kind must be one of "
                                  f"{sorted(FROUDE_EXPONENTS)}, got {kind!r}")
            columns[name] = TankColumn(raw["column"], _num(raw.get("scale", 1.0),
                                                           f"columns.{name}.scale"),
                                       _num(raw.get("offset", 0.0), f"columns.{name}.offset"),
                                       kind)
        else:
            raise IngestError(f"[tank.columns] {name} must be a column name or "
                              f"{{column = ..., scale = ..., offset = ..., kind = ...}}, "
                              f"got {raw!r}")
    st = data.get("sample_time")
    if st is not None:
        st = _num(st, "sample_time")
        if st <= 0:
            raise IngestError(f"[tank] sample_time must be positive, got {st}")
    if "time" not in columns and st is None:
        raise IngestError("[tank.columns] must map 'time' (the time column), or give "
                          "[tank] sample_time = seconds to build the time axis")
    delimiter = str(data.get("delimiter", "whitespace"))
    if delimiter not in _DELIMITERS:
        raise IngestError(f"[tank] delimiter must be one of {sorted(_DELIMITERS)}, "
                          f"got {delimiter!r}")
    header = data.get("header_lines", 0)
    if isinstance(header, bool) or not isinstance(header, int) or header < 0:
        raise IngestError(f"[tank] header_lines must be a non-negative integer, got {header!r}")
    unit = str(data.get("angle_unit", "rad"))
    if unit not in ("deg", "rad"):
        raise IngestError(f"[tank] angle_unit must be 'deg' or 'rad', got {unit!r}")
    frame = str(data.get("velocity_frame", "body"))
    if frame not in ("earth", "body"):
        raise IngestError(f"[tank] velocity_frame must be 'earth' or 'body', got {frame!r}")
    scale = data.get("scale")
    if scale is not None:
        scale = _num(scale, "scale")
        if scale <= 0:
            raise IngestError(f"[tank] scale must be positive, got {scale}")
    full = data.get("full_scale", False)
    if not isinstance(full, bool):
        raise IngestError(f"[tank] full_scale must be true or false, got {full!r}")
    if full and scale is None:
        raise IngestError("[tank] full_scale = true needs scale = λ (the model scale)")
    tol = _num(data.get("yaw_rate_tolerance", 0.25), "yaw_rate_tolerance")
    if tol <= 0:
        raise IngestError(f"[tank] yaw_rate_tolerance must be positive, got {tol}")
    fmt = TankFormat(
        columns=columns,
        files=_names(data.get("files", []), "files"),
        delimiter=delimiter, header_lines=header,
        encoding=str(data.get("encoding", "utf-8")),
        names=_names(data["names"], "names") if "names" in data else None,
        angle_unit=unit,
        angles=_names(data["angles"], "angles") if "angles" in data else None,
        velocity_frame=frame, scale=scale, full_scale=full, yaw_rate_tolerance=tol,
        sample_time=st, base=base)
    if frame == "earth" and not {"u", "v", "psi"} <= set(columns):
        raise IngestError("[tank] velocity_frame = 'earth' needs u, v and psi mapped (the "
                          "heading rotates the velocities into the body frame)")
    if full:
        missing = sorted(c for c in columns if fmt.kind(c) is None)
        if missing:
            raise IngestError(f"[tank] full_scale: channel(s) {missing} have no Froude kind; "
                              f"give kind = one of {sorted(FROUDE_EXPONENTS)} in "
                              f"[tank.columns]")
    return fmt


def load_tank_format(path: str | Path) -> TankFormat:
    """The ``[tank]`` table of an ingest configuration file as a :class:`TankFormat`
    (e.g. ``vesselid.model.specs.path("kvlcc2_hsva_ingest")``)."""
    from vesselid.data.ingest.config import load_config

    cfg = load_config(path)
    if cfg.tank is None:
        raise IngestError(f"{path}: no [tank] table")
    return tank_format_from_dict(cfg.tank, base=cfg.base)


def _read_table(path: Path, fmt: TankFormat) -> pd.DataFrame:
    try:
        frame = pd.read_csv(
            path, sep=_DELIMITERS[fmt.delimiter], skiprows=fmt.header_lines,
            header=None if fmt.names is not None else 0,
            names=list(fmt.names) if fmt.names is not None else None,
            encoding=fmt.encoding, engine="python" if fmt.delimiter == "whitespace" else "c",
            skipinitialspace=True, index_col=False)
    except (OSError, pd.errors.ParserError, pd.errors.EmptyDataError, UnicodeDecodeError,
            LookupError) as exc:
        raise IngestError(f"cannot read table {path}: {str(exc).splitlines()[0]}") from exc
    frame.columns = [str(c).strip() for c in frame.columns]
    if fmt.names is not None and frame.shape[1] != len(fmt.names):  # pragma: no cover
        raise IngestError(f"{path.name}: {frame.shape[1]} columns, [tank] names has "
                          f"{len(fmt.names)}")
    return frame


def _numeric(frame: pd.DataFrame, column: str, path: Path) -> np.ndarray:
    x = pd.to_numeric(frame[column], errors="coerce").to_numpy(dtype=float)
    bad = np.flatnonzero(~np.isfinite(x))
    if bad.size:
        raise IngestError(f"{path.name}: column {column!r} has {bad.size} non-numeric or "
                          f"missing value(s), first at data row {int(bad[0]) + 1}")
    return x


def _relative_misfit(rate: np.ndarray, psi_dot: np.ndarray) -> float:
    den = float(np.linalg.norm(psi_dot))
    return float(np.linalg.norm(rate - psi_dot) / den) if den > 0 else math.inf


def _check_yaw_rate(values: dict[str, np.ndarray], t: np.ndarray, fmt: TankFormat,
                    frame: pd.DataFrame, path: Path) -> dict[str, Any]:
    """Compare ``r`` with ``dψ/dt``; refuse with one line naming the column otherwise."""
    if "r" not in values or "psi" not in values:
        return {"checked": False, "why": "r or psi not mapped"}
    psi_dot = np.gradient(np.unwrap(values["psi"]), t)
    if float(np.sqrt(np.mean(psi_dot ** 2))) < 1e-4:  # rad/s: the heading hardly moves
        return {"checked": False, "why": "the heading hardly changes (rms dψ/dt < 1e-4 rad/s)"}
    misfit = _relative_misfit(values["r"], psi_dot)
    out = {"checked": True, "relative_misfit": misfit, "tolerance": fmt.yaw_rate_tolerance}
    if misfit <= fmt.yaw_rate_tolerance:
        return out
    col = fmt.columns["r"]
    unit = np.pi / 180 if "r" in fmt.angle_channels() else 1.0
    best, best_fit = None, math.inf
    for name in frame.columns:
        if name == col.column:
            continue
        x = pd.to_numeric(frame[name], errors="coerce").to_numpy(dtype=float)
        if not np.all(np.isfinite(x)):
            continue
        m = _relative_misfit((x * col.scale + col.offset) * unit, psi_dot)
        if m < best_fit:
            best, best_fit = name, m
    hint = (f"; column {best!r} matches (misfit {best_fit:.2f}): map r to it"
            if best is not None and best_fit <= fmt.yaw_rate_tolerance else
            f"; check the column, its unit (angle_unit = {fmt.angle_unit!r}) and its sign")
    raise IngestError(
        f"{path.name}: yaw rate r (column {col.column!r}) disagrees with the derivative of the "
        f"heading psi (column {fmt.columns['psi'].column!r}): ‖r − dψ/dt‖/‖dψ/dt‖ = "
        f"{misfit:.2f} > yaw_rate_tolerance {fmt.yaw_rate_tolerance:g}{hint}")


def read_tank_file(path: str | Path, fmt: TankFormat, dt: float | None = None
                   ) -> tuple[pd.DataFrame, dict[str, Any]]:
    """Read one model-test table into the columns of a trial log (one experiment).

    Parameters
    ----------
    path : path
        The table.
    fmt : TankFormat
        Layout, column map and conversions.
    dt : float, optional
        Output sample time (s, in the output scale); ``None`` keeps the file's rows.

    Returns
    -------
    frame : DataFrame
        ``time`` (s from the first sample) and the mapped channels in SI units, body-frame
        ``u, v`` and unwrapped ``psi`` (rad).
    quality : dict
        File, rows, sample time, yaw-rate check, conversions.

    Raises
    ------
    IngestError
        Unreadable file, a mapped column missing or non-numeric, time not increasing, or a
        yaw rate that disagrees with the heading.
    """
    path = Path(path)
    frame = _read_table(path, fmt)
    missing = [c.column for c in fmt.columns.values() if c.column not in frame.columns]
    if missing:
        raise IngestError(f"{path.name}: columns {missing} of [tank.columns] are not in the "
                          f"file (columns: {list(frame.columns)})")
    if len(frame) < 2:
        raise IngestError(f"{path.name}: fewer than two data rows")
    angles = set(fmt.angle_channels())
    values: dict[str, np.ndarray] = {}
    for name, col in fmt.columns.items():
        x = _numeric(frame, col.column, path) * col.scale + col.offset
        values[name] = np.deg2rad(x) if name in angles else x
    t = values.pop("time", None)
    if fmt.sample_time is not None:
        if t is not None and np.any(np.diff(t) < 0):
            k = int(np.flatnonzero(np.diff(t) < 0)[0])
            raise IngestError(f"{path.name}: time column {fmt.columns['time'].column!r} goes "
                              f"backwards at data row {k + 2}: rows out of order")
        t = np.arange(len(frame)) * fmt.sample_time
    d = np.diff(t)
    if np.any(d <= 0):
        k = int(np.flatnonzero(d <= 0)[0])
        raise IngestError(
            f"{path.name}: time column {fmt.columns['time'].column!r} is not strictly "
            f"increasing at data row {k + 2} ({t[k]!r} then {t[k + 1]!r}); if the table is "
            f"sampled at a fixed rate, state it with [tank] sample_time = seconds to rebuild "
            f"the time axis (no row is dropped)")
    t = t - t[0]
    q: dict[str, Any] = {"file": str(path), "type": "tank", "rows": int(t.size),
                         "dt_file": float(np.median(d)), "conversions": []}
    if angles:
        q["conversions"].append(f"degrees to radians: {sorted(angles & set(fmt.columns))}")
    if "psi" in values:
        values["psi"] = np.unwrap(values["psi"])
    q["yaw_rate_check"] = _check_yaw_rate(values, t, fmt, frame, path)
    if fmt.velocity_frame == "earth":
        psi, vn, ve = values["psi"], values["u"], values["v"]
        c, s = np.cos(psi), np.sin(psi)
        values["u"], values["v"] = c * vn + s * ve, -s * vn + c * ve
        q["conversions"].append("earth-fixed (u, v) rotated into the body frame by psi")
    if fmt.full_scale:
        lam = float(fmt.scale)  # type: ignore[arg-type]
        t = t * lam ** FROUDE_EXPONENTS["time"]
        for name in values:
            e = FROUDE_EXPONENTS[fmt.kind(name) or "none"]
            if e:
                values[name] = values[name] * lam ** e
        q["conversions"].append(f"Froude-scaled to full scale, λ = {lam:g}")
    q["dt_out"] = q["dt_file"] * (math.sqrt(fmt.scale) if fmt.full_scale else 1.0)
    if dt is not None:
        values, t, method = _regrid(values, t, float(dt))
        q["resampling"] = method
        q["dt_out"] = float(dt)
    out = {"time": t}
    for c in [c for c in _ORDER if c in values] + sorted(c for c in values if c not in _ORDER):
        out[c] = values[c]
    return pd.DataFrame(out), q


def _regrid(values: dict[str, np.ndarray], t: np.ndarray, dt: float):
    d = np.diff(t)
    regular = float(np.max(np.abs(d - dt))) <= 1e-6 * dt
    if regular:
        return values, np.arange(t.size) * dt, "none (the file's sample time)"
    from vesselid.data.ingest.streams import Stream, resample

    grid = np.arange(math.floor(t[-1] / dt + 1e-9) + 1) * dt
    out, method = {}, ""
    for name, x in values.items():
        vals, info = resample(Stream(name, t, x, kind="angle" if name == "psi" else "linear"),
                              grid, dt)
        out[name] = vals
        method = info["method"]
    return out, grid, method


def _files(paths: Sequence[Path], fmt: TankFormat) -> list[Path]:
    if fmt.files:
        hits: list[Path] = []
        for pattern in fmt.files:
            found = sorted(Path(x) for x in glob.glob(str(fmt.base / pattern)))
            if not found:
                raise IngestError(f"[tank] files: no file matches {pattern!r} "
                                  f"(relative to {fmt.base})")
            hits += [f for f in found if f not in hits]
        return hits
    return [p for p in paths if p.suffix.lower() != ".toml"]


def ingest_tank(paths: Sequence[str | Path], dt: float, fmt: TankFormat,
                config_file: str | Path | None = None) -> Any:
    """Read model-test tables into one :class:`~vesselid.data.logs.TrialLog`.

    Parameters
    ----------
    paths : sequence of paths
        The table files (used when ``fmt.files`` is empty).
    dt : float
        Sample time of the log (s, in the output scale).
    fmt : TankFormat
        From the ``[tank]`` table of the ingest configuration.
    config_file : path, optional
        Recorded in the metadata.

    Returns
    -------
    TrialLog
        ``experiment`` (the file's stem), ``time`` and the channels of
        :func:`read_tank_file`; ``metadata["quality"]`` per file.
    """
    files = _files([Path(p) for p in paths], fmt)
    if not files:
        raise IngestError("no model-test table among the inputs")
    from vesselid.core import limits

    check = getattr(limits, "check_file_size", None)
    for f in files if check is not None else ():
        check(f)  # a file too large for this machine is refused before it is read
    parts, sources = [], []
    stems = [f.stem for f in files]
    dupes = sorted({s for s in stems if stems.count(s) > 1})
    if dupes:
        raise IngestError(f"two tables share the name(s) {dupes}; experiments are named by "
                          f"the file stem")
    for f in files:
        frame, q = read_tank_file(f, fmt, dt)
        frame.insert(0, "experiment", f.stem)
        parts.append(frame)
        sources.append(q)
    data = pd.concat(parts, ignore_index=True)
    from vesselid import __version__
    from vesselid.data.logs import TrialLog

    meta: dict[str, Any] = {
        "source": "vesselid ingest (model-test tables)",
        "inputs": [str(f) for f in files],
        "config": str(config_file) if config_file is not None else None,
        "dt": float(dt),
        "model_scale": fmt.scale,
        "full_scale": fmt.full_scale,
        "quality": {"dt": float(dt), "rows": len(data), "sources": sources,
                    "experiments": [{"experiment": f.stem, "rows": len(p)}
                                    for f, p in zip(files, parts, strict=True)]},
        "vesselid_version": __version__,
    }
    return TrialLog(data, meta)
