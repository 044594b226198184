"""Timestamped multi-rate CSV files → channel streams, through a column mapping.

Each ``[[csv]]`` table of the ingest configuration (:mod:`vesselid.data.ingest.config`) names a
file, its time column and unit, a clock offset, whether it holds commands (zero-order
hold) or measurements, and which CSV column (scaled and offset) feeds which channel.
Rows with an empty or unparsable value are skipped per column and counted. A quantised
time column (repeated stamps) is refused unless the sample rate is stated, and then
rebuilt (:func:`vesselid.data.ingest.timeaxis.check_time_axis`).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from vesselid.data.ingest.config import ANGLE_CHANNELS, CsvMapping, IngestError
from vesselid.data.ingest.streams import Stream
from vesselid.data.ingest.timeaxis import check_time_axis

__all__ = ["read_csv_streams"]

_UNITS = {"s": 1.0, "ms": 1e-3, "us": 1e-6, "ns": 1e-9}


def _numeric(col: pd.Series) -> np.ndarray:
    """Float values; unparsable entries (a column pandas read as text) become NaN."""
    if pd.api.types.is_numeric_dtype(col.dtype) and not pd.api.types.is_bool_dtype(col.dtype):
        return col.to_numpy(dtype=float, na_value=np.nan)
    return pd.to_numeric(col, errors="coerce").to_numpy(dtype=float)


def _duplicated_header(path: Path) -> list[str]:
    """Names that occur more than once in the header line."""
    import csv

    try:
        with open(path, encoding="utf-8", newline="") as fh:
            header = next(csv.reader(fh, skipinitialspace=True), [])
    except (OSError, UnicodeDecodeError, csv.Error):
        return []  # read_csv reports it
    names = [h.strip() for h in header]
    return sorted({n for n in names if names.count(n) > 1})


def read_csv_streams(path: str | Path, mapping: CsvMapping) -> tuple[list[Stream], dict[str, Any]]:
    """Read one mapped CSV file.

    Returns
    -------
    streams : list of Stream
    quality : dict
        ``rows``, ``bad_time`` (rows without a usable time), ``bad_values`` per channel,
        ``clock_jumps`` (time going backwards), ``time_rebuilt`` (a quantised time column
        rebuilt from ``sample_rate``).

    Raises
    ------
    IngestError
        Unreadable file, a mapped column (or the time column) that is not in the file, or
        a quantised time column without a sample rate.
    """
    path = Path(path)
    try:
        frame = pd.read_csv(path, skipinitialspace=True)
    except (OSError, pd.errors.ParserError, pd.errors.EmptyDataError, UnicodeDecodeError) as exc:
        raise IngestError(f"cannot read CSV {path}: {str(exc).splitlines()[0]}") from exc
    dup = _duplicated_header(path)
    if dup:  # pandas would rename the second one ('x.1') and read the first silently
        raise IngestError(f"{path.name}: CSV header has duplicated column names {dup}")
    need = [mapping.time, *(c.column for c in mapping.columns.values())]
    missing = [c for c in need if c not in frame.columns]
    if missing:
        raise IngestError(f"{path.name}: columns {missing} of the mapping are not in the file "
                          f"(columns: {list(frame.columns)})")
    raw_t = frame[mapping.time]
    if mapping.time_unit == "iso":
        ts = pd.to_datetime(raw_t, errors="coerce", utc=True, format="ISO8601")
        t = ts.to_numpy(dtype="datetime64[ns]").astype(np.int64) / 1e9
        t[ts.isna().to_numpy()] = np.nan
    else:
        t = _numeric(raw_t) * _UNITS[mapping.time_unit]
    t = t - mapping.clock_offset
    t, rebuilt = check_time_axis(t, path.name, mapping.sample_rate)
    q: dict[str, Any] = {"file": str(path), "rows": len(frame),
                         "bad_time": int((~np.isfinite(t)).sum()), **rebuilt}
    ft = t[np.isfinite(t)]
    if ft.size == 0 and len(frame):
        raise IngestError(f"{path.name}: no row has a usable time in column {mapping.time!r} "
                          f"(time_unit = {mapping.time_unit!r}; first value "
                          f"{str(raw_t.iloc[0])!r})")
    q["clock_jumps"] = int(np.sum(np.diff(ft) < 0)) if ft.size > 1 else 0
    kind = "hold" if mapping.kind == "command" else "linear"
    streams = []
    bad: dict[str, int] = {}
    for name, col in mapping.columns.items():
        x = _numeric(frame[col.column])
        x = x * col.scale + col.offset
        nbad = int((~np.isfinite(x) & np.isfinite(t)).sum())
        if nbad:
            bad[name] = nbad
        k = "angle" if name in ANGLE_CHANNELS and kind != "hold" else kind
        streams.append(Stream(name, t, x, kind=k, source=f"{path.name}:{col.column}").clean())
    q["bad_values"] = bad
    return streams, q
