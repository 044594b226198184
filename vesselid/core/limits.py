"""Resource guard: refuse a request that does not fit this machine *before* allocating it.

Every command estimates from its arguments alone (no data is allocated, nothing is
simulated) how much memory, disk and time it needs, and calls :func:`check`. A
request beyond a limit raises :class:`~vesselid.errors.ResourceLimitError` (a
``ValueError``; the command line turns it into exit code 2) with a one-line reason
naming the need and the limit, e.g.::

    simulate: 1e+13 samples need ~3.6 PB of memory; this machine has 18.7 GB available
    (80% of MemAvailable; set VESSELID_MAX_MEMORY to change)

Limits
------
* memory: 80 % of the memory available now (``MemAvailable`` in ``/proc/meminfo``,
  else ``os.sysconf`` pages; no psutil needed), or ``VESSELID_MAX_MEMORY`` (bytes,
  suffixes k/M/G/T allowed);
* disk: the free space of the file system an output goes to, less 1 %;
* time: ``VESSELID_MAX_SECONDS`` (default 24 h).

The estimators below use per-value costs measured on the development machine
(2 cores; see the constants) and are deliberately generous: a refused request
would really not have fitted, and a request that passes may still be slow.
Commands whose output may exceed the memory budget (``simulate``) stream it to
disk in chunks instead of refusing; see :mod:`vesselid.plant.todisk`.

Public API for commands
-----------------------
:func:`check` (the guard), :func:`table_memory`, :func:`file_bytes`,
:func:`write_seconds`, :func:`simulation_seconds`, :func:`available_memory`,
:func:`free_disk`, :func:`memory_limit`, :func:`time_limit`,
:func:`format_bytes`, :func:`format_seconds`.
"""

from __future__ import annotations

import math
import os
import re
import shutil
from pathlib import Path

from vesselid.errors import ResourceLimitError

__all__ = [
    "BASE_MEMORY",
    "BYTES_PER_VALUE",
    "MEMORY_FRACTION",
    "STREAM_HINT",
    "available_memory",
    "check",
    "check_file_size",
    "check_grid",
    "check_inputs",
    "file_bytes",
    "format_bytes",
    "format_seconds",
    "free_disk",
    "memory_limit",
    "raw_read_memory",
    "raw_read_seconds",
    "read_memory",
    "read_seconds",
    "simulation_seconds",
    "table_memory",
    "time_limit",
    "write_seconds",
]

#: Share of the available memory one request may plan to use.
MEMORY_FRACTION = 0.8
#: Default time limit (seconds) unless ``VESSELID_MAX_SECONDS`` says otherwise.
DEFAULT_TIME_LIMIT = 24 * 3600.0
#: Resident memory of the interpreter with numpy, pandas, pyarrow and numba loaded and
#: LLVM initialised (measured ~215 MB at the start of a long log's fit).
BASE_MEMORY = 250e6
#: Peak memory per float64 value of a tidy log while simulating and writing it: the
#: simulation arrays, the DataFrame and the CSV formatter's buffers. Measured 28 B
#: (heave, 7 columns) and 36 B (CyberShip II, 14 columns); 48 B leaves a margin.
BYTES_PER_VALUE = 48.0
#: Bytes per value in a CSV file written with 17 significant digits (measured 16-19 B).
CSV_BYTES_PER_VALUE = 21.0
#: Bytes per value in a Parquet file (float64, random data barely compresses).
PARQUET_BYTES_PER_VALUE = 8.5
#: Seconds to format and write one value as CSV text (measured ~1.5 µs on 2 busy cores).
CSV_SECONDS_PER_VALUE = 2.5e-6
#: Seconds to write one value to Parquet.
PARQUET_SECONDS_PER_VALUE = 5e-8
#: Seconds per sample and state of the compiled simulation including drawing the noise
#: (CyberShip II, the slowest plant: ~4 µs per sample for 3 states; heave ~0.05 µs).
SIMULATION_SECONDS_PER_STATE_SAMPLE = 2e-6

_SUFFIX = {"": 1.0, "k": 1e3, "m": 1e6, "g": 1e9, "t": 1e12, "p": 1e15}


def _parse_size(text: str) -> float | None:
    m = re.fullmatch(r"\s*([0-9]*\.?[0-9]+(?:e[0-9]+)?)\s*([kmgtp]?)i?b?\s*", text.lower())
    if m is None:
        return None
    return float(m[1]) * _SUFFIX[m[2]]


