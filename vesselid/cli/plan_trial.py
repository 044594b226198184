"""``vesselid plan-trial``: manoeuvres and predicted standard errors
(:mod:`vesselid.studies.planner`)."""

from __future__ import annotations

import argparse
import json
import math

from vesselid.cli.common import finite_float, int_at_least
from vesselid.studies.closed_loop_trial import plan_closed_loop_trial
from vesselid.studies.planner import (
    PREDICTED_ESTIMATORS,
    DisturbanceLevels,
    PlannerError,
    plan_trial,
)


def add_arguments(p: argparse.ArgumentParser) -> None:
    """The arguments of ``vesselid plan-trial``."""
    p.add_argument("--vessel", default="cybership2", choices=["cybership2"])
    p.add_argument("--samples", type=int_at_least(50), default=None,
                   help="total sample budget (default 120000; 24000 with --closed-loop)")
    p.add_argument("--experiments", type=int_at_least(1), default=None,
                   help="experiments (default 6; 4 with --closed-loop)")
    p.add_argument("--wind-speed", type=finite_float, default=1.0, help="m/s (model scale)")
    p.add_argument("--estimator", default="auto", choices=list(PREDICTED_ESTIMATORS),
                   help="estimator whose covariance is predicted (default auto, the "
                        "identify default: SRIV on a sea trial)")
    p.add_argument("--closed-loop", action="store_true",
                   help="plan a closed-loop trial (PI velocity loops with references and "
                        "dithers, identified with cl-iv): its design and the standard "
                        "errors predicted from a simulated trial (default budget 24000 "
                        "samples over 4 experiments)")
    p.add_argument("--seed", type=int_at_least(0), default=0,
                   help="seed of the simulated trial of --closed-loop")
    p.add_argument("--json", action="store_true", help="print the plan as JSON")
    p.set_defaults(func=cmd_plan_trial)


def cmd_plan_trial(args: argparse.Namespace) -> int:
    """``vesselid plan-trial``: print the plan and the predicted standard errors."""
    closed = bool(getattr(args, "closed_loop", False))
    if args.samples is None:
        args.samples = 24_000 if closed else 120_000
    if args.experiments is None:
        args.experiments = 4 if closed else 6
    if closed:
        if not (math.isfinite(args.wind_speed) and args.wind_speed >= 0):
            raise PlannerError(f"--wind-speed must be a non-negative number, got "
                               f"{args.wind_speed}")
        if getattr(args, "estimator", "auto") != "auto":
            raise PlannerError("--closed-loop predicts the closed-loop estimator cl-iv; "
                               "leave --estimator out")
        from vesselid.core import limits

        limits.check("plan-trial", f"{args.samples} closed-loop samples",
                     memory=limits.table_memory(args.samples, 40),
                     seconds=50.0 * limits.simulation_seconds(args.samples, 3))
        cplan = plan_closed_loop_trial(args.samples, args.experiments,
                                       wind_speed=args.wind_speed, seed=args.seed)
        if args.json:
            print(json.dumps(cplan.to_dict(), indent=2, allow_nan=False))
        else:
            print(cplan.summary())
        return 0
    if args.experiments < 1:
        raise PlannerError(f"--experiments must be at least 1, got {args.experiments}")
    if args.samples < 50 * max(args.experiments, 1):
        raise PlannerError(f"--samples must be at least 50 per experiment, got {args.samples}")
    if not (math.isfinite(args.wind_speed) and args.wind_speed >= 0):
        raise PlannerError(f"--wind-speed must be a non-negative number, got {args.wind_speed}")
    from vesselid.core import limits

    # every candidate manoeuvre is simulated over the budget to predict its moments
    limits.check("plan-trial", f"{args.samples} samples × {args.experiments} experiments",
                 memory=limits.table_memory(args.samples, 40),
                 seconds=limits.simulation_seconds(40.0 * args.samples, 3))
    plan = plan_trial(args.samples, args.experiments,
                      levels=DisturbanceLevels(wind_speed=args.wind_speed),
                      estimator=getattr(args, "estimator", "auto"))
    if not math.isfinite(plan.worst_relative_se()):
        # e.g. an absurd wind speed: every candidate's simulation diverges
        raise PlannerError(
            f"no plan has finite predicted standard errors for {args.samples} samples at "
            f"--wind-speed {args.wind_speed:g} m/s (the manoeuvre simulations diverge or the "
            "parameters are not identifiable); use a realistic wind speed or a larger budget")
    if args.json:
        print(json.dumps(plan.to_dict(), indent=2, allow_nan=False))
    else:
        print(plan.summary())
    return 0
