"""Robustness study: is the default estimate honest on disturbances outside its models?

Heave of an underwater vehicle with its own θ0 (not the paper's),

    w(k+1) = a·w_r(k) + n·w_r(k)|w_r(k)| + f·τ(k) + ξ(k),   w_r = w − v,
    y(k)   = w(k) + e(k) (+ coloured sensor noise c(k)),

random pulses τ of random sign, simulated here (independently of the library's
simulator), and identified through the public API exactly as a user does
(``identify(log, spec, method)``, default options) with ``auto``, ``iv-zero-mean``,
``pem``, ``lagged-2sls`` and ``pem-switching`` (the telegraph-current likelihood) on the
same logs. Designs (one disturbance class each):

* ``white``: white current inside the modulus, white process and sensor noise;
* ``gm-current``: a Gauss–Markov current (``pem``'s own model);
* ``two-coloured``: a Gauss–Markov current and Gauss–Markov sensor noise at once;
* ``telegraph``: a "tidal-step" current ±0.06 switching sign w.p. 0.02 a sample;
* ``mean-current``: a white current with mean +0.05, no current sensor;
* ``drift``: the input gain ``f`` drifts linearly by 5 % over the log (θ0: its mean);
* ``heavy-tailed``: Student-t (3 d.o.f.) sensor noise;
* ``short``: the white design with 10³ samples.

Per design, method and parameter: 95 % coverage with its Wilson interval, the bias in
Monte Carlo standard errors (z), the median relative error, the ratio of the mean
reported SE to the Monte Carlo sd, and the distribution of ``auto``'s choices (and
how many runs raised or carried each warning). Writes ``docs/robustness.csv`` and
``docs/robustness.md``::

    nice -n 10 python scripts/robustness_study.py --runs 200 --samples 10000 --seed 2024
    python scripts/robustness_study.py --runs 30 --designs white telegraph
    python scripts/robustness_study.py --methods auto --update   # rerun auto only
    python scripts/robustness_study.py --methods auto-unbounded --update  # add a variant

``--methods`` also takes the study's variants (:data:`VARIANTS`).
"""

from __future__ import annotations

import argparse
import sys
import time
import warnings
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd
from numba import njit

from vesselid.core.fileio import atomic_write_text
from vesselid.identify import identify
from vesselid.model.spec import ModelSpec

#: The study's own true parameters (a, n, f): not the paper's.
THETA0 = (0.9, -0.2, 0.8)
METHODS = ("auto", "iv-zero-mean", "pem", "lagged-2sls", "pem-switching")
#: Study variants beyond the registry (``--methods``): ``auto`` with the joint model's
#: sensor-noise variance always estimated without its bound at zero where the likelihood
#: does not establish it (``pem_boundary="unbounded"``), or always bounded
#: (``pem_boundary="bounded"``); ``auto`` itself chooses by the shape of the smoothed
#: current (``scripts/pem_boundary_study.py``); ``auto-no-fixed-b``: ``auto`` with
#: normal critical values for its GMM and SRIV intervals (:data:`COV_CONFIG`);
#: ``auto-no-switching``: ``auto`` without its switching-current model
#: (``pem_switching=False``: the Gauss–Markov likelihood models alone).
VARIANTS = ("auto-unbounded", "auto-bounded", "auto-no-fixed-b", "auto-no-switching")
#: ``cov_config`` of a variant (``auto-no-fixed-b``: ``auto``'s intervals without the
#: fixed-b critical values of :mod:`vesselid.identify.fixedb`).
COV_CONFIG = {"auto-no-fixed-b": {"fixed_b": False}}
#: The methods whose choices are tabulated.
AUTOS = ("auto", "auto-unbounded", "auto-bounded", "auto-no-fixed-b", "auto-no-switching")
PARAMS = ("a", "n", "f")
SPEC = ModelSpec(name="heave-robustness", states=["w"], inputs=["tau"],
                 equations={"w": ["w", "w*|w|", "tau"]},
                 theta0={"w": list(THETA0)}, dt=1.0)


