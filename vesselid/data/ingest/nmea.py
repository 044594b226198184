"""NMEA 0183 files → channel streams, with per-sentence quality counts.

Supported sentences (any talker): GGA, RMC, GLL (position, time of fix; RMC also
speed/course over ground), ZDA (UTC date and time), VTG (speed/course over ground), HDT and
THS (true heading), HDG and HDM (magnetic heading, made true with the variation and
deviation of the sentence, else of ``[nmea]`` in the ingest configuration, else RMC's
variation), ROT (rate of turn), RSA (rudder angle), RPM (shaft/engine speed), XDR
(transducers, read by the names mapped in ``[nmea] xdr``), VHW (speed through water), VBW
(dual-axis water speed), MWV (apparent wind). Lines may
carry a receive time as an IEC 61162-450 TAG block (``\\c:<unix s or ms>*hh\\``) or as a
leading UNIX time or ISO 8601 stamp (``1780308000.123 $GPGGA,...``).

Clocks. GGA and RMC carry the UTC time of validity of the fix. Their receive times give
the logger clock offset (receive − fix, i.e. logger offset plus GNSS latency), estimated
as the median over runs of consecutive sentences; a change of more than 0.5 s is a clock
jump, counted, and starts a new run. ZDA, GLL and GGA without a date take the date of the
nearest RMC/ZDA, else of the receive time. Untimed sentences (HDT, HDG, ROT, VTG, VHW,
...) get ``receive time − offset of the run − relative latency`` (``[relative_latency]``
in the ingest configuration: the sensor's latency minus the GNSS receiver's). Without
receive times, an untimed sentence takes the time of the last timed sentence before it
(one burst per epoch); where a sentence type comes several times between two timed
sentences, its sentences are spread evenly over that interval and counted as
``time_interpolated``. A file with neither a timed sentence nor receive times is refused
("no time source").

Headings in whole degrees (typical of magnetic compasses) are detected and reported
(``quantisation_deg`` with the equivalent noise standard deviation ``q/√12``).

Speed. Parsing is vectorised over the file's bytes (:func:`_scan`): checksums from one
cumulative XOR, talker and formatter by byte gathers, and the fields of each sentence type
are split by :func:`pandas.read_csv` in one call. pynmea2 supplies the field layout
(:func:`vesselid.data.nmea0183.field_index`) and is the reference the tests compare against; calling
``pynmea2.parse`` per line costs ~25-40 µs (25-40 s per
10⁶ sentences), far over the 10 s budget.
"""

from __future__ import annotations

import io
import math
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from vesselid.data.ingest.config import IngestError, NmeaOptions
from vesselid.data.ingest.streams import Stream
from vesselid.data.nmea0183 import KNOT, field_index

__all__ = ["NmeaError", "read_nmea"]

MAX_LINE = 255
_HEXVAL = np.full(256, -1, dtype=np.int16)
for _i, _c in enumerate(b"0123456789ABCDEF"):
    _HEXVAL[_c] = _i
for _i, _c in enumerate(b"abcdef"):
    _HEXVAL[_c] = 10 + _i

TIMED = ("GGA", "RMC", "ZDA", "GLL")
DATED = ("RMC", "ZDA")
SUPPORTED = ("GGA", "RMC", "ZDA", "GLL", "VTG", "HDT", "THS", "HDG", "HDM", "ROT", "RSA", "RPM",
             "XDR", "VHW", "VBW", "MWV")
#: Most XDR quadruplets (type, value, unit, name) read from one sentence.
XDR_MAX = 10


class NmeaError(IngestError):
    """An NMEA file that cannot be used at all."""


def _fields(kind: str) -> tuple[int, int, dict[str, int]]:
    """(min fields, max fields, name -> index) of a sentence type."""
    fi = field_index
    if kind == "GGA":
        return 9, 15, {"time": fi("GGA", "timestamp"), "lat": fi("GGA", "lat"),
                       "lat_dir": fi("GGA", "lat_dir"), "lon": fi("GGA", "lon"),
                       "lon_dir": fi("GGA", "lon_dir"), "qual": fi("GGA", "gps_qual"),
                       "alt": fi("GGA", "altitude")}
    if kind == "RMC":
        return 9, 14, {"time": fi("RMC", "timestamp"), "status": fi("RMC", "status"),
                       "var": fi("RMC", "mag_variation"), "var_dir": fi("RMC", "mag_var_dir"),
                       "lat": fi("RMC", "lat"), "lat_dir": fi("RMC", "lat_dir"),
                       "lon": fi("RMC", "lon"), "lon_dir": fi("RMC", "lon_dir"),
                       "sog": fi("RMC", "spd_over_grnd"), "cog": fi("RMC", "true_course"),
                       "date": fi("RMC", "datestamp")}
    if kind == "ZDA":
        return 4, 6, {"time": fi("ZDA", "timestamp"), "day": fi("ZDA", "day"),
                      "month": fi("ZDA", "month"), "year": fi("ZDA", "year")}
    if kind == "GLL":
        return 6, 7, {"lat": fi("GLL", "lat"), "lat_dir": fi("GLL", "lat_dir"),
                      "lon": fi("GLL", "lon"), "lon_dir": fi("GLL", "lon_dir"),
                      "time": fi("GLL", "timestamp"), "status": fi("GLL", "status")}
    if kind == "HDG":
        return 1, 5, {"heading": fi("HDG", "heading"), "dev": fi("HDG", "deviation"),
                      "dev_dir": fi("HDG", "dev_dir"), "var": fi("HDG", "variation"),
                      "var_dir": fi("HDG", "var_dir")}
    if kind == "HDM":
        return 1, 2, {"heading": fi("HDM", "heading")}
    if kind == "RSA":
        return 2, 4, {"stbd": fi("RSA", "rsa_starboard"),
                      "stbd_status": fi("RSA", "rsa_starboard_status"),
                      "port": fi("RSA", "rsa_port"), "port_status": fi("RSA", "rsa_port_status")}
    if kind == "RPM":
        return 3, 5, {"source": fi("RPM", "source"), "number": fi("RPM", "engine_no"),
                      "speed": fi("RPM", "speed"), "status": fi("RPM", "status")}
    if kind == "XDR":
        base = {"type": fi("XDR", "type"), "value": fi("XDR", "value"),
                "unit": fi("XDR", "units"), "id": fi("XDR", "id")}
        return 4, 4 * XDR_MAX, {f"x{k}_{name}": 4 * k + i for k in range(XDR_MAX)
                                for name, i in base.items()}
    if kind == "VTG":
        return 5, 10, {"cog": fi("VTG", "true_track"), "sog": fi("VTG", "spd_over_grnd_kts")}
    if kind == "HDT":
        return 1, 2, {"heading": fi("HDT", "heading")}
    if kind == "THS":  # not in pynmea2: heading, mode (A/E/M/S/V)
        return 2, 2, {"heading": 0, "status": 1}
    if kind == "ROT":
        return 2, 2, {"rot": fi("ROT", "rate_of_turn"), "status": fi("ROT", "status")}
    if kind == "VHW":
        return 6, 8, {"speed": fi("VHW", "water_speed_knots")}
    if kind == "VBW":
        return 3, 10, {"lon": fi("VBW", "lon_water_spd"), "trans": fi("VBW", "trans_water_spd"),
                       "status": fi("VBW", "data_validity_water_spd")}
    if kind == "MWV":
        return 5, 5, {"angle": fi("MWV", "wind_angle"), "ref": fi("MWV", "reference"),
                      "speed": fi("MWV", "wind_speed"), "unit": fi("MWV", "wind_speed_units"),
                      "status": fi("MWV", "status")}
    raise KeyError(kind)  # pragma: no cover


