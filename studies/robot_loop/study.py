"""Does a robot in the loop tune better per robot trial than one-shot robot-free tuning, a model-free prior and
robot-based search? The simulator plays the robot.

    python -m studies.robot_loop.study --ckpt models/dcm_diverse_contact.ckpt --demos wavelike line spiral \
        --seeds 0 1 2 3 --out outputs/studies/robot_loop [--shard 0/2] [--quick]
    python -m studies.robot_loop.study --out outputs/studies/robot_loop --report studies/robot_loop/reports/<name>.md

Per (checkpoint, skill, tuning seed), every arm spends robot trials (one simulator rollout each, ``repeat`` 0),
picks up to ``--picks`` schedules spread along the front of what it observed, and is judged by the hypervolume
of those picks over ``--judge`` fresh rollouts each (repeats 1..R: none of them a draw the arm saw), on the
skill's reference point (``tune.py``'s rule):

* ``loop_<correction>_<n>``: ``tune.py robot=sim`` with rounds of ``--batch`` trials, after n = 5, 10, 15 trials;
* ``one_shot_5``: the robot-free search's ``--batch`` validated picks (``tune.py``'s one-shot run);
* ``prior_5``, ``prior_15``: constant isotropic stiffness levels (the tuning study's model-free prior);
* ``robot_based_20``, ``robot_based_50``: MOTPE on the simulator, truncated to N trials.

Every case writes ``<out>/cases/<ckpt>/<demo>/seed_<s>.json`` when done, so a killed study resumes; shards
split the cases between processes.
"""

from __future__ import annotations

import argparse
import json
import shutil
import time
from pathlib import Path
from typing import Any

import numpy as np

REPO = Path(__file__).resolve().parents[2]
CORRECTIONS = ("gp", "none")
COUNTS = (5, 10, 15)


def tune_config(ckpt: str, demo: str, seed: int, out_dir: Path, overrides: list[str], *extra: str) -> Any:
    """``conf/quickstart.yaml`` for one case; ``overrides``: the study's own (e.g. a faster embodiment)."""
    from hydra import compose, initialize_config_dir

    with initialize_config_dir(config_dir=str(REPO / "conf")):
        return compose("quickstart", overrides=[f"ckpt={ckpt}", f"demo={demo}", f"seed={seed}", f"out_dir={out_dir}",
                                                "robot_based.n_trials=0", "torch_threads=1", *overrides, *extra])


class Judge:
    """Mean L_task over fresh rollouts of a schedule (cached: the rollouts are deterministic)."""

    def __init__(self, simulator: Any, demo: Any, skill: Any, rollouts: int):
        from dcm.tuning.objectives import SimulatorObjective

        self.objective = SimulatorObjective(simulator, demo, skill, rollouts)
        self.cache: dict[bytes, np.ndarray] = {}

    def __call__(self, params: np.ndarray) -> np.ndarray:
        keys = [np.asarray(k, np.float64).tobytes() for k in params]
        todo = [i for i, key in enumerate(keys) if key not in self.cache]
        if todo:
            for i, value in zip(todo, self.objective(np.asarray(params)[todo])):
                self.cache[keys[i]] = value
            self.objective.trials.clear()
        return np.stack([self.cache[key] for key in keys]) if keys else np.zeros((0, 2))


def judged(judge: Judge, params: np.ndarray, observed: np.ndarray, picks: int, reference: np.ndarray
           ) -> dict[str, Any]:
    """The arm's picks from its observed trials and their hypervolume over fresh rollouts."""
    from dcm.tuning.pareto import hypervolume, pick_spread

    chosen = pick_spread(observed, picks)
    values = judge(params[chosen])
    finite = values[np.isfinite(values).all(axis=1)]
    return {"n_trials": len(observed), "picks": params[chosen].tolist(), "judged": values.tolist(),
            "hypervolume": hypervolume(finite, reference) if len(finite) else 0.0,
            "hypervolume_observed": hypervolume(observed[np.isfinite(observed).all(axis=1)], reference)}


