"""The arithmetic of scripts/selection_study.py: the per-term power table, the detectable
structure, and the FROLS comparator's one-pass information criterion."""

from __future__ import annotations

import math
from statistics import NormalDist

import numpy as np
import pandas as pd
import pytest
from _scripts import load_script

from vesselid.model.spec import ModelSpec
from vesselid.selection.engine import critical_value


@pytest.fixture(scope="module")
def study():
    return load_script("selection_study")


def _truth() -> ModelSpec:
    return ModelSpec("t", ["x"], ["f"], {"x": ["x", "x*|x|", "f"]}, dt=1.0,
                     theta0={"x": [0.9, -0.02, 0.5]})


def _table() -> pd.DataFrame:
    """Four runs of two methods: 'a' keeps x, f and (run 3) the zero term f*x; 'b' keeps
    x, x*|x|, f in every run."""
    rows = []
    for run in range(4):
        for method in ("a", "b"):
            row = {"method": method, "run": run, "design": "d", "exact": method == "b",
                   "all_true_kept": method == "b", "seconds": 1.0,
                   "n_rows": 10000, "n_candidates": 12, "critical_value": 3.5}
            for term, true in (("x", True), ("x*|x|", True), ("f", True), ("f*x", False)):
                kept = (term in ("x", "f") or (term == "f*x" and run == 3)) if method == "a" \
                    else true
                row[f"keep|x|{term}"] = kept
                row[f"true|x|{term}"] = true
                if true:
                    row[f"tkeep|x|{term}"] = kept
            if method == "a":  # the oracle columns live on the selection's rows
                for term, se, t in (("x", 0.01, 90.0), ("x*|x|", 0.01 * (1 + run), 2.0),
                                    ("f", 0.05, 10.0)):
                    row[f"oracle_t|x|{term}"] = t
                    row[f"oracle_se|x|{term}"] = se
                    row[f"oracle_cover|x|{term}"] = run != 0
            rows.append(row)
    df = pd.DataFrame(rows)
    df["method"] = df["method"].map({"a": "ivsel", "b": "frols"})
    return df


def test_power_table_by_hand(study):
    df = _table()
    power = study.power_table(df, _truth(), 10000, 12)
    row = power.set_index("term").loc["x*|x|"]
    delta = 0.02 / 0.025  # median SE of the four runs: (0.02 + 0.03) / 2
    assert row["noncentrality"] == pytest.approx(delta)
    c = critical_value(0.01, 12, 10000)
    nd = NormalDist()
    assert row["power"] == pytest.approx(nd.cdf(delta - c) + nd.cdf(-delta - c))
    # the length for 95 % power solves δ √(n/10⁴) = c(n) + z_0.95
    n95 = row["samples_for_95pct_power"]
    assert delta * math.sqrt(n95 / 10000) == pytest.approx(
        critical_value(0.01, 12, int(n95)) + 1.644854, rel=1e-6)
    assert row["kept_ivsel"] == 0.0 and row["kept_frols"] == 1.0
    assert row["oracle_coverage"] == pytest.approx(0.75)
    assert power.set_index("term").loc["x", "power"] > 0.999


def test_detectable_structure_by_hand(study):
    df = _table()
    power = study.power_table(df, _truth(), 10000, 12)
    # detectable: x (δ = 0.9/0.01) and f (δ = 10); x*|x| (δ = 0.8) is not
    assert set(power.loc[power.power >= 0.95, "term"]) == {"x", "f"}
    det = study.detectable_structure(df, power)
    assert det["ivsel"] == pytest.approx(0.75)  # run 3 keeps the zero term f*x
    assert det["frols"] == pytest.approx(1.0)
    summary = study.summarise(df).set_index("method")
    assert summary.loc["ivsel", "max_false_keep"] == pytest.approx(0.25)
    assert summary.loc["ivsel", "true_terms_kept"] == pytest.approx(2.0)
    assert summary.loc["ivsel", "false_terms_kept"] == pytest.approx(0.25)
    assert summary.loc["frols", "true_terms_kept"] == pytest.approx(3.0)