_STRING_FIELDS = {"lat_dir", "lon_dir", "status", "ref", "unit", "dev_dir", "var_dir",
                  "stbd_status", "port_status", "source", "number"}


def _is_string_field(name: str) -> bool:
    return name in _STRING_FIELDS or (name.startswith("x") and not name.endswith("_value"))


# ----------------------------------------------------------------------------- scanning
def _first_at_or_after(positions: np.ndarray, lo: np.ndarray, hi: np.ndarray):
    """First element of sorted ``positions`` in ``[lo, hi)`` per row; (found, position)."""
    j = np.searchsorted(positions, lo)
    p = positions[np.minimum(j, max(positions.size - 1, 0))] if positions.size else lo
    found = (j < positions.size) & (p < hi) if positions.size else np.zeros(lo.size, bool)
    return found, np.where(found, p, lo)


def _scan(buf: np.ndarray, off: np.ndarray, ln: np.ndarray) -> dict[str, np.ndarray]:
    """Vectorised per-line analysis on the flat file bytes (no per-line Python).

    Positions of ``$``/``!``, ``*`` and ``c:`` are found once for the whole file and
    assigned to lines with ``searchsorted``; checksums come from one cumulative XOR over
    the file (the XOR of a byte range is ``cx[end] ^ cx[start]``), field counts from the
    sorted comma positions.
    """
    n = off.size
    end = off + ln
    pad = np.concatenate([buf, np.zeros(8, dtype=np.uint8)])
    cx = np.bitwise_xor.accumulate(pad)
    comma_pos = np.flatnonzero(buf == 44)
    dollars = np.flatnonzero((buf == 36) | (buf == 33))  # '$' or '!'
    stars = np.flatnonzero(buf == 42)
    has_start, st = _first_at_or_after(dollars, off, end)
    has_star, sr = _first_at_or_after(stars, st + 1, end)
    c1 = _HEXVAL[pad[sr + 1]]
    c2 = _HEXVAL[pad[sr + 2]]
    given = (c1.astype(np.int32) << 4) | c2
    body_xor = cx[np.maximum(sr - 1, 0)] ^ cx[st]
    structure = has_start & has_star & (sr >= st + 7) & (c1 >= 0) & (c2 >= 0) & \
        (sr + 2 < end)
    cs_ok = structure & (body_xor == given)
    talker = pad[st + 1].astype(np.int32) << 8 | pad[st + 2]
    fmt = (pad[st + 3].astype(np.int32) << 16) | (pad[st + 4].astype(np.int32) << 8) | pad[st + 5]
    sep_ok = pad[st + 6] == 44
    commas = np.searchsorted(comma_pos, sr) - np.searchsorted(comma_pos, st + 1)
    # TAG block receive time: "\...c:<digits>...*hh\" before the '$'
    tag = (pad[off] == 92) & has_start & (st > off)
    rx = np.full(n, np.nan)
    tag_ok = np.zeros(n, dtype=bool)
    if tag.any():
        cpairs = np.flatnonzero((buf[:-1] == 99) & (buf[1:] == 58))
        has_c, cpos = _first_at_or_after(cpairs, off, st)
        has_c &= tag
        val = np.zeros(n, dtype=np.int64)
        going = has_c.copy()
        for k in range(16):
            ch = pad[np.minimum(cpos + 2 + k, pad.size - 1)].astype(np.int64)
            dig = (ch >= 48) & (ch <= 57) & going
            val = np.where(dig, val * 10 + (ch - 48), val)
            going &= dig
        # TAG checksum: XOR of the bytes between the leading '\' and the '*' in the tag
        has_ts, ts = _first_at_or_after(stars, off + 1, st)
        tc1 = _HEXVAL[pad[ts + 1]]
        tc2 = _HEXVAL[pad[ts + 2]]
        txor = cx[np.maximum(ts - 1, 0)] ^ cx[off]
        tag_ok = has_c & has_ts & (tc1 >= 0) & (tc2 >= 0) & \
            (txor == ((tc1.astype(np.int32) << 4) | tc2))
        rx = np.where(tag_ok, np.where(val >= 100_000_000_000, val / 1000.0, val * 1.0), np.nan)
    return {"start": st - off, "star": sr - off, "cs_ok": cs_ok, "structure": structure,
            "talker": talker, "fmt": fmt, "sep_ok": sep_ok, "commas": commas,
            "tag": tag, "tag_ok": tag_ok, "rx": rx}


def _code(kind: str) -> int:
    b = kind.encode()
    return (b[0] << 16) | (b[1] << 8) | b[2]


def _decode(code: int, nbytes: int) -> str:
    return bytes((code >> (8 * (nbytes - 1 - i))) & 0xFF for i in range(nbytes)).decode(
        "ascii", errors="replace")


