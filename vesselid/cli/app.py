"""The ``vesselid`` command line.

::

    vesselid simulate  --system heave --samples 10000 --seed 0 --out trial.csv
    vesselid identify  trial.csv --model heave.toml [--method NAME] [--cov NAME] [--json PATH|-]
    vesselid identify  LOGS_DIR --stream [--method ls|iv|iv-zero-mean]   # Parquet, bounded memory
    vesselid reproduce [--table 1|2|all] [--runs 1000] [--samples 10000] [--seed 0] [--out DIR]
    vesselid sea-trial --vessel cybership2 --experiments 6 --samples 20000 --seed 0 --out DIR

Exit code 0 on success, 2 on bad input (:class:`~vesselid.errors.VesselidError`, ``OSError``)
with a one-line reason on stderr; 3 from ``identify`` when the input is valid but no usable
model came out (no finite estimate, or one that is unstable on the log or has non-finite fit
figures; one line on stderr); anything else is a bug (traceback, exit code 1).
Subcommands living in other modules register themselves through an
``add_parser(subparsers)`` function that sets ``func`` (returning an exit code).
"""

from __future__ import annotations

import argparse
import gc
import importlib
import math
import signal
import sys
import warnings
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from vesselid import __version__
from vesselid.cli.common import (
    check_output_file,
    check_raw_dir,
    finite_float,
    int_at_least,
    write_json,
)
from vesselid.errors import CLIError, VesselidError

__all__ = ["main"]

#: Plugin commands imported only when they are run (or their own ``--help`` is asked
#: for): command -> (module, one-line help, description of its ``--help``); the plugin
#: module adds its arguments (``add_arguments(parser)``). ``vesselid --help`` lists them without
#: importing the module, so it loads neither pandas nor numba.
LAZY_COMMANDS = {
    "reproduce": (
        "vesselid.cli.reproduce", "reproduce the paper's Tables 1-2 and Figure 1",
        "Monte Carlo reproduction of Ljungberg & Enqvist §6: LS, IV and IV with zero-mean "
        "instruments on the heave system; prints the published and reproduced tables row by "
        "row and checks the paper's claims."),
    "sea-trial": (
        "vesselid.cli.sea_trial", "design and simulate a multi-experiment sea trial",
        "Design a multi-experiment sea trial (steady turns to both sides at several levels plus "
        "pulses), simulate it with current and wind, and write the trial log and the model "
        "spec for `vesselid identify`."),
    "plan-trial": (
        "vesselid.cli.plan_trial", "plan a sea trial: manoeuvres and predicted standard errors",
        "Choose standard manoeuvres (turning circles, zig-zags, pull-outs, spirals, stopping, "
        "thruster tests) for a sample budget so that the worst relative standard error of the "
        "identified parameters is smallest, predicted from the asymptotic IV covariance (no "
        "Monte Carlo)."),
    "ingest": (
        "vesselid.cli.ingest",
        "turn raw sensor streams (NMEA 0183, ROS 2 bags, CSV) into a trial log",
        "Read NMEA 0183 logs, ROS 2 bags and mapped multi-rate CSV files, align the clocks, "
        "resample onto a uniform grid, convert to local NED and body-frame velocities, split "
        "experiments at gaps, and write a trial log with a quality report in its metadata."),
    "validate": (
        "vesselid.cli.validate", "validate an identified model on held-out experiments",
        "Simulate an identified model on (held-out) experiments with their measured inputs: "
        "free-run and k-step-ahead fit per state, and for zig-zags and turning circles "
        "(detected from the rudder) the overshoot angles, advance, tactical diameter and "
        "steady turn rate, measured vs simulated; optional compare-style figure and JSON."),
    "closed-loop": (
        "vesselid.cli.closed_loop", "simulate a closed-loop trial log (PI loop, reference, dither)",
        "Simulate the heave system under a PI(D) controller with a random-step reference and a "
        "white dither; the log has the reference and dither columns and names the controller "
        "in its metadata, for `vesselid identify LOG --method cl-iv`."),
    "recursive": (
        "vesselid.cli.recursive", "recursive (online) LS / IV with a forgetting factor",
        "Run recursive least squares or recursive IV with forgetting factor λ over a trial "
        "log in one compiled pass; print the final estimate and optionally write the "
        "estimate's trajectory."),
    "select": (
        "vesselid.cli.select", "select the modulus terms of each equation from a log",
        "Choose the terms of every state equation from a candidate library (Definition 2.1 "
        "forms): IV backward elimination with instruments simulated from the inputs, HAC "
        "Wald tests and block-bootstrap selection probabilities; writes a spec for "
        "`vesselid identify`."),
}



