"""The prediction-error fit's candidate models on two threads: every number equals the
serial fit's (also where the model fitted ahead loses), and the unbounded one-step
estimate reuses the converged fit's last tangent pass without changing a number."""

import numpy as np
import pytest

from vesselid.core import threads
from vesselid.identify import from_arrays, pem
from vesselid.identify.estimators import estimate
from vesselid.studies.calibration import heave_scenario


def _data(scenario, seed, samples=3000):
    system, _, _ = heave_scenario(scenario)
    spec = system.identification_spec(aggregate=False)
    sim = system.simulate(samples, seed=seed)
    data = from_arrays(spec, sim.y, sim.u)
    base = estimate(data, spec, "iv-zero-mean", combine="pooled")
    return data, spec, base.theta


def _same(a, b):
    assert a.keys() == b.keys()
    for key in a:
        if a[key].dtype == object:
            assert list(a[key]) == list(b[key]), key
        else:
            np.testing.assert_array_equal(a[key], b[key], err_msg=key)


@pytest.mark.parametrize(("scenario", "winner"), [("gm-current-random", "current"),
                                                  ("gm-sensor-random", "sensor")])
def test_two_threads_give_the_serial_numbers(scenario, winner):
    if threads.n_threads() < 2:
        pytest.skip("one core: the candidates are fitted in turn either way")
    data, spec, theta = _data(scenario, seed=3)
    kw = {"joint": True, "boundary": "auto", "details": True}
    both = pem.fit_groups(data, spec, theta, parallel=True, **kw)
    one = pem.fit_groups(data, spec, theta, parallel=False, **kw)
    assert str(one["model"][0]).startswith(winner) or one["model"][0] in (
        pem.JOINT, pem.JOINT_LOCAL)
    assert np.argmax(one["loglik"][0]) == pem.DISTURBANCE_MODELS.index(winner)
    _same(both, one)


def test_background_runs_in_the_calling_thread_when_serial():
    with threads.serial_here():
        assert threads.background(lambda: 1) is None
    job = threads.background(lambda: 2)
    assert job is None or job.result() == 2


def _filter_and_start(model: str, **kwargs):
    """The filter of a Gauss–Markov-current log (in units of each signal's spread) and
    the start of ``model``'s scoring: ``(filter, spec, psi0, free)``."""
    data, spec, theta = _data("gm-current-random", **kwargs)
    rows, starts = data.group_rows(0)
    y = data.target[rows, 0]
    filt = pem._Filter(y / np.std(y), data.u[rows] / np.std(data.u[rows]), starts,
                       spec.codes.factors, parallel=False)
    psi0, free, _ = pem._start(theta[0], filt.y, filt.u, filt.starts, spec.codes.factors,
                               model)
    return filt, spec, psi0, free


def test_local_joint_reuses_the_last_tangent_pass_exactly():
    filt, spec, psi0, free = _filter_and_start("current", seed=5)
    fit = pem._scoring(filt, psi0, free, 100, pem.SCORING_TOL)
    assert fit["converged"] and fit["sandwich_parts"] is not None
    reused = pem._local_joint(filt, fit, spec.n_params)
    fresh = pem._local_joint(filt, {**fit, "sandwich_parts": None}, spec.n_params)
    for key in ("psi", "cov", "cov_sandwich"):
        np.testing.assert_array_equal(reused[key], fresh[key], err_msg=key)
    assert reused["q_z"] == fresh["q_z"]


@pytest.mark.parametrize("scenario", ["gm-current-random", "gm-sensor-random"])
def test_secant_tail_changes_no_reported_number(scenario, monkeypatch):
    """The losing model's tail takes secant steps; a winner is the plain scoring's fit:
    the estimate, its covariances, the choice and the winner's likelihood are those of
    plain Fisher scoring everywhere (``TAIL_DEC = 0``: no tail)."""
    data, spec, theta = _data(scenario, seed=3)
    kw = {"joint": True, "boundary": "auto", "parallel": False}
    fast = pem.fit_groups(data, spec, theta, **kw)
    monkeypatch.setattr(pem, "TAIL_DEC", 0.0)
    plain = pem.fit_groups(data, spec, theta, **kw)
    best = int(np.argmax(plain["loglik"][0]))
    for key in ("theta", "cov", "cov_sandwich", "cov_conservative", "psi", "lr_joint",
                "local_z", "shape_z"):
        np.testing.assert_array_equal(fast[key], plain[key], err_msg=key)
    assert list(fast["model"]) == list(plain["model"])
    assert fast["loglik"][0, best] == plain["loglik"][0, best]
    # the loser's likelihood: the same maximum up to a change of Vuong's z (the one
    # statistic that reads it) far below its resolution
    assert abs(fast["vuong"][0] - plain["vuong"][0]) < 0.01
    np.testing.assert_allclose(fast["loglik"][0], plain["loglik"][0], rtol=1e-6)


