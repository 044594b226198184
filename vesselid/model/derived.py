"""Derived signals: model states and inputs computed from measured columns (``[derived]``).

Manoeuvring practice writes rudder and propeller forces with more than two factors
(``u²δ``, ``U²δ = (u² + v²)δ``, ``u²δ²``) and expands the surge equation about the
approach speed (``Δu = u − U₀``, Abkowitz). The regressors of Definition 2.1 have at most
two factors, so a spec names such signals in its ``[derived]`` table and uses them like
any other state or input::

    states = ["du", "v", "r"]
    inputs = ["delta", "uud"]

    [derived]
    du = "u - 1.177"          # a derived state: affine in one measured column
    uud = "u*u*delta"         # a derived input: a polynomial of measured columns

An expression is a polynomial with modulus factors: sums and differences of products of
numbers, column names, ``|name|`` and integer powers ``name**k`` (e.g.
``"(u**2 + v**2)*delta"``, ``"u*|u|*delta"``). It refers to *measured* columns of the log
(never to another derived name). A derived **state** must be affine in one column
(``a*col + c``); its column is recovered from the simulated state when a model is
simulated (:mod:`vesselid.validation.report`). A derived **input** is recomputed at every step of
a simulation from the simulated states (and the measured inputs).

What this does to the consistency results
-----------------------------------------
* A derived state ``a·y + c`` of a measured state ``y = x + e`` is the affine image of
  the measurement, with sensor noise ``a·e``: Definition 2.1 and every result of the paper
  hold for it unchanged (the terms are second-order modulus terms of that state).
* A derived input built only from exogenous inputs (``δ|δ|``, ``n|n|·δ``) is itself
  exogenous: the theory holds unchanged.
* A derived input that uses a **measured state** (``u²δ``) is *not* exogenous: it carries
  that state's sensor noise ``e(k)``, which also enters the equation error of sample ``k``
  through the other regressors and, for the state itself, the target. The estimators
  treat every input column as exogenous, so for such a column LS has the usual
  errors-in-variables bias, and the instrumental-variable estimators use the measured
  column itself as its own instrument — an instrument correlated with the equation error.
  The IV consistency results of the paper therefore do **not** cover the parameters of
  state-dependent derived inputs (nor, through the joint solution, exactly the other
  parameters of that equation). The bias is of the order of the noise-to-signal power of
  the state in the product (``σ_e² / E[u²]`` for ``u²δ``), small in tank and sea trials
  with a good speed sensor. To stay inside the theory, write the state dependence with
  Definition 2.1 terms (``u·δ``, ``Δu·δ`` with a derived state ``Δu``) and keep derived
  inputs to functions of the inputs; :meth:`DerivedSignal.uses` and
  :func:`state_dependent` say which derived inputs use states, and ``identify`` warns
  (:class:`~vesselid.errors.DerivedInputWarning`) when a spec has one.
"""

from __future__ import annotations

import ast
import math
import re
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from vesselid.errors import ModelSpecError

__all__ = ["DerivedSignal", "Monomial", "add_derived", "state_dependent"]

_ABS_RE = re.compile(r"\|\s*([A-Za-z_][A-Za-z0-9_]*)\s*\|")
#: A factor: (column name, modulus).
Factor = tuple[str, bool]
#: A monomial: sorted factors -> coefficient.
Monomial = tuple[Factor, ...]
_MAX_DEGREE = 6


def _poly_mul(a: dict[Monomial, float], b: dict[Monomial, float]) -> dict[Monomial, float]:
    out: dict[Monomial, float] = {}
    for ma, ca in a.items():
        for mb, cb in b.items():
            m = tuple(sorted(ma + mb))
            out[m] = out.get(m, 0.0) + ca * cb
    return out


def _poly_add(a: dict[Monomial, float], b: dict[Monomial, float], sign: float = 1.0):
    out = dict(a)
    for m, c in b.items():
        out[m] = out.get(m, 0.0) + sign * c
    return out


def _expand(node: ast.AST, text: str) -> dict[Monomial, float]:
    if isinstance(node, ast.Expression):
        return _expand(node.body, text)
    if isinstance(node, ast.Constant) and isinstance(node.value, int | float) \
            and not isinstance(node.value, bool):
        return {(): float(node.value)}
    if isinstance(node, ast.Name):
        return {((node.id, False),): 1.0}
    if (isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id == "abs"
            and len(node.args) == 1 and not node.keywords and isinstance(node.args[0], ast.Name)):
        return {((node.args[0].id, True),): 1.0}
    if isinstance(node, ast.UnaryOp) and isinstance(node.op, ast.USub | ast.UAdd):
        inner = _expand(node.operand, text)
        sign = -1.0 if isinstance(node.op, ast.USub) else 1.0
        return {m: sign * c for m, c in inner.items()}
    if isinstance(node, ast.BinOp):
        if isinstance(node.op, ast.Add | ast.Sub):
            return _poly_add(_expand(node.left, text), _expand(node.right, text),
                             1.0 if isinstance(node.op, ast.Add) else -1.0)
        if isinstance(node.op, ast.Mult):
            return _poly_mul(_expand(node.left, text), _expand(node.right, text))
        if isinstance(node.op, ast.Pow) and isinstance(node.right, ast.Constant) \
                and isinstance(node.right.value, int) and 0 <= node.right.value <= _MAX_DEGREE:
            base = _expand(node.left, text)
            out: dict[Monomial, float] = {(): 1.0}
            for _ in range(node.right.value):
                out = _poly_mul(out, base)
            return out
    raise ModelSpecError(
        f"derived expression {text!r}: only numbers, column names, |name|, +, -, * and "
        f"integer powers name**k are allowed")


