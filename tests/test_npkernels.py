"""The no-JIT estimation path (``vesselid.identify._npkernels``) against the compiled one.

Recursions and regressor rows must be bit-identical (same operations in the same order);
sums are numpy reductions, equal to the compiled sequential sums to rounding (tolerances
a few hundred ulps of the summed magnitudes, far below any statistical error). A whole
``identify`` agrees to rounding for every registered method, and a small log in a fresh
process is estimated without importing numba.
"""

from __future__ import annotations

import subprocess
import sys
import warnings

import numpy as np
import pytest

from vesselid.identify import _ivkernels as ivk
from vesselid.identify import _npkernels as npk
from vesselid.identify import backend
from vesselid.identify import kernels as jk
from vesselid.identify.data import block_starts, from_log
from vesselid.plant.catalogue import get_system

EPS = np.finfo(float).eps


def _data(system: str, samples: int, runs: int, seed: int):
    sim = get_system(system).simulate(samples, n_runs=runs, seed=seed)
    log = sim.to_log()
    data, spec = from_log(log, None)
    return data, spec


def _close(a, b, scale):
    """Equal to rounding: within 500 ulps of the magnitude of the summed terms."""
    np.testing.assert_allclose(a, b, rtol=0, atol=500 * EPS * scale)


@pytest.mark.parametrize("system", ["heave", "cybership2"])
def test_rows_and_recursions_bit_identical(system):
    data, spec = _data(system, 600, 3, 1)
    c = spec.codes
    np.testing.assert_array_equal(
        npk.regressor_matrix(data.regsig, data.u, data.starts, c.factors),
        jk.regressor_matrix(data.regsig, data.u, data.starts, c.factors))
    theta = np.tile(spec.theta0_vector(), (data.n_groups, 1))
    limit = np.full(data.n_segments, 1e6)
    z1, ok1 = npk.simulated_regressors(data.target, data.u, data.starts, data.group, theta,
                                       c.factors, c.equation, limit)
    z2, ok2 = ivk.simulated_regressors(data.target, data.u, data.starts, data.group, theta,
                                       c.factors, c.equation, limit)
    np.testing.assert_array_equal(z1, z2)
    np.testing.assert_array_equal(ok1, ok2)
    a = npk.instrument_matrix(data.target, data.u, data.starts, theta[0], c.factors,
                              c.equation, spec.n_states)
    b = jk.instrument_matrix(data.target, data.u, data.starts, theta[0], c.factors,
                             c.equation, spec.n_states)
    for x, y in zip(a, b, strict=True):
        np.testing.assert_array_equal(x, y)


def test_divergence_matches():
    """A diverging auxiliary model: same flags, same NaN segments, same free run."""
    data, spec = _data("heave", 400, 2, 2)
    c = spec.codes
    th = spec.theta0_vector()
    th[:2] = [1.2, 0.5]  # w(k+1) = 1.2 w + 0.5 w|w| + τ: explodes
    theta = np.tile(th, (data.n_groups, 1))
    limit = np.full(data.n_segments, 50.0)
    z1, ok1 = npk.simulated_regressors(data.target, data.u, data.starts, data.group, theta,
                                       c.factors, c.equation, limit)
    z2, ok2 = ivk.simulated_regressors(data.target, data.u, data.starts, data.group, theta,
                                       c.factors, c.equation, limit)
    assert not ok2.any()
    np.testing.assert_array_equal(ok1, ok2)
    np.testing.assert_array_equal(z1, z2)
    from vesselid.plant.simulate import simulate_states

    sl = data.segment(0)
    x1 = npk.simulate_states(spec, data.u[sl], theta=theta[0], x0=data.target[sl][0],
                             limit=1e3)
    x2 = simulate_states(spec, data.u[sl], theta=theta[0], x0=data.target[sl][0], limit=1e3,
                         raise_on_divergence=False)
    assert np.isnan(x2[-1]).all()
    np.testing.assert_array_equal(x1, x2)


