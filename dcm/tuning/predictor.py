"""The predictor of a tune run: the checkpoint (or stiffness reference) of ``ckpt``, checked against the skill and
set to sample as ``robot_free`` asks, for this process only (the checkpoint file is untouched)."""

from __future__ import annotations

import warnings
from typing import Any

from dcm.console import one_line
from dcm.tuning.checks import AUTO_SAMPLER, TuneConfigError, check_predictor
from dcm.tuning.diagnostics import DemoRecordingWarning, SampleSpreadWarning, recording_mismatch, spread_warning
from dcm.tuning.settings import as_settings


def use_sampler(model: Any, sampler: str | None = None, sampling_steps: int | None = None) -> bool:
    """Make a loaded DCM sample with ``sampler`` over ``sampling_steps`` denoising steps, in this process only
    (:meth:`dcm.models.dcm.DCM.set_sampler`; the checkpoint file is untouched): a run trades the full chain's
    accuracy for speed without a new checkpoint.

    ``sampler``: ``"ddpm"`` (ancestral), ``"ddim"`` or ``"ddim_even"`` (deterministic given the start noise;
    the latter's steps end at t = 0); None keeps the checkpoint's; ``"auto"`` keeps a one-step student's single
    step (:mod:`dcm.training.distill`) and runs any other DCM with ``"ddim"``. ``sampling_steps``: steps of the chain
    (ddim: must divide T); None keeps the checkpoint's
    when the sampler is unchanged, else T. Predictors that do not diffuse (baseline, stiffness reference) are
    left alone. Returns whether ``model`` was changed; raises :class:`TuneConfigError` naming
    ``robot_free.sampling_steps`` for a step count the sampler cannot run.
    """
    from dcm.models.dcm import DCM

    if not isinstance(model, DCM) or (sampler is None and sampling_steps is None):
        return False
    student = model.is_one_step_student
    if sampler == AUTO_SAMPLER:
        if student:
            return False
        sampler = "ddim"
    kind = model.cfg.sampler if sampler is None else sampler
    steps = sampling_steps
    if steps is None and kind == model.cfg.sampler:
        steps = model.cfg.sampling_steps
    try:
        model.set_sampler(kind, steps)
    except ValueError as err:
        hint = "robot_free.sampler=auto" if student else "robot_free.sampling_steps=null runs all T steps"
        raise TuneConfigError(f"robot_free.sampling_steps = {steps} with robot_free.sampler = {kind}: "
                              f"{one_line(err)} ({hint})") from None
    return True


def load_predictor(cfg: Any, spec: Any, device: Any) -> Any:
    """The predictor of ``cfg.ckpt`` as the robot-free search uses it: checked against the skill (warning when
    its demo is recorded otherwise than the predictor's training demos), with ``robot_free``'s sampler, sampling
    steps, precision and task loss, and blended with the stiffness ridge ``prior`` at ``prior_weight`` when one is
    given (:mod:`dcm.models.prior_blend`)."""
    from dcm.models.dcm import DCM
    from dcm.models.predict import load_model, with_prior

    cfg = as_settings(cfg)
    free = cfg.robot_free
    model = load_model(cfg.ckpt, map_location=device)
    check_predictor(model, cfg)
    if (mismatch := recording_mismatch(cfg.ckpt, spec, cfg.control_hz)) is not None:
        warnings.warn(mismatch, DemoRecordingWarning, stacklevel=3)
    use_sampler(model, free.sampler, free.sampling_steps)
    if free.precision is not None and hasattr(model, "set_precision"):  # force models
        try:
            model.set_precision(free.precision)
        except ValueError as err:
            raise TuneConfigError(f"robot_free.precision: {err}") from None
    if free.shared_steps is not None and hasattr(model, "set_shared_steps"):  # DCM only
        try:
            model.set_shared_steps(free.shared_steps)
        except ValueError as err:
            raise TuneConfigError(f"robot_free.shared_steps: {err}") from None
    if free.task_loss is not None and hasattr(model, "set_task_loss"):  # not the ridge
        model.set_task_loss(free.task_loss)
    if isinstance(model, DCM) and (why := spread_warning(
            model.cfg.sampler, int(free.n_samples), model.cfg.task_loss)) is not None:
        warnings.warn(why, SampleSpreadWarning, stacklevel=3)
    if cfg.prior:
        try:
            model = with_prior(model, cfg.prior, cfg.prior_weight, source=f"tune prior={cfg.prior}")
        except ValueError as err:
            raise TuneConfigError(str(err)) from None
        check_predictor(model, cfg)  # the prior's phases and L_task window
    return model


def inference_precision(model: Any) -> str | None:
    """The precision a force model's predictions run in (a blend's force model's); None for a predictor without
    a net (the stiffness reference)."""
    return getattr(getattr(model, "model", model), "inference_precision", None)


__all__ = ["inference_precision", "load_predictor", "use_sampler"]
