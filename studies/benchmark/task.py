"""The benchmark task: which skills, on which bowl, in which domain, and the schedules the oracle judges.

A skill is one seeded draw of the ``paced_curve`` family (a smooth curve wiped at a different drawn speed in
each third of the demo), recorded by the leading demonstrator on one bowl. Skills are named by their seed;
the seed ranges of the splits are fixed here so that design work on TRAIN seeds never sees VALID or the
held-out seeds (studies/benchmark/PROTOCOL.md fixes the held-out ones).
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass, field
from typing import Any

import numpy as np

DOMAIN = "replaced_bowl"  # dcm.sim.domain.PRESETS
EMBODIMENT = "panda"
CONTROL_HZ = 20.0
DURATION_S = 12.0
APPROACH_S = 1.0
N_PHASES = 3
BOWL = {"shape": "spherical_cap", "rim_radius_m": 0.14, "depth_m": 0.04}
FAMILY_PARAMS = {"harmonics": 3, "extent": 0.7, "speed_mps": [0.02, 0.20], "n_segments": N_PHASES,
                 "blend_s": 0.8, "press_range_m": [0.005, 0.015]}
# Task revisions: what each changes in FAMILY_PARAMS. "paced" is the task PROTOCOL.md section 1 describes;
# "fast_third" gives every skill one fast third (0.10-0.20 m/s) at a drawn place and two slow ones
# (0.02-0.05 m/s), so that where stiffness could pay differs between skills (docs/benchmark_task.md).
REVISIONS: dict[str, dict[str, Any]] = {
    "paced": {},
    "fast_third": {"speed_mps": [0.02, 0.05], "fast_speed_mps": [0.10, 0.20]},
}
REVISION = "paced"
DEMO_STIFFNESS_NPM = 800.0

# Seeds of the skills by split. Train seeds are for designing the task and finding the fixed rules; valid seeds
# certify it. (Held-out seeds live in PROTOCOL.md and are never run before the models are trained.)
TRAIN_SEEDS = (1000, 1001, 1002, 1003)
VALID_SEEDS = (2000, 2001, 2002, 2003, 2004, 2005, 2006, 2007)

GRID_LEVELS_NPM = (150.0, 400.0, 1000.0, 2500.0)
# The model-free prior: five constant isotropic levels, log-spaced over the grid's range (both ends included).
PRIOR_LEVELS_NPM = tuple(float(v) for v in np.round(np.geomspace(150.0, 2500.0, 5)))
ROLLOUTS = 8
RULE_SIZE = 5  # a fixed rule proposes as many schedules as the prior (the robot budget of a tuner's validation)


def skill_spec(seed: int, revision: str = REVISION) -> dict[str, Any]:
    """The DemoSpec mapping of the skill drawn with ``seed`` in task ``revision`` (a key of ``REVISIONS``)."""
    if revision not in REVISIONS:
        raise ValueError(f"benchmark task revision {revision!r} is unknown; known: {sorted(REVISIONS)}")
    params = {"seed": int(seed), **FAMILY_PARAMS, **REVISIONS[revision]}
    return {"name": f"paced_{seed}", "family": "paced_curve", "params": params,
            "press_m": 0.01, "duration_s": DURATION_S, "approach_s": APPROACH_S,
            "stiffness_Npm": [DEMO_STIFFNESS_NPM] * 3, "bowl": dict(BOWL), "lead": True}


@dataclass
class ScheduleSet:
    """The per-phase isotropic schedules the oracle judges: (S, P) stiffness [N/m] and what each one is."""

    phase_Npm: np.ndarray
    kinds: list[str] = field(default_factory=list)  # "grid", "prior", "demo"

    def labels(self) -> list[str]:
        return ["/".join(f"{k:g}" for k in row) for row in self.phase_Npm]


def oracle_schedules() -> ScheduleSet:
    """Every grid schedule (levels^P), then the prior's constants not on the grid, then the demo's stiffness."""
    grid = [list(p) for p in itertools.product(GRID_LEVELS_NPM, repeat=N_PHASES)]
    kinds = ["grid"] * len(grid)
    rows = [tuple(r) for r in grid]
    for level in PRIOR_LEVELS_NPM:
        if (level,) * N_PHASES not in rows:
            rows.append((level,) * N_PHASES)
            kinds.append("prior")
    if (DEMO_STIFFNESS_NPM,) * N_PHASES not in rows:
        rows.append((DEMO_STIFFNESS_NPM,) * N_PHASES)
        kinds.append("demo")
    return ScheduleSet(np.asarray(rows, dtype=np.float64), kinds)
