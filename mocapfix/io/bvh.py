"""BVH reader and writer.

A BVH file is a joint tree (HIERARCHY: OFFSET + CHANNELS per joint) and one row of channel
values per frame (MOTION). Positions come from forward kinematics of that tree; the clip also
keeps the local rotations, so rotation-based models and noise can use them.

Conventions (the BVH ones, as Blender, MotionBuilder and the Bandai Namco data use them):
- Euler angles in degrees, applied in channel order as intrinsic rotations: channels
  "Zrotation Xrotation Yrotation" give R = Rz(a) @ Rx(b) @ Ry(c).
- A joint's translation in its parent's frame is its OFFSET, with each component that has a
  position channel replaced by that channel's value (Bandai Namco's Hips carries the global
  translation this way, under a root joint_Root that mostly stays at the origin).
- End Site blocks are not joints.
- Missing data is a channel value that is not a number (nan, inf). A joint's position comes from
  its parent's rotation and its own translation, so a missing rotation channel makes the joints
  below it missing (the joint itself stays where its parent puts it), and a missing position
  channel the joint and the joints below it. write_bvh_like writes numbers only.
"""

from __future__ import annotations

import logging
import math
import re
import warnings
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from mocapfix.core.clip import (
    Clip,
    MotionFileError,
    check_frame_rate,
    depth_levels,
    frame_blocks,
    rotation_vectors,
    shown,
)
from mocapfix.core.skeleton import Skeleton
from mocapfix.io.conventions import guess_up_axis, metres_per_unit, resolve_unit
from mocapfix.io.files import atomic_write
from mocapfix.io.untrusted import check_size, file_size, open_regular, quoted, read_bytes
from mocapfix.rig.labels import limb_groups
from mocapfix.rig.structure import body_structure

log = logging.getLogger(__name__)

# y-up -> z-up is a +90 degree rotation about x: (x, y, z) -> (x, -z, y). Right-handed (det +1),
# so rotations stay rotations and left stays left (conventions.to_z_up as a matrix).
Y_UP_TO_Z_UP = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])
AXES = {"y": Y_UP_TO_Z_UP, "z": np.eye(3)}
FK_TOLERANCE_M = 1e-4  # rotations are kept only if their FK reproduces the positions this well

# Writing a clip back into its file (write_bvh_like): a channel value fix left alone comes back as
# the file's own text. "Alone" is at fix's own precision: the clip holds float32 rotations, and
# inverse kinematics leaves a joint it did not move within 3e-6 rad (Bandai and CMU takes).
KEEP_RADIANS = 1e-5  # a joint turned less than this keeps its rotation tokens (0.01 mm at 1 m)
KEEP_METRES = 1e-5  # a position channel moved less than this keeps its token (0.01 mm)
# A changed value is written with the digits its column uses, never coarser than these: a take
# 100 km from the origin needs more than the 6 significant digits a file may use.
PRINT_DEGREES = 1e-4  # 2e-6 rad
PRINT_METRES = 1e-6

_CHANNEL = re.compile(r"^([XYZ])(position|rotation)$", re.I)


