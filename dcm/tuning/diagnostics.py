"""What a tune run reports while it runs, besides refusing a setting (:mod:`dcm.tuning.checks`): a demo recorded
otherwise than the predictor's training demos (with the overrides that record it so), samples that barely
spread, model inputs outside the training range, and a prediction error beyond the card's valid error.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np


class DemoRecordingWarning(UserWarning):
    """The new skill's demo is recorded otherwise than the predictor's training demos."""


def recording_mismatch(ckpt: Any, spec: Any, control_hz: float = 20.0) -> str | None:
    """Why the skill's demo (a DemoSpec) is not recorded as the predictor's training demos were; None if it
    is, or if the predictor does not say how its demos were recorded. F_demo and x_demo are model inputs, so another
    duration or demonstrator is an input the model never saw, and its ranking can drop. A waypoint file sets
    its own duration: it matches when it gives the training demos' step count at ``control_hz``."""
    from dcm.data.recording import Recording
    from dcm.models.predict import trained_on, trained_recording
    from dcm.sim.demos import waypoint_span_s

    trained = trained_recording(ckpt)
    if trained is None:
        return None
    fixes = []
    if spec.family == "waypoints":
        trained_horizon = round(trained.duration_s * control_hz)
        if spec.horizon(control_hz) != trained_horizon:
            fixes.append(f"retime {spec.waypoints} to span {waypoint_span_s(trained_horizon, control_hz):g} s "
                         f"({trained_horizon} steps at {control_hz:g} Hz, the last row at step {trained_horizon - 1})")
    elif float(spec.duration_s) != trained.duration_s:
        fixes.append(f"demo.duration_s={trained.duration_s:g}")
    if bool(spec.lead) != trained.lead:
        fixes.append(f"++demo.lead={str(trained.lead).lower()}")
    grid = int(spec.bowl.hfield_res)
    if trained.bowl_grid is not None and grid != trained.bowl_grid:
        name = {"name": f"{spec.bowl.name}_{trained.bowl_grid}"} if spec.bowl.name else {}
        fixes.append(bowl_override(spec.bowl, hfield_res=trained.bowl_grid, **name))
    if trained.hover_m is not None and float(spec.hover_m) != trained.hover_m:
        fixes.append(f"++demo.hover_m={trained.hover_m:g}")
    if not fixes:
        return None
    here = Recording(float(spec.duration_s), bool(spec.lead), None if trained.bowl_grid is None else grid,
                     None if trained.hover_m is None else float(spec.hover_m))
    return (f"ckpt={ckpt} learned from {trained.describe()} (dataset {trained_on(ckpt)}); this skill's demo: "
            f"{here.describe()}. To record it as the model's training demos were: {' '.join(fixes)} "
            "(or those fields of demo_file)")


def bowl_override(bowl: Any, **changes: Any) -> str:
    """The command-line override that gives the skill ``bowl`` (a BowlSpec) with ``changes``: the fields that
    differ from BowlSpec's defaults, as one inline mapping (a bowl preset name cannot take a field override)."""
    from dcm.sim.geometry import BowlSpec

    default = BowlSpec().to_dict()
    fields = {k: v for k, v in {**bowl.to_dict(), **changes}.items() if v != default[k] or k in changes}
    plain = lambda v: "[" + ",".join(f"{x:g}" for x in v) + "]" if isinstance(v, list) else (  # noqa: E731
        f"{v:g}" if isinstance(v, float) else str(v))
    return "'demo.bowl={" + ",".join(f"{k}:{plain(v)}" for k, v in fields.items()) + "}'"



class SampleSpreadWarning(UserWarning):
    """The samples of one prediction branch only where the net sees an almost clean force, so they barely differ
    and a loss over them ranks by about the mean alone."""


