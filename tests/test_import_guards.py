"""python -m dcm.data.import_logs: a malformed meta.json is one line naming the file, line and column."""

from __future__ import annotations

import os
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

    from dcm.cli import QUIET_LOGGERS
    from dcm.data.import_logs import main

    write_episode(tmp_path / "logs", "episode_0", np.random.default_rng(0))
    for name in QUIET_LOGGERS:
        logging.getLogger(name).setLevel(logging.NOTSET)
    assert main([str(tmp_path / "logs"), "--out", str(tmp_path / "real.h5")]) == 0
    assert all(logging.getLogger(name).level == logging.WARNING for name in QUIET_LOGGERS)
