"""Definition 2.1 terms: parsing and printing (evaluation: test_regressors.py)."""

import pytest
from hypothesis import given
from hypothesis import strategies as st

from vesselid.errors import ModelSpecError
from vesselid.model.terms import Term

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


def test_terms_and_model_import_no_numba():
    """Parsing terms and specs is plain Python: numba loads only with a kernel."""
    import subprocess
    import sys

    code = ("import sys, vesselid, vesselid.model.terms, vesselid.model.spec; "
            "vesselid.model.spec.ModelSpec('m', ['x'], ['u'], {'x': ['x', 'x*|x|', 'u']}); "
            "assert 'numba' not in sys.modules, 'numba imported'")
    subprocess.run([sys.executable, "-c", code], check=True)
