"""Multi-objective stiffness optimisation loop shared by robot-free (model) and robot-based (simulator) tuning.

The loop asks the search strategy for a batch of per-phase stiffness proposals, evaluates them in one call
(one batched model prediction, or a few simulator rollouts), tells the outcomes and appends them to a log
that is saved atomically after every batch. A killed run resumes by replaying the log: the strategy is seeded,
so re-asking with the logged outcomes reproduces the same proposals without evaluating them again.

Every log carries a *fingerprint*: a JSON mapping of everything that determines its values (predictor content
hash, demo, simulator, stiffness space, search settings, seed, sampler ...). A log is only resumed by a run
with the same fingerprint; any other run stops with one line naming the log and what differs
(:class:`TrialLogMismatch`), unless it is told to overwrite the log.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from tqdm import tqdm

from dcm.data.atomic import atomic_path
from dcm.search import StiffnessSearch

# (B, P, 3) proposals in N/m, index of the batch's first trial -> (B, 2) objectives (L_task, L_comp); NaN rows
# mark failed trials. The index lets a stochastic evaluator seed each batch the same way whether the run
# was resumed or not.
BatchEvaluator = Callable[[np.ndarray, int], np.ndarray]


class TrialLogMismatch(ValueError):
    """A trial log on disk that this run cannot resume: another configuration wrote it, or it does not replay."""


@dataclass
class TrialLog:
    """Every proposal and its outcome, in the order they were asked, and the fingerprint of what produced them."""

    phase_stiffness: list[np.ndarray] = field(default_factory=list)  # each (P, 3) N/m
    objectives: list[np.ndarray] = field(default_factory=list)  # each (2,), NaN if the trial failed
    fingerprint: dict[str, Any] | None = None  # JSON mapping; None: the log records none
    # Not part of the fingerprint, only quoted in messages (e.g. the checkpoint path that was hashed).
    notes: dict[str, Any] = field(default_factory=dict)

    def __len__(self) -> int:
        return len(self.objectives)

    def arrays(self) -> tuple[np.ndarray, np.ndarray]:
        return np.stack(self.phase_stiffness), np.stack(self.objectives)

    def save(self, path: Path) -> None:
        extra = {}
        if self.fingerprint is not None:
            extra["fingerprint"] = np.asarray(json.dumps(self.fingerprint, sort_keys=True))
            extra["notes"] = np.asarray(json.dumps(self.notes, sort_keys=True, default=str))
        with atomic_path(path) as tmp, open(tmp, "wb") as f:
            np.savez(f, phase_stiffness=np.stack(self.phase_stiffness), objectives=np.stack(self.objectives), **extra)

    @classmethod
    def load(cls, path: Path) -> TrialLog:
        with np.load(path) as saved:
            fingerprint = json.loads(str(saved["fingerprint"])) if "fingerprint" in saved.files else None
            notes = json.loads(str(saved["notes"])) if "notes" in saved.files else {}
            return cls(list(saved["phase_stiffness"]), list(saved["objectives"]), fingerprint, notes)


def fingerprint_differences(old: Mapping[str, Any], new: Mapping[str, Any], old_notes: Mapping[str, Any] | None = None,
                            new_notes: Mapping[str, Any] | None = None) -> list[str]:
    """``key: old -> new`` for every setting that differs between two fingerprints (flattened keys).

    A differing ``predictor_sha256`` is shown with the files it was computed from (``notes["predictor"]``)."""
    from dcm.configs import config_diff

    lines = config_diff(old, new)
    old_notes, new_notes = old_notes or {}, new_notes or {}
    for i, line in enumerate(lines):
        if line.startswith("predictor_sha256:"):
            was, now = str(old.get("predictor_sha256"))[:12], str(new.get("predictor_sha256"))[:12]
            lines[i] = (f"predictor: {old_notes.get('predictor', '?')} (sha256 {was}) "
                        f"-> {new_notes.get('predictor', '?')} (sha256 {now})")
    return lines


def resumable_log(path: Path | None, fingerprint: Mapping[str, Any] | None, overwrite: bool = False,
                  notes: Mapping[str, Any] | None = None) -> TrialLog:
    """The log at ``path`` if this run may resume it, else an empty log.

    A log written with another fingerprint (or without one) raises :class:`TrialLogMismatch` naming the file
    and the differing settings; with ``overwrite`` it is discarded instead (the file is replaced at the first
    save). A log with the same fingerprint is resumed either way: replaying it gives the values a rerun would.
    ``fingerprint=None`` skips the check (plain library use).
    """
    if path is None or not Path(path).exists():
        return TrialLog()
    log = TrialLog.load(Path(path))
    if fingerprint is None:
        return log
    fingerprint = json.loads(json.dumps(fingerprint, sort_keys=True))  # compare what would be saved
    if log.fingerprint == fingerprint:
        return log
    if overwrite:
        return TrialLog()
    if log.fingerprint is None:
        why = "it holds no fingerprint of the settings that wrote it (an older version of the tuner wrote it)"
    else:
        why = "it was written with other settings: " + "; ".join(
            fingerprint_differences(log.fingerprint, fingerprint, log.notes, notes))
    raise TrialLogMismatch(f"{path}: cannot resume its {len(log)} trials: {why}; use another run directory "
                           "(hydra.run.dir=...) or overwrite=true to discard them")


def ask_batch(search: StiffnessSearch, count: int) -> np.ndarray:
    """``count`` proposals (count, P, 3) evaluated together: from one fit where the strategy plans batches
    (``ask_batch``, e.g. batched MOTPE), else one ask after another."""
    if hasattr(search, "ask_batch"):
        return np.asarray(search.ask_batch(count))
    return np.stack([search.ask() for _ in range(count)])


def _tell(search: StiffnessSearch, objectives: np.ndarray) -> None:
    search.tell(None if np.isnan(objectives).any() else (float(objectives[0]), float(objectives[1])))


@dataclass
class LoopTimes:
    """What one :func:`optimize` call spent: wall time by where it went [s], and how many of its log's trials it
    replayed from an earlier run's log (at no evaluation cost) and how many it evaluated, so a resumed run's
    time is read as the time of the trials it computed, not of all of them."""

    ask: float = 0.0  # search.ask (the optimiser proposing)
    tell: float = 0.0  # search.tell (the optimiser updating)
    evaluate: float = 0.0  # the evaluator (model prediction with its input preparation, or rollouts)
    total: float = 0.0  # everything, including replay, logging and saving
    replayed: int = 0  # trials taken from the log on disk, asked again but not evaluated
    computed: int = 0  # trials evaluated by this call

    @property
    def optimiser(self) -> float:
        return self.ask + self.tell

    @property
    def overhead(self) -> float:
        return max(0.0, self.total - self.optimiser - self.evaluate)


def optimize(
    search: StiffnessSearch,
    evaluate: BatchEvaluator,
    n_trials: int,
    batch_size: int = 1,
    log_path: Path | None = None,
    desc: str = "trials",
    fingerprint: Mapping[str, Any] | None = None,
    overwrite: bool = False,
    notes: Mapping[str, Any] | None = None,
    times: LoopTimes | None = None,
    progress: bool = True,
) -> TrialLog:
    """Run ``n_trials`` trials of ``search`` in batches; resume from ``log_path`` if it holds earlier trials.

    ``fingerprint`` (a JSON mapping) is stored in the log and must match a log being resumed (see
    :func:`resumable_log`; ``overwrite`` discards a mismatching one). ``notes`` are stored beside it for
    messages only. ``evaluate(proposals, first)`` gets the index of the batch's first trial. ``times``, if
    given, accumulates where the wall time went.
    """
    if n_trials < 1 or batch_size < 1:
        raise ValueError(f"n_trials={n_trials} and batch_size={batch_size} must both be >= 1")
    started = time.perf_counter()
    times = times if times is not None else LoopTimes()
    previous = resumable_log(log_path, fingerprint, overwrite, notes)
    saved_fingerprint = json.loads(json.dumps(dict(fingerprint), sort_keys=True)) if fingerprint is not None else None
    log = TrialLog(fingerprint=saved_fingerprint if fingerprint is not None else previous.fingerprint,
                   notes=dict(notes or previous.notes))
    # Replay in the batches the trials were asked in: a batch's later proposals depend on its pending ones.
    for first in range(0, len(previous), batch_size):
        logged = slice(first, min(first + batch_size, len(previous)))
        proposals = ask_batch(search, logged.stop - logged.start)
        for i, proposal in enumerate(proposals, start=first):
            if not np.allclose(proposal, previous.phase_stiffness[i]):
                raise TrialLogMismatch(
                    f"{log_path}: trial {i} does not replay (the search config, seed, batch size or the optimiser's "
                    "version changed); use another run directory or overwrite=true to discard the log"
                )
        for proposal, outcome in zip(proposals, previous.objectives[logged]):
            _tell(search, outcome)
            log.phase_stiffness.append(proposal)
            log.objectives.append(outcome)
    times.replayed = len(previous)
    with tqdm(total=n_trials, initial=len(log), desc=desc, unit="trial", dynamic_ncols=True,
              disable=not progress) as bar:
        while len(log) < n_trials:
            count = min(batch_size, n_trials - len(log))
            t0 = time.perf_counter()
            proposals = ask_batch(search, count)
            t1 = time.perf_counter()
            outcomes = np.asarray(evaluate(proposals, len(log)), dtype=np.float64).reshape(count, 2)
            t2 = time.perf_counter()
            for proposal, outcome in zip(proposals, outcomes):
                _tell(search, outcome)
                log.phase_stiffness.append(proposal)
                log.objectives.append(outcome)
            t3 = time.perf_counter()
            times.ask, times.evaluate, times.tell = times.ask + t1 - t0, times.evaluate + t2 - t1, times.tell + t3 - t2
            times.computed += count
            if log_path is not None:
                log.save(log_path)
            bar.update(count)
    times.total += time.perf_counter() - started
    return log