@pytest.mark.slow
def test_frols_one_pass_criterion_matches_sysidentpy(study):
    """The comparator's one ERR pass gives the terms of SysIdentPy's own
    information_criterion (which reruns the greedy ERR for every model size)."""
    pytest.importorskip("sysidentpy")
    from sysidentpy.model_structure_selection import FROLS
    from sysidentpy.parameter_estimation import LeastSquares

    rng = np.random.default_rng(4)
    n, p = 600, 8
    phi = rng.normal(size=(n, p))
    phi[:, 5] = phi[:, 1] + 0.3 * rng.normal(size=n)
    y = phi[:, [0, 1, 3]] @ np.array([1.0, -0.4, 0.05]) + 0.2 * rng.normal(size=n)
    new = study._frols(phi, y)
    model = FROLS(order_selection=True, info_criteria="aic", n_info_values=p, ylag=1,
                  xlag=1, estimator=LeastSquares())
    y_lag = np.concatenate([y[:1], y]).reshape(-1, 1)
    ic = np.asarray(model.information_criterion(phi, y_lag), dtype=float)
    n_terms = int(np.nanargmin(ic)) + 1
    _, piv, _ = model.error_reduction_ratio(phi, y_lag, n_terms)
    old = np.zeros(p, dtype=bool)
    old[np.asarray(piv[:n_terms], dtype=int)] = True
    assert np.array_equal(new, old)
    assert new[[0, 1]].all()


def test_design_names_and_viknes_truth(study):
    """Every design maps to its ``--system`` name; the Viknes 830 designs carry the
    catalogue's structure (10 terms) with the current inside the modulus on u and v."""
    d = study.designs(True)
    assert {study.system_key(n) for n in d} == {"heave", "cybership2", "viknes830"}
    system, n, k, library = d["Viknes 830, Gauss-Markov current"]
    truth = (system.model or system.spec).with_aggregate(None)
    assert {s: [str(t) for t in truth.equations[s]] for s in truth.states} == {
        "u": ["u", "u*|u|", "v*r", "X"], "v": ["v", "v*|v|", "u*r", "Y"], "r": ["r", "N"]}
    assert set(system.current) == {"u", "v"} and (n, k, library) == (1000, 4, "vessel")
    assert study.system_key("CyberShip II planned, white current") == "cybership2-planned"
    assert study.system_key("Viknes 830 manoeuvres, white current") == "viknes830-manoeuvres"


def test_schedule_input_is_the_fixed_schedule(study):
    sched = study._Schedule(np.arange(10.0), "experiment 0")
    rng = np.random.default_rng(0)
    assert np.array_equal(sched.sample(rng, 4), np.arange(4.0))
    assert sched.to_dict() == {"kind": "schedule", "programme": "experiment 0", "samples": 10}
    with pytest.raises(ValueError, match="10 samples"):
        sched.sample(rng, 11)


def test_viknes_manoeuvres_change_signs(study):
    """The thruster-square design: u, v and r change sign within every experiment."""
    d = study.designs(True, manoeuvres=True)
    system, n, k, _ = d["Viknes 830 manoeuvres, white current"]
    log = system.simulate(n, k, seed=0).to_log(aggregate=False)
    for _, g in log.data.groupby("experiment"):
        for s in ("u", "v", "r"):
            assert g[s].min() < 0 < g[s].max()


def test_partial_csv_is_whole(study, tmp_path):
    out = tmp_path / "runs.csv"
    study._write_csv(pd.DataFrame({"a": [1, 2]}), out)
    assert pd.read_csv(out)["a"].tolist() == [1, 2] and not (tmp_path / "runs.csv.tmp").exists()


def _experiments_changing_sign(system, n: int, k: int) -> list:
    """The experiments of one seeded log of ``system`` (the full 25-term CyberShip II
    structure), after asserting that u, v and r change sign within every one."""
    assert sum(len(v) for v in system.spec.equations.values()) == 25
    log = system.simulate(n, k, seed=0).to_log(aggregate=False)
    groups = [g for _, g in log.data.groupby("experiment")]
    for g in groups:
        for s in ("u", "v", "r"):
            assert g[s].min() < 0 < g[s].max()
    return groups


@pytest.mark.slow
def test_planned_cybership_design_changes_signs(study):
    """The planner's manoeuvres make u, v and r change sign within every experiment, so
    the planned design's truth is the hull's full 25-term structure."""
    d = study.designs(True, planned=True)
    system, n, k, _ = d["CyberShip II planned, white current"]
    assert (n, k) == (1000, 4)
    _experiments_changing_sign(system, n, k)


