"""Wave filtering of trial measurements before identification.

First-order wave-induced motion (:mod:`vesselid.plant.waves`) is zero-mean, but it enters
the modulus regressors (``v·|v|``, ``r·|v|``, ...) of the manoeuvring model: the mean of
``(v + w)·|v + w|`` depends on the wave motion ``w``, so the regressors of the measured
velocities are biased whatever the instruments (measured on the planned CyberShip II
trial in a moderate sea: 4–7 SE on ``v: v``, ``v: v·|v|``, ``r: v``, ``r: v·|v|``; none
once the wave motion is removed from ``v``). A trial team removes the wave-frequency
motion before identification ("wave filtering", Fossen 2011, *Handbook of Marine Craft
Hydrodynamics and Motion Control*, Wiley, §11.3; Fossen & Perez 2009, *Kalman filtering
for positioning and heading control of ships and offshore rigs*, IEEE Control Systems
29(6)): the wave spectrum is known from the trial's wave buoy or motion records, and the
manoeuvring motion lies well below its peak.

Here the filter is an offline, zero-phase Butterworth low-pass (forward–backward, so
no delay between the signals) applied per experiment to the velocities *and* the
forces, so that the linear part of the one-step relation is preserved exactly (the
same LTI filter on both sides) and only the nonlinear terms see the (small) distortion
of the manoeuvring content near the cut-off. The cut-off is a fraction of the
model-scale peak frequency of the sea (default ``0.9 f_p``); the magnitude response at
the peak is ``(1 + (f_p/f_c)^{2n})^{-1}`` (squared Butterworth, order ``n``).

The filtered noise is coloured: identify with instruments that are independent of it
(``iv-zero-mean``: simulated from the inputs); delayed measured regressors are not
valid instruments any more.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from vesselid.errors import VesselidError

__all__ = ["WaveFilter", "WaveFilterError", "wave_filter_log"]


class WaveFilterError(VesselidError):
    """Bad wave-filter settings or a log the filter cannot be applied to."""


class WaveFilter:
    """Zero-phase Butterworth low-pass below the wave band.

    Parameters
    ----------
    cutoff : float
        Cut-off frequency (Hz, model scale).
    dt : float
        Sample time (s).
    order : int
        Butterworth order of one pass (the forward–backward filter has twice the roll-off).
    """

    def __init__(self, cutoff: float, dt: float, order: int = 8) -> None:
        cutoff, dt = float(cutoff), float(dt)
        if not (math.isfinite(dt) and dt > 0):
            raise WaveFilterError(f"dt must be positive, got {dt}")
        nyq = 0.5 / dt
        if not (math.isfinite(cutoff) and 0 < cutoff < nyq):
            raise WaveFilterError(f"cut-off must lie in (0, {nyq:g}) Hz (Nyquist), got {cutoff}")
        if int(order) != order or order < 1:
            raise WaveFilterError(f"order must be a positive integer, got {order}")
        self.cutoff, self.dt, self.order = cutoff, dt, int(order)

    @classmethod
    def for_waves(cls, waves: Any, dt: float, *, fraction: float = 0.9,
                  order: int = 8) -> WaveFilter:
        """The filter for a sea state: cut-off ``fraction`` × the model-scale peak frequency."""
        if not (math.isfinite(fraction) and 0 < fraction):
            raise WaveFilterError(f"fraction must be positive, got {fraction}")
        return cls(fraction / float(waves.model_period), dt, order)

    def gain(self, freq: np.ndarray | float) -> np.ndarray:
        """Magnitude response of the forward–backward filter at ``freq`` (Hz)."""
        f = np.asarray(freq, float) / self.cutoff
        return 1.0 / (1.0 + f ** (2 * self.order))

    def apply(self, x: np.ndarray) -> np.ndarray:
        """Filter ``x`` along axis 0 (zero phase)."""
        from scipy.signal import butter, sosfiltfilt  # lazily: ~1.5 s of process start

        x = np.asarray(x, float)
        sos = butter(self.order, self.cutoff, fs=1.0 / self.dt, output="sos")
        pad = 3 * (2 * sos.shape[0] + 1)
        if x.shape[0] <= pad:
            raise WaveFilterError(f"an experiment needs more than {pad} samples to be "
                                  f"wave-filtered, got {x.shape[0]}")
        return sosfiltfilt(sos, x, axis=0)

    def to_dict(self) -> dict[str, Any]:
        return {"type": "butterworth-zero-phase", "cutoff_hz": self.cutoff,
                "order": self.order, "dt": self.dt}


def wave_filter_log(log: Any, filt: WaveFilter,
                    columns: Sequence[str] | None = None, *, keep_raw: bool = True) -> Any:
    """A copy of a trial log with ``columns`` wave-filtered experiment by experiment.

    Parameters
    ----------
    log : vesselid.data.logs.TrialLog
        The measured log.
    filt : WaveFilter
        The filter.
    columns : sequence of str, optional
        Columns to filter (default: every signal of the log's model spec — the
        velocities and the forces).
    keep_raw : bool
        Keep the unfiltered columns as ``<name>_unfiltered``.

    Returns
    -------
    vesselid.data.logs.TrialLog
        With ``metadata["wave_filter"]`` describing the filter.
    """
    from vesselid.data.logs import TrialLog

    data = log.data
    if columns is None:
        spec = log.spec
        if spec is None:
            raise WaveFilterError("the log has no model spec: pass the columns to filter")
        columns = list(spec.signals)
    missing = [c for c in columns if c not in data]
    if missing:
        raise WaveFilterError(f"columns not in the log: {missing}")
    out = data.copy()
    exp = data["experiment"].to_numpy() if "experiment" in data else np.zeros(len(data))
    values = data[list(columns)].to_numpy(float)
    filtered = np.empty_like(values)
    for e in np.unique(exp):
        idx = np.flatnonzero(exp == e)
        filtered[idx] = filt.apply(values[idx])
    for j, c in enumerate(columns):
        if keep_raw:
            out[f"{c}_unfiltered"] = data[c].to_numpy()
        out[c] = filtered[:, j]
    meta = dict(log.metadata)
    meta["wave_filter"] = {**filt.to_dict(), "columns": list(columns)}
    # the filter changes the sensor noise (coloured, smaller variance): the white-noise
    # std of the errors-in-variables correction no longer describes it
    meta.pop("sensor_noise_std", None)
    return TrialLog(out, meta)
