"""What a study measures without a model: the fixed reference point and the model-free prior.

**Reference point.** Hypervolumes compare only against one point, and a point pooled from the worst results
lets one diverging outlier decide every I_H. The study fixes it per skill from the skill itself:
``(task_factor × L_task of a rollout at the demo's own stiffness, comp_factor × L_comp at max stiffness)``.
The demo's stiffness is what the demonstrator used, so "no worse than ``task_factor`` times that" is the
accuracy a tuned schedule must reach to count at all; the stiffest schedule bounds L_comp for every
schedule of the search space, so no solution is cut off by compliance.

**Model-free prior.** ``n_levels`` constant isotropic stiffness schedules at the midpoints of ``n_levels``
equal bins of [min_Npm, max_Npm] (5 levels, default space: 240, 520, 800, 1080, 1360 N/m), validated like a
tuner's solutions. Constant levels rather than random schedules because: L_comp of a constant isotropic
schedule is linear in its level, so the 5 points are spread evenly along L_comp by construction; it is what
an engineer would try without any model; and 5 random schedules would duplicate robot-based N = 5, whose
first ``n_startup_trials`` (10) MOTPE trials are random already. The prior is seed-independent in a
noise-free domain, so its I_H is the same for every seed there.

**Judging by the expected loss.** With ``validation_rollouts`` R > 1 (a domain where one rollout is one draw
of a spread), every solution is judged by its mean L_task over R rollouts: the reference point's demo
rollout, the prior's levels and, through :func:`run_robot_based_picks`, the robot-based search truncated to
N trials, whose front of one-rollout values is re-run like a robot-free tuner's Pareto set.
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from dcm.control import compliance_loss
from dcm.data.atomic import atomic_path
from dcm.tuning.objectives import SimulatorObjective, Skill


@dataclass
class SkillSetup:
    """The recorded skill of a tune config, as :func:`dcm.tuning.run.tune` builds it."""

    spec: Any  # DemoSpec
    space: Any  # SearchSpace
    simulator: Any
    demo: Any
    skill: Skill

    def evaluate(self, phase_stiffness: np.ndarray, rollouts: int = 1) -> np.ndarray:
        """(B, P, 3) N/m -> (B, 2) simulated (L_task, L_comp), L_task the mean over ``rollouts``; NaN rows for
        failed rollouts."""
        return self.objective(rollouts)(phase_stiffness)

    def objective(self, rollouts: int = 1) -> SimulatorObjective:
        return SimulatorObjective(self.simulator, self.demo, self.skill, rollouts)


def setup_skill(tune_cfg: Any) -> SkillSetup:
    """Record the demo of ``tune_cfg`` in its simulator and build its skill (the same steps as ``tune``)."""
    from dcm.tuning.checks import check_config
    from dcm.tuning.setup import record_skill

    checked = check_config(tune_cfg)
    simulator, demo, skill = record_skill(tune_cfg, checked)
    return SkillSetup(checked.spec, checked.space, simulator, demo, skill)


def max_compliance_loss(setup: SkillSetup) -> float:
    """L_comp [kN/m] of the stiffest schedule of the search space (every axis at max_Npm)."""
    stiffest = np.full((1, setup.space.n_phases, 3), setup.space.max_Npm)
    return float(compliance_loss(setup.skill.schedules(stiffest))[0])


def demo_reference_point(setup: SkillSetup, task_factor: float, comp_factor: float,
                         rollouts: int = 1) -> dict[str, Any]:
    """The study's reference point from the demo's own stiffness rollout (the mean of ``rollouts``); raises if
    that rollout fails."""
    demo_stiffness = np.tile(np.asarray(setup.spec.stiffness_Npm, dtype=np.float64), (1, setup.space.n_phases, 1))
    task, comp = setup.evaluate(demo_stiffness, rollouts)[0]
    if not np.isfinite(task):
        raise RuntimeError(f"the rollout at the demo's own stiffness {list(setup.spec.stiffness_Npm)} N/m failed, "
                           "so it cannot set the reference point; give reference_point.value=[L_task_N,L_comp_kNpm]")
    return {"L_task_N": float(task_factor * task), "L_comp_kNpm": float(comp_factor * max_compliance_loss(setup)),
            "source": "demo_stiffness",
            "demo_stiffness_Npm": [float(v) for v in setup.spec.stiffness_Npm],
            "demo_stiffness_L_task_N": float(task), "demo_stiffness_L_comp_kNpm": float(comp),
            "task_factor": float(task_factor), "comp_factor": float(comp_factor)}


def prior_levels(min_Npm: float, max_Npm: float, n_levels: int) -> np.ndarray:
    """Midpoints of ``n_levels`` equal bins of [min_Npm, max_Npm] (N/m)."""
    return min_Npm + (np.arange(n_levels) + 0.5) * (max_Npm - min_Npm) / n_levels


def run_prior(setup: SkillSetup, n_levels: int, out_dir: Path, rollouts: int = 1) -> dict[str, Any]:
    """Validate the prior's schedules in the simulator; writes ``results.json`` to ``out_dir`` (a finished run)."""
    from dcm.tuning.pareto import solution_record

    levels = prior_levels(setup.space.min_Npm, setup.space.max_Npm, n_levels)
    schedules = np.stack([np.full((setup.space.n_phases, 3), level) for level in levels])
    start = time.perf_counter()
    validated = setup.evaluate(schedules, rollouts)
    seconds = time.perf_counter() - start
    results = {
        "tuner": "prior",
        "seed": int(setup.simulator.seed),
        "levels_Npm": levels.tolist(),
        "validation_seconds": seconds,
        "solutions": [solution_record(k, v) for k, v in zip(schedules, validated)],
    }
    write_json(out_dir / "results.json", results)
    return results


