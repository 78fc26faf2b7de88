"""Is ONNX Runtime a cheaper way to ask the score net than torch on a CPU? One forward of a checkpoint's net at
the tuner's shapes, timed in both runtimes in one process, alternating, with their outputs compared.

    pip install onnxruntime onnxscript "numpy<2"      # not dependencies of dcm
    python -m studies.tuning_speed.onnx_forward --ckpt models/dcm_diverse_contact.ckpt --rows 64 --threads 1

The net is exported with torch's dynamo exporter, the batch axis dynamic, as predictions run it (no gradient,
so the chunkwise retention).
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import numpy as np


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--ckpt", default="models/dcm_diverse_contact.ckpt")
    parser.add_argument("--rows", type=int, default=64, help="rows per forward (the tuner's rows per call)")
    parser.add_argument("--horizon", type=int, default=240, help="steps per row (12 s at 20 Hz)")
    parser.add_argument("--step", type=int, default=9, help="the diffusion step fed to the net")
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--repeats", type=int, default=5, help="alternating rounds of 10 forwards each")
    args = parser.parse_args(argv)

    import onnxruntime as ort
    import torch

    from studies.tuning_speed.forward_timing import net_and_inputs, print_rounds

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
