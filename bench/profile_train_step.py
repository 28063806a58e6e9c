"""What bounds an XMAE training step: torch.profiler over a few steps of the product path.

Issue 6 asks where the training step's time goes once the throughput benchmark
(train_throughput.py) has said how long it takes. This runs the same path (MotionDataModule with
batches on the device -> XMAEModule.training_step -> Adam, in Lightning's Trainer, bf16-mixed on
a GPU, compiled unless --eager), records `--steps` steps after `--warmup` untimed ones, and says:

    wall ms/step       the step as the host sees it (GPU finished at both ends), under the
                       profiler: a little slower than train_throughput.py's unprofiled figure
    kernel ms/step     the sum of the GPU kernels' durations in a step
    busy               kernel time / wall time: well below 1 means the GPU waits on the host
                       (launches, Python, the data path), near 1 that the kernels are the bound
    kernels/step       how many launches a step costs
    by kind            kernel time split into matmul, attention, compiled (Triton), optimiser,
                       copies and the rest; and the slowest kernels by total time

On a CPU there are no kernels: the table is the operators' own CPU time.

    python bench/profile_train_step.py                                   # the issue's case on a GPU
    python bench/profile_train_step.py --device cpu --batch 8 --warmup 1 --steps 2
"""

from __future__ import annotations

import argparse
import re
import sys
import time

import lightning as L  # noqa: E402
import torch
from common import describe, pick_device, print_table, sync, write_result
from torch.autograd import DeviceType
from torch.profiler import ProfilerActivity, profile

from mocapfix.data.datamodule import MotionDataModule  # noqa: E402
from mocapfix.training.xmae_module import XMAEModule  # noqa: E402

# Kernel names -> what they do; the first pattern that matches wins. cuBLAS / CUTLASS GEMMs are
# named after their tile shapes (sm90_xmma_gemm_..., cutlass_80_tensorop_...), FlashAttention and
# the memory-efficient and cuDNN SDPA kernels after the algorithm, Inductor's fused kernels start triton_.
KINDS = (
    ("attention", r"flash|fmha|sdpa|attention|attn|cudnn::fusion"),  # cuDNN SDPA's helper kernels too
    ("matmul", r"gemm|cutlass|xmma|cublas|matmul|nvjet|sm90_|sm80_"),
    ("compiled (triton)", r"^triton_"),
    ("optimiser", r"multi_tensor|adam|foreach"),
    ("copy / fill", r"memcpy|memset|copy|fill"),
)


def kind_of(name: str) -> str:
    for kind, pattern in KINDS:
        if re.search(pattern, name, re.IGNORECASE):
            return kind
    return "other"


class ProfileWindow(L.Callback):
    """Profiles the optimiser steps [start, start + steps) and times them on the wall clock."""

    def __init__(self, start: int, steps: int, activities: list):
        self.start, self.steps, self.activities = start, steps, activities
        self.prof, self.seconds = None, None

    def on_train_batch_start(self, trainer, pl_module, batch, batch_idx):
        if trainer.global_step == self.start and self.prof is None:
            sync(pl_module.device)
            self.prof = profile(activities=self.activities)
            self.prof.__enter__()
            self._t0 = time.perf_counter()

    def on_train_batch_end(self, trainer, pl_module, outputs, batch, batch_idx):
        if self.prof is not None and self.seconds is None and trainer.global_step == self.start + self.steps:
            sync(pl_module.device)
            self.seconds = time.perf_counter() - self._t0
            self.prof.__exit__(None, None, None)


def summarise(prof, steps: int, wall_s: float, gpu: bool, top: int) -> tuple[dict, list[dict]]:
    """-> (summary, rows of the slowest kernels / operators)."""
    if not gpu:
        ops = sorted(prof.key_averages(), key=lambda e: e.self_cpu_time_total, reverse=True)
        rows = [
            {
                "name": e.key[:70],
                "kind": "cpu op",
                "calls_per_step": e.count / steps,
                "ms_per_step": e.self_cpu_time_total / 1000 / steps,
            }
            for e in ops[:top]
        ]
        return {"wall_ms_per_step": 1000 * wall_s / steps}, rows
    # user annotations (record_function ranges) have a GPU-side copy spanning their kernels: not
    # kernels. Lightning runs forward and backward inside optimizer.step(closure), so the
    # "Optimizer.step#Adam.step" range covers the whole step (session 7's first GPU run counted it).
    kernels = [
        e for e in prof.events() if e.device_type == DeviceType.CUDA and not getattr(e, "is_user_annotation", False)
    ]
    if not kernels:
        raise SystemExit("the profile holds no CUDA kernels (profiler without CUDA activity?)")
    # a kernel's own duration: its time range (device_time_total reads 0 for events marked async)
    dur = {id(e): e.time_range.elapsed_us() for e in kernels}
    total_us = sum(dur.values())
    by_kind: dict[str, float] = {}
    by_name: dict[str, list] = {}
    for e in kernels:
        kind = kind_of(e.name)
        by_kind[kind] = by_kind.get(kind, 0.0) + dur[id(e)]
        acc = by_name.setdefault(e.name, [0, 0.0])
        acc[0] += 1
        acc[1] += dur[id(e)]
    summary = {
        "wall_ms_per_step": 1000 * wall_s / steps,
        "kernel_ms_per_step": total_us / 1000 / steps,
        "busy": total_us / 1e6 / wall_s,
        "kernels_per_step": len(kernels) / steps,
        "kernel_ms_by_kind": {k: v / 1000 / steps for k, v in sorted(by_kind.items(), key=lambda kv: -kv[1])},
    }
    slow = sorted(by_name.items(), key=lambda kv: -kv[1][1])[:top]
    rows = [
        {
            "name": name[:70],
            "kind": kind_of(name),
            "calls_per_step": n / steps,
            "ms_per_step": us / 1000 / steps,
            "share": us / total_us,
        }
        for name, (n, us) in slow
    ]
    return summary, rows


