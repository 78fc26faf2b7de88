"""Does the fast sampler rank a skill's candidate schedules as the previous default does?

    python -m studies.tuning_speed.ranking [--skill wavelike] [--count 300] [--log <robot_free_trials.npz>]
        [--threads 1]

Why: the robot-free search only needs the model's order of schedules within the skill. The candidates are
proposals a tuner actually met: ``--count`` schedules drawn (seeded) from a robot-free trial log of the skill
(``--log``; default: a seeded random draw from the search box when no log is given). Each setting predicts
their L_task on the quickstart's recording of the skill, every batch seeded as the tuner seeds it, and is
compared with the previous default (DDIM 5 steps, float32) by Spearman and Pearson correlation.
"""

from __future__ import annotations

import argparse
import warnings
from collections.abc import Sequence
from pathlib import Path

import numpy as np

SETTINGS = {
    "ddim-5 float32 (previous default)": ["robot_free.sampler=ddim", "robot_free.sampling_steps=5",
                                          "robot_free.precision=float32"],
    "ddim-5 bfloat16": ["robot_free.sampler=ddim", "robot_free.sampling_steps=5", "robot_free.precision=bfloat16"],
    "ddim-1 float32": ["robot_free.sampler=ddim", "robot_free.sampling_steps=1", "robot_free.precision=float32"],
    "ddim-1 auto": ["robot_free.sampler=ddim", "robot_free.sampling_steps=1"],
    "ddim-2 auto": ["robot_free.sampler=ddim", "robot_free.sampling_steps=2"],
    "ddim-3 auto": ["robot_free.sampler=ddim", "robot_free.sampling_steps=3"],
    "ddim-5 auto": ["robot_free.sampler=ddim", "robot_free.sampling_steps=5"],
}


def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--skill", default="wavelike")
    parser.add_argument("--count", type=int, default=300)
    parser.add_argument("--log", type=Path, default=None, help="a robot_free_trials.npz of the skill")
    parser.add_argument("--threads", type=int, default=1)
    args = parser.parse_args(argv)

    import torch
    from scipy.stats import pearsonr, spearmanr

    from dcm.devices import resolve_device
    from dcm.tuning.checks import check_config
    from dcm.tuning.objectives import ModelObjective
    from dcm.tuning.optimize import TrialLog
    from dcm.tuning.predictor import load_predictor
    from dcm.tuning.setup import record_skill
    from studies.tuning_speed.compare_defaults import tune_config

    torch.set_num_threads(args.threads)
    rng = np.random.default_rng(0)
    base = tune_config(args.skill, 0, "new", args.threads, Path("unused"))
    checked = check_config(base)
    simulator, demo, skill = record_skill(base, checked)
    if args.log is not None:
        params = TrialLog.load(args.log).arrays()[0]
        params = params[np.sort(rng.choice(len(params), min(args.count, len(params)), replace=False))]
        source = f"{len(params)} proposals of {args.log}"
    else:
        space = checked.space
        params = rng.uniform(space.min_Npm, space.max_Npm, (args.count, space.n_phases, 3))
        source = f"{len(params)} seeded uniform draws from the search box"
    predicted = {}
    for name, overrides in SETTINGS.items():
        cfg = tune_config(args.skill, 0, "new", args.threads, Path("unused"), overrides)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            model = load_predictor(cfg, checked.spec, resolve_device(cfg.device, "device"))
        objective = ModelObjective(model, skill, simulator, demo, 1, seed=0)
        batch = int(cfg.robot_free.batch_size)
        predicted[name] = np.concatenate([objective(params[i:i + batch], i)[:, 0]
                                          for i in range(0, len(params), batch)])
    reference = predicted[next(iter(SETTINGS))]
    print(f"skill {args.skill} (quickstart's recording), {source}; predicted L_task against "
          f"{next(iter(SETTINGS))}:")
    print("| setting | Spearman | Pearson | median abs. difference (N) | L_task range (N) |")
    print("|---|---|---|---|---|")
    for name, values in predicted.items():
        print(f"| {name} | {spearmanr(reference, values)[0]:.3f} | {pearsonr(reference, values)[0]:.3f} | "
              f"{np.median(np.abs(values - reference)):.4f} | {np.ptp(values):.3f} |")


if __name__ == "__main__":
    main()
