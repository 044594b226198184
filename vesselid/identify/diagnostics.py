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

from vesselid.model.spec import ModelSpec

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
    "smoothness_bias",
    "smoothness_report",
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


#: A modulus's non-smoothness "matters" when the bias it induces reaches this many standard
#: errors of some parameter: nominal 95 % normal intervals then cover the truth in less than
#: 93 % of runs (Φ(1.96 − b) − Φ(−1.96 − b) = 0.93 at b = 0.4155), the lower edge of the
#: coverage band the package calibrates to.
SMOOTHNESS_BIAS_SE = 0.4155

def _mean_factor(f_idx: int, n_s: int, mu: Sequence[np.ndarray], sig: np.ndarray,
                 erf_t: dict[int, np.ndarray]) -> np.ndarray:
    """``E[F_idx(μ + e)]``, ``e ~ N(0, σ²)`` per signal (closed form; inputs: σ = 0);
    ``mu``: the signals, one column each."""
    if f_idx >= 2 * n_s:
        return np.ones(mu[0].shape[0])
    j = f_idx % n_s
    m = mu[j]
    if f_idx < n_s or sig[j] <= 0:
        return m if f_idx < n_s else np.abs(m)
    s = sig[j]
    return s * math.sqrt(2 / math.pi) * np.exp(-0.5 * (m / s) ** 2) + m * erf_t[j]


def _mean_square_modulus(mu: np.ndarray, s: float, erf_t: np.ndarray) -> np.ndarray:
    """``E[Y|Y|]``, ``Y ~ N(μ, s²)``: ``(μ² + s²) erf(μ/(s√2)) + μ s √(2/π) e^{−μ²/2s²}``."""
    return ((mu**2 + s**2) * erf_t
            + mu * s * math.sqrt(2 / math.pi) * np.exp(-0.5 * (mu / s) ** 2))


