"""The on-disk dataset format (HDF5, robomimic-like) and its validating reader/writer.

One file holds every trial of a dataset; the models read it through :func:`load_dataset`, which refuses
anything that would silently train on garbage (wrong shapes, NaN, another control rate, ...).

Layout, format version "1"::

    /                   attrs: format_version, dcm_version, packages (JSON: the versions of python, numpy,
                               mujoco and robosuite that wrote it), control_hz, horizon, embodiment, domain,
                               channels (JSON), config (YAML: the settings that made the file; written and
                               read only through :func:`config_text` / :func:`read_config`),
                               created (ISO 8601), + any extra attrs
    /data/traj_%06d     one group per trial; attrs: demo_id, demo (JSON), bowl (JSON), embodiment,
                               domain (JSON), seed, trial, L_task, L_comp, failed, failure_reason, ...
        x_demo (H,6) f4, F_demo (H,6) f4, x_attr (H,6) f4, K (H,6) f4, x_obs (H,6) f4, F_obs (H,6) f4,
        contact (H,) u1
    /mask/<split>       1-D "S" array of trajectory names (train, valid, test; possibly empty)
    /stats/<field>/{min,max,mean,std}   (C,) f4 over the train split's non-failed trials
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from dcm.console import one_line
from dcm.data.atomic import atomic_path

FORMAT_VERSION = "1"
CONFIG_ATTR = "config"  # root attribute: the settings that made the file, as YAML text
SPLITS = ("train", "valid", "test")

POSE_CHANNELS = ["x_m", "y_m", "z_m", "rx_rad", "ry_rad", "rz_rad"]
WRENCH_CHANNELS = ["Fx_N", "Fy_N", "Fz_N", "Tx_Nm", "Ty_Nm", "Tz_Nm"]
STIFFNESS_CHANNELS = ["Kx_Npm", "Ky_Npm", "Kz_Npm", "Krx_Nmprad", "Kry_Nmprad", "Krz_Nmprad"]

# field -> channel names; "contact" is a per-step flag stored as (H,) u1 and has no channel axis.
CHANNELS: dict[str, list[str]] = {
    "x_demo": POSE_CHANNELS,
    "F_demo": WRENCH_CHANNELS,
    "x_attr": POSE_CHANNELS,
    "K": STIFFNESS_CHANNELS,
    "x_obs": POSE_CHANNELS,
    "F_obs": WRENCH_CHANNELS,
    "contact": ["in_contact"],
}
FIELDS: tuple[str, ...] = tuple(CHANNELS)
VECTOR_FIELDS: tuple[str, ...] = tuple(f for f in FIELDS if f != "contact")
SCALARS: tuple[str, ...] = ("L_task", "L_comp")
TRAJ_NAME_FORMAT = "traj_%06d"

# What a contact model reads and predicts: per-step conditions and the target, in this order along the
# channel axis. The data layout owns it (models read it); changing it invalidates checkpoints.
COND_FIELDS: tuple[str, ...] = ("x_demo", "F_demo", "x_attr", "K")
FORCE_FIELD = "F_obs"  # the target's force part: the observed wrench
# The target's pose part: the realised translation x_obs - x_demo, derived from two stored fields. A delta, not
# x_obs itself, so that its normaliser sees how far the tool strays from the demo rather than where the bowl is.
POSE_DELTA_FIELD = "dx_obs"
POSE_DELTA_SOURCES = ("x_obs", "x_demo")
POSE_DELTA_WIDTH = 3  # the translation; the tool's orientation is held, not learned
TARGET_FIELDS = ("force", "force_and_pose")  # a model's ``target_fields`` option


@dataclass(frozen=True)
class TargetLayout:
    """What a contact model predicts, channel by channel: the wrench F_obs and, for ``force_and_pose``, the
    realised translation ``x_obs - x_demo`` (``dx_obs``). Models, their normalisers, metrics and the data
    pipeline read widths and slices from here, so the target's make-up is stated once.

    ``channels``: the stored fields' channel names the layout is built from (a dataset's own declaration).
    """

    target_fields: str = "force"
    channels: Mapping[str, Sequence[str]] = field(default_factory=lambda: CHANNELS)

    def __post_init__(self) -> None:
        if self.target_fields not in TARGET_FIELDS:
            raise ValueError(f"target_fields = {self.target_fields!r} is not one of {', '.join(TARGET_FIELDS)}")

    @property
    def predicts_pose(self) -> bool:
        return self.target_fields == "force_and_pose"

    @property
    def parts(self) -> tuple[tuple[str, list[str]], ...]:
        """(field, channel names) in order along the target's channel axis."""
        force = (FORCE_FIELD, list(self.channels.get(FORCE_FIELD, [])))
        if not self.predicts_pose:
            return (force,)
        return force, (POSE_DELTA_FIELD, list(self.channels.get(POSE_DELTA_SOURCES[0], []))[:POSE_DELTA_WIDTH])

    def channel_names(self) -> list[str]:
        """E.g. ``F_obs.Fx_N`` ... ``F_obs.Tz_Nm`` and, with the pose, ``dx_obs.x_m`` ... ``dx_obs.z_m``."""
        return [f"{name}.{c}" for name, channels in self.parts for c in channels]

    def part(self, field_name: str) -> slice:
        """Where ``field_name`` (``F_obs`` or ``dx_obs``) sits along the target's channel axis."""
        start = 0
        for name, channels in self.parts:
            if name == field_name:
                return slice(start, start + len(channels))
            start += len(channels)
        raise KeyError(f"{field_name!r} is not a part of the {self.target_fields} target; parts: "
                       f"{[name for name, _ in self.parts]}")

    @property
    def width(self) -> int:
        return sum(len(channels) for _, channels in self.parts)

    @property
    def force(self) -> slice:
        return self.part(FORCE_FIELD)

    @property
    def pose(self) -> slice | None:
        """The translation delta's channels; None for a force-only target."""
        return self.part(POSE_DELTA_FIELD) if self.predicts_pose else None

    def objective_problem(self, objective: Any) -> str | None:
        """Why a model of this target cannot be trained or scored for ``objective`` (a
        :class:`dcm.control.objectives.TaskObjective`), or None: one that counts the tool's path needs the pose,
        since a force-only model cannot tell one schedule's path from another's."""
        if objective.counts_path and not self.predicts_pose:
            return (f"objective {objective.describe()} counts the path; this model predicts only the force: "
                    "train it with model.target_fields=force_and_pose")
        return None

    def from_arrays(self, arrays: Mapping[str, np.ndarray]) -> np.ndarray:
        """The target (..., H, width) float32 from stored fields (..., H, 6): F_obs, and for the pose the
        translation of x_obs - x_demo."""
        force = np.asarray(arrays[FORCE_FIELD], dtype=np.float32)
        if not self.predicts_pose:
            return force
        observed, demo = (np.asarray(arrays[f], dtype=np.float32)[..., :POSE_DELTA_WIDTH] for f in POSE_DELTA_SOURCES)
        return np.concatenate([force, observed - demo], axis=-1)


