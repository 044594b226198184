"""KVLCC2 free-running model tests (HSVA, SIMMAN 2008): ingest → identify → validate.

Trains the shipped 3-DOF specs (:mod:`vesselid.model.specs`: ``kvlcc2.toml``, two-factor terms
only, ``kvlcc2_u2delta.toml``, rudder forces in ``u²δ`` as derived inputs, and
``kvlcc2_vr.toml``, the first with the yaw cross term ``v*|r|``) on nine of the thirteen HSVA
zig-zags and validates on the four held out (one of each family: 10°/10°, 15°/5°, 20°/10°,
25°/5°), with the package's default estimator, least squares, refined IV, IV_E{ζ}=0 and SRIV
side by side on the first two (the last two separate the two reasons SRIV loses on these
data: the per-experiment constants of the zero-mean instruments, and the AR prefilter, whose
order is varied on the first spec), the default and least squares on the others.

The structure is chosen on the training runs only:

* **leave-one-run-out cross-validation** over the nine training zig-zags of candidate
  structures (the shipped spec plus manoeuvring-practice terms: the cross terms ``v*|r|``,
  ``r*|v|`` in sway and yaw, surge ``v*v``, ``r*r``, rudder-lift saturation ``delta*|delta|``),
  each fitted on eight runs by least squares and by the default estimator and validated
  on the ninth: pooled free-run fit per state and the first and
  second overshoot errors (``--no-cv`` skips it);
* **term selection** (:func:`vesselid.selection.select_terms`, library ``vessel``, the
  shipped spec as base model) on the nine training runs; the selected structure is then
  fitted and validated like the hand-written ones (``--no-select`` skips it).

* per state, the free-run fit on every held-out run (``vesselid validate``);
* the identified model's stability (spectral radius of the discrete map linearised at the
  approach equilibrium) and whether the free runs stayed bounded;
* the zig-zag overshoot angles measured vs simulated (each held-out zig-zag simulated as a
  zig-zag at its nominal switching angle, read off the file name ``Z_<δ>_<ψ>``).

The data have no licence, so they are not in the repository: give their folder with
``--data DIR`` or ``VESSELID_KVLCC2_DIR`` (the folder holding ``raw_data/`` or the
``.dat`` files themselves); without it the script says so and exits 0.

Writes ``docs/kvlcc2.csv`` (every number, tidy), ``docs/kvlcc2.md`` (the tables the user
guide quotes) and ``docs/_static/kvlcc2.png`` (measured vs simulated, < 200 kB)::

    python scripts/kvlcc2_study.py --data /path/to/kvlcc2_hsva
"""

from __future__ import annotations

import argparse
import math
import os
import re
import sys
import warnings
from dataclasses import replace
from pathlib import Path

import numpy as np
import pandas as pd

ROOT = Path(__file__).resolve().parent.parent
HELD_OUT = ("Z_10_10_S", "Z_15_05", "Z_20_10_P", "Z_25_05")
METHODS = (("default", None), ("ls", "ls"), ("iv", "iv"), ("iv-zero-mean", "iv-zero-mean"),
           ("sriv", "sriv"))
#: the estimators drawn in the figure (the others are in the tables)
FIGURE = ("default", "ls", "iv")
#: the shipped specs: every estimator of METHODS on the first two, the default and LS on the rest
SHIPPED = ("kvlcc2", "kvlcc2_u2delta", "kvlcc2_vr")
FULL_METHODS = ("kvlcc2", "kvlcc2-u2delta")
SHORT_METHODS = (("default", None), ("ls", "ls"))
#: candidate terms added to the shipped kvlcc2 spec in the cross-validation (equation: terms)
CANDIDATES = {
    "kvlcc2": {},
    "+v|r|,r|v| (sway)": {"v": ["v*|r|", "r*|v|"]},
    "+v|r|,r|v| (yaw)": {"r": ["v*|r|", "r*|v|"]},
    "+v|r|,r|v| (sway, yaw)": {"v": ["v*|r|", "r*|v|"], "r": ["v*|r|", "r*|v|"]},
    "+v|r| (yaw) = kvlcc2-vr": {"r": ["v*|r|"]},
    "+r|v| (yaw)": {"r": ["r*|v|"]},
    "+vv,rr (surge)": {"du": ["v*v", "r*r"]},
    "+vv,rr (surge), v|r|,r|v| (yaw)": {"du": ["v*v", "r*r"], "r": ["v*|r|", "r*|v|"]},
    "+δ|δ| (sway, yaw)": {"v": ["delta*|delta|"], "r": ["delta*|delta|"]},
}
CV_METHODS = (("ls", "ls"), ("default", None))
_NAME = re.compile(r"Z_(\d+)_(\d+)")


