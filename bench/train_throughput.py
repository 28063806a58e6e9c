"""Benchmark 1: XMAE training throughput (sequences/s) through the real product path, beside the
independent reference step (../shared/bench/ref_xmae.py) measured in the same run.

The product path is the one `python -m mocapfix fit` runs: MotionDataModule -> corruption on
the device inside XMAEModule.training_step (masking, displacement, normalisation, z rotation,
L1 loss) -> Adam + warm-up/cosine schedule -> Lightning's Trainer loop. Each row is one Trainer
run; the clock runs from the end of the warm-up steps to the end of the last step, with the GPU
finished at both ends.

Rows:
    loader          the standard DataLoader (host windows, copied to the device per batch)
    device          batches_on_device: windows live on the device, batches cut there
    device+compile  the same with compile_model (torch.compile of the network)
    device+cudagraphs   the same with compile_mode "reduce-overhead": the network's forward and
                    backward replayed as CUDA graphs (no graphs on a CPU: there it is device+compile)
    device+autotune     the same with compile_mode "max-autotune": CUDA graphs, and Inductor times
                    Triton matmul templates against cuBLAS and can fuse the ReLU / bias / residual
                    work into them (minutes of compiling: not in the default rows, ask for it)
    constant        one batch repeated, no data pipeline at all: the model's own ceiling;
                    `device` at the same rate means the GPU never waits on data
    ref naive / ref fast    ref_xmae.py (its own timing: 20 steps on CUDA, 2 on CPU)

    python bench/train_throughput.py                          # the issue's case on the GPU
    python bench/train_throughput.py --device cpu --batch 16 --steps 5 --rows device,constant
"""

from __future__ import annotations

import argparse
import itertools
import re
import subprocess
import sys
from pathlib import Path

import lightning as L  # noqa: E402
import torch
from common import StepClock, describe, pick_device, print_table, write_result

from mocapfix.data.datamodule import MotionDataModule  # noqa: E402
from mocapfix.training.xmae_module import XMAEModule  # noqa: E402

ROWS = ("loader", "device", "device+compile", "device+cudagraphs", "device+autotune", "constant")
DEFAULT_ROWS = tuple(r for r in ROWS if r != "device+autotune")
COMPILE_MODE = {"device+compile": "default", "device+cudagraphs": "reduce-overhead", "device+autotune": "max-autotune"}
DEFAULT_REF = Path(__file__).resolve().parents[2] / "shared" / "bench" / "ref_xmae.py"


class RepeatBatch:
    """One batch, `n` times: the training loop with no data pipeline behind it."""

    def __init__(self, batch: dict, n: int):
        self.batch, self.n = batch, n

    def __len__(self):
        return self.n

    def __iter__(self):
        return itertools.repeat(self.batch, self.n)


def run_trainer(row: str, args, device: torch.device) -> dict:
    torch.manual_seed(0)
    dm = MotionDataModule(
        source=args.source,
        path=args.path,
        fps=args.fps,
        window_s=args.window_s,
        stride_s=1.0 / args.fps,
        batch_size=args.batch,
        cache_dir=None,
        synthetic_clips=args.synthetic_clips,
        drop_joints=args.drop_joints or None,
        batches_on_device=row != "loader",
        pin_memory=row == "loader" and device.type == "cuda",
        val_fraction=0.0,
        test_fraction=0.0,
    )
    steps = args.warmup + args.steps
    model = XMAEModule(
        compile_model=row in COMPILE_MODE,
        compile_mode=COMPILE_MODE.get(row, "default"),
        warmup_steps=10,
        total_steps=10 * steps,
    )
    clock = StepClock(args.warmup)
    trainer = L.Trainer(
        accelerator=device.type,
        devices=1,
        precision=args.precision,
        max_steps=steps,
        logger=False,
        enable_checkpointing=False,
        enable_progress_bar=False,
        enable_model_summary=False,
        limit_val_batches=0,
        num_sanity_val_steps=0,
        callbacks=[clock],
    )
    if row == "constant":
        dm.setup("fit")
        batch = {k: v.to(device) for k, v in dm.datasets["train"].__getitems__(list(range(args.batch))).items()}
        model.bind_data(dm.spec(), "fit")
        trainer.fit(model, train_dataloaders=RepeatBatch(batch, steps))
    else:
        trainer.fit(model, datamodule=dm)
    seconds = clock.t1 - clock.t0
    J = len(model.hparams.skeleton["parents"])
    return {
        "row": row,
        "joints": J,
        "frames": model.hparams.window_frames,
        "batch": args.batch,
        "precision": args.precision,
        "steps": clock.steps,
        "ms_per_step": 1000 * seconds / clock.steps,
        "seq_per_s": clock.steps * args.batch / seconds,
        "host_ms_between_steps": 1000 * clock.between / max(clock.steps - 1, 1),
    }


