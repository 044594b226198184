"""Specification tests (first stage, J/C, Durbin–Wu–Hausman, whiteness) against linearmodels."""

from __future__ import annotations

import linearmodels.iv as lm_iv
import numpy as np
import pytest

from vesselid.identify.specification import (
    difference_in_j,
    endogeneity_test,
    first_stage,
    hansen_j,
    ljung_box,
    residual_correlations,
)


def _endogenous(rng, n=600, rho=0.6, const=0.2):
    """y = 1·x + 0.5·u + c + e with x correlated with e; instruments z1, z2 and u."""
    z = rng.normal(size=(n, 2))
    u = rng.normal(size=n)
    e = rng.normal(size=n)
    x = z @ np.array([0.8, 0.5]) + 0.3 * u + rho * e + rng.normal(size=n)
    y = x + 0.5 * u + const + e
    return y, np.column_stack([x, u]), np.column_stack([z, u])


def test_first_stage_partial_f_matches_linearmodels():
    rng = np.random.default_rng(0)
    y, phi, z = _endogenous(rng)
    fs = first_stage(z, phi, zero_mean=True, skip_first=False, names=["x", "u"])
    assert fs["endogenous"] == ["x"]
    ref = lm_iv.IV2SLS(y, np.column_stack([np.ones(y.size), phi[:, 1]]), phi[:, 0], z[:, :2]
                       ).fit(cov_type="unadjusted").first_stage.diagnostics
    assert fs["partial_f"]["x"] == pytest.approx(float(ref["f.stat"].iloc[0]), rel=1e-8)
    assert fs["partial_r2"]["x"] == pytest.approx(float(ref["partial.rsquared"].iloc[0]), rel=1e-8)
    # one endogenous regressor: Cragg–Donald equals the partial F
    assert fs["cragg_donald"] == pytest.approx(fs["partial_f"]["x"], rel=1e-8)
    weak = first_stage(rng.normal(size=(600, 2)), phi[:, :1], skip_first=False)
    assert weak["cragg_donald"] < 10 < fs["cragg_donald"]


def test_hansen_j_matches_ivgmm_and_c_test():
    rng = np.random.default_rng(1)
    y, phi, z = _endogenous(rng, const=0.0)
    bad = z[:, 0] + 0.5 * (y - phi @ np.array([1.0, 0.5]))  # correlated with the error
    zz = np.column_stack([z, rng.normal(size=y.size) + phi[:, 0] * 0.3, bad])
    res = hansen_j(zz[:, :4], phi, y, zero_mean=False, skip_first=False, cov_type="hac",
                   kernel="bartlett", bandwidth=3)
    ref = lm_iv.IVGMM(y, phi[:, 1:], phi[:, :1], zz[:, [0, 1, 3]], weight_type="kernel",
                      kernel="bartlett", bandwidth=3).fit(iter_limit=2)
    assert res.stat == pytest.approx(float(ref.j_stat.stat), rel=1e-8)
    assert res.df == int(ref.j_stat.df) == 2
    c = difference_in_j(zz, phi, y, [4], zero_mean=False, skip_first=False, cov_type="hac",
                        kernel="bartlett", bandwidth=3)
    assert c.df == 1 and c.pvalue < 1e-6 and "rejected" in c.sentence
    c_ok = difference_in_j(zz[:, :4], phi, y, [3], zero_mean=False, skip_first=False)
    assert c_ok.stat >= 0 and c_ok.df == 1


def test_endogeneity_test_matches_wu_hausman_and_says_it_plainly():
    rng = np.random.default_rng(2)
    y, phi, z = _endogenous(rng)
    res = endogeneity_test(z, phi, y, zero_mean=True, skip_first=False, cov_type="unadjusted")
    ref = lm_iv.IV2SLS(y, np.column_stack([np.ones(y.size), phi[:, 1]]), phi[:, 0], z[:, :2]
                       ).fit(cov_type="unadjusted").wu_hausman()
    # chi² form with the augmented regression's σ² = F × q × (n−k−q)/n … compare p-values
    assert res.pvalue < 1e-6 and float(ref.pval) < 1e-6
    assert res.sentence.startswith("LS is biased on this log: p ")
    y0, phi0, z0 = _endogenous(np.random.default_rng(3), rho=0.0)
    ok = endogeneity_test(z0, phi0, y0, skip_first=False, cov_type="unadjusted")
    ref0 = lm_iv.IV2SLS(y0, np.column_stack([np.ones(y0.size), phi0[:, 1]]), phi0[:, 0],
                        z0[:, :2]).fit(cov_type="unadjusted").wu_hausman()
    n, k, q = y0.size, 3, 1
    assert ok.stat == pytest.approx(float(ref0.stat) * q * n / (n - k - q), rel=1e-8)
    if ok.pvalue >= 0.05:
        assert ok.sentence.startswith("no evidence that LS is biased: p ")


