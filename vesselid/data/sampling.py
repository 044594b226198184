"""The sampling of a trial log against the model's sample time (``identify``'s check).

The identified model is a discrete-time model at the spec's ``dt`` (paper eq. (2): one
step of the recursion is one sample). A log sampled at another interval, or irregularly,
gives a model that is silently wrong (its ``dt`` exported as the spec says). Hence
:func:`check_sampling`, run by ``vesselid identify`` before anything is estimated:

* the ``time`` column's steps, per experiment, must all lie within ``tolerance · h`` of
  their median ``h`` (regular sampling), and
* ``h`` must equal the spec's ``dt`` within ``tolerance · dt``.

Otherwise the log is refused with one line naming ``vesselid ingest --dt`` (which
resamples any timestamped log onto a uniform grid). Cases without a check: a log without
a ``time`` column (its rows are taken as the samples, at the spec's ``dt``), a spec without
``dt`` (only the regularity is checked; the log's interval is reported), experiments of
fewer than two rows.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from vesselid.errors import LogValidationError

__all__ = ["DEFAULT_TOLERANCE", "SamplingError", "SamplingReport", "check_sampling"]

#: Relative tolerance on every time step (1 %: a float text column of ``k·dt`` is far
#: inside it; timestamp jitter of real loggers is not, and needs ``ingest``).
DEFAULT_TOLERANCE = 0.01


class SamplingError(LogValidationError):
    """The log's sampling interval disagrees with the spec's ``dt``, or is irregular."""


@dataclass(frozen=True)
class SamplingReport:
    """What :func:`check_sampling` found.

    Attributes
    ----------
    interval : float or None
        Median time step over the experiments (s); ``None`` without a time column.
    spec_dt : float or None
    checked : bool
        Whether a time column was there to check.
    worst_step_deviation : float
        Largest ``|step − median| / median`` over the experiments (0 when unchecked).
    """

    interval: float | None
    spec_dt: float | None
    checked: bool
    worst_step_deviation: float = 0.0


def _experiment_runs(column: Any) -> list[tuple[Any, np.ndarray]] | None:
    """``groupby(sort=False).indices`` of an experiment column whose experiments are
    contiguous runs of rows with distinct labels and no missing label (what a log holds):
    the same keys in the same order with the same positions, from the run boundaries
    instead of a hash grouping. None where that does not hold (the caller groups)."""
    import pandas as pd

    if isinstance(column.dtype, pd.CategoricalDtype):
        return None
    e = column.to_numpy()
    if e.size == 0 or bool(pd.isna(e).any()):
        return None
    cut = np.flatnonzero(e[1:] != e[:-1]) + 1
    bounds = np.concatenate([[0], cut, [e.size]])
    keys = [column.iloc[int(a)] for a in bounds[:-1]]
    if len(set(keys)) != len(keys):
        return None
    return [(k, np.arange(a, b)) for k, a, b in zip(keys, bounds[:-1], bounds[1:],
                                                    strict=True)]


def _name(eid: Any) -> str:
    return repr(eid.item() if hasattr(eid, "item") else eid)


def _fix(dt: float) -> str:
    return f"vesselid ingest RAW --dt {dt:g}"


def check_sampling(log: Any, spec_dt: float | None, *,
                   tolerance: float = DEFAULT_TOLERANCE) -> SamplingReport:
    """Refuse a log whose sampling is irregular or disagrees with ``spec_dt``.

    Parameters
    ----------
    log : TrialLog or pandas.DataFrame
        With an optional ``time`` column (s) and optional ``experiment`` column.
    spec_dt : float or None
        The model's sample time (``ModelSpec.dt``).
    tolerance : float
        Relative tolerance on each step and on the median step against ``spec_dt``.

    Returns
    -------
    SamplingReport

    Raises
    ------
    SamplingError
        One line naming the experiment, the steps found and ``ingest --dt``.
    """
    if not (math.isfinite(tolerance) and 0 <= tolerance < 1):
        raise SamplingError(f"the sampling tolerance must be in [0, 1), got {tolerance}")
    data = getattr(log, "data", log)
    if "time" not in data.columns:
        return SamplingReport(None, spec_dt, False)
    t = data["time"].to_numpy(dtype=float)
    if "experiment" in data.columns:
        groups = _experiment_runs(data["experiment"])
        if groups is None:
            groups = list(data.groupby("experiment", sort=False).indices.items())
    else:
        groups = [(0, np.arange(t.size))]
    medians: list[tuple[Any, float]] = []
    worst = 0.0
    for eid, pos in groups:
        if pos.size < 2:
            continue
        steps = np.diff(t[pos])
        h = float(np.median(steps))
        if not (math.isfinite(h) and h > 0):
            continue  # reading the log refuses non-increasing time
        dev = np.abs(steps - h)
        j = int(np.argmax(dev))
        rel = float(dev[j] / h)
        worst = max(worst, rel)
        if rel > tolerance:
            target = spec_dt if spec_dt is not None else h
            raise SamplingError(
                f"irregular sampling in experiment {_name(eid)}: time steps from "
                f"{float(steps.min()):.4g} to {float(steps.max()):.4g} s (median {h:.4g} s; "
                f"the step before row {int(pos[j + 1])} is {float(steps[j]):.4g} s, beyond "
                f"the {100 * tolerance:g} % tolerance): resample it onto a uniform grid with "
                f"`{_fix(target)}`")
        medians.append((eid, h))
    if not medians:
        return SamplingReport(None, spec_dt, False)
    interval = float(np.median([h for _a, h in medians]))
    if spec_dt is not None:
        for eid, h in medians:
            if abs(h - spec_dt) > tolerance * spec_dt:
                raise SamplingError(
                    f"the log is sampled every {h:.4g} s (experiment {_name(eid)}) but the "
                    f"spec's dt is {spec_dt:g} s: set dt = {h:.6g} in the spec, or resample "
                    f"the log with `{_fix(spec_dt)}`")
    return SamplingReport(interval, spec_dt, True, worst)
