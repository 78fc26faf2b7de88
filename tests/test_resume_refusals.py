"""A refused ``resume=`` of tune.py leaves the run it names as it was: no ``<run>/resumed/<time>/`` folder."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def _tune(args: list[str], cwd: Path) -> subprocess.CompletedProcess:
    env = dict(os.environ, HYDRA_FULL_ERROR="0", PYTHONWARNINGS="ignore", MUJOCO_GL="egl")
    return subprocess.run([sys.executable, str(REPO / "tune.py"), *args], cwd=cwd, env=env, capture_output=True,
                          text=True, timeout=300)


def _tree(root: Path) -> list[str]:
    return sorted(str(p.relative_to(root)) for p in root.rglob("*"))


def test_a_refused_resume_leaves_no_resumed_folder(tmp_path: Path) -> None:
    (tmp_path / "notarun").mkdir()
    proc = _tune(["resume=notarun"], cwd=tmp_path)
    assert proc.returncode == 1 and proc.stderr.strip().splitlines()[-1] == (
        "error: resume=notarun: no loop/config.yaml there: not a run started with robot=sim or robot=files")
    assert _tree(tmp_path) == ["notarun"]

    # a loop run (its settings file) resumed with a setting it cannot change; an earlier resume's record stays
    run = tmp_path / "run"
    (run / "loop").mkdir(parents=True)
    (run / "loop" / "config.yaml").write_text("seed: 0\n")
    (run / "resumed" / "earlier").mkdir(parents=True)
    before = _tree(tmp_path)
    proc = _tune([f"resume={run}", "seed=3", "--config-name", "quickstart"], cwd=tmp_path)
    assert proc.returncode == 1 and "seed cannot change" in proc.stderr.strip().splitlines()[-1], proc.stderr[-2000:]
    assert _tree(tmp_path) == before
