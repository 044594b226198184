"""Diagnostics: experiment-design margins (A10/A15), collinearity, instrument strength, fit.

* :func:`design_margins` — per state and experiment, the share of samples whose
  magnitude lies within a margin ``η`` of zero, and the number of sign changes.
  The consistency proofs (Lemma 3.1 with A10, Lemma 4.1 with A15) need every
  state that appears under a modulus to stay farther than ``η`` from zero, so that
  ``|x|`` can be treated as ``±x``.
* :func:`collinear_terms` — names the terms behind a rank-deficient regressor
  matrix (e.g. ``w`` and ``|w|`` when ``w`` never changes sign).
* :func:`condition_number` — of the column-equilibrated ``ZᵀΦ`` (instrument
  strength).
* NRMSE, one definition with two faces: the ratio ``r = ‖y − ŷ‖ / ‖y − ȳ‖``
  (:func:`nrmse_ratio`; :func:`free_run_ratio` pools the experiments of a data set, each
  about its own mean), reported either as an error :func:`nrmse` ``= 100 r`` percent
  (0 = perfect; the sea-trial validation) or as a fit :func:`nrmse_fit` ``= 100 (1 − r)``
  percent (100 = perfect; ``IdentificationResult.diagnostics``).
* :func:`normalized_error` — the paper's ``(θ̂ − θ0) / θ0``, NaN where ``θ0 = 0``.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING, Any

import numpy as np
import pandas as pd

from vesselid.model import ModelSpec

if TYPE_CHECKING:
    from vesselid.identify.data import RegressionData

__all__ = [
    "check_moment_range",
    "collinear_terms",
    "condition_number",
    "design_frame",
    "design_margins",
    "design_rows",
    "free_run_ratio",
    "modulus_signals",
    "normalized_error",
    "nrmse",
    "nrmse_fit",
    "nrmse_ratio",
]


def modulus_signals(spec: ModelSpec) -> list[str]:
    """States that appear under a modulus in some term (they need A10/A15 margins)."""
    out: list[str] = []
    for s in spec.states:
        for terms in spec.equations.values():
            for t in terms:
                if (t.left == s and t.left_abs) or (t.right == s and t.right_abs):
                    out.append(s)
                    break
            else:
                continue
            break
    return out


def design_margins(
    signal: np.ndarray,
    starts: np.ndarray,
    spec: ModelSpec,
    eta: Mapping[str, float],
    experiment_ids: Sequence | None = None,
    *,
    threshold: float = 0.01,
) -> pd.DataFrame:
    """Experiment-design check for A10/A15.

    Parameters
    ----------
    signal : ndarray (T, n)
        The regressor signal per state (measured or aggregated state).
    starts : ndarray (S+1,)
        Experiment boundaries.
    spec : ModelSpec
    eta : mapping state -> float
        Margin ``η_i`` (A10: ``max(η_e, η_v)``; A15: ``η_e1 + η_e2 + η_v``).
    threshold : float
        Largest acceptable share of samples inside the margin.

    Returns
    -------
    DataFrame
        One row per (experiment, state): ``eta``, ``share_within_eta``,
        ``sign_changes``, ``min_abs``, ``under_modulus``, ``ok``.
    """
    return design_frame(design_rows(signal, starts, spec, eta, experiment_ids,
                                    threshold=threshold))


def design_rows(
    signal: np.ndarray,
    starts: np.ndarray,
    spec: ModelSpec,
    eta: Mapping[str, float],
    experiment_ids: Sequence | None = None,
    *,
    threshold: float = 0.01,
) -> list[dict[str, Any]]:
    """The rows of :func:`design_margins` as dicts (column name -> value), before the
    frame is built: ``identify`` words its A10/A15 warnings from them (no row lookups in
    the frame)."""
    ids = list(experiment_ids) if experiment_ids is not None else list(range(starts.size - 1))
    mod = set(modulus_signals(spec))
    rows: list[dict[str, Any]] = []
    for sidx in range(starts.size - 1):
        seg = signal[int(starts[sidx]) : int(starts[sidx + 1])]
        for i, s in enumerate(spec.states):
            x = seg[:, i]
            e = float(eta.get(s, 0.0))
            share = float(np.mean(np.abs(x) <= e)) if x.size else 1.0
            sgn = np.sign(x)
            changes = int(np.count_nonzero(sgn[1:] * sgn[:-1] < 0))
            under = s in mod
            rows.append({
                "experiment": ids[sidx],
                "state": s,
                "eta": e,
                "share_within_eta": share,
                "sign_changes": changes,
                "min_abs": float(np.min(np.abs(x))) if x.size else np.nan,
                "under_modulus": under,
                "ok": (not under) or share <= threshold,
            })
    return rows


def design_frame(rows: list[dict[str, Any]]) -> pd.DataFrame:
    """The frame of :func:`design_margins` from :func:`design_rows`."""
    if not rows:
        return pd.DataFrame(rows)
    # column by column: the frame pandas builds from the records, at a fraction of the cost
    return pd.DataFrame({key: [r[key] for r in rows] for key in rows[0]})


def collinear_terms(
    phi: np.ndarray, names: Sequence[str], *, rtol: float = 1e-9, gram: np.ndarray | None = None
) -> list[list[str]]:
    """Groups of terms that are (near) linearly dependent in the regressor matrix ``phi``.

    Columns are scaled to unit norm; every singular value below ``rtol`` times the
    largest gives a null-space direction, and the terms with a noticeable weight in
    it are reported. An all-zero column is reported alone. ``gram`` (``ΦᵀΦ``, if the
    caller has it) saves recomputing it for the cheap full-rank screen.
    """
    phi = np.asarray(phi, dtype=float)
    if gram is None:
        gram = phi.T @ phi
    norms = np.sqrt(np.diag(gram))
    groups: list[list[str]] = [[names[j]] for j in np.flatnonzero(norms == 0)]
    keep = np.flatnonzero(norms > 0)
    if keep.size == 0:
        return groups
    eig = np.linalg.eigvalsh(gram[np.ix_(keep, keep)] / np.outer(norms[keep], norms[keep]))
    if eig[0] > (1e3 * rtol) ** 2 * eig[-1]:
        # Gram eigenvalues are accurate to ~1e-16 of the largest, so this proves the
        # smallest singular value exceeds 1e3·rtol of the largest: surely full rank
        return groups
    scaled = phi[:, keep] / norms[keep]
    # Φ = QR: the singular values and right vectors of R are those of Φ (cheap for tall Φ)
    r_factor = np.linalg.qr(scaled, mode="r")
    _, sv, vt = np.linalg.svd(r_factor)
    for k in np.flatnonzero(sv < rtol * sv[0]):
        vec = vt[k]
        members = [names[keep[j]] for j in np.flatnonzero(np.abs(vec) > 0.05)]
        if members:
            groups.append(members)
    return groups


def check_moment_range(phi: np.ndarray, names: Sequence[str]) -> None:
    """Refuse regressors whose moment sums ``ΦᵀΦ``/``ZᵀΦ`` would overflow (or underflow)
    float64.

    Every moment is a sum of ``N`` products of two regressors, so a regressor above
    ``sqrt(max float64 / (N P))`` can make a sum infinite (e.g. signals of ~1e150, or
    finite garbage from a corrupted file); the message names the regressor and its
    magnitude instead of a later "singular" or "did not converge".

    Raises
    ------
    IdentificationError
        A regressor is not finite or too large.
    """
    from vesselid.errors import IdentificationError

    phi = np.asarray(phi, dtype=float)
    if phi.size == 0:
        return
    with np.errstate(invalid="ignore"):
        # column by column (a maximum is exact in any order; numpy's axis-0 reduction of a
        # few columns pays a call per row)
        big = (np.array([np.max(np.abs(phi[:, j])) for j in range(phi.shape[1])])
               if phi.shape[1] <= 16 else np.max(np.abs(phi), axis=0))
    limit = math.sqrt(np.finfo(float).max / (phi.shape[0] * max(phi.shape[1], 1))) / 16.0
    # below this a regressor's squares leave float64's normal range (precision is lost in
    # subnormals, or the products round to zero): the "collinear" it would cause is units
    floor = math.sqrt(np.finfo(float).tiny) * 2.0**26
    tiny = (big > 0) & (big < floor)
    if tiny.any():
        j = int(np.flatnonzero(tiny)[0])
        raise IdentificationError(
            f"regressor {names[j]!r} reaches only {big[j]:.3g}: its products underflow "
            f"float64 (its moments need values above ~{floor:.2g}); rescale the signals "
            "(e.g. to SI units)")
    bad = ~(big <= limit)
    if bad.any():
        j = int(np.flatnonzero(bad)[0])
        if not np.isfinite(big[j]):
            raise IdentificationError(
                f"regressor {names[j]!r} is not finite (the signals overflow float64 in "
                "its product); rescale the signals (e.g. to SI units)")
        raise IdentificationError(
            f"regressor {names[j]!r} reaches {big[j]:.3g}: its moment sums over "
            f"{phi.shape[0]} samples would overflow float64 (limit ~{limit:.2g}); rescale the "
            "signals (e.g. to SI units) or check the log for corrupted values")


def condition_number(a: np.ndarray) -> float:
    """Condition number of ``a`` after scaling rows and columns to unit norm."""
    a = np.asarray(a, dtype=float)
    r = np.linalg.norm(a, axis=1)
    c = np.linalg.norm(a, axis=0)
    if np.any(r == 0) or np.any(c == 0):
        return float("inf")
    return float(np.linalg.cond(a / r[:, None] / c[None, :]))


def normalized_error(estimate: np.ndarray, theta0: np.ndarray) -> np.ndarray:
    """The paper's normalised error ``(θ̂ − θ0) / θ0`` (Tables 1–2, Figure 1), elementwise.

    The one definition (results' ``compare()``, Monte Carlo tables, sea trials). Where
    ``θ0 = 0`` the relative error is undefined and the result is NaN (never ±inf), so a
    zero true value shows as a gap, not as an infinitely bad estimate.
    """
    est = np.asarray(estimate, dtype=float)
    th0 = np.asarray(theta0, dtype=float)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(th0 != 0, (est - th0) / np.where(th0 != 0, th0, 1.0), np.nan)


def nrmse_ratio(y: np.ndarray, y_hat: np.ndarray) -> float:
    """``‖y − ŷ‖ / ‖y − ȳ‖`` over the samples where both are finite (NaN if undefined).

    The one NRMSE definition; :func:`nrmse` and :func:`nrmse_fit` only scale it.
    """
    y = np.asarray(y, dtype=float)
    y_hat = np.asarray(y_hat, dtype=float)
    ok = np.isfinite(y) & np.isfinite(y_hat)
    if not ok.any():
        return float("nan")
    den = np.linalg.norm(y[ok] - y[ok].mean())
    if den == 0:
        return float("nan")
    return float(np.linalg.norm(y[ok] - y_hat[ok]) / den)


def nrmse(y: np.ndarray, y_hat: np.ndarray) -> float:
    """NRMSE as an error in percent, ``100 ‖y − ŷ‖ / ‖y − ȳ‖`` (0 = perfect)."""
    return 100.0 * nrmse_ratio(y, y_hat)


def nrmse_fit(y: np.ndarray, y_hat: np.ndarray) -> float:
    """NRMSE as a fit in percent, ``100 (1 − ‖y − ŷ‖ / ‖y − ȳ‖)`` (100 = perfect;
    MATLAB ``compare``'s convention), i.e. ``100 −`` :func:`nrmse`."""
    return float(100.0 * (1.0 - nrmse_ratio(y, y_hat)))


def free_run_ratio(data: RegressionData, spec: ModelSpec, theta: np.ndarray,
                   sims: list[np.ndarray] | None = None) -> tuple[np.ndarray, bool]:
    """Free-run (simulation) NRMSE ratio per state, pooled over the experiments of ``data``.

    Each experiment is simulated from its measured inputs and initial state (with the
    measured current inside the nonlinearity when the spec has an aggregate relation);
    ``r = sqrt(Σ_E ‖y − ŷ‖² / Σ_E ‖y − ȳ_E‖²)``, each experiment about its own mean.
    Experiments whose simulation diverges are left out of the sums. ``sims``: those
    simulations when the caller has them already
    (:func:`vesselid.identify.stability.free_run_states`).

    Returns
    -------
    ratio : ndarray
        One ratio per state (NaN where every experiment diverged).
    all_ok : bool
        False if some experiment diverged.
    """
    if sims is None:
        from vesselid.identify.stability import free_run_states

        sims = free_run_states(data, spec, theta)
    num = np.zeros(spec.n_states)
    den = np.zeros(spec.n_states)
    all_ok = True
    for s, x in enumerate(sims):
        y = data.target[data.segment(s)]
        if not np.all(np.isfinite(x)):
            all_ok = False
            continue
        num += np.sum((y - x) ** 2, axis=0)
        den += np.sum((y - y.mean(axis=0)) ** 2, axis=0)
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.sqrt(num / den)
    if not all_ok and not np.any(den):
        ratio[:] = np.nan
    return ratio, all_ok
