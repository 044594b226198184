"""Term selection on the KVLCC2 HSVA free-running zig-zags, validated on held-out runs.

Reads the thirteen HSVA zig-zag files (``*KVLCC2_Z_*.dat``: four header lines, then
whitespace columns ``time, x0, y0, psi, u, v, r, p, delta, rev, thrust, torque`` at 20 Hz;
angles in degrees, ``r`` in deg/s, ``u, v`` earth-fixed) with a small loader: ``u, v`` are
rotated into the body frame with ``psi``, angles converted to radians, and 10-sample
means give ``dt = 0.5 s``. States ``du = u − 1.177`` (the approach speed: the propeller
turns at constant rpm in every run, so ``rev`` terms are constants absorbed by the
zero-mean instruments), ``v``, ``r``; input ``delta``.

Nine runs train, four are held out (one per family: 10°/10° S, 15°/5°, 20°/10° P,
25°/5°). On the training runs ``select_terms`` picks the terms from the ``vessel``
library (28 candidates per equation) with the hand-written structure as the base model;
the hand-written and the selected spec are then identified (``iv-zero-mean``) on the
training runs and simulated in free run on the held-out runs from their measured
initial state and rudder. Printed: the selected structure with every kept candidate's
probability, and per held-out run and state the free-run fit ``100 (1 − ‖y − ŷ‖/‖y − ȳ‖)``
of both models.

The data have no licence and are not in the repository: give their folder with
``--data DIR`` or ``VESSELID_KVLCC2_DIR``; without it the script says so and exits 0.

    nice -n 10 python scripts/kvlcc2_selection.py --data /work/data/kvlcc2_hsva
"""

from __future__ import annotations

import argparse
import os
import re
import sys
import warnings
from pathlib import Path

import numpy as np
import pandas as pd

U0 = 1.177
DT = 0.5
DECIMATE = 10  # 20 Hz -> 2 Hz
HELD_OUT = ("Z_10_10_S", "Z_15_05", "Z_20_10_P", "Z_25_05")
HAND = {  # the hand-written structure, in du = u - U0 (constant rpm: rev*|rev| is a constant)
    "du": ["du", "du*|du|", "v*r", "delta*delta"],
    "v": ["v", "du*v", "r", "du*r", "v*|v|", "delta", "du*delta"],
    "r": ["r", "v", "du*v", "du*r", "r*|r|", "delta", "du*delta", "v*|v|"],
}
COLUMNS = ["time", "x0", "y0", "psi", "u", "v", "r", "p", "delta", "rev", "thrust", "torque"]


def read_run(path: Path) -> pd.DataFrame:
    """One HSVA zig-zag file → body-frame ``du, v, r`` (rad/s) and ``delta`` (rad) at 2 Hz."""
    raw = pd.read_csv(path, skiprows=4, sep=r"\s+", header=None, names=COLUMNS,
                      encoding="latin-1")
    psi = np.deg2rad(raw["psi"].to_numpy())
    ue, ve = raw["u"].to_numpy(), raw["v"].to_numpy()
    body = pd.DataFrame({
        "u": ue * np.cos(psi) + ve * np.sin(psi),
        "v": -ue * np.sin(psi) + ve * np.cos(psi),
        "r": np.deg2rad(raw["r"].to_numpy()),
        "delta": np.deg2rad(raw["delta"].to_numpy()),
    })
    n = len(body) // DECIMATE
    avg = body.iloc[: n * DECIMATE].groupby(np.arange(n * DECIMATE) // DECIMATE).mean()
    out = pd.DataFrame({"time": np.arange(n) * DT, "du": avg["u"] - U0, "v": avg["v"],
                        "r": avg["r"], "delta": avg["delta"]})
    out.insert(0, "experiment", re.search(r"Z_\d+_\d+(?:_[PS])?", path.name).group(0))
    return out


def free_run_fit(spec, theta, run: pd.DataFrame) -> dict[str, float]:
    from vesselid.plant.simulate import simulate_states

    y = run[list(spec.states)].to_numpy()
    u = run[list(spec.inputs)].to_numpy()
    x = simulate_states(spec, u, theta=np.asarray(theta, float), x0=y[0],
                        raise_on_divergence=False)
    out = {}
    for i, s in enumerate(spec.states):
        err = np.linalg.norm(y[:, i] - x[:, i])
        den = np.linalg.norm(y[:, i] - y[:, i].mean())
        out[s] = float(100.0 * (1.0 - err / den)) if np.all(np.isfinite(x[:, i])) else np.nan
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", default=os.environ.get("VESSELID_KVLCC2_DIR"))
    ap.add_argument("--bootstrap", type=int, default=100)
    args = ap.parse_args(argv)
    if not args.data:
        print("no KVLCC2 data: give --data DIR or VESSELID_KVLCC2_DIR; nothing to do")
        return 0
    data = Path(args.data)
    raw = data / "raw_data" if (data / "raw_data").is_dir() else data
    files = sorted(raw.glob("*KVLCC2_Z_*.dat"))
    if not files:
        print(f"no *KVLCC2_Z_*.dat files under {raw}; nothing to do")
        return 0
    from vesselid.data.logs import TrialLog
    from vesselid.model.spec import ModelSpec
    from vesselid.selection import fit_structure, select_terms

    runs = {f: read_run(f) for f in files}
    frames = {df["experiment"].iloc[0]: df for df in runs.values()}
    train = pd.concat([df for k, df in frames.items() if k not in HELD_OUT], ignore_index=True)
    hand = ModelSpec("kvlcc2", ["du", "v", "r"], ["delta"], HAND, dt=DT)
    log = TrialLog(train, {"spec": hand.to_dict()})
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = select_terms(log, hand, "vessel", n_boot=args.bootstrap)
    print(res.summary())
    print()
    rows = []
    fits = {"hand-written": (hand, fit_structure(log, hand)),
            "selected": (res.spec, fit_structure(log, res.spec))}
    for name, (spec, theta) in fits.items():
        for k in HELD_OUT:
            if k in frames:
                rows.append({"model": name, "run": k, "terms": spec.n_params,
                             **free_run_fit(spec, theta.to_numpy(), frames[k])})
    table = pd.DataFrame(rows)
    print("held-out free-run fit (%); both structures fitted by refined IV with zero-mean "
          "instruments on the nine training runs")
    print(table.to_string(index=False, float_format=lambda x: f"{x:.1f}"))
    print(table.groupby("model")[["du", "v", "r"]].mean().to_string(
        float_format=lambda x: f"{x:.1f}"))
    sys.stdout.flush()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