def run_reference(ref: Path, J: int, T: int, B: int) -> list[dict]:
    """ref_xmae.py in its own process (it builds its model at import), parsed from its lines:
    'naive  J=22 T=60 B=128 cuda:     128.0 ms/step      1000 seq/s  params=5.60M'."""
    out = subprocess.run(
        [sys.executable, str(ref), str(J), str(T), str(B)], capture_output=True, text=True, check=True
    ).stdout
    rows = []
    for line in out.splitlines():
        m = re.match(r"\s*(naive|fast)\s.*?([\d.]+) ms/step\s+([\d.]+) seq/s\s+params=([\d.]+)M", line)
        if m:
            rows.append(
                {
                    "row": f"ref {m[1]}",
                    "joints": J,
                    "frames": T,
                    "batch": B,
                    "precision": "32-true" if m[1] == "naive" else "bf16 autocast",
                    # from ms/step: the printed seq/s is rounded to a whole number
                    "ms_per_step": float(m[2]),
                    "seq_per_s": B / (float(m[2]) / 1000),
                    "params_m": float(m[4]),
                }
            )
    if len(rows) != 2:
        raise SystemExit(f"could not read ref_xmae.py's output:\n{out}")
    return rows


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--device", default="auto", choices=("auto", "cpu", "cuda"))
    ap.add_argument("--source", default="synthetic", help="data source (synthetic: smpl22, the issue's case)")
    ap.add_argument("--path", default=None, help="data path for other sources (e.g. an archive .npz)")
    ap.add_argument("--drop-joints", nargs="*", default=[])
    ap.add_argument("--synthetic-clips", type=int, default=48)
    ap.add_argument("--fps", type=float, default=60.0)
    ap.add_argument("--window-s", type=float, default=1.0)
    ap.add_argument("--batch", type=int, default=128)
    ap.add_argument("--precision", default=None, help="Trainer precision (default: bf16-mixed on CUDA, 32-true on CPU)")
    ap.add_argument("--warmup", type=int, default=None, help="untimed steps (default 30 on CUDA, 2 on CPU)")
    ap.add_argument("--steps", type=int, default=None, help="timed steps (default 300 on CUDA, 5 on CPU)")
    ap.add_argument("--rows", default=",".join(DEFAULT_ROWS), help=f"comma-separated subset of {', '.join(ROWS)}")
    ap.add_argument("--ref", default=str(DEFAULT_REF), help="ref_xmae.py ('none' to skip it)")
    ap.add_argument("--json-out", default=None)
    args = ap.parse_args(argv)
    device = pick_device(args.device)
    gpu = device.type == "cuda"
    args.precision = args.precision or ("bf16-mixed" if gpu else "32-true")
    args.warmup = args.warmup if args.warmup is not None else (30 if gpu else 2)
    args.steps = args.steps or (300 if gpu else 5)
    # as `python -m mocapfix fit` sets it; ref_xmae.py runs in its own process, as written
    torch.set_float32_matmul_precision("high")

    names = [r for r in args.rows.split(",") if r]
    if unknown := sorted(set(names) - set(ROWS)):
        ap.error(f"unknown rows {unknown}: choose from {', '.join(ROWS)}")
    rows = [run_trainer(r, args, device) for r in names]
    if args.ref != "none":
        rows += run_reference(Path(args.ref), rows[0]["joints"], rows[0]["frames"], args.batch)
    ref = {r["row"]: r["seq_per_s"] for r in rows if r["row"].startswith("ref")}
    for r in rows:
        for name in ("naive", "fast"):
            if f"ref {name}" in ref:
                r[f"x_ref_{name}"] = r["seq_per_s"] / ref[f"ref {name}"]
    result = {
        "benchmark": "xmae_train_throughput",
        "env": describe(device),
        "command": " ".join(sys.argv),
        "rows": rows,
    }
    path = write_result("train_throughput", result, args.json_out)
    print_table(
        f"XMAE training throughput, {result['env'].get('gpu', result['env'].get('cpu'))}, "
        f"{rows[0]['joints']} joints x {rows[0]['frames']} frames, batch {args.batch}",
        rows,
        [
            ("row", "path"),
            ("precision", "precision"),
            ("steps", "steps"),
            ("ms_per_step", "ms/step"),
            ("seq_per_s", "seq/s"),
            ("host_ms_between_steps", "host ms between steps"),
            ("x_ref_naive", "x ref naive"),
            ("x_ref_fast", "x ref fast"),
        ],
    )
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