def _files(data: Path) -> list[Path]:
    raw = data / "raw_data" if (data / "raw_data").is_dir() else data
    return sorted(raw.glob("*KVLCC2_Z_*.dat"))


def _short(eid: str) -> str:
    m = re.search(r"Z_\d+_\d+(?:_[PS])?", str(eid))
    return m.group(0) if m else str(eid)


def spectral_radius(spec, theta) -> float:
    """Largest |eigenvalue| of the discrete map linearised at the approach equilibrium
    (all states and inputs zero), by central differences."""
    from vesselid.model.regressors import predict

    n, m = spec.n_states, spec.n_inputs
    jac = np.empty((n, n))
    h = 1e-6
    for j in range(n):
        s = np.zeros(n + m)
        s[j] = h
        jac[:, j] = (predict(spec.codes, theta, s) - predict(spec.codes, theta, -s)) / (2 * h)
    return float(np.max(np.abs(np.linalg.eigvals(jac))))


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--data", default=os.environ.get("VESSELID_KVLCC2_DIR"),
                   help="folder of the HSVA files (default: $VESSELID_KVLCC2_DIR)")
    p.add_argument("--dt", type=float, default=None, help="sample time (default: the spec's)")
    p.add_argument("--out", default=str(ROOT / "docs"), help="folder for kvlcc2.csv/.md")
    p.add_argument("--figure", default=str(ROOT / "docs" / "_static" / "kvlcc2.png"))
    p.add_argument("--no-cv", dest="cv", action="store_false",
                   help="skip the leave-one-run-out cross-validation of candidate structures")
    p.add_argument("--no-select", dest="select", action="store_false",
                   help="skip term selection on the training runs")
    p.add_argument("--bootstrap", type=int, default=20,
                   help="bootstrap replicates of the selection probabilities (default 20)")
    args = p.parse_args(argv)
    if not args.data or not _files(Path(args.data)):
        print("KVLCC2 data not found: give --data DIR or set VESSELID_KVLCC2_DIR to the folder "
              "holding the HSVA_CPMC_KVLCC2_Z_*.dat files; skipping the study")
        return 0
    warnings.simplefilter("ignore")  # the design warnings are in the JSON of identify
    from vesselid.data.ingest.tank import ingest_tank, load_tank_format
    from vesselid.data.logs import TrialLog
    from vesselid.identify import DEFAULT_METHOD, identify
    from vesselid.model.specs import load_spec, path
    from vesselid.validation.report import validate

    specs = [load_spec(n) for n in SHIPPED]
    dt = args.dt or specs[0].dt
    if args.dt:
        specs = [replace(sp, dt=float(args.dt)) for sp in specs]
    files = _files(Path(args.data))
    fmt = load_tank_format(path("kvlcc2_hsva_ingest"))
    log = ingest_tank(files, dt, fmt)
    nominal = {}
    for f in files:
        m = _NAME.search(f.stem)
        if m:
            nominal[f.stem] = {"delta0_deg": float(m.group(1)), "psi_switch_deg": float(m.group(2))}
    log.metadata["manoeuvres"] = nominal
    data = log.data
    held = data["experiment"].map(_short).isin(HELD_OUT)
    train = TrialLog(data[~held].reset_index(drop=True), log.metadata)
    test = TrialLog(data[held].reset_index(drop=True), log.metadata)
    print(f"{len(files)} HSVA runs at dt = {dt:g} s: training on "
          f"{[_short(e) for e in train.experiment_ids]}, validating on "
          f"{[_short(e) for e in test.experiment_ids]}")
    rows, reports = [], {}
    if args.cv:
        rows += _cross_validate(train, specs[0])
    if args.select:
        from vesselid.selection import select_terms

        sel = select_terms(train, specs[0], "vessel", n_boot=args.bootstrap)
        print("\nterm selection on the training runs (library vessel, base model "
              f"{specs[0].name}):\n{sel.summary()}")
        specs.append(replace(sel.spec, name="kvlcc2-selected"))
    runs = [(sp, lm) for sp in specs
            for lm in (METHODS if sp.name in FULL_METHODS else SHORT_METHODS)]
    for spec, (label, method) in runs:
        name = method or DEFAULT_METHOD
        res = identify(train, spec, method=name)
        theta = np.asarray(res.params, dtype=float)
        finite = bool(np.all(np.isfinite(theta)))
        rho = spectral_radius(spec, theta) if finite else float("nan")
        print(f"\n{spec.name}, {label} ({res.method}): converged {res.converged} after "
              f"{res.iterations} iteration(s) ({res.stop_reason}); spectral radius at the approach "
              f"equilibrium {rho:.5f}")
        diag = res.diagnostics if isinstance(res.diagnostics, dict) else {}
        choice = str(diag.get("noise_model") or diag.get("instruments") or "")
        if diag.get("instrument_choice"):
            print(f"  instrument choice: {diag['instrument_choice']}")
        check = diag.get("specification_check") or {}
        if check.get("sentence"):
            print(f"  {check['sentence']}")
        if diag.get("choice") and diag.get("choice_reason") and label == "default":
            choice = f"{choice} (auto: {diag['choice']})" if choice else f"auto: {diag['choice']}"
        pre = check.get("prefilter") or {}
        lev = check.get("levels") or {}
        base = {"spec": spec.name, "estimator": label, "method": str(res.method),
                "converged": bool(res.converged), "spectral_radius": rho, "choice": choice,
                "check_prefilter": pre.get("statistic", float("nan")),
                "check_levels": lev.get("statistic", float("nan")),
                "check_critical": pre.get("critical", float("nan"))}
        for (eq, term), v, se in zip(spec.param_index, theta, np.asarray(res.std_errors),
                                     strict=True):
            rows.append({**base, "kind": "parameter", "experiment": "", "state": eq,
                         "figure": term, "value": v, "stderr": se})
        if not finite:
            continue
        rep = validate(test, spec.with_theta0(theta))
        if spec is specs[0] and label in FIGURE:
            reports[label] = rep
        print(rep.summary())
        for e in rep.experiments:
            for s in spec.states:
                rows.append({**base, "kind": "free_run_fit", "experiment": _short(e.experiment),
                             "state": s, "figure": "fit_percent", "value": e.free_run_fit[s]})
                rows.append({**base, "kind": "k_step_fit", "experiment": _short(e.experiment),
                             "state": s, "figure": f"fit_percent_{rep.horizon}_step",
                             "value": e.k_step_fit[s]})
            if e.manoeuvre:
                for key in ("first_overshoot_deg", "second_overshoot_deg"):
                    rows.append({**base, "kind": "overshoot", "experiment": _short(e.experiment),
                                 "state": "psi", "figure": key,
                                 "measured": e.manoeuvre["measured"][key],
                                 "value": e.manoeuvre["simulated"][key]})
        for s in spec.states:
            rows.append({**base, "kind": "free_run_fit", "experiment": "pooled", "state": s,
                         "figure": "fit_percent", "value": rep.free_run_fit[s]})
        # the same zig-zags with the switching angle read at the tank's own reversals
        read = TrialLog(test.data, {k: v for k, v in test.metadata.items()
                                    if k != "manoeuvres"})
        for e in validate(read, spec.with_theta0(theta)).experiments:
            if e.manoeuvre:
                for key in ("first_overshoot_deg", "second_overshoot_deg"):
                    rows.append({**base, "kind": "overshoot_read",
                                 "experiment": _short(e.experiment), "state": "psi",
                                 "figure": key, "measured": e.manoeuvre["measured"][key],
                                 "value": e.manoeuvre["simulated"][key],
                                 "psi_switch_deg": e.manoeuvre["psi_switch_deg"]})
    rows += _prefilter_orders(train, test, specs[0])
    table = pd.DataFrame(rows)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    from vesselid.core.fileio import atomic_write_text

    atomic_write_text(out / "kvlcc2.csv", table.to_csv(index=False, float_format="%.6g"))
    atomic_write_text(out / "kvlcc2.md", "\n".join(
        [_cv_markdown(table, dt)]
        + [_markdown(table[table.spec == sp.name], sp, dt) for sp in specs]))
    print(f"\nwrote {out / 'kvlcc2.csv'} and {out / 'kvlcc2.md'}")
    if reports:
        _figure(reports, Path(args.figure))
        print(f"wrote {args.figure} ({Path(args.figure).stat().st_size / 1e3:.0f} kB)")
    return 0


