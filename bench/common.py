"""What every benchmark script shares: the device description, timing that waits for the GPU,
the device's measured matmul rate, and the JSON + table output."""

from __future__ import annotations

import json
import os
import platform
import sys
import time
from pathlib import Path

import lightning as L
import torch

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
RESULTS = REPO / "bench" / "results"


def pick_device(name: str) -> torch.device:
    if name == "auto":
        name = "cuda" if torch.cuda.is_available() else "cpu"
    if name == "cuda" and not torch.cuda.is_available():
        raise SystemExit("--device cuda: no CUDA device here")
    return torch.device(name)


def add_window_arguments(ap) -> None:
    """--device, and the issue's window: --joints (smpl22), --fps (60), --window-s (1)."""
    ap.add_argument("--device", default="auto", choices=("auto", "cpu", "cuda"))
    ap.add_argument("--joints", type=int, default=22)
    ap.add_argument("--fps", type=float, default=60.0)
    ap.add_argument("--window-s", type=float, default=1.0)


def describe(device: torch.device) -> dict:
    """The facts a reader needs to compare two tables."""
    info = {"device": device.type, "torch": torch.__version__, "python": platform.python_version()}
    if device.type == "cuda":
        info["gpu"] = torch.cuda.get_device_name(device)
        info["gpu_memory_gib"] = round(torch.cuda.get_device_properties(device).total_memory / 2**30, 1)
    else:
        info["cpu"] = platform.processor() or platform.machine()
        info["cpus"] = os.cpu_count()
        info["threads"] = torch.get_num_threads()
    return info


def sync(device: torch.device) -> None:
    if device.type == "cuda":
        torch.cuda.synchronize(device)


def timed(fn, device: torch.device, repeat: int, warmup: int = 2) -> float:
    """Seconds per call of fn(), the mean over `repeat` calls after `warmup` calls (the GPU
    finished before the clock starts and before it stops)."""
    for _ in range(warmup):
        fn()
    sync(device)
    t0 = time.perf_counter()
    for _ in range(repeat):
        fn()
    sync(device)
    return (time.perf_counter() - t0) / repeat


def matmul_tflops(device: torch.device, dtype: torch.dtype) -> float:
    """The device's measured dense matmul rate (TFLOP/s): a large square product, the best a
    real kernel gets, the yardstick for a model's achieved rate."""
    n = 8192 if device.type == "cuda" else 1024
    a = torch.randn(n, n, device=device, dtype=dtype)
    b = torch.randn(n, n, device=device, dtype=dtype)
    seconds = timed(lambda: a @ b, device, repeat=20 if device.type == "cuda" else 3)
    return 2 * n**3 / seconds / 1e12


def write_result(name: str, result: dict, json_out: str | None, variant: str | None = None) -> Path:
    """bench/results/<name>-<device>[-<variant>].json unless --json-out names another file."""
    stem = f"{name}-{result['env']['device']}" + (f"-{variant}" if variant else "")
    path = Path(json_out) if json_out else RESULTS / f"{stem}.json"
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(result, indent=2) + "\n")
    return path


def print_table(title: str, rows: list[dict], columns: list[tuple[str, str]]) -> None:
    """columns: (key, header) pairs; floats get 4 significant digits."""

    def fmt(v):
        if isinstance(v, float):
            return f"{v:.4g}"
        return "" if v is None else str(v)

    cells = [[fmt(r.get(k)) for k, _ in columns] for r in rows]
    widths = [max([len(h)] + [len(c[i]) for c in cells]) for i, (_, h) in enumerate(columns)]
    print(title)
    print("  ".join(h.ljust(w) for (_, h), w in zip(columns, widths)))
    for c in cells:
        print("  ".join(v.ljust(w) for v, w in zip(c, widths)))


class StepClock(L.Callback):
    """Wall time of the optimiser steps after `warmup`, and the host time spent between steps
    (fetching the next batch plus the loop's own bookkeeping)."""

    def __init__(self, warmup: int):
        self.warmup, self.t0, self.t1, self.steps = warmup, None, None, 0
        self.between, self._last_end = 0.0, None

    def on_train_batch_start(self, trainer, pl_module, batch, batch_idx):
        if trainer.global_step == self.warmup and self.t0 is None:
            sync(pl_module.device)
            self.t0 = time.perf_counter()
        elif self.t0 is not None and self._last_end is not None:
            self.between += time.perf_counter() - self._last_end

    def on_train_batch_end(self, trainer, pl_module, outputs, batch, batch_idx):
        if self.t0 is not None:
            self.steps += 1
            self._last_end = time.perf_counter()

    def on_train_end(self, trainer, pl_module):
        sync(pl_module.device)
        self.t1 = time.perf_counter()
