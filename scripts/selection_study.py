"""Monte Carlo study of term selection (``vesselid select``) against FROLS and STLSQ.

For every design, ``--runs`` independent logs are simulated with a current inside the
modulus (white or Gauss–Markov), and on each log:

* ``ivsel`` — :func:`vesselid.selection.select_terms` (IV stepwise selection, HAC Wald
  tests), base model: every equation linear in the states and inputs;
* ``frols`` — SysIdentPy's FROLS (error-reduction ratio, AIC for the number of terms) on
  the same candidate regressors of the same log (``pip install sysidentpy``);
* ``stlsq`` — PySINDy's STLSQ (its default threshold 0.1) on the same candidates
  (``pip install pysindy``).

A method finds the true structure in a run when the set of selected candidates, each
mapped to the candidate that represents it in that log (``|w| = w`` when ``w > 0``),
equals the set of true terms so mapped. Reported per design and method: the share of
runs with the true structure (with its binomial standard error), the share keeping every
true term, the largest share of runs keeping any one zero-coefficient candidate, and for
``ivsel`` the coverage of the 95 % intervals of ``identify(method="iv-zero-mean")`` on the
selected spec (runs with the true structure; HAC covariance). A comparator that is not
installed is skipped. Also printed: each true term's keep rate and its median ``|t|`` in
the IV fit of the true structure (the oracle), which bounds what any test can detect.

    nice -n 10 python scripts/selection_study.py --runs 200 --out docs/selection_study.csv
"""

from __future__ import annotations

import argparse
import math
import sys
import time
import warnings
from pathlib import Path

import numpy as np
import pandas as pd

from vesselid.identify import identify
from vesselid.model.spec import ModelSpec
from vesselid.model.terms import Term
from vesselid.plant.disturbances import Gaussian, GaussMarkov
from vesselid.plant.systems import System, heave
from vesselid.selection import select_terms
from vesselid.selection.engine import library_factors, regressors
from vesselid.selection.library import canonical, resolve_library


# ----------------------------------------------------------------------------- designs
def _heave_system(current) -> System:
    base = heave(xi_mean=0.0, pulse_high=0.5)  # w stays positive (A10)
    return System(spec=base.spec.with_aggregate(None), inputs=base.inputs,
                  current={"w": current}, current_sign={"w": -1},
                  process_noise=base.process_noise, sensor_noise=base.sensor_noise,
                  x0=base.x0)


def _cybership_system(current_u, current_v) -> System:
    from vesselid.plant.vessels.cybership2 import cybership2_system

    base = cybership2_system()
    return System(spec=base.spec, inputs=base.inputs,
                  current={"u": current_u, "v": current_v},
                  process_noise=base.process_noise, sensor_noise=base.sensor_noise,
                  x0=base.x0, model=base.model)


def designs(quick: bool) -> dict:
    """name -> (system, samples per experiment, experiments, library)."""
    dt = 0.1
    n_h = 3000 if quick else 30000
    n_c = 1000 if quick else 5000
    return {
        "heave, white current": (_heave_system(Gaussian(0.0, 0.1)), n_h, 1, "vessel"),
        "heave, Gauss-Markov current": (
            _heave_system(GaussMarkov(0.0, 0.05, 5.0, 1.0, 0.15)), n_h, 1, "vessel"),
        "CyberShip II, white current": (
            _cybership_system(Gaussian(0.0, 0.005), Gaussian(0.0, 0.005)), n_c, 4, "vessel"),
        "CyberShip II, Gauss-Markov current": (
            _cybership_system(GaussMarkov(0.0, 0.002, 1.0, dt, 0.006),
                              GaussMarkov(0.0, 0.002, 1.0, dt, 0.006)), n_c, 4, "vessel"),
    }


def linear_base(spec: ModelSpec) -> ModelSpec:
    """Every equation linear in all states and inputs (the first auxiliary model)."""
    return ModelSpec(spec.name, spec.states, spec.inputs,
                     {s: list(spec.signals) for s in spec.states}, dt=spec.dt)


