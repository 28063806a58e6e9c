"""What `mocapfix fix FOLDER --library DIR` costs on this machine: the 14 CMU strangers of
bench/fix_strangers_cmu.py holed with one kind of hole (4 per take), the fill policy measured
over them with the library searched, then each take fixed, as fix does. Prints the seconds of
each step; no training is involved, so this is what the library costs a user.

    python bench/fix_library_cost.py --library /other/takes/of/the/same/people --part full --gap 0.7
"""

from __future__ import annotations

import argparse
import time

from fix_strangers_cmu import DEFAULT_CMU, PARTS

from mocapfix.core.skeleton import preset
from mocapfix.evaluation.recording import spread_holes, with_holes
from mocapfix.fix import fix_clips, measure_recordings, motion_library
from mocapfix.fix.fixers import load_fixer
from mocapfix.io import list_motion_files, read_motion
from mocapfix.pretrained import pretrained_path
from mocapfix.rig.mapping import onto_skeleton


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--data", default=str(DEFAULT_CMU))
    ap.add_argument("--library", required=True, help="a folder of other takes of the same performers")
    ap.add_argument("--model", default="xmae-cpu-bandai")
    ap.add_argument("--part", choices=list(PARTS), default="full")
    ap.add_argument("--gap", type=float, default=0.7, help="hole length, seconds")
    ap.add_argument("--min-seconds", type=float, default=8.0)
    args = ap.parse_args(argv)
    fixer = load_fixer(str(pretrained_path(args.model)), "cpu")
    body = preset("body21")
    clips = (read_motion(f)[0] for f in list_motion_files(args.data, "bvh"))
    takes = [onto_skeleton(c, body) for c in clips if c.duration_s >= args.min_seconds]
    joints = body.groups.get(PARTS[args.part])
    holed = []
    for c in takes:
        hidden = spread_holes(c.num_frames, body.num_joints, c.fps, args.gap, joints)
        holed.append(c.replace(positions=with_holes(c.positions, hidden)))
    recordings = [[c] for c in holed]

    t0 = time.perf_counter()
    extra = [[onto_skeleton(read_motion(f)[0], body)] for f in list_motion_files(args.library, "bvh")]
    extra_library = motion_library(extra, fixer)
    t1 = time.perf_counter()
    measured = measure_recordings(recordings, fixer, "infill", library=extra_library)
    t2 = time.perf_counter()
    own = motion_library(recordings, fixer)
    library = extra_library.including(own.takes, own.keys)
    for c in holed:
        fix_clips([c], fixer, "infill", measured=measured, library=library)
    t3 = time.perf_counter()
    seconds = sum(c.duration_s for c in takes)
    print(
        f"{len(takes)} takes ({seconds:.0f} s of motion), {args.part} {args.gap:g}-s holes, library of"
        f" {len(extra)} takes: read {t1 - t0:.0f} s, policy measured {t2 - t1:.0f} s,"
        f" takes fixed {t3 - t2:.0f} s, total {t3 - t0:.0f} s"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
