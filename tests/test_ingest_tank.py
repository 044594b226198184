"""Model-test tables (vesselid.data.ingest.tank): synthetic files in the SIMMAN/HSVA layout."""

from __future__ import annotations

import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from vesselid.data.ingest import ingest
from vesselid.data.ingest.config import IngestError
from vesselid.data.ingest.tank import tank_format_from_dict

NAMES = ["time", "x0", "y0", "psi", "u", "v", "r", "p", "delta", "rev", "thrust", "torque"]
DT = 0.05


def _kinematics(n: int = 801, phase: float = 0.0):
    """Body-frame motion with a known heading; returns (t, psi_deg, r_deg, u_b, v_b, ...)."""
    t = np.arange(n) * DT
    w = 2 * math.pi / 20.0
    psi = 25.0 * np.sin(w * t + phase) + 3.0          # deg
    r = 25.0 * w * np.cos(w * t + phase)              # deg/s, exact derivative
    u_b = 1.1 - 0.05 * np.sin(0.5 * w * t)
    v_b = -0.04 * np.cos(w * t + phase)
    delta = 10.0 * np.sign(np.sin(w * t + phase + 0.4))
    return t, psi, r, u_b, v_b, delta


def _write_dat(path: Path, r_column: int = 6, phase: float = 0.0, n: int = 801) -> dict:
    t, psi, r, u_b, v_b, delta = _kinematics(n, phase)
    c, s = np.cos(np.deg2rad(psi)), np.sin(np.deg2rad(psi))
    u_e, v_e = c * u_b - s * v_b, s * u_b + c * v_b   # earth-fixed (north, east)
    x0 = np.cumsum(u_e) * DT
    y0 = np.cumsum(v_e) * DT
    roll = 0.3 * np.sin(0.7 * t)
    cols = [t, x0, y0, psi, u_e, v_e, r, roll, delta, np.full(n, 10.2295),
            np.full(n, 40.5), np.full(n, 1.02)]
    if r_column != 6:  # swap the yaw rate with another column (a mislabelled file)
        cols[6], cols[r_column] = cols[r_column], cols[6]
    header = " HSVA, experimental data CPMC\n KVLCC2\n Z10\u00b0/5\u00b0\n Time series of motions\n"
    body = "\n".join(" ".join(f"{x:18.9f}" for x in row) for row in np.column_stack(cols))
    path.write_bytes((header + body + "\n").encode("latin-1"))
    return {"t": t, "psi": np.deg2rad(psi), "r": np.deg2rad(r), "u": u_b, "v": v_b,
            "delta": np.deg2rad(delta), "north": x0, "east": y0}


TANK = {
    "delimiter": "whitespace", "header_lines": 4, "encoding": "latin-1", "names": NAMES,
    "angle_unit": "deg", "angles": ["psi", "r", "delta"], "velocity_frame": "earth",
    "columns": {"time": "time", "north": "x0", "east": "y0", "psi": "psi", "u": "u",
                "v": "v", "r": "r", "delta": "delta", "n": "rev"},
}


def _toml(tank: dict) -> str:
    import tomli_w

    return tomli_w.dumps({"tank": tank})


def _setup(tmp_path: Path, tank: dict | None = None, **kw) -> tuple[Path, list[dict]]:
    truth = [_write_dat(tmp_path / "Z_10_05.dat", **kw),
             _write_dat(tmp_path / "Z_20_05.dat", phase=0.5, **kw)]
    (tmp_path / "ingest.toml").write_text(_toml(tank or TANK))
    return tmp_path, truth


def test_earth_velocities_rotated_degrees_converted_one_experiment_per_file(tmp_path):
    d, truth = _setup(tmp_path)
    log = ingest(d, DT)
    assert log.experiment_ids == ["Z_10_05", "Z_20_05"]
    for eid, part in log.experiments():
        tr = truth[0] if eid == "Z_10_05" else truth[1]
        np.testing.assert_allclose(part["time"], tr["t"], atol=1e-9)
        for c in ("u", "v", "psi", "r", "delta", "north", "east"):
            np.testing.assert_allclose(part[c], tr[c], atol=1e-8, err_msg=c)
        assert np.all(part["n"] == 10.2295)
    q = log.metadata["quality"]["sources"][0]
    assert q["yaw_rate_check"]["checked"] and q["yaw_rate_check"]["relative_misfit"] < 0.01
    assert any("body frame" in c for c in q["conversions"])


