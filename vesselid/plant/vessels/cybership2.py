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

The data live here; the discrete-time model, the compiled kernel, disturbances and
sensors are the generic ones of :mod:`vesselid.plant.vessels`
(:class:`~vesselid.plant.vessels.hull.Hull`,
:mod:`vesselid.plant.vessels.kernel`).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass, fields
from typing import Any

import numpy as np

from vesselid.errors import VesselidError
from vesselid.model.spec import ModelSpec
from vesselid.plant.vessels.hull import Hull, block_inverse
from vesselid.plant.vessels.kernel import DEFAULT_DT, VesselSimulation, simulate_vessel
from vesselid.plant.vessels.wind import BLENDERMANN94

__all__ = [
    "CYBERSHIP2",
    "HULL",
    "CyberShip2Coefficients",
    "cybership2_hull",
    "cybership2_spec",
    "cybership2_system",
    "simulate_cybership2",
    "system",
]

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
        return block_inverse(self.mass_matrix())

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
    # sway: Y − (m − X_u̇) u r + damping;  yaw: N − (m x_g − (N_v̇+Y_ṙ)/2) u r − (X_u̇ − Y_v̇) u v
    # + damping; the same six damping terms in both, e.g. Y_v v + Y_|v|v v|v| + Y_|r|v v|r|
    # + Y_r r + Y_|v|r r|v| + Y_|r|r r|r| (coefficient names Y_v, Y_vv, Y_rv, Y_r, Y_vr, Y_rr)
    f[1, col["u*r"]] = -(c.m - c.X_udot)
    f[2, col["u*r"]] = -a
    f[2, col["u*v"]] = -(c.X_udot - c.Y_vdot)
    damping = {"v": "v", "v*|v|": "vv", "v*|r|": "rv", "r": "r", "r*|v|": "vr", "r*|r|": "rr"}
    for row, force in ((1, "Y"), (2, "N")):
        f[row, col[force]] = 1.0
        for term, name in damping.items():
            f[row, col[term]] = getattr(c, f"{force}_{name}")
    return f


#: Actuator limits ``|X|, |Y|, |N|`` (N, N, N m) of the model ship.
FORCE_MAX = (2.0, 1.5, 1.0)


def cybership2_hull(coefficients: CyberShip2Coefficients = CYBERSHIP2) -> Hull:
    """CyberShip II as a generic :class:`~vesselid.plant.vessels.hull.Hull`."""
    c = coefficients
    return Hull(
        name="cybership2", mass_matrix=c.mass_matrix(), basis=_BASIS,
        force_table=_force_matrix(c), equation_order=_EQ_ORDER, cubic=(c.X_uuu, 0.0, 0.0),
        length=c.L, beam=c.B, force_max=FORCE_MAX, wind=BLENDERMANN94,
        description="CyberShip II, 1:70 supply ship (Skjetne, Smogeli & Fossen 2004)",
        parameters=asdict(c),
    )


#: The published CyberShip II hull.
HULL = cybership2_hull()


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
        Aggregate relations to attach (e.g. ``{"u": "u - u_c", "v": "v - v_c"}``).

    Returns
    -------
    ModelSpec
        Named ``"cybership2"`` with ``theta0`` and ``dt``.
    """
    hull = HULL if coefficients is CYBERSHIP2 else cybership2_hull(coefficients)
    return hull.spec(dt, aggregate=aggregate)


def simulate_cybership2(
    inputs: np.ndarray,
    *,
    coefficients: CyberShip2Coefficients = CYBERSHIP2,
    **options: Any,
) -> VesselSimulation:
    """:func:`~vesselid.plant.vessels.kernel.simulate_vessel` for CyberShip II (same options)."""
    hull = HULL if coefficients is CYBERSHIP2 else cybership2_hull(coefficients)
    return simulate_vessel(hull, inputs, **options)

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
    """CyberShip II as a :class:`vesselid.plant.systems.System` (heading-independent case).

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
    the sensor suite use :func:`simulate_cybership2` or :mod:`vesselid.studies.seatrial`.
    """
    from vesselid.plant.vessels.system import pulse_system

    hull = HULL if coefficients is CYBERSHIP2 else cybership2_hull(coefficients)
    return pulse_system(
        hull, {"X": (1.0, 2.0), "Y": ((-0.3, 0.1), (-0.1, 0.3)),
               "N": ((0.15, 0.3), (-0.3, -0.15))},
        dt=dt, process_noise_std=process_noise_std,
        process_noise_time_constant=process_noise_time_constant,
        sensor_noise_std=sensor_noise_std, x0=x0, merges=TRIAL_MERGES,
        description="CyberShip II (Skjetne et al. 2004), Euler at dt, no current (see "
                    "vesselid.plant.vessels.simulate_cybership2 for current/wind/sensors)",
    )


#: Terms collinear in every steady turn (``v·|r| = −r·|v|`` since ``v·r < 0``): the sea
#: trial folds ``v·|r|`` into ``r·|v|`` (:func:`vesselid.studies.seatrial.seatrial_spec`).
TRIAL_MERGES = (("r*|v|", "v*|r|", -1.0),)

#: Catalogue entry (:mod:`vesselid.plant.catalogue`).
system = cybership2_system

