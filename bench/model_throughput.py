"""Training and sampling throughput of the default DCM (RetNet d=128, T=30, linear) on this machine.

    python bench/model_throughput.py [--horizon 160] [--train-batch 64] [--sample-batch 256] [--net retnet]

Prints training samples/s (trajectories of H steps per second, forward+backward+AdamW) and sampling
throughput (trajectories/s for the full T-step ancestral DDPM chain, k=1), plus the implied epoch time
on the full sim set (1,600 training trajectories).
"""

from __future__ import annotations

import argparse
import time

import torch

from dcm.models.dcm import DCM


def _timeit(fn, min_seconds: float, min_reps: int = 2) -> float:
    fn()  # warm-up
    reps, start = 0, time.perf_counter()
    while reps < min_reps or time.perf_counter() - start < min_seconds:
        fn()
        reps += 1
    return (time.perf_counter() - start) / reps


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--net", default="retnet")
    parser.add_argument("--d-model", type=int, default=128)
    parser.add_argument("--steps", type=int, default=30, help="diffusion steps T")
    parser.add_argument("--horizon", type=int, default=160)
    parser.add_argument("--train-batch", type=int, default=64)
    parser.add_argument("--sample-batch", type=int, default=256)
    parser.add_argument("--seconds", type=float, default=10.0, help="minimum timing window per measurement")
    parser.add_argument("--threads", type=int, default=0, help="torch threads (0 = torch default)")
    args = parser.parse_args()
    if args.threads:
        torch.set_num_threads(args.threads)

    model = DCM(net={"name": args.net, "d_model": args.d_model}, diffusion_steps=args.steps,
                schedule={"name": "linear"})
    model.fit_normalizers(torch.rand(8, 16, 24) * 2 - 1, torch.rand(8, 16, 6) * 2 - 1)
    n_params = sum(p.numel() for p in model.net.parameters())
    opt = torch.optim.AdamW(model.net.parameters(), lr=1e-4)
    H = args.horizon
    cond = torch.rand(args.train_batch, H, 24) * 2 - 1
    target = torch.rand(args.train_batch, H, 6) * 2 - 1

    def train_step() -> None:
        opt.zero_grad(set_to_none=True)
        loss = model.loss(model.net, cond, target)
        loss.backward()
        opt.step()

    model.train()
    t_train = _timeit(train_step, args.seconds)
    train_sps = args.train_batch / t_train

    cond_s = torch.rand(args.sample_batch, H, 24) * 2 - 1
    gen = torch.Generator().manual_seed(0)
    t_sample = _timeit(lambda: model.predict_normalized(cond_s, 1, gen), args.seconds, min_reps=1)
    sample_tps = args.sample_batch / t_sample

    print(f"device cpu, torch threads {torch.get_num_threads()}, net {args.net} d={args.d_model} "
          f"({n_params / 1e3:.0f}k params), T={args.steps}, H={H}")
    print(f"training: {train_sps:.1f} samples/s (batch {args.train_batch}, {t_train * 1e3:.0f} ms/step)")
    print(f"sampling: {sample_tps:.1f} trajectories/s (batch {args.sample_batch}, {args.steps} DDPM steps, "
          f"{t_sample:.2f} s/batch)")
    print(f"full sim set (1,600 train trajectories): {1600 / train_sps:.1f} s/epoch of training; "
          f"validation metrics on 64 trajectories: {64 / sample_tps:.1f} s")


if __name__ == "__main__":
    main()
