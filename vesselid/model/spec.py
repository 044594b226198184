"""Model structures: states, inputs, per-state term lists, θ0 and aggregate relations.

A :class:`ModelSpec` describes the second-order modulus system (2a)–(2b) of the
paper: for every state ``x_i`` an equation ``x_i(k+1) = φ_iᵀ([x(k)+v(k); u(k)]) θ_i``
with terms from Definition 2.1. It loads from and saves to the TOML contract of
docs/architecture.md::

    name = "heave"
    states = ["w"]
    inputs = ["tau"]
    dt = 1.0

    [equations]
    w = ["w", "w*|w|", "tau"]

    [theta0]
    w = [0.99, -0.1, 1.0]

    [aggregate]
    w = "w - w_c"

The optional ``[aggregate]`` relation (paper §4, §6) says that the regressors of the
predictor use the state combined with a measured disturbance column,
``ỹ = y ± y₂`` (eq. (9)); the target stays the state measurement ``y``.
"""

from __future__ import annotations

import functools
import math
import re
import sys
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import pandas as pd

from vesselid.core.fileio import atomic_write_text
from vesselid.errors import ModelSpecError
from vesselid.model.derived import DerivedSignal
from vesselid.model.terms import Term

if TYPE_CHECKING:  # pragma: no cover
    from vesselid.model.regressors import RegressorLayout

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

__all__ = ["Aggregate", "ModelSpec"]

_NAME_RE = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")
_AGG_RE = re.compile(r"^\s*([A-Za-z_][A-Za-z0-9_]*)\s*([+-])\s*([A-Za-z_][A-Za-z0-9_]*)\s*$")


@dataclass(frozen=True)
class Aggregate:
    """Aggregated-state relation of paper eq. (9) and Remark 4.3.

    ``"w - w_c"`` / ``"w + w_c"``: the regressors use ``r = state ± sensor`` where the
    sensor measures the disturbance (a current meter, ``sign = ±1``). A bare column
    name, ``"u_log"``, says the sensor measures the aggregated state itself (a Doppler
    speed log measures the velocity through water, Remark 4.3): the regressors use
    that column directly (``sign = 0``).

    Parameters
    ----------
    state : str
        The state whose regressors use the aggregated signal.
    sensor : str
        Name of the measured column.
    sign : int
        ``+1``, ``-1``, or ``0`` for a direct measurement of the aggregated state.
    """

    state: str
    sensor: str
    sign: int

    @classmethod
    def parse(cls, state: str, text: str) -> Aggregate:
        if isinstance(text, str) and _NAME_RE.match(text.strip()):
            name = text.strip()
            if name == state:
                raise ModelSpecError(
                    f"aggregate relation for {state!r} cannot be the state itself"
                )
            return cls(state=state, sensor=name, sign=0)
        match = _AGG_RE.match(text) if isinstance(text, str) else None
        if match is None:
            raise ModelSpecError(
                f"aggregate relation for {state!r} must read '{state} + sensor', "
                f"'{state} - sensor' or name a column measuring the aggregated state, "
                f"got {text!r}"
            )
        lhs, op, sensor = match.groups()
        if lhs != state:
            raise ModelSpecError(
                f"aggregate relation for {state!r} must start with the state itself, got {text!r}"
            )
        return cls(state=state, sensor=sensor, sign=1 if op == "+" else -1)

    def __str__(self) -> str:
        if self.sign == 0:
            return self.sensor
        return f"{self.state} {'+' if self.sign > 0 else '-'} {self.sensor}"


def _check_name(kind: str, name: Any) -> str:
    if not isinstance(name, str) or not _NAME_RE.match(name):
        raise ModelSpecError(f"{kind} name {name!r} is not a valid identifier")
    return name


@functools.lru_cache(maxsize=64)
def _param_index(tuples: tuple[tuple[str, str], ...]) -> pd.MultiIndex:
    """The MultiIndex of :attr:`ModelSpec.param_index`, built once per structure
    (``from_tuples`` factorises string labels: ~0.3 ms, and a log's spec is rebuilt
    from its metadata on every fit)."""
    return pd.MultiIndex.from_tuples(list(tuples), names=["equation", "term"])