def target_layout(target_fields: str = "force", channels: Mapping[str, Sequence[str]] | None = None) -> TargetLayout:
    """The :class:`TargetLayout` of a model's ``target_fields`` (``force`` | ``force_and_pose``), over the
    channels a dataset declares (default: this format's)."""
    return TargetLayout(target_fields, CHANNELS if channels is None else channels)


FORCE_LAYOUT = target_layout("force")


def cond_channel_names() -> list[str]:
    """The 24 condition channel names, e.g. ``x_demo.x_m`` ... ``K.Krz_Nmprad``."""
    return [f"{f}.{c}" for f in COND_FIELDS for c in CHANNELS[f]]


def target_channel_names(target_fields: str = "force") -> list[str]:
    """The target channel names of ``target_fields``: ``F_obs.Fx_N`` ... ``F_obs.Tz_Nm``, and for
    ``force_and_pose`` then ``dx_obs.x_m`` ... ``dx_obs.z_m``."""
    return target_layout(target_fields).channel_names()


def cond_slice(field_name: str) -> slice:
    """Where ``field_name`` sits along the condition channel axis (e.g. ``F_demo`` -> 6:12)."""
    start = 0
    for f in COND_FIELDS:
        if f == field_name:
            return slice(start, start + len(CHANNELS[f]))
        start += len(CHANNELS[f])
    raise KeyError(f"{field_name!r} is not a condition field; conditions are {COND_FIELDS}")