def _prefix_times(raw: bytes, off: np.ndarray, idx: np.ndarray, start: np.ndarray) -> np.ndarray:
    """Receive times from a leading UNIX time or ISO stamp (lines without a TAG block)."""
    text = pd.Series([raw[o:o + s].decode("ascii", "replace").strip(" ,;\t")
                      for o, s in zip(off[idx].tolist(), start[idx].tolist(), strict=True)],
                     dtype=object)
    num = pd.to_numeric(text, errors="coerce").to_numpy(dtype=float)
    bad = ~np.isfinite(num)
    if bad.any():
        iso = pd.to_datetime(text[bad], errors="coerce", utc=True, format="ISO8601")
        vals = iso.to_numpy(dtype="datetime64[ns]").astype(np.int64) / 1e9
        vals[iso.isna().to_numpy()] = np.nan
        num[bad] = vals
    num = np.where(num >= 1e11, num / 1000.0, num)
    return num


def _split_fields(buf: np.ndarray, off: np.ndarray, idx: np.ndarray, start: np.ndarray,
                  star: np.ndarray, n_fields: np.ndarray, kind: str) -> pd.DataFrame:
    """The fields of the given lines (one sentence type) as a DataFrame."""
    _mn, mx, names = _fields(kind)
    first = off[idx] + start[idx] + 7
    stop = off[idx] + star[idx]
    missing = mx - n_fields[idx]
    # every body padded with commas to mx fields, then a newline: one row copy per line
    ln = stop - first
    width = int(ln.max()) + mx + 1 if ln.size else mx + 1
    padded = np.concatenate([buf, np.zeros(width, dtype=np.uint8)])
    m = np.lib.stride_tricks.sliding_window_view(padded, width)[first]
    cols = np.arange(width)[None, :]
    end = (ln + missing)[:, None]
    m[(cols >= ln[:, None]) & (cols < end)] = 44  # ','
    m[np.arange(ln.size), ln + missing] = 10  # '\n'
    text = m[cols <= end].tobytes()
    usecols = sorted(names.values())
    str_cols = {names[k] for k in names if _is_string_field(k)}
    dtypes = {c: (str if c in str_cols else float) for c in usecols}
    kwargs: dict[str, Any] = {"header": None, "names": list(range(mx)), "usecols": usecols,
                              "skip_blank_lines": False, "keep_default_na": False,
                              "na_values": [""]}
    try:
        frame = pd.read_csv(io.BytesIO(text), dtype=dtypes, **kwargs)
    except (ValueError, pd.errors.ParserError):
        frame = pd.read_csv(io.BytesIO(text), dtype=str, **kwargs)
        for c in usecols:
            if c not in str_cols:
                frame[c] = pd.to_numeric(frame[c], errors="coerce")
    if len(frame) != idx.size:  # pragma: no cover - blank bodies are kept as rows
        raise NmeaError(f"internal: {kind} field split returned {len(frame)} rows for "
                        f"{idx.size} sentences")
    return frame.rename(columns={v: k for k, v in names.items()})


def _degrees(ddmm: np.ndarray, hemi: pd.Series, negative: str) -> np.ndarray:
    deg = np.floor(ddmm / 100.0)
    out = deg + (ddmm - 100.0 * deg) / 60.0
    sign = np.where(hemi.astype(str).str.upper().to_numpy() == negative, -1.0, 1.0)
    return out * sign


def _time_of_day(hhmmss: np.ndarray) -> np.ndarray:
    hh = np.floor(hhmmss / 10000.0)
    mm = np.floor(hhmmss / 100.0) - 100.0 * hh
    ss = hhmmss - 10000.0 * hh - 100.0 * mm
    bad = (hh > 23) | (mm > 59) | (ss >= 61) | (hhmmss < 0)
    out = 3600.0 * hh + 60.0 * mm + ss
    out[bad] = np.nan
    return out


def _dates(ddmmyy: np.ndarray) -> np.ndarray:
    """UNIX seconds of midnight of ``ddmmyy`` dates (NaN when invalid)."""
    out = np.full(ddmmyy.size, np.nan)
    ok = np.isfinite(ddmmyy)
    v = ddmmyy[ok].astype(np.int64)
    dd, mm, yy = v // 10000, (v // 100) % 100, v % 100
    year = np.where(yy < 80, 2000 + yy, 1900 + yy)
    frame = pd.DataFrame({"year": year, "month": mm, "day": dd})
    ts = pd.to_datetime(frame, errors="coerce", utc=True)
    secs = ts.to_numpy(dtype="datetime64[ns]").astype(np.int64) / 1e9
    secs[ts.isna().to_numpy()] = np.nan
    out[ok] = secs
    return out


def _runs(offset: np.ndarray, jump: float = 0.5, min_run: int = 3):
    """Split a sequence of clock offsets into runs at jumps; short runs are outliers."""
    n = offset.size
    if n == 0:
        return np.zeros(0, dtype=np.int64), np.zeros(0), np.zeros(0, dtype=bool), 0
    brk = np.concatenate([[True], np.abs(np.diff(offset)) > jump])
    run = np.cumsum(brk) - 1
    n_runs = int(run[-1]) + 1
    sizes = np.bincount(run, minlength=n_runs)
    med = np.array([np.median(offset[run == k]) for k in range(n_runs)])
    outlier = sizes[run] < min_run
    if outlier.all():
        outlier[:] = False
    good_runs = np.flatnonzero(sizes >= min_run) if (sizes >= min_run).any() else np.arange(n_runs)
    # jumps: changes between consecutive good runs
    jumps = int(np.sum(np.abs(np.diff(med[good_runs])) > jump))
    return run, med, outlier, jumps


# ------------------------------------------------------------------------------- chunks
#: Bytes read at a time (whole lines): the per-byte work of :func:`_scan` and
#: :func:`_split_fields` runs on one chunk, so memory grows with the number of sentences,
#: not with several times the file size.
CHUNK_BYTES = 1 << 24


