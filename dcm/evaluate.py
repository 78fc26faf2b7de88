"""Score a trained force model on any dataset file: ``python -m dcm.evaluate ckpt=<ckpt> dataset=<h5>``.

Writes a JSON file with L_MSE (normalised units), R (Pearson correlation of predicted vs true L_task over
trajectories), per-axis RMSE [N, N·m], n, and what produced them (model kind, T, sampler, samples, seed).
The dataset must have the model's channels and control rate; it need not be one the model saw.
"""

from __future__ import annotations

import json
import logging
from pathlib import Path
from typing import Any

import sys

import torch
from omegaconf import OmegaConf

from dcm.data.datamodule import TrajectoryDataset, dataset_channels
from dcm.data.schema import load_dataset
from dcm.models.callbacks import evaluate_model
from dcm.models.configuration import ModelInputError
from dcm.models.dcm import DCM
from dcm.models.predict import load_model

log = logging.getLogger("dcm.evaluate")


def _device(name: str) -> torch.device:
    if name == "auto":
        if torch.cuda.is_available():
            return torch.device("cuda")
        if getattr(torch.backends, "mps", None) is not None and torch.backends.mps.is_available():
            return torch.device("mps")
        return torch.device("cpu")
    return torch.device(name)


def evaluate(ckpt: str | Path, dataset: str | Path, split: str = "test", n_samples: int | None = None,
             n_eval: int | None = None, seed: int = 0, device: str = "auto") -> dict[str, Any]:
    """Metrics of checkpoint ``ckpt`` on ``split`` of ``dataset`` (see the module docstring)."""
    model = load_model(ckpt, map_location="cpu").to(_device(device))
    loaded = load_dataset(dataset, split=None if split == "all" else split)
    cond_channels, target_channels = dataset_channels(loaded)
    model.data_spec.check(cond_channels, target_channels, loaded.control_hz, source=f"dataset {dataset}")
    data = TrajectoryDataset.from_loaded(loaded)
    if n_eval is not None:
        if int(n_eval) < 1:
            raise ModelInputError(f"n_eval must be >= 1 or null, got {n_eval}")
        data = data.subset(int(n_eval))
    metrics, _ = evaluate_model(model, data, n_samples, seed)
    is_dcm = isinstance(model, DCM)
    k = (model.default_samples if n_samples is None else int(n_samples)) if is_dcm else 1
    return {
        **metrics,
        "n": len(data),
        "model": model.model_kind,
        "T": int(model.cfg.diffusion_steps) if is_dcm else 1,
        "sampler": model.cfg.sampler if is_dcm else "single-pass",
        "sampling_steps": (model.cfg.sampling_steps or model.cfg.diffusion_steps) if is_dcm else 1,
        "n_samples": k,
        "net": model.cfg.net.get("name"),
        "seed": int(seed),
        "ckpt": str(Path(ckpt).resolve()),
        "dataset": str(Path(dataset).resolve()),
        "split": split,
        "control_hz": loaded.control_hz,
        "horizon": loaded.horizon,
    }


CONFIG = Path(__file__).resolve().parent.parent / "conf" / "evaluate.yaml"


def main(argv: list[str] | None = None) -> dict[str, Any]:
    """CLI: ``key=value`` arguments over conf/evaluate.yaml; writes ``out`` and returns the metrics."""
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    args = sys.argv[1:] if argv is None else argv
    if any(a in ("-h", "--help") for a in args):
        print(__doc__ + "\n" + CONFIG.read_text())
        return {}
    bad = [a for a in args if "=" not in a]
    if bad:
        raise SystemExit(f"error: arguments must be key=value, got {bad}")
    cfg = OmegaConf.merge(OmegaConf.load(CONFIG), OmegaConf.from_dotlist(args))
    unknown = sorted(set(cfg.keys()) - set(OmegaConf.load(CONFIG).keys()))
    missing = sorted(k for k in ("ckpt", "dataset") if OmegaConf.is_missing(cfg, k))
    if unknown or missing:
        raise SystemExit(f"error: unknown keys {unknown} / missing keys {missing}; see python -m dcm.evaluate --help")
    try:
        result = evaluate(cfg.ckpt, cfg.dataset, split=str(cfg.split), n_samples=cfg.n_samples, n_eval=cfg.n_eval,
                          seed=int(cfg.seed), device=str(cfg.device))
    except ValueError as err:  # ModelInputError, DatasetError, DatasetMismatchError, CheckpointKindError
        raise SystemExit(f"error: {err}") from None
    out = Path(str(cfg.out))
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(result, indent=2, sort_keys=True) + "\n")
    log.info("n=%d  L_MSE=%.4g  R=%.3f  rmse Fx/Fy/Fz=%.3f/%.3f/%.3f N -> %s", result["n"], result["L_MSE"],
             result["R"], result["rmse_Fx"], result["rmse_Fy"], result["rmse_Fz"], out)
    return result


if __name__ == "__main__":
    main()
