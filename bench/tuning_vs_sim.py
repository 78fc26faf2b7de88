"""Robot-free tuning against the simulator it stands in for: 1,000 virtual trials beside 1,000 simulated ones.

    MUJOCO_GL=egl python bench/tuning_vs_sim.py [--threads 1] [--trials 1000] [--sim-trials 50]
        [--row "label: k=v k=v"] [--parallel-retention] [k=v ...]

In one process, on the quickstart's skill (``conf/quickstart.yaml``: the shipped DCM's one-step student, the wavelike
demo recorded as its training demos were) and at one torch thread count, it times

* ``default``: ``--trials`` virtual trials exactly as ``tune.py`` runs its robot-free search (the composed
  config's predictor, sampler, precision, batch size and search; :func:`dcm.tuning.optimize.optimize`, no log);
* ``16 samples``: the same with ``robot_free.n_samples=16 robot_free.task_loss=over_samples`` (the samples of a
  proposal share the leading denoising steps, ``robot_free.shared_steps=auto``; ``--row "independent:
  robot_free.n_samples=16 robot_free.task_loss=over_samples robot_free.shared_steps=0"`` times them unshared);
* every ``--row`` given (its overrides on top of the rest, e.g. the multi-step DCM as the tuner ran it before:
  ``--row "ddim-5 float32 unbatched: ckpt=models/dcm_diverse_contact.ckpt robot_free.sampling_steps=5
  robot_free.precision=float32 robot_free.batched_search=false"``); a row's ``objective=`` scores its virtual trials
  with that L_task (e.g. ``--row "wipe: ckpt=<a force_and_pose student> objective=wipe"``), the simulator's with
  the quickstart's;
* ``--sim-trials`` simulator rollouts of the same skill (seeded random schedules from the same box), whose
  mean time per trial is extrapolated to ``--trials``;

and prints, per row, the wall time split into model (the predictor's calls), inputs (schedules and
attractors), optimiser (ask + tell) and overhead (the rest of the loop), how many times faster than the
simulated trials it is, and the load average before and after. Trailing ``k=v`` arguments override the
quickstart's settings for every row (e.g. ``device=cuda``). It reports numbers; it asserts nothing.
"""

from __future__ import annotations

import argparse
import os
import time
import warnings
from pathlib import Path
from typing import Any

CONF_DIR = Path(__file__).resolve().parents[1] / "conf"


def load_average() -> str:
    try:
        return "/".join(f"{v:.2f}" for v in os.getloadavg())
    except OSError:  # pragma: no cover - not on every platform
        return "n/a"


def compose(overrides: list[str]) -> Any:
    from hydra import compose as hydra_compose
    from hydra import initialize_config_dir

    with initialize_config_dir(config_dir=str(CONF_DIR)):
        return hydra_compose(config_name="quickstart", overrides=["out_dir=unused", *overrides])


def parse_row(text: str) -> tuple[str, list[str]]:
    label, _, overrides = text.partition(":")
    return label.strip(), overrides.split()


def time_model(cfg: Any, spec: Any, simulator: Any, demo: Any, skill: Any, space: Any) -> dict[str, float]:
    """One robot-free search of ``cfg.robot_free.n_trials`` virtual trials, as ``tune`` runs it, timed."""
    from dataclasses import replace

    from dcm.control.objectives import TaskObjective
    from dcm.devices import resolve_device
    from dcm.models.predict import describe
    from dcm.search import make_search
    from dcm.tuning.objectives import ModelObjective
    from dcm.tuning.optimize import LoopTimes, optimize
    from dcm.tuning.predictor import load_predictor
    from dcm.tuning.setup import free_search_options

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the quickstart's recording warning, not a timing
        model = load_predictor(cfg, spec, resolve_device(cfg.device, "device"))
    row_objective = TaskObjective.from_config(cfg.objective)
    if row_objective != skill.objective:  # a row of its own objective (a wipe model: objective=wipe) costs its L_task
        skill = replace(skill, objective=row_objective)
    objective = ModelObjective(model, skill, simulator, demo, cfg.robot_free.n_samples,
                               seed=cfg.seed)
    search = make_search(cfg.search.name, space, cfg.seed, **free_search_options(cfg))
    times = LoopTimes()
    optimize(search, objective, cfg.robot_free.n_trials, cfg.robot_free.batch_size, times=times, progress=False)
    described = describe(model, cfg.robot_free.n_samples)  # the sampler in use, e.g. a student's one step
    return {"total": times.total, "model": objective.seconds_model, "inputs": objective.seconds_inputs,
            "optimiser": times.optimiser,
            "overhead": times.total - objective.seconds_model - objective.seconds_inputs - times.optimiser,
            "precision": getattr(model, "inference_precision", "-"),
            "sampler": f"{described.get('sampler', '-')}-{described.get('sampling_steps', '-')}",
            "shared_steps": getattr(model, "resolved_shared_steps", 0)}