@dataclass(frozen=True)
class ModelSpec:
    """A second-order modulus model structure (paper eq. (1)–(3)).

    Parameters
    ----------
    name : str
        Model name.
    states : sequence of str
        State names; in trial logs one measured column per state, same name.
    inputs : sequence of str
        Known input names (one column each).
    equations : mapping state -> sequence of terms (str or :class:`Term`)
        The terms of each state equation, Definition 2.1.
    theta0 : mapping state -> sequence of float, optional
        True parameter values, same order as the terms.
    aggregate : mapping state -> str or :class:`Aggregate`, optional
        Aggregated-state relations (``"w - w_c"``).
    dt : float, optional
        Sample time in seconds.
    derived : mapping name -> str or :class:`~vesselid.model.derived.DerivedSignal`, optional
        States and inputs computed from measured columns (``du = "u - 1.177"``,
        ``uud = "u*u*delta"``); see :mod:`vesselid.model.derived` for the grammar and what
        they do to the consistency results.

    Raises
    ------
    ModelSpecError
        Unknown signal, empty equation, duplicate term, θ0 length mismatch, ...
    """

    name: str
    states: tuple[str, ...]
    inputs: tuple[str, ...]
    equations: Mapping[str, tuple[Term, ...]]
    theta0: Mapping[str, tuple[float, ...]] | None = None
    aggregate: Mapping[str, Aggregate] = field(default_factory=dict)
    dt: float | None = None
    derived: Mapping[str, DerivedSignal] = field(default_factory=dict)

    def __init__(
        self,
        name: str,
        states: Sequence[str],
        inputs: Sequence[str],
        equations: Mapping[str, Sequence[str | Term]],
        theta0: Mapping[str, Sequence[float]] | None = None,
        aggregate: Mapping[str, str | Aggregate] | None = None,
        dt: float | None = None,
        derived: Mapping[str, str | DerivedSignal] | None = None,
    ) -> None:
        for label, names_ in (("states", states), ("inputs", inputs)):
            if isinstance(names_, (str, Mapping)) or not isinstance(names_, Sequence):
                raise ModelSpecError(f"{label}: expected a list of names, got {_kind(names_)}")
        states_t = tuple(_check_name("state", s) for s in states)
        inputs_t = tuple(_check_name("input", u) for u in inputs)
        if not states_t:
            raise ModelSpecError("a model needs at least one state")
        names = states_t + inputs_t
        dupes = sorted({n for n in names if names.count(n) > 1})
        if dupes:
            raise ModelSpecError(f"signal names must be unique across states and inputs: {dupes}")
        if not isinstance(equations, Mapping):
            raise ModelSpecError(
                f"equations: expected a table mapping each state to a list of terms, got "
                f"{_kind(equations)}")
        unknown_eq = sorted(set(equations) - set(states_t))
        if unknown_eq:
            raise ModelSpecError(f"equations given for unknown states {unknown_eq}")
        eqs: dict[str, tuple[Term, ...]] = {}
        for state in states_t:
            if state not in equations:
                raise ModelSpecError(f"no equation for state {state!r}")
            raw = equations[state]
            if isinstance(raw, (str, Mapping)) or not isinstance(raw, Sequence):
                raise ModelSpecError(
                    f"[equations] {state}: expected a list of terms, got {_kind(raw)}")
            terms = tuple(Term.parse(t) for t in raw)
            if not terms:
                raise ModelSpecError(f"equation of {state!r} is empty")
            seen: dict[str, str] = {}
            for term in terms:
                for sig in term.signals:
                    if sig not in names:
                        raise ModelSpecError(
                            f"term {term} in equation {state!r} uses unknown signal {sig!r}; "
                            f"states {list(states_t)}, inputs {list(inputs_t)}"
                        )
                key = _canonical(term)
                if key in seen:
                    raise ModelSpecError(
                        f"duplicate term in equation {state!r}: {seen[key]} and {term}"
                    )
                seen[key] = str(term)
            eqs[state] = terms
        th: dict[str, tuple[float, ...]] | None = None
        if theta0 is not None:
            if not isinstance(theta0, Mapping):
                raise ModelSpecError(f"theta0: expected a table, got {_kind(theta0)}")
            th = {}
            unknown_th = sorted(set(theta0) - set(states_t))
            if unknown_th:
                raise ModelSpecError(f"theta0 given for unknown states {unknown_th}")
            for state in states_t:
                if state not in theta0:
                    raise ModelSpecError(f"theta0 has no values for state {state!r}")
                raw_th = theta0[state]
                if isinstance(raw_th, (str, Mapping)) or not isinstance(raw_th, Sequence):
                    if not isinstance(raw_th, np.ndarray):
                        raise ModelSpecError(
                            f"[theta0] {state}: expected a list of numbers, got {_kind(raw_th)}")
                for i, x in enumerate(raw_th):
                    if isinstance(x, (str, bytes, bool)) or not isinstance(x, (int, float,
                                                                                np.number)):
                        raise ModelSpecError(
                            f"[theta0] {state}[{i}]: expected a number, got {_kind(x)}")
                values = tuple(float(x) for x in raw_th)
                if len(values) != len(eqs[state]):
                    raise ModelSpecError(
                        f"theta0 of {state!r} has {len(values)} values but the equation has "
                        f"{len(eqs[state])} terms"
                    )
                if not all(math.isfinite(x) for x in values):
                    raise ModelSpecError(f"theta0 of {state!r} holds non-finite values")
                th[state] = values
        agg: dict[str, Aggregate] = {}
        if aggregate is not None and not isinstance(aggregate, Mapping):
            raise ModelSpecError(f"aggregate: expected a table, got {_kind(aggregate)}")
        for state, rel in (aggregate or {}).items():
            if state not in states_t:
                raise ModelSpecError(f"aggregate relation given for unknown state {state!r}")
            a = rel if isinstance(rel, Aggregate) else Aggregate.parse(state, rel)
            if a.state != state:
                raise ModelSpecError(f"aggregate relation {a} filed under state {state!r}")
            if a.sensor in names:
                raise ModelSpecError(
                    f"aggregate sensor column {a.sensor!r} must differ from state/input names"
                )
            agg[state] = a
        if dt is not None:
            if isinstance(dt, (str, bytes, bool)) or not isinstance(dt, (int, float, np.number)):
                raise ModelSpecError(f"dt: expected a number of seconds, got {_kind(dt)}")
            dt = float(dt)
            if not (math.isfinite(dt) and dt > 0):
                raise ModelSpecError(f"dt must be a positive number, got {dt}")
        der: dict[str, DerivedSignal] = {}
        if derived is not None and not isinstance(derived, Mapping):
            raise ModelSpecError(f"derived: expected a table, got {_kind(derived)}")
        for dname, expr in (derived or {}).items():
            d = expr if isinstance(expr, DerivedSignal) else DerivedSignal.parse(dname, expr)
            if dname not in names:
                raise ModelSpecError(
                    f"[derived] {dname} is neither a state nor an input of the spec; list it "
                    f"in states or inputs")
            der[dname] = d
        for dname, d in der.items():
            inner = sorted(set(d.uses) & set(der))
            if inner:
                raise ModelSpecError(f"[derived] {dname}: uses derived signal(s) {inner}; "
                                     f"write it over measured columns")
            if dname in states_t and d.affine() is None:
                raise ModelSpecError(
                    f"[derived] {dname} is a state, so it must be affine in one measured "
                    f"column (a*col + c), got {d.expression!r}")
            if dname in states_t and d.affine()[0] in names:  # type: ignore[index]
                raise ModelSpecError(
                    f"[derived] state {dname} is defined from {d.affine()[0]!r}, which is "
                    f"itself a signal of the spec")
        object.__setattr__(self, "name", str(name))
        object.__setattr__(self, "states", states_t)
        object.__setattr__(self, "inputs", inputs_t)
        object.__setattr__(self, "equations", eqs)
        object.__setattr__(self, "theta0", th)
        object.__setattr__(self, "aggregate", agg)
        object.__setattr__(self, "dt", dt)
        object.__setattr__(self, "derived", der)

    # ------------------------------------------------------------------ derived
    @property
    def signals(self) -> tuple[str, ...]:
        """Ordered signal vector ``[states..., inputs...]`` the terms are encoded against."""
        return self.states + self.inputs

    @property
    def n_states(self) -> int:
        return len(self.states)

    @property
    def n_inputs(self) -> int:
        return len(self.inputs)

    @cached_property
    def codes(self) -> RegressorLayout:
        """Factor layout of all terms over :attr:`signals` (see :mod:`vesselid.model.regressors`).

        Imports the compiled kernel module on first use (parsing a spec does not).
        """
        from vesselid.model.regressors import encode_terms

        return encode_terms([self.equations[s] for s in self.states], self.signals)

    @property
    def n_params(self) -> int:
        return sum(len(t) for t in self.equations.values())

    @cached_property
    def param_index(self) -> pd.MultiIndex:
        """``(equation, term)`` labels of the stacked parameter vector θ."""
        tuples = tuple((s, str(t)) for s in self.states for t in self.equations[s])
        return _param_index(tuples).copy()  # a copy: its names may be set in place

    @property
    def measured_columns(self) -> tuple[str, ...]:
        """Log columns a trial log needs for this spec: states, inputs and sensors, with
        every derived signal replaced by the measured columns it is computed from."""
        out: list[str] = []
        for name in (*self.states, *self.inputs, *self.sensors):
            for c in (self.derived[name].uses if name in self.derived else (name,)):
                if c not in out:
                    out.append(c)
        return tuple(out)

    @property
    def sensors(self) -> tuple[str, ...]:
        """Measured disturbance columns the aggregate relations need."""
        return tuple(self.aggregate[s].sensor for s in self.states if s in self.aggregate)

    def theta0_vector(self) -> np.ndarray:
        """θ0 stacked in :attr:`param_index` order.

        Raises
        ------
        ModelSpecError
            If the spec has no θ0.
        """
        if self.theta0 is None:
            raise ModelSpecError(f"model {self.name!r} has no theta0")
        return np.concatenate([np.asarray(self.theta0[s], dtype=float) for s in self.states])

    def theta0_series(self) -> pd.Series:
        """θ0 as a labelled Series indexed by ``(equation, term)``."""
        return pd.Series(self.theta0_vector(), index=self.param_index, name="theta0")

    def vector_from(self, values: Mapping[str, Sequence[float]] | pd.Series | np.ndarray):
        """Stack parameters given per equation (or as a Series/array) into θ order."""
        if isinstance(values, pd.Series):
            return values.reindex(self.param_index).to_numpy(dtype=float)
        if isinstance(values, np.ndarray):
            arr = np.asarray(values, dtype=float)
            if arr.shape != (self.n_params,):
                raise ModelSpecError(f"expected {self.n_params} parameters, got {arr.shape}")
            return arr
        return ModelSpec(
            self.name, self.states, self.inputs, self.equations, theta0=values
        ).theta0_vector()

    def with_theta0(self, theta: Mapping[str, Sequence[float]] | pd.Series | np.ndarray):
        """A copy with new θ0 values."""
        vec = self.vector_from(theta)
        per_state, start = {}, 0
        for s in self.states:
            n = len(self.equations[s])
            per_state[s] = vec[start : start + n].tolist()
            start += n
        return ModelSpec(
            self.name, self.states, self.inputs, self.equations, per_state, self.aggregate, self.dt,
            self.derived,
        )

    def merge_terms(self, keep: str, drop: str, factor: float) -> ModelSpec:
        """Fold term ``drop`` into ``keep`` (``drop = factor · keep`` on the data).

        For data where two regressors are proportional — e.g. ``v·|r| = −r·|v|``
        whenever ``v`` and ``r`` have opposite signs, as in every steady turn of a
        ship — only their combination is identifiable. In each equation holding
        both, ``drop`` is removed and θ0 of ``keep`` becomes
        ``θ_keep + factor · θ_drop`` (exact on data satisfying the relation).
        """
        k, d = Term.parse(keep), Term.parse(drop)
        equations, theta = {}, {} if self.theta0 is not None else None
        for s in self.states:
            terms = list(self.equations[s])
            keys = [_canonical(t) for t in terms]
            values = list(self.theta0[s]) if self.theta0 is not None else None
            if _canonical(k) in keys and _canonical(d) in keys:
                ik, idrop = keys.index(_canonical(k)), keys.index(_canonical(d))
                if values is not None:
                    values[ik] += factor * values[idrop]
                    del values[idrop]
                del terms[idrop]
            equations[s] = terms
            if theta is not None:
                theta[s] = values
        return ModelSpec(self.name, self.states, self.inputs, equations, theta, self.aggregate,
                         self.dt, self.derived)

    def with_aggregate(self, aggregate: Mapping[str, str | Aggregate] | None) -> ModelSpec:
        """A copy with other aggregate relations (``None`` or ``{}`` removes them)."""
        return ModelSpec(
            self.name, self.states, self.inputs, self.equations, self.theta0, aggregate, self.dt,
            self.derived,
        )

    # ---------------------------------------------------------------------- I/O
    def to_dict(self) -> dict[str, Any]:
        """Plain-data form matching the TOML contract."""
        out: dict[str, Any] = {
            "name": self.name,
            "states": list(self.states),
            "inputs": list(self.inputs),
        }
        if self.dt is not None:
            out["dt"] = self.dt
        out["equations"] = {s: [str(t) for t in self.equations[s]] for s in self.states}
        if self.theta0 is not None:
            out["theta0"] = {s: list(self.theta0[s]) for s in self.states}
        if self.aggregate:
            out["aggregate"] = {s: str(a) for s, a in self.aggregate.items()}
        if self.derived:
            out["derived"] = {n: d.expression for n, d in self.derived.items()}
        return out

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> ModelSpec:
        """Build from the plain-data form (as read from TOML or JSON).

        The type of every table and entry is checked; a message names the key, e.g.
        ``[theta0] w: expected a list of numbers, got a number (0.99)``.
        """
        if not isinstance(data, Mapping):
            raise ModelSpecError(f"a model spec must be a table/mapping, got {_kind(data)}")
        allowed = {"name", "states", "inputs", "dt", "equations", "theta0", "aggregate",
                   "derived"}
        # "estimate": uncertainty of an exported identified model (vesselid.model.export)
        unknown = sorted(map(str, set(data) - allowed - {"estimate"}))
        if unknown:
            raise ModelSpecError(f"unknown model spec keys {unknown}; allowed {sorted(allowed)}")
        for key in ("states", "equations"):
            if key not in data:
                raise ModelSpecError(f"model spec is missing {key!r}")
        _expect(data.get("name", "model"), str, "name", "a string")
        for key in ("states", "inputs"):
            value = data.get(key, [])
            _expect(value, list, key, "a list of names")
            for i, item in enumerate(value):
                _expect(item, str, f"{key}[{i}]", "a name (string)")
        dt = data.get("dt")
        if dt is not None:
            _expect_number(dt, "dt")
        for table in ("equations", "theta0", "aggregate", "derived"):
            value = data.get(table)
            if value is None and table != "equations":
                continue
            _expect(value, Mapping, table, f"a table [{table}]")
            for key, entry in value.items():
                where = f"[{table}] {key}"
                if table == "equations":
                    _expect(entry, list, where, "a list of terms")
                    for i, term in enumerate(entry):
                        _expect(term, str, f"{where}[{i}]", "a term (string)")
                elif table == "theta0":
                    _expect(entry, list, where, "a list of numbers")
                    for i, x in enumerate(entry):
                        _expect_number(x, f"{where}[{i}]")
                elif table == "aggregate":
                    _expect(entry, str, where, "a relation such as 'w - w_c'")
                else:
                    _expect(entry, str, where, "an expression such as 'u*u*delta'")
        return cls(
            name=data.get("name", "model"),
            states=data["states"],
            inputs=data.get("inputs", []),
            equations=data["equations"],
            theta0=data.get("theta0"),
            aggregate=data.get("aggregate"),
            dt=data.get("dt"),
            derived=data.get("derived"),
        )

    def to_toml(self) -> str:
        """TOML text of the spec (docs/architecture.md contract)."""
        import tomli_w

        return tomli_w.dumps(self.to_dict())

    @classmethod
    def from_toml(cls, text: str) -> ModelSpec:
        """Parse TOML text."""
        try:
            data = tomllib.loads(text)
        except tomllib.TOMLDecodeError as exc:
            raise ModelSpecError(f"invalid TOML: {exc}") from exc
        return cls.from_dict(data)

    @classmethod
    def load(cls, path: str | Path) -> ModelSpec:
        """Read a TOML spec file.

        Raises
        ------
        ModelSpecError
            Missing file, not UTF-8 text, invalid TOML or an invalid spec (the message
            starts with the path).
        OSError
            The file cannot be read (permissions, a directory, ...).
        """
        path = Path(path)
        if path.is_dir():
            raise IsADirectoryError(21, "model spec path is a directory", str(path))
        if not path.exists():
            raise ModelSpecError(f"model spec file {str(path)!r} does not exist")
        raw = path.read_bytes()
        try:
            text = raw.decode("utf-8")
        except UnicodeDecodeError as exc:
            raise ModelSpecError(f"{path}: not a TOML text file (not UTF-8 at byte "
                                 f"{exc.start})") from exc
        try:
            return cls.from_toml(text)
        except ModelSpecError as exc:
            raise ModelSpecError(f"{path}: {exc}") from exc

    def save(self, path: str | Path) -> Path:
        """Write the spec as TOML, atomically."""
        atomic_write_text(path, self.to_toml())
        return Path(path)

    def __str__(self) -> str:
        lines = [f"ModelSpec {self.name!r}: states {list(self.states)}, inputs {list(self.inputs)}"]
        for s in self.states:
            terms = ", ".join(str(t) for t in self.equations[s])
            agg = f"   (regressors use {self.aggregate[s]})" if s in self.aggregate else ""
            lines.append(f"  {s}(k+1) = [{terms}] θ_{s}{agg}")
        for d in self.derived.values():
            lines.append(f"  derived: {d}")
        return "\n".join(lines)


