"""Errors-in-variables correction of the square modulus regressors (vesselid.identify.eiv)."""

import warnings

import numpy as np
import pandas as pd
import pytest

from vesselid.data.logs import TrialLog
from vesselid.errors import IdentificationError
from vesselid.identify import identify
from vesselid.identify.eiv import (
    correct_regressors,
    modulus_bias,
    noise_vector,
    regressor_error_mean,
    resolve_sensor_noise,
    signed_square_bias,
)
from vesselid.model.spec import ModelSpec

SPEC = ModelSpec("toy", ["x"], ["u"], {"x": ["x", "x*|x|", "u"]})
THETA = np.array([0.9, -1.0, 0.05])


def _toy_log(seed: int, sigma: float, n: int = 20000, experiments: int = 4,
             process: float = 0.002) -> TrialLog:
    """x(k+1) = 0.9 x − x|x| + 0.05 u + w under a ±1 square input of random amplitude
    (x changes sign every 2.5 s, |x| ≈ 0.15), measured as y = x + e, e ~ N(0, σ²)."""
    rng = np.random.default_rng(seed)
    frames = []
    for e in range(experiments):
        amp = rng.uniform(0.7, 1.3, n // 25 + 1).repeat(25)[:n]
        u = np.where((np.arange(n) // 25) % 2 == 0, 1.0, -1.0) * amp
        w = process * rng.standard_normal(n)
        x = np.zeros(n)
        for k in range(n - 1):
            x[k + 1] = THETA[0] * x[k] + THETA[1] * x[k] * abs(x[k]) + THETA[2] * u[k] + w[k]
        y = x + sigma * rng.standard_normal(n)
        frames.append(pd.DataFrame({"time": np.arange(n) * 0.1, "experiment": e, "x": y,
                                    "u": u}))
    return TrialLog(pd.concat(frames, ignore_index=True))


def _fit(log, method="sriv", **kw):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return identify(log, SPEC, method=method, **kw)


def test_correction_of_the_columns():
    """x·|x| columns lose σ² sign(x(k−1)), x·x columns σ²; cross terms, inputs and the
    NaN first row of each segment are untouched; σ = 0 or None returns phi itself."""
    spec = ModelSpec("m", ["x", "y"], ["u"], {"x": ["x*|x|", "y", "x*x", "x*|y|", "u"],
                                              "y": ["y*|y|", "x*y", "|x|*x"]})
    codes = spec.codes
    sig = np.array([[0.5, -0.2], [-0.3, 0.4], [0.0, 0.1]])
    u = np.ones((3, 1))
    from vesselid.identify.backend import kernels

    phi = kernels.regressor_matrix(sig, u, np.array([0, 3]), codes.factors)
    noise = np.array([0.1, 0.2])
    got = correct_regressors(phi, sig, codes.factors, codes.n_signals, noise)
    want = phi.copy()
    want[1:, 0] -= 0.1**2 * np.sign(sig[:-1, 0])
    want[1:, 2] -= 0.1**2
    want[1:, 5] -= 0.2**2 * np.sign(sig[:-1, 1])
    want[1:, 7] -= 0.1**2 * np.sign(sig[:-1, 0])
    np.testing.assert_array_equal(got, want)
    assert np.all(np.isnan(got[0]))
    assert correct_regressors(phi, sig, codes.factors, codes.n_signals, None) is phi
    assert noise_vector(["x", "y"], {"x": 0.0}) is None
    assert resolve_sensor_noise(False, {"sensor_noise_std": {"x": 0.1}}, ["x"]) is None
    np.testing.assert_array_equal(resolve_sensor_noise(None, {"sensor_noise_std": {"y": 0.2}},
                                                       ["x", "y"]), [0.0, 0.2])


def test_corrected_regressor_is_conditionally_unbiased():
    """E[h(x+e) | x] = x|x| for |x| ≫ σ (5-20 σ, both signs): the corrected regressor's
    mean error is within 4 sample SE of zero, the raw y|y|'s is σ²·sign(x)."""
    rng = np.random.default_rng(7)
    sigma, n = 0.01, 400_000
    x = rng.uniform(5, 20, n) * sigma * rng.choice([-1.0, 1.0], n)
    y = x + sigma * rng.standard_normal(n)
    layout = SPEC.codes
    sig = np.column_stack([y, x])[:, :1]
    phi = np.full((n, 3), np.nan)
    phi[1:, 1] = sig[:-1, 0] * np.abs(sig[:-1, 0])
    h = correct_regressors(phi, sig, layout.factors, layout.n_signals, np.array([sigma]))
    err_raw = (phi[1:, 1] - x[:-1] * np.abs(x[:-1])) * np.sign(x[:-1])
    err = (h[1:, 1] - x[:-1] * np.abs(x[:-1])) * np.sign(x[:-1])
    assert abs(err.mean()) <= 4 * err.std() / np.sqrt(err.size)
    se_raw = err_raw.std() / np.sqrt(err_raw.size)
    assert abs(err_raw.mean() - sigma**2) <= 4 * se_raw
    assert err_raw.mean() > 10 * se_raw  # the raw regressor's bias is resolved: the test can fail


@pytest.mark.parametrize("x", [0.0, 0.3, -0.6, 1.0, -2.5, 4.0])
def test_conditional_means_against_numerical_integration(x):
    """E[|x+e|] − |x| and E[(x+e)|x+e| − σ² sign(x+e)] − x|x| (e ~ N(0, σ²)) by
    quadrature against the closed forms, near zero speed where the corrected score is not
    exact; at x = 0 the modulus bias is 2σφ(0) = σ·√(2/π) and the score's is 0."""
    from scipy import integrate, stats

    sigma = 0.5
    xs = x * sigma

    def expect(f):
        return integrate.quad(lambda e: f(xs + e) * stats.norm.pdf(e, 0, sigma),
                              -12 * sigma, 12 * sigma, points=[-xs], epsabs=1e-14)[0]

    mod = expect(np.abs) - abs(xs)
    sq = expect(lambda y: y * abs(y) - sigma**2 * np.sign(y)) - xs * abs(xs)
    assert modulus_bias(np.array(xs), sigma) == pytest.approx(mod, abs=1e-12)
    assert signed_square_bias(np.array(xs), sigma) == pytest.approx(sq, abs=1e-12)
    if x == 0.0:
        assert modulus_bias(np.array(0.0), sigma) == pytest.approx(sigma * np.sqrt(2 / np.pi))
    assert modulus_bias(np.array(xs), 0.0) == 0.0


def test_regressor_error_mean_is_the_mean_of_the_corrected_columns():
    """CyberShip II's 25 regressor columns at one true state near zero sway speed and yaw
    rate (v = 0.4σ_v, r = −0.5σ_r, u = 0.6 m/s, forces fixed), 100 000 noisy
    measurements: the mean error of the corrected columns (correct_regressors) equals
    regressor_error_mean within 4 sample standard errors, column by column, and the
    cross-modulus columns' mean error (v·|r|, r·|v|) is resolved (more than 10 SE)."""
    from vesselid.identify.backend import kernels
    from vesselid.plant.closedloop import DESIGNS

    spec = DESIGNS["3dof"]().spec
    codes = spec.codes
    sigma = np.array([0.005, 0.005, 0.002])
    x = np.array([0.6, 0.4 * 0.005, -0.5 * 0.002])
    forces = np.array([1.5, -0.2, 0.1])
    n = 100_000
    rng = np.random.default_rng(11)
    y = x + sigma * rng.standard_normal((n, 3))
    u = np.tile(forces, (n, 1))
    starts = np.array([0, n])
    phi = correct_regressors(kernels.regressor_matrix(y, u, starts, codes.factors), y,
                             codes.factors, codes.n_signals, sigma)
    truth = kernels.regressor_matrix(np.tile(x, (n, 1)), u, starts, codes.factors)
    err = (phi - truth)[1:]
    want = regressor_error_mean(np.tile(np.r_[x, forces], (n, 1)), codes.factors,
                                codes.n_signals, sigma)
    assert np.all(np.isnan(want[0])) and np.allclose(want[1:], want[1])
    se = err.std(axis=0, ddof=1) / np.sqrt(err.shape[0])
    assert np.all(np.abs(err.mean(axis=0) - want[1]) <= 4 * se + 1e-15), (
        err.mean(axis=0) - want[1]) / se
    terms = [f"{e}: {t}" for e, t in spec.param_index]
    for name in ("v: v*|r|", "v: r*|v|"):
        k = terms.index(name)
        assert abs(want[1, k]) > 10 * se[k]


def test_exact_on_noise_free_data_and_unchanged_with_zero_sigma():
    """No noise at all: SRIV recovers θ0 exactly; σ = 0 (or False) gives the results
    of the uncorrected estimator bit for bit."""
    log = _toy_log(0, 0.0, n=1500, experiments=2, process=0.0)
    res = _fit(log, sensor_noise={"x": 0.0})
    np.testing.assert_allclose(res.params.to_numpy(), THETA, rtol=0, atol=1e-9)
    noisy = _toy_log(1, 0.02, n=1500, experiments=2)
    a, b = _fit(noisy, "auto"), _fit(noisy, "auto", sensor_noise={"x": 0.0})
    np.testing.assert_array_equal(a.params.to_numpy(), b.params.to_numpy())
    np.testing.assert_array_equal(a.std_errors.to_numpy(), b.std_errors.to_numpy())
    assert a.diagnostics["sensor_noise_correction"] == "none"
    c = _fit(TrialLog(noisy.data, {"sensor_noise_std": {"x": 0.0}}), "auto", sensor_noise=False)
    np.testing.assert_array_equal(a.params.to_numpy(), c.params.to_numpy())


def test_bias_removed_with_known_sigma():
    """y = x + e (σ = 0.03, |x| ≈ 0.15, x changes sign within each experiment): over 3
    seeds the mean of (θ̂ − θ0)/SE is within 3.5/√3 of zero for every parameter with the
    correction (option or log metadata); without it the x coefficient's is not."""
    z_raw, z_cor = [], []
    for seed in range(3):
        log = _toy_log(seed, 0.03)
        raw = _fit(log)
        cor = _fit(TrialLog(log.data, {"sensor_noise_std": {"x": 0.03}}))
        np.testing.assert_array_equal(
            cor.params.to_numpy(), _fit(log, sensor_noise={"x": 0.03}).params.to_numpy())
        assert "corrected" in cor.diagnostics["sensor_noise_correction"]
        z_raw.append((raw.params.to_numpy() - THETA) / raw.std_errors.to_numpy())
        z_cor.append((cor.params.to_numpy() - THETA) / cor.std_errors.to_numpy())
    limit = 3.5 / np.sqrt(3)
    assert np.all(np.abs(np.mean(z_cor, axis=0)) <= limit)
    assert np.mean(z_raw, axis=0)[0] > limit  # the bias the correction removes


@pytest.mark.parametrize("bad", [{"w": 0.1}, {"x": -1.0}, {"x": "a"}, {"x": np.nan}, [0.1]])
def test_bad_sensor_noise_is_a_clear_error(bad):
    log = _toy_log(0, 0.01, n=200, experiments=1)
    with pytest.raises(IdentificationError, match="sensor_noise"):
        _fit(log, sensor_noise=bad)


def test_cli_sensor_noise_option(tmp_path, capsys):
    """`identify --sensor-noise x=0.03` corrects (and says so), `none` does not, a bad
    value exits 2 with one line."""
    from vesselid.cli import main

    log = _toy_log(0, 0.03, n=1500, experiments=2)
    path = log.save(tmp_path / "toy.csv")
    model = SPEC.save(tmp_path / "toy.toml")
    assert main(["identify", str(path), "--model", str(model), "--method", "sriv",
                 "--sensor-noise", "x=0.03"]) == 0
    assert "sensor noise correction: square modulus regressors corrected" in capsys.readouterr().out
    assert main(["identify", str(path), "--model", str(model), "--method", "sriv",
                 "--sensor-noise", "none"]) == 0
    assert "sensor noise correction" not in capsys.readouterr().out
    assert main(["identify", str(path), "--model", str(model), "--sensor-noise", "x=-1"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--sensor-noise" in err[0]


def test_sea_trial_records_the_regressor_noise():
    """`sea-trial` writes the std of the (clipped at ±3σ) white noise on the regressor signals
    (speed log for u, v; gyro for r); a low-pass-filtered log drops it."""
    from math import erf, erfc, exp, pi, sqrt

    from vesselid.data.wavefilter import WaveFilter, wave_filter_log
    from vesselid.studies.seatrial import simulate_sea_trial

    log = simulate_sea_trial(2, 300, seed=0, design="static-offset")
    c = 3.0
    factor = erf(c / sqrt(2)) - 2 * c * exp(-c * c / 2) / sqrt(2 * pi) + c * c * erfc(c / sqrt(2))
    got = log.metadata["sensor_noise_std"]
    assert got == pytest.approx({"u": 0.005 * sqrt(factor), "v": 0.005 * sqrt(factor),
                                 "r": 0.002 * sqrt(factor)}, rel=1e-12)
    rng = np.random.default_rng(0)
    e = np.clip(rng.standard_normal(400_000), -c, c)
    assert e.std() == pytest.approx(sqrt(factor), abs=4 * sqrt(factor) / sqrt(2 * e.size))
    filtered = wave_filter_log(log, WaveFilter(0.5, 0.1))
    assert "sensor_noise_std" not in filtered.metadata


def test_noise_order_is_the_option_never_the_log():
    """The `noise_order` option sets SRIV's AR order; a log's `metadata["noise_order"]`
    is ignored, with a warning naming the option (estimators without a prefilter say
    nothing); a bad order is a clear error; the sea trial writes none."""
    log = _toy_log(1, 0.02, n=1500, experiments=2)
    tagged = TrialLog(log.data, {"noise_order": 8})
    with pytest.warns(FutureWarning, match=r"metadata\['noise_order'\] \(8\).*ignored"):
        a = identify(tagged, SPEC, method="sriv")
    assert "AR(4)" in a.diagnostics["noise_model"]
    assert any("noise_order" in w for w in a.diagnostics["warnings"])
    np.testing.assert_array_equal(a.params.to_numpy(), _fit(log).params.to_numpy())
    b = _fit(log, noise_order=8)
    assert "AR(8)" in b.diagnostics["noise_model"]
    assert "AR(2)" in _fit(tagged, noise_order=2).diagnostics["noise_model"]
    with warnings.catch_warnings(record=True) as record:
        warnings.simplefilter("always")
        identify(tagged, SPEC, method="sriv", noise_order=8)  # the option given: no note
        zm = identify(tagged, SPEC, method="iv-zero-mean")  # no prefilter: no note either
    assert not any("noise_order" in str(r.message) for r in record)
    np.testing.assert_array_equal(zm.params.to_numpy(),
                                  _fit(log, "iv-zero-mean").params.to_numpy())
    for bad in (0, 51, 2.5, True):
        with pytest.raises(IdentificationError, match="noise_order"):
            _fit(log, noise_order=bad)
    from vesselid.studies.seatrial import simulate_sea_trial

    assert "noise_order" not in simulate_sea_trial(2, 300, seed=0, design="static-offset"
                                                   ).metadata
