"""Keypoint arrays: joint positions with no names or tree, as video lifters (VideoPose3D,
MotionBERT: H36M-17), SMPL regressors (SMPL-24), MediaPipe, OpenPose and depth cameras (Kinect,
Azure Kinect) hand them over.

    .npy                     (T, J, 3) or (T, J, 4), or (P, T, J, 3|4) for P people
    .npz                     the same under "positions", "keypoints3d", "keypoints" or
                             "reconstruction" (MHFormer's demo), or as "arr_0" with nothing but
                             fps, unit and times beside it (np.savez(path, prediction):
                             VideoPose3D's in-the-wild scripts); no joint names, no parents (a
                             positions file with those is io/positions.py's), optionally "fps",
                             "unit" and "times" (T,) seconds of each row

The joints are those of a published layout (io/layouts.py): --layout names it, or the joint
count tells it where only one layout has that many. A 4th column is each joint's confidence or
tracking state: a joint at or below min_confidence in a frame is missing there (a hole fix
fills), and the column is written back as read. Unit: the option, the file's, else guessed from
the body's size (Azure Kinect writes mm, the lifters m). fps: the file's or --fps; an array has
none of its own, and jitter and holes are measured in seconds, so it is asked for, never assumed.

Rows with times are put on a regular clock at the fps (given, the file's, or told from the
times): a dropped frame is a hole fix fills, a row that repeats a frame's time is read once
(the first); the output has the file's rows and times again. Without times each row is a frame.

Outputs (write_keypoints) keep the file type, key, shape, dtype, joint order, unit and axes; the
tokens fix left alone are the file's own numbers, bit for bit.
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import NamedTuple

import numpy as np

from mocapfix.core.clip import Clip, MotionFileError
from mocapfix.io.conventions import from_z_up, metres_per_unit
from mocapfix.io.files import atomic_write
from mocapfix.io.layouts import BODY_FIRST, LAYOUTS, layout, layout_skeleton, layouts_for
from mocapfix.io.npz import deflated, listed_keys, load_npz, npz_array, one_line
from mocapfix.io.positions import _check_fps, _clips, _fps_from_times, _npz_scalar_str
from mocapfix.io.untrusted import open_regular

log = logging.getLogger(__name__)
ARRAY_KEYS = ("positions", "keypoints3d", "keypoints", "reconstruction")
UNNAMED_KEY = "arr_0"  # np.savez's name for an array passed without one: read with only ABOUT_KEYS beside it
ABOUT_KEYS = {"fps", "unit", "times"}  # what an npz may hold beside its array


def array_key(keys) -> str | None:
    """The npz key a keypoint array is under, None if none."""
    keys = set(keys)
    return next((k for k in ARRAY_KEYS if k in keys), UNNAMED_KEY if keys - ABOUT_KEYS == {UNNAMED_KEY} else None)


class KeypointFile(NamedTuple):
    raw: np.ndarray  # (T, J, C) or (P, T, J, C) as stored
    key: str | None  # its npz key; None for .npy
    fps: float | None
    unit: str | None
    times: np.ndarray | None  # (T,) seconds of each row
    compressed: bool = True  # an npz's arrays deflated (np.savez_compressed), not stored


def _load(path: Path) -> KeypointFile:
    if path.suffix.lower() == ".npy":
        with open_regular(path, "npy file") as f:
            try:
                return KeypointFile(np.lib.format.read_array(f, allow_pickle=False), None, None, None, None)
            except ValueError as e:
                if "allow_pickle" in str(e):
                    raise MotionFileError(path, "holds Python objects (a pickle), not numbers") from None
                raise MotionFileError(path, f"not a readable .npy array ({one_line(e)})") from None
            except Exception as e:
                raise MotionFileError(path, f"not a readable .npy array ({one_line(e)})") from None
    with load_npz(path) as data:
        key = array_key(data.files)
        if key is None:
            raise MotionFileError(
                path,
                f"no keypoint array ({' or '.join(ARRAY_KEYS)}, or {UNNAMED_KEY} alone; keys: "
                f"{listed_keys(data.files)})",
            )
        raw = npz_array(path, data, key)
        fps = None
        if "fps" in data.files:
            f = npz_array(path, data, "fps")
            if f.size != 1 or f.dtype.kind not in "iuf":
                raise MotionFileError(path, f"fps must be one number, got {f.dtype} of shape {f.shape}")
            fps = f.reshape(()).item()
        times = None
        if "times" in data.files:
            times = npz_array(path, data, "times")
            if times.ndim != 1 or times.dtype.kind not in "iuf" or not np.isfinite(times).all():
                raise MotionFileError(
                    path, f"times must be finite seconds, one per row, got {times.dtype} {times.shape}"
                )
        return KeypointFile(raw, key, fps, _npz_scalar_str(path, data, "unit"), times, deflated(data))


MAX_CLOCK_GROWTH = 20  # a clock this many times the rows is a wrong time unit, not dropped frames


def frame_slots(path: Path, times: np.ndarray | None, rows: int, fps: float) -> np.ndarray:
    """(T,) the frame of the regular clock each row falls on (rows without times: 0..T-1)."""
    if times is None:
        return np.arange(rows)
    if len(times) != rows:
        raise MotionFileError(path, f"{len(times)} times for {rows} rows")
    slots = np.round((times.astype(np.float64) - times[0]) * fps).astype(np.int64)
    back = np.nonzero(np.diff(slots) < 0)[0]
    if back.size:
        raise MotionFileError(path, f"times go back at row {back[0] + 1}")
    if slots[-1] + 1 > MAX_CLOCK_GROWTH * rows + 100:
        raise MotionFileError(
            path, f"times span {slots[-1] + 1} frames at {fps:g} fps for {rows} rows: seconds expected"
        )
    return slots


def on_clock(rows: np.ndarray, slots: np.ndarray) -> np.ndarray:
    """rows: (T, ...) the file's rows, slots: (T,) non-decreasing, the clock frame of each
    (frame_slots) -> (N, ...) on the clock, NaN where no row falls; a row repeating its frame is
    read once (the first)."""
    first = np.concatenate([[True], slots[1:] != slots[:-1]])
    clock = np.full((int(slots[-1]) + 1,) + rows.shape[1:], np.nan)
    clock[slots[first]] = rows[first]
    return clock


def file_tokens(clip: Clip, before: Clip, order) -> tuple[np.ndarray, np.ndarray]:
    """What a keypoint writer puts back: clip, fix's output; before, the clip as read; order: (J,)
    the file's joint of each of the clip's joints -> ((N, J, 3) its positions in the file's joint
    order, unit and axes; (N, J) bool, the tokens fix changed: the only ones a writer rewrites)."""
    shape = (clip.num_frames, len(order), 3)
    now, was = np.empty(shape), np.empty(shape)
    now[:, order], was[:, order] = clip.positions, before.positions
    changed = np.isfinite(now).all(-1) & ~(now == was).all(-1)
    return from_z_up(now + clip.origin, clip.meta["up_axis"]) / metres_per_unit(clip.meta), changed


def layout_skeleton_of(path: Path, lay, groups=None):
    """The layout's skeleton and order (layouts.layout_skeleton) with a user's limb groups; a
    group naming a joint the layout lacks is the file's one-line error."""
    skeleton, order = layout_skeleton(lay)
    if groups:
        try:
            skeleton = skeleton.with_groups(groups)
        except (KeyError, ValueError) as e:
            raise MotionFileError(path, one_line(e)) from None
    return skeleton, order


