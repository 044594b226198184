"""Time series of one raw channel, and their resampling onto a uniform grid.

Every reader (NMEA, ROS 2 bag, CSV) produces :class:`Stream` objects: samples of one
canonical channel (``lat``, ``lon``, ``vel_north``, ``psi``, ``r``, an input ...) at their
own, irregular times on the common clock (UNIX seconds, UTC). :func:`resample` puts a
stream on the grid ``t_k = k·dt``:

* faster than the grid (rate > 1.25/dt): linear interpolation onto an integer multiple ``m``
  of the grid rate, then :func:`scipy.signal.resample_poly` (zero-phase FIR anti-aliasing
  filter, decimation by ``m``),
* otherwise linear interpolation,
* commands (``kind="hold"``): zero-order hold of the last command logged at or before the
  grid time (within half a command period, so that timestamp jitter does not shift a step
  by one sample),
* angles (``kind="angle"``) are unwrapped before and kept unwrapped after.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

__all__ = ["Stream", "coverage", "resample"]

KINDS = ("linear", "angle", "hold")


@dataclass
class Stream:
    """Samples of one channel.

    Attributes
    ----------
    name : str
        Canonical channel name.
    t : ndarray
        Sample times, UNIX seconds (sorted, unique after :meth:`clean`).
    values : ndarray
        Sample values (SI units; angles in rad).
    kind : {"linear", "angle", "hold"}
    source : str
        Where the samples came from (file, sentence/topic/column), for the quality report.
    priority : int
        Lower wins when two sources provide the same channel.
    notes : dict
        Source-specific counts copied into the quality report.
    """

    name: str
    t: np.ndarray
    values: np.ndarray
    kind: str = "linear"
    source: str = ""
    priority: int = 0
    notes: dict[str, Any] = field(default_factory=dict)

    def clean(self) -> Stream:
        """Drop non-finite samples and duplicate times; sort by time."""
        t = np.asarray(self.t, dtype=float)
        x = np.asarray(self.values, dtype=float)
        ok = np.isfinite(t) & np.isfinite(x)
        dropped = int((~ok).sum())
        t, x = t[ok], x[ok]
        order = np.argsort(t, kind="stable")
        t, x = t[order], x[order]
        dup = np.concatenate([[False], np.diff(t) <= 0])
        if dup.any():
            t, x = t[~dup], x[~dup]
        if dropped:
            self.notes["non_finite"] = self.notes.get("non_finite", 0) + dropped
        if dup.any():
            self.notes["duplicate_times"] = self.notes.get("duplicate_times", 0) + int(dup.sum())
        self.t, self.values = t, x
        return self

    @property
    def period(self) -> float:
        """Median sample spacing (s); ``inf`` with fewer than two samples."""
        if self.t.size < 2:
            return math.inf
        return float(np.median(np.diff(self.t)))


def max_gap_for(stream: Stream, max_gap: float) -> float:
    """Longest spacing still bridged by interpolation: ``max(max_gap, 3 periods)``."""
    p = stream.period
    return max(max_gap, 3.0 * p) if math.isfinite(p) else max_gap


def coverage(stream: Stream, grid: np.ndarray, max_gap: float) -> np.ndarray:
    """Grid points where the stream can give a value (inside its samples, no long gap).

    Within half a period beyond the first/last sample counts as covered (edge values).
    """
    t = stream.t
    if t.size == 0:
        return np.zeros(grid.size, dtype=bool)
    gap = max_gap_for(stream, max_gap)
    p = stream.period
    edge = 0.5 * p if math.isfinite(p) else 0.0
    j = np.searchsorted(t, grid, side="right") - 1
    inside = (j >= 0) & (j < t.size - 1)
    jj = np.clip(j, 0, max(t.size - 2, 0))
    ok = np.zeros(grid.size, dtype=bool)
    if t.size >= 2:
        ok = inside & ((t[jj + 1] - t[jj]) <= gap)
    if stream.kind == "hold":
        # a command holds until the next one (or one period after the last)
        ok |= (j == t.size - 1) & (grid - t[-1] <= (p if math.isfinite(p) else 0.0) + 1e-9)
    ok |= np.abs(grid - t[0]) <= edge + 1e-9
    ok |= np.abs(grid - t[-1]) <= edge + 1e-9
    return ok


def resample(stream: Stream, grid: np.ndarray, dt: float) -> tuple[np.ndarray, dict[str, Any]]:
    """Values of ``stream`` on ``grid`` (one contiguous segment of ``t_k = k·dt``).

    Returns
    -------
    values : ndarray
    info : dict
        ``method`` and ``bridged`` (grid points whose neighbouring samples are more than
        1.5 periods apart, i.e. interpolated across a dropout).
    """
    t, x = stream.t, stream.values
    if stream.kind == "angle":
        x = np.unwrap(x)
    p = stream.period
    j = np.searchsorted(t, grid, side="right") - 1
    jj = np.clip(j, 0, max(t.size - 2, 0))
    if t.size >= 2 and math.isfinite(p):
        spacing = t[jj + 1] - t[jj]
        inside = (j >= 0) & (j < t.size - 1)
        bridged = inside & (spacing > 1.5 * p)
    else:
        bridged = np.zeros(grid.size, dtype=bool)
    if stream.kind == "hold":
        tol = 0.5 * min(dt, p) if math.isfinite(p) else 0.5 * dt
        k = np.searchsorted(t, grid + tol, side="right") - 1
        values = x[np.clip(k, 0, t.size - 1)]
        return values, {"method": "hold", "bridged": int(bridged.sum())}
    rate_ratio = dt / p if math.isfinite(p) and p > 0 else 0.0
    if rate_ratio > 1.25 and grid.size > 1:
        m = max(2, math.ceil(rate_ratio - 0.01))
        fine = grid[0] + np.arange((grid.size - 1) * m + 1) * (dt / m)
        xf = np.interp(fine, t, x)
        from scipy import signal

        # odd reflection about the segment ends (keeps value and slope, as filtfilt pads),
        # a whole number of output samples long, so the FIR sees no artificial edge step
        k = 12
        pad = min(k * m, xf.size - 1)
        pad -= pad % m
        xp = np.pad(xf, pad, mode="reflect", reflect_type="odd") if pad else xf
        y = signal.resample_poly(xp, 1, m, padtype="constant")
        values = y[pad // m: pad // m + grid.size]
        method = f"anti-aliased decimation x{m} (resample_poly)"
    else:
        values = np.interp(grid, t, x)
        method = "linear interpolation" if rate_ratio >= 0.8 else "linear interpolation (upsampled)"
    return values, {"method": method, "bridged": int(bridged.sum())}


def stream_quality(stream: Stream) -> dict[str, Any]:
    """Rate, dropouts and gaps of a stream's raw samples."""
    t = stream.t
    p = stream.period
    out: dict[str, Any] = {"source": stream.source, "samples": int(t.size)}
    if t.size >= 2 and math.isfinite(p):
        d = np.diff(t)
        gaps = d > 1.5 * p
        out["rate_hz"] = float(1.0 / p) if p > 0 else None
        out["dropouts"] = int(gaps.sum())
        out["missing_samples"] = int(np.sum(np.round(d[gaps] / p) - 1)) if gaps.any() else 0
        out["longest_gap_s"] = float(d.max())
        out["span_s"] = float(t[-1] - t[0])
    out.update(stream.notes)
    return out