@pytest.mark.slow
def test_monte_carlo_viknes_manoeuvres_selection(study):
    """40 seeded Viknes 830 thruster-square logs (Gauss–Markov current inside the
    modulus), selection from the library model: the true structure (10 terms) in at
    least 95 % of the runs and no zero term in more than 5 %, both within one-sided
    binomial tolerances (z = 2.33) of the runs."""
    import math
    import warnings

    from vesselid.selection import select_terms
    from vesselid.selection.library import canonical, resolve_library

    runs = 40
    d = study.designs(False, manoeuvres=True)
    system, n, k, library = d["Viknes 830 manoeuvres, Gauss-Markov current"]
    truth = (system.model or system.spec).with_aggregate(None)
    base = study.linear_base(truth)
    lib = resolve_library(library, base)
    exact = 0
    false_kept: dict[str, int] = {}
    for r in range(runs):
        log = system.simulate(n, k, seed=np.random.SeedSequence([12, r])).to_log(
            aggregate=False)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            res = select_terms(log, base, lib, n_boot=0, first_model="library")
        rep = {(x.equation, x.term): (x.represented_by or x.term)
               for x in res.table.itertuples()}
        ok = True
        for s in truth.states:
            true = {rep[(s, str(canonical(t)))] for t in truth.equations[s]}
            picked = {rep[(s, t)] for t in res.selected[s]}
            ok &= picked == true
            for t in picked - true:
                false_kept[f"{s}: {t}"] = false_kept.get(f"{s}: {t}", 0) + 1
        exact += ok
    tol = 2.33 * math.sqrt(0.95 * 0.05 / runs)
    assert exact / runs >= 0.95 - tol
    assert max(false_kept.values(), default=0) / runs <= 0.05 + tol


def test_detectable_structure_up_to_undecided_pairs(study):
    """The selection read with its undecided pairs: run 3's zero term f*x reported as
    undecided with the true f stands for f (ukeep/utkeep columns), so every run has the
    detectable structure; FROLS has no such columns and is left out."""
    df = _table()
    power = study.power_table(df, _truth(), 10000, 12)
    iv = df.method == "ivsel"
    for term in ("x", "x*|x|", "f", "f*x"):
        df.loc[iv, f"ukeep|x|{term}"] = df.loc[iv, f"keep|x|{term}"]
    df.loc[iv & (df.run == 3), "ukeep|x|f*x"] = False
    for term in ("x", "x*|x|", "f"):
        df.loc[iv, f"utkeep|x|{term}"] = df.loc[iv, f"ukeep|x|{term}"]
    det = study.detectable_structure(df, power, prefix="u")
    assert det == {"ivsel": pytest.approx(1.0)}
    # without the reading, run 3 fails
    assert study.detectable_structure(df, power)["ivsel"] == pytest.approx(0.75)


def test_wilson_interval_by_hand(study):
    # k = 8 of n = 10: centre (0.8 + z²/20)/(1 + z²/10), half-width
    # z √(0.8·0.2/10 + z²/400)/(1 + z²/10), z = 1.959964
    z = 1.959964
    den = 1 + z * z / 10
    mid = (0.8 + z * z / 20) / den
    half = z * math.sqrt(0.016 + z * z / 400) / den
    lo, hi = study.wilson(8, 10)
    assert (lo, hi) == pytest.approx((mid - half, mid + half))
    assert study.wilson(0, 20)[0] == 0.0 and study.wilson(20, 20)[1] == 1.0
    assert study.wilson(0, 20)[1] == pytest.approx(z * z / (20 + z * z))


