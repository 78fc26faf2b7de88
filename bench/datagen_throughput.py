"""Data-generation throughput: the full ``sim`` train set (80 spiral skills x 20 trials) on 2 workers.

    MUJOCO_GL=egl .venv/bin/python bench/datagen_throughput.py [--embodiment panda] [--workers 2]
        [--subset-shards 20] [--out data/sim_train.h5]

Prints wall time and trajectories/s of the 2-worker run and the 1-vs-2-worker scaling. The 1-worker time
is MEASURED ON A SUBSET (every ``subset-shards``-th demo, i.e. 1/20 of the skills by default) and
extrapolated linearly to the full set by trial count; both runs include process start-up and model builds.
Targets (issue): full train set <= 15 min, scaling >= 1.8x.
"""

from __future__ import annotations

import argparse
import os
import resource
import shutil
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")

from dcm.data.generate import compose_config, generate  # noqa: E402
from dcm.data.schema import load_dataset  # noqa: E402


def _cpu_seconds() -> float:
    """CPU time of this process and its finished children (the pool's workers are joined at the end)."""
    own, children = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + children.ru_utime + children.ru_stime


def timed_generate(overrides: list[str]) -> tuple[float, int, float]:
    """(wall s, trajectories, CPU s): CPU/wall shows how much of the cores the run actually got."""
    cfg = compose_config("sim", overrides)
    cpu, start = _cpu_seconds(), time.perf_counter()
    path = generate(cfg)
    elapsed = time.perf_counter() - start
    return elapsed, len(load_dataset(path, include_failed=True)), _cpu_seconds() - cpu


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--embodiment", default="panda")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--subset-shards", type=int, default=20, help="1-worker run uses 1/N of the demos")
    parser.add_argument("--out", type=Path, default=None, help="keep the full train set here")
    args = parser.parse_args()
    tmp = Path(tempfile.mkdtemp(prefix="dcm_datagen_bench_"))
    common = ["skills=[spiral]", f"embodiment={args.embodiment}", "progress=true"]
    try:
        t1_subset, n1, cpu1 = timed_generate([*common, f"out={tmp / 'subset.h5'}", "workers=1",
                                        f"shard.count={args.subset_shards}", "shard.index=0"])
        out = args.out.resolve() if args.out else tmp / "sim_train.h5"
        t2, n2, cpu2 = timed_generate([*common, f"out={out}", f"workers={args.workers}"])
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    t1_full = t1_subset * n2 / n1
    print(f"embodiment {args.embodiment}, cpu count {os.cpu_count()}, load average {os.getloadavg()[0]:.2f}")
    print(f"1 worker : {n1} trajectories in {t1_subset:.1f} s = {n1 / t1_subset:.2f} traj/s "
          f"(subset 1/{args.subset_shards}; extrapolated full set {t1_full / 60:.1f} min); "
          f"CPU {cpu1:.0f} s = {cpu1 / t1_subset:.2f} cores busy")
    print(f"{args.workers} workers: {n2} trajectories in {t2:.1f} s ({t2 / 60:.1f} min) = {n2 / t2:.2f} traj/s; "
          f"CPU {cpu2:.0f} s = {cpu2 / t2:.2f} cores busy")
    print(f"scaling {args.workers} vs 1 worker: {t1_full / t2:.2f}x wall; per CPU-second "
          f"{(n2 / cpu2) / (n1 / cpu1):.2f} of the 1-worker efficiency (other load on the machine lowers the first)")
    if args.out:
        print(f"kept {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
