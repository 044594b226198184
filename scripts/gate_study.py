"""Which gate should keep ``auto`` off the delayed instruments where its tests miss?

``auto`` keeps the delayed measurements as instruments (``combined``) where neither the
C test of the delayed instruments nor the colour test rejects white disturbances. Under
coloured sensor noise both tests miss some logs, and there the delayed instruments bias
the estimate. This study runs ``auto`` without its colour guard (``colour_guard=0``)
once per log and keeps, per run, its choice, estimate, reported SE and test p-values;
the combined and IV_{E{ζ}=0} estimates with their full HAC covariances; the estimate
and SE of ``auto``'s SRIV fallback; and (``--pem-below``) the estimate and SE of its
likelihood fallback on the combined runs whose colour-test p-value is below that. Every
gate is then evaluated on the same estimates: the colour guards ``--guards`` (the
combined runs with a colour-test p-value below the guard move to SRIV or to the
likelihood fallback with every candidate model; ``auto``'s default is 0.2 with the
sensor-noise model alone, ``vesselid.identify.efficient._guard_band_fits``, which the
calibration table measures), a Hausman test
(``d = θ̂_c − θ̂_s``, ``H = d' (V_s − V_c)⁺ d``, χ²(rank): under white disturbances the
combined estimate is the efficient one) and SRIV on every combined run::

    nice -n 10 python scripts/gate_study.py calibration:gm-sensor-random --runs 1000 \
        --pem-below 0.3 --md docs/gate_study_gm_sensor_random.md
    nice -n 10 python scripts/gate_study.py calibration:table1-alternating --runs 1000 \
        --pem-below 0.3 --md docs/gate_study_table1_alternating.md
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np
import pandas as pd
from scipy import stats

sys.path.insert(0, str(Path(__file__).resolve().parent))

from pem_covariance_study import _logs  # the scripts folder, on the path above
from robustness_study import wilson

from vesselid.core.fileio import atomic_write_text

Z95 = 1.959964
#: Colour-test guards evaluated by default.
GUARDS = [0.1, 0.15, 0.2, 0.3]


def _full_covariances(data, spec, it, est) -> np.ndarray:
    """Full HAC covariances (G, P, P) of an estimator's batched estimates (one-state
    models), computed as :func:`vesselid.studies.calibration.registry_covariances`
    computes their standard errors."""
    from vesselid.identify import kernels
    from vesselid.identify.covariance import DEFAULT_COV_TYPE, get_covariance_estimator
    from vesselid.studies.calibration import one_group

    ce = get_covariance_estimator(DEFAULT_COV_TYPE)
    n, p = data.n_groups, spec.n_params
    out = np.full((n, p, p), np.nan)
    for g in range(n):
        if not np.all(np.isfinite(it.theta[g])):
            continue
        sub, it_g = one_group(data, it, g)
        phi = kernels.regressor_matrix(sub.regsig, sub.u, sub.starts, spec.codes.factors)
        designs = est.equation_designs(sub, spec, it_g, phi, "pooled")
        if len(designs) < spec.n_states:
            it_g = est.estimate_parameters(sub, spec, combine="pooled", keep_history=True)
            designs = est.equation_designs(sub, spec, it_g, phi, "pooled")
        d = designs[0]
        res = ce.estimate(d.z, d.phi, d.resid, d.starts, weight=d.weight,
                          zero_mean=d.zero_mean, combine="pooled", skip_first=False,
                          weight_jacobian=d.weight_jacobian, fixed_b_square=d.fixed_b)
        out[g] = res.cov
    return out


def hausman(d: np.ndarray, v: np.ndarray) -> tuple[float, int]:
    """``d' V⁺ d`` over the eigen-directions of ``V`` above 1e-8 of its largest
    eigenvalue, and their number."""
    w, q = np.linalg.eigh(0.5 * (v + v.T))
    keep = w > 1e-8 * max(w.max(), 0.0)
    if not keep.any():
        return float("nan"), 0
    proj = q[:, keep].T @ d
    return float(np.sum(proj * proj / w[keep])), int(keep.sum())


def chunk(design: str, seed: int, start: int, stop: int, samples: int,
          pem_below: float = 0.0) -> list[dict]:
    """Per run of ``range(start, stop)`` and parameter: ``auto``'s choice, estimate,
    reported SE and p-values; the combined, IV_{E{ζ}=0} and SRIV estimates and SEs; the
    Hausman statistic; and, on the runs ``auto`` kept combined whose colour-test p-value
    is below ``pem_below``, the estimate and SE of ``auto``'s likelihood fallback."""
    from vesselid.identify import estimate, from_arrays, get_estimator, pem
    from vesselid.identify.covariance import DEFAULT_COV_TYPE
    from vesselid.identify.efficient import InstrumentalGMM, _subset
    from vesselid.identify.registry import entry
    from vesselid.studies.calibration import registry_covariances

    spec, y, u = _logs(design, seed, range(start, stop), samples)
    data = from_arrays(spec, y, u)
    # auto without the colour guard: the guards are evaluated on its combined runs
    auto = InstrumentalGMM(**{**entry("auto").options, "colour_guard": 0.0})
    it = auto.estimate_parameters(data, spec)
    base = it.info["base"]
    se_auto = registry_covariances(data, spec, it, "auto", {"d": (DEFAULT_COV_TYPE, {})},
                                   estimator=auto)["d"]
    gmm_est = get_estimator("gmm")
    it_c = gmm_est.estimate_parameters(data, spec, base=base)
    cov_c = _full_covariances(data, spec, it_c, gmm_est)
    ivz = get_estimator("iv-zero-mean")
    base_it = estimate(data, spec, "iv-zero-mean", combine="pooled")
    cov_s = _full_covariances(data, spec, base_it, ivz)
    sriv = get_estimator("sriv")
    it_r = sriv.estimate_parameters(data, spec, base=base)
    se_r = registry_covariances(data, spec, it_r, "sriv", {"d": (DEFAULT_COV_TYPE, {})},
                                estimator=sriv)["d"]
    used = it.info["instrument_set"]
    model = it.info.get("pem_model", np.full(data.n_groups, "", dtype=object))
    theta0 = np.asarray(spec.theta0_vector(), dtype=float)
    band = (np.asarray(used) == "combined") & (np.asarray(it.info["colour_pvalue"]) < pem_below)
    pem_th = np.full((data.n_groups, spec.n_params), np.nan)
    pem_se = np.full((data.n_groups, spec.n_params), np.nan)
    if band.any() and pem.supports(spec, data):
        res = pem.fit_groups(_subset(data, band), spec, base.theta[band], joint=True,
                             boundary=auto.pem_boundary)
        ok = res["converged"]
        idx = np.flatnonzero(band)
        pem_th[idx[ok]] = res["theta"][ok]
        cov = res[pem.COVARIANCE_KEYS[auto.pem_cov]]
        pem_se[idx[ok]] = np.sqrt(np.abs(np.diagonal(cov, axis1=1, axis2=2)))[ok]
    names = [f"{eq}: {term}" for eq, term in spec.param_index]
    rows = []
    for g in range(data.n_groups):
        choice = "pem-" + str(model[g]) if used[g] == "pem" else (
            {"simulated": "sriv"}.get(str(used[g]), str(used[g])))
        d = it_c.theta[g] - base_it.theta[g]
        h, df = hausman(d, cov_s[g] - cov_c[g])
        for j, p in enumerate(names):
            rows.append({
                "design": design, "run": start + g, "choice": choice, "param": p,
                "theta0": theta0[j], "estimate": it.theta[g, j], "se_reported": se_auto[g, j],
                "c_p": float(it.info["c_pvalue"][g]),
                "colour_p": float(it.info["colour_pvalue"][g]),
                "hausman": h, "hausman_df": df,
                "hausman_p": float(stats.chi2.sf(h, df)) if df else float("nan"),
                "z_param": float(d[j] / np.sqrt(max(cov_s[g, j, j] - cov_c[g, j, j], 1e-300))),
                "combined_estimate": it_c.theta[g, j],
                "combined_se": float(np.sqrt(cov_c[g, j, j])),
                "ivz_estimate": base_it.theta[g, j], "ivz_se": float(np.sqrt(cov_s[g, j, j])),
                "sriv_estimate": it_r.theta[g, j], "sriv_se": se_r[g, j],
                "pem_estimate": pem_th[g, j], "pem_se": pem_se[g, j]})
    return rows


