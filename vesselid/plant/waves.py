"""First-order wave-induced motion from a JONSWAP spectrum, as a coloured sensor disturbance.

Spectrum
--------
JONSWAP (Hasselmann et al. 1973, *Measurements of wind-wave growth and swell decay
during the Joint North Sea Wave Project*, Dtsch. Hydrogr. Z. A8(12)) in the
parametrisation of DNV-RP-C205 (*Environmental conditions and environmental loads*,
§3.5.5) by significant wave height ``H_s``, peak period ``T_p`` and peak enhancement
``γ`` (3.3 by default)::

    S(ω) = A_γ · (5/16) H_s² ω_p⁴ ω⁻⁵ exp(−5/4 (ω/ω_p)⁻⁴) · γ^exp(−(ω−ω_p)²/(2σ²ω_p²)),
    A_γ = 1 − 0.287 ln γ,  σ = 0.07 (ω ≤ ω_p), 0.09 (ω > ω_p),  ω_p = 2π/T_p.

Long-crested waves travel towards ``direction`` (earth frame, going-to, rad). A
model-scale vessel (scale ``1:λ``) sees the Froude-scaled sea: ``H_s/λ``, ``T_p/√λ``
(Fossen 2011, *Handbook of Marine Craft Hydrodynamics and Motion Control*, Wiley, ch. 10;
the sea-state table there gives e.g. sea state 4, "moderate": H_s 1.25–2.5 m).

Realisation
-----------
The sea is a sum of ``M`` regular components (Fossen 2011 §10.2.1; Faltinsen 1990,
*Sea Loads on Ships and Offshore Structures*, Cambridge, ch. 2) with amplitudes
``a_i = √(2 S(ω_i) Δω)``, frequencies drawn inside equal bins and phases uniform on
``[0, 2π)``, all from the caller's seeded generator; deep-water wave numbers
``k = ω²/g``. The phase seen by the moving vessel is ``Θ_i(t) = ω_i t − k_i (n cos χ +
e sin χ) + φ_i`` along its track ``(n, e)`` (this gives the encounter frequency). The
whole ``(samples × components)`` array is evaluated at once (no per-sample loop).

Response (first order, horizontal plane)
----------------------------------------
A slender hull of length ``L`` follows the horizontal orbital motion of the surface
particles, averaged over its length (the long-wave, Froude–Krylov limit of strip theory,
Faltinsen 1990 ch. 3 and 5; the averaging factors cut off waves shorter than the hull).
With ``β = χ − ψ`` the wave direction relative to the bow and ``s = k L cos β / 2``:

* surge displacement ``x_w = a cos β · sinc(s) · sin Θ``,
* sway displacement  ``y_w = a sin β · sinc(s) · sin Θ``,
* yaw ``ψ_w = −a k sin β cos β · h(s) · cos Θ`` with ``h(s) = 3 (sin s − s cos s)/s³``
  (the least-squares slope of the lateral displacement along the hull; ``h → 1`` for
  long waves),

and the velocities are their time derivatives at the encounter frequency. These are
added to the *measured* positions, heading and velocities (GNSS, speed log, gyro) as a
coloured sensor disturbance; the low-frequency manoeuvring model is not changed (the
usual separation of wave-frequency and manoeuvring motion, Fossen 2011 §10.2).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from vesselid.errors import VesselidError

__all__ = [
    "SEA_STATES",
    "WaveConditions",
    "WaveError",
    "jonswap",
    "velocity_lines",
    "wave_motion",
]

G = 9.81


class WaveError(VesselidError):
    """Bad wave settings."""


#: Full-scale sea states (WMO code; H_s mid-range in m, typical T_p in s; Fossen 2011 ch. 8
#: and DNV-RP-C205 scatter diagrams).
SEA_STATES: dict[str, tuple[float, float]] = {
    "calm": (0.05, 3.0),
    "smooth": (0.3, 5.0),
    "slight": (0.9, 6.5),
    "moderate": (1.9, 8.0),
    "rough": (3.25, 9.5),
}


@dataclass(frozen=True)
class WaveConditions:
    """A sea state and the vessel it acts on.

    Parameters
    ----------
    height, period : float
        Full-scale significant wave height ``H_s`` (m) and peak period ``T_p`` (s).
    direction : float
        Going-to direction of the waves, earth frame (rad; 0 = towards north).
    gamma : float
        JONSWAP peak enhancement factor.
    scale : float
        Model scale ``λ`` (CyberShip II: 70); the sea is Froude-scaled by it.
    length : float
        Hull length ``L`` (m, model scale).
    components : int
        Number of regular components in a realisation.
    band : (float, float)
        Frequency band as multiples of ``ω_p``.
    """

    height: float = 1.9
    period: float = 8.0
    direction: float = math.radians(45.0)
    gamma: float = 3.3
    scale: float = 70.0
    length: float = 1.255
    components: int = 48
    band: tuple[float, float] = (0.6, 3.0)

    def __post_init__(self) -> None:
        for name in ("height", "period", "direction", "gamma", "scale", "length"):
            v = float(getattr(self, name))
            if not math.isfinite(v):
                raise WaveError(f"wave {name} must be finite, got {v!r}")
        if self.height < 0:
            raise WaveError(f"wave height must be >= 0, got {self.height}")
        for name in ("period", "scale", "length"):
            if getattr(self, name) <= 0:
                raise WaveError(f"wave {name} must be positive")
        if self.gamma < 1:
            raise WaveError(f"JONSWAP gamma must be >= 1, got {self.gamma}")
        if int(self.components) < 1:
            raise WaveError("need at least one wave component")
        lo, hi = (float(b) for b in self.band)
        if not (0 < lo < hi):
            raise WaveError(f"band must be 0 < low < high, got {self.band}")

    @classmethod
    def sea_state(cls, name: str, **kwargs: Any) -> WaveConditions:
        """Conditions of a named sea state (:data:`SEA_STATES`)."""
        if name not in SEA_STATES:
            raise WaveError(f"unknown sea state {name!r}; choose from {sorted(SEA_STATES)}")
        hs, tp = SEA_STATES[name]
        return cls(height=hs, period=tp, **kwargs)

    @property
    def model_height(self) -> float:
        """``H_s/λ`` (m)."""
        return self.height / self.scale

    @property
    def model_period(self) -> float:
        """``T_p/√λ`` (s)."""
        return self.period / math.sqrt(self.scale)

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d["band"] = list(self.band)
        d["model_height"] = self.model_height
        d["model_period"] = self.model_period
        return d


def jonswap(omega: np.ndarray, height: float, period: float, gamma: float = 3.3) -> np.ndarray:
    """JONSWAP spectral density ``S(ω)`` (m² s), DNV-RP-C205 §3.5.5 (see module doc)."""
    w = np.asarray(omega, dtype=float)
    wp = 2.0 * math.pi / period
    out = np.zeros_like(w)
    pos = w > 0
    wpos = w[pos]
    sigma = np.where(wpos <= wp, 0.07, 0.09)
    pm = 5.0 / 16.0 * height**2 * wp**4 * wpos**-5.0 * np.exp(-1.25 * (wpos / wp) ** -4.0)
    peak = gamma ** np.exp(-((wpos - wp) ** 2) / (2.0 * sigma**2 * wp**2))
    out[pos] = (1.0 - 0.287 * math.log(gamma)) * pm * peak
    return out


def _components(waves: WaveConditions, rng: np.random.Generator | None):
    """Frequencies, amplitudes, wave numbers and phases of a realisation (model scale).

    With ``rng=None`` the bin centres and zero phases (for covariance computations)."""
    m = int(waves.components)
    wp = 2.0 * math.pi / waves.model_period
    lo, hi = waves.band[0] * wp, waves.band[1] * wp
    edges = np.linspace(lo, hi, m + 1)
    dw = edges[1] - edges[0]
    if rng is None:
        omega = 0.5 * (edges[:-1] + edges[1:])
        phase = np.zeros(m)
    else:
        omega = edges[:-1] + dw * rng.random(m)
        phase = 2.0 * math.pi * rng.random(m)
    amp = np.sqrt(2.0 * jonswap(omega, waves.model_height, waves.model_period, waves.gamma)
                  * dw)
    return omega, amp, omega**2 / G, phase


def _transfer(waves: WaveConditions, k: np.ndarray, beta: np.ndarray):
    """Hull-averaged response factors (surge, sway, yaw) for wave numbers ``k`` (M,) and
    relative directions ``beta`` (N, 1)."""
    cb, sb = np.cos(beta), np.sin(beta)
    s = (0.5 * waves.length * k)[None, :] * cb
    small = np.abs(s) < 1e-3
    ss = np.where(small, 1.0, s)
    es = np.exp(1j * ss)
    sin_s, cos_s = es.imag, es.real
    sinc = np.where(small, 1.0 - s * s / 6.0, sin_s / ss)
    h = np.where(small, 1.0 - s * s / 10.0, 3.0 * (sin_s - ss * cos_s) / ss**3)
    return cb * sinc, sb * sinc, -(k[None, :] * (sb * cb)) * h


def wave_motion(
    waves: WaveConditions,
    dt: float,
    psi: np.ndarray,
    north: np.ndarray,
    east: np.ndarray,
    rng: np.random.Generator,
    *,
    chunk: int = 4096,
) -> dict[str, np.ndarray]:
    """Wave-induced motion along a track: displacements and body-frame velocities.

    Parameters
    ----------
    waves : WaveConditions
    dt : float
        Sample time (s).
    psi, north, east : ndarray (N,)
        Heading (rad) and earth-frame position (m) of the vessel, one row per sample.
    rng : numpy.random.Generator
        Draws the component frequencies and phases.
    chunk : int
        Samples evaluated at once (bounds the ``chunk × M`` work arrays).

    Returns
    -------
    dict
        ``x, y, psi`` (surge/sway displacement in m, yaw in rad) and ``u, v, r``
        (their rates, m/s and rad/s), each ``(N,)``.
    """
    psi = np.asarray(psi, dtype=float)
    north = np.asarray(north, dtype=float)
    east = np.asarray(east, dtype=float)
    n = psi.shape[0]
    omega, amp, k, phase = _components(waves, rng)
    chi = float(waves.direction)
    out = {c: np.zeros(n) for c in ("x", "y", "psi", "u", "v", "r")}
    if n == 0 or waves.height == 0:
        return out
    t = np.arange(n) * float(dt)
    along = north * math.cos(chi) + east * math.sin(chi)
    # encounter frequency from the along-wave velocity of the track
    v_along = np.gradient(along, float(dt)) if n > 1 else np.zeros(n)
    for a in range(0, n, int(chunk)):
        b = min(n, a + int(chunk))
        theta = omega[None, :] * t[a:b, None] - k[None, :] * along[a:b, None] + phase
        we = omega[None, :] - k[None, :] * v_along[a:b, None]
        fx, fy, fpsi = _transfer(waves, k, (chi - psi[a:b])[:, None])
        e = np.exp(1j * theta)
        s, c = e.imag, e.real
        fx *= amp
        fy *= amp
        fpsi *= amp
        out["x"][a:b] = np.einsum("ij,ij->i", fx, s)
        out["y"][a:b] = np.einsum("ij,ij->i", fy, s)
        out["psi"][a:b] = np.einsum("ij,ij->i", fpsi, c)
        c *= we
        s *= we
        out["u"][a:b] = np.einsum("ij,ij->i", fx, c)
        out["v"][a:b] = np.einsum("ij,ij->i", fy, c)
        out["r"][a:b] = -np.einsum("ij,ij->i", fpsi, s)
    return out


def velocity_lines(waves: WaveConditions, dt: float, psi: np.ndarray, north: np.ndarray,
                   east: np.ndarray) -> np.ndarray:
    """Complex line sequences ``g[c, k, i]`` of the velocity disturbance of channel ``c``
    (u, v, r) from component ``i``: the realisation is ``Re Σ_i e^{iφ_i} g[c, k, i]`` with
    independent uniform phases ``φ_i`` (bin-centre frequencies; for covariances)."""
    psi = np.asarray(psi, dtype=float)
    omega, amp, k, _ = _components(waves, None)
    chi = float(waves.direction)
    n = psi.shape[0]
    t = np.arange(n) * float(dt)
    along = np.asarray(north) * math.cos(chi) + np.asarray(east) * math.sin(chi)
    v_along = np.gradient(along, float(dt)) if n > 1 else np.zeros(n)
    theta = omega[None, :] * t[:, None] - k[None, :] * along[:, None]
    we = omega[None, :] - k[None, :] * v_along[:, None]
    fx, fy, fpsi = _transfer(waves, k, (chi - psi)[:, None])
    e = np.exp(1j * theta)
    # cos Θ = Re e^{iΘ}, sin Θ = Re(−i e^{iΘ})
    return np.stack([amp * fx * we * e, amp * fy * we * e, -amp * fpsi * we * (-1j) * e])