@pytest.mark.parametrize("system", ["heave", "cybership2"])
@pytest.mark.parametrize("mode", [jk.MODE_LS, jk.MODE_SIMULATED, jk.MODE_LAGGED])
def test_moments_equal_to_rounding(system, mode):
    data, spec = _data(system, 500, 3, 3)
    c = spec.codes
    n_seg, p, n = data.n_segments, spec.n_params, spec.n_states
    theta = np.tile(spec.theta0_vector(), (data.n_groups, 1))
    blocks = block_starts(spec)
    src = np.arange(n, dtype=np.int64)
    outs = []
    for mod in (npk, jk):
        o = [np.zeros((n_seg, p, p)), np.zeros((n_seg, p)), np.zeros((n_seg, p)),
             np.zeros((n_seg, p)), np.zeros((n_seg, n)), np.zeros(n_seg, dtype=np.int64),
             np.zeros(n_seg, dtype=np.int64)]
        mod.moments(data.regsig, data.target, data.u, data.starts, data.group, theta,
                    np.ones(data.n_groups, dtype=bool), mode, c.factors, c.equation, blocks,
                    src, np.full(n_seg, 1e6), *o)
        outs.append(o)
    scale = data.regsig.shape[0] * (1.0 + np.max(np.abs(data.target))) ** 4
    for a, b in zip(*outs, strict=True):
        _close(a, b, scale)
    np.testing.assert_array_equal(outs[0][-1], outs[1][-1])  # status
    np.testing.assert_array_equal(outs[0][-2], outs[1][-2])  # count


def test_matrix_helpers_equal_to_rounding():
    rng = np.random.default_rng(4)
    x = rng.normal(size=(300, 4))
    starts = np.array([0, 120, 300], dtype=np.int64)
    valid = rng.random(300) > 0.1
    _close(npk.center(x, starts, valid), ivk.center(x, starts, valid), 300 * 5)
    coef = rng.normal(size=(2, 3))
    (a1, v1), (a2, v2) = (npk.ar_filter(x, starts, valid, coef),
                          ivk.ar_filter(x, starts, valid, coef))
    np.testing.assert_array_equal(v1, v2)
    np.testing.assert_array_equal(a1, a2)  # same products in the same order
    for r1, r2 in zip(npk.autocov(x[:, 0], starts, valid, 3),
                      ivk.autocov(x[:, 0], starts, valid, 3), strict=True):
        _close(r1, r2, 300 * 25)
    z = rng.normal(size=(300, 3))
    z[[5, 130], 1] = np.nan  # a diverged simulated column
    cols = np.array([0, 1], dtype=np.int64)
    np.testing.assert_array_equal(npk.noise_window(x, z, cols, starts, 1, 8),
                                  ivk.noise_window(x, z, cols, starts, 1, 8))
    tgt = x[:, 2:].copy()
    tgt[7, 0] = np.inf
    v1, c1 = npk.design_scan(z, x, 1, 3, tgt, 0)
    v2, c2 = ivk.design_scan(z, x, 1, 3, tgt, 0)
    np.testing.assert_array_equal(v1, v2)
    np.testing.assert_array_equal(c1, c2)
    col = np.array([0.5, 2.0, 1.0, 4.0, 0.25, 1.0])
    for r1, r2 in zip(npk.design_centre(z, x, 1, 3, tgt, 0, v2, col, starts),
                      ivk.design_centre(z, x, 1, 3, tgt, 0, v2, col, starts), strict=True):
        _close(r1, r2, 300 * 20)
    y = x[:, 3].copy()
    for r1, r2 in zip(npk.cross_sums(x[:, :2].copy(), x[:, 2:3].copy(), y, starts, valid),
                      ivk.cross_sums(x[:, :2].copy(), x[:, 2:3].copy(), y, starts, valid),
                      strict=True):
        _close(r1, r2, 300 * 25)