def pick_layout(path: Path, name: str | None, num_joints: int):
    """The layout an array of num_joints joints is in: the one named, else the only one of that
    many joints; a one-line error naming the candidates otherwise. An array of BODY_FIRST's size
    is its body layout's (the array's first points; read_keypoints carries the others through)."""
    if name:
        try:
            lay = layout(name)
        except ValueError as e:
            raise MotionFileError(path, str(e)) from None
        if len(lay.joint_names) != num_joints and BODY_FIRST.get(num_joints) != name:
            raise MotionFileError(path, f"layout {name} has {len(lay.joint_names)} joints, the file {num_joints}")
        return lay
    candidates = layouts_for(num_joints)
    if num_joints in BODY_FIRST:
        return layout(BODY_FIRST[num_joints])
    if len(candidates) == 1:
        return candidates[0]
    if candidates:
        names = " or ".join(f"--layout {c.name}" for c in candidates)
        raise MotionFileError(path, f"{num_joints} joints could be any of {len(candidates)} layouts: give {names}")
    known = ", ".join(f"{n} ({len(lay.joint_names)})" for n, lay in LAYOUTS.items())
    raise MotionFileError(
        path, f"{num_joints} joints match no keypoint layout ({known}); save joint_names and parents with it"
    )


def read_keypoints(
    path,
    layout: str | None = None,
    min_confidence: float = 0.0,
    unit: str = "auto",
    up_axis: str = "auto",
    fps: float | None = None,
    groups=None,
) -> list[Clip]:
    """A keypoint array -> one Clip per person (metres, z up), on the layout's skeleton (parents
    before children: meta "joint_order" maps it back to the file's columns)."""
    path = Path(path)
    raw, key, file_fps, file_unit, times, compressed = _load(path)
    if raw.dtype.kind not in "iuf":
        raise MotionFileError(path, f"keypoints must be numbers, got dtype {raw.dtype}")
    if raw.ndim not in (3, 4) or raw.shape[-1] not in (3, 4) or 0 in raw.shape:
        raise MotionFileError(
            path, f"keypoints must be (frames, joints, 3 or 4) or (people, frames, joints, 3 or 4), got {raw.shape}"
        )
    squeeze, dtype, columns = raw.ndim == 3, raw.dtype, raw.shape[-1]
    raw = raw[None] if squeeze else raw
    lay = pick_layout(path, layout, raw.shape[2])
    carried = raw.shape[2] - len(lay.joint_names)  # points after the body (BODY_FIRST), written back as read
    raw = raw[:, :, : len(lay.joint_names)]
    skeleton, order = layout_skeleton_of(path, lay, groups)
    rows = raw.shape[1]
    if fps is None:
        fps = file_fps
    if fps is None and times is not None and rows > 1:
        fps = _fps_from_times(path, times.astype(np.float64), np.arange(rows), np.zeros(rows))
    if fps is None:
        raise MotionFileError(path, "a keypoint array has no frame rate: give it (--fps; render: --take-fps)")
    fps = _check_fps(path, fps)
    slots = frame_slots(path, times, rows, fps)
    xyz = raw[..., :3].astype(np.float64)  # (P, T, J, 3)
    confidence = raw[..., 3] if columns == 4 else None
    if confidence is not None:
        seen = confidence > min_confidence  # NaN confidence: not seen
        if not seen.any():
            raise MotionFileError(
                path, f"no joint has a confidence above {min_confidence:g} in any frame: nothing was tracked"
            )
        xyz[~seen] = np.nan
    clock = on_clock(xyz.swapaxes(0, 1), slots).swapaxes(0, 1)  # (P, N, J, 3)
    repeated = int((np.diff(slots) == 0).sum())
    dropped = clock.shape[1] - (rows - repeated)
    if dropped or repeated:
        log.warning(
            "warning: %s: %d frames missing from the %g-fps clock (holes), %d rows repeating a frame (read once)",
            path.name, dropped, fps, repeated,
        )  # fmt: skip
    meta = {"layout": lay.name, "joint_order": order, "squeeze": squeeze, "key": key, "dtype": dtype.str}
    meta.update(columns=columns, slots=slots, times=times, carried=carried, compressed=compressed)
    people = [dict(meta, confidence=None if confidence is None else confidence[i]) for i in range(raw.shape[0])]
    fmt = "keypoints-npy" if key is None else "keypoints-npz"
    return _clips(path, clock[:, :, order], fps, skeleton, unit, file_unit, up_axis, None, fmt, people)