def read_bvh(
    path,
    unit: str | float = "auto",
    up_axis: str = "auto",
    groups: dict | None = None,
    keep_joints: list[str] | None = None,
    drop_joints: list[str] | None = None,
    fill_missing_channels: bool = False,
) -> list[Clip]:
    """One BVH file -> [Clip] (a list, like every reader) in metres, z up.

    unit: "m" | "cm" | "mm" | "inch" | metres per file unit | "auto" (from the body's limbs,
        conventions.resolve_unit); up_axis: "y" | "z" | "auto" (head above pelvis).
    groups: explicit limb groups {name: joint names or indices of the returned skeleton};
        guessed from the joint names when None.
    keep_joints / drop_joints: joint names to keep / to remove (Clip.select_joints, here where
        the exact local rotations are still at hand). Needed for rotations when a joint below
        the root carries a moving translation, as Bandai Namco's Hips does under joint_Root:
        no constant bone offsets reproduce such a tree, so with it whole the clip comes without
        rotations rather than with wrong ones (meta["no_rotations"] says why), and
        drop_joints=["joint_Root"] makes Hips the root and the rotations exact. A root like that
        (one child, a rotation that never changes: a helper that carries or holds the body, not
        a joint of it) is dropped without being named, unless keep_joints keeps it.
    fill_missing_channels: non-finite channel values (missing data) interpolated over time per
        channel first, so the clip has rotations everywhere (meta["filled_channels"] counts them):
        the input's pose and twist for inverse kinematics to start from when a fixed clip goes
        back into this file's hierarchy; not data.
    """
    path = Path(path)
    names, parents, offsets, channels, data, frame_time, encoding = _parse(path)
    filled = 0
    if fill_missing_channels and not np.isfinite(data).all():
        data, filled = _interpolated(data), int((~np.isfinite(data)).sum())
    J = len(names)
    if encoding != "utf-8":
        shown_names = ", ".join(quoted(n) for n in names[:3])  # the file's text: escaped, short
        log.warning("warning: %s: not UTF-8 text; joint names read as Latin-1 (%s)", shown(path), shown_names)

    finite = bool(np.isfinite(data).all())
    with np.errstate(invalid="ignore", over="ignore"):  # non-finite channels give NaN positions (below)
        local_r, local_t = _local_transforms(offsets, channels, data)  # (T, J, 3, 3), (T, J, 3)
        del data  # (T, 3 J) float64: read
        pos = _forward_kinematics(local_r, local_t, parents)  # (T, J, 3) file units, file axes

    # Which joint is which from the rig's structure (names only confirm): the unit and the up
    # axis then come from the legs and the trunk, whatever the exporter called them.
    structure = body_structure(parents, pos, names, source=path)
    labels = structure.labels if structure is not None else None
    unit = resolve_unit(path, unit, None, pos, names, parents, labels)
    up_axis = guess_up_axis(pos, names, parents, labels) if up_axis == "auto" else str(up_axis).lower()
    if up_axis not in AXES:
        raise MotionFileError(path, f"unknown up axis {up_axis!r}; use 'y', 'z' or 'auto'")
    scale, C = unit.metres, AXES[up_axis]

    # A global change of axes C (and scale s): p' = s C p, so local rotations become C R C^T and
    # every translation s C t.
    # (The rotations change when they are converted, a block of frames at a time.)
    with np.errstate(invalid="ignore", over="ignore"):
        positions = scale * pos @ C.T
        local_t = scale * local_t @ C.T
    del pos

    skeleton = Skeleton(names, parents, {}, path.stem, labels or ())
    meta = {"format": "bvh", "unit": unit.name, "unit_source": unit.how, "up_axis": up_axis, "frame_time": frame_time}
    if encoding != "utf-8":
        meta["encoding"] = encoding
    if filled:
        meta["filled_channels"] = filled
    # FK above ran in float64; the clip keeps float32 about an origin near the body, so a take
    # far from the file's origin (georeferenced) loses nothing in the cast.
    clip = Clip.centred(positions, 1.0 / frame_time, skeleton, path.stem, str(path), meta=meta)
    root = positions[:, 0] - clip.origin  # (T, 3) float64, as the clip's positions

    # FK with one constant offset per joint is exact when no joint below the root moves its
    # translation; the error bound adds each joint's deviation down its chain.
    offs = local_t.mean(axis=0)  # (J, 3)
    offs[0] = 0.0  # the root's translation is root_translation, not an offset
    dev = np.linalg.norm(local_t - offs, axis=-1).max(axis=0) if finite else np.full(J, np.inf)  # (J,)
    dev[0] = 0.0
    chain_dev = dev.copy()
    for j in range(1, J):
        chain_dev[j] += chain_dev[parents[j]]

    unknown = [n for n in list(keep_joints or []) + list(drop_joints or []) if n not in names]
    if unknown:
        listed = ", ".join(quoted(n) for n in names[:12]) + (f" and {J - 12} more" if J > 12 else "")
        raise MotionFileError(path, f"joints {unknown} not in this file ({J} joints: {listed})")
    keep = [
        j for j, n in enumerate(names) if (not keep_joints or n in set(keep_joints)) and n not in set(drop_joints or [])
    ]
    root_r = C @ local_r[:, :1] @ C.T  # (T, 1, 3, 3)
    if 0 in keep and _helper_root(parents, root_r) and not (keep_joints and names[0] in keep_joints):
        keep.remove(0)
        meta["dropped_root"] = names[0]
    exact = finite and (len(keep) < J or chain_dev.max() <= FK_TOLERANCE_M)
    rotations = _rotation_vectors(local_r, C) if exact else None  # (T, J, 3) float32
    del local_r  # 72 B a joint-frame: gone before select_joints makes its own
    if len(keep) < J:
        if finite:
            # These rotations are exact but the offsets may not be (see above); select_joints works
            # from the positions and the global rotations only, and checks its result.
            clip = clip.replace(rotations=rotations, root_translation=root, offsets=offs.astype(np.float32))
        try:
            clip = clip.select_joints(keep)
        except ValueError as e:  # the kept joints do not form one tree
            raise MotionFileError(path, str(e).replace("\n", " ")) from None
        clip.meta = dict(meta)
        if not clip.has_rotations:
            clip.meta["no_rotations"] = (
                "non-finite channel values" if not finite else "the kept joints have no constant bone offsets"
            )
    elif not finite:
        clip.meta["no_rotations"] = "non-finite channel values"
    elif chain_dev.max() > FK_TOLERANCE_M:
        j = int(np.argmax(dev))
        above, a = [], parents[j]
        while a >= 0:
            above.insert(0, names[a])
            a = parents[a]
        clip.meta["no_rotations"] = (
            f"joint {quoted(names[j])} has a time-varying translation (up to {dev[j]:.3g} m); "
            f"drop_joints={above} makes it the root"
        )
    else:
        clip = clip.replace(
            rotations=rotations, root_translation=root.astype(np.float32), offsets=offs.astype(np.float32)
        )

    # In a frame with a non-finite channel: a rotation leaves the joints below its joint missing
    # (the joint is where its parent puts it), a position its joint and the joints below
    if not finite:
        clip.meta["absurd_tokens"] = int(clip.missing_mask().sum())
    sk = clip.skeleton
    try:
        sk = sk.with_groups(groups) if groups is not None else sk.with_groups(limb_groups(sk))
    except (KeyError, ValueError) as e:
        raise MotionFileError(path, f"bad groups: {e}") from None
    return [clip.replace(skeleton=sk)]