def test_identify_both_paths_agree_to_rounding(monkeypatch):
    """Every method: the numpy path (forced) and the compiled path agree to rounding."""
    from vesselid.identify import ESTIMATORS, identify
    from vesselid.plant.closedloop import heave_pi_design, simulate_closed_loop

    system = get_system("heave")
    open_loop = system.simulate(3000, n_runs=2, seed=9).to_log()
    design = heave_pi_design()  # the closed-loop estimator needs a closed-loop log
    closed_loop = simulate_closed_loop(system, design.controller, design.reference,
                                       dither=design.dither, n_samples=3000, n_runs=2,
                                       seed=9).to_log()
    for method in ESTIMATORS:
        log = closed_loop if method == "cl-iv" else open_loop
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            monkeypatch.setenv("VESSELID_KERNELS", "numpy")
            a = identify(log, method=method)
            monkeypatch.setenv("VESSELID_KERNELS", "compiled")
            b = identify(log, method=method)
        if method in ("pem", "pem-switching"):
            # a likelihood maximised by Fisher scoring (pem-switching: BHHH and Newton
            # steps) from the IV start, which the two paths give to rounding: it stops
            # where the next step is below 0.01 standard errors (pem.SCORING_TOL,
            # switching.TOL), so the two estimates agree to that, not to rounding
            se = b.std_errors.to_numpy()
            assert np.all(np.abs(a.params.to_numpy() - b.params.to_numpy()) <= 0.01 * se)
            np.testing.assert_allclose(a.std_errors.to_numpy(), se, rtol=1e-3)
            assert a.diagnostics["disturbance_model"] == b.diagnostics["disturbance_model"]
            continue
        np.testing.assert_allclose(a.params.to_numpy(), b.params.to_numpy(), rtol=1e-9,
                                   err_msg=method)
        np.testing.assert_allclose(a.std_errors.to_numpy(), b.std_errors.to_numpy(),
                                   rtol=1e-8, err_msg=method)
        la, lb = _leaves(a.to_dict()), _leaves(b.to_dict())  # p-values, CIs, fits, ...
        assert la.keys() == lb.keys()
        for key, va in la.items():
            vb = lb[key]
            if isinstance(va, float) and isinstance(vb, float):
                # the fixed-point residual is the last step's relative change (≈ 1e-10): its
                # own digits are rounding, so only its size is compared
                # (and the bound on the last step in standard errors, ∝ that residual)
                tol = (1e-8 if key.endswith("fixed_point_residual")
                       else 1e-5 if key.endswith(("fixed_point_step_se",
                                                  "fixed_point_step_own_se")) else 1e-12)
                assert va == pytest.approx(vb, rel=1e-7, abs=tol), (method, key)
            else:
                assert va == vb, (method, key)


def _leaves(obj, prefix=""):
    """Flat ``{path: value}`` of a nested dict/list (ints and strings exact)."""
    if isinstance(obj, dict):
        return {k: v for key, val in obj.items()
                for k, v in _leaves(val, f"{prefix}/{key}").items()}
    if isinstance(obj, list | tuple):
        return {k: v for i, val in enumerate(obj)
                for k, v in _leaves(val, f"{prefix}/{i}").items()}
    return {prefix: float(obj) if isinstance(obj, float) else obj}


def test_choice_rules(monkeypatch):
    monkeypatch.delenv("VESSELID_KERNELS", raising=False)
    # numba is loaded in this test process: the compiled kernels are faster at every size
    assert not backend.use_numpy(100, 3)
    monkeypatch.setenv("VESSELID_KERNELS", "numpy")
    assert backend.use_numpy(10**9, 3)
    with backend.choose(10, 3) as numpy_path:
        assert numpy_path and backend.numpy_active()
        assert backend.kernels.moments is npk.moments
        assert backend.ivk.combined_moments is ivk.combined_moments  # no numpy version
    assert not backend.numpy_active()
    monkeypatch.setenv("VESSELID_KERNELS", "compiled")
    assert not backend.use_numpy(10, 3)


@pytest.mark.parametrize(("seed", "choice", "numba"), [(1, "combined", False),
                                                     (0, "pem-sensor", True)])
def test_small_log_identify_process_loads_numba_only_for_a_likelihood_fit(
        tmp_path, seed, choice, numba):
    """``vesselid identify`` on a 10⁴-sample heave log: no numba in the process where
    the default keeps its instruments (the numpy kernels); the likelihood filter of a
    log in the colour test's guard band is compiled only."""
    import json

    log = tmp_path / "heave.csv"
    get_system("heave").simulate(10_000, seed=seed).to_log().save(log)
    out_json = tmp_path / "r.json"
    code = ("import sys\nfrom vesselid.cli import main\n"
            f"rc = main(['identify', {str(log)!r}, '--json', {str(out_json)!r}])\n"
            "print('NUMBA', 'numba' in sys.modules, rc)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True, env={**__import__("os").environ,
                                          "VESSELID_KERNELS": "auto"})
    assert json.loads(out_json.read_text())["diagnostics"]["choice"] == choice
    assert f"NUMBA {numba} 0" in out.stdout


