"""Blendermann (1994) wind loads: coefficients and the one load formula.

The formula is :func:`wind_load` (compiled, scalar); the vessel kernel inlines it and
:func:`blendermann_wind_force` maps it over arrays, so there is one implementation.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit

__all__ = ["BLENDERMANN94", "BlendermannWind", "blendermann_wind_force", "wind_load"]


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

    def parameters(self) -> np.ndarray:
        """The packed parameters of :func:`wind_load` (9 floats)."""
        return np.array([self.rho_air, self.frontal_area, self.lateral_area, self.length,
                         self.s_l, self.cd_t, self.cd_l_bow, self.cd_l_stern, self.delta])


#: Default wind-load model (offshore supply vessel row, 1:70 model-scale areas).
BLENDERMANN94 = BlendermannWind()

#: Number of packed wind parameters.
N_WIND_PAR = 9


@njit(cache=True, inline="always")
def wind_load(gam, v2, wp, o):
    """Wind force/moment ``(X, Y, N)`` for relative wind angle ``γ_rw`` and speed² ``V²``.

    ``wp[o:o + 9]`` holds :meth:`BlendermannWind.parameters`. The yaw coefficient is
    extended to ``γ < 0`` by symmetry, ``C_N = (s_L/L − 0.18(|γ| − π/2)) C_Y``.
    """
    rho, af, al, loa, sl = wp[o], wp[o + 1], wp[o + 2], wp[o + 3], wp[o + 4]
    cdt, cdl_bow, cdl_stern, delta = wp[o + 5], wp[o + 6], wp[o + 7], wp[o + 8]
    ag = abs(gam)
    cdl_af = cdl_bow if ag <= 0.5 * math.pi else cdl_stern
    cdl = cdl_af * af / al
    s2 = math.sin(2.0 * gam)
    den = 1.0 - 0.5 * delta * (1.0 - cdl / cdt) * s2 * s2
    cy = cdt * math.sin(gam) / den
    q = 0.5 * rho * v2
    xw = q * (-cdl_af * math.cos(gam) / den) * af
    yw = q * cy * al
    nw = q * (sl / loa - 0.18 * (ag - 0.5 * math.pi)) * cy * al * loa
    return xw, yw, nw


@njit(cache=True)
def _wind_loads(g, v2, wp, out):
    for i in range(g.shape[0]):
        out[i, 0], out[i, 1], out[i, 2] = wind_load(g[i], v2[i], wp, 0)


def blendermann_wind_force(
    gamma_rw: np.ndarray | float, speed_rw: np.ndarray | float,
    wind: BlendermannWind = BLENDERMANN94,
) -> np.ndarray:
    """Wind force/moment ``[X, Y, N]`` from the relative wind angle and speed.

    ``γ_rw = −atan2(v_rw, u_rw)`` (0: wind from ahead) with ``[u_rw, v_rw] = ν − ν_w``.
    Evaluates :func:`wind_load`, the formula of the simulation kernels.
    """
    g, v = np.broadcast_arrays(np.asarray(gamma_rw, dtype=float),
                               np.asarray(speed_rw, dtype=float))
    out = np.empty((g.size, 3))
    _wind_loads(np.ascontiguousarray(g).ravel(), np.ascontiguousarray(v ** 2).ravel(),
                wind.parameters(), out)
    return out.reshape(*g.shape, 3)
