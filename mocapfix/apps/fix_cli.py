"""`mocapfix fix INPUT... --ckpt CKPT`: clean motion files with a trained checkpoint.

Per file: read (any format the data module reads), fix (mocapfix.fix), write positions in the
input's layout (a BVH input comes back as a BVH in its own hierarchy: a rotation model's
rotations, or a positions model's positions through inverse kinematics), one report line. A bad
file is one error line and the others still run; the exit code is 1 when any file failed.
Outputs are written to a temporary file and renamed: never half a file, never over the input,
never over an existing file without --force.
"""

from __future__ import annotations

import argparse
import functools
import signal
import sys
import threading
from pathlib import Path

import torch

from mocapfix.apps.fix_run import fix_files, parse_shard
from mocapfix.fix import MODES
from mocapfix.fix.fixers import PRECISIONS
from mocapfix.io import add_read_arguments, read_options
from mocapfix.io.joint_map import read_joint_map
from mocapfix.pretrained import pretrained_path


def _device(name: str) -> str:
    if name == "auto":
        return "cuda" if torch.cuda.is_available() else "cpu"
    return name


def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(
        prog="mocapfix fix",
        description=__doc__.split("\n")[0],
        epilog="example: mocapfix fix take.bvh --model xmae-cpu-bandai -o take.fixed.bvh   "
        "(a folder: mocapfix fix takes/ --model xmae-cpu-bandai --out-dir fixed/)",
    )
    ap.add_argument("paths", nargs="+", metavar="INPUT", help="motion files or folders")
    which = ap.add_mutually_exclusive_group(required=True)
    which.add_argument(
        "--ckpt",
        help="a mocapfix checkpoint (XMAE, Motion-DVAE's denoising stage, a jitter remover, a learned correction)",
    )
    which.add_argument("--model", help="a model shipped with mocapfix (`mocapfix models` lists them)")
    where = ap.add_mutually_exclusive_group()
    where.add_argument("-o", "--out", default=None, help="output file (one input file only)")
    where.add_argument("--out-dir", default=None, help="folder for the outputs (default: <input>.fixed.<ext>)")
    ap.add_argument(
        "--mode",
        default=None,
        choices=MODES,
        help="infill: fill missing tokens only; denoise: replace observed tokens; both: both "
        "(default: denoise for a jitter remover, else infill)",
    )
    ap.add_argument("--device", default="auto", choices=("auto", "cpu", "cuda"))
    ap.add_argument("--batch-size", type=int, default=64, help="windows per model call")
    ap.add_argument(
        "--precision",
        default="auto",
        choices=PRECISIONS,
        help="XMAE's matmuls: auto = bf16 on GPUs and CPUs with native bf16, else fp32",
    )
    ap.add_argument("--overlap", type=float, default=0.5, help="fraction of a window shared by neighbours, [0, 1)")
    ap.add_argument("--force", action="store_true", help="overwrite existing outputs")
    ap.add_argument(
        "--resume",
        action="store_true",
        help="skip inputs whose output exists (outputs appear whole under their name): rerun a killed run",
    )
    ap.add_argument(
        "--jobs",
        type=int,
        default=None,
        help="files fixed side by side, each worker with its share of the cores (default: the cores, "
        "if each gets 8 files; 1 on a GPU)",
    )
    ap.add_argument(
        "--shard",
        default="0/1",
        metavar="i/N",
        help="fix only part i of N of the files (e.g. a SLURM array: --shard $SLURM_ARRAY_TASK_ID/N); docs/scaling.md",
    )
    ap.add_argument(
        "--render",
        action="store_true",
        help="also write OUTPUT.gif (the input beside the output) and OUTPUT.holes.png (joints x time)",
    )
    ap.add_argument(
        "--library",
        nargs="+",
        default=None,
        metavar="TAKES",
        help="files or folders of other takes of the same performers and rig: holes are also filled "
        "from the moments of them that match (motion matching), where the recording says it is better",
    )
    ap.add_argument(
        "--library-index",
        default=None,
        metavar="FILE",
        help="keep the --library takes, read and put on the model's joints, in FILE: a later run with the same "
        "takes and model reads FILE instead (made again when a take changed)",
    )
    ap.add_argument("--json", action="store_true", help="one JSON object per file instead of the report line")
    ap.add_argument(
        "--progress",
        default="auto",
        choices=("auto", "always", "never"),
        help="auto: on a terminal, or for inputs over 10 minutes",
    )
    ap.add_argument(
        "--joint-map",
        default=None,
        help="YAML, `input name: model name` per line, for joints the automatic matching misses",
    )
    add_read_arguments(ap)
    return ap


