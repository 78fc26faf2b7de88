"""How :mod:`dcm.data.generate` runs its demos: one process or a pool, each demo into its own part file.

A part file carries its job's fingerprint, so a rerun keeps the finished demos of the same settings and refuses
those of other settings; the work dir's plan file names the configuration its parts belong to.
"""

from __future__ import annotations

import json
import multiprocessing as mp
import os
import queue
import sys
import threading
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from dcm.configs import JSONFileError, load_json
from dcm.control.objectives import TaskObjective
from dcm.data.atomic import atomic_path
from dcm.data.generate_checks import GenerationError, differences
from dcm.data.merge import MergeError, part_path, read_part, write_part
from dcm.data.presets import DemoJob, fingerprint
from dcm.search import make_search, space_from_settings
from dcm.sim.domain import DomainSpec

# ----------------------------------------------------------------------------------------------- work dir
PLAN_FILE = "plan.json"  # in the work dir: which configuration its part files belong to


def part_files_in(work_dir: Path) -> list[Path]:
    """The finished demos' part files in ``work_dir``."""
    return sorted(work_dir.glob("demo_*.npz"))


def claim_work_dir(work_dir: Path, plan: str, config: dict[str, Any], overwrite: bool) -> bool:
    """Check (or create) ``work_dir`` as this plan's part folder; returns whether it was created now.

    A folder whose plan file names another configuration is refused, naming it and what differs, unless
    ``overwrite`` (its parts are then deleted). The plan file itself is written by :func:`mark_work_dir`
    once the parts already there were checked."""
    created = not work_dir.exists()
    marker = work_dir / PLAN_FILE
    if marker.exists():
        try:
            saved = load_json(marker)
        except JSONFileError as err:
            saved = {"config": {}, "plan_fingerprint": f"unreadable: {err}"}
        if not isinstance(saved, dict) or saved.get("plan_fingerprint") != plan:
            saved = saved if isinstance(saved, dict) else {}
            what = differences(saved.get("config") or {}, config, ignore=("shard",))
            if not overwrite:
                raise GenerationError(f"part folder {work_dir} holds demos generated with different settings "
                                      f"({what}); delete it, choose another out= or work_dir=, or pass "
                                      "overwrite=true to discard them")
            print(f"overwrite=true: discarding the parts of another configuration in {work_dir} ({what})",
                  file=sys.stderr)
            for path in part_files_in(work_dir):
                path.unlink()
            marker.unlink()
    work_dir.mkdir(parents=True, exist_ok=True)
    return created


def mark_work_dir(work_dir: Path, plan: str, config: dict[str, Any]) -> None:
    """Record which configuration the folder's parts belong to (read by :func:`claim_work_dir`)."""
    marker = work_dir / PLAN_FILE
    if not marker.exists():
        with atomic_path(marker) as tmp:
            tmp.write_text(json.dumps({"plan_fingerprint": plan, "config": config}, sort_keys=True, default=str))


