"""`make demo`: train configs/xmae.yaml briefly on the CPU, on the embedded synthetic data,
then say where the TensorBoard logs and the checkpoint went."""
from __future__ import annotations

import argparse
from pathlib import Path

# configs/ sits beside the package in a checkout (and in an editable install); a `pip install .`
# copies the package alone, so then it is the checkout in the working folder, or --config.
CONFIG = Path(__file__).resolve().parents[1] / "configs" / "xmae.yaml"


def find_config(given: str | None) -> Path:
    for candidate in ([Path(given)] if given else [CONFIG, Path.cwd() / "configs" / "xmae.yaml"]):
        if candidate.is_file():
            return candidate
    raise SystemExit(f"mocapfix demo: {given or 'configs/xmae.yaml'} not found (run it in a checkout of the "
                     "repository, or give --config)")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="mocapfix demo", description=__doc__)
    ap.add_argument("--steps", type=int, default=200, help="optimiser steps (default 200: a few minutes on 2 cores)")
    ap.add_argument("--experiment", default="demo")
    ap.add_argument("--config", default=None, help="default: configs/xmae.yaml of the checkout")
    args = ap.parse_args(argv)
    config = find_config(args.config)
    from mocapfix.cli import main as cli_main
    print(f"mocapfix demo: training XMAE ({config.name}) for {args.steps} steps on the CPU, synthetic data")
    return cli_main(["fit", "--config", str(config), "--experiment", args.experiment,
                     "--trainer.max_steps", str(args.steps), "--trainer.accelerator", "cpu",
                     "--trainer.val_check_interval", str(min(100, args.steps)),
                     "--model.init_args.warmup_steps", str(max(1, args.steps // 10)),
                     # the fill policy from a few val windows: the paper-sized network is slow on a CPU
                     "--model.init_args.calibration_windows", "32"])
