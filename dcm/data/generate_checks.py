"""What :mod:`dcm.data.generate` checks before any simulation starts, so a bad setting fails at once.

The run's own settings, the stiffness search, the embodiment, every demo spec, and an existing output file
against the configuration that would overwrite it.
"""

from __future__ import annotations

import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from dcm.configs import check_integer, check_number, config_diff
from dcm.control.objectives import ObjectiveError, TaskObjective
from dcm.data.atomic import write_problem
from dcm.data.presets import DemoJob
from dcm.data.schema import DatasetError, read_config, read_root_attrs
from dcm.search import StiffnessSearch, make_search, space_from_settings

# Settings that do not change the generated arrays: ignored when comparing with an existing file or part folder.
RUN_ONLY_KEYS = ("out", "work_dir", "keep_parts", "workers", "progress", "overwrite")
SIM_CONTROL_HZ = (1.0, 500.0)  # the range dcm.sim.rollout.Simulator accepts
SPLIT_CHOICES = ("train", "valid", "test", "trainval")  # as in a preset's skill groups
WAYPOINT_DEMO_KEYS = ("waypoints", "bowl", "split", "n_trials")  # conf/generate.yaml's demo group
# demo-side names of the preset's recording settings, which the waypoint demo takes from the preset
RECORDING_KEYS = {"duration_s": "dataset.duration_s", "lead": "dataset.demo_lead", "hover_m": "dataset.demo_hover_m"}


class GenerationError(RuntimeError):
    """Generation cannot proceed (bad settings, a missing embodiment, stale part files, a failed demo)."""


# ----------------------------------------------------------------------------------------------- settings
def build_settings(cfg: Any) -> dict[str, Any]:
    """Plain-dict settings shared by all demos (what the workers need and what the fingerprint covers)."""
    from omegaconf import OmegaConf

    domain = OmegaConf.to_container(cfg.domain, resolve=True) if OmegaConf.is_config(cfg.domain) else cfg.domain
    settings = {
        "embodiment": str(cfg.embodiment),
        "domain": domain,
        "control_hz": float(cfg.control_hz),
        "stiffness": OmegaConf.to_container(cfg.stiffness, resolve=True),
        "search": {"name": str(cfg.search.name), "options": OmegaConf.to_container(cfg.search.options, resolve=True)},
    }
    try:
        objective = TaskObjective.from_config(cfg.get("objective"))
    except ObjectiveError as err:
        raise GenerationError(str(err)) from None
    if objective.name != "paper":  # only then: every dataset of the paper's objective keeps its fingerprint
        settings["objective"] = objective.to_dict()
    if settings["stiffness"].get("frame", "world") == "world":  # likewise for the world frame's datasets
        settings["stiffness"].pop("frame", None)
    return settings


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
    check_duration(cfg.dataset.get("duration_s"), bool(cfg.demo.get("waypoints")))
    for key in cfg.demo:
        if key in RECORDING_KEYS:
            raise GenerationError(f"demo.{key} = {cfg.demo[key]!r}: the waypoint demo is recorded as the preset's "
                                  f"demos are; set {RECORDING_KEYS[key]} instead")
        if key not in WAYPOINT_DEMO_KEYS:
            raise GenerationError(f"demo.{key} = {cfg.demo[key]!r}: not a setting of the waypoint demo "
                                  f"(it has {', '.join(WAYPOINT_DEMO_KEYS)})")
    if cfg.demo.get("waypoints"):
        _integer(cfg.demo.n_trials, "demo.n_trials", 1)
        if cfg.demo.split not in SPLIT_CHOICES:
            raise GenerationError(f"demo.split = {cfg.demo.split!r}; expected one of {', '.join(SPLIT_CHOICES)}")


def check_duration(duration_s: Any, waypoint_demo: bool) -> None:
    """``dataset.duration_s``: seconds, or null for a waypoint demo, which then keeps its file's own timing (as
    ``demo.duration_s=null`` does for the tuner)."""
    if duration_s is None:
        if not waypoint_demo:
            raise GenerationError("dataset.duration_s = null keeps a waypoint file's own timing, but this run has "
                                  "no demo.waypoints=<file>; give the demos' duration in seconds")
        return
    if isinstance(duration_s, bool) or not isinstance(duration_s, (int, float)) or not 0 < duration_s < float("inf"):
        raise GenerationError(f"dataset.duration_s = {duration_s!r} must be a duration in seconds > 0 (or null with "
                              "demo.waypoints=<file>: the file's own timing)")