def release_work_dir(work_dir: Path, part_files: Sequence[Path]) -> None:
    """Delete this run's part files, leftovers of killed writes and, when nothing else is left, the folder."""
    for path in [*part_files, *work_dir.glob(".demo_*.tmp")]:
        path.unlink(missing_ok=True)
    if not part_files_in(work_dir):
        (work_dir / PLAN_FILE).unlink(missing_ok=True)
        try:
            work_dir.rmdir()
        except OSError:  # someone else's files: leave them
            pass


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
                                  domain=DomainSpec.resolve(self.settings["domain"]),
                                  control_hz=self.settings["control_hz"], seed=seed,
                                  damping=self.settings["stiffness"]["damping"])
            self._sim_key = key
        # The simulator draws its noise from (seed, hash of the inputs), so setting the demo's seed makes the
        # results independent of which demos this worker ran before.
        self._sim.seed = int(seed)
        return self._sim

    def run(self, job: DemoJob, job_fingerprint: str, on_trial: Callable[[], None] = lambda: None) -> Path:
        """Record the demo, run its stiffness search, write its part file; returns the part path."""
        from dcm.control.schedule import StiffnessSchedule, frame_axes, phase_boundaries, schedule_from_phases
        from dcm.sim.demos import DemoSpec

        stiffness_cfg = self.settings["stiffness"]
        objective = TaskObjective.from_dict(self.settings.get("objective"))
        spec = DemoSpec.from_dict(job.spec)
        sim = self._simulator(spec.bowl.to_dict(), job.seed)
        demo = sim.record_demo(spec)
        horizon = demo.x_demo.shape[0]
        n_phases = int(stiffness_cfg["n_phases"])
        try:  # the same segmentation the robot-free tuner uses
            boundaries = phase_boundaries(str(stiffness_cfg["phases"]), n_phases, demo.force_demo)
        except ValueError as err:
            raise GenerationError(f"stiffness.phases / n_phases: {err}") from err
        space = space_from_settings(stiffness_cfg, GenerationError)
        search = make_search(self.settings["search"]["name"], space, job.seed, **self.settings["search"]["options"])
        try:
            frame = frame_axes(space.frame, demo.x_demo, demo.force_demo, f"demo {job.index} ({spec.name or spec.family})")
        except ValueError as err:
            raise GenerationError(str(err)) from None

        records: dict[str, list[Any]] = {k: [] for k in ("x_attr", "K", "x_obs", "F_obs", "contact", "L_task",
                                                          "L_comp", "failed", "failure_reason",
                                                          "phase_stiffness_Npm")}
        for _ in range(job.n_trials):
            phase_stiffness = search.ask()
            schedule = schedule_from_phases(space.diagonal(phase_stiffness), boundaries,
                                            rot_stiffness=stiffness_cfg["rot_Nmprad"])
            trial = sim.rollout(demo, StiffnessSchedule(schedule, frame))
            failed = bool(trial.failed)
            l_task = objective.trial_task_loss(trial, demo.x_demo, demo.force_demo)
            search.tell(None if failed else (l_task, float(trial.L_comp)))
            records["x_attr"].append(np.asarray(trial.x_attr, np.float32))
            records["K"].append(np.asarray(trial.stiffness, np.float32))
            records["x_obs"].append(np.asarray(trial.x_obs, np.float32))
            records["F_obs"].append(np.asarray(trial.force_obs, np.float32))
            records["contact"].append(np.asarray(trial.contact, np.uint8))
            records["L_task"].append(l_task)
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
                "embodiment": self.settings["embodiment"],
                "domain": DomainSpec.resolve(self.settings["domain"]).to_dict(),
                "search": self.settings["search"]["name"], "horizon": int(horizon)}
        return write_part(self.work_dir, job.index, arrays, meta)


# ----------------------------------------------------------------------------------------------- workers
_WORKER: dict[str, Any] = {}


def _worker_init(settings: dict[str, Any], work_dir: str, progress: Any, parent_pid: int) -> None:
    threading.Thread(target=_exit_with_parent, args=(parent_pid,), name="exit-with-parent", daemon=True).start()
    os.environ.setdefault("MUJOCO_GL", "egl")
    _WORKER["runner"] = DemoRunner(settings, Path(work_dir))
    _WORKER["progress"] = progress


def _exit_with_parent(parent_pid: int, period_s: float = 0.5) -> None:
    """End this worker once the generating process is gone.

    A parent killed with SIGKILL runs no cleanup, and a pool worker holds both ends of its task queue, so it
    would finish its demo and then wait forever; re-parenting (``getppid`` changes) is the portable sign."""
    while os.getppid() == parent_pid:
        time.sleep(period_s)
    os._exit(1)


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


def finished_jobs(jobs: Sequence[DemoJob], fingerprints: dict[int, str], work_dir: Path,
                  overwrite: bool = False) -> set[int]:
    """Demos whose part file exists and matches; a part from other settings stops the run (``overwrite``
    deletes it instead, and its demo is generated again)."""
    done = set()
    for job in jobs:
        path = part_path(work_dir, job.index)
        if not path.exists():
            continue
        try:
            _, meta = read_part(path)
        except MergeError as err:
            raise GenerationError(str(err)) from None
        if meta.get("fingerprint") != fingerprints[job.index]:
            if overwrite:
                path.unlink()
                continue
            raise GenerationError(f"{path} was generated with different settings; delete {work_dir}, choose "
                                  "another out= or work_dir=, or pass overwrite=true to discard it")
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
                                 initargs=(settings, str(work_dir), progress, os.getpid())) as pool:
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

