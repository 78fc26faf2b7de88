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
    """The schedules the oracle judges and what each one is.

    ``phase_Npm`` is (S, P) for per-phase isotropic stiffness [N/m] (the committed task's grid), or (S, P, 3)
    for the diagonal per phase along the axes of ``frame``: world (K_x, K_y, K_z) or surface (K_t, K_t, K_n)
    (``dcm.control.StiffnessSchedule``).
    """

    phase_Npm: np.ndarray
    kinds: list[str] = field(default_factory=list)  # "grid", "prior", "demo", "design"
    frame: str = "world"

    def diagonal(self) -> np.ndarray:
        """(S, P, 3) the diagonal per phase in the frame's axes."""
        return phase_diagonal(self.phase_Npm)

    def labels(self) -> list[str]:
        return [schedule_label(row, self.frame) for row in self.phase_Npm]


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


# ---------------------------------------------------------------------------------------------------------------
# Designs of issue 67: the objective, the stiffness frame, the schedule set and the domain a run chooses.
# The committed task (PROTOCOL.md section 1) is the design "paper_isotropic"; the others are candidates designed on
# the train seeds (studies/benchmark/reports/wipe_designs.md). No disturbance is resized by any of them.

# The objectives an oracle run can score (dcm.control.objectives.TaskObjective). "wipe" is conf/objective/wipe.yaml
# with its tolerances as the docs fix them (1 N, 5 mm; docs/conventions.md "Objectives and hypervolume").
OBJECTIVES = {"paper": {"name": "paper"},
              "wipe": {"name": "wipe", "force_tolerance_N": 1.0, "path_tolerance_m": 0.005}}
# Domains: the benchmark's replaced_bowl (docs/benchmark_task.md gives each size and its source), and the same with
# the Panda's joint friction as Gaz et al. (IEEE RA-L 2019) identified it (docs/benchmark_task.md "The arm's own
# friction"; DomainSpec(joint_friction="gaz2019")).
DOMAINS: dict[str, str | dict[str, Any]] = {
    "replaced_bowl": "replaced_bowl",
    "replaced_bowl_gaz2019": {"preset": "replaced_bowl", "name": "replaced_bowl_gaz2019",
                              "joint_friction": "gaz2019"},
}
# Stiffness levels of the anisotropic sets [N/m]. They are the isotropic grid's levels (GRID_LEVELS_NPM), no new
# size: stiff along the surface (K_t, or K_x = K_y) from 400 to 2500 N/m, soft along the normal (K_n, K_z) from
# 150 to 1000 N/m, the practice docs/conventions.md "Stiffness frames" describes (soft along the normal so a
# placement error costs little force, stiff along the surface so a friction change moves the tool little). Which
# three or two levels per axis is a choice of the design (an assumption, sized for a 15 min train run), not a
# measured value.
TANGENT_LEVELS_NPM = (400.0, 1000.0, 2500.0)
NORMAL_LEVELS_NPM = (150.0, 400.0, 1000.0)
TANGENT_PHASE_LEVELS_NPM = (400.0, 2500.0)  # K_t varied per phase, with K_n held at one of:
NORMAL_HELD_LEVELS_NPM = (150.0, 400.0)
WORLD_Z_LEVELS_NPM = (150.0, 400.0)  # the probe of issue 67: K_x = K_y per phase in TANGENT_LEVELS_NPM, K_z held


def phase_diagonal(phase_Npm: np.ndarray) -> np.ndarray:
    """(S, P, 3) of per-phase values (S, P) isotropic or (S, P, 3) already per axis."""
    values = np.asarray(phase_Npm, dtype=np.float64)
    return np.repeat(values[..., None], 3, axis=-1) if values.ndim == 2 else values


def schedule_label(row: np.ndarray, frame: str = "world") -> str:
    """"150/400/150" for an isotropic schedule; per phase "t<K_t>n<K_n>" (surface) or "xy<K>z<K>" (world,
    K_x = K_y) otherwise, the phases joined by "/" as the isotropic ones are."""
    row = np.asarray(row, dtype=np.float64)
    if row.ndim == 1 or np.all(row == row[:, :1]):
        return "/".join(f"{k:g}" for k in (row if row.ndim == 1 else row[:, 0]))
    parts = []
    for x, y, z in row:
        if frame == "surface" and x == y:
            parts.append(f"t{x:g}n{z:g}")
        elif x == y:
            parts.append(f"xy{x:g}z{z:g}")
        else:
            parts.append(f"{x:g},{y:g},{z:g}")
    return "/".join(parts)


def _with_prior_and_demo(rows: list[np.ndarray], kinds: list[str], frame: str) -> ScheduleSet:
    """Append the prior's isotropic constants and the demo's 800 N/m where the set does not hold them (every set
    holds both: the prior is T3's control and the demo's stiffness sets the I_H reference point)."""
    seen = {tuple(np.asarray(r).ravel()) for r in rows}
    for level, kind in [(lv, "prior") for lv in PRIOR_LEVELS_NPM] + [(DEMO_STIFFNESS_NPM, "demo")]:
        row = np.full((N_PHASES, 3), level)
        if tuple(row.ravel()) not in seen:
            rows.append(row)
            kinds.append(kind)
            seen.add(tuple(row.ravel()))
    return ScheduleSet(np.asarray(rows, dtype=np.float64), kinds, frame)