class _Parser(argparse.ArgumentParser):
    """``argparse`` with one-line usage errors (``vesselid CMD: error: ...``, exit 2).

    The usage block argparse prints before a usage error is left out: bad input gets
    one line on stderr, like every other refusal (``--help`` still shows the usage).
    Subcommand parsers inherit the class (``add_subparsers`` uses ``type(self)``).
    """

    def error(self, message: str) -> Any:  # type: ignore[override]
        self.exit(2, f"{self.prog}: error: {message}\n")


def _spec_path_for(out: Path) -> Path:
    return out.with_name(out.stem + ".toml")


def cmd_simulate(args: argparse.Namespace) -> int:
    from vesselid.core import limits
    from vesselid.plant.catalogue import get_system
    from vesselid.plant.todisk import log_columns, peak_rows, simulate_to_file

    out = Path(args.out)
    if out.suffix.lower() not in (".csv", ".parquet", ".pq"):
        raise CLIError(f"--out must end in .csv or .parquet, got {out.name!r}")
    options: dict = {}
    if args.system in ("heave", "siso"):
        key = "current_mean" if args.system == "heave" else "v_mean"
        if args.current_mean is not None:
            options[key] = args.current_mean
        if args.current_sensor:
            options["current_sensor"] = True
    elif args.current_mean is not None or args.current_sensor:
        raise CLIError(f"--current-mean/--current-sensor apply to heave and siso; system "
                       f"{args.system!r} has no current here (for CyberShip II with current, "
                       f"wind and sensors use `vesselid sea-trial --current-speed`)")
    system = get_system(args.system, **options)
    if args.raw:  # refuse before simulating: nothing is written for a request that must fail
        _check_raw_request(args.raw, system)
    if args.experiments is None:
        # a system with per-experiment designs (e.g. turns to both sides) needs all of them
        n_designs = [len(d) for d in system.inputs.values() if isinstance(d, (list, tuple))]
        args.experiments = max(n_designs, default=1)
    rows = args.samples * args.experiments
    cols = log_columns(system)
    fmt = "csv" if out.suffix.lower() == ".csv" else "parquet"
    limits.check(
        "simulate", f"{args.experiments} experiment(s) × {args.samples} samples × {cols} columns",
        memory=limits.table_memory(peak_rows(args.samples, args.experiments), cols)
        + 400.0 * args.experiments,
        seconds=limits.simulation_seconds(rows, system.spec.n_states)
        + limits.write_seconds(rows, cols, fmt),
        disk=limits.file_bytes(rows, cols, fmt) + 200.0 * args.experiments, disk_path=out)
    spec_path = _spec_path_for(out)
    command = "vesselid " + " ".join(sys.argv[1:]) if sys.argv else ""
    n = simulate_to_file(system, args.samples, args.experiments, args.seed, out,
                         metadata={"command": command},
                         extra={spec_path: system.identification_spec().to_toml()})
    print(f"wrote {out} ({n} rows, {args.experiments} experiment(s)) and model spec "
          f"{spec_path}")
    if args.raw:
        from vesselid.data.logs import TrialLog
        from vesselid.data.rawexport import write_raw_streams

        log = TrialLog.load(out)  # the log just written (simulation streams it to disk)
        manifest = write_raw_streams(log, args.raw, seed=args.seed)
        n = sum(manifest["sentences"].values())
        print(f"wrote raw sensor streams to {args.raw} ({n} NMEA sentences, actuators.csv, "
              f"ingest.toml, {manifest['files'][-1]})")
        print(f"next: vesselid ingest {args.raw} --dt {log.spec.dt} --out trial.csv")
    print(f"next: vesselid identify {out} --model {spec_path}")
    return 0