def smoothness_bias(data: RegressionData, spec: ModelSpec, theta: np.ndarray,
                    sims: list[np.ndarray], sigma: Mapping[str, float],
                    cov: np.ndarray, phi: np.ndarray | None = None,
                    corrected: bool = False) -> dict[str, float] | None:
    """Bias of the zero-mean IV estimate caused by the modulus's non-smoothness, per state,
    in standard errors (the largest over the parameters).

    A10/A15 ask every state under a modulus to stay away from zero so that ``|x|`` can be
    treated as ``±x``. Where the noisy measurement ``y = x + e`` crosses zero, the
    regressor's conditional mean ``E[φ(y) | x]`` departs from ``φ(x)`` by ``h(x)``
    (``x|x|``: ``h = (x² + σ²)(2Φ(x/σ) − 1) + 2xσ ϕ(x/σ) − x|x|``, which moves from
    ``−σ²`` to ``+σ²`` within a few σ of zero). A constant ``h`` per experiment is absorbed
    by zero-mean instruments; its variation enters the equation error as ``Σ_p θ_p h_p(x)``
    and biases the estimate by ``δθ = (Z_cᵀ Φ)⁻¹ Z_cᵀ Σ θ_p h_p``. This evaluates ``h`` in
    closed form (Gaussian moments of ``|y|`` and ``y|y|``) at the measured signals (the
    operating points; their spread near zero also holds the process noise and currents),
    with instruments ``Z = Φ(x̂)``
    from the noise-free free run ``sims``, centred per experiment (the refined IV's), and
    returns ``max_j |δθ_j| / SE_j`` for the terms under each state's modulus.
    ``corrected``: the estimator's ``s|s|`` regressors carry the errors-in-variables
    correction ``− σ² sign(y)`` (:mod:`vesselid.identify.eiv`), whose mean is subtracted.

    Returns
    -------
    dict state -> float, or None
        ``None`` where the free run is not finite (no operating points).
    """
    from vesselid.identify.backend import kernels

    if not all(np.all(np.isfinite(x)) for x in sims):
        return None
    codes = spec.codes
    n = spec.n_states
    n_s = n + spec.n_inputs
    # operating points: the measured regressor signals (their spread around zero holds the
    # process noise and currents the noise-free free run lacks); instruments: the free run
    x_free = np.concatenate(sims, axis=0)
    if data.regsig is data.target:  # nothing aggregated: a zero offset (the same sums)
        x_free += 0.0
    else:  # the aggregate relation's measured disturbance
        x_free += data.regsig - data.target
    # the signals one column each (the columns of [regsig, u], not a gathered copy)
    mu = [data.regsig[:, j] for j in range(n)] + [data.u[:, j] for j in range(spec.n_inputs)]
    sig = np.zeros(n_s)
    sig[:n] = [float(sigma.get(s, 0.0)) for s in spec.states]
    from scipy.special import erf

    erf_t = {j: erf(mu[j] / (sig[j] * math.sqrt(2))) for j in range(n) if sig[j] > 0}
    rows = np.ones(int(data.starts[-1]), dtype=bool)
    rows[data.starts[:-1]] = False
    z = kernels.regressor_matrix(np.ascontiguousarray(x_free), data.u, data.starts,
                                 codes.factors)
    if phi is None:
        phi = kernels.regressor_matrix(data.regsig, data.u, data.starts, codes.factors)
    se = np.sqrt(np.abs(np.diag(cov)))
    blocks = np.concatenate([[0], np.cumsum([len(spec.equations[s]) for s in spec.states])])
    zr, pr = (z[1:], phi[1:]) if data.n_segments == 1 else (z[rows], phi[rows])
    counts = np.diff(data.starts) - 1
    seg_starts = np.concatenate([[0], np.cumsum(counts)])[:-1][counts > 0]
    cnt = counts[counts > 0].astype(float)[:, None]
    z_sums = np.add.reduceat(zr, seg_starts, axis=0)
    p_sums = np.add.reduceat(pr, seg_starts, axis=0)
    out: dict[str, float] = {}
    mod = modulus_signals(spec)
    for st in mod:
        j = spec.states.index(st)
        if sig[j] <= 0:
            out[st] = 0.0
            continue
        d = np.zeros((mu[0].shape[0], n))
        for p in range(codes.n_params):
            a, b = int(codes.factors[p, 0]), int(codes.factors[p, 1])
            if n_s + j not in (a, b):  # only the terms with |st| carry its non-smoothness
                continue
            if a < 2 * n_s and b < 2 * n_s and a % n_s == b % n_s:  # s|s|: one noise
                expected = _mean_square_modulus(mu[j], sig[j], erf_t[j])
                if corrected:  # the regressor is y|y| − σ² sign(y) (identify.eiv)
                    expected = expected - sig[j] ** 2 * erf_t[j]
            else:  # independent noises (or a noise-free factor): a product of means
                expected = (_mean_factor(a, n_s, mu, sig, erf_t)
                            * _mean_factor(b, n_s, mu, sig, erf_t))
            exact = (_mean_factor(a, n_s, mu, np.zeros(n_s), erf_t)
                     * _mean_factor(b, n_s, mu, np.zeros(n_s), erf_t))
            d[:, int(codes.equation[p])] += theta[p] * (expected - exact)
        # the regressor row k uses the signals at k − 1 (the first row of each experiment
        # holds no equation)
        if data.n_segments == 1:  # rows 1.. take the signals of rows 0..: a view
            dr = d[:-1]
        else:
            d_rows = np.zeros_like(d)
            d_rows[1:] = d[:-1]
            dr = d_rows[rows]
        d_sums = np.add.reduceat(dr, seg_starts, axis=0)
        worst = 0.0
        for i in range(n):
            sl = slice(int(blocks[i]), int(blocks[i + 1]))
            # Σ_E (Z_Eᵀ Φ_E − z̄-sums): the instruments centred per experiment, from sums
            a_mat = zr[:, sl].T @ pr[:, sl] - z_sums[:, sl].T @ (p_sums[:, sl] / cnt)
            b_vec = zr[:, sl].T @ dr[:, i] - z_sums[:, sl].T @ (d_sums[:, i] / cnt[:, 0])
            try:
                delta = np.linalg.solve(a_mat, b_vec)
            except np.linalg.LinAlgError:
                continue
            with np.errstate(divide="ignore", invalid="ignore"):
                ratio = np.abs(delta) / se[sl]
            ratio = ratio[np.isfinite(ratio)]
            if ratio.size:
                worst = max(worst, float(ratio.max()))
        out[st] = worst
    return out


