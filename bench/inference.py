"""Benchmark 2: XMAE inference: windows/s batched (fully observed, and 10% of tokens missing at
random), batch-1 latency, FLOPs per window and the achieved rate beside the device's measured
matmul rate.

The timed call is the product's reconstruction pass (mocapfix.models.xmae_inference.xmae_reconstruct:
normalisation, observed-token index, encoder over observed tokens, cross-attention decoder over
all tokens), the one `fix`, validation and `predict` use, in the precision `fix --precision`
gives it: fp32 weights, bf16 autocast for the matmuls (default on CUDA), or fp32 throughout.
FLOPs are counted by torch.utils.flop_counter on batches of one and two windows and given per
window at the timed batch size (matmuls and attention, multiply-add = 2 FLOPs; elementwise work
is not counted; the decoder's first self-attention runs once per batch).

    python bench/inference.py                       # CUDA: bf16, batch 1024
    python bench/inference.py --device cpu --batch 16
    python bench/inference.py --compile             # also torch.compile(mode="reduce-overhead") rows (CUDA graphs)
    python bench/inference.py --compile --compile-mode max-autotune   # + Triton matmul templates (minutes to compile)
"""

from __future__ import annotations

import argparse
import sys
from functools import partial

import torch
from common import add_window_arguments, describe, matmul_tflops, pick_device, print_table, timed, write_result
from torch.nn.attention import SDPBackend, sdpa_kernel
from torch.utils.flop_counter import FlopCounterMode

from mocapfix.models.xmae import XMAE  # noqa: E402
from mocapfix.models.xmae_inference import xmae_reconstruct  # noqa: E402


def make_windows(B: int, T: int, J: int, missing: float, device, seed: int = 0):
    """Plausible-scale positions (metres, z up) and an observed mask with `missing` of the tokens
    dropped at random. Speed does not depend on the values, only on the counts."""
    g = torch.Generator().manual_seed(seed)
    positions = (torch.randn(B, T, J, 3, generator=g) * 0.3 + torch.tensor([0.0, 0.0, 1.0])).to(device)
    observed = (torch.rand(B, T, J, generator=g) >= missing).to(device)
    return positions, observed


def flops_per_window(net: XMAE, T: int, J: int, device) -> tuple[float, float]:
    """Counted FLOPs of fully observed windows as (per window, once per batch): the decoder's
    first self-attention runs once per batch, so a batch of n costs per_window * n + shared;
    counted at 1 and 2 windows."""

    def count(n):
        positions, observed = make_windows(n, T, J, 0.0, device)
        # The math backend spells attention out as matmuls, which the counter sees on every device
        # (it has no formula for the CPU's fused attention kernel).
        with FlopCounterMode(display=False) as counter, torch.inference_mode(), sdpa_kernel(SDPBackend.MATH):
            xmae_reconstruct(net, positions, observed)
        return counter.get_total_flops()

    one, two = count(1), count(2)
    return two - one, 2 * one - two


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    add_window_arguments(ap)
    ap.add_argument("--batch", type=int, default=None, help="windows per batch (default 1024 on CUDA, 16 on CPU)")
    ap.add_argument("--dtype", default=None, choices=("bf16", "fp32"), help="default: bf16 on CUDA, fp32 on CPU")
    ap.add_argument("--repeat", type=int, default=None)
    ap.add_argument("--compile", action="store_true", help="add rows with torch.compile")
    ap.add_argument(
        "--compile-mode",
        default="reduce-overhead",
        choices=("default", "reduce-overhead", "max-autotune", "max-autotune-no-cudagraphs"),
        help="torch.compile mode of the compiled rows on CUDA (a CPU uses 'default': no graphs there)",
    )
    ap.add_argument("--json-out", default=None)
    args = ap.parse_args(argv)
    device = pick_device(args.device)
    gpu = device.type == "cuda"
    B = args.batch or (1024 if gpu else 16)
    bf16 = (args.dtype or ("bf16" if gpu else "fp32")) == "bf16"
    dtype = torch.bfloat16 if bf16 else torch.float32
    repeat = args.repeat or (20 if gpu else 3)
    T, J = int(round(args.fps * args.window_s)), args.joints

    torch.manual_seed(0)
    eager = XMAE(J, T).to(device).eval()  # paper sizes (Table 1)
    params = sum(p.numel() for p in eager.parameters())
    per_window, shared = flops_per_window(eager, T, J, device)
    flops = {b: per_window + shared / b for b in (B, 1)}  # per window at the batch sizes timed
    peak = matmul_tflops(device, dtype)
    nets = {"eager": eager}
    if args.compile:
        compiled = XMAE(J, T).to(device).eval()
        compiled.load_state_dict(eager.state_dict())
        compiled.compile(mode=args.compile_mode if gpu else "default")
        nets["compiled"] = compiled

    rows = []
    for name, net in nets.items():
        for case, missing, batch in (("full", 0.0, B), ("10% missing", 0.1, B), ("full, batch 1", 0.0, 1)):
            positions, observed = make_windows(batch, T, J, missing, device)
            with torch.inference_mode(), torch.autocast(device.type, dtype=torch.bfloat16, enabled=bf16):
                seconds = timed(
                    partial(xmae_reconstruct, net, positions, observed),
                    device,
                    repeat=repeat * (10 if batch == 1 else 1),
                    warmup=3,
                )
            kept = observed.flatten(1).sum(1).float().mean().item()
            row = {
                "net": name,
                "case": case,
                "batch": batch,
                "observed_tokens": round(kept, 1),
                "ms_per_batch": 1000 * seconds,
                "windows_per_s": batch / seconds,
            }
            if missing == 0.0:  # the counted FLOPs are those of a fully observed window
                row["tflops"] = flops[batch] * batch / seconds / 1e12
                row["of_matmul_peak"] = row["tflops"] / peak
            rows.append(row)

    result = {
        "benchmark": "xmae_inference",
        "env": describe(device),
        "command": " ".join(sys.argv),
        "joints": J,
        "frames": T,
        "dtype": "bf16 autocast" if bf16 else "fp32",
        "parameters": params,
        "compile_mode": (args.compile_mode if gpu else "default") if args.compile else None,
        "gflop_per_window": flops[B] / 1e9,
        "gflop_per_window_batch_1": flops[1] / 1e9,
        "matmul_tflops_measured": peak,
        "rows": rows,
    }
    path = write_result("inference", result, args.json_out)
    print_table(
        f"XMAE inference, {result['env'].get('gpu', result['env'].get('cpu'))}, {J} joints x {T} frames, "
        f"{result['dtype']}, {params / 1e6:.2f} M parameters, {flops[B] / 1e9:.1f} GFLOP per full window at batch {B}, "
        f"measured {str(dtype).replace('torch.', '')} matmul rate {peak:.1f} TFLOP/s",
        rows,
        [
            ("net", "net"),
            ("case", "case"),
            ("batch", "batch"),
            ("observed_tokens", "observed"),
            ("ms_per_batch", "ms/batch"),
            ("windows_per_s", "windows/s"),
            ("tflops", "TFLOP/s"),
            ("of_matmul_peak", "of matmul rate"),
        ],
    )
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
