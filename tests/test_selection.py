"""Term selection (vesselid.selection): noise-free and hand cases, a seeded noisy case,
bad input and the command line. Monte Carlo evidence: scripts/selection_study.py."""

from __future__ import annotations

import json
import math
import warnings

import numpy as np
import pytest

from vesselid.cli import main
from vesselid.errors import VesselidError
from vesselid.model.spec import ModelSpec
from vesselid.model.terms import Term
from vesselid.plant.disturbances import Zero
from vesselid.plant.systems import System, heave
from vesselid.selection import SelectionError, full_library, select_terms
from vesselid.selection.engine import critical_value, same_in_data_groups
from vesselid.selection.library import canonical, parse_library, vessel_library


def _heave_log(n: int, seed: int, *, noise: bool = True):
    """The heave vehicle with w kept positive (A10): white current inside the modulus."""
    sys_ = heave(xi_mean=0.0, pulse_high=0.5)
    if not noise:
        sys_ = System(spec=sys_.spec.with_aggregate(None), inputs=sys_.inputs,
                      current={"w": Zero()}, process_noise={"w": Zero()},
                      sensor_noise={"w": Zero()}, x0=sys_.x0)
    return sys_.simulate(n, 1, seed=seed).to_log(aggregate=False)


def test_library_forms_and_canonical():
    spec = ModelSpec("m", ["u", "v"], ["d"], {"u": ["u"], "v": ["v"]})
    lib = full_library(spec)["u"]
    s = len(spec.signals)
    assert len(lib) == 2 * s + s + s * (s + 1) // 2 + s * (s - 1)
    assert len({str(t) for t in lib}) == len(lib)
    assert [str(t) for t in lib[:3]] == ["u", "v", "d"]
    assert str(canonical(Term.parse("|u|*v"))) == "v*|u|"
    assert str(canonical(Term.parse("v*u"))) == "u*v"
    assert len(vessel_library(spec)["u"]) == 2 * 2 + 2 + 3 + 2 + 1 + 2 + 2
    per = parse_library("u: u, u*|u|; v: v, |v|*v", spec)
    assert [str(t) for t in per["v"]] == ["v", "v*|v|"]


def test_critical_value_by_hand():
    # Bonferroni part: z_{1-0.05/(2*10)} = 2.807; sqrt(log 1000) = 2.628
    assert critical_value(0.05, 10, 1000) == pytest.approx(2.8070338, rel=1e-6)
    assert critical_value(0.05, 1, 10**8) == pytest.approx(math.sqrt(math.log(10**8)))


def test_same_in_data_groups_hand_case():
    rng = np.random.default_rng(0)
    x = 1.0 + rng.random(500)  # never changes sign: |x| = x, x*|x| = x²
    y = rng.standard_normal(500)
    cols = np.column_stack([x, np.abs(x), y, x * np.abs(x), x * x, np.full(500, 3.0)])
    cols = cols - cols.mean(axis=0)
    keep, groups = same_in_data_groups(cols, ["x", "|x|", "y", "x*|x|", "x*x", "c"], 1e-4)
    assert keep.tolist() == [0, 2, 3]
    members = [g["members"] for g in groups]
    assert ["x", "|x|"] in members and ["x*|x|", "x*x"] in members and ["c"] in members


def test_noise_free_heave_recovers_structure_and_theta():
    log = _heave_log(3000, 1, noise=False)
    res = select_terms(log, log.spec, "vessel", n_boot=10)
    assert res.selected == {"w": ["w", "w*|w|", "tau"]}
    assert np.allclose(res.theta.to_numpy(), [0.99, -0.1, 1.0], atol=1e-8)
    # the probabilities of the true terms are one, of the zero ones zero
    p = res.probabilities()["w"]
    assert p["w"] == 1.0 and p["tau"] == 1.0 and p["tau*w"] == 0.0


def test_noisy_heave_selects_true_terms_and_groups_collinear():
    log = _heave_log(30000, 3)
    res = select_terms(log, log.spec, "vessel", n_boot=0)
    assert res.selected == {"w": ["w", "w*|w|", "tau"]}
    tab = res.table.set_index("term")
    assert "the same as w" in tab.loc["|w|", "same_as"]  # w > 0: reported, not picked
    assert not tab.loc["|w|", "selected"]
    assert res.spec.theta0 is None and res.spec.aggregate == {}


