"""Azure Kinect body tracking as recording scripts write it to CSV (`.csv`; e.g. the example data
of justamad/PyMoCapViewer and the recordings of justamad/rpe-prediction):

    timestamp;body_idx;PELVIS (c);PELVIS (x);PELVIS (y);PELVIS (z);SPINE_NAVEL (c);...

Semicolon-separated, one row per body per frame the camera delivered: the device timestamp in
microseconds, the body's index, then each of the SDK's 32 joints (k4abt_joint_id_t names, any
column order) as its confidence level and position: 0 NONE (out of view: the SDK still writes a
position, its guess), 1 LOW (predicted from the rest), 2 MEDIUM, 3 HIGH; millimetres in
depth-camera axes (x right, y down, z away, up axis "-y" as the SDK's JSON). A joint at or below
min_confidence (default 0: NONE) is missing in that frame, a hole fix fills. The frames go on
the camera's clock (a frame the camera dropped is a hole); the body indices become people as in
the JSON (azure_kinect.people_clips).

The writer puts fix's positions back into the file's own lines: every other cell, and every
position fix left alone, is the file's text as it was.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from mocapfix.core.clip import Clip, MotionFileError
from mocapfix.io.azure_kinect import people_clips
from mocapfix.io.delimited import checked_stamps, numbers, write_cells
from mocapfix.io.layouts import layout
from mocapfix.io.untrusted import open_regular, read_text_lines

SEPARATOR = ";"
FIELDS = ("c", "x", "y", "z")  # each joint's columns: "<JOINT> (c)", "<JOINT> (x)", ...
US_PER_S = 1e6


def is_azure_kinect_csv(path) -> bool:
    """Whether a .csv file's header is this format's (timestamp;body_idx;...)."""
    with open_regular(path, "CSV file") as f:
        first = f.read(64 << 10).decode("utf-8", errors="replace").lstrip("\ufeff").split("\n", 1)[0]
    cells = [c.strip() for c in first.split(SEPARATOR)]
    return len(cells) > 2 and cells[:2] == ["timestamp", "body_idx"]


def _columns(path: Path, header: list[str]) -> np.ndarray:
    """-> (32, 4) the column of each azure32 joint's confidence, x, y, z."""
    named = {h.strip(): c for c, h in enumerate(header)}
    names = layout("azure32").joint_names
    lacking = [n for n in names if any(f"{n} ({f})" not in named for f in FIELDS)]
    if lacking:
        raise MotionFileError(
            path,
            f"an Azure Kinect body CSV without the (c), (x), (y), (z) columns of {len(lacking)} of the SDK's 32 "
            f"joints ({', '.join(lacking[:3])}{', ...' if len(lacking) > 3 else ''})",
        )
    return np.array([[named[f"{n} ({f})"] for f in FIELDS] for n in names])


def read_azure_kinect_csv(
    path, min_confidence: float = 0.0, unit: str = "auto", fps: float | None = None, groups=None
) -> list[Clip]:
    path = Path(path)
    lines, newline = read_text_lines(path, "Azure Kinect body CSV")
    header = lines[0].lstrip("\ufeff").split(SEPARATOR) if lines else []
    columns = _columns(path, header)
    rows = [k for k in range(1, len(lines)) if lines[k].strip()]  # (R,) the line of each row
    if not rows:
        raise MotionFileError(path, "a header and no frames")
    wanted = [0, 1, *columns.ravel()]
    values = numbers(path, lines, rows, wanted, SEPARATOR, len(header), "a timestamp, body index or joint cell")
    stamps = checked_stamps(path, values[:, 0], rows)
    first = np.concatenate([[True], np.diff(stamps) > 0])  # (R,) a row of a new camera frame
    frame_of = np.cumsum(first) - 1  # (R,) the camera frame of each row
    times = (stamps[first] - stamps[0]) / US_PER_S  # (F,) seconds of each frame
    joints = values[:, 2:].reshape(len(rows), -1, 4)  # (R, J, 4) confidence, x, y, z
    seen = joints[..., 0] > min_confidence
    if not seen.any():
        raise MotionFileError(
            path, f"no joint has a confidence above {min_confidence:g} in any frame: nothing was tracked"
        )
    xyz = np.where(seen[..., None], joints[..., 1:], np.nan)
    bodies: dict[str, list] = {}
    line_of: dict[tuple[int, str], int] = {}  # (frame, body ID) -> its line
    for r, (k, frame, body) in enumerate(zip(rows, frame_of.tolist(), values[:, 1])):
        key = f"{body:g}"
        if (frame, key) in line_of:
            raise MotionFileError(path, f"line {k + 1}: body {key} a second time in one frame")
        line_of[frame, key] = k
        bodies.setdefault(key, []).append((frame, xyz[r]))
    clips = people_clips(path, len(times), times, bodies, unit, fps, groups, "keypoints-azure-csv")
    for c in clips:
        c.meta.update(
            file_lines=lines,
            newline=newline,
            xyz_columns=columns[:, 1:],
            cells_at=[(line_of[i, body], c.meta["slots"][i]) for i, body in c.meta["bodies_at"]],
        )
    return clips


def write_azure_kinect_csv(path, clips: list[Clip], inputs: list[Clip]) -> Path:
    """fix's positions put back into the file's lines (delimited.write_cells): the x, y, z cells of
    a joint whose position fix changed get the new numbers."""
    return write_cells(path, clips, inputs, SEPARATOR)
