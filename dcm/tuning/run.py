"""Robot-free stiffness tuning of one new skill, validated in the simulator and compared with robot-based search.

Steps (each resumable from the run directory):
1. record the new skill's demo in the simulator;
2. robot-free search: ``robot_free.n_trials`` virtual trials, L_task predicted by the checkpoint (or by a
   stiffness reference JSON, ``python -m dcm.models.references fit``; ``copy_demo`` is refused: it ranks nothing);
3. validate up to ``robot_free.n_validate`` solutions spread along the predicted Pareto front in the simulator;
4. robot-based search: ``robot_based.n_trials`` simulated trials with the same strategy;
5. hypervolume I_H of both, against one reference point, written to ``results.json`` with figures.
"""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Any

import numpy as np
import torch

from dcm.control import phase_boundaries
from dcm.data.search import SearchSpace, make_search
from dcm.tuning.objectives import ModelObjective, SimulatorObjective, Skill
from dcm.tuning.optimize import TrialLog, optimize
from dcm.tuning.pareto import hypervolume, pareto_mask, reference_point
from dcm.tuning.report import plot_pareto, plot_solution_forces


def pick_spread(objectives: np.ndarray, count: int) -> np.ndarray:
    """Indices of up to ``count`` Pareto-optimal rows spread evenly along the front (sorted by L_comp)."""
    finite = np.flatnonzero(np.isfinite(objectives).all(axis=1))
    front = finite[pareto_mask(objectives[finite])]
    front = front[np.argsort(objectives[front, 1])]
    if len(front) <= count:
        return front
    return front[np.unique(np.round(np.linspace(0, len(front) - 1, count)).astype(int))]


def resolve_device(name: str) -> str:
    if name == "auto":
        return "cuda" if torch.cuda.is_available() else "cpu"
    return name


