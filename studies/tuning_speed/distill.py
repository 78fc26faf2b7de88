"""A one-step student of the DCM: one net call maps the start noise to the teacher's deterministic sample.

    python -m studies.tuning_speed.distill pairs   [--ckpt models/dcm_diverse_contact.ckpt] [--draws 2]
        [--teacher-steps 10] [--threads 1] [--pairs outputs/studies/tuning_speed/distill/pairs.npz]
    python -m studies.tuning_speed.distill train   [--epochs 6] [--batch 32] [--lr 3e-4] [--threads 1]
        [--out outputs/studies/tuning_speed/distill/dcm_one_step.ckpt]
    python -m studies.tuning_speed.distill check   --split valid --pairs <pairs of the valid split> [--out <student>]

Why: the tuner's default asks the DCM three DDIM steps per virtual trial, and with 16 samples 2 shared + 16 rows
of net calls per proposal. A student that returns the sample in one call costs 1 and 16 rows. Fewer DDIM steps
of the teacher itself lose the ranking (one step) or the spread (the net sees the start noise scaled by
sqrt(alpha_bar_T) ~ 1e-3, so its one-step samples nearly coincide): the student instead sees the noise at unit
scale (``input_scaling=unit``) and learns where the teacher's chain takes it.

``pairs``: for every trial of the training split and ``--draws`` seeded start noises z, the teacher's
deterministic DDIM chain (``--teacher-steps`` steps, eta = 0) from z to its sample x0, in normalised units.
``train``: the student starts from the teacher's weights (EMA) and regresses x0 from (condition, z) at
t = T-1 (MSE, AdamW, cosine decay, a fixed seed), then is written as a DCM checkpoint whose own sampler is DDIM
with one step: ``tune.py ckpt=<student> robot_free.sampler=null robot_free.sampling_steps=null`` runs it.
Both stages write their file atomically at the end; a killed stage is re-run from its start.
"""

from __future__ import annotations

import argparse
import copy
import math
import os
import time
import warnings
from collections.abc import Sequence
from pathlib import Path

import numpy as np

OUT = Path("outputs/studies/tuning_speed/distill")


def _load(ckpt: Path):
    from dcm.models.predict import load_model

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return load_model(ckpt)


def _train_conditions(model, dataset: Path, split: str):
    """Normalised (N, H, C) conditions of a split, as the model's net sees them."""
    import torch

    from dcm.data.datamodule import TrajectoryDataset
    from dcm.data.schema import load_dataset

    data = TrajectoryDataset.from_loaded(load_dataset(dataset, split=split))
    with torch.no_grad():
        return model.normalized_cond(data.cond)


def teacher_pairs(args: argparse.Namespace) -> None:
    import torch

    from dcm.models import diffusion
    from dcm.models.force_model import OUT_DIM

    model = _load(args.ckpt)
    cond_n = _train_conditions(model, args.dataset, args.split)
    N, H = cond_n.shape[:2]
    scheduler = diffusion.make_scheduler("ddim", model.noise_schedule, model.cfg.diffusion_steps,
                                         model.cfg.prediction_type)
    diffusion.check_inference_steps(scheduler, args.teacher_steps)
    net = diffusion.scale_noisy_input(model.inference_net, scheduler, model.cfg.input_scaling)
    gen = torch.Generator().manual_seed(args.seed)
    z = torch.randn((args.draws, N, H, OUT_DIM), generator=gen)
    x0 = torch.empty_like(z)
    rows = args.draws * N
    start, done = time.perf_counter(), 0
    with torch.no_grad():
        for d in range(args.draws):
            for lo in range(0, N, args.batch_rows):
                c, x = cond_n[lo:lo + args.batch_rows], z[d, lo:lo + args.batch_rows]
                scheduler.set_timesteps(args.teacher_steps)
                for t in scheduler.timesteps:
                    out = net(c, x, torch.full((len(c),), int(t), dtype=torch.long))
                    x = scheduler.step(out, t, x).prev_sample
                x0[d, lo:lo + len(c)] = x
                done += len(c)
                spent = time.perf_counter() - start
                print(f"teacher: {done}/{rows} samples, {spent:.0f} s, ETA {spent / done * (rows - done):.0f} s",
                      flush=True)
    args.pairs.parent.mkdir(parents=True, exist_ok=True)
    tmp = args.pairs.with_suffix(".tmp.npz")
    np.savez(tmp, z=z.numpy(), x0=x0.numpy(), teacher_steps=args.teacher_steps, seed=args.seed,
             ckpt=str(args.ckpt), split=args.split)
    os.replace(tmp, args.pairs)
    print(f"wrote {args.pairs}: {rows} pairs in {time.perf_counter() - start:.0f} s")


