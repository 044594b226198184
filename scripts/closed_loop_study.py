"""Monte Carlo study of identification in closed loop.

Run ``python scripts/closed_loop_study.py [--design heave|3dof|both] [--runs 200]
[--out docs/closed_loop_study.csv]``.

Designs (every run its own seeds, spawned from ``--seed``):

* ``heave`` — the paper's heave system (§6 noise levels: current, ξ and sensor noise of
  variance 0.01) under a PI loop on the heave velocity (``K_p = 0.3``, ``K_i = 0.05``,
  feed-forward 0.2), random-step reference on [1, 2] held 50–200 samples, white dither of
  std 0.05 on the thrust; 5 000 samples per run.
* ``3dof`` — CyberShip II (catalogue system: Gauss–Markov process noise, sensor noise)
  under three PI velocity loops ``X → u``, ``Y → v``, ``N → r`` (a DP-like velocity
  controller) with random-step references (``u`` on [0.5, 1] m/s, ``v`` and ``r`` on
  ±[0.05, 0.15] with the four sign combinations in four experiments of 3 000 samples, so
  that every modulus term is identifiable) and white dithers (0.3 N, 0.3 N, 0.03 N m).

Per run: least squares and the open-loop IV_E{ζ}=0 (both biased under feedback), and the
closed-loop refined IV ``cl-iv`` with its HAC 95 % intervals (its modulus regressors
corrected for the sensor noise the log declares; ``--no-sensor-noise-correction``: not),
on the closed-loop log — the default intervals (Bartlett HAC with the fixed-b critical
value at each parameter's effective bandwidth ratio) and, on the same fits, those with
the normal critical value (``cov_config`` ``fixed_b=False``); the
feedback test (open-loop warning) on the closed-loop log and on an open-loop log of the
same system (the catalogue input design, same noise).

Reported per estimator and parameter: bias, Monte Carlo sd, ``z = bias / (sd/√R)`` (the
bias in its own Monte Carlo standard errors) and, for ``cl-iv``, the mean HAC SE over the
Monte Carlo sd and the 95 % coverage with its Wilson interval (``coverage_%``: the default
intervals; ``coverage_normal_%``, ``se_normal_over_sd``: the normal critical value); and
the warning rates.
"""

from __future__ import annotations

import argparse
import time
import warnings
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from vesselid.identify import identify
from vesselid.identify.closedloop import feedback_test
from vesselid.identify.data import from_log
from vesselid.identify.estimators import estimate
from vesselid.plant.closedloop import DESIGNS, ClosedLoopDesign

__all__ = ["run_design"]

def _one_run(d: ClosedLoopDesign, ss: np.random.SeedSequence,
             cov_config: dict[str, Any] | None = None, correct: bool = True
             ) -> dict[str, Any]:
    cl_seed, ol_seed = ss.spawn(2)
    log = d.simulate(seed=cl_seed).to_log(aggregate=False)
    data, spec = from_log(log, d.spec, sensor_noise=False)
    out: dict[str, Any] = {}
    for m in ("ls", "iv-zero-mean"):
        out[m] = estimate(data, spec, m).theta[0]
    kw = {} if correct else {"sensor_noise": False}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = identify(log, d.spec, "cl-iv", cov_config=cov_config, **kw)
        normal = identify(log, d.spec, "cl-iv",
                          cov_config={**(cov_config or {}), "fixed_b": False}, **kw)
    out["cl-iv"] = res.params.to_numpy()
    out["cl-iv se"] = res.std_errors.to_numpy()
    out["cl-iv se normal"] = normal.std_errors.to_numpy()
    out["fired closed"] = feedback_test(log, d.spec).rejects
    ol = d.system.simulate(d.samples, n_runs=d.experiments, seed=ol_seed).to_log(aggregate=False)
    out["fired open"] = feedback_test(ol, d.system.identification_spec(aggregate=False)).rejects
    return out


def _wilson(k: int, n: int, z: float = 1.96) -> tuple[float, float]:
    p = k / n
    den = 1 + z**2 / n
    c = (p + z**2 / (2 * n)) / den
    h = z * np.sqrt(p * (1 - p) / n + z**2 / (4 * n**2)) / den
    return c - h, c + h


def _save_runs(path: Path, name: str, names: list[str], theta0: np.ndarray,
               est: dict[str, list], ses: list, ses_normal: list) -> None:
    """Every run's estimates (one row per run and estimator, ``cl-iv se`` its HAC
    standard errors, ``cl-iv se normal`` those with the normal critical value) as CSV,
    for looking at the Monte Carlo distribution itself."""
    from vesselid.core.fileio import atomic_write_text

    frames = []
    for m, vals in [*est.items(), ("cl-iv se", ses), ("cl-iv se normal", ses_normal)]:
        f = pd.DataFrame(np.asarray(vals), columns=names)
        f.insert(0, "run", np.arange(len(vals)))
        f.insert(0, "estimator", m)
        f.insert(0, "design", name)
        frames.append(f)
    f0 = pd.DataFrame([theta0], columns=names)
    f0.insert(0, "run", -1)
    f0.insert(0, "estimator", "theta0")
    f0.insert(0, "design", name)
    atomic_write_text(path, pd.concat([f0, *frames], ignore_index=True)
                      .to_csv(index=False, float_format="%.9g"))


