"""Part files (one finished demo each), their assembly into a dataset, and merging of shard files.

A generation run writes every finished demo atomically as ``<work_dir>/demo_%05d.npz`` (temp file +
``os.replace``), so a killed run loses at most the demos in flight and a restart skips the rest. The final
file is assembled from the parts in demo order, so it does not depend on worker count, order or restarts.

Shards (``shard.index=i shard.count=n``) each write ``<out stem>.shard-<i>-of-<n>.h5``; join them with::

    python -m dcm.data.merge data/sim.h5 data/sim.shard-*-of-4.h5

An existing output is refused unless ``--overwrite`` is given, as ``dcm-generate`` and ``dcm-import-logs`` do:
a mistyped command (the output left out, so the first shard is taken for it) must not replace a dataset.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from dcm.console import print_error
from dcm.data.atomic import atomic_path, write_problem
from dcm.data.schema import FIELDS, SCALARS, SPLITS, TRAJ_NAME_FORMAT, DatasetError, _decode_attr, read_root_attrs, write_dataset

PART_ARRAYS = ("x_attr", "K", "x_obs", "F_obs", "contact", "L_task", "L_comp", "failed", "failure_reason",
               "phase_stiffness_Npm")


class MergeError(ValueError):
    """Shards or parts that do not belong together (names the file and the reason)."""


def part_path(work_dir: Path, demo_index: int) -> Path:
    return work_dir / f"demo_{demo_index:05d}.npz"


def write_part(work_dir: Path, demo_index: int, arrays: dict[str, np.ndarray], meta: dict[str, Any]) -> Path:
    """Atomically store one finished demo (all its trials) in the work dir."""
    target = part_path(work_dir, demo_index)
    with atomic_path(target) as tmp, open(tmp, "wb") as handle:
        np.savez(handle, meta=np.array(json.dumps(meta, sort_keys=True)), **arrays)
    return target


def read_part(path: Path) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
    """Load a part file; a damaged one raises ``MergeError`` (delete it and rerun to regenerate the demo)."""
    try:
        with np.load(path, allow_pickle=False) as npz:
            arrays = {key: npz[key] for key in npz.files if key != "meta"}
            meta = json.loads(str(npz["meta"]))
    except Exception as err:  # zipfile/json/pickle errors all mean the same thing here
        raise MergeError(f"{path}: unreadable part file ({err}); delete it and rerun to regenerate it") from err
    return arrays, meta


def part_trajectories(arrays: dict[str, np.ndarray], meta: dict[str, Any]) -> list[dict[str, Any]]:
    """Turn one demo's part into ``write_dataset`` trajectory dicts (one per trial)."""
    job = meta["job"]
    trajs = []
    for t in range(int(job["n_trials"])):
        failed = bool(arrays["failed"][t])
        traj: dict[str, Any] = {
            "name": TRAJ_NAME_FORMAT % (int(job["first_traj"]) + t),
            "x_demo": arrays["x_demo"],
            "F_demo": arrays["F_demo"],
            "x_attr": arrays["x_attr"][t],
            "K": arrays["K"][t],
            "x_obs": arrays["x_obs"][t],
            "F_obs": arrays["F_obs"][t],
            "contact": arrays["contact"][t],
            "L_task": float(arrays["L_task"][t]),
            "L_comp": float(arrays["L_comp"][t]),
            "failed": failed,
            "failure_reason": str(arrays["failure_reason"][t]),
            "demo_id": int(job["index"]),
            "skill": job["skill"],
            "trial": t,
            "split": job["trial_splits"][t],
            "seed": int(job["seed"]),
            "demo": meta["demo"],
            "bowl": meta["demo"].get("bowl", {}),
            "embodiment": meta["embodiment"],
            "domain": meta["domain"],
            "search": meta["search"],
            "phase_boundaries": list(map(int, arrays["phase_boundaries"])),
            "phase_stiffness_Npm": arrays["phase_stiffness_Npm"][t].tolist(),
        }
        if failed:  # a diverged rollout may carry garbage; keep the record, not the numbers
            for key in ("x_attr", "K", "x_obs", "F_obs"):
                traj[key] = np.nan_to_num(traj[key], nan=0.0, posinf=0.0, neginf=0.0)
        trajs.append(traj)
    return trajs


def masks_of(trajectories: Sequence[dict[str, Any]]) -> dict[str, list[str]]:
    masks: dict[str, list[str]] = {split: [] for split in SPLITS}
    for traj in trajectories:
        masks[traj["split"]].append(traj["name"])
    return masks


def assemble(part_files: Sequence[Path], out: Path, attrs: dict[str, Any]) -> int:
    """Write the dataset from part files (in the given order); returns the number of trajectories."""
    trajectories: list[dict[str, Any]] = []
    for path in part_files:
        arrays, meta = read_part(path)
        trajectories.extend(part_trajectories(arrays, meta))
    write_dataset(out, trajectories, masks_of(trajectories), attrs)
    return len(trajectories)


