"""The controller's designed closed loop, checked sample by sample (tests of
:mod:`vesselid.control.controllers` on every vessel): tolerances from float32/float64 round-off."""

from __future__ import annotations

import numpy as np

from vesselid.control.controllers import FeedbackLinearizingController

__all__ = ["QUIET", "closed_loop_residuals", "quiet_env"]


def closed_loop_residuals(ctrl: FeedbackLinearizingController, tr) -> tuple[float, float, float]:
    """Largest deviation of the recorded surge speed and yaw rate from the closed loop the
    controller designs (``u(k+1) = u + dt/T_u e_u + k_iu dt ∫``, ``r(k+1) = r + dt/T_r
    (r_ref − r)``), over the unsaturated steps, and the tolerance: one float32 ulp of the
    action (the environment's action dtype) times the model's input gain, plus float64
    round-off. Exact for θ0 in an environment without disturbances or sensor noise."""
    dt, fmax = ctrl.dt, ctrl.fmax
    u, u_ref, x = tr["u"].to_numpy(), tr["u_ref"].to_numpy(), tr["X"].to_numpy()
    r, n = tr["r"].to_numpy(), tr["N"].to_numpy()
    e_psi = np.angle(np.exp(1j * (tr["psi_ref"].to_numpy() - tr["psi"].to_numpy())))
    e_u = u_ref - u
    ok_x = np.abs(x) < fmax[0]
    i_u = np.concatenate([[0.0], np.cumsum(np.where(ok_x, e_u / ctrl.t_u, 0.0))[:-1]])
    du = u[1:] - (u + dt / ctrl.t_u * e_u + ctrl.ki_u * dt * i_u)[:-1]
    i_psi, r_ref = 0.0, np.empty_like(r)
    for k in range(r.size):  # the outer PI law with its anti-windup, as designed
        r_ref[k] = np.clip(ctrl.k_psi * e_psi[k] + ctrl.ki_psi * i_psi, -ctrl.r_max, ctrl.r_max)
        if abs(n[k]) < fmax[2] and abs(r_ref[k]) < ctrl.r_max:
            i_psi += e_psi[k] * dt
    dr = r[1:] - (r + dt / ctrl.t_r * (r_ref - r))[:-1]
    ok_n = np.abs(n) < fmax[2]
    tol = 2.0**-23 * max(abs(ctrl._gain[("u", "X")]) * fmax[0],
                         abs(ctrl._gain[("r", "N")]) * fmax[2]) + 1e-12
    return float(np.max(np.abs(du[ok_x[:-1]]))), float(np.max(np.abs(dr[ok_n[:-1]]))), tol


QUIET = dict(current_speed=0.0, wind_speed=0.0, wind_gust=0.0)


def quiet_env() -> dict:
    from vesselid.plant.vessels import VesselSensors

    return {"sensors": VesselSensors.noiseless(), "current_variation": 0.0, "force_noise": 0.0}
