"""The kernel module: factor layout, Φ (numpy, compiled, generated), one-step update."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from numba import njit

from vesselid.errors import ModelSpecError
from vesselid.model.regressors import (
    SALT,
    advance,
    encode_terms,
    evaluate,
    factor_source,
    fill_factors,
    fill_factors_xu,
    kernel,
    one_step,
    predict,
    regressors,
)
from vesselid.model.terms import Term

NAMES = ["u", "v", "r", "X"]

term_strategy = st.builds(
    lambda a, la, b, rb, second: (
        Term(a, la, b, rb and not la) if second else Term(a, la)
    ),
    st.sampled_from(NAMES), st.booleans(), st.sampled_from(NAMES), st.booleans(), st.booleans(),
)


def _definition(term: Term, named: dict) -> float:
    """Definition 2.1 written out: x, |x|, x*y, x*|y|, |x|*y."""
    a = abs(named[term.left]) if term.left_abs else named[term.left]
    if term.right is None:
        return a
    b = abs(named[term.right]) if term.right_abs else named[term.right]
    return a * b


@njit
def _compiled_phi(fac, s):
    f = np.empty(2 * s.shape[0] + 1)
    phi = np.empty(fac.shape[0])
    fill_factors(s, f)
    regressors(fac, f, phi)
    return phi


@njit
def _compiled_phi_xu(fac, x, u):
    f = np.empty(2 * (x.shape[0] + u.shape[0]) + 1)
    phi = np.empty(fac.shape[0])
    fill_factors_xu(x, u, f)
    regressors(fac, f, phi)
    return phi


@njit
def _compiled_step(fac, eq, theta, s, out):
    f = np.empty(2 * s.shape[0] + 1)
    phi = np.empty(fac.shape[0])
    advance(fac, eq, theta, s, f, phi, out)


@settings(deadline=None)
@given(
    st.lists(term_strategy, min_size=1, max_size=6),
    st.lists(st.floats(-1e3, 1e3), min_size=len(NAMES), max_size=len(NAMES)),
)
def test_every_evaluation_matches_the_definition(terms, values):
    """numpy, compiled (signal vector / states + inputs) evaluation equal Definition 2.1."""
    layout = encode_terms([terms], NAMES)
    s = np.asarray(values, dtype=float)
    named = dict(zip(NAMES, s, strict=True))
    expected = np.array([_definition(t, named) for t in terms])
    np.testing.assert_array_equal(evaluate(layout, s), expected)
    np.testing.assert_array_equal(_compiled_phi(layout.factors, s), expected)
    np.testing.assert_array_equal(_compiled_phi_xu(layout.factors, s[:3], s[3:]), expected)


@settings(deadline=None)
@given(st.lists(st.floats(-10, 10), min_size=6, max_size=6))
def test_one_step_update_numpy_and_compiled_agree_bitwise(values):
    from vesselid.plant.vessels import cybership2_spec

    spec = cybership2_spec(0.1)
    layout, theta = spec.codes, spec.theta0_vector()
    s = np.asarray(values)
    phi = evaluate(layout, s)
    for k, start in enumerate((np.zeros(3), np.array([0.5, -0.25, 0.125]))):
        ref = start.copy()  # written out: additive part first, then terms in order
        for p in range(spec.n_params):
            ref[layout.equation[p]] += theta[p] * phi[p]
        out = start.copy()
        _compiled_step(layout.factors, layout.equation, theta, s, out)
        np.testing.assert_array_equal(out, ref)
        one = start.copy()
        _one_step(layout.equation, theta, phi, one)
        np.testing.assert_array_equal(one, ref)
        if k == 0:
            np.testing.assert_array_equal(predict(layout, theta, s), ref)


@njit
def _one_step(eq, theta, phi, out):
    one_step(eq, theta, phi, out)


def test_vectorised_evaluation_shapes():
    layout = encode_terms([[Term.parse("u*|u|"), Term.parse("X")]], NAMES)
    sig = np.random.default_rng(0).normal(size=(5, 7, 4))
    phi = evaluate(layout, sig)
    assert phi.shape == (5, 7, 2)
    np.testing.assert_array_equal(phi[..., 0], sig[..., 0] * np.abs(sig[..., 0]))
    np.testing.assert_array_equal(phi[..., 1], sig[..., 3])
    assert predict(layout, [2.0, 3.0], sig).shape == (5, 7, 1)


def test_layout_and_factor_source():
    layout = encode_terms([[Term.parse("u")], [Term.parse("|r|*v"), Term.parse("X*|u|")]], NAMES)
    assert layout.n_signals == 4 and layout.n_factors == 9 and layout.n_params == 3
    np.testing.assert_array_equal(layout.equation, [0, 1, 1])
    decoded = [[factor_source(int(i), 4) for i in row] for row in layout.factors]
    assert decoded == [[(0, False), None], [(2, True), (1, False)], [(3, False), (0, True)]]


def test_unknown_signal_in_encoding():
    with pytest.raises(ModelSpecError, match="unknown signal 'q'"):
        encode_terms([[Term.parse("q")]], NAMES)


def test_kernel_cache_key_is_salted():
    """Cached kernels carry the module digest in their cache key (edits here invalidate)."""

    @kernel()
    def twice(x):
        return 2.0 * x

    assert twice(1.5) == 3.0
    key = twice._cache._index_key(twice.signatures[0], twice.targetctx.codegen())
    assert key[-1] == SALT and len(SALT) == 16
