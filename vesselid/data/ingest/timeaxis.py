"""Time columns of logged tables: duplicated (quantised) timestamps and their rebuild.

A logger that writes its time column with too few digits (e.g. three significant digits:
``123.456 s`` → ``123``) repeats each stamp for several rows. Dropping the repeats loses
most of the data and shifts the rest; interpolating them hides it. :func:`check_time_axis`
therefore refuses such a column unless the logger's sample rate is stated, and then rebuilds
the axis ``t_k = t_0 + k / rate`` from the row numbers, with ``t_0`` fitted to the stamps
(the mean rounding error is zero) and checked: the rebuilt times must stay within the
stamps' resolution (the largest step between distinct stamps) plus one sample of them,
otherwise the rate is wrong or the logger paused, and the table is refused.

Used by every table reader (mapped CSV, model-test tables): one rule, one message.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from vesselid.data.ingest.config import IngestError

__all__ = ["DUPLICATE_FRACTION", "check_time_axis"]

#: Duplicated stamps above this fraction of the rows mark a quantised time column; fewer
#: are dropped (the later row of each pair) and counted in the quality report.
DUPLICATE_FRACTION = 0.01


def check_time_axis(t: np.ndarray, where: str, sample_rate: float | None = None,
                    option: str = "--sample-rate HZ (or sample_rate in the [[csv]] table)"
                    ) -> tuple[np.ndarray, dict[str, Any]]:
    """Check a table's time column (s) and rebuild it when it is quantised.

    Parameters
    ----------
    t : ndarray
        Times in seconds, one per row (NaN where unparsable).
    where : str
        The table, for messages.
    sample_rate : float, optional
        The logger's sample rate (Hz). When given and the column has duplicated stamps,
        the axis is rebuilt from the row numbers.
    option : str
        How the user states the rate (named in the refusal).

    Returns
    -------
    t : ndarray
        The times (rebuilt, or the input unchanged).
    info : dict
        Empty when nothing was done; else ``time_rebuilt`` with ``sample_rate_hz``,
        ``duplicate_times``, ``max_shift_s`` (largest |rebuilt − stamp|).

    Raises
    ------
    IngestError
        More than :data:`DUPLICATE_FRACTION` duplicated stamps and no sample rate; or a
        stated rate that does not fit the stamps.
    """
    t = np.asarray(t, dtype=float)
    ok = np.isfinite(t)
    ft = t[ok]
    if ft.size < 3:
        return t, {}
    d = np.diff(ft)
    dup = int(np.sum(d == 0))
    if dup <= DUPLICATE_FRACTION * ft.size:
        return t, {}
    span = float(ft[-1] - ft[0])
    implied = (ft.size - 1) / span if span > 0 else float("nan")
    distinct = np.unique(ft)
    step = float(np.max(np.diff(distinct))) if distinct.size > 1 else float("nan")
    if sample_rate is None:
        raise IngestError(
            f"{where}: the time column repeats {dup} of {ft.size} timestamps (quantised to "
            f"~{step:.3g} s; about {implied:.3g} rows per second): state the logger's sample "
            f"rate with {option} to rebuild the time axis; rows are not dropped silently")
    k = np.arange(t.size, dtype=float)
    t0 = float(np.mean(ft - k[ok] / sample_rate))
    rebuilt = t0 + k / sample_rate
    shift = np.abs(rebuilt[ok] - ft)
    allowed = step + 1.0 / sample_rate
    worst = float(shift.max())
    if worst > allowed:
        j = int(np.argmax(shift))
        raise IngestError(
            f"{where}: the stated sample rate {sample_rate:g} Hz does not fit the time "
            f"column: the rebuilt time of row {int(np.flatnonzero(ok)[j])} is {worst:.3g} s "
            f"from its stamp (allowed {allowed:.3g} s; the stamps suggest about "
            f"{implied:.4g} Hz, or the logger paused)")
    return rebuilt, {"time_rebuilt": {"sample_rate_hz": float(sample_rate),
                                      "duplicate_times": dup, "max_shift_s": worst,
                                      "rows_without_time": int((~ok).sum())}}