class DatasetMismatchError(ValueError):
    """A dataset's channels or control rate differ from those a model was trained on."""


class DatasetError(ValueError):
    """A dataset file is unusable; the message names the file, the trajectory and the field."""

    def __init__(self, path: str | os.PathLike, message: str, trajectory: str | None = None,
                 field: str | None = None):
        self.path = str(path)
        self.trajectory = trajectory
        self.field = field
        where = [f"file {self.path}"]
        if trajectory is not None:
            where.append(f"trajectory {trajectory}")
        if field is not None:
            where.append(f"field {field}")
        super().__init__(f"{', '.join(where)}: {message}")


@dataclass
class LoadedDataset:
    """The validated contents of one split (or of all usable trials) of a dataset file."""

    path: Path
    names: list[str]
    arrays: dict[str, np.ndarray]  # field -> (N,H,C) float32; contact -> (N,H) float32 in {0,1}
    L_task: np.ndarray  # (N,) N
    L_comp: np.ndarray  # (N,) kN/m
    stats: dict[str, dict[str, np.ndarray]]  # field -> {min,max,mean,std} (C,)
    attrs: dict[str, Any]
    meta: list[dict[str, Any]] = field(default_factory=list)  # per-trajectory attributes, decoded
    split: str | None = None

    @property
    def control_hz(self) -> float:
        return float(self.attrs["control_hz"])

    @property
    def horizon(self) -> int:
        return int(self.attrs["horizon"])

    @property
    def demo_ids(self) -> np.ndarray:
        return np.array([int(m.get("demo_id", -1)) for m in self.meta], dtype=np.int64)

    def __len__(self) -> int:
        return len(self.names)


# ----------------------------------------------------------------------------------------------- helpers
def _encode_attr(value: Any) -> Any:
    """HDF5 attributes hold scalars/strings/arrays; nested metadata goes in as JSON text."""
    if isinstance(value, (dict, list, tuple)):
        return json.dumps(value, sort_keys=True, default=_json_default)
    if value is None:
        return ""
    if isinstance(value, (np.bool_, bool)):
        return bool(value)
    if isinstance(value, Path):
        return str(value)
    return value


def _json_default(obj: Any) -> Any:
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, Path):
        return str(obj)
    raise TypeError(f"cannot store {type(obj).__name__} as JSON metadata")


def config_text(config: Mapping[str, Any] | str | None, path: str | os.PathLike = "<dataset>") -> str:
    """The ``config`` root attribute for a configuration: YAML text, ``""`` for none.

    Text is kept as given (a merge keeps its shards' bytes) once it reads back as a mapping, so whatever
    writes a file, :func:`read_config` reads it."""
    import yaml

    if config is None:
        return ""
    if isinstance(config, str):
        _parse_config(config, path)
        return config
    if not isinstance(config, Mapping):
        raise TypeError(f"a dataset's config must be a mapping, got {type(config).__name__}")
    plain = json.loads(json.dumps(config, default=_json_default))  # numpy scalars, paths -> YAML-safe values
    return yaml.safe_dump(plain, sort_keys=False, default_flow_style=False, allow_unicode=True)


