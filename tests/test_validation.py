"""vesselid validate: free-run / k-step fits, zig-zag and turning-circle figures, CLI."""

from __future__ import annotations

import json
import math
import subprocess
import sys

import numpy as np
import pandas as pd
import pytest
from _ship import SHIP, zigzag_log

from vesselid.model.spec import ModelSpec
from vesselid.validation.metrics import detect, integrate_track, turning_figures, zigzag_figures
from vesselid.validation.report import ValidationError, validate


@pytest.fixture(scope="module")
def spec():
    return ModelSpec.from_toml(SHIP)


@pytest.fixture(scope="module")
def log(spec):
    parts = [zigzag_log(spec, delta0=0.17, psi_s=0.17).assign(experiment="zz10"),
             zigzag_log(spec, delta0=0.35, psi_s=0.09, first=-1).assign(experiment="zz20")]
    return pd.concat(parts, ignore_index=True)


def test_noise_free_log_fits_100_percent(spec, log):
    nominal = {"zz10": {"psi_switch_deg": math.degrees(0.17)},
               "zz20": {"psi_switch_deg": math.degrees(0.09)}}
    rep = validate(log, spec, horizon=5, manoeuvres=nominal)
    assert rep.stable
    for e in rep.experiments:
        for s in spec.states:
            assert e.free_run_fit[s] == pytest.approx(100.0, abs=1e-6)
            assert e.k_step_fit[s] == pytest.approx(100.0, abs=1e-6)
    assert all(v == pytest.approx(100.0, abs=1e-6) for v in rep.free_run_fit.values())
    # the model's own zig-zag: detected, simulated as a zig-zag, same overshoots
    for e in rep.experiments:
        m = e.manoeuvre
        assert m is not None and m["kind"] == "zigzag"
        for key in ("first_overshoot_deg", "second_overshoot_deg"):
            assert m["simulated"][key] == pytest.approx(m["measured"][key], abs=1e-9)


def test_a_wrong_model_fits_worse(spec, log):
    theta = spec.theta0_vector().copy()
    theta[spec.param_index.get_loc(("r", "uud"))] *= 0.7  # weaker rudder
    rep = validate(log, spec.with_theta0(theta), experiments=["zz10"])
    e = rep.experiments[0]
    assert e.free_run_fit["r"] < 95.0
    m = e.manoeuvre  # a weaker rudder checks the swing later: a larger overshoot
    assert m["simulated"]["first_overshoot_deg"] > m["measured"]["first_overshoot_deg"] + 0.5


def test_hand_computed_zigzag_overshoots():
    """Heading change +10° at the first reversal, peak +14.5°; −10° at the second, trough
    −17°: overshoots 4.5° and 7°."""
    dt = 1.0
    delta = np.zeros(80)
    delta[5:8] = [0.1, 0.2, 0.3]
    delta[8:30] = 0.35             # plateau to starboard, leaves at sample 29
    delta[30:33] = [0.2, 0.0, -0.2]
    delta[33:55] = -0.35           # leaves at sample 54
    delta[55:58] = [-0.2, 0.0, 0.2]
    delta[58:] = 0.35
    h = np.zeros(80)               # heading change (deg), piecewise linear
    h[5:31] = np.linspace(0, 10, 26)          # 10° at the first sample off the plateau (30)
    h[31:40] = np.linspace(10.5, 14.5, 9)     # peak 14.5° at 39
    h[40:56] = np.linspace(13, -10, 16)       # -10° at the second reversal (55)
    h[56:65] = np.linspace(-11, -17, 9)       # trough -17° at 64
    h[65:] = np.linspace(-16, 0, 15)
    psi = np.radians(h) + 0.3
    info = detect(delta, psi, dt)
    assert info.kind == "zigzag" and info.execute == 4 and info.reversals[:2] == (30, 55)
    assert math.degrees(info.psi_switch) == pytest.approx(10.0)
    assert math.degrees(info.delta0) == pytest.approx(math.degrees(0.35))
    fig = zigzag_figures(psi, delta, info, dt)
    assert fig["first_overshoot_deg"] == pytest.approx(4.5)
    assert fig["second_overshoot_deg"] == pytest.approx(7.0)
    assert fig["first_overshoot_time_s"] == pytest.approx(35.0)