def candidate_spec(base, add: dict[str, list[str]], label: str):
    """``base`` with the terms ``add`` (equation -> terms) appended to its equations."""
    from vesselid.model.spec import ModelSpec

    eqs = {s: [str(t) for t in base.equations[s]] + list(add.get(s, ())) for s in base.states}
    return ModelSpec(label, base.states, base.inputs, eqs, dt=base.dt,
                     derived=dict(base.derived) or None)


def _cross_validate(train, base) -> list[dict]:
    """Leave-one-run-out cross-validation over the training runs of every candidate
    structure (:data:`CANDIDATES`) and estimator (:data:`CV_METHODS`): fitted on all runs
    but one, validated on that one (free-run fit pooled over the left-out runs, overshoot
    errors of each left-out zig-zag)."""
    from vesselid.data.logs import TrialLog
    from vesselid.identify import DEFAULT_METHOD, identify
    from vesselid.validation.report import validate

    data = train.data
    short = data["experiment"].map(_short)
    names = list(dict.fromkeys(short))
    out = []
    print(f"\nleave-one-run-out cross-validation over {names}")
    for label, add in CANDIDATES.items():
        spec = candidate_spec(base, add, label)
        for est, method in CV_METHODS:
            num = dict.fromkeys(spec.states, 0.0)
            den = dict.fromkeys(spec.states, 0.0)
            errs, used = [], []
            for name in names:
                fit_log = TrialLog(data[short != name].reset_index(drop=True), train.metadata)
                val_log = TrialLog(data[short == name].reset_index(drop=True), train.metadata)
                res = identify(fit_log, spec, method=method or DEFAULT_METHOD)
                used.append(str(res.method))
                theta = np.asarray(res.params, dtype=float)
                e = validate(val_log, spec.with_theta0(theta)).experiments[0]
                for s in spec.states:
                    y, yh = e.series[f"measured_{s}"], e.series[f"simulated_{s}"]
                    num[s] += float(np.sum((y - yh) ** 2)) if np.all(np.isfinite(yh)) \
                        else float("inf")
                    den[s] += float(np.sum((y - np.mean(y)) ** 2))
                row = {"spec": f"cv {label}", "estimator": est, "method": str(res.method),
                       "kind": "cv", "experiment": name, "state": "psi"}
                for key in ("first_overshoot_deg", "second_overshoot_deg"):
                    meas = e.manoeuvre["measured"][key] if e.manoeuvre else None
                    sim = e.manoeuvre["simulated"][key] if e.manoeuvre else None
                    out.append({**row, "figure": key, "measured": meas,
                                "value": np.nan if sim is None else sim})
                    if sim is not None and meas is not None:
                        errs.append((key, sim - meas))
            for s in spec.states:
                out.append({"spec": f"cv {label}", "estimator": est,
                            "method": "/".join(sorted(set(used))),
                            "kind": "cv", "experiment": "pooled", "state": s,
                            "figure": "fit_percent",
                            "value": 100.0 * (1.0 - math.sqrt(num[s] / den[s]))})
            e2 = [abs(v) for k, v in errs if k.startswith("second")]
            print(f"  {label:34s} {est:3s} free-run fit " + " / ".join(
                f"{100.0 * (1.0 - math.sqrt(num[s] / den[s])):.1f}" for s in spec.states)
                + f" %, mean |2nd overshoot error| {np.mean(e2):.2f}° (method "
                f"{'/'.join(sorted(set(used)))})", flush=True)
    return out


