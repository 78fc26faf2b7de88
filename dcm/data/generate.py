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

import json
import multiprocessing as mp
import os
import queue
import sys
import threading
import time
from datetime import datetime, timezone
from pathlib import Path
from typing import Any, Callable, Sequence

import numpy as np

from dcm.cli import JSONFileError, check_integer, check_number, config_diff, load_json
from dcm.data.atomic import atomic_path
from dcm.data.merge import MergeError, assemble, part_path, read_part, write_part
from dcm.data.presets import DemoJob, PresetError, fingerprint, plan_demos
from dcm.data.schema import DatasetError, read_root_attrs
from dcm.search import StiffnessSearch, check_budget, make_search, space_from_settings
from dcm.sim.domain import DomainSpec

CONF_DIR = Path(__file__).resolve().parents[2] / "conf"
REPO_ROOT = CONF_DIR.parent
PLAN_FILE = "plan.json"  # in the work dir: which configuration its part files belong to
# Settings that do not change the generated arrays: ignored when comparing with an existing file or part folder.
RUN_ONLY_KEYS = ("out", "work_dir", "keep_parts", "workers", "progress", "overwrite")
SIM_CONTROL_HZ = (1.0, 500.0)  # the range dcm.sim.rollout.Simulator accepts
SPLIT_CHOICES = ("train", "valid", "test", "trainval")  # as in a preset's skill groups


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


# ----------------------------------------------------------------------------------------------- checks
def _integer(value: Any, key: str, minimum: int, note: str = "") -> int:
    return check_integer(value, key, minimum, GenerationError, note)


def _number(value: Any, key: str) -> float:
    return check_number(value, key, GenerationError)


def check_run_settings(cfg: Any) -> None:
    """The run's own settings (counts, seed, shard, the waypoint demo), checked before anything is planned.

    Conventions, not errors: ``n_trials=null`` keeps every skill's own trial count, ``work_dir=null`` means
    ``<out>.parts/``, ``skills=null`` keeps every skill group, ``workers=1`` runs in this process.
    """
    if cfg.n_trials is not None:
        _integer(cfg.n_trials, "n_trials", 1, " (or null: each skill's own count)")
    _integer(cfg.workers, "workers", 1, " (1 runs the demos in this process)")
    _integer(cfg.seed, "seed", 0)
    count = _integer(cfg.shard.count, "shard.count", 1)
    index = _integer(cfg.shard.index, "shard.index", 0)
    if index >= count:
        raise GenerationError(f"shard.index = {index} must be in [0, shard.count = {count})")
    control_hz = _number(cfg.control_hz, "control_hz")
    if not SIM_CONTROL_HZ[0] <= control_hz <= SIM_CONTROL_HZ[1]:
        raise GenerationError(f"control_hz = {control_hz:g} is outside the simulator's range "
                              f"[{SIM_CONTROL_HZ[0]:g}, {SIM_CONTROL_HZ[1]:g}] Hz")
    for key in ("overwrite", "keep_parts", "progress"):
        if not isinstance(cfg.get(key), bool):
            raise GenerationError(f"{key} = {cfg.get(key)!r} must be true or false")
    fraction = cfg.dataset.get("valid_fraction", 0.1)
    if _number(fraction, "dataset.valid_fraction") < 0 or fraction >= 1:
        raise GenerationError(f"dataset.valid_fraction = {fraction!r} must be in [0, 1)")
    if cfg.demo.get("waypoints"):
        _integer(cfg.demo.n_trials, "demo.n_trials", 1)
        if cfg.demo.split not in SPLIT_CHOICES:
            raise GenerationError(f"demo.split = {cfg.demo.split!r}; expected one of {', '.join(SPLIT_CHOICES)}")


def check_stiffness_settings(settings: dict[str, Any]) -> StiffnessSearch:
    """The stiffness search space against the controller's limits, and the search strategy's options;
    returns a strategy built from them (for :func:`check_budget` once the trial counts are known)."""
    space = space_from_settings(settings["stiffness"], GenerationError)
    search = settings["search"]
    try:  # builds the strategy once, so unknown names and options fail here rather than in every worker
        return make_search(search["name"], space, 0, **search["options"])
    except (TypeError, ValueError) as err:
        raise GenerationError(f"search={search['name']} with options {search['options']}: {err}") from None


def check_demos(jobs: Sequence[DemoJob], control_hz: float, stiffness: dict[str, Any]) -> None:
    """Every demo spec (and waypoint file) parses, stays inside its bowl and has room for the phases.

    Cheap (no simulator), so a bad file or value fails in a second, not after the demos before it ran."""
    from dcm.control.schedule import phase_boundaries
    from dcm.sim.demos import DemoSpec, DemoSpecError

    horizons: set[int] = set()
    for job in jobs:
        try:
            horizons.add(DemoSpec.from_dict(job.spec, where=f"demo {job.index} ({job.skill})").horizon(control_hz))
        except DemoSpecError as err:
            raise GenerationError(str(err)) from None
    method, n_phases = str(stiffness["phases"]), int(stiffness["n_phases"])
    for horizon in sorted(horizons):
        probe = np.random.default_rng(0).normal(size=(horizon, 6))  # stands in for the demo force
        try:
            phase_boundaries(method, n_phases, probe)
        except ValueError as err:
            raise GenerationError(f"stiffness.phases = {method!r}, stiffness.n_phases = {n_phases}: {err}") from None


