"""The result of :func:`~vesselid.selection.select_terms`: chosen spec, table and report."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pandas as pd

from vesselid.core.fileio import atomic_write_text
from vesselid.model.spec import ModelSpec

__all__ = ["SelectionResult"]


@dataclass
class SelectionResult:
    """Selected model structure with the evidence for every candidate.

    Attributes
    ----------
    spec : ModelSpec
        The base spec with the selected terms (no ``theta0``); ``vesselid identify`` runs
        on it.
    base : ModelSpec
        The base spec.
    library : dict
        The candidates per equation.
    table : DataFrame
        One row per candidate: ``equation, term, represented_by`` (the candidate that
        stands for it in this log: itself, the earlier candidate it is the same as, or
        empty for a linear combination of several), ``selected, probability`` (block-bootstrap
        share of replicates keeping it, or its group's representative), ``estimate``,
        ``stderr`` (IV with the final instruments, batch-means HAC), ``t`` (in the final
        model, or in the model it was dropped from), ``same_as`` (why it is not a
        separate candidate in this log), ``alternatives`` (unselected candidates almost
        collinear with a selected one), ``undecided`` (unselected candidates the log
        cannot tell apart from this selected one:
        :func:`~vesselid.selection.engine.indistinguishable`).
    groups : dict
        Per equation, the candidates that are the same in the data.
    theta : Series or None
        Refined-IV estimate (zero-mean instruments) of the selected spec.
    """

    spec: ModelSpec
    base: ModelSpec
    library: dict
    table: pd.DataFrame
    groups: dict
    alpha: float
    critical_value: float
    n_candidates: int
    n_boot: int
    block_length: int
    n_blocks: int
    passes: int
    converged: bool
    history: list
    aux_source: str
    n_samples: int
    n_experiments: int
    seed: int
    theta: pd.Series | None = None
    notes: list[str] = field(default_factory=list)

    @property
    def selected(self) -> dict[str, list[str]]:
        """state -> selected terms."""
        return {s: [str(t) for t in self.spec.equations[s]] for s in self.spec.states}

    def probabilities(self) -> pd.Series:
        """Selection probability of every candidate, indexed by (equation, term)."""
        return self.table.set_index(["equation", "term"])["probability"]

    # ----------------------------------------------------------------- output
    def summary(self) -> str:
        """Human-readable report."""
        lines = [
            f"Term selection for {self.base.name!r}: {self.n_samples} samples, "
            f"{self.n_experiments} experiment(s)",
            f"IV stepwise selection, instruments from the {self.aux_source}; "
            f"|t| >= {self.critical_value:.3g} (alpha {self.alpha:g} over "
            f"{self.n_candidates} candidates, or sqrt(log n)); batch-means HAC, "
            f"{self.n_blocks} blocks of {self.block_length} samples",
            f"passes: {self.passes} ({'structure settled' if self.converged else 'last pass'})"
            + (f"; selection probabilities from {self.n_boot} block-bootstrap replicates"
               if self.n_boot else ""),
        ]
        for s in self.spec.states:
            sub = self.table[self.table.equation == s]
            lines.append("")
            lines.append(f"equation {s}: " + ", ".join(self.selected[s]))
            lines.append(f"  {'term':<14}{'sel':>4}{'prob':>7}{'estimate':>13}{'t':>10}  note")
            shown = sub[sub.selected | (sub.probability.fillna(0) >= 0.05)
                        | (sub.same_as != "") & sub.term.isin(_group_members(self.groups[s]))]
            for r in shown.itertuples():
                note = r.same_as or "; ".join(
                    x for x in (f"near: {r.alternatives}" if r.alternatives else "",
                                f"or: {r.undecided}" if r.undecided else "") if x)
                prob = "" if math.isnan(r.probability) else f"{r.probability:.2f}"
                est = "" if math.isnan(r.estimate) else f"{r.estimate:.5g}"
                tt = "" if math.isnan(r.t) else f"{r.t:.1f}"
                lines.append(f"  {r.term:<14}{'*' if r.selected else '':>4}{prob:>7}{est:>13}"
                             f"{tt:>10}  {note}")
            rest = len(sub) - len(shown)
            if rest:
                lines.append(f"  ({rest} more candidates: never or rarely kept)")
        return "\n".join(lines)

    def to_dict(self) -> dict[str, Any]:
        """Plain-data (JSON-ready; non-finite numbers as None)."""
        def num(x: Any) -> Any:
            return None if isinstance(x, float) and not math.isfinite(x) else x

        return {
            "spec": self.spec.to_dict(),
            "selected": self.selected,
            "candidates": [{k: num(v) for k, v in row.items()}
                           for row in self.table.to_dict(orient="records")],
            "groups": self.groups,
            "estimate": (None if self.theta is None else
                         {s: {str(t): num(float(self.theta[(s, str(t))]))
                              for t in self.spec.equations[s]} for s in self.spec.states}),
            "alpha": self.alpha,
            "critical_value": self.critical_value,
            "candidates_tested": self.n_candidates,
            "bootstrap": self.n_boot,
            "block_length": self.block_length,
            "blocks": self.n_blocks,
            "passes": self.passes,
            "converged": self.converged,
            "history": self.history,
            "instruments": self.aux_source,
            "samples": self.n_samples,
            "experiments": self.n_experiments,
            "seed": self.seed,
            "notes": list(self.notes),
        }

    def to_toml(self) -> str:
        """The selected spec (TOML contract) followed by the selection report as comments."""
        lines = [self.spec.to_toml().rstrip(), "",
                 "# Selected by `vesselid select` (IV stepwise selection, HAC Wald tests, "
                 f"|t| >= {self.critical_value:.3g}).",
                 f"# Selection probability over {self.n_boot} block-bootstrap replicates "
                 f"(blocks of {self.block_length} samples):"]
        for r in self.table.itertuples():
            prob = "   -" if math.isnan(r.probability) else f"{r.probability:4.2f}"
            tail = f"  ({r.same_as})" if r.same_as else ""
            lines.append(f"#   {r.equation:<6} {r.term:<14} {'kept' if r.selected else '    '} "
                         f"{prob}{tail}")
        return "\n".join(lines) + "\n"

    def save(self, path: str | Path) -> Path:
        """Write :meth:`to_toml` atomically."""
        atomic_write_text(Path(path), self.to_toml())
        return Path(path)

    def __repr__(self) -> str:
        return f"SelectionResult({self.selected})"


def _group_members(groups: list[dict]) -> list[str]:
    return [m for g in groups for m in g["members"]]