def time_simulator(simulator: Any, demo: Any, skill: Any, space: Any, count: int, seed: int) -> float:
    """Mean wall seconds per simulated trial of ``count`` seeded random schedules."""
    from dcm.search import make_search
    from dcm.tuning.objectives import SimulatorObjective

    search = make_search("random", space, seed)
    proposals = [search.ask() for _ in range(count)]
    objective = SimulatorObjective(simulator, demo, skill)
    start = time.perf_counter()
    for proposal in proposals:
        objective(proposal[None])
    return (time.perf_counter() - start) / count


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--threads", type=int, default=1, help="torch threads of every model row")
    parser.add_argument("--trials", type=int, default=1000, help="virtual trials per row; simulated ones extrapolated")
    parser.add_argument("--sim-trials", type=int, default=50, help="simulator rollouts actually run")
    parser.add_argument("--samples", type=int, default=16, help="samples per virtual trial of the second row")
    parser.add_argument("--row", action="append", default=[], metavar='"LABEL: k=v ..."',
                        help="another model row: a label and its overrides (repeatable)")
    parser.add_argument("--parallel-retention", action="store_true",
                        help="predict with the RetNet's parallel form instead of its chunkwise one (same outputs)")
    parser.add_argument("overrides", nargs="*", help="k=v overrides of conf/quickstart.yaml for every row")
    args = parser.parse_args()
    if args.parallel_retention:
        from dcm.models.nets.retnet import MultiScaleRetention

        MultiScaleRetention.CHUNK_STEPS = 2**31  # longer than any demo: the parallel form everywhere

    import torch

    from dcm.tuning.checks import check_config
    from dcm.tuning.setup import record_skill

    torch.set_num_threads(args.threads)
    common = [f"robot_free.n_trials={args.trials}", f"torch_threads={args.threads}", *args.overrides]
    rows = [("default", []),
            (f"{args.samples} samples", [f"robot_free.n_samples={args.samples}", "robot_free.task_loss=over_samples"]),
            *map(parse_row, args.row)]
    base = compose(common)
    load_before = load_average()
    checked = check_config(base)
    simulator, demo, skill = record_skill(base, checked)
    space = checked.space
    print(f"quickstart skill {checked.spec.name} (H = {demo.horizon}, {base.embodiment}), ckpt {base.ckpt}, "
          f"torch threads {torch.get_num_threads()}, {os.cpu_count()} CPUs, load average {load_before} before")

    sim_s = time_simulator(simulator, demo, skill, space, args.sim_trials, int(base.seed))
    sim_total = sim_s * args.trials
    print(f"simulator: {args.sim_trials} rollouts at {1 / sim_s:.2f} trials/s -> {args.trials} simulated trials "
          f"{sim_total:.1f} s (extrapolated), load average {load_average()}", flush=True)

    header = (f"{'row':<34} {'precision':>9} | {'wall s':>7} {'model':>6} {'inputs':>6} {'optim':>6} {'other':>6} "
              f"| {'optim %':>7} {'trials/s':>8} | {'x faster than sim':>17} | load avg")
    lines = []
    for label, overrides in rows:
        cfg = compose([*common, *overrides])
        t = time_model(cfg, checked.spec, simulator, demo, skill, space)
        settings = f"{t['sampler']}, k={cfg.robot_free.n_samples}"
        if cfg.robot_free.n_samples > 1:
            settings += f", shared {t['shared_steps']}"
        lines.append(f"{label + ' (' + settings + ')':<34} {t['precision']:>9} | {t['total']:7.1f} {t['model']:6.1f} "
                     f"{t['inputs']:6.2f} {t['optimiser']:6.2f} {t['overhead']:6.2f} | "
                     f"{100 * t['optimiser'] / t['total']:6.1f}% {args.trials / t['total']:8.0f} | "
                     f"{sim_total / t['total']:16.1f}x | {load_average()}")
        print(lines[-1] if len(lines) > 1 else f"{header}\n{lines[-1]}", flush=True)
    print(f"\n{args.trials} virtual trials against {args.trials} simulated trials ({sim_total:.1f} s), "
          f"torch threads {args.threads}; load average before {load_before}, after {load_average()}")
    print(header + "\n" + "\n".join(lines))


if __name__ == "__main__":
    main()