def write_bvh(path, clip: Clip, template: str | Path | None = None) -> None:
    """Write a clip with rotations as BVH, atomically.

    Units and up axis go back to clip.meta["unit"] / ["up_axis"] (what read_bvh found); without
    them, those guessed for the template (a BVH file), else metres and z up. The template also
    supplies the End Site offsets of joints of the same name (zero-length End Sites otherwise).
    Layout: root with Xposition Yposition Zposition Zrotation Xrotation Yrotation, every other
    joint Zrotation Xrotation Yrotation; the root OFFSET is zero (its channels carry the
    translation).
    """
    path = Path(path)
    if not clip.has_rotations:
        raise MotionFileError(path, f"clip {clip.name!r} has no rotations; only rotation clips can be written as BVH")
    # The template is the file the clip came from (or one like it): its End Sites are copied as
    # they are, in its own units, which are the clip's meta unit and up axis.
    meta = clip.meta
    end_sites = {}
    if template is not None:
        template = Path(template)
        end_sites = _parse_hierarchy(template, _sections(template)[0])[4]
        if "unit" not in meta or "up_axis" not in meta:
            meta = {**read_bvh(template)[0].meta, **meta}
    up_axis = meta.get("up_axis", "z")
    if up_axis not in AXES:
        raise MotionFileError(path, f"cannot write up axis {up_axis!r}")
    scale, C = metres_per_unit(meta), AXES[up_axis]
    T, J = clip.rotations.shape[:2]
    parents, names = clip.skeleton.parents, clip.skeleton.joint_names

    # Back to the file frame: R_file = C^T R C, t_file = C^T t / s.
    R = Rotation.from_rotvec(clip.rotations.reshape(-1, 3).astype(np.float64)).as_matrix().reshape(T, J, 3, 3)
    R = C.T @ R @ C
    with warnings.catch_warnings():  # gimbal lock still gives angles that rebuild the same matrix
        warnings.simplefilter("ignore", UserWarning)
        euler = Rotation.from_matrix(R.reshape(-1, 3, 3)).as_euler("ZXY", degrees=True).reshape(T, J, 3)
    root = (clip.root_translation.astype(np.float64) + clip.origin) @ C / scale  # (T, 3); row-vector form of C^T t
    offsets = clip.offsets.astype(np.float64) @ C / scale  # (J, 3)
    children = [[c for c in range(J) if parents[c] == j] for j in range(J)]
    lines = ["HIERARCHY"]
    order = []  # joints as the hierarchy lists them (depth first): the order of a frame's channels

    def emit(j: int, depth: int) -> None:
        order.append(j)
        ind = "  " * depth
        if j == 0:
            lines.extend(
                [
                    f"ROOT {names[0]}",
                    "{",
                    "  OFFSET 0 0 0",
                    "  CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation",
                ]
            )
        else:
            o = offsets[j]
            lines.extend(
                [
                    f"{ind}JOINT {names[j]}",
                    f"{ind}{{",
                    f"{ind}  OFFSET {o[0]:.6f} {o[1]:.6f} {o[2]:.6f}",
                    f"{ind}  CHANNELS 3 Zrotation Xrotation Yrotation",
                ]
            )
        for c in children[j]:
            emit(c, depth + 1)
        if not children[j]:
            e = end_sites.get(names[j], (0.0, 0.0, 0.0))
            lines.extend(
                [f"{ind}  End Site", f"{ind}  {{", f"{ind}    OFFSET {e[0]:.6f} {e[1]:.6f} {e[2]:.6f}", f"{ind}  }}"]
            )
        lines.append(f"{ind}}}")

    emit(0, 0)
    frames = np.concatenate([root, euler[:, order].reshape(T, -1)], axis=1)  # (T, 3 + 3J)
    lines.extend(["MOTION", f"Frames: {T}", f"Frame Time: {1.0 / clip.fps:.8f}"])
    body = "\n".join(" ".join(f"{v:.6f}" for v in row) for row in frames.tolist())
    text = "\n".join(lines) + "\n" + body + "\n"

    atomic_write(path, lambda f: f.write(text.encode()))