@dataclass(frozen=True)
class Design:
    """One disturbance class (standard deviations in units of the heave speed)."""

    name: str
    text: str
    current: str = "white"        # white | gm | telegraph
    current_mean: float = 0.0
    current_std: float = 0.05
    current_tau: float = 25.0
    sensor: str = "white"         # white | gm+white | t3
    sensor_std: float = 0.05
    sensor_gm_std: float = 0.05
    sensor_gm_tau: float = 20.0
    xi_std: float = 0.05
    drift: float = 0.0            # relative linear drift of f over the log
    samples: int | None = None    # overrides --samples


DESIGNS: dict[str, Design] = {d.name: d for d in (
    Design("white", "white current, process and sensor noise (control)"),
    Design("gm-current", "Gauss–Markov current (std 0.1, time constant 25 samples)",
           current="gm", current_std=0.1),
    Design("two-coloured", "Gauss–Markov current and Gauss–Markov sensor noise at once",
           current="gm", current_std=0.1, sensor="gm+white"),
    Design("telegraph", "telegraph current ±0.06, sign switches w.p. 0.02 a sample",
           current="telegraph", current_std=0.06),
    Design("mean-current", "white current with mean +0.05, no current sensor",
           current_mean=0.05),
    Design("drift", "input gain f drifts linearly by 5 % over the log", drift=0.05),
    Design("heavy-tailed", "Student-t (3 d.o.f.) sensor noise, std 0.05", sensor="t3"),
    Design("short", "white disturbances, 10³ samples", samples=1000),
)}


@njit(cache=True)
def _heave(a, n, f, tau, v, xi, w0):  # pragma: no cover - compiled
    w = np.empty(tau.size)
    w[0] = w0
    for k in range(tau.size - 1):
        wr = w[k] - v[k]
        w[k + 1] = a * wr + n * wr * abs(wr) + f[k] * tau[k] + xi[k]
    return w


@njit(cache=True)
def _ar1(e, rho):  # pragma: no cover - compiled
    x = np.empty(e.size)
    x[0] = e[0] / np.sqrt(1.0 - rho * rho)
    for k in range(1, e.size):
        x[k] = rho * x[k - 1] + e[k]
    return x