def _rules(df: pd.DataFrame, guards: tuple[float, ...]):
    """``(rule, flag, alternative)``: the runs ``auto`` (without the guard) kept combined
    that a rule moves to another estimate (``sriv`` or ``pem``)."""
    comb = (df["choice"] == "combined").to_numpy()
    yield "no guard (combined kept)", np.zeros(len(df), bool), "sriv"
    for g in guards:
        yield f"colour p < {g:g}: SRIV", comb & (df["colour_p"] < g).to_numpy(), "sriv"
        if "pem_estimate" in df and df["pem_estimate"].notna().any():
            yield (f"colour p < {g:g}: likelihood fallback", comb
                   & (df["colour_p"] < g).to_numpy() & df["pem_estimate"].notna().to_numpy(),
                   "pem")
    yield "Hausman p < 0.05: SRIV", comb & (df["hausman_p"] < 0.05).to_numpy(), "sriv"
    yield "every combined run: SRIV", comb, "sriv"


def evaluate(df: pd.DataFrame, guards: tuple[float, ...]) -> pd.DataFrame:
    """Per rule and parameter: coverage with Wilson interval, Monte Carlo sd and median
    relative error, and how many runs the rule moves off the combined estimate."""
    out = []
    for rule, flag, alt in _rules(df, guards):
        est = np.where(flag, df[alt + "_estimate"], df["estimate"])
        se = np.where(flag, df[alt + "_se"], df["se_reported"])
        err = est - df["theta0"].to_numpy()
        for p in df["param"].unique():
            m = (df["param"] == p).to_numpy()
            e, s = err[m], se[m]
            hit = int(np.sum(np.abs(e) <= Z95 * s))
            r = int(m.sum())
            lo, hi = wilson(hit, r)
            out.append({"rule": rule, "param": p, "runs": r, "moved": int(flag[m].sum()),
                        "coverage": hit / r, "wilson_lo": lo, "wilson_hi": hi,
                        "mc_sd": float(np.std(e, ddof=1)),
                        "median_abs_rel_err": float(np.median(
                            np.abs(e / df["theta0"].to_numpy()[m])))})
    return pd.DataFrame(out)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("design", help="robustness:<design> or calibration:<scenario>")
    ap.add_argument("--runs", type=int, default=1000)
    ap.add_argument("--samples", type=int, default=10_000)
    ap.add_argument("--seed", type=int, default=None)
    ap.add_argument("--chunk", type=int, default=25)
    ap.add_argument("--guards", type=float, nargs="+", default=GUARDS,
                    help="colour-test guards to evaluate")
    ap.add_argument("--pem-below", type=float, default=0.0,
                    help="also fit auto's likelihood fallback on the combined runs whose "
                         "colour-test p-value is below this")
    ap.add_argument("--raw", type=Path, default=None)
    ap.add_argument("--from-raw", type=Path, default=None)
    ap.add_argument("--out", type=Path, default=None, help="write the table as CSV")
    ap.add_argument("--md", type=Path, default=None,
                    help="write the table as a Markdown page (the command line on it)")
    args = ap.parse_args(argv)
    kind = args.design.partition(":")[0]
    seed = args.seed if args.seed is not None else (2024 if kind == "robustness" else 0)
    if args.from_raw is not None:
        df = pd.read_csv(args.from_raw)
    else:
        t0 = time.perf_counter()
        rows: list[dict] = []
        for a in range(0, args.runs, args.chunk):
            b = min(a + args.chunk, args.runs)
            rows += chunk(args.design, seed, a, b, args.samples, args.pem_below)
            print(f"{b} runs: {time.perf_counter() - t0:.0f} s", file=sys.stderr, flush=True)
        df = pd.DataFrame(rows)
        if args.raw is not None:
            atomic_write_text(args.raw, df.to_csv(index=False))
    res = evaluate(df, tuple(args.guards))
    pd.set_option("display.width", 200)
    one = df.drop_duplicates("run")
    print(f"{args.design}: {one.shape[0]} runs, seed {seed}; choices "
          f"{one['choice'].value_counts().to_dict()}")
    print(res.to_string(index=False, float_format=lambda x: f"{x:.4g}"))
    if args.md is not None:
        cmd = (f"python scripts/gate_study.py {args.design} --runs {one.shape[0]} --seed {seed}"
               f" --samples {args.samples}"
               + (f" --pem-below {args.pem_below:g}" if args.pem_below else "")
               + ("" if args.guards == GUARDS else
                  " --guards " + " ".join(f"{g:g}" for g in args.guards)) + " --md ...")
        atomic_write_text(args.md, markdown(res, args.design, seed, cmd,
                                            one["choice"].value_counts().to_dict()))
    if args.out is not None:
        atomic_write_text(args.out, res.to_csv(index=False, float_format="%.5g"))
    return 0