def _check_raw_request(raw: str, system: Any) -> None:
    """``simulate --raw DIR``: a surface vessel, and a directory that can be made."""
    states = list(system.spec.states)
    missing = [c for c in ("u", "v", "r") if c not in states]
    if missing:
        raise CLIError(f"--raw needs a surface vessel with surge u, sway v and yaw rate r "
                       f"(e.g. --system cybership2); {system.spec.name!r} has states {states}")
    check_raw_dir(raw)


def _check_cov(cov: str | None) -> None:
    from vesselid.identify import registry as _names

    if cov is not None and cov not in _names.COV_TYPES:
        raise CLIError(f"argument --cov: invalid choice {cov!r} "
                       f"(choose from {', '.join(_names.COV_TYPES)})")


def _fraction(text: str) -> float:
    """A number in [0, 1) (argparse type)."""
    try:
        value = float(text)
    except ValueError:
        value = float("nan")
    if not (math.isfinite(value) and 0 <= value < 1):
        raise argparse.ArgumentTypeError(f"expected a fraction in [0, 1), got {text!r}")
    return value


def cmd_identify(args: argparse.Namespace) -> int:
    for option, target in (("--json", args.json), ("--export", getattr(args, "export", None))):
        if target and target != "-":  # fail before the work (and the imports), not after it
            check_output_file(option, target)
    if getattr(args, "stream", False):
        return _identify_stream(args)
    from vesselid.identify import registry as _names

    # static names: an argument error loads neither the registry nor the compiled kernels
    if args.method is None:
        args.method = _names.DEFAULT_METHOD
    if args.method not in _names.names():
        raise CLIError(f"argument --method: invalid choice {args.method!r} "
                       f"(choose from {', '.join(_names.names())})")
    _check_cov(args.cov)
    from vesselid.core import memory as _memory

    # freed temporaries leave the resident memory, and a Parquet log's columns hold no
    # more than themselves (vesselid.core.memory; Arrow's pool is chosen on its import)
    _memory.unmap_large_blocks()
    _memory.arrow_system_allocator()
    # and the code pages of Arrow (once the log is read) and of LLVM (once numba has
    # loaded the kernels) leave it between the steps of the fit
    _memory.release_library_code()
    from vesselid.core import limits
    from vesselid.data.logs import TrialLog, estimate_shape
    from vesselid.identify import identify
    from vesselid.model.spec import ModelSpec

    spec = ModelSpec.load(args.model) if args.model else None
    rows, cols = estimate_shape(args.log)
    limits.check("identify", f"{args.log} (~{rows:.3g} rows × {cols} columns)",
                 memory=limits.read_memory(rows, cols), seconds=limits.read_seconds(rows, cols),
                 memory_hint=limits.STREAM_HINT)
    log = TrialLog.load(args.log, spec=spec, truth=False)  # no estimator reads the truth
    if spec is None and log.spec is None:
        raise CLIError(f"{args.log} carries no model spec; pass --model SPEC.toml")
    from vesselid.data.sampling import check_sampling

    check_sampling(log, (spec or log.spec).dt, tolerance=args.dt_tolerance)
    dt_tolerance = args.dt_tolerance
    if "time" in log.data.columns and "time" not in (spec or log.spec).measured_columns:
        # the time column is validated and the sampling checked: the fit reads the rows as
        # the samples at dt and needs the column no more (on a long log it is not held
        # through the fit; the other columns are shared, not copied)
        log = TrialLog(log.data.drop(columns="time"), log.metadata)
        dt_tolerance = None
    from vesselid.errors import EstimationFailedError

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            result = identify(log, spec, method=args.method, combine=args.combine,
                              target=args.target, cov_type=args.cov, max_iter=args.max_iter,
                              sensor_noise=_sensor_noise(getattr(args, "sensor_noise", None)),
                              noise_order=getattr(args, "noise_order", None),
                              dt_tolerance=dt_tolerance)
        except EstimationFailedError as exc:  # valid input, no finite estimate: exit 3
            msg = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
            print(f"vesselid identify: error: no usable model: {msg}", file=sys.stderr)
            return EXIT_NO_MODEL
    return _report_identify(args, result, caught)


