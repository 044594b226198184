"""Consistent term selection: IV stepwise selection with batch-means HAC Wald tests.

For one trial log and a candidate library per state equation (Definition 2.1 forms):

1. **Instruments** (paper §3): the states ``x̂`` are simulated from the inputs alone by an
   auxiliary model — first the base spec fitted by refined IV with zero-mean instruments,
   then the selected model — and every candidate's instrument is the candidate evaluated
   on ``[x̂; u]``. The instruments, regressors and targets are centred per experiment (A7,
   the paper's ``IV_E{ζ}=0``): a current inside the modulus adds per-experiment
   constants to the equation error (Lemma 3.1) that the centring absorbs. Any such
   instrument is independent of the current and the sensor noise, whatever the
   auxiliary structure, so every test below is valid for every candidate set; the
   auxiliary model only decides how strong the instruments are.
2. **Same-in-the-data groups**: candidates whose centred regressor is (up to ``tol``) a
   linear combination of earlier candidates — ``|x|`` and ``x`` when ``x`` keeps its
   sign, ``v*|r|`` and ``−r*|v|`` in steady turns, a column constant within every
   experiment — are not identifiable from the log; the first (library order) represents
   the group, the rest are reported with it and never picked at random.
3. **Stepwise selection** per equation: starting from no term, add the candidate with
   the largest HAC Wald statistic ``|t|`` (its ``t`` when added to the current model)
   while that ``|t|`` reaches the critical value
   ``c = max(z_{1−α/(2M)}, √log n)`` (Bonferroni over the ``M`` candidates of all
   equations, and the BIC rate ``√log n`` so that the chance of keeping a zero term
   vanishes as the log grows while the ``|t|`` of a true term grows like ``√n``: a
   consistent rule); after every addition drop the term with the smallest ``|t|``
   while it is below ``c``. Only small models are fitted, so nearly collinear
   candidates never enter one ill-conditioned fit. The equation errors are
   autocorrelated (coloured currents, sensor noise entering through the modulus), so
   the covariance is the batch-means HAC estimator over non-overlapping blocks of
   ``L`` samples (blocks never straddle experiments).
4. **Refinement**: the selected model becomes the auxiliary model and the selection is
   repeated until the structure no longer changes (at most ``passes`` passes). Where
   several auxiliary fits compete (the library model's), the one whose simulation
   tracks the log best (:func:`simulation_error`) gives the instruments.
5. **Pairs the log cannot tell apart** (:func:`indistinguishable`): an unselected
   candidate that, with a selected one in the model, leaves neither significant, while
   replacing it keeps every term significant, is reported with it (``undecided``).
6. **Selection probabilities**: a block bootstrap (blocks of ``L`` samples drawn with
   replacement within each experiment, the autocorrelation kept inside the blocks)
   repeats step 3 on resampled moment sums; a candidate's probability is the share of
   replicates that keep it (or its group's representative).

Everything runs on per-block moment matrices ``Σ_b ζ̃ φ̃ᵀ`` and ``Σ_b ζ̃ ỹ``: a bootstrap
replicate is a weighted sum of blocks, never a pass over the samples.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from statistics import NormalDist

import numpy as np

from vesselid.identify.backend import kernels
from vesselid.identify.data import RegressionData
from vesselid.model.regressors import encode_terms
from vesselid.model.terms import Term
from vesselid.selection.library import Library, SelectionError

__all__ = ["Blocks", "critical_value", "eliminate", "indistinguishable", "make_blocks",
           "same_in_data_groups", "simulation_error"]

#: most blocks used by the batch-means HAC estimator and the bootstrap (longer blocks
#: beyond that: the moment arrays stay small on long logs)
MAX_BLOCKS = 300


@dataclass(frozen=True)
class Blocks:
    """Non-overlapping blocks of equation rows: ``rows[b]`` slice bounds, the experiment
    of each block, the block length."""

    start: np.ndarray
    stop: np.ndarray
    experiment: np.ndarray
    length: int

    @property
    def n(self) -> int:
        return int(self.start.size)


def equation_rows_per_segment(data: RegressionData) -> list[tuple[int, int]]:
    """``[a, b)`` of the rows holding an equation (all but the first) of each experiment."""
    return [(int(data.starts[s]) + 1, int(data.starts[s + 1])) for s in range(data.n_segments)]


def make_blocks(data: RegressionData, block_length: int | None = None) -> Blocks:
    """Blocks of ``L`` consecutive equation rows within each experiment (the remainder of
    an experiment joins its last block).

    Default ``L = max(10, ⌈2 n_e^{1/3}⌉, ⌈n / 600⌉)`` with ``n_e`` the median experiment
    length and ``n`` all rows: the batch-means rate ``n^{1/3}`` with at most
    :data:`MAX_BLOCKS` blocks.
    """
    segs = equation_rows_per_segment(data)
    lengths = np.array([b - a for a, b in segs])
    n = int(lengths.sum())
    if block_length is None:
        med = float(np.median(lengths)) if lengths.size else 0.0
        block_length = max(10, math.ceil(2.0 * med ** (1.0 / 3.0)), math.ceil(n / MAX_BLOCKS))
    block_length = int(block_length)
    if block_length < 1:
        raise SelectionError(f"block_length must be a positive integer, got {block_length}")
    start, stop, exp = [], [], []
    for e, (a, b) in enumerate(segs):
        k = (b - a) // block_length
        if k == 0:
            continue
        s = a + block_length * np.arange(k)
        t = s + block_length
        t[-1] = b
        start.append(s)
        stop.append(t)
        exp.append(np.full(k, e))
    if not start:
        raise SelectionError(f"every experiment is shorter than one block of {block_length} "
                             "samples; use longer experiments or a shorter --block-length")
    return Blocks(np.concatenate(start), np.concatenate(stop), np.concatenate(exp),
                  block_length)


def critical_value(alpha: float, n_candidates: int, n_rows: int) -> float:
    """``max(z_{1−α/(2M)}, √log n)``: Bonferroni over ``M`` candidates and the BIC rate."""
    bonf = float(NormalDist().inv_cdf(1.0 - alpha / (2.0 * max(n_candidates, 1))))
    return max(bonf, math.sqrt(math.log(max(n_rows, 3))))


def centred(x: np.ndarray, segs: list[tuple[int, int]]) -> np.ndarray:
    """The equation rows of ``x`` stacked, each experiment minus its mean (A7)."""
    parts = []
    for a, b in segs:
        blk = x[a:b]
        parts.append(blk - blk.mean(axis=0))
    return np.concatenate(parts)


def library_factors(library: Library, spec) -> tuple[list[Term], dict[str, np.ndarray]]:
    """The union of all equations' candidates (first-seen order) and, per equation, the
    column indices of its candidates in that union."""
    union: list[Term] = []
    pos: dict[str, int] = {}
    cols: dict[str, np.ndarray] = {}
    for s in spec.states:
        idx = []
        for t in library[s]:
            key = str(t)
            if key not in pos:
                pos[key] = len(union)
                union.append(t)
            idx.append(pos[key])
        cols[s] = np.asarray(idx, dtype=np.int64)
    return union, cols


def regressors(data: RegressionData, union: list[Term], spec) -> np.ndarray:
    """Φ of every union candidate on the log's regressor signals (rows as the kernels)."""
    fac = encode_terms([union], spec.signals).factors
    return kernels.regressor_matrix(data.regsig, data.u, data.starts, fac)


