"""Tests of the CyberShip II sea-trial pipeline (vesselid.studies.seatrial)."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from _stats import bonferroni_z

from vesselid.cli import main
from vesselid.errors import VesselidError
from vesselid.identify import identify
from vesselid.plant.catalogue import get_hull
from vesselid.plant.vessels import VesselSensors
from vesselid.studies.seatrial import (
    SeaTrialError,
    design_sea_trial,
    normalized_errors,
    run_pipeline,
    seatrial_spec,
    simulate_sea_trial,
)

QUIET = dict(sensors=VesselSensors.noiseless(), current_speed=0.0, current_variation=0.0,
             wind_speed=0.0, wind_gust=0.0, force_noise=(0.0, 0.0, 0.0))


@pytest.fixture(scope="module")
def design():
    return design_sea_trial(6, 5000, seed=0)


def test_design_margins_every_state_every_experiment(design):
    m = design.margins
    assert design.ok
    assert len(m) == 6 * 3 and m["ok"].all()
    assert (m["sign_changes"] == 0).all() and (m["share_within_eta"] == 0).all()
    nom = design.nominal
    assert np.all(nom[:, :, 0] > design.eta["u"])
    for e, side in enumerate(design.table["side"]):
        sgn = 1.0 if side == "starboard" else -1.0
        assert np.all(sgn * nom[e, :, 2] > design.eta["r"])  # r keeps its sign
        assert np.all(-sgn * nom[e, :, 1] > design.eta["v"])  # v opposite to r
    assert set(design.table["side"]) == {"starboard", "port"}
    assert np.all(np.abs(design.inputs) <= np.array(get_hull("cybership2").force_max) + 1e-12)


def test_design_violation_is_reported():
    bad = [(0.4, 0.0, 0.4, 1), (0.4, 0.0, 0.4, -1)]
    with pytest.raises(SeaTrialError, match="margin"):
        design_sea_trial(2, 2000, levels=bad)
    d = design_sea_trial(2, 2000, levels=bad, check=False)
    assert not d.ok and not d.violations().empty


def test_data_margins_in_identification_diagnostics():
    """The static-offset design keeps every modulus state away from zero (A10/A15); the
    planned default's ahead/astern thruster tests (and acceleration/stopping runs) reverse
    the surge speed, and the diagnostics flag those (the check can fail)."""
    log = simulate_sea_trial(6, 3000, seed=1, design="static-offset")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = identify(log, method="ls")
    assert res.diagnostics["design"]["ok"].all()
    assert res.n_experiments == 6
    planned = simulate_sea_trial(6, 3000, seed=1)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = identify(planned, method="ls")
    d = res.diagnostics["design"]
    reversing = [i for i, p in enumerate(planned.metadata["design"]["programme"])
                 if "acceleration/stopping" in p or "/-" in p]  # X=2/-2: ahead/astern
    assert reversing
    assert not d[(d["state"] == "u") & d["experiment"].isin(reversing)]["ok"].any()


def test_noise_free_recovers_theta0():
    log = simulate_sea_trial(6, 3000, seed=0, **QUIET)
    spec = log.spec
    assert spec.aggregate == {}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for m in ("ls", "iv", "iv-zero-mean"):
            res = identify(log, spec, method=m)
            err = normalized_errors(res.params, spec.theta0_series())
            assert np.max(np.abs(res.params.to_numpy() - spec.theta0_vector())) < 1e-8, m
            assert np.all(np.isfinite(err))


@pytest.mark.slow
def test_wind_load_from_the_anemometer_is_a_known_input():
    """With wind (no gusts, noise-free sensors, no force noise) the regression is exact
    once the anemometer's wind load is added to the forces; without it it is not."""
    windy = dict(QUIET, wind_speed=1.0)
    log = simulate_sea_trial(4, 1500, seed=0, **windy)
    fr = log.to_frame()
    assert log.metadata["wind_input"] == "anemometer"
    np.testing.assert_allclose(fr["X"], fr["X_cmd"] + fr["X_wind"])
    assert np.abs(fr["Y_wind"]).max() > 1e-3
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        known = identify(log, method="ls").params.to_numpy()
        old = identify(simulate_sea_trial(4, 1500, seed=0, wind_input="none", **windy),
                       method="ls").params.to_numpy()
    theta0 = log.spec.theta0_vector()
    assert np.max(np.abs(known - theta0)) < 1e-8
    assert np.max(np.abs(old - theta0)) > 1e-6
    with pytest.raises(SeaTrialError, match="wind input"):
        simulate_sea_trial(2, 100, seed=0, wind_input="sonar")


@pytest.mark.parametrize("agg", ["speed_log", "current_meter", "none"])
def test_aggregate_specs_noise_free(agg):
    log = simulate_sea_trial(4, 1500, seed=0, aggregate=agg, **QUIET)
    assert log.metadata["aggregate"] == agg
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = identify(log, method="ls")
    assert np.allclose(res.params.to_numpy(), log.spec.theta0_vector(), atol=1e-8)