def _cv_markdown(table: pd.DataFrame, dt: float) -> str:
    cv = table[table.kind == "cv"]
    if not len(cv):
        return ""
    names = [e for e in dict.fromkeys(cv.experiment) if e != "pooled"]
    lines = ["<!-- generated by scripts/kvlcc2_study.py; do not edit -->",
             f"Training cross-validation (leave one of the {len(names)} training runs out, "
             f"dt = {dt:g} s): free-run fit pooled over the left-out runs (%), mean and "
             "largest |simulated − measured| overshoot angle over the left-out zig-zags (°), "
             "and the mean signed second-overshoot error:", "",
             "| structure | estimator | fit du | fit v | fit r | 1st mean | 2nd mean | "
             "2nd largest | 2nd signed |", "|---|---|---|---|---|---|---|---|---|"]
    for (spec, est), g in cv.groupby(["spec", "estimator"], sort=False):
        used = g[g.experiment == "pooled"].method.iloc[0]
        est = est if used == est else f"{est} ({used})"
        fit = {s: g[(g.experiment == "pooled") & (g.state == s)].value.iloc[0]
               for s in ("du", "v", "r")}
        err = {k: (g[g.figure == k].value - g[g.figure == k].measured).astype(float).dropna()
               for k in ("first_overshoot_deg", "second_overshoot_deg")}
        e1, e2 = err["first_overshoot_deg"], err["second_overshoot_deg"]
        label = spec.removeprefix("cv ").replace("|", "\\|")  # a pipe would end the cell
        lines.append(f"| {label} | {est} | {fit['du']:.1f} | {fit['v']:.1f} "
                     f"| {fit['r']:.1f} | {e1.abs().mean():.2f} | {e2.abs().mean():.2f} | "
                     f"{e2.abs().max():.2f} | {e2.mean():+.2f} |")
    base = cv[(cv.spec == "cv kvlcc2") & (cv.estimator == "ls")
              & (cv.figure == "second_overshoot_deg")]
    if len(base):
        lines += ["", "Second overshoot per left-out training run, measured and simulated "
                      "(structure kvlcc2, least squares; °):", "",
                  "| run | " + " | ".join(base.experiment) + " |",
                  "|---|" + "---|" * len(base),
                  "| measured | " + " | ".join(f"{v:.1f}" for v in base.measured) + " |",
                  "| simulated | " + " | ".join(f"{v:.1f}" for v in base.value) + " |"]
    return "\n".join(lines) + "\n"


