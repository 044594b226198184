"""``auto`` on closed-loop logs that do not declare their loop: the PID law recovered from
the log, the route to ``cl-iv`` when a reference is logged, and the prominent note when it
cannot be (feedback test rejects, no reference)."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from vesselid.data.logs import TrialLog
from vesselid.errors import ClosedLoopWarning
from vesselid.identify import identify
from vesselid.identify.loop import closed_loop_note, estimate_controller
from vesselid.plant.closedloop import PID, simulate_closed_loop
from vesselid.plant.disturbances import Gaussian
from vesselid.plant.signals import RandomPulses
from vesselid.plant.systems import heave

PI = PID(loops={"tau": "w"}, kp={"tau": 0.3}, ki={"tau": 0.05}, offset={"tau": 0.2})


def _logs(seed: int, n: int = 3000, limits=None):
    system = heave()
    pid = PI if limits is None else PID(loops=PI.loops, kp=PI.kp, ki=PI.ki, offset=PI.offset,
                                         limits=limits)
    sim = simulate_closed_loop(system, pid, {"w": RandomPulses(1.0, 2.0, 50, 200)},
                               dither={"tau": Gaussian(0.0, 0.05)}, n_samples=n, seed=seed)
    log = sim.to_log(aggregate=False)
    meta = {k: v for k, v in log.metadata.items() if k != "closed_loop"}
    return system.identification_spec(aggregate=False), log, TrialLog(log.data, meta), pid


def test_pid_law_recovered_exactly_with_the_dither_logged() -> None:
    spec, _, log, _ = _logs(1)
    fit = estimate_controller(log, spec)
    assert fit is not None and dict(fit.controller.loops) == {"tau": "w"}
    c = fit.controller
    got = [c.kp["tau"], c.ki["tau"], c.kd["tau"], c.offset["tau"]]
    np.testing.assert_allclose(got, [0.3, 0.05, 0.0, 0.2], atol=1e-9)
    assert fit.r2["tau"] > 1 - 1e-12
    assert fit.dither == {"tau": "tau_dither"}


def test_pid_law_with_saturation_and_conditional_integration() -> None:
    """Limits hit on some rows: they are found from the log, those rows leave the fit and
    the integrator freezes there, as in the controller — the law is again exact."""
    spec, _, log, _ = _logs(2, limits={"tau": (-10.0, 0.5)})
    tau = log.data["tau"].to_numpy()
    assert np.mean(tau == 0.5) > 0.01  # the design saturates
    fit = estimate_controller(log, spec)
    c = fit.controller
    np.testing.assert_allclose([c.kp["tau"], c.ki["tau"], c.offset["tau"]], [0.3, 0.05, 0.2],
                               atol=1e-9)
    assert c.limits["tau"][1] == 0.5


def test_auto_routes_an_undeclared_loop_with_a_reference_to_cl_iv() -> None:
    """Same log with and without metadata['closed_loop']: the recovered law is the true one,
    so the estimates agree to rounding; the result says what happened."""
    spec, declared, undeclared, _ = _logs(3)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        res = identify(undeclared, spec)
    ref = identify(declared, spec)
    assert res.method == "cl-iv"
    assert any(issubclass(w.category, ClosedLoopWarning) for w in caught)
    assert "does not declare its loop" in res.diagnostics["choice_reason"]
    assert res.diagnostics["closed_loop_detected"]["feedback"]["rejects"]
    scale = ref.std_errors.to_numpy()
    assert np.max(np.abs(res.params.to_numpy() - ref.params.to_numpy()) / scale) < 1e-6
    assert "choice reason: cl-iv" in res.summary()


def test_no_reference_logged_auto_says_closed_loop_prominently() -> None:
    spec, _, undeclared, _ = _logs(4)
    noref = TrialLog(undeclared.data.drop(columns=["w_ref"]), undeclared.metadata)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        res = identify(noref, spec)
    assert res.method != "cl-iv"
    assert res.diagnostics["choice_reason"].startswith("CLOSED LOOP — the feedback test "
                                                        "rejects open loop")
    assert any(issubclass(w.category, ClosedLoopWarning) for w in caught)
    assert "choice reason: CLOSED LOOP" in res.summary()


def test_open_loop_log_with_a_reference_like_column_stays_open_loop() -> None:
    """A column named like a reference on an open-loop log: the feedback test does not
    reject, so auto neither re-routes nor adds the note."""
    system = heave()
    log = system.simulate(3000, seed=5).to_log(aggregate=False)
    frame = log.data.copy()
    frame["w_ref"] = np.random.default_rng(0).uniform(1, 2, len(frame))
    spec = system.identification_spec(aggregate=False)
    with warnings.catch_warnings():
        warnings.simplefilter("error", ClosedLoopWarning)
        res = identify(TrialLog(frame, log.metadata), spec)
    assert res.method != "cl-iv"
    assert not str(res.diagnostics.get("choice_reason") or "").startswith("CLOSED LOOP")


@pytest.mark.parametrize("fb, expect", [
    (None, None), ({"rejects": False, "declared_closed_loop": False}, None),
    ({"rejects": True, "declared_closed_loop": False, "pvalue": 1e-9}, "feedback test"),
    ({"rejects": False, "declared_closed_loop": True}, "declares closed loop")])
def test_closed_loop_note(fb, expect) -> None:
    note = closed_loop_note(fb)
    assert (note is None) if expect is None else (expect in note)


@pytest.mark.slow
def test_undeclared_loop_monte_carlo() -> None:
    """60 undeclared closed-loop heave logs with the dither not logged (the law is fitted
    with the dither as its error): auto routes every one to cl-iv, and its 95 % intervals
    cover θ0 at a rate compatible with 0.95 (exact binomial test at 1e-3, per parameter)."""
    from _stats import binomial_ok

    runs = 60
    cover = np.zeros(3, dtype=int)
    routed = 0
    for seed in range(runs):
        spec, _, log, _ = _logs(3000 + seed, n=5000)
        log = TrialLog(log.data.drop(columns=["tau_dither"]), log.metadata)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            res = identify(log, spec)
        routed += res.method == "cl-iv"
        theta0 = spec.theta0_vector()
        cover += np.abs(res.params.to_numpy() - theta0) <= 1.96 * res.std_errors.to_numpy()
    assert routed == runs
    assert all(binomial_ok(int(c), runs, 0.95) for c in cover), cover