def available_memory() -> float | None:
    """Bytes of memory available to a new allocation now, or ``None`` when unknown.

    Reads ``MemAvailable`` from ``/proc/meminfo`` (Linux); elsewhere uses
    ``os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")``.
    """
    try:
        with open("/proc/meminfo", encoding="ascii") as fh:
            for line in fh:
                if line.startswith("MemAvailable:"):
                    return float(line.split()[1]) * 1024.0
    except (OSError, ValueError, IndexError):
        pass
    try:
        pages = os.sysconf("SC_AVPHYS_PAGES")
        size = os.sysconf("SC_PAGE_SIZE")
    except (AttributeError, ValueError, OSError):
        return None
    if pages <= 0 or size <= 0:
        return None
    return float(pages) * float(size)


def memory_limit() -> tuple[float, str]:
    """Memory one request may use, in bytes, and where that number comes from."""
    env = os.environ.get("VESSELID_MAX_MEMORY")
    if env:
        value = _parse_size(env)
        if value is not None:
            return value, "VESSELID_MAX_MEMORY"
    avail = available_memory()
    if avail is None:
        return math.inf, "available memory unknown"
    return MEMORY_FRACTION * avail, (
        f"{MEMORY_FRACTION:.0%} of the {format_bytes(avail)} available; "
        "set VESSELID_MAX_MEMORY to change")


def time_limit() -> tuple[float, str]:
    """Seconds one request may plan to run, and where that number comes from."""
    env = os.environ.get("VESSELID_MAX_SECONDS")
    if env:
        try:
            value = float(env)
        except ValueError:
            value = math.nan
        if value > 0:
            return value, "VESSELID_MAX_SECONDS"
    return DEFAULT_TIME_LIMIT, "default; set VESSELID_MAX_SECONDS to change"


def free_disk(path: str | os.PathLike[str]) -> float | None:
    """Free bytes on the file system that ``path`` (or its nearest existing parent) is on."""
    p = Path(path).absolute()
    for candidate in (p, *p.parents):
        try:
            if candidate.exists():
                return float(shutil.disk_usage(candidate).free)
        except OSError:
            return None
    return None


def format_bytes(n: float) -> str:
    """``1.5 GB`` style (decimal units)."""
    if not math.isfinite(n):
        return "unlimited"
    for unit, scale in (("EB", 1e18), ("PB", 1e15), ("TB", 1e12), ("GB", 1e9), ("MB", 1e6),
                        ("kB", 1e3)):
        if n >= scale:
            return f"{n / scale:.3g} {unit}"
    return f"{n:.0f} B"


def format_seconds(s: float) -> str:
    """``3.2 h`` style."""
    if not math.isfinite(s):
        return "forever"
    for unit, scale in (("years", 365.25 * 86400), ("days", 86400), ("h", 3600), ("min", 60)):
        if s >= scale:
            return f"{s / scale:.3g} {unit}"
    return f"{s:.3g} s"


# ------------------------------------------------------------------- estimators
def table_memory(rows: float, columns: float, *, per_value: float = BYTES_PER_VALUE) -> float:
    """Peak bytes to build and write a ``rows × columns`` float64 table (plus the interpreter)."""
    return BASE_MEMORY + float(rows) * float(columns) * per_value


def file_bytes(rows: float, columns: float, fmt: str = "csv") -> float:
    """Size on disk of a ``rows × columns`` log written as ``"csv"`` or ``"parquet"``."""
    per = CSV_BYTES_PER_VALUE if fmt == "csv" else PARQUET_BYTES_PER_VALUE
    return float(rows) * float(columns) * per


def write_seconds(rows: float, columns: float, fmt: str = "csv") -> float:
    """Seconds to write a ``rows × columns`` log."""
    per = CSV_SECONDS_PER_VALUE if fmt == "csv" else PARQUET_SECONDS_PER_VALUE
    return float(rows) * float(columns) * per


def simulation_seconds(samples: float, states: int) -> float:
    """Seconds to simulate ``samples`` samples (all runs) of a plant with ``states`` states."""
    return float(samples) * max(int(states), 1) * SIMULATION_SECONDS_PER_STATE_SAMPLE


#: Peak bytes per value of reading a log and identifying a model from it (the parsed
#: frame, the float arrays, regressors and instruments of every equation).
READ_BYTES_PER_VALUE = 120.0
#: Seconds per value to parse a CSV log and identify (parsing dominates).
READ_SECONDS_PER_VALUE = 1e-6


def read_memory(rows: float, columns: float) -> float:
    """Peak bytes to load a ``rows × columns`` log and identify a model from it."""
    return BASE_MEMORY + float(rows) * max(float(columns), 4.0) * READ_BYTES_PER_VALUE


def read_seconds(rows: float, columns: float) -> float:
    """Seconds to load a ``rows × columns`` log and identify a model from it."""
    return float(rows) * float(columns) * READ_SECONDS_PER_VALUE