def test_summary_table_counts(study):
    df = _table()
    df["base"] = "linear"
    df.loc[df.method == "ivsel", "cpu_seconds"] = [1.0, 2.0, 3.0, 4.0]
    power = study.power_table(df, _truth(), 10000, 12)
    tab = study.summary_table(df, power).set_index(["method", "measure"])
    # 'a' (ivsel): never the true structure; keeps the zero term f*x in run 3
    assert tab.loc[("ivsel", "true_structure"), "count"] == 0
    worst = tab.loc[("ivsel", "worst_zero_term")]
    assert (worst["count"], worst["runs"], worst["term"]) == (1, 4, "x: f*x")
    assert tab.loc[("ivsel", "detectable_structure"), "count"] == 3
    assert tab.loc[("frols", "true_structure"), "count"] == 4
    # oracle: |t| of x*|x| is 2 < 3.5 in every run: never the whole structure, always
    # the detectable one (x, f); its intervals cover in runs 1-3
    assert tab.loc[("oracle", "true_structure"), "count"] == 0
    assert tab.loc[("oracle", "detectable_structure"), "count"] == 4
    cov = tab.loc[("oracle", "coverage")]
    assert (cov["count"], cov["runs"]) == (9, 12)
    assert (cov["wilson_lo"], cov["wilson_hi"]) == pytest.approx(study.wilson(9, 12))
    assert tab.loc[("ivsel", "median_cpu_seconds_per_run"), "share"] == 2.5


def test_run_seed_is_the_spawned_child(study):
    kids = np.random.SeedSequence([7, 3]).spawn(5)
    for r in (0, 4):
        assert (study.run_seed(7, 3, r).generate_state(4) == kids[r].generate_state(4)).all()


def test_results_do_not_depend_on_workers(study, tmp_path):
    """Two heave runs on one process and on two: the same per-run table."""
    out = {}
    for w in (1, 2):
        path = tmp_path / f"w{w}.csv"
        study.main(["--system", "heave", "--design", "white", "--quick", "--runs", "2",
                    "--oracle-runs", "2", "--comparators", "off", "--workers", str(w),
                    "--out", str(path), "--summary-out", str(tmp_path / f"w{w}.json")])
        out[w] = pd.read_csv(path).drop(columns=["seconds", "cpu_seconds"])
    pd.testing.assert_frame_equal(out[1], out[2])
    assert set(out[1]["method"]) == {"ivsel"} and out[1]["run"].tolist() == [0, 1]


def test_squares_design_changes_signs(study):
    """The thruster squares make u, v and r change sign, with v and r of equal and of
    opposite signs, within every experiment: the truth is the full 25-term structure."""
    d = study.designs(True, squares=True)
    system, n, k, _ = d["CyberShip II squares, Gauss-Markov current"]
    assert (n, k) == (2500, 4)
    for g in _experiments_changing_sign(system, n, k):
        vr = np.sign(g["v"].to_numpy() * g["r"].to_numpy())
        assert (vr > 0).mean() > 0.1 and (vr < 0).mean() > 0.1


def test_oracle_bias_by_hand(study):
    """The oracle's bias per term: from the ``oracle_est|`` columns where the table has
    them, else ``sign(θ0)·|t|·SE`` for terms with ``|t| ≥ 4`` in every run (``x*|x|``,
    ``|t| = 2``, gets none)."""
    df = _table()
    power = study.power_table(df, _truth(), 10000, 12).set_index("term")
    # x and f: sign(θ0)·|t|·SE is the same in every run (no spread: undefined)
    assert np.isnan(power.loc["x", "oracle_bias_z"])
    assert np.isnan(power.loc["f", "oracle_bias_sd"])
    assert np.isnan(power.loc["x*|x|", "oracle_bias_sd"])
    iv = df.method == "ivsel"
    df.loc[iv, "oracle_est|x|f"] = est = np.array([0.49, 0.52, 0.47, 0.55])
    power = study.power_table(df, _truth(), 10000, 12).set_index("term")
    sd = est.std(ddof=1)
    assert power.loc["f", "oracle_bias_sd"] == pytest.approx((est.mean() - 0.5) / sd)
    assert power.loc["f", "oracle_bias_z"] == pytest.approx((est.mean() - 0.5) / (sd / 2))
    assert power.loc["f", "oracle_se_over_sd"] == pytest.approx(0.05 / sd)
    df.loc[iv, "oracle_t|x|x"] = [88.0, 90.0, 91.0, 93.0]
    power = study.power_table(df, _truth(), 10000, 12).set_index("term")
    x = np.array([88.0, 90.0, 91.0, 93.0]) * 0.01
    assert power.loc["x", "oracle_bias_z"] == pytest.approx(
        (x.mean() - 0.9) / (x.std(ddof=1) / 2))