#: The design, instrument options and flags of the runs the worker processes compute
#: (set in the parent before the workers fork).
_WORK: dict[str, Any] = {}


def _worker_start() -> None:
    """A worker process: its BLAS and compiled kernels on one thread (each worker has a
    core of its own), so that the results do not depend on the number of workers."""
    import numba

    from vesselid.identify.linalg import pin_blas_to_one_thread

    pin_blas_to_one_thread()

    numba.set_num_threads(1)


def _worker_run(ss: np.random.SeedSequence) -> dict[str, Any]:
    return _one_run(_WORK["design"], ss, _WORK["cov_config"], _WORK["correct"])


def _runs(d: ClosedLoopDesign, seeds: list[np.random.SeedSequence],
          cov_config: dict[str, Any] | None, correct: bool, workers: int,
          time_limit: float | None) -> Iterator[dict[str, Any]]:
    """Every run's results in the order of ``seeds`` (each run a function of its own
    seed alone, so the same whatever ``workers``): in this process, or the first run here
    (compiling the kernels the forked workers then share) and the rest in ``workers``
    forked processes. With ``time_limit`` (seconds) the study is the runs that finished,
    in order, before it passed."""
    start = time.perf_counter()

    def in_time() -> bool:
        return time_limit is None or time.perf_counter() - start < time_limit

    if workers <= 1 or len(seeds) < 2:
        for ss in seeds:
            if not in_time():
                return
            yield _one_run(d, ss, cov_config, correct)
        return
    import multiprocessing

    yield _one_run(d, seeds[0], cov_config, correct)
    _WORK.update(design=d, cov_config=cov_config, correct=correct)
    with multiprocessing.get_context("fork").Pool(workers, initializer=_worker_start) as pool:
        for out in pool.imap(_worker_run, seeds[1:]):
            if not in_time():
                return  # leaving the block terminates the workers
            yield out


