"""``scripts/pem_covariance_study.py``: its batched rows are ``identify``'s numbers, and its
summary counts coverage as defined."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from _scripts import load_script

pcs = load_script("pem_covariance_study")
rs = load_script("robustness_study")


@pytest.mark.slow  # ~12 s: compiles and runs both paths
def test_rows_are_identify_results_on_a_gauss_markov_current_log():
    """The study's batched ``auto`` (one run of the robustness design) reports the same
    choice, estimate and standard error as ``identify(log, spec, "auto")``; where the
    likelihood fallback is taken the reported SE is its conservative covariance's and
    lies above the inverse Fisher's and the sandwich's."""
    from vesselid.identify import identify

    rows = pcs.chunk("robustness:gm-current", 5, 0, 1, 3000, False)
    seed = np.random.SeedSequence(np.random.SeedSequence(5).entropy,
                                  spawn_key=(list(rs.DESIGNS).index("gm-current"),)
                                  ).spawn(1)[0]
    log = rs.simulate(rs.DESIGNS["gm-current"], np.random.default_rng(seed), 3000)
    res = identify(log, rs.SPEC, "auto")
    choice = str(res.diagnostics.get("choice"))
    assert [r["choice"] for r in rows] == [choice] * 3
    np.testing.assert_allclose([r["estimate"] for r in rows], res.params.to_numpy(),
                               rtol=1e-12)
    np.testing.assert_allclose([r["se_reported"] for r in rows],
                               res.std_errors.to_numpy(), rtol=1e-12)
    if choice.startswith("pem"):
        for r in rows:
            assert r["se_conservative"] == pytest.approx(r["se_reported"], rel=1e-12)
            assert r["se_conservative"] >= max(r["se_fisher"], r["se_sandwich"]) * (1 - 1e-12)


def test_summary_counts_coverage_and_wilson_interval_by_hand():
    """Four runs, errors 0, 1, 2, 3 with SE 1: |err| ≤ 1.96 SE in 2 of 4."""
    df = pd.DataFrame({"design": "x", "run": range(4), "choice": ["a", "a", "b", "b"],
                       "param": "p", "theta0": 0.0, "estimate": [0.0, 1.0, 2.0, 3.0],
                       **{f"se_{c}": 1.0 for c in ("reported", *pcs.COVS)}})
    s = pcs.summarise(df)
    row = s[(s["choice"] == "all") & (s["covariance"] == "reported")].iloc[0]
    assert row["coverage"] == 0.5
    lo, hi = pcs.wilson(2, 4)
    assert (row["wilson_lo"], row["wilson_hi"]) == (lo, hi)
    assert row["se_over_sd"] == pytest.approx(1.0 / np.std([0, 1, 2, 3], ddof=1))
    b = s[(s["choice"] == "b") & (s["covariance"] == "fisher")].iloc[0]
    assert b["coverage"] == 0.0 and b["runs"] == 2
    assert b["rms_se_over_rms_err"] == pytest.approx(1.0 / np.sqrt((4 + 9) / 2))
