"""Regression data: trial logs (or simulated arrays) turned into concatenated segments.

One :class:`RegressionData` holds everything the estimators need, for one log
with several experiments or for a whole Monte Carlo study (one parameter group
per run):

* ``target`` — the state measurements ``y(k)`` (the left-hand side of (4)/(10)),
* ``regsig`` — the signal the regressors are built from: ``y`` for the predictor
  (3), the aggregated ``ỹ = y ± y₂`` for the aggregated-state predictor (9),
* ``u`` — the known inputs,
* ``starts`` — segment (experiment) boundaries, ``group`` — segment → group.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from functools import cached_property
from typing import Any

import numpy as np

from vesselid.errors import IdentificationError, LogValidationError
from vesselid.model.spec import ModelSpec

__all__ = ["RegressionData", "from_arrays", "from_log"]


@dataclass(frozen=True)
class RegressionData:
    """Concatenated regression data (see module docstring)."""

    target: np.ndarray
    regsig: np.ndarray
    u: np.ndarray
    starts: np.ndarray
    group: np.ndarray
    n_groups: int
    experiment_ids: tuple = ()
    sensor: np.ndarray | None = None
    #: the log's signals were low-pass filtered (``metadata["wave_filter"]``, e.g.
    #: ``sea-trial --wave-filter``): a whitening noise-model prefilter would re-weight the
    #: regression toward the band the filter removed
    lowpassed: bool = False
    #: std of the white sensor noise on each regressor signal (``regsig`` column), for the
    #: errors-in-variables correction of the square modulus regressors
    #: (:mod:`vesselid.identify.eiv`); ``None``: no correction
    regressor_noise: np.ndarray | None = None
    #: AR order of the noise-model prefilter identify's ``noise_order`` asks for; ``None``:
    #: the estimator's own. Used by the estimators that prefilter (SRIV, ``auto``'s fallback)
    noise_order: int | None = None

    @property
    def n_segments(self) -> int:
        return int(self.starts.size - 1)

    @property
    def lengths(self) -> np.ndarray:
        return np.diff(self.starts)

    @cached_property
    def target_abs_max(self) -> np.ndarray:
        """``max |target|`` per segment (:func:`segment_abs_max`), computed once: every
        refined-IV call scales its divergence limits by it."""
        out = segment_abs_max(self.target, self.starts)
        out.flags.writeable = False
        return out

    def group_rows(self, g: int) -> tuple[slice, np.ndarray]:
        """The rows of group ``g`` (its experiments are contiguous) and its experiment
        starts relative to them."""
        segs = np.flatnonzero(self.group == g)
        a, b = int(self.starts[segs[0]]), int(self.starts[segs[-1] + 1])
        return slice(a, b), self.starts[segs[0]: segs[-1] + 2] - a

    def segment(self, s: int) -> slice:
        return slice(int(self.starts[s]), int(self.starts[s + 1]))

    def check_lengths(self, spec: ModelSpec, min_samples: int | None = None) -> None:
        """Every experiment needs enough samples to estimate its equations."""
        p_max = max(len(t) for t in spec.equations.values())
        need = max(p_max + 2, 3) if min_samples is None else int(min_samples)
        short = np.flatnonzero(self.lengths < need)
        if short.size:
            s = int(short[0])
            eid = self.experiment_ids[s] if self.experiment_ids else s
            raise IdentificationError(
                f"experiment {eid} has {int(self.lengths[s])} samples; at least {need} are "
                f"needed for {p_max} parameters per equation"
            )


def _aggregated(spec: ModelSpec, states: np.ndarray, sensors: dict[str, np.ndarray]):
    if not any(s in spec.aggregate for s in spec.states):
        # nothing aggregated: the regressors are built from the measured states
        # themselves (one array serves both; nothing writes into either)
        return states, np.zeros(states.shape)
    regsig = states.copy()
    sensor = np.zeros(states.shape)  # calloc: pages untouched where nothing is aggregated
    for i, s in enumerate(spec.states):
        if s in spec.aggregate:
            agg = spec.aggregate[s]
            if agg.sign == 0:  # the column measures the aggregated state itself
                regsig[:, i] = sensors[agg.sensor]
                sensor[:, i] = regsig[:, i] - states[:, i]
            else:
                sensor[:, i] = agg.sign * sensors[agg.sensor]
                regsig[:, i] = states[:, i] + sensor[:, i]
    return regsig, sensor


def from_log(log, spec: ModelSpec | None = None, *, min_samples: int | None = None,
             sensor_noise: Any = None, noise_order: int | None = None):
    """Build regression data from a :class:`~vesselid.data.logs.TrialLog` (or DataFrame).

    The log is validated first (missing columns, NaN/inf, time order, samples per
    experiment); nothing is silently dropped. ``sensor_noise`` (``{state: σ}``, or
    ``False`` for none; default the log's ``metadata["sensor_noise_std"]``) sets
    ``regressor_noise`` (:func:`vesselid.identify.eiv.resolve_sensor_noise`);
    ``noise_order`` the AR order of the noise-model prefilter (an integer in 1..50; default
    ``None``: the estimator's own; never read from the log).

    Returns
    -------
    (RegressionData, ModelSpec)
    """
    from vesselid.data.logs import TrialLog

    if not isinstance(log, TrialLog):
        log = TrialLog(log)
    spec = spec or log.spec
    if spec is None:
        raise IdentificationError("no model spec given and the log carries none")
    if spec.derived:  # states/inputs computed from measured columns (vesselid.model.derived)
        from vesselid.model.derived import add_derived, state_dependent

        log = TrialLog(add_derived(log.data, spec), log.metadata)
        dep = state_dependent(spec)
        if dep:
            import warnings

            from vesselid.errors import DerivedInputWarning

            uses = "; ".join(f"{k} uses {list(v)}" for k, v in dep.items())
            warnings.warn(f"derived input(s) computed from measured states ({uses}) are not "
                          f"exogenous: the consistency results of the instrumental-variable "
                          f"estimators do not cover their parameters (see vesselid.model.derived)",
                          DerivedInputWarning, stacklevel=2)
    # validated; the rows of each experiment (TrialLog.experiments() order) as the
    # validation split them, taken from the columns directly: no sub-frame copies, and
    # column by column (selecting a list of columns builds a new frame, ~50x slower)
    parts = log._validate(spec)
    lengths = [pos.size for _, pos in parts]
    starts = np.concatenate([[0], np.cumsum(lengths)]).astype(np.int64)
    order = np.concatenate([pos for _, pos in parts])
    if order.size == len(log.data) and np.array_equal(order, np.arange(order.size)):
        order = None  # one experiment (or sorted ones): every row, in place

    def take(x: np.ndarray) -> np.ndarray:
        return x if order is None else x[order]

    try:
        states = take(_columns(log.data, spec.states))
        inputs = (take(_columns(log.data, spec.inputs)) if spec.inputs
                  else np.zeros((starts[-1], 0)))
        sensors = {c: take(log.data[c].to_numpy(float, copy=True)) for c in spec.sensors}
    except (KeyError, ValueError) as exc:  # pragma: no cover - validate() catches these first
        raise LogValidationError(str(exc)) from exc
    regsig, sensor = _aggregated(spec, states, sensors)
    from vesselid.identify.eiv import resolve_sensor_noise

    noise = resolve_sensor_noise(sensor_noise, log.metadata, spec.states)
    data = RegressionData(
        target=np.ascontiguousarray(states),
        regsig=np.ascontiguousarray(regsig),
        u=np.ascontiguousarray(inputs),
        starts=starts,
        group=np.zeros(len(parts), dtype=np.int64),
        n_groups=1,
        experiment_ids=tuple(eid for eid, _ in parts),
        sensor=sensor,
        lowpassed=bool((log.metadata or {}).get("wave_filter")),
        regressor_noise=noise,
        noise_order=_noise_order(noise_order),
    )
    data.check_lengths(spec, min_samples)
    return data, spec


def _noise_order(val: Any) -> int | None:
    """The AR noise-model order asked for, or ``None``; an integer in 1..50 (else
    :class:`IdentificationError`)."""
    if val is None:
        return None
    if isinstance(val, bool) or not isinstance(val, int | np.integer) or not 1 <= val <= 50:
        raise IdentificationError(f"noise_order must be an integer in 1..50, got {val!r}")
    return int(val)


def _columns(frame: Any, names: Sequence[str]) -> np.ndarray:
    """``frame[list(names)].to_numpy(float)`` (the same numbers, C order) without the
    intermediate DataFrame; one float64 column is the column itself (a read-only view:
    no copy of a long log's column is held beside the log)."""
    if len(names) == 1:
        return frame[names[0]].to_numpy(float)[:, None]
    return np.column_stack([frame[c].to_numpy(float) for c in names])


def from_arrays(
    spec: ModelSpec,
    y: np.ndarray,
    u: np.ndarray,
    *,
    y2: np.ndarray | None = None,
    experiments_per_group: int = 1,
) -> RegressionData:
    """Build regression data from batch arrays ``(R, N, ·)`` without a DataFrame.

    The Monte Carlo fast path: ``R`` runs, consecutive blocks of
    ``experiments_per_group`` runs form one parameter group. ``y2`` holds the
    disturbance-sensor readings for the aggregated states, in the order of
    ``spec.states`` that have an aggregate relation.
    """
    y = np.asarray(y, dtype=float)
    u = np.asarray(u, dtype=float)
    n_runs, n_samples, n = y.shape
    if n_runs % experiments_per_group:
        raise IdentificationError("runs must be a multiple of experiments_per_group")
    target = y.reshape(-1, n)
    sensors: dict[str, np.ndarray] = {}
    if spec.aggregate:
        if y2 is None:
            raise IdentificationError("the spec aggregates states but no sensor readings y2 given")
        agg_states = [s for s in spec.states if s in spec.aggregate]
        y2 = np.asarray(y2, dtype=float).reshape(-1, len(agg_states))
        for j, s in enumerate(agg_states):
            sensors[spec.aggregate[s].sensor] = y2[:, j]
    regsig, sensor = _aggregated(spec, target, sensors)
    n_groups = n_runs // experiments_per_group
    return RegressionData(
        target=np.ascontiguousarray(target),
        regsig=np.ascontiguousarray(regsig),
        u=np.ascontiguousarray(u.reshape(-1, u.shape[-1])),
        starts=np.arange(n_runs + 1, dtype=np.int64) * n_samples,
        group=np.repeat(np.arange(n_groups, dtype=np.int64), experiments_per_group),
        n_groups=n_groups,
        experiment_ids=tuple(range(n_runs)),
        sensor=sensor,
    )


def block_starts(spec: ModelSpec) -> np.ndarray:
    """Parameter offsets of each state equation's block in θ."""
    sizes: Sequence[int] = [len(spec.equations[s]) for s in spec.states]
    return np.concatenate([[0], np.cumsum(sizes)]).astype(np.int64)


def duplicate_blocks(spec: ModelSpec) -> np.ndarray:
    """For each state equation, the first equation with the same term list (or itself)."""
    keys = [tuple(str(t) for t in spec.equations[s]) for s in spec.states]
    return np.array([keys.index(k) for k in keys], dtype=np.int64)


def segment_abs_max(values: np.ndarray, starts: np.ndarray) -> np.ndarray:
    """``max |values[a:b]|`` of every segment ``[a, b)`` of ``starts`` (0 when empty; NaN
    when the segment holds a NaN): the per-segment loop in one vectorised reduction
    (a maximum is exact, so the values are those of the loop)."""
    starts = np.asarray(starts, dtype=np.int64)
    out = np.zeros(starts.size - 1)
    full = np.diff(starts) > 0
    if full.any():
        a = np.abs(np.asarray(values, dtype=float)[:int(starts[-1])])
        red = np.maximum.reduceat(a, starts[:-1][full], axis=0)
        out[full] = red.max(axis=1) if red.ndim == 2 else red
    return out