def _pulses(rng: np.random.Generator, n: int) -> np.ndarray:
    widths = rng.integers(10, 101, size=n // 10 + 2)
    levels = rng.uniform(0.1, 0.4, size=widths.size) * rng.choice([-1.0, 1.0], widths.size)
    return np.repeat(levels, widths)[:n]


def _gm(rng: np.random.Generator, n: int, std: float, tau: float) -> np.ndarray:
    rho = float(np.exp(-1.0 / tau))
    return _ar1(rng.normal(0.0, std * np.sqrt(1 - rho * rho), n), rho)


def simulate(design: Design, rng: np.random.Generator, n: int) -> pd.DataFrame:
    """One log of ``design`` (columns ``time``, ``w``, ``tau``)."""
    tau = _pulses(rng, n)
    if design.current == "gm":
        v = _gm(rng, n, design.current_std, design.current_tau)
    elif design.current == "telegraph":
        flips = rng.random(n) < 0.02
        sign = rng.choice([-1.0, 1.0]) * np.where(np.cumsum(flips) % 2 == 0, 1.0, -1.0)
        v = design.current_std * sign
    else:
        v = rng.normal(0.0, design.current_std, n)
    v = v + design.current_mean
    xi = rng.normal(0.0, design.xi_std, n)
    a, nn, f0 = THETA0
    f = f0 * (1.0 + design.drift * (np.arange(n) / max(n - 1, 1) - 0.5))
    w = _heave(a, nn, f, tau, v, xi, 0.0)
    if design.sensor == "t3":
        e = rng.standard_t(3, n) * design.sensor_std / np.sqrt(3.0)
    else:
        e = rng.normal(0.0, design.sensor_std, n)
        if design.sensor == "gm+white":
            e = e + _gm(rng, n, design.sensor_gm_std, design.sensor_gm_tau)
    return pd.DataFrame({"time": np.arange(n, dtype=float), "w": w + e, "tau": tau})


def estimator(method: str):
    """The registered estimator ``method``, or a study variant (:data:`VARIANTS`)."""
    if method == "auto-no-fixed-b":
        return "auto"
    if method in ("auto-unbounded", "auto-bounded"):
        from vesselid.identify.efficient import InstrumentalGMM
        from vesselid.identify.registry import entry

        return InstrumentalGMM(**{**entry("auto").options,
                                  "pem_boundary": method.removeprefix("auto-")})
    if method == "auto-no-switching":
        from vesselid.identify.efficient import InstrumentalGMM
        from vesselid.identify.registry import entry

        return InstrumentalGMM(**{**entry("auto").options, "pem_switching": False})
    return method


def one_run(design: Design, seed: np.random.SeedSequence, n: int,
            methods: tuple[str, ...] = METHODS) -> list[dict]:
    """Every method on one log: estimate, SE, choice, warnings (one row per parameter)."""
    log = simulate(design, np.random.default_rng(seed), n)
    rows = []
    for method in methods:
        t0 = time.perf_counter()
        base = {"design": design.name, "method": method}
        try:
            with warnings.catch_warnings(record=True) as caught:
                warnings.simplefilter("always")
                cfg = {"cov_config": COV_CONFIG[method]} if method in COV_CONFIG else {}
                res = identify(log, SPEC, estimator(method), **cfg)
        except Exception as exc:
            for p, th in zip(PARAMS, THETA0, strict=True):
                rows.append({**base, "param": p, "theta0": th, "estimate": np.nan,
                             "se": np.nan, "choice": "raised", "raised": str(exc)[:80],
                             "warnings": "", "seconds": time.perf_counter() - t0})
            continue
        dt = time.perf_counter() - t0
        diag = res.diagnostics
        choice = str(diag.get("choice") or diag.get("instruments", method))
        wtxt = " | ".join(sorted({type(w.message).__name__ for w in caught}))
        extra = _identifiable(diag)
        for i, (p, th) in enumerate(zip(PARAMS, THETA0, strict=True)):
            rows.append({**base, "param": p, "theta0": th,
                         "estimate": float(res.params.iloc[i]),
                         "se": float(res.std_errors.iloc[i]), "choice": choice,
                         "raised": "", "warnings": wtxt, "seconds": dt, **extra})
    return rows


def _identifiable(diag: dict) -> dict:
    """The mean-current diagnostic's identified combination (when reported)."""
    mc = diag.get("mean_current")
    if not mc:
        return {}
    return {"mc_warned": bool(mc.get("warned")), "mc_vbar": mc.get("estimate"),
            "mc_vbar_se": mc.get("std_error")}


def wilson(k: int, n: int, z: float = 1.959964) -> tuple[float, float]:
    if n == 0:
        return float("nan"), float("nan")
    p = k / n
    den = 1 + z * z / n
    c = (p + z * z / (2 * n)) / den
    h = z * np.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / den
    return c - h, c + h


def summarise(df: pd.DataFrame) -> pd.DataFrame:
    out = []
    for (design, method, param), g in df.groupby(["design", "method", "param"], sort=False):
        ok = g[np.isfinite(g["estimate"]) & np.isfinite(g["se"])]
        err = ok["estimate"] - ok["theta0"]
        r = len(ok)
        cover = int((np.abs(err) <= 1.959964 * ok["se"]).sum())
        lo, hi = wilson(cover, r)
        sd = float(err.std(ddof=1)) if r > 1 else float("nan")
        out.append({
            "design": design, "method": method, "param": param, "runs": len(g),
            "raised": int((g["choice"] == "raised").sum()),
            "coverage": cover / r if r else float("nan"), "wilson_lo": lo, "wilson_hi": hi,
            "bias_z": float(err.mean() / (sd / np.sqrt(r))) if r > 1 and sd > 0 else 0.0,
            "median_rel_err": float(np.median(np.abs(err / ok["theta0"]))) if r else np.nan,
            "mc_sd": sd, "se_over_sd": float(ok["se"].mean() / sd) if r > 1 else np.nan,
            "median_ms": 1e3 * float(g["seconds"].median()),
        })
    return pd.DataFrame(out)


def choices(df: pd.DataFrame) -> pd.DataFrame:
    a = df[df["method"].isin(AUTOS) & (df["param"] == PARAMS[0])]
    return a.groupby(["method", "design", "choice"], sort=False).size().rename(
        "runs").reset_index()


def warning_shares(df: pd.DataFrame) -> pd.DataFrame:
    """Per design: share of ``auto``'s runs carrying each diagnostic's warning, and the
    coverage of the current's mean by the mean-current interval (that design)."""
    # the diagnostics come from the IV_E{ζ}=0 start: the same for every auto variant
    present = [m for m in AUTOS if (df["method"] == m).any()]
    a = df[(df["method"] == (present[0] if present else "auto")) & (df["param"] == PARAMS[0])]
    out = []
    for design, g in a.groupby("design", sort=False):
        row = {"design": design, "runs": len(g)}
        for cat in ("IdentifiabilityWarning", "ParameterDriftWarning"):
            row[cat] = float(g["warnings"].str.contains(cat).mean())
        d = DESIGNS.get(design)
        if d is not None and d.current_mean and "mc_vbar" in g:
            ok = g[np.isfinite(g["mc_vbar"].astype(float))]
            hit = np.abs(ok["mc_vbar"].astype(float) - d.current_mean) <= (
                1.959964 * ok["mc_vbar_se"].astype(float))
            row["vbar_coverage"] = float(hit.mean()) if len(ok) else float("nan")
        out.append(row)
    return pd.DataFrame(out)


def markdown(summary: pd.DataFrame, ch: pd.DataFrame, ws: pd.DataFrame,
             args: argparse.Namespace) -> str:
    variants = [v for v in VARIANTS if (summary["method"] == v).any()]
    lines = ["---", "orphan: true", "---", "", "# Robustness study table", "",
             f"Robustness study: {args.runs} runs × {args.samples} samples per design "
             f"(short: 10³), seed {args.seed}; θ0 = (a, n, f) = {THETA0}. "
             "`python scripts/robustness_study.py "
             f"--runs {args.runs} --samples {args.samples} --seed {args.seed}`"
             + (f" (the variants' rows: then `--methods {' '.join(variants)} --update`, on "
                "the same logs)" if variants else ""), "",
             "| design | method | param | coverage [Wilson 95 %] | bias z | median rel. err "
             "| SE / MC sd | raised |", "|---|---|---|---|---|---|---|---|"]
    for _, r in summary.iterrows():
        lines.append(f"| {r.design} | {r.method} | {r.param} | {100 * r.coverage:.1f} % "
                     f"[{100 * r.wilson_lo:.1f}, {100 * r.wilson_hi:.1f}] | {r.bias_z:+.2f} | "
                     f"{r.median_rel_err:.4f} | {r.se_over_sd:.2f} | {r.raised} |")
    lines += ["", "`auto`'s choices:", "", "| method | design | choice | runs |",
              "|---|---|---|---|"]
    for _, r in ch.iterrows():
        lines.append(f"| {r.method} | {r.design} | {r.choice} | {r.runs} |")
    lines += ["", "Share of `auto`'s runs with each diagnostic's warning (and, on the mean-"
              "current design, how often the reported interval of the current's mean "
              "covers it):", "", "| design | identifiability | parameter drift | "
              "v̄ covered |", "|---|---|---|---|"]
    for _, r in ws.iterrows():
        cov = r.get("vbar_coverage", float("nan"))
        lines.append(f"| {r.design} | {100 * r.IdentifiabilityWarning:.1f} % | "
                     f"{100 * r.ParameterDriftWarning:.1f} % | "
                     + (f"{100 * cov:.1f} % |" if np.isfinite(cov) else "— |"))
    return "\n".join(lines) + "\n"


def study_parser(description: str, *, runs: int, seed: int,
                 designs: list[str] | tuple[str, ...]) -> argparse.ArgumentParser:
    """The options every study over these designs takes: ``--runs``, ``--samples``,
    ``--seed``, ``--designs`` and ``--out`` (checked by :func:`check_study_args`)."""
    ap = argparse.ArgumentParser(description=description)
    ap.add_argument("--runs", type=int, default=runs)
    ap.add_argument("--samples", type=int, default=10_000)
    ap.add_argument("--seed", type=int, default=seed)
    ap.add_argument("--designs", nargs="+", default=list(designs))
    ap.add_argument("--out", type=Path, default=Path(__file__).resolve().parents[1] / "docs")
    return ap


def design_seeds(seed: int, name: str, runs: int) -> list[np.random.SeedSequence]:
    """The seeds of the first ``runs`` runs of design ``name`` under the root ``seed``:
    each design draws from its own child of the root (its index in :data:`DESIGNS`), so
    a design's logs do not depend on which other designs a study runs."""
    root = np.random.SeedSequence(seed)
    return np.random.SeedSequence(root.entropy, spawn_key=(list(DESIGNS).index(name),)
                                  ).spawn(runs)


def run_designs(args: argparse.Namespace, run: Callable[..., list[dict]]) -> list[dict]:
    """The rows of ``run(design, seed, samples)`` (a list of rows per run) over the runs of
    every design of ``args.designs`` (:func:`design_seeds`), with each design's time on
    stderr."""
    rows: list[dict] = []
    for j, name in enumerate(args.designs):
        d = DESIGNS[name]
        t0 = time.perf_counter()
        for s in design_seeds(args.seed, name, args.runs):
            rows += run(d, s, d.samples or args.samples)
        print(f"[{j + 1}/{len(args.designs)}] {name}: {time.perf_counter() - t0:.0f} s",
              file=sys.stderr, flush=True)
    return rows


def check_study_args(ap: argparse.ArgumentParser, args: argparse.Namespace) -> None:
    """A one-line reason (``ap.error``, exit 2) for bad :func:`study_parser` options."""
    if args.runs < 2:
        ap.error("--runs must be at least 2 (coverage and sd need several runs)")
    if args.samples < 200:
        ap.error("--samples must be at least 200")
    unknown = sorted(set(args.designs) - set(DESIGNS))
    if unknown:
        ap.error(f"unknown designs {unknown}; choose from {list(DESIGNS)}")


def main(argv: list[str] | None = None) -> int:
    ap = study_parser(__doc__.split("\n\n")[0], runs=200, seed=2024, designs=list(DESIGNS))
    ap.add_argument("--methods", nargs="+", default=list(METHODS),
                    help="registered estimator names or the study's variants "
                         f"{list(VARIANTS)} (default: %(default)s)")
    ap.add_argument("--raw", type=Path, default=None, help="also write every run's rows")
    ap.add_argument("--update", action="store_true",
                    help="keep the rows of the other methods from --out's robustness.csv "
                         "(the tables of auto's choices and warnings need auto among "
                         "--methods)")
    ap.add_argument("--from-raw", type=Path, default=None,
                    help="rebuild the tables from a file --raw wrote (no simulation)")
    args = ap.parse_args(argv)
    check_study_args(ap, args)
    from vesselid.identify.registry import METHODS as registered

    bad = sorted(set(args.methods) - set(registered) - set(VARIANTS))
    if bad:
        ap.error(f"unknown methods {bad}; choose from {list(registered)}")
    if args.from_raw is not None:
        if not args.from_raw.is_file():
            ap.error(f"--from-raw: no such file {str(args.from_raw)!r}")
        return _report(pd.read_csv(args.from_raw, keep_default_na=False,
                                   na_values=[""]), args)
    methods = tuple(args.methods)
    df = pd.DataFrame(run_designs(args, lambda d, s, n: one_run(d, s, n, methods)))
    if args.raw is not None:
        atomic_write_text(args.raw, df.to_csv(index=False))
    return _report(df, args)


def _report(df: pd.DataFrame, args: argparse.Namespace) -> int:
    """Print and write the tables of the per-run rows ``df``."""
    df = df.assign(choice=df["choice"].fillna("").astype(str),
                   warnings=df["warnings"].fillna("").astype(str))
    summary = summarise(df)
    old_csv = args.out / "robustness.csv"
    if getattr(args, "update", False) and old_csv.is_file():
        old = pd.read_csv(old_csv)
        done = set(zip(summary["design"], summary["method"], strict=True))
        keep = old[[(d, m) not in done for d, m in zip(old["design"], old["method"],
                                                       strict=True)]]
        summary = pd.concat([summary, keep], ignore_index=True)
        order = {m: i for i, m in enumerate(METHODS + VARIANTS)}
        summary = summary.sort_values(
            ["design", "method", "param"], kind="stable",
            key=lambda c: c.map({d: i for i, d in enumerate(DESIGNS)}) if c.name == "design"
            else c.map(order) if c.name == "method" else c.map(PARAMS.index)
        ).reset_index(drop=True)
    ch = choices(df)
    old_ch = args.out / "robustness_choices.csv"
    if getattr(args, "update", False) and old_ch.is_file():
        prev = pd.read_csv(old_ch)
        redone = set(zip(ch["method"], ch["design"], strict=True))
        stale = [(m, d) in redone for m, d in zip(prev["method"], prev["design"],
                                                   strict=True)]
        ch = pd.concat([prev[~np.array(stale, dtype=bool)], ch], ignore_index=True)
        ch = ch.sort_values(
            ["design", "method"], kind="stable",
            key=lambda c: c.map({m: i for i, m in enumerate(AUTOS)}) if c.name == "method"
            else c.map({d: i for i, d in enumerate(DESIGNS)})).reset_index(drop=True)
    ws = warning_shares(df)
    old_ws = args.out / "robustness_warnings.csv"
    if getattr(args, "update", False) and old_ws.is_file():
        # auto's warning shares of the designs not rerun stand
        prev = pd.read_csv(old_ws)
        ws = pd.concat([prev[~prev["design"].isin(ws["design"])] if len(ws) else prev, ws],
                       ignore_index=True)
        ws = ws.sort_values("design", kind="stable",
                            key=lambda c: c.map({d: i for i, d in enumerate(DESIGNS)})
                            ).reset_index(drop=True)
    pd.set_option("display.width", 200)
    print(summary.to_string(index=False, float_format=lambda x: f"{x:.4g}"))
    print(ch.to_string(index=False))
    print(ws.to_string(index=False))
    args.out.mkdir(parents=True, exist_ok=True)
    atomic_write_text(args.out / "robustness.csv", summary.to_csv(index=False,
                                                                  float_format="%.5g"))
    atomic_write_text(args.out / "robustness_choices.csv", ch.to_csv(index=False))
    atomic_write_text(old_ws, ws.to_csv(index=False, float_format="%.5g"))
    atomic_write_text(args.out / "robustness.md", markdown(summary, ch, ws, args))
    return 0


if __name__ == "__main__":
    sys.exit(main())
