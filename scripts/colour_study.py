"""Colour-test study: how often do ``auto``'s tests reject the delayed instruments?

Size (white Table-1 designs) and power (Gauss–Markov sensor noise and current) of

* the difference-in-J (C) test of the delayed instruments (``auto``, level 1 %),
* the colour test (:func:`vesselid.identify.gmm.colour_test`, ``auto``'s, level 5 %):
  unfiltered over noise lags 1–32 (the default) and whitened by an AR(p) noise model
  (``noise_order``, lags p+1 … p+span),
* tests of zero autocorrelation of the equation error at lags ≥ 2 (white disturbances
  make it an MA(1)): the residual at the IV_E{ζ}=0 estimate averaged over lags 2–L as
  an extra instrument of the colour test's GMM (Hansen's J), alone and added to the
  colour test's noise moments, and a Wald test of the sample autocovariances at lags
  2–L with a Bartlett HAC variance,

all on the same runs (heave of §6, 10⁴ samples per run). With ``--coverage`` it also
runs the calibration's Gauss–Markov sensor-noise, random-pulse scenario (its seed) and
prints the default covariance's coverage for ``auto`` as it is, ``auto`` with the whitened
colour test and ``sriv`` in every run.

    python scripts/colour_study.py --runs 1000 --seed 100 [--designs 0 1 5]
    python scripts/colour_study.py --coverage --runs 1000
"""

from __future__ import annotations

import argparse
import sys
import time
import warnings
from pathlib import Path

import numpy as np
import pandas as pd

sys.path.insert(0, str(Path(__file__).resolve().parent))

from estimator_study import DESIGNS, system

from vesselid.identify import get_estimator, gmm
from vesselid.identify._special import chi2_sf
from vesselid.identify.backend import kernels
from vesselid.identify.data import block_starts, from_arrays


def _window_mean(x: np.ndarray, starts: np.ndarray, lo: int, hi: int) -> np.ndarray:
    """Mean of ``x(k − hi) … x(k − lo)`` within each experiment (NaN where the window
    reaches the experiment's first row, whose residual is not defined)."""
    out = np.full_like(x, np.nan)
    for s in range(starts.size - 1):
        a, b = int(starts[s]), int(starts[s + 1])
        c = np.concatenate([[0.0], np.cumsum(np.nan_to_num(x[a:b]))])
        k = np.arange(hi + 1, b - a)
        out[a + k] = (c[k - lo + 1] - c[k - hi]) / (hi - lo + 1)
    return out


def _acf_wald(e: np.ndarray, data, lags: int) -> np.ndarray:
    """Per group: Wald statistic of the mean products ``e(k) e(k − j)``, j = 2 … lags,
    centred per experiment, Bartlett HAC (Newey–West bandwidth); χ²(lags − 1)."""
    stat = np.zeros(data.n_groups)
    for g in range(data.n_groups):
        total, s_mat = 0.0, 0.0
        for s in np.flatnonzero(data.group == g):
            x = e[int(data.starts[s]):int(data.starts[s + 1])]
            x = x[np.isfinite(x)]
            x = x - x.mean()
            m = np.column_stack([x[lags:] * x[lags - j:x.size - j] for j in range(2, lags + 1)])
            bw = gmm.hac_lags(m.shape[0])
            s_g = m.T @ m
            for lag in range(1, bw + 1):
                c = m[lag:].T @ m[:-lag]
                s_g = s_g + (1.0 - lag / (bw + 1.0)) * (c + c.T)
            total, s_mat = total + m.sum(axis=0), s_mat + s_g
        stat[g] = total @ np.linalg.solve(s_mat, total)
    return stat


def pvalues(data, spec, auto_info) -> dict[str, np.ndarray]:
    """p-values of every candidate test for every group of ``data`` (one equation)."""
    theta = auto_info["base"].theta
    phi = kernels.regressor_matrix(data.regsig, data.u, data.starts, spec.codes.factors)
    z_sim, _ = gmm.simulated_instruments(data, spec, theta)
    blocks = block_starts(spec)
    cols = np.arange(int(blocks[0]), int(blocks[1]))
    rg = np.repeat(data.group, np.diff(data.starts))
    resid = data.target[:, 0] - np.einsum("tp,tp->t", phi[:, cols], np.nan_to_num(theta)[rg])
    eta = gmm.noise_instruments(data, spec, phi, z_sim)
    out = {"C (1 %)": auto_info["c_pvalue"], "colour, unfiltered": auto_info["colour_pvalue"]}
    for order, span in ((1, 16), (2, 8), (2, 16), (2, 24), (3, 16), (4, 32)):
        stat, df = gmm.colour_test(data, spec, phi, z_sim, (order + 1, order + span),
                                   theta=theta, noise_order=order)
        out[f"colour, AR({order}) whitened, lags {order + 1}-{order + span}"] = \
            chi2_sf(stat[:, 0], df[0])
    for lo, hi in ((2, 8), (2, 32), (2, 64)):
        eps = _window_mean(resid, data.starts, lo, hi)[:, None]
        for with_eta in (False, True):
            extra = [eta[:, :2], eps] if with_eta else [eps]
            z = np.column_stack([z_sim[:, cols], *extra])
            sol = gmm.solve_equations(data, spec, phi, [(z, z.shape[1] - cols.size)])
            name = f"residual lags {lo}-{hi}" + (" + colour moments" if with_eta else "")
            out[name] = chi2_sf(sol.c[:, 0], sol.c_df[0])
    for lags in (8, 32):
        out[f"autocovariance Wald, lags 2-{lags}"] = chi2_sf(_acf_wald(resid, data, lags),
                                                             lags - 1)
    return out


