"""Distil a trained DCM into a one-step student: one net call per sample instead of a denoising chain.

    dcm-distill models/dcm_diverse_contact.ckpt data/diverse_contact.h5 --out my_dcm_one_step.ckpt
        [--draws 4] [--teacher-steps 10] [--epochs 8] [--batch-size 32] [--lr 3e-4] [--seed 0] [--device auto]

Why: a robot-free search asks the model about a thousand schedules, and every DDIM step is a pass of the score
net. Fewer steps of the teacher itself rank worse, and with the ``signal`` input scaling the net sees the start
noise scaled by sqrt(alpha_bar_T) ~ 1e-3, so its one-step samples barely differ. The student instead sees the
noise at unit scale and learns where the teacher's deterministic chain takes it (a distilled sampler in the
sense of Luhman & Luhman 2021), so one call keeps both the order of schedules and the spread of samples.

1. **Pairs:** for every trial of the dataset's train split and ``--draws`` seeded start noises z, the teacher's
   DDIM chain over ``--teacher-steps`` steps (eta = 0, deterministic) from z to its sample x0.
2. **Student:** the teacher's (EMA) weights, trained to return x0 from (condition, z) at t = T-1 by MSE in
   normalised units (AdamW, cosine decay, seeded batches). Noise and samples span the teacher's whole target
   (the wrench, and for a teacher that predicts the pose its translation too), so the student predicts what
   the teacher does, for the same objective.
3. **Checkpoint:** a DCM with ``sampler=one_step`` and ``input_scaling=unit``, whose card keeps the teacher's
   and adds how it was distilled and the student's metrics on the valid split (:func:`dcm.evaluate.evaluate`),
   which ``tune.py`` compares its predictions with. ``tune.py ckpt=<student>`` runs it as it is
   (``robot_free.sampler=auto``).

The pairs and the training state after every epoch are kept in ``<out>.work/``; the same command started
again resumes there and ends with the weights of an uninterrupted run. The folder is removed at the end.
"""

from __future__ import annotations

import argparse
import copy
import math
import shutil
import sys
import warnings
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from dcm.console import print_error
from dcm.shipped import shipped_path

WORK_SUFFIX = ".work"


class DistillError(ValueError):
    """A teacher, dataset or setting distillation cannot use; names the file or the option."""


@dataclass(frozen=True)
class DistillSettings:
    """How the student is made; recorded in its card and in the work folder, which a resume must match."""

    draws: int = 4  # start noises per training trial
    teacher_steps: int = 10  # the teacher's DDIM steps (must divide its T)
    epochs: int = 8
    batch_size: int = 32
    lr: float = 3e-4
    seed: int = 0

    def __post_init__(self) -> None:
        for name in ("draws", "teacher_steps", "epochs", "batch_size"):
            value = getattr(self, name)
            if isinstance(value, bool) or int(value) != value or value < 1:
                raise DistillError(f"--{name.replace('_', '-')} must be an integer >= 1, got {value!r}")
        if not (math.isfinite(self.lr) and self.lr > 0):
            raise DistillError(f"--lr must be a number > 0, got {self.lr!r}")


def load_teacher(path: Path) -> Any:
    """The DCM to distil, refused in one line if it is no multi-step DCM."""
    from dcm.models.dcm import DCM
    from dcm.models.predict import load_model

    model = load_model(path)
    if not isinstance(model, DCM):
        raise DistillError(f"{path}: a {getattr(model, 'model_kind', type(model).__name__)} predictor; only a DCM "
                           "checkpoint has a denoising chain to distil")
    if model.is_one_step_student:
        raise DistillError(f"{path}: already a one-step student; distil its teacher instead")
    return model


def train_conditions(model: Any, dataset: Path) -> Any:
    """The train split's conditions as the model's net sees them (encoded, normalised), checked against it."""
    import torch

    from dcm.data.datamodule import TrajectoryDataset, dataset_channels
    from dcm.data.schema import load_dataset
    from dcm.models.predict import check_dataset

    loaded = load_dataset(dataset, split="train")
    check_dataset(model, *dataset_channels(loaded, model.cfg.target_fields), loaded.control_hz,
                  source=f"dataset {dataset}")
    if not len(loaded.names):
        raise DistillError(f"{dataset}: no trials in its train split")
    with torch.no_grad():
        return model.normalized_cond(TrajectoryDataset.from_loaded(loaded).cond.to(model.device))


