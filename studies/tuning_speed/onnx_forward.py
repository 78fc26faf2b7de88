"""Is ONNX Runtime a cheaper way to ask the score net than torch on a CPU? One forward of a checkpoint's net at
the tuner's shapes, timed in both runtimes in one process, alternating, with their outputs compared.

    pip install onnxruntime onnxscript "numpy<2"      # not dependencies of dcm
    python -m studies.tuning_speed.onnx_forward --ckpt models/dcm_diverse_contact.ckpt --rows 64 --threads 1

The net is exported with torch's dynamo exporter, the batch axis dynamic, as predictions run it (no gradient,
so the chunkwise retention).
"""

from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np

from studies.tuning_speed.forward_timing import forward_parser, net_and_inputs, print_rounds


def main(argv: list[str] | None = None) -> None:
    args = forward_parser(__doc__.split("\n\n")[0]).parse_args(argv)

    import onnxruntime as ort
    import torch

    torch.set_num_threads(args.threads)
    net, (cond, noisy, step) = net_and_inputs(args.ckpt, args.rows, args.horizon, args.step)
    batch = torch.export.Dim("rows")
    with tempfile.TemporaryDirectory() as folder, torch.no_grad():
        path = Path(folder) / "net.onnx"
        torch.onnx.export(net, (cond, noisy, step), str(path), input_names=["cond", "noisy", "step"],
                          output_names=["out"], dynamic_shapes=({0: batch}, {0: batch}, {0: batch}), dynamo=True)
        options = ort.SessionOptions()
        options.intra_op_num_threads, options.inter_op_num_threads = args.threads, 1
        session = ort.InferenceSession(str(path), options, providers=["CPUExecutionProvider"])
    feeds = {"cond": cond.numpy(), "noisy": noisy.numpy(), "step": step.numpy()}
    with torch.inference_mode():
        expected = net(cond, noisy, step).numpy()
    got = session.run(None, feeds)[0]

    def torch_forward() -> None:
        with torch.inference_mode():
            net(cond, noisy, step)

    print(f"outputs: max |ORT - torch| {np.abs(got - expected).max():.2e} (output RMS {np.sqrt((expected ** 2).mean()):.3f})")
    print_rounds(f"{args.ckpt}: {args.rows} rows x {args.horizon} steps, {args.threads} thread(s), torch "
                 f"{torch.__version__}, onnxruntime {ort.__version__}", torch_forward,
                 lambda: session.run(None, feeds), "ORT", args.repeats)


if __name__ == "__main__":
    main()
