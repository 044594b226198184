"""scripts/kvlcc2_study.py on synthetic files in the HSVA layout: it skips cleanly without
data, and its leave-one-run-out cross-validation scores the true structure of a noise-free
model as exact (free-run fit 100 %, simulated overshoots equal to the measured ones) and a
structure missing a term as worse."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from _scripts import load_script


def _study():
    return load_script("kvlcc2_study")


def test_skips_cleanly_without_data(monkeypatch, capsys, tmp_path):
    monkeypatch.delenv("VESSELID_KVLCC2_DIR", raising=False)
    study = _study()
    assert study.main(["--out", str(tmp_path)]) == 0
    assert study.main(["--data", str(tmp_path), "--out", str(tmp_path)]) == 0
    assert "skipping" in capsys.readouterr().out
    assert not list(tmp_path.iterdir())


def _write_runs(folder: Path, spec, runs) -> dict:
    """Noise-free zig-zags of ``spec`` written as HSVA tables (earth-fixed velocities,
    degrees); returns the nominal manoeuvres for the log's metadata."""
    from _ship import write_hsva, zigzag_log

    nominal = {}
    for i, (d0, ps, first) in enumerate(runs):
        g = zigzag_log(spec, n=640, delta0=d0, psi_s=ps, first=first, u0=1.177)
        stem = f"HSVA_CPMC_KVLCC2_Z_{i + 10:02d}_05"
        write_hsva(folder / f"{stem}.dat", g)
        nominal[stem] = {"psi_switch_deg": math.degrees(ps)}
    return nominal


@pytest.mark.filterwarnings("ignore")
def test_cross_validation_scores_the_true_structure_exact(tmp_path, monkeypatch):
    from vesselid.data.ingest import ingest
    from vesselid.model.specs import load_spec, path

    study = _study()
    truth = load_spec("kvlcc2_vr").with_theta0(
        {"du": [0.99, -0.01, 0.3, -0.006],
         "v": [0.95, 0.01, -0.1, -0.05, -0.2, 0.02, 0.01],
         "r": [0.93, -0.02, -0.01, -0.05, -0.2, -0.015, -0.01, 0.1, 0.4]})
    nominal = _write_runs(tmp_path, truth, [(0.17, 0.17, 1), (0.35, 0.09, -1),
                                            (0.26, 0.17, -1)])
    log = ingest(tmp_path, truth.dt, config=path("kvlcc2_hsva_ingest"))
    log.metadata["manoeuvres"] = nominal
    monkeypatch.setattr(study, "CANDIDATES", {"kvlcc2": {}, "+v|r| (yaw)": {"r": ["v*|r|"]}})
    monkeypatch.setattr(study, "CV_METHODS", (("ls", "ls"),))
    rows = pd.DataFrame(study._cross_validate(log, load_spec("kvlcc2")))
    fit = rows[rows.experiment == "pooled"].set_index(["spec", "state"]).value
    for s in ("du", "v", "r"):
        assert fit[("cv +v|r| (yaw)", s)] == pytest.approx(100.0, abs=1e-3)
    # the structure without the term is worse in yaw on runs it has not seen
    assert fit[("cv kvlcc2", "r")] < 99.0
    os_ = rows[(rows.spec == "cv +v|r| (yaw)") & (rows.experiment != "pooled")]
    assert len(os_) == 6 and os_.measured.notna().all()
    np.testing.assert_allclose(os_.value.astype(float), os_.measured.astype(float), atol=1e-6)
    assert "Training cross-validation" in study._cv_markdown(rows, truth.dt)


def test_markdown_tables_of_one_spec():
    """The held-out tables: free-run fits per run, overshoots at the nominal and at the read
    switching angle, with the simulated-minus-measured difference in brackets."""
    from vesselid.model.specs import load_spec

    study = _study()
    spec = load_spec("kvlcc2_vr")
    base = {"spec": spec.name, "estimator": "ls", "method": "ls", "converged": True,
            "spectral_radius": 1.01, "choice": "", "check_prefilter": float("nan"),
            "check_levels": float("nan"), "check_critical": float("nan")}
    fits = dict(zip(spec.states, (80, 90, 95), strict=True))
    rows = [{**base, "kind": "free_run_fit", "experiment": "Z_15_05", "state": s,
             "figure": "fit_percent", "value": v} for s, v in fits.items()]
    rows += [{**base, "kind": "overshoot", "experiment": "Z_15_05", "state": "psi",
              "figure": "second_overshoot_deg", "measured": 12.6, "value": 10.4},
             {**base, "kind": "overshoot_read", "experiment": "Z_15_05", "state": "psi",
              "figure": "second_overshoot_deg", "measured": 11.6, "value": 11.0,
              "psi_switch_deg": 6.05}]
    md = study._markdown(pd.DataFrame(rows), spec, 0.25)
    assert "| Z_15_05 | 80.0 | 90.0 | 95.0 |" in md
    assert "| Z_15_05 | 2nd | 12.6 | 10.4 (-2.2) |" in md
    assert "| Z_15_05 | 6.05 | 2nd | 11.6 | 11.0 (-0.6) |" in md
    assert "| ls | ls |  | True | 1.01000 |" in md
