"""Generated moment kernels: bit-identity with the generic kernel on every catalogue
structure, and the hardening of their cache (private directory, fallbacks, pruning)."""

from __future__ import annotations

import os
import sys
import time
import warnings
from pathlib import Path

import numpy as np
import pytest

from vesselid.identify import _fastkernels as fk
from vesselid.identify import estimators
from vesselid.identify.data import block_starts, from_log
from vesselid.plant.catalogue import get_system, names

#: Every catalogue system (the CyberShip II structure has 23 parameters).
CATALOGUE = names()

POSIX = hasattr(os, "getuid")


@pytest.fixture(autouse=True)
def _fresh_cache():
    fk._clear()
    yield
    fk._clear()


def _forget_loaded(monkeypatch):
    """Forget the generated modules this process imported (so they are loaded anew)."""
    for name in [n for n in sys.modules if n.startswith(fk._PREFIX)]:
        monkeypatch.delitem(sys.modules, name)


@pytest.mark.parametrize("name", CATALOGUE)
def test_generated_kernel_bit_identical_to_generic_on_every_catalogue_spec(monkeypatch, name):
    system = get_system(name)
    log = system.simulate(400, n_runs=2, seed=1).to_log()
    generated = []
    for spec in (system.spec, system.identification_spec()):
        # the structure (what the kernel is generated for) does not depend on aggregation
        if not set(spec.sensors) <= set(log.data.columns):
            spec = spec.with_aggregate(None)
        if _check_identity(monkeypatch, name, log, spec):
            generated.append(spec.n_params)
    assert generated, f"{name}: no structure has a generated kernel"
    if name == "cybership2":
        # the identification structure (v|r| and r|v| merged) and the sea-trial model
        # (25 parameters; the v and r equations share their terms)
        assert {23, 25} <= set(generated)


def _check_identity(monkeypatch, name, log, spec):
    data, spec = from_log(log, spec)
    codes = spec.codes
    kern = fk.specialised_moments(spec.n_states, spec.n_inputs, codes.factors, codes.equation,
                                  block_starts(spec))
    products = fk.moment_products(codes.factors, block_starts(spec))
    assert (kern is None) == (products > fk.MAX_SPECIALISED_PRODUCTS), name
    if spec.n_params <= fk.MAX_SPECIALISED_PARAMS:  # generated before the size rule
        assert kern is not None, name
    theta = np.tile(spec.theta0_vector(), (data.n_groups, 1))
    unstable = np.abs(theta) + 1.5  # an auxiliary model that diverges
    slow = _assert_generic_moments(monkeypatch, data, spec, (None, theta, unstable), name)
    assert np.all(slow.status == 1)  # the unstable model did diverge (the branch is covered)
    return kern is not None


def _assert_generic_moments(monkeypatch, data, spec, thetas, name):
    """The moments of this process's kernels equal the generic kernel's, bit for bit, for
    every auxiliary model of ``thetas`` (None: least squares); the last generic ones."""
    for th in thetas:
        fast = estimators.compute_moments(data, spec, th)
        with monkeypatch.context() as m:
            m.setenv("VESSELID_GENERIC_KERNELS", "1")
            slow = estimators.compute_moments(data, spec, th)
        for field in ("zphi", "zy", "z", "phi", "y", "count", "status"):
            np.testing.assert_array_equal(getattr(fast, field), getattr(slow, field),
                                          err_msg=f"{name} {field}")
    return slow


def test_both_source_forms_are_used_and_match_the_generic_kernel(monkeypatch):
    """Small structures get unrolled scalar sums, large ones looped array sums (whose
    code grows with the parameters, not the products); both are the generic kernel's
    numbers, here on a 39-parameter structure with three distinct 13-term equations."""
    from vesselid.model.spec import ModelSpec

    forms = {}
    for name in ("heave", "cybership2"):
        spec = get_system(name).spec
        codes = spec.codes
        source = fk._source(spec.n_states, spec.n_inputs, codes.factors, codes.equation,
                            block_starts(spec))
        forms[name] = "(looped sums)" in source.splitlines()[0]
    assert forms == {"heave": False, "cybership2": True}
    pool = ["u", "v", "r", "u*|u|", "v*|v|", "r*|r|", "u*v", "u*r", "v*r", "v*|r|", "r*|v|",
            "|u|"]
    eqs = {s: [*pool, f"{x}*{s}"] for s, x in zip("uvr", "XYN", strict=True)}
    big = ModelSpec("big", states=["u", "v", "r"], inputs=["X", "Y", "N"], equations=eqs,
                    theta0={s: [0.0] * 13 for s in "uvr"}, dt=0.1)
    system = get_system("cybership2")
    log = system.simulate(400, n_runs=2, seed=1).to_log()
    data, big = from_log(log, big)
    assert fk.moment_products(big.codes.factors, block_starts(big)) == 3 * 13 ** 2
    theta = np.zeros((data.n_groups, 39))
    theta[:, [0, 13 + 1, 26 + 2]] = 0.95  # a stable diagonal auxiliary model
    _assert_generic_moments(monkeypatch, data, big, (None, theta), "big")