def write_bvh_like(path, clip: Clip, template: str | Path) -> None:
    """Write a clip with rotations into the hierarchy of the BVH file it was read from, atomically.

    The template's HIERARCHY text is copied as it is (joints, offsets, End Sites, channel layout,
    unit, up axis). The clip covers some or all of its joints, by name (a clip read with
    drop_joints / keep_joints) and has the template's frames. The channels of the clip's joints
    are recomputed from the clip: each joint's rotation relative to its parent in the template, in
    the joint's own Euler order, and its translation where it has position channels; so a joint
    the clip dropped above its root (Bandai Namco's joint_Root) keeps its channels and still
    carries the root. Every other channel keeps its values.
    The file's text stays where the clip leaves the motion as it was: every line before the
    first frame (HIERARCHY, MOTION, Frames, Frame Time), each value's token where the joint
    turned less than KEEP_RADIANS and a position channel moved less than KEEP_METRES, line ends
    (LF, CRLF, CR), spaces, a byte order mark. Changed values are written with the digits their
    column uses (significant digits where it writes exponents, else decimals), never coarser
    than PRINT_DEGREES and PRINT_METRES. The result is checked: FK of the channels as written
    gives the clip's positions to 1e-4 m, or nothing is written.
    """
    path, template = Path(path), Path(template)
    if not clip.has_rotations:
        raise MotionFileError(path, f"clip {clip.name!r} has no rotations; only rotation clips can be written as BVH")
    names, parents, offsets, channels, data, frame_time, encoding = _parse(template)
    T, J = data.shape[0], len(names)
    if clip.num_frames != T or abs(clip.fps * frame_time - 1.0) > 1e-4:
        raise MotionFileError(
            path,
            f"the clip has {clip.num_frames} frames at {clip.fps:g} fps, {template.name} "
            f"{T} at {1.0 / frame_time:g} fps: write_bvh_like keeps the template's frames",
        )
    up_axis = clip.meta.get("up_axis", "z")
    if up_axis not in AXES:
        raise MotionFileError(path, f"cannot write up axis {up_axis!r}")
    scale, C = metres_per_unit(clip.meta), AXES[up_axis]
    where = {n: j for j, n in enumerate(names)}
    unknown = [n for n in clip.skeleton.joint_names if n not in where]
    if unknown:
        raise MotionFileError(path, f"joints {', '.join(unknown)} are not in {template.name}")
    of_clip = {where[n]: k for k, n in enumerate(clip.skeleton.joint_names)}  # template joint -> clip joint

    # The clip in the file's units and axes (R_file = C^T R C, t_file = C^T t / s), posed by FK.
    Tc, Jc = clip.rotations.shape[:2]
    R = Rotation.from_rotvec(clip.rotations.reshape(-1, 3).astype(np.float64)).as_matrix().reshape(Tc, Jc, 3, 3)
    R = C.T @ R @ C
    clip_t = np.broadcast_to(clip.offsets.astype(np.float64) @ C / scale, (T, Jc, 3)).copy()  # (T, Jc, 3)
    clip_t[:, 0] = (clip.root_translation.astype(np.float64) + clip.origin) @ C / scale  # where the file has it
    clip_pos, clip_glob = _forward_kinematics(R, clip_t, clip.skeleton.parents, with_rotations=True)

    # Global transforms of every template joint, parents first: the clip's where it has the
    # joint, the template's own local transform under its (new) parent otherwise.
    local_r, local_t = _local_transforms(offsets, channels, data)
    base = _root_base(offsets, channels, data)  # the file's own reading of its root channels, kept
    G, P = np.empty_like(local_r), np.empty_like(local_t)  # (T, J, 3, 3), (T, J, 3)
    for j in range(J):
        p = parents[j]
        if j in of_clip:
            G[:, j], P[:, j] = clip_glob[:, of_clip[j]], clip_pos[:, of_clip[j]]
        elif p < 0:
            G[:, j], P[:, j] = local_r[:, j], local_t[:, j]
        else:
            G[:, j] = G[:, p] @ local_r[:, j]
            P[:, j] = P[:, p] + (G[:, p] @ local_t[:, j, :, None])[..., 0]

    out = data.copy()  # (T, C) the channels the clip gives
    kept = np.ones(data.shape, dtype=bool)  # (T, C) where the value is the input's, token and all
    for j in of_clip:
        p = parents[j]
        Gp_T = np.swapaxes(G[:, p], -1, -2) if p >= 0 else np.eye(3)
        local = Gp_T @ G[:, j]  # (T, 3, 3)
        trans = (Gp_T @ (P[:, j] - (P[:, p] if p >= 0 else 0.0))[..., None])[..., 0]  # (T, 3)
        rot = [(col, axis) for col, (axis, kind) in channels[j] if kind == "rotation"]
        if rot:
            # A joint with fewer than 3 rotation channels (legal BVH) turns about those axes only:
            # Euler angles in its order, the axes it lacks last, whose angles (0 for a rotation the
            # file can hold) are dropped. The FK check below refuses a rotation it cannot hold.
            order = "".join(a for _, a in rot)
            order += "".join(a for a in "xyz" if a not in order)
            with warnings.catch_warnings():  # gimbal lock: scipy sets the last angle to 0, as wanted here
                warnings.simplefilter("ignore", UserWarning)
                euler = Rotation.from_matrix(local).as_euler(order.upper(), degrees=True)
            # Compared as rotations, not angles: Euler angles of one rotation differ by 360 degrees
            # (a file's 365.26 is scipy's 5.26) and near gimbal lock. |A - B| = sqrt(2) * angle
            # for small angles; a channel that was missing (NaN) is never kept.
            still = np.linalg.norm(local - local_r[:, j], axis=(-2, -1)) < np.sqrt(2) * KEEP_RADIANS  # (T,)
            for i, (col, _) in enumerate(rot):
                out[:, col] = euler[:, i]
                kept[:, col] = still
        for col, (axis, kind) in channels[j]:
            if kind == "position":
                out[:, col] = trans[:, "xyz".index(axis)] - (base["xyz".index(axis)] if j == 0 else 0.0)
                kept[:, col] = np.abs(out[:, col] - data[:, col]) * scale < KEEP_METRES

    lines, first, skip, tokens = _frame_tokens(template, encoding, data)
    C = data.shape[1]
    new_text = {}  # {t * C + column: the changed value's text}
    written = data.copy()  # (T, C) the values as the output will read
    kinds = {col: kind for chans in channels for col, (_, kind) in chans}
    for col in np.nonzero(~kept.all(axis=0))[0].tolist():
        rows = np.nonzero(~kept[:, col])[0]
        quantum = PRINT_DEGREES if kinds[col] == "rotation" else PRINT_METRES / scale  # in the file's unit
        new = _formatted(out[rows, col], tokens[col::C], quantum)
        written[rows, col] = np.array(new, dtype=np.float64)
        new_text.update(zip((rows * C + col).tolist(), new))
    kept |= written == data  # a new value that prints as the old one keeps its token ("1.50" stays)

    # A clip joint whose translation the template has no channel for keeps the template's offset:
    # right only if the clip's bone is that long.
    check = _forward_kinematics(*_local_transforms(offsets, channels, written), parents)[:, list(of_clip)]
    err = np.linalg.norm(check - clip_pos[:, list(of_clip.values())], axis=-1).max(axis=0) * scale  # (Jc,) metres
    if not np.all(err < FK_TOLERANCE_M):
        worst = list(of_clip)[int(np.nanargmax(np.nan_to_num(err, nan=np.inf)))]
        # The joint above it (or itself) that the file lets turn about fewer than 3 axes, if any.
        stiff, a = None, parents[worst]
        while a >= 0 and stiff is None:
            turns = sum(kind == "rotation" for _, (_, kind) in channels[a])
            stiff = (a, turns) if turns < 3 else None
            a = parents[a]
        why = (
            f"{quoted(names[stiff[0]])} has {stiff[1]} rotation channels here, too few to turn it as the motion does"
            if stiff is not None
            else "its translation has no channels?"
        )
        # Named by the template: the problem is its hierarchy (path may be a temporary file).
        raise MotionFileError(
            template,
            f"cannot write the motion in this file's hierarchy: joint {quoted(names[worst])} would be "
            f"{np.nanmax(err):.3g} m off ({why}); write .npz or .csv",
        )
    text = "".join(_with_tokens(lines, first, skip, kept.ravel(), new_text))
    atomic_write(path, lambda f: f.write(text.encode(encoding)))  # joint names as the input spelled them


