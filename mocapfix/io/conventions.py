"""How a file's numbers become metres and z up: from what the file or the user says, else from the body.

A unit is metres per file unit: a name (m, cm, mm, inch) or any positive number. Odd units are
common: BVH converted from ASF/AMC keeps the ASF length unit (CMU's is 1/0.45 inch = 0.0564 m),
and no menu of names reads those right. So "auto" measures the body: the leg (hip to ankle along
the bones) and the arm (shoulder to wrist) against a standard adult's, which gives metres per
unit to within a person's build. A named unit near that estimate is taken as exact (a file in cm
holding a tall or a short adult stays in cm); otherwise the estimate is the unit.

The up axis, where the file does not say, is the axis from the pelvis to the head, over the
median frame: a few absurd frames cannot turn a recording over.
"""

from __future__ import annotations

import math
import re
import warnings
from contextlib import contextmanager
from dataclasses import dataclass

import numpy as np

from mocapfix.core.clip import MotionFileError
from mocapfix.io.untrusted import quoted
from mocapfix.rig.labels import guess_groups, pelvis_joint
from mocapfix.rig.tree import column_percentiles, path_length

# metres per unit. "asf": the Acclaim ASF/AMC convention of the CMU database and every BVH
# converted from it (":units length 0.45": a unit is 1/0.45 inch, 0.0564 m), the largest public
# BVH collection: its subjects' bodies differ by +-5 %, the unit does not.
NAMED_UNITS = {"m": 1.0, "cm": 0.01, "mm": 0.001, "inch": 0.0254, "asf": 0.0254 / 0.45}
_ALIASES = {
    "meter": "m",
    "metre": "m",
    "meters": "m",
    "metres": "m",
    "centimeter": "cm",
    "centimetre": "cm",
    "centimeters": "cm",
    "centimetres": "cm",
    "millimeter": "mm",
    "millimetre": "mm",
    "millimeters": "mm",
    "millimetres": "mm",
    "in": "inch",
    "inches": "inch",
}

# A standard adult, 1.70 m tall, in the joint-centre convention of motion-capture skeletons:
# thigh + shank (hip to ankle) and upper arm + forearm (shoulder to wrist). Bandai Namco's
# actor (0.80 / 0.47 m) and the Human3.6M subjects (0.90 / 0.53 m) sit either side of it.
REFERENCE_STATURE_M = 1.70
REFERENCE_LENGTH_M = {"leg": 0.82, "arm": 0.48}
# A named unit within this factor of the body's estimate is the file's unit: people differ from
# the standard adult by less (statures 1.36-2.13 m), named units differ from each other by more
# (2.2 at the closest, inch and asf).
SNAP_FACTOR = 1.25
HUMAN_STATURE_M = (1.2, 2.2)  # outside: a warning on every command that reads the file

# Joints where a limb's measured chain ends, in order of preference (the first that the group has).
_LIMB_END = {
    "leg": (r"ankle", r"foot(?!.*(toe|end|tip))"),
    "arm": (r"wrist", r"hand(?!.*(thumb|index|middle|ring|pinky|finger))"),
}


@dataclass(frozen=True)
class Unit:
    name: str  # "cm", or the number of metres for other units ("0.0564"): parse_unit reads it back
    metres: float  # metres per file unit
    how: str  # where it came from, for inspect: "option", "file", "auto: ..."


def parse_unit(value, path="", where: str = "option") -> Unit | None:
    """A unit as a user or a file gives it: a name, an alias or a positive number of metres.
    None or "auto" -> None (to be estimated)."""
    if value is None:
        return None
    text = str(value).strip().lower()
    if text in ("", "auto"):
        return None
    text = _ALIASES.get(text, text)
    if text in NAMED_UNITS:
        return Unit(text, NAMED_UNITS[text], where)
    try:
        metres = float(text)
    except ValueError:
        metres = math.nan
    if not (math.isfinite(metres) and metres > 0):
        raise MotionFileError(
            path,
            f"unknown unit {quoted(value)} (from {where}): give a name ({', '.join(NAMED_UNITS)}) "
            "or the metres per file unit as a positive number (e.g. 0.0564)",
        )
    return Unit(f"{metres:g}", metres, where)


