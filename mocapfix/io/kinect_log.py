"""Kinect body-frame logs (`.skl`): one line per frame the SDK delivered, tab-separated, under a
header that names each column, as recording tools built on the Kinect SDK write them (e.g.
ranBernstein/GaitKinect, Kinect v1 and v2):

    timestamp  [framenum]  [other columns]  <Joint>_X  <Joint>_Y  <Joint>_Z  <Joint>_tracked  ...

The joints are the SDK's JointType names: Kinect v1's 20 (kinect20: HipCenter, Spine, ...) or
v2's 25 (kinect25: SpineBase, SpineMid, ...; some v2 logs call SpineShoulder by v1's name,
ShoulderCenter), in any column order; other columns (framenum, FloorPlane_A..D, a logger's
sensors) are kept as they are. Camera space: metres, y up. `_tracked` is the joint's tracking
state (0 not tracked, 1 inferred, 2 tracked): at or below min_confidence (default 0) the joint is
missing in that frame.

The timestamps put the frames on the camera's clock (v1 logs count milliseconds, v2's SDK 100-ns
ticks: told apart by the step, ~33 against ~333,333), at --fps or the rate told from the steps: a
frame the SDK dropped is a hole fix fills, a line on a tick already taken is read once (the
writer gives it its tick's positions where fix changed them). A pause of more than MAX_GAP_S (the
person left the view, the logger stopped) starts a new take: each stretch between pauses is one
clip (person_id "1", "2", ... in time order).

The writer puts fix's positions back into the file's own lines: every other cell, and every
position fix left alone, is the file's text as it was.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from mocapfix.core.clip import Clip, MotionFileError
from mocapfix.io.delimited import checked_stamps, numbers, write_cells
from mocapfix.io.keypoints import frame_slots, layout_skeleton_of, on_clock
from mocapfix.io.layouts import layout
from mocapfix.io.positions import _check_fps, _clips, _fps_from_times
from mocapfix.io.untrusted import read_text_lines

LAYOUTS = ("kinect25", "kinect20")  # v2 first: its joints include most of v1's names
ALIASES = {"SpineShoulder": "ShoulderCenter"}  # a v2 joint some logs name as v1 did
TICKS_PER_S, MS_PER_S = 1e7, 1e3
MAX_GAP_S = 1.0  # a pause longer than this starts a new take; shorter ones are dropped frames (holes)
FIELDS = ("X", "Y", "Z", "tracked")


def _columns(path: Path, header: list[str]):
    """header -> (the layout, (J, 4) column of each joint's X, Y, Z, tracked in the layout's order)."""
    named = {h: c for c, h in enumerate(header)}
    for name in LAYOUTS:
        lay = layout(name)
        joints = [n if f"{n}_X" in named else ALIASES.get(n, n) for n in lay.joint_names]
        if all(f"{n}_{f}" in named for n in joints for f in FIELDS):
            return lay, np.array([[named[f"{n}_{f}"] for f in FIELDS] for n in joints])
    found = sorted({h[:-2] for h in header if h.endswith("_X")})
    raise MotionFileError(
        path,
        f"not a Kinect v1 or v2 body log: its <joint>_X/_Y/_Z/_tracked columns name {len(found)} joints "
        f"({', '.join(found[:4])}{', ...' if len(found) > 4 else ''}), not Kinect's 20 or 25",
    )


def _seconds(path: Path, stamps: np.ndarray, rows: list[int]) -> tuple[np.ndarray, float]:
    """The timestamp column (rows: the file's 0-based line of each) -> (seconds from the first
    line, the seconds one unit of the column is: milliseconds or 100-ns ticks)."""
    steps = np.diff(checked_stamps(path, stamps, rows))
    per_s = TICKS_PER_S if len(steps) and np.median(steps) > 1e4 else MS_PER_S
    return (stamps - stamps[0]) / per_s, 1.0 / per_s


def read_kinect_log(
    path, min_confidence: float = 0.0, unit: str = "auto", up_axis: str = "auto", fps: float | None = None, groups=None
) -> list[Clip]:
    path = Path(path)
    lines, newline = read_text_lines(path, "Kinect log")
    header = lines[0].split("\t") if lines else []
    if "timestamp" not in header:
        raise MotionFileError(path, "not a Kinect body log: no tab-separated header with a 'timestamp' column")
    lay, columns = _columns(path, header)
    rows = [k for k in range(1, len(lines)) if lines[k].strip()]  # (T,) the line of each frame
    if not rows:
        raise MotionFileError(path, "a header and no frames")
    wanted = [header.index("timestamp"), *columns.ravel()]
    values = numbers(path, lines, rows, wanted, "\t", len(header), "a timestamp or joint cell")  # (T, 1 + 4 J)
    seconds, resolution = _seconds(path, values[:, 0], rows)
    joints = values[:, 1:].reshape(len(rows), -1, 4)  # (T, J, 4) x, y, z, tracked
    # each stretch between pauses is a take on its own clock
    bounds = np.concatenate([[0], np.flatnonzero(np.diff(seconds) > MAX_GAP_S) + 1, [len(rows)]])
    if fps is None:
        if len(rows) < 2:
            raise MotionFileError(path, "one frame: no steps to tell the frame rate from; give --fps")
        take_of = np.repeat(np.arange(len(bounds) - 1), np.diff(bounds))  # (T,) no step across a pause
        fps = _fps_from_times(path, seconds, np.arange(len(rows)), take_of, resolution)
    fps = _check_fps(path, fps)
    seen = joints[..., 3] > min_confidence  # (T, J)
    if not seen.any():
        raise MotionFileError(path, f"no joint tracked above state {min_confidence:g} in any frame")
    xyz = np.where(seen[..., None], joints[..., :3], np.nan)
    skeleton, order = layout_skeleton_of(path, lay, groups)
    takes = []  # (its frames on the clock, the line of each row, the clock frame of each row)
    for a, b in zip(bounds[:-1], bounds[1:]):
        slots = frame_slots(path, seconds[a:b], b - a, fps)
        takes.append((on_clock(xyz[a:b], slots), np.array(rows[a:b]), slots))
    frames = max(len(c) for c, _, _ in takes)
    raw = np.full((len(takes), frames, len(order), 3), np.nan)  # (P, N, J, 3) padded to the longest take
    for p, (clock, _, _) in enumerate(takes):
        raw[p, : len(clock)] = clock
    people = [
        {"layout": lay.name, "joint_order": order, "person_id": str(p + 1), "cells_at": list(zip(lines_of, slots))}
        for p, (_, lines_of, slots) in enumerate(takes)
    ]
    clips = _clips(path, raw[:, :, order], fps, skeleton, unit, "m", up_axis, "y", "keypoints-kinect-log", people)
    out = []
    for c, (clock, _, _) in zip(clips, takes):
        c = c.replace(positions=c.positions[: len(clock)])  # each take its own length
        c.meta.update(file_lines=lines, newline=newline, xyz_columns=columns[:, :3])
        out.append(c)
    return out


def write_kinect_log(path, clips: list[Clip], inputs: list[Clip]) -> Path:
    """fix's positions put back into the file's lines (delimited.write_cells): the X, Y, Z cells of
    a joint whose position fix changed get the new numbers on every line of its frame."""
    return write_cells(path, clips, inputs, "\t")
