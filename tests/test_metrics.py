"""One normalised-error and one NRMSE definition, used the same way everywhere."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from vesselid.identify.diagnostics import normalized_error, nrmse, nrmse_fit, nrmse_ratio


def test_normalized_error_is_nan_where_theta0_is_zero() -> None:
    est = np.array([1.5, 2.0, -3.0])
    th0 = np.array([1.0, 0.0, -2.0])
    with np.errstate(all="raise"):  # no division warning leaks out
        err = normalized_error(est, th0)
    assert err[0] == pytest.approx(0.5) and err[2] == pytest.approx(0.5)
    assert np.isnan(err[1])


def test_nrmse_error_and_fit_are_one_ratio() -> None:
    rng = np.random.default_rng(0)
    y = rng.standard_normal(200)
    y_hat = y + 0.3 * rng.standard_normal(200)
    r = np.linalg.norm(y - y_hat) / np.linalg.norm(y - y.mean())
    assert nrmse_ratio(y, y_hat) == pytest.approx(r, rel=1e-12)
    assert nrmse(y, y_hat) == pytest.approx(100 * r, rel=1e-12)
    assert nrmse_fit(y, y_hat) == pytest.approx(100 * (1 - r), rel=1e-12)
    assert nrmse(y, y) == 0.0 and nrmse_fit(y, y) == 100.0
    assert np.isnan(nrmse(np.ones(5), np.zeros(5)))  # ‖y − ȳ‖ = 0: undefined


@pytest.mark.filterwarnings("ignore::vesselid.errors.ExperimentDesignWarning")
def test_sea_trial_nrmse_is_the_complement_of_the_result_fit() -> None:
    from vesselid.identify import identify
    from vesselid.plant.catalogue import get_system
    from vesselid.studies.seatrial import free_run_nrmse, normalized_errors

    system = get_system("heave")
    log = system.simulate(1500, n_runs=2, seed=2).to_log()
    res = identify(log, method="iv-zero-mean")
    err = free_run_nrmse(log, res.spec, res.params.to_numpy())
    fit = res.diagnostics["fit_free_run"]
    for s in res.spec.states:
        assert err[s] == pytest.approx(100.0 - fit[s], rel=1e-12, abs=1e-10)
    cmp = res.compare()
    ne = normalized_errors(res.params, res.spec.theta0_series())
    pd.testing.assert_series_equal(ne, cmp["normalized_error"], check_names=False)
