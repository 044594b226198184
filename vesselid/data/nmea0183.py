"""NMEA 0183 text, vectorised: checksums, sentence assembly and field conventions.

Shared by the raw-stream generator (:mod:`vesselid.data.rawexport`) and the NMEA reader
(:mod:`vesselid.data.ingest.nmea`). Field order and names follow pynmea2's sentence
definitions (``pynmea2.GGA.fields`` ...), which :func:`field_index` looks up, so both
sides agree with the reference parser; the per-sentence work (formatting, checksums,
splitting) is done on whole arrays because pynmea2 object construction and parsing cost
~40 µs per sentence (≈ 40 s for 10⁶ sentences on the reference machine).

A sentence is ``$TTSSS,f1,f2,...*hh`` where ``hh`` is the XOR of every byte between ``$``
and ``*`` in two upper-case hex digits. Lines may carry an IEC 61162-450 / NMEA 4.10 TAG
block with the logger's receive time, ``\\c:<unix time>*hh\\$...``; ``c`` is written in
milliseconds (values ≥ 1e11 are read as milliseconds, smaller ones as seconds).
"""

from __future__ import annotations

from collections.abc import Sequence
from functools import cache
from typing import Any

import numpy as np

__all__ = [
    "KNOT",
    "checksums",
    "const_field",
    "field_index",
    "fixed_field",
    "format_latitude",
    "format_longitude",
    "format_utc_date",
    "format_utc_time",
    "hex_checksums",
    "latitude_fields",
    "longitude_fields",
    "sentence_lines",
    "sentence_rows",
    "utc_date_field",
    "utc_time_field",
    "write_rows",
]

#: One knot in m/s.
KNOT = 1852.0 / 3600.0

_HEX = np.array([f"{i:02X}" for i in range(256)], dtype=object)


@cache
def field_index(sentence_type: str, name: str) -> int:
    """0-based index of field ``name`` (pynmea2's attribute name) in a sentence type.

    >>> field_index("GGA", "lat")
    1
    """
    import pynmea2

    cls = getattr(pynmea2, sentence_type)
    names = [f[1] for f in cls.fields]
    return names.index(name)


def checksums(bodies: Sequence[str]) -> np.ndarray:
    """XOR checksum of every string (the bytes between ``$`` and ``*``), vectorised.

    Parameters
    ----------
    bodies : sequence of str
        ASCII sentence bodies without ``$`` and ``*hh``.

    Returns
    -------
    ndarray of uint8
    """
    n = len(bodies)
    if n == 0:
        return np.zeros(0, dtype=np.uint8)
    lens = np.fromiter((len(b) for b in bodies), dtype=np.int64, count=n)
    data = np.frombuffer("".join(bodies).encode("ascii"), dtype=np.uint8)
    return segment_xor(data, np.concatenate([[0], np.cumsum(lens)]))


def segment_xor(data: np.ndarray, offsets: np.ndarray) -> np.ndarray:
    """XOR of ``data[offsets[i]:offsets[i+1]]`` for every ``i`` (empty segments give 0)."""
    offsets = np.asarray(offsets, dtype=np.int64)
    if data.size == 0:
        return np.zeros(offsets.size - 1, dtype=np.uint8)
    cx = np.concatenate([[0], np.bitwise_xor.accumulate(data)]).astype(np.uint8)
    return cx[offsets[1:]] ^ cx[offsets[:-1]]


def hex_checksums(bodies: Sequence[str]) -> np.ndarray:
    """Two-digit upper-case hex checksums (object array of str)."""
    return _HEX[checksums(bodies)]


