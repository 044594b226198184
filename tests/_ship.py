"""A small ship model with derived signals and its noise-free zig-zags (shared test data)."""

from __future__ import annotations

import numpy as np
import pandas as pd

from vesselid.model.spec import ModelSpec

SHIP = """
name = "ship"
states = ["du", "v", "r"]
inputs = ["delta", "uud"]
dt = 0.5

[derived]
du = "u - 1.0"
uud = "u*u*delta"

[equations]
du = ["du", "du*|du|", "v*r", "delta*delta"]
v = ["v", "r", "du*v", "uud"]
r = ["r", "v", "du*r", "r*|r|", "uud"]

[theta0]
du = [0.99, 0.01, 0.3, -0.004]
v = [0.95, -0.08, 0.02, 0.006]
r = [0.96, -0.03, -0.05, -0.2, -0.005]
"""



def zigzag_log(spec: ModelSpec, n: int = 600, delta0: float = 0.35, psi_s: float = 0.17,
               first: float = 1.0, theta: np.ndarray | None = None, u0: float = 1.0):
    """A noise-free zig-zag of the spec's own model (rudder switched on its heading)."""
    from vesselid.validation.freerun import Plant, ZigZagLogic

    plant = Plant(spec, theta)
    frame = pd.DataFrame({"u": np.full(n, u0), "v": np.zeros(n), "r": np.zeros(n),
                          "delta": np.zeros(n)})
    logic = ZigZagLogic(execute=10, rudder="delta", delta0=delta0, psi_switch=psi_s,
                        rate=np.radians(10.0), gain_sign=-1.0, first_sign=first)
    x, u_used, bad = plant.simulate(frame, x0=np.array([0.0, 0.0, 0.0]), zigzag=logic,
                                    dt=spec.dt)
    assert bad == -1
    from vesselid.validation.metrics import integrate_track

    uu = x[:, 0] + u0
    psi, north, east = integrate_track(uu, x[:, 1], x[:, 2], spec.dt)
    return pd.DataFrame({"time": np.arange(n) * spec.dt, "u": uu, "v": x[:, 1], "r": x[:, 2],
                         "psi": psi, "north": north, "east": east, "delta": u_used[:, 0]})


def write_hsva(path, g: pd.DataFrame) -> None:
    """A zig-zag of :func:`zigzag_log` written as an HSVA table (``.dat``): four header
    lines, then time, x0, y0, ψ (deg), the earth-fixed u and v, r (deg/s), p, δ (deg), rpm
    (constant), thrust and torque."""
    c, s = np.cos(g["psi"]), np.sin(g["psi"])
    cols = [g["time"], g["north"], g["east"], np.degrees(g["psi"]),
            c * g["u"] - s * g["v"], s * g["u"] + c * g["v"], np.degrees(g["r"]),
            np.zeros(len(g)), np.degrees(g["delta"]), np.full(len(g), 10.2295),
            np.zeros(len(g)), np.zeros(len(g))]
    body = "\n".join(" ".join(f"{x:.12e}" for x in row) for row in np.column_stack(cols))
    path.write_text("a\nb\nc\nd\n" + body + "\n", encoding="latin-1")
