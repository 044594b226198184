"""The switching-current (telegraph) likelihood estimator and its place in ``auto``."""

from __future__ import annotations

import json
import math
import warnings

import numpy as np
import pandas as pd
import pytest

from vesselid.errors import IdentificationError
from vesselid.identify import identify
from vesselid.model.spec import ModelSpec

THETA0 = (0.9, -0.2, 0.8)
SPEC = ModelSpec(name="heave-switch", states=["w"], inputs=["tau"],
                 equations={"w": ["w", "w*|w|", "tau"]}, theta0={"w": list(THETA0)}, dt=1.0)


def telegraph_log(n: int, seed: int, *, c: float = 0.06, p: float = 0.02,
                  xi: float = 0.05, e: float = 0.05, current: str = "telegraph",
                  scale: float = 1.0) -> pd.DataFrame:
    """Heave ``w(k+1) = a w_r + n w_r|w_r| + f τ + ξ``, ``w_r = w − v``, ``y = w + e``
    with random pulses ``τ``; ``v`` a telegraph current ±c switching w.p. ``p`` (or a
    Gauss–Markov current of std ``c`` and time constant 25 samples)."""
    rng = np.random.default_rng(seed)
    widths = rng.integers(10, 101, size=n // 10 + 2)
    levels = rng.uniform(0.1, 0.4, widths.size) * rng.choice([-1.0, 1.0], widths.size)
    tau = np.repeat(levels, widths)[:n]
    if current == "telegraph":
        flips = rng.random(n) < p
        v = c * rng.choice([-1.0, 1.0]) * np.where(np.cumsum(flips) % 2 == 0, 1.0, -1.0)
    else:
        rho = math.exp(-1.0 / 25.0)
        drive = rng.normal(0.0, c * math.sqrt(1 - rho * rho), n)
        v = np.empty(n)
        v[0] = rng.normal(0.0, c)
        for k in range(1, n):
            v[k] = rho * v[k - 1] + drive[k]
    ks = rng.normal(0.0, xi, n)
    a, nn, f = THETA0
    w = np.zeros(n)
    for k in range(n - 1):
        wr = w[k] - v[k]
        w[k + 1] = a * wr + nn * wr * abs(wr) + f * tau[k] + ks[k]
    y = w + rng.normal(0.0, e, n) if e > 0 else w
    return pd.DataFrame({"time": np.arange(n, dtype=float), "w": y * scale,
                         "tau": tau * scale})


def _fit(log, method="pem-switching", spec=SPEC, **kw):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return identify(log, spec, method, **kw)


@pytest.fixture(scope="module")
def light():
    """A long, noise-light telegraph log and its fit."""
    log = telegraph_log(20_000, 3, xi=0.002, e=0.002)
    return log, _fit(log)


def test_noise_light_telegraph_log_is_recovered(light):
    """Process and sensor noise 0.002 against a current ±0.06: θ to a few 1e-4 (within
    4 of its own standard errors), the current's level and switching rate to a few %."""
    _, res = light
    est, se = res.params.to_numpy(), res.std_errors.to_numpy()
    assert np.all(se < 2e-3)
    assert np.all(np.abs(est - THETA0) <= 4.0 * se)
    assert np.all(np.abs(est - THETA0) < 2e-3)
    noise = res.diagnostics["noise_parameters"]
    assert noise["c"] == pytest.approx(0.06, rel=0.03)
    assert noise["p"] == pytest.approx(0.02, rel=0.25)
    assert noise["sigma_w"] == pytest.approx(0.002, rel=0.25)
    assert res.disturbance_model == "switching"
    assert np.isfinite(res.log_likelihood["switching"])
    assert res.noise_parameters["c"] == noise["c"]
    assert res.converged


def test_noise_free_log_is_exact():
    log = telegraph_log(3000, 1, xi=0.0, e=0.0, c=0.0)
    res = _fit(log)
    np.testing.assert_allclose(res.params.to_numpy(), THETA0, atol=1e-10)
    assert res.diagnostics["disturbance_model"] == "none"


def test_units_do_not_matter(light):
    """Signals × 1e3: a and f unchanged, n / 1e3, the same standard errors (scaled)."""
    log, ref = light
    log = log.iloc[:6000]
    ref = _fit(log)
    res = _fit(telegraph_log(20_000, 3, xi=0.002, e=0.002, scale=1e3).iloc[:6000])
    unit = np.array([1.0, 1e3, 1.0])
    np.testing.assert_allclose(res.params.to_numpy() * unit, ref.params.to_numpy(),
                               rtol=1e-6)
    np.testing.assert_allclose(res.std_errors.to_numpy() * unit,
                               ref.std_errors.to_numpy(), rtol=1e-4)


def test_without_a_current_the_filter_is_the_kalman_filter():
    """A linear equation and a vanishing current level: the two-level filter's
    log-likelihood is the Kalman filter's, computed here by hand."""
    from vesselid.identify._pemkernels import term_kinds
    from vesselid.identify._switchkernels import switching_filter

    rng = np.random.default_rng(0)
    n = 300
    u = rng.normal(size=(n, 1))
    y = rng.normal(size=n).cumsum() * 0.1
    a, f, mw, sw, se = 0.8, 0.5, 0.01, 0.1, 0.2
    fac = np.array([[0, 4], [1, 4]], dtype=np.int64)  # x, u  (F = [x, u, |x|, |u|, 1])
    psi = np.array([[a, f, mw, math.log(1e-12), 0.0, math.log(sw), math.log(se)]])
    ll = np.zeros((1, n))
    tot = np.empty(1)
    p0 = np.array([float(np.var(y))])
    switching_filter(psi, y, u, np.array([0, n]), p0, *term_kinds(fac, 2), ll, tot)
    m, p, ref = y[0], p0[0], 0.0
    for k in range(n):
        if k:
            s = p + se * se
            ref += -0.5 * (math.log(2 * math.pi * s) + (y[k] - m) ** 2 / s)
        g = p / (p + se * se)
        m, p = m + g * (y[k] - m), p - g * p
        m, p = a * m + f * u[k, 0] + mw, a * a * p + sw * sw
    assert tot[0] == pytest.approx(ref, rel=1e-9)
    assert ll[0, 0] == 0.0 and np.sum(ll[0]) == pytest.approx(tot[0], rel=1e-12)


def test_vuong_statistic_by_hand():
    from vesselid.identify.switching import vuong_switching

    a = np.array([np.nan, 1.0, 2.0, 0.5, 1.5])
    b = np.array([np.nan, 0.5, 1.0, 1.0, 0.5])
    d = a[1:] - b[1:]
    want = (d.sum() - 0.5 * (6 - 8) * math.log(4)) / (2.0 * d.std())
    assert vuong_switching(a, b, 6, 8) == pytest.approx(want, rel=1e-12)


@pytest.mark.parametrize(("options", "reason"), [
    ({"max_iter": 0}, "max_iter must be a positive integer"),
    ({"max_iter": True}, "max_iter must be a positive integer"),
    ({"tol": -1.0}, "tol must be a positive number"),
    ({"tol": float("nan")}, "tol must be a positive number"),
    ({"covariance": "hac"}, "covariance must be one of"),
])
def test_bad_options_get_one_line_reasons(options, reason):
    from vesselid.identify.switching import SwitchingCurrent

    log = telegraph_log(500, 2)
    with pytest.raises(IdentificationError, match=reason) as exc:
        _fit(log, SwitchingCurrent(**options))
    assert "\n" not in str(exc.value)


def test_unsupported_specs_and_options_are_refused():
    two = ModelSpec(name="two", states=["u", "r"], inputs=["t"],
                    equations={"u": ["u", "t"], "r": ["r", "t"]}, dt=1.0)
    rng = np.random.default_rng(0)
    log2 = pd.DataFrame({"time": np.arange(300.0), "u": rng.normal(size=300),
                         "r": rng.normal(size=300), "t": rng.normal(size=300)})
    with pytest.raises(IdentificationError, match="one state equation") as exc:
        _fit(log2, spec=two)
    assert "\n" not in str(exc.value)
    with pytest.raises(IdentificationError, match="cov_type 'hac'"):
        _fit(telegraph_log(500, 2), cov_type="hac")


def test_cli_bad_input_exits_two(tmp_path, capsys):
    from vesselid.cli import main

    path = tmp_path / "two.csv"
    rng = np.random.default_rng(0)
    pd.DataFrame({"time": np.arange(300.0), "u": rng.normal(size=300),
                  "r": rng.normal(size=300), "t": rng.normal(size=300)}).to_csv(path,
                                                                              index=False)
    toml = tmp_path / "two.toml"
    toml.write_text('name = "two"\nstates = ["u", "r"]\ninputs = ["t"]\ndt = 1.0\n'
                    '[equations]\nu = ["u", "t"]\nr = ["r", "t"]\n')
    code = main(["identify", str(path), "--model", str(toml), "--method", "pem-switching"])
    err = capsys.readouterr().err
    assert code == 2 and "one state equation" in err and len(err.strip().splitlines()) == 1


def test_cli_identifies_with_pem_switching(tmp_path, capsys):
    from vesselid.cli import main

    path = tmp_path / "tele.csv"
    telegraph_log(4000, 8).to_csv(path, index=False)
    toml = tmp_path / "heave.toml"
    toml.write_text('name = "heave"\nstates = ["w"]\ninputs = ["tau"]\ndt = 1.0\n'
                    '[equations]\nw = ["w", "w*|w|", "tau"]\n')
    code = main(["identify", str(path), "--model", str(toml), "--method", "pem-switching",
                 "--json", "-"])
    out = capsys.readouterr().out
    assert code == 0
    payload = json.loads(out[out.index("{"):])
    assert "telegraph current" in json.dumps(payload, ensure_ascii=False)


def test_auto_takes_the_switching_model_on_a_telegraph_log_only():
    """auto's default chain: a telegraph log ends at the switching model (with the
    reason in one sentence), a Gauss–Markov-current log at the Gauss–Markov models."""
    res = _fit(telegraph_log(10_000, 11), "auto")
    d = res.diagnostics
    assert d["choice"] == "pem-switching"
    assert "two-level switching" in d["choice_reason"] and "Vuong" in d["choice_reason"]
    assert d["choice_reason"].count(". ") == 0
    assert np.isfinite(res.log_likelihood["switching"])
    assert res.noise_parameters["c"] == pytest.approx(0.06, rel=0.15)
    json.dumps(res.to_dict())  # the report is JSON-ready
    gm = _fit(telegraph_log(10_000, 11, current="gm", c=0.1), "auto")
    assert gm.diagnostics["choice"] in ("pem-current", "pem-joint", "pem-joint-local")


def test_auto_keeps_the_gaussian_model_where_vuong_does_not_prefer_switching(monkeypatch):
    """A telegraph log with Vuong's level made unreachable: auto reports the bounded
    Gauss–Markov joint fit and says that the switching model fitted no better."""
    from vesselid.identify import switching

    monkeypatch.setattr(switching, "VUONG_ALPHA", 1e-300)
    res = _fit(telegraph_log(10_000, 11), "auto")
    d = res.diagnostics
    assert d["choice"] == "pem-joint"
    assert "fits no better" in d["choice_reason"]
    assert d["switching_current"]["vuong_z"] > 1.645


@pytest.mark.slow
def test_coverage_and_bias_on_the_telegraph_design():
    """30 telegraph logs (the robustness study's design, 10⁴ samples): each parameter's
    95 % intervals cover θ0 at least as often as a one-sided binomial test at 1 % allows
    (≥ 25 of 30 under 95 %), and the mean error is within 3.5 of its own Monte Carlo
    standard errors."""
    from scipy.stats import binom

    est, se = [], []
    for seed in range(30):
        res = _fit(telegraph_log(10_000, 100 + seed))
        est.append(res.params.to_numpy())
        se.append(res.std_errors.to_numpy())
    err = np.array(est) - THETA0
    se = np.array(se)
    covered = (np.abs(err) <= 1.959964 * se).sum(axis=0)
    floor = int(binom.ppf(0.01, 30, 0.95))
    assert np.all(covered >= floor), (covered, floor)
    z = err.mean(axis=0) / (err.std(axis=0, ddof=1) / math.sqrt(30))
    assert np.all(np.abs(z) <= 3.5), z