def _sensor_noise(text: str | None) -> dict[str, float] | bool | None:
    """``--sensor-noise``: ``None`` (the log's metadata), ``none`` (False: no correction)
    or ``STATE=STD,...``."""
    if text is None:
        return None
    if text.strip().lower() == "none":
        return False
    out: dict[str, float] = {}
    for item in text.split(","):
        name, sep, val = item.partition("=")
        try:
            std = float(val)
        except ValueError:
            std = float("nan")
        if not sep or not name.strip() or not math.isfinite(std) or std < 0:
            raise CLIError(f"argument --sensor-noise: expected STATE=STD,... with STD >= 0 "
                           f"(or 'none'), got {item!r}")
        out[name.strip()] = std
    return out


def _identify_stream(args: argparse.Namespace) -> int:
    """``identify --stream``: Parquet logs read one experiment at a time (bounded memory)."""
    from vesselid.identify import registry as _names

    if args.method is None:
        args.method = _names.DEFAULT_STREAM_METHOD
    if args.method not in _names.STREAM_METHODS:
        raise CLIError(f"argument --method: {args.method!r} cannot be streamed (its estimate is "
                       f"not a sum over experiments); with --stream choose from "
                       f"{', '.join(_names.STREAM_METHODS)}")
    _check_cov(args.cov)
    from vesselid.core import limits
    from vesselid.identify.streaming import ParquetExperiments, identify_stream
    from vesselid.model.spec import ModelSpec

    if args.target != "measured":
        raise CLIError("--target aggregated is not available with --stream")
    spec = ModelSpec.load(args.model) if args.model else None
    source = ParquetExperiments(args.log)
    _check_stream_sampling(source, spec, args.dt_tolerance)
    # memory: the largest experiment (with its regressors and instruments); time: one pass
    biggest = max(source.rows, default=0)
    limits.check("identify", f"{args.log} (largest experiment ~{biggest:.3g} rows × "
                 f"{source.columns} columns, streamed)",
                 memory=limits.read_memory(biggest, source.columns),
                 seconds=limits.read_seconds(sum(source.rows), source.columns))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        result = identify_stream(source, spec, method=args.method, combine=args.combine,
                                 cov_type=args.cov, max_iter=args.max_iter)
    return _report_identify(args, result, caught)


def _check_stream_sampling(source: Any, spec: Any, tolerance: float) -> None:
    """The sampling check of ``identify --stream``: only the time and experiment columns
    of each file are read."""
    import pyarrow.parquet as pq

    from vesselid.data.sampling import check_sampling

    the_spec = spec or source.spec
    dt = the_spec.dt if the_spec is not None else None
    for f in source.files:
        names = pq.read_schema(f).names
        if "time" in names:
            cols = [c for c in ("experiment", "time") if c in names]
            check_sampling(pq.read_table(f, columns=cols).to_pandas(), dt, tolerance=tolerance)


def _report_identify(args: argparse.Namespace, result: Any, caught: list) -> int:
    wrote = write_json(args.json, result.to_json(indent=2))
    if args.json != "-":
        print(result.summary())
        if wrote:
            print(f"\nwrote {args.json}")
    status = getattr(result, "status", "ok")
    unusable = status in UNUSABLE_STATUS
    if getattr(args, "export", None):
        if unusable:
            print(f"not written: {args.export} (the model is not usable: {status})",
                  file=sys.stderr)
        else:
            path = result.export(args.export, source=str(args.log))
            print(f"wrote {path} (spec with the estimate as theta0, its standard errors and "
                  "covariance)", file=sys.stderr if args.json == "-" else sys.stdout)
    if args.json == "-":  # otherwise the summary already lists the warnings
        for w in caught:
            print(f"warning: {w.message}", file=sys.stderr)
    if unusable:
        print(f"vesselid identify: error: no usable model: {result.status_reason}",
              file=sys.stderr)
        return EXIT_NO_MODEL
    return 0


#: ``vesselid identify``'s exit code when the input is valid but no usable model came out:
#: no finite estimate from any estimator tried, or an estimate that is unstable on the log
#: or has non-finite fit figures (the result is still printed / written with ``--json``,
#: ``status`` says which; ``--export`` is refused). 2 stays bad input.
EXIT_NO_MODEL = 3
#: result statuses that are not a usable model
UNUSABLE_STATUS = ("non-finite", "unstable")


