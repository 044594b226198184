"""The prediction-error fit with and without the secant steps in the losing model's tail.

:func:`vesselid.identify.pem.fit_groups` fits the sensor-noise model with secant steps
once its scoring is near the optimum (:data:`vesselid.identify.pem.TAIL_DEC`) and
continues a winning one with plain Fisher scoring from there. This study fits the same
seeded logs both ways (``TAIL_DEC = 0``: plain scoring throughout) with ``auto``'s
options (``joint=True``, ``boundary="auto"``, one thread) and reports, per scenario:

* the reported estimate: the largest change of any parameter in standard errors (those
  of the plain fit), the largest relative change of a standard error, and how often the
  reported model agrees;
* the log-likelihood of each candidate model (the winner's and the loser's): the largest
  and median absolute change, how many logs change by more than 10⁻³ and in how many of
  those the secant fit's maximum is the higher one;
* the scoring steps of all fits of a log and the CPU time of ``fit_groups``, medians.

::

    nice -n 10 python scripts/pem_secant_study.py --runs 120 --seed 0
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
import warnings
from pathlib import Path

import numpy as np

SCENARIOS = ("gm-current-random", "gm-sensor-random")


def _fit(data, spec, theta, plain: bool):
    from vesselid.identify import pem

    old = pem.TAIL_DEC
    if plain:
        pem.TAIL_DEC = 0.0
    try:
        t0 = time.process_time()
        out = pem.fit_groups(data, spec, theta, joint=True, boundary="auto",
                             parallel=False)
        return out, time.process_time() - t0
    finally:
        pem.TAIL_DEC = old


def study(scenario: str, runs: int, seed: int, samples: int) -> dict:
    """Both fits of ``runs`` logs of ``scenario`` (seeds ``seed …``)."""
    from vesselid.identify import from_arrays
    from vesselid.identify.estimators import estimate
    from vesselid.studies.calibration import heave_scenario

    system, _, _ = heave_scenario(scenario)
    spec = system.identification_spec(aggregate=False)
    dtheta, dse, agree, win, lose, higher, steps, cpu = [], [], 0, [], [], 0, [], []
    for s in range(seed, seed + runs):
        sim = system.simulate(samples, seed=s)
        data = from_arrays(spec, sim.y, sim.u)
        theta = estimate(data, spec, "iv-zero-mean", combine="pooled").theta
        ref, c_ref = _fit(data, spec, theta, plain=True)
        new, c_new = _fit(data, spec, theta, plain=False)
        se = np.sqrt(np.diag(ref["cov"][0]))
        dtheta.append(float(np.max(np.abs(new["theta"][0] - ref["theta"][0]) / se)))
        dse.append(float(np.max(np.abs(np.sqrt(np.diag(new["cov"][0])) / se - 1.0))))
        agree += str(new["model"][0]) == str(ref["model"][0])
        best = int(np.argmax(ref["loglik"][0]))
        d = new["loglik"][0] - ref["loglik"][0]
        win.append(abs(float(d[best])))
        lose.append(abs(float(d[1 - best])))
        higher += bool(d[1 - best] > 1e-3)
        steps.append((int(ref["iterations"][0]), int(new["iterations"][0])))
        cpu.append((c_ref, c_new))
    lose_a = np.array(lose)
    return {
        "scenario": scenario, "logs": runs,
        "max_dtheta_se": max(dtheta), "max_rel_dse": max(dse), "model_agrees": agree,
        "max_dll_winner": max(win), "max_dll_loser": float(lose_a.max()),
        "median_dll_loser": float(np.median(lose_a)),
        "loser_changes_over_1e-3": int(np.sum(lose_a > 1e-3)),
        "of_which_secant_higher": higher,
        "median_steps_plain": statistics.median(a for a, _ in steps),
        "median_steps_secant": statistics.median(b for _, b in steps),
        "median_cpu_ms_plain": 1000 * statistics.median(a for a, _ in cpu),
        "median_cpu_ms_secant": 1000 * statistics.median(b for _, b in cpu),
    }


def main(argv: list[str] | None = None) -> list[dict]:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--runs", type=int, default=120)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--samples", type=int, default=10_000)
    parser.add_argument("--scenario", choices=SCENARIOS, action="append")
    parser.add_argument("--out", type=Path, help="write the table as CSV")
    args = parser.parse_args(argv)
    warnings.simplefilter("ignore")
    rows = [study(sc, args.runs, args.seed, args.samples)
            for sc in (args.scenario or SCENARIOS)]
    for row in rows:
        print(row["scenario"])
        for key, val in row.items():
            if key != "scenario":
                print(f"    {key:28s} {val:.4g}" if isinstance(val, float) else
                      f"    {key:28s} {val}")
    if args.out is not None:
        import pandas as pd

        from vesselid.core.fileio import atomic_write_text

        atomic_write_text(args.out, pd.DataFrame(rows).to_csv(index=False))
    return rows


if __name__ == "__main__":
    sys.exit(0 if main() else 1)
