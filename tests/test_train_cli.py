"""train.py end to end, as a user runs it: a 2-run sweep, evaluate, fine-tune, resume, bad input."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

REPO = Path(__file__).resolve().parents[1]
# a few steps of a small RetNet; every run still writes TensorBoard logs, checkpoints and its config
TINY = ["trainer=fast", "trainer.max_epochs=1", "net.d_model=32", "net.n_layers=1", "net.n_heads=2",
        "data.batch_size=8", "model.warmup_steps=2", "metrics.n_plot=1"]


def _run(args: list[str], cwd: Path, check: bool = True) -> subprocess.CompletedProcess:
    env = dict(os.environ, HYDRA_FULL_ERROR="0", PYTHONWARNINGS="ignore")
    proc = subprocess.run([sys.executable, *args], cwd=cwd, env=env, capture_output=True, text=True, timeout=600)
    if check and proc.returncode != 0:
        raise AssertionError(f"{args} failed ({proc.returncode}):\n{proc.stdout[-3000:]}\n{proc.stderr[-3000:]}")
    return proc


@pytest.fixture(scope="module")
def sweep(tiny_dataset_path: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("sweep")
    _run([str(REPO / "train.py"), "-m", "model.diffusion_steps=1,2", f"data.path={tiny_dataset_path}",
          *TINY, f"hydra.sweep.dir={out}"], cwd=out)
    return out


def test_sweep_makes_one_run_dir_per_job(sweep: Path) -> None:
    runs = sorted(p for p in sweep.iterdir() if p.is_dir() and (p / "config.yaml").exists())
    assert len(runs) == 2, list(sweep.iterdir())
    assert "diffusion_steps-1" in runs[0].name and "diffusion_steps-2" in runs[1].name
    for run in runs:
        assert list((run / "tb").glob("events.out.tfevents.*")), f"no TensorBoard events in {run}"
        assert (run / "checkpoints" / "last.ckpt").exists()
        assert list((run / "checkpoints").glob("epoch*-Rw*.ckpt")), "no checkpoint selected on val/R_within"
        assert (run / ".hydra" / "config.yaml").exists()
        summary = json.loads((run / "summary.json").read_text())
        assert summary["monitor"] == "val/R_within"
        # the selected checkpoint, under the name the guides use
        best = run / "checkpoints" / "best.ckpt"
        assert summary["best_checkpoint"] == str(best) and summary["selected_from"].startswith("epoch")
        assert best.read_bytes() == (run / "checkpoints" / summary["selected_from"]).read_bytes()
        assert {"test/R_within", "test/R_within_spearman", "test/R_pooled", "test/force_rmse_ratio_copy"} <= set(
            summary["test"])


def test_evaluate_writes_json(sweep: Path, tiny_dataset_path: Path, tmp_path: Path) -> None:
    from dcm.evaluate import main as evaluate_main

    ckpt = next(sweep.glob("1_*/checkpoints/last.ckpt"))
    evaluate_main([f"ckpt={ckpt}", f"dataset={tiny_dataset_path}", "split=valid", f"out={tmp_path / 'm.json'}",
                   "n_samples=2"])
    result = json.loads((tmp_path / "m.json").read_text())
    assert result["n"] == 3 and result["T"] == 2 and result["split"] == "valid"
    assert {"L_MSE", "R", "R_within", "R_pooled", "rmse_Fx", "rmse_Fy", "rmse_Fz"} <= set(result)
    assert {"copy_demo", "stiffness_ridge"} <= set(result["references"])


def test_finetune_keeps_the_pretraining_normaliser_and_resume_continues(sweep: Path, tiny_dataset_path: Path,
                                                                         tmp_path: Path) -> None:
    import torch

    ckpt = next(sweep.glob("1_*/checkpoints/last.ckpt"))
    run = tmp_path / "ft"
    # net, T and normaliser come from init_from whatever the command line says; the optimiser's fields apply
    not_applied = ["net.d_model=64", "model.diffusion_steps=5", "model.normalization=minmax"]
    tiny = [arg for arg in TINY if not arg.startswith("net.d_model=")]
    _run([str(REPO / "train.py"), "stage=finetune", f"init_from={ckpt}", *not_applied, "model.lr=5e-4",
          f"data.path={tiny_dataset_path}", "usage_rate=0.5", *tiny, f"hydra.run.dir={run}"], cwd=tmp_path)
    saved = yaml.safe_load((run / "config.yaml").read_text())  # what was trained, not the unused overrides
    assert saved["net"]["d_model"] == 32 and saved["model"]["diffusion_steps"] == 2
    assert saved["model"]["normalization"] == "zscore" and saved["model"]["lr"] == 5e-4
    pre = torch.load(ckpt, map_location="cpu", weights_only=True)["state_dict"]
    ft = torch.load(run / "checkpoints" / "last.ckpt", map_location="cpu", weights_only=True)
    for key in ("target_norm.scale", "target_norm.center", "cond_norm.scale"):
        assert torch.equal(pre[key], ft["state_dict"][key])
    summary = json.loads((run / "summary.json").read_text())
    assert summary["stage"] == "finetune" and summary["n_train_used"] < summary["n_train_total"]
    steps_before = ft["global_step"]

    # resume the same run (its saved config) for one more epoch
    _run([str(REPO / "train.py"), f"resume={run}", "trainer.max_epochs=2", "test_after_fit=false"], cwd=tmp_path)
    resumed = torch.load(run / "checkpoints" / "last.ckpt", map_location="cpu", weights_only=True)
    assert resumed["global_step"] > steps_before and resumed["epoch"] == 1


def test_a_killed_run_resumes_to_the_weights_of_an_uninterrupted_one(tiny_dataset_path: Path, tmp_path: Path) -> None:
    """The DCM's training noise and the shuffle order continue from the checkpoint, not from the seed."""
    import torch

    common = [f"data.path={tiny_dataset_path}", *[a for a in TINY if "max_epochs" not in a],
              "model.lr_schedule=constant", "test_after_fit=false"]
    _run([str(REPO / "train.py"), *common, "trainer.max_epochs=2", f"hydra.run.dir={tmp_path / 'whole'}"], cwd=tmp_path)
    _run([str(REPO / "train.py"), *common, "trainer.max_epochs=1", f"hydra.run.dir={tmp_path / 'cut'}"], cwd=tmp_path)
    _run([str(REPO / "train.py"), f"resume={tmp_path / 'cut'}", "trainer.max_epochs=2"], cwd=tmp_path)
    whole, cut = (torch.load(tmp_path / run / "checkpoints" / "last.ckpt", map_location="cpu", weights_only=True)
                  for run in ("whole", "cut"))
    assert cut["global_step"] == whole["global_step"] > 0
    for key, value in whole["state_dict"].items():
        assert torch.equal(value, cut["state_dict"][key]), key