def test_mislabelled_yaw_rate_refused_naming_the_columns(tmp_path):
    d, _ = _setup(tmp_path, r_column=7)   # yaw rate in the 8th column, roll rate in the 7th
    with pytest.raises(IngestError, match=r"yaw rate r \(column 'r'\).*column 'p' matches"):
        ingest(d, DT)
    # the user's fix: map r to the 8th column
    fixed = {**TANK, "columns": {**TANK["columns"], "r": "p"}}
    (d / "ingest.toml").write_text(_toml(fixed))
    log = ingest(d, DT)
    assert log.metadata["quality"]["sources"][0]["yaw_rate_check"]["relative_misfit"] < 0.01


def test_yaw_rate_in_wrong_unit_refused(tmp_path):
    d, _ = _setup(tmp_path, tank={**TANK, "angles": ["psi", "delta"]})  # r left in deg/s
    with pytest.raises(IngestError, match="angle_unit"):
        ingest(d, DT)


def test_froude_scaling_to_full_scale(tmp_path):
    lam = 45.7
    d, truth = _setup(tmp_path, tank={**TANK, "scale": lam, "full_scale": True})
    log = ingest(d, DT * math.sqrt(lam))
    part = log.experiments()[0][1]
    tr = truth[0]
    np.testing.assert_allclose(part["time"], tr["t"] * math.sqrt(lam), rtol=1e-9)
    np.testing.assert_allclose(part["u"], tr["u"] * math.sqrt(lam), rtol=1e-9)
    np.testing.assert_allclose(part["r"], tr["r"] / math.sqrt(lam), atol=1e-9)
    np.testing.assert_allclose(part["north"], tr["north"] * lam, atol=1e-7)
    np.testing.assert_allclose(part["delta"], tr["delta"], rtol=1e-12)
    np.testing.assert_allclose(part["n"], 10.2295 / math.sqrt(lam), rtol=1e-12)
    assert log.metadata["model_scale"] == lam and log.metadata["full_scale"] is True


def test_resampled_when_dt_differs(tmp_path):
    d, truth = _setup(tmp_path)
    log = ingest(d, 2 * DT)
    part = log.experiments()[0][1]
    assert len(part) == 401
    np.testing.assert_allclose(np.diff(part["time"]), 2 * DT)
    # smooth signals survive the anti-aliased decimation
    np.testing.assert_allclose(part["psi"].to_numpy()[20:-20], truth[0]["psi"][::2][20:-20],
                               atol=2e-4)
    assert "decimation" in log.metadata["quality"]["sources"][0]["resampling"]


def test_csv_with_header_row_body_frame_radians(tmp_path):
    t, psi, r, u_b, v_b, delta = _kinematics()
    pd.DataFrame({"t": t, "heading": np.deg2rad(psi), "yaw_rate": np.deg2rad(r), "surge": u_b,
                  "sway": v_b, "rudder": np.deg2rad(delta)}).to_csv(tmp_path / "run1.csv",
                                                                     index=False)
    tank = {"delimiter": "comma", "columns": {"time": "t", "psi": "heading", "r": "yaw_rate",
                                              "u": "surge", "v": "sway", "delta": "rudder"}}
    (tmp_path / "ingest.toml").write_text(_toml(tank))
    log = ingest(tmp_path, DT)
    assert log.experiment_ids == ["run1"]
    np.testing.assert_allclose(log.data["v"], v_b, atol=1e-12)
    np.testing.assert_allclose(log.data["r"], np.deg2rad(r), atol=1e-12)


