"""The oracle: every schedule of a set rolled out ``rollouts`` times on one skill, in the simulator.

What is kept per (schedule, rollout) is enough for every certification statistic without re-running: the squared
force error (mean over the 3 axes per step) and the squared path error (the tool's distance to the demo's in the
surface's tangent plane, ``dcm.control.objectives.path_error``) each summed over the approach and over the whole
trajectory, and the step counts, so L_task of either objective (``task.OBJECTIVES``) can be formed over the whole
trajectory or from contact on. A schedule set is per-phase isotropic (S, P) or per-phase diagonal (S, P, 3) along
the axes of a stiffness frame (world, or surface: the frame that follows the demo's normal). Rollout r of every
schedule meets the same disturbance draws (``Simulator.rollout(common_draws=True)``), so schedules are compared on
equal terms. One skill's results are one ``.npz``, written atomically; a finished skill is skipped on a re-run, so
a killed run resumes where it stopped.
"""

from __future__ import annotations

import json
import os
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from dcm.control import compliance_loss, equal_time_phases, schedule_from_phases
from dcm.control.objectives import PAPER, TaskObjective
from studies.benchmark import task as bench


def skill_path(out_dir: Path, seed: int) -> Path:
    return Path(out_dir) / "skills" / f"paced_{seed}.npz"


def run_skill(seed: int, out_dir: Path, rollouts: int = bench.ROLLOUTS, domain: Any = bench.DOMAIN,
              spec_override: dict[str, Any] | None = None, schedules: np.ndarray | None = None,
              first_repeat: int = 0, tag: str = "", embodiment: str = bench.EMBODIMENT,
              revision: str = bench.REVISION, frame: str = "world", kinds: list[str] | None = None) -> Path:
    """Roll out every oracle schedule ``rollouts`` times on the skill of ``seed``; returns the ``.npz`` path.

    ``domain`` is a preset name or DomainSpec mapping; ``spec_override`` replaces fields of the skill's spec
    (the known-answer checks use it: a flat plate, no disturbance); ``first_repeat`` > 0 draws fresh rollouts
    (``Simulator.rollout(repeat=...)``) that none of the first ones shares; ``revision`` names the task revision
    (``task.REVISIONS``) the skill is drawn from. ``schedules`` is (S, P) isotropic or (S, P, 3) per axis of
    ``frame`` (``world`` or ``surface``); ``kinds`` names what each one is (default "given").
    """
    from dcm.control import StiffnessSchedule, frame_axes
    from dcm.control.objectives import surface_normals, tangential
    from dcm.sim import DemoSpec, DomainSpec, Simulator

    path = skill_path(out_dir, seed) if not tag else Path(out_dir) / "skills" / f"paced_{seed}_{tag}.npz"
    if path.is_file():
        return path
    spec_dict = {**bench.skill_spec(seed, revision), **(spec_override or {})}
    spec = DemoSpec.from_dict(spec_dict, where=f"benchmark skill {seed}")
    dom = DomainSpec.resolve(domain)
    sim = Simulator(embodiment=embodiment, bowl=spec.bowl, domain=dom, control_hz=bench.CONTROL_HZ)
    demo = sim.record_demo(spec)
    boundaries = equal_time_phases(demo.horizon, bench.N_PHASES)
    sched = bench.oracle_schedules()
    phase_Npm = sched.phase_Npm if schedules is None else np.asarray(schedules, dtype=np.float64)
    if kinds is None:
        kinds = sched.kinds if schedules is None else ["given"] * len(phase_Npm)
    diagonal = bench.phase_diagonal(phase_Npm)
    if frame not in ("world", "surface"):
        raise ValueError(f"stiffness frame {frame!r} is unknown; expected world or surface")
    axes = frame_axes(frame, demo.x_demo, demo.force_demo, f"benchmark skill {seed}")
    normals = surface_normals(demo.x_demo, demo.force_demo)
    n_s = len(phase_Npm)
    approach_steps = int(round(spec.approach_s * bench.CONTROL_HZ))
    sq_total = np.full((n_s, rollouts), np.nan)
    sq_approach = np.full((n_s, rollouts), np.nan)
    path_total = np.full((n_s, rollouts), np.nan)
    path_approach = np.full((n_s, rollouts), np.nan)
    failed = np.zeros((n_s, rollouts), dtype=bool)
    comp = np.zeros(n_s)
    start = time.time()
    for i, levels in enumerate(diagonal):
        stiffness = schedule_from_phases(levels, boundaries)
        comp[i] = float(compliance_loss(stiffness))
        commanded = stiffness if axes is None else StiffnessSchedule(stiffness, axes)
        for r in range(rollouts):
            trial = sim.rollout(demo, commanded, repeat=first_repeat + r, common_draws=True)
            if trial.failed:
                failed[i, r] = True
                continue
            sq = ((trial.force_obs[:, :3] - demo.force_demo[:, :3]) ** 2).mean(axis=1)
            sq_total[i, r] = float(sq.sum())
            sq_approach[i, r] = float(sq[:approach_steps].sum())
            path_sq = (tangential(trial.x_obs[:, :3] - demo.x_demo[:, :3], normals) ** 2).sum(axis=1)
            path_total[i, r] = float(path_sq.sum())
            path_approach[i, r] = float(path_sq[:approach_steps].sum())
        done = i + 1
        if done % 8 == 0 or done == n_s:
            rate = (time.time() - start) / done
            print(f"[skill {seed}{'/' + tag if tag else ''}] {done}/{n_s} schedules, {rate * 1:.1f} s each, "
                  f"ETA {rate * (n_s - done) / 60:.1f} min", file=sys.stderr, flush=True)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".tmp.npz")
    np.savez(tmp, phase_Npm=phase_Npm, L_comp=comp, sq_total=sq_total, sq_approach=sq_approach, failed=failed,
             path_sq_total=path_total, path_sq_approach=path_approach, frame=frame,
             horizon=demo.horizon, approach_steps=approach_steps, kinds=np.array(kinds),
             spec=json.dumps(spec.to_dict()), domain=json.dumps(dom.to_dict()),
             demo_force_mean_N=float(np.abs(demo.force_demo[:, 2]).mean()))
    os.replace(tmp, path)
    return path


