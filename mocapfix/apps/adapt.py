"""`mocapfix adapt FOLDER... --model NAME`: fine-tune an XMAE on your own takes, a few CPU minutes.

A model trained on other people's motion learns their proportions and their rig's joint
placement. Adapting continues its training objective (masking and displacing tokens, XMAE
section 3) on the observed tokens of your recordings: no labels and no clean data needed, the
holes in your takes are never read. The adapted model is saved (weights only) and reused with
`mocapfix fix INPUT --ckpt ADAPTED`; `fix` still measures on each recording whether it beats the
classical fills there (docs/fix.md), so adapting can only help where it helped.

    mocapfix adapt takes/ --model xmae-many --minutes 5 -o my-studio.ckpt
    mocapfix fix takes/ --ckpt my-studio.ckpt --out-dir fixed/
"""

from __future__ import annotations

import argparse
import math
import os
import sys
from pathlib import Path

from mocapfix.apps.console import quiet_lightning
from mocapfix.core.clip import MotionFileError, shown
from mocapfix.core.skeleton import preset
from mocapfix.io import add_read_arguments

# What adapting keeps from the starting model's training: the objective and the network. The
# body augmentations stay off (these are the performers the model will meet), and so does
# compiling (minutes on a CPU).
OBJECTIVE = (
    "mask_ratio",
    "displace_ratio",
    "max_displacement_m",
    "clean_loss_ratio",
    "gap_ratio",
    "hole_ratio",
    "max_hole_s",
    "rotate_augment",
)


def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(
        prog="mocapfix adapt",
        description="Fine-tune a trained XMAE on your own takes (its training objective on their observed tokens).",
        epilog="example: mocapfix adapt takes/ --model xmae-many --minutes 5 -o my-studio.ckpt",
    )
    ap.add_argument("inputs", nargs="+", help="folders or files of your takes (any format `fix` reads)")
    which = ap.add_mutually_exclusive_group(required=True)
    which.add_argument("--model", help="a shipped model to start from (`mocapfix models`)")
    which.add_argument("--ckpt", help="a checkpoint to start from")
    ap.add_argument("--minutes", type=float, default=5.0, help="training time (default 5)")
    ap.add_argument("--lr", type=float, default=1e-4, help="learning rate after a 50-step warm-up (default 1e-4)")
    ap.add_argument("--batch-size", type=int, default=32)
    ap.add_argument("-o", "--out", default=None, help="the adapted checkpoint (default checkpoints/adapt/<model>.ckpt)")
    ap.add_argument("--seed", type=int, default=0)
    add_read_arguments(ap)
    return ap


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    if not (0 < args.minutes <= 24 * 60) or not math.isfinite(args.minutes):
        print(f"mocapfix adapt: --minutes {args.minutes}: give a time between 0 and 1440 minutes", file=sys.stderr)
        return 2
    try:
        # the run ends on its time limit: Lightning's "Time limit reached ... Signaling Trainer to stop" is
        # the plan, and the steps taken are said below
        with quiet_lightning({"lightning.pytorch.utilities.rank_zero": (r"Time limit reached\. ",)}):
            out = adapt(args)
    except (MotionFileError, ValueError) as e:
        print(f"mocapfix adapt: {e}", file=sys.stderr)
        return 1
    print(f"adapted model: {shown(out)}\nuse it: mocapfix fix INPUT --ckpt {shown(out)}")
    return 0


