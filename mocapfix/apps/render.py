"""`mocapfix render INPUT [FIXED ...] -o OUT.gif|mp4|png`: a recording beside fix's outputs of it,
front and side views, filled and replaced tokens in their own colours, a time bar of the holes
(core/render.py). Any file fix reads; the first person of each unless --person.

The output is drawn into a temporary file beside it and moved into place whole: a failure (a full
disk) leaves no partial file and an existing output as it was; an existing file is replaced, a
link or a folder at the output's name is refused."""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

from mocapfix.core.clip import MotionFileError
from mocapfix.core.render import render, tracks_for
from mocapfix.io import add_read_arguments, frame_rate, read_motion, read_options
from mocapfix.io.files import check_output, claimed, staged, writing


def render_files(
    input_path,
    fixed_paths,
    out,
    start_s: float = 0.0,
    duration_s: float | None = None,
    fps: float | None = None,
    person: int = 0,
    take_fps: float | None = None,
    **read_options,
) -> Path:
    """Read, match and draw; MotionFileError (one line) for what a user can mend, an error
    writing the output (OSError) included. fps: the animation's; take_fps: the recordings' where a
    file has none of its own (a keypoint array)."""
    if take_fps is not None:
        read_options["fps"] = take_fps
    clips = read_motion(input_path, **read_options)
    if not 0 <= person < len(clips):
        raise MotionFileError(input_path, f"--person {person}: the file has {len(clips)} clip(s)")
    base = clips[person]
    fixed = []
    for p in fixed_paths:
        other = read_motion(p, **read_options)
        if person >= len(other):
            raise MotionFileError(p, f"--person {person}: the file has {len(other)} clip(s)")
        fixed.append((Path(p).name, other[person]))
    out = Path(out)
    try:
        tracks = tracks_for(base.replace(name=Path(input_path).name), fixed)
        with claimed(out), writing(out):  # a second render to out fails at once; a killed one's temporary files go
            check_output(out, replace=True)
            with staged([out], replace=True) as [temp]:
                return render(tracks, base.skeleton.limbs, base.fps, out, start_s, duration_s, fps, write_to=temp)
    except MotionFileError:
        raise
    except ValueError as e:
        raise MotionFileError(input_path, str(e)) from None


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(
        prog="mocapfix render",
        description=__doc__.split("\n")[0],
        epilog="example: mocapfix render take.bvh take.fixed.bvh -o take.gif --start 2 --duration 4",
    )
    ap.add_argument("input", help="the recording (the reference: holes and changes are against it)")
    ap.add_argument("fixed", nargs="*", help="fix's outputs of it, drawn beside it")
    ap.add_argument("-o", "--out", required=True, help=".gif (Pillow), .mp4 (needs ffmpeg) or .png (a filmstrip)")
    ap.add_argument("--start", type=float, default=0.0, help="seconds into the recording")
    ap.add_argument("--duration", type=float, default=None, help="seconds to draw (default: to the end)")
    ap.add_argument(
        "--fps", type=frame_rate, default=None, help="the animation's frame rate (default: the recording's, <= 30)"
    )
    ap.add_argument("--person", type=int, default=0, help="which clip of a multi-person file")
    ap.add_argument(
        "--take-fps", type=frame_rate, default=None, help="the recording's frame rate, for a file without one"
    )
    add_read_arguments(ap, fps=False)
    args = ap.parse_args(argv)
    if not (math.isfinite(args.start) and args.start >= 0):
        ap.error(f"--start must be seconds >= 0, got {args.start}")
    if args.duration is not None and not (math.isfinite(args.duration) and args.duration > 0):
        ap.error(f"--duration must be seconds > 0, got {args.duration}")
    try:
        out = render_files(
            args.input,
            args.fixed,
            args.out,
            args.start,
            args.duration,
            args.fps,
            args.person,
            source=args.source,
            take_fps=args.take_fps,
            **read_options(args, fps=False),
        )
    except (ValueError, OSError) as e:  # MotionFileError is a ValueError: "path: problem"
        print(f"error: {' '.join(str(e).split())}", file=sys.stderr)
        return 1
    print(f"wrote {out}")
    return 0