def spread_warning(sampler: str | None, n_samples: int, task_loss: str | None) -> str | None:
    """Why ``task_loss=over_samples`` will see little spread under ``sampler``; None where it will not.
    ddim_even's last step is at t = 0, where the samples of a proposal converge; ddim's last step, at t = T/n - 1,
    keeps their spread."""
    if sampler != "ddim_even" or n_samples <= 1 or task_loss != "over_samples":
        return None
    return ("robot_free.sampler=ddim_even ends its chain at t = 0, where the robot_free.n_samples barely differ; "
            "robot_free.sampler=ddim robot_free.sampling_steps=3 keeps the spread task_loss=over_samples ranks by")


class ConditioningRangeWarning(UserWarning):
    """A model input of this skill lies far outside the range the model was trained on: its predictions there
    are extrapolations."""


class PredictionErrorWarning(UserWarning):
    """The model's L_task on the validated solutions is much further from the simulator's than on its valid
    split: its ranking of this skill's schedules is likely off."""


# Inputs are judged in the model's normalised units, where the normaliser's training range is [-1, 1]: warn
# beyond this many half-widths from its centre (past the range by half its width; zscore: 6 std from the mean).
CONDITIONING_LIMIT = 2.0
# The validated solutions' mean |predicted - realised| L_task may reach this multiple of the model's valid
# error (its card's evaluation on the valid split) ...
PREDICTION_ERROR_FACTOR = 3.0
# ... or, without one (a training checkpoint, a stiffness reference, a blend with a prior), this many newtons.
PREDICTION_TOLERANCE_N = 0.3
_UNITS = {"m": "m", "rad": "rad", "N": "N", "Nm": "N·m", "Npm": "N/m", "Nmprad": "N·m/rad"}


def _force_model(model: Any) -> Any:
    """The force model behind a predictor (a blend's model), or None for one without an input range."""
    inner = getattr(model, "model", model)  # PriorBlend keeps the force model as .model
    return inner if hasattr(inner, "input_range") and hasattr(inner, "cfg") else None


def conditioning_check(model: Any, inputs: tuple[np.ndarray, ...], stiffness_Npm: list[float]) -> dict[str, Any]:
    """Where this skill's model inputs leave the model's training range, channel by channel.

    ``inputs``: the raw (x_demo, F_demo, x_attr, K), each (B, H, 6), of the B constant schedules at
    ``stiffness_Npm`` (the search space's softest and stiffest), so the attractor is judged over the space's
    stiffness range. Returns what ``results.json`` records; the range is the one the model's input normaliser
    stores (``minmax``: the train split's min..max; ``zscore``: its mean ± 3 std).
    """
    from dcm.data.schema import cond_channel_names, cond_slice

    force_model = _force_model(model)
    if force_model is None:
        return {"checked": False, "why": "the predictor has no input normaliser (a stiffness reference)"}
    encoding = force_model.cfg.cond_encoding
    encoded, low, high = force_model.input_range(np.concatenate(inputs, axis=-1))  # (B, H, 24)
    center, half = (low + high) / 2, (high - low) / 2
    normalised = (encoded - center) / half
    x_attr, k = cond_slice("x_attr"), cond_slice("K")
    outside = []
    for c, name in enumerate(cond_channel_names()):
        b, t = np.unravel_index(np.argmax(np.abs(normalised[..., c])), normalised.shape[:2])
        z = float(normalised[b, t, c])
        if abs(z) <= CONDITIONING_LIMIT:
            continue
        value, lo, hi, shown = float(encoded[b, t, c]), float(low[c]), float(high[c]), name
        if encoding == "physical" and k.start <= c < k.stop:  # the net reads log K: show it in N/m
            value, lo, hi = (float(np.exp(v)) for v in (value, lo, hi))
        elif encoding == "physical" and x_attr.start <= c < x_attr.stop:  # the net reads x_attr - x_demo
            shown = f"{name} - x_demo.{name.split('.', 1)[1]}"
        depends = x_attr.start <= c < x_attr.stop or k.start <= c < k.stop
        outside.append({"channel": shown, "value": value, "unit": _UNITS[name.rsplit("_", 1)[1]],
                        "training_low": lo, "training_high": hi, "normalised": z,
                        "stiffness_Npm": float(stiffness_Npm[b]) if depends else None})
    return {"checked": True, "normalization": force_model.cfg.normalization, "cond_encoding": encoding,
            "limit": CONDITIONING_LIMIT, "in_range": not outside, "outside": outside}


