"""Generate a dataset: per demo, a robot-based multi-objective stiffness search whose every trial is kept.

    python -m dcm.data.generate                                   # sim preset, panda, MOTPE, 2 workers
    python -m dcm.data.generate dataset=realistic
    python -m dcm.data.generate dataset=tiny embodiment=tool n_trials=5 workers=1 out=/tmp/t.h5
    python -m dcm.data.generate search=random seed=3 stiffness.n_phases=4 stiffness.max_Npm=2000
    python -m dcm.data.generate demo.waypoints=my_path.csv demo.bowl.rim_radius_m=0.12 out=data/mine.h5

Each demo is recorded once, then ``n_trials`` stiffness proposals (one constant [Kx, Ky, Kz] per phase,
from ``search=motpe`` or ``search=random``) are rolled out in the simulator. Demo ``i`` is seeded from
(``seed``, i), so results do not depend on the number of workers, the order or restarts.

Resumable: each finished demo is written atomically to ``<out>.parts/demo_%05d.npz``; rerunning the same
command skips those demos and ends with exactly the arrays of an uninterrupted run. The final HDF5 is also
written atomically. Parts from a different config are refused (their fingerprint differs).

Sharding for clusters: ``shard.index=i shard.count=n`` generates demos with ``index % n == i`` and writes
``<out stem>.shard-<i>-of-<n>.h5``; ``python -m dcm.data.merge <out> <shard files>`` joins them. With
Hydra's multirun every shard is one job, e.g. locally ``-m shard.count=4 shard.index=0,1,2,3 workers=1``
or on SLURM with the submitit launcher plugin (``pip install hydra-submitit-launcher``)
``-m hydra/launcher=submitit_slurm shard.count=8 shard.index=range(8)``.
"""

from __future__ import annotations

import json
import multiprocessing as mp
import os
import queue
import shutil
import sys
import time
from datetime import datetime, timezone
from pathlib import Path
from typing import Any, Callable, Sequence

import numpy as np

from dcm.data.merge import assemble, part_path, read_part, write_part
from dcm.data.presets import DemoJob, fingerprint, plan_demos
from dcm.data.search import SearchSpace, make_search

CONF_DIR = Path(__file__).resolve().parents[2] / "conf"
REPO_ROOT = CONF_DIR.parent


class GenerationError(RuntimeError):
    """Generation cannot proceed (bad settings, a missing embodiment, stale part files, a failed demo)."""


# ----------------------------------------------------------------------------------------------- settings
def build_settings(cfg: Any) -> dict[str, Any]:
    """Plain-dict settings shared by all demos (what the workers need and what the fingerprint covers)."""
    from omegaconf import OmegaConf

    domain = OmegaConf.to_container(cfg.domain, resolve=True) if OmegaConf.is_config(cfg.domain) else cfg.domain
    return {
        "embodiment": str(cfg.embodiment),
        "domain": domain,
        "control_hz": float(cfg.control_hz),
        "stiffness": OmegaConf.to_container(cfg.stiffness, resolve=True),
        "search": {"name": str(cfg.search.name), "options": OmegaConf.to_container(cfg.search.options, resolve=True)},
    }


def resolve_domain(domain: Any) -> "Any":
    from dcm.sim.domain import DomainSpec

    if isinstance(domain, str):
        return DomainSpec.preset(domain)
    if isinstance(domain, dict):
        return DomainSpec.from_dict(domain)
    raise GenerationError(f"domain = {domain!r}: expected a preset name or a mapping of DomainSpec fields")


def check_embodiment(name: str) -> None:
    """Fail early and clearly if the chosen embodiment cannot be built here."""
    try:
        from dcm.sim.rollout import EMBODIMENTS, embodiment_class
    except ImportError as err:
        raise GenerationError(f"the simulator (dcm.sim.rollout) cannot be imported: {err}") from err
    if name not in EMBODIMENTS:
        hint = " (the panda embodiment is missing; run with embodiment=tool)" if name == "panda" else ""
        raise GenerationError(f"embodiment={name!r} is not available; known: {sorted(EMBODIMENTS)}{hint}")
    try:
        embodiment_class(name)  # registry entries import lazily; import now to fail before spawning workers
    except (ImportError, ValueError) as err:
        raise GenerationError(f"the {name} embodiment cannot be loaded ({err}); run with embodiment=tool") from err