def rejection_rates(runs: int, seed: int, designs: list[int], batch: int = 100) -> pd.DataFrame:
    names = list(DESIGNS)
    auto = get_estimator("auto")
    cols = {}
    for i in designs:
        pulses, tau = DESIGNS[names[i]]
        sysm = system(pulses, tau)
        spec = sysm.identification_spec(aggregate=False)
        seeds = np.random.SeedSequence(seed + 1000 * i).spawn(runs)
        parts: dict[str, list] = {}
        t0 = time.perf_counter()
        for a in range(0, runs, batch):
            sim = sysm.simulate(10_000, run_seeds=seeds[a:a + batch])
            data = from_arrays(spec, sim.y, sim.u)
            info = auto.estimate_parameters(data, spec).info
            for k, v in pvalues(data, spec, info).items():
                parts.setdefault(k, []).append(np.asarray(v))
        p = {k: np.concatenate(v) for k, v in parts.items()}
        rej = {k: float(np.mean(v < (0.01 if k.startswith("C ") else 0.05)))
               for k, v in p.items()}
        c_rej = p["C (1 %)"] < 0.01
        for k in list(p):
            if k.startswith("colour, AR(2) whitened, lags 3-18"):
                rej["rule: C or unfiltered colour (auto)"] = float(np.mean(
                    c_rej | (p["colour, unfiltered"] < 0.05)))
                rej["rule: C or whitened colour"] = float(np.mean(c_rej | (p[k] < 0.05)))
        cols[names[i]] = pd.Series(rej)
        print(f"{names[i]}: {runs} runs, {time.perf_counter() - t0:.0f} s", flush=True)
    return pd.DataFrame(cols)


def coverage(runs: int, seed: int = 6, scenario: str = "gm-sensor-random") -> pd.DataFrame:
    """Coverage of the default covariance: ``auto`` and ``auto`` with the whitened colour
    test, on the calibration's runs of ``scenario`` (``scripts/calibration.py`` uses seed
    ``i`` for its ``i``-th scenario: 6 for gm-sensor-random)."""
    from vesselid.identify.efficient import InstrumentalGMM
    from vesselid.studies.calibration import (
        _heave_batches,
        _heave_data,
        heave_scenario,
        registry_covariances,
        wilson_interval,
    )

    system_, aggregate, target = heave_scenario(scenario)
    spec = system_.identification_spec(aggregate=aggregate)
    th0 = spec.theta0_vector()
    cov = {"hac": ("hac", {})}
    variants = {"auto": get_estimator("auto"),
                "auto, whitened colour test": InstrumentalGMM(
                    "auto", noise_order=4, refine=1, colour_order=gmm.WHITENED_COLOUR_ORDER,
                    name="auto-whitened"),
                "sriv (every run)": get_estimator("sriv")}
    hits: dict[str, list] = {k: [] for k in variants}
    for sim in _heave_batches(system_, runs, 10_000, seed, 200):
        data = _heave_data(spec, sim, aggregate, target)
        for k, est in variants.items():
            it = est.estimate_parameters(data, spec)
            se = registry_covariances(data, spec, it, est, cov)["hac"]
            hits[k].append(np.abs(it.theta - th0) / se < 1.959964)
    rows = []
    names = [f"{eq}: {term}" for eq, term in spec.param_index]
    for k, v in hits.items():
        h = np.vstack(v)
        for j, name in enumerate(names):
            lo, hi = wilson_interval(int(h[:, j].sum()), h.shape[0])
            rows.append({"estimator": k, "parameter": name, "runs": h.shape[0],
                         "coverage": h[:, j].mean(), "wilson_low": lo, "wilson_high": hi})
    return pd.DataFrame(rows)


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=400)
    ap.add_argument("--seed", type=int, default=100)
    ap.add_argument("--designs", nargs="*", type=int, default=[0, 1, 5, 4, 3],
                    help="indices into scripts/estimator_study.py's design list")
    ap.add_argument("--coverage", action="store_true",
                    help="coverage on the calibration's GM sensor-noise random-pulse runs")
    args = ap.parse_args(argv)
    warnings.simplefilter("ignore")
    with pd.option_context("display.width", 200, "display.max_colwidth", 60):
        if args.coverage:
            print(coverage(args.runs).round(4).to_string(index=False))
            return
        print(rejection_rates(args.runs, args.seed, args.designs).round(4).to_string())


if __name__ == "__main__":
    main()
