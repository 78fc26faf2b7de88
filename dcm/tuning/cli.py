"""``python tune.py ckpt=<model.ckpt> [demo=wavelike] [k=v ...]`` and the console script ``dcm-tune``.

See conf/tune.yaml for every option and docs/tune.md for the guide. Writes results.json, overview.png,
pareto.png and solution_forces.png to the run directory; a killed run resumes with the same command plus
``hydra.run.dir=<that run directory>``. A setting that cannot work stops the run with one line on stderr
(``error: ...``), also written to the run directory's ``tune.log``, and exit code 1.
"""

from __future__ import annotations

import sys
from pathlib import Path

import hydra
from omegaconf import DictConfig

from dcm.configs import CONF_DIR, discard_resumed_dir, group_choice_problem, register_resolvers
from dcm.console import error_line, one_line_warnings, quiet_libraries, to_run_log
from dcm.control.objectives import TaskObjective
from dcm.shipped import with_shipped_paths


# An absolute config path: a relative one would be looked up as a Python package once this is imported as a module.
@hydra.main(config_path=str(CONF_DIR), config_name="tune")
def hydra_main(cfg: DictConfig) -> None:
    quiet_libraries()
    one_line_warnings()
    from dcm.tuning.run import OneShotResult, run_once, run_robot_loop
    from dcm.tuning.setup import prepare

    try:
        if cfg.get("resume"):  # continue a robot loop with its own settings
            from hydra.core.hydra_config import HydraConfig

            from dcm.tuning.loop import resume_config

            run_cfg = with_shipped_paths(resume_config(cfg.resume, list(HydraConfig.get().overrides.task)))
            setup = prepare(run_cfg, Path(cfg.resume))
            observations = Path(cfg.observations) if cfg.get("observations") else None
            result = run_robot_loop(setup, observations) if setup.settings.robot else run_once(setup)
        else:
            if cfg.get("observations"):
                raise ValueError(f"observations = {cfg.observations} needs resume=<the run directory that proposed "
                                 "the schedules>")
            setup = prepare(with_shipped_paths(cfg), Path(cfg.out_dir))  # models/... from any directory
            result = run_robot_loop(setup) if setup.settings.robot else run_once(setup)
    except (ValueError, OSError) as err:  # TuneConfigError, TrialLogMismatch, ModelInputError, DemoSpecError, ...
        line = error_line(err)
        to_run_log(line)  # the run directory's tune.log says why the run stopped
        if cfg.get("resume"):  # ... but a refused resume leaves no <run>/resumed/<time>/ behind
            from hydra.core.hydra_config import HydraConfig

            discard_resumed_dir(cfg.resume, HydraConfig.get().runtime.output_dir)
        raise SystemExit(line) from None
    if not isinstance(result, OneShotResult):
        _print_loop(result.loop, result.out_dir)
        return
    for line in summary_lines(result.results):
        print(line)
    out = Path(cfg.out_dir)
    print(f"results: {out / 'results.json'}")
    print("figures: " + ", ".join(str(out / name) for name in ("overview.png", "pareto.png", "solution_forces.png")
                                  if (out / name).is_file()))


def summary_lines(results: dict) -> list[str]:
    """The one-shot run's printout of ``results`` (what results.json holds): the reference point, both searches
    and the prediction error. A search that replayed trials from the run directory's log says how many it
    replayed and how many it computed, and its times are those of this invocation, so they read as timings of
    the computed trials only; the per-trial ratio of the two searches is left out then."""
    free, robot, ref = results["robot_free"], results["robot_based"], results["reference_point"]
    objective = TaskObjective.from_dict(results.get("objective"))
    unit = " N" if objective.unit == "N" else ""  # a wipe's L_task is in tolerances
    rule = ref.get("rule")
    how = "given" if rule is None else (
        f"{rule['task_factor']:g} x L_task at the demo's stiffness {rule['demo_stiffness_Npm'][0]:g} N/m, "
        f"{rule['comp_factor']:g} x L_comp at {rule['stiffest_Npm']:g} N/m")
    lines = [f"hypervolume reference point: L_task {ref['L_task_N']:.4g}{unit}, L_comp {ref['L_comp_kNpm']:.4g} kN/m "
             f"({how})"]
    if objective.name != "paper":
        lines.insert(0, f"objective: {objective.describe()}")
    lines.append(f"robot-free: {free['n_virtual_trials']} virtual trials{_replayed(free)} in {free['seconds']:.1f} s "
                 f"(model {free['seconds_model']:.1f} s, optimiser {free['seconds_optimiser']:.1f} s), "
                 f"{free['n_validated']} solutions validated, hypervolume {free['hypervolume']:.4g}")
    prediction = free["prediction"]
    if prediction["L_task_mae_N"] is not None:
        pairs = ", ".join(f"{p:.3g} -> {r:.3g}" for p, r in zip(prediction["predicted_L_task_N"],
                                                               prediction["realised_L_task_N"]))
        verdict = "exceeds" if prediction["exceeded"] else "within"
        lines.append(f"robot-free L_task predicted -> validated{' [N]' if unit else ''}: {pairs}; "
                     f"mean |error| {prediction['L_task_mae_N']:.3g}{unit}, {verdict} {prediction['limit_N']:.3g}{unit} "
                     f"({prediction['limit_source']})")
    if robot["hypervolume"] is not None:
        ratio = ""
        if not free.get("n_replayed") and not robot.get("n_replayed"):  # both searches ran all their trials here
            virtual_s = free["seconds"] / free["n_virtual_trials"]
            simulated_s = robot["seconds"] / max(robot["n_trials"], 1)
            if virtual_s > 0 and simulated_s > 0:
                ratio = f" ({simulated_s / virtual_s:.0f}x the time of a virtual trial)"
        lines.append(f"robot-based: {robot['n_trials']} simulated trials{_replayed(robot)} in {robot['seconds']:.1f} s"
                     f"{ratio}, hypervolume {robot['hypervolume']:.4g}")
    return lines


def _replayed(search: dict) -> str:
    """How many of a search's trials were replayed from the run directory's log and how many computed; empty
    when none was replayed."""
    if not search.get("n_replayed"):
        return ""
    return f" ({search['n_replayed']} replayed from the run directory's log, {search['n_computed']} computed)"


def main() -> None:
    """Entry point of tune.py and ``dcm-tune``; the run directory's ``${dcm.run_dir_of:...}`` is resolved by Hydra
    before :func:`hydra_main` runs."""
    if problem := group_choice_problem(sys.argv[1:]):
        raise SystemExit(error_line(problem))
    register_resolvers()
    hydra_main()


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
