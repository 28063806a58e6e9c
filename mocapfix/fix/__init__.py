"""`mocapfix fix` as a library: a checkpoint -> a Fixer (fixers.py) that fixes the clips of a file
itself (positions, rotations or jitter), a file -> what the command writes (files.py).

    from mocapfix.fix import fix_file, load_fixer
    fixer = load_fixer("model.ckpt")
    fixed = fix_file("take.bvh", fixer)        # or fix_clips(clips, fixer, mode="infill")
    fixed.write("take.fixed.bvh")              # the bytes `mocapfix fix take.bvh` writes
    print(fixed.report.as_dict())              # its --json report
"""

from mocapfix.fix.clips import fix_clips
from mocapfix.fix.files import FixedFile, fix_file
from mocapfix.fix.fixer import MODES, Fixer, FixOptions
from mocapfix.fix.fixers import load_fixer
from mocapfix.fix.joints import map_joints
from mocapfix.fix.measure import measure_recordings, motion_library
from mocapfix.fix.report import FixReport
from mocapfix.fix.rotations import rotation_clips

__all__ = [
    "MODES",
    "FixOptions",
    "FixReport",
    "FixedFile",
    "Fixer",
    "fix_clips",
    "fix_file",
    "load_fixer",
    "map_joints",
    "measure_recordings",
    "motion_library",
    "rotation_clips",
]
