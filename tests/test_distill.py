"""dcm-distill: a one-step student of a DCM, its sampler rules, and a killed run that resumes to the same bytes."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

from dcm.models.checkpoint import checkpoint_card
from dcm.models.predict import load_model
from dcm.training import distill as distill_module
from dcm.training.distill import DistillError, DistillSettings, distill, main

FAST = DistillSettings(draws=2, teacher_steps=5, epochs=2, batch_size=8)


@pytest.fixture(scope="module")
def student(tiny_checkpoint: Path, tiny_dataset_path: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("student") / "student.ckpt"
    return distill(tiny_checkpoint, tiny_dataset_path, out, FAST, device="cpu", progress=False)


def test_the_student_samples_in_one_call_and_keeps_a_spread(student: Path, tiny_dataset_path: Path) -> None:
    model = load_model(student)
    assert (model.cfg.sampler, model.cfg.sampling_steps, model.cfg.input_scaling) == ("one_step", 1, "unit")
    assert not Path(str(student) + distill_module.WORK_SUFFIX).exists()
    card = checkpoint_card(student)
    assert card["distilled"]["teacher_steps"] == 5 and card["distilled"]["draws"] == 2
    (evaluation,) = card["evaluations"].values()
    assert evaluation["split"] == "valid" and evaluation["sampler"] == "one_step"
    assert evaluation["ckpt"] == str(student.resolve())

    calls = []
    model.inference_net.register_forward_hook(lambda module, args, out: calls.append(args[0].shape[0]))
    cond = torch.randn(3, 40, 24)
    gen = lambda: torch.Generator().manual_seed(0)  # noqa: E731
    mean, std = model.predict_normalized(cond, n_samples=4, generator=gen())
    assert calls == [12]  # 3 conditions x 4 samples, one net call
    assert float(std.mean()) > 0  # the samples differ: the noise reaches the net at unit scale
    again, _ = model.predict_normalized(cond, n_samples=4, generator=gen())
    assert torch.equal(mean, again)


def test_the_student_keeps_its_sampler(student: Path, tiny_checkpoint: Path) -> None:
    from dcm.tuning.checks import TuneConfigError
    from dcm.tuning.predictor import use_sampler

    model = load_model(student)
    with pytest.raises(ValueError, match="one-step student"):
        model.set_sampler("ddim", 5)
    assert use_sampler(model, "auto", 3) is False and model.cfg.sampling_steps == 1
    with pytest.raises(TuneConfigError, match=r"robot_free.sampler=auto"):
        use_sampler(model, "ddim", 3)
    with pytest.raises(ValueError, match="one-step student"):
        model.on_fit_start()  # train.py would retrain its net with the diffusion loss
    teacher = load_model(tiny_checkpoint)
    assert use_sampler(teacher, "auto", 5) and (teacher.cfg.sampler, teacher.cfg.sampling_steps) == ("ddim", 5)
    with pytest.raises(ValueError, match="needs a one-step student"):
        teacher.set_sampler("one_step")


def test_a_killed_distillation_resumes_to_the_same_weights(student: Path, tiny_checkpoint: Path,
                                                         tiny_dataset_path: Path, tmp_path: Path,
                                                         monkeypatch: pytest.MonkeyPatch) -> None:
    out = tmp_path / student.name
    out.parent.mkdir(exist_ok=True)
    save = distill_module._save

    def killed_after_one_epoch(obj, path):
        save(obj, path)
        if isinstance(obj, dict) and obj.get("epochs_done") == 1:
            raise KeyboardInterrupt

    monkeypatch.setattr(distill_module, "_save", killed_after_one_epoch)
    with pytest.raises(KeyboardInterrupt):
        distill(tiny_checkpoint, tiny_dataset_path, out, FAST, device="cpu", progress=False)
    monkeypatch.setattr(distill_module, "_save", save)
    with pytest.raises(DistillError, match="other settings"):
        distill(tiny_checkpoint, tiny_dataset_path, out, DistillSettings(draws=3, teacher_steps=5, epochs=2,
                                                                         batch_size=8), device="cpu", progress=False)
    # the same command again; the fixture's student was written to another folder, so compare the weights
    distill(tiny_checkpoint, tiny_dataset_path, out, FAST, device="cpu", progress=False)
    resumed, straight = (torch.load(p, weights_only=False)["state_dict"] for p in (out, student))
    assert resumed.keys() == straight.keys() and all(torch.equal(resumed[k], straight[k]) for k in resumed)


def test_bad_inputs_end_in_one_line(tiny_checkpoint: Path, tiny_dataset_path: Path, student: Path, tmp_path: Path,
                                    capsys: pytest.CaptureFixture[str]) -> None:
    base = [str(tiny_checkpoint), str(tiny_dataset_path), "--out", str(tmp_path / "s.ckpt"), "--no-progress"]
    for extra, expected in ((["--epochs", "0"], "--epochs must be an integer >= 1"),
                            (["--teacher-steps", "3"], "--teacher-steps")):
        assert main([*base, *extra]) != 0
        err = capsys.readouterr().err.strip()
        assert expected in err and len(err.splitlines()) == 1
    assert main([str(student), *base[1:]]) != 0
    assert "already a one-step student" in capsys.readouterr().err
    assert not (tmp_path / "s.ckpt").exists()
