"""Shipped checkpoints: the slim export keeps predictions, carries its card, and versions are checked on load."""

from __future__ import annotations

import json
import warnings
from pathlib import Path

import numpy as np
import pytest
import torch

from dcm import __version__
from dcm.models.checkpoint import VERSION_KEY, checkpoint_card
from dcm.models.configuration import CheckpointIncompatibleError, CheckpointVersionWarning
from dcm.models.predict import load_model
from dcm.training.export import main


def _inputs(seed: int = 0, horizon: int = 16) -> tuple[np.ndarray, ...]:
    rng = np.random.default_rng(seed)
    x_demo, F_demo, x_attr = (rng.normal(size=(2, horizon, 6)).astype(np.float32) for _ in range(3))
    return x_demo, F_demo, x_attr, rng.uniform(100, 2500, size=(2, horizon, 6)).astype(np.float32)


@pytest.fixture()
def run_dir(tiny_checkpoint: Path, tiny_dataset_path: Path, tmp_path: Path) -> Path:
    """A train.py-like run directory around the tiny checkpoint."""
    run = tmp_path / "run"
    (run / "checkpoints").mkdir(parents=True)
    (run / ".hydra").mkdir()
    ckpt = run / "checkpoints" / "epoch000.ckpt"
    ckpt.write_bytes(tiny_checkpoint.read_bytes())
    (run / "summary.json").write_text(json.dumps({
        "model": "dcm", "stage": "pretrain", "seed": 0, "epochs": 1, "best_checkpoint": str(ckpt),
        "best_score": 0.5, "monitor": "val/R_within", "dataset": str(tiny_dataset_path), "test": {"test/R": 0.1}}))
    (run / ".hydra" / "overrides.yaml").write_text("- model=dcm\n- seed=0\n- hydra.run.dir=x\n")
    (run / "config.yaml").write_text("model: {}\n")
    return run


def test_export_is_slim_predicts_the_same_and_carries_its_card(run_dir: Path, tmp_path: Path) -> None:
    out = tmp_path / "shipped" / "dcm.ckpt"
    assert main([str(run_dir), "--out", str(out), "--name", "dcm_tiny"]) == 0
    source = run_dir / "checkpoints" / "epoch000.ckpt"
    assert out.stat().st_size < source.stat().st_size
    raw = torch.load(out, weights_only=True)
    assert "optimizer_states" not in raw and raw[VERSION_KEY] == __version__

    inputs = _inputs()
    original, shipped = load_model(source), load_model(out)
    a, _ = original.predict_forces(*inputs, generator=torch.Generator().manual_seed(3))
    b, _ = shipped.predict_forces(*inputs, generator=torch.Generator().manual_seed(3))
    np.testing.assert_array_equal(np.asarray(a), np.asarray(b))

    card = checkpoint_card(out)
    assert card["kind"] == "dcm" and card["name"] == "dcm_tiny"
    assert card["train_command"] == "python train.py model=dcm seed=0"
    assert card["dataset"]["plan_fingerprint"] and card["selected_on"]["checkpoint"] == "epoch000.ckpt"


def test_a_moved_run_exports_its_selection_and_a_lost_one_is_an_error(
        run_dir: Path, tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    # the last checkpoint differs from the selected one, so exporting the wrong one shows in the card
    (run_dir / "checkpoints" / "last.ckpt").write_bytes((run_dir / "checkpoints" / "epoch000.ckpt").read_bytes())
    moved = run_dir.rename(tmp_path / "moved")
    out = tmp_path / "moved.ckpt"
    assert main([str(moved), "--out", str(out)]) == 0
    assert checkpoint_card(out)["exported_from"]["checkpoint"] == "epoch000.ckpt"

    (moved / "checkpoints" / "epoch000.ckpt").unlink()
    assert main([str(moved), "--out", str(tmp_path / "lost.ckpt")]) == 1
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "epoch000.ckpt" in err and "selected checkpoint" in err
    assert not (tmp_path / "lost.ckpt").exists()


def test_another_code_version_warns_naming_both(tiny_checkpoint: Path, tmp_path: Path) -> None:
    raw = torch.load(tiny_checkpoint, weights_only=True)
    raw[VERSION_KEY] = "0.0.1"
    old = tmp_path / "old.ckpt"
    torch.save(raw, old)
    with pytest.warns(CheckpointVersionWarning, match=rf"dcm 0\.0\.1; this is dcm {__version__}"):
        load_model(old)
    with warnings.catch_warnings():
        warnings.simplefilter("error", CheckpointVersionWarning)
        load_model(tiny_checkpoint)  # written by this version: silent


def test_renamed_parameters_fail_with_a_clear_error(tiny_checkpoint: Path, tmp_path: Path) -> None:
    raw = torch.load(tiny_checkpoint, weights_only=True)
    state = raw["state_dict"]
    name = next(iter(state))
    state["old_" + name] = state.pop(name)
    renamed = tmp_path / "renamed.ckpt"
    torch.save(raw, renamed)
    with pytest.raises(CheckpointIncompatibleError, match=rf"parameter names changed: missing \"{name}\""):
        load_model(renamed)


def test_cli_reports_a_missing_source_in_one_line(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    assert main([str(tmp_path / "nope.ckpt"), str(tmp_path / "out.ckpt")]) == 1
    err = capsys.readouterr().err
    assert err.startswith("error: checkpoint") and "nope.ckpt" in err and err.count("\n") == 1
    assert not (tmp_path / "out.ckpt").exists()