def tune(cfg: Any, out_dir: Path) -> dict[str, Any]:
    """Run the whole comparison for the config of ``conf/tune.yaml``; returns what ``results.json`` holds."""
    from omegaconf import OmegaConf

    from dcm.data.generate import resolve_domain
    from dcm.models.predict import load_model
    from dcm.sim.demos import DemoSpec
    from dcm.sim.rollout import Simulator

    out_dir.mkdir(parents=True, exist_ok=True)
    model = load_model(cfg.ckpt, map_location=resolve_device(cfg.device))
    if not getattr(model, "ranks_schedules", True):
        raise ValueError(f"ckpt={cfg.ckpt} cannot tune: it predicts F_obs = F_demo, hence L_task = 0, for every "
                         "stiffness schedule, so it cannot rank them; use a checkpoint or a stiffness reference "
                         "JSON (python -m dcm.models.references fit)")
    if hasattr(model, "check_phases"):  # the stiffness reference reads K as per-phase values
        model.check_phases(cfg.stiffness.n_phases, source="tune stiffness.n_phases")
    spec_model = model.data_spec
    spec_model.check(spec_model.cond_channels, spec_model.target_channels, cfg.control_hz,
                     source=f"tune.control_hz for {cfg.ckpt}")

    if cfg.demo_file:
        spec = DemoSpec.load(cfg.demo_file)
    else:
        spec = DemoSpec.from_dict(OmegaConf.to_container(cfg.demo, resolve=True), where="tune.demo")
    simulator = Simulator(embodiment=cfg.embodiment, bowl=spec.bowl, domain=resolve_domain(OmegaConf.to_container(cfg.domain) if OmegaConf.is_config(cfg.domain) else cfg.domain),
                          control_hz=cfg.control_hz, seed=cfg.seed, damping=cfg.stiffness.damping)
    demo = simulator.record_demo(spec)
    stiffness_cfg = cfg.stiffness
    boundaries = phase_boundaries(stiffness_cfg.phases, stiffness_cfg.n_phases, demo.force_demo)
    skill = Skill(demo.x_demo, demo.force_demo, boundaries, stiffness_cfg.rot_Nmprad)
    space = SearchSpace(stiffness_cfg.n_phases, stiffness_cfg.min_Npm, stiffness_cfg.max_Npm, stiffness_cfg.log)

    def new_search():
        return make_search(cfg.search.name, space, cfg.seed, **cfg.search.options)

    model_objective = ModelObjective(model, skill, lambda k: simulator.attractor(demo, k), cfg.robot_free.n_samples)
    start = time.perf_counter()
    free_log = optimize(new_search(), model_objective, cfg.robot_free.n_trials, cfg.robot_free.batch_size,
                        out_dir / "robot_free_trials.npz", desc="robot-free (model)")
    free_seconds = time.perf_counter() - start
    free_params, free_predicted = free_log.arrays()

    chosen = pick_spread(free_predicted, cfg.robot_free.n_validate)
    validation = SimulatorObjective(simulator, demo, skill)
    start = time.perf_counter()
    validated = validation(free_params[chosen])
    validation_seconds = time.perf_counter() - start

    robot_based = np.zeros((0, 2))
    robot_seconds = 0.0
    if cfg.robot_based.n_trials > 0:
        start = time.perf_counter()
        robot_log = optimize(new_search(), SimulatorObjective(simulator, demo, skill), cfg.robot_based.n_trials,
                             1, out_dir / "robot_based_trials.npz", desc="robot-based (simulator)")
        robot_seconds = time.perf_counter() - start
        robot_based = robot_log.arrays()[1]

    finite = lambda a: a[np.isfinite(a).all(axis=1)]  # noqa: E731
    reference = reference_point(finite(validated), finite(robot_based))
    results = {
        "checkpoint": str(cfg.ckpt),
        "model": type(model).__name__,
        "demo": spec.to_dict(),
        "embodiment": cfg.embodiment,
        "reference_point": {"L_task_N": reference[0], "L_comp_kNpm": reference[1]},
        "robot_free": {
            "n_virtual_trials": len(free_log),
            "seconds": free_seconds,
            "n_validated": len(chosen),
            "validation_seconds": validation_seconds,
            "hypervolume": hypervolume(finite(validated), reference),
            "solutions": [
                {
                    "phase_stiffness_Npm": free_params[i].tolist(),
                    "predicted": {"L_task_N": free_predicted[i, 0], "L_comp_kNpm": free_predicted[i, 1]},
                    "validated": {"L_task_N": validated[j, 0], "L_comp_kNpm": validated[j, 1],
                                  "failed": bool(np.isnan(validated[j]).any())},
                }
                for j, i in enumerate(chosen)
            ],
        },
        "robot_based": {
            "n_trials": len(robot_based),
            "seconds": robot_seconds,
            "hypervolume": hypervolume(finite(robot_based), reference) if len(robot_based) else None,
        },
    }
    (out_dir / "results.json").write_text(json.dumps(results, indent=2, default=float))
    plot_pareto(out_dir / "pareto.png", free_predicted[np.isfinite(free_predicted).all(axis=1)], finite(validated),
                finite(robot_based), reference, type(model).__name__)
    _plot_best(out_dir / "solution_forces.png", model_objective, free_params[chosen], validated, validation.trials,
               demo)
    return results


def _plot_best(path: Path, objective: ModelObjective, params: np.ndarray, validated: np.ndarray,
               trials: list[Any], demo: Any) -> None:
    """Forces of the validated solution with the lowest genuine L_task."""
    if not len(params) or np.isnan(validated[:, 0]).all():
        return
    best = int(np.nanargmin(validated[:, 0]))
    stiffness, predicted, _ = objective.predict(params[best : best + 1])
    plot_solution_forces(path, demo.dt, demo.force_demo, None if predicted is None else predicted[0],
                         trials[best].force_obs, stiffness[0],
                         f"validated solution {best}: L_task={validated[best, 0]:.2f} N, "
                         f"L_comp={validated[best, 1]:.2f} kN/m")


__all__ = ["TrialLog", "pick_spread", "tune"]