def _command_word(argv: Sequence[str] | None) -> str | None:
    """The subcommand named on the command line (the first non-option word), if any."""
    for arg in argv or ():
        if not arg.startswith("-"):
            return arg
    return None


def build_parser(argv: Sequence[str] | None = None) -> argparse.ArgumentParser:
    """The command-line parser; a lazy plugin's module is imported only if ``argv`` runs it.

    Without ``argv`` every plugin module is imported (complete parser, e.g. for docs).
    """

    parser = _Parser(
        prog="vesselid",
        description="Simulate marine vessels under current, wind and sensor noise, and identify "
                    "their second-order modulus models consistently (Ljungberg & Enqvist).",
    )
    parser.add_argument("--version", action="version", version=f"vesselid {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")

    p = sub.add_parser("simulate", help="simulate a catalogue system and write a trial log",
                       description="Simulate a catalogue system; writes the trial log and the "
                                   "matching model spec (<out stem>.toml).")
    p.add_argument("--system", default="heave",
                   help="catalogue name: heave (paper §6), siso (§5) or a vessel "
                        "(vesselid.plant.catalogue: cybership2, ...)")
    p.add_argument("--samples", type=int_at_least(2), default=10000,
                   help="samples per experiment")
    p.add_argument("--experiments", type=int_at_least(1), default=None,
                   help="independent experiments (default 1; cybership2: 2, a turn to each side)")
    p.add_argument("--current-mean", type=finite_float, default=None,
                   help="mean current (heave: w̄c; default 0)")
    p.add_argument("--current-sensor", action="store_true",
                   help="log a current-meter reading and use the aggregated-state predictor")
    p.add_argument("--seed", type=int_at_least(0), default=0)
    p.add_argument("--out", required=True, help="trial.csv or trial.parquet")
    p.add_argument("--raw", metavar="DIR",
                   help="also write the raw sensor streams (NMEA 0183, actuator CSV, spec) to DIR "
                        "(surface vessels: cybership2)")
    p.set_defaults(func=cmd_simulate)

    wanted = _command_word(argv) if argv is not None else None
    # The estimator registry loads compiled kernels: only a help text needs it up front. Otherwise
    # --method/--cov are checked against the registry when identify runs (exit 2 with the choices).
    full = argv is None or (wanted == "identify" and ("-h" in argv or "--help" in argv))
    method_opts: dict[str, Any] = {"default": None,
                                   "help": "estimator (default: the package default)"}
    cov_opts: dict[str, Any] = {"default": None, "help": "covariance estimator"}
    if full:
        from vesselid.identify import covariance_api
        from vesselid.identify.registry import DEFAULT_METHOD, ESTIMATORS, method_labels

        method_opts = {"default": DEFAULT_METHOD, "choices": list(ESTIMATORS),
                       "help": f"estimator (default {DEFAULT_METHOD}): "
                       + "; ".join(f"{k}: {v}" for k, v in method_labels("long").items())}
        cov_opts = {"default": None, "choices": covariance_api.available(),
                    "help": f"covariance estimator (default {covariance_api.default_cov_type()})"}
    p = sub.add_parser("identify", help="identify a model from a trial log",
                       description="Identify θ from a trial log (CSV or Parquet).")
    p.add_argument("log", help="trial log (.csv with optional .json sidecar, or .parquet); "
                               "with --stream a Parquet log or a directory of them")
    p.add_argument("--model", help="model spec TOML (default: the spec stored in the log)")
    p.add_argument("--method", **method_opts)
    p.add_argument("--cov", **cov_opts)
    p.add_argument("--target", default="measured", choices=["measured", "aggregated"],
                   help="regression target with a current sensor: y1(k) as in eq. (10) "
                        "(default) or the aggregated ỹ(k) (reproduce --table 2 uses it)")
    p.add_argument("--combine", default="pooled", choices=["pooled", "stacked"],
                   help="multi-experiment equations: pooled normal equations (default) or the "
                        "stacked least-squares form (6)")
    p.add_argument("--max-iter", type=int_at_least(1), default=100)
    p.add_argument("--sensor-noise", metavar="STATE=STD,...|none", default=None,
                   help="std of the white sensor noise on each regressor signal (e.g. "
                        "u=0.005,v=0.005,r=0.002): auto/sriv/gmm correct the square modulus "
                        "regressors for it; default the log's metadata sensor_noise_std "
                        "(written by sea-trial); 'none': no correction")
    p.add_argument("--noise-order", type=int_at_least(1), default=None,
                   help="AR order of the noise-model prefilter of sriv / auto's fallback "
                        "(default 4; a sea trial needs 16, which sea-trial prints; never read "
                        "from the log)")
    p.add_argument("--json", metavar="PATH|-", help="write the result as JSON ('-' = stdout)")
    p.add_argument("--stream", action="store_true",
                   help="logs larger than memory: read the Parquet log(s) one experiment at a "
                        "time (methods ls, iv, iv-zero-mean; default iv-zero-mean)")
    p.add_argument("--export", metavar="MODEL.toml",
                   help="write the identified model (spec with θ̂ and its covariance) for reuse")
    p.add_argument("--dt-tolerance", type=_fraction, default=0.01, metavar="FRACTION",
                   help="relative tolerance of the sampling check: every time step within it "
                        "of the median step, which must equal the spec's dt within it "
                        "(default 0.01; a log that fails: resample it with `ingest --dt`)")
    p.set_defaults(func=cmd_identify)

    modules: list[str] = []
    command_of: dict[str, str] = {}
    for command, (module, help_text, _) in LAZY_COMMANDS.items():
        command_of[module] = command
        if argv is None or command == wanted:
            modules.append(module)
        else:  # listed in the help; never parsed in this run
            sub.add_parser(command, help=help_text, add_help=False)
    for name in dict.fromkeys(modules):
        try:
            module = importlib.import_module(name)
        except ModuleNotFoundError as exc:
            if exc.name != name:
                raise
            continue
        _, help_text, description = LAZY_COMMANDS[command_of[name]]
        module.add_arguments(sub.add_parser(command_of[name], help=help_text,
                                            description=description))
    return parser


