"""`make demo`: train the packaged xmae config briefly on the CPU, on the embedded synthetic
data, then say where the TensorBoard logs and the checkpoint went."""

from __future__ import annotations

import argparse


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="mocapfix demo", description=__doc__)
    ap.add_argument("--steps", type=int, default=200, help="optimiser steps (default 200: a few minutes on 2 cores)")
    ap.add_argument("--experiment", default="demo")
    ap.add_argument("--config", default="xmae", help="a packaged config's name or a file (default: xmae)")
    args = ap.parse_args(argv)
    from mocapfix.apps.cli import run_lightning

    print(f"mocapfix demo: training XMAE ({args.config}) for {args.steps} steps on the CPU, synthetic data")
    return run_lightning(
        "fit",
        [
            "fit",
            "--config",
            args.config,
            "--experiment",
            args.experiment,
            "--trainer.max_steps",
            str(args.steps),
            "--trainer.accelerator",
            "cpu",
            "--trainer.val_check_interval",
            str(min(100, args.steps)),
            "--model.init_args.warmup_steps",
            str(max(1, args.steps // 10)),
            # the fill policy from a few val windows: the paper-sized network is slow on a CPU
            "--model.init_args.calibration_windows",
            "32",
        ],
    )
