"""A built wheel runs the quick start from any directory: its configs, bowl presets, example waypoints and shipped
models resolve as package data, and its outputs go to the working directory, not into site-packages.

The wheel is built offline (no build isolation, no index: torch itself requires the setuptools >= 77 that
pyproject.toml builds with) from a copy of the source tree, so the checkout gets no build/ folder. It is installed
into a fresh virtual environment that reuses this environment's dependencies through a .pth file (a venv made from
a venv sees only the base interpreter's packages, not these)."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import sysconfig
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
SOURCES = ["pyproject.toml", "setup.py", "MANIFEST.in", "README.md", "dcm", "conf", "models", "data/demos",
           "data/waypoints"]


def _run(cmd: list[str], cwd: Path, env: dict[str, str] | None = None, timeout: float = 120) -> str:
    done = subprocess.run(cmd, cwd=cwd, env=env, capture_output=True, text=True, timeout=timeout)
    assert done.returncode == 0, f"{' '.join(map(str, cmd))} failed ({done.returncode}):\n{done.stdout}\n{done.stderr}"
    return done.stdout + done.stderr


@pytest.fixture(scope="module")
def wheel_env(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The bin folder of a venv holding only the wheel of this tree (its dependencies come from this one)."""
    root = tmp_path_factory.mktemp("wheel")
    src = root / "src"
    for name in SOURCES:
        if (REPO / name).is_dir():
            shutil.copytree(REPO / name, src / name, ignore=shutil.ignore_patterns("__pycache__", "*.pyc"))
        else:
            (src / name).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(REPO / name, src / name)
    pip = [sys.executable, "-m", "pip", "--disable-pip-version-check", "--no-input"]
    build_log = _run([*pip, "wheel", "--no-deps", "--no-build-isolation", "--no-index", "-v", "-w", str(root / "dist"),
                      str(src)], cwd=root)
    assert "deprecat" not in build_log.lower(), build_log  # e.g. setuptools on the license field
    (wheel,) = (root / "dist").glob("dcm-*.whl")
    venv = root / "venv"
    _run([sys.executable, "-m", "venv", "--without-pip", str(venv)], cwd=root)
    python = venv / "bin" / "python"
    install_log = _run([*pip, "--python", str(python), "install", "--no-deps", "--no-index", str(wheel)], cwd=root)
    assert "deprecat" not in install_log.lower(), install_log
    purelib = _run([str(python), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"], cwd=root).strip()
    # After the wheel's own site-packages: this environment's dependencies, but not its editable dcm (a plain
    # path entry; the editable install's finder lives in a .pth file that only a site directory runs).
    (Path(purelib) / "zz_dependencies.pth").write_text(sysconfig.get_paths()["purelib"] + "\n")
    return venv / "bin"


def test_wheel_carries_the_shipped_files(wheel_env: Path, tmp_path: Path) -> None:
    code = ("import dcm, dcm.configs, dcm.shipped as s; print(dcm.__file__); print(dcm.configs.CONF_DIR); "
            "print(s.shipped_path('models/dcm_diverse_contact_one_step.ckpt')); "
            "print(s.shipped_path('data/waypoints/example.csv')); print(s.work_root())")
    package, conf, model, waypoints, work = _run([str(wheel_env / "python"), "-c", code], cwd=tmp_path).split()
    venv = wheel_env.parent
    assert Path(package).is_relative_to(venv), package  # the wheel's dcm, not the editable one of the checkout
    assert Path(conf).is_relative_to(venv) and (Path(conf) / "bowl" / "medium.yaml").is_file()
    assert Path(model).is_relative_to(venv) and Path(model).is_file()
    assert Path(waypoints).is_relative_to(venv) and Path(waypoints).is_file()
    assert Path(work) == tmp_path.resolve()  # default outputs: the working directory
    # A user's own file of a shipped name is theirs: it is never swapped for the shipped copy.
    (tmp_path / "data" / "waypoints").mkdir(parents=True)
    (tmp_path / "data" / "waypoints" / "example.csv").write_text("t,x,y,press\n0,0,0,0.01\n1,0.01,0,0.01\n")
    own = _run([str(wheel_env / "python"), "-c", code], cwd=tmp_path).split()[3]
    assert own == "data/waypoints/example.csv"


def test_wheel_runs_the_quickstart_from_a_temporary_directory(wheel_env: Path, tmp_path: Path) -> None:
    env = {**os.environ, "MUJOCO_GL": os.environ.get("MUJOCO_GL", "egl"), "OMP_NUM_THREADS": "1"}
    out = _run([str(wheel_env / "dcm-tune"), "--config-name", "quickstart", "robot_free.n_trials=20",
                "robot_free.batch_size=10", "robot_free.n_validate=1", "robot_based.n_trials=11"],
               cwd=tmp_path, env=env, timeout=300)
    (results,) = (tmp_path / "outputs" / "demo").glob("*/results.json")  # the run wrote to the working directory
    data = json.loads(results.read_text())
    assert data["robot_free"]["n_virtual_trials"] == 20
    assert data["robot_based"]["hypervolume"] is not None
    # the shipped one-step model, found as package data
    assert Path(data["checkpoint"]).is_relative_to(wheel_env.parent), data["checkpoint"]
    assert "deprecat" not in out.lower(), out


def test_source_tree_resolves_only_shipped_files(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """In a clone, from another directory: a shipped name is the tree's file; a data file or an output is not."""
    from dcm.shipped import INSTALLED, SHIPPED_ROOT, shipped_path, work_root

    assert not INSTALLED and SHIPPED_ROOT == REPO and work_root() == REPO
    monkeypatch.chdir(tmp_path)
    assert shipped_path("models/dcm_diverse_contact.ckpt") == str(REPO / "models" / "dcm_diverse_contact.ckpt")
    assert shipped_path("./data/demos/line.yaml") == str(REPO / "data" / "demos" / "line.yaml")
    for given in ("models/none.ckpt", "data/diverse_contact.h5", "outputs/x/results.json", "pyproject.toml"):
        assert shipped_path(given) == given
