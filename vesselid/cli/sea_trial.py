"""``vesselid sea-trial``: design, simulate and identify a multi-experiment sea trial
(:mod:`vesselid.studies.seatrial`)."""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path
from typing import Any

from vesselid.cli.common import check_raw_dir, finite_float, int_at_least
from vesselid.errors import SeaTrialError
from vesselid.studies.seatrial import (
    DESIGNS,
    WIND_INPUTS,
    aggregate_key,
    closed_loop_trial_controller,
    run_pipeline,
    simulate_sea_trial,
)


def add_arguments(p: argparse.ArgumentParser) -> None:
    """The arguments of ``vesselid sea-trial``."""
    from vesselid.plant.catalogue import vessel_names

    p.add_argument("--vessel", default="cybership2", choices=vessel_names())
    p.add_argument("--experiments", type=int_at_least(2), default=6)
    p.add_argument("--samples", type=int_at_least(50), default=20000,
                   help="samples per experiment")
    p.add_argument("--current-speed", type=finite_float, default=0.05, help="m/s (model scale)")
    p.add_argument("--current-direction", type=finite_float, default=30.0,
                   help="going-to direction, degrees from north")
    p.add_argument("--wind-speed", type=finite_float, default=1.0, help="m/s (model scale)")
    p.add_argument("--wind-input", default="anemometer", choices=list(WIND_INPUTS),
                   help="wind load from the anemometer and the vessel's wind model added to "
                        "the logged forces X, Y, N as a known input (anemometer, default; "
                        "commands kept in X_cmd, Y_cmd, N_cmd) or left as an unmodelled "
                        "disturbance (none)")
    p.add_argument("--aggregate", default="relative",
                   choices=["relative", "speed_log", "current_meter", "none"],
                   help="signals for u, v: speed log as target and regressors (relative, "
                        "default), GNSS target with speed-log regressors (Remark 4.3), GNSS "
                        "target with GNSS - current meter regressors (eq. (9)), GNSS only")
    p.add_argument("--design", default=None, choices=list(DESIGNS),
                   help="input design: standard manoeuvres chosen by the trial planner "
                        "(planned, default; see `vesselid plan-trial`) or the original "
                        "steady turns with random pulses (static-offset; the default for vessels "
                        "other than cybership2)")
    p.add_argument("--sea-state", default=None, choices=["none", "calm", "smooth", "slight",
                                                          "moderate", "rough"],
                   help="waves (JONSWAP, Froude-scaled 1:70): first-order wave-induced "
                        "motion on the measurements; default none")
    p.add_argument("--wave-height", type=finite_float, default=None,
                   help="full-scale significant wave height H_s (m); overrides --sea-state")
    p.add_argument("--wave-period", type=finite_float, default=None,
                   help="full-scale peak period T_p (s)")
    p.add_argument("--wave-direction", type=finite_float, default=45.0,
                   help="going-to direction of the waves, degrees from north")
    p.add_argument("--wave-filter", type=finite_float, default=0.9, metavar="FRACTION",
                   help="with waves: zero-phase low-pass of the logged velocities and forces "
                        "at FRACTION x the model-scale wave peak frequency before they are "
                        "written (vesselid.data.wavefilter; unfiltered columns kept as "
                        "<name>_unfiltered; identify with iv-zero-mean); 0 writes the "
                        "unfiltered measurements; default 0.9")
    p.add_argument("--source", default="batch", choices=["batch", "env"],
                   help="batch simulator or Manoeuvring3DOF-v0 through the recorder")
    p.add_argument("--format", default=None, choices=["csv", "parquet"],
                   help="trial log format: parquet (default when pyarrow is installed; "
                        "metadata in the file) or csv (+ JSON sidecar)")
    p.add_argument("--closed-loop", action="store_true",
                   help="run the trial under feedback: PI velocity loops X->u, Y->v, N->r on "
                        "the speed log and gyro with random-step references and force "
                        "dithers (declared in the log, so identify uses cl-iv); CyberShip II, "
                        "--aggregate relative, no --design")
    p.add_argument("--identify", action="store_true",
                   help="also run LS, IV and IV-zero-mean and print the comparison")
    p.add_argument("--seed", type=int_at_least(0), default=0)
    p.add_argument("--out", required=True, help="output directory")
    p.add_argument("--raw", metavar="DIR",
                   help="also write the raw sensor streams (NMEA 0183, actuator CSV, spec) to DIR")
    p.set_defaults(func=cmd_sea_trial)


def _guard(args: argparse.Namespace) -> None:
    """Refuse a trial that does not fit this machine (:mod:`vesselid.core.limits`)."""
    from vesselid.core import limits

    rows = args.experiments * args.samples + args.samples  # + the held-out validation run
    cols = 24  # states, inputs, sensors, GNSS/heading channels and ground truth
    fmt = args.format
    runs = 4 if args.identify else 1  # --identify simulates again and fits three methods
    limits.check(
        "sea-trial", f"{args.experiments} experiments × {args.samples} samples",
        memory=limits.table_memory(rows, cols) + (limits.read_memory(rows, cols)
                                                  if args.identify else 0.0),
        seconds=runs * limits.simulation_seconds(rows, 3) + limits.write_seconds(rows, cols, fmt),
        disk=limits.file_bytes(rows, cols, fmt), disk_path=Path(args.out) / "seatrial.csv")


