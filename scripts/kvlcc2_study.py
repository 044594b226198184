"""KVLCC2 free-running model tests (HSVA, SIMMAN 2008): ingest → identify → validate.

Trains the shipped 3-DOF specs (:mod:`vesselid.model.specs`: ``kvlcc2.toml``, two-factor terms
only, and ``kvlcc2_u2delta.toml``, rudder forces in ``u²δ`` as derived inputs) on nine of the
thirteen HSVA zig-zags and validates on the four held out (one of each family: 10°/10°,
15°/5°, 20°/10°, 25°/5°), with the package's default estimator, least squares, refined
IV, IV_E{ζ}=0 and SRIV side by side (the last two separate the two reasons SRIV loses on
these data: the per-experiment constants of the zero-mean instruments, and the AR
prefilter, whose order is varied on the first spec):

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
from pathlib import Path

import numpy as np
import pandas as pd

ROOT = Path(__file__).resolve().parent.parent
HELD_OUT = ("Z_10_10_S", "Z_15_05", "Z_20_10_P", "Z_25_05")
METHODS = (("default", None), ("ls", "ls"), ("iv", "iv"), ("iv-zero-mean", "iv-zero-mean"),
           ("sriv", "sriv"))
#: the estimators drawn in the figure (the others are in the tables)
FIGURE = ("default", "ls", "iv")
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

    specs = [load_spec("kvlcc2"), load_spec("kvlcc2_u2delta")]
    dt = args.dt or specs[0].dt
    if args.dt:
        from dataclasses import replace

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
    for spec, (label, method) in ((sp, lm) for sp in specs for lm in METHODS):
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
    rows += _prefilter_orders(train, test, specs[0])
    table = pd.DataFrame(rows)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    from vesselid.core.fileio import atomic_write_text

    atomic_write_text(out / "kvlcc2.csv", table.to_csv(index=False, float_format="%.6g"))
    atomic_write_text(out / "kvlcc2.md", "\n".join(
        _markdown(table[table.spec == sp.name], sp, dt) for sp in specs))
    print(f"\nwrote {out / 'kvlcc2.csv'} and {out / 'kvlcc2.md'}")
    if reports:
        _figure(reports, Path(args.figure))
        print(f"wrote {args.figure} ({Path(args.figure).stat().st_size / 1e3:.0f} kB)")
    return 0


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


def _markdown(table: pd.DataFrame, spec, dt: float) -> str:
    lines = ["<!-- generated by scripts/kvlcc2_study.py; do not edit -->",
             f"Held-out free-run fit (%, 100 = perfect), spec `{spec.name}`, dt = {dt:g} s:",
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
            meas = grp.measured.iloc[0]
            sims = []
            for e in ests:
                v = grp[grp.estimator == e].value
                sims.append("—" if v.empty or pd.isna(v.iloc[0]) else
                            f"{v.iloc[0]:.1f} ({v.iloc[0] - meas:+.1f})")
            which = "1st" if fig.startswith("first") else "2nd"
            lines.append(f"| {exp} | {which} | {meas:.1f} | " + " | ".join(sims) + " |")
    po = table[table.kind == "prefilter_order"]
    if len(po):
        lines += ["", "SRIV's held-out free-run fit (%, pooled) against the order of its AR "
                      "noise-model prefilter (AR(0): no prefilter, i.e. IV_E{ζ}=0 refined):",
                  "", "| prefilter | " + " | ".join(spec.states) + " |",
                  "|" + "---|" * (1 + spec.n_states)]
        for est, grp in po.groupby("estimator", sort=False):
            cells = [f"{grp[grp.state == s].value.iloc[0]:.1f}" for s in spec.states]
            lines.append(f"| AR({est.removeprefix('sriv-ar')}) | " + " | ".join(cells) + " |")
    st = table[table.kind != "prefilter_order"].drop_duplicates("estimator")
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
