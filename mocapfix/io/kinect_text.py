"""Kinect v1 skeletons as the action-recognition datasets publish them, as whitespace-separated
text (.txt), told apart by the numbers on a line:

- UTKinect-Action3D's `joints_sXX_eXX.txt` (61 numbers a line): the camera's frame number, then
  the 20 joints' x y z in the SDK's order (kinect20), metres, y up, the SDK's right-handed camera
  space. The frame numbers count the Kinect's 30 frames a second (a walk's hips cover 1.75 m in
  138 of them: 0.38 m/s at 30 fps), and the rows come irregularly, 2 to 12 frames apart (s01_e01:
  mostly 4), some repeated. The rows are put on a clock of the numbers' common step (their
  greatest common divisor: 2, so 15 fps): a row exactly where its number says, the frames
  between rows holes fix fills (and does not write: the file has no line for them). A repeated
  number is read once, its first row (in 515 of the dataset's 542 repeats the first continues the
  rows before; 4 repeats are another body 0.3 m or more away), and its other rows are written
  back as they were. --fps is the frame numbers' rate (a Kinect's 30), asked for, never assumed.
- MSR Action3D's `aXX_sXX_eXX_skeleton3D.txt` (4 numbers a line): 20 lines a frame, one a joint
  (x y z c) in the dataset's own order (MSR_ORDER), metres, y up, x along the
  depth image's columns: a left-handed frame, read with x negated (a body whose right shoulder
  is on its right; written back negated again). The 4th number is not a tracking state: the hip
  centre, spine, shoulder centre and feet read 0 in every frame of a01_s01_e01 while holding their
  places, so it is kept as written and never makes a joint missing. fps: the dataset's paper
  says about 15. Its `_skeleton.txt` twin holds
  screen coordinates (pixels and depth), not positions: a one-line error names the 3D file.
  A joint at 0, 0, 0 (the camera's own origin) was not tracked: missing in that frame (MSR
  Action3D writes untracked frames as zeros: 20 of its 567 files, one of them all zeros).

Both are one person, no timestamps. The writer puts fix's positions back into the file's lines:
only the numbers of a joint fix changed are new, every other character is the file's.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from mocapfix.core.clip import Clip, MotionFileError
from mocapfix.io.files import atomic_write
from mocapfix.io.keypoints import file_tokens, layout_skeleton_of, on_clock
from mocapfix.io.layouts import layout
from mocapfix.io.positions import _check_fps, _clips
from mocapfix.io.untrusted import read_text_lines

UTKINECT_FIELDS = 1 + 20 * 3
MSR_FIELDS = 4
# MSR Action3D's joint order as kinect20's names (the dataset's drawskt.m: 1 right shoulder, 2 left
# shoulder, ... 20 head, 1-based there), checked on 24 of its takes: the pairs whose distance
# varies least over a take chain up exactly as these names' bones do.
MSR_ORDER = (
    "ShoulderRight", "ShoulderLeft", "ShoulderCenter", "Spine", "HipRight", "HipLeft", "HipCenter",
    "ElbowRight", "ElbowLeft", "WristRight", "WristLeft", "HandRight", "HandLeft", "KneeRight", "KneeLeft",
    "AnkleRight", "AnkleLeft", "FootRight", "FootLeft", "Head",
)  # fmt: skip
SCREEN_LIMIT = 20.0  # a "position" beyond this many metres in x or y is a pixel: MSR's screen coordinates
_NUMBER = re.compile(r"\S+")


def kinect_text_kind(first_line: str) -> str | None:
    """ "utkinect" or "msr" by the numbers on a file's first line, None for neither."""
    n = len(first_line.split())
    return "utkinect" if n == UTKINECT_FIELDS else "msr" if n == MSR_FIELDS else None


def _numbers(path: Path, lines: list[str], rows: list[int], fields: int) -> np.ndarray:
    """The lines `rows` (0-based) as (len(rows), fields) numbers; a line of another count or a
    cell that is not a number is the file's one-line error naming the line."""
    out = np.empty((len(rows), fields))
    for r, k in enumerate(rows):
        cells = lines[k].split()
        if len(cells) != fields:
            raise MotionFileError(path, f"line {k + 1} has {len(cells)} numbers, the file's lines {fields}")
        try:
            out[r] = [float(c) for c in cells]
        except ValueError:
            raise MotionFileError(path, f"line {k + 1}: a cell that is not a number") from None
    return out