def _heave_data():
    system = get_system("heave")
    log = system.simulate(300, n_runs=1, seed=0).to_log()
    return from_log(log, system.identification_spec())


def test_compile_failure_at_first_call_falls_back_to_generic(monkeypatch):
    data, spec = _heave_data()
    with monkeypatch.context() as m:
        m.setenv("VESSELID_GENERIC_KERNELS", "1")
        ref = estimators.compute_moments(data, spec, None)
    source = fk._source
    # valid Python that numba cannot type: fails at the first call, not at import
    monkeypatch.setattr(fk, "_source", lambda *a: source(*a).replace(
        "    status[s] = 0\n", "    status[s] = 0\n    undefined_helper_xyz(s)\n", 1))
    with pytest.warns(RuntimeWarning, match="failed to compile"):
        got = estimators.compute_moments(data, spec, None)
    np.testing.assert_array_equal(got.zphi, ref.zphi)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # disabled now: no second attempt, no second warning
        again = estimators.compute_moments(data, spec, None)
    np.testing.assert_array_equal(again.zy, ref.zy)


@pytest.mark.skipif(not POSIX, reason="POSIX permissions")
def test_kernel_dir_is_private(monkeypatch, tmp_path):
    target = tmp_path / "a" / "kernels"
    monkeypatch.setenv("VESSELID_KERNEL_DIR", str(target))
    assert fk.kernel_dir() == target
    assert target.stat().st_mode & 0o777 == 0o700
    target.chmod(0o755)  # an own directory that is too open is tightened
    assert fk.kernel_dir() == target
    assert target.stat().st_mode & 0o777 == 0o700


@pytest.mark.skipif(not POSIX, reason="POSIX ownership")
def test_foreign_or_exposed_directory_is_refused_and_generic_kernel_used(monkeypatch, tmp_path):
    target = tmp_path / "kernels"
    monkeypatch.setenv("VESSELID_KERNEL_DIR", str(target))
    assert fk.kernel_dir() == target
    monkeypatch.setattr(fk, "_uid", lambda: os.getuid() + 1)  # somebody else's directory
    assert fk.kernel_dir() is None
    monkeypatch.undo()
    # a parent that others can write to (not sticky): they could swap the directory
    parent = tmp_path / "open"
    parent.mkdir()
    parent.chmod(0o777)
    monkeypatch.setenv("VESSELID_KERNEL_DIR", str(parent / "kernels"))
    assert fk.kernel_dir() is None
    data, spec = _heave_data()
    _forget_loaded(monkeypatch)
    codes = spec.codes
    assert fk.specialised_moments(1, 1, codes.factors, codes.equation, block_starts(spec)) is None
    mom = estimators.compute_moments(data, spec, None)  # the generic kernel still works
    assert np.all(np.isfinite(mom.zphi))
    assert not list((parent / "kernels").glob("*.py"))