def markdown(res: pd.DataFrame, design: str, seed: int, cmd: str,
             choices: dict[str, int]) -> str:
    """The rule table as a Markdown page."""
    runs = int(res["runs"].max())
    lines = ["---", "orphan: true", "---", "",
             f"# Gates of the delayed instruments: {design}", "",
             f"{runs} runs, seed {seed}: `{cmd}`. `auto` without the colour guard "
             f"(`colour_guard=0`) chose {', '.join(f'{k} {v}' for k, v in choices.items())}."
             " Each rule moves the runs it flags among those `auto` kept on the combined "
             "(simulated + delayed) instruments to the named estimate (SRIV, or `auto`'s "
             "likelihood fallback from the same start); every other run keeps `auto`'s "
             "estimate and reported SE. `colour p < g`: the colour test's p-value below "
             "the guard g (`colour_guard = g`; `auto`'s default is 0.2 with the likelihood "
             "fallback, and SRIV where that fit's sandwich standard errors exceed its "
             "inverse-Fisher ones more than 1.5 times, `guard_misfit`, which the rows here "
             "do not apply); `Hausman`: the combined against the IV_E{ζ}=0 estimate, "
             "`d' (V_s − V_c)⁺ d`, χ²(3).", "",
             "| rule | parameter | moved | coverage [Wilson 95 %] | MC sd | "
             "median rel. err |", "|---|---|---|---|---|---|"]
    for _, r in res.iterrows():
        param = r.param.replace("|", "\\|")  # (w*|w| inside a table cell)
        lines.append(f"| {r.rule} | {param} | {r.moved} | {100 * r.coverage:.1f} % "
                     f"[{100 * r.wilson_lo:.1f}, {100 * r.wilson_hi:.1f}] | {r.mc_sd:.5f} | "
                     f"{r.median_abs_rel_err:.4f} |")
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    sys.exit(main())
