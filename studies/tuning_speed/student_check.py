"""Does the one-step student return what its teacher's chain returns, on trials neither trained on?

    python -m studies.tuning_speed.student_check [--student models/dcm_diverse_contact_one_step.ckpt]
        [--teacher models/dcm_diverse_contact.ckpt] [--dataset data/diverse_contact.h5] [--split valid] [--draws 2]

For every trial of ``--split`` and ``--draws`` seeded start noises z, the teacher's deterministic DDIM chain
(the student card's number of steps, :func:`dcm.training.distill.teacher_pairs`) and the student's one call from
the same z, in normalised units: the student's MSE to the teacher, the MSE a z-blind student would have (each
trial's mean over draws), the spread over draws of each, and the correlation of their deviations from the
trial's mean (does the noise move the student's sample as it moves the teacher's?).
"""

from __future__ import annotations

import argparse
import warnings
from collections.abc import Sequence
from pathlib import Path


def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--student", type=Path, default=Path("models/dcm_diverse_contact_one_step.ckpt"))
    parser.add_argument("--teacher", type=Path, default=Path("models/dcm_diverse_contact.ckpt"))
    parser.add_argument("--dataset", type=Path, default=Path("data/diverse_contact.h5"))
    parser.add_argument("--split", default="valid")
    parser.add_argument("--draws", type=int, default=2)
    parser.add_argument("--seed", type=int, default=1, help="of the start noises (the student trained on seed 0's)")
    args = parser.parse_args(argv)

    import torch

    from dcm.data.datamodule import TrajectoryDataset
    from dcm.data.schema import load_dataset
    from dcm.models.checkpoint import checkpoint_card
    from dcm.models.predict import load_model
    from dcm.training.distill import DistillSettings, teacher_pairs

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        teacher, student = load_model(args.teacher), load_model(args.student)
    steps = checkpoint_card(args.student)["distilled"]["teacher_steps"]
    cond_n = teacher.normalized_cond(TrajectoryDataset.from_loaded(load_dataset(args.dataset, split=args.split)).cond)
    z, x0 = teacher_pairs(teacher, cond_n, DistillSettings(draws=args.draws, teacher_steps=steps, seed=args.seed),
                          progress=False)
    top = torch.full((z.shape[1],), student.cfg.diffusion_steps - 1, dtype=torch.long)
    clip = student.noise_schedule.clip_sample_range
    with torch.no_grad():
        out = torch.stack([student.inference_net(cond_n, z[d], top) for d in range(len(z))])
    out = out if clip is None else out.clamp(-clip, clip)
    mse, blind = float(((out - x0) ** 2).mean()), float(x0.var(dim=0, unbiased=False).mean())
    spread_t, spread_s = float(x0.std(dim=0, unbiased=False).mean()), float(out.std(dim=0, unbiased=False).mean())
    corr = float(torch.corrcoef(torch.stack([(x0 - x0.mean(0)).flatten(), (out - out.mean(0)).flatten()]))[0, 1])
    print(f"{args.split} of {args.dataset}, {len(z)} draws x {z.shape[1]} trials, teacher DDIM-{steps}: student MSE "
          f"{mse:.2e}, z-blind MSE {blind:.2e}; spread over draws (normalised) teacher {spread_t:.4f}, student "
          f"{spread_s:.4f}; correlation of the deviations from each trial's mean {corr:.3f}")


if __name__ == "__main__":
    main()