# ----------------------------------------------------------------------------------------------- one demo
class DemoRunner:
    """Runs demos in one process, reusing one simulator while the bowl stays the same."""

    def __init__(self, settings: dict[str, Any], work_dir: Path):
        self.settings = settings
        self.work_dir = work_dir
        self._sim: Any = None
        self._sim_key: str | None = None

    def _simulator(self, bowl: dict[str, Any], seed: int) -> Any:
        from dcm.sim.geometry import BowlSpec
        from dcm.sim.rollout import Simulator

        key = json.dumps(bowl, sort_keys=True)
        if self._sim is None or key != self._sim_key:  # one model per bowl; drop the old one to bound memory
            self._sim = Simulator(embodiment=self.settings["embodiment"], bowl=BowlSpec.from_dict(bowl),
                                  domain=resolve_domain(self.settings["domain"]),
                                  control_hz=self.settings["control_hz"], seed=seed,
                                  damping=self.settings["stiffness"]["damping"])
            self._sim_key = key
        # The simulator draws its noise from (seed, hash of the inputs), so setting the demo's seed makes the
        # results independent of which demos this worker ran before.
        self._sim.seed = int(seed)
        return self._sim

    def run(self, job: DemoJob, job_fingerprint: str, on_trial: Callable[[], None] = lambda: None) -> Path:
        """Record the demo, run its stiffness search, write its part file; returns the part path."""
        from dcm.control.schedule import phase_boundaries, schedule_from_phases
        from dcm.sim.demos import DemoSpec

        stiffness_cfg = self.settings["stiffness"]
        spec = DemoSpec.from_dict(job.spec)
        sim = self._simulator(spec.bowl.to_dict(), job.seed)
        demo = sim.record_demo(spec)
        horizon = demo.x_demo.shape[0]
        n_phases = int(stiffness_cfg["n_phases"])
        try:  # the same segmentation the robot-free tuner uses
            boundaries = phase_boundaries(str(stiffness_cfg["phases"]), n_phases, demo.force_demo)
        except ValueError as err:
            raise GenerationError(f"stiffness.phases / n_phases: {err}") from err
        space = SearchSpace(n_phases=n_phases, min_Npm=float(stiffness_cfg["min_Npm"]),
                            max_Npm=float(stiffness_cfg["max_Npm"]), log=bool(stiffness_cfg["log"]))
        search = make_search(self.settings["search"]["name"], space, job.seed, **self.settings["search"]["options"])

        records: dict[str, list[Any]] = {k: [] for k in ("x_attr", "K", "x_obs", "F_obs", "contact", "L_task",
                                                          "L_comp", "failed", "failure_reason",
                                                          "phase_stiffness_Npm")}
        for _ in range(job.n_trials):
            phase_stiffness = search.ask()
            schedule = schedule_from_phases(phase_stiffness, boundaries, rot_stiffness=stiffness_cfg["rot_Nmprad"])
            trial = sim.rollout(demo, schedule)
            failed = bool(trial.failed)
            search.tell(None if failed else (float(trial.L_task), float(trial.L_comp)))
            records["x_attr"].append(np.asarray(trial.x_attr, np.float32))
            records["K"].append(np.asarray(trial.stiffness, np.float32))
            records["x_obs"].append(np.asarray(trial.x_obs, np.float32))
            records["F_obs"].append(np.asarray(trial.force_obs, np.float32))
            records["contact"].append(np.asarray(trial.contact, np.uint8))
            records["L_task"].append(float(trial.L_task))
            records["L_comp"].append(float(trial.L_comp))
            records["failed"].append(failed)
            records["failure_reason"].append(str(trial.failure_reason or ""))
            records["phase_stiffness_Npm"].append(phase_stiffness)
            on_trial()
        arrays = {key: np.asarray(values) for key, values in records.items()}
        arrays["failure_reason"] = np.asarray(records["failure_reason"], dtype="U")
        arrays["x_demo"] = np.asarray(demo.x_demo, np.float32)
        arrays["F_demo"] = np.asarray(demo.force_demo, np.float32)
        arrays["phase_boundaries"] = np.asarray(boundaries, np.int64)
        meta = {"job": job.to_dict(), "fingerprint": job_fingerprint, "demo": demo.spec.to_dict(),
                "embodiment": self.settings["embodiment"], "domain": resolve_domain(self.settings["domain"]).to_dict(),
                "search": self.settings["search"]["name"], "horizon": int(horizon)}
        return write_part(self.work_dir, job.index, arrays, meta)