def run_case(ckpt: str, demo: str, seed: int, out: Path, args: argparse.Namespace) -> dict[str, Any]:
    """Every arm for one (checkpoint, skill, tuning seed); returns what the case file holds."""
    from dcm.search import make_search
    from dcm.tuning.checks import check_config, to_container
    from dcm.tuning.objectives import SimulatorObjective
    from dcm.tuning.optimize import optimize
    from dcm.tuning.run import tune
    from dcm.tuning.setup import record_skill
    from studies.tuning_study.study_controls import prior_levels

    started = time.perf_counter()
    work = out / "work" / Path(ckpt).stem / demo / f"seed_{seed:03d}"
    loop_extra = ["robot=sim", f"loop.rounds={len(COUNTS)}", f"loop.batch={args.batch}", "loop.tolerance_N=0",
                  f"loop.n_trials={args.loop_trials}", f"robot_free.n_trials={args.free_trials}",
                  f"robot_free.n_validate={args.picks}"]
    arms: dict[str, Any] = {}
    loops = {}
    for correction in CORRECTIONS:
        folder = work / f"loop_{correction}"
        first = work / f"loop_{CORRECTIONS[0]}" / "robot_free_trials.npz"
        if correction != CORRECTIONS[0] and first.is_file() and not (folder / "robot_free_trials.npz").is_file():
            folder.mkdir(parents=True, exist_ok=True)
            shutil.copy(first, folder / "robot_free_trials.npz")  # the same robot-free search: replayed, not re-run
        cfg = tune_config(ckpt, demo, seed, folder, args.override, *loop_extra, f"loop.correction={correction}")
        loops[correction] = tune(cfg, folder)["loop"]
    cfg = tune_config(ckpt, demo, seed, work, args.override, *loop_extra)
    reference_info = loops[CORRECTIONS[0]]["reference_point"]
    reference = np.array([reference_info["L_task_N"], reference_info["L_comp_kNpm"]])
    checked = check_config(cfg)
    simulator, recorded, skill = record_skill(cfg, checked)
    judge = Judge(simulator, recorded, skill, args.judge)

    for correction in CORRECTIONS:
        state = json.loads((work / f"loop_{correction}" / "loop/state.json").read_text())
        observed = [r["observations"] for r in state["rounds"] if r.get("observations")]
        params = np.concatenate([np.asarray(o["phase_stiffness_Npm"], float) for o in observed])
        objectives = np.concatenate([np.asarray(o["objectives"], float) for o in observed])
        for n in COUNTS:
            arms[f"loop_{correction}_{n}"] = judged(judge, params[:n], objectives[:n], args.picks, reference)
        arms[f"loop_{correction}_{COUNTS[-1]}"]["prediction_mae_N"] = [
            r.get("prediction_mae_N") for r in loops[correction]["rounds"]]
        if correction == CORRECTIONS[0]:  # round 1 = the one-shot run's validated picks, all of them judged
            first = np.asarray(state["rounds"][0]["proposals"], float)
            values = judge(first)
            from dcm.tuning.pareto import hypervolume

            arms["one_shot_5"] = {"n_trials": len(first), "picks": first.tolist(), "judged": values.tolist(),
                                  "hypervolume": hypervolume(values[np.isfinite(values).all(axis=1)], reference)}

    once = SimulatorObjective(simulator, recorded, skill)
    space = checked.space
    for n_levels in (5, 15):
        levels = prior_levels(space.min_Npm, space.max_Npm, n_levels)
        params = np.stack([np.full((space.n_phases, 3), level) for level in levels])
        arms[f"prior_{n_levels}"] = judged(judge, params, once(params), args.picks, reference)

    search = make_search(cfg.search.name, space, seed, **(to_container(cfg.search.options) or {}))
    log = optimize(search, SimulatorObjective(simulator, recorded, skill), max(args.robot_based), 1,
                   log_path=work / "robot_based_trials.npz", desc="robot-based (simulator)")
    params, objectives = log.arrays()
    for n in args.robot_based:
        arms[f"robot_based_{n}"] = judged(judge, params[:n], objectives[:n], args.picks, reference)
    return {"ckpt": ckpt, "demo": demo, "seed": seed, "reference_point": reference_info, "arms": arms,
            "judge_rollouts": args.judge, "picks": args.picks, "loop_batch": args.batch,
            "loop_n_trials": args.loop_trials, "robot_free_n_trials": args.free_trials,
            "seconds": time.perf_counter() - started}


def run_study(args: argparse.Namespace) -> None:
    import torch

    torch.set_num_threads(1)
    cases = [(c, d, s) for c in args.ckpt for d in args.demos for s in args.seeds]
    index, count = (int(v) for v in args.shard.split("/"))
    mine = cases[index::count]
    for i, (ckpt, demo, seed) in enumerate(mine):
        path = args.out / "cases" / Path(ckpt).stem / demo / f"seed_{seed:03d}.json"
        if path.is_file():
            continue
        print(f"[{i + 1}/{len(mine)}] {Path(ckpt).stem} {demo} seed {seed}", flush=True)
        case = run_case(ckpt, demo, seed, args.out, args)
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps(case, indent=1, default=float))
        print(f"  done in {case['seconds']:.0f} s", flush=True)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--ckpt", nargs="+", default=["models/dcm_diverse_contact.ckpt"],
                        help="one or more trained DCMs: one is one training seed, statistics need several")
    parser.add_argument("--demos", nargs="+", default=["wavelike", "line", "spiral"])
    parser.add_argument("--seeds", nargs="+", type=int, default=[0, 1, 2, 3])
    parser.add_argument("--out", type=Path, default=Path("outputs/studies/robot_loop"))
    parser.add_argument("--shard", default="0/1", help="i/n: run every n-th case from the i-th")
    parser.add_argument("--batch", type=int, default=5)
    parser.add_argument("--picks", type=int, default=5)
    parser.add_argument("--judge", type=int, default=8, help="fresh rollouts per judged pick")
    parser.add_argument("--free-trials", dest="free_trials", type=int, default=1000)
    parser.add_argument("--loop-trials", dest="loop_trials", type=int, default=200)
    parser.add_argument("--robot-based", dest="robot_based", nargs="+", type=int, default=[20, 50])
    parser.add_argument("--override", nargs="*", default=[], help="tune.py overrides for every case")
    parser.add_argument("--report", type=Path, default=None, help="write the report of --out's finished cases")
    args = parser.parse_args(argv)
    if args.report is not None:
        from studies.robot_loop.report import write_report

        write_report(args.out, args.report)
        return
    run_study(args)


if __name__ == "__main__":
    main()
