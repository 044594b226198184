"""Planning a closed-loop sea trial: the declared controller, references and dithers of
``vesselid sea-trial --closed-loop``, and the ``cl-iv`` standard errors predicted from one
simulated trial (``vesselid plan-trial --closed-loop``)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import pandas as pd

from vesselid.studies.planner import PlannerError, _finite

__all__ = ["ClosedLoopPlan", "plan_closed_loop_trial"]


@dataclass
class ClosedLoopPlan:
    """A closed-loop sea trial (:func:`plan_closed_loop_trial`): the declared controller,
    references and dithers, and the ``cl-iv`` standard errors predicted from a simulated
    trial of that design (``table``: ``theta0``, ``se``, ``relative_se`` per parameter)."""

    experiments: int
    samples_per_experiment: int
    wind_speed: float
    seed: int
    design: dict[str, Any]
    table: pd.DataFrame
    method: str

    def worst_relative_se(self) -> float:
        rel = self.table["relative_se"].to_numpy(float)
        return float(np.nanmax(rel)) if rel.size else float("nan")

    def command(self) -> str:
        return (f"vesselid sea-trial --closed-loop --experiments {self.experiments} "
                f"--samples {self.samples_per_experiment} --wind-speed {self.wind_speed:g} "
                "--out trial")

    def to_dict(self) -> dict[str, Any]:
        return _finite({"kind": "closed-loop", "experiments": self.experiments,
                        "samples_per_experiment": self.samples_per_experiment,
                        "wind_speed": self.wind_speed, "seed": self.seed,
                        "design": self.design, "method": self.method,
                        "predicted": {f"{e}: {t}": {"theta0": float(r.theta0),
                                                    "se": float(r.se),
                                                    "relative_se": float(r.relative_se)}
                                      for (e, t), r in self.table.iterrows()},
                        "command": self.command()})

    def summary(self) -> str:
        ctrl = self.design["controller"]
        loops = ", ".join(f"{j} -> {x}" for j, x in ctrl["loops"].items())
        lines = [f"closed-loop sea trial: {self.experiments} experiments x "
                 f"{self.samples_per_experiment} samples, wind {self.wind_speed:g} m/s",
                 f"controller: PI loops {loops}; kp {ctrl['kp']}, ki {ctrl['ki']}, "
                 f"feed-forward {ctrl['offset']}, limits {ctrl['limits']}",
                 f"references: {self.design['references']} (held {self.design['hold_s']} s; "
                 "sway/yaw sign combinations cycled over the experiments)",
                 f"dither std: {self.design['dither_std']}",
                 f"predicted standard errors of {self.method} (HAC, from a simulated trial "
                 f"of this design, seed {self.seed}):", ""]
        tab = self.table.copy()
        tab.index = [f"{e}: {t}" for e, t in tab.index]
        lines.append(tab.to_string(float_format=lambda x: f"{x:.4g}"))
        lines += ["", f"worst relative SE: {self.worst_relative_se():.3g}",
                  f"run it: {self.command()}"]
        return "\n".join(lines)


def plan_closed_loop_trial(samples: int = 24_000, experiments: int = 4, *,
                           wind_speed: float = 1.0, seed: int = 0) -> ClosedLoopPlan:
    """Plan a closed-loop sea trial: the PI velocity-loop design of
    ``vesselid sea-trial --closed-loop`` (:data:`vesselid.studies.seatrial.CLOSED_LOOP_TRIAL`) with
    ``samples`` split over ``experiments`` (at least 4: the four sign combinations of the
    sway and yaw references), and the closed-loop estimator's standard errors predicted by
    simulating one trial of that size (same disturbance levels as the sea trial) and
    identifying it with ``cl-iv`` (its HAC standard errors: an estimate of the design's
    standard errors with the relative precision of a HAC estimate, about ±10 %).
    """
    import warnings

    from vesselid.identify import identify
    from vesselid.studies.seatrial import simulate_sea_trial

    if experiments < 4:
        raise PlannerError(f"a closed-loop trial needs at least 4 experiments (the sign "
                           f"combinations of the sway and yaw references), got {experiments}")
    per = samples // experiments
    if per < 200:
        raise PlannerError(f"--samples must give at least 200 per experiment, got {per}")
    log = simulate_sea_trial(experiments, per, seed, closed_loop=True, wind_speed=wind_speed)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = identify(log, log.spec, "cl-iv")
    theta0 = log.spec.theta0_vector()
    se = res.std_errors.to_numpy()
    table = pd.DataFrame({"theta0": theta0, "se": se,
                          "relative_se": se / np.maximum(np.abs(theta0), 1e-300)},
                         index=res.params.index)
    info = log.metadata["closed_loop_trial"]
    # the design as the simulated log records it
    design = {"controller": info["controller"],
              "references": {k: v for k, v in info["references"].items() if k != "hold_s"},
              "hold_s": info["references"]["hold_s"], "dither_std": info["dither_std"]}
    return ClosedLoopPlan(experiments=experiments, samples_per_experiment=per,
                          wind_speed=float(wind_speed), seed=int(seed), design=design,
                          table=table, method=res.method)
