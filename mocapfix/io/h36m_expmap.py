"""Human3.6M as the motion-prediction community mirrors it: exponential maps, one text file per
subject, action and trial (`S1/walking_1.txt`, e.g. in limaosen0/DMGNN's data/h3.6m/dataset/).

Each line is a frame at 50 Hz: 99 comma-separated numbers, 33 triplets. The first two are the
root's motion since the previous frame (a translation in mm, in the previous frame's root axes,
and a rotation as an exponential map); then one exponential map per joint of the 32-joint
Human3.6M tree (the root's own is the zero triplet the deltas replace; end sites and fixed joints
are zero). The file holds joint angles only, so the body is the one skeleton the dataset's
angles were solved on (the bone vectors below: subject S1's, the same for every file); positions
come from forward kinematics, in metres, z up, on the 17 joints everyone evaluates on (preset
h36m17).

Conventions, as the files were written (y up, row vectors): a joint's rotation matrix R is the
Rodrigues matrix of its exponential map; a child's global rotation is R_child @ R_parent and its
position offset @ R_parent + parent's position; the root's rotation is the running product of
its per-frame rotations, R_t = dR_t @ R_(t-1), and its position the running sum of the
translations turned by the previous frame's rotation, p_t = p_(t-1) + d_t @ R_(t-1).

The deltas leave out where the root pointed in the first frame: integrated from the identity, a
take stands the pelvis upright, and the body leans as the pelvis tilts (6-40 degrees on S1 and
S9; a walk climbs 0.4 m in 10 s). Gravity is found again from the floor: the plane of the ankles'
lowest positions over the take (its normal within 0-3 degrees of the mean head-over-ankles
direction on standing and walking takes; seated takes lean that direction, the floor does not).
A take whose ankles cover too little of the floor to span a plane keeps that mean direction.
"""

from __future__ import annotations

import io
import re
from pathlib import Path

import numpy as np
import torch

from mocapfix.core import lazy_roma as roma
from mocapfix.core.clip import Clip, MotionFileError
from mocapfix.io.h36m import H36M_FPS, H36M_KEEP, H36M_SPLIT, h36m_skeleton
from mocapfix.io.untrusted import read_bytes

COLUMNS = 99  # 33 triplets: root translation delta, root rotation delta, 31 more joints' maps
# The 32-joint tree (parents, -1: root) and each joint's bone vector from its parent, mm, y up.
PARENTS = (-1, 0, 1, 2, 3, 4, 0, 6, 7, 8, 9, 0, 11, 12, 13, 14, 12, 16, 17, 18, 19, 20, 19, 22, 12)
PARENTS += (24, 25, 26, 27, 28, 27, 30)
OFFSETS_MM = (
    (0.0, 0.0, 0.0),
    (-132.948591, 0.0, 0.0),
    (0.0, -442.894612, 0.0),
    (0.0, -454.206447, 0.0),
    (0.0, 0.0, 162.767078),
    (0.0, 0.0, 74.999437),
    (132.948826, 0.0, 0.0),
    (0.0, -442.894413, 0.0),
    (0.0, -454.20659, 0.0),
    (0.0, 0.0, 162.767426),
    (0.0, 0.0, 74.999948),
    (0.0, 0.1, 0.0),
    (0.0, 233.383263, 0.0),
    (0.0, 257.077681, 0.0),
    (0.0, 121.134938, 0.0),
    (0.0, 115.002227, 0.0),
    (0.0, 257.077681, 0.0),
    (0.0, 151.034226, 0.0),
    (0.0, 278.882773, 0.0),
    (0.0, 251.733451, 0.0),
    (0.0, 0.0, 0.0),
    (0.0, 0.0, 99.999627),
    (0.0, 100.000188, 0.0),
    (0.0, 0.0, 0.0),
    (0.0, 257.077681, 0.0),
    (0.0, 151.031437, 0.0),
    (0.0, 278.892924, 0.0),
    (0.0, 251.72868, 0.0),
    (0.0, 0.0, 0.0),
    (0.0, 0.0, 99.999888),
    (0.0, 137.499922, 0.0),
    (0.0, 0.0, 0.0),
)


