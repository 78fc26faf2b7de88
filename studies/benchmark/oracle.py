"""The oracle: every schedule of a set rolled out ``rollouts`` times on one skill, in the simulator.

What is kept per (schedule, rollout) is enough for every certification statistic without re-running: the
squared force error summed over the approach and over the whole trajectory, and the step counts, so L_task can
be formed over the whole trajectory or from contact on. Rollout r of every schedule meets the same disturbance
draws (``Simulator.rollout(common_draws=True)``), so schedules are compared on equal terms. One skill's
results are one ``.npz``, written atomically; a finished skill is skipped on a re-run, so a killed run resumes
where it stopped.
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
from studies.benchmark import task as bench


def skill_path(out_dir: Path, seed: int) -> Path:
    return Path(out_dir) / "skills" / f"paced_{seed}.npz"


def run_skill(seed: int, out_dir: Path, rollouts: int = bench.ROLLOUTS, domain: Any = bench.DOMAIN,
              spec_override: dict[str, Any] | None = None, schedules: np.ndarray | None = None,
              first_repeat: int = 0, tag: str = "", embodiment: str = bench.EMBODIMENT,
              revision: str = bench.REVISION) -> Path:
    """Roll out every oracle schedule ``rollouts`` times on the skill of ``seed``; returns the ``.npz`` path.

    ``domain`` is a preset name or DomainSpec mapping; ``spec_override`` replaces fields of the skill's spec
    (the known-answer checks use it: a flat plate, no disturbance); ``first_repeat`` > 0 draws fresh rollouts
    (``Simulator.rollout(repeat=...)``) that none of the first ones shares; ``revision`` names the task revision
    (``task.REVISIONS``) the skill is drawn from.
    """
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
    n_s = len(phase_Npm)
    approach_steps = int(round(spec.approach_s * bench.CONTROL_HZ))
    sq_total = np.full((n_s, rollouts), np.nan)
    sq_approach = np.full((n_s, rollouts), np.nan)
    failed = np.zeros((n_s, rollouts), dtype=bool)
    comp = np.zeros(n_s)
    start = time.time()
    for i, levels in enumerate(phase_Npm):
        stiffness = schedule_from_phases(np.repeat(levels[:, None], 3, axis=1), boundaries)
        comp[i] = float(compliance_loss(stiffness))
        for r in range(rollouts):
            trial = sim.rollout(demo, stiffness, repeat=first_repeat + r, common_draws=True)
            if trial.failed:
                failed[i, r] = True
                continue
            sq = ((trial.force_obs[:, :3] - demo.force_demo[:, :3]) ** 2).mean(axis=1)
            sq_total[i, r] = float(sq.sum())
            sq_approach[i, r] = float(sq[:approach_steps].sum())
        done = i + 1
        if done % 8 == 0 or done == n_s:
            rate = (time.time() - start) / done
            print(f"[skill {seed}{'/' + tag if tag else ''}] {done}/{n_s} schedules, {rate * 1:.1f} s each, "
                  f"ETA {rate * (n_s - done) / 60:.1f} min", file=sys.stderr, flush=True)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".tmp.npz")
    np.savez(tmp, phase_Npm=phase_Npm, L_comp=comp, sq_total=sq_total, sq_approach=sq_approach, failed=failed,
             horizon=demo.horizon, approach_steps=approach_steps, kinds=np.array(sched.kinds if schedules is None
                                                                                   else ["given"] * n_s),
             spec=json.dumps(spec.to_dict()), domain=json.dumps(dom.to_dict()),
             demo_force_mean_N=float(np.abs(demo.force_demo[:, 2]).mean()))
    os.replace(tmp, path)
    return path


def task_losses(data: Any, from_contact: bool) -> np.ndarray:
    """(S, R) L_task [N] of each rollout: over the whole trajectory, or from the end of the approach on.
    Failed rollouts are inf."""
    horizon, approach = int(data["horizon"]), int(data["approach_steps"])
    if from_contact:
        loss = np.sqrt((data["sq_total"] - data["sq_approach"]) / (horizon - approach))
    else:
        loss = np.sqrt(data["sq_total"] / horizon)
    return np.where(data["failed"], np.inf, loss)
