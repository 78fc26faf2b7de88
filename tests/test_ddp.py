"""``trainer=ddp`` end to end: 2 CPU processes (gloo) train a small DCM on ``tiny``, and what the run selects and
logs is the whole valid split's, as one process evaluating the same checkpoint finds it."""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

REPO = Path(__file__).resolve().parents[1]
WORLD = 2
# 2 epochs of a small RetNet, a validation after each: the second can select another checkpoint than the first
SMALL = ["trainer=ddp", "trainer.accelerator=cpu", f"trainer.devices={WORLD}", "trainer.max_epochs=2",
         "trainer.max_time=null", "trainer.check_val_every_n_epoch=1", "trainer.log_every_n_steps=1",
         "trainer.enable_progress_bar=false", "net.d_model=16", "net.n_layers=1", "net.n_heads=2",
         "model.diffusion_steps=5", "model.warmup_steps=2", "data.batch_size=4", "metrics.n_plot=0"]


@pytest.fixture(scope="module")
def ddp_run(tiny_dataset_path: Path, tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, subprocess.Popen, str, str]:
    run = tmp_path_factory.mktemp("ddp") / "run"
    # Python's default warning filters, so a warning Lightning gives reaches stderr
    env = {k: v for k, v in os.environ.items() if k != "PYTHONWARNINGS"}
    env.update(OMP_NUM_THREADS="1", HYDRA_FULL_ERROR="1")
    proc = subprocess.Popen([sys.executable, str(REPO / "train.py"), *SMALL, f"data.path={tiny_dataset_path}",
                             f"hydra.run.dir={run}"], cwd=run.parent, env=env, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    out, err = proc.communicate(timeout=300)
    assert proc.returncode == 0, f"{out[-3000:]}\n{err[-3000:]}"
    return run, proc, out, err


def _valid_and_test(path: Path):
    from dcm.data.datamodule import DCMDataModule

    dm = DCMDataModule(path, expect_control_hz=20.0)
    dm.setup("fit")
    dm.setup("test")
    return dm.eval_set("valid"), dm.eval_set("test")


def _scalars(run: Path) -> dict[str, dict[int, float]]:
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    out: dict[str, dict[int, float]] = {}
    for events in sorted((run / "tb").glob("events.out.tfevents.*")):
        acc = EventAccumulator(str(events), size_guidance={"scalars": 0})
        acc.Reload()
        for tag in acc.Tags()["scalars"]:
            out.setdefault(tag, {}).update({e.step: e.value for e in acc.Scalars(tag)})
    return out


def test_ddp_selects_and_logs_the_whole_valid_split(ddp_run, tiny_dataset_path: Path) -> None:
    from dcm.models.callbacks import evaluate_model
    from dcm.models.metrics import MIN_TRIALS
    from dcm.models.predict import load_model

    run, _, _, _ = ddp_run
    valid, test = _valid_and_test(tiny_dataset_path)
    # the premise: a rank's half of the valid skill has too few trials for a within-skill correlation
    assert len(np.unique(valid.skills)) == 1 and math.ceil(len(valid) / WORLD) < MIN_TRIALS <= len(valid)

    summary = json.loads((run / "summary.json").read_text())
    best = run / "checkpoints" / "best.ckpt"
    assert summary["best_checkpoint"] == str(best)
    model = load_model(best)
    one, _ = evaluate_model(model, valid, None, 0, valid.skills.numpy())  # conf/train.yaml's metrics: seed 0
    assert math.isfinite(one["R_within"])
    assert summary["best_score"] == pytest.approx(one["R_within"], abs=1e-6)

    # every val/ metric TensorBoard holds for the selected validation is the one-process figure
    # (Lightning logs a validation at the last training step before it)
    step = int(torch.load(best, map_location="cpu", weights_only=True)["global_step"]) - 1
    scalars = _scalars(run)
    for key in ("R_within", "R_within_spearman", "R_pooled", "L_task_mae_N", "force_rmse_N", "L_MSE"):
        assert scalars[f"val/{key}"][step] == pytest.approx(one[key], rel=1e-5, abs=1e-6), key

    # val/loss counts each valid trial once: rank r holds trials r, r + WORLD, ... (no padding), each rank's
    # mean weighted by its count; its one batch draws the noise of validation batch 0
    parts = []
    for rank in range(WORLD):
        batch = valid[list(range(rank, len(valid), WORLD))]
        gen = torch.Generator().manual_seed(10_000)
        with torch.no_grad():
            parts.append((float(model._batch_loss(model.inference_net, batch, gen)), len(batch["cond"])))
    expected = sum(loss * n for loss, n in parts) / len(valid)
    assert scalars["val/loss"][step] == pytest.approx(expected, rel=1e-5)

    # the test pass of the selected checkpoint is the whole test split's too
    one_test, _ = evaluate_model(model, test, None, 0, test.skills.numpy())
    for key in ("R_pooled", "force_rmse_N", "L_MSE"):
        assert summary["test"][f"test/{key}"] == pytest.approx(one_test[key], rel=1e-5, abs=1e-6), key


def test_ddp_warns_of_no_unsynced_metric_and_only_rank_zero_writes(ddp_run) -> None:
    run, proc, out, err = ddp_run
    assert "sync_dist" not in err, err[-3000:]
    assert "DistributedSampler" not in err, err[-3000:]
    assert out.count("selected checkpoint:") == 1, out
    # TensorBoard event files carry their writer's pid: rank 0 is the process started here
    events = list((run / "tb").glob("events.out.tfevents.*"))
    assert events and all(e.name.rsplit(".", 2)[1] == str(proc.pid) for e in events), [e.name for e in events]
    assert sorted(p.name for p in run.iterdir() if not p.name.startswith(".")) == [
        "checkpoints", "config.yaml", "summary.json", "tb", "train.log", "train_ddp_process_1.log"]
