"""Memory of ``identify`` on large logs: freed blocks leave the resident memory, and a
log beyond memory is refused with the way out (``--stream``)."""

from __future__ import annotations

import sys

import numpy as np
import pytest

from vesselid.cli import main


def test_unmap_large_blocks_keeps_arrays_working() -> None:
    from vesselid.core.memory import unmap_large_blocks

    done = unmap_large_blocks()
    assert done is sys.platform.startswith("linux") or done is False
    a = np.arange(1 << 18, dtype=float)  # 2 MiB: mapped from now on, same values
    assert a.sum() == (1 << 18) * ((1 << 18) - 1) / 2


def test_identify_refusal_names_stream(tmp_path, monkeypatch, capsys) -> None:
    log = tmp_path / "t.csv"
    assert main(["simulate", "--samples", "400", "--out", str(log)]) == 0
    capsys.readouterr()
    monkeypatch.setenv("VESSELID_MAX_MEMORY", "1M")
    assert main(["identify", str(log)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1
    assert "would need" in err and "--stream" in err


def test_bartlett_blocks_equal_the_whole_array_sums() -> None:
    """The bounded-memory Bartlett long-run covariance (blocks of rows, carried running
    sums) is the whole-array one to rounding, for block sizes below, at and above the
    lag window and a block count that does not divide the rows."""
    from vesselid.identify import covariance as cv

    rng = np.random.default_rng(3)
    n = 5003
    g = rng.standard_normal((n, 4)) + 0.4
    g[:, 0] += np.convolve(rng.standard_normal(n), np.ones(9), "same")  # coloured column
    for lags, rows in ((7, 512), (71, 64), (300, 128), (12, n), (1, 1)):
        ref = cv.bartlett_long_run(g, lags)
        got = cv._bartlett_blocks(g, lags, rows)
        assert np.max(np.abs(got - ref)) <= 1e-13 * np.max(np.abs(ref)), (lags, rows)
    # the lag-by-lag definition as well
    ref = cv.long_run_covariance(g, cv.kernel_weights("bartlett", 7, n))
    got = cv._bartlett_blocks(g, 7, 700)
    assert np.max(np.abs(got - ref)) <= 1e-12 * np.max(np.abs(ref))


def test_large_log_paths_agree_with_the_whole_array_paths(monkeypatch) -> None:
    """``identify`` on a log forced through the bounded-memory paths (taken above
    ``LARGE_ROWS`` rows) gives the estimates, covariance and test statistics of the
    whole-array paths to rounding."""
    import warnings

    from vesselid.identify import covariance as cv
    from vesselid.identify import identify
    from vesselid.identify import specification as sp
    from vesselid.plant.systems import heave

    log = heave().simulate(6000, seed=11).to_log()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        ref = identify(log)
        monkeypatch.setattr(cv, "LARGE_ROWS", 1000)
        monkeypatch.setattr(cv, "BLOCK_ROWS", 700)
        monkeypatch.setattr(sp, "BLOCK_ROWS", 700)
        got = identify(log)
    np.testing.assert_allclose(got.params.to_numpy(), ref.params.to_numpy(), rtol=1e-12)
    c_ref, c_got = ref.cov.to_numpy(), got.cov.to_numpy()
    assert np.max(np.abs(c_got - c_ref)) <= 1e-11 * np.max(np.abs(c_ref))
    spec_ref = ref.diagnostics["specification"]["w"]
    spec_got = got.diagnostics["specification"]["w"]
    for test in ("endogeneity", "hansen_j"):
        assert spec_ref[test]["stat"] is not None
        assert np.isclose(spec_got[test]["stat"], spec_ref[test]["stat"], rtol=1e-9)
    fs_ref, fs_got = spec_ref["first_stage"], spec_got["first_stage"]
    assert np.isclose(fs_got["cragg_donald"], fs_ref["cragg_donald"], rtol=1e-9)
    for name, f in fs_ref["partial_f"].items():
        assert np.isclose(fs_got["partial_f"][name], f, rtol=1e-9)
    d_ref, d_got = ref.diagnostics, got.diagnostics
    # the feedback test (views of one long experiment), split-sample stability (block-wise
    # Bartlett sums of each half), and the GMM colour and C tests (block-wise weights)
    assert np.isclose(d_got["feedback"]["statistic"], d_ref["feedback"]["statistic"], rtol=1e-9)
    assert np.isclose(d_got["parameter_stability"]["statistic"],
                      d_ref["parameter_stability"]["statistic"], rtol=1e-9)
    for key in ("colour_test", "c_test_lagged", "hansen_j_combined"):
        assert np.isclose(d_got[key][0]["stat"], d_ref[key][0]["stat"], rtol=1e-9), key


def test_minus_fit_in_blocks(monkeypatch) -> None:
    """``a − b·coef`` formed block by block in ``a``'s buffer on long logs equals the
    whole product's difference to rounding."""
    from vesselid.identify import covariance as cv
    from vesselid.identify import specification as sp

    rng = np.random.default_rng(8)
    a = rng.standard_normal((5000, 3))
    b = rng.standard_normal((5000, 6))
    coef = rng.standard_normal((6, 3))
    ref = a - b @ coef
    monkeypatch.setattr(cv, "LARGE_ROWS", 1000)
    monkeypatch.setattr(sp, "BLOCK_ROWS", 777)
    work = a.copy()
    got = sp._minus_fit(work, b, coef)
    assert got is work
    np.testing.assert_allclose(got, ref, rtol=0, atol=1e-13 * np.max(np.abs(ref)))


def test_long_log_least_squares_equal_lstsq(monkeypatch) -> None:
    """The specification tests' least squares on long logs (refined normal equations)
    give ``np.linalg.lstsq``'s coefficients to rounding, for one and several right-hand
    sides; collinear columns take ``lstsq`` itself (its minimum-norm solution)."""
    from vesselid.identify import covariance as cv
    from vesselid.identify import specification as sp

    rng = np.random.default_rng(8)
    n = 5000
    a = rng.standard_normal((n, 6)) * np.array([1.0, 10.0, 0.1, 1.0, 3.0, 1e3])
    b = a @ rng.standard_normal((6, 2)) + rng.standard_normal((n, 2))
    ref = np.linalg.lstsq(a, b, rcond=None)[0]
    ref1 = np.linalg.lstsq(a, b[:, 0], rcond=None)[0]
    a_dup = np.column_stack([a[:, :3], a[:, 0]])
    ref_dup = np.linalg.lstsq(a_dup, b, rcond=None)[0]
    monkeypatch.setattr(cv, "LARGE_ROWS", 1000)
    monkeypatch.setattr(sp, "BLOCK_ROWS", 777)
    got = sp._lstsq(a, b)
    assert got.shape == ref.shape
    assert np.max(np.abs(got - ref)) <= 1e-12 * np.max(np.abs(ref))
    got1 = sp._lstsq(a, b[:, 0])
    assert got1.shape == ref1.shape
    assert np.max(np.abs(got1 - ref1)) <= 1e-12 * np.max(np.abs(ref1))
    assert np.array_equal(sp._lstsq(a_dup, b), ref_dup)


def test_gmm_hac_sums_in_blocks_equal_the_whole_array(monkeypatch) -> None:
    """The GMM weight's Bartlett sums of a long experiment (blocks of rows) equal the
    whole-array moving sums to rounding, with invalid rows among the valid ones."""
    from vesselid.identify import covariance as cv
    from vesselid.identify import gmm

    rng = np.random.default_rng(5)
    n = 4000
    z = rng.standard_normal((n, 5))
    e = np.convolve(rng.standard_normal(n), np.ones(4), "same")
    valid = np.ones(n, dtype=bool)
    valid[[0, 1, 1700, 3999]] = False
    starts = np.array([0, 2500, n])
    ref = gmm.hac_sums(z, e, starts, valid, 23)
    monkeypatch.setattr(cv, "LARGE_ROWS", 1000)
    monkeypatch.setattr(cv, "BLOCK_ROWS", 333)
    got = gmm.hac_sums(z, e, starts, valid, 23)
    assert np.max(np.abs(got - ref)) <= 1e-13 * np.max(np.abs(ref))


def test_gmm_weight_derivative_on_long_experiments(monkeypatch) -> None:
    """The derivative of the GMM weight's sums on a long experiment with invalid rows
    (taken out of the sums instead of zeroed in a copy) equals the zeroed-copy form."""
    from vesselid.identify import covariance as cv
    from vesselid.identify import gmm

    rng = np.random.default_rng(6)
    n = 3000
    z = rng.standard_normal((n, 4))
    phi = rng.standard_normal((n, 2))
    e = rng.standard_normal(n)
    u = rng.standard_normal(4)
    valid = np.ones(n, dtype=bool)
    valid[[0, 1500, 1501]] = False
    starts = np.array([0, 1500, n])
    ref = gmm.hac_sums_derivative(z, phi, e, starts, valid, 9, u)
    monkeypatch.setattr(cv, "LARGE_ROWS", 1000)
    got = gmm.hac_sums_derivative(z, phi, e, starts, valid, 9, u)
    assert np.max(np.abs(got - ref)) <= 1e-12 * np.max(np.abs(ref))
    z[[0, 1500]] = np.nan  # non-finite invalid rows: zeroed as before, never in a sum
    monkeypatch.setattr(cv, "LARGE_ROWS", 1 << 17)
    ref = gmm.hac_sums_derivative(z, phi, e, starts, valid, 9, u)
    monkeypatch.setattr(cv, "LARGE_ROWS", 1000)
    got = gmm.hac_sums_derivative(z, phi, e, starts, valid, 9, u)
    assert np.all(np.isfinite(got)) and np.array_equal(got, ref)


def test_identify_reads_no_ground_truth(tmp_path) -> None:
    """``TrialLog.load(truth=False)`` (what ``vesselid identify`` reads) leaves the
    simulator's ``true_*`` columns in the file, the same frame otherwise (CSV and
    Parquet), and keeps a ``true_*`` column that the model spec names."""
    from vesselid.data.logs import TrialLog
    from vesselid.model.spec import ModelSpec
    from vesselid.plant.systems import heave

    log = heave().simulate(300, seed=1).to_log()
    spec = ModelSpec.from_dict({"name": "t", "states": ["true_w"], "inputs": ["tau"],
                                "dt": 1.0,
                                "equations": {"true_w": ["true_w", "true_w*|true_w|", "tau"]}})
    for suffix in ("csv", "parquet"):
        path = tmp_path / f"log.{suffix}"
        log.save(path)
        full = TrialLog.load(path)
        lean = TrialLog.load(path, truth=False)
        assert any(c.startswith("true_") for c in full.data.columns)
        assert not any(c.startswith("true_") for c in lean.data.columns)
        assert lean.data.equals(full.data[list(lean.data.columns)])
        assert lean.metadata == full.metadata
        named = TrialLog.load(path, spec=spec, truth=False)
        assert "true_w" in named.data.columns
        assert "true_current_w" not in named.data.columns


def test_lean_csv_read_still_refuses_ragged_rows(tmp_path) -> None:
    """Leaving the ground-truth columns unread must not let a CSV row with extra fields
    through (pandas' ``usecols`` would drop them silently)."""
    import pytest

    from vesselid.data.logs import TrialLog
    from vesselid.errors import LogValidationError
    from vesselid.plant.systems import heave

    path = tmp_path / "log.csv"
    heave().simulate(50, seed=1).to_log().save(path)
    lines = path.read_text().splitlines()
    lines[10] += ",1,2,3"
    path.write_text("\n".join(lines) + "\n")
    for truth in (True, False):
        with pytest.raises(LogValidationError):
            TrialLog.load(path, truth=truth)


def test_hac_long_run_in_blocks(monkeypatch) -> None:
    """The HAC long-run covariance of one long experiment (the J test's weight) from
    scores formed block by block equals the whole-array one to rounding, with the same
    Newey-West bandwidth, for a rule and a fixed bandwidth; other kernels keep the
    whole-array path."""
    from vesselid.identify import covariance as cv

    rng = np.random.default_rng(9)
    n = 5000
    z = rng.standard_normal((n, 4)) * np.array([1.0, 5.0, 0.2, 1.0])
    e = np.convolve(rng.standard_normal(n), np.ones(6), "same")
    for config in ({}, {"bandwidth": 7.0}):
        est = cv.get_covariance_estimator(cv.DEFAULT_COV_TYPE, **config)
        ref, used_ref = est.long_run(z, e, zero_mean=True, skip_first=False)
        with monkeypatch.context() as m:
            m.setattr(cv, "LARGE_ROWS", 1000)
            m.setattr(cv, "BLOCK_ROWS", 333)
            assert est._long_run_in_blocks(z, e, None, None, True, False) is not None
            got, used = est.long_run(z, e, zero_mean=True, skip_first=False)
        assert used["bandwidth"] == used_ref["bandwidth"] > 1
        assert np.max(np.abs(got - ref)) <= 1e-12 * np.max(np.abs(ref))
    monkeypatch.setattr(cv, "LARGE_ROWS", 1000)
    parzen = cv.get_covariance_estimator(cv.DEFAULT_COV_TYPE, kernel="parzen")
    assert parzen._long_run_in_blocks(z, e, None, None, True, False) is None


def test_instruments_centred_in_place_equal_the_compiled_centring() -> None:
    """A long log's handed-over instruments centred in their own buffer are the compiled
    kernel's centred instruments bit for bit (invalid rows, non-finite ones among them,
    and two experiments), and the regressors and target from the kernel without the
    instruments are its own."""
    from vesselid.identify import _ivkernels as ivk
    from vesselid.identify import gmm

    rng = np.random.default_rng(7)
    n = 5000
    phi = rng.standard_normal((n, 3))
    target = rng.standard_normal((n, 1)) + 0.3
    starts = np.array([0, 1234, n])
    for k in (2, 5):
        z = rng.standard_normal((n, k)) * 3.0 + 1.0
        z[[0, 1234, 4000]] = np.nan
        valid, cmax = ivk.design_scan(z, phi, 0, 3, target, 0)
        assert not valid[[0, 1234, 4000]].any()
        col = 2.0 ** -np.round(np.log2(np.maximum(cmax, 1e-300)))
        zz, pp, yy = ivk.design_centre(z, phi, 0, 3, target, 0, valid, col, starts)
        own = z.copy()
        got = gmm._centre_in_place(own, valid, col[:k], starts)
        assert got is own and np.array_equal(got, zz)
        _, pp2, yy2 = ivk.design_centre(own[:, :0], phi, 0, 3, target, 0, valid, col[k:],
                                        starts)
        assert np.array_equal(pp2, pp) and np.array_equal(yy2, yy)


def test_covariance_of_handed_over_regressors_is_the_same() -> None:
    """``estimate(..., overwrite=True)`` equilibrates the caller's regressors in their
    own buffer and gives the covariance of the copying form bit for bit."""
    from vesselid.identify.covariance import get_covariance_estimator

    rng = np.random.default_rng(8)
    x = rng.standard_normal((3000, 4)) * [1.0, 10.0, 0.1, 3.0]
    e = np.convolve(rng.standard_normal(3000), np.ones(3), "same")
    est = get_covariance_estimator("hac")
    ref = est.estimate(x, x, e, skip_first=False)
    mine = x.copy()
    got = est.estimate(mine, mine, e, skip_first=False, overwrite=True)
    assert np.array_equal(got.cov, ref.cov)
    assert not np.array_equal(mine, x)  # the buffer was used



def test_feedback_scores_of_one_long_experiment(monkeypatch) -> None:
    """The feedback test of a long one-experiment log (rows and lags as slices, matrices
    computed into the test's own buffers) is the whole-array test to rounding."""
    from vesselid.identify import covariance as cv
    from vesselid.identify import loop
    from vesselid.identify.data import from_log
    from vesselid.plant.systems import heave

    for seed in (4, 5):
        data, spec = from_log(heave().simulate(6000, seed=seed).to_log(), None,
                              sensor_noise=False)
        ref = loop.feedback_test_data(data, spec, loop.reference_designs(data, spec))
        with monkeypatch.context() as m:
            m.setattr(cv, "LARGE_ROWS", 1000)
            got = loop.feedback_test_data(data, spec, loop.reference_designs(data, spec))
        assert got.df == ref.df > 0
        assert abs(got.statistic - ref.statistic) <= 1e-9 * abs(ref.statistic), seed
        assert abs(got.pvalue - ref.pvalue) <= 1e-9


def _pulse_heave(seed: int, n: int, vbar: float):
    """Heave driven by pulses of random sign, with a current of mean ``vbar``."""
    import pandas as pd

    rng = np.random.default_rng(seed)
    widths = rng.integers(10, 101, size=n // 10 + 2)
    levels = rng.uniform(0.1, 0.4, widths.size) * rng.choice([-1.0, 1.0], widths.size)
    tau = np.repeat(levels, widths)[:n]
    v = rng.normal(vbar, 0.05, n)
    xi = rng.normal(0.0, 0.05, n)
    w = np.zeros(n)
    for k in range(n - 1):
        wr = w[k] - v[k]
        w[k + 1] = 0.9 * wr - 0.2 * wr * abs(wr) + 0.8 * tau[k] + xi[k]
    y = w + rng.normal(0.0, 0.05, n)
    return pd.DataFrame({"time": np.arange(n, dtype=float), "w": y, "tau": tau})


def test_mean_current_of_one_long_experiment(monkeypatch) -> None:
    """The mean-current test of a long one-experiment log (matrices formed in their final
    buffers, scores summed block by block) is the whole-array test to rounding, with and
    without a current's mean."""
    from vesselid.identify import covariance as cv
    from vesselid.identify import validity
    from vesselid.identify.data import from_log
    from vesselid.identify.estimators import estimate
    from vesselid.model.spec import ModelSpec

    spec = ModelSpec(name="heave-test", states=["w"], inputs=["tau"],
                     equations={"w": ["w", "w*|w|", "tau"]}, dt=1.0)
    for seed, vbar in ((4, 0.0), (5, 0.05)):
        data, spec = from_log(_pulse_heave(seed, 6000, vbar), spec, sensor_noise=False)
        theta_aux = estimate(data, spec, "iv-zero-mean").theta_aux[0]
        ref = validity.mean_current(data, spec, theta_aux)
        with monkeypatch.context() as m:
            m.setattr(cv, "LARGE_ROWS", 1000)
            m.setattr(cv, "BLOCK_ROWS", 777)
            assert validity._one_long_experiment(data)
            got = validity.mean_current(data, spec, theta_aux)
        assert ref is not None and got is not None
        for key in ("statistic", "abs_coefficient", "abs_coefficient_se", "estimate",
                    "std_error", "pvalue"):
            assert abs(got[key] - ref[key]) <= 1e-9 * abs(ref[key]) + 1e-15, (seed, key)
        assert got["warned"] == ref["warned"] == (vbar > 0)


def test_gmm_weight_derivative_filtered_in_blocks(monkeypatch) -> None:
    """The derivative of the GMM weight's sums with the filtered series formed block by
    block (each block widened by the lag window) equals the whole-series form, for blocks
    shorter than, near and longer than the window, with invalid rows inside blocks and
    at block edges."""
    from vesselid.identify import covariance as cv
    from vesselid.identify import gmm

    rng = np.random.default_rng(7)
    n = 3001
    z = rng.standard_normal((n, 4)) + 0.3
    phi = rng.standard_normal((n, 2))
    e = np.convolve(rng.standard_normal(n), np.ones(5), "same")  # coloured
    u = rng.standard_normal(4)
    valid = np.ones(n, dtype=bool)
    valid[[0, 200, 201, 1500, 2999]] = False
    starts = np.array([0, 1500, n])
    for lags in (9, 40):
        ref = gmm.hac_sums_derivative(z, phi, e, starts, valid, lags, u)
        for rows in (3, 20, 100, 4096):
            with monkeypatch.context() as m:
                m.setattr(cv, "LARGE_ROWS", 1000)
                m.setattr(cv, "BLOCK_ROWS", rows)
                got = gmm.hac_sums_derivative(z, phi, e, starts, valid, lags, u)
            assert np.max(np.abs(got - ref)) <= 1e-12 * np.max(np.abs(ref)), (lags, rows)


def test_deferred_gmm_designs_are_the_kept_ones(monkeypatch) -> None:
    """A long log's GMM designs formed again when the covariance needs them (not held
    through the tests between) give the covariance and specification tests of the
    designs the refinement kept, bit for bit."""
    import warnings

    from vesselid.identify import covariance as cv
    from vesselid.identify import efficient, identify
    from vesselid.plant.systems import heave

    warnings.simplefilter("ignore")
    log = heave().simulate(6000, seed=2).to_log()
    monkeypatch.setattr(cv, "LARGE_ROWS", 1000)
    calls = []
    rows = efficient.InstrumentalGMM._final_rows
    monkeypatch.setattr(efficient.InstrumentalGMM, "_final_rows",
                        lambda self, *a: calls.append(1) or rows(self, *a))
    got = identify(log)
    assert calls == [1]
    monkeypatch.setattr(efficient, "_long_log", lambda data: False)
    ref = identify(log)
    assert calls == [1]
    assert np.array_equal(got.params.to_numpy(), ref.params.to_numpy())
    assert np.array_equal(got.cov.to_numpy(), ref.cov.to_numpy())
    assert got.diagnostics["specification"] == ref.diagnostics["specification"]
    assert (got.diagnostics["instrument_condition"]
            == ref.diagnostics["instrument_condition"])
    # every other diagnostic too (the colour test simulates its instruments again)
    assert got.to_json() == ref.to_json()


def test_covariance_of_one_long_experiment_in_blocks(monkeypatch) -> None:
    """The HAC sandwich of one long experiment with every sum over blocks of rows (no
    equilibrated copy of the instruments, no scores array) is the whole-array sandwich to
    rounding: IV, 2SLS, a given GMM weight with and without Windmeijer's correction,
    instruments that are the regressors (LS), centred and raw residuals, a fixed and the
    automatic bandwidth."""
    from vesselid.identify import covariance as cv

    rng = np.random.default_rng(9)
    n = 5000
    x = rng.standard_normal((n, 2))
    z = np.column_stack([x + 0.5 * rng.standard_normal((n, 2)), rng.standard_normal((n, 2))])
    z *= [1.0, 1e3, 1e-2, 1.0]  # badly scaled columns: the equilibration matters
    resid = np.convolve(rng.standard_normal(n), np.ones(4), "same") + 0.1
    w = np.linalg.inv(z.T @ z / n)
    jac = 0.01 * rng.standard_normal((2, 2))
    cases = [(z[:, :2], x, {}), (z, x, {}), (z, x, {"weight": w}),
             (z, x, {"weight": w, "weight_jacobian": jac}), (z, z, {})]
    for est in (cv.KernelCovariance(), cv.KernelCovariance(bandwidth=7.0)):
        for zz, xx, kw in cases:
            for zero_mean in (False, True):
                args = (zz, xx, resid, np.array([0, n]))
                opts = dict(zero_mean=zero_mean, skip_first=False, **kw)
                ref = est.estimate(*args, **opts)
                with monkeypatch.context() as m:
                    m.setattr(cv, "LARGE_ROWS", 1000)
                    m.setattr(cv, "BLOCK_ROWS", 333)
                    assert est._estimate_in_blocks(*args, None, None, kw.get("weight"),
                                                   zero_mean, "pooled", False,
                                                   kw.get("weight_jacobian")) is not None
                    got = est.estimate(*args, **opts)
                assert np.max(np.abs(got.cov - ref.cov)) <= 1e-11 * np.max(np.abs(ref.cov))
                assert np.allclose(got.long_run, ref.long_run, rtol=1e-11, atol=0)
                rounded = ("effective_b", "critical_value")  # read from the covariance
                assert ({k: v for k, v in got.config.items() if k not in rounded}
                        == {k: v for k, v in ref.config.items() if k not in rounded})
                for key in rounded:
                    assert (key in got.config) == (key in ref.config)
                    if key in ref.config:
                        assert np.allclose(got.config[key], ref.config[key], rtol=1e-11)
                assert got.label == ref.label


def test_fixed_b_ratios_of_one_long_experiment_in_blocks(monkeypatch) -> None:
    """The fixed-b scaling of the block-wise sandwich (effective bandwidth ratios from
    row blocks, never whole arrays) equals the whole-array one to rounding, for a
    two-step GMM estimate with Windmeijer's correction and for a just-identified
    estimate; and the block-wise Bartlett sums equal the whole-array ones."""
    from vesselid.identify import covariance as cv
    from vesselid.identify.fixedb import bartlett_cross

    rng = np.random.default_rng(21)
    for n, lags, block in ((1000, 5, 100), (50, 80, 16), (999, 0, 7), (300, 3, 1000)):
        x = rng.standard_normal((n, 3))
        got = np.diag(cv.bartlett_block_sums(lambda a, b, x=x: x[a:b], n, 3, np.zeros(3),
                                             lags, block))
        np.testing.assert_allclose(got, bartlett_cross(x, x, lags, [slice(0, n)]),
                                   rtol=1e-13)
    n = 4000
    x = rng.standard_normal((n, 2))
    z = np.column_stack([x + 0.5 * rng.standard_normal((n, 2)), rng.standard_normal((n, 2))])
    resid = np.convolve(rng.standard_normal(n), np.ones(5), "same") + 0.1
    w = np.linalg.inv(z.T @ z / n)
    jac = 0.05 * rng.standard_normal((2, 2))
    cases = [(z, {"weight": w, "weight_jacobian": jac}), (z[:, :2], {"fixed_b_square": True})]
    for zz, kw in cases:
        for zero_mean in (False, True):
            est = cv.KernelCovariance()
            opts = dict(zero_mean=zero_mean, skip_first=False, **kw)
            ref = est.estimate(zz, x, resid, np.array([0, n]), **opts)
            assert ref.config["fixed_b"] and "critical_value" in ref.config
            with monkeypatch.context() as m:
                m.setattr(cv, "LARGE_ROWS", 1000)
                m.setattr(cv, "BLOCK_ROWS", 333)
                got = est._estimate_in_blocks(zz, x, resid, np.array([0, n]), None, None,
                                              kw.get("weight"), zero_mean, "pooled", False,
                                              kw.get("weight_jacobian"),
                                              kw.get("fixed_b_square", False))
                assert got is not None and got.config["fixed_b"]
                assert est.estimate(zz, x, resid, np.array([0, n]), **opts).config == got.config
            np.testing.assert_allclose(got.config["effective_b"], ref.config["effective_b"],
                                       rtol=1e-10)
            np.testing.assert_allclose(got.cov, ref.cov, rtol=1e-10)
            assert got.label == ref.label


def test_first_stage_of_a_long_log_in_blocks(monkeypatch) -> None:
    """The first stage of a long log with the partialled-out instruments and regressors
    formed block by block (never whole) gives the whole-array partial F, partial R² and
    Cragg–Donald to rounding, with and without exogenous regressors among the
    instruments."""
    from vesselid.identify import covariance as cv
    from vesselid.identify import specification as sp

    rng = np.random.default_rng(11)
    n = 4000
    tau = rng.standard_normal(n)
    inst = rng.standard_normal((n, 3)) * [1e3, 1.0, 1e-2]  # badly scaled instruments
    x = np.column_stack([inst @ [5e-4, 0.2, 10.0] + rng.standard_normal(n),
                         inst @ [1e-4, 0.4, 30.0] + rng.standard_normal(n), tau])
    for z, phi in ((np.column_stack([inst, tau]), x), (inst, x[:, :2])):
        ref = sp.first_stage(z, phi, names=[f"p{j}" for j in range(phi.shape[1])])
        with monkeypatch.context() as m:
            m.setattr(cv, "LARGE_ROWS", 1000)
            m.setattr(sp, "BLOCK_ROWS", 333)
            got = sp.first_stage(z, phi, names=[f"p{j}" for j in range(phi.shape[1])])
        assert got.keys() == ref.keys() and got["df"] == ref["df"]
        assert got["endogenous"] == ref["endogenous"] == ["p0", "p1"]
        assert abs(got["cragg_donald"] - ref["cragg_donald"]) <= 1e-11 * ref["cragg_donald"]
        for key in ("partial_f", "partial_r2"):
            for name, value in ref[key].items():
                assert abs(got[key][name] - value) <= 1e-11 * abs(value), (key, name)


def test_endogeneity_of_a_long_log_in_blocks(monkeypatch) -> None:
    """The Durbin–Wu–Hausman test of a long log with the augmented regressors
    ``[φ, v̂]`` formed block by block (never whole) gives the whole-array statistic to
    rounding, on an endogenous and on an exogenous regressor, with the automatic and a
    fixed bandwidth."""
    from vesselid.identify import covariance as cv
    from vesselid.identify import specification as sp

    rng = np.random.default_rng(12)
    n = 4000
    tau = rng.standard_normal(n)
    inst = rng.standard_normal((n, 3)) * [1e3, 1.0, 1e-2]
    err = np.convolve(rng.standard_normal(n), np.ones(3), "same")
    rows, done = sp._endogeneity_rows, []

    def counted(*args):  # the block form, recorded: it must be the one taken
        done.append(rows(*args))
        return done[-1]

    for share in (0.0, 0.8):  # exogenous, endogenous
        xe = inst @ [5e-4, 0.3, 20.0] + rng.standard_normal(n) + share * err
        phi = np.column_stack([xe, tau])
        y = phi @ [0.7, -1.2] + err
        z = np.column_stack([inst, tau])
        for config in ({}, {"bandwidth": 6.0}):
            ref = sp.endogeneity_test(z, phi, y, **config)
            with monkeypatch.context() as m:
                m.setattr(cv, "LARGE_ROWS", 1000)
                m.setattr(cv, "BLOCK_ROWS", 333)
                m.setattr(sp, "BLOCK_ROWS", 333)
                m.setattr(sp, "_endogeneity_rows", counted)
                got = sp.endogeneity_test(z, phi, y, **config)
            assert len(done) == 1 and done.pop() is not None
            assert got.df == ref.df == 1
            assert abs(got.stat - ref.stat) <= 1e-10 * abs(ref.stat), (share, config)
            assert abs(got.pvalue - ref.pvalue) <= 1e-10 * max(ref.pvalue, 1e-12)


def test_arrow_system_allocator_before_the_import() -> None:
    """Set before pyarrow is imported, the C library's allocator is Arrow's default pool;
    a pool named in the environment is kept; after the import the pool is reported."""
    import json
    import os
    import subprocess

    pytest.importorskip("pyarrow")
    code = ("import json, sys\n"
            "from vesselid.core.memory import arrow_system_allocator\n"
            "first = arrow_system_allocator()\n"
            "import pyarrow as pa\n"
            "print(json.dumps([first, pa.default_memory_pool().backend_name,\n"
            "                  arrow_system_allocator()]))\n")
    env = {k: v for k, v in os.environ.items() if k != "ARROW_DEFAULT_MEMORY_POOL"}
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True, env=env).stdout
    assert json.loads(out) == [True, "system", True]
    env["ARROW_DEFAULT_MEMORY_POOL"] = "jemalloc"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True, env=env).stdout
    first, backend, after = json.loads(out)
    assert first is False and after is (backend == "system")


def test_identify_command_equals_identify_on_the_log(tmp_path, capsys) -> None:
    """``vesselid identify LOG --json -`` (which lets go of the checked time column before
    the fit) writes the result ``identify`` gives on the whole log, byte for byte, for a
    log of two experiments in Parquet and in CSV."""
    import warnings

    pytest.importorskip("pyarrow")
    from vesselid.data.logs import TrialLog, concat_logs
    from vesselid.identify import identify
    from vesselid.plant.systems import heave

    log = concat_logs([heave().simulate(1500, seed=s).to_log() for s in (3, 4)])
    assert "time" in log.data.columns
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        want = identify(log).to_json(indent=2)
    for suffix in (".parquet", ".csv"):
        path = tmp_path / f"two{suffix}"
        log.save(path)
        assert "time" in TrialLog.load(path).data.columns
        assert main(["identify", str(path), "--json", "-"]) == 0
        assert capsys.readouterr().out.strip() == want.strip()


_DROP_CODE = """
import numpy as np
from vesselid.core import memory

assert memory.drop_library_code() == 0  # switched off: nothing is touched
assert memory.release_library_code()
from numba import njit

@njit(cache=False)
def before(x):
    return np.sum(x * x)

x = np.arange(1000.0)
ref = before(x)

def llvm_rss_kb():
    kb, on = 0, False
    for line in open("/proc/self/smaps"):
        head = line.split()
        if not head[0].endswith(":"):
            on = len(head) > 5 and "libllvmlite" in head[5] and "w" not in head[1]
        elif on and head[0] == "Rss:":
            kb += int(head[1])
    return kb

held = llvm_rss_kb()
advised = memory.drop_library_code()
assert advised > 0, advised
assert llvm_rss_kb() < held / 2, (llvm_rss_kb(), held)
assert before(x) == ref  # a loaded kernel runs on

@njit(cache=False)
def after(x):  # and LLVM compiles again (its pages fault in again)
    return np.sum(x * x)

assert after(x) == ref
assert memory.drop_library_code() == advised
try:  # Arrow's code as well (the parquet extra): reading runs on after the drop
    import io
    import pyarrow as pa
    import pyarrow.parquet as pq
except ImportError:
    pass
else:
    # Arrow without its thread pool: with the pool's threads started after LLVM's pages
    # were dropped, about one process in seven aborted at interpreter exit (std::terminate
    # of a joinable pool thread, Arrow's own exit race: apache/arrow#34314, #39862) after
    # every check here had passed (6 of 40; without the pool 0 of 80); `vesselid
    # identify`, which reads before numba loads, showed no abort in 32 runs
    pa.set_cpu_count(1)
    pa.set_io_thread_count(1)
    buf = io.BytesIO()
    pq.write_table(pa.table({"a": x}), buf)
    assert memory.drop_library_code() > advised
    got = pq.read_table(io.BytesIO(buf.getvalue()), use_threads=False)["a"].to_numpy()
    assert np.array_equal(got, x)
print("ok")
"""


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="madvise and /proc: Linux")
def test_dropped_llvm_code_pages_leave_kernels_working() -> None:
    """``drop_library_code`` (switched on by ``release_library_code``) takes LLVM's (and
    Arrow's) clean code pages out of the resident memory; compiled kernels run on, LLVM
    compiles and Parquet reads again afterwards (own process: the switch is
    process-wide)."""
    import subprocess

    out = subprocess.run([sys.executable, "-c", _DROP_CODE], capture_output=True, text=True,
                         timeout=120, check=False)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "ok"