def add_output_arguments(ap) -> None:
    """--top, --trace-out, --json-out: what a profile script writes."""
    ap.add_argument("--top", type=int, default=25, help="slowest kernels / operators listed")
    ap.add_argument("--trace-out", default=None, help="also write a Chrome trace (chrome://tracing, Perfetto)")
    ap.add_argument("--json-out", default=None)


def print_profile(title: str, summary: dict, rows: list[dict], gpu: bool, per: str = "step") -> None:
    """The summary and the slowest kernels as printed lines; `per`: what the figures are per
    (their keys end in _per_<per>)."""
    print(f"{title}: wall {summary[f'wall_ms_per_{per}']:.2f} ms/{per}", end="")
    if gpu:
        kernel_ms = summary[f"kernel_ms_per_{per}"]
        print(
            f", kernels {kernel_ms:.2f} ms/{per} (busy {summary['busy']:.0%}), "
            f"{summary[f'kernels_per_{per}']:.0f} kernels/{per}"
        )
        for kind, ms in summary["kernel_ms_by_kind"].items():
            print(f"  {kind:<18} {ms:8.2f} ms/{per}  {ms / kernel_ms:6.1%}")
    else:
        print()
    print_table(
        "slowest " + ("kernels" if gpu else "operators (self CPU time)"),
        rows,
        [("name", "name"), ("kind", "kind"), (f"calls_per_{per}", f"calls/{per}"), (f"ms_per_{per}", f"ms/{per}")]
        + ([("share", "share")] if gpu else []),
    )


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--device", default="auto", choices=("auto", "cpu", "cuda"))
    ap.add_argument("--source", default="synthetic", help="data source (synthetic: smpl22, the issue's case)")
    ap.add_argument("--path", default=None)
    ap.add_argument("--synthetic-clips", type=int, default=48)
    ap.add_argument("--fps", type=float, default=60.0)
    ap.add_argument("--window-s", type=float, default=1.0)
    ap.add_argument("--batch", type=int, default=128)
    ap.add_argument("--precision", default=None, help="default: bf16-mixed on CUDA, 32-true on CPU")
    ap.add_argument("--eager", action="store_true", help="no torch.compile (default: compiled on CUDA)")
    ap.add_argument("--compile-mode", default="default", help="torch.compile mode (reduce-overhead: CUDA graphs)")
    ap.add_argument("--warmup", type=int, default=None, help="steps before the profile (default 30 CUDA, 2 CPU)")
    ap.add_argument("--steps", type=int, default=None, help="profiled steps (default 20 CUDA, 3 CPU)")
    add_output_arguments(ap)
    args = ap.parse_args(argv)
    device = pick_device(args.device)
    gpu = device.type == "cuda"
    precision = args.precision or ("bf16-mixed" if gpu else "32-true")
    warmup = args.warmup if args.warmup is not None else (30 if gpu else 2)
    steps = args.steps or (20 if gpu else 3)
    compiled = gpu and not args.eager
    torch.set_float32_matmul_precision("high")  # as `python -m mocapfix fit` sets it

    torch.manual_seed(0)
    dm = MotionDataModule(
        source=args.source,
        path=args.path,
        fps=args.fps,
        window_s=args.window_s,
        stride_s=1.0 / args.fps,
        batch_size=args.batch,
        cache_dir=None,
        batches_on_device=True,
        synthetic_clips=args.synthetic_clips,
        val_fraction=0.0,
        test_fraction=0.0,
    )
    model = XMAEModule(
        compile_model=compiled, compile_mode=args.compile_mode, warmup_steps=10, total_steps=10 * (warmup + steps)
    )
    activities = [ProfilerActivity.CPU] + ([ProfilerActivity.CUDA] if gpu else [])
    window = ProfileWindow(warmup, steps, activities)
    trainer = L.Trainer(
        accelerator=device.type,
        devices=1,
        precision=precision,
        max_steps=warmup + steps + 1,
        logger=False,
        enable_checkpointing=False,
        enable_progress_bar=False,
        enable_model_summary=False,
        limit_val_batches=0,
        num_sanity_val_steps=0,
        callbacks=[window],
    )
    trainer.fit(model, datamodule=dm)
    if window.seconds is None:
        raise SystemExit(f"the run ended before step {warmup + steps}: too little training data for this batch?")
    if args.trace_out:
        window.prof.export_chrome_trace(args.trace_out)
    summary, rows = summarise(window.prof, steps, window.seconds, gpu, args.top)
    J, T = len(model.hparams.skeleton["parents"]), model.hparams.window_frames
    result = {
        "benchmark": "xmae_train_step_profile",
        "env": describe(device),
        "command": " ".join(sys.argv),
        "joints": J,
        "frames": T,
        "batch": args.batch,
        "precision": precision,
        "compiled": compiled,
        "compile_mode": args.compile_mode if compiled else None,
        "profiled_steps": steps,
        **summary,
        "rows": rows,
    }
    path = write_result("profile_train_step", result, args.json_out)
    how = f"compiled ({args.compile_mode})" if compiled else "eager"
    print_profile(
        f"XMAE training step, {J} joints x {T} frames, batch {args.batch}, {precision}, {how}", summary, rows, gpu
    )
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