def run_design(name: str, runs: int, seed: int, progress: bool = True,
               cov_config: dict[str, Any] | None = None, samples: int | None = None,
               experiments: int | None = None, save_runs: str | Path | None = None,
               correct: bool = True, workers: int = 1, time_limit: float | None = None
               ) -> tuple[pd.DataFrame, dict[str, float]]:
    opts = {k: v for k, v in (("samples", samples), ("experiments", experiments))
            if v is not None}
    d = DESIGNS[name](**opts)
    theta0 = d.spec.theta0_vector()
    names = [f"{e}: {t}" for e, t in d.spec.param_index]
    seeds = np.random.SeedSequence(seed).spawn(runs)
    est = {m: [] for m in ("ls", "iv-zero-mean", "cl-iv")}
    ses, ses_normal, fired_c, fired_o = [], [], 0, 0
    t0 = time.perf_counter()
    done = 0
    for r, out in enumerate(_runs(d, seeds, cov_config, correct, workers, time_limit)):
        done = r + 1
        for m in est:
            est[m].append(out[m])
        ses.append(out["cl-iv se"])
        ses_normal.append(out["cl-iv se normal"])
        fired_c += bool(out["fired closed"])
        fired_o += bool(out["fired open"])
        if progress and (r + 1) % 20 == 0:
            print(f"  {name}: {r + 1}/{runs} runs ({time.perf_counter() - t0:.0f} s)",
                  flush=True)
    if done < 2:
        raise SystemExit(f"{name}: the time limit passed after {done} finished run(s); a "
                         "study needs at least 2")
    if done < runs:
        print(f"  {name}: time limit reached after {done} of {runs} runs; the table "
              f"reports runs 0-{done - 1}", flush=True)
        runs = done
    if save_runs is not None:
        _save_runs(Path(save_runs), name, names, theta0, est, ses, ses_normal)
    rows = []
    for m, vals in est.items():
        a = np.asarray(vals)
        ok = np.all(np.isfinite(a), axis=1)
        a = a[ok]
        bias = a.mean(axis=0) - theta0
        sd = a.std(axis=0, ddof=1)
        z = bias / (sd / np.sqrt(a.shape[0]))
        for p, pname in enumerate(names):
            row = {"design": name, "samples": d.samples, "experiments": d.experiments,
                   "estimator": m, "parameter": pname, "theta0": theta0[p],
                   "runs": int(a.shape[0]), "bias": bias[p], "mc_sd": sd[p], "z": z[p]}
            if m == "cl-iv":
                for tag, vals_se in (("", ses), ("_normal", ses_normal)):
                    se = np.asarray(vals_se)[ok]
                    cover = np.abs(a[:, p] - theta0[p]) <= 1.96 * se[:, p]
                    k = int(cover.sum())
                    lo, hi = _wilson(k, a.shape[0])
                    row |= {f"se{tag}_over_sd": float(np.mean(se[:, p]) / sd[p]),
                            f"coverage{tag}_%": 100.0 * k / a.shape[0],
                            f"coverage{tag}_lo_%": 100 * lo,
                            f"coverage{tag}_hi_%": 100 * hi}
            rows.append(row)
    rates = {"design": name, "samples": d.samples, "experiments": d.experiments, "runs": runs,
             "warning_closed_loop_%": 100.0 * fired_c / runs,
             "warning_open_loop_%": 100.0 * fired_o / runs}
    return pd.DataFrame(rows), rates


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--design", choices=[*DESIGNS, "both"], default="both")
    ap.add_argument("--runs", type=int, default=200)
    ap.add_argument("--seed", type=int, default=2024)
    ap.add_argument("--bandwidth", default=None,
                    help="HAC bandwidth of cl-iv's intervals: a number of lags or a rule "
                         "('andrews', 'newey-west'); default the package's")
    ap.add_argument("--samples", type=int, default=None,
                    help="samples per experiment (default: the design's)")
    ap.add_argument("--experiments", type=int, default=None,
                    help="experiments per run (default: the design's)")
    ap.add_argument("--out", default="docs/closed_loop_study.csv",
                    help="table of every estimator and parameter (CSV); the warning "
                         "rates go to the same name with _warnings.csv")
    ap.add_argument("--no-sensor-noise-correction", dest="correct", action="store_false",
                    help="cl-iv without the errors-in-variables correction of the modulus "
                         "regressors (identify(..., sensor_noise=False))")
    ap.add_argument("--workers", type=int, default=1,
                    help="processes computing runs at once (the results are the same "
                         "whatever the number)")
    ap.add_argument("--time-limit", type=float, default=None,
                    help="seconds after which the study stops: it is the runs that "
                         "finished, in order, before then (the table's runs column says "
                         "how many)")
    ap.add_argument("--save-runs", default=None,
                    help="also write every run's estimates to this CSV (one design: the "
                         "name as given; both: <stem>_<design>.csv)")
    args = ap.parse_args()
    if args.runs < 2:
        ap.error(f"--runs must be at least 2 (a Monte Carlo sd needs two runs), got {args.runs}")
    if args.workers < 1:
        ap.error(f"--workers must be at least 1, got {args.workers}")
    if args.time_limit is not None and not args.time_limit > 0:
        ap.error(f"--time-limit must be a positive number of seconds, got {args.time_limit}")
    names = list(DESIGNS) if args.design == "both" else [args.design]
    tables, rates = [], []
    for name in names:
        bw = args.bandwidth
        cov_config = None if bw is None else {
            "bandwidth": bw if bw in ("andrews", "newey-west") else float(bw)}
        save = args.save_runs
        if save is not None and len(names) > 1:
            save = Path(save).with_name(f"{Path(save).stem}_{name}.csv")
        table, rate = run_design(name, args.runs, args.seed, cov_config=cov_config,
                                 samples=args.samples, experiments=args.experiments,
                                 save_runs=save, correct=args.correct,
                                 workers=args.workers, time_limit=args.time_limit)
        tables.append(table)
        rates.append(rate)
    table = pd.concat(tables, ignore_index=True)
    rate = pd.DataFrame(rates)
    from vesselid.core.fileio import atomic_write_text

    out = Path(args.out)
    atomic_write_text(out, table.to_csv(index=False, float_format="%.6g"))
    atomic_write_text(out.with_name(out.stem + "_warnings.csv"),
                      rate.to_csv(index=False, float_format="%.4g"))
    pd.set_option("display.width", 160)
    for name in names:
        t = table[table.design == name]
        print(f"\n== {name}: {int(t['runs'].max())} runs ==")
        for m in ("ls", "iv-zero-mean"):
            z = t[t.estimator == m]["z"].abs()
            print(f"{m:13} max |z| = {z.max():.1f} (median {z.median():.1f})")
        c = t[t.estimator == "cl-iv"]
        print(f"cl-iv         max |z| = {c['z'].abs().max():.2f}; coverage "
              f"{c['coverage_%'].min():.1f}-{c['coverage_%'].max():.1f} % (normal critical "
              f"value: {c['coverage_normal_%'].min():.1f}-{c['coverage_normal_%'].max():.1f} "
              f"%); SE/sd {c['se_over_sd'].min():.2f}-{c['se_over_sd'].max():.2f}")
        print(c[["parameter", "theta0", "bias", "mc_sd", "z", "se_over_sd", "coverage_%",
                 "coverage_normal_%"]].to_string(index=False, float_format="%.4g"))
    print()
    print(rate.to_string(index=False))
    print(f"\nwrote {out} and {out.with_name(out.stem + '_warnings.csv')}")


if __name__ == "__main__":
    main()
