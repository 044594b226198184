"""CyberShip II surge/sway/yaw model, its discrete-time second-order modulus form, and a
compiled batch simulator with ocean current, Blendermann wind and sensors.

Physical model
--------------
CyberShip II is a 1:70 model of a supply ship (L = 1.255 m, m = 23.8 kg) identified by
Skjetne, Smogeli & Fossen (2004), "A nonlinear ship manoeuvering model: identification
and adaptive control with experiments for a model ship", *Modeling, Identification and
Control* 25(1), 3–27 (the coefficient table is reproduced in :class:`CyberShip2Coefficients`).
With ``ν = [u, v, r]`` (surge, sway, yaw rate), an irrotational earth-fixed current and
the velocity relative to water ``ν_r = ν − ν_c`` (Fossen 2011, §10.3)::

    M ν̇_r + C(ν_r) ν_r + D(ν_r) ν_r = τ + τ_wind,      M = M_RB + M_A,  C = C_RB + C_A,

with linear plus modulus damping ``D`` (X_|u|u, Y_|v|v, Y_|r|v, Y_|v|r, Y_|r|r, N_|v|v,
N_|r|v, N_|v|r, N_|r|r) and generalised forces ``τ = [X, Y, N]``. The published cubic
surge term ``X_uuu u³`` is *not* a second-order modulus term; it is left out of the
identification model and offered as the option ``cubic_surge=True`` of the simulator and
the environment (the identification spec is then misspecified).

Discrete-time regression (paper Definition 2.1, eq. (1)–(2))
-----------------------------------------------------------
Explicit Euler at ``dt`` gives ``ν_r(k+1) = ν_r(k) + dt M⁻¹(τ − C(ν_r)ν_r − D(ν_r)ν_r)``,
a second-order modulus function ``Φᵀ([ν_r; τ]) θ0`` (see :func:`cybership2_spec`). In the
paper's notation, with the absolute velocity as state (GNSS measures it)::

    x(k+1) = Φᵀ([x(k) + v(k); τ(k)]) θ0 + w(k),
    v(k) = −ν_c(k),  w(k) = ν_c(k+1) + dt M⁻¹ (τ_wind(k) + τ_noise(k) [+ X_uuu u_r³ e₁]),

so the current enters *inside* the nonlinearity (the paper's non-additive ``v``) and the
wind, force noise and the change of the body-frame current are additive (``w``). A
Doppler speed log measures ``ν_r = x + v`` directly: the aggregated state of Remark 4.3.

Kinematics ``η = [north, east, ψ]``: ``η(k+1) = η(k) + dt R(ψ(k)) ν(k)``.

One implementation of the physics
---------------------------------
The compiled kernels below evaluate the hydrodynamics only through the spec's factor
layout and θ0 (:func:`vesselid.regressors.advance`), exactly like
:func:`vesselid.simulate.simulate_states`; they add the heading-dependent current, wind,
force noise and sensors around it. :func:`simulate_cybership2` (offline trials) and the
gymnasium environments in :mod:`vesselid.envs.manoeuvring` share them.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass, field, fields
from typing import Any

import numpy as np
from numba import njit, prange
from scipy import signal as sps

from vesselid.disturbances import GaussMarkov
from vesselid.errors import SimulationDivergedError, VesselidError
from vesselid.model import ModelSpec
from vesselid.regressors import advance, kernel
from vesselid.simulate import DEFAULT_DIVERGENCE_LIMIT

__all__ = [
    "BLENDERMANN94",
    "CYBERSHIP2",
    "SENSOR_CHANNELS",
    "SENSOR_GROUPS",
    "BlendermannWind",
    "CyberShip2Coefficients",
    "CyberShip2Disturbances",
    "CyberShip2Sensors",
    "CyberShip2Simulation",
    "VesselModel",
    "blendermann_wind_force",
    "cybership2_spec",
    "cybership2_system",
    "simulate_cybership2",
]

DEFAULT_DT = 0.1


# --------------------------------------------------------------------------- coefficients
@dataclass(frozen=True)
class CyberShip2Coefficients:
    """Published CyberShip II coefficients (Skjetne, Smogeli & Fossen 2004, MIC 25(1)).

    Values as tabulated in the paper and reproduced in open-source ports (e.g. the
    ``CyberShipII`` class of TUD-RL, ``tud_rl/envs/_envs/CyberShipII.py``). Units SI;
    forces in N, moments in N m. Field names drop the modulus bars: ``X_uu`` is
    X_|u|u (coefficient of ``|u| u``), ``Y_rv`` is Y_|r|v (coefficient of ``|r| v``),
    ``Y_vr`` is Y_|v|r (coefficient of ``|v| r``), and so on.

    ========  =========  ========  =========  ========  =========
    m         23.8       X_u̇       −2.0       X_u       −0.72253
    I_z       1.76       Y_v̇       −10.0      X_|u|u    −1.32742
    x_g       0.046      Y_ṙ       0.0        X_uuu     −5.86643
    L         1.255      N_v̇       0.0        Y_v       −0.88965
    B         0.29       N_ṙ       −1.0       Y_|v|v    −36.47287
    Y_|r|v    −0.805     Y_r       −7.250     Y_|v|r    −0.845
    Y_|r|r    −3.450     N_v       0.03130    N_|v|v    3.95645
    N_|r|v    0.130      N_r       −1.900     N_|v|r    0.080
    N_|r|r    −0.750
    ========  =========  ========  =========  ========  =========
    """

    m: float = 23.8
    I_z: float = 1.76
    x_g: float = 0.046
    X_udot: float = -2.0
    Y_vdot: float = -10.0
    Y_rdot: float = 0.0
    N_vdot: float = 0.0
    N_rdot: float = -1.0
    X_u: float = -0.72253
    X_uu: float = -1.32742
    X_uuu: float = -5.86643
    Y_v: float = -0.88965
    Y_vv: float = -36.47287
    Y_rv: float = -0.805
    Y_r: float = -7.250
    Y_vr: float = -0.845
    Y_rr: float = -3.450
    N_v: float = 0.03130
    N_vv: float = 3.95645
    N_rv: float = 0.130
    N_r: float = -1.900
    N_vr: float = 0.080
    N_rr: float = -0.750
    L: float = 1.255
    B: float = 0.29

    def __post_init__(self) -> None:
        for f in fields(self):
            v = getattr(self, f.name)
            if not math.isfinite(float(v)):
                raise VesselidError(f"coefficient {f.name} must be finite, got {v}")
        for name in ("m", "I_z", "L", "B"):
            if getattr(self, name) <= 0:
                raise VesselidError(f"coefficient {name} must be positive")
        mm = self.mass_matrix()
        if np.any(np.linalg.eigvalsh(0.5 * (mm + mm.T)) <= 0):
            raise VesselidError("the mass matrix M = M_RB + M_A must be positive definite")

    def mass_matrix(self) -> np.ndarray:
        """``M = M_RB + M_A`` (3×3)."""
        m, xg = self.m, self.x_g
        return np.array([
            [m - self.X_udot, 0.0, 0.0],
            [0.0, m - self.Y_vdot, m * xg - self.Y_rdot],
            [0.0, m * xg - self.N_vdot, self.I_z - self.N_rdot],
        ])

    def mass_matrix_inverse(self) -> np.ndarray:
        """``M⁻¹`` by blocks, so the structural zeros of ``M`` stay exactly zero."""
        mm = self.mass_matrix()
        out = np.zeros((3, 3))
        out[0, 0] = 1.0 / mm[0, 0]
        a, b, c, d = mm[1, 1], mm[1, 2], mm[2, 1], mm[2, 2]
        det = a * d - b * c
        out[1:, 1:] = np.array([[d, -b], [-c, a]]) / det
        return out

    def coriolis_matrix(self, nu: np.ndarray) -> np.ndarray:
        """``C(ν) = C_RB(ν) + C_A(ν)`` (Fossen 2011, 3-DOF, as in Skjetne et al. 2004)."""
        u, v, r = (float(x) for x in nu)
        m, xg = self.m, self.x_g
        c13 = -m * (xg * r + v) + self.Y_vdot * v + 0.5 * (self.N_vdot + self.Y_rdot) * r
        c23 = m * u - self.X_udot * u
        return np.array([[0.0, 0.0, c13], [0.0, 0.0, c23], [-c13, -c23, 0.0]])

    def damping_matrix(self, nu: np.ndarray, *, cubic_surge: bool = False) -> np.ndarray:
        """``D(ν)``: linear plus modulus damping (plus ``−X_uuu u²`` if ``cubic_surge``)."""
        u, v, r = (float(x) for x in nu)
        au, av, ar = abs(u), abs(v), abs(r)
        d11 = -self.X_u - self.X_uu * au - (self.X_uuu * u * u if cubic_surge else 0.0)
        d22 = -self.Y_v - self.Y_vv * av - self.Y_rv * ar
        d23 = -self.Y_r - self.Y_vr * av - self.Y_rr * ar
        d32 = -self.N_v - self.N_vv * av - self.N_rv * ar
        d33 = -self.N_r - self.N_vr * av - self.N_rr * ar
        return np.array([[d11, 0.0, 0.0], [0.0, d22, d23], [0.0, d32, d33]])

    def acceleration(
        self, nu_r: np.ndarray, tau: np.ndarray, *, cubic_surge: bool = False
    ) -> np.ndarray:
        """``ν̇_r = M⁻¹ (τ − C(ν_r)ν_r − D(ν_r)ν_r)`` (matrix form, for checks)."""
        nu_r = np.asarray(nu_r, dtype=float)
        rhs = np.asarray(tau, dtype=float) - self.coriolis_matrix(nu_r) @ nu_r
        rhs = rhs - self.damping_matrix(nu_r, cubic_surge=cubic_surge) @ nu_r
        return self.mass_matrix_inverse() @ rhs

    def steady_surge_speed(self, X: float, *, cubic_surge: bool = False) -> float:
        """Steady surge speed for a constant surge force ``X`` (v = r = 0).

        Solves the force balance ``X = −X_u u − X_|u|u u|u| [− X_uuu u³]``.
        """
        X = float(X)
        if X == 0.0:
            return 0.0
        sgn = 1.0 if X > 0 else -1.0
        a, b = -self.X_uu, -self.X_u
        if not cubic_surge:
            return sgn * (-b + math.sqrt(b * b + 4.0 * a * abs(X))) / (2.0 * a)
        roots = np.roots([-self.X_uuu, a, b, -abs(X)])
        real = roots[np.abs(roots.imag) < 1e-12].real
        return sgn * float(real[real > 0][0])


#: The published CyberShip II coefficients.
CYBERSHIP2 = CyberShip2Coefficients()

# Basis of the force expansion f = τ − Cν − Dν over signals [u, v, r, X, Y, N].
_BASIS = ("u", "v", "r", "u*|u|", "v*r", "r*r", "u*r", "u*v",
          "v*|v|", "v*|r|", "r*|v|", "r*|r|", "X", "Y", "N")
_EQ_ORDER = {
    "u": ("u", "u*|u|", "v*r", "r*r", "X"),
    "v": ("v", "r", "u*r", "u*v", "v*|v|", "v*|r|", "r*|v|", "r*|r|", "Y", "N"),
    "r": ("v", "r", "u*r", "u*v", "v*|v|", "v*|r|", "r*|v|", "r*|r|", "Y", "N"),
}


def _force_matrix(c: CyberShip2Coefficients) -> np.ndarray:
    """``F`` with ``τ − C(ν)ν − D(ν)ν = F φ(ν, τ)`` over :data:`_BASIS` (no cubic term)."""
    col = {name: i for i, name in enumerate(_BASIS)}
    f = np.zeros((3, len(_BASIS)))
    a = c.m * c.x_g - 0.5 * (c.N_vdot + c.Y_rdot)
    # surge: X + X_u u + X_|u|u u|u| + (m − Y_v̇) v r + (m x_g − (N_v̇+Y_ṙ)/2) r²
    f[0, col["X"]] = 1.0
    f[0, col["u"]] = c.X_u
    f[0, col["u*|u|"]] = c.X_uu
    f[0, col["v*r"]] = c.m - c.Y_vdot
    f[0, col["r*r"]] = a
    # sway: Y − (m − X_u̇) u r + Y_v v + Y_|v|v v|v| + Y_|r|v v|r| + Y_r r
    #       + Y_|v|r r|v| + Y_|r|r r|r|
    f[1, col["Y"]] = 1.0
    f[1, col["u*r"]] = -(c.m - c.X_udot)
    f[1, col["v"]] = c.Y_v
    f[1, col["v*|v|"]] = c.Y_vv
    f[1, col["v*|r|"]] = c.Y_rv
    f[1, col["r"]] = c.Y_r
    f[1, col["r*|v|"]] = c.Y_vr
    f[1, col["r*|r|"]] = c.Y_rr
    # yaw: N − (m x_g − (N_v̇+Y_ṙ)/2) u r − (X_u̇ − Y_v̇) u v + N_v v + ... + N_|r|r r|r|
    f[2, col["N"]] = 1.0
    f[2, col["u*r"]] = -a
    f[2, col["u*v"]] = -(c.X_udot - c.Y_vdot)
    f[2, col["v"]] = c.N_v
    f[2, col["v*|v|"]] = c.N_vv
    f[2, col["v*|r|"]] = c.N_rv
    f[2, col["r"]] = c.N_r
    f[2, col["r*|v|"]] = c.N_vr
    f[2, col["r*|r|"]] = c.N_rr
    return f


def cybership2_spec(
    dt: float = DEFAULT_DT,
    coefficients: CyberShip2Coefficients = CYBERSHIP2,
    *,
    aggregate: Mapping[str, str] | None = None,
) -> ModelSpec:
    """Discrete-time second-order modulus model of CyberShip II (explicit Euler at ``dt``).

    States ``["u", "v", "r"]`` (velocity relative to water when used as regressors),
    inputs ``["X", "Y", "N"]`` (generalised forces). Writing the continuous model as
    ``M ν̇_r = τ − C(ν_r)ν_r − D(ν_r)ν_r = F φ(ν_r, τ)`` with the regressor basis
    ``φ = [u, v, r, u|u|, v r, r², u r, u v, v|v|, v|r|, r|v|, r|r|, X, Y, N]`` (Definition
    2.1), Euler gives ``ν_r(k+1) = (E + dt M⁻¹ F) φ(ν_r(k), τ(k))`` where ``E`` picks the
    own linear state. Hence the matrix of θ0 is::

        Θ = E + dt M⁻¹ F,

    e.g. θ_u[u] = 1 + dt X_u/(m − X_u̇), θ_u[u|u|] = dt X_|u|u/(m − X_u̇),
    θ_u[v r] = dt (m − Y_v̇)/(m − X_u̇), θ_u[r²] = dt (m x_g − (N_v̇+Y_ṙ)/2)/(m − X_u̇),
    θ_u[X] = dt/(m − X_u̇); the sway and yaw rows mix the sway and yaw forces through
    the 2×2 block of ``M⁻¹`` (``m x_g − Y_ṙ ≠ 0``), so both equations have the terms
    ``v, r, u r, u v, v|v|, v|r|, r|v|, r|r|, Y, N``. Terms whose coefficient is exactly
    zero are dropped. The cubic surge term ``X_uuu u³`` is not second-order modulus and is
    not part of this spec.

    Parameters
    ----------
    dt : float
        Sample time (s).
    coefficients : CyberShip2Coefficients
        Physical coefficients (default: the published values).
    aggregate : mapping, optional
        Aggregate relations to attach (e.g. ``{"u": "u - u_c", "v": "v - v_c"}`` for a
        current meter, paper eq. (9)).

    Returns
    -------
    ModelSpec
        Named ``"cybership2"`` with ``theta0`` and ``dt``.
    """
    dt = float(dt)
    if not (math.isfinite(dt) and dt > 0):
        raise VesselidError(f"dt must be a positive number, got {dt}")
    theta = dt * coefficients.mass_matrix_inverse() @ _force_matrix(coefficients)
    col = {name: i for i, name in enumerate(_BASIS)}
    for i, s in enumerate(("u", "v", "r")):
        theta[i, col[s]] += 1.0
    equations: dict[str, list[str]] = {}
    theta0: dict[str, list[float]] = {}
    for i, s in enumerate(("u", "v", "r")):
        nonzero = [t for t in _BASIS if theta[i, col[t]] != 0.0]
        extra = [t for t in nonzero if t not in _EQ_ORDER[s]]
        if extra:  # pragma: no cover - cannot happen with the block structure of M
            raise VesselidError(f"unexpected terms {extra} in equation {s}")
        terms = [t for t in _EQ_ORDER[s] if theta[i, col[t]] != 0.0]
        equations[s] = terms
        theta0[s] = [float(theta[i, col[t]]) for t in terms]
    return ModelSpec(
        name="cybership2", states=["u", "v", "r"], inputs=["X", "Y", "N"],
        equations=equations, theta0=theta0, aggregate=aggregate, dt=dt,
    )


# ------------------------------------------------------------------------------- wind
@dataclass(frozen=True)
class BlendermannWind:
    """Blendermann (1994) wind-load coefficients and projected areas.

    Coefficients from Blendermann, W. (1994), "Parameter identification of wind loads on
    ships", J. Wind Eng. Ind. Aerodyn. 51, 339–351, as tabulated in Fossen's MSS
    ``blendermann94.m`` (Fossen 2021, §10.1). Default row: *offshore supply vessel*
    (CD_t = 0.90, CD_l,AF(0) = 0.55, CD_l,AF(π) = 0.80, δ = 0.55). Areas are those of a
    1:70 model of a supply ship (full-scale A_F ≈ 220 m², A_L ≈ 740 m², L ≈ 88 m);
    ``s_L`` is the horizontal distance from midship to the centroid of A_L.
    """

    cd_t: float = 0.90
    cd_l_bow: float = 0.55
    cd_l_stern: float = 0.80
    delta: float = 0.55
    frontal_area: float = 0.045
    lateral_area: float = 0.15
    length: float = 1.255
    s_l: float = 0.05
    rho_air: float = 1.224


#: Default wind-load model (offshore supply vessel row, 1:70 model-scale areas).
BLENDERMANN94 = BlendermannWind()


def blendermann_wind_force(
    gamma_rw: np.ndarray | float, speed_rw: np.ndarray | float,
    wind: BlendermannWind = BLENDERMANN94,
) -> np.ndarray:
    """Wind force/moment ``[X, Y, N]`` from the relative wind angle and speed (numpy).

    ``γ_rw = −atan2(v_rw, u_rw)`` (0: wind from ahead) with ``[u_rw, v_rw] = ν − ν_w``;
    the yaw coefficient is extended to ``γ < 0`` by symmetry,
    ``C_N = (s_L/L − 0.18(|γ| − π/2)) C_Y``. Same formulas as the compiled kernel.
    """
    g = np.asarray(gamma_rw, dtype=float)
    v2 = np.asarray(speed_rw, dtype=float) ** 2
    ag = np.abs(g)
    cdl_af = np.where(ag <= 0.5 * np.pi, wind.cd_l_bow, wind.cd_l_stern)
    cdl = cdl_af * wind.frontal_area / wind.lateral_area
    den = 1.0 - 0.5 * wind.delta * (1.0 - cdl / wind.cd_t) * np.sin(2.0 * g) ** 2
    cx = -cdl_af * np.cos(g) / den
    cy = wind.cd_t * np.sin(g) / den
    cn = (wind.s_l / wind.length - 0.18 * (ag - 0.5 * np.pi)) * cy
    q = 0.5 * wind.rho_air * v2
    return np.stack([q * cx * wind.frontal_area, q * cy * wind.lateral_area,
                     q * cn * wind.lateral_area * wind.length], axis=-1)


# ------------------------------------------------------------------------ disturbances
@dataclass(frozen=True)
class CyberShip2Disturbances:
    """Current, wind and unmodelled-force settings (model scale, SI units).

    Directions are *going-to* angles in the earth frame, from north towards east (rad).
    Each variation is a first-order Gauss–Markov process (:class:`GaussMarkov`) with
    stationary std ``*_std``, time constant ``*_time_constant`` and, for the current,
    the bound ``current_bound`` (in units of its std), so that the current is bounded as
    the paper's A11 asks.

    Parameters
    ----------
    current_speed, current_direction : float
        Mean earth-frame current ``V_c`` (m/s) and direction ``β_c`` (rad).
    current_speed_std, current_direction_std : float
        Std of the GM variation of speed (m/s) and direction (rad).
    current_time_constant, current_bound : float
        Time constant (s) and bound (in stds) of both current variations.
    wind_speed, wind_direction : float
        Mean true wind speed (m/s, model scale: Froude-scaled ≈ full scale / 8.4) and
        going-to direction (rad).
    gust_std, gust_time_constant : float
        Coloured gusts: GM variation of the wind speed (bounded at 3 std, speed ≥ 0).
    wind_direction_std, wind_direction_time_constant : float
        GM variation of the wind direction (rad, s).
    force_noise_std : tuple of 3 floats
        Std of unmodelled GM forces ``[X, Y, N]`` (N, N, N m) added to ``w``.
    force_noise_time_constant : float
        Their time constant (s).
    cubic_surge : bool
        Add the published cubic surge damping ``X_uuu u_r³`` (not second-order modulus:
        the identification spec is then misspecified).
    wind_model : BlendermannWind
        Wind-load coefficients and areas.
    wind_loads : bool, optional
        Compute wind loads from the apparent wind. Default: only with wind or gusts, so
        that without wind the plant is exactly the identification model (the air drag of
        the vessel's own motion, ~1 % of the thrust, is then neglected).
    """

    current_speed: float = 0.0
    current_direction: float = 0.0
    current_speed_std: float = 0.0
    current_direction_std: float = 0.0
    current_time_constant: float = 120.0
    current_bound: float = 3.0
    wind_speed: float = 0.0
    wind_direction: float = 0.0
    gust_std: float = 0.0
    gust_time_constant: float = 5.0
    wind_direction_std: float = 0.0
    wind_direction_time_constant: float = 30.0
    force_noise_std: tuple[float, float, float] = (0.0, 0.0, 0.0)
    force_noise_time_constant: float = 2.0
    cubic_surge: bool = False
    wind_model: BlendermannWind = field(default_factory=BlendermannWind)
    wind_loads: bool | None = None

    @property
    def wind_on(self) -> bool:
        """Whether wind loads are computed (default: iff there is wind or gusts)."""
        if self.wind_loads is not None:
            return bool(self.wind_loads)
        return self.wind_speed > 0 or self.gust_std > 0

    def __post_init__(self) -> None:
        fn = tuple(float(x) for x in self.force_noise_std)
        if len(fn) != 3:
            raise VesselidError("force_noise_std needs three values (X, Y, N)")
        object.__setattr__(self, "force_noise_std", fn)
        for name in ("current_speed_std", "current_direction_std", "gust_std",
                     "wind_direction_std", "wind_speed"):
            if not getattr(self, name) >= 0:
                raise VesselidError(f"{name} must be non-negative")
        if any(x < 0 for x in fn):
            raise VesselidError("force_noise_std must be non-negative")

    def processes(self, dt: float) -> list[GaussMarkov]:
        """The seven zero-mean GM variations, in disturbance-channel order.

        ``[current speed, current direction, wind speed, wind direction, X, Y, N]``.
        """
        b = self.current_bound
        ct = self.current_time_constant
        fn = self.force_noise_std

        def gm(std: float, tc: float, bound: float) -> GaussMarkov:
            return GaussMarkov(0.0, std, tc, dt, bound * std if std > 0 else math.inf)

        return [
            gm(self.current_speed_std, ct, b),
            gm(self.current_direction_std, ct, b),
            gm(self.gust_std, self.gust_time_constant, 3.0),
            gm(self.wind_direction_std, self.wind_direction_time_constant, 3.0),
            gm(fn[0], self.force_noise_time_constant, 3.0),
            gm(fn[1], self.force_noise_time_constant, 3.0),
            gm(fn[2], self.force_noise_time_constant, 3.0),
        ]

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d["force_noise_std"] = list(self.force_noise_std)
        d["wind_loads"] = self.wind_on
        return d


#: Sensor groups and the channels (columns) each produces, in kernel order.
SENSOR_GROUPS: dict[str, tuple[str, ...]] = {
    "gnss": ("u", "v"),
    "speed_log": ("u_log", "v_log"),
    "current_meter": ("u_c", "v_c"),
    "anemometer": ("wind_speed", "wind_angle"),
    "gyro": ("r",),
    "heading": ("psi",),
}
#: All sensor channels in kernel order.
SENSOR_CHANNELS: tuple[str, ...] = tuple(c for g in SENSOR_GROUPS.values() for c in g)
_N_SENS = len(SENSOR_CHANNELS)


@dataclass(frozen=True)
class CyberShip2Sensors:
    """Sensor suite; each entry is the noise std, ``None`` switches the sensor off.

    * ``gnss`` (m/s): absolute body-frame velocity ``[u, v] + e`` (the paper's ``y₁``),
    * ``speed_log`` (m/s): Doppler log, velocity through water ``[u_r, v_r] + e`` — the
      aggregated state of Remark 4.3 (``r_r = r``: the current is irrotational),
    * ``current_meter`` (m/s): body-frame current ``[u_c, v_c] + e`` (the paper's ``y₂``),
    * ``anemometer`` (m/s, rad): apparent wind speed and angle ``γ_rw`` (0 = from ahead),
    * ``gyro`` (rad/s): yaw rate ``r + e``,
    * ``heading`` (rad): ``ψ + e`` wrapped to ``[−π, π)``.

    Noise is white Gaussian clipped at ``clip`` std, i.e. zero-mean and bounded (A2).
    """

    gnss: float | None = 0.005
    speed_log: float | None = 0.005
    current_meter: float | None = 0.005
    anemometer: tuple[float, float] | None = (0.05, 0.05)
    gyro: float | None = 0.002
    heading: float | None = 0.005
    clip: float = 3.0

    def __post_init__(self) -> None:
        if not self.clip > 0:
            raise VesselidError("sensor noise clip must be positive")
        for name in SENSOR_GROUPS:
            val = getattr(self, name)
            if val is None:
                continue
            vals = np.atleast_1d(np.asarray(val, dtype=float))
            if vals.size not in (1, len(SENSOR_GROUPS[name])) or np.any(~(vals >= 0)):
                raise VesselidError(f"sensor {name!r}: noise std must be >= 0, got {val!r}")

    @classmethod
    def noiseless(cls) -> CyberShip2Sensors:
        """All sensors on, without noise."""
        return cls(0.0, 0.0, 0.0, (0.0, 0.0), 0.0, 0.0)

    @property
    def enabled(self) -> tuple[str, ...]:
        """Enabled sensor groups in kernel order."""
        return tuple(g for g in SENSOR_GROUPS if getattr(self, g) is not None)

    @property
    def channels(self) -> tuple[str, ...]:
        """Channels of the enabled sensors in kernel order."""
        return tuple(c for g in self.enabled for c in SENSOR_GROUPS[g])

    def channel_index(self) -> np.ndarray:
        """Kernel indices of :attr:`channels`."""
        return np.array([SENSOR_CHANNELS.index(c) for c in self.channels], dtype=np.int64)

    def std_vector(self) -> np.ndarray:
        """Noise std per kernel channel (0 for disabled sensors)."""
        out = np.zeros(_N_SENS)
        i = 0
        for g, chans in SENSOR_GROUPS.items():
            val = getattr(self, g)
            if val is not None:
                out[i:i + len(chans)] = np.broadcast_to(np.asarray(val, dtype=float), len(chans))
            i += len(chans)
        return out

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        if self.anemometer is not None:
            d["anemometer"] = list(self.anemometer)
        return d


def _coerce(cls, value, name: str):
    if value is None:
        return cls()
    if isinstance(value, cls):
        return value
    if isinstance(value, Mapping):
        try:
            return cls(**value)
        except TypeError as exc:
            raise VesselidError(f"invalid {name} settings: {exc}") from exc
    raise VesselidError(f"{name} must be a {cls.__name__} or a mapping, got {type(value)}")


# ------------------------------------------------------------------- compiled kernels
# Layout of the parameter vector ``par``.
P_DT = 0
P_MINV = 1  # 9 entries: dt M⁻¹ row-major
P_RHO = 10
P_AF = 11
P_AL = 12
P_LOA = 13
P_SL = 14
P_CDT = 15
P_CDL_BOW = 16
P_CDL_STERN = 17
P_DELTA = 18
P_XUUU = 19
P_LIMIT = 20
P_CLIP = 21  # 1.0: inputs are normalised actions, clipped to [-1, 1]
P_TAU = 22  # 3 entries: input scale (force per unit action)
P_UREF = 25
P_PSIREF = 26
P_WU = 27
P_WPSI = 28
P_WA = 29
P_WIND = 30  # 1.0: compute wind loads
N_PAR = 31

# Disturbance rows ``dist[b, k]``: zero-mean variations and noise at time k.
D_VC = 0  # current speed variation
D_BC = 1  # current direction variation
D_VW = 2  # wind speed gust
D_BW = 3  # wind direction variation
D_F = 4  # 3 unmodelled forces
D_E = 7  # sensor noise, _N_SENS channels
N_DIST = D_E + _N_SENS
N_GM = 7  # GM channels (the first seven)

# Vessel state rows ``st[b]`` (env) or ``st[r, k]`` (rollout). The first S_INFO columns
# are the environments' info layout.
S_NU = 0  # ν (3)
S_NUR = 3  # ν_r = ν − ν_c (3)
S_ETA = 6  # η = [north, east, ψ] (3)
S_CUR = 9  # body-frame current [u_c, v_c, 0] (3)
S_WIND = 12  # apparent wind [V_rw, γ_rw] (2)
S_WF = 14  # wind force [X, Y, N] (3)
S_TAU = 17  # applied τ (3)
S_SENS = 20  # sensor readings (_N_SENS)
S_INFO = S_SENS + _N_SENS
S_W = S_INFO  # the paper's w(k) (3)
S_REW = S_W + 3  # reward of the step into this row
S_STAT = S_REW + 1  # divergence status
S_ENV = S_STAT + 1  # means [V_c, β_c, V_w, β_w] (4)
S_ACT = S_ENV + 4  # input: action or τ (3)
N_ST = S_ACT + 3

STATUS_OK, STATUS_NONFINITE, STATUS_LIMIT = 0, 1, 2


@njit(cache=True, inline="always")
def _wrap(a):
    return a - 2.0 * math.pi * math.floor((a + math.pi) / (2.0 * math.pi))


@njit(cache=True, inline="always")
def _observe(st, i, dist, b, j, par):
    """Current, wind and sensor readings of state row ``st[i]`` with noise ``dist[b, j]``."""
    u = st[i, S_NU]
    v = st[i, S_NU + 1]
    r = st[i, S_NU + 2]
    psi = st[i, S_ETA + 2]
    vc = st[i, S_ENV] + dist[b, j, D_VC]
    dc = st[i, S_ENV + 1] + dist[b, j, D_BC] - psi
    uc = vc * math.cos(dc)
    vcb = vc * math.sin(dc)
    vw = st[i, S_ENV + 2] + dist[b, j, D_VW]
    if vw < 0.0:
        vw = 0.0
    dw = st[i, S_ENV + 3] + dist[b, j, D_BW] - psi
    urw = u - vw * math.cos(dw)
    vrw = v - vw * math.sin(dw)
    v2 = urw * urw + vrw * vrw
    gam = -math.atan2(vrw, urw)
    xw = 0.0
    yw = 0.0
    nw = 0.0
    if v2 > 0.0 and par[P_WIND] > 0.0:
        ag = abs(gam)
        cdl_af = par[P_CDL_BOW] if ag <= 0.5 * math.pi else par[P_CDL_STERN]
        cdl = cdl_af * par[P_AF] / par[P_AL]
        s2 = math.sin(2.0 * gam)
        den = 1.0 - 0.5 * par[P_DELTA] * (1.0 - cdl / par[P_CDT]) * s2 * s2
        cy = par[P_CDT] * math.sin(gam) / den
        q = 0.5 * par[P_RHO] * v2
        xw = q * (-cdl_af * math.cos(gam) / den) * par[P_AF]
        yw = q * cy * par[P_AL]
        nw = q * (par[P_SL] / par[P_LOA] - 0.18 * (ag - 0.5 * math.pi)) * cy \
            * par[P_AL] * par[P_LOA]
    vr = math.sqrt(v2)
    st[i, S_CUR] = uc
    st[i, S_CUR + 1] = vcb
    st[i, S_CUR + 2] = 0.0
    st[i, S_NUR] = u - uc
    st[i, S_NUR + 1] = v - vcb
    st[i, S_NUR + 2] = r
    st[i, S_WIND] = vr
    st[i, S_WIND + 1] = gam
    st[i, S_WF] = xw
    st[i, S_WF + 1] = yw
    st[i, S_WF + 2] = nw
    e = D_E
    o = S_SENS
    st[i, o] = u + dist[b, j, e]
    st[i, o + 1] = v + dist[b, j, e + 1]
    st[i, o + 2] = (u - uc) + dist[b, j, e + 2]
    st[i, o + 3] = (v - vcb) + dist[b, j, e + 3]
    st[i, o + 4] = uc + dist[b, j, e + 4]
    st[i, o + 5] = vcb + dist[b, j, e + 5]
    st[i, o + 6] = vr + dist[b, j, e + 6]
    st[i, o + 7] = _wrap(gam + dist[b, j, e + 7])
    st[i, o + 8] = r + dist[b, j, e + 8]
    st[i, o + 9] = _wrap(psi + dist[b, j, e + 9])


@njit(cache=True, inline="always")
def _advance(st, i, i1, dist, b, j, codes, eq, theta, par, s):
    """One Euler step ``st[i] → st[i1]`` (``i1`` may equal ``i``) with disturbance rows
    ``dist[b, j]`` (time k) and ``dist[b, j + 1]`` (time k+1).

    ``ν(k+1) = Φᵀ([ν(k) − ν_c(k); τ(k)]) θ0 + w(k)`` with
    ``w(k) = ν_c(k+1) + dt M⁻¹ (τ_wind + τ_noise [+ X_uuu u_r³])``: the hydrodynamics are
    evaluated only through the factor layout ``codes, eq`` and θ (one physics). Needs
    ``_observe`` of row ``i`` first (current and wind at time k). ``s`` is a work buffer
    of length ``19 + P``: signals ``[x + v; τ]``, factor vector, regressors.
    """
    dt = par[P_DT]
    u = st[i, S_NU]
    v = st[i, S_NU + 1]
    r = st[i, S_NU + 2]
    n0 = st[i, S_ETA]
    e0 = st[i, S_ETA + 1]
    psi = st[i, S_ETA + 2]
    # regressor signals [x + v; τ] with v = −ν_c
    s[0] = u - st[i, S_CUR]
    s[1] = v - st[i, S_CUR + 1]
    s[2] = r
    asq = 0.0
    for q in range(3):
        a = st[i, S_ACT + q]
        if par[P_CLIP] > 0.0:
            if a > 1.0:
                a = 1.0
            elif a < -1.0:
                a = -1.0
            asq += a * a
        s[3 + q] = a * par[P_TAU + q]
    # additive forces: wind + unmodelled noise (+ cubic surge damping)
    fx = st[i, S_WF] + dist[b, j, D_F]
    fy = st[i, S_WF + 1] + dist[b, j, D_F + 1]
    fn = st[i, S_WF + 2] + dist[b, j, D_F + 2]
    if par[P_XUUU] != 0.0:
        fx += par[P_XUUU] * s[0] * s[0] * s[0]
    # body-frame current at k+1 (heading after the step)
    psi1 = psi + dt * r
    vc1 = st[i, S_ENV] + dist[b, j + 1, D_VC]
    dc1 = st[i, S_ENV + 1] + dist[b, j + 1, D_BC] - psi1
    m = P_MINV
    w0 = vc1 * math.cos(dc1) + (par[m] * fx + par[m + 1] * fy + par[m + 2] * fn)
    w1 = vc1 * math.sin(dc1) + (par[m + 3] * fx + par[m + 4] * fy + par[m + 5] * fn)
    w2 = 0.0 + (par[m + 6] * fx + par[m + 7] * fy + par[m + 8] * fn)
    st[i, S_W] = w0
    st[i, S_W + 1] = w1
    st[i, S_W + 2] = w2
    for q in range(3):
        st[i, S_TAU + q] = s[3 + q]
    st[i1, S_NU] = w0
    st[i1, S_NU + 1] = w1
    st[i1, S_NU + 2] = w2
    advance(codes, eq, theta, s[:6], s[6:19], s[19:], st[i1, S_NU:S_NU + 3])
    c = math.cos(psi)
    sn = math.sin(psi)
    st[i1, S_ETA] = n0 + dt * (c * u - sn * v)
    st[i1, S_ETA + 1] = e0 + dt * (sn * u + c * v)
    st[i1, S_ETA + 2] = psi1
    status = STATUS_OK
    for q in range(3):
        x = st[i1, S_NU + q]
        if not math.isfinite(x):
            status = STATUS_NONFINITE
        elif abs(x) > par[P_LIMIT]:
            status = STATUS_LIMIT
    st[i1, S_STAT] = status
    du = st[i1, S_NU] - par[P_UREF]
    dpsi = _wrap(psi1 - par[P_PSIREF])
    st[i1, S_REW] = -(par[P_WU] * du * du + par[P_WPSI] * dpsi * dpsi + par[P_WA] * asq)
    return status


@kernel(parallel=True)
def _rollout_kernel(st, dist, codes, eq, theta, par, fail_at):
    """Roll out ``R`` vessels for ``N`` samples (parallel over vessels).

    ``st`` ``(R, N, N_ST)`` holds the initial ν, η in row 0, and the means and inputs in
    every row; everything else is written.
    """
    n_runs, n_samples = st.shape[0], st.shape[1]
    for b in prange(n_runs):
        s = np.empty(19 + theta.shape[0])
        x = st[b]
        fail_at[b] = -1
        _observe(x, 0, dist, b, 0, par)
        for k in range(n_samples - 1):
            status = _advance(x, k, k + 1, dist, b, k, codes, eq, theta, par, s)
            if status != STATUS_OK:
                fail_at[b] = k + 1
                for kk in range(k + 1, n_samples):
                    for q in range(S_INFO):
                        x[kk, q] = np.nan
                break
            _observe(x, k + 1, dist, b, k + 1, par)
        for q in range(3):
            x[n_samples - 1, S_W + q] = 0.0


@kernel()
def _env_chunk(st, dist, j, codes, eq, theta, par, obs_idx, obs, skip, lo, hi, s):
    for b in range(lo, hi):
        if skip[b]:
            st[b, S_REW] = 0.0
            st[b, S_STAT] = 0.0
            for q in range(3):
                st[b, S_W + q] = 0.0
                st[b, S_TAU + q] = 0.0
        else:
            _advance(st, b, b, dist, b, j, codes, eq, theta, par, s)
        _observe(st, b, dist, b, j + 1, par)
        for q in range(obs_idx.shape[0]):
            obs[b, q] = st[b, S_SENS + obs_idx[q]]


@kernel()
def _env_step_serial(st, dist, j, codes, eq, theta, par, obs_idx, obs, skip):
    """Advance a batch of vessels one step in place (serial; for single envs).

    Vessels with ``skip`` set are only observed (next-step autoreset).
    """
    s = np.empty(19 + theta.shape[0])
    _env_chunk(st, dist, j, codes, eq, theta, par, obs_idx, obs, skip, 0, st.shape[0], s)


@kernel(parallel=True)
def _env_step_parallel(st, dist, j, codes, eq, theta, par, obs_idx, obs, skip, n_chunks):
    """Advance a batch of vessels one step in place, in ``n_chunks`` parallel chunks."""
    n_b = st.shape[0]
    for c in prange(n_chunks):
        s = np.empty(19 + theta.shape[0])
        _env_chunk(st, dist, j, codes, eq, theta, par, obs_idx, obs, skip,
                   c * n_b // n_chunks, (c + 1) * n_b // n_chunks, s)


@njit(cache=True)
def _env_observe(st, dist, j, par, obs_idx, obs, mask):
    """Sensor readings at buffer row ``j`` for the vessels in ``mask`` (after a reset)."""
    for b in range(st.shape[0]):
        if mask[b]:
            _observe(st, b, dist, b, j, par)
            for q in range(obs_idx.shape[0]):
                obs[b, q] = st[b, S_SENS + obs_idx[q]]


# ------------------------------------------------------------------------ vessel model
@dataclass
class VesselModel:
    """Compiled-kernel parameters for one vessel configuration (shared by all users).

    Builds the identification spec (:func:`cybership2_spec`), θ0, the term codes and
    the packed parameter vector of the kernels, and draws the disturbance rows.
    """

    dt: float = DEFAULT_DT
    coefficients: CyberShip2Coefficients = CYBERSHIP2
    disturbances: CyberShip2Disturbances = field(default_factory=CyberShip2Disturbances)
    sensors: CyberShip2Sensors = field(default_factory=CyberShip2Sensors)
    tau_scale: tuple[float, float, float] = (1.0, 1.0, 1.0)
    normalized_inputs: bool = False
    u_ref: float = 0.3
    psi_ref: float = 0.0
    reward_weights: tuple[float, float, float] = (10.0, 1.0, 0.01)
    limit: float = DEFAULT_DIVERGENCE_LIMIT

    def __post_init__(self) -> None:
        self.dt = float(self.dt)
        if not (math.isfinite(self.dt) and self.dt > 0):
            raise VesselidError(f"dt must be a positive number, got {self.dt}")
        self.disturbances = _coerce(CyberShip2Disturbances, self.disturbances, "disturbances")
        self.sensors = _coerce(CyberShip2Sensors, self.sensors, "sensors")
        self.spec = cybership2_spec(self.dt, self.coefficients)
        self.codes = np.ascontiguousarray(self.spec.codes.factors)
        self.eq = np.ascontiguousarray(self.spec.codes.equation)
        self.theta = np.ascontiguousarray(self.spec.theta0_vector())
        c, wm = self.coefficients, self.disturbances.wind_model
        par = np.zeros(N_PAR)
        par[P_DT] = self.dt
        par[P_MINV:P_MINV + 9] = (self.dt * c.mass_matrix_inverse()).ravel()
        par[P_RHO] = wm.rho_air
        par[P_AF] = wm.frontal_area
        par[P_AL] = wm.lateral_area
        par[P_LOA] = wm.length
        par[P_SL] = wm.s_l
        par[P_CDT] = wm.cd_t
        par[P_CDL_BOW] = wm.cd_l_bow
        par[P_CDL_STERN] = wm.cd_l_stern
        par[P_DELTA] = wm.delta
        par[P_XUUU] = c.X_uuu if self.disturbances.cubic_surge else 0.0
        par[P_LIMIT] = float(self.limit)
        par[P_CLIP] = 1.0 if self.normalized_inputs else 0.0
        par[P_TAU:P_TAU + 3] = np.asarray(self.tau_scale, dtype=float)
        par[P_UREF] = self.u_ref
        par[P_PSIREF] = self.psi_ref
        par[P_WU:P_WU + 3] = np.asarray(self.reward_weights, dtype=float)
        par[P_WIND] = 1.0 if self.disturbances.wind_on else 0.0
        self.par = par
        self.processes = self.disturbances.processes(self.dt)
        self._gm = [(i, gm.pole, gm.std_, gm.bound_) for i, gm in enumerate(self.processes)
                    if not gm.is_zero]
        self.sensor_std = self.sensors.std_vector()
        self._noisy = np.flatnonzero(self.sensor_std > 0)
        self.obs_idx = self.sensors.channel_index()

    def env_means(self, n: int) -> np.ndarray:
        """``(n, 4)`` per-vessel means ``[V_c, β_c, V_w, β_w]``."""
        d = self.disturbances
        return np.tile([d.current_speed, d.current_direction, d.wind_speed,
                        d.wind_direction], (n, 1)).astype(float)

    # -- disturbance draws ---------------------------------------------------
    def draw_run(self, rng: np.random.Generator, n: int) -> np.ndarray:
        """All disturbance rows of one run, ``(n, N_DIST)``, in a fixed draw order.

        GM variations with :meth:`GaussMarkov.sample`, then the sensor noise (Gaussian
        clipped at ``clip`` std).
        """
        out = np.zeros((n, N_DIST))
        for i, gm in enumerate(self.processes):
            if not gm.is_zero:
                out[:, i] = gm.sample(rng, n)
        z = rng.standard_normal((n, _N_SENS))
        clip = self.sensors.clip
        np.clip(z, -clip, clip, out=z)
        out[:, D_E:] = z * self.sensor_std
        return out

    def start_block(self, rng: np.random.Generator, buf: np.ndarray,
                    latent: np.ndarray) -> None:
        """Fill a ``(B, K+1, N_DIST)`` block buffer from a stationary start.

        ``latent`` ``(B, N_GM)`` keeps the unsaturated GM states between blocks.
        """
        n_b = buf.shape[0]
        buf[:, 0, :] = 0.0
        latent[:] = 0.0
        for i, _a, std, bound in self._gm:
            g = std * rng.standard_normal(n_b)
            latent[:, i] = g
            buf[:, 0, i] = bound * np.tanh(g / bound) if math.isfinite(bound) else g
        self._sensor_noise(rng, buf[:, 0:1, :])
        buf[:, 1:, :] = 0.0
        self.continue_block(rng, buf, latent, first=True)

    def continue_block(self, rng: np.random.Generator, buf: np.ndarray, latent: np.ndarray,
                       *, first: bool = False) -> None:
        """Draw rows ``1..K`` continuing every GM process from row 0 (row K → row 0 first).

        Same recursion and saturation as :meth:`GaussMarkov.sample`
        (``g(k) = a g(k−1) + ε(k)``, bounded processes ``b·tanh(g/b)``), so the block-wise
        draws of the environments form one stationary process. One normal draw per block
        covers the GM innovations and the sensor noise.
        """
        if not first:
            buf[:, 0, :] = buf[:, -1, :]
        n_b, k1 = buf.shape[0], buf.shape[1] - 1
        n_gm, idx = len(self._gm), self._noisy
        if n_gm + idx.size == 0:
            return
        z = rng.standard_normal((n_gm + idx.size, n_b, k1))
        for c, (i, a, std, bound) in enumerate(self._gm):
            innov = z[c]
            innov *= std * math.sqrt(1.0 - a * a)
            g = sps.lfilter([1.0], [1.0, -a], innov, axis=1, zi=a * latent[:, i:i + 1])[0]
            latent[:, i] = g[:, -1]
            if math.isfinite(bound):
                g *= 1.0 / bound
                np.tanh(g, out=g)
                g *= bound
            buf[:, 1:, i] = g
        if idx.size:
            e = z[n_gm:]
            clip = self.sensors.clip
            np.clip(e, -clip, clip, out=e)
            e *= self.sensor_std[idx][:, None, None]
            for c, i in enumerate(idx):
                buf[:, 1:, D_E + i] = e[c]

    def _sensor_noise(self, rng: np.random.Generator, view: np.ndarray) -> None:
        idx = self._noisy
        view[..., D_E:] = 0.0
        if idx.size == 0:
            return
        z = rng.standard_normal((*view.shape[:-1], idx.size))
        clip = self.sensors.clip
        np.clip(z, -clip, clip, out=z)
        z *= self.sensor_std[idx]
        view[..., D_E + idx] = z


# --------------------------------------------------------------------- batch simulator
@dataclass
class CyberShip2Simulation:
    """Result of :func:`simulate_cybership2`; arrays have shape ``(runs, samples, ·)``.

    Properties: ``nu`` true absolute velocity ``[u, v, r]`` (the paper's ``x``), ``nu_r``
    velocity relative to water (the aggregated state ``x + v``), ``nu_c`` body-frame
    current ``[u_c, v_c, 0]``, ``v = −nu_c`` and ``w`` the paper's disturbances of (1a)
    (``w[:, -1]`` is zero, unused), ``eta = [north, east, ψ]`` (ψ not wrapped), ``tau``
    applied forces, ``wind`` apparent wind ``[V_rw, γ_rw]``, ``tau_wind`` its force,
    ``sensors`` readings of all channels (:data:`SENSOR_CHANNELS`).
    """

    model: VesselModel
    state: np.ndarray
    seed: int | None = None
    spawn_keys: list | None = None

    def _cols(self, start: int, n: int) -> np.ndarray:
        return self.state[..., start:start + n]

    nu = property(lambda self: self._cols(S_NU, 3), doc="True absolute velocity ν.")
    nu_r = property(lambda self: self._cols(S_NUR, 3), doc="ν_r = ν − ν_c.")
    nu_c = property(lambda self: self._cols(S_CUR, 3), doc="Body-frame current [u_c, v_c, 0].")
    eta = property(lambda self: self._cols(S_ETA, 3), doc="η = [north, east, ψ].")
    tau = property(lambda self: self._cols(S_ACT, 3), doc="Applied forces [X, Y, N].")
    wind = property(lambda self: self._cols(S_WIND, 2), doc="Apparent wind [V_rw, γ_rw].")
    tau_wind = property(lambda self: self._cols(S_WF, 3), doc="Wind force [X, Y, N].")
    sensors = property(lambda self: self._cols(S_SENS, _N_SENS), doc="Sensor readings.")
    w = property(lambda self: self._cols(S_W, 3), doc="The paper's additive w(k).")
    env_means = property(lambda self: self.state[:, 0, S_ENV:S_ENV + 4],
                         doc="Per-run means [V_c, β_c, V_w, β_w].")

    @property
    def v(self) -> np.ndarray:
        """The paper's non-additive disturbance ``v(k) = −ν_c(k)``."""
        return -self.nu_c

    @property
    def spec(self) -> ModelSpec:
        return self.model.spec

    @property
    def n_runs(self) -> int:
        return int(self.state.shape[0])

    @property
    def n_samples(self) -> int:
        return int(self.state.shape[1])

    def to_frame(self) -> Any:
        """Tidy trial-log frame (DESIGN.md): one row per sample, runs are experiments.

        Columns: ``experiment, time``, measured ``u, v`` (GNSS) and ``r`` (gyro), inputs
        ``X, Y, N``, ``psi`` (heading sensor), speed log ``u_log, v_log, r_log`` (``r_log``
        repeats the gyro: ``r_r = r``), current meter ``u_c, v_c``, anemometer
        ``wind_speed, wind_angle`` — each only if its sensor is enabled — and ground truth
        ``true_u, true_v, true_r, true_u_r, true_v_r, true_u_c, true_v_c, true_north,
        true_east, true_psi``.
        """
        import pandas as pd

        m = self.model
        n_r, n_k = self.n_runs, self.n_samples
        cols: dict[str, np.ndarray] = {
            "experiment": np.repeat(np.arange(n_r, dtype=np.int64), n_k),
            "time": np.tile(np.arange(n_k) * m.dt, n_r),
        }
        sens = {c: self.sensors[:, :, i].ravel() for i, c in enumerate(SENSOR_CHANNELS)}
        en = set(m.sensors.channels)
        for c in ("u", "v", "r"):
            if c in en:
                cols[c] = sens[c]
        for j, c in enumerate(("X", "Y", "N")):
            cols[c] = self.tau[:, :, j].ravel()
        if "psi" in en:
            cols["psi"] = sens["psi"]
        if "u_log" in en:
            cols["u_log"] = sens["u_log"]
            cols["v_log"] = sens["v_log"]
            if "r" in en:
                cols["r_log"] = sens["r"]
        for c in ("u_c", "v_c", "wind_speed", "wind_angle"):
            if c in en:
                cols[c] = sens[c]
        nu_r, nu_c = self.nu_r, self.nu_c
        for j, c in enumerate(("u", "v", "r")):
            cols[f"true_{c}"] = self.nu[:, :, j].ravel()
        cols["true_u_r"] = nu_r[:, :, 0].ravel()
        cols["true_v_r"] = nu_r[:, :, 1].ravel()
        cols["true_u_c"] = nu_c[:, :, 0].ravel()
        cols["true_v_c"] = nu_c[:, :, 1].ravel()
        for j, c in enumerate(("north", "east", "psi")):
            cols[f"true_{c}"] = self.eta[:, :, j].ravel()
        return pd.DataFrame(cols)

    def to_log(self, *, aggregate: str | None = None):
        """A :class:`~vesselid.logs.TrialLog` with metadata (spec, θ0, seeds, settings).

        Parameters
        ----------
        aggregate : {None, "current_meter"}
            ``"current_meter"`` attaches the aggregate relations ``u - u_c``, ``v - v_c``
            (paper eq. (9)) to the spec in the metadata. The speed-log columns
            ``u_log, v_log, r_log`` measure the aggregated state directly (Remark 4.3).
        """
        from vesselid import __version__
        from vesselid.logs import TrialLog

        spec = self.spec
        if aggregate == "current_meter":
            spec = spec.with_aggregate({"u": "u - u_c", "v": "v - v_c"})
        elif aggregate is not None:
            raise VesselidError(f"unknown aggregate option {aggregate!r}")
        m = self.model
        meta = {
            "spec": spec.to_dict(),
            "system": {
                "name": "cybership2",
                "dt": m.dt,
                "coefficients": asdict(m.coefficients),
                "disturbances": m.disturbances.to_dict(),
                "sensors": m.sensors.to_dict(),
                "env_means": np.asarray(self.env_means).tolist(),
            },
            "seed": self.seed,
            "spawn_keys": self.spawn_keys,
            "vesselid_version": __version__,
            "samples_per_experiment": self.n_samples,
            "experiments": self.n_runs,
        }
        return TrialLog(self.to_frame(), meta)


def simulate_cybership2(
    inputs: np.ndarray,
    *,
    n_runs: int | None = None,
    seed: int | np.random.SeedSequence | None = None,
    run_seeds: Sequence[np.random.SeedSequence] | None = None,
    dt: float = DEFAULT_DT,
    disturbances: CyberShip2Disturbances | Mapping[str, Any] | None = None,
    sensors: CyberShip2Sensors | Mapping[str, Any] | None = None,
    coefficients: CyberShip2Coefficients = CYBERSHIP2,
    nu0: np.ndarray | None = None,
    eta0: np.ndarray | None = None,
    current_direction: np.ndarray | float | None = None,
    wind_direction: np.ndarray | float | None = None,
    limit: float = DEFAULT_DIVERGENCE_LIMIT,
) -> CyberShip2Simulation:
    """Simulate CyberShip II trials with current, wind, force noise and sensors.

    Runs the compiled batch kernel (parallel over runs). Run ``r`` draws all its
    disturbances from ``default_rng(SeedSequence(seed).spawn(R)[r])`` in a fixed order
    (:meth:`VesselModel.draw_run`), so results are deterministic and any run can be
    regenerated alone.

    Parameters
    ----------
    inputs : ndarray, shape (R, N, 3) or (N, 3)
        Generalised forces ``τ = [X, Y, N]`` (N, N, N m) per run and sample.
    n_runs : int, optional
        Number of runs when ``inputs`` is ``(N, 3)`` (the same input for all runs).
    seed, run_seeds
        Root seed, or explicit per-run seed sequences.
    dt : float
        Sample time (s).
    disturbances, sensors : settings or mapping, optional
        Defaults: no current, wind or force noise; default sensors.
    coefficients : CyberShip2Coefficients
        Vessel coefficients.
    nu0 : ndarray, shape (3,) or (R, 3), optional
        Initial absolute velocity; default: at rest in the water (``ν(0) = ν_c(0)``).
    eta0 : ndarray, shape (3,) or (R, 3), optional
        Initial ``[north, east, ψ]``; default zeros.
    current_direction, wind_direction : float or ndarray (R,), optional
        Per-run mean directions overriding the settings.
    limit : float
        Divergence limit on ``|ν|``.

    Returns
    -------
    CyberShip2Simulation

    Raises
    ------
    SimulationDivergedError
        If a run becomes non-finite or exceeds ``limit``.
    """
    tau = np.asarray(inputs, dtype=np.float64)
    if tau.ndim == 2:
        tau = tau[None]
    if tau.ndim != 3 or tau.shape[2] != 3:
        raise VesselidError(f"inputs must have shape (R, N, 3) or (N, 3), got {np.shape(inputs)}")
    if run_seeds is not None:
        n_r = len(run_seeds)
    elif n_runs is not None:
        n_r = int(n_runs)
    else:
        n_r = tau.shape[0]
    if n_r < 1:
        raise VesselidError(f"need at least one run, got {n_r}")
    if tau.shape[0] not in (1, n_r):
        raise VesselidError(f"inputs hold {tau.shape[0]} runs but {n_r} runs were asked for")
    n_k = tau.shape[1]
    if n_k < 2:
        raise VesselidError(f"need at least 2 samples, got {n_k}")
    if not np.all(np.isfinite(tau)):
        raise VesselidError("inputs hold non-finite values")
    tau = np.ascontiguousarray(np.broadcast_to(tau, (n_r, n_k, 3)))
    model = VesselModel(dt=dt, coefficients=coefficients, disturbances=disturbances,
                        sensors=sensors, limit=limit)
    if run_seeds is None:
        root = seed if isinstance(seed, np.random.SeedSequence) else np.random.SeedSequence(seed)
        run_seeds = root.spawn(n_r)
    dist = np.empty((n_r, n_k, N_DIST))
    for r, ss in enumerate(run_seeds):
        dist[r] = model.draw_run(np.random.default_rng(ss), n_k)
    envp = model.env_means(n_r)
    if current_direction is not None:
        envp[:, 1] = np.broadcast_to(np.asarray(current_direction, dtype=float), n_r)
    if wind_direction is not None:
        envp[:, 3] = np.broadcast_to(np.asarray(wind_direction, dtype=float), n_r)
    eta0_arr = np.zeros((n_r, 3)) if eta0 is None else np.asarray(eta0, dtype=float)
    eta0_arr = np.broadcast_to(np.atleast_2d(eta0_arr), (n_r, 3))
    if nu0 is None:
        vc = envp[:, 0] + dist[:, 0, D_VC]
        dc = envp[:, 1] + dist[:, 0, D_BC] - eta0_arr[:, 2]
        nu0_arr = np.column_stack([vc * np.cos(dc), vc * np.sin(dc), np.zeros(n_r)])
    else:
        nu0_arr = np.asarray(nu0, dtype=float)
    nu0_arr = np.broadcast_to(np.atleast_2d(nu0_arr), (n_r, 3))
    if not (np.all(np.isfinite(nu0_arr)) and np.all(np.isfinite(eta0_arr))):
        raise VesselidError("nu0 and eta0 must be finite")
    st = np.zeros((n_r, n_k, N_ST))
    st[:, 0, S_NU:S_NU + 3] = nu0_arr
    st[:, 0, S_ETA:S_ETA + 3] = eta0_arr
    st[:, :, S_ENV:S_ENV + 4] = envp[:, None, :]
    st[:, :, S_ACT:S_ACT + 3] = tau
    fail_at = np.empty(n_r, dtype=np.int64)
    _rollout_kernel(st, dist, model.codes, model.eq, model.theta, model.par, fail_at)
    if np.any(fail_at >= 0):
        bad = np.flatnonzero(fail_at >= 0)
        r = int(bad[0])
        raise SimulationDivergedError(
            f"CyberShip II simulation diverged in {bad.size} of {n_r} run(s): run {r} became "
            f"non-finite or exceeded |ν| > {limit:g} at sample {int(fail_at[r])}; reduce the "
            f"input forces or dt"
        )
    seed_int = None if seed is None or isinstance(seed, np.random.SeedSequence) else int(seed)
    return CyberShip2Simulation(model=model, state=st, seed=seed_int,
                                spawn_keys=[list(ss.spawn_key) for ss in run_seeds])


# ------------------------------------------------------------------- catalogue system
def cybership2_system(
    *,
    dt: float = DEFAULT_DT,
    process_noise_std: Sequence[float] = (2e-4, 2e-4, 2e-4),
    process_noise_time_constant: float = 2.0,
    sensor_noise_std: Sequence[float] = (0.005, 0.005, 0.002),
    x0: Sequence[float] = (0.6, 0.0, 0.0),
    coefficients: CyberShip2Coefficients = CYBERSHIP2,
):
    """CyberShip II as a :class:`vesselid.systems.System` (heading-independent case).

    A :class:`System` cannot express a heading-dependent body-frame current or wind, so
    this catalogue entry has **zero current** (``v = 0``), additive Gauss–Markov process
    noise ``w`` (unmodelled forces, bounded at 3 std) and Gaussian state-measurement noise;
    it lets ``vesselid simulate --system cybership2`` work. The inputs are random-width
    pulses with static offsets (paper §6 / A10) that keep ``u > 0`` and, within one
    experiment, ``v`` and ``r`` of one sign: even-numbered experiments turn to
    starboard (``v < 0``, ``r > 0``), odd-numbered ones to port. Both directions are
    needed for the sign-dependent terms. In every steady turn of this vessel ``v`` and
    ``r`` have opposite signs (whatever the sway force), so ``v·|r| = −r·|v|`` on all
    such data: the logs carry the identifiable structure with ``v·|r|`` folded into
    ``r·|v|`` (:meth:`ModelSpec.merge_terms`, θ0 of ``r·|v|`` becomes
    ``θ_r|v| − θ_v|r|``); the simulation uses the full physics. For current, wind and
    the sensor suite use :func:`simulate_cybership2` or :mod:`vesselid.seatrial`.
    """
    from vesselid.disturbances import Gaussian
    from vesselid.signals import RandomPulses
    from vesselid.systems import System

    spec = cybership2_spec(dt, coefficients)
    states = ("u", "v", "r")
    w = {s: GaussMarkov(0.0, float(sd), process_noise_time_constant, dt, 3.0 * float(sd))
         for s, sd in zip(states, process_noise_std, strict=True) if sd > 0}
    e = {s: Gaussian(0.0, float(sd)) for s, sd in zip(states, sensor_noise_std, strict=True)}
    width = (max(1, round(20.0 / dt)), max(1, round(60.0 / dt)))
    inputs = {
        "X": RandomPulses(1.0, 2.0, *width),
        "Y": (RandomPulses(-0.3, 0.1, *width), RandomPulses(-0.1, 0.3, *width)),
        "N": (RandomPulses(0.15, 0.3, *width), RandomPulses(-0.3, -0.15, *width)),
    }
    return System(
        spec=spec, inputs=inputs, process_noise=w, sensor_noise=e,
        model=spec.merge_terms("r*|v|", "v*|r|", -1.0),
        x0=dict(zip(states, (float(x) for x in x0), strict=True)),
        description="CyberShip II (Skjetne et al. 2004), Euler at dt, no current (see "
                    "vesselid.vessels.simulate_cybership2 for current/wind/sensors)",
    )