def _parse_config(text: str, path: str | os.PathLike) -> dict[str, Any]:
    import yaml

    try:
        loaded = yaml.safe_load(text) if text.strip() else {}
    except yaml.YAMLError as err:
        raise DatasetError(path, f"not readable as YAML ({one_line(err)})", field=CONFIG_ATTR) from None
    if not isinstance(loaded, dict):
        raise DatasetError(path, f"expected a mapping of settings, got {type(loaded).__name__}", field=CONFIG_ATTR)
    return loaded


def read_config(attrs: Mapping[str, Any], path: str | os.PathLike = "<dataset>") -> dict[str, Any]:
    """The settings a file's ``config`` root attribute holds (root attributes as :func:`read_root_attrs`
    gives them); ``{}`` when the file records none. Raises :class:`DatasetError` naming ``path`` when the
    attribute is not a mapping."""
    value = attrs.get(CONFIG_ATTR)
    if value is None:
        return {}
    if isinstance(value, Mapping):
        return dict(value)
    return _parse_config(str(value), path)


def _decode_attr(value: Any) -> Any:
    if isinstance(value, bytes):
        value = value.decode()
    if isinstance(value, str) and value[:1] in "{[":
        try:
            return json.loads(value)
        except json.JSONDecodeError:
            return value
    if isinstance(value, np.generic):
        return value.item()
    return value


def expected_shape(field_name: str, horizon: int) -> tuple[int, ...]:
    return (horizon,) if field_name == "contact" else (horizon, len(CHANNELS[field_name]))


def compute_stats(arrays: Mapping[str, np.ndarray]) -> dict[str, dict[str, np.ndarray]]:
    """Per-channel min/max/mean/std of stacked (N,H,C) arrays; used for normalisation by the models."""
    stats: dict[str, dict[str, np.ndarray]] = {}
    for name, stacked in arrays.items():
        flat = np.asarray(stacked, dtype=np.float64)
        flat = flat.reshape(-1, 1) if name == "contact" else flat.reshape(-1, flat.shape[-1])
        stats[name] = {
            "min": flat.min(axis=0).astype(np.float32),
            "max": flat.max(axis=0).astype(np.float32),
            "mean": flat.mean(axis=0).astype(np.float32),
            "std": flat.std(axis=0).astype(np.float32),
        }
    return stats


def _value_problem(field_name: str, value: np.ndarray) -> str | None:
    """What is wrong with one trajectory's array, or None: NaN/inf anywhere, or a stiffness that is not > 0.

    K > 0 is checked here, where data enters, so that nothing downstream (log K, 1/K features) has to.
    """
    if field_name == "contact":
        return None
    if not np.all(np.isfinite(value)):
        return f"contains NaN or inf (first at index {np.argwhere(~np.isfinite(value))[0].tolist()})"
    if field_name == "K" and not np.all(value > 0):
        bad = np.argwhere(~(value > 0))[0]
        return f"stiffness must be positive, got {float(value[tuple(bad)]):.4g} (first at index {bad.tolist()})"
    return None


def _is_failed(traj: Mapping[str, Any]) -> bool:
    return bool(traj.get("failed", False))


# ----------------------------------------------------------------------------------------------- writer
RECORDED_PACKAGES = ("numpy", "mujoco", "robosuite")


def package_versions() -> dict[str, str]:
    """The versions a file's numbers depend on. Why: the same seed gives the same bytes only with the same
    numerics, and a file that does not say which wrote it cannot tell a changed draw from a changed library."""
    import platform
    from importlib.metadata import PackageNotFoundError, version

    out = {"python": platform.python_version()}
    for name in RECORDED_PACKAGES:
        try:
            out[name] = version(name)
        except PackageNotFoundError:
            out[name] = "absent"
    return out


