"""Coverage of the reported confidence intervals (Monte Carlo, binomial tolerances)."""

from __future__ import annotations

import numpy as np
import pytest
from _stats import binomial_ok
from scipy import stats

from vesselid.calibration import coverage_table, wilson_interval


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
@pytest.mark.parametrize("scenario", ["table1-random", "gm-current-random"])
def test_default_covariance_covers_95_percent(scenario):
    """The default estimator's default-covariance 95 % intervals cover θ0 at the nominal
    rate on the paper's white design and under a coloured (Gauss–Markov) current:
    binomial test at α = 0.001 on 150 runs per parameter. The test can fail: on the
    coloured current the white-noise formula applied to the paper's IV_{E{ζ}=0} (whose
    equation error stays coloured, unlike the default's prefiltered one) covers ~60 %."""
    from vesselid.calibration import coverage_study

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
