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


def test_a_config_group_option_that_does_not_exist_is_one_line_naming_the_options() -> None:
    from pathlib import Path

    from dcm.configs import group_choice_problem

    assert group_choice_problem(["objective=foo", "seed=1"]) == (
        "objective=foo: the objective group has no option 'foo'; expected one of paper, wipe")
    assert group_choice_problem(["objective=wipe", "objective.force_tolerance_N=2", "+domain.x=1",
                                 "dataset=tiny,sim", "hydra/launcher=joblib", "seed=3"]) is None
    studies = Path(__file__).resolve().parents[1] / "studies" / "conf"  # a --config-dir adds its presets
    assert group_choice_problem(["--config-dir", str(studies), "dataset=diverse_contact_fine"]) is None
    assert "dataset=diverse_contact_fine" in group_choice_problem(["dataset=diverse_contact_fine"])
