"""Sea-trial acceptance study and planner-vs-Monte-Carlo check.

The default (planned) sea-trial design is computed once; for every seed the trial is
simulated with the default disturbances (and optionally a moderate model-scaled sea
state) and identified with ``auto`` (the package default) and ``iv-zero-mean``. Printed:
the fraction of seeds where every parameter with ``|θ0| ≥ 1e-3`` is within 10 % of θ0
and every parameter within 3.5 reported SE, and per parameter the ratio of the
planner's predicted SE to the Monte Carlo standard deviation of the estimates. A figure
(predicted vs observed SE) is written with ``--figure``.

    nice -n 10 python scripts/planner_study.py --seeds 50 --out /tmp/study.json \
        --figure docs/planner_vs_mc.png
    nice -n 10 python scripts/planner_study.py --seeds 20 --sea-state moderate ...
"""

from __future__ import annotations

import argparse
import json
import time
import warnings

import numpy as np


def run(seeds: int, methods: list[str], sea_state: str | None, out: str | None,
        first: int = 0, wave_filter: float = 0.9) -> dict:
    from vesselid.identify import identify
    from vesselid.plant.waves import SEA_STATES, WaveConditions
    from vesselid.studies.planner import SRIV_ORDER
    from vesselid.studies.seatrial import planned_sea_trial_design, simulate_sea_trial

    design = planned_sea_trial_design(6, 20000)
    waves = None
    if sea_state:
        hs, tp = SEA_STATES[sea_state]
        waves = WaveConditions(height=hs, period=tp, direction=np.radians(45.0))
    pred = design.plan.table()
    rec: dict = {"index": [f"{e}: {t}" for e, t in pred.index],
                 "success_probability": design.plan.success_probability(),
                 "theta0": pred["theta0"].tolist(), "predicted_se": pred["predicted_se"].tolist(),
                 "sea_state": sea_state, "wave_filter": wave_filter if waves else 0.0,
                 "seeds": [], **{m: {"params": [], "se": [], "instruments": []}
                                 for m in methods}}
    for s in range(first, first + seeds):
        t = time.perf_counter()
        log = simulate_sea_trial(6, 20000, seed=s, design=design, waves=waves)
        if waves is not None and wave_filter:
            # what `vesselid sea-trial` does with waves (default --wave-filter 0.9)
            from vesselid.data.wavefilter import WaveFilter, wave_filter_log

            log = wave_filter_log(log, WaveFilter.for_waves(waves, 0.1, fraction=wave_filter))
        for m in methods:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                r = identify(log, log.spec, method=m, noise_order=SRIV_ORDER)
            rec[m]["params"].append(r.params.to_numpy().tolist())
            rec[m]["se"].append(r.std_errors.to_numpy().tolist())
            rec[m]["instruments"].append(str(r.diagnostics.get("instruments", "")))
        rec["seeds"].append(s)
        print(f"seed {s}: {time.perf_counter() - t:.1f} s", flush=True)
        if out:
            with open(out, "w") as f:
                json.dump(rec, f)
    return rec


def predictions(rec: dict) -> None:
    """Predicted SEs of the planned design for every estimator of the study (the design
    is re-planned: the same default plan the seeds were simulated with)."""
    from vesselid.plant.waves import SEA_STATES, WaveConditions
    from vesselid.studies.planner import PREDICTED_ESTIMATORS, DisturbanceLevels, predict_design
    from vesselid.studies.seatrial import planned_sea_trial_design

    plan = planned_sea_trial_design(6, 20000).plan
    rec["success_probability"] = plan.success_probability()
    levels = None
    if rec.get("sea_state"):
        hs, tp = SEA_STATES[rec["sea_state"]]
        levels = DisturbanceLevels(waves=WaveConditions(height=hs, period=tp,
                                                        direction=np.radians(45.0)))
    rec["predicted"] = {}
    for m in [k for k in rec if isinstance(rec[k], dict) and "params" in rec[k]]:
        est = m if m in PREDICTED_ESTIMATORS else "iv-zero-mean"
        pred = predict_design(plan.forces(), warmup=plan.warmup, estimator=est, levels=levels)
        rec["predicted"][m] = pred.std_errors.to_numpy().tolist()