def _scan_chunk(raw: bytes, out: dict[str, Any]) -> None:
    """Scan the complete lines in ``raw`` (numbered after the ``out["n"]`` kept so far)."""
    buf = np.frombuffer(raw, dtype=np.uint8)
    nl = np.flatnonzero(buf == 10)
    off = np.concatenate([[0], nl + 1]).astype(np.int64)
    end = np.concatenate([nl, [buf.size]]).astype(np.int64)
    cr = (end > off) & (buf[np.maximum(end - 1, 0)] == 13) if buf.size else end > off
    end = end - cr
    ln = end - off
    keep = ln > 0
    off, ln = off[keep], ln[keep]
    out["lines"] += int(off.size)
    long = ln > MAX_LINE
    if long.any():
        off, ln = off[~long], ln[~long]
    out["corrupt"] += int(long.sum())
    if off.size == 0:
        return
    sc = _scan(buf, off, ln)
    bad_cs = sc["structure"] & ~sc["cs_ok"]
    corrupt = ~sc["structure"] | ~sc["sep_ok"]
    bad_tag = sc["tag"] & ~sc["tag_ok"]
    good = sc["cs_ok"] & sc["sep_ok"] & ~bad_tag
    out["bad_checksum"] += int((bad_cs & sc["sep_ok"]).sum() + (bad_tag & sc["cs_ok"]).sum())
    out["corrupt"] += int(corrupt.sum())
    rx = sc["rx"].copy()
    no_tag = good & ~sc["tag"] & (sc["start"] > 0)
    if no_tag.any():
        idx = np.flatnonzero(no_tag)
        rx[idx] = _prefix_times(raw, off, idx, sc["start"])
    for key, value in (("good", good), ("rx", rx), ("fmt", sc["fmt"]),
                       ("talker", sc["talker"])):
        out.setdefault(key, []).append(value)
    nf = sc["commas"]  # the comma after the formatter opens field 1
    for kind in SUPPORTED:
        sel = good & (sc["fmt"] == _code(kind))
        if not sel.any():
            continue
        mn, mx, _ = _fields(kind)
        ok_count = sel & (nf >= mn) & (nf <= mx)
        out["corrupt"] += int((sel & ~ok_count).sum())
        idx = np.flatnonzero(ok_count)
        if idx.size:
            frame = _split_fields(buf, off, idx, sc["start"], sc["star"], nf, kind)
            out["frames"].setdefault(kind, []).append((idx + out["n"], frame))
    out["n"] += int(off.size)


def _scan_file(path: Path, chunk: int | None = None) -> dict[str, Any]:
    """Per-line scan of an NMEA file, read ``chunk`` bytes at a time (whole lines).

    Returns the line counts, per-line arrays of the lines kept (``good``, ``rx``, ``fmt``,
    ``talker``; ``n`` of them) and, per supported sentence type, the line numbers and
    fields of its well-formed sentences.
    """
    chunk = chunk or CHUNK_BYTES
    out: dict[str, Any] = {"lines": 0, "n": 0, "bad_checksum": 0, "corrupt": 0, "frames": {}}
    carry = b""
    skipping = False  # inside a line far longer than MAX_LINE: dropped up to its end
    with open(path, "rb") as fh:
        while True:
            block = fh.read(chunk)
            eof = not block
            if skipping:
                nl = block.find(b"\n")
                if nl < 0:
                    if eof:
                        break
                    continue
                block, skipping = block[nl + 1:], False
            data, carry = carry + block, b""
            if not eof:
                cut = data.rfind(b"\n") + 1
                if cut == 0:  # no line end in the data
                    if len(data) <= max(chunk, 2 * MAX_LINE):
                        carry = data  # read on
                        continue
                    out["lines"] += 1  # one overlong line: corrupt, as if read whole
                    out["corrupt"] += 1
                    skipping = True
                    continue
                data, carry = data[:cut], data[cut:]
            if data:
                _scan_chunk(data, out)
            if eof:
                break
    for key in ("good", "rx", "fmt", "talker"):
        parts = out.get(key, [])
        out[key] = np.concatenate(parts) if parts else np.zeros(0)
    out["frames"] = {kind: (np.concatenate([i for i, _ in parts]),
                            pd.concat([f for _, f in parts], ignore_index=True))
                     for kind, parts in out["frames"].items()}
    return out