def _read_file_trajectories(path: Path) -> tuple[list[dict[str, Any]], dict[str, list[str]]]:
    trajectories = []
    try:
        with h5py.File(path, "r") as f:
            for name in f["data"]:
                group = f["data"][name]
                traj: dict[str, Any] = {k: _decode_attr(v) for k, v in group.attrs.items()}
                for field in FIELDS:
                    traj[field] = group[field][()]
                traj["name"] = name
                trajectories.append(traj)
            masks = {split: [n.decode() for n in f["mask"][split][()]] for split in f["mask"]}
    except (OSError, KeyError) as err:
        raise DatasetError(path, f"unreadable shard (truncated or corrupt?): {err}") from err
    return trajectories, masks


def check_output(out: Path, shard_paths: Sequence[Path], overwrite: bool) -> None:
    """Refuse an ``out`` that exists (without ``overwrite``), is a directory, is one of the shards or cannot be
    written, before any shard is read."""
    if problem := write_problem(out):
        raise MergeError(f"cannot write {out}: {problem}")
    if any(out.resolve() == p.resolve() for p in shard_paths):
        raise MergeError(f"{out} is both the output and a shard; choose another output")
    if out.exists() and not overwrite:
        raise MergeError(f"{out} exists; pass --overwrite to replace it, or choose another output")


def merge_shards(out: str | Path, shard_paths: Sequence[str | Path], overwrite: bool = False) -> int:
    """Join shard files of one generation plan into one dataset (stats recomputed over the whole train split).

    An existing ``out`` is replaced only with ``overwrite``; the shards are only read."""
    out = Path(out)
    shard_paths = [Path(p) for p in shard_paths]
    if not shard_paths:
        raise MergeError("no shard files given")
    check_output(out, shard_paths, overwrite)
    roots = [read_root_attrs(p) for p in shard_paths]
    plans = {r.get("plan_fingerprint") for r in roots}
    if len(plans) != 1:
        raise MergeError(f"shards come from different generation plans: {dict(zip(map(str, shard_paths), plans))}")
    counts = {int(r.get("shard_count", 1)) for r in roots}
    indices = sorted(int(r.get("shard_index", 0)) for r in roots)
    if len(counts) != 1 or indices != list(range(next(iter(counts)))):
        raise MergeError(f"need every shard 0..n-1 exactly once; got indices {indices} of counts {sorted(counts)}")
    for key in ("control_hz", "horizon", "embodiment"):
        values = {str(r.get(key)) for r in roots}
        if len(values) != 1:
            raise MergeError(f"shards disagree on {key}: {values}")
    trajectories: list[dict[str, Any]] = []
    masks: dict[str, list[str]] = {split: [] for split in SPLITS}
    for path in shard_paths:
        shard_trajs, shard_masks = _read_file_trajectories(path)
        trajectories.extend(shard_trajs)
        for split, names in shard_masks.items():
            masks.setdefault(split, []).extend(names)
    trajectories.sort(key=lambda t: t["name"])
    names = [t["name"] for t in trajectories]
    if len(set(names)) != len(names):
        raise MergeError("two shards hold the same trajectory names; were shards generated with the same plan?")
    expected = int(roots[0].get("n_trajectories_total", len(names)))
    if len(names) != expected:
        raise MergeError(f"shards hold {len(names)} trajectories, the plan has {expected}")
    for split in masks:
        masks[split] = sorted(masks[split])
    # failed trials are out of the masks already; put them back only as stored records
    attrs = {k: v for k, v in roots[0].items() if k not in ("shard_index", "shard_count", "created", "horizon",
                                                              "format_version", "dcm_version", "packages", "channels",
                                                              "stats_split")}
    attrs["merged_from"] = [p.name for p in shard_paths]
    for traj in trajectories:
        for scalar in SCALARS:
            traj[scalar] = float(traj[scalar])
    write_dataset(out, trajectories, masks, attrs)
    return len(trajectories)


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m dcm.data.merge", description=__doc__.split("\n")[0])
    parser.add_argument("out", help="merged dataset to write (atomically)")
    parser.add_argument("shards", nargs="+", help="shard files written with shard.index=i shard.count=n")
    parser.add_argument("--overwrite", action="store_true", help="replace an existing output file")
    args = parser.parse_args(argv)
    try:
        n = merge_shards(args.out, args.shards, overwrite=args.overwrite)
    except (MergeError, DatasetError) as err:
        return print_error(f"merge failed: {err}")
    except OSError as err:  # the output's directory cannot be created or written
        return print_error(f"merge failed: cannot write {args.out}: {err}")
    print(f"wrote {args.out}: {n} trajectories from {len(args.shards)} shards")
    return 0


if __name__ == "__main__":
    sys.exit(main())
