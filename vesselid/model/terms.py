"""Second-order modulus terms (paper Definition 2.1).

A second-order modulus function is ``f(x, θ) = Φᵀ(x) θ`` where every regressor is
one of ``x_i``, ``|x_i|``, ``x_i x_j`` or ``x_i |x_j|`` over the signals ``x``
(states and inputs). This module parses such terms from text (``"u"``, ``"|u|"``,
``"u*r"``, ``"u*|u|"``, ``"|r|*v"``) and prints them back; it is plain Python (no
numba). Their encoding over a signal vector and every evaluation — vectorised,
compiled, generated — belong to :mod:`vesselid.model.regressors`.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

from vesselid.errors import ModelSpecError

__all__ = ["ALLOWED_FORMS", "Term"]

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