def write_dataset(path: str | os.PathLike, trajectories: Sequence[Mapping[str, Any]],
                  masks: Mapping[str, Sequence[str]], attrs: Mapping[str, Any]) -> None:
    """Write a complete dataset file atomically (temp file in the same directory + ``os.replace``).

    Each trajectory dict holds the arrays of :data:`FIELDS`, ``L_task``, ``L_comp`` and optionally ``name``
    (default ``traj_%06d`` by position), ``failed``/``failure_reason`` and any other metadata (stored as group
    attributes, dicts/lists as JSON). Failed trials are stored but dropped from the masks. ``attrs`` must hold
    ``control_hz``; ``horizon``, ``format_version``, ``dcm_version``, ``packages``, ``channels`` and ``created``
    are filled in; ``config`` (a mapping of settings, or YAML text) is stored through :func:`config_text`.
    Stats cover the train split (all usable trials if the file has no train split, e.g. a test-only import).
    """
    from dcm import __version__

    path = Path(path)
    if "control_hz" not in attrs:
        raise DatasetError(path, "root attribute 'control_hz' is required", field="control_hz")
    if not trajectories:
        raise DatasetError(path, "no trajectories to write")
    horizon = int(np.asarray(trajectories[0]["x_demo"]).shape[0])

    prepared: list[tuple[str, dict[str, np.ndarray], dict[str, Any]]] = []
    seen: set[str] = set()
    for index, traj in enumerate(trajectories):
        name = str(traj.get("name", TRAJ_NAME_FORMAT % index))
        if name in seen:
            raise DatasetError(path, "duplicate trajectory name", trajectory=name)
        seen.add(name)
        arrays: dict[str, np.ndarray] = {}
        for field_name in FIELDS:
            if field_name not in traj:
                raise DatasetError(path, "missing array", trajectory=name, field=field_name)
            value = np.asarray(traj[field_name])
            if value.shape != expected_shape(field_name, horizon):
                raise DatasetError(path, f"shape {value.shape}, expected {expected_shape(field_name, horizon)}",
                                   trajectory=name, field=field_name)
            if field_name == "contact":
                value = value.astype(np.uint8)
            else:
                value = value.astype(np.float32)
                problem = _value_problem(field_name, value)
                if problem:
                    raise DatasetError(path, problem, trajectory=name, field=field_name)
            arrays[field_name] = value
        meta = {k: v for k, v in traj.items() if k not in FIELDS and k != "name"}
        for scalar in SCALARS:
            if scalar not in meta:
                raise DatasetError(path, "missing scalar", trajectory=name, field=scalar)
            meta[scalar] = float(meta[scalar])
            if not _is_failed(traj) and not math.isfinite(meta[scalar]):
                raise DatasetError(path, f"non-finite value {meta[scalar]}", trajectory=name, field=scalar)
        meta["failed"] = _is_failed(traj)
        meta.setdefault("failure_reason", "")
        prepared.append((name, arrays, meta))

    usable = {name for name, _, meta in prepared if not meta["failed"]}
    clean_masks: dict[str, list[str]] = {split: [] for split in SPLITS}
    for split, names in masks.items():
        for name in names:
            if name not in seen:
                raise DatasetError(path, f"mask '{split}' names an unknown trajectory", trajectory=name)
        clean_masks[split] = [n for n in names if n in usable]

    stats_split = "train" if clean_masks.get("train") else "all"
    stats_names = set(clean_masks["train"]) if stats_split == "train" else usable
    if not stats_names:
        raise DatasetError(path, "every trial failed: nothing to compute normalisation stats from")
    stacked = {f: np.stack([a[f] for n, a, _ in prepared if n in stats_names]) for f in FIELDS}
    stats = compute_stats(stacked)

    root_attrs = {k: v for k, v in attrs.items()}
    root_attrs.update(
        format_version=FORMAT_VERSION,
        dcm_version=__version__,
        packages=package_versions(),
        horizon=horizon,
        channels=CHANNELS,
        stats_split=stats_split,
    )
    root_attrs.setdefault("created", datetime.now(UTC).isoformat(timespec="seconds"))
    root_attrs[CONFIG_ATTR] = config_text(root_attrs.get(CONFIG_ATTR), path)

    with atomic_path(path) as tmp_name:
        with h5py.File(tmp_name, "w") as f:
            for key, value in root_attrs.items():
                f.attrs[key] = _encode_attr(value)
            data = f.create_group("data")
            for name, arrays, meta in prepared:
                group = data.create_group(name)
                for field_name, value in arrays.items():
                    group.create_dataset(field_name, data=value)
                for key, value in meta.items():
                    group.attrs[key] = _encode_attr(value)
            mask = f.create_group("mask")
            for split, names in clean_masks.items():
                mask.create_dataset(split, data=np.array(names, dtype="S"))
            stats_group = f.create_group("stats")
            for field_name, per_stat in stats.items():
                group = stats_group.create_group(field_name)
                for stat_name, value in per_stat.items():
                    group.create_dataset(stat_name, data=value)


