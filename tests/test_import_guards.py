"""python -m dcm.data.import_logs: a malformed meta.json, a bad meta.json value or a bad option is one line
naming the file (and line and column, or key and value) or the option."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

from dcm.data.import_logs import LogFormatError, import_logs

REPO = Path(__file__).resolve().parents[1]


def test_malformed_meta_json_is_one_line(tmp_path: Path) -> None:
    episode = tmp_path / "logs" / "ep000"
    episode.mkdir(parents=True)
    meta = episode / "meta.json"
    meta.write_text('{\n  "demo_id": 0,\n  "split": "train"\n  "base_frame": "panda_link0"\n}\n')
    out = tmp_path / "real.h5"
    proc = subprocess.run([sys.executable, "-m", "dcm.data.import_logs", str(tmp_path / "logs"), "--out", str(out)],
                          cwd=REPO, capture_output=True, text=True, timeout=120,
                          env=dict(os.environ, PYTHONWARNINGS="ignore"))
    assert proc.returncode == 1
    assert proc.stderr.strip() == f"error: {meta}, line 4, column 3: invalid JSON (Expecting ',' delimiter)"
    assert not out.exists()


def test_meta_json_must_be_an_object(tmp_path: Path) -> None:
    episode = tmp_path / "logs" / "ep000"
    episode.mkdir(parents=True)
    (episode / "meta.json").write_text("[1, 2]")
    with pytest.raises(LogFormatError, match=r"meta.json: expected a JSON object \{...\}, got list"):
        import_logs(tmp_path / "logs", tmp_path / "real.h5")


def test_an_existing_out_is_refused_unless_overwrite(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """As dcm.data.generate: an existing file is replaced only when asked, and a refusal loses nothing."""
    import numpy as np
    from test_data_import import write_episode

    from dcm.data.import_logs import main
    from dcm.data.schema import load_dataset

    write_episode(tmp_path / "logs", "episode_0", np.random.default_rng(0))
    out = tmp_path / "real.h5"
    out.write_bytes(b"an earlier import")
    assert main([str(tmp_path / "logs"), "--out", str(out)]) == 1
    captured = capsys.readouterr()
    assert captured.out == ""
    assert captured.err == f"error: {out} exists; pass --overwrite to replace it, or choose another --out\n"
    assert out.read_bytes() == b"an earlier import"
    with pytest.raises(FileExistsError, match="overwrite=True"):
        import_logs(tmp_path / "logs", out)
    assert main([str(tmp_path / "logs"), "--out", str(out), "--overwrite"]) == 0
    assert len(load_dataset(out, split="train")) == 1


def test_library_chatter_is_hushed(tmp_path: Path) -> None:
    import logging

    import numpy as np
    from test_data_import import write_episode

    from dcm.console import QUIET_LOGGERS
    from dcm.data.import_logs import main

    write_episode(tmp_path / "logs", "episode_0", np.random.default_rng(0))
    for name in QUIET_LOGGERS:
        logging.getLogger(name).setLevel(logging.NOTSET)
    assert main([str(tmp_path / "logs"), "--out", str(tmp_path / "real.h5")]) == 0
    assert all(logging.getLogger(name).level == logging.WARNING for name in QUIET_LOGGERS)



def _episode_with_meta(root: Path, remove: tuple[str, ...] = (), **changes: object) -> Path:
    """One synthetic episode under ``root/logs`` with ``changes`` set in its meta.json and ``remove`` dropped."""
    import json

    import numpy as np
    from test_data_import import write_episode

    write_episode(root / "logs", "episode_0", np.random.default_rng(0))
    meta_path = root / "logs" / "episode_0" / "meta.json"
    meta = json.loads(meta_path.read_text())
    meta.update(changes)
    for key in remove:
        meta.pop(key)
    meta_path.write_text(json.dumps(meta))
    return meta_path


@pytest.mark.parametrize(("key", "value", "shown"), [
    ("wrench_frame", "k", "'k'"), ("wrench_frame", "EE", "'EE'"), ("wrench_frame", "K_F_ext_hat_K", "'K_F_ext_hat_K'"),
    ("demo_id", "abc", "'abc'"), ("trial", None, "None"), ("free_motion_s", [0.0], "[0.0]"),
    ("free_motion_s", "0 0.9", "'0 0.9'"), ("tip_offset_m", [0, 0], "[0, 0]"), ("start_s", "x", "'x'"),
    ("split", "training", "'training'"), ("bowl_in_base", [[1, 0], [0, 1]], "[[1, 0], [0, 1]]"),
    ("demo", [1], "[1]"),
])
def test_a_bad_meta_value_is_one_line_naming_file_key_and_value(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], key: str, value: object, shown: str) -> None:
    """A misspelt wrench_frame used to read as the base frame (wrong forces, exit 0); the others were tracebacks."""
    from dcm.data.import_logs import main

    meta_path = _episode_with_meta(tmp_path, **{key: value})
    out = tmp_path / "real.h5"
    assert main([str(tmp_path / "logs"), "--out", str(out)]) == 1
    err = capsys.readouterr().err
    assert err.startswith(f"error: {meta_path}: {key} = {shown} must be ") and err.count("\n") == 1
    assert not out.exists()


def test_wrench_frame_base_is_the_default(tmp_path: Path) -> None:
    import numpy as np

    from dcm.data.schema import load_dataset

    _episode_with_meta(tmp_path / "named", wrench_frame="base")
    _episode_with_meta(tmp_path / "default")
    for name in ("named", "default"):
        import_logs(tmp_path / name / "logs", tmp_path / f"{name}.h5")
    named, default = (load_dataset(tmp_path / f"{name}.h5", split="train") for name in ("named", "default"))
    np.testing.assert_array_equal(named.arrays["F_obs"], default.arrays["F_obs"])


def test_a_meta_without_split_is_refused(tmp_path: Path) -> None:
    """docs/robot_logs.md: the splits are the ones each episode's meta.json names; there is no default."""
    meta_path = _episode_with_meta(tmp_path, remove=("split",))
    with pytest.raises(LogFormatError, match=rf"^{re.escape(str(meta_path))}: missing key 'split'$"):
        import_logs(tmp_path / "logs", tmp_path / "real.h5")


@pytest.mark.parametrize(("option", "value"), [
    ("--horizon", "0"), ("--horizon", "-5"), ("--control-hz", "0"), ("--control-hz", "-20"), ("--control-hz", "inf"),
    ("--lowpass-order", "0"), ("--lowpass-hz", "-1"), ("--lowpass-hz", "nan"), ("--contact-threshold-N", "nan"),
    ("--contact-threshold-N", "-1"),
])
def test_a_bad_numeric_option_is_one_line_naming_it(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], option: str, value: str) -> None:
    from dcm.data.import_logs import main

    _episode_with_meta(tmp_path)
    out = tmp_path / "real.h5"
    assert main([str(tmp_path / "logs"), "--out", str(out), option, value]) == 1
    err = capsys.readouterr().err
    assert err.startswith(f"error: {option} {value}") and "must be" in err and err.count("\n") == 1
    assert not out.exists()