# ------------------------------------------------------------------------- comparators
def _frols(phi: np.ndarray, y: np.ndarray) -> np.ndarray | None:
    try:
        from sysidentpy.model_structure_selection import FROLS
    except ImportError:
        return None
    from sysidentpy.parameter_estimation import LeastSquares

    p = phi.shape[1]
    model = FROLS(order_selection=True, info_criteria="aic", n_info_values=min(p, 20),
                  ylag=1, xlag=1, estimator=LeastSquares())
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        # information_criterion drops the first max_lag (= 1) target rows: give it one more
        y_lag = np.concatenate([y[:1], y]).reshape(-1, 1)
        ic = np.asarray(model.information_criterion(phi, y_lag), dtype=float)
        n_terms = int(np.nanargmin(ic)) + 1
        _, piv, _ = model.error_reduction_ratio(phi, y_lag, n_terms)
    out = np.zeros(p, dtype=bool)
    out[np.asarray(piv[:n_terms], dtype=int)] = True
    return out


def _stlsq(phi: np.ndarray, y: np.ndarray) -> np.ndarray | None:
    try:
        import pysindy as ps
    except ImportError:
        return None
    opt = ps.STLSQ()  # defaults: threshold 0.1, alpha 0.05
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        opt.fit(phi, y)
    return np.abs(np.asarray(opt.coef_).ravel()) > 0


# --------------------------------------------------------------------------------- run
def one_run(system: System, n: int, k: int, library: str, seed, oracle: bool = True
            ) -> list[dict]:
    sim = system.simulate(n, k, seed=seed)
    log = sim.to_log(aggregate=False)
    truth = system.model if system.model is not None else system.spec
    truth = truth.with_aggregate(None)
    base = linear_base(truth)
    lib = resolve_library(library, base)
    rows: list[dict] = []
    t0 = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = select_terms(log, base, lib, n_boot=0)
    secs = time.perf_counter() - t0
    tab = res.table
    rep = {(r.equation, r.term): (r.represented_by or r.term) for r in tab.itertuples()}
    theta0 = truth.theta0_series()
    true_rep = {s: {rep[(s, str(canonical(t)))] for t in truth.equations[s]}
                for s in truth.states}
    # the candidate regressors of the log for the comparators (rows k -> target k)
    from vesselid.identify.data import from_log

    data, _ = from_log(log, base)
    union, cols = library_factors(lib, base)
    phi = regressors(data, union, base)
    ok = np.isfinite(phi).all(axis=1)
    selections: dict[str, dict[str, set]] = {"ivsel": {s: {rep[(s, t)] for t in res.selected[s]}
                                                       for s in truth.states}}
    for name, fn in (("frols", _frols), ("stlsq", _stlsq)):
        picked: dict[str, set] = {}
        for i, s in enumerate(truth.states):
            sel = fn(phi[ok][:, cols[s]], data.target[ok, i])
            if sel is None:
                picked = {}
                break
            picked[s] = {rep[(s, str(union[cols[s][j]]))] for j in np.flatnonzero(sel)}
        if picked:
            selections[name] = picked
    # oracle: |t| of the true terms in the IV fit of the true structure
    t_oracle = None
    if oracle:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            try:
                fit_true = identify(log, truth, "iv-zero-mean")
                t_oracle = (fit_true.params / np.sqrt(np.diag(fit_true.cov))).abs()
            except Exception:
                t_oracle = None
    for method, picked in selections.items():
        exact = all(picked[s] == true_rep[s] for s in truth.states)
        row = {"method": method, "exact": exact,
               "all_true_kept": all(true_rep[s] <= picked[s] for s in truth.states),
               "seconds": secs if method == "ivsel" else math.nan}
        for s in truth.states:
            for cand in {rep[(s, str(t))] for t in lib[s]}:
                row[f"keep|{s}|{cand}"] = cand in picked[s]
        if method == "ivsel" and exact:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                fit = identify(log, res.spec, "iv-zero-mean")
            se = np.sqrt(np.diag(fit.cov))
            hits = 0
            total = 0
            for (s, term), est, sd in zip(fit.params.index, fit.params.to_numpy(), se,
                                          strict=True):
                true_terms = [t for t in truth.equations[s]
                              if rep[(s, str(canonical(t)))] == term]
                if len(true_terms) != 1:
                    continue
                th0 = float(theta0[(s, str(true_terms[0]))])
                sign = _sign(Term.parse(term), true_terms[0], log, s)
                hits += int(abs(est - sign * th0) <= 1.959964 * sd)
                total += 1
            row["covered"], row["intervals"] = hits, total
        if t_oracle is not None and method == "ivsel":
            for (s, term), tv in t_oracle.items():
                row[f"oracle_t|{s}|{term}"] = float(tv)
        rows.append(row)
    return rows


