"""The one seed scheme: a root seed, one child per run, one grandchild per experiment.

Every simulation draws run ``r`` from ``default_rng(run_seeds(seed, R)[r])``
(``SeedSequence(seed).spawn(R)[r]``), so any run can be regenerated alone and results do
not depend on batching, threads or workers. A signal drawn apart from a run's main stream
(the experiments of a Monte Carlo run, the reference of a closed loop) uses
:func:`child` of the run's seed with its own key. A study that needs a stream
independent of another study with the same root seed names its offset in
:data:`STUDY_OFFSETS`.
"""

from __future__ import annotations

import numpy as np

__all__ = ["STUDY_OFFSETS", "SeedLike", "child", "experiment_seed", "root", "run_seeds",
           "study_seed"]

SeedLike = int | np.random.SeedSequence | None

#: Offsets of the root seed that keep studies with the same ``--seed`` independent:
#: the paper's Table 2 (Table 1 uses the seed itself) and the sea-trial runs of the
#: calibration study (its heave scenarios use the seed itself).
STUDY_OFFSETS: dict[str, int] = {"table2": 1, "calibration-seatrial": 2000}


def root(seed: SeedLike) -> np.random.SeedSequence:
    """``seed`` as a :class:`~numpy.random.SeedSequence` (one passes through)."""
    return seed if isinstance(seed, np.random.SeedSequence) else np.random.SeedSequence(seed)


def run_seeds(seed: SeedLike, n_runs: int) -> list[np.random.SeedSequence]:
    """The seeds of runs ``0 … n_runs − 1``: the children of the root seed."""
    return root(seed).spawn(int(n_runs))


def child(seed: np.random.SeedSequence, key: int) -> np.random.SeedSequence:
    """The child ``key`` of ``seed`` (e.g. experiment ``e`` of a run, or a named stream),
    without advancing ``seed``'s own spawn counter."""
    return np.random.SeedSequence(seed.entropy, spawn_key=(*seed.spawn_key, int(key)))


def study_seed(seed: int, study: str) -> int:
    """The root seed of ``study`` for the user's ``seed`` (:data:`STUDY_OFFSETS`)."""
    return int(seed) + STUDY_OFFSETS[study]


def experiment_seed(seed: int, experiment: int) -> int:
    """The integer seed of experiment ``experiment`` of a deterministic design evaluation
    (the trial planner's disturbed paths of its experiment ``e``: ``seed + e``), so that
    the experiments of one plan draw different paths and one plan is reproducible."""
    return int(seed) + int(experiment)