# ----------------------------------------------------------------------------------------------- workers
_WORKER: dict[str, Any] = {}


def _worker_init(settings: dict[str, Any], work_dir: str, progress: Any) -> None:
    os.environ.setdefault("MUJOCO_GL", "egl")
    _WORKER["runner"] = DemoRunner(settings, Path(work_dir))
    _WORKER["progress"] = progress


def _worker_run(job: DemoJob, job_fingerprint: str) -> int:
    progress = _WORKER["progress"]
    try:
        _WORKER["runner"].run(job, job_fingerprint, on_trial=lambda: progress.put(1))
    except Exception as err:  # the parent reports which demo broke and why
        raise GenerationError(f"demo {job.index} ({job.skill}, spec {json.dumps(job.spec)}) failed: "
                              f"{type(err).__name__}: {err}") from None
    return job.index


def job_fingerprints(jobs: Sequence[DemoJob], settings: dict[str, Any]) -> dict[int, str]:
    return {job.index: fingerprint({"job": job.to_dict(), "settings": settings}) for job in jobs}


def finished_jobs(jobs: Sequence[DemoJob], fingerprints: dict[int, str], work_dir: Path) -> set[int]:
    """Demos whose part file exists and matches; a part from other settings stops the run."""
    done = set()
    for job in jobs:
        path = part_path(work_dir, job.index)
        if not path.exists():
            continue
        _, meta = read_part(path)
        if meta.get("fingerprint") != fingerprints[job.index]:
            raise GenerationError(f"{path} was generated with different settings; delete {work_dir} or choose "
                                  "another out/work_dir")
        done.add(job.index)
    return done


def run_jobs(jobs: Sequence[DemoJob], fingerprints: dict[int, str], settings: dict[str, Any], work_dir: Path,
             workers: int, show_progress: bool, total_trials: int, done_trials: int) -> None:
    """Run the pending demos on ``workers`` processes with a trial-level progress bar."""
    from tqdm import tqdm

    bar = tqdm(total=total_trials, initial=done_trials, unit="trial", disable=not show_progress,
               desc="generate", dynamic_ncols=True, file=sys.stderr)
    try:
        if workers <= 1:
            runner = DemoRunner(settings, work_dir)
            for job in jobs:
                try:
                    runner.run(job, fingerprints[job.index], on_trial=lambda: bar.update(1))
                except Exception as err:
                    raise GenerationError(f"demo {job.index} ({job.skill}) failed: {type(err).__name__}: {err}") \
                        from err
            return
        from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait

        context = mp.get_context("spawn")  # fresh interpreters: no forked MuJoCo/threads state
        progress = context.Queue()
        with ProcessPoolExecutor(max_workers=workers, mp_context=context, initializer=_worker_init,
                                 initargs=(settings, str(work_dir), progress)) as pool:
            pending = {pool.submit(_worker_run, job, fingerprints[job.index]) for job in jobs}
            try:
                while pending:
                    finished, pending = wait(pending, timeout=0.2, return_when=FIRST_COMPLETED)
                    _drain(progress, bar)
                    for future in finished:
                        future.result()  # re-raise a worker's GenerationError here
            except BaseException:
                pool.shutdown(wait=False, cancel_futures=True)  # don't sit through the remaining demos
                raise
            _drain(progress, bar)
    finally:
        bar.close()


def _drain(progress: Any, bar: Any) -> None:
    while True:
        try:
            bar.update(progress.get_nowait())
        except queue.Empty:
            return


# ----------------------------------------------------------------------------------------------- driver
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