def main(argv: list[str] | None = None) -> int:
    ap = build_parser()
    args = ap.parse_args(argv)
    if args.out and (len(args.paths) > 1 or Path(args.paths[0]).is_dir()):
        ap.error("-o/--out takes one input file; use --out-dir for several")
    if args.out_dir and Path(args.out_dir).exists() and not Path(args.out_dir).is_dir():
        ap.error(f"--out-dir {args.out_dir} is a file, not a folder")
    if args.batch_size < 1:
        ap.error("--batch-size must be at least 1")
    if args.jobs is not None and args.jobs < 1:
        ap.error("--jobs must be at least 1")
    try:
        shard = parse_shard(args.shard)
    except ValueError as e:
        ap.error(str(e))
    if args.library_index and not args.library:
        ap.error("--library-index keeps the takes of --library: name them too (--library TAKES)")
    if not 0.0 <= args.overlap < 1.0:
        ap.error("--overlap must be in [0, 1)")
    if args.device == "cuda" and not torch.cuda.is_available():
        ap.error("--device cuda, but no CUDA device is available")
    try:
        joint_map = read_joint_map(args.joint_map) if args.joint_map else None
        ckpt = str(pretrained_path(args.model)) if args.model else args.ckpt
    except ValueError as e:  # MotionFileError is one
        print(f"error: {e}", file=sys.stderr)
        return 1
    run = functools.partial(
        fix_files,
        args.paths,
        ckpt,
        args.out,
        args.out_dir,
        args.mode,
        _device(args.device),
        args.batch_size,
        args.overlap,
        args.force,
        args.source,
        args.progress,
        args.json,
        precision=args.precision,
        joint_map=joint_map,
        render_gif=args.render,
        joint_map_path=args.joint_map,
        jobs=args.jobs,
        shard=shard,
        resume=args.resume,
        library=args.library,
        library_index=args.library_index,
        **read_options(args),
    )
    return _until_stopped(run)


def _until_stopped(run) -> int:
    """run() -> its exit code; Ctrl-C and SIGTERM end it with theirs and a line saying so.
    SIGTERM (a scheduler's time limit, `kill`) ends the run the way Ctrl-C does: as an exception,
    so the output being written loses its temporary file (atomic_write) instead of the process
    dying with it on disk."""
    previous = (
        signal.signal(signal.SIGTERM, _terminated) if threading.current_thread() is threading.main_thread() else None
    )
    try:
        return run()
    except KeyboardInterrupt:  # outputs are renamed into place whole: nothing half-written is left
        print(
            "mocapfix fix: interrupted (outputs written so far are whole; the one in progress was not written)",
            file=sys.stderr,
        )
        return 130
    except _Terminated:
        print(
            "mocapfix fix: stopped by SIGTERM (outputs written so far are whole; the one in progress was not written)",
            file=sys.stderr,
        )
        return 128 + signal.SIGTERM
    finally:
        if previous is not None:
            signal.signal(signal.SIGTERM, previous)


class _Terminated(BaseException):
    """SIGTERM, raised where the program is: not an Exception, so no per-file handler swallows it."""


def _terminated(signum, frame):
    raise _Terminated()


if __name__ == "__main__":
    sys.exit(main())