#: AR orders of the SRIV prefilter compared on the first spec (0: no prefilter)
PREFILTER_ORDERS = (0, 1, 2, 4, 8, 16)


def _prefilter_orders(train, test, spec) -> list[dict]:
    """Held-out free-run fit of SRIV against the order of its AR noise-model prefilter
    (the refined IV with zero-mean simulated instruments, three refinement steps)."""
    from vesselid.identify import identify
    from vesselid.identify.efficient import InstrumentalGMM
    from vesselid.validation.report import validate

    out = []
    for order in PREFILTER_ORDERS:
        est = InstrumentalGMM("simulated", noise_order=order, refine=3,
                              name=f"sriv-ar{order}")
        res = identify(train, spec, method=est)
        theta = np.asarray(res.params, dtype=float)
        if not np.all(np.isfinite(theta)):
            continue
        rep = validate(test, spec.with_theta0(theta))
        for s in spec.states:
            out.append({"spec": spec.name, "estimator": f"sriv-ar{order}", "method": "sriv",
                        "converged": bool(res.converged), "kind": "prefilter_order",
                        "experiment": "pooled", "state": s, "figure": "fit_percent",
                        "value": rep.free_run_fit[s], "prefilter_order": order})
    return out


def _overshoot_cells(figure: str, grp: pd.DataFrame, ests) -> tuple[str, float, list[str]]:
    """One overshoot row: ``1st``/``2nd``, the measured angle and, per estimator, the
    simulated one with its error (``—`` where the model diverged)."""
    meas = grp.measured.iloc[0]
    sims = []
    for e in ests:
        v = grp[grp.estimator == e].value
        sims.append("—" if v.empty or pd.isna(v.iloc[0]) else
                    f"{v.iloc[0]:.1f} ({v.iloc[0] - meas:+.1f})")
    return ("1st" if figure.startswith("first") else "2nd"), meas, sims


