"""A ``device=`` or ``trainer.accelerator=`` setting checked against this machine, so that a device it does not
have is refused in one line naming the option, instead of a CUDA traceback deep inside the first forward pass.
"""

from __future__ import annotations

from typing import Any

DEVICE_CHOICES = "auto, cpu, cuda, cuda:<index> or mps"


class DeviceError(ValueError):
    """A requested device is unknown or not present on this machine; names the option and the value."""


def resolve_device(name: str, option: str = "device") -> Any:
    """The ``torch.device`` for a setting (``auto``: cuda, else mps, else cpu).

    ``option`` is the setting's name as the user types it (``device``, ``trainer.accelerator`` ...) and appears
    in the error, e.g. ``device=cuda: CUDA is not available on this machine (torch <version>+cpu); use device=cpu
    or device=auto``.
    """
    import torch

    name = str(name).strip().lower()
    if name == "auto":
        if torch.cuda.is_available():
            return torch.device("cuda")
        return torch.device("mps" if _mps_available() else "cpu")
    try:
        device = torch.device(name)
    except (RuntimeError, ValueError):
        raise DeviceError(f"{option}={name}: not a device; use {DEVICE_CHOICES}") from None
    if device.type not in ("cpu", "cuda", "mps"):
        raise DeviceError(f"{option}={name}: unsupported device type {device.type!r}; use {DEVICE_CHOICES}")
    _check_present(device.type, device.index, option, name)
    return device


def check_accelerator(name: str, option: str = "trainer.accelerator") -> None:
    """Refuse a Lightning accelerator this machine does not have (``gpu``/``cuda``/``mps``; others pass)."""
    name = str(name).strip().lower()
    if name in ("gpu", "cuda", "mps"):
        _check_present("mps" if name == "mps" else "cuda", None, option, name)


def _mps_available() -> bool:
    import torch

    mps = getattr(torch.backends, "mps", None)
    return mps is not None and mps.is_available()


def _check_present(kind: str, index: int | None, option: str, value: str) -> None:
    import torch

    fallback = f"use {option}=cpu or {option}=auto"
    if kind == "cuda":
        if not torch.cuda.is_available():
            raise DeviceError(f"{option}={value}: CUDA is not available on this machine (torch {torch.__version__}); "
                              f"{fallback}")
        count = torch.cuda.device_count()
        if index is not None and index >= count:
            raise DeviceError(f"{option}={value}: this machine has {count} CUDA device(s), cuda:0..cuda:{count - 1}")
    elif kind == "mps" and not _mps_available():
        raise DeviceError(f"{option}={value}: Apple MPS is not available on this machine; {fallback}")