def test_noisy_heave_library_first_model():
    """The library model as the first auxiliary model: a linear base, the same true
    structure as from the true base, the instruments' source reported."""
    log = _heave_log(30000, 3)
    base = ModelSpec("heave", ["w"], ["tau"], {"w": ["w", "tau"]}, dt=1.0)
    res = select_terms(log, base, "vessel", n_boot=0, first_model="library")
    assert res.selected == {"w": ["w", "w*|w|", "tau"]}
    assert res.aux_source.startswith(("library model", "selected model"))


def test_stepwise_ends_at_a_fixed_point_with_a_near_copy():
    """Forward-backward search on exact instruments (z = φ, independent noise): the
    final model is the true one, and no candidate left out would pass the test when
    added to it (the search ends at a fixed point, whatever it dropped on the way)."""
    from vesselid.selection.engine import _added_t, critical_value, stepwise

    rng = np.random.default_rng(7)
    n, nb = 20000, 50
    x1, x2, x4 = rng.standard_normal((3, n))
    x3 = x1 + 0.3 * x2 + 0.05 * rng.standard_normal(n)  # near-copy of the true pair's sum
    phi = np.column_stack([x3, x1, x2, x4])
    y = x1 + 0.3 * x2 + 0.2 * rng.standard_normal(n)
    m_mat = np.stack([b.T @ b for b in np.split(phi, nb)])
    m_vec = np.stack([b.T @ yy for b, yy in zip(np.split(phi, nb), np.split(y, nb),
                                                 strict=True)])
    crit = critical_value(0.01, 4, n)
    c = np.ones(nb)
    keep, theta, _, _ = stepwise(m_mat, m_vec, c, crit)
    assert np.flatnonzero(keep).tolist() == [1, 2]
    assert np.allclose(theta[[1, 2]], [1.0, 0.3], atol=0.02)
    out = [j for j in range(4) if not keep[j]]
    added = _added_t(m_mat.sum(0), m_vec.sum(0), m_mat, m_vec, c, float(nb),
                     np.flatnonzero(keep).tolist(), out)
    assert np.all(added < crit)


@pytest.mark.parametrize("library, match", [
    ("", "empty"),
    ("w, q", "unknown signal 'q'"),
    ("w, w*|w|*tau", "invalid term"),
    ("x: w", "unknown state"),
    ({"w": []}, "empty"),
])
def test_bad_library_one_line(library, match):
    log = _heave_log(400, 0)
    with pytest.raises(SelectionError, match=match) as exc:
        select_terms(log, log.spec, library)
    assert "\n" not in str(exc.value) and isinstance(exc.value, ValueError)


def test_library_larger_than_data():
    log = _heave_log(80, 0)
    with pytest.raises(SelectionError, match="more than this log supports"):
        select_terms(log, log.spec, "full")


@pytest.mark.parametrize("kw", [{"alpha": 0.0}, {"alpha": float("nan")}, {"n_boot": -1},
                                {"passes": 0}, {"block_length": 1},
                                {"first_model": "lasso"}])
def test_bad_options(kw):
    log = _heave_log(400, 0)
    with pytest.raises(VesselidError):
        select_terms(log, log.spec, "vessel", **kw)


