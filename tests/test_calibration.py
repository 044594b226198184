"""Coverage of the reported confidence intervals (Monte Carlo, binomial tolerances)."""

from __future__ import annotations

import numpy as np
import pytest
from _stats import binomial_ok, bonferroni_z
from scipy import stats

from vesselid.studies.calibration import coverage_table, wilson_interval


def test_wilson_interval_matches_statsmodels():
    import statsmodels.stats.proportion as sm
    for k, n in ((0, 10), (37, 40), (380, 400), (400, 400)):
        lo, hi = wilson_interval(k, n)
        ref = sm.proportion_confint(k, n, alpha=0.05, method="wilson")
        np.testing.assert_allclose([lo, hi], ref, rtol=1e-12, atol=1e-15)


def test_coverage_table_counts_and_ratios():
    rng = np.random.default_rng(0)
    theta = rng.normal(size=(2000, 2)) * np.array([1.0, 2.0])
    se = np.column_stack([np.ones(2000), np.ones(2000)])  # second parameter: SE too small
    tab = coverage_table(theta, se, np.zeros(2), ["a", "b"])
    p_a = 2 * stats.norm.cdf(1.959964) - 1
    assert abs(tab.loc[0, "coverage"] - p_a) < 3 * np.sqrt(p_a * (1 - p_a) / 2000)
    assert tab.loc[1, "coverage"] < 0.8 and tab.loc[1, "se_ratio"] == pytest.approx(0.5, rel=0.05)
    assert (tab["runs"] == 2000).all()


@pytest.mark.slow
@pytest.mark.parametrize("scenario", ["table1-alternating", "table1-random", "table2",
                                      "gm-current-random", "gm-sensor-alternating"])
def test_default_covariance_covers_95_percent(scenario):
    """The default estimator's default-covariance 95 % intervals cover θ0 at the nominal
    rate on the paper's white design, under a coloured (Gauss–Markov) current and under
    coloured sensor noise: binomial test at α = 0.001 on 150 runs per parameter. The
    test can fail: on the coloured current the white-noise formula applied to the
    paper's IV_{E{ζ}=0} (whose equation error stays coloured, unlike the default's
    prefiltered one) covers ~60 %; under coloured sensor noise ``auto`` with the C test
    alone kept the invalid delayed instruments in ~10 % (alternating pulses) to ~56 %
    (random pulses) of runs (random pulses: next test)."""
    from vesselid.studies.calibration import coverage_study

    runs = 150
    tab = coverage_study(scenario, runs, seed=11, covariances={"hac": ("hac", {})})
    assert (tab["runs"] == runs).all()
    for _, r in tab.iterrows():
        hits = round(r["coverage"] * r["runs"])
        assert binomial_ok(hits, int(r["runs"]), 0.95), (scenario, r["parameter"], r["coverage"])
    if scenario == "gm-current-random":
        unadj = coverage_study(scenario, runs, seed=11, method="iv-zero-mean",
                               covariances={"unadjusted": ("unadjusted", {})})
        worst = unadj.sort_values("coverage").iloc[0]
        assert not binomial_ok(round(worst["coverage"] * worst["runs"]),
                               int(worst["runs"]), 0.95)


@pytest.mark.slow
def test_default_estimator_not_fooled_by_coloured_sensor_noise():
    """Gauss–Markov sensor noise with random pulses: the delayed measurements are invalid
    but the C test alone keeps them in ~56 % of runs, and ``auto`` then covered θ0 in
    39–67 % of runs (150 runs, this seed). With the colour test it falls back to SRIV;
    coverage must not be significantly below 93 % (the lower edge of the acceptance band;
    one-sided exact binomial test at α = 0.001). Not tested against 95 %: the HAC SEs of
    every simulated-instrument estimator are 0.8–0.9× the Monte Carlo spread here
    (IV_{E{ζ}=0} and SRIV cover 89–97 % on these runs; docs/guide/uncertainty.md)."""
    from vesselid.studies.calibration import coverage_study

    runs = 150
    tab = coverage_study("gm-sensor-random", runs, seed=11, covariances={"hac": ("hac", {})})
    for _, r in tab.iterrows():
        hits = round(r["coverage"] * r["runs"])
        p = stats.binomtest(hits, int(r["runs"]), 0.93, alternative="less").pvalue
        assert p > 1e-3, (r["parameter"], r["coverage"], p)


@pytest.mark.slow
def test_default_covariance_matches_the_spread_on_the_default_sea_trial():
    """CyberShip II sea trial as ``simulate_sea_trial`` gives it (default design, the
    anemometer's wind load among the forces), default estimator and covariance, 20 runs:
    per parameter the RMS reported SE is within the sampling error of the Monte Carlo
    spread, ``|log(SE / sd)| ≤ z · SE(log sd)`` with ``SE(log sd) = √((κ − 1)/(4n))``
    (κ the sample kurtosis of the errors, at least 3) and a Bonferroni ``z`` over the 25
    parameters (α = 0.001; ratio band ≈ [0.5, 1.9] at κ = 3). It can fail: the old
    calibration trial (static offsets, wind load not measured) gave ratios 1.2–3.6 (median
    1.65 on 30 runs; docs/guide/uncertainty.md)."""
    from vesselid.studies.calibration import seatrial_coverage

    runs = 20
    tab = seatrial_coverage(runs, seed=3, covariances={"hac": ("hac", {})})
    z = bonferroni_z(len(tab))
    for _, r in tab.iterrows():
        assert r["runs"] == runs, r["parameter"]
        kurt = max(3.0, float(r["kurtosis"]))
        tol = z * np.sqrt((kurt - 1.0) / (4.0 * runs))  # SE of log(sd), delta method
        assert abs(np.log(r["se_ratio"])) <= tol, (r["parameter"], r["se_ratio"], tol)


def test_calibration_script_pem_level_and_colour_guard_need_by_choice():
    """``--pem-level`` and ``--colour-guard`` apply to ``--by-choice`` only, with a value in
    (0, 1] and [0, 1): a one-line usage error (exit 2) otherwise."""
    from _scripts import load_script

    script = load_script("calibration")
    for argv in (["--pem-level", "0.5"],
                 ["--by-choice", "gm-sensor-random", "--pem-level", "0"],
                 ["--by-choice", "gm-sensor-random", "--pem-level", "1.5"],
                 ["--colour-guard", "0"],
                 ["--by-choice", "gm-sensor-random", "--colour-guard", "1"]):
        with pytest.raises(SystemExit) as exc:
            script.main(argv)
        assert exc.value.code == 2
