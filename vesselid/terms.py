"""Second-order modulus terms (paper Definition 2.1).

A second-order modulus function is ``f(x, θ) = Φᵀ(x) θ`` where every regressor is
one of ``x_i``, ``|x_i|``, ``x_i x_j`` or ``x_i |x_j|`` over the signals ``x``
(states and inputs). This module parses such terms from text (``"u"``, ``"|u|"``,
``"u*r"``, ``"u*|u|"``, ``"|r|*v"``), prints them back, and evaluates them, both
vectorised with numpy and inside compiled (numba) kernels through a small integer
encoding shared by simulation, estimation, instrument generation and the
gymnasium environments.
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numba import njit

from vesselid.errors import ModelSpecError

__all__ = [
    "ALLOWED_FORMS",
    "Term",
    "TermCodes",
    "encode_terms",
    "evaluate_terms",
    "factor_codes",
    "fill_factors",
    "term_value",
]

ALLOWED_FORMS = "x, |x|, x*y, x*|y|, |x|*y (x, y signal names; y may equal x)"

_NAME = r"[A-Za-z_][A-Za-z0-9_]*"
_FACTOR = rf"(?:\|\s*(?P<{{g}}abs>{_NAME})\s*\||(?P<{{g}}>{_NAME}))"
_TERM_RE = re.compile(
    r"^\s*" + _FACTOR.format(g="a") + r"\s*(?:\*\s*" + _FACTOR.format(g="b") + r"\s*)?$"
)


@dataclass(frozen=True)
class Term:
    """One regressor of Definition 2.1.

    Parameters
    ----------
    left : str
        Name of the first signal.
    left_abs : bool
        Take the modulus of the first factor.
    right : str or None
        Name of the second signal for product terms, ``None`` for first-order terms.
    right_abs : bool
        Take the modulus of the second factor.
    """

    left: str
    left_abs: bool = False
    right: str | None = None
    right_abs: bool = False

    def __post_init__(self) -> None:
        if self.right is None and self.right_abs:
            raise ModelSpecError("a first-order term cannot have a modulus on a missing factor")
        if self.left_abs and self.right_abs:
            raise ModelSpecError(
                f"term {self!s} (|x|*|y|) is not a second-order modulus term; "
                f"allowed forms: {ALLOWED_FORMS}"
            )

    @classmethod
    def parse(cls, text: str) -> Term:
        """Parse a term such as ``"u*|u|"``.

        Raises
        ------
        ModelSpecError
            If the text is not one of the allowed forms; the message names the term.
        """
        if isinstance(text, Term):
            return text
        if not isinstance(text, str):
            raise ModelSpecError(f"term {text!r} must be a string; allowed forms: {ALLOWED_FORMS}")
        match = _TERM_RE.match(text)
        if match is None:
            raise ModelSpecError(f"invalid term {text!r}; allowed forms: {ALLOWED_FORMS}")
        left = match.group("aabs") or match.group("a")
        left_abs = match.group("aabs") is not None
        right = match.group("babs") or match.group("b")
        right_abs = match.group("babs") is not None
        if left_abs and right_abs:
            raise ModelSpecError(
                f"invalid term {text!r}: |x|*|y| is not a second-order modulus term; "
                f"allowed forms: {ALLOWED_FORMS}"
            )
        return cls(left, left_abs, right, right_abs)

    @property
    def signals(self) -> tuple[str, ...]:
        """Names of the signals the term uses."""
        return (self.left,) if self.right is None else (self.left, self.right)

    @property
    def order(self) -> int:
        """Polynomial order of the term (1 or 2)."""
        return 1 if self.right is None else 2

    def __str__(self) -> str:
        left = f"|{self.left}|" if self.left_abs else self.left
        if self.right is None:
            return left
        right = f"|{self.right}|" if self.right_abs else self.right
        return f"{left}*{right}"

    def evaluate(self, values: dict[str, np.ndarray]) -> np.ndarray:
        """Evaluate the term on named signal arrays (vectorised)."""
        a = np.asarray(values[self.left], dtype=float)
        if self.left_abs:
            a = np.abs(a)
        if self.right is None:
            return a
        b = np.asarray(values[self.right], dtype=float)
        if self.right_abs:
            b = np.abs(b)
        return a * b


@dataclass(frozen=True)
class TermCodes:
    """Integer encoding of a list of terms over an ordered signal vector.

    ``codes[p] = (left_index, left_abs, right_index or -1, right_abs)`` and
    ``equation[p]`` is the state equation the ``p``-th parameter belongs to.
    """

    codes: np.ndarray
    equation: np.ndarray

    @property
    def n_params(self) -> int:
        return int(self.codes.shape[0])

    @property
    def factors(self) -> np.ndarray:
        """Branch-free form: term ``p`` is ``F[f[p, 0]] * F[f[p, 1]]`` with
        ``F = [s, |s|, 1]`` (length ``2 S + 1``) filled by :func:`fill_factors`."""
        return factor_codes(self.codes, self.n_signals)

    n_signals: int = 0


def encode_terms(
    terms_per_equation: Sequence[Sequence[Term]], signal_names: Sequence[str]
) -> TermCodes:
    """Encode per-equation term lists against an ordered list of signal names."""
    index = {name: i for i, name in enumerate(signal_names)}
    rows: list[tuple[int, int, int, int]] = []
    equation: list[int] = []
    for eq, terms in enumerate(terms_per_equation):
        for term in terms:
            for name in term.signals:
                if name not in index:
                    raise ModelSpecError(
                        f"term {term} uses unknown signal {name!r}; known: {list(signal_names)}"
                    )
            right = -1 if term.right is None else index[term.right]
            rows.append((index[term.left], int(term.left_abs), right, int(term.right_abs)))
            equation.append(eq)
    codes = np.asarray(rows, dtype=np.int64).reshape(-1, 4)
    return TermCodes(codes=codes, equation=np.asarray(equation, dtype=np.int64),
                     n_signals=len(signal_names))


def factor_codes(codes: np.ndarray, n_signals: int) -> np.ndarray:
    """Convert ``(P, 4)`` term codes to ``(P, 2)`` indices into ``F = [s, |s|, 1]``."""
    one = 2 * n_signals
    left = codes[:, 0] + n_signals * codes[:, 1]
    right = np.where(codes[:, 2] >= 0, codes[:, 2] + n_signals * codes[:, 3], one)
    return np.ascontiguousarray(np.column_stack([left, right]).astype(np.int64))


@njit(cache=True, inline="always")
def fill_factors(s: np.ndarray, f: np.ndarray) -> None:
    """Fill ``f = [s, |s|, 1]`` (``len(f) == 2 len(s) + 1``) for factor-coded terms."""
    n_s = s.shape[0]
    for i in range(n_s):
        f[i] = s[i]
        f[n_s + i] = abs(s[i])
    f[2 * n_s] = 1.0


@njit(cache=True, inline="always")
def term_value(codes: np.ndarray, p: int, s: np.ndarray) -> float:
    """Value of encoded term ``p`` at the signal vector ``s`` (compiled)."""
    a = s[codes[p, 0]]
    a = abs(a) if codes[p, 1] == 1 else a
    j = codes[p, 2]
    b = s[j] if j >= 0 else 1.0
    b = abs(b) if codes[p, 3] == 1 else b
    return a * b


def evaluate_terms(codes: np.ndarray, signals: np.ndarray) -> np.ndarray:
    """Evaluate encoded terms on an array of signal vectors (vectorised numpy).

    Parameters
    ----------
    codes : ndarray, shape (P, 4)
        Encoded terms from :func:`encode_terms`.
    signals : ndarray, shape (..., S)
        Signal vectors, last axis ordered as at encoding.

    Returns
    -------
    ndarray, shape (..., P)
        The regressor values Φ.
    """
    signals = np.asarray(signals, dtype=float)
    left = signals[..., codes[:, 0]]
    left = np.where(codes[:, 1] == 1, np.abs(left), left)
    has_right = codes[:, 2] >= 0
    right = signals[..., np.where(has_right, codes[:, 2], 0)]
    right = np.where(codes[:, 3] == 1, np.abs(right), right)
    return np.where(has_right, left * right, left)