def surface_schedules() -> ScheduleSet:
    """Surface frame: K_n per phase in NORMAL_LEVELS_NPM with K_t held at one of TANGENT_LEVELS_NPM (81), then K_t
    per phase in TANGENT_PHASE_LEVELS_NPM with K_n held at one of NORMAL_HELD_LEVELS_NPM (those not yet in), then
    the prior and the demo."""
    rows: list[np.ndarray] = []
    kinds: list[str] = []
    seen: set[tuple[float, ...]] = set()

    def add(kt: tuple[float, ...], kn: tuple[float, ...]) -> None:
        row = np.column_stack([kt, kt, kn]).astype(np.float64)
        if tuple(row.ravel()) not in seen:
            seen.add(tuple(row.ravel()))
            rows.append(row)
            kinds.append("design")

    for kt in TANGENT_LEVELS_NPM:
        for kn in itertools.product(NORMAL_LEVELS_NPM, repeat=N_PHASES):
            add((kt,) * N_PHASES, kn)
    for kn in NORMAL_HELD_LEVELS_NPM:
        for kt in itertools.product(TANGENT_PHASE_LEVELS_NPM, repeat=N_PHASES):
            add(kt, (kn,) * N_PHASES)
    return _with_prior_and_demo(rows, kinds, "surface")


def world_axis_schedules() -> ScheduleSet:
    """World frame, as the probe of issue 67: the isotropic grid (GRID_LEVELS_NPM per phase), then K_x = K_y per
    phase in TANGENT_LEVELS_NPM with K_z held at one of WORLD_Z_LEVELS_NPM, then the prior and the demo."""
    grid = oracle_schedules()  # the isotropic grid, the prior and the demo
    rows, kinds = list(grid.diagonal()), list(grid.kinds)
    seen = {tuple(r.ravel()) for r in rows}
    for kz in WORLD_Z_LEVELS_NPM:
        for kxy in itertools.product(TANGENT_LEVELS_NPM, repeat=N_PHASES):
            row = np.column_stack([kxy, kxy, (kz,) * N_PHASES]).astype(np.float64)
            if tuple(row.ravel()) not in seen:  # 400 N/m on every axis is already on the grid
                seen.add(tuple(row.ravel()))
                rows.append(row)
                kinds.append("design")
    return _with_prior_and_demo(rows, kinds, "world")


SCHEDULE_SETS = {"isotropic_grid": oracle_schedules, "surface_tn": surface_schedules,
                 "world_axis": world_axis_schedules}
# A design: objective, schedule set (its frame with it), domain and revision. "paper_isotropic" is the committed
# task; the wipe designs are issue 67's candidates (reports/wipe_designs.md).
DESIGNS: dict[str, dict[str, str]] = {
    "paper_isotropic": {"objective": "paper", "schedules": "isotropic_grid", "domain": "replaced_bowl",
                        "revision": "paced"},
    "wipe_surface": {"objective": "wipe", "schedules": "surface_tn", "domain": "replaced_bowl", "revision": "paced"},
    "wipe_world_axis": {"objective": "wipe", "schedules": "world_axis", "domain": "replaced_bowl",
                        "revision": "paced"},
    "wipe_surface_gaz2019": {"objective": "wipe", "schedules": "surface_tn", "domain": "replaced_bowl_gaz2019",
                             "revision": "paced"},
    "wipe_world_axis_gaz2019": {"objective": "wipe", "schedules": "world_axis", "domain": "replaced_bowl_gaz2019",
                                "revision": "paced"},
    "wipe_world_axis_fast_third": {"objective": "wipe", "schedules": "world_axis", "domain": "replaced_bowl",
                                   "revision": "fast_third"},
    "wipe_surface_fast_third": {"objective": "wipe", "schedules": "surface_tn", "domain": "replaced_bowl",
                                "revision": "fast_third"},
}


def schedule_set(name: str) -> ScheduleSet:
    if name not in SCHEDULE_SETS:
        raise ValueError(f"benchmark schedule set {name!r} is unknown; known: {sorted(SCHEDULE_SETS)}")
    return SCHEDULE_SETS[name]()


def objective(name: str) -> Any:
    """The TaskObjective of ``name`` (a key of OBJECTIVES)."""
    from dcm.control.objectives import TaskObjective

    if name not in OBJECTIVES:
        raise ValueError(f"benchmark objective {name!r} is unknown; known: {sorted(OBJECTIVES)}")
    return TaskObjective.from_config(OBJECTIVES[name])


def domain(name: str) -> Any:
    """The DomainSpec of ``name`` (a key of DOMAINS)."""
    from dcm.sim import DomainSpec
    from dcm.sim.domain import PRESETS

    if name not in DOMAINS:
        raise ValueError(f"benchmark domain {name!r} is unknown; known: {sorted(DOMAINS)}")
    entry = DOMAINS[name]
    if isinstance(entry, str):
        return DomainSpec.resolve(entry)
    fields = {k: v for k, v in entry.items() if k != "preset"}
    return DomainSpec.from_dict({**PRESETS[str(entry["preset"])], **fields})