def train_student(args: argparse.Namespace) -> None:
    import torch

    from dcm.models.checkpoint import read_checkpoint

    torch.manual_seed(args.seed)
    teacher = _load(args.ckpt)
    cond_n = _train_conditions(teacher, args.dataset, args.split)
    pairs = np.load(args.pairs)
    z, x0 = torch.as_tensor(pairs["z"]), torch.as_tensor(pairs["x0"])
    draws, N = z.shape[:2]
    # what the start noise decides: a student blind to z, returning each trial's mean over draws, has this MSE
    blind = float(x0.var(dim=0, unbiased=False).mean()) if draws > 1 else float("nan")
    print(f"{draws * N} pairs; MSE of the mean over draws (a z-blind student): {blind:.2e}", flush=True)
    top = torch.full((args.batch,), teacher.cfg.diffusion_steps - 1, dtype=torch.long)
    student = copy.deepcopy(teacher.inference_net).train().requires_grad_(True)
    optim = torch.optim.AdamW(student.parameters(), lr=args.lr, weight_decay=1e-4)
    steps = args.epochs * math.ceil(draws * N / args.batch)
    sched = torch.optim.lr_scheduler.LambdaLR(optim, lambda s: 0.5 * (1 + math.cos(math.pi * min(1.0, s / steps))))
    gen = torch.Generator().manual_seed(args.seed)
    start, step = time.perf_counter(), 0
    for epoch in range(args.epochs):
        order, total = torch.randperm(draws * N, generator=gen), 0.0
        for lo in range(0, len(order), args.batch):
            idx = order[lo:lo + args.batch]
            d, i = idx // N, idx % N
            out = student(cond_n[i], z[d, i], top[: len(idx)])
            loss = torch.nn.functional.mse_loss(out, x0[d, i])
            optim.zero_grad(set_to_none=True)
            loss.backward()
            optim.step()
            sched.step()
            step, total = step + 1, total + loss.item() * len(idx)
            if step % 20 == 0:
                spent = time.perf_counter() - start
                print(f"epoch {epoch + 1}/{args.epochs} step {step}/{steps}: loss {loss.item():.2e}, {spent:.0f} s, "
                      f"ETA {spent / step * (steps - step):.0f} s", flush=True)
        print(f"epoch {epoch + 1}: mean MSE to the teacher {total / len(order):.2e} (normalised units)", flush=True)

    ckpt = read_checkpoint(args.ckpt)
    weights = {k: v.detach().clone() for k, v in student.state_dict().items()}
    for prefix in ("net.", "ema_net."):
        ckpt["state_dict"].update({prefix + k: v for k, v in weights.items()})
    ckpt["hyper_parameters"].update(input_scaling="unit", sampler="ddim", sampling_steps=1)
    ckpt.setdefault("dcm_card", {})["distilled"] = {
        "teacher": str(args.ckpt), "teacher_sampler": f"ddim, {int(pairs['teacher_steps'])} steps",
        "pairs": int(draws * N), "epochs": args.epochs, "batch": args.batch, "lr": args.lr, "seed": args.seed}
    ckpt["dcm_card"]["name"] = args.out.stem
    args.out.parent.mkdir(parents=True, exist_ok=True)
    tmp = args.out.with_suffix(".tmp")
    torch.save(ckpt, tmp)
    os.replace(tmp, args.out)
    _load(args.out)  # it loads with this code
    print(f"wrote {args.out} after {time.perf_counter() - start:.0f} s")


def check_student(args: argparse.Namespace) -> None:
    """The student against the teacher on a pairs file (``pairs --split valid`` for held-out trials): its MSE, the
    MSE of a z-blind student, and how much of the teacher's spread over start noises it reproduces."""
    import torch

    student = _load(args.out)
    cond_n = _train_conditions(student, args.dataset, args.split)
    pairs = np.load(args.pairs)
    z, x0 = torch.as_tensor(pairs["z"]), torch.as_tensor(pairs["x0"])
    top = torch.full((z.shape[1],), student.cfg.diffusion_steps - 1, dtype=torch.long)
    with torch.no_grad():
        out = torch.stack([student.inference_net(cond_n, z[d], top) for d in range(len(z))]).clamp(-1.5, 1.5)
    mse, blind = float(((out - x0) ** 2).mean()), float(x0.var(dim=0, unbiased=False).mean())
    spread_t, spread_s = float(x0.std(dim=0, unbiased=False).mean()), float(out.std(dim=0, unbiased=False).mean())
    dev_t, dev_s = (x0 - x0.mean(0)).flatten(), (out - out.mean(0)).flatten()
    corr = float(torch.corrcoef(torch.stack([dev_t, dev_s]))[0, 1])
    print(f"{args.split}, {len(z)} draws x {z.shape[1]} trials: MSE to the teacher {mse:.2e}, of a z-blind student "
          f"{blind:.2e}; spread over draws (normalised) teacher {spread_t:.4f}, student {spread_s:.4f}; "
          f"correlation of their deviations from the trial's mean {corr:.3f}")


def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("stage", choices=["pairs", "train", "check"])
    parser.add_argument("--ckpt", type=Path, default=Path("models/dcm_diverse_contact.ckpt"), help="the teacher")
    parser.add_argument("--dataset", type=Path, default=Path("data/diverse_contact.h5"))
    parser.add_argument("--split", default="train")
    parser.add_argument("--pairs", type=Path, default=OUT / "pairs.npz")
    parser.add_argument("--draws", type=int, default=2, help="start noises per trial")
    parser.add_argument("--teacher-steps", type=int, default=10, help="the teacher's DDIM steps (divide T)")
    parser.add_argument("--batch-rows", type=int, default=256, help="trials per teacher call")
    parser.add_argument("--epochs", type=int, default=6)
    parser.add_argument("--batch", type=int, default=32)
    parser.add_argument("--lr", type=float, default=3e-4)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--out", type=Path, default=OUT / "dcm_one_step.ckpt")
    args = parser.parse_args(argv)

    import torch

    torch.set_num_threads(args.threads)
    {"pairs": teacher_pairs, "train": train_student, "check": check_student}[args.stage](args)


if __name__ == "__main__":
    main()
