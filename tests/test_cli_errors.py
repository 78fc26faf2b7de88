"""Every command ends a refused input with one ``error: ...`` line, whatever line breaks its message holds."""

from __future__ import annotations

import pytest

from dcm.console import error_line, print_error


def test_a_message_over_several_lines_is_printed_as_one(capsys: pytest.CaptureFixture[str]) -> None:
    err = ValueError("logs/ep_000/meta.json: key 'split'\n  must be one of train, valid, test;\tgot 'tran'")
    assert print_error(err) == 1
    out, printed = capsys.readouterr()
    assert out == ""
    assert printed == "error: logs/ep_000/meta.json: key 'split' must be one of train, valid, test; got 'tran'\n"


def test_the_line_keeps_what_it_names() -> None:
    assert error_line("--seed -1: must be an integer >= 0") == "error: --seed -1: must be an integer >= 0"