def _markdown(table: pd.DataFrame, spec, dt: float) -> str:
    lines = ["<!-- generated by scripts/kvlcc2_study.py; do not edit -->"]
    if spec.name.endswith("-selected"):
        lines += ["Structure selected on the training runs (`select_terms`, library `vessel`, "
                  "base model `kvlcc2`):", ""]
        lines += [f"* `{s}`: " + ", ".join(f"`{t}`" for t in spec.equations[s])
                  for s in spec.states]
        lines += [""]
    lines += [f"Held-out free-run fit (%, 100 = perfect), spec `{spec.name}`, dt = {dt:g} s:",
              ""]
    fr = table[(table.kind == "free_run_fit")]
    ests = list(dict.fromkeys(fr.estimator))
    head = "| experiment | " + " | ".join(f"{e} {s}" for e in ests for s in spec.states) + " |"
    lines += [head, "|" + "---|" * (1 + len(ests) * spec.n_states)]
    for exp in dict.fromkeys(fr.experiment):
        cells = []
        for e in ests:
            for s in spec.states:
                v = fr[(fr.experiment == exp) & (fr.estimator == e) & (fr.state == s)].value
                cells.append("diverged" if v.empty or pd.isna(v.iloc[0]) else
                             f"{v.iloc[0]:.1f}")
        lines.append(f"| {exp} | " + " | ".join(cells) + " |")
    os_ = table[table.kind == "overshoot"]
    if len(os_):
        lines += ["", "Zig-zag overshoot angles (°), measured vs simulated as a zig-zag:", "",
                  "| experiment | overshoot | measured | " + " | ".join(ests) + " |",
                  "|" + "---|" * (3 + len(ests))]
        for (exp, fig), grp in os_.groupby(["experiment", "figure"], sort=False):
            which, meas, sims = _overshoot_cells(fig, grp, ests)
            lines.append(f"| {exp} | {which} | {meas:.1f} | " + " | ".join(sims) + " |")
    rd = table[table.kind == "overshoot_read"]
    if len(rd):
        lines += ["", "The same zig-zags with the switching angle read from each run (the heading "
                      "change at which the tank's rudder reversed, later than the nominal "
                      "angle) for both the measured and the simulated overshoot (°):", "",
                  "| experiment | switch | overshoot | measured | " + " | ".join(ests) + " |",
                  "|" + "---|" * (4 + len(ests))]
        for (exp, fig), grp in rd.groupby(["experiment", "figure"], sort=False):
            which, meas, sims = _overshoot_cells(fig, grp, ests)
            lines.append(f"| {exp} | {grp.psi_switch_deg.iloc[0]:.2f} | {which} | {meas:.1f} | "
                         + " | ".join(sims) + " |")
    po = table[table.kind == "prefilter_order"]
    if len(po):
        lines += ["", "SRIV's held-out free-run fit (%, pooled) against the order of its AR "
                      "noise-model prefilter (AR(0): no prefilter, i.e. IV_E{ζ}=0 refined):",
                  "", "| prefilter | " + " | ".join(spec.states) + " |",
                  "|" + "---|" * (1 + spec.n_states)]
        for est, grp in po.groupby("estimator", sort=False):
            cells = [f"{grp[grp.state == s].value.iloc[0]:.1f}" for s in spec.states]
            lines.append(f"| AR({est.removeprefix('sriv-ar')}) | " + " | ".join(cells) + " |")
    st = table[~table.kind.isin(("prefilter_order", "overshoot_read"))].drop_duplicates(
        "estimator")
    lines += ["", "| estimator | method | instruments / noise model | converged | "
                  "spectral radius at U0 |", "|---|---|---|---|---|"]
    for _, r in st.iterrows():
        choice = "" if pd.isna(r.choice) else r.choice
        lines.append(f"| {r.estimator} | {r.method} | {choice} | {r.converged} | "
                     f"{r.spectral_radius:.5f} |")
    d = st[st.estimator == "default"]
    if len(d) and np.isfinite(d.check_prefilter.iloc[0]):
        r = d.iloc[0]
        lines += ["", "Specification check of the default (largest parameter difference in "
                      "summed standard errors; critical value "
                      f"{r.check_critical:.2f}): SRIV vs IV_E{{ζ}}=0 {r.check_prefilter:.2f}"
                  + ("" if not np.isfinite(r.check_levels) else
                     f", IV vs IV_E{{ζ}}=0 {r.check_levels:.2f}") + "."]
    return "\n".join(lines) + "\n"