def test_ljung_box_sums_experiments_and_matches_statsmodels():
    import statsmodels.stats.diagnostic as sm
    rng = np.random.default_rng(4)
    white = rng.normal(size=2000)
    ma = np.convolve(rng.normal(size=2001), [1.0, -0.7], "valid")
    resid = np.column_stack([white, ma])
    starts = np.array([0, 1000, 2000])
    out = ljung_box(resid, starts, lags=10, skip_first=False, names=["w", "m"])
    q = sum(float(sm.acorr_ljungbox(white[a:b] - white[a:b].mean(), lags=[10])["lb_stat"].iloc[0])
            for a, b in ((0, 1000), (1000, 2000)))
    assert out["w"].stat == pytest.approx(q) and out["w"].df == 20
    assert out["m"].pvalue < 1e-6 and "not white" in out["m"].sentence


def test_residual_correlations_find_a_delayed_input_and_respect_experiments():
    rng = np.random.default_rng(5)
    n = 3000
    u = rng.normal(size=n)
    e = rng.normal(size=n) + 0.5 * np.roll(u, 3)  # residual depends on u(k−3)
    rc = residual_correlations(e, u, np.array([0, 1500, 3000]), max_lag=10, skip_first=False)
    assert rc.acf[0, 0] == pytest.approx(1.0)
    k = int(np.argmax(np.abs(rc.ccf[0, 0])))
    assert rc.cross_lags[k] == 3 and abs(rc.ccf[0, 0, k]) > 5 * rc.band
    assert rc.band == pytest.approx(2.5758 / np.sqrt(3000), rel=1e-3)
    assert set(rc.to_dict()) >= {"acf", "ccf", "band"}


def test_identify_reports_diagnostics_and_plots_residuals():
    import json
    import warnings

    from vesselid.identify import identify
    from vesselid.plant.systems import heave

    log = heave(pulse_design="alternating").simulate(3000, 1, seed=6).to_log()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = identify(log)
    # an instrumental estimate (a likelihood fit has no instrument diagnostics)
    assert res.diagnostics["choice"] == "combined"
    text = res.summary()
    assert "LS is biased on this log" in text or "no evidence that LS is biased" in text
    assert "Ljung-Box" in text and "Cragg-Donald" in text
    json.loads(json.dumps(res.to_dict(), allow_nan=False))
    fig = res.plot_residuals()
    assert len(fig.axes) == 2
    rc = res.diagnostics["residual_correlation"]
    assert len(rc["acf"][0]) == len(rc["lags"]) and rc["band"] > 0


def test_equations_with_the_same_rows_share_their_work_and_get_the_same_numbers():
    """``shared``: a second equation with the same instruments and regressors (another
    target) reuses the prepared rows, first stage and first-stage residuals; its results
    are those of a call on its own, and a third equation with other regressors is not
    served from the shared work."""
    from vesselid.identify.specification import equation_diagnostics

    rng = np.random.default_rng(3)
    y, phi, z = _endogenous(rng, n=900)
    y2 = y + 0.7 * phi[:, 0] + rng.normal(size=y.size)
    z3 = z.copy()
    z3[:, 0] += 0.3 * rng.normal(size=z.shape[0])
    starts = np.array([0, 400, 900])
    opts = {"names": ["x", "u"], "skip_first": True}
    shared: dict = {}
    got = [equation_diagnostics(zz, phi, yy, starts, shared=shared, **opts)
           for zz, yy in ((z, y), (z, y2), (z3, y2))]
    alone = [equation_diagnostics(zz, phi, yy, starts, **opts)
             for zz, yy in ((z, y), (z, y2), (z3, y2))]
    assert got == alone
    assert got[0]["endogeneity"] != got[1]["endogeneity"]  # the target does matter
    assert got[1]["first_stage"] is not got[0]["first_stage"]  # copies, not one object
    assert got[2]["first_stage"] != got[1]["first_stage"]