def _os_error_text(exc: OSError) -> str:
    """``cannot write 'out/x.csv': Is a directory`` — the reason and the path."""
    reason = exc.strerror or str(exc) or type(exc).__name__
    paths = [p for p in (exc.filename, exc.filename2) if p is not None]
    where = " -> ".join(repr(str(p)) for p in paths)
    return f"{reason}: {where}" if where else reason


def _terminate(signum: int, frame: Any) -> None:
    """SIGTERM: unwind like Ctrl-C so that temporary files are removed."""
    raise SystemExit(128 + signum)


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command line; returns the exit code.

    Called as a program (``argv`` None: the ``vesselid`` script, ``python -m vesselid``),
    the heap is frozen at the end (:func:`gc.freeze`): the interpreter's shutdown then
    does not walk every object of numpy, pandas, numba and matplotlib with its cyclic
    collections — ≈ 0.3–0.4 s of CPU after ``reproduce`` (measured with the imports of
    ``reproduce`` and the figure; the process exits normally, atexit handlers and stream
    flushing included, and the operating system reclaims the memory). In-process callers
    (tests) pass ``argv`` and keep their collector.
    """
    try:
        return _main(argv)
    finally:
        if argv is None:
            gc.freeze()


def _main(argv: Sequence[str] | None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    parser = build_parser(argv)
    try:
        args = parser.parse_args(argv)
    except SystemExit as exc:  # --help, --version, or a usage error (already printed)
        return exc.code if isinstance(exc.code, int) else 2
    if not getattr(args, "func", None):
        parser.print_help()
        return 0
    previous = None
    try:
        previous = signal.signal(signal.SIGTERM, _terminate)
    except ValueError:  # not the main thread
        pass
    try:
        return int(args.func(args) or 0)
    except OSError as exc:
        # unreadable/unwritable files: exit 2 with the reason and the path
        print(f"vesselid {args.command}: error: {_os_error_text(exc)}", file=sys.stderr)
        return 2
    except MemoryError:
        print(f"vesselid {args.command}: error: not enough memory for this request",
              file=sys.stderr)
        return 2
    except VesselidError as exc:
        # bad input: exit 2, one line; any other exception is a bug and propagates with
        # its traceback (exit 1)
        msg = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        print(f"vesselid {args.command}: error: {msg}", file=sys.stderr)
        return 2
    finally:
        if previous is not None:
            signal.signal(signal.SIGTERM, previous)


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