def sentence_lines(
    talker: str, sentence_type: str, fields: Sequence[Sequence[str]],
    receive_time: np.ndarray | None = None,
) -> list[str]:
    """Assemble complete sentences (with checksum and optional TAG block), no newline.

    Parameters
    ----------
    talker : str
        Two-letter talker id (``"GN"``, ``"HE"``, ...).
    sentence_type : str
        Three-letter sentence formatter (``"GGA"``, ...).
    fields : sequence of columns
        One sequence of already formatted strings per field, all of the same length.
    receive_time : ndarray, optional
        Logger receive times (UNIX seconds); written as a TAG block ``\\c:<ms>*hh\\``.

    Returns
    -------
    list of str
    """
    head = f"{talker}{sentence_type},"
    bodies = [head + ",".join(row) for row in zip(*fields, strict=True)]
    cs = hex_checksums(bodies)
    lines = [f"${b}*{c}" for b, c in zip(bodies, cs, strict=True)]
    if receive_time is None:
        return lines
    ms = np.round(np.asarray(receive_time, dtype=float) * 1000.0).astype(np.int64)
    tags = [f"c:{m}" for m in ms.tolist()]
    tcs = hex_checksums(tags)
    return [f"\\{t}*{c}\\{s}" for t, c, s in zip(tags, tcs, lines, strict=True)]


def _fixed(values: np.ndarray, decimals: int) -> list[str]:
    fmt = f"{{:.{decimals}f}}"
    return [fmt.format(v) for v in np.asarray(values, dtype=float).tolist()]


def _format_angle(deg_value: np.ndarray, decimals: int, deg_digits: int,
                  hemispheres: tuple[str, str]) -> tuple[list[str], list[str]]:
    """Degrees and decimal minutes (``deg_digits`` degree digits) and the hemisphere
    letter (``hemispheres = (positive, negative)``); minutes that round to 60 carry."""
    x = np.asarray(deg_value, dtype=float)
    a = np.abs(x)
    deg = np.floor(a)
    minutes = np.round((a - deg) * 60.0, decimals)
    carry = minutes >= 60.0
    deg = deg + carry
    minutes = np.where(carry, minutes - 60.0, minutes)
    w = 3 + decimals
    text = [f"{int(d):0{deg_digits}d}{m:0{w}.{decimals}f}"
            for d, m in zip(deg.tolist(), minutes.tolist(), strict=True)]
    hemi = np.where(x < 0, hemispheres[1], hemispheres[0]).tolist()
    return text, hemi


def format_latitude(lat_deg: np.ndarray, decimals: int = 7) -> tuple[list[str], list[str]]:
    """``ddmm.mmmmmmm`` and ``N``/``S`` columns."""
    return _format_angle(lat_deg, decimals, 2, ("N", "S"))


def format_longitude(lon_deg: np.ndarray, decimals: int = 7) -> tuple[list[str], list[str]]:
    """``dddmm.mmmmmmm`` and ``E``/``W`` columns."""
    return _format_angle(lon_deg, decimals, 3, ("E", "W"))


