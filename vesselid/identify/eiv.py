"""Errors-in-variables correction of the square modulus regressors (sensor noise).

The regressors of (3)/(9) are evaluated at the *measured* signal ``y = x + e``. With
white sensor noise ``e`` of variance ``σ²`` independent of ``x``,

* ``E[(x+e)|x+e| | x] = (x²+σ²)(2Φ(x/σ)−1) + 2xσφ(x/σ) → x|x| + σ²·sign(x)`` for
  ``|x| ≫ σ``,
* ``E[(x+e)² | x] = x² + σ²``,

while products of different signals (independent noises) and the modulus ``|x+e|`` away
from zero are unbiased. Under A10 (the sign of ``x`` fixed within an experiment) the
``σ²`` terms are constants that the per-experiment zero-mean instruments remove (the
proof of Lemma 3.1); on a design where a noisy state changes sign within an experiment
(e.g. the planned sea trial's thruster squares) ``σ²·θ·sign(x(k))`` correlates with the
instruments and biases the estimate (``scripts/seatrial_study.py`` measures it on the
planned CyberShip II trial).

The corrected regressors (a *corrected score*, Nakamura 1990; Carroll, Ruppert,
Stefanski & Crainiceanu 2006, *Measurement Error in Nonlinear Models*, ch. 7)

* ``h(y) = y|y| − σ²·sign(y)`` for every ``x·|x|`` (or ``|x|·x``) term,
* ``h(y) = y² − σ²`` for every ``x·x`` term,

have ``E[h(x+e) | x] = x|x|`` (resp. ``x²``) exactly for the square and up to a bump of
height ``0.2 σ²`` within ``|x| < 2σ`` for the modulus (``2t(φ(t) − tQ(t))σ²``,
``t = |x|/σ``: ``sign`` is itself smoothed by the noise there). With ``σ = 0`` nothing
changes (the correction is skipped: results are bit-identical to the uncorrected ones).
What remains near zero has closed forms: :func:`signed_square_bias` for the corrected
``x·|x|``, :func:`modulus_bias` for a modulus factor ``|z+e|`` of a product of two
different states (which has no conditionally unbiased score: ``|z|`` is not analytic at
0), and :func:`regressor_error_mean` for every column of a spec — what
``scripts/closed_loop_bias_decomposition.py`` uses to measure the bias they leave.

``σ`` is the standard deviation of the white noise on each *regressor* signal (the
measured state, or the aggregated signal ``ỹ`` of (9)); it comes from the sensor
specification: a log's ``metadata["sensor_noise_std"]`` (``{state: σ}``, written by
``vesselid sea-trial``) or ``identify(..., sensor_noise={...})``. Only white noise is
meant: a coloured disturbance (waves) or a low-pass-filtered log changes the variance
(:func:`vesselid.data.wavefilter.wave_filter_log` drops the entry).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from vesselid.errors import IdentificationError

__all__ = ["METADATA_KEY", "correct_regressors", "corrected_regressor_matrix",
           "forget_regressors", "modulus_bias", "noise_vector", "regressor_error_mean",
           "resolve_sensor_noise", "signed_square_bias"]

#: Log metadata entry with the std of the white sensor noise on each regressor signal.
METADATA_KEY = "sensor_noise_std"


def noise_vector(states: tuple[str, ...] | list[str], sensor_noise: Any
                 ) -> np.ndarray | None:
    """``σ`` per state (zeros where not given) from a mapping ``{state: σ}``; ``None``
    when nothing is given or every ``σ`` is zero (no correction).

    Raises
    ------
    IdentificationError
        A name that is not a state of the spec, or a ``σ`` that is not a finite number
        ``≥ 0``.
    """
    if sensor_noise is None or sensor_noise is False:
        return None
    if not isinstance(sensor_noise, Mapping):
        raise IdentificationError(
            f"sensor_noise must be a mapping state -> noise std (or False), got "
            f"{type(sensor_noise).__name__}")
    out = np.zeros(len(states))
    for name, val in sensor_noise.items():
        if name not in states:
            raise IdentificationError(
                f"sensor_noise names {name!r}, which is not a state of the model "
                f"(states: {', '.join(states)})")
        try:
            s = float(val)
        except (TypeError, ValueError):
            s = float("nan")
        if not (np.isfinite(s) and s >= 0):
            raise IdentificationError(
                f"sensor_noise[{name!r}] must be a finite number >= 0, got {val!r}")
        out[list(states).index(name)] = s
    return out if np.any(out > 0) else None


def resolve_sensor_noise(option: Any, metadata: Mapping[str, Any] | None,
                         states: tuple[str, ...] | list[str]) -> np.ndarray | None:
    """The ``σ`` vector an estimation uses: the ``sensor_noise`` option when given
    (``False`` or ``{}``: no correction), else the log's :data:`METADATA_KEY`."""
    if option is None:
        option = (metadata or {}).get(METADATA_KEY)
    return noise_vector(states, option)