# --- writing back into a file's own text ---

_LINE = re.compile(r"[^\r\n]*(?:\r\n|\r|\n)|[^\r\n]+$")  # a line with its end, as the file has it


def _frame_tokens(path: Path, encoding: str, data: np.ndarray) -> tuple[list[str], int, int, list[str]]:
    """The file's text as it is (_text evens out line ends) -> its lines with their ends, the line
    of the first frame value, how many tokens of that line come before it, and the values' tokens
    (T * C, frame by frame). The frame values are the file's last T * C tokens (_parse splits them
    so); checked against data (T, C), as _parse read them."""
    try:
        raw = read_bytes(path, "BVH file")
    except OSError as e:
        raise MotionFileError(path, f"cannot read ({e.strerror or type(e).__name__})") from None
    lines = _LINE.findall(raw.decode(encoding))
    n, count, first = data.size, 0, len(lines)
    while count < n and first > 0:
        first -= 1
        count += len(lines[first].split())
    tokens = "".join(lines[first:]).split()[count - n :] if count >= n else []
    try:
        same = len(tokens) == n and np.array_equal(np.array(tokens, dtype=np.float64), data.ravel(), equal_nan=True)
    except ValueError:
        same = False
    if not same:
        raise MotionFileError(path, "changed while it was being fixed; fix it again")
    return lines, first, count - n, tokens


def _formatted(values: np.ndarray, column: list[str], quantum: float) -> list[str]:
    """values: (N,) new values of one channel; column: the file's T tokens of that channel ->
    the values as text in the column's style: significant digits (as %g) where it writes
    exponents (5.1072e-06), else fixed decimals (0.000005); as many as its longest token, and
    never coarser than `quantum` (file units)."""
    mantissas = [t.lower().split("e")[0] for t in set(column) if math.isfinite(float(t))] or ["0"]
    floor = math.floor(math.log10(quantum))  # the last place the value needs
    if any("e" in t.lower() for t in column):
        digits = max(len(m.lstrip("+-").replace(".", "").lstrip("0")) for m in mantissas)
        return [
            f"{v:.{min(max(digits, math.floor(math.log10(abs(v))) - floor + 1), 17)}g}"
            if np.isfinite(v) and v != 0
            else f"{v:g}"
            for v in values.tolist()
        ]
    decimals = max(max(len(m.partition(".")[2]) for m in mantissas), -floor)
    return [f"{v:.{decimals}f}" for v in values.tolist()]


def _with_tokens(lines: list[str], first: int, skip: int, kept: np.ndarray, new_text: dict[int, str]):
    """The file's lines with the frame values' tokens replaced by new_text where not kept (kept:
    (T * C,), in the file's order); a line with none replaced is yielded as it is, and a changed
    one keeps its spaces and its end."""
    yield from lines[:first]
    i = -skip  # index of the line's first token among the frame values
    for line in lines[first:]:
        k = len(line.split())
        if kept[max(i, 0) : i + k].all():
            yield line
        else:
            content = line.rstrip("\r\n")
            pieces = re.split(r"(\s+)", content)  # tokens at the even places (the first and last may be "")
            for p in range(0, len(pieces), 2):
                if pieces[p]:
                    if i >= 0 and not kept[i]:
                        pieces[p] = new_text[i]
                    i += 1
            yield "".join(pieces) + line[len(content) :]
            continue
        i += k


# --- parsing ---


def _frame_rate(frame_time: str) -> float:
    """fps from the text of a 'Frame Time:' line. Files print the frame time to a few digits
    (0.0333333 at 30 fps), and 1 / 0.0333333 = 30.00003 fps would send every clip through
    resampling (one frame short, every frame interpolated) and shift its timestamps. Take the
    roundest rate (0 to 3 decimals) that prints as the same frame time at the file's precision."""
    t = float(frame_time)
    digits = max(len(frame_time.lower().split("e")[0].lstrip("+-").replace(".", "").lstrip("0")), 1)
    for decimals in range(4):
        fps = round(1.0 / t, decimals)
        if fps > 0 and float(f"{1.0 / fps:.{digits}g}") == float(f"{t:.{digits}g}"):
            return fps
    return 1.0 / t


SNIFF_BYTES = 1 << 16  # a BVH says HIERARCHY in its first lines


