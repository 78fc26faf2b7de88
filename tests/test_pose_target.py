"""A contact model that predicts where the tool goes as well as what it feels (``model.target_fields=
force_and_pose``), trained, selected and scored for the configured L_task (``objective``)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import warnings
from pathlib import Path

import lightning as L
import numpy as np
import pytest
import torch

from dcm.control.objectives import PAPER, TaskObjective, path_error, task_loss, task_loss_over_samples
from dcm.data.datamodule import DCMDataModule
from dcm.data.schema import load_dataset, target_layout, write_dataset
from dcm.models.baseline import Baseline
from dcm.models.configuration import ModelInputError
from dcm.models.dcm import DCM
from dcm.models.metrics import pose_metrics
from dcm.models.predict import load_model, predict_contact, predict_task_loss
from dcm.models.references import CopyDemo, StiffnessRegression, load_reference

REPO = Path(__file__).resolve().parents[1]
WIPE = TaskObjective("wipe", force_tolerance_N=1.0, path_tolerance_m=0.005)
TINY_NET = {"name": "retnet", "d_model": 16, "n_layers": 1, "n_heads": 2}
TINY = ["trainer=fast", "trainer.max_epochs=1", "net.d_model=16", "net.n_layers=1", "net.n_heads=2",
        "data.batch_size=8", "model.warmup_steps=2", "metrics.n_plot=0", "model.diffusion_steps=5"]


def write_pose_dataset(path: Path, n_skills: int = 12, per_skill: int = 4, horizon: int = 16) -> Path:
    """Skills of ``per_skill`` trials each (train / valid / test: half / a quarter / a quarter of the trials), whose
    tool lags behind the demo along the path the more the softer its stiffness, so the pose depends on K."""
    rng = np.random.default_rng(0)
    t = np.linspace(0.0, 1.0, horizon)
    trajectories = []
    for skill in range(n_skills):
        radius, press = rng.uniform(0.02, 0.06), rng.uniform(3.0, 8.0)
        for _ in range(per_skill):
            x_demo = np.zeros((horizon, 6), np.float32)
            x_demo[:, 0], x_demo[:, 1] = radius * np.cos(4 * t + skill), radius * np.sin(4 * t + skill)
            x_demo[:, 2] = 5.0 * (x_demo[:, 0] ** 2 + x_demo[:, 1] ** 2)
            F_demo = np.zeros((horizon, 6), np.float32)
            F_demo[:, 2] = press
            K = np.full((horizon, 6), 20.0, np.float32)
            K[:, :3] = rng.uniform(100, 1500, size=3)[None]
            K[horizon // 2:, :3] = rng.uniform(100, 1500, size=3)[None]
            x_attr = x_demo.copy()
            x_attr[:, 2] -= F_demo[:, 2] / K[:, 2]
            F_obs = np.zeros((horizon, 6), np.float32)
            F_obs[:, 2] = np.minimum(press, 2.0 + 0.004 * K[:, 2]) + rng.normal(0, 0.05, horizon)
            x_obs = x_demo.copy()
            x_obs[:, :2] -= (150.0 / K[:, :2]) * np.gradient(x_demo[:, :2], axis=0)
            x_obs[:, 2] -= np.maximum(press - F_obs[:, 2], 0.0) / K[:, 2]  # pressed in where the force falls short
            trajectories.append(dict(x_demo=x_demo, F_demo=F_demo, x_attr=x_attr, K=K, x_obs=x_obs, F_obs=F_obs,
                                     contact=np.ones(horizon, np.uint8), demo_id=skill,
                                     L_task=float(task_loss(F_obs, F_demo)), L_comp=float(K[:, 0].mean() / 1000)))
    names = [f"traj_{i:06d}" for i in range(len(trajectories))]
    n_train, n_valid = len(names) // 2, len(names) // 4
    masks = {"train": names[:n_train], "valid": names[n_train:n_train + n_valid], "test": names[n_train + n_valid:]}
    write_dataset(path, trajectories, masks, {"control_hz": 20.0, "embodiment": "synthetic"})
    return path


def _run(args: list[str], cwd: Path) -> subprocess.CompletedProcess:
    env = dict(os.environ, HYDRA_FULL_ERROR="0", PYTHONWARNINGS="ignore")
    return subprocess.run([sys.executable, str(REPO / "train.py"), *args], cwd=cwd, env=env, capture_output=True,
                          text=True, timeout=300)


def _inputs(path: Path, split: str = "test") -> tuple[np.ndarray, ...]:
    loaded = load_dataset(path, split)
    return tuple(loaded.arrays[f] for f in ("x_demo", "F_demo", "x_attr", "K"))


@pytest.fixture(scope="module")
def pose_data(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_pose_dataset(tmp_path_factory.mktemp("pose_data") / "pose.h5")


@pytest.fixture(scope="module")
def pose_run(pose_data: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A pose model trained from the command line for the wipe objective, its task term on."""
    run = tmp_path_factory.mktemp("pose_run")
    proc = _run(["model.target_fields=force_and_pose", "objective=wipe", f"data.path={pose_data}",
                 "model.task_weight=0.5", "data.skill_group=4", *TINY, f"hydra.run.dir={run}"], run)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return run


