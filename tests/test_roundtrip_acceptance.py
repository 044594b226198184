"""Round-trip acceptance: simulate --raw -> ingest -> identify against θ0 and the ideal log."""

from __future__ import annotations

import warnings

import numpy as np
import pymap3d  # noqa: F401  (a missing test dependency fails)
import pynmea2  # noqa: F401  (a missing test dependency fails)
import pytest

from vesselid.cli import main
from vesselid.data.ingest import ingest
from vesselid.data.logs import TrialLog
from vesselid.identify import identify
from vesselid.model.spec import ModelSpec


@pytest.mark.slow
def test_raw_round_trip_acceptance(tmp_path):
    raw = tmp_path / "raw"
    assert main(["simulate", "--system", "cybership2", "--experiments", "2", "--samples",
                 "20000", "--seed", "3", "--out", str(tmp_path / "ideal.csv"),
                 "--raw", str(raw)]) == 0
    spec = ModelSpec.load(raw / "cybership2.toml")
    log = ingest(raw, 0.1)
    theta0 = spec.theta0_series().to_numpy()
    ideal_log = TrialLog.load(tmp_path / "ideal.csv")
    for method in ("auto", "iv-zero-mean"):  # the package default (HAC SEs) and the paper's
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            got = identify(log, spec, method)
            ideal = identify(ideal_log, spec, method)
        z = np.abs(got.params.to_numpy() - theta0) / got.std_errors.to_numpy()
        delta = (np.abs(got.params.to_numpy() - ideal.params.to_numpy())
                 / ideal.std_errors.to_numpy())
        print(f"{method}: max |z| vs theta0 {z.max():.3f}; max |delta|/SE vs ideal "
              f"{delta.max():.3f}; converged raw {got.converged} ideal {ideal.converged}")
        assert z.max() <= 3.5
        assert delta.max() <= 2.0