# ----------------------------------------------------------------------------------------------- reader
def _read_names(path: Path, f: h5py.File, split: str) -> list[str]:
    if "mask" not in f:
        raise DatasetError(path, "missing group /mask", field="mask")
    if split not in f["mask"]:
        available = sorted(f["mask"].keys())
        raise DatasetError(path, f"no split '{split}' (available: {available})", field=f"mask/{split}")
    raw = f["mask"][split][()]
    names = [n.decode() if isinstance(n, bytes) else str(n) for n in np.atleast_1d(raw)]
    if not names:
        raise DatasetError(path, f"split '{split}' is empty", field=f"mask/{split}")
    return names


def _read_stats(path: Path, f: h5py.File) -> dict[str, dict[str, np.ndarray]]:
    if "stats" not in f:
        raise DatasetError(path, "missing group /stats", field="stats")
    stats: dict[str, dict[str, np.ndarray]] = {}
    for field_name in FIELDS:
        n_channels = len(CHANNELS[field_name])
        stats[field_name] = {}
        for stat_name in ("min", "max", "mean", "std"):
            key = f"{field_name}/{stat_name}"
            if key not in f["stats"]:
                raise DatasetError(path, "missing statistic", field=f"stats/{key}")
            value = np.asarray(f["stats"][key][()], dtype=np.float32)
            if value.shape != (n_channels,):
                raise DatasetError(path, f"shape {value.shape}, expected ({n_channels},)", field=f"stats/{key}")
            if not np.all(np.isfinite(value)):
                raise DatasetError(path, "contains NaN or inf", field=f"stats/{key}")
            stats[field_name][stat_name] = value
    return stats


def read_root_attrs(path: str | os.PathLike) -> dict[str, Any]:
    """Root attributes of a dataset file (decoded), after checking the format version."""
    path = Path(path)
    with _open(path) as f:
        return _check_root(path, f)


def _open(path: Path) -> h5py.File:
    if not path.exists():
        raise DatasetError(path, "file does not exist")
    try:
        return h5py.File(path, "r")
    except OSError as err:
        raise DatasetError(path, f"not a readable HDF5 file (truncated or corrupt?): {err}") from err


def _check_root(path: Path, f: h5py.File) -> dict[str, Any]:
    attrs = {k: _decode_attr(v) for k, v in f.attrs.items() if k != CONFIG_ATTR}
    if CONFIG_ATTR in f.attrs:  # text whatever it looks like: read_config parses it
        raw = f.attrs[CONFIG_ATTR]
        attrs[CONFIG_ATTR] = raw.decode() if isinstance(raw, bytes) else str(raw)
    version = attrs.get("format_version")
    if version is None:
        raise DatasetError(path, "no format_version attribute: not a dcm dataset", field="format_version")
    if str(version) != FORMAT_VERSION:
        raise DatasetError(path, f"unknown format version {version!r} (this dcm reads {FORMAT_VERSION!r})",
                           field="format_version")
    for key in ("control_hz", "horizon"):
        if key not in attrs:
            raise DatasetError(path, "missing root attribute", field=key)
    if not (isinstance(attrs["horizon"], (int, np.integer)) and attrs["horizon"] > 0):
        raise DatasetError(path, f"invalid horizon {attrs['horizon']!r}", field="horizon")
    return attrs


