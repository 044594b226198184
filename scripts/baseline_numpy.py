"""Plain-numpy baseline of Table 1: the same three estimators, no numba.

Time-recursive parts (the true system and the auxiliary-model simulations of the
refined IV iteration, paper §6) are Python loops over samples, vectorised across
the Monte Carlo runs; moment sums are vectorised numpy. The input design, noise and
seeds are those of ``vesselid reproduce`` (the random draws come from
:meth:`vesselid.plant.systems.System._draw_batch`, which is plain numpy), and the refined
iteration is the plain fixed point ``θ ← T(θ)`` with the same tolerance (1e-9),
iteration cap (100) and per-run stopping — so the results agree with the compiled
path to iteration tolerance while all the arithmetic runs in numpy.

    python scripts/baseline_numpy.py --runs 1000 --samples 10000
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from vesselid.studies.reproduce import table_study

THETA0 = np.array([0.99, -0.1, 1.0])


def _simulate_true(u: np.ndarray, v: np.ndarray, w: np.ndarray, x0: float) -> np.ndarray:
    n_runs, n = u.shape
    x = np.empty((n_runs, n))
    x[:, 0] = x0
    a, nn, f = THETA0
    for k in range(n - 1):
        s = x[:, k] + v[:, k]
        x[:, k + 1] = a * s + nn * s * np.abs(s) + f * u[:, k] + w[:, k]
    return x


def _aux(theta: np.ndarray, y: np.ndarray, u: np.ndarray) -> np.ndarray:
    """Auxiliary model x̂(k) = â x̂ + n̂ x̂|x̂| + f̂ τ from x̂(0) = y(0), per run."""
    n_runs, n = u.shape
    xh = np.empty((n_runs, n))
    xh[:, 0] = y[:, 0]
    a, nn, f = theta[:, 0], theta[:, 1], theta[:, 2]
    for k in range(n - 1):
        s = xh[:, k]
        xh[:, k + 1] = a * s + nn * s * np.abs(s) + f * u[:, k]
    return xh


def _regressors(sig: np.ndarray, u: np.ndarray) -> np.ndarray:
    s = sig[:, :-1]
    return np.stack([s, s * np.abs(s), u[:, :-1]], axis=-1)  # (R, N-1, 3)


def _solve(z: np.ndarray, phi: np.ndarray, y: np.ndarray, zero_mean: bool) -> np.ndarray:
    if zero_mean:
        z = z - z.mean(axis=1, keepdims=True)
    a = np.einsum("rkp,rkq->rpq", z, phi)
    b = np.einsum("rkp,rk->rp", z, y)
    return np.linalg.solve(a, b[..., None])[..., 0]


def _refined_iv(theta_ls, y, u, phi, target, zero_mean, tol=1e-9, max_iter=100):
    theta = theta_ls.copy()
    est = np.full_like(theta, np.nan)
    active = np.ones(len(theta), dtype=bool)
    iterations = np.zeros(len(theta), dtype=int)
    for _ in range(max_iter):
        idx = np.flatnonzero(active)
        if idx.size == 0:
            break
        xh = _aux(theta[idx], y[idx], u[idx])
        z = _regressors(xh, u[idx])
        t = _solve(z, phi[idx], target[idx], zero_mean)
        iterations[idx] += 1
        res = np.linalg.norm(t - theta[idx], axis=1) / np.linalg.norm(theta[idx], axis=1)
        est[idx] = t
        theta[idx] = t
        active[idx[res < tol]] = False
    return est, iterations


def table1_numpy(runs: int = 1000, samples: int = 10_000, seed: int = 0) -> dict:
    """Table 1 with numpy only. Returns normalized errors per method and timings."""
    t0 = time.perf_counter()
    study = table_study(1, runs=runs, samples=samples, seed=seed)
    system = study.build_system()
    draws = system._draw_batch(study.run_seeds(), samples)
    u = draws["u"][:, :, 0]
    x = _simulate_true(u, -draws["q"][:, :, 0], draws["w"][:, :, 0], system.x0["w"])
    y = x + draws["e"][:, :, 0]
    t_data = time.perf_counter() - t0
    phi = _regressors(y, u)
    target = y[:, 1:]
    theta_ls = _solve(phi, phi, target, zero_mean=False)
    errors = {"ls": (theta_ls - THETA0) / THETA0}
    iters = {}
    for method, zm in (("iv", False), ("iv-zero-mean", True)):
        est, it = _refined_iv(theta_ls, y, u, phi, target, zm)
        errors[method] = (est - THETA0) / THETA0
        iters[method] = float(it.mean())
    return {"errors": errors, "iterations": iters, "data_s": t_data,
            "total_s": time.perf_counter() - t0}


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--runs", type=int, default=1000)
    p.add_argument("--samples", type=int, default=10_000)
    p.add_argument("--seed", type=int, default=0)
    args = p.parse_args()
    res = table1_numpy(args.runs, args.samples, args.seed)
    for m, e in res["errors"].items():
        print(f"{m:13s}", "  ".join(f"{mu:+.4f} ± {sd:.4f}" for mu, sd in
                                     zip(np.nanmean(e, 0), np.nanstd(e, 0, ddof=1), strict=True)))
    print(f"iterations {res['iterations']}; data {res['data_s']:.2f} s; "
          f"total {res['total_s']:.2f} s")


if __name__ == "__main__":
    main()
