"""Viknes 830: an 8.3 m motor boat (Telemetron USV) with modulus-type surge and sway damping.

Coefficients from Loe, Ø. A. G. (2008), *Collision Avoidance for Unmanned Surface
Vehicles*, MSc thesis, Norwegian University of Science and Technology (NTNU), Trondheim,
model of the Viknes 830 (as reproduced in open-source USV simulators that cite it):

=========  ==========  ======  =========  ==========  =========
m          3980 kg     X_u     −50        X_|u|u      −135
I_z        19703 kg m² Y_v     −200       Y_|v|v      −2000
added mass 0           N_r     −3224      N_rrr       −3224 (cubic)
=========  ==========  ======  =========  ==========  =========

(``Y_r = N_v = N_|r|r = 0``, ``x_g = 0``; actuator limits ``X ∈ [−6550, 13100]`` N,
``|Y| ≤ 645`` N at a rudder arm of 4 m, here ``|N| ≤ 2580`` N m.) With no added mass
and ``x_g = 0`` the rigid-body Coriolis forces are ``m v r`` (surge) and ``−m u r``
(sway), so the force table is::

    X + X_u u + X_|u|u u|u| + m v r,   Y + Y_v v + Y_|v|v v|v| − m u r,   N + N_r r.

The cubic yaw damping ``N_rrr r³`` is not second-order modulus: it is simulated only with
``cubic_surge=True`` (the option name is shared with CyberShip II's cubic surge term) and is
then absent from the identification spec.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from vesselid.plant.vessels.hull import Hull

__all__ = ["HULL", "PARAMETERS", "system"]

#: The published coefficients (Loe 2008).
PARAMETERS = {"m": 3980.0, "I_z": 19703.0, "X_u": -50.0, "X_uu": -135.0, "Y_v": -200.0,
              "Y_vv": -2000.0, "N_r": -3224.0, "N_rrr": -3224.0, "L": 8.3, "B": 2.8}

_P = PARAMETERS
HULL = Hull.from_table(
    "viknes830",
    np.diag([_P["m"], _P["m"], _P["I_z"]]),
    {
        "u": {"u": _P["X_u"], "u*|u|": _P["X_uu"], "v*r": _P["m"], "X": 1.0},
        "v": {"v": _P["Y_v"], "v*|v|": _P["Y_vv"], "u*r": -_P["m"], "Y": 1.0},
        "r": {"r": _P["N_r"], "N": 1.0},
    },
    cubic=(0.0, 0.0, _P["N_rrr"]),
    length=_P["L"],
    beam=_P["B"],
    force_max=(13100.0, 645.0, 2580.0),
    velocity_limit=20.0,
    description="Viknes 830 motor boat (Loe 2008, NTNU MSc thesis)",
    parameters=PARAMETERS,
)


def system(
    *,
    dt: float = 0.1,
    process_noise_std: Sequence[float] = (2e-3, 2e-3, 2e-4),
    process_noise_time_constant: float = 2.0,
    sensor_noise_std: Sequence[float] = (0.02, 0.02, 0.002),
    x0: Sequence[float] = (4.0, 0.0, 0.0),
):
    """Viknes 830 as a :class:`vesselid.plant.systems.System` (no current; catalogue entry).

    Additive Gauss–Markov process noise ``w`` (unmodelled forces, bounded at 3 std) and
    Gaussian measurement noise; inputs are random-width pulses on static offsets that
    keep ``u > 0`` and, within one experiment, ``v`` and ``r`` of one sign (even
    experiments turn to starboard, odd ones to port).
    """
    from vesselid.plant.vessels.system import pulse_system

    return pulse_system(
        HULL, {"X": (2000.0, 5000.0), "Y": (-400.0, 400.0),
               "N": ((400.0, 1500.0), (-1500.0, -400.0))},
        dt=dt, process_noise_std=process_noise_std,
        process_noise_time_constant=process_noise_time_constant,
        sensor_noise_std=sensor_noise_std, x0=x0,
        description=HULL.description + ", Euler at dt, no current")


#: Sea-trial operating points ``(X [N], Y [N], N [N m], side)`` (:mod:`vesselid.studies.seatrial`):
#: steady turns, each to both sides; ``v·r < 0`` in every turn, ``|v| ≳ 0.5`` m/s, ``r ≳ 0.1``
#: rad/s with the pulses below, inside :attr:`Hull.force_max`.
TRIAL_LEVELS = tuple((4000.0, y, n, side)
                     for y, n in ((0.0, 1200.0), (300.0, 1400.0), (-300.0, 1000.0))
                     for side in (+1, -1))
#: Pulse amplitudes ``(X, Y, N)`` of the sea trial.
TRIAL_PERTURBATION = (2000.0, 300.0, 500.0)
#: Margins of the sea-trial design check (A10/A15).
TRIAL_ETA = {"u": 0.1, "v": 0.1, "r": 0.02}
