"""Definition 2.1 terms: parsing, printing, evaluation (numpy and compiled)."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from vesselid.errors import ModelSpecError
from vesselid.terms import (
    Term,
    encode_terms,
    evaluate_terms,
    factor_codes,
    fill_factors,
    term_value,
)

NAMES = ["u", "v", "r", "X"]


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ("u", Term("u")),
        ("|u|", Term("u", True)),
        ("u*r", Term("u", False, "r")),
        ("u*|u|", Term("u", False, "u", True)),
        ("|r|*v", Term("r", True, "v")),
        (" u * | r | ", Term("u", False, "r", True)),
    ],
)
def test_parse(text, expected):
    assert Term.parse(text) == expected


@pytest.mark.parametrize("bad", ["", "u+r", "u*r*v", "|u|*|r|", "2*u", "u^2", "|u", "u**2", "1u"])
def test_invalid_terms_name_the_term_and_forms(bad):
    with pytest.raises(ModelSpecError) as err:
        Term.parse(bad)
    assert repr(bad) in str(err.value)
    assert "x*|y|" in str(err.value)


def test_modulus_error_is_value_error():
    with pytest.raises(ValueError):
        Term.parse("|u|*|v|")


term_strategy = st.builds(
    lambda a, la, b, rb, second: (
        Term(a, la, b, rb and not la) if second else Term(a, la)
    ),
    st.sampled_from(NAMES), st.booleans(), st.sampled_from(NAMES), st.booleans(), st.booleans(),
)


@given(term_strategy)
def test_print_parse_round_trip(term):
    assert Term.parse(str(term)) == term


@settings(deadline=None)
@given(
    st.lists(term_strategy, min_size=1, max_size=6),
    st.lists(st.floats(-1e3, 1e3), min_size=len(NAMES), max_size=len(NAMES)),
)
def test_encoded_evaluation_matches_definition(terms, values):
    """numpy, compiled and factor-coded evaluation agree with the term's own evaluate()."""
    codes = encode_terms([terms], NAMES)
    s = np.asarray(values, dtype=float)
    named = dict(zip(NAMES, s, strict=True))
    expected = np.array([t.evaluate(named) for t in terms])
    np.testing.assert_array_equal(evaluate_terms(codes.codes, s), expected)
    compiled = np.array([term_value(codes.codes, p, s) for p in range(len(terms))])
    np.testing.assert_array_equal(compiled, expected)
    f = np.empty(2 * len(NAMES) + 1)
    fill_factors(s, f)
    fac = factor_codes(codes.codes, len(NAMES))
    np.testing.assert_array_equal(f[fac[:, 0]] * f[fac[:, 1]], expected)


def test_vectorised_evaluation_shapes():
    codes = encode_terms([[Term.parse("u*|u|"), Term.parse("X")]], NAMES)
    sig = np.random.default_rng(0).normal(size=(5, 7, 4))
    phi = evaluate_terms(codes.codes, sig)
    assert phi.shape == (5, 7, 2)
    np.testing.assert_allclose(phi[..., 0], sig[..., 0] * np.abs(sig[..., 0]))


def test_unknown_signal_in_encoding():
    with pytest.raises(ModelSpecError, match="unknown signal 'q'"):
        encode_terms([[Term.parse("q")]], NAMES)
