"""`mocapfix fix` as a library: a checkpoint -> a Fixer (fixers.py), a recording's clips -> windows
at the model's fps, blended back (windowing.py), merged with the input by mode (clips.py).

    from mocapfix.fix import load_fixer, fix_clips
    fixer = load_fixer("model.ckpt")
    fixed, report = fix_clips(clips, fixer, mode="infill")
"""

from mocapfix.fix.clips import MODES, FixReport, fix_clips, map_joints, measure_recordings, rotation_clips
from mocapfix.fix.fixers import load_fixer

__all__ = ["MODES", "FixReport", "fix_clips", "load_fixer", "map_joints", "measure_recordings", "rotation_clips"]
