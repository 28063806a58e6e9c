"""What `fix` writes for an input: the output's kind from the input's (a BVH back as a BVH, positions
files in their own layout, Human3.6M and AMASS as .npz), where it goes, and the writing itself
in the input's unit, axis and layout."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from mocapfix.core.clip import Clip, MotionFileError
from mocapfix.fix.joints import map_joints
from mocapfix.io.azure_kinect import write_azure_kinect
from mocapfix.io.azure_kinect_csv import write_azure_kinect_csv
from mocapfix.io.bvh import write_bvh_like
from mocapfix.io.conventions import metres_per_unit, to_z_up
from mocapfix.io.files import atomic_write
from mocapfix.io.keypoints import write_keypoints
from mocapfix.io.kinect_log import write_kinect_log
from mocapfix.io.kinect_skeleton import write_kinect_skeleton
from mocapfix.io.kinect_text import write_kinect_text
from mocapfix.io.mediapipe_json import write_mediapipe_json
from mocapfix.io.npz import load_npz, npz_array
from mocapfix.io.positions import write_clips, write_positions

FIXED = ".fixed"  # default output: <stem>.fixed<ext> beside the input
# A keypoint file's writer by its reader's format: each puts fix's positions back into the file's
# own structure (path, clips, the clips as read).
KEYPOINT_WRITERS = {
    "keypoints-npy": write_keypoints,
    "keypoints-npz": write_keypoints,
    "keypoints-skeleton": write_kinect_skeleton,
    "keypoints-kinect-log": write_kinect_log,
    "keypoints-text": write_kinect_text,
    "keypoints-mediapipe-json": write_mediapipe_json,
    "keypoints-azure-json": write_azure_kinect,
    "keypoints-azure-csv": write_azure_kinect_csv,
}


def output_suffix(clips: list[Clip], path: Path, rotations: bool = False) -> str:
    """Positions and keypoint files keep their extension; BVH stays BVH (a rotation model's rotations, or a
    positions model's positions put back on the input's hierarchy by inverse kinematics);
    AMASS (rotations in, positions out) and Human3.6M become .npz. rotations: the output has
    rotations to write (a rotation model, or a reference pose for inverse kinematics)."""
    fmt = clips[0].meta.get("format", "")
    if fmt == "bvh" and (rotations or clips[0].has_rotations):
        return ".bvh"
    own_form = fmt in ("positions-npz", "positions-csv") or fmt.startswith("keypoints-")  # their own kind back
    return path.suffix.lower() if own_form else ".npz"


def output_path(
    path: Path, clips: list[Clip], out: Path | None, out_dir: Path | None, rel: Path | None, rotations: bool = False
) -> Path:
    suffix = output_suffix(clips, path, rotations)
    if out is not None:
        target = out
    elif out_dir is not None:
        target = out_dir / (rel if rel is not None else Path(path.name)).with_suffix(suffix)
    else:
        target = path.with_name(path.stem + FIXED + suffix)
    fmt = clips[0].meta.get("format", "")
    ext = target.suffix.lower()
    if ext == ".bvh" and fmt == "bvh" and (rotations or clips[0].has_rotations):
        return target
    if ext == ".bvh":
        why = "a BVH output needs a BVH input" if fmt != "bvh" else "the input has no joint rotations"
        raise MotionFileError(path, f"cannot write {target.name}: {why}; write .npz or .csv")
    if fmt.startswith("keypoints-"):  # a keypoint array comes back as one, in its own file type
        if ext != path.suffix.lower():
            raise MotionFileError(path, f"cannot write {target.name}: a keypoint array is written as {path.suffix}")
        return target
    if ext not in (".npz", ".csv") or (fmt == "h36m" and ext != ".npz"):
        raise MotionFileError(
            path, f"cannot write {target.name}: outputs are {'.npz' if fmt == 'h36m' else '.npz or .csv'}"
        )
    return target


def write_output(target: Path, clips: list[Clip], inputs: list[Clip], path: Path | None = None) -> None:
    """Positions in the input's layout (people, unit, up axis, csv columns); Human3.6M as its
    own {subject: {action: (T, 17, 3)}} npz; a .bvh target: the input BVH file `path` with the
    clip's motion (write_bvh_like). inputs: the clips as read, for exact copies."""
    if target.suffix.lower() == ".bvh":
        write_bvh_like(target, clips[0], path)
        return
    clips = on_input_joints(clips, inputs)
    fmt = clips[0].meta.get("format")
    if fmt == "h36m":
        tree: dict = {}
        for c in clips:
            scale = metres_per_unit(c.meta)  # back to the file's unit
            tree.setdefault(c.meta["subject"], {})[c.meta["action"]] = (c.positions / scale).astype(np.float32)
        atomic_write(target, lambda f: np.savez_compressed(f, positions_3d=np.array(tree, dtype=object)))
        return
    if fmt in KEYPOINT_WRITERS:
        KEYPOINT_WRITERS[fmt](target, clips, inputs)
        return
    m = clips[0].meta
    if fmt == "positions-npz" and metres_per_unit(m) != 1.0:
        # Metres -> cm/mm -> metres is not exact in float32 (1 value in 8 is off by an ulp): tokens
        # fix left alone are written from the file's own numbers, so they come back bit-identical.
        with load_npz(Path(inputs[0].source)) as data:
            raw = npz_array(Path(inputs[0].source), data, "positions").astype(np.float64)
        raw = to_z_up(raw.reshape((-1,) + raw.shape[-3:]) * metres_per_unit(m), m.get("up_axis", "z"))
        origin = inputs[0].origin  # the positions below are relative to it (a take far from the origin)
        new = np.stack([c.positions for c in clips]).astype(np.float64)  # (P, T, J, 3)
        old = np.stack([c.positions for c in inputs])
        same = ((new == old) & np.isfinite(old)).all(-1, keepdims=True)
        write_positions(
            target,
            np.where(same, raw - origin, new),
            clips[0].fps,
            clips[0].skeleton,
            m["unit"],
            m.get("up_axis", "z"),
            squeeze=m.get("squeeze"),
            origin=origin,
        )
        return
    write_clips(target, clips)


def on_input_joints(fixed: list[Clip], inputs: list[Clip]) -> list[Clip]:
    """Fixed clips on the input's joints: a rotation model fixes a BVH read with its joints only;
    the file's other joints pass through, as with any model."""
    out = []
    for f, c in zip(fixed, inputs):
        if f.skeleton.joint_names == c.skeleton.joint_names:
            out.append(f)
            continue
        positions = c.positions.copy()
        positions[:, map_joints(c.skeleton, f.skeleton, c.source)] = about_origin(f, c.origin)  # a second read's origin
        out.append(c.replace(positions=positions, rotations=None, root_translation=None, offsets=None))
    return out


def about_origin(clip: Clip, origin: np.ndarray) -> np.ndarray:
    """clip's positions (T, J, 3) relative to `origin` (Clip.origin) instead of its own: the same
    float32 array when the two agree, as they do for every take near the file's origin."""
    if (clip.origin == origin).all():
        return clip.positions
    return (clip.positions.astype(np.float64) + (clip.origin - origin)).astype(np.float32)