def modulus_bias(x: np.ndarray, sigma: float) -> np.ndarray:
    """``E[|x+e| | x] − |x| = 2σ(φ(t) − t·Q(t))``, ``t = |x|/σ``, ``e ~ N(0, σ²)``.

    The bias of the modulus ``|y|`` of a measured signal: ``0.8σ`` at ``x = 0`` and below
    ``10⁻³σ`` for ``|x| > 3σ`` (``Q = 1 − Φ``). ``|y|`` has no conditionally unbiased
    correction (``|x|`` is not analytic at 0), which is why :func:`correct_regressors`
    leaves a modulus factor of a product of two different signals as it is.
    """
    from scipy.special import ndtr

    x = np.asarray(x, dtype=float)
    if sigma <= 0:
        return np.zeros_like(x)
    t = np.abs(x) / sigma
    return 2.0 * sigma * (np.exp(-0.5 * t * t) / np.sqrt(2 * np.pi) - t * ndtr(-t))


def signed_square_bias(x: np.ndarray, sigma: float) -> np.ndarray:
    """``E[h(x+e) | x] − x|x|`` of the corrected score ``h(y) = y|y| − σ²·sign(y)``:
    ``σ²·sign(x)·2t(φ(t) − t·Q(t))``, ``t = |x|/σ`` (module docstring; at most ``0.2σ²``,
    at ``|x| ≈ 0.6σ``, and below ``10⁻³σ²`` for ``|x| > 3.5σ``)."""
    x = np.asarray(x, dtype=float)
    if sigma <= 0:
        return np.zeros_like(x)
    return np.sign(x) * np.abs(x) * modulus_bias(x, sigma)


def regressor_error_mean(xsig: np.ndarray, factors: np.ndarray, n_signals: int,
                         noise: np.ndarray) -> np.ndarray:
    """``E[φ̃(k) | x] − φ(x(k−1), u(k−1))``: the conditional mean, given the true states,
    of the error of every regressor column as :func:`correct_regressors` forms it, for
    white Gaussian sensor noise of std ``noise`` on the states (independent between
    states; the inputs exact).

    ``x·x``: 0 (exact score); ``x·|x|``: :func:`signed_square_bias`; a product of
    different signals: the product of the factors' conditional means (``x`` for a
    signal, ``|x| +`` :func:`modulus_bias` for a modulus) minus the product of the
    factors. This is the part of the measurement error that can correlate with
    instruments independent of the noise; the rest has zero conditional mean.

    Parameters
    ----------
    xsig : ndarray (T, S)
        True states followed by the inputs at every row (row ``k`` of the result uses
        row ``k − 1``, as :func:`vesselid.identify.kernels.regressor_matrix`; the first
        row is NaN).
    factors, n_signals
        The spec's factor layout (:func:`correct_regressors`).
    noise : ndarray (n_states,)
        ``σ`` per state.

    Returns
    -------
    ndarray (T, P)
    """
    xsig = np.asarray(xsig, dtype=float)
    noise = np.asarray(noise, dtype=float)
    n_x = noise.size
    prev = xsig[:-1]
    out = np.full((xsig.shape[0], len(factors)), np.nan)

    def signal(j: int) -> tuple[int, bool]:  # (signal index or -1 for the constant, modulus)
        return (-1, False) if j >= 2 * n_signals else (j % n_signals, j >= n_signals)

    def value_and_mean(j: int) -> tuple[np.ndarray, np.ndarray]:
        sig, mod = signal(j)
        if sig < 0:
            return np.ones(prev.shape[0]), np.ones(prev.shape[0])
        x = prev[:, sig]
        if not mod:
            return x, x
        s = float(noise[sig]) if sig < n_x else 0.0
        return np.abs(x), np.abs(x) + modulus_bias(x, s)

    for p, (a, b) in enumerate(np.asarray(factors, np.int64)):
        (sa, ma), (sb, mb) = signal(int(a)), signal(int(b))
        if sa == sb and 0 <= sa < n_x:  # one noisy state twice
            if ma != mb:  # x·|x|: the corrected score
                out[1:, p] = signed_square_bias(prev[:, sa], float(noise[sa]))
            else:  # x·x corrected exactly; |x|·|x| = y² left as it is
                out[1:, p] = float(noise[sa]) ** 2 if ma else 0.0
            continue
        fa, ea = value_and_mean(int(a))
        fb, eb = value_and_mean(int(b))
        out[1:, p] = ea * eb - fa * fb
    return out


