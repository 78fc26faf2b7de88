"""Expand a dataset preset (``conf/dataset/*.yaml``) into the ordered list of demos to generate.

The plan is a pure function of the config: demo indices, trajectory names, splits and seeds never depend
on the number of workers, on sharding or on which demos were already finished.
"""

from __future__ import annotations

import copy
import hashlib
import itertools
import json
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

from dcm.configs import CONF_DIR


class PresetError(ValueError):
    """An invalid dataset preset; names the config key."""


@dataclass(frozen=True)
class DemoJob:
    """One demo and its stiffness search: everything a worker needs, picklable."""

    index: int  # demo id within the dataset
    skill: str  # skill group name in the preset
    spec: dict[str, Any]  # DemoSpec dict (incl. bowl)
    n_trials: int
    trial_splits: tuple[str, ...]  # split of each trial: train | valid | test
    seed: int  # derived from (base seed, index)
    first_traj: int  # global index of its first trajectory (names are traj_%06d)

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


def derive_seed(base_seed: int, *keys: int) -> int:
    """A 32-bit seed that depends only on (base seed, keys): independent of worker count and order."""
    return int(np.random.SeedSequence([int(base_seed), *map(int, keys)]).generate_state(1, dtype=np.uint32)[0])


def deep_merge(base: Mapping[str, Any], override: Mapping[str, Any]) -> dict[str, Any]:
    out = copy.deepcopy(dict(base))
    for key, value in override.items():
        if isinstance(value, Mapping) and isinstance(out.get(key), Mapping):
            out[key] = deep_merge(out[key], value)
        else:
            out[key] = copy.deepcopy(value)
    return out


def _set_dotted(spec: dict[str, Any], dotted: str, value: Any) -> dict[str, Any]:
    """Set ``a.b.c`` in a nested dict; a mapping value is deep-merged into what is there."""
    keys = dotted.split(".")
    patch: Any = value
    for key in reversed(keys):
        patch = {key: patch}
    return deep_merge(spec, patch)


def _axis_settings(axis: Mapping[str, Any], where: str) -> list[list[tuple[str, Any]]]:
    """One ``vary`` axis -> its settings, each a list of (dotted key, value).

    ``{key: k, values: [a, b]}`` sets one key; ``{keys: [k1, k2], values: [[a1, a2], [b1, b2]]}`` sets several
    keys together (zipped, e.g. a subset of another preset's combinations)."""
    values = axis.get("values")
    if not values or not isinstance(values, list) or ("key" in axis) == ("keys" in axis):
        raise PresetError(f"{where} needs 'key' (or 'keys') and a non-empty 'values' list")
    if "key" in axis:
        return [[(str(axis["key"]), v)] for v in values]
    keys = [str(k) for k in axis["keys"]]
    for j, row in enumerate(values):
        if not isinstance(row, list) or len(row) != len(keys):
            raise PresetError(f"{where}.values[{j}] = {row!r} must list {len(keys)} values, one per key {keys}")
    return [list(zip(keys, row)) for row in values]


def expand_skill(skill: Mapping[str, Any], defaults: Mapping[str, Any], where: str) -> list[dict[str, Any]]:
    """Cartesian product of the skill's ``vary`` axes applied to its base demo spec.

    ``enumerate: {key: params.seed, start: 0}`` then sets ``key`` to start, start + 1, ... across the
    expanded specs, so that e.g. every random curve of the group gets its own seed."""
    base = deep_merge(defaults, skill.get("spec", {}))
    axes = skill.get("vary", []) or []
    value_lists = [_axis_settings(axis, f"{where}.vary[{i}]") for i, axis in enumerate(axes)]
    specs = []
    for combo in itertools.product(*value_lists):
        spec = base
        for key, value in itertools.chain.from_iterable(combo):
            spec = _set_dotted(spec, key, value)
        specs.append(spec)
    numbering = skill.get("enumerate")
    if numbering is not None:
        if not isinstance(numbering, Mapping) or "key" not in numbering:
            raise PresetError(f"{where}.enumerate = {numbering!r} must be a mapping "
                              "{key: <dotted key>, start: <int>}")
        start = numbering.get("start", 0)
        if isinstance(start, bool) or not isinstance(start, int) or start < 0:
            raise PresetError(f"{where}.enumerate.start = {start!r} must be an integer >= 0")
        specs = [_set_dotted(spec, str(numbering["key"]), start + k) for k, spec in enumerate(specs)]
    return specs