def simulation_error(data: RegressionData, xhat: np.ndarray) -> float:
    """How poorly the auxiliary simulation ``x̂`` tracks the measured states: the sum over
    states of ``Σ (x̃ − x̂̃)² / Σ x̃²`` with ``x̃``, ``x̂̃`` centred per experiment (the
    instruments' strength grows as it falls; 0 for a perfect simulation)."""
    segs = [(int(data.starts[s]), int(data.starts[s + 1])) for s in range(data.n_segments)]
    x = centred(data.target, segs)
    e = x - centred(xhat, segs)
    ss = np.einsum("ij,ij->j", x, x)
    return float(np.sum(np.einsum("ij,ij->j", e, e) / np.where(ss > 0, ss, 1.0)))


def instruments(data: RegressionData, union: list[Term], aux_spec, theta_aux,
                with_error: bool = False):
    """ζ of every union candidate: the candidate evaluated on ``[x̂; u]``, ``x̂`` simulated
    from the inputs by the auxiliary model (restarted from the measurement at each
    experiment's start). ``with_error``: also :func:`simulation_error` of ``x̂``."""
    codes = aux_spec.codes
    _, xhat = kernels.instrument_matrix(data.target, data.u, data.starts,
                                        np.asarray(theta_aux, dtype=float), codes.factors,
                                        codes.equation, aux_spec.n_states)
    bound = 1e3 * max(float(np.nanmax(np.abs(data.target))), 1.0)
    if not np.all(np.isfinite(xhat)) or float(np.abs(xhat).max()) > bound:
        raise SelectionError("the auxiliary model's simulation diverges on this log, so no "
                             "instruments can be formed; give a stable base model (--model) "
                             "whose equations hold the dominant terms")
    fac = encode_terms([union], aux_spec.signals).factors
    z = kernels.regressor_matrix(xhat, data.u, data.starts, fac)
    return (z, simulation_error(data, xhat)) if with_error else z


