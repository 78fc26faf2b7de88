"""Are int8 weights a cheaper way to ask the score net on a CPU without native bfloat16? One forward of a
checkpoint's net with its Linear layers dynamically quantised to int8 (torch's ``quantize_dynamic``, the
fbgemm kernels), timed against float32 in one process, alternating, with their outputs compared.

    python -m studies.tuning_speed.int8_forward --ckpt models/dcm_diverse_contact.ckpt --rows 64 --threads 1
"""

from __future__ import annotations

import copy
import warnings

import numpy as np

from studies.tuning_speed.forward_timing import forward_parser, net_and_inputs, print_rounds


def main(argv: list[str] | None = None) -> None:
    args = forward_parser(__doc__.split("\n\n")[0]).parse_args(argv)

    import torch

    torch.set_num_threads(args.threads)
    net, inputs = net_and_inputs(args.ckpt, args.rows, args.horizon, args.step)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)  # torch.ao.quantization, kept for its CPU kernels
        from torch.ao.quantization import quantize_dynamic

        int8_net = quantize_dynamic(copy.deepcopy(net), {torch.nn.Linear}, dtype=torch.qint8)
    with torch.inference_mode():
        expected, got = net(*inputs).numpy(), int8_net(*inputs).numpy()

    def forward(model: torch.nn.Module):
        def call() -> None:
            with torch.inference_mode():
                model(*inputs)
        return call

    print(f"outputs: max |int8 - float32| {np.abs(got - expected).max():.2e}, RMS "
          f"{np.sqrt(((got - expected) ** 2).mean()):.2e} (output RMS {np.sqrt((expected ** 2).mean()):.3f})")
    print_rounds(f"{args.ckpt}: {args.rows} rows x {args.horizon} steps, {args.threads} thread(s), torch "
                 f"{torch.__version__}, backend {torch.backends.quantized.engine}", forward(net), forward(int8_net),
                 "int8", args.repeats)


if __name__ == "__main__":
    main()
