"""Does the tuner's sampler rank a skill's trials as the checkpoint's own does? Within-skill ranking on valid.

    python -m studies.tuning_speed.valid_ranking [--dataset data/diverse_contact_valid.h5] [--split valid]
        [--ckpt models/dcm_diverse_contact.ckpt] [--seeds 0 1 2] [--threads 1] [--settings own ddim3 ...]
        [--first N]

Why: the robot-free search only needs the model's order of one skill's schedules, and the model table's
metric for that is the Spearman correlation of predicted against simulated L_task across one skill's trials,
averaged over skills (``R_within_spearman``, :func:`dcm.models.metrics.ranking_metrics`). Each setting scores
the same trajectories with :func:`dcm.evaluate.score` (the sampling generator seeded with each ``--seed``), in
float32, as ``tune.py`` predicts where the CPU has no native bfloat16. The valid split of ``diverse_contact``
alone is ``dcm-generate dataset=diverse_contact "splits=[valid]" out=data/diverse_contact_valid.h5``.
"""

from __future__ import annotations

import argparse
import os
import time
import warnings
from collections.abc import Sequence
from pathlib import Path

import numpy as np

# label -> (sampler, sampling steps, samples, task loss, shared steps); None keeps the checkpoint's
SETTINGS = {
    "own": (None, None, 1, "of_mean", 0),
    "own_k16": (None, None, 16, "over_samples", "auto"),  # e.g. a one-step student's spread (dcm-distill)
    "ddim5": ("ddim", 5, 1, "of_mean", 0),  # the tuner's default before DDIM-3
    "ddim10": ("ddim", 10, 1, "of_mean", 0),  # the one-step student's teacher (dcm-distill)
    "ddim3": ("ddim", 3, 1, "of_mean", 0),
    "ddim3_k16_independent": ("ddim", 3, 16, "over_samples", 0),
    "ddim3_k16_shared": ("ddim", 3, 16, "over_samples", "auto"),
    # steps spread evenly from t = T-1 to t = 0 (the last net call sees an almost clean force)
    "even2": ("ddim_even", 2, 1, "of_mean", 0),
    "even3": ("ddim_even", 3, 1, "of_mean", 0),
    "even2_k16_shared": ("ddim_even", 2, 16, "over_samples", "auto"),
    "even3_k16_shared": ("ddim_even", 3, 16, "over_samples", "auto"),
}


def describe_setting(model: object, label: str) -> str:
    from dcm.models.predict import describe

    sampler, steps, k, task, shared = SETTINGS[label]
    d = describe(model, k)
    text = f"{d['sampler']}, {d['sampling_steps']} steps, k = {k}, {task}"
    return text + (f", {d['shared_steps']} shared steps" if d.get("shared_steps") else "")


def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--dataset", type=Path, default=Path("data/diverse_contact_valid.h5"))
    parser.add_argument("--split", default="valid")
    parser.add_argument("--ckpt", type=Path, default=Path("models/dcm_diverse_contact.ckpt"))
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--settings", nargs="+", default=list(SETTINGS), choices=list(SETTINGS))
    parser.add_argument("--first", type=int, default=None,
                        help="score only the split's first N trials (whole skills when N is a multiple of 20)")
    args = parser.parse_args(argv)

    import torch

    from dcm.data.datamodule import TrajectoryDataset
    from dcm.data.schema import load_dataset
    from dcm.evaluate import score
    from dcm.models.predict import load_model

    torch.set_num_threads(args.threads)
    loaded = load_dataset(args.dataset, split=args.split)
    data, skills = TrajectoryDataset.from_loaded(loaded).subset(args.first), loaded.demo_ids[: args.first]
    print(f"{args.ckpt} on {args.dataset} ({args.split}: {len(data)} trials, {len(np.unique(skills))} skills), "
          f"seeds {args.seeds}, torch threads {args.threads}, load average "
          f"{'/'.join(f'{v:.2f}' for v in os.getloadavg())}", flush=True)
    print("| setting | what | Spearman within per seed | mean | Pearson within mean | mean spread xyz (N) | s |")
    print("|---|---|---|---|---|---|---|")
    for label in args.settings:
        sampler, steps, k, task, shared = SETTINGS[label]
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            model = load_model(args.ckpt)
        if sampler is not None:
            model.set_sampler(sampler, steps)
        model.set_task_loss(task)
        model.set_shared_steps(shared)
        start = time.perf_counter()
        results = [score(model, data, skills, k, seed) for seed in args.seeds]
        seconds = time.perf_counter() - start
        spearman = [r["R_within_spearman"] for r in results]
        pearson = [r["R_within"] for r in results]
        spread = [r.get("mean_std_N", float("nan")) for r in results]
        print(f"| {label} | {describe_setting(model, label)} | {', '.join(f'{v:.4f}' for v in spearman)} | "
              f"{np.mean(spearman):.4f} | {np.mean(pearson):.4f} | {np.mean(spread):.4f} | {seconds:.0f} |",
              flush=True)


if __name__ == "__main__":
    main()