@dataclass(frozen=True)
class DerivedSignal:
    """One ``[derived]`` entry: ``name = Σ c_m Π factors`` over measured columns.

    Parameters
    ----------
    name : str
        The state or input it defines.
    expression : str
        The defining text (kept for printing and TOML).
    terms : tuple of (Monomial, float)
        The expanded polynomial (zero coefficients dropped).
    """

    name: str
    expression: str
    terms: tuple[tuple[Monomial, float], ...]

    @classmethod
    def parse(cls, name: str, text: Any) -> DerivedSignal:
        """Parse ``text`` (e.g. ``"u*u*delta"``, ``"u - 1.177"``, ``"(u**2+v**2)*delta"``)."""
        if not isinstance(text, str) or not text.strip():
            raise ModelSpecError(f"[derived] {name}: expected an expression string, got "
                                 f"{text!r}")
        src = _ABS_RE.sub(r"abs(\1)", text)
        if "|" in src:
            raise ModelSpecError(f"[derived] {name}: a modulus |...| may only hold one name: "
                                 f"{text!r}")
        try:
            tree = ast.parse(src, mode="eval")
        except SyntaxError:
            raise ModelSpecError(f"[derived] {name}: cannot parse {text!r}") from None
        poly = _expand(tree, text)
        terms = tuple((m, c) for m, c in sorted(poly.items()) if c != 0.0)
        if not terms:
            raise ModelSpecError(f"[derived] {name}: {text!r} is identically zero")
        if not all(math.isfinite(c) for _, c in terms):
            raise ModelSpecError(f"[derived] {name}: non-finite coefficient in {text!r}")
        if max(len(m) for m, _ in terms) > _MAX_DEGREE:
            raise ModelSpecError(f"[derived] {name}: degree above {_MAX_DEGREE} in {text!r}")
        out = cls(name=name, expression=text.strip(), terms=terms)
        if name in out.uses:
            raise ModelSpecError(f"[derived] {name}: the expression uses {name!r} itself")
        return out

    @property
    def uses(self) -> tuple[str, ...]:
        """Measured columns the expression reads, in first-use order."""
        seen: list[str] = []
        for m, _ in self.terms:
            for col, _abs in m:
                if col not in seen:
                    seen.append(col)
        return tuple(seen)

    def affine(self) -> tuple[str, float, float] | None:
        """``(column, a, c)`` when the expression is ``a·column + c``; else None."""
        col, a, c = None, 0.0, 0.0
        for m, coef in self.terms:
            if m == ():
                c = coef
            elif len(m) == 1 and not m[0][1] and (col is None or col == m[0][0]):
                col, a = m[0][0], a + coef
            else:
                return None
        return (col, a, c) if col is not None and a != 0.0 else None

    def evaluate(self, columns: Mapping[str, np.ndarray]) -> np.ndarray:
        """The derived signal from arrays of the columns it uses (vectorised)."""
        out = None
        for m, coef in self.terms:
            v = np.full(np.shape(columns[self.uses[0]]), coef, dtype=float)
            for col, mod in m:
                x = np.asarray(columns[col], dtype=float)
                v = v * (np.abs(x) if mod else x)
            out = v if out is None else out + v
        return out  # type: ignore[return-value]

    def __str__(self) -> str:
        return f"{self.name} = {self.expression}"


def state_dependent(spec: Any) -> dict[str, tuple[str, ...]]:
    """Derived *inputs* of ``spec`` that use measured states (not exogenous), with the
    state columns each uses (a derived state's source column counts as that state)."""
    state_cols = set(spec.states)
    for name in spec.states:
        d = spec.derived.get(name)
        if d is not None:
            state_cols.update(d.uses)
    out = {}
    for name in spec.inputs:
        d = spec.derived.get(name)
        if d is not None:
            hit = tuple(c for c in d.uses if c in state_cols)
            if hit:
                out[name] = hit
    return out


def add_derived(frame: Any, spec: Any) -> Any:
    """A copy of the DataFrame ``frame`` with the spec's derived columns computed.

    Returns ``frame`` itself when the spec has no ``[derived]`` table. A derived column
    already in the frame is recomputed (the spec's definition wins); a column an
    expression needs that the frame lacks raises
    :class:`~vesselid.errors.LogValidationError` naming it.
    """
    derived = getattr(spec, "derived", None)
    if not derived:
        return frame
    from vesselid.errors import LogValidationError

    cols: dict[str, np.ndarray] = {}
    for d in derived.values():
        for c in d.uses:
            if c not in frame.columns:
                raise LogValidationError(
                    f"missing column {c!r}: the derived signal {d} needs it")
            if c not in cols:
                cols[c] = frame[c].to_numpy(dtype=float)
    out = frame.copy()
    for name, d in derived.items():
        out[name] = d.evaluate(cols)
    return out
