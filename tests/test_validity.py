"""Parameter-stability and mean-current diagnostics, pem's sandwich covariance and
``auto``'s choice sentence (:mod:`vesselid.identify.validity`)."""

from __future__ import annotations

import warnings

import numpy as np
import pandas as pd
import pytest

from vesselid.errors import IdentifiabilityWarning, IdentificationError, ParameterDriftWarning
from vesselid.identify import identify
from vesselid.identify.efficient import InstrumentalGMM
from vesselid.identify.pem import PredictionError
from vesselid.model.spec import ModelSpec

THETA0 = (0.9, -0.2, 0.8)
SPEC = ModelSpec(name="heave-test", states=["w"], inputs=["tau"],
                 equations={"w": ["w", "w*|w|", "tau"]}, theta0={"w": list(THETA0)}, dt=1.0)


def _log(seed: int, n: int = 10_000, *, vbar: float = 0.0, drift: float = 0.0,
         gm_current: float = 0.0, gm_sensor: float = 0.0) -> pd.DataFrame:
    """Heave with random pulses of random sign (the robustness study's design)."""
    rng = np.random.default_rng(seed)
    widths = rng.integers(10, 101, size=n // 10 + 2)
    levels = rng.uniform(0.1, 0.4, widths.size) * rng.choice([-1.0, 1.0], widths.size)
    tau = np.repeat(levels, widths)[:n]
    if gm_current:
        v = _gauss_markov(rng, n, gm_current, 25.0)
    else:
        v = rng.normal(0.0, 0.05, n)
    v += vbar
    xi = rng.normal(0.0, 0.05, n)
    f = THETA0[2] * (1 + drift * (np.arange(n) / (n - 1) - 0.5))
    w = np.zeros(n)
    a, nn, _ = THETA0
    for k in range(n - 1):
        wr = w[k] - v[k]
        w[k + 1] = a * wr + nn * wr * abs(wr) + f[k] * tau[k] + xi[k]
    y = w + rng.normal(0.0, 0.05, n)
    if gm_sensor:
        y += _gauss_markov(rng, n, gm_sensor, 20.0)
    return pd.DataFrame({"time": np.arange(n, dtype=float), "w": y, "tau": tau})


def _gauss_markov(rng: np.random.Generator, n: int, std: float, tau: float) -> np.ndarray:
    from scipy.signal import lfilter

    rho = np.exp(-1 / tau)
    e = rng.normal(0.0, std * np.sqrt(1 - rho * rho), n)
    e[0] = rng.normal(0.0, std)
    return lfilter([1.0], [1.0, -rho], e)


def _fit(log, method="auto"):
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        res = identify(log, SPEC, method)
    return res, {type(w.message) for w in caught}


def test_mean_current_is_detected_and_its_mean_reported():
    res, cats = _fit(_log(1, vbar=0.05))
    mc = res.diagnostics["mean_current"]
    assert mc["warned"] and IdentifiabilityWarning in cats
    # the reported mean of the current: within 4 of its own standard errors of the truth
    assert abs(mc["estimate"] - 0.05) < 4 * mc["std_error"]
    assert mc["std_error"] < 0.05 / 3  # and distinguishable from zero
    assert "v̄ =" in mc["sentence"]


def test_no_mean_current_warning_on_a_zero_mean_current():
    res, cats = _fit(_log(2))
    assert not res.diagnostics["mean_current"]["warned"]
    assert IdentifiabilityWarning not in cats


def test_stability_test_names_a_drifting_gain_and_not_a_constant_one():
    res, cats = _fit(_log(3, drift=0.3))
    st = res.diagnostics["parameter_stability"]
    assert st["rejected"] and ParameterDriftWarning in cats
    assert st["second_half"]["w: tau"] > st["first_half"]["w: tau"]
    res, cats = _fit(_log(4))
    assert not res.diagnostics["parameter_stability"]["rejected"]
    assert ParameterDriftWarning not in cats


@pytest.mark.parametrize("kwargs", [{"drift": 0.3}, {"vbar": 0.05}, {"gm_current": 0.08}])
def test_validity_checks_on_a_second_thread_give_the_serial_numbers(kwargs):
    from vesselid.core import threads

    log = _log(5, **kwargs)
    with threads.serial_here():
        serial, _ = _fit(log)
    threaded, _ = _fit(log)
    for key in ("parameter_stability", "mean_current"):
        assert serial.diagnostics[key] == threaded.diagnostics[key], key
    np.testing.assert_array_equal(serial.params.to_numpy(), threaded.params.to_numpy())


def test_choice_text_does_not_blame_colour_when_the_parameters_drift():
    est = InstrumentalGMM("auto", noise_order=4, pem_fallback=True)
    info = {"c_pvalue": np.array([1e-5]), "colour_pvalue": np.array([1e-4]),
            "instrument_set": np.array(["simulated"], dtype=object), "pem_applies": False,
            "stability": {"rejected": True, "pvalue": 1e-4}}
    text = est._choice_text(info)
    assert "look coloured" not in text and "drifting parameters" in text
    assert "may drift" in est._choice_sentence(info)
    info["stability"] = {"rejected": False, "pvalue": 0.5}
    assert "look coloured" in est._choice_text(info)


def test_auto_models_a_gm_current_and_says_why_in_one_sentence():
    res, _ = _fit(_log(5, gm_current=0.1))
    assert res.diagnostics["choice"].startswith("pem-")
    reason = res.diagnostics["choice_reason"]
    assert reason.startswith("auto used the prediction-error estimator") and reason.count(". ") == 0
    assert res.diagnostics["cov_type"] == "conservative"
    assert "quasi-ML sandwich" in res.summary()
    sand, _ = _fit(_log(5, gm_current=0.1), InstrumentalGMM("auto", noise_order=4, refine=1,
                                                             pem_fallback=True,
                                                             pem_cov="sandwich"))
    fisher, _ = _fit(_log(5, gm_current=0.1), InstrumentalGMM("auto", noise_order=4, refine=1,
                                                              pem_fallback=True,
                                                              pem_cov="fisher"))
    np.testing.assert_array_equal(res.params, sand.params)
    # the conservative covariance lies above both in the Loewner order
    for other in (sand, fisher):
        gap = np.linalg.eigvalsh(res.cov.to_numpy() - other.cov.to_numpy())
        assert gap.min() >= -1e-12 * np.abs(res.cov.to_numpy()).max()


def test_weak_rejection_takes_sriv_and_says_why():
    """The likelihood fallback needs the rejection at pem_level × the test's level; below
    that auto takes SRIV and says so (pem_level so small that no rejection reaches it)."""
    log = _log(5, gm_current=0.1)
    strict, _ = _fit(log, InstrumentalGMM("auto", noise_order=4, refine=1, pem_fallback=True,
                                          pem_level=1e-300))
    assert strict.diagnostics["choice"] == "sriv"
    assert "too weak" in strict.diagnostics["choice_reason"]
    default, _ = _fit(log)
    assert default.diagnostics["choice"].startswith("pem-")


def test_colour_guard_sends_the_guard_band_to_the_likelihood_fit_and_says_why():
    """Where neither test rejects at its level, auto keeps the delayed instruments exactly
    when the colour test's p-value is at least colour_guard; in the band below it takes
    the likelihood fallback and names the guard (without the fallback the band keeps the
    delayed instruments). Ten white logs, each decided by its own p-values."""
    banded = 0
    for seed in range(10):
        log = _log(seed, n=3000)
        off, _ = _fit(log, InstrumentalGMM("auto", noise_order=4, refine=1, pem_fallback=True,
                                           colour_guard=0.0))
        res, _ = _fit(log)
        p_w = off.diagnostics["colour_test"][0]["pvalue"]
        p_c = off.diagnostics["c_test_lagged"][0]["pvalue"]
        if p_c < 0.01 or p_w < 0.05:  # a rejection at the level: the guard plays no part
            assert res.diagnostics["choice"] == off.diagnostics["choice"]
            continue
        assert off.diagnostics["choice"] == "combined"
        if p_w < 0.2:
            banded += 1
            assert res.diagnostics["choice"].startswith("pem-")
            assert "guard 0.2" in res.diagnostics["choice_reason"]
            # without the likelihood fallback the band keeps the delayed instruments
            bare, _ = _fit(log, InstrumentalGMM("auto", noise_order=4, refine=1))
            assert bare.diagnostics["choice"] == "combined"
            np.testing.assert_array_equal(bare.params, off.params)
        else:
            assert res.diagnostics["choice"] == "combined"
            np.testing.assert_array_equal(res.params, off.params)
    assert banded  # the band was exercised


def test_conservative_covariance_by_hand():
    from vesselid.identify.pem import conservative_covariance

    fisher = np.diag([4.0, 1.0])
    sandwich = np.diag([2.0, 3.0])  # excess -2 (dropped) and +2 (kept)
    np.testing.assert_allclose(conservative_covariance(fisher, sandwich), np.diag([4.0, 3.0]))
    rot = np.array([[1.0, 1.0], [-1.0, 1.0]]) / np.sqrt(2.0)
    np.testing.assert_allclose(conservative_covariance(rot @ fisher @ rot.T,
                                                       rot @ sandwich @ rot.T),
                               rot @ np.diag([4.0, 3.0]) @ rot.T, atol=1e-12)
    assert np.isnan(conservative_covariance(fisher, np.full((2, 2), np.nan))).all()


def test_pem_sandwich_and_fisher_agree_on_its_own_model():
    log = _log(6, gm_current=0.1)
    fisher, _ = _fit(log, PredictionError())
    sand, _ = _fit(log, PredictionError(covariance="sandwich"))
    np.testing.assert_array_equal(fisher.params, sand.params)
    ratio = sand.std_errors / fisher.std_errors
    assert ((ratio > 0.7) & (ratio < 1.4)).all(), ratio
    assert "assumes the disturbances are" in fisher.diagnostics["assumption"]


@pytest.mark.parametrize("make,msg", [
    (lambda: PredictionError(covariance="hc0"), "covariance must be one of"),
    (lambda: PredictionError(joint="yes"), "joint must be True or False"),
    (lambda: InstrumentalGMM("auto", pem_cov="robust"), "pem_cov must be one of"),
    (lambda: PredictionError(covariance="largest"), "covariance must be one of"),
    (lambda: InstrumentalGMM("auto", pem_level=0.0), "pem_level must be in"),
    (lambda: InstrumentalGMM("auto", pem_level=True), "pem_level must be in"),
    (lambda: InstrumentalGMM("auto", colour_guard=1.0), "colour_guard must be in"),
    (lambda: InstrumentalGMM("auto", colour_guard=-0.1), "colour_guard must be in"),
    (lambda: InstrumentalGMM("auto", colour_guard=True), "colour_guard must be in"),
    (lambda: InstrumentalGMM("auto", colour_guard="0.2"), "colour_guard must be in"),
    (lambda: InstrumentalGMM("auto", guard_misfit=0.9), "guard_misfit must be"),
    (lambda: InstrumentalGMM("auto", guard_misfit=float("nan")), "guard_misfit must be"),
])
def test_bad_options_one_line_reasons(make, msg):
    with pytest.raises(IdentificationError, match=msg) as err:
        identify(_log(7, n=500), SPEC, make())
    assert "\n" not in str(err.value)


@pytest.mark.slow
@pytest.mark.parametrize("kind", ["gm-current", "two-coloured"])
def test_auto_coverage_on_coloured_currents(kind):
    """auto's 95 % intervals cover θ0 in a binomially plausible share of 60 runs (three
    binomial standard errors below 95 %)."""
    runs = 60
    hits = np.zeros(3)
    for seed in range(runs):
        log = _log(100 + seed, gm_current=0.1, gm_sensor=0.05 if kind == "two-coloured" else 0.0)
        res, _ = _fit(log)
        ci = res.conf_int()
        hits += (ci["lower"].to_numpy() <= THETA0) & (np.asarray(THETA0) <= ci["upper"])
    floor = 0.95 - 3 * np.sqrt(0.95 * 0.05 / runs)
    assert (hits / runs >= floor).all(), hits / runs


@pytest.mark.slow
def test_mean_current_without_a_sensor_is_flagged_and_its_mean_covered():
    """A current with a mean and no sensor: a and the offset are not separately
    identifiable, so what the default must get right is the warning (in a binomially
    plausible share of 95 % of 60 runs or more) and the interval of the identifiable
    quantity it reports, the current's mean v̄ (95 % interval, same floor); f, which the
    mean does not confound, keeps its θ0 coverage."""
    runs, vbar = 60, 0.05
    warned = covered = f_hits = 0
    for seed in range(runs):
        res, cats = _fit(_log(100 + seed, vbar=vbar))
        mc = res.diagnostics["mean_current"]
        warned += bool(mc["warned"]) and IdentifiabilityWarning in cats
        covered += abs(mc["estimate"] - vbar) <= 1.96 * mc["std_error"]
        lo, hi = res.conf_int().iloc[2]
        f_hits += lo <= THETA0[2] <= hi
    floor = 0.95 - 3 * np.sqrt(0.95 * 0.05 / runs)
    assert warned / runs >= floor, warned / runs
    assert covered / runs >= floor, covered / runs
    assert f_hits / runs >= floor, f_hits / runs


@pytest.mark.slow
def test_white_logs_take_the_likelihood_fit_in_the_guard_band_and_coloured_currents_always():
    """pem_level and colour_guard: on the paper's white Table 1 design the likelihood
    fallback is used in a share of runs binomially plausible for the guard band's 15 %
    (colour-test p-value in [0.05, 0.2), uniform under white disturbances) plus the strict
    levels' 0.5 % (three binomial standard errors), and exactly on the runs the two
    tests' p-values send there; on a Gauss–Markov current every run takes it (the strict
    level keeps the power where pem matters)."""
    from vesselid.identify.registry import get_estimator
    from vesselid.studies.calibration import _heave_batches, _heave_data, heave_scenario

    shares = {}
    for scenario, runs in (("table1-alternating", 200), ("gm-current-random", 60)):
        system, agg, target = heave_scenario(scenario)
        spec = system.identification_spec(aggregate=agg)
        sim = next(_heave_batches(system, runs, 10_000, 7, runs))
        it = get_estimator("auto").estimate_parameters(_heave_data(spec, sim, agg, target),
                                                      spec)
        took = it.info["instrument_set"] == "pem"
        shares[scenario] = float(np.mean(took))
        c_p, w_p = it.info["c_pvalue"], it.info["colour_pvalue"]
        sent = (c_p < 0.001) | (w_p < 0.005) | ((c_p >= 0.01) & (w_p >= 0.05) & (w_p < 0.2))
        assert not (took & ~sent).any()  # the likelihood fit only where the gate sends it
    share = 0.15 + 0.005
    assert shares["table1-alternating"] <= share + 3 * np.sqrt(share * (1 - share) / 200), \
        shares
    assert shares["gm-current-random"] == 1.0, shares


def test_sandwich_fisher_ratio_by_hand():
    """The guard band's misfit measure: the largest sandwich / inverse-Fisher standard
    error ratio over the parameters, NaN where the likelihood fit was not made."""
    from vesselid.identify.efficient import _sandwich_fisher_ratio

    fisher = np.stack([np.diag([1.0, 4.0]), np.full((2, 2), np.nan)])
    sandwich = np.stack([np.diag([2.25, 4.0]), np.full((2, 2), np.nan)])
    ratio = _sandwich_fisher_ratio({"pem_cov": fisher, "pem_cov_sandwich": sandwich})
    assert ratio[0] == 1.5 and np.isnan(ratio[1])
