"""NMEA 0183 text, vectorised: checksums, sentence assembly and field conventions.

Shared by the raw-stream generator (:mod:`vesselid.rawstreams`) and the NMEA reader
(:mod:`vesselid.ingest.nmea`). Field order and names follow pynmea2's sentence
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

import numpy as np

__all__ = [
    "KNOT",
    "checksums",
    "field_index",
    "format_latitude",
    "format_longitude",
    "format_utc_date",
    "format_utc_time",
    "hex_checksums",
    "sentence_lines",
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


def format_utc_time(unix_seconds: np.ndarray, decimals: int = 2) -> list[str]:
    """``hhmmss.ss`` time of day of UNIX times (rounded to ``decimals``)."""
    scale = 10**decimals
    ticks = np.round(np.asarray(unix_seconds, dtype=float) * scale).astype(np.int64)
    tod = ticks % (86400 * scale)
    sec_whole, frac = np.divmod(tod, scale)
    hh, rem = np.divmod(sec_whole, 3600)
    mm, ss = np.divmod(rem, 60)
    return [f"{h:02d}{m:02d}{s:02d}.{f:0{decimals}d}" for h, m, s, f in
            zip(hh.tolist(), mm.tolist(), ss.tolist(), frac.tolist(), strict=True)]


def format_utc_date(unix_seconds: np.ndarray) -> list[str]:
    """``ddmmyy`` UTC dates of UNIX times."""
    days = np.floor(np.asarray(unix_seconds, dtype=float) / 86400.0).astype("datetime64[D]")
    text = np.datetime_as_string(days, unit="D")  # YYYY-MM-DD
    return [f"{t[8:10]}{t[5:7]}{t[2:4]}" for t in text.tolist()]


fixed = _fixed