def _sign(chosen: Term, true: Term, log, state: str) -> float:
    """+1 or −1: the representative equals ± the true term on this log."""
    if str(canonical(chosen)) == str(canonical(true)):
        return 1.0
    spec = ModelSpec("s", log.spec.states, log.spec.inputs, {s: [chosen, true] if s == state
                                                              else [Term.parse(s)]
                                                              for s in log.spec.states})
    from vesselid.identify.data import from_log

    data, _ = from_log(log, spec)
    phi = regressors(data, [chosen, true], spec)
    ok = np.isfinite(phi).all(axis=1)
    return float(np.sign(np.sum(phi[ok, 0] * phi[ok, 1])))


def summarise(df: pd.DataFrame) -> pd.DataFrame:
    out = []
    for (design, method), g in df.groupby(["design", "method"], sort=False):
        n = len(g)
        p = g["exact"].mean()
        keep_cols = [c for c in g.columns if c.startswith("keep|") and g[c].notna().any()]
        truth_cols = g.attrs.get("truth", None)
        false_rates = [g[c].mean() for c in keep_cols if not g[c.replace("keep|", "true|")].any()
                       ] if any(c.replace("keep|", "true|") in g for c in keep_cols) else []
        row = {"design": design, "method": method, "runs": n,
               "true_structure": p, "se": math.sqrt(max(p * (1 - p), 1e-12) / n),
               "all_true_kept": g["all_true_kept"].mean(),
               "max_false_keep": max(false_rates) if false_rates else math.nan}
        if "covered" in g and g["intervals"].sum() > 0:
            cov = g["covered"].sum() / g["intervals"].sum()
            row["coverage"] = cov
            row["coverage_se"] = math.sqrt(cov * (1 - cov) / g["intervals"].sum())
            row["intervals"] = int(g["intervals"].sum())
        if method == "ivsel":
            row["median_seconds"] = float(g["seconds"].median())
        del truth_cols
        out.append(row)
    return pd.DataFrame(out)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=200)
    ap.add_argument("--seed", type=int, default=2024)
    ap.add_argument("--quick", action="store_true", help="short logs (development)")
    ap.add_argument("--design", action="append", help="only these designs (substring)")
    ap.add_argument("--out", type=Path, help="write the per-run table (CSV)")
    ap.add_argument("--oracle-runs", type=int, default=25,
                    help="runs that also fit the true structure for the oracle |t|")
    args = ap.parse_args(argv)
    frames = []
    for d_i, (name, (system, n, k, library)) in enumerate(designs(args.quick).items()):
        if args.design and not any(s in name for s in args.design):
            continue
        truth = (system.model or system.spec).with_aggregate(None)
        seeds = np.random.SeedSequence([args.seed, d_i]).spawn(args.runs)
        rows = []
        t0 = time.perf_counter()
        for r, ss in enumerate(seeds):
            for row in one_run(system, n, k, library, ss, oracle=r < args.oracle_runs):
                row.update(design=name, run=r)
                rows.append(row)
            if (r + 1) % 10 == 0:
                print(f"  {name}: {r + 1} runs, {time.perf_counter() - t0:.0f} s",
                      file=sys.stderr, flush=True)
        df = pd.DataFrame(rows)
        lib = resolve_library(library, linear_base(truth))
        for s in truth.states:  # which candidates are true (by representative, per run)
            for c in [c for c in df.columns if c.startswith(f"keep|{s}|")]:
                term = c.split("|", 2)[2]
                df[c.replace("keep|", "true|")] = term in {
                    str(canonical(t)) for t in truth.equations[s]}
        del lib
        frames.append(df)
        print(f"{name}: {args.runs} runs, {k} x {n} samples, {time.perf_counter() - t0:.0f} s",
              file=sys.stderr)
        summary = summarise(df)
        print(summary.to_string(index=False, float_format=lambda x: f"{x:.3f}"))
        iv = df[df.method == "ivsel"]
        per_term = []
        for s in truth.states:
            for t in truth.equations[s]:
                tc = str(canonical(t))
                kc = f"keep|{s}|{tc}"
                oc = f"oracle_t|{s}|{t}"
                per_term.append({
                    "term": f"{s}: {t}",
                    **{m: (df[df.method == m][kc].mean() if kc in df else math.nan)
                       for m in df.method.unique()},
                    "oracle_median_|t|": iv[oc].median() if oc in iv else math.nan})
        print(pd.DataFrame(per_term).to_string(index=False, float_format=lambda x: f"{x:.2f}"))
        sys.stdout.flush()
    if args.out and frames:
        pd.concat(frames, ignore_index=True).to_csv(args.out, index=False)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
