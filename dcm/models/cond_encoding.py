"""How the per-step conditions reach the score net, before normalisation.

``raw`` feeds (x_demo | F_demo | x_attr | K) as recorded, the paper's encoding. ``physical`` feeds the same
information in the quantities the impedance law acts on: the attractor as its offset from the demo pose,
``x_attr - x_demo`` (the spring's commanded deflection, millimetres to centimetres, which a bowl-sized
min-max range of x_attr compresses), and the stiffness as ``log K``, so that 100 → 200 N/m weighs as much
as 1,000 → 2,000 N/m (the tracking error goes with the compliance 1/K, not with K). Both are invertible, so
no information is lost; the channel layout and count stay those of ``dcm.data.schema``. K > 0 is checked
where data enters (``load_dataset``, ``predict_forces``), not per batch here, which would stall a GPU.
"""

from __future__ import annotations

import torch

from dcm.data.schema import cond_slice

COND_ENCODINGS = ("raw", "physical")
_X_DEMO, _X_ATTR, _K = cond_slice("x_demo"), cond_slice("x_attr"), cond_slice("K")


def encode_conditions(cond: torch.Tensor, encoding: str) -> torch.Tensor:
    """Raw conditions (..., 24) in physical units -> the net's input channels (..., 24), before normalising."""
    if encoding == "raw":
        return cond
    if encoding != "physical":
        raise ValueError(f"cond_encoding must be one of {COND_ENCODINGS}, got {encoding!r}")
    out = cond.clone()
    out[..., _X_ATTR] = cond[..., _X_ATTR] - cond[..., _X_DEMO]
    out[..., _K] = torch.log(cond[..., _K])
    return out
