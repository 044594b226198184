"""Trial planner: predicted parameter covariance of a design, and an optimal design.

Predicted covariance (no Monte Carlo)
-------------------------------------
``identify`` with zero-mean instruments (the paper's IV_{E{ζ}=0}, multi-experiment
pooled form of eq. (6)) returns, per state equation ``i``,
``θ̂_i − θ_i ≈ A_i⁻¹ Σ_k ζ̃(k) ε_i(k)`` with ``A_i = Σ_k ζ̃(k) φ(k)ᵀ``, where ζ̃ are the
refined instruments — the regressors simulated noise-free from the estimate with the
measured inputs (at convergence θ̂ ≈ θ0), centred per experiment (A7) — and ``ε_i`` is
the equation error of the predictor. Its asymptotic covariance is the sandwich

    Cov θ̂_i = A_i⁻¹ S_i A_i⁻ᵀ,      S_i = Σ_k Σ_l ζ̃(k) ζ̃(l)ᵀ E[ε_i(k) ε_i(l)],

evaluated here on the *simulated* instruments of the design with the autocovariance
of ``ε`` implied by the disturbance levels (linearised). The cross moment ``A_i`` uses
the regressors of the vessel's *disturbed* path, averaged over a few realisations of the
unmodelled forces, gusts and wind-direction changes (:data:`DISTURBED_PATHS`, fixed
seed): the instruments are simulated open loop from the logged inputs and do not follow
the random departures of the vessel from its noise-free path. Where the motion is weakly
damped (full-ahead thruster squares) those departures are large and weaken the
instruments, which the noise-free path as regressors (``paths=0``) does not see
(``scripts/planner_study.py`` compares the predictions with Monte Carlo).

* white sensor noise ``e`` (std ``σ``) enters the target and, through the regressors,
  the prediction: ``ε_i(k) = e_i(k) − Σ_j J_ij(k−1) e_j(k−1)`` with the Jacobian
  ``J = ∂(Φᵀθ)/∂x`` along the nominal trajectory (lags 0 and ±1, time varying);
* unmodelled forces: Gauss–Markov, ``dt M⁻¹ τ_noise`` (autocovariance ``s² a^|τ|``);
* wind gusts and wind-direction changes: Gauss–Markov, through the gain of the
  Blendermann wind load along the nominal heading and velocity (time-varying gains);
* waves (:mod:`vesselid.plant.waves`): coloured sensor noise ``ξ``, ``ε ≈ ξ(k) − ξ(k−1)``,
  stationary autocovariance from the wave spectrum and response (FFT).

``identify``'s default estimator ``auto`` rejects the delayed measured instruments on a
sea trial (the Gauss–Markov forces colour the equation error; its C and colour tests)
and falls back to SRIV: the same simulated, per-experiment centred instruments with
target, regressors and instruments prefiltered by the Yule–Walker AR model ``C(q)``
of the equation error (Young 1976; Söderström & Stoica 1989, ch. 8). Its prediction
(``estimator="auto"``, the default) pools the equation-error autocovariance above over
the experiments (lags 0–4), fits ``C`` as :func:`vesselid.identify.gmm.ar_coefficients`
does, and evaluates ``A_f = Σ ζ_f φ_fᵀ`` and the meat with the instruments
``y(j) = Σ_m c_m ζ_f(j+m)`` (``Σ ζ_f ε_f = Σ ε y``), so every disturbance term above
applies unchanged.

With the load of the mean wind as a known input (``wind_input="anemometer"``, the
sea-trial default) only the gusts and direction changes remain. Without it
(``"none"``) the mean wind load is a deterministic, heading-dependent force that the
estimator does not know; its predicted *bias* ``A_i⁻¹ Σ ζ̃ ε_wind`` is reported next to
the standard errors.

Design
------
Candidate manoeuvres (:mod:`vesselid.studies.manoeuvres`) are evaluated as *blocks* of a fixed
length; information is additive over blocks (``A`` and ``S`` add up), so a design is a
multiset of blocks and its covariance is ``(ΣA)⁻¹ (ΣS) (ΣA)⁻ᵀ``. :func:`plan_trial`
chooses blocks greedily and improves the choice by exchange (Fedorov 1972; Atkinson,
Donev & Tobias 2007, ch. 12) to minimise the worst relative standard error
``max_p SE_p/|θ0_p|`` over the parameters with ``|θ0_p| ≥ relevance``, then packs the
blocks into the experiments and evaluates the assembled design exactly (each
experiment simulated continuously, instruments centred per experiment).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pandas as pd
from scipy.fft import next_fast_len

from vesselid.core import seeds
from vesselid.errors import VesselidError
from vesselid.model.regressors import evaluate as evaluate_regressors
from vesselid.model.regressors import predict as predict_regressors
from vesselid.model.spec import ModelSpec
from vesselid.plant.plant import heading
from vesselid.plant.vessels.environment import (
    SENSOR_CHANNELS,
    DisturbanceComponent,
    VesselDisturbances,
    VesselSensors,
    clipped_variance,
)
from vesselid.plant.vessels.hull import Hull
from vesselid.plant.vessels.kernel import VesselModel
from vesselid.studies.manoeuvres import (
    FORCE_LIMITS,
    AccelerationStopping,
    Crabbing,
    Manoeuvre,
    ManoeuvreError,
    Programme,
    PullOut,
    Spiral,
    ThrusterSquare,
    TurningCircle,
    ZigZag,
)

__all__ = [
    "DisturbanceLevels",
    "PlannerError",
    "TrialPlan",
    "candidate_library",
    "design_information",
    "plan_trial",
    "predict_covariance",
]


class PlannerError(VesselidError):
    """Bad planner settings (budget too small, no feasible design, ...)."""


#: Identification structures: ``"full"`` keeps ``v·|r|`` and ``r·|v|`` apart (manoeuvres
#: with ``v·r > 0`` separate them); ``"merged"`` folds ``v·|r|`` into ``r·|v|`` (exact only
#: while ``v·r < 0``, as in the steady turns of the static-offset design).
STRUCTURES = ("full", "merged")


# ---------------------------------------------------------------------------- noise
@dataclass(frozen=True)
class DisturbanceLevels:
    """Disturbance levels the planner assumes (model scale, SI units).

    Defaults are those of ``vesselid sea-trial``
    (:func:`vesselid.studies.seatrial.simulate_sea_trial`); :meth:`plant` turns the
    levels into the vessel plant the planner works on.

    Parameters
    ----------
    sensor_std : (float, float, float)
        White noise std of the signals of ``u, v, r`` (speed log, gyro).
    sensor_clip : float
        Clipping of the sensor noise in stds (variance factor of a clipped normal).
    force_noise_std, force_noise_time_constant
        Unmodelled Gauss–Markov forces ``[X, Y, N]`` and their time constant (s).
    wind_speed, wind_direction, gust_std, gust_time_constant
        Mean wind (m/s, going-to rad) and its Gauss–Markov gusts.
    wind_direction_std, wind_direction_time_constant
        Gauss–Markov variations of the wind direction (rad) and their time constant (s).
    waves : vesselid.plant.waves.WaveConditions, optional
        Sea state (first-order wave-induced motion on the measurements).
    wind_input : {"anemometer", "none"}
        ``"anemometer"`` (the sea-trial default): the load of the mean wind (estimated
        from the anemometer per experiment) is part of the logged forces, so only the
        gusts and direction changes remain in the equation error; ``"none"``: the whole
        wind load does (its mean a bias).
    components : tuple of DisturbanceComponent
        Further process disturbances of the plant (e.g.
        :class:`~vesselid.plant.vessels.environment.ProcessForce`): their forces move the
        vessel's disturbed paths (:meth:`VesselModel.disturbed_paths`).
    """

    sensor_std: tuple[float, float, float] = (0.005, 0.005, 0.002)
    sensor_clip: float = 3.0
    force_noise_std: tuple[float, float, float] = (0.02, 0.02, 0.01)
    force_noise_time_constant: float = 2.0
    wind_speed: float = 1.0
    wind_direction: float = math.radians(-60.0)
    gust_std: float = 0.1
    gust_time_constant: float = 5.0
    wind_direction_std: float = 0.1
    wind_direction_time_constant: float = 30.0
    waves: Any = None
    wind_input: str = "anemometer"
    components: tuple[DisturbanceComponent, ...] = ()

    def plant(self, dt: float = 0.1, hull: Hull | None = None) -> VesselModel:
        """The vessel plant of these levels: ``hull`` (default CyberShip II) with the
        unmodelled forces, wind and components as :class:`VesselDisturbances` and the
        speed log (``u, v``) and gyro (``r``) as :class:`VesselSensors`."""
        if hull is None:
            from vesselid.plant.vessels import cybership2

            hull = cybership2.HULL
        su, sv, sr = (float(x) for x in self.sensor_std)
        disturbances = VesselDisturbances(
            wind_speed=self.wind_speed, wind_direction=self.wind_direction,
            gust_std=self.gust_std, gust_time_constant=self.gust_time_constant,
            wind_direction_std=self.wind_direction_std,
            wind_direction_time_constant=self.wind_direction_time_constant,
            force_noise_std=self.force_noise_std,
            force_noise_time_constant=self.force_noise_time_constant,
            components=tuple(self.components))
        sensors = VesselSensors(gnss=None, speed_log=(su, sv), current_meter=None,
                                anemometer=None, gyro=sr, heading=None, clip=self.sensor_clip)
        return VesselModel(hull=hull, dt=dt, disturbances=disturbances, sensors=sensors)

    def to_dict(self) -> dict[str, Any]:
        skip = ("waves", "components")
        d = {k: getattr(self, k) for k in self.__dataclass_fields__ if k not in skip}
        d["waves"] = None if self.waves is None else self.waves.to_dict()
        if self.components:
            d["components"] = [{"name": c.name, **c.to_dict()} for c in self.components]
        return {k: list(v) if isinstance(v, tuple) else v for k, v in d.items()}


# ------------------------------------------------------------------- the plant
def _planner_plant(dt: float, structure: str,
                   levels: DisturbanceLevels) -> tuple[VesselModel, ModelSpec]:
    """CyberShip II as the plant of ``levels`` and its identification spec for
    ``structure`` (merged: :data:`~vesselid.plant.vessels.cybership2.TRIAL_MERGES`)."""
    from vesselid.plant.vessels import cybership2

    if structure not in STRUCTURES:
        raise PlannerError(f"unknown structure {structure!r}; choose from {STRUCTURES}")
    plant = levels.plant(dt, cybership2.HULL)
    ident = plant.spec
    if structure == "merged":
        for keep, drop, factor in cybership2.TRIAL_MERGES:
            ident = ident.merge_terms(keep, drop, factor)
    return plant, ident


def _regressor_noise_std(sensors: VesselSensors) -> np.ndarray:
    """Noise std of the measured ``u, v, r`` (speed log, else GNSS; gyro)."""
    std = sensors.std_vector()
    uv = ("u_log", "v_log") if sensors.speed_log is not None else ("u", "v")
    return std[[SENSOR_CHANNELS.index(c) for c in (*uv, "r")]]


# ----------------------------------------------------------------- information
@dataclass
class Information:
    """Additive moments of one experiment (or of blocks of one experiment).

    Per equation, over the instruments augmented with a constant (uncentred):
    ``A = Σ ζ_a φ_aᵀ``, ``S = ΣΣ ζ_a ζ_aᵀ E[εε]`` (the meat) and the wind moment
    ``b = Σ ζ_a ε_wind``; ``n`` samples. :meth:`centred` applies the per-experiment
    centring of the zero-mean instruments (A7) exactly. ``acov`` ``(n_states, L + 1)``:
    ``Σ_k E[ε_i(k) ε_i(k+τ)]``, τ = 0..L, of the equation errors (summed over samples;
    pooled over experiments it gives the AR noise model of SRIV, :func:`sriv_prefilter`).
    """

    a: list[np.ndarray]
    s: list[np.ndarray]
    b: list[np.ndarray]
    n: int
    acov: np.ndarray | None = None

    def __add__(self, other: Information) -> Information:
        acov = (None if self.acov is None or other.acov is None
                else self.acov + other.acov)
        return Information([x + y for x, y in zip(self.a, other.a, strict=True)],
                           [x + y for x, y in zip(self.s, other.s, strict=True)],
                           [x + y for x, y in zip(self.b, other.b, strict=True)],
                           self.n + other.n, acov)

    def scaled(self, f: float) -> Information:
        return Information([f * x for x in self.a], [f * x for x in self.s],
                           [f * x for x in self.b], round(f * self.n),
                           None if self.acov is None else f * self.acov)

    def centred(self) -> Centred:
        """Moments of the instruments centred over this experiment."""
        a_out, s_out, b_out = [], [], []
        for a, s, b in zip(self.a, self.s, self.b, strict=True):
            n = a[-1, -1]
            if n <= 0:
                p = a.shape[0] - 1
                a_out.append(np.zeros((p, p)))
                s_out.append(np.zeros((p, p)))
                b_out.append(np.zeros(p))
                continue
            zbar = a[:-1, -1] / n
            a_out.append(a[:-1, :-1] - np.outer(zbar, a[-1, :-1]))
            q = s[:-1, -1]
            s_out.append(s[:-1, :-1] - np.outer(zbar, q) - np.outer(q, zbar)
                         + np.outer(zbar, zbar) * s[-1, -1])
            b_out.append(b[:-1] - zbar * b[-1])
        return Centred(a_out, s_out, b_out)


@dataclass
class Centred:
    """Per-equation moments of centred instruments; adds over experiments."""

    a: list[np.ndarray]
    s: list[np.ndarray]
    b: list[np.ndarray]

    def __add__(self, other: Centred) -> Centred:
        return Centred([x + y for x, y in zip(self.a, other.a, strict=True)],
                       [x + y for x, y in zip(self.s, other.s, strict=True)],
                       [x + y for x, y in zip(self.b, other.b, strict=True)])

    def __sub__(self, other: Centred) -> Centred:
        return Centred([x - y for x, y in zip(self.a, other.a, strict=True)],
                       [x - y for x, y in zip(self.s, other.s, strict=True)],
                       [x - y for x, y in zip(self.b, other.b, strict=True)])


def _ar1_meat(y: np.ndarray, a: float) -> np.ndarray:
    """``Σ_k Σ_l y_k y_lᵀ a^|k−l|`` for rows ``y`` ``(N, p)``.

    With the causal AR filter ``f_k = Σ_{l≤k} a^{k−l} y_l`` the double sum is
    ``yᵀf + fᵀy − yᵀy`` (one filter pass).
    """
    if y.shape[0] == 0:
        return np.zeros((y.shape[1], y.shape[1]))
    from vesselid.core.filters import ar1_filter

    yt = np.ascontiguousarray(y.T)
    f = ar1_filter(yt, a, np.zeros(yt.shape[0]))
    m = yt @ f.T
    return m + m.T - yt @ yt.T


def _stationary_meat(y: np.ndarray, acov: np.ndarray) -> np.ndarray:
    """``Σ_k Σ_l y_k y_lᵀ R(k−l)`` for a stationary autocovariance ``R(0..L)`` (FFT)."""
    n = y.shape[0]
    lags = acov.size - 1
    m = next_fast_len(n + lags + 1)
    r = np.zeros(m)
    r[: lags + 1] = acov
    r[m - lags:] = acov[1:][::-1]
    spec = np.fft.rfft(r).real
    yf = np.fft.rfft(y, n=m, axis=0)
    w = np.ones(yf.shape[0])
    w[1: (m + 1) // 2] = 2.0
    out = (yf.conj().T * (spec * w)) @ yf
    return (out.real + out.real.T) / (2.0 * m)


def _jacobian(factors: np.ndarray, eq: np.ndarray, theta: np.ndarray, sig: np.ndarray,
              n: int) -> np.ndarray:
    """``J[k, i, j] = ∂(Φᵀθ)_i/∂x_j`` at the signal rows ``sig`` (analytic, vectorised).

    Term ``p`` is ``F[f0]·F[f1]`` with ``F = [s, |s|, 1]``."""
    from vesselid.model.regressors import factor_vector

    n_s = sig.shape[1]
    f = factor_vector(sig)
    jac = np.zeros((sig.shape[0], n, n))
    for p in range(factors.shape[0]):
        for this, other in ((int(factors[p, 0]), int(factors[p, 1])),
                            (int(factors[p, 1]), int(factors[p, 0]))):
            j = this % n_s if this < 2 * n_s else -1
            if j < 0 or j >= n:
                continue
            d = f[:, other] if this < n_s else np.sign(sig[:, j]) * f[:, other]
            jac[:, eq[p], j] += theta[p] * d
    return jac


def _fir(x: np.ndarray, c: np.ndarray, reverse: bool = False) -> np.ndarray:
    """``Σ_m c_m x(k−m)`` (rows before ``p`` zero, as the estimator drops them) or, with
    ``reverse``, the adjoint ``Σ_m c_m x(k+m)``."""
    c = np.asarray(c, float)
    out = np.zeros_like(x)
    n = x.shape[0]
    for m, cm in enumerate(c):
        if reverse:
            out[: n - m] += cm * x[m:]
        else:
            out[c.size - 1:] += cm * x[c.size - 1 - m: n - m]
    return out


def sriv_prefilter(acov: np.ndarray) -> list[np.ndarray]:
    """Yule–Walker AR(L) noise models ``C_i(q) = 1 + c₁q⁻¹ + …`` from the pooled
    equation-error autocovariances ``acov`` ``(n_states, L + 1)`` — what
    :func:`vesselid.identify.gmm.ar_coefficients` estimates from the residuals, by the
    same :func:`vesselid.identify.gmm.yule_walker`."""
    from vesselid.identify.gmm import yule_walker

    return list(yule_walker(acov))


def _modulus_bias(factors: np.ndarray, sig: np.ndarray, std: np.ndarray,
                  corrected: bool = False) -> np.ndarray:
    """``E[φ(x + e)] − φ(x)`` of every regressor for Gaussian sensor noise ``e`` of std
    ``std`` on the states (the first ``std.size`` signals; inputs noise free):
    ``E|x+e| = x erf(x/σ√2) + σ√(2/π) e^{−x²/2σ²}``,
    ``E[(x+e)|x+e|] = (x²+σ²) erf(x/σ√2) + xσ√(2/π) e^{−x²/2σ²}``, ``E(x+e)² = x²+σ²``;
    different signals have independent noise. ``corrected``: of the errors-in-variables
    corrected regressors ``y|y| − σ² sign(y)``, ``y² − σ²`` (:mod:`vesselid.identify.eiv`,
    what ``identify``'s refined-IV family evaluates on a log with its sensor noise):
    ``E[sign(x+e)] = erf(x/σ√2)``, so only the bump within a few σ of zero remains."""
    from scipy.special import erf

    n_s = sig.shape[1]
    n_x = std.size
    ones = np.ones(sig.shape[0])

    cache: dict[int, tuple[np.ndarray, np.ndarray, int]] = {}

    def expect(c: int) -> tuple[np.ndarray, np.ndarray, int]:
        if c in cache:
            return cache[c]
        if c >= 2 * n_s:
            return ones, ones, -1
        j = c % n_s
        x = sig[:, j]
        if c < n_s or j >= n_x or std[j] <= 0:
            v = x if c < n_s else np.abs(x)
            out_c = (v, v, j)
        else:
            s = std[j]
            out_c = (np.abs(x), x * erf(x / (s * math.sqrt(2)))
                     + s * math.sqrt(2 / math.pi) * np.exp(-0.5 * (x / s) ** 2), j)
        cache[c] = out_c
        return out_c

    out = np.zeros((sig.shape[0], factors.shape[0]))
    for p, (a, b) in enumerate(np.asarray(factors, int)):
        fa, ea, ja = expect(int(a))
        fb, eb, jb = expect(int(b))
        if ja >= 0 and ja == jb and ja < n_x and std[ja] > 0:
            x, s = sig[:, ja], std[ja]
            if (a >= n_s) != (b >= n_s):  # x·|x|
                e = ((x * x + (0.0 if corrected else s * s)) * erf(x / (s * math.sqrt(2)))
                     + x * s * math.sqrt(2 / math.pi) * np.exp(-0.5 * (x / s) ** 2))
            else:  # x·x or |x|·|x|
                e = x * x + (0.0 if corrected and a == b else s * s)
            out[:, p] = e - fa * fb
        elif ea is not fa or eb is not fb:  # else no noisy modulus factor: exactly zero
            out[:, p] = ea * eb - fa * fb
    return out


def design_information(
    forces: np.ndarray,
    plant: VesselModel,
    *,
    spec: ModelSpec | None = None,
    waves: Any = None,
    wind_input: str = "anemometer",
    warmup: int = 0,
    x0: Sequence[float] | None = None,
    prefilter: Sequence[np.ndarray] | None = None,
    acov_lags: int = 4,
    acov_only: bool = False,
    paths: int = 0,
    seed: int = 0,
    sensor_noise_corrected: bool = False,
) -> Information:
    """Information of one experiment with the given forces (first ``warmup`` discarded).

    Parameters
    ----------
    forces : ndarray (warmup + N, 3)
        Open-loop input schedule.
    plant : VesselModel
        The vessel plant (physics, its disturbances and sensors, e.g.
        :meth:`DisturbanceLevels.plant`): the nominal path, the disturbed paths, the
        wind load and its gains, ``dt M⁻¹`` and the noise levels all come from it.
    spec : ModelSpec, optional
        Identification spec (default the plant's physics spec).
    waves : vesselid.plant.waves.WaveConditions, optional
        Sea state (first-order wave-induced motion on the measurements).
    wind_input : {"anemometer", "none"}
        Whether the mean wind's load is a known input (:class:`DisturbanceLevels`).
    warmup : int
        Leading samples simulated and discarded (the experiment starts after them).
    x0 : sequence of float, optional
        Initial state of the simulation (default zeros).
    prefilter : sequence of ndarray, optional
        Per equation the FIR noise-model prefilter ``C(q) = 1 + c₁q⁻¹ + … + c_pq⁻ᵖ`` of
        SRIV (Young's refined IV, the ``auto`` estimator's choice under coloured
        disturbances): target, regressors and instruments are filtered by ``C(q)``, so
        ``θ̂ − θ ≈ A_f⁻¹ Σ ζ_f(k) ε_f(k)`` with ``A_f = Σ ζ_f φ_fᵀ`` and
        ``Σ_k ζ_f(k) ε_f(k) = Σ_j ε(j) y(j)``, ``y(j) = Σ_m c_m ζ_f(j+m)``: the meat is
        that of the unfiltered error with the instruments ``y``.
    acov_lags : int
        Lags of the equation-error autocovariance recorded in ``Information.acov``.
    acov_only : bool
        Only the autocovariance (no moments): the first pass of SRIV.
    paths : int
        Disturbed realisations of the vessel's path for the cross moment
        ``A = Σ ζ φᵀ`` (:meth:`VesselModel.disturbed_paths`; 0: the regressors of the
        noise-free path, i.e. instruments that track the vessel exactly).
    seed : int
        Seed of those realisations (``np.random.default_rng``; the planner is
        deterministic).
    sensor_noise_corrected : bool
        The estimator corrects the square modulus regressors for the sensor noise
        (:mod:`vesselid.identify.eiv`; ``auto`` and ``sriv`` on a sea-trial log): the
        predicted errors-in-variables bias is that of the corrected regressors.

    Returns
    -------
    Information
    """
    dt = plant.dt
    dist = plant.disturbances
    x_init = np.zeros(3) if x0 is None else np.asarray(x0, float)
    x_nominal = plant.run(forces, x_init)
    xs = x_nominal[:-1]
    psi = heading(xs, dt)
    x_paths = None
    if int(paths) > 0 and not acov_only:
        x_paths = plant.disturbed_paths(np.asarray(forces, float), x_init, paths=int(paths),
                                        seed=seed, nominal=x_nominal)[:, warmup:-1]
    xs, tau, psi = xs[warmup:], np.asarray(forces, float)[warmup:], psi[warmup:]
    spec = plant.spec if spec is None else spec
    codes = spec.codes
    n_k = xs.shape[0]
    if n_k < 3:
        raise PlannerError("an experiment needs at least 3 samples")
    # instruments: the identification model simulated noise-free from the first sample
    from vesselid.plant.simulate import simulate_states

    xi = simulate_states(spec, tau, x0=xs[0])
    sig_i = np.hstack([xi, tau])
    sig_t = np.hstack([xs, tau])
    zeta = evaluate_regressors(codes, sig_i[:-1])  # row k predicts sample k+1
    if x_paths is None:
        phi = evaluate_regressors(codes, sig_t[:-1])
    else:
        # E[Σ ζ φ(x)ᵀ] over the disturbed paths: the instruments (simulated from the
        # logged inputs) do not follow the vessel's random departures from its
        # noise-free path, which weakens them where the motion is weakly damped
        phi = np.mean([evaluate_regressors(codes, np.hstack([xp, tau])[:-1])
                       for xp in x_paths], axis=0)
    # Jacobian of the one-step map of the identification model along the trajectory
    jac = _jacobian(codes.factors, codes.equation, spec.theta0_vector(), sig_t[:-1],
                    spec.n_states)
    # deterministic equation error: the structure's misspecification (merged terms)
    full = plant.spec
    pred_full = predict_regressors(full.codes, full.theta0_vector(), sig_t[:-1])
    eps_det = pred_full - predict_regressors(codes, spec.theta0_vector(), sig_t[:-1])
    # errors in variables at the zero crossings: E|x + e| ≠ |x| for |x| of a few σ, so the
    # measured modulus regressors are biased there (what A10/A15 exclude) and the
    # noise-free instruments do not remove it
    noise_std = _regressor_noise_std(plant.sensors)
    clip = plant.sensors.clip
    sig_std = noise_std * math.sqrt(clipped_variance(clip))
    if x_paths is None:
        d_phi = _modulus_bias(codes.factors, sig_t[:-1], sig_std, sensor_noise_corrected)
    else:  # where the vessel's states are near zero: along its disturbed paths
        d_phi = np.mean([_modulus_bias(codes.factors, np.hstack([xp, tau])[:-1], sig_std,
                                       sensor_noise_corrected)
                         for xp in x_paths], axis=0)
    theta_id = spec.theta0_vector()
    for i in range(spec.n_states):
        cols = np.flatnonzero(codes.equation == i)
        eps_det[:, i] -= d_phi[:, cols] @ theta_id[cols]
    # wind: mean load (deterministic bias) and gains of gust / direction changes
    wind_on = dist.wind_on
    if wind_input not in ("anemometer", "none"):
        raise PlannerError(f"unknown wind input {wind_input!r}; choose 'anemometer' "
                           "or 'none'")
    dt_minv = plant.dt_minv
    if wind_on:
        base, g_speed, g_dir = plant.wind_linearisation(xs[:-1], psi[:-1])
        if wind_input == "none":
            # the mean load is a deterministic equation error (a bias); with the load
            # of the anemometer's mean wind as a known input only the variations remain
            eps_det = eps_det + base @ dt_minv.T
        g_speed = g_speed @ dt_minv.T
        g_dir = g_dir @ dt_minv.T
    sig = noise_std ** 2 * clipped_variance(clip)
    fn = np.asarray(dist.force_noise_std, float)
    w_var = (dt_minv**2) @ (fn**2)
    a_fn = math.exp(-dt / dist.force_noise_time_constant)
    a_g = math.exp(-dt / dist.gust_time_constant)
    a_d = math.exp(-dt / dist.wind_direction_time_constant)
    wave_lines = None
    if waves is not None and waves.height > 0:
        from vesselid.plant.waves import velocity_lines

        c, sn = np.cos(psi), np.sin(psi)
        north = dt * np.concatenate([[0.0], np.cumsum(c * xs[:, 0] - sn * xs[:, 1])[:-1]])
        east = dt * np.concatenate([[0.0], np.cumsum(sn * xs[:, 0] + c * xs[:, 1])[:-1]])
        g = velocity_lines(waves, dt, psi, north, east)
        wave_lines = g[:, 1:, :] - g[:, :-1, :]  # ε(row k) ≈ ξ(k+1) − ξ(k)
    # autocovariance of ε_i summed over samples (lags 0..L), for the SRIV noise model
    acov = np.zeros((spec.n_states, int(acov_lags) + 1))
    lags = np.arange(acov.shape[1])
    m_k = n_k - 1
    for i in range(spec.n_states):
        acov[i, 0] += float(np.sum(sig[i] + (jac[:, i, :] ** 2) @ sig))
        if lags.size > 1:
            acov[i, 1] -= float(np.sum(jac[1:, i, i])) * sig[i]
        acov[i] += w_var[i] * m_k * a_fn**lags
        if wind_on:
            acov[i] += dist.gust_std**2 * float(np.sum(g_speed[:, i] ** 2)) * a_g**lags
            acov[i] += (dist.wind_direction_std**2 * float(np.sum(g_dir[:, i] ** 2))
                        * a_d**lags)
        if wave_lines is not None:
            wl = wave_lines[i]
            for lag in lags:
                acov[i, lag] += 0.5 * float(np.sum((wl[:m_k - lag] * wl[lag:].conj()).real))
    if acov_only:
        return Information([], [], [], n_k, acov)
    a_list, s_list, b_list = [], [], []
    start = 0
    ar_cache: dict[Any, np.ndarray] = {}
    for i in range(spec.n_states):
        cols = np.flatnonzero(codes.equation == i)
        # augmented with a constant column: centring per experiment happens later
        # (:meth:`Information.centred`), so blocks of one experiment can be added first
        z = np.hstack([zeta[:, cols], np.ones((n_k - 1, 1))])
        ph = np.hstack([phi[:, cols], np.ones((n_k - 1, 1))])
        if prefilter is not None:
            z, ph = _fir(z, prefilter[i]), _fir(ph, prefilter[i])
            a_list.append(z.T @ ph)
            z = _fir(z, prefilter[i], reverse=True)  # y(j) = Σ_m c_m ζ_f(j+m)
        else:
            a_list.append(z.T @ ph)
        # white sensor noise: lag 0 and lag ±1 (time-varying Jacobian)
        v0 = sig[i] + (jac[:, i, :] ** 2) @ sig
        c1 = -jac[1:, i, i] * sig[i]  # cov(ε(k), ε(k+1)) for rows k, k+1
        meat = (z * v0[:, None]).T @ z
        cross = (z[:-1] * c1[:, None]).T @ z[1:]
        meat += cross + cross.T
        if w_var[i] > 0:
            # equations with the same terms share the meat (not when prefiltered: each
            # equation has its own noise model)
            key = (tuple(map(tuple, codes.factors[cols].tolist())),
                   None if prefilter is None else i)
            if key not in ar_cache:
                ar_cache[key] = _ar1_meat(z, a_fn)
            meat += w_var[i] * ar_cache[key]
        b = z.T @ eps_det[:, i]
        if wind_on:
            if dist.gust_std > 0:
                meat += dist.gust_std**2 * _ar1_meat(z * g_speed[:, i:i + 1], a_g)
            if dist.wind_direction_std > 0:
                meat += dist.wind_direction_std**2 * _ar1_meat(z * g_dir[:, i:i + 1], a_d)
        if wave_lines is not None:
            # random-phase lines: E[(Σ z ε)(Σ z ε)ᵀ] = ½ Re(W Wᴴ), W = Σ_k z_k ε-lines
            w = z.T @ wave_lines[i]
            meat += 0.5 * (w.real @ w.real.T + w.imag @ w.imag.T)
        s_list.append(meat)
        b_list.append(b)
        start += len(cols)
    return Information(a_list, s_list, b_list, n_k, acov)


@dataclass
class Prediction:
    """Predicted covariance and wind bias of a design."""

    cov: pd.DataFrame
    bias: pd.Series
    theta0: pd.Series

    @property
    def std_errors(self) -> pd.Series:
        return pd.Series(np.sqrt(np.clip(np.diag(self.cov.to_numpy()), 0, None)),
                         index=self.cov.index, name="predicted_se")

    def relative(self) -> pd.Series:
        with np.errstate(divide="ignore"):
            return (self.std_errors / self.theta0.abs()).rename("relative_se")


def predict_covariance(info: Centred | Information, spec: ModelSpec) -> Prediction:
    """``Cov θ̂ = A⁻¹ S A⁻ᵀ`` per equation (block diagonal) and the wind bias ``A⁻¹ b``."""
    from vesselid.identify.linalg import condition_number

    if isinstance(info, Information):
        info = info.centred()
    p = spec.n_params
    cov = np.full((p, p), 0.0)
    bias = np.zeros(p)
    codes = spec.codes
    for i in range(spec.n_states):
        cols = np.flatnonzero(codes.equation == i)
        try:
            a_inv = np.linalg.inv(info.a[i])
            c = a_inv @ info.s[i] @ a_inv.T
            bi = a_inv @ info.b[i]
            # equilibrated: a design is not singular because of the units of its terms
            if not (np.all(np.isfinite(c)) and condition_number(info.a[i]) < 1e14):
                raise np.linalg.LinAlgError
        except np.linalg.LinAlgError:
            c = np.full((len(cols), len(cols)), np.inf)
            bi = np.full(len(cols), np.nan)
        cov[np.ix_(cols, cols)] = c
        bias[cols] = bi
    idx = spec.param_index
    return Prediction(pd.DataFrame(cov, index=idx, columns=idx), pd.Series(bias, index=idx,
                      name="predicted_bias"), spec.theta0_series())


# --------------------------------------------------------------------- candidates
def candidate_library(limits: Sequence[float] = FORCE_LIMITS) -> list[Manoeuvre]:
    """Candidate manoeuvres for CyberShip II within the actuator ``limits``.

    Turning circles (35°, both sides), zig-zags (10/10, 20/20, 35/20, 35/35) at a low
    and a high engine setting, a pull-out, a spiral, acceleration/stopping with three
    rudder angles, thruster (crabbing) tests with three moment ratios, and thruster
    tests with independent sway force and yaw moment (:class:`ThrusterSquare`) at full
    engine, steady or alternating full ahead / full astern (``low = −1``, every 15 or
    30 s; the surge speed sweeps both signs).
    """
    lo, hi = min(0.8, limits[0]), limits[0]
    out: list[Manoeuvre] = [TurningCircle(thrust=hi, rudder=35.0, side=1, turn=360.0),
                            TurningCircle(thrust=hi, rudder=35.0, side=-1, turn=360.0)]
    for x in (lo, hi):
        out += [ZigZag(thrust=x, rudder=d, heading=h) for d, h in
                ((10, 10), (20, 20), (35, 20), (35, 35))]
    out += [PullOut(thrust=hi, rudder=35.0),
            Spiral(thrust=0.75 * hi, rudder=35.0, steps=8, hold=40.0)]
    out += [AccelerationStopping(thrust=limits[0], astern=limits[0], rudder=r)
            for r in (0.0, 15.0, 35.0)]
    out += [Crabbing(thrust=x, sway=limits[1], moment=m) for x in (0.0, 0.75 * hi)
            for m in (-0.5, 0.0, 0.5)]
    out += [ThrusterSquare(thrust=hi, sway=limits[1], moment=limits[2], hold_y=hy, hold_n=hn)
            for hy, hn in ((10.0, 7.0), (5.0, 3.5))]
    # ahead/astern: u sweeps from +1 to −0.8 m/s, which separates the constant sway/yaw
    # couplings (r: v, v: v·|r|, r: r·|v|, ...) from the u-proportional ones
    out += [ThrusterSquare(thrust=hi, sway=limits[1], moment=limits[2], hold_y=hy, hold_n=hn,
                           low=-1.0, hold_x=hx)
            for hy, hn in ((10.0, 7.0), (7.0, 10.0), (5.0, 3.5)) for hx in (15.0, 30.0)]
    return out


# --------------------------------------------------------------------------- plan
@dataclass
class TrialPlan:
    """A planned multi-experiment trial and its predicted accuracy.

    Attributes
    ----------
    programmes : list of Programme
        One manoeuvre programme per experiment.
    experiments, samples, warmup : int
        ``N_E``, samples per experiment and discarded approach samples.
    prediction : Prediction
        Predicted covariance (exact evaluation of the assembled design).
    candidates : DataFrame
        Every candidate: label, blocks chosen, feasibility.
    identifiability : list of dict
        Parameters whose predicted relative SE exceeds the target, with the best
        identified combination of the near-collinear group they belong to.
    paths, seed : int
        Disturbed path realisations behind the instrument–regressor cross moment and
        their seed (:func:`plan_trial`).
    """

    programmes: list[Programme]
    experiments: int
    samples: int
    warmup: int
    dt: float
    prediction: Prediction
    candidates: pd.DataFrame
    identifiability: list[dict[str, Any]]
    target: float
    relevance: float
    levels: DisturbanceLevels = field(default_factory=DisturbanceLevels)
    structure: str = "full"
    spec: ModelSpec | None = None
    estimator: str = "iv-zero-mean"
    paths: int = 0
    seed: int = 0

    def table(self) -> pd.DataFrame:
        """Per parameter: θ0, predicted SE, relative SE and predicted wind bias."""
        p = self.prediction
        out = pd.DataFrame({"theta0": p.theta0, "predicted_se": p.std_errors,
                            "relative_se": p.relative(), "predicted_bias": p.bias})
        out["relevant"] = p.theta0.abs() >= self.relevance
        return out

    def worst_relative_se(self) -> float:
        t = self.table()
        return float(t.loc[t["relevant"], "relative_se"].max())

    def success_probability(self, tolerance: float = 0.10, draws: int = 20000,
                            seed: int = 0) -> float:
        """Predicted probability that every relevant parameter lands within
        ``tolerance · |θ0|`` of θ0: the estimates drawn from ``N(θ0 + bias, Cov)`` of the
        prediction (block diagonal per equation, the predicted bias included), ``draws``
        samples with ``np.random.default_rng(seed)``. The trial team's chance that the
        trial identifies everything; its Monte Carlo counterpart is the fraction of seeds
        in ``scripts/planner_study.py``."""
        t = self.table()
        cov = self.prediction.cov.to_numpy()
        keep = t["relevant"].to_numpy()
        if not np.all(np.isfinite(cov[np.ix_(keep, keep)])):
            return 0.0
        bias = np.nan_to_num(t["predicted_bias"].to_numpy())[keep]
        c = cov[np.ix_(keep, keep)]
        w, v = np.linalg.eigh(0.5 * (c + c.T))
        root = v * np.sqrt(np.clip(w, 0.0, None))
        z = np.random.default_rng(seed).standard_normal((int(draws), root.shape[1]))
        err = bias + z @ root.T
        lim = float(tolerance) * t["theta0"].abs().to_numpy()[keep]
        return float(np.mean(np.all(np.abs(err) <= lim, axis=1)))

    def forces(self, plant: VesselModel | None = None) -> np.ndarray:
        """Input schedule ``(N_E, warmup + N, 3)`` of the planned experiments (switching
        instants on ``plant``, default the plan's: :meth:`DisturbanceLevels.plant`)."""
        v = plant or self.levels.plant(self.dt)
        return np.stack([p.schedule(v, self.samples, warmup=self.warmup)
                         for p in self.programmes])

    def to_dict(self) -> dict[str, Any]:
        t = self.table()

        def fin(x: float) -> float | None:
            return float(x) if math.isfinite(float(x)) else None

        params: dict[str, dict[str, Any]] = {}
        for (eq, term), row in t.iterrows():
            params.setdefault(eq, {})[term] = {
                "theta0": fin(row["theta0"]), "predicted_se": fin(row["predicted_se"]),
                "relative_se": fin(row["relative_se"]),
                "predicted_bias": fin(row["predicted_bias"]), "relevant": bool(row["relevant"])}
        return {
            "experiments": self.experiments, "samples_per_experiment": self.samples,
            "warmup_samples": self.warmup, "dt": self.dt,
            "programmes": [p.to_dict() for p in self.programmes],
            "labels": [p.label() for p in self.programmes],
            "worst_relative_se": fin(self.worst_relative_se()),
            "success_probability_10pct": fin(self.success_probability()),
            "structure": self.structure, "estimator": self.estimator,
            "disturbed_paths": self.paths, "seed": self.seed,
            "target_relative_se": self.target, "relevance": self.relevance,
            "parameters": params, "identifiability": _finite(self.identifiability),
            "levels": self.levels.to_dict(),
        }

    def summary(self) -> str:
        lines = [f"Trial plan: {self.experiments} experiments x {self.samples} samples "
                 f"(+{self.warmup} approach samples each), dt = {self.dt:g} s", ""]
        for e, p in enumerate(self.programmes):
            lines.append(f"  experiment {e}: {p.label()}")
        t = self.table().copy()
        t.index = [f"{eq}: {term}" for eq, term in t.index]
        model = {"iv-zero-mean": "asymptotic IV, zero-mean instruments",
                 "sriv": "asymptotic SRIV: zero-mean simulated instruments, "
                         f"AR({SRIV_ORDER}) prefilter",
                 "auto": "estimator auto = SRIV here: zero-mean simulated instruments, "
                         f"AR({SRIV_ORDER}) prefilter"}[self.estimator]
        if self.estimator != "iv-zero-mean":
            model += f"; identify with --noise-order {SRIV_ORDER}"
        if self.paths:
            model += (f"; instruments against the regressors of {self.paths} disturbed "
                      "paths")
        lines += ["", f"Predicted standard errors ({model}):", "",
                  _markdown(t), "",
                  f"worst relative SE over |θ0| ≥ {self.relevance:g}: "
                  f"{100 * self.worst_relative_se():.2f} % (target {100 * self.target:.1f} %)",
                  "predicted probability that every one lands within 10 % of θ0 "
                  f"(normal, with the predicted bias): {100 * self.success_probability():.0f} %"]
        if self.identifiability:
            lines.append("Not separately identifiable to the target within this budget:")
            for item in self.identifiability:
                lines.append(f"  - {item['message']}")
        infeasible = self.candidates[~self.candidates["feasible"]]
        for _, row in infeasible.iterrows():
            lines.append(f"candidate skipped: {row['label']}: {row['reason']}")
        return "\n".join(lines)


def _markdown(df: pd.DataFrame) -> str:
    """A pipe table of ``df`` with its index."""
    def cell(x: Any) -> str:
        return format(float(x), ".4g") if isinstance(x, (float, np.floating)) else str(x)

    head = ["", *map(str, df.columns)]
    lines = ["| " + " | ".join(head) + " |", "|" + "|".join(["---"] * len(head)) + "|"]
    for idx, row in df.iterrows():
        lines.append("| " + " | ".join([cell(idx), *(cell(x) for x in row)]) + " |")
    return "\n".join(lines)


def _finite(obj: Any) -> Any:
    """Replace non-finite floats by ``None`` (strict JSON), recursively."""
    if isinstance(obj, dict):
        return {k: _finite(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_finite(v) for v in obj]
    if isinstance(obj, (float, np.floating)):
        return float(obj) if math.isfinite(float(obj)) else None
    return obj


def _objective(info: Centred, spec: ModelSpec, theta0: np.ndarray, relevant: np.ndarray,
               prior: tuple[list[np.ndarray], list[np.ndarray]] | None = None,
               mode: str = "worst", bias: bool = True) -> float:
    """Design criterion on the relative mean-square errors ``(var_p + bias_p²)/θ0_p²``
    of the relevant parameters (``bias`` from the deterministic equation errors):
    ``"worst"`` (the largest relative SE, minimax) or ``"mean"`` (mean
    relative variance, A-optimality in relative units). ``prior`` adds a weak
    pseudo-experiment ``(A_p, S_p)`` so that designs that leave a direction unidentified
    get a large but finite value (greedy steps from an empty design)."""
    rel_var = []
    codes = spec.codes
    for i in range(spec.n_states):
        cols = np.flatnonzero(codes.equation == i)
        a, s = info.a[i], info.s[i]
        if prior is not None:
            a, s = a + prior[0][i], s + prior[1][i]
        try:
            a_inv = np.linalg.inv(a)
        except np.linalg.LinAlgError:
            return math.inf
        var = np.clip(np.einsum("ij,jk,ik->i", a_inv, s, a_inv), 0, None)
        if bias:
            var = var + (a_inv @ info.b[i]) ** 2
        keep = relevant[cols]
        rel_var.append(var[keep] / theta0[cols][keep] ** 2)
    rv = np.concatenate(rel_var)
    if not np.all(np.isfinite(rv)):
        return math.inf
    if rv.size == 0:
        return 0.0
    return float(math.sqrt(rv.max())) if mode == "worst" else float(rv.mean())


def _identifiability(pred: Prediction, target: float, relevance: float) -> list[dict[str, Any]]:
    """Parameters above the target and their best-identified pairwise combinations."""
    cov = pred.cov.to_numpy()
    se = pred.std_errors.to_numpy()
    th = pred.theta0.to_numpy()
    idx = list(pred.cov.index)
    out = []
    for p in range(len(idx)):
        if abs(th[p]) < relevance or not (se[p] / abs(th[p]) > target):
            continue
        eq = idx[p][0]
        best = None
        for q in range(len(idx)):
            if q == p or idx[q][0] != eq or not (se[q] > 0) or not math.isfinite(se[q]):
                continue
            corr = cov[p, q] / (se[p] * se[q])
            if best is None or abs(corr) > abs(best[1]):
                best = (q, corr)
        item: dict[str, Any] = {"equation": eq, "term": idx[p][1],
                                "relative_se": float(se[p] / abs(th[p]))}
        msg = (f"{eq}: {idx[p][1]} — predicted SE {100 * item['relative_se']:.1f} % of θ0")
        if best is not None and math.isfinite(best[1]):
            q, corr = best
            c2 = cov[np.ix_([p, q], [p, q])] / np.outer([abs(th[p]), abs(th[q])],
                                                          [abs(th[p]), abs(th[q])])
            w, v = np.linalg.eigh(c2)
            comb = v[:, 0] / np.max(np.abs(v[:, 0]))
            item.update({"partner": idx[q][1], "correlation": float(corr),
                         "combination": {idx[p][1]: float(comb[0] / abs(th[p])),
                                         idx[q][1]: float(comb[1] / abs(th[q]))},
                         "combination_relative_se": float(math.sqrt(max(w[0], 0.0)))})
            msg += (f"; correlated {corr:+.2f} with {idx[q][1]}: the combination "
                    f"{comb[0]:+.2f}·θ[{idx[p][1]}]/|θ0| {comb[1]:+.2f}·θ[{idx[q][1]}]/|θ0| "
                    f"is identified to {100 * math.sqrt(max(w[0], 0.0)):.1f} %")
        item["message"] = msg
        out.append(item)
    return out


def plan_trial(
    samples: int = 120_000,
    experiments: int = 6,
    *,
    levels: DisturbanceLevels | None = None,
    candidates: Sequence[Manoeuvre] | None = None,
    block: int = 4000,
    warmup: int = 600,
    dt: float = 0.1,
    relevance: float = 1e-3,
    target: float = 0.033,
    limits: Sequence[float] = FORCE_LIMITS,
    max_exchange: int = 2,
    evaluate_block: int = 4000,
    structure: str = "full",
    estimator: str = "auto",
    paths: int | None = None,
    seed: int = 0,
) -> TrialPlan:
    """Plan a trial: choose the manoeuvres (and how long each runs) for a sample budget.

    Parameters
    ----------
    samples : int
        Total sample budget (all experiments).
    experiments : int
        Number of experiments ``N_E``; each gets ``samples // experiments`` samples.
    levels : DisturbanceLevels, optional
        Disturbances assumed (default: the sea-trial defaults).
    candidates : sequence of Manoeuvre, optional
        Candidate manoeuvres (default :func:`candidate_library`).
    block : int
        Length of a design block (samples); experiments are packed with blocks.
    warmup : int
        Straight-approach samples before each experiment (simulated, discarded).
    dt : float
        Sample time (s).
    relevance : float
        Parameters with ``|θ0|`` below this do not enter the objective (their SE is
        still predicted and reported).
    target : float
        Relative SE that counts as identified (default 3.3 %: a 10 % error is 3 SE).
    limits : (float, float, float)
        Actuator limits ``|X|, |Y|, |N|``.
    max_exchange : int
        Passes of the exchange algorithm.
    evaluate_block : int
        Samples simulated per candidate (its information is scaled to ``block``).
    structure : {"full", "merged"}
        Identification structure (:data:`STRUCTURES`).
    estimator : {"auto", "sriv", "iv-zero-mean"}
        Estimator whose covariance the assembled design's prediction models
        (:data:`PREDICTED_ESTIMATORS`); the manoeuvres are always chosen on the
        additive zero-mean IV moments.
    paths : int, optional
        Disturbed path realisations per design evaluation for the instrument–regressor
        cross moment (default :data:`DISTURBED_PATHS`; 0: instruments assumed to track
        the vessel exactly).
    seed : int
        Seed of those realisations.

    Returns
    -------
    TrialPlan
    """
    if estimator not in PREDICTED_ESTIMATORS:
        raise PlannerError(f"unknown estimator {estimator!r}; choose from "
                           f"{list(PREDICTED_ESTIMATORS)}")
    n_e = int(experiments)
    if n_e < 1:
        raise PlannerError(f"need at least one experiment, got {experiments}")
    n_d = int(samples) // n_e
    if n_d < 50:
        raise PlannerError(f"need at least 50 samples per experiment, got {n_d}")
    blk = int(min(block, n_d))
    per_exp = max(1, n_d // blk)
    n_blocks = n_e * per_exp
    lv = levels or DisturbanceLevels()
    n_paths = DISTURBED_PATHS if paths is None else int(paths)
    if n_paths < 0:
        raise PlannerError(f"paths must be non-negative, got {paths}")
    plant, spec = _planner_plant(dt, structure, lv)
    lims = tuple(float(x) for x in limits)
    theta0 = spec.theta0_vector()
    relevant = np.abs(theta0) >= relevance
    cands = list(candidates) if candidates is not None else candidate_library(limits)
    infos: list[Information | None] = []
    rows = []
    n_eval = min(blk, int(evaluate_block))
    for m in cands:
        try:
            f = Programme([m]).schedule(plant, n_eval, warmup=warmup, limits=lims)
            info = design_information(f, plant, spec=spec, waves=lv.waves,
                                      wind_input=lv.wind_input, warmup=warmup, paths=n_paths,
                                      seed=seed)
            infos.append(info.scaled(blk / n_eval))
            rows.append({"label": m.label(), "feasible": True, "reason": ""})
        except (ManoeuvreError, VesselidError) as exc:
            infos.append(None)
            rows.append({"label": m.label(), "feasible": False, "reason": str(exc)})
    ok = [i for i, x in enumerate(infos) if x is not None]
    if not ok:
        raise PlannerError("no candidate manoeuvre is feasible within the actuator limits and "
                           f"disturbance levels (first: {rows[0]['label']}: {rows[0]['reason']})")
    # a weak prior (SE = 10 |θ0|) so greedy steps from an empty design are defined
    cen = [infos[i].centred() for i in ok]
    prior_a, prior_s = [], []
    for q in range(spec.n_states):
        # isotropic in relative units θ_p/|θ0_p|: A_p = λ D⁻¹, S_p = 100 λ² I
        cols = np.flatnonzero(spec.codes.equation == q)
        d = np.maximum(np.abs(theta0[cols]), relevance)
        lam = 1e-4 * max(float(np.max(np.abs(np.diag(c.a[q]) * d))) for c in cen)
        prior_a.append(np.diag(lam / d))
        prior_s.append(100.0 * lam**2 * np.eye(cols.size))
    prior = (prior_a, prior_s)
    empty = infos[ok[0]].scaled(0.0)
    slots: list[list[int]] = [[] for _ in range(n_e)]
    sums = [empty for _ in range(n_e)]
    cents = [empty.centred() for _ in range(n_e)]

    def total_without(e: int) -> Centred:
        out = None
        for j in range(n_e):
            if j != e:
                out = cents[j] if out is None else out + cents[j]
        return out if out is not None else empty.centred()

    def score(rest: Centred, base: Information, i: int, mode: str) -> float:
        return _objective(rest + (base + infos[i]).centred(), spec, theta0, relevant, prior,
                          mode)

    for step in range(n_blocks):
        e = step % n_e
        rest = total_without(e)
        best = min(ok, key=lambda i: score(rest, sums[e], i, "mean"))
        slots[e].append(best)
        sums[e] = sums[e] + infos[best]
        cents[e] = sums[e].centred()
    for _ in range(int(max_exchange)):
        improved = False
        for e in range(n_e):
            rest = total_without(e)
            for pos in range(len(slots[e])):
                base = sums[e] + infos[slots[e][pos]].scaled(-1.0)
                cur = score(rest, base, slots[e][pos], "worst")
                best_i, best_v = slots[e][pos], cur
                for i in ok:
                    v = score(rest, base, i, "worst")
                    if v < best_v * (1 - 1e-6):
                        best_i, best_v = i, v
                if best_i != slots[e][pos]:
                    slots[e][pos] = best_i
                    sums[e] = base + infos[best_i]
                    cents[e] = sums[e].centred()
                    improved = True
        if not improved:
            break
    chosen = [i for sl in slots for i in sl]
    counts = np.bincount(chosen, minlength=len(cands))
    cand_table = pd.DataFrame(rows)
    cand_table["blocks"] = counts
    programmes = []
    for items in slots:
        uniq: list[int] = []
        for i in items:
            if i not in uniq:
                uniq.append(i)
        durs = [blk * items.count(i) for i in uniq]
        durs[-1] += n_d - sum(durs)
        programmes.append(Programme([cands[i] for i in uniq], durs))
    # exact evaluation of the assembled design
    forces = [p.schedule(plant, n_d, warmup=warmup, limits=lims) for p in programmes]
    pred = _assembled_prediction(forces, plant, spec, lv, warmup, estimator, n_paths, seed)
    with np.errstate(invalid="ignore"):  # a negative variance is a non-finite SE below
        worst = np.sqrt(np.diag(pred.cov.to_numpy()))[relevant]
    if candidates is None and not np.all(np.isfinite(worst)):
        # small budgets: the greedy choice among thruster squares at one engine setting
        # can leave the surge equation unexcited; plan with the rudder manoeuvres only
        lib = [c for c in cands if not isinstance(c, ThrusterSquare)]
        return plan_trial(samples, experiments, levels=levels, candidates=lib, block=block,
                          warmup=warmup, dt=dt, relevance=relevance, target=target,
                          limits=limits, max_exchange=max_exchange,
                          evaluate_block=evaluate_block, structure=structure,
                          estimator=estimator, paths=paths, seed=seed)
    return TrialPlan(programmes=programmes, experiments=n_e, samples=n_d, warmup=int(warmup),
                     dt=float(dt), prediction=pred, candidates=cand_table,
                     identifiability=_identifiability(pred, target, relevance),
                     target=float(target), relevance=float(relevance), levels=lv,
                     structure=structure, spec=spec, estimator=estimator, paths=n_paths,
                     seed=int(seed))


def predict_design(forces: np.ndarray, *, warmup: int = 0, dt: float = 0.1,
                   levels: DisturbanceLevels | None = None,
                   structure: str = "full", estimator: str = "iv-zero-mean",
                   paths: int | None = None, seed: int = 0) -> Prediction:
    """Predicted covariance of explicit input schedules ``(N_E, warmup + N, 3)``
    (``paths``, ``seed``: as :func:`plan_trial`)."""
    if estimator not in PREDICTED_ESTIMATORS:
        raise PlannerError(f"unknown estimator {estimator!r}; choose from "
                           f"{list(PREDICTED_ESTIMATORS)}")
    lv = levels or DisturbanceLevels()
    plant, spec = _planner_plant(dt, structure, lv)
    return _assembled_prediction(list(np.asarray(forces, float)), plant, spec, lv, warmup,
                                 estimator, DISTURBED_PATHS if paths is None else int(paths),
                                 seed)


#: Estimators the planner predicts: ``iv-zero-mean`` (the paper's IV_{E{ζ}=0}),
#: ``sriv`` (simulated instruments prefiltered with the AR(:data:`SRIV_ORDER`) noise
#: model of the equation error) and ``auto`` (the package default: on a sea trial its
#: colour and C tests reject the delayed instruments — the Gauss–Markov forces colour the
#: equation error — and it falls back to SRIV, so it is predicted as SRIV).
PREDICTED_ESTIMATORS = ("auto", "sriv", "iv-zero-mean")
#: AR order of the SRIV noise model on a sea trial, passed to identify explicitly
#: (``noise_order``; ``vesselid identify --noise-order``, which ``vesselid sea-trial``
#: prints): ``auto``'s fallback and ``sriv`` then use it instead of their default 4.
#: The equation error is the differenced white sensor noise
#: (an MA(1) whose root is near the unit circle: lag-1 correlation −0.5) plus 2-s
#: Gauss–Markov forces, which a low-order AR model whitens poorly
#: (``scripts/planner_study.py`` compares the orders on simulated trials).
SRIV_ORDER = 16
#: Disturbed path realisations per design evaluation (:meth:`VesselModel.disturbed_paths`): the
#: instrument–regressor cross moment is averaged over them.
DISTURBED_PATHS = 4


def _assembled_prediction(forces: list[np.ndarray], plant: VesselModel, spec: ModelSpec,
                          lv: DisturbanceLevels, warmup: int, estimator: str,
                          paths: int = 0, seed: int = 0) -> Prediction:
    """Covariance of the assembled experiments (each simulated continuously, instruments
    centred per experiment) for ``estimator``; SRIV evaluates the design twice: the
    pooled equation-error autocovariance gives the AR noise model, then the prefiltered
    moments."""
    c = None
    if estimator != "iv-zero-mean":
        acov = sum(design_information(f, plant, spec=spec, waves=lv.waves,
                                      wind_input=lv.wind_input, warmup=warmup,
                                      acov_lags=SRIV_ORDER, acov_only=True).acov
                   for f in forces)
        c = sriv_prefilter(acov)
    # identify's refined-IV family (auto's SRIV fallback) corrects the square modulus
    # regressors for the sensor noise recorded in the sea-trial log; IV_E{ζ}=0 does not
    raw = [design_information(f, plant, spec=spec, waves=lv.waves, wind_input=lv.wind_input,
                              warmup=warmup, prefilter=c, paths=paths,
                              seed=seeds.experiment_seed(seed, e),
                              sensor_noise_corrected=c is not None)
           for e, f in enumerate(forces)]
    info = None
    for r in raw:
        e = r.centred()
        info = e if info is None else info + e
    return predict_covariance(info, spec)