def check_stiffness_settings(settings: dict[str, Any]) -> StiffnessSearch:
    """The stiffness search space against the controller's limits, and the search strategy's options;
    returns a strategy built from them (for :func:`check_budget` once the trial counts are known)."""
    space = space_from_settings(settings["stiffness"], GenerationError)
    search = settings["search"]
    try:  # builds the strategy once, so unknown names and options fail here rather than in every worker
        return make_search(search["name"], space, 0, **search["options"])
    except (TypeError, ValueError) as err:
        raise GenerationError(f"search={search['name']} with options {search['options']}: {err}") from None


def check_waypoint_recording(job: DemoJob, dataset: dict[str, Any], waypoints: str, control_hz: float) -> float:
    """The waypoint demo is recorded as the preset says its demos are, or refused naming the setting; returns
    the duration the dataset records for it (``horizon / control_hz``, what ``dataset.duration_s=null`` means).

    The file stores the preset's recording (:mod:`dcm.data.recording`) as its own, and tools pair predictors
    and datasets on it. Its lead and hover reach the waypoint demo (:func:`dcm.data.presets.plan_demos`), but
    a waypoint file sets its own timing and the bowl may be another, so those must agree."""
    from dcm.data.recording import recording
    from dcm.sim.demos import DemoSpec, DemoSpecError

    try:
        spec = DemoSpec.from_dict(job.spec, where=f"demo.waypoints={waypoints}")
        horizon = spec.horizon(control_hz)
    except DemoSpecError as err:
        raise GenerationError(str(err)) from None
    own_duration_s = horizon / control_hz
    if dataset.get("duration_s") is None:
        dataset = {**dataset, "duration_s": own_duration_s}
    preset, name = recording(dataset), dataset.get("name")
    if horizon != int(round(preset.duration_s * control_hz)):
        raise GenerationError(f"dataset.duration_s = {preset.duration_s:g} s (dataset={name}) does not apply to "
                              f"demo.waypoints={waypoints}, which sets its own timing ({horizon} steps at "
                              f"{control_hz:g} Hz); pass dataset.duration_s={own_duration_s:g} (or null) to record "
                              "it as it is")
    grid = spec.bowl.hfield_res
    if preset.bowl_grid is not None and grid != preset.bowl_grid:
        raise GenerationError(f"demo.bowl has a {grid} x {grid} heightfield grid, but dataset={name} records its "
                              f"demos on a {preset.bowl_grid} x {preset.bowl_grid} grid (dataset.bowl.hfield_res); "
                              f"give the waypoint demo a bowl on that grid (hfield_res: {preset.bowl_grid})")
    return own_duration_s


def check_demos(jobs: Sequence[DemoJob], control_hz: float, stiffness: dict[str, Any]) -> None:
    """Every demo spec (and waypoint file) parses, stays inside its bowl and has room for the phases.

    Cheap (no simulator), so a bad file or value fails at once, not after the demos before it ran."""
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


def _config_of(path: Path, attrs: dict[str, Any]) -> dict[str, Any]:
    """A dataset's stored generating config as a mapping; {} if unreadable (it only explains a refusal)."""
    try:
        return read_config(attrs, path)
    except DatasetError:
        return {}


def differences(saved: dict[str, Any], current: dict[str, Any], ignore: Sequence[str] = ()) -> str:
    """What differs between a saved and this configuration, as one clause of an error message."""
    lines = config_diff(saved, current, ignore=(*RUN_ONLY_KEYS, *ignore))
    return "; ".join(lines) if lines else "same settings, but the preset's contents or the code changed"


def existing_output_is_current(out: Path, plan: str, config: dict[str, Any], n_trajectories: int,
                               shard: tuple[int, int], overwrite: bool) -> bool:
    """True when ``out`` already holds this configuration's complete dataset (nothing to do).

    Refuses any other existing file (naming what differs) unless ``overwrite``; the new file then replaces
    it atomically at the end, so the old one stays usable until then."""
    if problem := write_problem(out):
        raise GenerationError(f"out={out} cannot be written: {problem}")
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
            problem = f"was generated with different settings ({differences(_config_of(out, attrs), config)})"
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
