"""``scripts/gate_study.py``: the Hausman statistic by hand and the gates' coverage
counted as defined."""

from __future__ import annotations

import numpy as np
import pandas as pd
from _scripts import load_script

gs = load_script("gate_study")


def test_hausman_by_hand_and_on_a_singular_difference():
    d = np.array([1.0, 2.0, -1.0])
    h, df = gs.hausman(d, np.diag([1.0, 4.0, 0.25]))
    assert df == 3 and np.isclose(h, 1.0 + 1.0 + 4.0)
    # a null direction is dropped, not inverted
    h, df = gs.hausman(d, np.diag([1.0, 4.0, 0.0]))
    assert df == 2 and np.isclose(h, 2.0)
    assert gs.hausman(d, np.zeros((3, 3)))[1] == 0


def test_gates_move_only_the_flagged_combined_runs():
    """Two runs: a combined one with colour p 0.1 (biased, not covered) and a pem one; the
    guard 0.2 moves the first to its SRIV estimate (covered), the guard 0.05 moves
    nothing, and the pem run never moves."""
    rows = []
    for run, choice, cp in ((0, "combined", 0.1), (1, "pem-joint", 0.001)):
        for p, th in (("a", 0.9), ("n", -0.2)):
            rows.append({"run": run, "choice": choice, "param": p, "theta0": th,
                         "estimate": th + (1.0 if choice == "combined" else 0.0),
                         "se_reported": 0.1, "c_p": 0.5, "colour_p": cp,
                         "hausman_p": 0.5, "sriv_estimate": th + 0.05, "sriv_se": 0.1,
                         "pem_estimate": np.nan, "pem_se": np.nan})
    res = gs.evaluate(pd.DataFrame(rows), (0.05, 0.2)).set_index(["rule", "param"])
    assert res.loc[("no guard (combined kept)", "n"), "coverage"] == 0.5
    assert res.loc[("colour p < 0.05: SRIV", "n"), "moved"] == 0
    assert res.loc[("colour p < 0.2: SRIV", "n"), "moved"] == 1
    assert res.loc[("colour p < 0.2: SRIV", "n"), "coverage"] == 1.0
    assert res.loc[("every combined run: SRIV", "a"), "moved"] == 1