# ------------------------------------------------------------------------------- reader
def read_nmea(
    path: str | Path,
    *,
    relative_latency: dict[str, float] | None = None,
    epoch_tolerance: float = 0.02,
    options: NmeaOptions | None = None,
) -> tuple[list[Stream], dict[str, Any]]:
    """Parse an NMEA 0183 log into channel streams.

    Parameters
    ----------
    path : str or Path
    relative_latency : dict sentence -> s, optional
        Latency of untimed sentences relative to the GNSS time of validity.
    epoch_tolerance : float
        An untimed sentence whose aligned time is within this many seconds of a GNSS
        epoch (a GGA/RMC time of validity) takes the epoch's time (burst association;
        0 switches it off).
    options : NmeaOptions, optional
        Magnetic variation/deviation, channel renames and XDR transducer names (the
        ``[nmea]`` table of the ingest configuration).

    Returns
    -------
    streams : list of Stream
        ``lat, lon, alt`` (GGA, else RMC, else GLL), ``vel_north, vel_east`` (RMC, else
        VTG), ``psi`` (HDT, else THS, else HDG, else HDM; true heading), ``r`` (ROT),
        ``rudder``/``rudder_port`` (RSA), ``shaft_rpm``/``engine_rpm`` (RPM), mapped XDR
        transducers, ``u_log`` (+ ``v_log``: VBW, else VHW), ``wind_speed, wind_angle``
        (MWV, relative); renamed by ``options.channels``.
    quality : dict
        Line and sentence counts: ``lines``, ``sentences``, ``bad_checksum``, ``corrupt``,
        ``unsupported`` (per formatter), ``invalid`` (void status/no fix, per formatter),
        ``talkers`` (per formatter and talker), ``ignored_talkers``, ``clock_jumps``,
        ``time_outliers``, ``timing``, ``unusable`` (sentence type → why it gave no
        samples), ``xdr_unmapped`` (transducer name → count).

    Raises
    ------
    NmeaError
        Unreadable file, no valid supported sentence in it, or no time source.
    """
    path = Path(path)
    opts = options or NmeaOptions()
    rel = {k.upper(): float(v) for k, v in (relative_latency or {}).items()}
    q: dict[str, Any] = {"file": str(path)}
    try:
        lines = _scan_file(path)
    except OSError as exc:
        raise NmeaError(f"cannot read {path}: {exc.strerror or exc}") from exc
    q["lines"] = lines["lines"]
    if lines["n"] == 0:
        raise NmeaError(f"{path} holds no NMEA 0183 lines")
    n = lines["n"]
    good, rx, fmt = lines["good"], lines["rx"], lines["fmt"]
    sc = {"talker": lines["talker"]}
    q["bad_checksum"] = lines["bad_checksum"]
    q["corrupt"] = lines["corrupt"]
    has_rx = np.isfinite(rx)
    # clock jumps in the receive time itself are handled through the GNSS offsets below
    supported = {k: _code(k) for k in SUPPORTED}
    known = np.isin(fmt, list(supported.values()))
    unsup = good & ~known
    q["unsupported"] = {_decode(int(c), 3): int(k) for c, k in
                        zip(*np.unique(fmt[unsup], return_counts=True), strict=True)}
    q["sentences"] = int(good.sum())
    frames: dict[str, tuple[np.ndarray, pd.DataFrame]] = lines["frames"]
    invalid: dict[str, int] = {}
    unusable: dict[str, str] = {}
    talkers: dict[str, dict[str, int]] = {}
    for kind, (idx, _frame) in frames.items():
        tk, cnt = np.unique(sc["talker"][idx], return_counts=True)
        talkers[kind] = {_decode(int(t), 2): int(c) for t, c in zip(tk, cnt, strict=True)}
    q["talkers"] = talkers
    if not frames:
        raise NmeaError(
            f"no valid NMEA 0183 sentence of a supported type ({', '.join(SUPPORTED)}) in "
            f"{path}: {n} lines, {q['bad_checksum']} bad checksums, {q['corrupt']} corrupt"
            + (f"; found {_counts_text(q['unsupported'])}" if q["unsupported"] else ""))

    # ----------------------------------------------------------- times of validity
    line_time = np.full(n, np.nan)
    line_tod = np.full(n, np.nan)
    timed_lines = []
    for kind in TIMED:
        if kind not in frames:
            continue
        idx, f = frames[kind]
        tod = _time_of_day(f["time"].to_numpy(dtype=float))
        if kind == "RMC":
            day = _dates(f["date"].to_numpy(dtype=float))
        elif kind == "ZDA":
            day = _ymd(f["year"].to_numpy(float), f["month"].to_numpy(float),
                       f["day"].to_numpy(float))
        else:
            day = np.full(idx.size, np.nan)
        t_abs = day + tod
        r = rx[idx]
        use_rx = np.isfinite(r) & np.isfinite(tod) & ~np.isfinite(day)
        # anchor the time of day on the receive time (any logger clock within 12 h of UTC)
        wrap = np.mod(tod - np.mod(r, 86400.0) + 43200.0, 86400.0) - 43200.0
        t_abs = np.where(use_rx, r + wrap, t_abs)
        line_time[idx] = t_abs
        line_tod[idx] = tod
        timed_lines.append(idx)
    timed_idx = np.sort(np.concatenate(timed_lines)) if timed_lines else np.zeros(0, np.int64)
    if timed_idx.size:
        # a time of day without date and receive time: the date of the nearest dated
        # sentence (RMC/ZDA), across midnight where the times of day say so
        miss = timed_idx[~np.isfinite(line_time[timed_idx]) & np.isfinite(line_tod[timed_idx])]
        dated = [frames[k][0] for k in DATED if k in frames]
        dated_idx = np.sort(np.concatenate(dated)) if dated else np.zeros(0, np.int64)
        dated_idx = dated_idx[np.isfinite(line_time[dated_idx])]
        if miss.size and dated_idx.size:
            pos = np.searchsorted(dated_idx, miss).clip(0, dated_idx.size - 1)
            ref = line_time[dated_idx[pos]]
            t = ref - np.mod(ref, 86400.0) + line_tod[miss]
            line_time[miss] = t + 86400.0 * np.round((ref - t) / 86400.0)
        if not np.isfinite(line_time[timed_idx]).any():
            # neither date nor receive time: relative times of day
            line_time[timed_idx] = line_tod[timed_idx]
            q["timing_note"] = "no date and no receive time: times are seconds of the UTC day"
    timed_ok = timed_idx[np.isfinite(line_time[timed_idx])]
    if timed_ok.size == 0 and not has_rx.any():
        found = {k: int(frames[k][0].size) for k in TIMED if k in frames}
        why = (f"{_counts_text(found)} but none with a valid time field" if found
               else "found no RMC/GGA/ZDA/GLL sentences with a time")
        raise NmeaError(
            f"{path.name}: no time source: {why}, and no receive times (TAG block or a "
            f"leading UNIX/ISO time) on the lines; sentences found: "
            f"{_counts_text(_sentence_counts(frames, q['unsupported']))}")
    jumps = 0
    outliers = 0
    offset_of_line = np.full(n, np.nan)
    if timed_ok.size and has_rx[timed_ok].any():
        ti = timed_ok[has_rx[timed_ok]]
        off = rx[ti] - line_time[ti]
        run, med, outl, jumps = _runs(off)
        outliers = int(outl.sum())
        line_time[ti[outl]] = np.nan
        keep = ~outl
        # every line takes the offset of the run of the previous or the next good timed
        # line, whichever places it closer to that line's fix (a jump between them)
        tk = ti[keep]
        off_k = med[run[keep]]
        pos = np.clip(np.searchsorted(tk, np.arange(n), side="right") - 1, 0, tk.size - 1)
        nxt = np.minimum(pos + 1, tk.size - 1)
        lines_rx = np.where(np.isfinite(rx), rx, 0.0)
        err_p = np.abs(lines_rx - off_k[pos] - line_time[tk[pos]])
        err_n = np.abs(lines_rx - off_k[nxt] - line_time[tk[nxt]])
        offset_of_line = np.where(err_n < err_p, off_k[nxt], off_k[pos])
        q["timing"] = "GNSS time of validity; untimed sentences: receive time - logger offset"
        q["logger_offset_s"] = [float(x) for x in np.unique(np.round(med, 3))[:10]]
    elif has_rx.any():
        offset_of_line = np.zeros(n)
        q["timing"] = "receive times (no GNSS time of validity)"
    else:
        q["timing"] = ("GNSS time of validity; untimed sentences take the preceding fix time "
                       "(several between two fixes: spread evenly over the interval)")
    q["clock_jumps"] = int(jumps)
    q["time_outliers"] = outliers

    epochs = np.unique(line_time[timed_ok]) if timed_ok.size else np.zeros(0)
    epochs = epochs[np.isfinite(epochs)]
    spread: dict[str, int] = {}

    def untimed_times(kind: str, idx: np.ndarray) -> np.ndarray:
        if np.isfinite(offset_of_line).any():
            t = rx[idx] - offset_of_line[idx]
        else:
            # burst association: the last timed line before this one
            good_t = timed_ok[np.isfinite(line_time[timed_ok])]
            if good_t.size == 0:
                return np.full(idx.size, np.nan)
            pos = np.searchsorted(good_t, idx, side="right") - 1
            t = np.where(pos >= 0, line_time[good_t[np.clip(pos, 0, None)]], np.nan)
            t = _spread(t, epochs, kind, spread)
        return t - rel.get(kind, 0.0)

    def times(kind: str, idx: np.ndarray) -> np.ndarray:
        if kind in TIMED:
            return line_time[idx]
        t = untimed_times(kind, idx)
        if epoch_tolerance > 0 and epochs.size:
            # burst association: an untimed sentence within the tolerance of a GNSS epoch
            # takes that epoch's time of validity (removes the receive jitter)
            j = np.clip(np.searchsorted(epochs, t), 1, max(epochs.size - 1, 1))
            lo, hi = epochs[j - 1], epochs[np.minimum(j, epochs.size - 1)]
            near = np.where(np.abs(t - lo) <= np.abs(hi - t), lo, hi)
            snap = np.abs(near - t) <= epoch_tolerance
            t = np.where(snap, near, t)
        return t

    # ------------------------------------------------------------------- streams
    streams: list[Stream] = []
    ignored: dict[str, int] = {}
    name = path.name

    def add(kind, idx, valid, channels, why_invalid="", notes=None, t_all=None, moved=0):
        bad = int((~valid).sum())
        if bad:
            invalid[kind] = invalid.get(kind, 0) + bad
        if t_all is None:
            # times of the valid sentences only (spreading counts the sentences used)
            before = spread.get(kind, 0)
            t_all = np.full(idx.size, np.nan)
            if valid.any():
                t_all[valid] = times(kind, idx[valid])
            moved = spread.get(kind, 0) - before
        tk = sc["talker"][idx]
        keep = valid & np.isfinite(t_all)
        if not keep.any():
            if not valid.any():
                why = why_invalid or "none with a valid value (empty fields or void status)"
            else:
                why = "none with a usable time"
            unusable[kind] = f"{idx.size} {kind} sentence(s), {why}"
        primary = _primary_talker(tk[keep])
        sel = keep & (tk == primary)
        other = keep & (tk != primary)
        if other.any():
            # a second source of the same sentence: keep its samples only where the primary
            # talker has none (a receiver that changed its talker id), ignore the rest
            tp = np.sort(t_all[sel])
            p = float(np.median(np.diff(tp))) if tp.size > 1 else math.inf
            to = t_all[other]
            j = np.searchsorted(tp, to).clip(1, max(tp.size - 1, 1))
            near = np.minimum(np.abs(to - tp[j - 1]), np.abs(to - tp[np.minimum(j, tp.size - 1)]))
            fill = near > 0.75 * p if math.isfinite(p) else np.ones(to.size, dtype=bool)
            o_idx = np.flatnonzero(other)
            sel[o_idx[fill]] = True
            ignored[kind] = ignored.get(kind, 0) + int((~fill).sum())
        src = f"{name}:{kind} ({_decode(int(primary), 2)})" if keep.any() else f"{name}:{kind}"
        extra = dict(notes or {})
        if moved:
            extra["time_interpolated"] = moved
        for ch, values, knd, prio in channels:
            streams.append(Stream(ch, t_all[sel], np.asarray(values)[sel], kind=knd,
                                  source=src, priority=prio, notes=dict(extra)).clean())

    if "GGA" in frames:
        idx, f = frames["GGA"]
        lat = _degrees(f["lat"].to_numpy(float), f["lat_dir"], "S")
        lon = _degrees(f["lon"].to_numpy(float), f["lon_dir"], "W")
        qual = f["qual"].to_numpy(float)
        valid = (qual > 0) & np.isfinite(lat) & np.isfinite(lon)
        alt = np.nan_to_num(f["alt"].to_numpy(float))
        add("GGA", idx, valid, [("lat", lat, "linear", 0), ("lon", lon, "linear", 0),
                                ("alt", alt, "linear", 0)])
    rmc_var: tuple[np.ndarray, np.ndarray] | None = None
    if "RMC" in frames:
        idx, f = frames["RMC"]
        status = f["status"].astype(str).str.upper().to_numpy()
        sog = f["sog"].to_numpy(float) * KNOT
        cog = np.radians(f["cog"].to_numpy(float))
        valid = (status == "A") & np.isfinite(sog)
        cog_ok = np.where(sog == 0, 0.0, cog)
        lat = _degrees(f["lat"].to_numpy(float), f["lat_dir"], "S")
        lon = _degrees(f["lon"].to_numpy(float), f["lon_dir"], "W")
        add("RMC", idx, valid & np.isfinite(cog_ok),
            [("vel_north", sog * np.cos(cog_ok), "linear", 0),
             ("vel_east", sog * np.sin(cog_ok), "linear", 0),
             ("lat", lat, "linear", 1), ("lon", lon, "linear", 1)])
        var = _east_positive(f["var"].to_numpy(float), f["var_dir"])
        t_var = line_time[idx]
        ok = np.isfinite(var) & np.isfinite(t_var)
        if ok.any():
            order = np.argsort(t_var[ok], kind="stable")
            rmc_var = (t_var[ok][order], var[ok][order])
    if "GLL" in frames:
        idx, f = frames["GLL"]
        lat = _degrees(f["lat"].to_numpy(float), f["lat_dir"], "S")
        lon = _degrees(f["lon"].to_numpy(float), f["lon_dir"], "W")
        status = f["status"].astype(str).str.upper().to_numpy()
        valid = (status == "A") & np.isfinite(lat) & np.isfinite(lon)
        add("GLL", idx, valid, [("lat", lat, "linear", 2), ("lon", lon, "linear", 2)])
    if "VTG" in frames:
        idx, f = frames["VTG"]
        sog = f["sog"].to_numpy(float) * KNOT
        cog = np.where(sog == 0, 0.0, np.radians(f["cog"].to_numpy(float)))
        valid = np.isfinite(sog) & np.isfinite(cog)
        add("VTG", idx, valid, [("vel_north", sog * np.cos(cog), "linear", 1),
                                ("vel_east", sog * np.sin(cog), "linear", 1)])
    for kind, prio in (("HDT", 0), ("THS", 1)):
        if kind in frames:
            idx, f = frames[kind]
            raw_deg = f["heading"].to_numpy(float)
            hdg = np.radians(raw_deg)
            valid = np.isfinite(hdg)
            if kind == "THS":
                valid &= f["status"].astype(str).str.upper().to_numpy() != "V"
            add(kind, idx, valid, [("psi", hdg, "angle", prio)],
                notes=_quantisation(raw_deg[valid]))
    for kind, prio in (("HDG", 2), ("HDM", 3)):
        if kind not in frames:
            continue
        idx, f = frames[kind]
        raw_deg = f["heading"].to_numpy(float)
        n_s = idx.size
        if kind == "HDG":
            dev = _east_positive(f["dev"].to_numpy(float), f["dev_dir"])
            var = _east_positive(f["var"].to_numpy(float), f["var_dir"])
        else:
            dev = var = np.full(n_s, np.nan)
        var_src = np.where(np.isfinite(var), "sentence", "")
        if opts.magnetic_variation is not None:
            var_src = np.where(np.isfinite(var), var_src, "configuration")
            var = np.where(np.isfinite(var), var, opts.magnetic_variation)
        has_hdg = np.isfinite(raw_deg)
        before = spread.get(kind, 0)
        t_h = np.full(idx.size, np.nan)
        if has_hdg.any():
            t_h[has_hdg] = times(kind, idx[has_hdg])
        moved = spread.get(kind, 0) - before
        if rmc_var is not None and not np.isfinite(var).all():
            j = np.clip(np.searchsorted(rmc_var[0], t_h, side="right") - 1, 0,
                        rmc_var[0].size - 1)
            from_rmc = ~np.isfinite(var) & np.isfinite(t_h)
            var = np.where(from_rmc, rmc_var[1][j], var)
            var_src = np.where(from_rmc, "RMC", var_src)
        dev = np.where(np.isfinite(dev), dev,
                       opts.deviation if opts.deviation is not None else 0.0)
        true_deg = raw_deg + dev + var
        valid = has_hdg & np.isfinite(var)
        why = ""
        if has_hdg.any() and not valid.any():
            why = ("magnetic headings without a magnetic variation (none in the sentence, "
                   "no RMC variation; set [nmea] magnetic_variation in ingest.toml)")
        srcs, cnt = np.unique(var_src[valid], return_counts=True)
        notes = {**_quantisation(raw_deg[valid]), "magnetic": True,
                 "variation_from": {str(a): int(c) for a, c in zip(srcs, cnt, strict=True)}}
        add(kind, idx, valid, [("psi", np.radians(true_deg), "angle", prio)], why, notes,
            t_h, moved)
    if "ROT" in frames:
        idx, f = frames["ROT"]
        rot = np.radians(f["rot"].to_numpy(float)) / 60.0
        valid = np.isfinite(rot) & (f["status"].astype(str).str.upper().to_numpy() == "A")
        add("ROT", idx, valid, [("r", rot, "linear", 0)])
    if "RSA" in frames:
        idx, f = frames["RSA"]
        for side, ch in (("stbd", "rudder"), ("port", "rudder_port")):
            val = np.radians(f[side].to_numpy(float))
            valid = np.isfinite(val) & \
                (f[f"{side}_status"].astype(str).str.upper().to_numpy() == "A")
            if side == "port" and not valid.any():
                continue  # a single rudder sensor
            add("RSA", idx, valid, [(ch, val, "linear", 0)])
    if "RPM" in frames:
        idx, f = frames["RPM"]
        source = f["source"].fillna("").astype(str).str.strip().str.upper().to_numpy()
        number = f["number"].fillna("").astype(str).str.strip().to_numpy()
        speed = f["speed"].to_numpy(float)
        status = f["status"].fillna("").astype(str).str.strip().str.upper().to_numpy()
        okr = np.isfinite(speed) & ((status == "A") | (status == ""))
        for src_code, base in (("S", "shaft_rpm"), ("E", "engine_rpm")):
            mine = source == src_code
            if not mine.any():
                continue
            nums = sorted(set(number[mine]))
            for num in nums:
                g = mine & (number == num)
                ch = base if len(nums) == 1 else f"{base}_{num}"
                add("RPM", idx[g], okr[g], [(ch, speed[g], "linear", 0)])
    if "XDR" in frames:
        _xdr(frames["XDR"], opts, add, q)
    if "VBW" in frames:
        idx, f = frames["VBW"]
        valid = (f["status"].astype(str).str.upper().to_numpy() == "A") & \
            np.isfinite(f["lon"].to_numpy(float)) & np.isfinite(f["trans"].to_numpy(float))
        add("VBW", idx, valid, [("u_log", f["lon"].to_numpy(float) * KNOT, "linear", 0),
                                ("v_log", f["trans"].to_numpy(float) * KNOT, "linear", 0)])
    if "VHW" in frames:
        idx, f = frames["VHW"]
        spd = f["speed"].to_numpy(float) * KNOT
        add("VHW", idx, np.isfinite(spd), [("u_log", spd, "linear", 1)])
    if "MWV" in frames:
        idx, f = frames["MWV"]
        unit = f["unit"].astype(str).str.upper().to_numpy()
        scale = np.select([unit == "M", unit == "K", unit == "N"], [1.0, 1 / 3.6, KNOT], np.nan)
        spd = f["speed"].to_numpy(float) * scale
        ang = -np.radians(f["angle"].to_numpy(float))  # γ_rw: 0 from ahead, + from port
        ang = np.mod(ang + math.pi, 2 * math.pi) - math.pi
        valid = (f["ref"].astype(str).str.upper().to_numpy() == "R") & \
            (f["status"].astype(str).str.upper().to_numpy() == "A") & np.isfinite(spd) & \
            np.isfinite(ang)
        add("MWV", idx, valid, [("wind_speed", spd, "linear", 0),
                                ("wind_angle", ang, "angle", 0)],
            "none relative (R) with status A and a speed unit M/K/N")
    for s in streams:
        m = opts.channels.get(s.name)
        if m is not None:
            s.notes["renamed_from"] = s.name
            s.name = m.name
            s.values = s.values * m.scale + m.offset
    q["invalid"] = invalid
    q["ignored_talkers"] = ignored
    q["unusable"] = unusable
    q["time_interpolated"] = spread
    return streams, q