def adapt(args) -> Path:
    import lightning as L
    from lightning.pytorch.loggers import TensorBoardLogger

    from mocapfix.data.datamodule import MotionDataModule
    from mocapfix.models.checkpoint import (
        hyperparameters,
        named_kind,
        read_checkpoint,
        save_checkpoint,
        set_fill_policy,
        weights_checkpoint,
    )
    from mocapfix.pretrained import pretrained_path
    from mocapfix.training.xmae_module import XMAEModule

    start = str(pretrained_path(args.model)) if args.model else args.ckpt
    ckpt = read_checkpoint(start)
    kind = named_kind(ckpt)
    if kind != "xmae":
        raise ValueError(f"{start}: adapt fine-tunes XMAE checkpoints; this one holds {kind}")
    hp = hyperparameters(ckpt)
    out = output_path(args, start)

    L.seed_everything(args.seed, verbose=False)
    fps, frames = float(hp["window_fps"]), int(hp["window_frames"])
    # Every recording onto the model's body; about a tenth of the files (by a hash of the name;
    # often none of a few files) is held out, where the fill policy is measured on takes adapting
    # did not see. Without one, the starting model's policy is kept (fix measures on each file anyway).
    files = args.inputs
    data = MotionDataModule(
        source=_source(files, args.source),
        path=files if len(files) > 1 else files[0],
        body="body21" if tuple(hp["skeleton"]["joint_names"]) == preset("body21").joint_names else None,
        fps=fps,
        window_s=frames / fps,
        stride_s=0.1,
        unit=args.unit,
        up_axis=args.up_axis,
        val_fraction=0.1,
        test_fraction=0.0,
        batch_size=args.batch_size,
        eval_batch_size=256,
    )
    data.setup("fit")
    has_val = len(data.datasets["val"]) > 0
    module = XMAEModule(
        init_weights=start,
        lr=args.lr,
        warmup_steps=50,
        total_steps=10**9,  # a constant rate after the warm-up: the run ends on time, not on a step count
        calibration_windows=256 if has_val else 0,
        **{k: hp[k] for k in OBJECTIVE if k in hp},
    )
    trainer = L.Trainer(
        max_time={"minutes": args.minutes},
        max_epochs=-1,
        accelerator="auto",
        devices=1,
        logger=TensorBoardLogger("logs", name="adapt", default_hp_metric=False),
        enable_checkpointing=False,
        limit_val_batches=0,  # measured once, at the end
        num_sanity_val_steps=0,
        log_every_n_steps=10,
        enable_model_summary=False,
    )
    trainer.fit(module, datamodule=data)
    if has_val:  # the fill policy on the held-out takes
        trainer.limit_val_batches = 1.0
        trainer.validate(module, datamodule=data, verbose=False)
    module.net.float()
    saved = weights_checkpoint("xmae", module.net, module.hparams, global_step=trainer.global_step, adapted_from=start)
    if module.fill_policy is not None:
        set_fill_policy(saved, module.fill_policy.to_dict())
    save_checkpoint(out, saved)  # a temporary file beside out, renamed over it: never written through a link
    print(f"adapted {trainer.global_step} steps on {sum(len(c) for c in data.clips.values())} takes")
    return out


def output_path(args, start: str) -> Path:
    """Where the adapted checkpoint goes: --out, or checkpoints/adapt/<model or checkpoint
    name>.ckpt. Never one of adapt's inputs (the starting checkpoint, a take): an --out that is
    one, by any name (a link, a hard link), is a ValueError; a default that is one moves to
    <name>-adapted.ckpt beside it."""
    inputs = [Path(start), *map(Path, args.inputs)]
    if args.out:
        out = Path(args.out)
        if out.suffix != ".ckpt":
            raise ValueError(f"--out {out}: give a .ckpt file name")
        if out.is_dir():
            raise ValueError(f"--out {out}: is a folder; give a .ckpt file name")
        if any(_same_file(out, p) for p in inputs):
            raise ValueError(f"--out {out}: is the checkpoint adapt starts from, or one of its inputs; give another")
        return out
    name = args.model or Path(args.ckpt).stem
    out = Path("checkpoints") / "adapt" / f"{name}.ckpt"
    while any(_same_file(out, p) for p in inputs):
        out = out.with_name(f"{out.stem}-adapted.ckpt")
    return out


def _same_file(a: Path, b: Path) -> bool:
    """Whether two names are one file: the same inode (links, hard links, other spellings of the
    path), or, while either does not exist yet, the same resolved path."""
    try:
        return os.path.samefile(a, b)
    except OSError:  # one of them does not exist (or cannot be read): compare where the names lead
        return a.resolve() == b.resolve()


def _source(inputs: list[str], source: str) -> str:
    """The data module's source for --source auto: bvh when every motion file is a BVH, else
    positions files (.npz / .csv)."""
    if source != "auto":
        return source
    from mocapfix.io import list_motion_files

    files = [f for p in inputs for f in list_motion_files(p, "auto")]
    return "bvh" if files and all(f.suffix.lower() == ".bvh" for f in files) else "positions"