def test_cli_select_then_identify(tmp_path, capsys):
    log = _heave_log(6000, 2)
    path = tmp_path / "trial.csv"
    log.save(path)
    out, js = tmp_path / "sel.toml", tmp_path / "sel.json"
    assert main(["select", str(path), "--library", "vessel", "--out", str(out),
                 "--json", str(js), "--bootstrap", "20"]) == 0
    report = json.loads(js.read_text())
    probs = {(c["equation"], c["term"]): c["probability"] for c in report["candidates"]}
    assert set(probs) == {("w", str(t)) for t in vessel_library(log.spec)["w"]}
    assert all(p is None or 0.0 <= p <= 1.0 for p in probs.values())
    spec = ModelSpec.load(out)
    assert [str(t) for t in spec.equations["w"]] == report["selected"]["w"]
    capsys.readouterr()
    assert main(["identify", str(path), "--model", str(out), "--method", "iv-zero-mean"]) == 0
    assert main(["select", str(path), "--library", "w, nope", "--out",
                 str(tmp_path / "x.toml")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "unknown signal 'nope'" in err[0]
    assert not (tmp_path / "x.toml").exists()
    lib_out = tmp_path / "lib.toml"
    assert main(["select", str(path), "--library", "vessel", "--out", str(lib_out),
                 "--bootstrap", "0", "--first-model", "library"]) == 0
    assert lib_out.exists()


def test_seeded_bootstrap_reproducible():
    log = _heave_log(4000, 5)
    a = select_terms(log, log.spec, "vessel", n_boot=15, seed=3).probabilities()
    b = select_terms(log, log.spec, "vessel", n_boot=15, seed=3).probabilities()
    assert a.equals(b)



@pytest.mark.slow
def test_monte_carlo_heave_selection_and_coverage():
    """60 seeded heave logs (white current inside the modulus): the true structure is
    selected at the 95 % target and the intervals of identify on the selected spec keep
    their level, both within one-sided binomial tolerances (z = 2.33) of the runs."""
    from vesselid.identify import identify

    runs, n = 60, 30000
    sys_ = heave(xi_mean=0.0, pulse_high=0.5)
    base = ModelSpec("heave", ["w"], ["tau"], {"w": ["w", "tau"]}, dt=1.0)
    theta0 = dict(zip(["w", "w*|w|", "tau"], [0.99, -0.1, 1.0], strict=True))
    exact = false_kept = hits = total = 0
    for r in range(runs):
        log = sys_.simulate(n, 1, seed=np.random.SeedSequence([11, r])).to_log(aggregate=False)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            res = select_terms(log, base, "vessel", n_boot=0)
            sel = res.selected["w"]
            exact += sel == ["w", "w*|w|", "tau"]
            false_kept += "tau*w" in sel
            if sel == ["w", "w*|w|", "tau"]:
                fit = identify(log, res.spec, "iv-zero-mean")
                se = np.sqrt(np.diag(fit.cov))
                for (_, term), est, sd in zip(fit.params.index, fit.params, se, strict=True):
                    hits += abs(est - theta0[term]) <= 1.959964 * sd
                    total += 1
    tol = 2.33 * math.sqrt(0.95 * 0.05 / runs)
    assert exact / runs >= 0.95 - tol
    assert false_kept / runs <= 0.05 + tol
    cov_tol = 2.33 * math.sqrt(0.95 * 0.05 / total)
    assert abs(hits / total - 0.95) <= cov_tol



def test_derived_state_kept_in_the_selected_spec(tmp_path):
    """A base spec with a derived state (``dw = w - 0.2`` from the measured ``w``, as the
    KVLCC2 spec's ``du``): the selected spec and the file it is saved to keep the
    ``[derived]`` table, so identify and validate read the raw log with it."""
    from vesselid.data.logs import TrialLog
    from vesselid.identify import identify

    log = _heave_log(3000, 1, noise=False)
    raw = TrialLog(log.data, {})
    base = ModelSpec("heave-d", ["dw"], ["tau"], {"dw": ["dw", "tau"]}, dt=log.spec.dt,
                     derived={"dw": "w - 0.2"})
    res = select_terms(raw, base, "vessel", n_boot=0)
    assert {k: str(v) for k, v in res.spec.derived.items()} == {"dw": str(base.derived["dw"])}
    res.save(tmp_path / "sel.toml")
    again = ModelSpec.from_toml((tmp_path / "sel.toml").read_text())
    assert set(again.derived) == {"dw"}
    fit = identify(raw, again, method="ls")
    assert np.all(np.isfinite(np.asarray(fit.params)))


def test_simulation_error_by_hand():
    """Σ_states Σ(x̃ − x̂̃)²/Σx̃² with per-experiment centring: 0 for a perfect simulation,
    one per state for a simulation constant within every experiment, (1 − a)² for a
    simulation that is ``a`` times the measurement."""
    from vesselid.identify.data import RegressionData
    from vesselid.selection.engine import simulation_error

    rng = np.random.default_rng(1)
    x = rng.standard_normal((40, 2))
    data = RegressionData.__new__(RegressionData)
    object.__setattr__(data, "target", x)
    object.__setattr__(data, "starts", np.array([0, 25, 40]))
    assert simulation_error(data, x) == pytest.approx(0.0, abs=1e-12)
    const = np.zeros_like(x)
    const[25:] = 7.0  # constant within each experiment: centred away
    assert simulation_error(data, const) == pytest.approx(2.0)
    assert simulation_error(data, 0.75 * x) == pytest.approx(2 * 0.25**2)


def test_library_model_is_the_best_tracking_iterate():
    """The library model's instruments come from the iterate (IV chain from the base
    model's instruments, or refined IV from least squares) whose simulation tracks the
    log best, and the error returned is that of the instruments returned."""
    from vesselid.identify.data import from_log
    from vesselid.selection import engine
    from vesselid.selection import select as sel
    from vesselid.selection.library import resolve_library

    log = _heave_log(6000, 5)
    base = ModelSpec("heave", ["w"], ["tau"], {"w": ["w", "tau"]}, dt=1.0)
    lib = resolve_library("vessel", base)
    data, spec = from_log(log, base)
    union, cols = engine.library_factors(lib, spec)
    segs = engine.equation_rows_per_segment(data)
    phi_c = engine.centred(engine.regressors(data, union, spec), segs)
    y_c = engine.centred(data.target, segs)
    keep, _ = engine.same_in_data_groups(phi_c[:, cols["w"]], [str(union[j]) for j in
                                                               cols["w"]], 1e-4)
    theta = sel._refined_iv(data, spec)
    z, _ = engine.instruments(data, union, spec, theta, with_error=True)
    assert np.array_equal(z, engine.instruments(data, union, spec, theta), equal_nan=True)
    keep_idx = {"w": cols["w"][keep]}
    z_lib, err_lib, full = sel._library_model(data, spec, union, keep_idx, z, segs, phi_c,
                                              y_c)
    assert [str(t) for t in full.equations["w"]] == [str(union[j]) for j in keep_idx["w"]]
    first = sel._iv_start(data, full, union, keep_idx, z, segs, phi_c, y_c)
    alt = engine.instruments(data, union, full, sel._refined_iv(data, full, max_iter=3),
                             with_error=True)
    assert err_lib <= min(first[1], alt[1])
    assert any(np.array_equal(z_lib, c[0], equal_nan=True) for c in (first, alt)) or \
        err_lib < min(first[1], alt[1])


def test_indistinguishable_pair_by_hand():
    """y = x1 + e with x2 = x1 + 0.03 η: the model {x1} passes, {x2} passes, {x1, x2}
    leaves neither significant, so x2 is reported as undecided with x1; an independent
    zero-coefficient x3 is not."""
    from vesselid.selection.engine import critical_value, indistinguishable

    rng = np.random.default_rng(4)
    n, L = 2000, 20
    x1 = rng.standard_normal(n)
    x2 = x1 + 0.03 * rng.standard_normal(n)
    x3 = rng.standard_normal(n)
    y = x1 + rng.standard_normal(n)
    phi = np.column_stack([x1, x2, x3])
    phi = phi - phi.mean(axis=0)
    y = y - y.mean()
    nb = n // L
    pb = phi.reshape(nb, L, 3)
    m_mat = np.einsum("bkp,bkq->bpq", pb, pb)  # instruments = regressors (no noise in φ)
    m_vec = np.einsum("bkp,bk->bp", pb, y.reshape(nb, L))
    crit = critical_value(0.01, 3, n)
    keep = np.array([True, False, False])
    assert indistinguishable(m_mat, m_vec, keep, crit) == {0: [1]}
    # a clearly separable pair (x2 independent of x1) is decided
    phi[:, 1] = rng.standard_normal(n)
    pb = phi.reshape(nb, L, 3)
    m_mat = np.einsum("bkp,bkq->bpq", pb, pb)
    m_vec = np.einsum("bkp,bk->bp", pb, y.reshape(nb, L))
    assert indistinguishable(m_mat, m_vec, keep, crit) == {}


def test_undecided_column_in_table_and_summary():
    log = _heave_log(6000, 3)
    res = select_terms(log, log.spec, "vessel", n_boot=0)
    assert "undecided" in res.table.columns
    assert set(res.table.loc[~res.table.selected, "undecided"]) <= {""}
    assert res.to_dict()  # JSON report carries the column
