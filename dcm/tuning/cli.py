"""``python tune.py ckpt=<model.ckpt> [demo=wavelike] [k=v ...]`` and the console script ``dcm-tune``.

See conf/tune.yaml for every option and docs/tune.md for the guide. Writes results.json, overview.png,
pareto.png and solution_forces.png to the run directory; a killed run resumes with the same command plus
``hydra.run.dir=<that run directory>``. A setting that cannot work stops the run with one line on stderr
(``error: ...``) and exit code 1.
"""

from __future__ import annotations

from pathlib import Path

import hydra
from omegaconf import DictConfig

from dcm.cli import CONF_DIR, quiet_libraries


# An absolute config path: a relative one would be looked up as a Python package once this is imported as a module.
@hydra.main(config_path=str(CONF_DIR), config_name="tune")
def main(cfg: DictConfig) -> None:
    quiet_libraries()
    from dcm.tuning.run import tune

    try:
        results = tune(cfg, Path(cfg.out_dir))
    except (ValueError, OSError) as err:  # TuneConfigError, TrialLogMismatch, ModelInputError, DemoSpecError, ...
        raise SystemExit(f"error: {' '.join(str(err).split())}") from None
    free, robot = results["robot_free"], results["robot_based"]
    print(f"robot-free: {free['n_virtual_trials']} virtual trials in {free['seconds']:.1f} s "
          f"(model {free['seconds_model']:.1f} s, optimiser {free['seconds_optimiser']:.1f} s), "
          f"{free['n_validated']} solutions validated, hypervolume {free['hypervolume']:.4g}")
    if robot["hypervolume"] is not None:
        # Per trial, as both searches ran in this invocation (a resumed run replays logged trials at no cost).
        virtual_s = free["seconds"] / free["n_virtual_trials"]
        simulated_s = robot["seconds"] / max(robot["n_trials"], 1)
        ratio = (f" ({simulated_s / virtual_s:.0f}x the time of a virtual trial)"
                 if virtual_s > 0 and simulated_s > 0 else "")
        print(f"robot-based: {robot['n_trials']} simulated trials in {robot['seconds']:.1f} s{ratio}, "
              f"hypervolume {robot['hypervolume']:.4g}")
    out = Path(cfg.out_dir)
    print(f"results: {out / 'results.json'}")
    print("figures: " + ", ".join(str(out / name) for name in ("overview.png", "pareto.png", "solution_forces.png")
                                  if (out / name).is_file()))


if __name__ == "__main__":
    main()
