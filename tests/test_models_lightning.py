"""DCM and Baseline LightningModules: training lowers the loss, checkpoints round-trip, bad input errors."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import lightning as L
import numpy as np
import pytest
import torch
from test_models_synthetic import write_synthetic_dataset

from dcm.data.datamodule import DCMDataModule
from dcm.evaluate import evaluate
from dcm.models.baseline import Baseline
from dcm.models.configuration import CheckpointKindError, DatasetMismatchError, DataSpec, ModelInputError
from dcm.models.dcm import DCM
from dcm.models.predict import load_model

TINY_NET = {"name": "retnet", "d_model": 32, "n_layers": 1, "n_heads": 2}
REPO = Path(__file__).resolve().parents[1]


def _fit(model: L.LightningModule, dm: DCMDataModule, steps: int) -> L.Trainer:
    trainer = L.Trainer(accelerator="cpu", devices=1, max_steps=steps, logger=False, enable_checkpointing=False,
                        enable_progress_bar=False, enable_model_summary=False, limit_val_batches=0,
                        num_sanity_val_steps=0)
    trainer.fit(model, datamodule=dm)
    return trainer


def _fixed_loss(model, dm: DCMDataModule) -> float:
    train = dm.split("train")
    gen = torch.Generator().manual_seed(0)
    with torch.no_grad():
        return float(model.loss(model.net, model.cond_norm.normalize(train.cond),
                                model.target_norm.normalize(train.target), generator=gen))


@pytest.fixture(scope="module")
def tiny_dm(tiny_dataset_path: Path) -> DCMDataModule:
    dm = DCMDataModule(tiny_dataset_path, batch_size=4, expect_control_hz=20.0)
    dm.setup("fit")
    return dm


@pytest.fixture(scope="module")
def trained(tiny_dm: DCMDataModule, tmp_path_factory: pytest.TempPathFactory) -> dict:
    """A tiny DCM and Baseline trained a few steps on the tiny dataset, with their checkpoints."""
    out: dict = {"dir": tmp_path_factory.mktemp("ckpt")}
    for name, cls, extra in (("dcm", DCM, {"diffusion_steps": 10}), ("baseline", Baseline, {})):
        L.seed_everything(0)
        model = cls(net=dict(TINY_NET), lr=3e-3, warmup_steps=5, ema_decay=0.9,
                    data_spec={"control_hz": tiny_dm.control_hz}, **extra)
        model.fit_normalizers(*tiny_dm.train_arrays())
        before = _fixed_loss(model, tiny_dm)
        trainer = _fit(model, tiny_dm, steps=40)
        path = out["dir"] / f"{name}.ckpt"
        trainer.save_checkpoint(path)
        out[name] = {"model": model, "before": before, "after": _fixed_loss(model, tiny_dm), "ckpt": path}
    return out


@pytest.mark.parametrize("name", ["dcm", "baseline"])
def test_training_lowers_the_loss(trained: dict, name: str) -> None:
    run = trained[name]
    assert run["after"] < 0.8 * run["before"], (run["before"], run["after"])


def _inputs(dm: DCMDataModule, n: int = 2) -> list[np.ndarray]:
    cond = dm.split("valid").cond[:n].numpy()
    return [cond[..., 0:6], cond[..., 6:12], cond[..., 12:18], cond[..., 18:24]]


@pytest.mark.parametrize("name,cls", [("dcm", DCM), ("baseline", Baseline)])
def test_checkpoint_round_trip_gives_identical_predictions(trained: dict, tiny_dm: DCMDataModule, name: str,
                                                           cls: type) -> None:
    model = trained[name]["model"].eval()
    loaded = cls.load_from_checkpoint(trained[name]["ckpt"]).eval()
    x = _inputs(tiny_dm)
    a = model.predict_forces(*x, n_samples=3, generator=torch.Generator().manual_seed(7))
    b = loaded.predict_forces(*x, n_samples=3, generator=torch.Generator().manual_seed(7))
    np.testing.assert_array_equal(a[0], b[0])
    np.testing.assert_array_equal(a[1], b[1])
    assert torch.equal(model.target_norm.scale, loaded.target_norm.scale)


def test_checkpoint_loads_in_a_fresh_process(trained: dict, tiny_dm: DCMDataModule, tmp_path: Path) -> None:
    x = _inputs(tiny_dm, 1)
    np.save(tmp_path / "x.npy", np.stack(x))
    code = (
        "import numpy as np, torch, sys\n"
        "from dcm.models.dcm import DCM\n"
        f"m = DCM.load_from_checkpoint({str(trained['dcm']['ckpt'])!r})\n"
        f"x = np.load({str(tmp_path / 'x.npy')!r})\n"
        "mean, std = m.predict_forces(*x, n_samples=2, generator=torch.Generator().manual_seed(1))\n"
        f"np.save({str(tmp_path / 'y.npy')!r}, mean)\n"
    )
    subprocess.run([sys.executable, "-c", code], check=True, cwd=tmp_path, timeout=300)
    expected, _ = trained["dcm"]["model"].predict_forces(*x, n_samples=2, generator=torch.Generator().manual_seed(1))
    np.testing.assert_array_equal(np.load(tmp_path / "y.npy"), expected)


def test_predict_forces_shapes_units_and_spread(trained: dict, tiny_dm: DCMDataModule) -> None:
    dcm, base = trained["dcm"]["model"], trained["baseline"]["model"]
    x = _inputs(tiny_dm, 3)
    mean, std = dcm.predict_forces(*x, n_samples=4, generator=torch.Generator().manual_seed(0))
    assert isinstance(mean, np.ndarray) and mean.shape == std.shape == x[0].shape
    assert np.all(std[..., :3] > 0) and np.all(np.isfinite(mean))
    mean1, _ = dcm.predict_forces(*[torch.as_tensor(a[0]) for a in x], n_samples=1)
    assert torch.is_tensor(mean1) and mean1.shape == x[0].shape[1:]
    bmean, bstd = base.predict_forces(*x, n_samples=4)
    assert np.all(bstd == 0) and bmean.shape == x[0].shape
    with pytest.raises(ModelInputError, match="x_attr"):
        dcm.predict_forces(x[0], x[1], x[2][..., :3], x[3])


def test_loading_the_other_models_checkpoint_fails_clearly(trained: dict) -> None:
    with pytest.raises(CheckpointKindError, match="'baseline' model, not 'dcm'"):
        DCM.load_from_checkpoint(trained["baseline"]["ckpt"])
    with pytest.raises(CheckpointKindError, match="'dcm' model, not 'baseline'"):
        Baseline.load_from_checkpoint(trained["dcm"]["ckpt"])
    assert isinstance(load_model(trained["baseline"]["ckpt"]), Baseline)


def test_dataset_with_other_control_rate_or_channels_is_refused(trained: dict, tmp_path: Path) -> None:
    other = write_synthetic_dataset(tmp_path / "10hz.h5", n_train=4, n_valid=2, n_test=2, control_hz=10.0)
    with pytest.raises(DatasetMismatchError, match="control rate 10.0 Hz"):
        evaluate(trained["dcm"]["ckpt"], other, split="test")
    spec = DataSpec(control_hz=20.0)
    with pytest.raises(DatasetMismatchError, match="condition channels"):
        spec.check(spec.cond_channels[:-1], spec.target_channels, 20.0)


def test_evaluate_reports_metrics(trained: dict, tiny_dataset_path: Path) -> None:
    result = evaluate(trained["dcm"]["ckpt"], tiny_dataset_path, split="test", n_samples=2)
    assert result["n"] == 3 and result["T"] == 10 and result["model"] == "dcm" and result["n_samples"] == 2
    for key in ("L_MSE", "R", "rmse_Fx", "rmse_Fy", "rmse_Fz", "rmse_Tz"):
        assert key in result
    assert np.isfinite(result["L_MSE"]) and result["rmse_Fz"] >= 0


@pytest.mark.parametrize("kwargs,match", [
    ({"diffusion_steps": 0}, "diffusion_steps"),
    ({"diffusion_steps": 101}, "diffusion_steps"),
    ({"n_samples": 0}, "n_samples"),
    ({"sampler": "euler"}, "sampler"),
    ({"unknown_field": 1}, "unknown"),
])
def test_bad_model_config(kwargs: dict, match: str) -> None:
    with pytest.raises(ModelInputError, match=match):
        DCM(net=dict(TINY_NET), **kwargs)


def test_unfitted_normaliser_is_refused() -> None:
    model = Baseline(net=dict(TINY_NET))
    x = np.zeros((1, 8, 6), np.float32)
    with pytest.raises(ModelInputError, match="not fitted"):
        model.predict_forces(x, x, x, x)


def test_ddim_sampler_option(trained: dict, tiny_dm: DCMDataModule) -> None:
    base = trained["dcm"]["model"]
    ddim = DCM(**{**dict(base.hparams), "sampler": "ddim", "sampling_steps": 5})
    ddim.load_state_dict(base.state_dict())
    x = _inputs(tiny_dm, 2)
    a, _ = ddim.predict_forces(*x, n_samples=1, generator=torch.Generator().manual_seed(3))
    b, _ = ddim.predict_forces(*x, n_samples=1, generator=torch.Generator().manual_seed(3))
    np.testing.assert_array_equal(a, b)
    assert np.all(np.isfinite(a)) and a.shape == x[0].shape
    with pytest.raises(ValueError, match="divid"):
        DCM(**{**dict(base.hparams), "sampler": "ddim", "sampling_steps": 3})