def _figure(reports: dict, path: Path) -> None:
    """Two held-out runs: surge, sway, yaw rate and heading, measured vs each estimator."""
    from vesselid.core.figures import new_figure
    from vesselid.core.fileio import atomic_write_with

    first = next(iter(reports.values()))
    picks = [e.experiment for e in first.experiments][:2]
    states = list(first.states)
    fig = new_figure(7.0, 6.2)
    axes = fig.subplots(len(states) + 1, len(picks), squeeze=False, sharex="col")
    colours = {"default": "C3", "ls": "C0", "iv": "C2"}
    for j, eid in enumerate(picks):
        for k, (label, rep) in enumerate(reports.items()):
            e = next(x for x in rep.experiments if x.experiment == eid)
            t = e.series["time"]
            for i, s in enumerate(states):
                ax = axes[i, j]
                if k == 0:
                    ax.plot(t, e.series[f"measured_{s}"], color="k", lw=1.0, label="measured")
                fit = e.free_run_fit[s]
                ax.plot(t, e.series[f"simulated_{s}"], color=colours.get(label, "C4"), lw=0.8,
                        label=f"{label} {'div.' if fit is None else f'{fit:.0f} %'}")
            ax = axes[len(states), j]
            if k == 0:
                ax.plot(t, np.degrees(e.series["psi"]), color="k", lw=1.0, label="measured")
            if "psi_zigzag" in e.series:
                ax.plot(t, np.degrees(e.series["psi_zigzag"]), color=colours.get(label, "C4"),
                        lw=0.8, label=f"{label} zig-zag")
        for i, s in enumerate([*states, "heading (°)"]):
            axes[i, j].legend(fontsize=5, loc="lower left", ncol=2)
            if j == 0:
                axes[i, j].set_ylabel(s, fontsize=7)
        axes[0, j].set_title(_short(eid), fontsize=8)
        axes[-1, j].set_xlabel("time (s, model scale)", fontsize=7)
    for ax in axes.flat:
        ax.tick_params(labelsize=6)
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_with(path, lambda p: fig.savefig(p, dpi=90, format="png"))
    _ = math  # angles converted with numpy


if __name__ == "__main__":
    sys.exit(main())
