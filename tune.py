"""Robot-free stiffness tuning of a new skill: `python tune.py ckpt=<model.ckpt> [demo=wavelike] [k=v ...]`.

See conf/tune.yaml for every option. Writes results.json, pareto.png and solution_forces.png to the run
directory; a killed run resumes with the same command plus `hydra.run.dir=<that run directory>`.
"""

from pathlib import Path

import hydra
from omegaconf import DictConfig


@hydra.main(version_base=None, config_path="conf", config_name="tune")
def main(cfg: DictConfig) -> None:
    from dcm.tuning.run import tune

    results = tune(cfg, Path(cfg.out_dir))
    free, robot = results["robot_free"], results["robot_based"]
    print(f"robot-free: {free['n_virtual_trials']} virtual trials in {free['seconds']:.1f} s, "
          f"{free['n_validated']} solutions validated, hypervolume {free['hypervolume']:.4g}")
    if robot["hypervolume"] is not None:
        print(f"robot-based: {robot['n_trials']} simulated trials in {robot['seconds']:.1f} s, "
              f"hypervolume {robot['hypervolume']:.4g}")
    print(f"results: {Path(cfg.out_dir) / 'results.json'}")


if __name__ == "__main__":
    main()