def correct_regressors(phi: np.ndarray, regsig: np.ndarray, factors: np.ndarray,
                       n_signals: int, noise: np.ndarray | None) -> np.ndarray:
    """Corrected regressor matrix (module docstring): ``σ_i²·sign(ỹ_i(k−1))`` is
    subtracted from every ``x_i·|x_i|`` column and ``σ_i²`` from every ``x_i·x_i``
    column of ``phi``.

    Parameters
    ----------
    phi : ndarray (T, P)
        :func:`vesselid.identify.kernels.regressor_matrix` of ``regsig`` (row ``k`` uses
        ``ỹ(k−1)``; the first row of each segment is NaN and stays NaN).
    regsig : ndarray (T, n)
        The regressor signals (states).
    factors : ndarray (P, 2)
        Factor layout (:class:`vesselid.model.regressors.RegressorLayout`).
    n_signals : int
        ``S``: states + inputs (factor ``j < S`` is signal ``j``, ``S + j`` its modulus).
    noise : ndarray (n,) or None
        ``σ`` per state; ``None``: ``phi`` is returned unchanged (the same object).

    Returns
    -------
    ndarray (T, P)
        A corrected copy (``phi`` itself when there is nothing to correct).
    """
    if noise is None:
        return phi
    out = None
    n_x = noise.size
    for p, (a, b) in enumerate(np.asarray(factors, np.int64)):
        a, b = int(a), int(b)
        lo, hi = min(a, b), max(a, b)
        if lo >= n_x or noise[lo] <= 0:
            continue
        var = float(noise[lo]) ** 2
        if hi == lo + n_signals:  # x·|x|
            shift = var * np.sign(regsig[:-1, lo])
        elif hi == lo:  # x·x
            shift = var
        else:
            continue
        if out is None:
            out = phi.copy()
        out[1:, p] -= shift
    return phi if out is None else out


def corrected_regressor_matrix(data: Any, spec: Any) -> np.ndarray:
    """:func:`vesselid.identify.kernels.regressor_matrix` of ``data`` (a
    :class:`~vesselid.identify.data.RegressionData`) with :func:`correct_regressors`
    applied for ``data.regressor_noise`` (unchanged when it is ``None``)."""
    hit = getattr(data, "__dict__", {}).get(_REMEMBERED)
    if hit is not None and hit[0] is spec:
        return hit[1]
    from vesselid.identify.backend import kernels

    codes = spec.codes
    phi = kernels.regressor_matrix(data.regsig, data.u, data.starts, codes.factors)
    return correct_regressors(phi, data.regsig, codes.factors, codes.n_signals,
                              data.regressor_noise)


def uncorrected_regressor_matrix(data: Any, spec: Any) -> np.ndarray:
    """:func:`vesselid.identify.kernels.regressor_matrix` of ``data``: the rows
    :func:`remember_regressors` kept when they carry no correction (no
    ``data.regressor_noise``: the same numbers, not formed again), else formed. Read-only
    for the caller (the rows may be the fit's)."""
    if data.regressor_noise is None:
        return corrected_regressor_matrix(data, spec)
    from vesselid.identify.backend import kernels

    return kernels.regressor_matrix(data.regsig, data.u, data.starts, spec.codes.factors)


_REMEMBERED = "_corrected_regressors"


def remember_regressors(data: Any, spec: Any, phi: np.ndarray) -> None:
    """Keep ``phi`` (:func:`corrected_regressor_matrix` of ``data`` and ``spec``) on
    ``data`` for the later calls with the same ``spec``: the checked ``fit`` forms the
    rows for its rank check and residuals and the estimator would form them again. Only
    for a ``data`` that dies with the fit (the Monte Carlo's chunks must not hold rows);
    nothing writes into the rows."""
    data.__dict__[_REMEMBERED] = (spec, phi)


def forget_regressors(data: Any) -> None:
    """Drop the rows :func:`remember_regressors` kept on ``data`` (later calls form them
    again: the same numbers)."""
    getattr(data, "__dict__", {}).pop(_REMEMBERED, None)