def smoothness_report(data: RegressionData, spec: ModelSpec, theta: np.ndarray,
                      sims: list[np.ndarray], design_rows_: list[dict[str, Any]],
                      eta: Mapping[str, float], eta_default: bool,
                      cov: np.ndarray, phi: np.ndarray | None = None,
                      corrected: bool = False) -> dict[str, dict[str, Any]]:
    """The A10/A15 smoothness check per state under a modulus (JSON-ready).

    Always reports the share of samples within ``η`` of zero (pooled, and the worst
    experiment's); ``matters`` when :func:`smoothness_bias` reaches
    :data:`SMOOTHNESS_BIAS_SE` standard errors. The sensor-noise std ``σ`` is the log's
    (``data.regressor_noise``, e.g. the sea trial's metadata) or ``η/3`` (with the default
    ``η``: the one-step residual std, an upper bound: it holds the process noise too).
    """
    out: dict[str, dict[str, Any]] = {}
    mod = modulus_signals(spec)
    if not mod:
        return out
    if data.regressor_noise is not None:
        sigma = {s: float(v) for s, v in zip(spec.states, data.regressor_noise, strict=True)}
        source = "the log's sensor-noise std"
    else:
        sigma = {s: float(eta.get(s, 0.0)) / 3.0 for s in spec.states}
        source = ("the one-step residual std (an upper bound of the sensor noise)"
                  if eta_default else "eta / 3")
    try:
        bias = smoothness_bias(data, spec, np.asarray(theta, float), sims, sigma, cov, phi,
                               corrected)
    except (np.linalg.LinAlgError, FloatingPointError, ValueError):
        bias = None
    lengths = np.diff(data.starts)
    for st in mod:
        rows = [r for r in design_rows_ if r["state"] == st]
        n_rows = np.array([lengths[k] for k in range(len(rows))], dtype=float)
        shares = np.array([r["share_within_eta"] for r in rows])
        pooled = float(np.sum(shares * n_rows) / max(np.sum(n_rows), 1.0))
        k = int(np.argmax(shares)) if shares.size else 0
        worst = rows[k] if rows else {"experiment": None, "share_within_eta": float("nan"),
                                      "sign_changes": 0, "eta": float("nan")}
        b = None if bias is None else bias.get(st)
        matters = b is not None and b >= SMOOTHNESS_BIAS_SE
        exp_id = worst["experiment"]
        exp_id = exp_id.item() if hasattr(exp_id, "item") else exp_id
        where = (f"{100 * pooled:.1f} % of samples within η={worst['eta']:.3g} of zero "
                 f"(worst: experiment {exp_id}, {100 * worst['share_within_eta']:.1f} %, "
                 f"{worst['sign_changes']} sign changes)")
        if b is None:
            sentence = (f"state {st!r}: {where}; its effect on the estimate was not assessed "
                        "(the free run is not finite)")
        elif matters:
            sentence = (f"state {st!r} is too often near zero for the modulus to be treated "
                        f"as smooth (A10/A15): {where}; the non-smoothness biases the "
                        f"estimate by up to {b:.2g} standard errors (≥ "
                        f"{SMOOTHNESS_BIAS_SE:.2g}: 95 % intervals cover less than 93 %) — "
                        "use experiments that keep it away from zero")
        else:
            sentence = (f"state {st!r}: {where}; the modulus's non-smoothness biases the "
                        f"estimate by at most {b:.2g} standard errors (< "
                        f"{SMOOTHNESS_BIAS_SE:.2g}: negligible)")
        out[st] = {"share_within_eta": pooled, "worst_experiment": exp_id,
                   "worst_share_within_eta": float(worst["share_within_eta"]),
                   "eta": float(worst["eta"]), "sigma": sigma.get(st, 0.0),
                   "sigma_source": source, "bias_se": b,
                   "threshold_se": SMOOTHNESS_BIAS_SE, "matters": bool(matters),
                   "sentence": sentence}
    return out
