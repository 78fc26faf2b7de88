"""Robot-free tuning throughput: N virtual trials of MOTPE against a checkpoint, for several samplers.

    python bench/tuning_throughput.py --ckpt outputs/train/<run>/checkpoints/last.ckpt
        [--trials 1000] [--batch-sizes 50 200] [--grid ddpm:30 ddim:10 ddim:5 ddim:3] [--embodiment panda]
        [--demo wavelike] [--search-option n_ei_candidates=24 ...]

Runs exactly what ``tune.py`` runs for its robot-free search (dcm.tuning.optimize.optimize with a
ModelObjective on the recorded demo, no log file) and prints, per sampler and batch size, the wall time split
into model (the predictor's call), inputs (schedules and attractors), optimiser (ask + tell) and overhead
(the rest of the loop), and the load average, as a table. It reports numbers; it asserts nothing.
``--grid`` entries are ``sampler:steps``; DDIM steps that do not divide the checkpoint's T are skipped, and
DDPM always runs the full chain of T steps (``ddpm:30`` for T = 30).
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path


def _load_average() -> str:
    try:
        return "/".join(f"{v:.1f}" for v in os.getloadavg())
    except OSError:  # pragma: no cover - not on every platform
        return "n/a"


def _option(text: str) -> tuple[str, object]:
    import yaml

    key, _, value = text.partition("=")
    return key, yaml.safe_load(value)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--ckpt", required=True, type=Path, help="a DCM or baseline checkpoint")
    parser.add_argument("--trials", type=int, default=1000)
    parser.add_argument("--batch-sizes", type=int, nargs="+", default=[50])
    parser.add_argument("--grid", nargs="+", default=["ddpm:30", "ddim:10", "ddim:5", "ddim:3", "ddim_even:2"],
                        help="sampler:steps entries (a baseline ignores them and runs once)")
    parser.add_argument("--embodiment", default="panda")
    parser.add_argument("--demo", default="wavelike", help="conf/demo/<name>.yaml")
    parser.add_argument("--n-samples", type=int, default=1)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--search", default="motpe", help="conf/search/<name>.yaml")
    parser.add_argument("--search-option", action="append", default=[], metavar="KEY=VALUE",
                        help="override a search option, e.g. n_ei_candidates=8 (repeatable)")
    parser.add_argument("--threads", type=int, default=0, help="torch threads (0 = torch default)")
    args = parser.parse_args()

    import torch
    from omegaconf import OmegaConf

    from dcm.control import phase_boundaries
    from dcm.models.dcm import DCM
    from dcm.models.predict import load_model
    from dcm.search import SearchSpace, make_search
    from dcm.sim.demos import DemoSpec
    from dcm.sim.rollout import Simulator
    from dcm.tuning.objectives import ModelObjective, Skill
    from dcm.tuning.optimize import LoopTimes, optimize
    from dcm.tuning.predictor import use_sampler

    if args.threads:
        torch.set_num_threads(args.threads)
    conf = Path(__file__).resolve().parents[1] / "conf"
    stiffness = OmegaConf.load(conf / "stiffness" / "default.yaml")
    search_cfg = OmegaConf.load(conf / "search" / f"{args.search}.yaml")
    options = {**(OmegaConf.to_container(search_cfg.options) or {}), **dict(map(_option, args.search_option))}
    spec = DemoSpec.from_dict(OmegaConf.to_container(OmegaConf.load(conf / "demo" / f"{args.demo}.yaml")),
                              where=f"demo {args.demo}")
    simulator = Simulator(embodiment=args.embodiment, bowl=spec.bowl, control_hz=20.0, seed=args.seed,
                          damping=stiffness.damping)
    demo = simulator.record_demo(spec)
    skill = Skill(demo.x_demo, demo.force_demo,
                  phase_boundaries(stiffness.phases, stiffness.n_phases, demo.force_demo), stiffness.rot_Nmprad)
    space = SearchSpace(stiffness.n_phases, stiffness.min_Npm, stiffness.max_Npm, stiffness.log)

    probe = load_model(args.ckpt)
    T = int(probe.cfg.diffusion_steps) if isinstance(probe, DCM) else 1
    grid: list[tuple[str | None, int | None]] = []
    for entry in args.grid if isinstance(probe, DCM) else ["single-pass:1"]:
        kind, _, steps = entry.partition(":")
        n = int(steps) if steps else T
        if kind == "ddpm" and n != T:
            print(f"skipping {entry}: DDPM runs the full chain of T = {T} steps")
            continue
        if kind == "ddim" and T % n:
            print(f"skipping {entry}: {n} does not divide T = {T}")
            continue
        grid.append((None, None) if kind == "single-pass" else (kind, None if kind == "ddpm" else n))

    print(f"checkpoint {args.ckpt} ({type(probe).__name__}, T = {T}), {args.trials} virtual trials, demo {args.demo} "
          f"(H = {demo.horizon}) on {args.embodiment}, search {args.search} {options}, torch threads "
          f"{torch.get_num_threads()}, {os.cpu_count()} CPUs, load average {_load_average()} at start")
    header = (f"{'sampler':>9} {'steps':>5} {'batch':>5} | {'wall s':>7} {'model s':>7} {'inputs s':>8} "
              f"{'optim s':>7} {'other s':>7} | {'trials/s':>8} {'CPU s':>7} {'load avg':>14}")
    rows = []
    for batch in args.batch_sizes:
        for kind, steps in grid:
            model = load_model(args.ckpt)
            use_sampler(model, kind, steps)
            objective = ModelObjective(model, skill, simulator, demo, args.n_samples,
                                       seed=args.seed)
            times = LoopTimes()
            cpu = time.process_time()
            optimize(make_search(args.search, space, args.seed, **options), objective, args.trials, batch,
                     times=times, progress=False)
            cpu = time.process_time() - cpu
            name = kind or "single"
            shown = steps if steps is not None else T
            row = (f"{name:>8} {shown:>5} {batch:>5} | {times.total:7.1f} {objective.seconds_model:7.1f} "
                   f"{objective.seconds_inputs:8.1f} {times.optimiser:7.1f} "
                   f"{times.total - objective.seconds_model - objective.seconds_inputs - times.optimiser:7.1f} | "
                   f"{args.trials / times.total:8.1f} {cpu:7.1f} {_load_average():>14}")
            rows.append(row)
            print(row if len(rows) > 1 else f"{header}\n{row}", flush=True)
    print("\n" + header + "\n" + "\n".join(rows))


if __name__ == "__main__":
    main()