def _utkinect(path: Path, lines: list[str], rows: list[int]) -> tuple[np.ndarray, np.ndarray, list[int], int]:
    """-> ((N, 20, 3) on the clock, (T,) the clock frame of each row, its joints' field offsets,
    the camera frames a clock frame is)."""
    values = _numbers(path, lines, rows, UTKINECT_FIELDS)
    number = values[:, 0]
    with np.errstate(invalid="ignore"):
        whole = (number == np.round(number)) & (np.abs(number) < 1e12)  # NaN and inf: False
    if not whole.all():
        bad = int(np.argmax(~whole))
        raise MotionFileError(path, f"line {rows[bad] + 1}: not a frame number (a whole number under 10^12)")
    steps = np.diff(number)
    if (steps < 0).any():
        raise MotionFileError(path, f"line {rows[int(np.argmax(steps < 0)) + 1] + 1}: the frame number goes back")
    moves = steps[steps > 0].astype(np.int64)
    step = int(np.gcd.reduce(moves)) if len(moves) else 1  # every row on a frame of the clock
    slots = ((number - number[0]) // step).astype(np.int64)
    if slots[-1] + 1 > 20 * len(rows) + 100:
        raise MotionFileError(path, f"frame numbers span {slots[-1] + 1} rows of {step} frames for {len(rows)} lines")
    xyz = values[:, 1:].reshape(len(rows), 20, 3)
    return on_clock(xyz, slots), slots, [1 + 3 * j for j in range(20)], step


def _msr(path: Path, lines: list[str], rows: list[int]) -> tuple[np.ndarray, np.ndarray, list[int], int]:
    if len(rows) % 20:
        raise MotionFileError(path, f"{len(rows)} joint lines: MSR Action3D has 20 a frame")
    values = _numbers(path, lines, rows, MSR_FIELDS).reshape(-1, 20, MSR_FIELDS)  # (T, 20, 4) MSR order
    with np.errstate(invalid="ignore"):
        if np.nanmedian(np.abs(values[..., :2])) > SCREEN_LIMIT:
            raise MotionFileError(
                path,
                "MSR Action3D screen coordinates (pixels and depth), not positions: read the take's _skeleton3D.txt",
            )
    xyz = values[..., :3] * np.array([-1.0, 1.0, 1.0])  # x along the image's columns: left-handed
    return xyz, np.arange(len(xyz)), [0] * 20, 1


def read_kinect_text(
    path, unit: str = "auto", up_axis: str = "auto", fps: float | None = None, groups=None
) -> list[Clip]:
    path = Path(path)
    lines, newline = read_text_lines(path, "skeleton text file")
    rows = [k for k, line in enumerate(lines) if line.strip()]
    if not rows:
        raise MotionFileError(path, "empty file")
    kind = kinect_text_kind(lines[rows[0]])
    if kind is None:
        raise MotionFileError(
            path,
            f"{len(lines[rows[0]].split())} numbers on the first line: not UTKinect-Action3D joints "
            f"({UTKINECT_FIELDS}) nor MSR Action3D skeleton3D ({MSR_FIELDS})",
        )
    if fps is None:
        rate = "the rate its frame numbers count at (a Kinect's: 30)" if kind == "utkinect" else "MSR Action3D's: 15"
        raise MotionFileError(path, f"a skeleton text file holds no frame rate: give --fps, {rate}")
    clock, slots, offsets, step = (_utkinect if kind == "utkinect" else _msr)(path, lines, rows)
    fps = _check_fps(path, fps / step)
    clock[(clock == 0).all(-1)] = np.nan  # the camera's own origin: a joint not tracked (MSR's frames of zeros)
    if np.isnan(clock).all():
        raise MotionFileError(path, "no joint tracked in any frame (every position 0, 0, 0)")
    lay = layout("kinect20")
    names = lay.joint_names if kind == "utkinect" else MSR_ORDER
    to_layout = [names.index(n) for n in lay.joint_names]  # layout joint k is the file's joint to_layout[k]
    skeleton, order = layout_skeleton_of(path, lay, groups)
    file_joint = [to_layout[j] for j in order]  # skeleton joint k's place in the file's order
    meta = {
        "layout": lay.name,
        "joint_order": order,  # skeleton joint k is layout joint order[k], as for every keypoint reader
        "file_joints": to_layout,
        "kind": kind,
        "lines": rows,
        "slots": slots.tolist(),
        "field_offsets": offsets,
        "file_lines": lines,
        "newline": newline,
    }
    (clip,) = _clips(
        path, clock[None][:, :, file_joint], fps, skeleton, unit, "m", up_axis, "y", "keypoints-text", [meta]
    )
    return [clip]


def write_kinect_text(path, clips: list[Clip], inputs: list[Clip]) -> Path:
    """fix's positions put back into the file's lines (inputs: the clip as read): the x y z of a
    joint fix changed get new numbers on the line its frame was read from; every other character
    stays."""
    (clip,), (before,) = clips, inputs
    m = clip.meta
    lines = list(m["file_lines"])
    file_joint = np.asarray(m["file_joints"])[np.asarray(m["joint_order"])]  # skeleton joint k's in the file
    out, changed = file_tokens(clip, before, file_joint)  # (N, J, 3), (N, J) in the file's joint order
    if m["kind"] == "msr":
        out[..., 0] *= -1
    rows, slots, offsets = m["lines"], m["slots"], m["field_offsets"]
    for r, k in enumerate(rows):
        if m["kind"] == "utkinect":
            if r and slots[r] == slots[r - 1]:
                continue  # a repeated number: not read (sometimes a second body), kept as written
            t, joints = slots[r], np.flatnonzero(changed[slots[r]])
        else:  # a line a joint
            t, j = divmod(r, 20)
            joints = [j] if changed[t, j] else []
        if not len(joints):
            continue
        spans = [s.span() for s in _NUMBER.finditer(lines[k])]
        text = lines[k]
        for j in sorted(joints, reverse=True):  # from the line's end: earlier spans keep their places
            for field in (2, 1, 0):
                a, b = spans[offsets[j] + field]
                text = text[:a] + f"{out[t, j, field]:.6f}" + text[b:]
        lines[k] = text
    newline = m["newline"]
    atomic_write(path, lambda f: f.write((newline.join(lines) + newline).encode("utf-8")))
    return Path(path)
