"""Generate a dataset: per demo, a robot-based multi-objective stiffness search whose every trial is kept.

    python -m dcm.data.generate                                   # conf/generate.yaml as it stands
    python -m dcm.data.generate dataset=realistic
    python -m dcm.data.generate dataset=tiny embodiment=tool n_trials=5 workers=1 out=/tmp/t.h5
    python -m dcm.data.generate search=random seed=3 stiffness.n_phases=4 stiffness.max_Npm=2000
    python -m dcm.data.generate demo.waypoints=my_path.csv demo.bowl.rim_radius_m=0.12 out=data/mine.h5

Each demo is recorded once, then ``n_trials`` stiffness proposals (one constant [Kx, Ky, Kz] per phase,
from ``search=motpe`` or ``search=random``) are rolled out in the simulator. Demo ``i`` is seeded from
(``seed``, i), so results do not depend on the number of workers, the order or restarts.

Resumable: each finished demo is written atomically to ``<out>.parts/demo_%05d.npz``; rerunning the same
command skips those demos and ends with exactly the arrays of an uninterrupted run. The final HDF5 is also
written atomically. Worker processes exit when the generating process dies, even by ``kill -9``.

Nothing is overwritten silently: every setting is checked before any work starts; an existing ``out`` made
by the same configuration is left alone (exit 0), one made by another configuration is refused with what
differs (e.g. ``seed: 0 -> 3``), and so are part files of another configuration in ``<out>.parts/``;
``overwrite=true`` replaces both.

Sharding for clusters: ``shard.index=i shard.count=n`` generates demos with ``index % n == i`` and writes
``<out stem>.shard-<i>-of-<n>.h5``; ``python -m dcm.data.merge <out> <shard files>`` joins them. With
Hydra's multirun every shard is one job, e.g. locally ``-m shard.count=4 shard.index=0,1,2,3 workers=1``
or on SLURM with the submitit launcher plugin (``pip install hydra-submitit-launcher``)
``-m hydra/launcher=submitit_slurm shard.count=8 shard.index=range(8)``.
"""

from __future__ import annotations

import os
import sys
import time
from collections.abc import Sequence
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from dcm.configs import CONF_DIR, group_choice_problem, register_resolvers
from dcm.console import print_error, quiet_libraries
from dcm.control.objectives import TaskObjective
from dcm.data.generate_checks import (
    GenerationError,
    build_settings,
    check_demos,
    check_embodiment,
    check_run_settings,
    check_stiffness_settings,
    check_waypoint_recording,
    existing_output_is_current,
)
from dcm.data.generate_workers import (
    claim_work_dir,
    finished_jobs,
    job_fingerprints,
    mark_work_dir,
    part_files_in,
    release_work_dir,
    run_jobs,
)
from dcm.data.merge import MergeError, assemble, part_path
from dcm.data.presets import PresetError, compose_config, fingerprint, plan_demos
from dcm.data.schema import DatasetError
from dcm.search import check_budget
from dcm.shipped import work_root
from dcm.sim.domain import DomainSpec


def output_paths(cfg: Any) -> tuple[Path, Path]:
    """(file this run writes, work dir for part files)."""
    out = Path(str(cfg.out)).expanduser()
    if not out.is_absolute():
        out = Path.cwd() / out
    count = int(cfg.shard.count)
    if count > 1:
        out = out.with_name(f"{out.stem}.shard-{int(cfg.shard.index)}-of-{count}{out.suffix}")
    work_dir = Path(str(cfg.work_dir)) if cfg.work_dir else out.with_name(out.name + ".parts")
    return out, work_dir


def _names(value: Any) -> list[str] | None:
    """``skills=`` / ``splits=`` as a list: one name alone (``skills=spiral``) is that name, not its letters."""
    if value is None:
        return None
    return [value] if isinstance(value, str) else [str(v) for v in value]


