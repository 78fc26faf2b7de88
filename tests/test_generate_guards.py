"""dcm.data.generate never silently overwrites, mixes, leaves orphans or accepts nonsense (tiny scale)."""

from __future__ import annotations

import hashlib
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import h5py
import numpy as np
import pytest

from dcm.data.generate import GenerationError, compose_config, generate

REPO = Path(__file__).resolve().parents[1]
# one wavelike demo x 2 trials of the tool embodiment: about a second
SMALL = ["workers=1", "progress=false", "skills=[wavelike]", "n_trials=2"]


def _cli(args: list[str], tmp_path: Path, **kwargs) -> subprocess.Popen:
    env = {**os.environ, "MUJOCO_GL": "egl", "PYTHONWARNINGS": "ignore"}
    return subprocess.Popen([sys.executable, "-m", "dcm.data.generate", "dataset=tiny",
                             f"hydra.run.dir={tmp_path / 'hydra'}", *args], cwd=REPO, env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, **kwargs)


def _run_cli(args: list[str], tmp_path: Path) -> subprocess.CompletedProcess:
    proc = _cli(args, tmp_path)
    stdout, stderr = proc.communicate(timeout=300)
    return subprocess.CompletedProcess(proc.args, proc.returncode, stdout, stderr)


def _one_error_line(proc: subprocess.CompletedProcess) -> str:
    """A user error: exit code 2 and a single ``error: ...`` line on stderr, no traceback."""
    assert proc.returncode == 2, (proc.returncode, proc.stderr[-2000:])
    assert "Traceback" not in proc.stderr, proc.stderr[-2000:]
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: "), proc.stderr
    return lines[0]


def _digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _arrays_and_masks(path: Path) -> dict[str, bytes]:
    """Every array of the file as (dtype, shape, raw bytes): what 'same bytes' means."""
    out: dict[str, bytes] = {}
    with h5py.File(path, "r") as f:
        def visit(name: str, node) -> None:
            if isinstance(node, h5py.Dataset):
                value = node[()]
                out[name] = f"{value.dtype}{value.shape}".encode() + np.ascontiguousarray(value).tobytes()
        f.visititems(visit)
    return out


# ----------------------------------------------------------------------------------------------- 3, 4: inputs
@pytest.mark.parametrize("overrides, message", [
    (["stiffness.max_Npm=1e6"], "stiffness.max_Npm = 1e+06 is above the controller's limit 3000 N/m"),
    (["stiffness.min_Npm=5"], "stiffness.min_Npm = 5 is below the controller's limit 10 N/m"),
    (["stiffness.min_Npm=2000"], "stiffness.min_Npm = 2000 must be below stiffness.max_Npm = 1500"),
    (["stiffness.rot_Nmprad=1000"], "stiffness.rot_Nmprad = 1000 is above the controller's limit 300"),
    (["stiffness.n_phases=0"], "stiffness.n_phases = 0 must be an integer >= 1"),
    (["stiffness.n_phases=41"], "cannot split a horizon of 40 steps into n_phases=41"),
    (["stiffness.phases=other"], "phase method 'other' is unknown"),
    (["stiffness.damping=none"], "stiffness.damping = 'none'"),
    (["search.name=grid"], "unknown search strategy 'grid'"),
    (["n_trials=0"], "n_trials = 0 must be an integer >= 1"),
    (["n_trials=-3"], "n_trials = -3 must be an integer >= 1"),
    (["n_trials=2.5"], "n_trials = 2.5 must be an integer >= 1"),
    (["workers=0"], "workers = 0 must be an integer >= 1"),
    (["seed=-1"], "seed = -1 must be an integer >= 0"),
    (["control_hz=0"], "control_hz = 0 is outside the simulator's range"),
    (["shard.count=2", "shard.index=2"], "shard.index = 2 must be in [0, shard.count = 2)"),
    (["dataset.valid_fraction=1.5"], "dataset.valid_fraction = 1.5 must be in [0, 1)"),
    (["demo.waypoints=data/waypoints/example.csv", "demo.n_trials=0"], "demo.n_trials = 0 must be an integer >= 1"),
    (["demo.waypoints=data/waypoints/example.csv", "demo.split=tset"], "demo.split = 'tset'"),
    (["dataset.duration_s=abc"], "dataset.duration_s = 'abc' must be a duration in seconds > 0 (or null with "
                                 "demo.waypoints=<file>: the file's own timing)"),
    (["demo.waypoints=data/waypoints/example.csv", "dataset.duration_s=-1"], "dataset.duration_s = -1 must be"),
    (["dataset.duration_s=true"], "dataset.duration_s = True must be"),
    (["dataset.duration_s=null"], "dataset.duration_s = null keeps a waypoint file's own timing, but this run has "
                                  "no demo.waypoints=<file>"),
])
def test_settings_are_checked_before_any_work(tmp_path: Path, overrides: list[str], message: str) -> None:
    out = tmp_path / "x.h5"
    started = time.perf_counter()
    with pytest.raises(GenerationError) as info:
        generate(compose_config("tiny", [f"out={out}", "workers=1", "progress=false", *overrides]))
    assert message in str(info.value)
    assert time.perf_counter() - started < 30  # no simulation ran
    assert list(tmp_path.iterdir()) == []  # neither the file nor a part folder