def run_robot_based_picks(setup: SkillSetup, params: np.ndarray, objectives: np.ndarray, n_validate: int,
                          rollouts: int, out_dir: Path, tuned: dict[str, Any] | None = None) -> dict[str, Any]:
    """Re-run up to ``n_validate`` picks spread along the front of a robot-based search's trials (``params`` and
    their one-rollout ``objectives``, truncated to N) over ``rollouts`` rollouts each; writes ``results.json``.

    Why: in a domain with a per-rollout spread the search's own values of its front are the lucky draws it
    kept, so its I_H from them would be judged on other terms than the robot-free tuners' validated solutions.
    ``tuned``: the ``robot_based`` entry of the tune run that ran the search; when it validated these very
    picks over as many rollouts (its whole search, N = all trials), its numbers are taken instead of re-run.
    """
    from dcm.tuning.pareto import pick_spread, solution_record
    from dcm.tuning.run import validate_front

    picks = pick_spread(objectives, n_validate)
    reused = tuned is not None and tuned.get("validation_rollouts") == rollouts and "solutions" in tuned and \
        [s["phase_stiffness_Npm"] for s in tuned["solutions"]] == params[picks].tolist()
    if reused:
        solutions, seconds = tuned["solutions"], tuned["validation_seconds"]
    else:
        start = time.perf_counter()
        _, validated = validate_front(setup.objective(rollouts), params, objectives, n_validate)
        seconds = time.perf_counter() - start
        solutions = [solution_record(params[i], v, observed=objectives[i]) for i, v in zip(picks, validated)]
    results = {
        "tuner": f"robot_based_{len(params)}",
        "seed": int(setup.simulator.seed),
        "validation_rollouts": int(rollouts),
        "validation_seconds": seconds,
        "solutions": solutions,
    }
    write_json(out_dir / "results.json", results)
    return results


def write_json(path: Path, data: Any) -> None:
    """Write atomically: a file that exists is complete (a study treats a run with results.json as finished)."""
    with atomic_path(path) as tmp:
        tmp.write_text(json.dumps(data, indent=2, default=float))
