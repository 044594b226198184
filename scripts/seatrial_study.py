"""Sea-trial evidence for CyberShip II: consistency, Monte Carlo, validation, control.

Prints markdown tables and writes ``docs/seatrial_estimates.png`` and
``docs/control_tracking.png``:

(i)   normalized errors for N = 10⁴, 10⁵, 10⁶ samples per experiment (6 experiments) for
      LS, IV and IV with zero-mean instruments (relative predictor: speed log + gyro);
(ii)  which predictor: GNSS target with speed-log / current-meter aggregated regressors
      (Lemma 4.1-like) versus the relative predictor, at N = 10⁵;
(iii) a Monte Carlo of ``--runs`` runs at 6 × ``--samples`` (batched fast path
      ``from_arrays`` + ``estimate``) with mean ± sd of the normalized errors, and the
      estimate-vs-truth figure;
(iv)  free-run NRMSE % on a held-out experiment;
(v)   the control experiment (feedback linearisation from θ0, LS, IV) in
      ``Manoeuvring3DOF-v0`` with current and wind.

Run ``python scripts/seatrial_study.py`` (default < 5 min on 2 cores); ``--quick`` for a
smoke run.
"""

from __future__ import annotations

import argparse
import time
import warnings
from pathlib import Path

import numpy as np
import pandas as pd

from vesselid.control.controllers import run_control_experiment
from vesselid.identify.data import from_arrays
from vesselid.identify.diagnostics import normalized_error
from vesselid.identify.estimators import estimate
from vesselid.plant.vessels import SENSOR_CHANNELS, simulate_cybership2
from vesselid.studies.seatrial import (
    design_sea_trial,
    markdown_table,
    normalized_errors,
    run_pipeline,
    seatrial_spec,
    simulate_sea_trial,
)

DOCS = Path(__file__).resolve().parents[1] / "docs"
METHODS = ("ls", "iv", "iv-zero-mean")
_SIM = dict(current_speed=0.05, current_direction=np.radians(30.0), current_variation=0.005,
            wind_speed=1.0, wind_direction=np.radians(-60.0), wind_gust=0.1,
            force_noise=(0.02, 0.02, 0.01))


def _disturbances():
    from vesselid.studies.seatrial import _disturbances as make

    return make(_SIM["current_speed"], _SIM["current_direction"], _SIM["wind_speed"],
                _SIM["wind_direction"], _SIM["current_variation"], _SIM["wind_gust"],
                _SIM["force_noise"])