def _config_of(attrs_config: Any) -> dict[str, Any]:
    """A stored generating config (YAML text in a dataset's root attrs) as a mapping; {} if unreadable."""
    import yaml

    try:
        loaded = yaml.safe_load(attrs_config) if isinstance(attrs_config, str) else attrs_config
    except yaml.YAMLError:
        return {}
    return loaded if isinstance(loaded, dict) else {}


def _differences(saved: dict[str, Any], current: dict[str, Any], ignore: Sequence[str] = ()) -> str:
    lines = config_diff(saved, current, ignore=(*RUN_ONLY_KEYS, *ignore))
    return "; ".join(lines) if lines else "same settings, but the preset's contents or the code changed"


def existing_output_is_current(out: Path, plan: str, config: dict[str, Any], n_trajectories: int,
                               shard: tuple[int, int], overwrite: bool) -> bool:
    """True when ``out`` already holds this configuration's complete dataset (nothing to do).

    Refuses any other existing file (naming what differs) unless ``overwrite``; the new file then replaces
    it atomically at the end, so the old one stays usable until then."""
    if not out.exists():
        return False
    try:
        attrs = read_root_attrs(out)
        import h5py

        with h5py.File(out, "r") as f:
            stored = len(f["data"]) if "data" in f else 0
    except (DatasetError, OSError) as err:
        problem = f"is not a readable dcm dataset ({err})"
    else:
        if not attrs.get("plan_fingerprint"):
            problem = "was not written by dcm.data.generate (no plan_fingerprint attribute)"
        elif attrs["plan_fingerprint"] != plan or (int(attrs.get("shard_index", 0)),
                                                   int(attrs.get("shard_count", 1))) != shard:
            problem = f"was generated with different settings ({_differences(_config_of(attrs.get('config')), config)})"
        elif stored != n_trajectories:
            problem = f"holds {stored} trajectories where this configuration makes {n_trajectories}"
        elif not overwrite:
            print(f"{out} already holds this configuration's dataset ({stored} trajectories, plan {plan}): "
                  "nothing to do (overwrite=true regenerates it)", file=sys.stderr)
            return True
        else:
            problem = "holds this configuration's dataset"
    if not overwrite:
        raise GenerationError(f"{out} exists and {problem}; pass overwrite=true to replace it, or choose another out=")
    print(f"overwrite=true: {out} {problem}; it will be replaced", file=sys.stderr)
    return False


def _part_files(work_dir: Path) -> list[Path]:
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
            what = _differences(saved.get("config") or {}, config, ignore=("shard",))
            if not overwrite:
                raise GenerationError(f"part folder {work_dir} holds demos generated with different settings "
                                      f"({what}); delete it, choose another out= or work_dir=, or pass "
                                      "overwrite=true to discard them")
            print(f"overwrite=true: discarding the parts of another configuration in {work_dir} ({what})",
                  file=sys.stderr)
            for path in _part_files(work_dir):
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
    if not _part_files(work_dir):
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
        space = space_from_settings(stiffness_cfg, GenerationError)
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
                "embodiment": self.settings["embodiment"], "domain": DomainSpec.resolve(self.settings["domain"]).to_dict(),
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
    only_skills = list(cfg.skills) if cfg.get("skills") is not None else None
    try:
        all_jobs = plan_demos(dataset_cfg, int(cfg.seed), cfg.n_trials,
                              demo_cfg if demo_cfg.get("waypoints") else None, only_skills)
    except PresetError as err:
        raise GenerationError(f"dataset={cfg.dataset.get('name')}: {err}") from None
    jobs = [job for job in all_jobs if job.index % shard_count == shard_index]
    if not jobs:
        raise GenerationError(f"shard {shard_index} of {shard_count} holds no demos (the plan has {len(all_jobs)})")
    check_demos(jobs, settings["control_hz"], settings["stiffness"])
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
        if created and not _part_files(work_dir):  # nothing finished: leave no empty folder behind
            release_work_dir(work_dir, [])
        raise

    attrs = {
        "control_hz": settings["control_hz"],
        "embodiment": settings["embodiment"],
        "domain": DomainSpec.resolve(settings["domain"]).to_dict(),
        "dataset": str(cfg.dataset.name),
        "search": settings["search"]["name"],
        "seed": int(cfg.seed),
        "config": OmegaConf.to_yaml(cfg, resolve=True),
        "plan_fingerprint": plan,
        "n_demos_total": len(all_jobs),
        "n_trajectories_total": sum(job.n_trials for job in all_jobs),
        "shard_index": shard_index,
        "shard_count": shard_count,
        "created": datetime.now(timezone.utc).isoformat(timespec="seconds"),
    }
    part_files = [part_path(work_dir, job.index) for job in jobs]
    n = assemble(part_files, out, attrs)
    if not cfg.keep_parts:
        release_work_dir(work_dir, part_files)
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
        except (GenerationError, DatasetError, MergeError) as err:
            print(f"error: {err}", file=sys.stderr)
            sys.exit(2)

    main()


if __name__ == "__main__":
    _hydra_main()
