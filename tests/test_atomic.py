"""Atomic writes leave a complete file with ordinary permissions, or nothing."""

from __future__ import annotations

import os
import stat
from pathlib import Path

import pytest

from dcm.data.atomic import atomic_path


def _mode(path: Path) -> int:
    return stat.S_IMODE(path.stat().st_mode)


def test_a_new_file_gets_the_mode_of_a_plain_open_and_a_replaced_file_keeps_its_own(tmp_path: Path) -> None:
    mask = os.umask(0o027)
    try:
        with atomic_path(tmp_path / "new.json") as tmp:
            tmp.write_text("{}")
        assert _mode(tmp_path / "new.json") == 0o640  # not mkstemp's 0600
        (tmp_path / "new.json").chmod(0o604)
        with atomic_path(tmp_path / "new.json") as tmp:
            tmp.write_text("[]")
        assert _mode(tmp_path / "new.json") == 0o604 and (tmp_path / "new.json").read_text() == "[]"
    finally:
        os.umask(mask)


def test_a_failed_write_leaves_the_old_file_and_no_temporary(tmp_path: Path) -> None:
    target = tmp_path / "data.txt"
    target.write_text("old")
    with pytest.raises(RuntimeError):
        with atomic_path(target) as tmp:
            tmp.write_text("partial")
            raise RuntimeError("killed")
    assert target.read_text() == "old" and [p.name for p in tmp_path.iterdir()] == ["data.txt"]