def same_in_data_groups(phi_c: np.ndarray, names: list[str], tol: float,
                        min_samples: int = 20) -> tuple[np.ndarray, list[dict]]:
    """Candidates identifiable from the data, in library order, and the groups of the rest.

    ``phi_c`` holds the centred regressors (rows × candidates). Going through the
    candidates in order, one whose centred column leaves a share below ``tol`` of its
    sum of squares after projection on the candidates kept so far is the same in the
    data as a combination of them; so is one whose unexplained part lives on fewer than
    ``max(min_samples, n/200)`` effective samples (``(Σr²)²/Σr⁴``): ``x`` and ``|x|``
    when ``x`` dips below zero a few times differ by leverage, not by information.
    A column that is (relative to the
    largest) zero — constant within every experiment — is absorbed by the zero-mean
    instruments.

    Returns
    -------
    keep : ndarray of int
        Indices of the represented candidates.
    groups : list of dict
        ``{"kept": name or None, "members": [...], "reason": str}`` per dependency.
    """
    gram = phi_c.T @ phi_c
    ss = np.diag(gram).copy()
    scale = float(ss.max()) if ss.size else 0.0
    keep: list[int] = []
    groups: list[dict] = []
    for j in range(len(names)):
        if not np.isfinite(ss[j]) or ss[j] <= 1e-24 * max(scale, 1e-300):
            groups.append({"kept": None, "members": [names[j]],
                           "reason": "constant within every experiment"})
            continue
        if keep:
            k = np.asarray(keep)
            d = np.sqrt(ss[k])
            c = gram[np.ix_(k, k)] / np.outer(d, d)
            b = gram[k, j] / (d * math.sqrt(ss[j]))
            coef = np.linalg.lstsq(c, b, rcond=None)[0]
            resid = 1.0 - float(b @ coef)
        else:
            resid = 1.0
        few = False
        if keep and tol <= resid < 1e-2:
            # the part of the candidate the kept ones do not explain: when it lives on a
            # handful of samples (x and |x| when x dips below zero a few times) the data
            # cannot tell the candidates apart (leverage, not information)
            w = coef * math.sqrt(ss[j]) / d
            big = np.flatnonzero(np.abs(coef) > 1e-3 * np.abs(coef).max())
            r = phi_c[:, j] - phi_c[:, k[big]] @ w[big]
            r2 = r * r
            n_eff = float(r2.sum() ** 2 / max(float((r2 * r2).sum()), 1e-300))
            few = n_eff < max(min_samples, 0.005 * phi_c.shape[0])
        if resid < tol or few:
            weight = np.abs(coef)
            members = [names[keep[i]] for i in np.flatnonzero(weight > 0.05 * weight.max())]
            groups.append({"kept": members[0] if len(members) == 1 else None,
                           "members": [*members, names[j]],
                           "reason": ("the same as " + members[0] if len(members) == 1
                                      else "a linear combination of " + ", ".join(members))
                                     + (" but on a few samples" if few else "")
                                     + " in this log"})
            continue
        keep.append(j)
    return np.asarray(keep, dtype=np.int64), groups