def plan_demos(dataset: Mapping[str, Any], base_seed: int, n_trials_override: int | None = None,
               waypoints: Mapping[str, Any] | None = None, only_skills: Sequence[str] | None = None,
               only_splits: Sequence[str] | None = None) -> list[DemoJob]:
    """Every demo of a preset, in a fixed order, with its splits, trial count and seed.

    Splits: a skill group's ``split`` is ``train``, ``valid``, ``test`` or ``trainval``. For ``trainval`` a
    seeded ``valid_fraction`` goes to valid, either whole skills (``valid_by: skill``, the default; the
    model is checked on unseen skills) or single trials of every skill (``valid_by: trial``; for presets
    with very few skills). ``only_skills`` keeps just the named skill groups (e.g. the train set alone);
    demo indices and seeds are those of the full plan, so the kept demos are identical to the full run's.
    ``only_splits`` likewise keeps the demos with a trial in one of the named splits (e.g. ``valid``: a
    model's validation skills without generating the training set).
    ``extra_skills`` (group name -> skill group) come after ``skills``: a mapping, unlike a list, merges
    across Hydra defaults, so a preset extends another one's groups without restating them.
    """
    defaults = {"duration_s": dataset.get("duration_s", 8.0), "bowl": dict(dataset.get("bowl", {}))}
    demo_lead = dataset.get("demo_lead", False)
    if not isinstance(demo_lead, bool):
        raise PresetError(f"dataset {dataset.get('name')!r}: demo_lead = {demo_lead!r} must be true or false")
    if demo_lead:  # only when set: the specs of presets without it stay byte-identical
        defaults["lead"] = True
    hover = dataset.get("demo_hover_m")
    if hover is not None:  # only when set, as demo_lead
        if isinstance(hover, bool) or not isinstance(hover, (int, float)) or not 0.0 <= hover <= 0.1:
            raise PresetError(f"dataset {dataset.get('name')!r}: demo_hover_m = {hover!r} must be a number in "
                              "[0, 0.1] m")
        defaults["hover_m"] = float(hover)
    groups: list[tuple[str, str, int, list[dict[str, Any]]]] = []
    if waypoints is not None and waypoints.get("waypoints"):
        # recorded as the preset's demos are (its lead and hover); the file sets its own timing
        path = Path(str(waypoints["waypoints"])).expanduser().resolve()
        recorded_as = {key: defaults[key] for key in ("lead", "hover_m") if key in defaults}
        bowl = waypoints["bowl"]  # a mapping of BowlSpec fields or a conf/bowl preset name
        spec = {**recorded_as, "family": "waypoints", "waypoints": str(path),
                "bowl": dict(bowl) if isinstance(bowl, Mapping) else bowl}
        n = int(n_trials_override or waypoints.get("n_trials", 20))
        groups.append(("waypoints", str(waypoints.get("split", "train")), n, [spec]))
    else:
        skills = [(f"dataset.skills[{i}]", skill) for i, skill in enumerate(dataset.get("skills") or [])]
        extra = dataset.get("extra_skills") or {}
        if not isinstance(extra, Mapping):
            raise PresetError(f"dataset.extra_skills must map a group name to a skill group, got {extra!r}")
        for key, skill in extra.items():
            if not isinstance(skill, Mapping):
                raise PresetError(f"dataset.extra_skills.{key} = {skill!r} must be a skill group (a mapping)")
            skills.append((f"dataset.extra_skills.{key}", {"name": key, **skill}))
        if not skills:
            raise PresetError(f"dataset {dataset.get('name')!r} defines no skills")
        for i, (where, skill) in enumerate(skills):
            name = str(skill.get("name", skill.get("spec", {}).get("family", f"skill{i}")))
            split = str(skill.get("split", "train"))
            if split not in ("train", "valid", "test", "trainval"):
                raise PresetError(f"{where}.split = {split!r}; expected train, valid, test or trainval")
            n = int(n_trials_override or skill.get("n_trials", 20))
            if n < 1:
                raise PresetError(f"{where}.n_trials = {n} must be >= 1")
            groups.append((name, split, n, expand_skill(skill, defaults, where)))
        known = {g[0] for g in groups}
        if only_skills is not None and not set(only_skills) <= known:
            raise PresetError(f"skills={list(only_skills)}: unknown skill group(s); the preset has {sorted(known)}")

    valid_fraction = float(dataset.get("valid_fraction", 0.1))
    valid_by = str(dataset.get("valid_by", "skill"))
    if valid_by not in ("skill", "trial"):
        raise PresetError(f"dataset.valid_by = {valid_by!r}; expected 'skill' or 'trial'")
    split_rng = np.random.default_rng(derive_seed(base_seed, 0x5EED))

    jobs: list[DemoJob] = []
    next_traj = 0
    for name, split, n_trials, specs in groups:
        valid_skills: set[int] = set()
        if split == "trainval" and valid_by == "skill":
            n_valid = int(round(valid_fraction * len(specs)))
            valid_skills = set(split_rng.choice(len(specs), size=n_valid, replace=False).tolist())
        for k, spec in enumerate(specs):
            index = len(jobs)
            if split != "trainval":
                trial_splits = (split,) * n_trials
            elif valid_by == "skill":
                trial_splits = ("valid" if k in valid_skills else "train",) * n_trials
            else:
                n_valid = int(round(valid_fraction * n_trials))
                valid_trials = set(split_rng.choice(n_trials, size=n_valid, replace=False).tolist())
                trial_splits = tuple("valid" if t in valid_trials else "train" for t in range(n_trials))
            jobs.append(DemoJob(index=index, skill=name, spec=spec, n_trials=n_trials, trial_splits=trial_splits,
                                seed=derive_seed(base_seed, index), first_traj=next_traj))
            next_traj += n_trials
    if only_skills is not None:
        jobs = [job for job in jobs if job.skill in only_skills]
    if only_splits is not None:
        unknown = sorted(set(only_splits) - {"train", "valid", "test"})
        if unknown:
            raise PresetError(f"splits={list(only_splits)}: unknown split(s) {unknown}; expected train, valid or test")
        jobs = [job for job in jobs if set(job.trial_splits) & set(only_splits)]
    return jobs


def fingerprint(payload: Any) -> str:
    """A short stable hash of JSON-able settings; part files carry it so stale parts are detected."""
    text = json.dumps(payload, sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def compose_config(preset: str, overrides: Sequence[str] = ()) -> Any:
    """Compose ``conf/generate.yaml`` with ``dataset=<preset>`` outside of a Hydra app."""
    from hydra import compose, initialize_config_dir
    from hydra.core.global_hydra import GlobalHydra
    from hydra.initialize import get_gh_backup, restore_gh_from_backup

    outer = get_gh_backup()  # e.g. train.py's own Hydra app: put it back afterwards
    GlobalHydra.instance().clear()
    try:
        with initialize_config_dir(config_dir=str(CONF_DIR)):
            return compose(config_name="generate", overrides=[f"dataset={preset}", *overrides])
    finally:
        restore_gh_from_backup(outer)
