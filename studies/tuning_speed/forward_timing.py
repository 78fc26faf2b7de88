"""One forward of a checkpoint's score net at the tuner's shapes, timed against another way of running it.

Shared by the CPU-runtime comparisons of this study (ONNX Runtime, int8 weights): the same seeded inputs, the
same alternating rounds in one process, so that load drifting during the run falls on both sides alike.
"""

from __future__ import annotations

import argparse
import os
import time
from collections.abc import Callable
from typing import Any

import numpy as np


def forward_parser(description: str) -> argparse.ArgumentParser:
    """The options both comparisons take: the checkpoint, the forward's shape, threads and rounds."""
    parser = argparse.ArgumentParser(description=description)
    parser.add_argument("--ckpt", default="models/dcm_diverse_contact.ckpt")
    parser.add_argument("--rows", type=int, default=64, help="rows per forward (the tuner's rows per call)")
    parser.add_argument("--horizon", type=int, default=240, help="steps per row (12 s at 20 Hz)")
    parser.add_argument("--step", type=int, default=9, help="the diffusion step fed to the net")
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--repeats", type=int, default=5, help="alternating rounds of 10 forwards each")
    return parser


def net_and_inputs(ckpt: str, rows: int, horizon: int, step: int) -> tuple[Any, tuple[Any, Any, Any]]:
    """The checkpoint's score net in eval mode and seeded (cond, noisy, step) inputs of ``rows`` x ``horizon``."""
    import torch

    from dcm.models.predict import load_model

    net = load_model(ckpt).net.eval()
    generator = torch.Generator().manual_seed(0)
    cond = torch.randn(rows, horizon, net.cond_dim, generator=generator)
    noisy = torch.randn(rows, horizon, net.out_dim, generator=generator)
    return net, (cond, noisy, torch.full((rows,), step, dtype=torch.long))


def per_forward_ms(call: Callable[[], object], forwards: int = 10) -> float:
    started = time.perf_counter()
    for _ in range(forwards):
        call()
    return (time.perf_counter() - started) * 1000.0 / forwards


def print_rounds(header: str, torch_call: Callable[[], object], other_call: Callable[[], object], other: str,
                 repeats: int) -> None:
    """Alternate ``repeats`` rounds of 10 forwards each way and print each round and the medians."""
    rounds = np.array([(per_forward_ms(torch_call), per_forward_ms(other_call)) for _ in range(repeats)])
    print(f"{header}, load average {os.getloadavg()[0]:.2f}")
    for t_torch, t_other in rounds:
        print(f"  torch {t_torch:7.1f} ms   {other} {t_other:7.1f} ms   torch / {other} {t_torch / t_other:.2f}")
    print(f"median per forward: torch {np.median(rounds[:, 0]):.1f} ms, {other} {np.median(rounds[:, 1]):.1f} ms, "
          f"torch / {other} {np.median(rounds[:, 0] / rounds[:, 1]):.2f}")
