"""What bounds batched XMAE inference: torch.profiler over a few reconstruction passes.

Benchmark 2 (inference.py) says how many full windows a second the product's reconstruction pass
runs (8,530 on the H100 in session 7, against a target of 10,000) and what fraction of the
matmul rate that is; this says where the time goes, as profile_train_step.py does for training:
wall vs kernel time (busy), kernels per pass, kernel time by kind (matmul, attention, Triton,
copies), the slowest kernels. The pass is mocapfix.models.xmae_inference.xmae_reconstruct (the one `fix`,
validation and `predict` use) under bf16 autocast on a GPU, compiled with CUDA graphs unless
--eager.

    python bench/profile_inference.py                                    # the issue's case on a GPU
    python bench/profile_inference.py --device cpu --batch 4 --fps 10 --warmup 1 --passes 2
"""

from __future__ import annotations

import argparse
import sys
import time

import torch
from common import add_window_arguments, describe, pick_device, sync, write_result
from inference import make_windows
from profile_train_step import add_output_arguments, print_profile, summarise
from torch.profiler import ProfilerActivity, profile

from mocapfix.models.xmae import XMAE  # noqa: E402
from mocapfix.models.xmae_inference import xmae_reconstruct  # noqa: E402


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    add_window_arguments(ap)
    ap.add_argument("--batch", type=int, default=None, help="windows per pass (default 1024 on CUDA, 16 on CPU)")
    ap.add_argument("--missing", type=float, default=0.0, help="fraction of tokens missing (default 0: full windows)")
    ap.add_argument("--eager", action="store_true", help="no torch.compile (default: compiled on CUDA)")
    ap.add_argument("--compile-mode", default="reduce-overhead", help="torch.compile mode on CUDA")
    ap.add_argument("--warmup", type=int, default=None, help="passes before the profile (default 10 CUDA, 1 CPU)")
    ap.add_argument("--passes", type=int, default=None, help="profiled passes (default 10 CUDA, 2 CPU)")
    add_output_arguments(ap)
    args = ap.parse_args(argv)
    device = pick_device(args.device)
    gpu = device.type == "cuda"
    B = args.batch or (1024 if gpu else 16)
    warmup = args.warmup if args.warmup is not None else (10 if gpu else 1)
    passes = args.passes or (10 if gpu else 2)
    compiled = gpu and not args.eager
    T, J = int(round(args.fps * args.window_s)), args.joints

    torch.manual_seed(0)
    net = XMAE(J, T).to(device).eval()  # paper sizes (Table 1)
    if compiled:
        net.compile(mode=args.compile_mode)
    positions, observed = make_windows(B, T, J, args.missing, device)

    def run():
        with torch.inference_mode(), torch.autocast(device.type, dtype=torch.bfloat16, enabled=gpu):
            xmae_reconstruct(net, positions, observed)

    for _ in range(warmup):
        run()
    sync(device)
    activities = [ProfilerActivity.CPU] + ([ProfilerActivity.CUDA] if gpu else [])
    with profile(activities=activities) as prof:
        t0 = time.perf_counter()
        for _ in range(passes):
            run()
        sync(device)
        seconds = time.perf_counter() - t0
    if args.trace_out:
        prof.export_chrome_trace(args.trace_out)
    summary, rows = summarise(prof, passes, seconds, gpu, args.top)
    summary = {k.replace("_per_step", "_per_pass"): v for k, v in summary.items()}
    result = {
        "benchmark": "xmae_inference_profile",
        "env": describe(device),
        "command": " ".join(sys.argv),
        "joints": J,
        "frames": T,
        "batch": B,
        "missing": args.missing,
        "dtype": "bf16 autocast" if gpu else "fp32",
        "compiled": compiled,
        "compile_mode": args.compile_mode if compiled else None,
        "profiled_passes": passes,
        "windows_per_s_profiled": B * passes / seconds,
        **summary,
        "rows": [{k.replace("_per_step", "_per_pass"): v for k, v in r.items()} for r in rows],
    }
    path = write_result("profile_inference", result, args.json_out)
    how = f"compiled ({args.compile_mode})" if compiled else "eager"
    print_profile(
        f"XMAE inference, {J} joints x {T} frames, batch {B}, {result['dtype']}, {how}",
        summary,
        result["rows"],
        gpu,
        per="pass",
    )
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
