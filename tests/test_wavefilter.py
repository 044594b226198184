"""Wave filter of trial measurements (vesselid.data.wavefilter)."""

from __future__ import annotations

import math
import warnings

import numpy as np
import pandas as pd
import pytest
from _stats import bonferroni_z

from vesselid.data.logs import TrialLog
from vesselid.data.wavefilter import WaveFilter, WaveFilterError, wave_filter_log
from vesselid.errors import VesselidError
from vesselid.plant.waves import WaveConditions


@pytest.mark.parametrize("kwargs", [
    {"cutoff": 0.0, "dt": 0.1}, {"cutoff": 5.0, "dt": 0.1}, {"cutoff": math.nan, "dt": 0.1},
    {"cutoff": 0.5, "dt": -1.0}, {"cutoff": 0.5, "dt": 0.1, "order": 0},
    {"cutoff": 0.5, "dt": 0.1, "order": 2.5},
])
def test_bad_settings_are_clear_value_errors(kwargs) -> None:
    with pytest.raises(WaveFilterError):
        WaveFilter(**kwargs)
    assert issubclass(WaveFilterError, VesselidError) and issubclass(WaveFilterError, ValueError)


def test_cutoff_from_the_sea_state() -> None:
    waves = WaveConditions.sea_state("moderate")
    f = WaveFilter.for_waves(waves, 0.1)
    assert f.cutoff == pytest.approx(0.9 / waves.model_period)
    assert f.gain(f.cutoff) == pytest.approx(0.5)
    with pytest.raises(WaveFilterError):
        WaveFilter.for_waves(waves, 0.1, fraction=-1.0)


def test_removes_the_wave_band_and_keeps_the_manoeuvring_band() -> None:
    f = WaveFilter(0.8, 0.1)
    t = 0.1 * np.arange(4000)
    slow = np.sin(2 * np.pi * 0.05 * t)
    wave = 0.3 * np.sin(2 * np.pi * 1.5 * t + 0.4)
    y = f.apply(np.column_stack([slow + wave, slow]))
    mid = slice(500, -500)  # away from the edge transients
    # the gain formula predicts both bands: 0.05 Hz passes (within 0.5 % of its
    # amplitude), 1.5 Hz is removed (its residue is 0.3 × gain)
    g_slow, g_wave = f.gain(0.05), f.gain(1.5)
    assert g_wave < 1e-3 and g_slow > 1 - 1e-12
    np.testing.assert_allclose(y[mid, 1], slow[mid], atol=5e-3)
    assert np.max(np.abs(y[mid, 0] - y[mid, 1])) < 0.3 * g_wave + 1e-4
    with pytest.raises(WaveFilterError, match="more than"):
        f.apply(np.zeros(10))


def test_filters_per_experiment_and_keeps_raw_columns() -> None:
    n = 600
    data = pd.DataFrame({"experiment": np.repeat([0, 1], n),
                         "v": np.concatenate([np.full(n, 1.0), np.full(n, -2.0)]),
                         "Y": np.zeros(2 * n)})
    out = wave_filter_log(TrialLog(data, {"seed": 3}), WaveFilter(0.5, 0.1), ["v", "Y"])
    # constants per experiment stay constant: no leakage across the experiment boundary
    np.testing.assert_allclose(out.data["v"].to_numpy()[:n], 1.0, atol=1e-9)
    np.testing.assert_allclose(out.data["v"].to_numpy()[n:], -2.0, atol=1e-9)
    np.testing.assert_array_equal(out.data["v_unfiltered"], data["v"])
    assert out.metadata["wave_filter"]["columns"] == ["v", "Y"]
    assert out.metadata["seed"] == 3 and "wave_filter" not in data
    with pytest.raises(WaveFilterError, match="not in the log"):
        wave_filter_log(TrialLog(data), WaveFilter(0.5, 0.1), ["r"])
    with pytest.raises(WaveFilterError, match="no model spec"):
        wave_filter_log(TrialLog(data), WaveFilter(0.5, 0.1))


@pytest.mark.slow
def test_wave_filtered_trial_is_consistent_and_more_precise() -> None:
    """Moderate sea on the planned trial: the wave-filtered log identified with
    zero-mean simulated instruments is within the family-wise normal bound on every
    parameter, with smaller standard errors than the unfiltered log."""
    from vesselid.identify import identify
    from vesselid.studies.seatrial import simulate_sea_trial

    waves = WaveConditions.sea_state("moderate")
    log = simulate_sea_trial(6, 20000, seed=3, waves=waves)
    th0 = log.spec.theta0_series()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        raw = identify(log, log.spec, method="iv-zero-mean")
        filt = identify(wave_filter_log(log, WaveFilter.for_waves(waves, 0.1)), log.spec,
                        method="iv-zero-mean")
    z_f = ((filt.params - th0) / filt.std_errors).abs()
    assert z_f.max() <= bonferroni_z(z_f.size), z_f.sort_values().tail()
    assert float(np.median(filt.std_errors / raw.std_errors)) < 1.0


def test_sea_trial_cli_writes_the_wave_filtered_log(tmp_path, capsys) -> None:
    from vesselid.cli import main

    args = ["sea-trial", "--experiments", "2", "--samples", "800", "--design", "static-offset",
            "--sea-state", "moderate", "--seed", "1", "--format", "csv"]
    assert main([*args, "--out", str(tmp_path / "f")]) == 0
    assert "wave filter: zero-phase" in capsys.readouterr().out
    assert main([*args, "--wave-filter", "0", "--out", str(tmp_path / "raw")]) == 0
    filt = TrialLog.load(tmp_path / "f" / "seatrial.csv")
    raw = TrialLog.load(tmp_path / "raw" / "seatrial.csv")
    assert filt.metadata["wave_filter"]["cutoff_hz"] == pytest.approx(
        0.9 / WaveConditions.sea_state("moderate").model_period)
    assert "wave_filter" not in raw.metadata
    np.testing.assert_allclose(filt.data["v_unfiltered"], raw.data["v"])
    assert not np.allclose(filt.data["v"], raw.data["v"])