def test_secant_tail_converges_in_fewer_steps_to_the_same_maximum():
    """The sensor-noise model on a Gauss–Markov current (it loses there): its Hessian
    exceeds its Fisher information, plain scoring alternates about the optimum; the
    secant steps reach the same likelihood (within the stopping tolerance) in fewer."""
    filt, _, psi0, free = _filter_and_start("sensor", seed=0, samples=10_000)
    plain = pem._scoring(filt, psi0, free, 100, pem.SCORING_TOL)
    # a rival far better: the secant steps engage in the tail
    fast = pem._scoring(filt, psi0, free, 100, pem.SCORING_TOL, secant=lambda: -1e300)
    assert plain["converged"] and fast["converged"]
    assert fast["iterations"] < plain["iterations"]
    assert abs(np.sum(fast["nll_terms"]) - np.sum(plain["nll_terms"])) < 1e-3


def test_background_does_not_hold_up_run_ranges():
    """A job on the background thread never delays the calling thread's parallel
    kernels (their chunks go to another pool)."""
    import threading

    from numba import njit

    if threads.n_threads() < 2:
        pytest.skip("one core")

    @njit(nogil=True)
    def fill(lo, hi, out):  # pragma: no cover
        for i in range(lo, hi):
            out[i] = i

    release = threading.Event()
    job = threads.background(lambda: release.wait(30))
    try:
        out = np.zeros(64)
        done = threading.Event()

        def run():
            threads.run_ranges(fill, out.size, (out,), parallel=True)
            done.set()

        worker = threading.Thread(target=run)
        worker.start()
        assert done.wait(10), "run_ranges waited for the background job"
        np.testing.assert_array_equal(out, np.arange(64.0))
    finally:
        release.set()
        job.result()


def _scoring_fits(filt, psi0, free):
    return pem._scoring(filt, psi0, free, 100, pem.SCORING_TOL)


def _same_fit(a, b):
    for key in ("psi", "cov", "nll_terms"):
        np.testing.assert_array_equal(a[key], b[key], err_msg=key)
    assert (a["iterations"], a["reason"]) == (b["iterations"], b["reason"])


@pytest.mark.parametrize("model", ["current", "sensor"])
def test_line_search_several_trial_steps_at_once_takes_the_same_steps(model, monkeypatch):
    """The line search filters several trial steps together (as many as the previous
    search needed) and, in a pool's worker with idle cores, on threads: the fit is the
    one-step-at-a-time search's bit for bit."""
    import multiprocessing

    filt, _, psi0, free = _filter_and_start(model, seed=5)
    filt.parallel = True
    batched = _scoring_fits(filt, psi0, free)
    count = multiprocessing.Value("i", 0)
    monkeypatch.setattr(threads, "_SHARED", (count, 4))
    with threads.serial_here(overlap=True), threads.busy():
        assert threads.idle_cores() == 3
        spread = _scoring_fits(filt, psi0, free)
    monkeypatch.setattr(threads, "_SHARED", None)
    original = pem._LineSearch.step

    def one_at_a_time(self, *args):
        self.taken = (0, 0, 0)  # one trial point expected, then one at a time
        return original(self, *args)

    monkeypatch.setattr(pem._LineSearch, "step", one_at_a_time)
    monkeypatch.setattr(pem, "LINE_STEPS_MORE", 1)
    calls = []
    real_nll_rows = pem._Filter.nll_rows

    def spy(self, rows, **kwargs):
        calls.append(rows.shape[0])
        return real_nll_rows(self, rows, **kwargs)

    monkeypatch.setattr(pem._Filter, "nll_rows", spy)
    single = _scoring_fits(filt, psi0, free)
    assert calls and set(calls) == {1}  # the reference searched one step at a time
    _same_fit(batched, single)
    _same_fit(spread, single)


def test_aside_runs_in_a_copy_of_the_callers_context():
    import contextvars

    var = contextvars.ContextVar("aside_probe", default="unset")
    token = var.set("caller")
    try:
        job = threads.aside(var.get)
        assert job is None or job.result() == "caller"
        with threads.serial_here():
            assert threads.aside(lambda: 1) is None  # a worker runs it itself
    finally:
        var.reset(token)


def test_auto_with_the_likelihood_fit_aside_gives_the_serial_numbers(monkeypatch):
    """``auto`` on a coloured-current log runs its likelihood fit on a thread of its own
    (its candidate models then on two threads): every number of the result is the
    serial fit's."""
    import warnings

    from vesselid.identify import identify

    if threads.n_threads() < 2:
        pytest.skip("one core: the fit runs in turn either way")
    system, _, _ = heave_scenario("gm-current-random")
    log = system.simulate(3000, seed=3).to_log(aggregate=False)
    started = []
    real = threads.aside

    def spy(fn):
        job = real(fn)
        started.append(job is not None)
        return job

    monkeypatch.setattr(threads, "aside", spy)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        threaded = identify(log)
        with threads.serial_here():
            serial = identify(log)
    assert started == [True, False]  # aside in the first fit, in turn in the second
    assert threaded.diagnostics["choice"].startswith("pem")
    assert threaded.to_json() == serial.to_json()


def test_aside_on_its_own_thread_runs_the_job_in_place():
    """A job asked aside from the aside thread itself runs there (its one thread would
    wait for a job queued behind the one it runs)."""
    if threads.n_threads() < 2:
        pytest.skip("aside needs two threads")
    job = threads.aside(lambda: threads.aside(lambda: 1))
    assert job is not None
    assert job.result(timeout=10) is None