def generate(cfg: Any) -> Path:
    """Generate (or finish generating) the dataset described by a composed ``conf/generate.yaml``.

    Every setting, demo spec and waypoint file is checked first; then ``out`` (see
    :func:`existing_output_is_current`) and the part folder (:func:`claim_work_dir`) are checked against this
    configuration, and only then does the simulation start."""
    from omegaconf import OmegaConf

    from dcm import __version__

    os.environ.setdefault("MUJOCO_GL", "egl")
    check_run_settings(cfg)
    shard_index, shard_count = int(cfg.shard.index), int(cfg.shard.count)
    settings = build_settings(cfg)
    search = check_stiffness_settings(settings)
    check_embodiment(settings["embodiment"])
    DomainSpec.resolve(settings["domain"])  # validate before spawning workers
    dataset_cfg = OmegaConf.to_container(cfg.dataset, resolve=True)
    demo_cfg = OmegaConf.to_container(cfg.demo, resolve=True)
    only_skills, only_splits = _names(cfg.get("skills")), _names(cfg.get("splits"))
    try:
        all_jobs = plan_demos(dataset_cfg, int(cfg.seed), cfg.n_trials,
                              demo_cfg if demo_cfg.get("waypoints") else None, only_skills, only_splits)
    except PresetError as err:
        raise GenerationError(f"dataset={cfg.dataset.get('name')}: {err}") from None
    jobs = [job for job in all_jobs if job.index % shard_count == shard_index]
    if not jobs:
        raise GenerationError(f"shard {shard_index} of {shard_count} holds no demos (the plan has {len(all_jobs)})")
    check_demos(jobs, settings["control_hz"], settings["stiffness"])
    if demo_cfg.get("waypoints"):
        duration_s = check_waypoint_recording(jobs[0], dataset_cfg, str(demo_cfg["waypoints"]), settings["control_hz"])
        if cfg.dataset.get("duration_s") is None:  # the file's own timing, stored as a number: the file's recording
            cfg.dataset.duration_s = duration_s
    try:
        check_budget(search, max(job.n_trials for job in jobs))
    except ValueError as err:
        raise GenerationError(str(err)) from None
    fingerprints = job_fingerprints(all_jobs, settings)
    plan = fingerprint(sorted(fingerprints.items()))
    config = OmegaConf.to_container(cfg, resolve=True)
    total = sum(job.n_trials for job in jobs)
    out, work_dir = output_paths(cfg)
    overwrite = bool(cfg.overwrite)
    if existing_output_is_current(out, plan, config, total, (shard_index, shard_count), overwrite):
        return out

    created = claim_work_dir(work_dir, plan, config, overwrite)
    try:
        done = finished_jobs(jobs, fingerprints, work_dir, overwrite)
        mark_work_dir(work_dir, plan, config)
        pending = [job for job in jobs if job.index not in done]
        done_trials = sum(job.n_trials for job in jobs if job.index in done)
        if done:
            print(f"resuming: {len(done)} of {len(jobs)} demos already in {work_dir}", file=sys.stderr)
        started = time.perf_counter()
        run_jobs(pending, fingerprints, settings, work_dir, int(cfg.workers), bool(cfg.progress), total, done_trials)
        elapsed = time.perf_counter() - started
    except BaseException:
        if created and not part_files_in(work_dir):  # nothing finished: leave no empty folder behind
            release_work_dir(work_dir, [])
        raise

    attrs = {
        "control_hz": settings["control_hz"],
        "embodiment": settings["embodiment"],
        "domain": DomainSpec.resolve(settings["domain"]).to_dict(),
        "dataset": str(cfg.dataset.name),
        "search": settings["search"]["name"],
        "objective": TaskObjective.from_dict(settings.get("objective")).to_dict(),
        "stiffness_frame": str(settings["stiffness"].get("frame", "world")),
        "seed": int(cfg.seed),
        "config": config,
        "plan_fingerprint": plan,
        "n_demos_total": len(all_jobs),
        "n_trajectories_total": sum(job.n_trials for job in all_jobs),
        "shard_index": shard_index,
        "shard_count": shard_count,
        "created": datetime.now(UTC).isoformat(timespec="seconds"),
    }
    part_files = [part_path(work_dir, job.index) for job in jobs]
    n = assemble(part_files, out, attrs)
    if not cfg.keep_parts:
        release_work_dir(work_dir, part_files)
    print(f"wrote {out}: {n} trajectories from {len(jobs)} demos ({len(pending)} generated now in {elapsed:.1f} s, "
          f"dcm {__version__})")
    return out


def ensure_dataset(preset: str, path: str | Path | None = None, overrides: Sequence[str] = ()) -> Path:
    """Return the dataset file of a preset, generating it first if it does not exist (default ``data/<preset>.h5``)."""
    path = Path(path) if path is not None else work_root() / "data" / f"{preset}.h5"
    path = path.resolve()
    if path.exists():
        return path
    cfg = compose_config(preset, [*overrides, f"out={path}"])
    return generate(cfg)


def main() -> None:
    """``python -m dcm.data.generate [k=v ...]`` and the console script ``dcm-generate``: a user's error ends in
    one ``error: ...`` line on stderr and exit code 2."""
    import hydra

    @hydra.main(config_path=str(CONF_DIR), config_name="generate")
    def run(cfg: Any) -> None:
        quiet_libraries()
        try:
            generate(cfg)
        except (GenerationError, DatasetError, MergeError) as err:
            print_error(err)
            sys.exit(2)

    if problem := group_choice_problem(sys.argv[1:]):
        print_error(problem)
        sys.exit(2)
    register_resolvers()
    run()


if __name__ == "__main__":
    main()
