"""MediaPipe Pose world landmarks as JSON (`.json`), the way scripts dump MediaPipe's results:
33 landmarks {"x", "y", "z", "visibility"[, "presence"]} a frame, in MediaPipe's order (mediapipe33).

    [{"x": ..., "y": ..., "z": ..., "visibility": ...}, ... 33]            one frame
    [[... 33 ...], [... 33 ...], ...]                                      a frame a list
    [{"frame": 0, "pose_world_landmarks": [... 33 ...]}, ...]              a frame an object
    {"fps": 30, "frames": [...]}                                           the frames under "frames"

A frame object holds its landmarks under pose_world_landmarks, world_landmarks, worldLandmarks,
poseWorldLandmarks or landmarks, and may number itself (frame, frame_idx, frame_index: a frame
with no entry is a hole fix fills, as when a script writes only the frames with a detection) or
time itself (timestamp_ms; put on the clock at the fps given or told from the steps). An empty or
null landmark list is a frame with nobody detected (a hole).

World landmarks are metres about the hips' midpoint, x right, y down, z away from the camera (up
axis "-y", io/conventions.py; put back as it was). The image landmarks (pose_landmarks: x, y
fractions of the image, z on x's scale) are no 3D positions: told by the key, or for a bare
"landmarks" by where the hips are (world landmarks hold their midpoint at the origin), and
refused in one line. visibility (the lower of it and presence where both are given) is the
joint's confidence: at or below --min-confidence the joint is missing in that frame. One person:
MediaPipe gives each person's world landmarks about its own hips and no ID to follow a person
by, so a frame with two is refused.

The writer puts fix's positions into the file's own structure, every other value as read.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from mocapfix.core.clip import Clip, MotionFileError
from mocapfix.io.files import atomic_write
from mocapfix.io.keypoints import file_tokens, frame_slots, layout_skeleton_of, on_clock
from mocapfix.io.layouts import layout
from mocapfix.io.positions import _check_fps, _clips, _fps_from_times

WORLD_KEYS = ("pose_world_landmarks", "world_landmarks", "worldLandmarks", "poseWorldLandmarks")
IMAGE_KEYS = ("pose_landmarks", "poseLandmarks", "image_landmarks")
EITHER_KEYS = ("landmarks",)  # told by where the hips are
NUMBER_KEYS = ("frame", "frame_idx", "frame_index")
POINTS = 33
HIPS = (23, 24)  # left_hip, right_hip: world landmarks' origin is their midpoint
WORLD_HIPS_M = 0.05  # the hips' midpoint this near the origin in most frames: world landmarks


def _is_landmark(item) -> bool:
    return isinstance(item, dict) and "x" in item and "y" in item and "z" in item


def _landmark_list(item) -> bool:
    return isinstance(item, list) and len(item) > 0 and all(_is_landmark(v) for v in item)


def _entries(path: Path, data) -> tuple[list, float | None]:
    """The document -> (its frame entries, the fps it states)."""
    fps = None
    if isinstance(data, dict) and isinstance(data.get("frames"), list):
        fps = data.get("fps")
        if fps is not None and not isinstance(fps, (int, float)):
            raise MotionFileError(path, "'fps' is not a number")
        data = data["frames"]
    if isinstance(data, dict) and "frames" not in data:
        if not any(k in data for k in WORLD_KEYS + IMAGE_KEYS + EITHER_KEYS):
            raise MotionFileError(
                path,
                "a JSON object that is neither Azure Kinect body tracking (no 'frames' list of bodies) nor "
                f"MediaPipe landmarks (no {' / '.join(WORLD_KEYS)})",
            )
        return [data], fps  # one frame
    if _landmark_list(data):
        return [data], fps  # one frame
    if not isinstance(data, list):
        raise MotionFileError(path, "not MediaPipe landmarks: neither a list of frames nor one frame's 33 landmarks")
    return data, fps


def _landmarks_of(path: Path, i: int, entry) -> tuple[list | None, str]:
    """A frame entry -> (its landmark dicts, None where nobody was detected; which kind of key held
    them: "world", "image" or "either")."""
    if entry is None or entry == []:
        return None, "either"
    if isinstance(entry, list):
        if all(isinstance(v, list) for v in entry):  # a list of people (the Tasks API)
            people = [p for p in entry if p]
            if len(people) > 1:
                raise MotionFileError(
                    path,
                    f"frame {i}: {len(people)} people: MediaPipe's world landmarks are each about its own hips, "
                    "with no ID to follow a person by; save one person's",
                )
            return (people[0] if people else None), "either"
        return entry, "either"
    if not isinstance(entry, dict):
        raise MotionFileError(path, f"frame {i}: neither landmarks nor an object holding them")
    for keys, kind in ((WORLD_KEYS, "world"), (IMAGE_KEYS, "image"), (EITHER_KEYS, "either")):
        key = next((k for k in keys if k in entry), None)
        if key is not None:
            value, _ = _landmarks_of(path, i, entry[key])
            return value, kind
    raise MotionFileError(path, f"frame {i}: no landmarks ({', '.join(WORLD_KEYS + IMAGE_KEYS + EITHER_KEYS)})")


def _number(entry, keys) -> float | None:
    if isinstance(entry, dict):
        for k in keys:
            v = entry.get(k)
            if isinstance(v, (int, float)) and not isinstance(v, bool):
                return float(v)
    return None


def read_mediapipe_json(
    path, data, min_confidence: float = 0.0, unit: str = "auto", fps: float | None = None, groups=None
) -> list[Clip]:
    """data: the file's JSON document (untrusted.read_json)."""
    path = Path(path)
    entries, file_fps = _entries(path, data)
    if not entries:
        raise MotionFileError(path, "no frames")
    T = len(entries)
    xyz = np.full((T, POINTS, 3), np.nan)
    confidence = np.ones((T, POINTS))
    kinds = set()
    for i, entry in enumerate(entries):
        points, kind = _landmarks_of(path, i, entry)
        kinds.add(kind)
        if points is None:
            continue
        if len(points) != POINTS or not all(_is_landmark(p) for p in points):
            raise MotionFileError(path, f"frame {i}: {len(points)} landmarks, not MediaPipe Pose's {POINTS}")
        try:
            xyz[i] = [[float(p["x"]), float(p["y"]), float(p["z"])] for p in points]
            confidence[i] = [min(float(p.get("visibility", 1.0)), float(p.get("presence", 1.0))) for p in points]
        except (TypeError, ValueError):
            raise MotionFileError(path, f"frame {i}: a landmark's x, y, z or visibility is not a number") from None
    seen = (confidence > min_confidence) & np.isfinite(xyz).all(-1)
    if not seen.any():
        raise MotionFileError(path, f"no landmark with a visibility above {min_confidence:g} in any frame")
    hips = np.nanmedian(np.linalg.norm(xyz[:, list(HIPS)].mean(1), axis=-1))
    if "image" in kinds or ("world" not in kinds and not hips < WORLD_HIPS_M):
        raise MotionFileError(
            path,
            "MediaPipe's image landmarks (x, y fractions of the picture), not world landmarks in metres: "
            "save pose_world_landmarks",
        )
    xyz[~seen] = np.nan
    numbers = [_number(e, NUMBER_KEYS) for e in entries]
    stamps = [_number(e, ("timestamp_ms",)) for e in entries]
    times = None
    if all(n is not None for n in numbers):
        if fps is None and file_fps is None:
            raise MotionFileError(path, "numbered frames and no frame rate: give --fps")
        rate = _check_fps(path, fps if fps is not None else file_fps)
        times = (np.array(numbers) - numbers[0]) / rate  # a frame number's time at that rate
    elif all(s is not None for s in stamps) and T > 1:
        times = np.array(stamps) / 1000.0
        if fps is None and file_fps is None and not (np.diff(times) > 0).any():
            raise MotionFileError(path, "timestamp_ms never advances: no frame rate to tell from it; give --fps")
    if fps is None:
        fps = file_fps
    if fps is None and times is not None:
        fps = _fps_from_times(path, times, np.arange(T), np.zeros(T))
    if fps is None:
        raise MotionFileError(path, "MediaPipe landmarks hold no frame rate: give --fps")
    fps = _check_fps(path, fps)
    slots = frame_slots(path, times, T, fps)
    lay = layout("mediapipe33")
    skeleton, order = layout_skeleton_of(path, lay, groups)
    clock = on_clock(xyz, slots)  # (N, 33, 3) camera axes
    meta = {"layout": lay.name, "joint_order": order, "slots": slots.tolist(), "document": data}
    return _clips(
        path, clock[None][:, :, order], fps, skeleton, unit, "m", "-y", "-y", "keypoints-mediapipe-json", [meta]
    )


def write_mediapipe_json(path, clips: list[Clip], inputs: list[Clip]) -> Path:
    """fix's positions into the file's own structure (inputs: the clip as read): a landmark whose
    position fix changed gets the new x, y, z; every other value as read."""
    (clip,), (before,) = clips, inputs
    m = clip.meta
    data = json.loads(json.dumps(m["document"]))  # a copy to edit
    entries, _ = _entries(Path(path), data)
    order = np.asarray(m["joint_order"])
    out, changed = file_tokens(clip, before, order)  # (N, 33, 3) camera axes, the file's unit; (N, 33)
    for i, entry in enumerate(entries):
        t = m["slots"][i]
        points, _ = _landmarks_of(Path(path), i, entry)
        for j in np.flatnonzero(changed[t]) if points is not None else []:
            points[j].update(x=float(out[t, j, 0]), y=float(out[t, j, 1]), z=float(out[t, j, 2]))
    atomic_write(path, lambda f: f.write(json.dumps(data, indent=2).encode("utf-8")))
    return Path(path)