def task_losses(data: Any, from_contact: bool, objective: TaskObjective = PAPER) -> np.ndarray:
    """(S, R) L_task of each rollout under ``objective`` (the paper's force RMSE [N] by default, or a wipe's
    combined error in tolerances): over the whole trajectory, or from the end of the approach on. Failed rollouts
    are inf. A wipe needs the path sums, which oracle files written before them lack (refused, saying so)."""
    horizon, approach = int(data["horizon"]), int(data["approach_steps"])
    steps = horizon - approach if from_contact else horizon
    force_sq = data["sq_total"] - data["sq_approach"] if from_contact else data["sq_total"]
    force = np.sqrt(force_sq / steps)
    if objective.counts_path:
        if "path_sq_total" not in data:
            raise ValueError("this oracle file holds no path errors (written before they were kept); "
                             f"objective {objective.describe()} needs them: re-run the oracle")
        path_sq = data["path_sq_total"] - data["path_sq_approach"] if from_contact else data["path_sq_total"]
        loss = objective.combine(force, np.sqrt(path_sq / steps))
    else:
        loss = objective.combine(force, None)
    return np.where(data["failed"], np.inf, loss)


def squared_error_sums(data: Any, objective: TaskObjective = PAPER) -> tuple[np.ndarray, np.ndarray]:
    """(approach, total) (S, R) sums over steps of the squared error L_task combines: the force's (mean over axes)
    in N^2, or a wipe's (force / tolerance)^2 + (path / tolerance)^2. T1's approach share is their ratio."""
    if objective.name == "paper":
        return data["sq_approach"], data["sq_total"]
    scale_f = objective.force_tolerance_N ** -2
    if not objective.counts_path:
        return data["sq_approach"] * scale_f, data["sq_total"] * scale_f
    scale_p = objective.path_tolerance_m ** -2
    return (data["sq_approach"] * scale_f + data["path_sq_approach"] * scale_p,
            data["sq_total"] * scale_f + data["path_sq_total"] * scale_p)
