"""Models: score networks (`dcm.models.nets`), the DDPM machinery (`dcm.models.diffusion`) and the
LightningModules built on them.

Kept import-light on purpose: importing `dcm.models` must not pull Lightning or data modules, so the
submodules can import each other without cycles. Import what you need from the submodules directly.
"""

from dcm.models.nets import SCORE_NETS, build_score_net

__all__ = ["SCORE_NETS", "build_score_net"]


def __getattr__(name: str):
    """Lazy access to the LightningModules (`from dcm.models import DCM`) without importing Lightning eagerly."""
    if name == "DCM":
        from dcm.models.dcm import DCM

        return DCM
    if name == "Baseline":
        from dcm.models.baseline import Baseline

        return Baseline
    if name in ("load_model", "predict_contact", "predict_task_loss"):
        from dcm.models import predict

        return getattr(predict, name)
    raise AttributeError(f"module 'dcm.models' has no attribute {name!r}")


__all__ += ["DCM", "Baseline", "load_model", "predict_contact", "predict_task_loss"]
