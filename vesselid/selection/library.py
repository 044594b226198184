"""Candidate libraries of modulus terms (Definition 2.1) for term selection.

A library is, per state equation, an ordered tuple of candidate :class:`~vesselid.model.terms.Term`
objects. :func:`full_library` builds every form of Definition 2.1 over the states and
inputs of a spec — ``x``, ``|x|``, ``x*y`` and ``x*|y|`` — in a fixed order (first-order
terms before products, signals in spec order), so that among candidates that are the same
in the data the simpler, earlier one represents the group. :func:`parse_library` reads a
user list (``"u, v, r, u*|u|"`` for every equation, or ``"u: u, u*|u|; v: v, r"`` per
equation); :func:`library_from_spec` takes the ``[equations]`` table of a candidate spec.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path

from vesselid.errors import ModelSpecError, VesselidError
from vesselid.model.spec import ModelSpec
from vesselid.model.terms import Term

__all__ = ["Library", "SelectionError", "canonical", "full_library", "library_from_spec",
           "parse_library", "resolve_library", "vessel_library"]

#: state -> ordered candidate terms
Library = dict[str, tuple[Term, ...]]

#: names accepted by :func:`resolve_library` for generated libraries
PRESETS = ("full", "vessel")


class SelectionError(VesselidError):
    """Bad input to term selection (empty or unknown library term, too large a library)."""


def canonical(term: Term) -> Term:
    """One spelling per regressor: ``|x|*y`` → ``y*|x|``, ``y*x`` → ``x*y`` (name order),
    ``|x|*x`` → ``x*|x|``."""
    if term.right is None:
        return term
    if term.left_abs:  # |x|*y is y*|x|
        return Term(term.right, False, term.left, True)
    if not term.right_abs and term.right < term.left:
        return Term(term.right, False, term.left, False)
    return term


def full_library(spec: ModelSpec) -> Library:
    """Every term of Definition 2.1 over the spec's states and inputs, for every equation.

    Order (signals in ``states + inputs`` order): ``x``, ``|x|``, the damping forms
    ``x*|x|``, the products ``x*y`` (``i ≤ j``), then ``x*|y|`` for ``x ≠ y``. Among
    candidates that are the same in a log (``x*|x| = x²`` when ``x`` keeps its sign) the
    earlier one represents the group, so the physical forms win. With ``S`` signals that
    is ``2S + S(S+1)/2 + S²`` candidates (69 for three states and three inputs).
    """
    sig = list(spec.signals)
    terms: list[Term] = [Term(s) for s in sig]
    terms += [Term(s, True) for s in sig]
    terms += [Term(s, False, s, True) for s in sig]
    terms += [Term(a, False, b, False) for i, a in enumerate(sig) for b in sig[i:]]
    terms += [Term(a, False, b, True) for a in sig for b in sig if a != b]
    return {s: tuple(terms) for s in spec.states}


def vessel_library(spec: ModelSpec) -> Library:
    """Every form of Definition 2.1 over the states, plus each input alone and times each
    state and each state's modulus (``u``, ``x*u``, ``u*|x|``): models in which the inputs
    (forces, rudder) enter linearly, as in the usual manoeuvring models.

    Order as :func:`full_library`: ``x``, ``|x|``, ``x*|x|``, ``x*y``, ``x*|y|`` over the
    states, then the inputs, ``x*u`` and ``u*|x|``. Three states and three inputs give 42.
    """
    st, inp = list(spec.states), list(spec.inputs)
    terms: list[Term] = [Term(s) for s in st]
    terms += [Term(s, True) for s in st]
    terms += [Term(s, False, s, True) for s in st]
    terms += [canonical(Term(a, False, b, False)) for i, a in enumerate(st) for b in st[i:]]
    terms += [Term(a, False, b, True) for a in st for b in st if a != b]
    terms += [Term(u) for u in inp]
    terms += [canonical(Term(x, False, u, False)) for x in st for u in inp]
    terms += [Term(u, False, x, True) for x in st for u in inp]
    return {s: tuple(terms) for s in spec.states}


def _check_terms(spec: ModelSpec, state: str, terms: Sequence[Term | str]) -> tuple[Term, ...]:
    known = set(spec.signals)
    out: list[Term] = []
    seen: set[str] = set()
    for raw in terms:
        try:
            term = canonical(Term.parse(raw) if isinstance(raw, str) else raw)
        except ModelSpecError as exc:
            raise SelectionError(f"library of equation {state!r}: {exc}") from None
        unknown = [n for n in term.signals if n not in known]
        if unknown:
            raise SelectionError(
                f"library of equation {state!r}: term {term} uses unknown signal "
                f"{unknown[0]!r}; known: {list(spec.signals)}")
        if str(term) not in seen:
            seen.add(str(term))
            out.append(term)
    if not out:
        raise SelectionError(f"the candidate library of equation {state!r} is empty")
    return tuple(out)


def parse_library(text: str, spec: ModelSpec) -> Library:
    """Parse a library given on the command line.

    ``"u, v, u*|u|"`` (comma-separated terms) is the library of every equation;
    ``"u: u, u*|u|; v: v, r"`` gives one list per equation (every state needs one);
    ``"full"`` is :func:`full_library`, ``"vessel"`` :func:`vessel_library`.

    Raises
    ------
    SelectionError
        Empty library, unparsable or unknown term, a state without a list, an unknown state.
    """
    if not isinstance(text, str) or not text.strip():
        raise SelectionError("the candidate library is empty")
    text = text.strip()
    if text == "full":
        return full_library(spec)
    if text == "vessel":
        return vessel_library(spec)
    if ":" not in text:
        items = [t for t in (p.strip() for p in text.split(",")) if t]
        return {s: _check_terms(spec, s, items) for s in spec.states}
    lib: dict[str, list[str]] = {}
    for part in (p for p in text.split(";") if p.strip()):
        if ":" not in part:
            raise SelectionError(f"library part {part.strip()!r} must read 'state: term, term'")
        state, rest = part.split(":", 1)
        state = state.strip()
        if state not in spec.states:
            raise SelectionError(f"library given for unknown state {state!r}; states: "
                                 f"{list(spec.states)}")
        lib[state] = [t for t in (p.strip() for p in rest.split(",")) if t]
    return resolve_library(lib, spec)


def library_from_spec(path: str | Path, spec: ModelSpec) -> Library:
    """The ``[equations]`` table of a candidate spec file as a library (its states must be
    the base spec's)."""
    cand = ModelSpec.load(path)
    if tuple(cand.states) != tuple(spec.states):
        raise SelectionError(f"candidate spec states {list(cand.states)} differ from the model's "
                             f"{list(spec.states)}")
    return resolve_library({s: list(cand.equations[s]) for s in cand.states}, spec)


def resolve_library(library: str | Mapping[str, Sequence[Term | str]] | Sequence[Term | str]
                    | None, spec: ModelSpec) -> Library:
    """Any accepted library form → :data:`Library` (``None``: :func:`full_library`)."""
    if library is None:
        return full_library(spec)
    if isinstance(library, str):
        return parse_library(library, spec)
    if isinstance(library, Mapping):
        unknown = sorted(set(library) - set(spec.states))
        if unknown:
            raise SelectionError(f"library given for unknown states {unknown}; states: "
                                 f"{list(spec.states)}")
        missing = [s for s in spec.states if s not in library]
        if missing:
            raise SelectionError(f"the candidate library of equation {missing[0]!r} is empty")
        return {s: _check_terms(spec, s, list(library[s])) for s in spec.states}
    if isinstance(library, Sequence):
        return {s: _check_terms(spec, s, list(library)) for s in spec.states}
    raise SelectionError(f"library: expected a string, a list of terms or a mapping state -> "
                         f"terms, got {type(library).__name__}")