def load_dataset(path: str | os.PathLike, split: str | None = None, expect_control_hz: float | None = None,
                 include_failed: bool = False) -> LoadedDataset:
    """Load and validate one split (or, with ``split=None``, every non-failed trial) of a dataset file.

    Raises :class:`DatasetError` naming file/trajectory/field for a truncated or corrupt file, an unknown
    format version, a control rate other than ``expect_control_hz``, an empty or unknown split, a missing
    trajectory/array/attribute, a wrong shape, a NaN/inf value or a stiffness ≤ 0.
    """
    path = Path(path)
    try:
        with _open(path) as f:
            attrs = _check_root(path, f)
            control_hz = float(attrs["control_hz"])
            if expect_control_hz is not None and not math.isclose(control_hz, float(expect_control_hz),
                                                                  rel_tol=1e-9, abs_tol=1e-9):
                raise DatasetError(path, f"control rate {control_hz} Hz, expected {expect_control_hz} Hz",
                                   field="control_hz")
            horizon = int(attrs["horizon"])
            if "data" not in f:
                raise DatasetError(path, "missing group /data", field="data")
            data = f["data"]
            if split is None:
                names = sorted(n for n in data.keys()
                               if include_failed or not bool(data[n].attrs.get("failed", False)))
                if not names:
                    raise DatasetError(path, "no usable trajectories in /data", field="data")
            else:
                names = _read_names(path, f, split)
            stats = _read_stats(path, f)

            arrays = {f_: np.empty((len(names), *expected_shape(f_, horizon)), dtype=np.float32) for f_ in FIELDS}
            L_task = np.empty(len(names), dtype=np.float64)
            L_comp = np.empty(len(names), dtype=np.float64)
            meta: list[dict[str, Any]] = []
            for i, name in enumerate(names):
                if name not in data:
                    raise DatasetError(path, "listed in the mask but missing from /data", trajectory=name)
                group = data[name]
                for field_name in FIELDS:
                    if field_name not in group:
                        raise DatasetError(path, "missing array", trajectory=name, field=field_name)
                    dataset = group[field_name]
                    want = expected_shape(field_name, horizon)
                    if dataset.shape != want:
                        raise DatasetError(path, f"shape {dataset.shape}, expected {want} (horizon {horizon})",
                                           trajectory=name, field=field_name)
                    value = dataset[()]
                    problem = _value_problem(field_name, value)
                    if problem:
                        raise DatasetError(path, problem, trajectory=name, field=field_name)
                    arrays[field_name][i] = value
                traj_meta = {k: _decode_attr(v) for k, v in group.attrs.items()}
                for scalar, out in (("L_task", L_task), ("L_comp", L_comp)):
                    if scalar not in traj_meta:
                        raise DatasetError(path, "missing attribute", trajectory=name, field=scalar)
                    out[i] = float(traj_meta[scalar])
                    if not include_failed and not math.isfinite(out[i]):
                        raise DatasetError(path, f"non-finite value {out[i]}", trajectory=name, field=scalar)
                meta.append(traj_meta)
    except DatasetError:
        raise
    except (OSError, KeyError, RuntimeError) as err:  # h5py raises these on truncated datasets/chunks
        raise DatasetError(path, f"unreadable (truncated or corrupt?): {err}") from err
    return LoadedDataset(path=path, names=names, arrays=arrays, L_task=L_task, L_comp=L_comp, stats=stats,
                         attrs=attrs, meta=meta, split=split)