def _time_of_day(unix_seconds: np.ndarray, decimals: int
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Hours, minutes, seconds and ``decimals``-digit fraction of the UTC time of day."""
    scale = 10**decimals
    ticks = np.round(np.asarray(unix_seconds, dtype=float) * scale).astype(np.int64)
    sec_whole, frac = np.divmod(ticks % (86400 * scale), scale)
    hh, rem = np.divmod(sec_whole, 3600)
    mm, ss = np.divmod(rem, 60)
    return hh, mm, ss, frac


def format_utc_time(unix_seconds: np.ndarray, decimals: int = 2) -> list[str]:
    """``hhmmss.ss`` time of day of UNIX times (rounded to ``decimals``)."""
    hh, mm, ss, frac = _time_of_day(unix_seconds, decimals)
    return [f"{h:02d}{m:02d}{s:02d}.{f:0{decimals}d}" for h, m, s, f in
            zip(hh.tolist(), mm.tolist(), ss.tolist(), frac.tolist(), strict=True)]


def format_utc_date(unix_seconds: np.ndarray) -> list[str]:
    """``ddmmyy`` UTC dates of UNIX times."""
    days = np.floor(np.asarray(unix_seconds, dtype=float) / 86400.0).astype("datetime64[D]")
    text = np.datetime_as_string(days, unit="D")  # YYYY-MM-DD
    return [f"{t[8:10]}{t[5:7]}{t[2:4]}" for t in text.tolist()]


fixed = _fixed


# ----------------------------------------------------------------------------------------
# Byte-matrix formatting: a column of n fields is an (n, w) uint8 array of ASCII codes
# padded with zero bytes, which are dropped when the lines are written. No Python loop
# runs per sentence: digits come from integer arithmetic, checksums from an XOR reduction
# along the rows (the zero padding is neutral), lines are reordered as rows.

_HEX_BYTES = np.frombuffer("".join(f"{i:02X}" for i in range(256)).encode("ascii"),
                           dtype=np.uint8).reshape(256, 2)


def const_field(text: str, n: int) -> np.ndarray:
    """``n`` copies of ``text`` as an ``(n, len(text))`` byte matrix."""
    row = np.frombuffer(text.encode("ascii"), dtype=np.uint8)
    return np.broadcast_to(row, (n, row.size))


def _digits(ticks: np.ndarray, width: int) -> np.ndarray:
    """Zero-padded decimal digits of non-negative integers, ``(n, width)`` ASCII."""
    if width == 0:
        return np.zeros((ticks.size, 0), dtype=np.uint8)
    powers = 10 ** np.arange(width - 1, -1, -1, dtype=np.int64)
    return (ticks[:, None] // powers % 10 + 48).astype(np.uint8)


def _unpadded_digits(ticks: np.ndarray) -> np.ndarray:
    """Decimal digits without leading zeros (``0`` keeps one digit), zero-padded on the left."""
    top = int(ticks.max(initial=0))
    width = max(len(str(top)), 1)
    out = _digits(ticks, width)
    if width > 1:
        lead = ticks[:, None] < 10 ** np.arange(width - 1, 0, -1, dtype=np.int64)
        out[:, : width - 1][lead] = 0
    return out


def fixed_field(values: np.ndarray, decimals: int) -> np.ndarray:
    """``'{:.<decimals>f}'`` of every value as a byte matrix (non-finite values: empty field).

    The fraction is rounded to the nearest ``10⁻ᵈ`` (``np.rint`` of the exact fractional
    part times ``10ᵈ``), which can differ from Python's exactly rounded ``format`` in the
    last digit only for values within an ulp of a half tick; the sign is written for
    negative values as Python does (``-0.00``).
    """
    v = np.asarray(values, dtype=float)
    ok = np.isfinite(v)
    scale = 10**decimals
    mag = np.where(ok, np.abs(v), 0.0)
    whole = np.floor(mag) if decimals else np.rint(mag)  # ties to even, as format()
    frac = np.rint((mag - whole) * scale).astype(np.int64)  # mag − whole is exact
    whole = whole.astype(np.int64) + (frac >= scale)
    frac = np.where(frac >= scale, frac - scale, frac)
    sign = np.where(np.signbit(v) & ok, ord("-"), 0).astype(np.uint8)[:, None]
    parts = [sign, _unpadded_digits(whole)]
    if decimals > 0:
        parts += [const_field(".", v.size), _digits(frac, decimals)]
    out = np.hstack(parts) if v.size else np.zeros((0, 0), dtype=np.uint8)
    out[~ok] = 0
    return out


def _angle_fields(a_deg: np.ndarray, deg_width: int, decimals: int, signs: str):
    a = np.asarray(a_deg, dtype=float)
    mag = np.abs(a)
    deg = np.floor(mag).astype(np.int64)
    scale = 10**decimals
    ticks = np.rint((mag - deg) * 60.0 * scale).astype(np.int64)
    carry = ticks >= 60 * scale
    deg = deg + carry
    ticks = np.where(carry, ticks - 60 * scale, ticks)
    whole, frac = np.divmod(ticks, scale)
    text = np.hstack([_digits(deg, deg_width), _digits(whole, 2), const_field(".", a.size),
                      _digits(frac, decimals)])
    hemi = np.where(a < 0, ord(signs[1]), ord(signs[0])).astype(np.uint8)[:, None]
    return text, hemi


def latitude_fields(lat_deg: np.ndarray, decimals: int = 7) -> tuple[np.ndarray, np.ndarray]:
    """``ddmm.mmmmmmm`` and ``N``/``S`` byte matrices (as :func:`format_latitude`)."""
    return _angle_fields(lat_deg, 2, decimals, "NS")


def longitude_fields(lon_deg: np.ndarray, decimals: int = 7) -> tuple[np.ndarray, np.ndarray]:
    """``dddmm.mmmmmmm`` and ``E``/``W`` byte matrices (as :func:`format_longitude`)."""
    return _angle_fields(lon_deg, 3, decimals, "EW")


def utc_time_field(unix_seconds: np.ndarray, decimals: int = 2) -> np.ndarray:
    """``hhmmss.ss`` byte matrix (as :func:`format_utc_time`)."""
    hh, mm, ss, frac = _time_of_day(unix_seconds, decimals)
    return np.hstack([_digits(hh, 2), _digits(mm, 2), _digits(ss, 2),
                      const_field(".", hh.size), _digits(frac, decimals)])


def utc_date_field(unix_seconds: np.ndarray) -> np.ndarray:
    """``ddmmyy`` byte matrix (as :func:`format_utc_date`)."""
    days = np.floor(np.asarray(unix_seconds, dtype=float) / 86400.0).astype("datetime64[D]")
    month_start = days.astype("datetime64[M]")
    day = (days - month_start).astype(np.int64) + 1
    month = month_start.astype(np.int64) % 12 + 1
    year = days.astype("datetime64[Y]").astype(np.int64) + 1970
    return np.hstack([_digits(day, 2), _digits(month, 2), _digits(year % 100, 2)])


def sentence_rows(
    talker: str, sentence_type: str, fields: Sequence[np.ndarray],
    receive_time: np.ndarray | None = None,
) -> np.ndarray:
    """Complete sentences as a zero-padded byte matrix, one row per sentence, ending in CRLF.

    ``fields`` are byte matrices (:func:`fixed_field`, :func:`const_field`, ...) with the
    same number of rows; the rows equal :func:`sentence_lines` (plus ``\\r\\n``) with the
    zero bytes removed.
    """
    n = fields[0].shape[0] if fields else 0
    parts = [const_field(f"{talker}{sentence_type}", n)]
    for f in fields:
        parts += [const_field(",", n), f]
    body = np.hstack(parts)
    cs = _HEX_BYTES[np.bitwise_xor.reduce(body, axis=1)]
    line = [const_field("$", n), body, const_field("*", n), cs]
    if receive_time is not None:
        ms = np.round(np.asarray(receive_time, dtype=float) * 1000.0).astype(np.int64)
        tag = np.hstack([const_field("c:", n), _unpadded_digits(ms)])
        tcs = _HEX_BYTES[np.bitwise_xor.reduce(tag, axis=1)]
        line = [const_field("\\", n), tag, const_field("*", n), tcs, const_field("\\", n),
                *line]
    return np.hstack([*line, const_field("\r\n", n)])


def write_rows(blocks: Sequence[np.ndarray], order: np.ndarray, stream: Any,
               chunk: int = 1 << 16) -> None:
    """Write the rows of the stacked byte matrices ``blocks`` in ``order`` to a binary
    ``stream``, zero padding removed; ``chunk`` rows at a time (bounded extra memory)."""
    width = max((b.shape[1] for b in blocks), default=0)
    rows = np.zeros((sum(b.shape[0] for b in blocks), width), dtype=np.uint8)
    at = 0
    for b in blocks:  # right-align: the CRLF of every row lands in the last two columns
        rows[at:at + b.shape[0], width - b.shape[1]:] = b
        at += b.shape[0]
    for start in range(0, order.size, chunk):
        part = rows[order[start:start + chunk]]
        stream.write(part[part != 0].tobytes())