def test_a_run_prints_its_result_on_stdout_and_nothing_else(tmp_path: Path) -> None:
    env = {k: v for k, v in os.environ.items() if k != "PYTHONWARNINGS"}
    out = tmp_path / "d.h5"
    proc = subprocess.run([sys.executable, "-m", "dcm.data.generate", "dataset=tiny", f"hydra.run.dir={tmp_path / 'h'}",
                           f"out={out}", *SMALL], cwd=REPO, env={**env, "MUJOCO_GL": "egl"}, capture_output=True,
                          text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert proc.stderr == ""  # no library or deprecation chatter
    assert len(proc.stdout.splitlines()) == 1 and proc.stdout.startswith(f"wrote {out}: 2 trajectories")


def test_bad_waypoint_file_fails_in_one_line_and_leaves_nothing(tmp_path: Path) -> None:
    csv = tmp_path / "path.csv"
    csv.write_text("t,x,y,press\n0,0,0,0.01\n1,0.01,0,abc\n")
    out = tmp_path / "mine.h5"
    line = _one_error_line(_run_cli([f"demo.waypoints={csv}", f"out={out}", "workers=1", "progress=false"], tmp_path))
    assert f"{csv}, row 3, column press: 'abc' is not a number" in line
    assert not out.exists() and not (tmp_path / "mine.h5.parts").exists()


def test_a_failed_run_leaves_no_empty_part_folder(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    from dcm.data import generate_workers

    def broken(self, job, job_fingerprint, on_trial=lambda: None):
        raise RuntimeError("simulator exploded")

    monkeypatch.setattr(generate_workers.DemoRunner, "run", broken)
    with pytest.raises(GenerationError, match="simulator exploded"):
        generate(compose_config("tiny", [f"out={tmp_path / 'x.h5'}", *SMALL]))
    assert list(tmp_path.iterdir()) == []


# ----------------------------------------------------------------------------------------------- 1: overwrite
def test_an_existing_dataset_is_kept_or_refused_unless_overwrite(tmp_path: Path) -> None:
    out = tmp_path / "d.h5"
    first = _run_cli([f"out={out}", *SMALL], tmp_path)
    assert first.returncode == 0, first.stderr[-2000:]
    digest, mtime = _digest(out), out.stat().st_mtime_ns

    again = _run_cli([f"out={out}", *SMALL, "workers=2"], tmp_path)  # workers do not change the data
    assert again.returncode == 0, again.stderr[-2000:]
    assert "already holds this configuration's dataset" in again.stderr and "nothing to do" in again.stderr
    assert out.stat().st_mtime_ns == mtime and _digest(out) == digest

    line = _one_error_line(_run_cli([f"out={out}", *SMALL, "seed=3"], tmp_path))
    assert str(out) in line and "seed: 0 -> 3" in line and "overwrite=true" in line
    assert out.stat().st_mtime_ns == mtime and _digest(out) == digest
    assert not (tmp_path / "d.h5.parts").exists()

    replaced = _run_cli([f"out={out}", *SMALL, "seed=3", "overwrite=true"], tmp_path)
    assert replaced.returncode == 0, replaced.stderr[-2000:]
    with h5py.File(out, "r") as f:
        assert int(f.attrs["seed"]) == 3


def test_a_file_not_made_by_generate_is_refused(tmp_path: Path) -> None:
    out = tmp_path / "d.h5"
    out.write_text("my notes, not a dataset")
    with pytest.raises(GenerationError, match=r"d.h5 exists and is not a readable dcm dataset.*overwrite=true"):
        generate(compose_config("tiny", [f"out={out}", *SMALL]))
    assert out.read_text() == "my notes, not a dataset"


def test_parts_of_another_configuration_are_refused(tmp_path: Path) -> None:
    out = tmp_path / "p.h5"
    parts = tmp_path / "p.h5.parts"
    generate(compose_config("tiny", [f"out={out}", *SMALL, "keep_parts=true"]))
    out.unlink()  # as if the run was killed before writing the final file
    before = {p.name: _digest(p) for p in parts.glob("demo_*.npz")}
    assert before

    with pytest.raises(GenerationError) as info:
        generate(compose_config("tiny", [f"out={out}", *SMALL, "seed=3"]))
    assert f"part folder {parts} holds demos generated with different settings (seed: 0 -> 3)" in str(info.value)
    assert {p.name: _digest(p) for p in parts.glob("demo_*.npz")} == before and not out.exists()

    (parts / "plan.json").unlink()  # parts written without the folder's plan file: each part's fingerprint decides
    with pytest.raises(GenerationError, match=r"demo_00004.npz was generated with different settings"):
        generate(compose_config("tiny", [f"out={out}", *SMALL, "seed=3"]))

    generate(compose_config("tiny", [f"out={out}", *SMALL, "seed=3", "overwrite=true"]))
    with h5py.File(out, "r") as f:
        assert int(f.attrs["seed"]) == 3
    assert not parts.exists()


# ----------------------------------------------------------------------------------------------- 6: same bytes
def test_same_seed_gives_the_same_bytes(tmp_path: Path) -> None:
    a = generate(compose_config("tiny", [f"out={tmp_path / 'a.h5'}", *SMALL, "seed=7"]))
    b = generate(compose_config("tiny", [f"out={tmp_path / 'b.h5'}", *SMALL, "seed=7"]))
    c = generate(compose_config("tiny", [f"out={tmp_path / 'c.h5'}", *SMALL, "seed=8"]))
    arrays_a, arrays_b = _arrays_and_masks(a), _arrays_and_masks(b)
    assert sorted(arrays_a) == sorted(arrays_b)
    assert [k for k in arrays_a if arrays_a[k] != arrays_b[k]] == []
    arrays_c = _arrays_and_masks(c)
    stiffness = [k for k in arrays_a if k.endswith("/K")]
    assert stiffness and all(arrays_c[k] != arrays_a[k] for k in stiffness)  # the seed does matter


# ----------------------------------------------------------------------------------------------- 2: orphans
def _children(pid: int) -> list[int]:
    found = []
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            stat = (entry / "stat").read_text()
        except OSError:
            continue
        if int(stat[stat.rindex(")") + 2:].split()[1]) == pid:
            found.append(int(entry.name))
    return found


def _alive(pid: int) -> bool:
    """Running (a zombie no init reaps counts as gone)."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return False
    return stat[stat.rindex(")") + 2] not in "ZX"


def _is_pool_worker(pid: int) -> bool:
    try:
        return b"spawn_main" in Path(f"/proc/{pid}/cmdline").read_bytes()
    except OSError:
        return False


@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="needs /proc")
def test_workers_die_with_a_killed_parent(tmp_path: Path) -> None:
    # 4 demos x 300 trials keep both workers busy for well over the few seconds this test needs
    proc = _cli([f"out={tmp_path / 'o.h5'}", "workers=2", "progress=false", "skills=[spiral]", "n_trials=300"],
                tmp_path, start_new_session=True)
    workers: list[int] = []
    try:
        deadline = time.monotonic() + 120
        while len(workers) < 2:
            assert proc.poll() is None, proc.communicate()[1][-2000:]
            assert time.monotonic() < deadline, "the two workers did not start within 120 s"
            workers = [pid for pid in _children(proc.pid) if _is_pool_worker(pid)]
            time.sleep(0.1)
        time.sleep(2.0)  # let them get into their demos
        assert all(_alive(pid) for pid in workers)
        os.kill(proc.pid, signal.SIGKILL)  # the parent only, as a crash or the OOM killer would
        proc.wait()
        deadline = time.monotonic() + 5
        while any(_alive(pid) for pid in workers) and time.monotonic() < deadline:
            time.sleep(0.05)
        assert [pid for pid in workers if _alive(pid)] == [], "workers outlived their parent"
    finally:
        for pid in [proc.pid, *workers]:
            if _alive(pid):
                os.kill(pid, signal.SIGKILL)
        proc.communicate()


def test_demo_lead_reaches_every_spec_only_when_set() -> None:
    from dcm.data.presets import PresetError, plan_demos

    preset = {"name": "p", "skills": [{"name": "spiral", "split": "train", "n_trials": 2,
                                       "spec": {"family": "spiral", "press_m": 0.01}}]}
    assert "lead" not in plan_demos(preset, 0)[0].spec
    assert plan_demos({**preset, "demo_lead": True}, 0)[0].spec["lead"] is True
    with pytest.raises(PresetError, match="demo_lead = 'yes'"):
        plan_demos({**preset, "demo_lead": "yes"}, 0)


def test_demo_hover_reaches_every_spec_only_when_set_and_names_the_recording() -> None:
    """demo_hover_m: 0 starts every approach resting on the bowl (no touch-down impact); tune.py then names
    the override that records a new skill the same way."""
    from dcm.data.presets import PresetError, plan_demos
    from dcm.data.recording import recording
    from dcm.sim.demos import DemoSpec

    preset = {"name": "p", "skills": [{"name": "spiral", "split": "train", "n_trials": 2,
                                       "spec": {"family": "spiral", "press_m": 0.01}}]}
    assert "hover_m" not in plan_demos(preset, 0)[0].spec and recording(preset).hover_m is None
    resting = {**preset, "demo_hover_m": 0.0}
    spec = DemoSpec.from_dict(plan_demos(resting, 0)[0].spec)
    start = spec.start_pose(20.0)
    assert spec.hover_m == 0.0 and start[2] == pytest.approx(spec.bowl.height(*start[:2]))
    assert recording(resting).hover_m == 0.0 and "approaching from 0 m above the bowl" in recording(resting).describe()
    for bad in ("low", -0.01, 0.5):
        with pytest.raises(PresetError, match=f"demo_hover_m = {bad!r} must be a number in"):
            plan_demos({**preset, "demo_hover_m": bad}, 0)


# ----------------------------------------------------------------------------------------------- the waypoint demo
def _two_second_path(tmp_path: Path) -> Path:
    """A waypoint path of 40 steps at 20 Hz, as long as the tiny preset's demos, well inside its bowl."""
    csv = tmp_path / "path.csv"
    t = np.arange(40) * 0.05
    rows = [f"{ti:g},{0.03 * np.cos(ti):.5f},{0.03 * np.sin(ti):.5f},0.008" for ti in t]
    csv.write_text("t,x,y,press\n" + "\n".join(rows) + "\n")
    return csv


WAYPOINT_RUN = ["demo.n_trials=2", "workers=1", "progress=false"]


def test_the_waypoint_demo_is_recorded_as_the_presets_demos_are(tmp_path: Path) -> None:
    """The preset's demonstrator lead and hover reach the waypoint demo, so the file records what was recorded."""
    from dcm.data.recording import Recording, file_recording
    from dcm.data.schema import load_dataset

    out = tmp_path / "mine.h5"
    generate(compose_config("tiny", [f"demo.waypoints={_two_second_path(tmp_path)}", "+dataset.demo_lead=true",
                                     "+dataset.demo_hover_m=0.0", f"out={out}", *WAYPOINT_RUN]))
    loaded = load_dataset(out, split="train")
    assert loaded.horizon == 40 and len(loaded) == 2
    assert all(m["demo"].get("lead") is True and m["demo"]["hover_m"] == 0.0 for m in loaded.meta)
    assert file_recording(out) == Recording(2.0, True, 64, 0.0)


def test_a_null_duration_keeps_the_waypoint_files_own_timing(tmp_path: Path) -> None:
    """``dataset.duration_s=null`` records the file as it is, and the dataset stores the duration it was recorded
    at (so later checks read a number, not null)."""
    from dcm.data.recording import file_recording
    from dcm.data.schema import load_dataset

    out = tmp_path / "mine.h5"
    example = REPO / "data" / "waypoints" / "example.csv"  # 7.95 s: 160 steps at 20 Hz
    generate(compose_config("tiny", [f"demo.waypoints={example}", "dataset.duration_s=null", f"out={out}",
                                     "demo.n_trials=1", "workers=1", "progress=false"]))
    assert load_dataset(out, split="train").horizon == 160
    assert file_recording(out).duration_s == 8.0


def test_a_waypoint_demo_recorded_otherwise_than_the_preset_says_is_refused_by_name(tmp_path: Path) -> None:
    csv = _two_second_path(tmp_path)
    out = tmp_path / "mine.h5"
    example = REPO / "data" / "waypoints" / "example.csv"  # 7.95 s: 160 steps at 20 Hz
    with pytest.raises(GenerationError) as err:
        generate(compose_config("tiny", [f"demo.waypoints={example}", f"out={out}", *WAYPOINT_RUN]))
    assert str(err.value) == (f"dataset.duration_s = 2 s (dataset=tiny) does not apply to demo.waypoints={example}, "
                              "which sets its own timing (160 steps at 20 Hz); pass dataset.duration_s=8 (or null) "
                              "to record it as it is")
    with pytest.raises(GenerationError, match=r"^demo.bowl has a 112 x 112 heightfield grid, but dataset=tiny records "
                                              r"its demos on a 64 x 64 grid \(dataset.bowl.hfield_res\)"):
        generate(compose_config("tiny", [f"demo.waypoints={csv}", "demo.bowl=large", f"out={out}", *WAYPOINT_RUN]))
    with pytest.raises(GenerationError, match=r"^demo.lead = True: the waypoint demo is recorded as the preset's "
                                              r"demos are; set dataset.demo_lead instead"):
        generate(compose_config("tiny", [f"demo.waypoints={csv}", "+demo.lead=true", f"out={out}", *WAYPOINT_RUN]))
    with pytest.raises(GenerationError, match=r"^demo.color = 'red': not a setting of the waypoint demo"):
        generate(compose_config("tiny", [f"demo.waypoints={csv}", "+demo.color=red", f"out={out}", *WAYPOINT_RUN]))
    assert not out.exists() and not (tmp_path / "mine.h5.parts").exists()