def _xdr(frame: tuple[np.ndarray, pd.DataFrame], opts: NmeaOptions, add: Any,
         q: dict[str, Any]) -> None:
    """XDR quadruplets (type, value, unit, name): the names mapped in ``[nmea] xdr``."""
    idx, f = frame
    ids = {k: f[f"x{k}_id"].fillna("").astype(str).str.strip().to_numpy()
           for k in range(XDR_MAX)}
    seen: dict[str, int] = {}
    for k in range(XDR_MAX):
        names, cnt = np.unique(ids[k][f[f"x{k}_type"].notna().to_numpy()
                                      | f[f"x{k}_value"].notna().to_numpy()],
                               return_counts=True)
        for a, c in zip(names, cnt, strict=True):
            if a:
                seen[str(a)] = seen.get(str(a), 0) + int(c)
    q["xdr_unmapped"] = {a: c for a, c in seen.items() if a not in opts.xdr}
    for tname, m in opts.xdr.items():
        rows, vals = [], []
        for k in range(XDR_MAX):
            hit = ids[k] == tname
            if not hit.any():
                continue
            v = f[f"x{k}_value"].to_numpy(float)
            typ = f[f"x{k}_type"].fillna("").astype(str).str.strip().str.upper().to_numpy()
            unit = f[f"x{k}_unit"].fillna("").astype(str).str.strip().str.upper().to_numpy()
            v = np.where((typ == "A") & (unit == "D"), np.radians(v), v)
            rows.append(np.flatnonzero(hit))
            vals.append(v[hit])
        if not rows:
            continue
        r = np.concatenate(rows)
        v = np.concatenate(vals) * m.scale + m.offset
        order = np.argsort(r, kind="stable")
        r, v = r[order], v[order]
        add("XDR", idx[r], np.isfinite(v), [(m.name, v, "linear", 0)])


