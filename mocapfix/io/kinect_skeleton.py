"""Kinect v2 skeleton text files (`.skeleton`, the NTU RGB+D layout of the SDK's body frames).

    <frames>
    per frame:  <bodies>
      per body: <bodyID clippedEdges handLeftConfidence handLeftState handRightConfidence
                 handRightState isRestricted leanX leanY trackingState>
                <joints>   (25)
                per joint: <x y z depthX depthY colorX colorY orientW orientX orientY orientZ trackingState>

Camera space: metres, y up. Each person is one clip over the file's frames (missing where the
camera does not see them): two bodies seen at once are two people, a body ID that starts where
another ended is the same person found again (io/body_ids.py; person_id "id1+id2"). A joint's
tracking state (0 not tracked, 1 inferred, 2 tracked) is its confidence: at or below
min_confidence (default 0: not tracked) it is missing in that frame. The SDK runs at 30 fps,
which is the frame rate unless --fps says otherwise.

The writer puts fix's positions back into the file's own lines: every other number, and every
position fix left alone, is the file's text as it was.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from mocapfix.core.clip import Clip, MotionFileError
from mocapfix.io.body_ids import merged, one_person_chains
from mocapfix.io.files import atomic_write
from mocapfix.io.keypoints import file_tokens, layout_skeleton_of
from mocapfix.io.layouts import layout
from mocapfix.io.positions import _check_fps, _clips
from mocapfix.io.untrusted import read_text_lines

KINECT_FPS = 30.0
BODY_FIELDS, JOINT_FIELDS = 10, 12
MAX_BODY_FRAMES = 1_000_000  # people x frames read (6 bodies over 46 min); past it, not one take


def _parse(path: Path, lines: list[str]):
    """-> (frames, {body id: [(frame, [joint line index] * J)]}) in the order bodies appear."""
    at = 0

    def take(what: str) -> list[str]:
        nonlocal at
        while at < len(lines) and not lines[at].strip():
            at += 1
        if at >= len(lines):
            raise MotionFileError(path, f"ends before {what}")
        at += 1
        return lines[at - 1].split()

    def count(what: str) -> int:
        fields = take(what)
        if len(fields) != 1 or not fields[0].isdigit():
            raise MotionFileError(path, f"line {at}: expected the number of {what}, got {' '.join(fields)[:40]!r}")
        return int(fields[0])

    frames = count("frames")
    bodies: dict[str, list[tuple[int, list[int]]]] = {}
    for frame in range(frames):
        for _ in range(count(f"bodies in frame {frame}")):
            info = take("a body's line")
            if len(info) != BODY_FIELDS:
                raise MotionFileError(path, f"line {at}: a body's line has {BODY_FIELDS} numbers, not {len(info)}")
            joints = count("joints")
            rows = []
            for _ in range(joints):
                if len(take("a joint's line")) != JOINT_FIELDS:
                    raise MotionFileError(path, f"line {at}: a joint's line has {JOINT_FIELDS} numbers")
                rows.append(at - 1)
            bodies.setdefault(info[0], []).append((frame, rows))
    return frames, bodies


def read_kinect_skeleton(
    path, min_confidence: float = 0.0, unit: str = "auto", up_axis: str = "auto", fps: float | None = None, groups=None
) -> list[Clip]:
    path = Path(path)
    lines, newline = read_text_lines(path, "skeleton file")
    frames, bodies = _parse(path, lines)
    if not bodies:
        raise MotionFileError(path, f"{frames} frames and no body in any: nothing was tracked")
    lay = layout("kinect25")
    skeleton, order = layout_skeleton_of(path, lay, groups)
    J = len(lay.joint_names)
    if len(bodies) * frames > MAX_BODY_FRAMES:
        raise MotionFileError(path, f"{len(bodies)} body IDs over {frames} frames: more than one take holds")
    xyz = np.full((len(bodies), frames, J, 3), np.nan)
    state = np.zeros((len(bodies), frames, J))
    where = np.full((len(bodies), frames, J), -1, dtype=np.int64)  # the line of each joint, -1: none
    for p, appearances in enumerate(bodies.values()):
        for frame, rows in appearances:
            if len(rows) != J:
                raise MotionFileError(path, f"frame {frame}: a body of {len(rows)} joints; Kinect v2 has {J}")
            try:
                values = np.array([[float(v) for v in lines[r].split()] for r in rows])  # (J, 12)
            except ValueError:
                raise MotionFileError(path, f"frame {frame}: a joint's line that is not numbers") from None
            xyz[p, frame], state[p, frame], where[p, frame] = values[:, :3], values[:, -1], rows
    fps = _check_fps(path, KINECT_FPS if fps is None else fps)
    present = (where >= 0).all(-1)  # (P, T) the body in the frame
    chains = one_person_chains(np.where(present[..., None], xyz[:, :, 0], np.nan), fps)  # by the pelvis (m)
    xyz, state, where = (merged(a, chains, present) for a in (xyz, state, where))
    seen = (where >= 0) & (state > min_confidence)
    if not seen.any():
        raise MotionFileError(path, f"no joint tracked above state {min_confidence:g} in any frame")
    xyz[~seen] = np.nan
    ids = list(bodies)
    people = [
        {"layout": lay.name, "joint_order": order, "person_id": "+".join(ids[p] for p in chain), "lines": where[k]}
        for k, chain in enumerate(chains)
    ]
    clips = _clips(path, xyz[:, :, order], fps, skeleton, unit, "m", up_axis, "y", "keypoints-skeleton", people)
    for c in clips:
        c.meta["file_lines"] = lines  # one list for the file's people: the writer edits a copy
        c.meta["newline"] = newline
    return clips


def write_kinect_skeleton(path, clips: list[Clip], inputs: list[Clip]) -> Path:
    """fix's positions put back into the file's lines (inputs: the clips as read): a joint line
    whose position fix changed gets the new x y z, every other character stays the file's."""
    lines = list(clips[0].meta["file_lines"])
    for c, before in zip(clips, inputs):
        m = c.meta
        order = np.asarray(m["joint_order"])
        out, changed = file_tokens(c, before, order)  # (T, J, 3), (T, J) in the file's order
        changed &= m["lines"] >= 0
        for t, j in zip(*np.nonzero(changed)):
            fields = lines[m["lines"][t, j]].split()
            fields[:3] = [f"{v:.7g}" for v in out[t, j]]
            lines[m["lines"][t, j]] = " ".join(fields)
    newline = clips[0].meta["newline"]
    atomic_write(path, lambda f: f.write((newline.join(lines) + newline).encode("utf-8")))
    return Path(path)