def generate(cfg: Any) -> Path:
    """Generate (or finish generating) the dataset described by a composed ``conf/generate.yaml``."""
    from omegaconf import OmegaConf

    from dcm import __version__

    os.environ.setdefault("MUJOCO_GL", "egl")
    shard_index, shard_count = int(cfg.shard.index), int(cfg.shard.count)
    if shard_count < 1 or not 0 <= shard_index < shard_count:
        raise GenerationError(f"shard.index={shard_index} must be in [0, shard.count={shard_count})")
    settings = build_settings(cfg)
    check_embodiment(settings["embodiment"])
    resolve_domain(settings["domain"])  # validate before spawning workers
    dataset_cfg = OmegaConf.to_container(cfg.dataset, resolve=True)
    demo_cfg = OmegaConf.to_container(cfg.demo, resolve=True)
    n_trials = int(cfg.n_trials) if cfg.n_trials is not None else None
    only_skills = list(cfg.skills) if cfg.get("skills") is not None else None
    all_jobs = plan_demos(dataset_cfg, int(cfg.seed), n_trials, demo_cfg if demo_cfg.get("waypoints") else None,
                          only_skills)
    jobs = [job for job in all_jobs if job.index % shard_count == shard_index]
    if not jobs:
        raise GenerationError(f"shard {shard_index} of {shard_count} holds no demos (the plan has {len(all_jobs)})")
    fingerprints = job_fingerprints(all_jobs, settings)
    out, work_dir = output_paths(cfg)
    work_dir.mkdir(parents=True, exist_ok=True)

    done = finished_jobs(jobs, fingerprints, work_dir)
    pending = [job for job in jobs if job.index not in done]
    total = sum(job.n_trials for job in jobs)
    done_trials = sum(job.n_trials for job in jobs if job.index in done)
    if done:
        print(f"resuming: {len(done)} of {len(jobs)} demos already in {work_dir}", file=sys.stderr)
    started = time.perf_counter()
    run_jobs(pending, fingerprints, settings, work_dir, int(cfg.workers), bool(cfg.progress), total, done_trials)
    elapsed = time.perf_counter() - started

    attrs = {
        "control_hz": settings["control_hz"],
        "embodiment": settings["embodiment"],
        "domain": resolve_domain(settings["domain"]).to_dict(),
        "dataset": str(cfg.dataset.name),
        "search": settings["search"]["name"],
        "seed": int(cfg.seed),
        "config": OmegaConf.to_yaml(cfg, resolve=True),
        "plan_fingerprint": fingerprint(sorted(fingerprints.items())),
        "n_demos_total": len(all_jobs),
        "n_trajectories_total": sum(job.n_trials for job in all_jobs),
        "shard_index": shard_index,
        "shard_count": shard_count,
        "created": datetime.now(timezone.utc).isoformat(timespec="seconds"),
    }
    n = assemble([part_path(work_dir, job.index) for job in jobs], out, attrs)
    if not cfg.keep_parts:
        shutil.rmtree(work_dir, ignore_errors=True)
    print(f"wrote {out}: {n} trajectories from {len(jobs)} demos ({len(pending)} generated now in {elapsed:.1f} s, "
          f"dcm {__version__})", file=sys.stderr)
    return out


def compose_config(preset: str, overrides: Sequence[str] = ()) -> Any:
    """Compose ``conf/generate.yaml`` with ``dataset=<preset>`` outside of a Hydra app."""
    from hydra import compose, initialize_config_dir
    from hydra.core.global_hydra import GlobalHydra
    from hydra.initialize import get_gh_backup, restore_gh_from_backup

    outer = get_gh_backup()  # e.g. train.py's own Hydra app: put it back afterwards
    GlobalHydra.instance().clear()
    try:
        with initialize_config_dir(config_dir=str(CONF_DIR), version_base=None):
            return compose(config_name="generate", overrides=[f"dataset={preset}", *overrides])
    finally:
        restore_gh_from_backup(outer)


def ensure_dataset(preset: str, path: str | Path | None = None, overrides: Sequence[str] = ()) -> Path:
    """Return the dataset file of a preset, generating it first if it does not exist (default ``data/<preset>.h5``)."""
    path = Path(path) if path is not None else REPO_ROOT / "data" / f"{preset}.h5"
    path = path.resolve()
    if path.exists():
        return path
    cfg = compose_config(preset, [*overrides, f"out={path}"])
    return generate(cfg)


def _hydra_main() -> None:
    import hydra

    @hydra.main(version_base=None, config_path=str(CONF_DIR), config_name="generate")
    def main(cfg: Any) -> None:
        try:
            generate(cfg)
        except GenerationError as err:
            print(f"error: {err}", file=sys.stderr)
            sys.exit(2)

    main()


if __name__ == "__main__":
    _hydra_main()