def block_moments(z_c: np.ndarray, phi_c: np.ndarray, y_c: np.ndarray, blocks: Blocks,
                  row_offset: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``M_b = Σ_{k∈b} ζ̃_k φ̃_kᵀ`` (nb, P, P) and ``m_b = Σ_{k∈b} ζ̃_k ỹ_kᵀ`` (nb, P, n).

    ``row_offset`` maps log rows to rows of the stacked centred arrays.
    """
    nb = blocks.n
    p = phi_c.shape[1]
    m_mat = np.empty((nb, p, p))
    m_vec = np.empty((nb, p, y_c.shape[1]))
    for b in range(nb):
        a = int(row_offset[blocks.start[b]])
        e = a + int(blocks.stop[b] - blocks.start[b])
        zb = z_c[a:e]
        np.matmul(zb.T, phi_c[a:e], out=m_mat[b])
        np.matmul(zb.T, y_c[a:e], out=m_vec[b])
    return m_mat, m_vec


def eliminate(m_mat: np.ndarray, m_vec: np.ndarray, counts: np.ndarray, crit: float
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Backward elimination on block moments of one equation.

    Parameters
    ----------
    m_mat : ndarray (nb, P, P)
        Block sums ``Σ ζ̃ φ̃ᵀ`` of the equation's candidates.
    m_vec : ndarray (nb, P)
        Block sums ``Σ ζ̃ ỹ``.
    counts : ndarray (nb,)
        Multiplicity of every block (ones; bootstrap draws).
    crit : float
        Critical value of ``|t|``.

    Returns
    -------
    keep : ndarray of bool (P,)
        The selected candidates.
    theta : ndarray (P,)
        IV estimate of the final model (0 for dropped candidates).
    t : ndarray (P,)
        HAC Wald ``t`` of each kept candidate in the final model; for a dropped
        candidate, its ``t`` in the model it was dropped from.
    cov : ndarray (P, P)
        Batch-means HAC covariance of ``theta`` (zero rows/columns for dropped).
    """
    used = np.flatnonzero(counts > 0)
    c = counts[used].astype(float)
    mm = m_mat[used]
    mv = m_vec[used]
    p = mm.shape[1]
    a_full = np.tensordot(c, mm, axes=1)
    b_full = c @ mv
    n_eff = float(c.sum())
    active = np.arange(p)
    t_out = np.zeros(p)
    keep = np.zeros(p, dtype=bool)
    theta_out = np.zeros(p)
    cov_out = np.zeros((p, p))
    cur = mm  # the active sub-blocks, compacted as candidates leave
    while True:
        a = a_full[np.ix_(active, active)]
        try:
            theta = np.linalg.solve(a, b_full[active])
            a_inv = np.linalg.inv(a)
        except np.linalg.LinAlgError:
            theta = np.linalg.lstsq(a, b_full[active], rcond=None)[0]
            a_inv = np.linalg.pinv(a)
        g = mv[:, active] - cur @ theta
        dof = max(n_eff - active.size, 1.0)
        omega = (g * c[:, None]).T @ g * (n_eff / dof)
        cov = a_inv @ omega @ a_inv.T
        # floor: 1e-8 of the coefficient that would explain the target by the candidate
        # alone (noise-free logs: a zero term's ``0/0`` must read as 0, not as chance)
        diag_a = np.abs(np.diag(a))
        floor = 1e-8 * np.abs(b_full[active]) / np.where(diag_a > 0, diag_a, 1.0)
        se = np.maximum(np.sqrt(np.maximum(np.diag(cov), 0.0)), floor)
        with np.errstate(divide="ignore", invalid="ignore"):
            t = np.where(se > 0, theta / se, 0.0)
        t = np.nan_to_num(t, nan=0.0, posinf=np.inf, neginf=-np.inf)
        t_out[active] = t
        j = int(np.argmin(np.abs(t)))
        if abs(t[j]) >= crit or active.size == 1:
            break
        active = np.delete(active, j)
        cur = np.delete(np.delete(cur, j, axis=1), j, axis=2)
    keep[active] = True
    theta_out[active] = theta
    cov_out[np.ix_(active, active)] = cov
    return keep, theta_out, t_out, cov_out


def bootstrap_counts(blocks: Blocks, n_boot: int, rng: np.random.Generator) -> np.ndarray:
    """``(n_boot, nb)`` multiplicities: each experiment's blocks drawn with replacement
    from its own blocks (as many draws as it has blocks)."""
    out = np.zeros((n_boot, blocks.n))
    for e in np.unique(blocks.experiment):
        idx = np.flatnonzero(blocks.experiment == e)
        draws = rng.integers(0, idx.size, size=(n_boot, idx.size))
        for r in range(n_boot):
            out[r, idx] = np.bincount(draws[r], minlength=idx.size)
    return out


def _iv_fit(a_full, b_full, mm, mv, c, n_eff, idx):
    """IV estimate, batch-means HAC covariance and ``|t|`` of the candidates ``idx``."""
    a = a_full[np.ix_(idx, idx)]
    try:
        theta = np.linalg.solve(a, b_full[idx])
        a_inv = np.linalg.inv(a)
    except np.linalg.LinAlgError:
        return None
    if not (np.all(np.isfinite(theta)) and np.all(np.isfinite(a_inv))):
        return None
    ix = np.asarray(idx)
    g = mv[:, ix] - mm[:, ix[:, None], ix[None, :]] @ theta
    dof = max(n_eff - len(idx), 1.0)
    omega = (g * c[:, None]).T @ g * (n_eff / dof)
    cov = a_inv @ omega @ a_inv.T
    cov = 0.5 * (cov + cov.T)
    diag_a = np.abs(np.diag(a))
    floor = 1e-8 * np.abs(b_full[idx]) / np.where(diag_a > 0, diag_a, 1.0)
    se = np.maximum(np.sqrt(np.maximum(np.diag(cov), 0.0)), floor)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.where(se > 0, theta / se, 0.0)
    return theta, cov, np.nan_to_num(t, nan=0.0)


def _added_t(a_full, b_full, mm, mv, c, n_eff, model, cands):
    """HAC ``|t|`` of every candidate in ``cands`` when added alone to ``model`` (one
    batched solve: ``t_j = θ_j / sqrt(Σ_b c_b (r_j·g_b)²)`` with ``r_j`` the last row of
    the inverse moment matrix and ``g_b`` the block scores)."""
    cands = np.asarray(cands, dtype=np.int64)
    idx = np.concatenate([np.broadcast_to(np.asarray(model, dtype=np.int64),
                                          (cands.size, len(model))), cands[:, None]], axis=1)
    a = a_full[idx[:, :, None], idx[:, None, :]]  # (J, s+1, s+1)
    out = np.zeros(cands.size)
    with np.errstate(all="ignore"):
        try:
            a_inv = np.linalg.inv(a)
        except np.linalg.LinAlgError:  # a singular member: one at a time
            for q, j in enumerate(cands):
                fit = _iv_fit(a_full, b_full, mm, mv, c, n_eff, [*model, int(j)])
                out[q] = 0.0 if fit is None else abs(float(fit[2][-1]))
            return out
        theta = np.einsum("jpq,jq->jp", a_inv, b_full[idx])
        m_sub = mm[:, idx[:, :, None], idx[:, None, :]]  # (nb, J, s+1, s+1)
        g = mv[:, idx] - np.einsum("bjpq,jq->bjp", m_sub, theta)
        h = np.einsum("bjp,jp->bj", g, a_inv[:, -1, :])
        dof = max(n_eff - idx.shape[1], 1.0)
        var = (c @ (h * h)) * (n_eff / dof)
        diag_a = np.abs(a[:, -1, -1])
        floor = 1e-8 * np.abs(b_full[cands]) / np.where(diag_a > 0, diag_a, 1.0)
        se = np.maximum(np.sqrt(np.maximum(var, 0.0)), floor)
        t = np.abs(theta[:, -1]) / se
    ok = np.isfinite(t) & np.all(np.isfinite(theta), axis=1)
    out[ok] = t[ok]
    return out


def stepwise(m_mat: np.ndarray, m_vec: np.ndarray, counts: np.ndarray, crit: float,
             start: np.ndarray | None = None
             ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Forward–backward IV selection on block moments of one equation.

    From ``start`` (default empty), add the candidate with the largest HAC ``|t|`` when
    added to the current model while that ``|t|`` reaches ``crit``; after every addition
    drop the term with the smallest ``|t|`` while it is below ``crit``. A dropped term may
    come back when the model it left has changed (a near-copy that displaced it was itself
    dropped); a model already visited is never entered again, so the search cannot cycle.
    Only small models are ever fitted, so a large library with nearly
    collinear candidates never enters one ill-conditioned fit. An equation keeps at least
    one term (its strongest candidate), as in :func:`eliminate`.

    Returns the same as :func:`eliminate`: ``keep``, ``theta``, ``t`` (kept: in the final
    model; others: when tried last against the final model) and ``cov``.
    """
    used = np.flatnonzero(counts > 0)
    c = counts[used].astype(float)
    mm = np.ascontiguousarray(m_mat[used])
    mv = np.ascontiguousarray(m_vec[used])
    p = mm.shape[1]
    a_full = np.tensordot(c, mm, axes=1)
    b_full = c @ mv
    n_eff = float(c.sum())
    model: list[int] = [] if start is None else [int(j) for j in start]
    visited: set[frozenset[int]] = {frozenset(model)}
    singular: set[int] = set()  # candidates whose addition makes the moment matrix singular
    t_try = np.zeros(p)
    for _ in range(4 * p + 4):
        cands = [j for j in range(p) if j not in model and j not in singular]
        if not cands:
            break
        tj = _added_t(a_full, b_full, mm, mv, c, n_eff, model, cands)
        t_try[cands] = tj
        order = np.argsort(-tj, kind="stable")
        best = None
        for q in order:
            if tj[q] < crit:
                break
            if frozenset([*model, cands[q]]) not in visited:
                best = cands[int(q)]
                break
        if best is None:
            break
        model.append(best)
        visited.add(frozenset(model))
        while len(model) > 1:
            fit = _iv_fit(a_full, b_full, mm, mv, c, n_eff, model)
            if fit is None:
                singular.add(model.pop())
                continue
            k = int(np.argmin(np.abs(fit[2])))
            if abs(fit[2][k]) >= crit:
                break
            model.pop(k)
            visited.add(frozenset(model))
    if not model:  # an equation needs a term: its strongest candidate, as elimination keeps
        model = [int(np.argmax(t_try))]
    keep = np.zeros(p, dtype=bool)
    theta_out = np.zeros(p)
    cov_out = np.zeros((p, p))
    t_out = t_try.copy()
    if model:
        fit = _iv_fit(a_full, b_full, mm, mv, c, n_eff, model)
        if fit is not None:
            keep[model] = True
            theta_out[model] = fit[0]
            cov_out[np.ix_(model, model)] = fit[1]
            t_out[model] = fit[2]
    return keep, theta_out, t_out, cov_out


def equilibrated_condition(m_mat: np.ndarray) -> float:
    """Condition number of ``Σ_b M_b`` after row and column equilibration (how well the
    model with every candidate is determined by its instruments)."""
    a = m_mat.sum(axis=0)
    r = np.abs(a).max(axis=1)
    r = np.where(r > 0, r, 1.0)
    a = a / r[:, None]
    c = np.abs(a).max(axis=0)
    a = a / np.where(c > 0, c, 1.0)[None, :]
    try:
        return float(np.linalg.cond(a))
    except np.linalg.LinAlgError:
        return math.inf


def select_equation(m_mat: np.ndarray, m_vec: np.ndarray, counts: np.ndarray, crit: float,
                    max_condition: float = 1e6):
    """Backward elimination (:func:`eliminate`) when the model with every candidate is
    well determined (equilibrated condition number at most ``max_condition``): each
    test then conditions on every other candidate, the consistent classical rule; else
    forward–backward :func:`stepwise`, which never fits the ill-conditioned full model."""
    if equilibrated_condition(m_mat) <= max_condition:
        return eliminate(m_mat, m_vec, counts, crit)
    return stepwise(m_mat, m_vec, counts, crit)


def indistinguishable(m_mat: np.ndarray, m_vec: np.ndarray, keep: np.ndarray, crit: float
                      ) -> dict[int, list[int]]:
    """Unselected candidates the log cannot tell apart from a selected one.

    For a selected ``j`` and an unselected ``k`` of the model ``S``: with both in the
    model (``S ∪ {k}``) neither ``|t_j|`` nor ``|t_k|`` reaches ``crit``, while ``S`` with
    ``j`` replaced by ``k`` keeps every term significant. The data then support the
    model with either but cannot say which (``|r|`` and ``r*r`` when the turn rate
    spans too narrow a range): the selection's choice between them is not evidence,
    and they are reported together. Returns ``{j: [k, ...]}`` (candidate indices).
    """
    c = np.ones(m_mat.shape[0])
    a_full = m_mat.sum(axis=0)
    b_full = m_vec.sum(axis=0)
    n_eff = float(c.sum())
    model = [int(j) for j in np.flatnonzero(keep)]
    out: dict[int, list[int]] = {}
    if not model:
        return out
    for k in (int(q) for q in np.flatnonzero(~keep)):
        both = _iv_fit(a_full, b_full, m_mat, m_vec, c, n_eff, [*model, k])
        if both is None:
            continue
        t_both = np.abs(both[2])
        if t_both[-1] >= crit:
            continue
        for q, j in enumerate(model):
            if t_both[q] >= crit:
                continue
            swapped = _iv_fit(a_full, b_full, m_mat, m_vec, c, n_eff,
                              [k if i == j else i for i in model])
            if swapped is not None and float(np.min(np.abs(swapped[2]))) >= crit:
                out.setdefault(j, []).append(k)
    return out

