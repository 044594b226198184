"""Command line of closed-loop logs and online estimation.

``vesselid closed-loop``
    Simulate the heave system under a PI(D) loop, or CyberShip II under PI velocity loops
    (:mod:`vesselid.plant.closedloop` designs), with references and dithers, and write a
    closed-loop trial log (reference and dither columns, ``metadata["closed_loop"]``) for
    ``vesselid identify LOG --method cl-iv``.
``vesselid recursive``
    Run recursive LS / IV with a forgetting factor over a trial log; print the final
    estimate and optionally write the θ̂ trajectory.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from vesselid.cli.common import finite_float, int_at_least
from vesselid.errors import CLIError

__all__ = ["add_arguments", "cmd_closed_loop"]


def add_arguments(p: argparse.ArgumentParser) -> None:
    """The arguments of ``vesselid closed-loop``."""
    p.add_argument("--system", choices=["heave", "cybership2"], default="heave",
                   help="heave: PI(D) loop on the heave velocity (the options below); "
                        "cybership2: three PI velocity loops X->u, Y->v, N->r (DP-like) with "
                        "references of both signs and force dithers")
    p.add_argument("--samples", type=int_at_least(10), default=None,
                   help="samples per experiment (default 5000 heave, 3000 cybership2)")
    p.add_argument("--experiments", type=int_at_least(1), default=None,
                   help="experiments (default 1 heave, 4 cybership2: the four sign "
                        "combinations of the sway and yaw references)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--kp", type=finite_float, default=0.3, help="proportional gain")
    p.add_argument("--ki", type=finite_float, default=0.05, help="integral gain (1/s)")
    p.add_argument("--kd", type=finite_float, default=0.0, help="derivative gain (s)")
    p.add_argument("--offset", type=finite_float, default=0.2,
                   help="feed-forward thrust u0")
    p.add_argument("--reference", type=finite_float, nargs=2, default=(1.0, 2.0),
                   metavar=("LOW", "HIGH"),
                   help="reference levels: random steps uniform on [LOW, HIGH]")
    p.add_argument("--reference-width", type=int_at_least(1), nargs=2, default=(50, 200),
                   metavar=("MIN", "MAX"), help="samples each reference level is held")
    p.add_argument("--dither-std", type=finite_float, default=0.05,
                   help="std of the white Gaussian dither added to the thrust")
    p.add_argument("--out", required=True, help="trial log (.csv or .parquet)")
    p.set_defaults(func=cmd_closed_loop)


def cmd_closed_loop(args: argparse.Namespace) -> int:
    """``vesselid closed-loop``: write a closed-loop heave log."""
    from vesselid.plant.closedloop import cybership2_velocity_design, heave_pi_design

    out = Path(args.out)
    if out.suffix.lower() not in (".csv", ".parquet", ".pq"):
        raise CLIError(f"--out must end in .csv or .parquet, got {out.name!r}")
    if not args.dither_std >= 0:
        raise CLIError(f"--dither-std must be non-negative, got {args.dither_std}")
    if args.system == "cybership2":
        design = cybership2_velocity_design()
        what = "PI loops X->u, Y->v, N->r, references u_ref/v_ref/r_ref, force dithers"
    else:
        lo, hi = args.reference
        if not lo <= hi:
            raise CLIError(f"--reference needs LOW <= HIGH, got {lo} {hi}")
        wmin, wmax = args.reference_width
        if wmin > wmax:
            raise CLIError(f"--reference-width needs MIN <= MAX, got {wmin} {wmax}")
        design = heave_pi_design(kp=args.kp, ki=args.ki, kd=args.kd, offset=args.offset,
                                 reference=(lo, hi), hold=(wmin, wmax),
                                 dither_std=args.dither_std)
        what = "PI on w, reference w_ref, dither tau_dither"
    sim = design.simulate(samples=args.samples, experiments=args.experiments, seed=args.seed)
    log = sim.to_log(aggregate=False)
    log.metadata["spec"] = design.spec.to_dict()  # the structure these loops identify
    log.metadata["command"] = "vesselid " + " ".join(sys.argv[1:]) if sys.argv else ""
    spec_path = out.with_name(out.stem + "_spec.toml")
    log.save(out, extra={spec_path: log.spec.to_toml()})
    n_exp = int(log.data["experiment"].nunique())
    print(f"wrote {out} ({len(log.data)} rows, {n_exp} experiment(s), closed loop: {what}) "
          f"and model spec {spec_path}")
    print(f"next: vesselid identify {out} --method cl-iv")
    return 0