def _kind(value: Any) -> str:
    """TOML-flavoured name of a value's type, with the value when short."""
    if isinstance(value, bool):
        kind = "a boolean"
    elif isinstance(value, (int, float)):
        kind = "a number"
    elif isinstance(value, str):
        kind = "a string"
    elif isinstance(value, Mapping):
        kind = "a table"
    elif isinstance(value, (list, tuple)):
        kind = "a list"
    else:
        kind = type(value).__name__
    text = repr(value)
    return f"{kind} ({text})" if len(text) <= 40 else kind


def _expect(value: Any, types: Any, where: str, what: str) -> None:
    if not isinstance(value, types) or (isinstance(value, bool) and types is not bool):
        raise ModelSpecError(f"{where}: expected {what}, got {_kind(value)}")


def _expect_number(value: Any, where: str) -> None:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ModelSpecError(f"{where}: expected a number, got {_kind(value)}")
    if not math.isfinite(value):
        raise ModelSpecError(f"{where}: expected a finite number, got {value!r}")


def _canonical(term: Term) -> str:
    """Key under which commuting products are equal (``u*r`` == ``r*u``)."""
    if term.right is None:
        return str(term)
    a = f"|{term.left}|" if term.left_abs else term.left
    b = f"|{term.right}|" if term.right_abs else term.right
    return "*".join(sorted((a, b)))