def teacher_pairs(teacher: Any, cond_n: Any, settings: DistillSettings, progress: bool = True) -> tuple[Any, Any]:
    """(draws, N, H, C) start noises z and the teacher's deterministic samples x0 from them, normalised units;
    C is the teacher's target width (``out_dim``: the wrench, and the translation for a pose model)."""
    import torch
    from tqdm import tqdm

    from dcm.models import diffusion

    scheduler = diffusion.make_scheduler("ddim", teacher.noise_schedule, teacher.cfg.diffusion_steps,
                                         teacher.cfg.prediction_type)
    try:
        diffusion.check_inference_steps(scheduler, settings.teacher_steps)
    except ValueError as err:
        raise DistillError(f"--teacher-steps: {err}") from None
    net = diffusion.scale_noisy_input(teacher.inference_net, scheduler, teacher.cfg.input_scaling)
    N, H = cond_n.shape[:2]
    gen = torch.Generator().manual_seed(settings.seed)
    z = torch.randn((settings.draws, N, H, teacher.out_dim), generator=gen)
    x0 = torch.empty_like(z)
    rows = max(1, int(teacher.cfg.eval_batch_size))
    bar = tqdm(total=settings.draws * N, unit="sample", desc="teacher samples", disable=not progress)
    with torch.no_grad():
        for d in range(settings.draws):
            for lo in range(0, N, rows):
                cond, x = cond_n[lo:lo + rows], z[d, lo:lo + rows].to(cond_n.device)
                scheduler.set_timesteps(settings.teacher_steps)
                for t in scheduler.timesteps:
                    step = torch.full((len(cond),), int(t), dtype=torch.long, device=cond.device)
                    x = scheduler.step(net(cond, x, step), t, x).prev_sample
                x0[d, lo:lo + len(cond)] = x.cpu()
                bar.update(len(cond))
    bar.close()
    return z, x0


def _save(obj: Any, path: Path) -> None:
    import torch

    tmp = path.with_name(path.name + ".tmp")
    torch.save(obj, tmp)
    tmp.replace(path)


def train_student(teacher: Any, cond_n: Any, z: Any, x0: Any, settings: DistillSettings, state_path: Path,
                  progress: bool = True) -> dict[str, Any]:
    """The student's net weights: the teacher's, regressed onto x0 from (condition, z) at t = T-1. The state after
    every epoch is saved to ``state_path``, and a run that finds it there continues from it."""
    import torch
    from tqdm import tqdm

    device = cond_n.device
    student = copy.deepcopy(teacher.inference_net).train().requires_grad_(True)
    optimizer = torch.optim.AdamW(student.parameters(), lr=settings.lr, weight_decay=1e-4)
    draws, N = z.shape[:2]
    per_epoch = math.ceil(draws * N / settings.batch_size)
    total = settings.epochs * per_epoch
    schedule = torch.optim.lr_scheduler.LambdaLR(optimizer, lambda s: 0.5 * (1 + math.cos(math.pi * min(1.0, s / total))))
    gen = torch.Generator().manual_seed(settings.seed + 1)
    first = 0
    if state_path.is_file():
        state = torch.load(state_path, map_location="cpu", weights_only=False)  # the generator state stays on the CPU
        student.load_state_dict(state["student"])
        optimizer.load_state_dict(state["optimizer"])
        schedule.load_state_dict(state["schedule"])
        gen.set_state(state["generator"])
        first = int(state["epochs_done"])
    top = teacher.cfg.diffusion_steps - 1
    bar = tqdm(total=total, initial=first * per_epoch, unit="step", desc="student", disable=not progress)
    for epoch in range(first, settings.epochs):
        order = torch.randperm(draws * N, generator=gen)
        for lo in range(0, len(order), settings.batch_size):
            idx = order[lo:lo + settings.batch_size]
            d, i = idx // N, idx % N
            step = torch.full((len(idx),), top, dtype=torch.long, device=device)
            loss = torch.nn.functional.mse_loss(student(cond_n[i], z[d, i].to(device), step), x0[d, i].to(device))
            optimizer.zero_grad(set_to_none=True)
            loss.backward()
            optimizer.step()
            schedule.step()
            bar.update(1)
            bar.set_postfix(epoch=epoch + 1, mse=f"{loss.item():.2e}", refresh=False)
        _save({"student": student.state_dict(), "optimizer": optimizer.state_dict(), "schedule": schedule.state_dict(),
               "generator": gen.get_state(), "epochs_done": epoch + 1}, state_path)
    bar.close()
    return {k: v.detach().cpu().clone() for k, v in student.state_dict().items()}