def test_an_autopilot_rudder_is_not_a_manoeuvre():
    rng = np.random.default_rng(0)
    delta = np.radians(np.cumsum(rng.normal(0, 0.5, 2000)).clip(-20, 20))
    psi = np.cumsum(-0.01 * delta)
    assert detect(delta, psi, 0.1) is None


def test_turning_circle_figures_of_a_circle():
    """Constant speed U and yaw rate r from the execute: a circle of radius R = U/r, so
    advance = transfer = R, tactical diameter 2R, steady turn rate r."""
    dt, U, r0 = 0.05, 2.0, math.radians(3.0)
    n = 3000
    r = np.where(np.arange(n) >= 100, r0, 0.0)
    delta = np.where(np.arange(n) >= 100, 0.35, 0.0)
    psi, north, east = integrate_track(np.full(n, U), np.zeros(n), r, dt)
    info = detect(delta, psi, dt)
    assert info.kind == "turning_circle"
    fig = turning_figures(psi, north, east, r, info)
    R = U / r0
    assert fig["advance_m"] == pytest.approx(R, rel=2e-3)
    assert fig["transfer_m"] == pytest.approx(R, rel=2e-3)
    assert fig["tactical_diameter_m"] == pytest.approx(2 * R, rel=2e-3)
    assert fig["steady_turn_rate_deg_s"] == pytest.approx(3.0)


def test_bad_input_refused(spec, log):
    with pytest.raises(ValidationError, match=r"experiment\(s\) \['nope'\] not in the log"):
        validate(log, spec, experiments=["nope"])
    with pytest.raises(ValidationError, match="horizon"):
        validate(log, spec, horizon=0)
    fast = log.assign(time=log["time"] / 2)
    with pytest.raises(ValidationError, match=r"ingest --dt 0\.5"):
        validate(fast, spec)


def test_cli_strict_json_plot_and_exit_2(spec, log, tmp_path):
    from vesselid.data.logs import TrialLog

    TrialLog(log).save(tmp_path / "trial.csv")
    spec.save(tmp_path / "model.toml")
    cmd = [sys.executable, "-m", "vesselid", "validate", str(tmp_path / "trial.csv"),
           "--model", str(tmp_path / "model.toml")]
    run = subprocess.run([*cmd, "--experiments", "zz20", "--json", "-", "--plot",
                          str(tmp_path / "v.png")], capture_output=True, text=True)
    assert run.returncode == 0, run.stderr
    out = json.loads(run.stdout)
    assert [e["experiment"] for e in out["experiments"]] == ["zz20"]
    assert out["experiments"][0]["manoeuvre"]["kind"] == "zigzag"
    assert out["stable"] is True
    assert (tmp_path / "v.png").stat().st_size > 1000
    (tmp_path / "m.toml").write_text(f"[zz20]\npsi_switch_deg = {math.degrees(0.09)!r}\n")
    run = subprocess.run([*cmd, "--experiments", "zz20", "--manoeuvres", str(tmp_path / "m.toml"),
                          "--json", "-"], capture_output=True, text=True)
    m = json.loads(run.stdout)["experiments"][0]["manoeuvre"]
    assert m["simulated"]["first_overshoot_deg"] == pytest.approx(
        m["measured"]["first_overshoot_deg"], abs=1e-9)
    run = subprocess.run([*cmd, "--experiments", "zz30"], capture_output=True, text=True)
    assert run.returncode == 2 and len(run.stderr.strip().splitlines()) == 1
    assert "zz30" in run.stderr


def test_one_step_prediction_equals_the_regressor_prediction(spec, log):
    """k = 1: Φᵀ(y(k), u(k)) θ from the measured signals (derived columns included)."""
    from vesselid.model.derived import add_derived
    from vesselid.model.regressors import predict
    from vesselid.validation.freerun import Plant

    theta = spec.theta0_vector() * 1.01
    g = log[log["experiment"] == "zz10"].reset_index(drop=True)
    plant = Plant(spec, theta)
    pred = plant.k_step(g, 1)
    full = add_derived(g, spec)
    s = full[list(spec.signals)].to_numpy(float)
    np.testing.assert_allclose(pred[1:], predict(spec.codes, theta, s)[:-1], rtol=1e-12,
                               atol=1e-15)
    assert np.all(np.isnan(pred[0]))
