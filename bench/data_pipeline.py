"""Benchmark 5: the data pipeline: parsing and cache times, and the windows/s the DataModule
delivers with XMAE's training corruption applied on the device, against what the model consumes
(benchmark 1's result for the same device, when it has been run).

Rows:
    parse      reading every BVH file of a folder (default: the Bandai Namco subset beside the repo)
    cache      the same clips from the npz cache (what every later run pays)
    loader     the standard DataLoader (workers as given), host -> device copy, corruption on the device
    device     batches_on_device (DeviceBatches): windows already on the device, corruption there

    python bench/data_pipeline.py                   # CUDA when there is one
    python bench/data_pipeline.py --device cpu --batches 20
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import torch
from common import RESULTS, describe, pick_device, print_table, sync, write_result

from mocapfix.data.datamodule import DeviceBatches, MotionDataModule  # noqa: E402
from mocapfix.training.xmae_input import xmae_training_input  # noqa: E402

DEFAULT_BVH = Path(__file__).resolve().parents[2] / "shared" / "data" / "bandai-namco"


def corrupt(positions: torch.Tensor) -> torch.Tensor:
    """XMAE's training corruption (the one XMAEModule.training_step applies), paper ratios."""
    return xmae_training_input(positions, 0.85, 0.05, 1.0).tokens


def windows_per_s(batches, device: torch.device, n: int, non_blocking: bool) -> float:
    it = iter(batches)
    for _ in range(2):  # warm-up: worker start, first kernels
        corrupt(next(it)["positions"].to(device, non_blocking=non_blocking))
    sync(device)
    t0, count = time.perf_counter(), 0
    for _ in range(n):
        try:
            batch = next(it)
        except StopIteration:
            it = iter(batches)
            batch = next(it)
        corrupt(batch["positions"].to(device, non_blocking=non_blocking))
        count += len(batch["positions"])
    sync(device)
    return count / (time.perf_counter() - t0)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--device", default="auto", choices=("auto", "cpu", "cuda"))
    ap.add_argument("--bvh", default=str(DEFAULT_BVH), help="BVH folder for the parse/cache rows ('none' to skip)")
    ap.add_argument("--fps", type=float, default=60.0)
    ap.add_argument("--batch", type=int, default=128)
    ap.add_argument("--batches", type=int, default=None, help="timed batches (default 200 on CUDA, 20 on CPU)")
    ap.add_argument("--workers", default="0,4", help="comma-separated num_workers for the loader rows")
    ap.add_argument("--json-out", default=None)
    args = ap.parse_args(argv)
    device = pick_device(args.device)
    gpu = device.type == "cuda"
    n = args.batches or (200 if gpu else 20)
    rows = []

    if args.bvh != "none" and Path(args.bvh).is_dir():
        with tempfile.TemporaryDirectory() as cache:
            dm = MotionDataModule(source="bvh", path=args.bvh, drop_joints=["joint_Root"], fps=30, cache_dir=cache)
            for row in ("parse", "cache"):
                t0 = time.perf_counter()
                clips = dm.load_clips()
                seconds = time.perf_counter() - t0
                frames = sum(c.num_frames for c in clips)
                rows.append({"row": row, "files": len(clips), "seconds": seconds, "frames_per_s": frames / seconds})

    dm = MotionDataModule(
        source="synthetic",
        fps=args.fps,
        stride_s=1.0 / args.fps,
        batch_size=args.batch,
        cache_dir=None,
        val_fraction=0.0,
        test_fraction=0.0,
    )
    dm.setup("fit")
    for workers in (int(w) for w in args.workers.split(",") if w):
        dm.hparams.update(num_workers=workers, pin_memory=gpu, persistent_workers=workers > 0)
        rows.append(
            {
                "row": "loader",
                "workers": workers,
                "batch": args.batch,
                "windows_per_s": windows_per_s(dm._loader("train", shuffle=True), device, n, non_blocking=gpu),
            }
        )
    batches = DeviceBatches(dm.datasets["train"], args.batch, device)
    rows.append(
        {
            "row": "device",
            "workers": 0,
            "batch": args.batch,
            "windows_per_s": windows_per_s(batches, device, n, non_blocking=False),
        }
    )

    consumed = None
    trained = RESULTS / f"train_throughput-{device.type}.json"
    if trained.exists():
        speeds = [r["seq_per_s"] for r in json.loads(trained.read_text())["rows"] if not r["row"].startswith("ref")]
        consumed = max(speeds)
        for r in rows:
            if "windows_per_s" in r:
                r["x_model_consumption"] = r["windows_per_s"] / consumed
    result = {
        "benchmark": "data_pipeline",
        "env": describe(device),
        "command": " ".join(sys.argv),
        "fps": args.fps,
        "model_seq_per_s": consumed,
        "rows": rows,
    }
    path = write_result("data_pipeline", result, args.json_out)
    print_table(
        f"Data pipeline, {result['env'].get('gpu', result['env'].get('cpu'))}, smpl22 windows of "
        f"{dm.window_frames} frames, corruption on {device.type}; the model consumes "
        f"{'?' if consumed is None else f'{consumed:.0f}'} windows/s ({trained.name})",
        rows,
        [
            ("row", "row"),
            ("files", "files"),
            ("seconds", "seconds"),
            ("frames_per_s", "frames/s"),
            ("workers", "workers"),
            ("windows_per_s", "windows/s"),
            ("x_model_consumption", "x model consumption"),
        ],
    )
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