def test_special_functions_match_scipy(monkeypatch):
    from scipy.special import chdtrc, ndtri

    from vesselid.identify import _special

    for q in _special._NDTRI:  # the table holds scipy's exact values
        assert _special.norm_ppf(q) == ndtri(q)
    assert _special.norm_ppf(0.5 + 0.95 / 2) == ndtri(0.975)
    assert _special.norm_ppf(0.8) == ndtri(0.8)  # not tabulated: scipy
    x = np.concatenate([[0.0, 1e-8, 0.3, 1.0, 3.47, 20.0, 644.7, 2000.0, np.inf, np.nan],
                        np.linspace(0.01, 80, 37)])
    monkeypatch.setenv("VESSELID_KERNELS", "numpy")
    with backend.choose(10, 1):
        for df in (1, 2, 3, 4, 5, 8, 13, 20, 41):
            got = _special.chi2_sf(x, df)
            want = chdtrc(df, x)
            np.testing.assert_array_equal(np.isnan(got), np.isnan(want))
            ok = np.isfinite(want) & (want > 1e-300)
            np.testing.assert_allclose(got[ok], want[ok], rtol=1e-12, atol=0, err_msg=str(df))
            np.testing.assert_array_less(got[~np.isnan(want) & ~ok], 1e-290)
        assert _special.chi2_sf(3.47, 4) == pytest.approx(chdtrc(4, 3.47), rel=1e-13)
        assert _special.chi2_sf(1.0, 2.5) == chdtrc(2.5, 1.0)  # non-integer df: scipy
    assert _special.chi2_sf(3.47, 4) == chdtrc(4, 3.47)  # compiled path: scipy itself


def test_thread_ranges_cover_every_item_once_and_survive_fork():
    """run_ranges: every item exactly once in parallel; errors propagate; a forked child
    gets a fresh pool (the parent's threads do not exist there)."""
    import os

    from vesselid.core import threads as _threads

    hits = np.zeros(1000, dtype=np.int64)

    def kern(lo, hi, out):
        out[lo:hi] += 1

    _threads.run_ranges(kern, 1000, (hits,), parallel=True)
    np.testing.assert_array_equal(hits, 1)

    def bad(lo, hi):
        if lo > 0:
            raise ValueError("boom")

    with pytest.raises(ValueError, match="boom"):
        _threads.run_ranges(bad, 50, (), parallel=True)
    if not hasattr(os, "fork") or _threads.n_threads() < 2:
        return
    pid = os.fork()
    if pid == 0:  # child: must not hang on the parent's pool
        import signal

        signal.alarm(60)  # a hang ends the child (killed by SIGALRM: exit code != 0)
        try:
            out = np.zeros(100, dtype=np.int64)
            _threads.run_ranges(kern, 100, (out,), parallel=True)
            os._exit(0 if (out == 1).all() else 1)
        except BaseException:
            os._exit(2)
    _, status = os.waitpid(pid, 0)
    assert os.waitstatus_to_exitcode(status) == 0


def test_compiled_moving_sums_bit_identical(monkeypatch):
    """The compiled running-sum differences of the Bartlett long-run covariances are the
    numpy ones bit for bit (same sequential sums), signed zeros included, for every
    shape the estimators use and the edge cases (one row, bandwidth beyond the series)."""
    from vesselid.identify import covariance

    rng = np.random.default_rng(7)
    monkeypatch.setenv("VESSELID_KERNELS", "compiled")
    with backend.choose(10, 1):  # the compiled path: the dispatch uses the kernel
        assert covariance._loaded_kernel("moving_sums") is not None
    monkeypatch.setenv("VESSELID_KERNELS", "numpy")
    for q in (0, 1, 3, 7):
        for n in (1, 2, 5, 200):
            for lag in (0, 1, 4, 17, 300):
                x = rng.normal(size=(q, n)) * 10.0 ** rng.integers(-30, 30, size=(q, n))
                x[:, ::3] = -0.0
                got = ivk.moving_sums(np.ascontiguousarray(x), lag)
                with backend.choose(10, 1):  # the numpy path: numpy's cumsum
                    assert covariance._loaded_kernel("moving_sums") is None
                    want = covariance.moving_sums(x, lag)
                assert got.shape == want.shape == (q, n + lag)
                assert np.array_equal(got, want)
                assert np.array_equal(np.signbit(got), np.signbit(want))