def test_merged_term_and_spec():
    spec = seatrial_spec()
    names = {eq: [str(t) for t in spec.equations[eq]] for eq in spec.states}
    assert "v*|r|" not in names["v"] and "r*|v|" in names["v"]
    with pytest.raises(VesselidError):
        seatrial_spec(aggregate="sonar")


_WELL_IDENTIFIED = {("u", "X"), ("v", "Y"), ("r", "N"), ("u", "v*r"), ("v", "v*|v|"),
                    ("r", "u*v")}


def _z_scores(n: int, seed: int) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """(errors in own standard errors, SEs) of LS and IV_{E{ζ}=0} on the well-identified
    parameters of a static-offset sea trial (the design that satisfies A10/A15)."""
    log = simulate_sea_trial(6, n, seed=seed, design="static-offset")
    spec = log.spec
    idx = [i for i, (eq, t) in enumerate(spec.param_index) if (eq, str(t)) in _WELL_IDENTIFIED]
    out = {}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for m in ("ls", "iv-zero-mean"):
            r = identify(log, spec, method=m)
            se = r.std_errors.to_numpy()[idx]
            out[m] = ((r.params.to_numpy()[idx] - spec.theta0_vector()[idx]) / se, se)
    return out


@pytest.mark.slow
def test_consistency_trend_fixed_seeds():
    """IV_{E{ζ}=0} stays within its standard errors while they shrink with N; LS stays
    biased by many of its own standard errors (tolerances from the SEs of the same fit)."""
    small, large = _z_scores(5_000, 3), _z_scores(50_000, 3)
    k = len(_WELL_IDENTIFIED)
    bound = bonferroni_z(2 * k)
    for z, _ in (small["iv-zero-mean"], large["iv-zero-mean"]):
        assert np.all(np.abs(z) < bound), (z, bound)
    assert np.all(large["iv-zero-mean"][1] < small["iv-zero-mean"][1])
    assert np.median(np.abs(large["ls"][0])) > bonferroni_z(k), (large["ls"][0], bound)


def test_pipeline_summary_and_validation():
    res = run_pipeline(6, 4000, seed=0)
    assert set(res.results) == {"ls", "iv", "iv-zero-mean"}
    assert list(res.validation.index) == ["theta0", "ls", "iv", "iv-zero-mean"]
    assert np.all(np.isfinite(res.validation.to_numpy()))
    text = res.summary()
    assert "Normalized errors" in text and "held-out" in text
    assert set(res.thetas()) == {"theta0", "ls", "iv", "iv-zero-mean"}


def test_cli_end_to_end(tmp_path, capsys):
    out = tmp_path / "trial"
    code = main(["sea-trial", "--vessel", "cybership2", "--experiments", "4", "--samples",
                 "1500", "--seed", "0", "--out", str(out)])
    assert code == 0
    text = capsys.readouterr().out
    assert "next: vesselid identify" in text
    # the estimator setting the trial needs is handed to the user, not left in the log
    assert "--noise-order 16" in text
    from vesselid.data.logs import TrialLog

    assert "noise_order" not in TrialLog.load(out / "seatrial.parquet").metadata
    # Parquet (metadata inside) is the default when pyarrow is there; CSV on request
    assert (out / "seatrial.parquet").exists() and not (out / "seatrial.csv").exists()
    assert (out / "cybership2.toml").exists()
    code = main(["identify", str(out / "seatrial.parquet"), "--model",
                 str(out / "cybership2.toml"), "--method", "iv-zero-mean"])
    assert code == 0
    assert main(["sea-trial", "--experiments", "4", "--samples", "1500", "--seed", "0",
                 "--format", "csv", "--out", str(out)]) == 0
    assert (out / "seatrial.csv").exists() and (out / "seatrial.json").exists()
    capsys.readouterr()
    assert main(["identify", str(out / "seatrial.csv"), "--method", "ls"]) == 0
    from_csv = capsys.readouterr().out
    assert main(["identify", str(out / "seatrial.parquet"), "--method", "ls"]) == 0
    assert capsys.readouterr().out == from_csv  # same data, same estimates


def test_cli_bad_input_exit_2(tmp_path, capsys):
    assert main(["sea-trial", "--experiments", "1", "--out", str(tmp_path / "x")]) == 2
    assert "error" in capsys.readouterr().err
    assert main(["sea-trial", "--experiments", "2", "--samples", "500", "--wind-speed", "-1",
                 "--out", str(tmp_path / "y")]) == 2


@pytest.mark.slow
def test_env_source_matches_batch_physics():
    """The environment + recorder path gives the same identification structure."""
    log = simulate_sea_trial(2, 800, seed=0, source="env", **QUIET)
    assert set(log.to_frame()["experiment"]) == {0, 1}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = identify(log, method="ls")
    assert np.allclose(res.params.to_numpy(), log.spec.theta0_vector(), atol=1e-6)
