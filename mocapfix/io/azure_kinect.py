"""Azure Kinect body tracking as its SDK's offline processor writes it (`.json`).

    {"joint_names": [...32...], "bone_list": [...],
     "frames": [{"frame_id": 0, "timestamp_usec": 33366, "num_bodies": 1,
                 "bodies": [{"body_id": 1, "joint_positions": [[x, y, z] * 32],
                             "joint_orientations": [[w, x, y, z] * 32]}]}, ...]}

Depth-camera space: millimetres, x right, y down, z away from the camera (up axis "-y",
io/conventions.py) and put back as it was. Each person is one clip over the take's frames:
a body ID that starts where another ended is the same person found again (io/body_ids.py). The
frames' timestamps put them on the camera's clock (fps given, else told from the
steps: 30, 15 or 5): a frame the processor dropped is a hole fix fills. The layout is azure32
(io/layouts.py). The offline processor writes no confidence per joint.

The writer puts fix's positions into the file's own structure, everything else as read.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from mocapfix.core.clip import Clip, MotionFileError
from mocapfix.io.body_ids import merged, one_person_chains
from mocapfix.io.files import atomic_write
from mocapfix.io.keypoints import file_tokens, frame_slots, layout_skeleton_of
from mocapfix.io.layouts import layout
from mocapfix.io.positions import _check_fps, _clips, _fps_from_times
from mocapfix.io.untrusted import read_json

MAX_BODY_FRAMES = 1_000_000  # people x frames read; past it, a file is not one take


def _bodies(path: Path, data) -> tuple[list[dict], dict]:
    """-> (the frames, {body id: [(frame index, (32, 3) positions)]})."""
    frames = data.get("frames") if isinstance(data, dict) else None
    if not isinstance(frames, list):
        raise MotionFileError(path, "not an Azure Kinect body-tracking file: no 'frames' list")
    J = len(layout("azure32").joint_names)
    bodies: dict = {}
    for i, frame in enumerate(frames):
        for body in (frame.get("bodies") or []) if isinstance(frame, dict) else []:
            try:
                xyz = np.asarray(body["joint_positions"], dtype=np.float64)
                key = body["body_id"]
            except (KeyError, TypeError, ValueError):
                raise MotionFileError(path, f"frame {i}: a body without body_id and 32 joint_positions") from None
            if xyz.shape != (J, 3):
                raise MotionFileError(path, f"frame {i}: joint_positions of shape {xyz.shape}, not ({J}, 3)")
            bodies.setdefault(str(key), []).append((i, xyz))
    return frames, bodies


def is_azure_kinect(data) -> bool:
    """A JSON document (read_json) is the offline processor's: an object with a 'frames' list and
    its 'joint_names', or frames holding 'bodies'."""
    if not (isinstance(data, dict) and isinstance(data.get("frames"), list)):
        return False
    return "joint_names" in data or any(isinstance(f, dict) and "bodies" in f for f in data["frames"][:10])


def read_azure_kinect(path, unit: str = "auto", fps: float | None = None, groups=None, data=None) -> list[Clip]:
    """data: the file's JSON document where the caller has read it (read_json), None: read here."""
    path = Path(path)
    data = read_json(path, "body-tracking JSON") if data is None else data
    frames, bodies = _bodies(path, data)
    try:
        times = np.array([float(f["timestamp_usec"]) for f in frames]) / 1e6
    except (KeyError, TypeError, ValueError):
        times = None  # no clock: each frame one step
    clips = people_clips(path, len(frames), times, bodies, unit, fps, groups, "keypoints-azure-json")
    for c in clips:
        c.meta["document"] = data  # one object for the file's people: the writer edits a copy
    return clips


def people_clips(
    path: Path, num_frames: int, times: np.ndarray | None, bodies: dict, unit: str, fps: float | None, groups, fmt: str
) -> list[Clip]:
    """The people of a body-tracking file: num_frames frames the camera delivered, at times (s,
    or None: one step each); bodies: {body ID: [(frame, (32, 3) mm in camera axes, NaN where
    missing)]} -> one clip per person (io/body_ids.py), each clip's meta with the frames on the
    clock ("slots") and where each of its bodies was read ("bodies_at": (frame, body ID))."""
    if not bodies:
        raise MotionFileError(path, f"{num_frames} frames and no body in any: nothing was tracked")
    if len(bodies) * num_frames > MAX_BODY_FRAMES:
        raise MotionFileError(path, f"{len(bodies)} body IDs over {num_frames} frames: more than one take holds")
    if fps is None:
        if times is None:
            raise MotionFileError(path, "no timestamps to tell the frame rate: give --fps")
        if num_frames < 2:
            raise MotionFileError(path, "one frame: no steps to tell the frame rate from; give --fps")
        fps = _fps_from_times(path, times, np.arange(num_frames), np.zeros(num_frames))
    fps = _check_fps(path, fps)
    slots = frame_slots(path, times, num_frames, fps)
    repeated = np.nonzero(np.diff(slots) == 0)[0]
    if repeated.size:  # two frames on one tick of the camera's clock: not the tracker's output
        raise MotionFileError(path, f"timestamps that do not increase (frame {repeated[0] + 1})")
    lay = layout("azure32")
    skeleton, order = layout_skeleton_of(path, lay, groups)
    xyz = np.full((len(bodies), int(slots[-1]) + 1, len(lay.joint_names), 3), np.nan)  # (P, N, J, 3)
    present = np.zeros(xyz.shape[:2], bool)  # (P, N) the frames each body was delivered in
    for p, appearances in enumerate(bodies.values()):
        for i, positions in appearances:
            xyz[p, slots[i]] = positions
            present[p, slots[i]] = True
    chains = one_person_chains(xyz[:, :, 0] / 1000.0, fps)  # by the pelvis, mm -> m
    xyz = merged(xyz, chains, present)
    ids, appearances = list(bodies), list(bodies.values())
    people = [
        {
            "layout": lay.name,
            "joint_order": order,
            "person_id": "+".join(ids[p] for p in chain),
            "slots": slots,
            "bodies_at": [(i, ids[p]) for p in chain for i, _ in appearances[p]],  # (frame, its body ID)
        }
        for chain in chains
    ]
    return _clips(path, xyz[:, :, order], fps, skeleton, unit, "mm", "-y", "-y", fmt, people)


def write_azure_kinect(path, clips: list[Clip], inputs: list[Clip]) -> Path:
    """fix's positions into the file's own structure (inputs: the clips as read): a joint whose
    position fix changed gets the new one, everything else as read."""
    data = json.loads(json.dumps(clips[0].meta["document"]))  # a copy to edit
    for c, before in zip(clips, inputs):
        m = c.meta
        order = np.asarray(m["joint_order"])
        out, changed = file_tokens(c, before, order)  # file order, mm, camera axes
        for i, body_id in m["bodies_at"]:
            t = m["slots"][i]
            body = next(b for b in data["frames"][i]["bodies"] if str(b["body_id"]) == body_id)
            for j in np.nonzero(changed[t])[0]:
                body["joint_positions"][j] = [float(v) for v in out[t, j]]
    atomic_write(path, lambda f: f.write(json.dumps(data, indent=1).encode("utf-8")))
    return Path(path)