def _spread(t: np.ndarray, epochs: np.ndarray, kind: str, counts: dict[str, int]) -> np.ndarray:
    """Sentences of one type sharing the preceding fix time, spread over the interval to
    the next fix (k-th of m at ``T + k (T_next − T) / m``); counted in ``counts``."""
    if t.size < 2 or epochs.size < 2:
        return t
    ok = np.isfinite(t)
    e = np.searchsorted(epochs, t[ok])
    if e.size < 2:
        return t
    _u, first, inverse, m = np.unique(e, return_index=True, return_inverse=True,
                                      return_counts=True)
    rank = np.arange(e.size) - first[inverse]
    many = m[inverse] > 1
    nxt = np.minimum(e + 1, epochs.size - 1)
    width = epochs[nxt] - epochs[np.minimum(e, epochs.size - 1)]
    # after the last fix: the typical fix interval
    width = np.where(e + 1 < epochs.size, width, float(np.median(np.diff(epochs))))
    movable = many & (width > 0) & (e < epochs.size)
    if not movable.any():
        return t
    out = t.copy()
    vals = t[ok]
    vals = np.where(movable, vals + rank * width / m[inverse], vals)
    out[ok] = vals
    counts[kind] = counts.get(kind, 0) + int((movable & (rank > 0)).sum())
    return out


