"""The cluster recipe of docs/train.md ("On a cluster"), without a cluster: the sbatch job that
``hydra/launcher=slurm`` with ``trainer=ddp`` asks for has one task per GPU on every node, as Lightning needs."""

from __future__ import annotations

from pathlib import Path

import pytest
from omegaconf import OmegaConf

REPO = Path(__file__).resolve().parents[1]
RECIPE = ["hydra/launcher=slurm", "trainer=ddp", "trainer.accelerator=gpu", "trainer.devices=4", "trainer.num_nodes=2",
          "hydra.launcher.partition=gpu"]


def _composed(overrides: list[str]):
    from hydra import compose, initialize_config_dir

    from dcm.configs import CONF_DIR, register_resolvers

    register_resolvers()
    with initialize_config_dir(str(CONF_DIR), version_base=None):
        return compose("train", overrides=overrides, return_hydra_config=True)


def _sbatch(launcher: dict, folder: Path) -> str:
    """The sbatch file submitit writes for these launcher settings: Hydra's plugin hands its base settings to
    submitit under their own names and the others as ``slurm_<name>``; submitit renames them to sbatch's."""
    from submitit.slurm.slurm import SlurmExecutor, _convert_mem, _make_sbatch_string

    renamed = SlurmExecutor._equivalence_dict()
    params = {renamed.get(key, key): value for key, value in launcher.items()
              if key not in ("_target_", "submitit_folder", "max_num_timeout")}
    params["mem"] = _convert_mem(params["mem"])
    return _make_sbatch_string(command="python -u -m submitit.core._submit x", folder=folder, **params)


@pytest.mark.filterwarnings("ignore::UserWarning")  # hydra's version_base notice
def test_the_slurm_launcher_asks_for_one_task_per_gpu_on_every_node(tmp_path: Path) -> None:
    cfg = _composed(RECIPE)
    launcher = OmegaConf.to_container(cfg.hydra.launcher, resolve=True)
    assert launcher["_target_"].endswith("submitit_launcher.SlurmLauncher")
    assert (launcher["nodes"], launcher["tasks_per_node"], launcher["gpus_per_node"]) == (2, 4, 4)
    assert cfg.trainer.strategy == "ddp" and cfg.trainer.devices == 4 and cfg.trainer.num_nodes == 2
    assert launcher["timeout_min"] * 60 > 55 * 60  # above trainer.max_time, so the run writes its checkpoints
    text = _sbatch(launcher, tmp_path)
    for line in ("#SBATCH --nodes=2", "#SBATCH --ntasks-per-node=4", "#SBATCH --gpus-per-node=4",
                 "#SBATCH --partition=gpu", "#SBATCH --time=120", "#SBATCH --cpus-per-task=4"):
        assert line in text, text
    assert "srun" in text  # one process per task, each a rank of Lightning's SLURM environment
    # a task that stops ends the others, instead of leaving them to wait for it until the job times out
    assert text.index("export SLURM_KILL_BAD_EXIT=1") < text.index("srun")


@pytest.mark.filterwarnings("ignore::UserWarning")
def test_the_launcher_follows_the_trainer_and_leaves_the_partition_to_the_user() -> None:
    cfg = _composed(["hydra/launcher=slurm", "trainer=ddp", "trainer.devices=8"])
    launcher = OmegaConf.to_container(cfg.hydra.launcher, resolve=True)
    assert (launcher["nodes"], launcher["tasks_per_node"], launcher["gpus_per_node"]) == (1, 8, 8)
    assert launcher["partition"] is None