@contextmanager
def _quiet():
    """All-NaN slices (joints never seen) give NaN without a RuntimeWarning per call."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        yield


def _bone_lengths(positions: np.ndarray, parents) -> np.ndarray:
    """positions: (T, J, 3) -> (J,) each joint's distance to its parent, median over the frames
    where both are seen (NaN: never seen; the root: 0). Medians, so absurd frames do not count."""
    p = np.asarray(parents)
    length = np.zeros(len(p))
    child = np.flatnonzero(p >= 0)
    with np.errstate(invalid="ignore", over="ignore"), _quiet():
        d = np.linalg.norm(positions[:, child] - positions[:, p[child]], axis=-1)  # (T, J-1)
        length[child] = np.nanmedian(np.where(np.isfinite(d), d, np.nan), axis=0)
        # a "bone" whose length changes by a quarter is a trajectory (a root carrying the
        # translation), not a bone: tracking noise moves bone lengths by a few cm, not more
        low, high = column_percentiles(d, (10, 90))  # np.nanpercentile's, at numpy speed for many joints
        spread = high - low
    length[child[spread > 0.25 * length[child] + 1e-12]] = np.nan
    return length


def limb_measures(positions: np.ndarray, joint_names, parents, labels=None) -> dict[str, list[float]]:
    """positions: (T, J, 3) in any unit -> {"leg": [...], "arm": [...]}: each side's length from
    the hip joint down to the ankle (the shoulder to the wrist), along the bones. labels: the
    body parts of the rig's structure (rig/structure.py), else the joints are found by name
    (guess_groups)."""
    if labels:
        return _labelled_limbs(positions, list(labels))
    bones = _bone_lengths(positions, parents)
    out: dict[str, list[float]] = {"leg": [], "arm": []}
    for group, members in guess_groups(joint_names, parents).items():
        kind = group.split("_")[1]
        top = members[0]
        for pattern in _LIMB_END[kind]:
            ends = [j for j in members if j != top and re.search(pattern, joint_names[j], re.I)]
            if ends:
                break
        if not ends:
            continue
        j, total = min(ends), 0.0  # the end nearest the top: descendants come after their parents
        while j != top:
            total += bones[j]
            j = parents[j]
        if np.isfinite(total) and total > 0:
            out[kind].append(float(total))
    return out


def _labelled_limbs(positions: np.ndarray, labels: list) -> dict[str, list[float]]:
    out: dict[str, list[float]] = {"leg": [], "arm": []}
    for kind, parts in (("leg", ("thigh", "knee", "ankle")), ("arm", ("upper_arm", "elbow", "wrist"))):
        for side in ("left", "right"):
            names = [f"{side}_{p}" for p in parts]
            if all(n in labels for n in names):
                length = path_length(positions, *(labels.index(n) for n in names))
                if np.isfinite(length) and length > 0:
                    out[kind].append(length)
    return out


def body_scale(positions: np.ndarray, joint_names, parents, labels=None) -> tuple[float, str]:
    """positions: (T, J, 3) in any unit -> (the standard adult's metres per unit of this body, how).

    The median over the legs found of reference length / measured length (the arms where no leg
    is found: legs vary less between people, and arms are where rigs differ, clavicles and
    shoulder placement). Without any limb, the two longest bones stand for the leg (thigh and
    shank are the longest bones of a human). NaN when there are no bones to measure."""
    limbs = limb_measures(positions, joint_names, parents, labels)
    kind = "leg" if limbs["leg"] else "arm"
    ratios = [REFERENCE_LENGTH_M[kind] / v for v in limbs[kind]]
    if ratios:
        return float(np.median(ratios)), f"{kind} lengths{' (rig structure)' if labels else ''}"
    bones = _bone_lengths(positions, parents)
    bones = np.sort(bones[np.isfinite(bones) & (bones > 0)])
    if bones.size < 2:
        return math.nan, "no bones"
    return float(REFERENCE_LENGTH_M["leg"] / bones[-2:].sum()), "two longest bones"


def stature_m(positions: np.ndarray, joint_names, parents, labels=None) -> float:
    """positions: (T, J, 3) metres -> the body's height implied by its limbs (NaN: no bones)."""
    scale, _ = body_scale(positions, joint_names, parents, labels)
    return REFERENCE_STATURE_M / scale if scale > 0 else math.nan


def resolve_unit(path, option, declared, raw: np.ndarray, joint_names, parents, labels=None) -> Unit:
    """The unit of one file: the user's option, else what the file declares, else the body's.

    raw: (..., T, J, 3) positions in the file's unit (any axes); labels: body parts (body_scale)."""
    for value, where in ((option, "option"), (declared, "file")):
        unit = parse_unit(value, path, where)
        if unit is not None:
            return unit
    raw = np.asarray(raw, dtype=np.float64).reshape((-1,) + np.shape(raw)[-2:])
    estimate, how = body_scale(raw, joint_names, parents, labels)
    if not (math.isfinite(estimate) and estimate > 0):  # nothing to measure (every joint missing): no harm in m
        return Unit("m", 1.0, "auto: no bone seen, metres assumed")
    name = min(NAMED_UNITS, key=lambda n: abs(math.log(NAMED_UNITS[n] / estimate)))
    if abs(math.log(NAMED_UNITS[name] / estimate)) < math.log(SNAP_FACTOR):
        return Unit(name, NAMED_UNITS[name], f"auto: nearest named unit to the body's scale ({how})")
    metres = float(f"{estimate:.4g}")
    return Unit(
        f"{metres:g}", metres, f"auto: from the body's {how} (no named unit within {100 * (SNAP_FACTOR - 1):.0f} %)"
    )


def metres_per_unit(meta: dict) -> float:
    """The unit a reader put into a clip's meta (a name or a number), for writing back in it
    (metres without one)."""
    unit = parse_unit(meta.get("unit"), meta.get("source", ""), "clip meta")
    return unit.metres if unit is not None else 1.0


def stature_warning(stature: float, meta: dict, source) -> str | None:
    """One line when a body read with the unit in a clip's meta is not of a human height, else None."""
    lo, hi = HUMAN_STATURE_M
    if not math.isfinite(stature) or lo <= stature <= hi:
        return None
    return (
        f"{source}: the body is {stature:.2f} m tall (from its limbs), outside {lo}-{hi} m, read with unit "
        f"{meta.get('unit', 'm')} ({meta.get('unit_source', 'reader')}); if that is wrong, give the file's "
        "unit (--unit or data.unit: a name or metres per file unit)"
    )


# --- up axis ---


# The up axes a file's right-handed frame can have. "-y": y down, a camera's axes (x right, z away:
# video lifters' camera-space outputs, MediaPipe, OpenCV triangulation); "-z": z down.
UP_AXES = ("z", "y", "-y", "-z")


def to_z_up(x: np.ndarray, up_axis: str) -> np.ndarray:
    """x: (..., 3) in a right-handed frame with `up_axis` up -> the same points, z up (a rotation
    about x: left stays left; coordinates moved and negated, never multiplied, so values and
    NaN come through exactly)."""
    if up_axis == "z":
        return x
    a, b, c = x[..., 0], x[..., 1], x[..., 2]
    if up_axis == "y":  # x right, z towards the viewer: +90 deg about x, y -> z and z -> -y
        return np.stack([a, -c, b], axis=-1)
    if up_axis == "-y":  # -90 deg about x: -y -> z, z -> y
        return np.stack([a, c, -b], axis=-1)
    if up_axis == "-z":  # a half turn about x
        return np.stack([a, -b, -c], axis=-1)
    raise ValueError(f"unknown up axis {up_axis!r}; known: {', '.join(UP_AXES)}")


def from_z_up(x: np.ndarray, up_axis: str) -> np.ndarray:
    """Inverse of to_z_up."""
    if up_axis == "z":
        return x
    a, b, c = x[..., 0], x[..., 1], x[..., 2]
    if up_axis == "y":
        return np.stack([a, c, -b], axis=-1)
    if up_axis == "-y":
        return np.stack([a, -c, b], axis=-1)
    if up_axis == "-z":
        return np.stack([a, -b, -c], axis=-1)
    raise ValueError(f"unknown up axis {up_axis!r}; known: {', '.join(UP_AXES)}")


def _find(names, pattern: str) -> int | None:
    return next((j for j, n in enumerate(names) if re.search(pattern, n, re.I)), None)


def guess_up_axis(positions: np.ndarray, joint_names, parents, labels=None, signed: bool = False) -> str:
    """positions: (..., T, J, 3) in the file's axes -> 'y' or 'z': the axis along which the head
    sits above the pelvis (or the pelvis above the feet; the shoulders above the hips where
    neither is seen) in the median frame; without such joints (labels from the rig's structure,
    else names), the axis along which the body is tallest in the median frame. signed: '-y' or
    '-z' where the body stands the other way along it (a camera's y down; BVH files are read
    unsigned, their convention is y or z up)."""
    pos = np.asarray(positions, dtype=np.float64).reshape((-1,) + np.shape(positions)[-2:])  # (T, J, 3)
    pos = np.where(np.isfinite(pos), pos, np.nan)
    labels = list(labels) if labels else []
    if "pelvis" in labels and ("head" in labels or "neck" in labels):
        pelvis = labels.index("pelvis")
        head, foot = labels.index("head" if "head" in labels else "neck"), None
    else:
        pelvis = pelvis_joint(parents)
        head = _find(joint_names, r"head")
        head = _find(joint_names, r"neck") if head is None else head
        head = _find(joint_names, r"nose|eye|ear") if head is None else head  # a face's landmarks (MediaPipe)
        foot = _find(joint_names, r"foot|ankle|toe")
    d, by_joints = np.full(3, np.nan), True
    tops = [
        [labels.index(f"{side}_{part}") for side in ("left", "right") if f"{side}_{part}" in labels]
        for part in ("upper_arm", "thigh")
    ]
    with _quiet():
        if head is not None and head != pelvis:
            d = np.nanmedian(pos[:, head] - pos[:, pelvis], axis=0)
        elif foot is not None and foot != pelvis:
            d = np.nanmedian(pos[:, pelvis] - pos[:, foot], axis=0)
        else:
            by_joints = False
        if not np.isfinite(d[1:]).all() and all(tops):  # no head or feet seen: the shoulders above the hips
            d = np.nanmedian(pos[:, tops[0]].mean(1) - pos[:, tops[1]].mean(1), axis=0)
        if not np.isfinite(d[1:]).all() and not by_joints:
            d = np.nanmedian(np.nanmax(pos, axis=1) - np.nanmin(pos, axis=1), axis=0)  # extent per axis
    if not np.isfinite(d[1:]).all():
        return "y"  # the BVH default
    axis = 2 if abs(d[2]) > abs(d[1]) else 1
    return ("-" if signed and d[axis] < 0 else "") + "yz"[axis - 1]
