"""How the robot loop proposes a round: the model corrected on this skill from every observed trial, a search on the
corrected objective seeded by the round, and ``loop.batch`` picks spread along the corrected front of every
virtual trial so far, none of them a schedule already observed or proposed.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from dcm.tuning.correction import make_correction
from dcm.tuning.loop_state import LoopRun, LoopState, Round, same_schedule
from dcm.tuning.objectives import OBSERVED_BATCH, round_batch
from dcm.tuning.pareto import pick_spread


def _model_predictions(run: LoopRun, state: LoopState, params: np.ndarray, rounds: list[int]) -> np.ndarray:
    """The model's own (uncorrected) L_task of observed trials: the prediction made when the schedule was
    proposed, or a fresh one for a trial the robot ran without it being proposed."""
    proposed = {r.index: r for r in state.rounds}
    out = np.full(len(params), np.nan)
    missing = []
    for i, (k, r) in enumerate(zip(params, rounds)):
        entry = proposed.get(r)
        match = [] if entry is None else [j for j, c in enumerate(entry.proposals) if same_schedule(k[None], c[None])[0]]
        if match:
            out[i] = entry.model_L_task_N[match[0]]
        else:
            missing.append(i)
    if missing:
        out[missing] = run.model_objective(params[missing], OBSERVED_BATCH)[:, 0]
    return out


def fit_correction(run: LoopRun, state: LoopState) -> Any:
    observed, objectives, rounds = state.observed()
    model = _model_predictions(run, state, observed, rounds)
    correction = make_correction(str(run.loop.correction), run.space.min_Npm, run.space.max_Npm,
                                 lengthscale=float(run.loop.lengthscale), noise_ratio=float(run.loop.noise_ratio),
                                 ridge_alpha=float(run.loop.ridge_alpha))
    return correction.fit(observed, objectives[:, 0] - model)


def round_search(run: LoopRun, round_index: int, correction: Any) -> tuple[np.ndarray, np.ndarray]:
    """``loop.n_trials`` virtual trials of a search on the corrected objective, seeded by the round: their per-phase
    stiffness and the model's own (uncorrected) objectives."""
    from dcm.search import make_search
    from dcm.tuning.optimize import optimize

    n_trials = int(run.loop.n_trials)
    if n_trials == 0:
        return np.zeros((0, run.space.n_phases, 3)), np.zeros((0, 2))
    seed = int(np.random.SeedSequence([int(run.settings.seed), round_index]).generate_state(1)[0] >> 1)
    search = make_search(run.settings.search.name, run.space, seed, **run.search_options)
    raw: list[np.ndarray] = []

    def corrected(proposals: np.ndarray, first: int) -> np.ndarray:
        predicted = run.model_objective(proposals, round_batch(round_index, first))
        raw.append(predicted.copy())
        predicted[:, 0] += correction(proposals)
        return predicted

    log = optimize(search, corrected, n_trials, int(run.settings.robot_free.batch_size),
                   desc=f"round {round_index} search (corrected model)")
    return log.arrays()[0], np.concatenate(raw)


def pick_batch(objectives: np.ndarray, count: int) -> np.ndarray:
    """Indices of ``count`` rows: picks spread along the front, then along the next front of what is left, ...
    (a round runs ``loop.batch`` schedules even where the corrected front holds fewer)."""
    left, chosen = np.arange(len(objectives)), []
    while len(chosen) < count:
        picks = pick_spread(objectives[left], count - len(chosen))
        if not len(picks):
            break
        chosen.extend(left[picks].tolist())
        left = np.delete(left, picks)
    return np.asarray(chosen, dtype=int)


def propose(run: LoopRun, state: LoopState, round_index: int) -> Round:
    """Round ``round_index``: its proposals with their predicted (corrected) and model objectives."""
    batch = int(run.loop.batch)
    if round_index == 1:
        correction = make_correction("none", run.space.min_Npm, run.space.max_Npm)
        search = (np.zeros((0, run.space.n_phases, 3)), np.zeros((0, 2)))
    else:
        correction = fit_correction(run, state)
        search = round_search(run, round_index, correction)
    earlier, earlier_raw = state.searched()
    params = np.concatenate([p for p in (run.free_params, earlier, search[0]) if len(p)])
    raw = np.concatenate([p for p in (run.free_predicted, earlier_raw, search[1]) if len(p)])
    predicted = raw.copy()
    predicted[:, 0] += correction(params)
    observed = state.observed()[0]
    proposed = np.concatenate([r.proposals for r in state.rounds]) if state.rounds \
        else np.zeros((0, run.space.n_phases, 3))
    fresh = np.flatnonzero(~same_schedule(params, observed) & ~same_schedule(params, proposed))
    picks = fresh[pick_batch(predicted[fresh], batch)]
    searched = len(search[0]) > 0
    return Round(round_index, params[picks], predicted[picks], raw[picks, 0], correction.describe(),
                 search[0] if searched else None, search[1] if searched else None)


__all__ = ["fit_correction", "pick_batch", "propose", "round_search"]