def _rotations(maps: np.ndarray) -> np.ndarray:
    """maps: (..., 3) exponential maps -> (..., 3, 3) Rodrigues matrices (float64)."""
    return roma.rotvec_to_rotmat(torch.from_numpy(maps)).numpy()


def forward_kinematics(channels: np.ndarray) -> np.ndarray:
    """channels: (T, 99) one file's numbers, finite -> (T, 32, 3) joint positions, mm, y up."""
    T = len(channels)
    triplets = channels.reshape(T, 33, 3)
    delta_p, local = triplets[:, 0], _rotations(triplets[:, 1:])  # (T, 3), (T, 32, 3, 3)
    root_r, root_p = np.empty((T, 3, 3)), np.empty((T, 3))
    r, p = np.eye(3), np.zeros(3)
    for t in range(T):  # the root's path: a running product, sequential by nature
        p = p + delta_p[t] @ r
        r = local[t, 0] @ r
        root_r[t], root_p[t] = r, p
    offsets = np.asarray(OFFSETS_MM)
    glob = np.empty((T, 32, 3, 3))
    pos = np.empty((T, 32, 3))
    glob[:, 0], pos[:, 0] = root_r, root_p + offsets[0]
    for j in range(1, 32):  # parents come before children
        parent = PARENTS[j]
        glob[:, j] = local[:, j] @ glob[:, parent]
        pos[:, j] = np.einsum("c,tcd->td", offsets[j], glob[:, parent]) + pos[:, parent]
    return pos


ANKLES, HEAD = (3, 8), 15  # in the 32-joint tree
FLOOR_QUANTILE = 0.3  # the ankles' lowest 30 % of positions lie on the floor
MIN_FLOOR_SPREAD_MM = 20.0  # the plane's narrower in-plane spread (SD) for it to be trusted


def floor_up(pos: np.ndarray) -> tuple[np.ndarray, float]:
    """pos: (T, 32, 3) mm, NaN where missing -> (the take's up, a unit vector; the floor's height
    along it, mm): the normal of the plane through the ankles' lowest positions, or the mean
    direction from the ankles to the head where those do not span a plane."""
    ankles = pos[:, ANKLES].reshape(-1, 3)
    ankles = ankles[np.isfinite(ankles).all(-1)]
    rise = pos[:, HEAD] - pos[:, ANKLES].mean(1)
    rise = rise[np.isfinite(rise).all(-1)].mean(0) if np.isfinite(rise).all(-1).any() else np.array([0.0, 1.0, 0.0])
    up = rise / max(np.linalg.norm(rise), 1e-9)
    if len(ankles) < 3:
        return up, 0.0
    height = ankles @ up
    low = ankles[height <= np.quantile(height, FLOOR_QUANTILE)]
    centred = low - low.mean(0)
    spread, axes = np.linalg.eigh(centred.T @ centred / len(low))  # ascending
    normal = axes[:, 0] * np.sign(axes[:, 0] @ up)
    if np.sqrt(max(spread[1], 0.0)) >= MIN_FLOOR_SPREAD_MM and normal @ up > np.cos(np.radians(45)):
        up = normal
    return up, float(np.quantile(ankles @ up, FLOOR_QUANTILE / 2))


def _upright(up: np.ndarray) -> np.ndarray:
    """The smallest rotation (3, 3), for row vectors (v @ R), taking the unit vector up to +y."""
    y = np.array([0.0, 1.0, 0.0])
    axis = np.cross(up, y)
    angle = np.arctan2(np.linalg.norm(axis), up @ y)
    if np.linalg.norm(axis) < 1e-12:
        return np.eye(3) if angle < 1 else np.diag([1.0, -1.0, -1.0])
    return _rotations(axis / np.linalg.norm(axis) * angle).T


