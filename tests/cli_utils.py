"""Run `python -m mocapfix ...` in-process inside a scratch folder (logs/ and checkpoints/ land there)."""

from __future__ import annotations

import os
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
CONFIGS = REPO / "configs"

# A small network and batch for tests that exercise the training loop, not the model size.
TINY = [
    "--model.init_args.enc_dim",
    "32",
    "--model.init_args.enc_depth",
    "1",
    "--model.init_args.enc_mlp_dim",
    "64",
    "--model.init_args.dec_dim",
    "32",
    "--model.init_args.dec_depth",
    "1",
    "--model.init_args.dec_mlp_dim",
    "64",
    "--model.init_args.head_dim",
    "16",
]
SMALL_DATA = [
    "--data.synthetic_clips",
    "12",
    "--data.synthetic_seconds",
    "3",
    "--data.batch_size",
    "4",
    "--data.eval_batch_size",
    "8",
    "--data.cache_dir",
    "null",
    "--data.val_fraction",
    "0.25",
    "--data.test_fraction",
    "0.25",
]
QUIET = ["--trainer.enable_progress_bar", "false", "--trainer.enable_model_summary", "false"]


def run_cli(args: list[str], cwd: Path) -> int:
    from mocapfix.apps.main import main

    old = os.getcwd()
    os.chdir(cwd)
    try:
        return main([str(a) for a in args])
    finally:
        os.chdir(old)


def run_mocapfix(args, capsys) -> tuple[int, str, str]:
    """`mocapfix ARGS` in-process (pytest's capsys): its exit code and what it printed."""
    from mocapfix.apps.main import main

    capsys.readouterr()
    rc = main([str(a) for a in args])
    out = capsys.readouterr()
    return rc, out.out, out.err
