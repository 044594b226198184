"""Closed-loop sea trials: ``simulate_sea_trial(closed_loop=True)`` and
``vesselid sea-trial --closed-loop`` write a declared closed-loop log that ``identify``
hands to ``cl-iv``; bad combinations get one line and exit code 2."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from vesselid.cli import main
from vesselid.data.logs import TrialLog
from vesselid.errors import ClosedLoopWarning, SeaTrialError
from vesselid.identify import identify
from vesselid.plant.closedloop import PID
from vesselid.studies.seatrial import closed_loop_trial_controller, simulate_sea_trial


def test_closed_loop_sea_trial_log_is_declared_and_its_loop_is_the_logged_one() -> None:
    """The logged forces are the declared PI law of the logged speed-log/gyro readings,
    references and dithers (commands before the wind load), row by row."""
    log = simulate_sea_trial(4, 400, 3, closed_loop=True)
    info = log.metadata["closed_loop"]
    assert info["reference"] == {"u": "u_ref", "v": "v_ref", "r": "r_ref"}
    assert info["dither"] == {"X": "X_dither", "Y": "Y_dither", "N": "N_dither"}
    pid = PID.from_dict(info["controller"])
    frame = log.data
    assert sorted(frame["experiment"].unique()) == [0, 1, 2, 3]
    # the four sign combinations of the sway and yaw references
    signs = {(np.sign(g["v_ref"].iloc[0]), np.sign(g["r_ref"].iloc[0]))
             for _, g in frame.groupby("experiment")}
    assert signs == {(1, 1), (1, -1), (-1, 1), (-1, -1)}
    spec = log.spec
    for _, g in frame.groupby("experiment"):
        policy = pid.policy(spec)
        y = g[["u_log", "v_log", "r"]].to_numpy()
        ref = g[["u_ref", "v_ref", "r_ref"]].to_numpy()
        dith = g[["X_dither", "Y_dither", "N_dither"]].to_numpy()
        tau = np.array([policy(y[k], ref[k], dith[k]) for k in range(len(g))])
        cmd = g[["X_cmd", "Y_cmd", "N_cmd"]].to_numpy()
        # the environment takes float32 actions (force / force_max)
        fmax = np.array([2.0, 1.5, 1.0])
        assert np.max(np.abs(tau - cmd) / fmax) < 1e-6


def test_identify_uses_cl_iv_on_a_closed_loop_sea_trial() -> None:
    log = simulate_sea_trial(4, 1500, 5, closed_loop=True)
    with warnings.catch_warnings():
        warnings.simplefilter("error", ClosedLoopWarning)
        res = identify(log, log.spec)
    assert res.method == "cl-iv"
    assert "declares closed loop" in res.diagnostics["auto_choice"]
    with pytest.warns(ClosedLoopWarning):
        identify(log, log.spec, "ls")


def test_closed_loop_sea_trial_refusals() -> None:
    with pytest.raises(SeaTrialError, match="no open-loop force design"):
        simulate_sea_trial(4, 200, 0, closed_loop=True, design="planned")
    with pytest.raises(SeaTrialError, match="aggregate='relative'"):
        simulate_sea_trial(4, 200, 0, closed_loop=True, aggregate="none")
    with pytest.raises(SeaTrialError, match="tuned for CyberShip II"):
        closed_loop_trial_controller(0.1, "viknes830")


def test_cli_sea_trial_closed_loop_then_identify(tmp_path, capsys) -> None:
    out = tmp_path / "trial"
    assert main(["sea-trial", "--closed-loop", "--experiments", "4", "--samples", "600",
                 "--seed", "1", "--format", "csv", "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "closed loop: PI loops" in text and "auto -> cl-iv" in text
    log = TrialLog.load(out / "seatrial.csv")
    assert log.metadata["closed_loop"]["controller"]["kind"] == "pid"
    assert main(["identify", str(out / "seatrial.csv"), "--model",
                 str(out / "cybership2.toml")]) in (0, 3)
    assert "cl-iv" in capsys.readouterr().out


@pytest.mark.parametrize("extra, msg", [
    (["--design", "planned"], "takes no --design"),
    (["--aggregate", "none"], "--aggregate relative"),
    (["--source", "env"], "leave --source out"),
])
def test_cli_sea_trial_closed_loop_bad_input(tmp_path, capsys, extra, msg) -> None:
    code = main(["sea-trial", "--closed-loop", "--experiments", "2", "--samples", "100",
                 "--out", str(tmp_path / "x"), *extra])
    err = capsys.readouterr().err
    assert code == 2 and msg in err and "Traceback" not in err
    assert len(err.strip().splitlines()) == 1


def test_plan_trial_closed_loop(capsys) -> None:
    """The plan names the declared design and predicts cl-iv's standard errors from a
    simulated trial of it; the JSON form is valid JSON with every parameter."""
    import json

    assert main(["plan-trial", "--closed-loop", "--samples", "4000", "--json"]) == 0
    plan = json.loads(capsys.readouterr().out)
    assert plan["kind"] == "closed-loop" and plan["method"] == "cl-iv"
    assert plan["experiments"] == 4 and plan["samples_per_experiment"] == 1000
    assert plan["design"]["controller"]["loops"] == {"X": "u", "Y": "v", "N": "r"}
    assert len(plan["predicted"]) == 23
    se = np.array([p["se"] for p in plan["predicted"].values()])
    assert np.all(np.isfinite(se)) and np.all(se > 0)
    assert "--closed-loop" in plan["command"]


@pytest.mark.parametrize("extra, msg", [
    (["--experiments", "2"], "at least 4 experiments"),
    (["--estimator", "sriv"], "leave --estimator out"),
    (["--samples", "400"], "at least 200 per experiment"),
])
def test_plan_trial_closed_loop_bad_input(capsys, extra, msg) -> None:
    code = main(["plan-trial", "--closed-loop", *extra])
    err = capsys.readouterr().err
    assert code == 2 and msg in err and len(err.strip().splitlines()) == 1
