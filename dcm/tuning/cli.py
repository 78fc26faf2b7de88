"""``python tune.py ckpt=<model.ckpt> [demo=wavelike] [k=v ...]`` and the console script ``dcm-tune``.

See conf/tune.yaml for every option and docs/tune.md for the guide. Writes results.json, overview.png,
pareto.png and solution_forces.png to the run directory; a killed run resumes with the same command plus
``hydra.run.dir=<that run directory>``. A setting that cannot work stops the run with one line on stderr
(``error: ...``), also written to the run directory's ``tune.log``, and exit code 1.
"""

from __future__ import annotations

from pathlib import Path

import hydra
from omegaconf import DictConfig

from dcm.cli import CONF_DIR, error_line, one_line_warnings, quiet_libraries, to_run_log


# An absolute config path: a relative one would be looked up as a Python package once this is imported as a module.
@hydra.main(config_path=str(CONF_DIR), config_name="tune")
def main(cfg: DictConfig) -> None:
    quiet_libraries()
    one_line_warnings()
    from dcm.tuning.run import tune

    try:
        if cfg.get("resume"):  # continue a robot loop with its own settings
            from hydra.core.hydra_config import HydraConfig

            from dcm.tuning.loop import resume_config

            run_cfg = resume_config(cfg.resume, list(HydraConfig.get().overrides.task))
            results = tune(run_cfg, Path(cfg.resume), Path(cfg.observations) if cfg.get("observations") else None)
        else:
            if cfg.get("observations"):
                raise ValueError(f"observations = {cfg.observations} needs resume=<the run directory that proposed "
                                 "the schedules>")
            results = tune(cfg, Path(cfg.out_dir))
    except (ValueError, OSError) as err:  # TuneConfigError, TrialLogMismatch, ModelInputError, DemoSpecError, ...
        line = error_line(err)
        to_run_log(line)  # the run directory's tune.log says why the run stopped
        raise SystemExit(line) from None
    if "loop" in results:
        _print_loop(results["loop"], Path(cfg.resume or cfg.out_dir))
        return
    free, robot, ref = results["robot_free"], results["robot_based"], results["reference_point"]
    rule = ref.get("rule")
    how = "given" if rule is None else (
        f"{rule['task_factor']:g} x L_task at the demo's stiffness {rule['demo_stiffness_Npm'][0]:g} N/m, "
        f"{rule['comp_factor']:g} x L_comp at {rule['stiffest_Npm']:g} N/m")
    print(f"hypervolume reference point: L_task {ref['L_task_N']:.4g} N, L_comp {ref['L_comp_kNpm']:.4g} kN/m ({how})")
    print(f"robot-free: {free['n_virtual_trials']} virtual trials in {free['seconds']:.1f} s "
          f"(model {free['seconds_model']:.1f} s, optimiser {free['seconds_optimiser']:.1f} s), "
          f"{free['n_validated']} solutions validated, hypervolume {free['hypervolume']:.4g}")
    prediction = free["prediction"]
    if prediction["L_task_mae_N"] is not None:
        pairs = ", ".join(f"{p:.3g} -> {r:.3g}" for p, r in zip(prediction["predicted_L_task_N"],
                                                               prediction["realised_L_task_N"]))
        verdict = "exceeds" if prediction["exceeded"] else "within"
        print(f"robot-free L_task predicted -> validated [N]: {pairs}; "
              f"mean |error| {prediction['L_task_mae_N']:.3g} N, {verdict} {prediction['limit_N']:.3g} N "
              f"({prediction['limit_source']})")
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


def _print_loop(loop: dict, out: Path) -> None:
    """The loop's scores: one line per observed round, then what comes next (the loop printed its own line)."""
    for r in loop["rounds"]:
        if "n_trials" in r:
            print(f"round {r['round']}: {r['n_trials']} trials, observed hypervolume so far "
                  f"{r['hypervolume_observed']:.4g}, predicted -> observed mean |error| "
                  f"{'n/a' if r['prediction_mae_N'] is None else format(r['prediction_mae_N'], '.3g')} N")
    print(f"loop: {out / 'loop.json'}")


if __name__ == "__main__":
    main()