def test_no_temporary_directory_fallback(monkeypatch, tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("x")
    monkeypatch.setenv("VESSELID_KERNEL_DIR", str(blocker / "kernels"))  # cannot be created
    assert fk.kernel_dir() is None
    _, spec = _heave_data()
    _forget_loaded(monkeypatch)
    codes = spec.codes
    assert fk.specialised_moments(1, 1, codes.factors, codes.equation, block_starts(spec)) is None


def test_windows_without_getuid(monkeypatch, tmp_path):
    monkeypatch.delattr(os, "getuid", raising=False)
    monkeypatch.setenv("VESSELID_KERNEL_DIR", str(tmp_path / "k"))
    assert fk.kernel_dir() == tmp_path / "k"


def test_pruning_removes_stale_kernels_and_their_caches(tmp_path):
    now = time.time()
    cache = tmp_path / "__pycache__"
    cache.mkdir()
    names = [f"{fk._PREFIX}{i:016x}" for i in range(5)]
    for i, name in enumerate(names):
        path = tmp_path / f"{name}.py"
        path.write_text("# generated\n")
        (cache / f"{name}.parallel-1.py311.nbi").write_text("")
        age = 40 * 86400 if i == 0 else i  # file 0 unused for 40 days
        os.utime(path, (now - age, now - age))
    other = tmp_path / "unrelated.py"
    other.write_text("")
    os.utime(other, (now - 90 * 86400,) * 2)
    gone = fk.prune(tmp_path, now=now, keep=3)
    # the stale one, and beyond the 3 most recently used ones: files 0, 4
    assert sorted(p.name for p in gone) == sorted(f"{names[i]}.py" for i in (0, 4))
    assert sorted(p.stem for p in tmp_path.glob(f"{fk._PREFIX}*.py")) == names[1:4]
    assert sorted(p.name.split(".")[0] for p in cache.iterdir()) == names[1:4]
    assert other.exists()


def test_generated_file_name_is_salted(monkeypatch, tmp_path):
    monkeypatch.setenv("VESSELID_KERNEL_DIR", str(tmp_path))
    _, spec = _heave_data()
    _forget_loaded(monkeypatch)
    codes = spec.codes
    args = (1, 1, codes.factors, codes.equation, block_starts(spec))
    assert fk.specialised_moments(*args) is not None
    first = {p.name for p in Path(tmp_path).glob("*.py")}
    fk._clear()
    monkeypatch.setattr(fk, "SALT", "0" * 16)  # as after an edit of vesselid/model/regressors.py
    assert fk.specialised_moments(*args) is not None
    second = {p.name for p in Path(tmp_path).glob("*.py")}
    assert len(first) == 1 and len(second) == 2 and first < second


@pytest.mark.parametrize("name", CATALOGUE)
def test_generated_combined_pass_bit_identical_to_generic(monkeypatch, name):
    """The generated combined-instrument GMM pass (``auto``'s Monte Carlo fast path)
    equals the generic ``combined_moments`` bit for bit, both passes, diverging
    auxiliary models included; larger instrument sets keep the generic kernel."""
    from vesselid.identify import gmm
    from vesselid.identify.data import from_arrays

    system = get_system(name)
    spec = system.identification_spec()
    sim = system.simulate(400, n_runs=3, seed=1)
    data = from_arrays(spec, sim.y, sim.u, y2=sim.y2 if spec.aggregate else None)
    codes = spec.codes
    ztype, zpar, zeq, _, _ = gmm._combined_layout(spec)
    colour = gmm._colour_layout(spec)[:3]
    kern = fk.specialised_combined(spec.n_states, spec.n_inputs, codes.factors,
                                   codes.equation, ztype, zpar, zeq, *colour)
    assert (kern is None) == (max(ztype.size, colour[0].size) > fk.MAX_COMBINED_COLUMNS), name
    theta = np.tile(spec.theta0_vector(), (data.n_groups, 1))
    unstable = theta.copy()
    unstable[1] = np.abs(theta[1]) + 1.5  # one group's auxiliary model diverges
    for th in (theta, unstable):
        fast, ok_fast = gmm.combined_solution(data, spec, th)
        with monkeypatch.context() as m:
            m.setenv("VESSELID_GENERIC_KERNELS", "1")
            slow, ok_slow = gmm.combined_solution(data, spec, th)
        np.testing.assert_array_equal(ok_fast, ok_slow, err_msg=name)
        for field in ("theta", "ok", "j", "c"):
            np.testing.assert_array_equal(getattr(fast, field), getattr(slow, field),
                                          err_msg=f"{name} {field}")
    assert not ok_slow[1] and ok_slow[0]  # the divergence branch was taken


@pytest.mark.parametrize("name", CATALOGUE)
def test_generated_colour_test_equals_explicit(name):
    """The colour test fused into the generated combined pass gives
    :func:`vesselid.identify.gmm.colour_test`'s statistic to 1e-9 relative on every
    catalogue structure it is generated for (several equations included); none where the
    generic kernel runs."""
    from vesselid.identify import gmm, kernels
    from vesselid.identify.data import from_arrays

    system = get_system(name)
    spec = system.identification_spec()
    sim = system.simulate(1500, n_runs=3, seed=4)
    data = from_arrays(spec, sim.y, sim.u, y2=sim.y2 if spec.aggregate else None)
    theta = np.tile(spec.theta0_vector(), (data.n_groups, 1))
    sol, _ = gmm.combined_solution(data, spec, theta, colour=gmm.COLOUR_WINDOW)
    ztype = gmm._combined_layout(spec)[0]
    if max(ztype.size, gmm._colour_layout(spec)[0].size) > fk.MAX_COMBINED_COLUMNS:
        assert sol.colour is None
        return
    phi = kernels.regressor_matrix(data.regsig, data.u, data.starts, spec.codes.factors)
    z, _ = gmm.simulated_instruments(data, spec, theta)
    stat, df = gmm.colour_test(data, spec, phi, z)
    assert sol.colour_ok.all()
    np.testing.assert_array_equal(sol.colour_df, df)
    np.testing.assert_allclose(sol.colour, stat, rtol=1e-9, atol=0, err_msg=name)