def student_checkpoint(teacher_path: Path, weights: dict[str, Any], settings: DistillSettings) -> dict[str, Any]:
    """The teacher's checkpoint with the student's weights (as both the trained and the EMA net) and config."""
    from dcm.models.checkpoint import CARD_KEY, read_checkpoint

    ckpt = read_checkpoint(teacher_path)
    for prefix in ("net.", "ema_net."):
        if any(k.startswith(prefix) for k in ckpt["state_dict"]):
            ckpt["state_dict"].update({prefix + k: v for k, v in weights.items()})
    ckpt["hyper_parameters"].update(sampler="one_step", sampling_steps=1, input_scaling="unit",
                                    prediction_type="sample")
    card = dict(ckpt.get(CARD_KEY) or {})
    card.pop("evaluations", None)  # the teacher's; the student's own are added once it is written
    card["distilled"] = {"teacher": teacher_path.name, "teacher_card_name": card.get("name"),
                         "teacher_sampler": f"ddim, {settings.teacher_steps} steps", **asdict(settings)}
    ckpt[CARD_KEY] = card
    return ckpt


def distill(teacher_path: Path, dataset: Path, out: Path, settings: DistillSettings = DistillSettings(),
            device: str = "auto", progress: bool = True) -> Path:
    """Write the one-step student of ``teacher_path`` to ``out`` (see the module's docstring); returns ``out``."""
    import torch

    from dcm.data.atomic import write_problem
    from dcm.devices import resolve_device
    from dcm.evaluate import evaluate
    from dcm.models.checkpoint import CARD_KEY, export_checkpoint
    from dcm.models.predict import load_model

    teacher_path, dataset, out = Path(teacher_path), Path(dataset), Path(out)
    if problem := write_problem(out):
        raise DistillError(f"--out {out} cannot be written: {problem}")
    if out.exists() and out.resolve() == teacher_path.resolve():
        raise DistillError(f"--out {out} is the teacher; writing the student there would replace it")
    teacher = load_teacher(teacher_path).to(resolve_device(device, "--device"))
    cond_n = train_conditions(teacher, dataset)
    work = out.with_name(out.name + WORK_SUFFIX)
    work.mkdir(parents=True, exist_ok=True)
    recorded = {"teacher": str(teacher_path.resolve()), "dataset": str(dataset.resolve()), **asdict(settings)}
    pairs_path, state_path = work / "pairs.pt", work / "student_state.pt"
    if pairs_path.is_file():
        pairs = torch.load(pairs_path, weights_only=False)
        if pairs["settings"] != recorded:
            raise DistillError(f"{work}: left by a distillation with other settings ({pairs['settings']}); remove "
                               "it or repeat that command")
    else:
        z, x0 = teacher_pairs(teacher, cond_n, settings, progress)
        pairs = {"settings": recorded, "z": z, "x0": x0}
        _save(pairs, pairs_path)
    weights = train_student(teacher, cond_n, pairs["z"], pairs["x0"], settings, state_path, progress)
    student_path = work / "student.ckpt"
    student = student_checkpoint(teacher_path, weights, settings)
    _save(student, student_path)
    card = student[CARD_KEY]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        evaluation = evaluate(student_path, dataset, split="valid", device=device)
    card["evaluations"] = {f"eval_valid_{dataset.stem}": {**evaluation, "ckpt": str(out.resolve())}}
    export_checkpoint(student_path, out, card, verify=load_model)
    shutil.rmtree(work)
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter, epilog=__doc__)
    parser.add_argument("teacher", type=Path, help="a DCM checkpoint (train.py or dcm.training.export)")
    parser.add_argument("dataset", type=Path, help="the dataset file it learned from (its train split is used)")
    parser.add_argument("--out", type=Path, required=True, help="the student checkpoint to write")
    defaults = DistillSettings()
    for name, value in asdict(defaults).items():
        parser.add_argument(f"--{name.replace('_', '-')}", type=type(value), default=value)
    parser.add_argument("--device", default="auto", help="auto, cpu, cuda, cuda:<index> or mps")
    parser.add_argument("--no-progress", action="store_true", help="no progress bars")
    args = parser.parse_args(argv)
    try:
        settings = DistillSettings(**{name: getattr(args, name) for name in asdict(defaults)})
        out = distill(Path(shipped_path(args.teacher)), args.dataset, args.out, settings, args.device, not args.no_progress)
    except (ValueError, OSError) as err:
        return print_error(err)
    print(f"wrote {out} ({out.stat().st_size / 1e6:.1f} MB)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