# ------------------------------------------------------------------------ guard
#: The memory refusal's advice for logs beyond memory (``identify``).
STREAM_HINT = ("for a log beyond memory, `vesselid identify --stream` reads a Parquet log "
               "(or a directory of them) one experiment at a time")


def check(
    command: str,
    what: str,
    *,
    memory: float = 0.0,
    seconds: float = 0.0,
    disk: float = 0.0,
    disk_path: str | os.PathLike[str] | None = None,
    memory_hint: str = "",
) -> None:
    """Refuse a request whose estimated needs exceed this machine's limits.

    Parameters
    ----------
    command : str
        Command name for the message (``"simulate"``).
    what : str
        The request in words (``"1e+09 samples × 7 columns"``).
    memory, seconds, disk : float
        Estimated peak memory (bytes), run time (seconds) and output size (bytes).
    disk_path : path, optional
        Where the output goes (its file system's free space is the disk limit).
    memory_hint : str, optional
        What to do instead when the memory does not suffice (appended to that refusal,
        e.g. ``identify``'s ``--stream``).

    Raises
    ------
    ResourceLimitError
        With a one-line reason naming the estimate and the limit.
    """
    mem_limit, mem_why = memory_limit()
    if not memory <= mem_limit:  # also catches NaN
        raise ResourceLimitError(
            f"{command}: {what} would need ~{format_bytes(memory)} of memory; the limit is "
            f"{format_bytes(mem_limit)} ({mem_why})" + (f"; {memory_hint}" if memory_hint
                                                         else ""))
    if disk and disk_path is not None:
        free = free_disk(disk_path)
        if free is not None and not disk <= 0.99 * free:
            raise ResourceLimitError(
                f"{command}: {what} would need ~{format_bytes(disk)} on disk; "
                f"{format_bytes(free)} are free at {Path(disk_path).absolute().parent}")
    t_limit, t_why = time_limit()
    if not seconds <= t_limit:
        raise ResourceLimitError(
            f"{command}: {what} would take ~{format_seconds(seconds)}; the limit is "
            f"{format_seconds(t_limit)} ({t_why})")


# ------------------------------------------------------------------- raw sensor files
#: Peak bytes of memory per byte of raw input (NMEA text, mapped CSV, bag) while ingest
#: parses it into streams and resamples them: measured ~5 B/B (29 MB of NMEA + CSV from
#: ``simulate --raw``: 337 MB peak, 190 MB of it the interpreter); 12 leaves a margin.
RAW_BYTES_PER_BYTE = 12.0
#: Seconds per byte of raw input (measured ~5e-8 s/B on 2 busy cores).
RAW_SECONDS_PER_BYTE = 2e-7


def raw_read_memory(n_bytes: float) -> float:
    """Peak bytes to ingest ``n_bytes`` of raw sensor files."""
    return BASE_MEMORY + float(n_bytes) * RAW_BYTES_PER_BYTE


def raw_read_seconds(n_bytes: float) -> float:
    """Seconds to ingest ``n_bytes`` of raw sensor files."""
    return float(n_bytes) * RAW_SECONDS_PER_BYTE


def _input_bytes(paths: list[Path]) -> tuple[int, int]:
    """Total size and count of the regular files under ``paths`` (directories walked)."""
    total = count = 0
    for p in paths:
        if p.is_dir():
            for root, _dirs, files in os.walk(p):
                for f in files:
                    try:
                        total += os.stat(os.path.join(root, f)).st_size
                        count += 1
                    except OSError:
                        continue
        elif p.is_file():
            total += p.stat().st_size
            count += 1
    return total, count


def check_inputs(command: str, paths: list[str | os.PathLike[str]]) -> None:
    """Refuse raw inputs (files and directories) too large to ingest on this machine.

    Uses the files' sizes on disk only (a 200 GB sparse file is refused at once).
    """
    total, count = _input_bytes([Path(p) for p in paths])
    check(command, f"{count} raw input file(s), {format_bytes(total)}",
          memory=raw_read_memory(total), seconds=raw_read_seconds(total))


def check_file_size(path: str | os.PathLike[str], command: str = "ingest") -> None:
    """Refuse one raw input file too large to parse on this machine (see :func:`check_inputs`)."""
    check_inputs(command, [path])


#: Seconds per grid value to resample, convert and write (measured 3e-7 s: 8e6 × 14 in 33 s).
GRID_SECONDS_PER_VALUE = 5e-7


def check_grid(command: str, points: float, channels: float) -> None:
    """Refuse a resampling grid of ``points`` × ``channels`` values that does not fit."""
    check(command, f"a grid of {points:.3g} samples × {int(channels)} channels",
          memory=table_memory(points, channels + 2),
          seconds=float(points) * (channels + 2) * GRID_SECONDS_PER_VALUE)
