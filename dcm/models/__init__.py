"""Models: score networks (`dcm.models.nets`), the DDPM machinery (`dcm.models.diffusion`) and the
LightningModules built on them.

Kept import-light on purpose: importing `dcm.models` must not pull Lightning or data modules, so the
submodules can import each other without cycles. Import what you need from the submodules directly.
"""

from dcm.models.nets import SCORE_NETS, build_score_net

__all__ = ["SCORE_NETS", "build_score_net"]

# --- LightningModule exports (DCM, Baseline) go below this line ---