def summarize(rec: dict, figure: str | None = None) -> None:
    th = np.asarray(rec["theta0"])
    pse = np.asarray(rec["predicted_se"])
    big = np.abs(th) >= 1e-3
    if "success_probability" in rec and not rec.get("sea_state"):
        print(f"planner: predicted probability that every |θ0|≥1e-3 parameter is within 10 %: "
              f"{100 * rec['success_probability']:.0f} %")
    for m in [k for k in rec if isinstance(rec[k], dict) and "params" in rec[k]]:
        p, se = np.asarray(rec[m]["params"]), np.asarray(rec[m]["se"])
        if p.size == 0:
            continue
        z = (p - th) / se
        rel = np.abs(p - th) / np.abs(th)
        ok10 = (rel[:, big] <= 0.10).all(axis=1)
        ok35 = (np.abs(z) <= 3.5).all(axis=1)
        n = p.shape[0]
        print(f"{m}: {n} seeds; within 10 % on all |θ0|≥1e-3 and 3.5 SE on all: "
              f"{(ok10 & ok35).sum()}/{n}; within 3.5 SE: {ok35.sum()}/{n}; "
              f"within 10 %: {ok10.sum()}/{n}")
        sd = p.std(axis=0, ddof=1)
        pse = np.asarray(rec.get("predicted", {}).get(m, rec["predicted_se"]))
        ratio = pse / sd
        inside = int(((ratio >= 0.75) & (ratio <= 1.25)).sum())
        rep = se.mean(axis=0) / sd
        print(f"  predicted SE ({m} model) / MC sd: min {ratio.min():.2f} median "
              f"{np.median(ratio):.2f} max {ratio.max():.2f}, within 25 %: {inside}/{ratio.size}; "
              f"MC relative sd max {np.max(sd[big] / np.abs(th[big])):.3f}; "
              f"reported SE / MC sd: min {rep.min():.2f} median "
              f"{np.median(rep):.2f} max {rep.max():.2f}")
        for i, name in enumerate(rec["index"]):
            flag = "" if 0.75 <= ratio[i] <= 1.25 else "  <- outside 25 %"
            print(f"    {name:12s} θ0 {th[i]:+.4g} pred {pse[i]:.3g} mc {sd[i]:.3g} "
                  f"rel-mc {sd[i] / abs(th[i]):.3f} bias/sd {(p[:, i].mean() - th[i]) / sd[i]:+.2f}"
                  f" fail10 {(rel[:, i] > 0.1).sum() if big[i] else 0}{flag}")
        if figure and m == "auto":
            import matplotlib.pyplot as plt

            fig, ax = plt.subplots(figsize=(5, 4.5), dpi=80)
            ax.loglog(sd, pse, "o", label="planner (auto = SRIV)")
            ax.loglog(sd, se.mean(axis=0), "x", label="reported (mean)")
            lim = [min(sd.min(), pse.min()) / 2, max(sd.max(), pse.max()) * 2]
            ax.plot(lim, lim, "k-", lw=0.8)
            ax.fill_between(lim, [0.75 * x for x in lim], [1.25 * x for x in lim],
                            color="0.85", label="±25 %")
            ax.set_xlabel(f"Monte Carlo sd of the auto estimates ({p.shape[0]} seeds)")
            ax.set_ylabel("standard error")
            ax.set_title("Planned sea trial: predicted vs observed SE")
            ax.legend()
            fig.tight_layout()
            fig.savefig(figure)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=50)
    ap.add_argument("--methods", default="auto,iv-zero-mean")
    ap.add_argument("--sea-state", default=None)
    ap.add_argument("--out", default=None, help="JSON of per-seed estimates (rewritten per seed)")
    ap.add_argument("--first-seed", type=int, default=0, help="seeds first..first+seeds-1")
    ap.add_argument("--wave-filter", type=float, default=0.9,
                    help="low-pass fraction with --sea-state (as sea-trial; 0 = off)")
    ap.add_argument("--summarize", default=None,
                    help="only summarise these JSONs (comma-separated; seeds concatenated)")
    ap.add_argument("--figure", default=None)
    a = ap.parse_args()
    if a.summarize:
        rec = None
        for path in a.summarize.split(","):
            with open(path) as f:
                part = json.load(f)
            if rec is None:
                rec = part
                continue
            new = [i for i, sd in enumerate(part["seeds"]) if sd not in rec["seeds"]]
            rec["seeds"] += [part["seeds"][i] for i in new]
            for m in [k for k in part if isinstance(part[k], dict) and "params" in part[k]]:
                for key, val in part[m].items():
                    rec[m].setdefault(key, []).extend(val[i] for i in new)
        predictions(rec)
    else:
        rec = run(a.seeds, a.methods.split(","), a.sea_state, a.out, a.first_seed,
                  a.wave_filter)
    summarize(rec, a.figure)


if __name__ == "__main__":
    main()