def _parse(path: Path) -> np.ndarray:
    """The file's numbers, (T, 99) float64, or a MotionFileError in one line."""
    try:
        raw = read_bytes(path, "Human3.6M exponential-map file")
    except OSError as e:
        raise MotionFileError(path, f"cannot read ({e.strerror or type(e).__name__})") from None
    try:
        text = raw.decode("ascii")
    except UnicodeDecodeError as e:
        raise MotionFileError(path, f"not a Human3.6M exponential-map file: not text (byte {e.start})") from None
    lines = [(k + 1, line) for k, line in enumerate(text.splitlines()) if line.strip()]
    if not lines:
        raise MotionFileError(path, "empty file")
    for number, line in lines:
        if line.count(",") != COLUMNS - 1:
            raise MotionFileError(
                path,
                f"line {number} has {line.count(',') + 1} comma-separated values; a Human3.6M "
                f"exponential-map file has {COLUMNS} a line",
            )
    try:
        values = np.loadtxt(io.StringIO("\n".join(line for _, line in lines)), delimiter=",", ndmin=2)
    except ValueError:
        for number, line in lines:  # the line that is not numbers, for the message
            try:
                [float(v) for v in line.split(",")]
            except ValueError:
                raise MotionFileError(path, f"line {number}: not numbers") from None
        raise MotionFileError(path, "not numbers") from None
    root = ~np.isfinite(values[:, :6]).all(1)
    if root.any():
        number = lines[int(np.argmax(root))][0]
        raise MotionFileError(path, f"line {number}: the root's motion is not a number (every later frame hangs on it)")
    return values


def read_h36m_expmap(path, groups=None) -> list[Clip]:
    """One exponential-map file -> one Clip, 17 joints (h36m17), metres, z up, 50 fps, named like
    read_h36m's ("S1/walking 1"); meta subject (its folder, when named S<number>), action, trial,
    split. A joint one of whose ancestors' rotations is not a number in a frame is missing there.
    groups: {group name: [joint names or indices]} replacing the preset's limb groups."""
    path = Path(path)
    channels = _parse(path)
    # a joint's place hangs on its ancestors' rotations (its own turns only its children)
    turned = ~np.isfinite(channels[:, 3:].reshape(len(channels), 32, 3)).all(-1)  # (T, 32) unknown rotation
    lost = np.zeros_like(turned)  # (T, 32) unknown position
    for j in range(1, 32):
        turned[:, j] |= turned[:, PARENTS[j]]
        lost[:, j] = turned[:, PARENTS[j]]
    pos = forward_kinematics(np.where(np.isfinite(channels), channels, 0.0))
    pos[lost] = np.nan
    up, floor = floor_up(pos)
    pos = pos @ _upright(up)
    pos[..., 1] -= floor  # the floor at height 0
    # y up -> z up by a turn about x (x, y, z) -> (x, -z, y): a rotation, so left stays left
    pos = np.stack([pos[..., 0], -pos[..., 2], pos[..., 1]], -1)[:, H36M_KEEP] / 1000.0
    skel = h36m_skeleton(path, groups)
    subject = path.parent.name if re.fullmatch(r"S\d+", path.parent.name) else None
    match = re.fullmatch(r"(.*?)_(\d+)", path.stem)
    action, trial = (match.group(1), match.group(2)) if match else (path.stem, None)
    name = f"{subject}/{action}" if subject else action
    return [
        Clip(
            pos.astype(np.float32),
            H36M_FPS,
            skel,
            name=name + (f" {trial}" if trial else ""),
            source=str(path),
            meta={
                "format": "h36m_expmap",
                "subject": subject,
                "action": action,
                "trial": trial,
                "split": next((k for k, v in H36M_SPLIT.items() if subject in v), None),
                "unit": "m",
                "unit_source": "Human3.6M's skeleton, mm",
                "up_axis": "z",
            },
        )
    ]