def test_bad_invocations_fail_with_clear_messages(sweep: Path, tiny_dataset_path: Path, tmp_path: Path) -> None:
    ckpt = next(sweep.glob("0_*/checkpoints/last.ckpt"))
    common = [f"data.path={tiny_dataset_path}", *TINY, f"hydra.run.dir={tmp_path / 'bad'}"]
    proc = _run([str(REPO / "train.py"), "stage=finetune", *common], cwd=tmp_path, check=False)
    assert proc.returncode != 0 and "needs init_from" in proc.stderr
    proc = _run([str(REPO / "train.py"), "model=baseline", f"init_from={ckpt}", *common], cwd=tmp_path, check=False)
    assert proc.returncode != 0 and "holds a 'dcm' model" in proc.stderr
    proc = _run([str(REPO / "train.py"), "checkpoint.monitor=val/R_wthin", *common], cwd=tmp_path, check=False)
    assert proc.returncode != 0 and proc.stderr.strip().splitlines()[-1].startswith(
        "error: checkpoint.monitor=val/R_wthin: not a logged metric; one of ")
    assert not (tmp_path / "bad" / "checkpoints").exists()  # refused before training, not at the first validation
    from dcm.evaluate import main as evaluate_main

    with pytest.raises(SystemExit, match="no split 'nosuch'"):
        evaluate_main([f"ckpt={ckpt}", f"dataset={tiny_dataset_path}", "split=nosuch"])


def test_the_monitor_and_mode_are_checked_against_what_is_logged() -> None:
    from dcm.training.checks import TrainConfigError
    from dcm.training.train import check_monitor

    check_monitor({"monitor": "val/R_within", "mode": "max"}, task_term=False)
    check_monitor({"monitor": "val/force_rmse_N", "mode": "min"}, task_term=False)
    check_monitor({"monitor": "train/loss_epoch", "mode": "min"}, task_term=False)
    check_monitor({"monitor": "val/loss_task", "mode": "min"}, task_term=True)
    with pytest.raises(TrainConfigError, match=r"^checkpoint.monitor=val/loss_task: not a logged metric; one of .*"
                                               r"val/R_within, .*val/loss$"):
        check_monitor({"monitor": "val/loss_task", "mode": "min"}, task_term=False)
    with pytest.raises(TrainConfigError, match=r"^checkpoint.mode=maximum: must be min or max$"):
        check_monitor({"monitor": "val/R_within", "mode": "maximum"}, task_term=False)


