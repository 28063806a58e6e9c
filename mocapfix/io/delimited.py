"""A tracker's delimited text log (a Kinect SDK body log's tabs, an Azure Kinect recorder's
semicolons): its rows' numbers read with a one-line error for a broken row, and fix's positions
put back into the file's own cells, every other character as it was."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from mocapfix.core.clip import Clip, MotionFileError
from mocapfix.io.files import atomic_write
from mocapfix.io.keypoints import file_tokens


def numbers(path: Path, lines: list[str], rows: list[int], wanted: list[int], separator: str, cells: int, what: str):
    """lines: the file's; rows: the line of each row (0-based); wanted: the columns to read;
    cells: the header's count -> (R, len(wanted)) float64; a short row or a cell that is not a
    number is the file's one-line error (what: the cells read, for it)."""
    values = np.empty((len(rows), len(wanted)))
    for r, k in enumerate(rows):
        row = lines[k].split(separator)
        if len(row) < cells:
            raise MotionFileError(path, f"line {k + 1} has fewer cells than the header's {cells}")
        try:
            values[r] = [float(row[i]) for i in wanted]
        except ValueError:
            raise MotionFileError(path, f"line {k + 1}: {what} that is not a number") from None
    return values


def checked_stamps(path: Path, stamps: np.ndarray, rows: list[int]) -> np.ndarray:
    """stamps: (R,) the timestamp column -> the same, finite and never going back, else the
    file's one-line error naming the line."""
    if not np.isfinite(stamps).all():
        raise MotionFileError(
            path, f"line {rows[int(np.argmax(~np.isfinite(stamps)))] + 1}: a timestamp that is not a number"
        )
    back = np.flatnonzero(np.diff(stamps) < 0)
    if back.size:
        raise MotionFileError(path, f"line {rows[back[0] + 1] + 1}: the timestamp goes back")
    return stamps


def write_cells(path, clips: list[Clip], inputs: list[Clip], separator: str) -> Path:
    """fix's positions put back into the file's lines (inputs: the clips as read; each clip's meta:
    file_lines, newline, joint_order, xyz_columns (J, 3) each joint's x, y, z cells, cells_at
    [(line, clock frame)] where its person was read): the x, y, z cells of a joint whose
    position fix changed get the new numbers, every other character stays the file's."""
    lines = list(clips[0].meta["file_lines"])
    for c, before in zip(clips, inputs):
        m = c.meta
        order, columns = np.asarray(m["joint_order"]), np.asarray(m["xyz_columns"])
        out, changed = file_tokens(c, before, order)  # (N, J, 3), (N, J) in the file's order
        for line, t in m["cells_at"]:
            if changed[t].any():
                cells = lines[line].split(separator)
                for j in np.flatnonzero(changed[t]):
                    for col, v in zip(columns[j], out[t, j]):
                        cells[col] = repr(float(v))
                lines[line] = separator.join(cells)
    newline = clips[0].meta["newline"]
    atomic_write(path, lambda f: f.write((newline.join(lines) + newline).encode("utf-8")))
    return Path(path)