def _text(path: Path) -> tuple[str, str]:
    """The file's text and its encoding ("utf-8", or "latin-1" for bytes that are not UTF-8: every
    byte is a Latin-1 character, so a joint name never turns into U+FFFD and is written back as
    it was read). A file whose start is not a BVH's (binary, or no HIERARCHY line) is refused
    from its first bytes, before the rest is read; what is not a regular file (a FIFO, a device)
    before any. Line ends come back as "\\n" whatever the file used ("\\r\\n", or old Mac "\\r")."""
    try:
        with open_regular(path, "BVH file") as f:
            size = file_size(f)
            check_size(path, size, "BVH file")
            head = f.read(min(SNIFF_BYTES, size))
            if not head.strip():
                raise MotionFileError(path, "empty file")
            start = head[3:] if head.startswith(b"\xef\xbb\xbf") else head  # a UTF-8 byte order mark
            if b"\0" in head or re.search(rb"^\s*HIERARCHY\b", start.replace(b"\r", b"\n"), re.M) is None:
                raise MotionFileError(path, "not a BVH file (no HIERARCHY line at its start)")
            raw = start + f.read(size - len(head))  # no further than the size: the file may be growing
    except OSError as e:  # an I/O error while reading
        raise MotionFileError(path, f"cannot read ({e.strerror or type(e).__name__})") from None
    if b"\r" in raw:
        raw = raw.replace(b"\r\n", b"\n").replace(b"\r", b"\n")
    try:
        return raw.decode("utf-8"), "utf-8"
    except UnicodeDecodeError:
        return raw.decode("latin-1"), "latin-1"


def _sections(path: Path) -> tuple[str, str, int, str, int]:
    """(hierarchy text, motion text, 0-based line of MOTION, encoding, 1-based line of HIERARCHY)
    or a MotionFileError."""
    text, encoding = _text(path)
    h = re.search(r"^\s*HIERARCHY\b", text, re.M)
    m = re.search(r"^\s*MOTION\b", text, re.M)
    if m is None or m.start() < h.start():
        raise MotionFileError(path, "no MOTION section after HIERARCHY")
    hierarchy_line = text.count("\n", 0, h.end()) + 1
    return text[h.end() : m.start()], text[m.end() :], text.count("\n", 0, m.end()), encoding, hierarchy_line


def _parse_hierarchy(path: Path, text: str, first_line: int = 1):
    """-> names, parents, offsets (J, 3), channels [[(column, (axis, kind))]], end sites {joint: offset}, columns.

    text: the HIERARCHY section, whose first line is line `first_line` of the file. Messages name
    a line by its number and a joint by its (shortened, escaped) name, never the line's text."""
    names, parents, offsets, channels, end_sites = [], [], [], [], {}
    stack: list[int] = []  # open blocks: joint index, or -2 for an End Site
    pending = None  # joint or End Site declared, its "{" not yet seen
    col = 0
    for k, line in enumerate(text.split("\n")):
        at = f"line {first_line + k}"
        # Braces may share a line with other tokens; give them their own pieces.
        for ln in line.replace("{", "\n{\n").replace("}", "\n}\n").split("\n"):
            ln = ln.strip()
            if not ln:
                continue
            word, rest = (ln.split(None, 1) + [""])[:2]  # tabs or spaces after the keyword
            if word in ("ROOT", "JOINT"):
                if word == "ROOT" and names:
                    raise MotionFileError(
                        path, f"{at}: more than one ROOT (several skeletons in one file are not supported)"
                    )
                if word == "JOINT" and not stack:
                    raise MotionFileError(path, f"{at}: JOINT outside the ROOT block")
                if not rest.strip():
                    raise MotionFileError(path, f"{at}: {word} without a name")
                if stack and stack[-1] == -2:
                    raise MotionFileError(path, f"{at}: JOINT inside an End Site block")
                names.append(rest.strip())
                parents.append(stack[-1] if stack else -1)
                offsets.append(None)
                channels.append([])
                pending = len(names) - 1
            elif ln.replace(" ", "").lower() == "endsite":
                if not stack or stack[-1] < 0:
                    raise MotionFileError(path, f"{at}: End Site outside a joint")
                pending = -2
            elif word == "{":
                if pending is None:
                    raise MotionFileError(path, f"{at}: '{{' without a ROOT, JOINT or End Site before it")
                stack.append(pending)
                if pending == -2:
                    end_sites.setdefault(names[stack[-2]], (0.0, 0.0, 0.0))
                pending = None
            elif word == "}":
                if not stack:
                    raise MotionFileError(path, f"{at}: unbalanced '}}' in HIERARCHY")
                stack.pop()
            elif word == "OFFSET":
                try:
                    o = tuple(float(v) for v in rest.split())
                except ValueError:
                    raise MotionFileError(path, f"{at}: OFFSET has a value that is not a number") from None
                if len(o) != 3 or not np.isfinite(o).all():
                    raise MotionFileError(path, f"{at}: OFFSET needs 3 finite numbers, got {len(o)} values")
                if not stack:
                    raise MotionFileError(path, f"{at}: OFFSET outside a joint")
                if stack[-1] == -2:
                    end_sites[names[stack[-2]]] = o
                else:
                    offsets[stack[-1]] = o
            elif word == "CHANNELS":
                if not stack or stack[-1] < 0:
                    raise MotionFileError(path, f"{at}: CHANNELS outside a joint")
                toks = rest.split()
                j = stack[-1]
                if not toks or not toks[0].isdigit() or int(toks[0]) != len(toks) - 1:
                    raise MotionFileError(
                        path, f"{at}: joint {quoted(names[j])}: CHANNELS count does not match the channel names"
                    )
                seen = set()
                for i, name in enumerate(toks[1:], 1):
                    m = _CHANNEL.match(name)
                    if m is None:
                        raise MotionFileError(
                            path,
                            f"{at}: joint {quoted(names[j])}: channel {i} is not one of "
                            "Xposition ... Zposition, Xrotation ... Zrotation",
                        )
                    key = (m.group(1).lower(), m.group(2).lower())
                    if key in seen:
                        raise MotionFileError(path, f"{at}: joint {quoted(names[j])}: channel {name} given twice")
                    seen.add(key)
                    channels[j].append((col, key))
                    col += 1
            else:
                raise MotionFileError(
                    path, f"{at}: not a HIERARCHY line (ROOT, JOINT, End Site, OFFSET, CHANNELS or a brace)"
                )
    if not names:
        raise MotionFileError(path, "HIERARCHY has no ROOT joint")
    if stack or pending is not None:
        raise MotionFileError(path, "HIERARCHY ends inside an open block (missing '}')")
    missing = [n for n, o in zip(names, offsets) if o is None]
    if missing:
        raise MotionFileError(path, f"joint {quoted(missing[0])} has no OFFSET")
    # Joints are found by name (mapping, keep_joints, write_bvh_like): one must not stand for two.
    seen_names: set[str] = set()
    for n in names:  # one pass: a rig of 10,000 joints is checked in milliseconds
        if n in seen_names:
            raise MotionFileError(
                path, f"joint name {quoted(n)} is used by {names.count(n)} joints; names must be unique"
            )
        seen_names.add(n)
    return names, parents, np.array(offsets, dtype=np.float64), channels, end_sites, col


