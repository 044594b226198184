"""A vessel as data: the generic 3-DOF (surge, sway, yaw) second-order modulus hull.

A :class:`Hull` holds what distinguishes one vessel from another — the mass matrix
``M = M_RB + M_A``, the *force table* ``F`` with ``τ − C(ν_r)ν_r − D(ν_r)ν_r = F φ(ν_r, τ)``
over a basis of second-order modulus terms ``φ`` (Definition 2.1), optional cubic
damping outside that class, dimensions and actuator limits. Everything else (the
discrete-time model, the compiled kernel, disturbances, sensors, environments) is shared:
a vessel data module (e.g. :mod:`vesselid.plant.vessels.cybership2`) builds a ``Hull`` and a
catalogue entry, nothing more.

Explicit Euler at ``dt`` gives ``ν_r(k+1) = (E + dt M⁻¹ F) φ(ν_r(k), τ(k))`` where ``E``
picks each state's own linear term, so the θ0 of the identification spec is
``Θ = E + dt M⁻¹ F`` (:meth:`Hull.spec`); terms with an exactly zero coefficient are
dropped.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from vesselid.errors import VesselidError
from vesselid.model.spec import ModelSpec
from vesselid.plant.vessels.wind import BLENDERMANN94, BlendermannWind

__all__ = ["DOFS", "INPUTS", "Hull", "block_inverse"]

#: States (body-frame velocities) and inputs (generalised forces) of every hull.
DOFS = ("u", "v", "r")
INPUTS = ("X", "Y", "N")


def block_inverse(m: np.ndarray) -> np.ndarray:
    """``M⁻¹`` of a 3×3 mass matrix with decoupled surge, by blocks (structural zeros stay
    exactly zero); a general inverse otherwise."""
    m = np.asarray(m, dtype=float)
    if np.any(m[0, 1:] != 0.0) or np.any(m[1:, 0] != 0.0):
        return np.linalg.inv(m)
    out = np.zeros((3, 3))
    out[0, 0] = 1.0 / m[0, 0]
    a, b, c, d = m[1, 1], m[1, 2], m[2, 1], m[2, 2]
    det = a * d - b * c
    out[1:, 1:] = np.array([[d, -b], [-c, a]]) / det
    return out


@dataclass(frozen=True)
class Hull:
    """Data of one surface vessel (3 DOF).

    Parameters
    ----------
    name : str
        Catalogue name (also the spec name).
    mass_matrix : ndarray (3, 3)
        ``M = M_RB + M_A``, positive definite.
    basis : sequence of str
        Terms ``φ`` over the signals ``u, v, r, X, Y, N`` (Definition 2.1 syntax).
    force_table : ndarray (3, len(basis))
        ``F`` with ``τ − C(ν)ν − D(ν)ν = F φ(ν, τ)`` (rows surge, sway, yaw).
    equation_order : mapping state -> sequence of str
        Order of the terms in each equation of the spec (a subset of ``basis``).
    cubic : (float, float, float)
        Cubic damping ``X_uuu, Y_vvv, N_rrr`` (not second-order modulus; simulated only
        with ``cubic_damping=True`` and then absent from the identification spec).
    length, beam : float
        Dimensions (m), for rendering.
    force_max : (float, float, float)
        Actuator limits ``|X|, |Y|, |N|`` (N, N, N m): the environment's action scale and
        the bound a sea-trial design must respect.
    velocity_limit : float
        Speed (m/s) beyond which a simulated velocity counts as diverged in the
        environments (their default).
    wind : BlendermannWind
        Default wind-load model.
    description : str
        One line with the source of the data.
    parameters : mapping
        The published coefficients the hull was built from (log metadata).
    """

    name: str
    mass_matrix: np.ndarray
    basis: tuple[str, ...]
    force_table: np.ndarray
    equation_order: Mapping[str, tuple[str, ...]]
    cubic: tuple[float, float, float] = (0.0, 0.0, 0.0)
    length: float = 1.0
    beam: float = 0.3
    force_max: tuple[float, float, float] = (1.0, 1.0, 1.0)
    velocity_limit: float = 5.0
    wind: BlendermannWind = field(default_factory=lambda: BLENDERMANN94)
    description: str = ""
    parameters: Mapping[str, float] = field(default_factory=dict)

    def __post_init__(self) -> None:
        mm = np.asarray(self.mass_matrix, dtype=float)
        if mm.shape != (3, 3) or not np.all(np.isfinite(mm)):
            raise VesselidError(f"hull {self.name!r}: mass matrix must be a finite 3×3 array")
        if np.any(np.linalg.eigvalsh(0.5 * (mm + mm.T)) <= 0):
            raise VesselidError("the mass matrix M = M_RB + M_A must be positive definite")
        ft = np.asarray(self.force_table, dtype=float)
        if ft.shape != (3, len(self.basis)) or not np.all(np.isfinite(ft)):
            raise VesselidError(f"hull {self.name!r}: force table must be finite, "
                                f"shape (3, {len(self.basis)})")
        if min(self.force_max) <= 0:
            raise VesselidError(f"hull {self.name!r}: force_max must be positive")

    def mass_matrix_inverse(self) -> np.ndarray:
        """``M⁻¹`` (:func:`block_inverse`)."""
        return block_inverse(self.mass_matrix)

    def theta_matrix(self, dt: float) -> np.ndarray:
        """``Θ = E + dt M⁻¹ F`` over :attr:`basis` (3 × len(basis))."""
        theta = dt * self.mass_matrix_inverse() @ np.asarray(self.force_table, dtype=float)
        col = {name: i for i, name in enumerate(self.basis)}
        for i, s in enumerate(DOFS):
            theta[i, col[s]] += 1.0
        return theta

    def spec(self, dt: float, *, aggregate: Mapping[str, str] | None = None) -> ModelSpec:
        """Discrete-time second-order modulus model (explicit Euler at ``dt``).

        Returns
        -------
        ModelSpec
            States ``u, v, r``, inputs ``X, Y, N``, θ0 = the non-zero entries of
            :meth:`theta_matrix` in :attr:`equation_order`.
        """
        dt = float(dt)
        if not (math.isfinite(dt) and dt > 0):
            raise VesselidError(f"dt must be a positive number, got {dt}")
        theta = self.theta_matrix(dt)
        col = {name: i for i, name in enumerate(self.basis)}
        equations: dict[str, list[str]] = {}
        theta0: dict[str, list[float]] = {}
        for i, s in enumerate(DOFS):
            order = self.equation_order[s]
            extra = [t for t in self.basis if theta[i, col[t]] != 0.0 and t not in order]
            if extra:
                raise VesselidError(f"hull {self.name!r}: terms {extra} of equation {s} are "
                                    "missing from its equation order")
            terms = [t for t in order if theta[i, col[t]] != 0.0]
            equations[s] = terms
            theta0[s] = [float(theta[i, col[t]]) for t in terms]
        return ModelSpec(name=self.name, states=list(DOFS), inputs=list(INPUTS),
                         equations=equations, theta0=theta0, aggregate=aggregate, dt=dt)

    @classmethod
    def from_table(
        cls,
        name: str,
        mass_matrix: np.ndarray,
        table: Mapping[str, Mapping[str, float]],
        **options,
    ) -> Hull:
        """Build a hull from ``{state: {term: coefficient}}`` of ``F φ`` (basis and term
        order in the order the table lists them)."""
        basis: list[str] = []
        for terms in table.values():
            basis += [t for t in terms if t not in basis]
        for s in DOFS:
            if s not in basis:
                basis.append(s)
        ft = np.zeros((3, len(basis)))
        for i, s in enumerate(DOFS):
            for t, c in table.get(s, {}).items():
                ft[i, basis.index(t)] = float(c)
        order = {s: tuple(_equation_terms(basis, ft, mass_matrix, i)) for i, s in enumerate(DOFS)}
        return cls(name=name, mass_matrix=np.asarray(mass_matrix, dtype=float),
                   basis=tuple(basis), force_table=ft, equation_order=order, **options)


def _equation_terms(basis: Sequence[str], ft: np.ndarray, mm: np.ndarray, i: int) -> list[str]:
    """Terms of equation ``i`` that ``M⁻¹`` can mix in (rows coupled through ``M``)."""
    coupled = np.abs(block_inverse(mm)[i]) > 0
    used = np.any(ft[coupled] != 0.0, axis=0)
    return [t for j, t in enumerate(basis) if used[j] or t == DOFS[i]]