def default_log_format() -> str:
    """``"parquet"`` with pyarrow installed (smaller, faster, metadata inside), else ``"csv"``."""
    import importlib.util

    return "parquet" if importlib.util.find_spec("pyarrow") is not None else "csv"


def waves_from_args(args: argparse.Namespace) -> Any:
    """:class:`~vesselid.plant.waves.WaveConditions` from ``--sea-state``/``--wave-*`` (or None)."""
    from vesselid.plant.waves import SEA_STATES, WaveConditions

    name = getattr(args, "sea_state", None)
    hs = getattr(args, "wave_height", None)
    tp = getattr(args, "wave_period", None)
    if hs is None and tp is None and name in (None, "none"):
        return None
    base_hs, base_tp = SEA_STATES.get(name or "moderate", SEA_STATES["moderate"])
    return WaveConditions(height=base_hs if hs is None else float(hs),
                          period=base_tp if tp is None else float(tp),
                          direction=math.radians(float(getattr(args, "wave_direction", 45.0))))


def cmd_sea_trial(args: argparse.Namespace) -> int:
    """``vesselid sea-trial``: write DIR/seatrial.parquet (or .csv + .json), DIR/<vessel>.toml."""
    if args.format is None:
        args.format = default_log_format()
    if args.experiments < 2:
        raise SeaTrialError(f"--experiments must be at least 2, got {args.experiments}")
    if args.samples < 50:
        raise SeaTrialError(f"--samples must be at least 50, got {args.samples}")
    out = Path(args.out)
    if out.exists() and not out.is_dir():
        raise SeaTrialError(f"--out must be a directory, got the file {out}")
    if getattr(args, "raw", None):  # before simulating: all outputs or none

        check_raw_dir(args.raw)
    closed = bool(getattr(args, "closed_loop", False))
    if closed and args.design is not None:
        raise SeaTrialError("--closed-loop runs the trial under feedback; it takes no --design")
    if closed and args.source != "batch":
        raise SeaTrialError("--closed-loop always runs in the environment; leave --source out")
    if closed:
        closed_loop_trial_controller(0.1, args.vessel)  # one-line refusal for other vessels
        if aggregate_key(args.aggregate) != "relative":
            raise SeaTrialError("--closed-loop needs --aggregate relative (the loops control "
                                "the speed-log velocities)")
    _guard(args)
    out.mkdir(parents=True, exist_ok=True)
    opts = {"current_speed": args.current_speed,
            "current_direction": math.radians(args.current_direction),
            "wind_speed": args.wind_speed, "waves": waves_from_args(args),
            "wind_input": args.wind_input}
    opts["vessel"] = args.vessel
    log = simulate_sea_trial(args.experiments, args.samples, args.seed,
                             aggregate=args.aggregate, source=args.source,
                             design=args.design, closed_loop=closed, **opts)
    log.metadata["command"] = "vesselid " + " ".join(sys.argv[1:]) if sys.argv else ""
    raw_log = log
    if opts["waves"] is not None and opts["waves"].height > 0 and args.wave_filter != 0:
        from vesselid.data.wavefilter import WaveFilter, wave_filter_log

        filt = WaveFilter.for_waves(opts["waves"], float(log.spec.dt or 0.1),
                                    fraction=args.wave_filter)
        log = wave_filter_log(log, filt)
        print(f"wave filter: zero-phase Butterworth low-pass at {filt.cutoff:.3g} Hz "
              f"({args.wave_filter:g} x the wave peak frequency) on {', '.join(log.spec.signals)}")
    data = out / ("seatrial.csv" if args.format == "csv" else "seatrial.parquet")
    spec_path = out / f"{args.vessel}.toml"
    log.save(data, extra={spec_path: log.spec.to_toml()})  # all files appear together
    extra = f" and sidecar {data.with_suffix('.json')}" if args.format == "csv" else ""
    print(f"wrote {data} ({len(log)} rows, {args.experiments} experiments){extra}, model spec "
          f"{spec_path} (aggregate: {args.aggregate})")
    if closed:
        print("closed loop: PI loops X->u, Y->v, N->r; references u_ref, v_ref, r_ref; "
              "dithers X_dither, Y_dither, N_dither (metadata['closed_loop'])")
        print(f"next: vesselid identify {data} --model {spec_path}   (auto -> cl-iv)")
    else:
        from vesselid.studies.planner import SRIV_ORDER

        print(f"next: vesselid identify {data} --model {spec_path} --noise-order "
              f"{SRIV_ORDER}   (the default auto: its SRIV fallback needs an AR({SRIV_ORDER}) "
              "noise model on this trial's equation error, as the planner assumes)")
        print(f"  or: vesselid identify {data} --model {spec_path} --method iv-zero-mean")
    if getattr(args, "raw", None):
        from vesselid.data.rawexport import write_raw_streams

        manifest = write_raw_streams(raw_log, args.raw, seed=args.seed)
        print(f"wrote raw sensor streams to {args.raw} ({sum(manifest['sentences'].values())} "
              f"NMEA sentences, actuators.csv, ingest.toml, {manifest['files'][-1]})")
    if args.identify and closed:
        from vesselid.identify import identify

        print()
        print(identify(log, log.spec).summary())
    elif args.identify:
        res = run_pipeline(args.experiments, args.samples, args.seed, aggregate=args.aggregate,
                           source=args.source, design=args.design, **opts)
        print()
        print(res.summary())
    return 0
