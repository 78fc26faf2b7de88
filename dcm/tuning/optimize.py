"""Multi-objective stiffness optimisation loop shared by robot-free (model) and robot-based (simulator) tuning.

The loop asks the search strategy for a batch of per-phase stiffness proposals, evaluates them in one call
(one batched model prediction, or a few simulator rollouts), tells the outcomes and appends them to a log
that is saved atomically after every batch. A killed run resumes by replaying the log: the strategy is seeded,
so re-asking with the logged outcomes reproduces the same proposals without evaluating them again.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np
from tqdm import tqdm

from dcm.data.atomic import atomic_path
from dcm.data.search import StiffnessSearch

# (B, P, 3) proposals in N/m -> (B, 2) objectives (L_task, L_comp); NaN rows mark failed trials.
BatchEvaluator = Callable[[np.ndarray], np.ndarray]


@dataclass
class TrialLog:
    """Every proposal and its outcome, in the order they were asked."""

    phase_stiffness: list[np.ndarray] = field(default_factory=list)  # each (P, 3) N/m
    objectives: list[np.ndarray] = field(default_factory=list)  # each (2,), NaN if the trial failed

    def __len__(self) -> int:
        return len(self.objectives)

    def arrays(self) -> tuple[np.ndarray, np.ndarray]:
        return np.stack(self.phase_stiffness), np.stack(self.objectives)

    def save(self, path: Path) -> None:
        with atomic_path(path) as tmp, open(tmp, "wb") as f:
            np.savez(f, phase_stiffness=np.stack(self.phase_stiffness), objectives=np.stack(self.objectives))

    @classmethod
    def load(cls, path: Path) -> "TrialLog":
        with np.load(path) as saved:
            return cls(list(saved["phase_stiffness"]), list(saved["objectives"]))


def _tell(search: StiffnessSearch, objectives: np.ndarray) -> None:
    search.tell(None if np.isnan(objectives).any() else (float(objectives[0]), float(objectives[1])))


def optimize(
    search: StiffnessSearch,
    evaluate: BatchEvaluator,
    n_trials: int,
    batch_size: int = 1,
    log_path: Path | None = None,
    desc: str = "trials",
) -> TrialLog:
    """Run ``n_trials`` trials of ``search`` in batches; resume from ``log_path`` if it holds earlier trials."""
    if n_trials < 1 or batch_size < 1:
        raise ValueError(f"n_trials={n_trials} and batch_size={batch_size} must both be >= 1")
    log = TrialLog()
    previous = TrialLog.load(log_path) if log_path is not None and log_path.exists() else TrialLog()
    # Replay in the batches the trials were asked in: a batch's later proposals depend on its pending ones.
    for first in range(0, len(previous), batch_size):
        logged = slice(first, min(first + batch_size, len(previous)))
        proposals = [search.ask() for _ in range(logged.stop - logged.start)]
        for i, proposal in enumerate(proposals, start=first):
            if not np.allclose(proposal, previous.phase_stiffness[i]):
                raise RuntimeError(
                    f"{log_path}: trial {i} does not replay (the search config, seed or batch size changed); "
                    "delete the file or use another output directory"
                )
        for proposal, outcome in zip(proposals, previous.objectives[logged]):
            _tell(search, outcome)
            log.phase_stiffness.append(proposal)
            log.objectives.append(outcome)
    with tqdm(total=n_trials, initial=len(log), desc=desc, unit="trial", dynamic_ncols=True) as bar:
        while len(log) < n_trials:
            count = min(batch_size, n_trials - len(log))
            proposals = np.stack([search.ask() for _ in range(count)])
            outcomes = np.asarray(evaluate(proposals), dtype=np.float64).reshape(count, 2)
            for proposal, outcome in zip(proposals, outcomes):
                _tell(search, outcome)
                log.phase_stiffness.append(proposal)
                log.objectives.append(outcome)
            if log_path is not None:
                log.save(log_path)
            bar.update(count)
    return log