def test_quantised_time_refused_then_rebuilt_from_the_stated_sample_time(tmp_path):
    t, psi, r, u_b, v_b, delta = _kinematics()
    frame = pd.DataFrame({"t": np.round(t, 1), "psi": np.deg2rad(psi), "r": np.deg2rad(r),
                          "u": u_b, "v": v_b, "delta": np.deg2rad(delta)})
    frame.to_csv(tmp_path / "run1.csv", index=False)
    tank = {"delimiter": "comma", "columns": {c: c for c in ("psi", "r", "u", "v", "delta")}}
    tank["columns"]["time"] = "t"
    (tmp_path / "ingest.toml").write_text(_toml(tank))
    with pytest.raises(IngestError, match=r"not strictly increasing at data row \d+ .*sample_time"):
        ingest(tmp_path, DT)
    (tmp_path / "ingest.toml").write_text(_toml({**tank, "sample_time": DT}))
    log = ingest(tmp_path, DT)
    assert len(log) == len(frame)   # no row dropped
    np.testing.assert_allclose(log.data["time"], t, atol=1e-12)


@pytest.mark.parametrize("tank, match", [
    ({**TANK, "full_scale": True}, "needs scale"),
    ({**TANK, "bogus": 1}, "unknown \\[tank\\] keys"),
    ({**TANK, "angle_unit": "grad"}, "angle_unit"),
    ({**TANK, "columns": {"psi": "psi"}}, "must map 'time'"),
    ({**TANK, "velocity_frame": "earth", "columns": {"time": "time", "u": "u"}}, "needs u, v"),
    ({**TANK, "scale": 10.0, "full_scale": True,
      "columns": {**TANK["columns"], "foo": "p"}}, "no Froude kind"),
])
def test_bad_tank_tables_refused(tank, match):
    with pytest.raises(IngestError, match=match):
        tank_format_from_dict(tank)


def test_cli_ingest_and_one_line_refusal(tmp_path):
    d, _ = _setup(tmp_path, r_column=7)
    out = tmp_path / "trial.csv"
    run = subprocess.run([sys.executable, "-m", "vesselid", "ingest", str(d), "--dt", str(DT),
                          "--out", str(out)], capture_output=True, text=True)
    assert run.returncode == 2
    assert len(run.stderr.strip().splitlines()) == 1 and "column 'p' matches" in run.stderr
    (d / "ingest.toml").write_text(_toml({**TANK, "columns": {**TANK["columns"], "r": "p"}}))
    run = subprocess.run([sys.executable, "-m", "vesselid", "ingest", str(d), "--dt", str(DT),
                          "--out", str(out)], capture_output=True, text=True)
    assert run.returncode == 0, run.stderr
    assert "r vs dψ/dt misfit" in run.stdout
    back = pd.read_csv(out)
    assert sorted(back["experiment"].unique()) == ["Z_10_05", "Z_20_05"]


@pytest.mark.slow
def test_shipped_kvlcc2_config_and_spec_end_to_end(tmp_path):
    """HSVA-format files of a known model in the shipped spec's structure → ingest with the
    shipped configuration → LS recovers the parameters exactly → validate fits 100 %."""
    from _ship import write_hsva, zigzag_log

    from vesselid.identify import identify
    from vesselid.model.specs import load_spec, path
    from vesselid.validation.report import validate

    spec = load_spec("kvlcc2")
    theta = {"du": [0.99, -0.01, 0.3, -0.006],
             "v": [0.95, 0.01, -0.1, -0.05, -0.2, 0.02, 0.01],
             "r": [0.93, -0.02, -0.01, -0.05, -0.2, -0.015, -0.01, 0.1]}
    spec = spec.with_theta0(theta)
    u0 = 1.177
    for i, (d0, ps, first) in enumerate([(0.17, 0.17, 1), (0.35, 0.09, -1), (0.26, 0.17, -1)]):
        g = zigzag_log(spec, n=500, delta0=d0, psi_s=ps, first=first, u0=u0)
        write_hsva(tmp_path / f"HSVA_CPMC_KVLCC2_Z_{i}.dat", g)
    log = ingest(tmp_path, spec.dt, config=path("kvlcc2_hsva_ingest"))
    res = identify(log, load_spec("kvlcc2"), method="ls")
    np.testing.assert_allclose(np.asarray(res.params), spec.theta0_vector(), atol=1e-7)
    rep = validate(log, spec)
    assert all(v == pytest.approx(100.0, abs=1e-4) for v in rep.free_run_fit.values())
