"""`make demo`: train configs/xmae.yaml briefly on the CPU, on the embedded synthetic data,
then say where the TensorBoard logs and the checkpoint went."""
from __future__ import annotations

import argparse
from pathlib import Path

CONFIG = Path(__file__).resolve().parents[1] / "configs" / "xmae.yaml"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="mocapfix demo", description=__doc__)
    ap.add_argument("--steps", type=int, default=200, help="optimiser steps (default 200: a few minutes on 2 cores)")
    ap.add_argument("--experiment", default="demo")
    args = ap.parse_args(argv)
    if not CONFIG.exists():
        raise SystemExit(f"mocapfix demo: {CONFIG} not found (run it from a checkout of the repository)")
    from mocapfix.cli import main as cli_main
    print(f"mocapfix demo: training XMAE ({CONFIG.name}) for {args.steps} steps on the CPU, synthetic data")
    return cli_main(["fit", "--config", str(CONFIG), "--experiment", args.experiment,
                     "--trainer.max_steps", str(args.steps), "--trainer.accelerator", "cpu",
                     "--trainer.val_check_interval", str(min(100, args.steps)),
                     "--model.init_args.warmup_steps", str(max(1, args.steps // 10))])