def _east_positive(value: np.ndarray, direction: pd.Series) -> np.ndarray:
    """A magnetic variation/deviation with its E/W letter as degrees, east positive."""
    d = direction.astype(str).str.strip().str.upper().to_numpy()
    sign = np.where(d == "W", -1.0, np.where(d == "E", 1.0, np.nan))
    return np.abs(value) * sign


def _quantisation(deg: np.ndarray) -> dict[str, Any]:
    """Report a heading in whole (or half) degrees: step and equivalent noise std."""
    deg = deg[np.isfinite(deg)]
    if deg.size < 10:
        return {}
    for step in (1.0, 0.5):
        if np.all(np.abs(deg / step - np.round(deg / step)) < 1e-6):
            return {"quantisation_deg": step,
                    "quantisation_noise_std_rad": math.radians(step) / math.sqrt(12.0)}
    return {}


def _ymd(year: np.ndarray, month: np.ndarray, day: np.ndarray) -> np.ndarray:
    """UNIX seconds of midnight of (year, month, day) (NaN when invalid or missing)."""
    out = np.full(year.size, np.nan)
    year = np.where(year < 100, 2000 + year, year)  # two-digit years (seen in real logs)
    ok = np.isfinite(year) & np.isfinite(month) & np.isfinite(day) & (year >= 1970) & \
        (year < 2200)
    if ok.any():
        frame = pd.DataFrame({"year": year[ok].astype(np.int64),
                              "month": month[ok].astype(np.int64),
                              "day": day[ok].astype(np.int64)})
        ts = pd.to_datetime(frame, errors="coerce", utc=True)
        secs = ts.to_numpy(dtype="datetime64[ns]").astype(np.int64) / 1e9
        secs[ts.isna().to_numpy()] = np.nan
        out[ok] = secs
    return out


def _sentence_counts(frames: dict[str, Any], unsupported: dict[str, int]) -> dict[str, int]:
    out = {k: int(v[0].size) for k, v in frames.items()}
    out.update(unsupported)
    return out


def _counts_text(counts: dict[str, int]) -> str:
    items = sorted(counts.items(), key=lambda kv: -kv[1])
    return ", ".join(f"{v} {k}" for k, v in items) if items else "none"


def _primary_talker(talkers: np.ndarray) -> int:
    if talkers.size == 0:
        return -1
    vals, counts = np.unique(talkers, return_counts=True)
    return int(vals[np.argmax(counts)])