def write_keypoints(path, clips: list[Clip], inputs: list[Clip] | None = None) -> Path:
    """The clips of one keypoint file back in its own form (clips[0].meta: key, shape, dtype,
    joint order, unit, up axis), the confidence column as read. inputs: the clips as read, whose
    file's numbers are kept where the clips still hold the read value."""
    path = Path(path)
    m = clips[0].meta
    order = np.asarray(m["joint_order"])
    slots = np.asarray(m["slots"])  # the clock's frame of each of the file's rows
    pos = np.stack([c.positions.astype(np.float64) + c.origin for c in clips])  # (P, N, J, 3) metres z up
    out = np.empty_like(pos)
    out[:, :, order] = from_z_up(pos, m.get("up_axis", "z")) / metres_per_unit(m)  # file unit, axes, order
    out = out[:, slots]  # (P, T, J, 3) the file's rows
    raw = None  # the file as read: its numbers where fix left a token alone, its points after the body
    if inputs is not None or m.get("carried"):
        raw = _load(Path((inputs or clips)[0].source)).raw
        raw = raw[None] if m["squeeze"] else raw
    if inputs is not None:
        old = np.stack([c.positions for c in inputs])
        same = ((np.stack([c.positions for c in clips]) == old) & np.isfinite(old)).all(-1)  # (P, N, J) skeleton order
        keep = np.empty_like(same)
        keep[:, :, order] = same
        keep = keep[:, slots]  # a row repeating a frame keeps its own numbers where fix left the frame alone
        out[keep] = raw[:, :, : out.shape[2], :3][keep]
    if m["columns"] == 4:
        out = np.concatenate([out, np.stack([c.meta["confidence"] for c in clips])[..., None]], axis=-1)
    if m.get("carried"):
        out = np.concatenate([out, raw[:, :, out.shape[2] :]], axis=2)
    dtype = np.dtype(m["dtype"])  # integers (a camera's mm) cannot hold a fill's fractions or a hole
    out = (out[0] if m["squeeze"] else out).astype(dtype if dtype.kind == "f" else np.float32)
    if m["key"] is None:
        atomic_write(path, lambda f: np.save(f, out))
    else:
        arrays = {m["key"]: out, "fps": np.float64(clips[0].fps), "unit": np.array(m["unit"])}
        if m["times"] is not None:
            arrays["times"] = m["times"]
        save = np.savez_compressed if m.get("compressed", True) else np.savez
        atomic_write(path, lambda f: save(f, **arrays))
    return path