def test_one_state_regression_data_shares_the_log_columns(monkeypatch) -> None:
    """A one-state, one-input log's target and input are the log's own float64 columns
    (views, read-only: nothing writes into them), not copies held beside the log; the
    estimate is that of copied arrays."""
    import warnings

    from vesselid.identify import identify
    from vesselid.identify.data import from_log
    from vesselid.plant.systems import heave

    log = heave().simulate(3000, seed=4).to_log()
    data, spec = from_log(log)
    assert list(spec.states) == ["w"] and list(spec.inputs) == ["tau"]
    assert np.shares_memory(data.target, log.data["w"].to_numpy())
    assert np.shares_memory(data.u, log.data["tau"].to_numpy())
    assert not data.target.flags.writeable
    assert data.target.flags.c_contiguous and data.u.flags.c_contiguous
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        got = identify(log)
        from vesselid.identify import data as data_mod

        # the copying form: fresh, writeable arrays
        monkeypatch.setattr(data_mod, "_columns", lambda frame, names: np.column_stack(
            [frame[c].to_numpy(float) for c in names]))
        assert data_mod.from_log(log)[0].target.flags.writeable
        ref = identify(log)
    np.testing.assert_array_equal(got.params.to_numpy(), ref.params.to_numpy())
    np.testing.assert_array_equal(got.cov.to_numpy(), ref.cov.to_numpy())
