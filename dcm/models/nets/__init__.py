"""Score networks eps_theta(F^(i) | conditions, i) with one shared call signature.

Every net is built as `Net(cond_dim, out_dim, d_model=128, ...)` and called as
`net(cond (B,H,cond_dim), noisy (B,H,out_dim), step (B,)) -> (B,H,out_dim)`; nets are length-agnostic
(any H). The baseline calls the same net with `noisy = 0` and `step = 0` to regress F in one pass.

`build_score_net(name, cond_dim, out_dim, **kwargs)` is the single entry point the LightningModules
and the Hydra configs (`conf/net/*.yaml`) use, so an architecture ablation is a config change.
"""

from __future__ import annotations

import importlib

from torch import nn

from dcm.models.nets.embedding import NetShapeError

__all__ = ["SCORE_NETS", "UnknownNetError", "NetShapeError", "build_score_net", "get_score_net_class"]

# name -> "module:Class"; imported lazily so building one net never imports the others.
SCORE_NETS: dict[str, str] = {
    "retnet": "dcm.models.nets.retnet:RetNetScoreNet",
    "lstm": "dcm.models.nets.lstm:LSTMScoreNet",
    "unet1d": "dcm.models.nets.unet1d:UNet1DScoreNet",
    "transformer": "dcm.models.nets.transformer:TransformerScoreNet",
    "mlp": "dcm.models.nets.mlp:MLPScoreNet",
}
_ALIASES = {"unet": "unet1d", "retention": "retnet"}


class UnknownNetError(ValueError):
    """The requested score-net name is not registered."""


def get_score_net_class(name: str) -> type[nn.Module]:
    """Resolve a registered name (case-insensitive; 'unet' = 'unet1d') to its class."""
    key = _ALIASES.get(name.lower(), name.lower())
    if key not in SCORE_NETS:
        raise UnknownNetError(f"unknown score net {name!r}; choose one of {sorted(SCORE_NETS)}")
    module_name, cls_name = SCORE_NETS[key].split(":")
    return getattr(importlib.import_module(module_name), cls_name)


def build_score_net(name: str, cond_dim: int, out_dim: int, **kwargs) -> nn.Module:
    """Instantiate a score net by name; `kwargs` go to its constructor (d_model, n_layers, ...)."""
    cls = get_score_net_class(name)
    try:
        return cls(cond_dim=cond_dim, out_dim=out_dim, **kwargs)
    except TypeError as exc:  # unknown kwarg from a config: say which net rejected it
        raise UnknownNetError(f"score net {name!r} ({cls.__name__}) rejected arguments {sorted(kwargs)}: {exc}") from exc