def _parse(path: Path):
    """-> names, parents, offsets (J, 3), channels, data (T, columns) float64, frame time (s)."""
    hier, motion, motion_line, encoding, hierarchy_line = _sections(path)
    names, parents, offsets, channels, _, ncol = _parse_hierarchy(path, hier, hierarchy_line)

    mf = re.search(r"^\s*Frames\s*:\s*(\S+)", motion, re.M)
    mt = re.search(r"^\s*Frame\s+Time\s*:\s*(\S+)", motion, re.M)
    if mf is None:
        raise MotionFileError(path, "no 'Frames:' line after MOTION")
    if mt is None:
        raise MotionFileError(path, "no 'Frame Time:' line after MOTION")

    def line_of(match) -> int:  # 1-based line of a match in `motion`
        return motion_line + motion.count("\n", 0, match.start(1)) + 1

    try:
        n_frames = int(mf.group(1))
    except ValueError:
        raise MotionFileError(path, f"line {line_of(mf)}: 'Frames:' is not a whole number") from None
    try:
        frame_time = float(mt.group(1))
    except ValueError:
        raise MotionFileError(path, f"line {line_of(mt)}: 'Frame Time:' is not a number of seconds") from None
    if n_frames <= 0:
        raise MotionFileError(path, f"Frames: {n_frames} (no motion)")
    if not (np.isfinite(frame_time) and frame_time > 0):
        raise MotionFileError(path, f"Frame Time must be positive, got {frame_time:g}")
    frame_time = 1.0 / check_frame_rate(path, _frame_rate(mt.group(1)), f"Frame Time {frame_time:g} s is")

    # The frame rows start after whichever of the two header lines comes last; rows[0] is the rest
    # of that header line (normally empty). Line numbers in messages count from 1 in the file.
    start = max(mf.end(), mt.end())
    first_line = motion_line + motion.count("\n", 0, start) + 1
    block = motion[start:]
    rows = block.splitlines()
    counts = [len(r.split()) for r in rows]
    # Line numbers of the non-empty rows; trailing blank lines are fine, blank lines between rows are skipped.
    nonempty = [i for i, c in enumerate(counts) if c]
    bad = [i for i in nonempty if counts[i] != ncol]
    if bad:
        i = bad[0]
        frame = nonempty.index(i)
        if i == nonempty[-1] and counts[i] < ncol:
            raise MotionFileError(
                path, f"truncated: last frame row (line {first_line + i}) has {counts[i]} of {ncol} values"
            )
        raise MotionFileError(path, f"line {first_line + i} (frame {frame}): expected {ncol} values, got {counts[i]}")
    if len(nonempty) < n_frames:
        raise MotionFileError(path, f"truncated: 'Frames: {n_frames}' but only {len(nonempty)} frame rows")
    if len(nonempty) > n_frames:
        raise MotionFileError(path, f"'Frames: {n_frames}' but {len(nonempty)} frame rows")
    data = np.empty((n_frames, ncol))
    try:
        for frame, i in enumerate(nonempty):  # a row at a time: a string object per value costs 60 B
            data[frame] = np.array(rows[i].split(), dtype=np.float64)
    except ValueError:
        for frame, i in enumerate(nonempty):
            for v, tok in enumerate(rows[i].split(), 1):
                try:
                    float(tok)
                except ValueError:
                    raise MotionFileError(
                        path, f"line {first_line + i} (frame {frame}): non-numeric value (value {v} of the row)"
                    ) from None
        raise MotionFileError(path, "non-numeric frame values") from None
    return names, parents, offsets, channels, data, frame_time, encoding