def test_compiled_bartlett_long_run_bit_identical(monkeypatch):
    """The Bartlett long-run covariance from the centred moving sums computed straight
    from the time-major scores (no transposed centred copy) equals the numpy path bit
    for bit: the same column means (pairwise sums of each column) and running sums."""
    from vesselid.identify import covariance

    rng = np.random.default_rng(11)
    for q in (1, 3, 7):
        for n in (2, 9, 200, 20_001):
            for lag in (1, 4, 17, 300):
                g = rng.normal(size=(n, q)) * 10.0 ** rng.integers(-8, 8, size=q) + 0.3
                monkeypatch.setenv("VESSELID_KERNELS", "compiled")
                with backend.choose(10, 1):
                    assert covariance._loaded_kernel("centred_moving_sums") is not None
                    got = covariance.bartlett_long_run(g, lag)
                monkeypatch.setenv("VESSELID_KERNELS", "numpy")
                with backend.choose(10, 1):
                    assert covariance._loaded_kernel("centred_moving_sums") is None
                    want = covariance.bartlett_long_run(g, lag)
                assert np.array_equal(got, want), (q, n, lag)


def _badly_scaled(rng: np.random.Generator, shape: tuple[int, ...]) -> np.ndarray:
    """Normal matrices (the last two axes) with column scales 1e-8…1e7 and row scales
    1e-5…1e4, one draw per column and row shared by the leading axis."""
    *lead, n, m = shape
    ones = [1] * len(lead)
    return (rng.normal(size=shape) * 10.0 ** rng.integers(-8, 8, size=(*ones, 1, m))
            * 10.0 ** rng.integers(-5, 5, size=(*ones, n, 1)))


@pytest.mark.slow
def test_single_system_equilibration_bit_identical():
    """``linalg._equilibrate_one`` (the checked fit's one system) returns the scales of
    the vectorised ``equilibrate`` bit for bit: badly scaled, nearly singular, with zero,
    infinite and all-zero entries, converged or stopped at ``max_iter``."""
    from vesselid.identify import linalg

    rng = np.random.default_rng(11)
    for n, m in ((1, 1), (2, 2), (3, 3), (4, 4), (3, 5), (7, 3), (8, 8), (9, 9)):
        for k in range(60):
            a = _badly_scaled(rng, (1, n, m))
            if k % 5 == 0:
                a[0, rng.integers(n), rng.integers(m)] = 0.0
            if k % 7 == 0:
                a[0, 0] = a[0, -1] * 1e-12
            if k % 11 == 0:
                a[0, rng.integers(n), rng.integers(m)] = np.inf
            if k % 13 == 0:
                a[0, :, 0] = 0.0
            for max_iter, tol in ((50, 1e-9), (100, 1e-15), (3, 1e-9), (30, 1e-3), (20, 0.3)):
                r1, c1 = linalg.equilibrate(a, max_iter=max_iter, tol=tol)
                r2, c2 = linalg._equilibrate_one(a, max_iter, tol)
                assert np.array_equal(r1, r2) and np.array_equal(c1, c2)
                assert r1.shape == r2.shape and c1.shape == c2.shape


def test_single_system_condition_bit_identical():
    """``linalg._cond_one`` (one system: the checked fit's solves and condition numbers)
    equals the vectorised formulation (equilibrate, scale, ``np.linalg.cond``) bit for
    bit, including the infinite condition of non-finite, zero-row/column, all-zero and
    singular matrices; ``solve`` and ``inv_sym`` of one system equal those of the same
    system twice (the vectorised path)."""
    from vesselid.identify import linalg

    rng = np.random.default_rng(12)
    for n, m in ((1, 1), (2, 2), (3, 3), (4, 4), (3, 5), (5, 3), (8, 8), (9, 9)):
        for k in range(40):
            a = _badly_scaled(rng, (2, n, m))
            if k % 5 == 0:
                a[0, rng.integers(n), rng.integers(m)] = 0.0
            if k % 7 == 0:
                a[0, :, 0] = 0.0
            if k % 11 == 0:
                a[0, 0, 0] = np.inf if k % 2 else np.nan
            if k % 13 == 0 and n == m > 1:
                a[0, 1] = 3.0 * a[0, 0]
            if k % 17 == 0:
                a[0] = 0.0
            if k % 19 == 0:
                a[0, :, -1] *= 1e160  # column norms overflow: scaled as a zero column is
            x = a[:1]
            want = np.inf  # the vectorised formulation, written out for one system
            if (np.all(np.isfinite(x)) and np.all(np.any(x != 0, axis=1))
                    and np.all(np.any(x != 0, axis=2))):
                r, c = linalg.equilibrate(x, max_iter=50, tol=1e-9)
                try:
                    want = np.linalg.cond(x * r[:, :, None] * c[:, None, :])[0]
                except np.linalg.LinAlgError:  # the same error from the one-system path
                    with pytest.raises(np.linalg.LinAlgError):
                        linalg._cond_one(a[0])
                    continue
            one = linalg._cond_one(a[0])
            assert one == want or (np.isnan(one) and np.isnan(want))
            assert linalg._equilibrated_cond(x)[0] == one or np.isnan(one)
            if n == m:  # solve(): one system vs the same system twice (vectorised path)
                b = rng.normal(size=(1, n))
                one_x, one_ok = linalg.solve(x, b)
                two_x, two_ok = linalg.solve(np.concatenate([x, x]), np.concatenate([b, b]))
                assert np.array_equal(one_x[0], two_x[0], equal_nan=True)
                assert one_ok[0] == two_ok[0]
                sym = x @ np.swapaxes(x, 1, 2)  # inv_sym: one matrix vs the same twice
                sym[:, 0, 0] = sym[:, 0, 0] if k % 3 else -1.0
                one_w, one_ok = linalg.inv_sym(sym)
                two_w, two_ok = linalg.inv_sym(np.concatenate([sym, sym]))
                assert np.array_equal(one_w[0], two_w[0], equal_nan=True)
                assert one_ok[0] == two_ok[0]


