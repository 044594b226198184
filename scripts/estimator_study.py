"""Estimator study: which estimator should be the package default?

Monte Carlo on the heave system of §6, N = 10⁴ samples per run, for

* the white-noise Table-1 designs (alternating pulses — the reproduction design —
  and random pulses), and
* a Gauss–Markov current (``w_c`` first-order Gauss–Markov, mean 0, sd 0.1, time
  constant 25 samples) and Gauss–Markov sensor noise (sd 0.1, time constant 20
  samples), each with both pulse designs,

comparing IV_E{ζ}=0 (the paper), 2SLS with delayed measured regressors and a
constant (``lagged-2sls``; identical to linearmodels ``IV2SLS`` on the same rows,
checked on the first runs of every design), SRIV (refined IV with an AR(4)
noise-model prefilter), GMM with simulated + delayed instruments, the prediction-error
estimator ``pem`` (Gauss–Markov current or sensor noise as filter states), and ``auto``
(GMM unless the C test or the colour test rejects the delayed instruments; then PEM when
both reject, SRIV otherwise).

Prints, per design and estimator: mean, sd, z = mean/SE and median absolute value
of the normalized errors (θ̂ − θ0)/θ0, the sd ratio against lagged 2SLS and the
median-absolute-error ratio of IV_E{ζ}=0 over the estimator, and how often
``auto`` kept the delayed instruments. Writes ``docs/estimator_study.png``.

    python scripts/estimator_study.py --runs 200 [--samples 10000] [--seed 0]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import time
import warnings
from pathlib import Path

import numpy as np
import pandas as pd

from vesselid.identify import get_estimator
from vesselid.identify.data import from_arrays
from vesselid.identify.diagnostics import normalized_error
from vesselid.identify.efficient import InstrumentalGMM
from vesselid.plant.disturbances import GaussMarkov
from vesselid.plant.systems import heave

METHODS = ("iv-zero-mean", "lagged-2sls", "sriv", "gmm", "pem", "auto")
#: Noise-model orders compared for the SRIV prefilter (evidence for the registered order).
VARIANTS = {f"sriv-ar{p}": InstrumentalGMM("simulated", noise_order=p, name=f"sriv-ar{p}")
            for p in (1, 12)}
PARAMS = ("a", "n", "f")
DESIGNS = {
    "white, alternating pulses (Table 1)": ("alternating", None),
    "white, random pulses": ("random", None),
    "Gauss-Markov current τ=25, alternating": ("alternating", 25.0),
    "Gauss-Markov current τ=25, random": ("random", 25.0),
    "Gauss-Markov sensor noise τ=20, alternating": ("alternating", -20.0),
    "Gauss-Markov sensor noise τ=20, random": ("random", -20.0),
}


def system(pulses: str, tau: float | None):
    """Heave of §6; ``tau > 0``: Gauss–Markov current, ``tau < 0``: Gauss–Markov sensor
    noise with time constant ``|tau|`` (same stationary sd 0.1 as the white noise)."""
    s = heave(pulse_design=pulses)
    if tau is not None and tau > 0:
        s = dataclasses.replace(s, current={"w": GaussMarkov(0.0, 0.1, tau)})
    elif tau is not None:
        s = dataclasses.replace(s, sensor_noise={"w": GaussMarkov(0.0, 0.1, -tau)})
    return s


def linearmodels_check(sim, theta: np.ndarray, runs: int = 3) -> float:
    """Largest |difference| between lagged-2sls and linearmodels IV2SLS (constant,
    endogenous w and w|w| at k−1, instruments at k−2 and k−3, exogenous τ(k−1))."""
    from linearmodels.iv import IV2SLS

    worst = 0.0
    for r in range(min(runs, theta.shape[0])):
        y, u = sim.y[r, :, 0], sim.u[r, :, 0]
        k = np.arange(3, y.size)
        d = pd.DataFrame({"y": y[k], "c": 1.0, "tau": u[k - 1], "w1": y[k - 1],
                          "ww1": y[k - 1] * np.abs(y[k - 1]), "w2": y[k - 2],
                          "ww2": y[k - 2] * np.abs(y[k - 2]), "w3": y[k - 3],
                          "ww3": y[k - 3] * np.abs(y[k - 3])})
        fit = IV2SLS(d["y"], d[["c", "tau"]], d[["w1", "ww1"]],
                     d[["w2", "ww2", "w3", "ww3"]]).fit(cov_type="unadjusted")
        ref = fit.params[["w1", "ww1", "tau"]].to_numpy()
        worst = max(worst, float(np.max(np.abs(ref - theta[r]))))
    return worst


def run_design(pulses, tau, runs, samples, seed, batch=50, variants=False):
    sysm = system(pulses, tau)
    spec = sysm.identification_spec(aggregate=False)
    theta0 = spec.theta0_vector()
    seeds = np.random.SeedSequence(seed).spawn(runs)
    methods = {m: get_estimator(m) for m in METHODS} | (VARIANTS if variants else {})
    est = {m: [] for m in methods}
    kept, c_rej, colour_rej, by_pem = [], [], [], []
    lm_diff = None
    timing = dict.fromkeys(methods, 0.0)
    for a in range(0, runs, batch):
        sim = sysm.simulate(samples, run_seeds=seeds[a:a + batch])
        data = from_arrays(spec, sim.y, sim.u)
        for m, estimator in methods.items():
            t0 = time.perf_counter()
            res = estimator.estimate_parameters(data, spec)
            timing[m] += time.perf_counter() - t0
            est[m].append(res.theta)
            if m == "auto":
                kept.append(res.info["instrument_set"] == "combined")
                by_pem.append(res.info["instrument_set"] == "pem")
                c_rej.append(res.info["c_pvalue"] < estimator.alpha)
                colour_rej.append(res.info["colour_pvalue"] < estimator.colour_alpha)
            if m == "lagged-2sls" and lm_diff is None:
                lm_diff = linearmodels_check(sim, res.theta)
    errors = {m: normalized_error(np.vstack(v), theta0) for m, v in est.items()}
    rates = {"kept": float(np.mean(np.concatenate(kept))),
             "pem": float(np.mean(np.concatenate(by_pem))),
             "c_rejected": float(np.mean(np.concatenate(c_rej))),
             "colour_rejected": float(np.mean(np.concatenate(colour_rej)))}
    return errors, rates, lm_diff, timing


def summarize(errors: dict[str, np.ndarray]) -> pd.DataFrame:
    rows = []
    ref_sd = np.nanstd(errors["lagged-2sls"], axis=0, ddof=1)
    ref_mae = np.nanmedian(np.abs(errors["iv-zero-mean"]), axis=0)
    for m, e in errors.items():
        ok = np.all(np.isfinite(e), axis=1)
        e = e[ok]
        mean, sd = e.mean(axis=0), e.std(axis=0, ddof=1)
        mae = np.median(np.abs(e), axis=0)
        for j, p in enumerate(PARAMS):
            rows.append({"method": m, "param": p, "runs": int(ok.sum()),
                         "failed": int((~ok).sum()), "mean": mean[j], "sd": sd[j],
                         "z": mean[j] / (sd[j] / np.sqrt(ok.sum())), "mae": mae[j],
                         "sd_vs_2sls": sd[j] / ref_sd[j], "mae_gain_vs_ivzm": ref_mae[j] / mae[j]})
    return pd.DataFrame(rows)


def figure(tables: dict[str, pd.DataFrame], path: Path) -> None:
    """Mean ± sd of the normalized error of n per estimator and design (bias and spread)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(12, 3.4), layout="constrained")
    FigureCanvasAgg(fig)
    axes = np.atleast_1d(fig.subplots(1, len(tables)))
    for ax, (name, tab) in zip(axes, tables.items(), strict=True):
        sub = tab[tab["param"] == "n"].set_index("method")
        x = np.arange(len(sub))
        ax.errorbar(x, sub["mean"], yerr=sub["sd"], fmt="o", capsize=3)
        ax.axhline(0.0, color="0.5", lw=0.8)
        ax.set_xticks(x, sub.index, rotation=45, ha="right", fontsize=7)
        ax.set_title(name.replace(", ", ",\n", 1), fontsize=7)
        ax.tick_params(labelsize=7)
    axes[0].set_ylabel("(n̂ − n0)/n0: mean ± sd", fontsize=8)
    fig.savefig(path, dpi=80)


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=200)
    parser.add_argument("--samples", type=int, default=10_000)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--designs", nargs="*", type=int, help="indices into the design list")
    parser.add_argument("--json", help="write the tables as JSON")
    parser.add_argument("--variants", action="store_true",
                        help="also SRIV with AR(1) and AR(12) noise models")
    parser.add_argument("--figure", default="docs/estimator_study.png")
    args = parser.parse_args(argv)
    warnings.simplefilter("ignore")
    names = list(DESIGNS)
    chosen = [names[i] for i in args.designs] if args.designs else names
    tables, out = {}, {}
    for name in chosen:
        pulses, tau = DESIGNS[name]
        t0 = time.perf_counter()
        errors, rates, lm, timing = run_design(pulses, tau, args.runs, args.samples,
                                              args.seed + 1000 * names.index(name),
                                              variants=args.variants)
        tab = summarize(errors)
        tables[name] = tab
        print(f"\n== {name}: {args.runs} runs × {args.samples} samples "
              f"({time.perf_counter() - t0:.0f} s); auto kept the delayed instruments in "
              f"{100 * rates['kept']:.1f} % of runs (C test rejected "
              f"{100 * rates['c_rejected']:.1f} %, colour test "
              f"{100 * rates['colour_rejected']:.1f} %) and used PEM in "
              f"{100 * rates['pem']:.1f} %; lagged-2sls vs linearmodels IV2SLS "
              f"max |Δθ| {lm:.1e}")
        with pd.option_context("display.width", 160, "display.float_format", "{:.4f}".format):
            print(tab.to_string(index=False))
        print("seconds per run: " + ", ".join(f"{m} {v / args.runs:.3f}"
                                                for m, v in timing.items()))
        out[name] = {"runs": args.runs, "samples": args.samples, **rates,
                     "linearmodels_max_abs_diff": lm,
                     "table": json.loads(tab.to_json(orient="records"))}
    if args.figure and len(tables) == len(DESIGNS):
        figure(tables, Path(args.figure))
        print(f"wrote {args.figure}")
    if args.json:
        Path(args.json).write_text(json.dumps(out, indent=2) + "\n")
    return out


if __name__ == "__main__":
    main()