def _local_transforms(offsets: np.ndarray, channels, data: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The file's channels -> local rotations (T, J, 3, 3) and translations (T, J, 3), every frame,
    in the file's units and axes. float64 throughout: the Bandai files have translations of
    metres in cm, and we promise 1e-5 m."""
    T, J = data.shape[0], len(channels)
    local_t = np.broadcast_to(offsets, (T, J, 3)).copy()
    local_r = np.empty((T, J, 3, 3))
    base = _root_base(offsets, channels, data)
    turns = {}  # (k, axis) -> the joints whose k-th rotation channel turns about axis, and its columns
    for j, chans in enumerate(channels):
        rotations = [(col, axis) for col, (axis, kind) in chans if kind == "rotation"]
        for k, (col, axis) in enumerate(rotations):
            joints, cols = turns.setdefault((k, axis), ([], []))
            joints.append(j)
            cols.append(col)
        for col, (axis, kind) in chans:
            if kind == "position":
                local_t[:, j, "xyz".index(axis)] = data[:, col] + (base["xyz".index(axis)] if j == 0 else 0.0)
    # A block of frames at a time, one product for all joints of a (k, axis), k in order: each
    # joint's rotation is still I @ R1 @ R2 @ R3 in its channel order, and a rig of thousands of
    # joints costs a few numpy steps, not a Python loop of thousands.
    for frames in frame_blocks(T, J):
        block = data[frames]  # (t, columns)
        r = np.broadcast_to(np.eye(3), (len(block), J, 3, 3)).copy()
        for (_, axis), (joints, cols) in sorted(turns.items()):
            r[:, joints] = r[:, joints] @ _axis_rotation(axis, np.deg2rad(block[:, cols]))
        local_r[frames] = r
    return local_r, local_t


def _rotation_vectors(local_r: np.ndarray, C: np.ndarray) -> np.ndarray:
    """local_r: (T, J, 3, 3) rotations in the file's axes -> (T, J, 3) float32 rotation vectors in
    the axes C turns them into (C R C^T). A block of frames at a time: at once, the turn and
    scipy's checks would hold several float64 copies of every matrix (72 B a joint-frame each)."""
    T, J = local_r.shape[:2]
    out = np.empty((T, J, 3), dtype=np.float32)
    with np.errstate(invalid="ignore", over="ignore"):
        for frames in frame_blocks(T, J):
            out[frames] = rotation_vectors(C @ local_r[frames] @ C.T, np.float32)
    return out


def _interpolated(data: np.ndarray) -> np.ndarray:
    """data: (T, C) channel values, non-finite = missing -> each column linearly interpolated over
    the frames it has (held at the ends; a column with none: 0)."""
    out = data.copy()
    frames = np.arange(len(data))
    for c in range(data.shape[1]):
        ok = np.isfinite(data[:, c])
        if not ok.all():
            out[:, c] = np.interp(frames, frames[ok], data[ok, c]) if ok.any() else 0.0
    return out


def _root_base(offsets: np.ndarray, channels, data: np.ndarray) -> np.ndarray:
    """(3,) what the root's position channels are added to. Exporters disagree: most write the
    root's place itself in its channels (the OFFSET is the rest place, or zero: Blender, Bandai
    Namco, CMU), some write a displacement from the OFFSET (Character Creator puts the rest hip
    height there and centimetres of motion in the channels). The channels are displacements
    when they stay nearer zero than the OFFSET along an axis whose OFFSET is not zero."""
    base = np.zeros(3)
    cols = {axis: col for col, (axis, kind) in channels[0] if kind == "position"}
    for axis, col in cols.items():
        k = "xyz".index(axis)
        off = offsets[0, k]
        with np.errstate(invalid="ignore"), warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            typical = float(np.nanmedian(data[:, col]))
        if off != 0.0 and np.isfinite(typical) and abs(typical) < 0.5 * abs(off):
            base[k] = off
    return base


def _forward_kinematics(local_r: np.ndarray, local_t: np.ndarray, parents, with_rotations: bool = False):
    """local_r: (T, J, 3, 3), local_t: (T, J, 3) (row 0: the root's position) -> positions (T, J, 3)
    (and global rotations (T, J, 3, 3) with with_rotations).

    The numpy twin of kinematics.forward_kinematics: reading a file should not import torch.
    A level of the tree at a time (depth_levels), and without with_rotations a block of frames at
    a time (frame_blocks): only that block's global rotations are held, 72 B a joint-frame.
    """
    T, J = local_t.shape[:2]
    up, levels = np.asarray(parents), depth_levels(parents)
    pos, glob = np.empty_like(local_t), np.empty_like(local_r) if with_rotations else None
    for frames in [slice(None)] if with_rotations else frame_blocks(T, J, len(levels)):
        p, g = pos[frames], glob if with_rotations else np.empty_like(local_r[frames])  # p is a view of pos
        r, t = local_r[frames], local_t[frames]
        p[:, 0], g[:, 0] = t[:, 0], r[:, 0]
        for joints in levels:  # each joint's parent is done
            p[:, joints] = p[:, up[joints]] + (g[:, up[joints]] @ t[:, joints, :, None])[..., 0]
            g[:, joints] = g[:, up[joints]] @ r[:, joints]
    return (pos, glob) if with_rotations else pos


def _axis_rotation(axis: str, angle: np.ndarray) -> np.ndarray:
    """angle: (...) radians -> (..., 3, 3) rotations about one coordinate axis."""
    i = "xyz".index(axis)
    a, b = (i + 1) % 3, (i + 2) % 3  # the plane the rotation turns: (y, z), (z, x) or (x, y)
    c, s = np.cos(angle), np.sin(angle)
    m = np.zeros((*np.shape(angle), 3, 3))
    m[..., i, i] = 1.0
    m[..., a, a], m[..., a, b], m[..., b, a], m[..., b, b] = c, -s, s, c
    return m


# --- helper joints ---


def _helper_root(parents, local_r: np.ndarray) -> bool:
    """A root with one child and a rotation that never changes is a helper (Bandai Namco's
    joint_Root, MotionBuilder's Reference): it holds or carries the body, and a body joint
    placed there (at the origin, say) would be a joint of nothing."""
    one_child = sum(p == 0 for p in parents) == 1
    with np.errstate(invalid="ignore"):
        fixed = bool(np.all(np.abs(local_r[:, 0] - local_r[0, 0]) < 1e-9))
    return len(parents) > 2 and one_child and fixed
