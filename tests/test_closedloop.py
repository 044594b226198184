"""Closed-loop logs, the closed-loop refined IV and the feedback test."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from _stats import binomial_ok

from vesselid.cli import main
from vesselid.data.logs import TrialLog
from vesselid.errors import ClosedLoopWarning, ControlError, IdentificationError
from vesselid.identify import identify
from vesselid.identify.closedloop import feedback_test
from vesselid.plant.closedloop import PID, closed_loop_states, simulate_closed_loop
from vesselid.plant.disturbances import Gaussian
from vesselid.plant.signals import RandomPulses
from vesselid.plant.systems import heave

PI = PID(loops={"tau": "w"}, kp={"tau": 0.3}, ki={"tau": 0.05}, offset={"tau": 0.2})
REF = {"w": RandomPulses(1.0, 2.0, 50, 200)}
DITHER = {"tau": Gaussian(0.0, 0.05)}


def _closed(seed: int, n: int = 4000, system=None):
    system = system or heave()
    sim = simulate_closed_loop(system, PI, REF, dither=DITHER, n_samples=n, seed=seed)
    return system.identification_spec(aggregate=False), sim.to_log(aggregate=False)


def test_policy_equals_compiled_loop() -> None:
    """The per-sample PID (environment loops) and the compiled closed loop apply the same
    law: the same inputs and states to rounding, saturation and anti-windup included."""
    spec = heave().spec
    pid = PID(loops={"tau": "w"}, kp={"tau": 0.5}, ki={"tau": 0.2}, kd={"tau": 0.1},
              offset={"tau": 0.1}, limits={"tau": (0.0, 0.4)})
    rng = np.random.default_rng(0)
    n = 400
    ref = np.repeat(rng.uniform(0.5, 2.0, n // 50), 50)[:, None]
    dith = 0.05 * rng.standard_normal((n, 1))
    e = 0.05 * rng.standard_normal((n, 1))
    x, u, st = closed_loop_states(spec, pid, ref, dither=dith, e=e, x0=[1.0])
    assert st[0] == 0 and np.any(u == 0.4) and np.any(u == 0.0)  # saturates both ways
    pol = pid.policy(spec)
    xs = np.empty(n)
    xs[0] = 1.0
    theta = spec.theta0_vector()
    for k in range(n):
        uk = pol([xs[k] + e[k, 0]], ref[k], dith[k])
        assert abs(uk[0] - u[k, 0]) <= 1e-12 * max(1.0, abs(u[k, 0]))
        if k + 1 < n:
            w = xs[k]
            xs[k + 1] = theta[0] * w + theta[1] * w * abs(w) + theta[2] * uk[0]
    np.testing.assert_allclose(xs, x[:, 0], rtol=1e-10)


def test_log_columns_metadata_and_round_trip(tmp_path) -> None:
    _, log = _closed(1, 500)
    assert {"w_ref", "tau_dither"} <= set(log.data.columns)
    cl = log.metadata["closed_loop"]
    assert cl["reference"] == {"w": "w_ref"} and cl["dither"] == {"tau": "tau_dither"}
    assert PID.from_dict(cl["controller"]) == PI
    path = log.save(tmp_path / "cl.csv")
    back = TrialLog.load(path)
    assert back.metadata["closed_loop"] == cl
    # the inputs are the PI law of the logged measurement, reference and dither
    d = log.data
    err = d["w_ref"] - d["w"]
    integ = np.concatenate([[0.0], np.cumsum(err)[:-1]])
    np.testing.assert_allclose(d["tau"], 0.2 + 0.3 * err + 0.05 * integ + d["tau_dither"],
                               rtol=1e-10, atol=1e-12)


def test_noise_free_closed_loop_recovers_theta0() -> None:
    system = heave(stds={"current": 0.0, "xi": 0.0, "sensor": 0.0})
    spec, log = _closed(3, 2000, system)
    res = identify(log, spec, "cl-iv")
    np.testing.assert_allclose(res.params.to_numpy(), spec.theta0_vector(), rtol=1e-8)


def test_closed_loop_estimator_and_warning_on_a_noisy_log() -> None:
    """One seeded closed-loop log: cl-iv within 3 SE of θ0 (its own HAC SE), LS and the
    open-loop IV far outside (the feedback bias), the open-loop fits warn."""
    spec, log = _closed(5, 6000)
    theta0 = spec.theta0_vector()
    cl = identify(log, spec, "cl-iv")
    z = (cl.params.to_numpy() - theta0) / cl.std_errors.to_numpy()
    assert np.all(np.abs(z) < 3)
    for method in ("ls", "iv-zero-mean"):
        with pytest.warns(ClosedLoopWarning):
            res = identify(log, spec, method)
        zz = (res.params.to_numpy() - theta0) / res.std_errors.to_numpy()
        assert np.max(np.abs(zz)) > 5
    # without the metadata, the feedback test itself rejects
    with pytest.warns(ClosedLoopWarning, match="correlated with past output errors"):
        res = identify(log.data, spec, "ls")
    assert res.diagnostics["feedback"]["rejects"]
    assert feedback_test(log, spec).pvalue < 1e-6


def test_auto_uses_the_closed_loop_estimator() -> None:
    spec, log = _closed(6, 3000)
    with warnings.catch_warnings():
        warnings.simplefilter("error", ClosedLoopWarning)
        res = identify(log, spec, "auto")
    assert res.method == "cl-iv"
    assert "closed loop" in res.diagnostics["auto_choice"]


def test_open_loop_log_does_not_warn() -> None:
    system = heave()
    log = system.simulate(4000, seed=2).to_log(aggregate=False)
    spec = system.identification_spec(aggregate=False)
    with warnings.catch_warnings():
        warnings.simplefilter("error", ClosedLoopWarning)
        res = identify(log, spec, "iv-zero-mean")
    assert not res.diagnostics["feedback"]["rejects"]


def test_bad_input(tmp_path, capsys) -> None:
    system = heave()
    spec = system.identification_spec(aggregate=False)
    open_log = system.simulate(500, seed=0).to_log(aggregate=False)
    with pytest.raises(IdentificationError, match="needs a closed-loop log"):
        identify(open_log, spec, "cl-iv")
    _, log = _closed(1, 500)
    broken = TrialLog(log.data.drop(columns=["w_ref"]), log.metadata)
    with pytest.raises(IdentificationError, match="reference of the controlled state 'w'"):
        identify(broken, spec, "cl-iv")
    meta = dict(log.metadata, closed_loop=dict(log.metadata["closed_loop"], controller=None))
    with pytest.raises(IdentificationError, match="needs the controller"):
        identify(TrialLog(log.data, meta), spec, "cl-iv")
    with pytest.raises(ControlError):
        PID(loops={"tau": "w"}, limits={"tau": (1.0, 0.0)})
    # command line: one line, exit 2
    path = open_log.save(tmp_path / "open.csv")
    assert main(["identify", str(path), "--method", "cl-iv"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "closed-loop log" in err[0]
    bpath = broken.save(tmp_path / "broken.csv")
    assert main(["identify", str(bpath), "--method", "cl-iv"]) == 2
    assert "reference" in capsys.readouterr().err
    for lam in ("0", "1.5", "nan"):
        assert main(["recursive", str(path), "--forgetting", lam]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and "forgetting must be in (0, 1]" in err[0]


def test_cli_closed_loop_then_identify(tmp_path, capsys) -> None:
    out = tmp_path / "cl.csv"
    assert main(["closed-loop", "--samples", "1500", "--seed", "4", "--out", str(out)]) == 0
    assert main(["identify", str(out), "--method", "cl-iv"]) == 0
    assert "closed-loop refined IV" in capsys.readouterr().out
    assert main(["recursive", str(out), "--method", "ls", "--history",
                 str(tmp_path / "h.csv"), "--every", "100"]) == 0
    assert (tmp_path / "h.csv").read_text().count("\n") == 15


@pytest.mark.slow
def test_closed_loop_monte_carlo() -> None:
    """60 closed-loop heave logs: cl-iv's 95 % HAC intervals cover θ0 at a rate compatible
    with 0.95 (exact binomial test at 1e-3, per parameter), and the open-loop warning fires
    on a share compatible with at least 0.95 of the closed-loop logs and at most 0.05 of
    60 open-loop logs (one-sided binomial tests at 1e-3)."""
    from scipy import stats

    runs = 60
    system = heave()
    spec = system.identification_spec(aggregate=False)
    theta0 = spec.theta0_vector()
    cover = np.zeros(3, dtype=int)
    fired = 0
    for seed in range(runs):
        sim = simulate_closed_loop(system, PI, REF, dither=DITHER, n_samples=5000,
                                   seed=1000 + seed)
        log = sim.to_log(aggregate=False)
        res = identify(log, spec, "cl-iv")
        cover += np.abs(res.params.to_numpy() - theta0) <= 1.96 * res.std_errors.to_numpy()
        fired += feedback_test(log, spec).rejects
    assert all(binomial_ok(int(c), runs, 0.95) for c in cover), cover
    assert stats.binomtest(fired, runs, 0.95, alternative="less").pvalue > 1e-3
    false = sum(feedback_test(system.simulate(5000, seed=2000 + s).to_log(aggregate=False),
                              spec).rejects for s in range(runs))
    assert stats.binomtest(false, runs, 0.05, alternative="greater").pvalue > 1e-3


def test_recorder_logs_a_closed_loop_environment_run() -> None:
    """The heave environment under the PI loop (the policy of the same PID, thrust limits
    equal to the environment's), dither annotated: the recorded log names its loop and
    cl-iv identifies from it."""
    import gymnasium as gym

    import vesselid.envs  # noqa: F401
    from vesselid.envs.recorder import TrialRecorder

    env = gym.make("vesselid/Heave-v0", max_episode_steps=3000)
    rec = TrialRecorder(env)
    lo, hi = env.unwrapped.log_metadata()["settings"]["thrust_range"]
    pid = PID(loops={"tau": "w"}, kp={"tau": 0.3}, ki={"tau": 0.05}, offset={"tau": 0.2},
              limits={"tau": (lo, hi)})
    spec = rec.model_spec
    policy = pid.policy(spec)
    rec.declare_closed_loop(pid, reference={"w": "w_ref"}, dither={"tau": "tau_dither"})
    rng = np.random.default_rng(0)
    _, info = rec.reset(seed=0)
    for _ in range(3000):
        d = 0.03 * rng.standard_normal()
        tau = policy([info["y1"]], [info["w_ref"]], [d])[0]
        rec.annotate(tau_dither=d)
        _, _, term, trunc, info = rec.step(np.array([2 * (tau - lo) / (hi - lo) - 1],
                                                    dtype=np.float32))
        if term or trunc:
            break
    log = rec.to_log()
    assert log.metadata["closed_loop"]["dither"] == {"tau": "tau_dither"}
    assert np.isfinite(log.data["tau_dither"]).all()
    res = identify(log, spec, "auto")
    assert res.method == "cl-iv" and res.converged


def test_cli_closed_loop_cybership2_velocity_loops(tmp_path, capsys) -> None:
    out = tmp_path / "dp.csv"
    assert main(["closed-loop", "--system", "cybership2", "--samples", "300", "--out",
                 str(out)]) == 0
    log = TrialLog.load(out)
    assert log.data["experiment"].nunique() == 4
    assert {"u_ref", "v_ref", "r_ref", "X_dither", "Y_dither", "N_dither"} <= set(log.data)
    assert log.spec.n_params == 25  # the full structure: v, r of both relative signs
    cl = log.metadata["closed_loop"]
    assert PID.from_dict(cl["controller"]).loops == {"X": "u", "Y": "v", "N": "r"}
    assert main(["closed-loop", "--reference", "2", "1", "--out", str(out)]) == 2
    assert "LOW <= HIGH" in capsys.readouterr().err


def test_closed_loop_log_declares_white_sensor_noise() -> None:
    """A simulated closed-loop log carries its white sensor noise (the errors-in-variables
    correction of cl-iv reads it); with the modulus state's sign fixed the correction is
    a per-experiment constant that the zero-mean instruments absorb: the estimate moves
    only by rounding."""
    system = heave()
    spec = system.identification_spec(aggregate=False)
    log = simulate_closed_loop(system, PI, REF, dither=DITHER, n_samples=3000,
                               seed=8).to_log(aggregate=False)
    assert log.metadata["sensor_noise_std"] == {"w": 0.1}
    w = log.data["w"].to_numpy()
    assert np.all(w > 0), w.min()   # the measured modulus state keeps its sign
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        corrected = identify(log, spec, "cl-iv")
        raw = identify(log, spec, "cl-iv", sensor_noise=False)
    se = raw.std_errors.to_numpy()
    assert np.all(np.abs(corrected.params.to_numpy() - raw.params.to_numpy()) <= 1e-6 * se)


@pytest.mark.slow
def test_closed_loop_modulus_sign_changes_corrected() -> None:
    """A reference of both signs drives the heave velocity through zero, where the sensor
    noise's mean in the modulus regressor (σ²·sign(w)) varies with the state and biases
    the uncorrected estimate by an amount that does not shrink with the log's length. 30
    logs of 50 000 samples: with the log's sensor noise the corrected cl-iv's bias stays
    within 3.29 Monte Carlo standard errors (two-sided 0.1 %) on every parameter, and the
    correction moves the w*|w| coefficient by more than 5 paired standard errors."""
    system = heave()
    spec = system.identification_spec(aggregate=False)
    theta0 = spec.theta0_vector()
    pi = PID(loops={"tau": "w"}, kp={"tau": 0.3}, ki={"tau": 0.05})
    ref = {"w": RandomPulses(-0.6, 0.6, 50, 200)}
    corrected, raw = [], []
    for seed in range(30):
        log = simulate_closed_loop(system, pi, ref, dither=DITHER, n_samples=50_000,
                                   seed=300 + seed).to_log(aggregate=False)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            corrected.append(identify(log, spec, "cl-iv").params.to_numpy())
            raw.append(identify(log, spec, "cl-iv", sensor_noise=False).params.to_numpy())
    a, b = np.array(corrected), np.array(raw)
    z = (a.mean(axis=0) - theta0) / (a.std(axis=0, ddof=1) / np.sqrt(len(a)))
    assert np.all(np.abs(z) <= 3.29), z
    d = a - b
    shift = d.mean(axis=0) / (d.std(axis=0, ddof=1) / np.sqrt(len(d)))
    assert abs(shift[list(spec.param_index).index(("w", "w*|w|"))]) > 5, shift