def conditioning_warnings(conditioning: dict[str, Any]) -> list[str]:
    """One line per channel :func:`conditioning_check` found outside, naming it and how far out it lies."""
    lines = []
    for c in conditioning.get("outside", []):
        unit, at = c["unit"], "" if c["stiffness_Npm"] is None else f" at stiffness {c['stiffness_Npm']:g} N/m"
        lines.append(f"{c['channel']}: {c['value']:.3g} {unit}{at} lies outside the training range "
                     f"[{c['training_low']:.3g}, {c['training_high']:.3g}] {unit}, {abs(c['normalised']):.3g}x the "
                     f"range's half-width from its centre (warned above {conditioning['limit']:g}x); the model's "
                     "predictions there are extrapolations")
    return lines


def prediction_limit(ckpt: Any, prior: Any) -> dict[str, Any]:
    """How far the validated solutions' predicted L_task may be from the realised one before the run warns:
    ``PREDICTION_ERROR_FACTOR`` x the valid-split L_task error the checkpoint's card records for its own
    dataset, else ``PREDICTION_TOLERANCE_N`` (and always with a prior: the blend is not what the card scored)."""
    from dcm.models.checkpoint import checkpoint_card

    card: dict[str, Any] = {}
    if not prior and str(ckpt).lower().endswith(".ckpt"):
        try:
            card = checkpoint_card(ckpt) or {}
        except ValueError:
            card = {}
    trained_on = Path(str((card.get("dataset") or {}).get("path") or "")).name
    for key, evaluation in (card.get("evaluations") or {}).items():
        if not isinstance(evaluation, dict) or evaluation.get("split") != "valid" or not trained_on:
            continue
        error = evaluation.get("L_task_mae_N")
        if Path(str(evaluation.get("dataset", ""))).name == trained_on and isinstance(error, (int, float)) and \
                math.isfinite(error) and error > 0:
            return {"limit_N": PREDICTION_ERROR_FACTOR * float(error), "valid_L_task_mae_N": float(error),
                    "factor": PREDICTION_ERROR_FACTOR, "limit_source": f"{PREDICTION_ERROR_FACTOR:g} x the valid "
                    f"L_task error in the checkpoint's card ({key})"}
    return {"limit_N": PREDICTION_TOLERANCE_N, "valid_L_task_mae_N": None, "factor": None,
            "limit_source": "absolute tolerance"}


def prediction_check(predicted: np.ndarray, realised: np.ndarray, limit: dict[str, Any]) -> dict[str, Any]:
    """Predicted against realised L_task [N] of the validated solutions (failed rollouts left out), for
    ``results.json``: their mean absolute difference and whether it exceeds ``limit``."""
    keep = np.isfinite(predicted) & np.isfinite(realised)
    error = float(np.mean(np.abs(predicted[keep] - realised[keep]))) if keep.any() else None
    return {"predicted_L_task_N": predicted[keep].tolist(), "realised_L_task_N": realised[keep].tolist(),
            "L_task_mae_N": error, "n_solutions": int(keep.sum()), **limit,
            "exceeded": error is not None and error > limit["limit_N"]}


__all__ = ["CONDITIONING_LIMIT", "ConditioningRangeWarning", "DemoRecordingWarning", "PREDICTION_ERROR_FACTOR",
           "PREDICTION_TOLERANCE_N", "PredictionErrorWarning", "SampleSpreadWarning", "bowl_override",
           "conditioning_check", "conditioning_warnings", "prediction_check", "prediction_limit",
           "recording_mismatch", "spread_warning"]