def test_compiled_singularity_decision_is_the_exact_one():
    """``solve``'s singularity decision from the compiled equilibration
    (``linalg._cond_below``) equals the exact one on regular, badly scaled and nearly
    singular systems; the compiled condition number agrees with the exact one to
    rounding (``n ε κ``), far inside the margin the decision leaves to the exact path."""
    from vesselid.identify import linalg

    rng = np.random.default_rng(21)
    for n in (1, 2, 3, 5, 7):
        for k in range(300):
            a = _badly_scaled(rng, (n, n))
            if k % 3 == 0 and n > 1:  # nearly singular, across the threshold 1e15
                a[-1] = a[0] * rng.uniform(0.5, 2) + a[-1] * 10.0 ** rng.uniform(-18, -6)
            if k % 17 == 0:
                a[0, 0] = np.nan
            exact = linalg._cond_one(a)
            want = bool(np.isfinite(exact) and exact < linalg.COND_MAX)
            assert linalg._cond_below(a, linalg.COND_MAX) == want
            if np.isfinite(exact) and exact < 1e12:
                r, c = ivk.equilibrate_one(np.ascontiguousarray(a), 50, 1e-9)
                fast = np.linalg.cond((a * r[:, None]) * c[None, :])
                assert abs(fast - exact) <= 1e3 * n * EPS * exact**2 + 1e-8 * exact
                # the bound the decision uses: ‖S‖_F ‖S⁻¹‖_F, between κ₂ and n κ₂
                bound = ivk.cond_bound(np.ascontiguousarray(a), 50, 1e-9)
                slack = 1e3 * n * EPS * fast + 1e-8
                assert fast * (1 - slack) <= bound <= n * fast * (1 + slack)
            if not np.all(np.isfinite(a)):
                assert ivk.cond_bound(np.ascontiguousarray(a), 50, 1e-9) == np.inf


def test_compiled_column_sums_bit_identical(monkeypatch):
    """The compiled column sums (of squares) are numpy's row-order sums bit for bit, and
    ``covariance.column_means`` takes them only where numpy adds rows in order (C order,
    two columns or more) on the compiled path."""
    from vesselid.identify import covariance

    rng = np.random.default_rng(9)
    for rows in (1, 2, 7, 1000, 10001):
        for cols in range(2, 12):
            x = rng.normal(size=(rows, cols)) * 10.0 ** rng.integers(-20, 20, size=(rows, cols))
            x[::4] = -0.0
            assert np.array_equal(ivk.column_sums(x, False), x.sum(axis=0))
            assert np.array_equal(ivk.column_sums(x, True) / rows, np.mean(x**2, axis=0))
    monkeypatch.setenv("VESSELID_KERNELS", "compiled")
    x = rng.normal(size=(5000, 7))
    with backend.choose(10, 1):
        assert np.array_equal(covariance.column_means(x), x.mean(axis=0))
        assert np.array_equal(covariance.column_means(x[:, :1]), x[:, :1].mean(axis=0))
        assert np.array_equal(covariance.column_means(x.T), x.T.mean(axis=0))