@pytest.fixture(scope="module")
def force_checkpoint(pose_data: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A force-only DCM as every checkpoint before the pose target was (no target_fields, no objective)."""
    dm = DCMDataModule(pose_data, batch_size=8)
    dm.setup("fit")
    L.seed_everything(0)
    model = DCM(net=dict(TINY_NET), diffusion_steps=5, data_spec={"control_hz": dm.control_hz})
    model.fit_normalizers(*dm.train_arrays())
    trainer = L.Trainer(accelerator="cpu", devices=1, max_steps=3, logger=False, enable_checkpointing=False,
                        enable_progress_bar=False, enable_model_summary=False, limit_val_batches=0,
                        num_sanity_val_steps=0)
    trainer.fit(model, datamodule=dm)
    path = tmp_path_factory.mktemp("force_ckpt") / "dcm.ckpt"
    trainer.save_checkpoint(path)
    return path


def test_the_target_layout_gives_the_force_and_the_realised_translation(pose_data: Path) -> None:
    force, pose = target_layout("force"), target_layout("force_and_pose")
    assert force.width == 6 and force.pose is None and force.channel_names()[2] == "F_obs.Fz_N"
    assert pose.width == 9 and pose.force == slice(0, 6) and pose.pose == slice(6, 9)
    assert pose.channel_names()[6:] == ["dx_obs.x_m", "dx_obs.y_m", "dx_obs.z_m"]
    dm = DCMDataModule(pose_data, batch_size=4, target_fields="force_and_pose")
    train, raw = dm.split("train"), load_dataset(pose_data, "train")
    assert train.target.shape[-1] == 9 and dm.target_channels == pose.channel_names()
    np.testing.assert_array_equal(train.target[..., :6].numpy(), raw.arrays["F_obs"])
    np.testing.assert_array_equal(train.target[..., 6:].numpy(), raw.arrays["x_obs"][..., :3] - raw.arrays["x_demo"][..., :3])
    assert DCMDataModule(pose_data, batch_size=4).split("train").target.shape[-1] == 6  # the default: F_obs alone


def test_a_pose_model_trains_for_the_wipe_objective_reloads_and_predicts_the_pose(pose_run: Path,
                                                                                  pose_data: Path) -> None:
    summary = json.loads((pose_run / "summary.json").read_text())
    assert {"test/path_rmse_m", "test/path_rmse_copy_m", "test/R_within", "test/top3_regret"} <= set(summary["test"])
    model = load_model(pose_run / "checkpoints" / "best.ckpt")
    assert model.predicts_pose and model.objective == WIPE and model.out_dim == 9
    x_demo, F_demo, x_attr, K = _inputs(pose_data)
    contact = model.predict_contact(x_demo, F_demo, x_attr, K, n_samples=2, generator=torch.Generator().manual_seed(0))
    assert contact.force_mean.shape == contact.force_std.shape == x_demo.shape
    assert contact.x_mean.shape == contact.x_std.shape == (*x_demo.shape[:2], 3)
    assert np.all(np.isfinite(contact.x_mean)) and np.abs(contact.x_mean - x_demo[..., :3]).max() < 0.05
    one = model.predict_contact(x_demo[0], F_demo[0], x_attr[0], K[0])
    assert one.x_mean.shape == (x_demo.shape[1], 3)
    mean, std = model.predict_forces(x_demo, F_demo, x_attr, K, n_samples=2, generator=torch.Generator().manual_seed(0))
    np.testing.assert_array_equal(mean, contact.force_mean)  # the old call: the wrench alone
    L_own = predict_task_loss(model, x_demo, F_demo, x_attr, K, n_samples=2, generator=torch.Generator().manual_seed(0))
    expected = WIPE.task_loss(contact.force_mean.astype(np.float64), F_demo.astype(np.float64),
                              contact.x_mean.astype(np.float64), x_demo.astype(np.float64))
    np.testing.assert_allclose(L_own, expected, rtol=1e-12)
    looser = TaskObjective("wipe", force_tolerance_N=2.0, path_tolerance_m=0.01)  # the same kind: allowed
    assert np.all(predict_task_loss(model, x_demo, F_demo, x_attr, K, objective=looser) < L_own + 1e-9)
    with pytest.raises(ModelInputError, match=r"^objective paper .* differs from wipe .* of checkpoint .*best\.ckpt"):
        predict_task_loss(model, x_demo, F_demo, x_attr, K, objective=PAPER)

    from dcm.evaluate import evaluate

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        result = evaluate(pose_run / "checkpoints" / "best.ckpt", pose_data, split="test", n_phases=2)
    assert result["objective"] == WIPE.to_dict() and result["target_fields"] == "force_and_pose"
    copy = result["references"]["copy_demo"]
    assert result["path_rmse_copy_m"] == copy["path_rmse_m"] == copy["path_rmse_copy_m"] > 0
    assert np.isfinite(result["R_within_spearman"]) and np.isfinite(result["top3_regret"])
    assert result["references"]["stiffness_ridge"]["objective"] == WIPE.to_dict()  # fitted for the same L_task


def test_a_force_model_for_an_objective_that_counts_the_path_is_refused_in_one_line(
        pose_data: Path, force_checkpoint: Path, tmp_path: Path) -> None:
    fix = "counts the path; this model predicts only the force: train it with model.target_fields=force_and_pose"
    with pytest.raises(ModelInputError, match=fix) as err:
        Baseline(net=dict(TINY_NET), objective=WIPE.to_dict())
    assert "\n" not in str(err.value) and str(err.value).startswith("objective wipe (force over 1 N, path over 5 mm)")

    proc = _run(["objective=wipe", f"data.path={pose_data}", *TINY, f"hydra.run.dir={tmp_path / 'run'}"], tmp_path)
    assert proc.returncode == 2 and proc.stderr.strip().splitlines() == [f"error: objective {WIPE.describe()} {fix}"]
    assert not (tmp_path / "run" / "checkpoints").exists()

    model = load_model(force_checkpoint)  # an old-style checkpoint: the force alone, for the paper's L_task
    assert not model.predicts_pose and model.objective == PAPER and model.cfg.objective is None
    with pytest.raises(ModelInputError) as err:
        predict_task_loss(model, *_inputs(pose_data), objective=WIPE)
    message = str(err.value)
    assert "\n" not in message and "wipe" in message and "paper" in message and str(force_checkpoint) in message


@pytest.mark.parametrize("task_loss_mode", ["of_mean", "over_samples"])
def test_the_paper_objective_on_a_force_model_predicts_today_s_l_task_bit_for_bit(
        pose_data: Path, force_checkpoint: Path, task_loss_mode: str) -> None:
    model = load_model(force_checkpoint)
    model.set_task_loss(task_loss_mode)
    inputs, start = _inputs(pose_data), 4
    mean, std = model.predict_forces(*inputs, n_samples=3, generator=torch.Generator().manual_seed(5))
    window = (Ellipsis, slice(start, None), slice(None))
    mean, std, demo = (np.asarray(a, np.float64)[window] for a in (mean, std, inputs[1]))
    today = task_loss(mean, demo) if task_loss_mode == "of_mean" else task_loss_over_samples(mean, std, demo)
    for objective in (None, PAPER):
        got = predict_task_loss(model, *inputs, n_samples=3, generator=torch.Generator().manual_seed(5),
                                from_step=start, objective=objective)
        assert np.array_equal(got, today)


def test_copy_demo_predicts_the_demo_so_its_path_error_is_0(pose_data: Path) -> None:
    x_demo, F_demo, x_attr, K = _inputs(pose_data)
    copy = CopyDemo()
    assert copy.predicts_pose and copy.objective == PAPER
    contact = predict_contact(copy, x_demo, F_demo, x_attr, K)
    np.testing.assert_array_equal(contact.x_mean, x_demo[..., :3])
    assert np.all(path_error(contact.x_mean, x_demo, F_demo) == 0)
    # its wipe L_task is its force term alone, which copying F_demo makes 0 too
    assert np.all(predict_task_loss(copy, x_demo, F_demo, x_attr, K, objective=WIPE) == 0)
    x_obs = load_dataset(pose_data, "test").arrays["x_obs"]
    scores = pose_metrics(contact.x_mean, x_obs, x_demo, F_demo)
    assert scores["path_rmse_m"] == scores["path_rmse_copy_m"] > 0 and scores["path_rmse_ratio_copy"] == 1.0


def test_the_stiffness_ridge_learns_the_configured_objective(pose_data: Path, tmp_path: Path) -> None:
    ridge = StiffnessRegression.fit_dataset(pose_data, n_phases=2, objective=WIPE)
    paper = StiffnessRegression.fit_dataset(pose_data, n_phases=2)
    assert ridge.objective == WIPE and paper.objective == PAPER and ridge.intercept != paper.intercept
    loaded = load_reference(ridge.save(tmp_path / "wipe.json"))
    assert loaded.objective == WIPE and json.loads((tmp_path / "wipe.json").read_text())["objective"] == WIPE.to_dict()
    older = paper.to_dict()
    del older["objective"]  # a file written before objectives: the paper's
    (tmp_path / "old.json").write_text(json.dumps(older))
    assert load_reference(tmp_path / "old.json").objective == PAPER
    with pytest.raises(ModelInputError, match=r"objective paper .* differs from wipe") as err:
        predict_task_loss(loaded, None, None, None, _inputs(pose_data)[3], objective=PAPER)
    assert "\n" not in str(err.value) and "wipe.json" in str(err.value)

    from dcm.evaluate import evaluate

    # evaluated alone, a wipe ridge is scored on the file's pose as well as its force (its true L_task counts the path)
    scored = evaluate(tmp_path / "wipe.json", pose_data, split="valid", n_phases=2)
    assert scored["objective"] == WIPE.to_dict() and np.isfinite(scored["R_within_spearman"])


def test_a_student_draws_noise_of_its_teacher_s_target_width(pose_data: Path) -> None:
    from dcm.training.distill import DistillSettings, teacher_pairs

    dm = DCMDataModule(pose_data, batch_size=4, target_fields="force_and_pose")
    teacher = DCM(net=dict(TINY_NET), diffusion_steps=5, target_fields="force_and_pose", objective=WIPE.to_dict())
    teacher.fit_normalizers(*dm.train_arrays())
    cond_n = teacher.normalized_cond(dm.split("train").cond[:3])
    z, x0 = teacher_pairs(teacher, cond_n, DistillSettings(draws=1, teacher_steps=5), progress=False)
    assert z.shape == x0.shape == (1, 3, cond_n.shape[1], 9)


def test_a_pose_metric_is_a_monitor_of_a_pose_model_only() -> None:
    from dcm.training.train import TrainConfigError, check_monitor

    monitor = {"monitor": "val/path_rmse_m", "mode": "min"}
    check_monitor(monitor, task_term=False, target_fields="force_and_pose")
    with pytest.raises(TrainConfigError, match="val/path_rmse_m: not a logged metric"):
        check_monitor(monitor, task_term=False)
