"""Benchmark the recursive estimators: samples per second per state equation.

Run ``python scripts/bench_recursive.py [--samples N] [--repeats R]``. For recursive LS,
recursive IV with delayed instruments and with auxiliary-model instruments (λ = 0.999),
on the heave model (one equation, 3 parameters + intercept) and the CyberShip II sea-trial
model (three equations), one compiled pass over an ``N``-sample array (``run``) and the
per-sample Python call (``update``) used inside an environment loop. Medians over
``repeats`` timed runs after a warm-up (compilation excluded). A benchmark, never a timed
test.
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np

from vesselid.identify.recursive import RecursiveEstimator

__all__ = ["bench"]


def _designs():
    from vesselid.plant.systems import heave
    from vesselid.studies.seatrial import seatrial_spec

    rng = np.random.default_rng(0)
    out = []
    h = heave().identification_spec(aggregate=False)
    out.append(("heave", h))
    out.append(("cybership2 3-DOF", seatrial_spec()))
    return out, rng


def bench(samples: int = 1_000_000, repeats: int = 5) -> list[dict]:
    designs, rng = _designs()
    rows = []
    for name, spec in designs:
        n, m = spec.n_states, spec.n_inputs
        y = 1.0 + 0.3 * rng.standard_normal((samples, n))
        u = 0.2 + 0.1 * rng.standard_normal((samples, m))
        theta_aux = spec.theta0_vector()  # a stable auxiliary model
        for label, opts in (("RLS", dict(method="ls")),
                            ("RIV delayed", dict(method="iv", instruments="delayed")),
                            ("RIV auxiliary", dict(method="iv", instruments="auxiliary",
                                                   theta_aux=theta_aux))):
            RecursiveEstimator(spec, forgetting=0.999, **opts).run(y[:1000], u[:1000])
            times = []
            for _ in range(repeats):
                est = RecursiveEstimator(spec, forgetting=0.999, **opts)
                t0 = time.perf_counter()
                est.run(y, u)
                times.append(time.perf_counter() - t0)
            k = min(samples, 20_000)
            est = RecursiveEstimator(spec, forgetting=0.999, **opts)
            t0 = time.perf_counter()
            for i in range(k - 1):
                est.update(y[i], u[i], y[i + 1])
            t_upd = time.perf_counter() - t0
            rate = (samples - 1) / statistics.median(times)
            rows.append({"model": name, "estimator": label, "equations": n,
                         "samples/s": rate, "samples/s per equation": rate * n,
                         "update() calls/s": (k - 1) / t_upd})
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--samples", type=int, default=1_000_000)
    ap.add_argument("--repeats", type=int, default=5)
    args = ap.parse_args()
    rows = bench(args.samples, args.repeats)
    print(f"{'model':18} {'estimator':14} {'samples/s':>12} {'per equation':>14} "
          f"{'update()/s':>11}")
    for r in rows:
        print(f"{r['model']:18} {r['estimator']:14} {r['samples/s']:12.3g} "
              f"{r['samples/s per equation']:14.3g} {r['update() calls/s']:11.3g}")


if __name__ == "__main__":
    main()