def simulate_arrays(design, seeds: list[np.random.SeedSequence]):
    """Simulate every experiment of ``design`` for each seed, one experiment at a time
    (bounded memory); returns ``y`` (speed log u, v and gyro r) and ``τ``, both
    ``(len(seeds)·N_E, N, 3)``, groups of N_E consecutive experiments."""
    idx = [SENSOR_CHANNELS.index(c) for c in ("u_log", "v_log", "r")]
    inputs = design.warmup_inputs()
    n_e, n = design.n_experiments, design.n_samples
    y = np.empty((len(seeds) * n_e, n, 3))
    tau = np.empty_like(y)
    dist = _disturbances()
    for g, ss in enumerate(seeds):
        per_exp = ss.spawn(n_e)
        batch = max(1, min(n_e, int(4e6 // inputs.shape[1])))
        for e0 in range(0, n_e, batch):
            e1 = min(n_e, e0 + batch)
            sim = simulate_cybership2(inputs[e0:e1], run_seeds=per_exp[e0:e1], dt=design.dt,
                                      disturbances=dist)
            y[g * n_e + e0:g * n_e + e1] = sim.sensors[:, design.warmup:, idx]
            tau[g * n_e + e0:g * n_e + e1] = sim.tau[:, design.warmup:]
            del sim
    return y, tau


def batch_estimates(spec, y, tau, n_e: int) -> dict[str, np.ndarray]:
    data = from_arrays(spec, y, tau, experiments_per_group=n_e)
    out = {}
    for m in METHODS:
        it = estimate(data, spec, m)
        out[m] = it.theta
        out[m + "_converged"] = it.converged
    return out


def consistency(sizes, seeds_small: int, seed: int) -> pd.DataFrame:
    spec = seatrial_spec()
    theta0 = spec.theta0_series()
    rows = []
    for n in sizes:
        n_seeds = seeds_small if n <= 100_000 else 1
        design = design_sea_trial(6, n, seed=seed)
        root = np.random.SeedSequence(seed + 1000)
        y, tau = simulate_arrays(design, root.spawn(n_seeds))
        est = batch_estimates(spec, y, tau, 6)
        for m in METHODS:
            err = normalized_error(est[m], theta0.to_numpy())
            rms = np.sqrt(np.nanmean(err**2, axis=0))
            for (eq, term), v in zip(theta0.index, rms, strict=True):
                rows.append({"N": n, "method": m, "param": f"{eq}: {term}", "rms_err": v,
                             "seeds": n_seeds})
        print(f"  N = {n}: done ({n_seeds} seed(s))", flush=True)
    return pd.DataFrame(rows)


def monte_carlo(runs: int, samples: int, seed: int, chunk: int = 10):
    spec = seatrial_spec()
    design = design_sea_trial(6, samples, seed=seed)
    root = np.random.SeedSequence(seed + 2000)
    seeds = root.spawn(runs)
    est = {m: [] for m in METHODS}
    conv = {m: [] for m in METHODS}
    for c in range(0, runs, chunk):
        y, tau = simulate_arrays(design, seeds[c:c + chunk])
        e = batch_estimates(spec, y, tau, 6)
        for m in METHODS:
            est[m].append(e[m])
            conv[m].append(e[m + "_converged"])
    est = {m: np.vstack(v) for m, v in est.items()}
    conv = {m: np.concatenate(v) for m, v in conv.items()}
    return spec, est, conv


def plot_estimates(spec, est: dict[str, np.ndarray], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    theta0 = spec.theta0_vector()
    names = [f"{eq}: {t}" for eq, t in spec.param_index]
    fig, ax = plt.subplots(figsize=(9.0, 4.2))
    x = np.arange(theta0.size)
    for j, (m, col) in enumerate(zip(METHODS, ("C1", "C0", "C2"), strict=True)):
        ratio = est[m] / theta0
        mean, sd = np.nanmean(ratio, axis=0), np.nanstd(ratio, axis=0)
        ax.errorbar(x + (j - 1) * 0.25, np.clip(mean, -2, 4), yerr=sd, fmt="o", ms=3, lw=0.8,
                    color=col, label=f"{m} (mean ± sd)")
    ax.axhline(1.0, color="k", lw=0.8, ls="--")
    ax.set_ylim(-2, 4)
    ax.set_xticks(x)
    ax.set_xticklabels(names, rotation=70, fontsize=7)
    ax.set_ylabel("estimate / truth  θ̂/θ0")
    ax.set_title(f"CyberShip II sea trial, Monte Carlo {est['ls'].shape[0]} runs "
                 "(clipped to [-2, 4])", fontsize="medium")
    ax.legend(fontsize="small", ncol=3, loc="upper left")
    fig.tight_layout()
    fig.savefig(path, dpi=80)
    plt.close(fig)


def predictor_comparison(samples: int, seed: int) -> pd.DataFrame:
    rows = []
    for agg in ("relative", "speed_log", "current_meter", "none"):
        log = simulate_sea_trial(6, samples, seed, aggregate=agg)
        spec = log.spec
        data_rows = {"predictor": agg}
        from vesselid.identify import identify

        for m in ("ls", "iv-zero-mean"):
            try:
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")
                    r = identify(log, spec, method=m)
                err = normalized_errors(r.params, spec.theta0_series())
                data_rows[f"{m} median |err|"] = float(np.median(np.abs(err)))
                data_rows[f"{m} |err| u:X, r:N"] = (f"{abs(err[('u', 'X')]):.3f}, "
                                                    f"{abs(err[('r', 'N')]):.3f}")
                data_rows[f"{m} converged"] = r.converged if m != "ls" else "-"
            except Exception as exc:  # report any failure in the table
                data_rows[f"{m} median |err|"] = float("nan")
                data_rows[f"{m} |err| u:X, r:N"] = type(exc).__name__
                data_rows[f"{m} converged"] = False
        rows.append(data_rows)
    return pd.DataFrame(rows).set_index("predictor")


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--runs", type=int, default=100)
    p.add_argument("--samples", type=int, default=20000)
    p.add_argument("--sizes", type=int, nargs="*", default=[10_000, 100_000, 1_000_000])
    p.add_argument("--seeds", type=int, default=4, help="seeds for N <= 1e5")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--quick", action="store_true")
    args = p.parse_args(argv)
    if args.quick:
        args.runs, args.sizes, args.seeds, args.samples = 10, [10_000, 50_000], 2, 10_000
    DOCS.mkdir(exist_ok=True)
    warnings.simplefilter("ignore")
    t_all = time.perf_counter()

    print("## (i) Consistency trend (6 experiments, relative predictor)\n", flush=True)
    cons = consistency(args.sizes, args.seeds, args.seed)
    piv = cons.pivot_table(index="param", columns=["method", "N"], values="rms_err",
                           sort=False)
    piv.columns = [f"{m} N={n:.0e}" for m, n in piv.columns]
    print("RMS over seeds of the normalized error (θ̂ − θ0)/θ0:\n")
    print(markdown_table(piv, ".3f"))
    med = cons.groupby(["method", "N"])["rms_err"].median().unstack("N")
    med.columns = [f"N={n:.0e}" for n in med.columns]
    print("\nMedian over parameters:\n")
    print(markdown_table(med, ".3f"))

    print("\n## (ii) Predictor choice (N = 1e5 per experiment, one seed)\n", flush=True)
    n_cmp = 100_000 if not args.quick else 20_000
    print(markdown_table(predictor_comparison(n_cmp, args.seed), ".3f"))

    print(f"\n## (iii) Monte Carlo: {args.runs} runs x 6 x {args.samples}\n", flush=True)
    t0 = time.perf_counter()
    spec, est, conv = monte_carlo(args.runs, args.samples, args.seed)
    theta0 = spec.theta0_vector()
    tab = pd.DataFrame(index=[f"{eq}: {t}" for eq, t in spec.param_index])
    tab["θ0"] = [f"{v:.3g}" for v in theta0]
    for m in METHODS:
        err = normalized_error(est[m], theta0)
        tab[m] = [f"{a:+.3f} ± {b:.3f}" for a, b in zip(np.nanmean(err, 0), np.nanstd(err, 0),
                                                         strict=True)]
    tab.index.name = "parameter"
    print(markdown_table(tab))
    print("\nconverged: " + ", ".join(f"{m} {100 * conv[m].mean():.0f} %" for m in METHODS)
          + f"; {time.perf_counter() - t0:.1f} s")
    plot_estimates(spec, est, DOCS / "seatrial_estimates.png")
    print(f"\nwrote {DOCS / 'seatrial_estimates.png'}")

    print(f"\n## (iv) Held-out free-run NRMSE % (6 x {args.samples}, seed {args.seed})\n")
    res = run_pipeline(6, args.samples, args.seed)
    print(markdown_table(res.validation, ".2f"))
    print("\n(no disturbance model in the free run: θ0 sets the floor)")

    print("\n## (v) Control experiment (Manoeuvring3DOF-v0, current 0.05 m/s, wind 1 m/s)\n")
    th = res.thetas()
    exp = run_control_experiment({"θ0": th["theta0"], "LS": th["ls"], "IV": th["iv"],
                                  "IV-zero-mean": th["iv-zero-mean"]}, seed=args.seed)
    print(markdown_table(exp.table, ".4f"))
    exp.plot(DOCS / "control_tracking.png")
    print(f"\nwrote {DOCS / 'control_tracking.png'}")
    print(f"\ntotal {time.perf_counter() - t_all:.1f} s")


if __name__ == "__main__":
    main()