def test_the_within_skill_task_term_trains_from_the_cli(tiny_dataset_path: Path, tmp_path: Path) -> None:
    common = ["model=baseline", f"data.path={tiny_dataset_path}", *TINY, "model.task_weight=10",
              "model.task_from_s=0.5", "metrics.task_from_s=0.5"]
    proc = _run([str(REPO / "train.py"), *common, f"hydra.run.dir={tmp_path / 'ungrouped'}"], cwd=tmp_path, check=False)
    assert proc.returncode == 2 and "data.skill_group" in proc.stderr.strip().splitlines()[-1]
    _run([str(REPO / "train.py"), *common, "data.skill_group=3", f"hydra.run.dir={tmp_path / 'grouped'}"], cwd=tmp_path)
    summary = json.loads((tmp_path / "grouped" / "summary.json").read_text())
    assert summary["global_step"] > 0 and Path(summary["best_checkpoint"]).exists()
    config = yaml.safe_load((tmp_path / "grouped" / "config.yaml").read_text())
    assert config["model"]["task_weight"] == 10 and config["data"]["skill_group"] == 3
    # the metrics count from 0.5 s on: copying F_demo is scored on that window (20 Hz: from step 10)
    from dcm.data.schema import load_dataset
    from dcm.models.metrics import force_rmse

    test = load_dataset(tiny_dataset_path, split="test")
    expected = force_rmse(test.arrays["F_demo"][:, 10:], test.arrays["F_obs"][:, 10:])
    assert summary["test"]["test/force_rmse_copy_N"] == pytest.approx(expected, rel=1e-5)
    assert expected != pytest.approx(force_rmse(test.arrays["F_demo"], test.arrays["F_obs"]), rel=1e-3)


def test_checkpoints_are_selected_and_named_on_the_monitor(tmp_path: Path) -> None:
    """With two trials per skill the within-skill R is undefined: selecting on it keeps no checkpoint (the run
    says so before training and ends on last.ckpt, advised to monitor val/R_pooled), and files named after
    R_pooled never read ...nan."""
    from dcm.data.generate import ensure_dataset

    data = ensure_dataset("tiny", tmp_path / "two_trials.h5", ["n_trials=2", "workers=1", "progress=false"])
    common = [f"data.path={data}", *[a for a in TINY if "max_epochs" not in a], "trainer.max_epochs=2"]
    within = _run([str(REPO / "train.py"), *common, f"hydra.run.dir={tmp_path / 'within'}"], cwd=tmp_path)
    assert sorted(p.name for p in (tmp_path / "within" / "checkpoints").iterdir()) == ["best.ckpt", "last.ckpt"]
    logged = within.stdout + within.stderr  # Hydra's console log goes to stdout
    assert "checkpoint.monitor=val/R_within needs >= 3 trials per skill; the valid split has 2" in logged
    assert "use checkpoint.monitor=val/R_pooled" in logged
    summary = json.loads((tmp_path / "within" / "summary.json").read_text())
    assert summary["best_score"] is None and summary["selected_from"] == "last.ckpt"
    assert "val/R_within was undefined at every validation" in within.stdout

    pooled = _run([str(REPO / "train.py"), *common, "checkpoint.monitor=val/R_pooled",
                   f"hydra.run.dir={tmp_path / 'pooled'}"], cwd=tmp_path)
    names = sorted(p.name for p in (tmp_path / "pooled" / "checkpoints").iterdir())
    assert names[0] == "best.ckpt" and names[-1] == "last.ckpt"
    assert names[1:-1] and all(n.startswith("epoch") and "-Rp" in n for n in names[1:-1])
    assert not any("nan" in n for n in names) and "is undefined" not in pooled.stdout + pooled.stderr
    summary = json.loads((tmp_path / "pooled" / "summary.json").read_text())
    lines = pooled.stdout.strip().splitlines()
    closing = lines[lines.index(f"selected checkpoint: {summary['best_checkpoint']} ({summary['selected_from']})"):]
    assert closing[1] == f"  val/R_pooled = {summary['best_score']:.4f}" and closing[2].startswith("  test: R_pooled")
    assert closing[-1].startswith("  all metrics: ")


def test_a_research_preset_generates_into_its_own_file_and_trains_quietly(tmp_path: Path) -> None:
    """`--config-dir studies/conf dataset=<research preset>` generates data/<name>.h5 as `python -m
    dcm.data.generate` would, then trains; no library notice reaches the user (warnings not silenced here)."""
    env = dict(os.environ, HYDRA_FULL_ERROR="0", MUJOCO_GL="egl")
    env.pop("PYTHONWARNINGS", None)
    proc = subprocess.run([sys.executable, str(REPO / "train.py"), "--config-dir", str(REPO / "studies" / "conf"),
                           "dataset=tiny_diverse", *TINY, f"hydra.run.dir={tmp_path / 'run'}"],
                          cwd=tmp_path, env=env, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert (tmp_path / "data" / "tiny_diverse.h5").is_file()
    config = yaml.safe_load((tmp_path / "run" / "config.yaml").read_text())
    assert config["dataset"]["name"] == "tiny_diverse"
    assert config["data"]["path"] == str(tmp_path / "data" / "tiny_diverse.h5")
    assert "selected checkpoint: " in proc.stdout
    output = proc.stdout + proc.stderr
    for notice in ("Tip:", "litlogger", "litmodels", "OpenGL_accelerate", "deprecated", "Warning"):
        assert notice not in output, (notice, output[-3000:])
