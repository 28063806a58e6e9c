"""Procedural human motion on the smpl22 skeleton: the default dataset, no files needed.

Each clip is a seeded sequence of activities (walk, run, turn, jump, arm_swing, wave, idle)
cross-faded over 0.3-0.5 s. Poses are per-joint Euler angles, blended linearly between
activities so the motion stays smooth, then turned into local axis-angle and run through
mocapfix.core.kinematics, so positions == fk_axis_angle(rotations, root_translation, offsets,
parents) by construction.

Walking and running place the feet first and solve the legs with two-link IK: the stance
foot stays on the ground (heel strike, foot flat, push-off over the toe) while the body moves
at the segment's speed, and the pelvis rides as high as the legs reach (the inverted-pendulum
bob of walking, the flight of running). The other activities are keyframed or periodic.

Frame: metres, z up; the character faces +x at heading 0 and its left side is +y.
Rest pose (all rotations zero): standing straight, arms hanging down, soles on z = 0.
"""

from __future__ import annotations

import numpy as np
import torch
from scipy.interpolate import PchipInterpolator
from scipy.spatial.transform import Rotation

from mocapfix.core.clip import Clip
from mocapfix.core.kinematics import fk_axis_angle
from mocapfix.core.skeleton import preset

ACTIVITIES = ("walk", "run", "turn", "jump", "arm_swing", "wave", "idle")
_ACTIVITY_P = (0.18, 0.12, 0.16, 0.12, 0.14, 0.12, 0.16)

(
    PELVIS,
    L_HIP,
    R_HIP,
    SPINE1,
    L_KNEE,
    R_KNEE,
    SPINE2,
    L_ANKLE,
    R_ANKLE,
    SPINE3,
    L_FOOT,
    R_FOOT,
    NECK,
    L_COLLAR,
    R_COLLAR,
    HEAD,
    L_SHOULDER,
    R_SHOULDER,
    L_ELBOW,
    R_ELBOW,
    L_WRIST,
    R_WRIST,
) = range(22)

# (sign, hip, knee, ankle, collar, shoulder, elbow); sign mirrors lateral angles and offsets.
_SIDES = (
    (+1, L_HIP, L_KNEE, L_ANKLE, L_COLLAR, L_SHOULDER, L_ELBOW),
    (-1, R_HIP, R_KNEE, R_ANKLE, R_COLLAR, R_SHOULDER, R_ELBOW),
)
_UPPER_BODY = (SPINE1, SPINE2, SPINE3, NECK, HEAD, L_COLLAR, R_COLLAR, L_SHOULDER, R_SHOULDER, L_ELBOW, R_ELBOW)

# Rest offsets of an average adult (scale 1: 1.7 m tall, pelvis at 0.95 m), each in the parent's
# frame. Right-side joints mirror the left ones (y negated).
_REST = {
    "pelvis": (0.0, 0.0, 0.0),
    "left_hip": (-0.005, 0.085, -0.085),
    "spine1": (-0.015, 0.0, 0.11),
    "left_knee": (0.005, 0.01, -0.385),
    "spine2": (0.01, 0.0, 0.135),
    "left_ankle": (-0.02, 0.0, -0.40),
    "spine3": (0.0, 0.0, 0.055),
    "left_foot": (0.125, 0.015, -0.06),
    "neck": (-0.015, 0.0, 0.215),
    "left_collar": (-0.01, 0.075, 0.14),
    "head": (0.04, 0.0, 0.09),
    "left_shoulder": (-0.01, 0.11, 0.015),
    "left_elbow": (-0.01, 0.005, -0.265),
    "left_wrist": (0.01, 0.0, -0.25),
}
_TOE_DROP = 0.02  # sole below the foot (toe) joint, metres at scale 1
_HEEL_BACK = 0.05  # heel behind the ankle joint
_TAU = 0.01  # metres: soft-minimum temperature, smooths switches of the supporting foot

# Countermovement jump, keyframes over one jump cycle u in [0, 1): crouch depth (fraction of the
# deepest knee bend), ankle plantarflexion, shoulder flexion, elbow flexion (rad).
_JUMP_U = np.array([0.0, 0.08, 0.28, 0.44, 0.58, 0.72, 0.80, 0.92, 1.0])
_JUMP_CROUCH = np.array([0.0, 0.05, 1.0, 0.0, 0.25, 0.05, 0.55, 0.1, 0.0])
_JUMP_PLANTAR = np.array([0.0, 0.0, 0.0, 0.55, 0.35, 0.2, 0.0, 0.0, 0.0])
_JUMP_SHOULDER = np.array([0.0, -0.1, -0.6, 1.1, 1.0, 0.5, 0.1, 0.0, 0.0])
_JUMP_ELBOW = np.array([0.15, 0.2, 0.3, 0.4, 0.5, 0.4, 0.4, 0.2, 0.15])
_JUMP_FLIGHT = (0.45, 0.71)  # take-off and landing, fraction of the jump cycle


def generate_clips(num_clips: int = 64, seconds: float = 10.0, fps: float = 30.0, seed: int = 0) -> list[Clip]:
    """num_clips procedural clips of `seconds` at `fps`. Clip i depends only on (seed, i, seconds, fps).

    meta: format "synthetic", seed, activity (segment names in order), segments ([name, first
    frame, end frame) per segment, boundaries at the middle of each cross-fade), body_scale."""
    if int(num_clips) != num_clips or num_clips < 0:
        raise ValueError(f"num_clips must be a non-negative integer, got {num_clips!r}")
    if int(seed) != seed or seed < 0:
        raise ValueError(f"seed must be a non-negative integer, got {seed!r}")
    if not (np.isfinite(fps) and fps > 0 and np.isfinite(seconds) and seconds > 0):
        raise ValueError(f"seconds and fps must be positive, got seconds={seconds!r} fps={fps!r}")
    T = int(round(seconds * fps))
    if T < 2:
        raise ValueError(f"{seconds} s at {fps} fps is fewer than 2 frames")
    num_clips, seed, fps = int(num_clips), int(seed), float(fps)
    skeleton = preset("smpl22")
    if num_clips == 0:
        return []
    t = np.arange(T) / fps  # (T,) seconds

    plans = [_plan_clip(np.random.default_rng([seed, i]), t, fps) for i in range(num_clips)]
    euler = np.stack([p["euler"] for p in plans])  # (N, T, J, 3) x, y, z angles, R = Rz Ry Rx
    rot = Rotation.from_euler("ZYX", euler[..., ::-1].reshape(-1, 3))
    rotvec = rot.as_rotvec().reshape(euler.shape).astype(np.float32)
    offsets = np.stack([p["body"]["offsets"] for p in plans]).astype(np.float32)  # (N, J, 3)

    # Height: lift the body so that its lowest sole point (soft minimum over both heels and toes)
    # rests on z = 0, then add the activity's own lift (flight of jumps and runs).
    local = rot.as_matrix().reshape(*euler.shape, 3)  # (N, T, J, 3, 3)
    soles = np.stack([p["body"]["soles"] for p in plans])  # (N, 2, 3)
    sole_z = np.concatenate([_sole_heights(local, offsets, soles, side) for side in (0, 1)], -1)  # (N, T, 4)
    root = np.stack([p["root"] for p in plans])  # (N, T, 3), z = lift
    root[..., 2] -= _softmin(sole_z, axis=-1)
    root = root.astype(np.float32)

    positions = fk_axis_angle(
        torch.from_numpy(rotvec).double(),
        torch.from_numpy(root).double(),
        torch.from_numpy(offsets).double()[:, None],
        skeleton.parents,
    )
    positions = positions.numpy().astype(np.float32)  # (N, T, J, 3)
    return [
        Clip(
            positions=positions[i],
            fps=fps,
            skeleton=skeleton,
            name=f"synthetic_{i:04d}",
            source=f"synthetic://{seed}/{i}",
            rotations=rotvec[i],
            root_translation=root[i],
            offsets=offsets[i],
            meta={
                "format": "synthetic",
                "seed": seed,
                "activity": [s[0] for s in p["segments"]],
                "segments": p["segments"],
                "body_scale": p["body"]["scale"],
            },
        )
        for i, p in enumerate(plans)
    ]


def _sole_heights(local: np.ndarray, offsets: np.ndarray, soles: np.ndarray, side: int) -> np.ndarray:
    """Heights of the heel and toe sole points of one foot with the root at the origin, (N, T, 2).

    FK down one leg only (pelvis, hip, knee, ankle, foot). local: (N, T, J, 3, 3) local rotations,
    offsets (N, J, 3), soles (N, 2, 3): heel in the ankle's frame, toe in the foot joint's."""
    _, hip, knee, ankle, *_ = _SIDES[side]
    foot = L_FOOT if side == 0 else R_FOOT
    glob = local[..., PELVIS, :, :]  # (N, T, 3, 3)
    pos = np.zeros(glob.shape[:-1])  # (N, T, 3)
    for j in (hip, knee, ankle, foot):
        pos = pos + (glob @ offsets[:, None, j, :, None])[..., 0]
        glob = glob @ local[..., j, :, :]
        if j == ankle:
            heel = pos + (glob @ soles[:, None, 0, :, None])[..., 0]
    toe = pos + (glob @ soles[:, None, 1, :, None])[..., 0]
    return np.stack([heel[..., 2], toe[..., 2]], -1)


# --- one clip ---


def _body(rng: np.random.Generator) -> dict:
    """A random body: offsets (J, 3), scale, and the leg/foot geometry the gait IK needs."""
    names = preset("smpl22").joint_names
    scale = rng.uniform(0.85, 1.15)
    factor = {n: rng.uniform(0.95, 1.05) for n in _REST}  # per bone, the same on both sides
    offsets = np.zeros((len(names), 3))
    for j, n in enumerate(names):
        left = n.replace("right_", "left_")
        offsets[j] = np.array(_REST[left]) * scale * factor[left]
        if n.startswith("right_"):
            offsets[j, 1] *= -1
    thigh, shank, foot = offsets[L_KNEE], offsets[L_ANKLE], offsets[L_FOOT]
    b = {
        "offsets": offsets,
        "scale": float(scale),
        # sagittal bone lengths and their rest tilt (forward of straight down)
        "l1": float(np.hypot(thigh[0], thigh[2])),
        "a1": float(np.arctan2(thigh[0], -thigh[2])),
        "l2": float(np.hypot(shank[0], shank[2])),
        "a2": float(np.arctan2(shank[0], -shank[2])),
        "hb": _HEEL_BACK * scale,  # heel behind the ankle
        "fx": float(foot[0]),  # toe ahead of the ankle
        "h": float(-foot[2] + _TOE_DROP * scale),  # ankle above the sole
        "hip": offsets[L_HIP].copy(),
    }
    b["leg"] = b["l1"] + b["l2"] + b["h"] - b["hip"][2]  # pelvis height standing straight
    # Sole points: heel in the ankle's frame, toe in the foot joint's frame.
    b["soles"] = np.array([[-b["hb"], 0.0, -b["h"]], [0.0, 0.0, -_TOE_DROP * scale]])
    return b


def _plan_clip(rng: np.random.Generator, t: np.ndarray, fps: float) -> dict:
    """Everything of one clip but FK: Euler angles (T, J, 3), root (T, 3) with z = lift, body, segments."""
    T = len(t)
    body = _body(rng)
    style = {
        "arm": rng.uniform(0.6, 1.4),
        "lean": rng.uniform(-0.03, 0.08),
        "abd": rng.uniform(0.07, 0.18),
        "elbow": rng.uniform(0.1, 0.35),
    }

    # Segments: [activity, start (s), end (s), constants]. The first starts before t = 0 so that
    # clips do not all begin with a fresh segment.
    segs, start, prev = [], -rng.uniform(0.0, 1.0), None
    while start < t[-1]:
        # Never the same activity twice in a row (walk excepted: it changes speed).
        prob = np.array([0.0 if a == prev and a != "walk" else q for a, q in zip(ACTIVITIES, _ACTIVITY_P)])
        act = ACTIVITIES[rng.choice(len(ACTIVITIES), p=prob / prob.sum())]
        p = _segment_params(act, rng, body, prev_cadence=segs[-1][3]["cadence"] if segs else None)
        segs.append([act, start, start + p["duration"], p])
        start, prev = start + p["duration"], act

    # Blend weights (T, K): a quintic ease across each boundary, 0.3-0.5 s wide; they sum to 1.
    K = len(segs)
    s = np.zeros((T, K + 1))
    s[:, 0] = 1.0
    for k in range(1, K):
        width = segs[k][3]["blend"]
        s[:, k] = _smootherstep((t - segs[k][1] + width / 2) / width)
    w = s[:, :K] - s[:, 1:]  # (T, K)

    # One gait phase (cycles) for the whole clip, integrated from the blended cadence, so that
    # consecutive walk/run/turn segments stay in step through a cross-fade.
    cadence = w @ np.array([sg[3]["cadence"] for sg in segs])  # (T,) gait cycles per second
    phase = rng.uniform() + _integrate(cadence, fps)

    euler = np.zeros((T, 22, 3))
    speed, turn, lift, lateral = np.zeros(T), np.zeros(T), np.zeros(T), np.zeros(T)
    for k, (act, t0, _, p) in enumerate(segs):
        live = w[:, k] > 0
        if not live.any():
            continue
        out = _ACTIVITY_FN[act](t[live] - t0, phase[live], p, style, body)
        wk = w[live, k]
        euler[live] += wk[:, None, None] * out["euler"]
        speed[live] += wk * out.get("speed", 0.0)
        turn[live] += wk * out.get("turn", 0.0)
        lift[live] += wk * out.get("lift", 0.0)
        lateral[live] += wk * out.get("lateral", 0.0)

    # Small smooth wobble of the upper body, so that no two clips share a posture exactly.
    for j in _UPPER_BODY:
        f, ph, amp = rng.uniform(0.1, 0.6, (3, 3)), rng.uniform(0, 2 * np.pi, (3, 3)), rng.uniform(0.005, 0.015, (3, 3))
        euler[:, j, :] += (amp * np.sin(2 * np.pi * f * t[:, None, None] + ph)).sum(-1)

    heading = rng.uniform(0, 2 * np.pi) + _integrate(turn, fps)  # (T,)
    euler[:, PELVIS, 2] += heading
    fwd = np.stack([np.cos(heading), np.sin(heading)], -1)  # (T, 2)
    left = np.stack([-np.sin(heading), np.cos(heading)], -1)
    xy = np.stack([_integrate(speed * fwd[:, 0], fps), _integrate(speed * fwd[:, 1], fps)], -1)
    # Centre the path near the origin: float32 positions stay precise on long clips.
    xy = xy - (xy.min(0) + xy.max(0)) / 2 + rng.uniform(-0.5, 0.5, 2) + lateral[:, None] * left
    root = np.concatenate([xy, lift[:, None]], -1)  # (T, 3)

    segments = []
    for act, t0, t1, _ in segs:
        f0, f1 = max(0, int(round(t0 * fps))), min(T, int(round(t1 * fps)))
        if f1 > f0:
            segments.append([act, f0, f1])
    return {"euler": euler, "root": root, "body": body, "segments": segments}


def _segment_params(act: str, rng: np.random.Generator, body: dict, prev_cadence: float | None) -> dict:
    """Constants of one activity segment: duration and blend width (s), gait cadence (cycles/s), ..."""
    p = {"blend": rng.uniform(0.3, 0.5), "duration": rng.uniform(1.8, 4.0)}
    # Cadence grows with speed; taller people step slower. One gait cycle is two steps.
    if act in ("walk", "turn"):
        p["speed"] = rng.uniform(0.8, 1.6) if act == "walk" else rng.uniform(0.8, 1.3)
        p["cadence"] = (1.0 + 0.6 * p["speed"]) * rng.uniform(0.95, 1.05) / np.sqrt(body["scale"]) / 2
        p["turn"] = rng.uniform(-0.08, 0.08) if act == "walk" else rng.choice([-1, 1]) * rng.uniform(0.5, 1.4)
        p["arm_amp"] = rng.uniform(0.15, 0.3) * p["speed"] / 1.2
    elif act == "run":
        p["speed"] = rng.uniform(2.5, 4.0)
        p["cadence"] = (2.3 + 0.15 * p["speed"]) * rng.uniform(0.95, 1.05) / np.sqrt(body["scale"]) / 2
        p["turn"] = rng.uniform(-0.1, 0.1)
        p["arm_amp"] = rng.uniform(0.4, 0.6)
    else:
        p["cadence"] = prev_cadence if prev_cadence is not None else 0.9
    if act == "jump":
        p["period"] = rng.uniform(1.2, 1.6)
        p["count"] = int(rng.integers(1, 3))
        p["pad"] = 0.35  # standing still before and after the jumps
        p["duration"] = 2 * p["pad"] + p["count"] * p["period"]
        p["knee"] = rng.uniform(0.9, 1.2)
        flight = (_JUMP_FLIGHT[1] - _JUMP_FLIGHT[0]) * p["period"]
        p["height"] = 9.81 * flight**2 / 8 * rng.uniform(0.8, 1.1)  # ballistic apex for that flight time
        p["forward"] = rng.uniform(0.0, 0.4)
    elif act == "arm_swing":
        p["freq"] = rng.uniform(0.5, 1.0)
        p["sagittal"] = rng.uniform(0.3, 1.2)
        p["lateral"] = rng.uniform(0.0, 1.2) * rng.integers(0, 2)
        p["anti"] = float(rng.integers(0, 2))  # 1: arms in counter-phase
        p["elbow"] = rng.uniform(0.1, 0.6)
        p["phase"] = rng.uniform(0, 2 * np.pi)
        p["bounce"] = rng.uniform(0.0, 0.12)
    elif act == "wave":
        p["side"] = int(rng.choice([-1, 1]))
        p["raise"] = rng.uniform(1.15, 1.5)
        p["forward"] = rng.uniform(0.0, 0.4)
        p["elbow"] = rng.uniform(1.2, 1.6)
        p["freq"] = rng.uniform(1.5, 2.5)
        p["amp"] = rng.uniform(0.25, 0.5)
        p["phase"] = rng.uniform(0, 2 * np.pi)
    elif act == "idle":
        p["shift"] = rng.uniform(0.015, 0.045)
        p["freq"] = rng.uniform(0.12, 0.3)
        p["look"] = rng.uniform(0.1, 0.5)
        p["phase"] = rng.uniform(0, 2 * np.pi)
    return p


# --- poses: each takes (time in segment (n,), gait phase (n,), constants, style, body) and returns
# Euler angles (n, J, 3) plus root motion: forward speed, turn rate, lift, lateral shift.
# Sign conventions (rotations in the parent's frame, R = Rz Ry Rx):
#   hip/shoulder flexion (limb forward):  y = -angle     knee flexion (shank back): y = +angle
#   ankle dorsiflexion (toes up):         y = -angle     elbow flexion (forearm up): y = -angle
#   trunk forward lean / head nod down:   y = +angle     abduction of a left limb:  x = +angle (right: -)
#   turning left (counter-clockwise):     z = +angle


def _stand(n: int, style: dict, knee: float = 0.05) -> np.ndarray:
    """Relaxed standing: soft knees with flat feet, arms hanging slightly away from the body."""
    e = np.zeros((n, 22, 3))
    _squat(e, knee=np.full(n, knee), pelvis_pitch=np.zeros(n))
    for sign, *_, sh, el in _SIDES:
        e[:, sh, 0] = sign * style["abd"]
        e[:, el, 1] = -style["elbow"]
    e[:, SPINE2, 1] = style["lean"]
    return e


def _squat(e: np.ndarray, knee: np.ndarray, pelvis_pitch: np.ndarray) -> None:
    """Bend both knees keeping the feet flat under the pelvis: hip = pitch + knee / 2, ankle = knee / 2."""
    e[:, PELVIS, 1] += pelvis_pitch
    for _, hip, kn, an, *_ in _SIDES:
        e[:, hip, 1] += -(pelvis_pitch + knee / 2)
        e[:, kn, 1] += knee
        e[:, an, 1] += -(knee / 2)


def _gait_shape(p: dict, run: bool) -> dict:
    """Foot-placement constants of a walk or run at speed v (m/s) and cadence f (cycles/s)."""
    v = p["speed"]
    if run:  # forefoot-ish landing, short stance, high heel recovery
        return {
            "duty": 0.36 - 0.02 * (v - 2.5),
            "strike": 0.05,
            "flat": 0.05,
            "heel_off": 0.12,
            "push": -0.7,
            "ahead": 0.42,
            "kick_back": 0.06 * v,
            "kick_up": 0.08 * v,
            "reach": 0.99,
            "crouch": 0.93,
            "bounce": 0.06,
        }
    return {
        "duty": 0.64 - 0.04 * v,
        "strike": 0.3,
        "flat": 0.1,
        "heel_off": 0.32,
        "push": -0.8,
        "ahead": 0.41,
        "kick_back": 0.04,
        "kick_up": 0.08,
        "reach": 0.995,
        "crouch": None,
        "bounce": 0.0,
    }


def _stance_foot(c: np.ndarray, v: float, f: float, g: dict, b: dict) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Ankle (x, z) relative to the pelvis's ground point, and foot pitch (toes up +), during stance.

    c: (n,) cycle fraction in [0, duty]. The ground under the foot moves back at speed v; the foot
    rolls over the heel until flat, stays flat, then rolls over the toe until toe-off."""
    duty = g["duty"]
    pitch = np.where(c < g["flat"], g["strike"] * (1 - _smoothstep(c / g["flat"])), 0.0)
    roll = np.clip((c - g["heel_off"]) / (duty - g["heel_off"]), 0.0, None)
    pitch = np.where(c > g["heel_off"], g["push"] * roll**2, pitch)
    heel = g["ahead"] * v * duty / f - b["hb"] - v * c / f  # heel's ground point, forward of the pelvis
    cos, sin = np.cos(pitch), np.sin(pitch)
    # Rotate the ankle about the heel (toes up) or the toe (toes down); both agree when flat.
    on_heel = pitch >= 0
    px = np.where(on_heel, heel, heel + b["hb"] + b["fx"])
    rx = np.where(on_heel, b["hb"], -b["fx"])
    return px + rx * cos - b["h"] * sin, rx * sin + b["h"] * cos, pitch


def _foot_path(c: np.ndarray, v: float, f: float, g: dict, b: dict) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Ankle (x, z) and foot pitch over the whole cycle; c: (n,) in [0, 1), 0 = heel strike.

    The swing is a cubic Hermite from the toe-off state to the next heel strike (matching position
    and velocity, so the foot leaves and meets the ground without a jolt) plus a lift/kick bump."""
    duty = g["duty"]
    ax, az, pitch = _stance_foot(np.minimum(c, duty), v, f, g, b)
    eps = 1e-4
    ends = np.array([duty - eps, duty, 0.0, eps])
    ex, ez, ep = _stance_foot(ends, v, f, g, b)
    span = 1.0 - duty  # swing, in cycles
    s = np.clip((c - duty) / span, 0.0, 1.0)
    bump = np.sin(np.pi * s) ** 2

    def hermite(y):
        m0, m1 = (y[1] - y[0]) / eps * span, (y[3] - y[2]) / eps * span
        return _hermite(s, y[1], m0, y[2], m1)

    swing = c > duty
    ax = np.where(swing, hermite(ex) - g["kick_back"] * bump, ax)
    az = np.where(swing, hermite(ez) + g["kick_up"] * bump, az)
    pitch = np.where(swing, hermite(ep), pitch)
    return ax, az, pitch


def _leg_ik(dx: np.ndarray, dz: np.ndarray, b: dict) -> tuple[np.ndarray, np.ndarray]:
    """Hip flexion and knee flexion (rad, anatomical) that put the ankle at (dx, dz) from the hip."""
    l1, l2 = b["l1"], b["l2"]
    # Out of reach (a swing foot the pelvis rose away from): the ankle stops short, smoothly, rather
    # than snapping the knee straight.
    r_max, sharp = 0.997, 400.0
    r = np.hypot(dx, dz) / (l1 + l2)
    r = r_max - np.logaddexp(0.0, sharp * (r_max - r)) / sharp
    d = np.maximum(r * (l1 + l2), abs(l1 - l2) + 1e-3)
    bend = np.pi - np.arccos(np.clip((l1**2 + l2**2 - d**2) / (2 * l1 * l2), -1.0, 1.0))
    thigh = np.arctan2(dx, -dz) + np.arccos(np.clip((l1**2 + d**2 - l2**2) / (2 * l1 * d), -1.0, 1.0))
    hip = thigh - b["a1"]  # joint angle = bone angle less the bone's rest tilt
    knee = bend - b["a1"] + b["a2"]
    return hip, knee


def _gait(tl, phase, p, style, b, run: bool) -> dict:
    """Walk or run. Cycle fraction c = 0 at left heel strike; the right leg is half a cycle later."""
    n = len(tl)
    e = np.zeros((n, 22, 3))
    v, f = p["speed"], p["cadence"]
    g = _gait_shape(p, run)
    c = phase % 1.0
    # Pelvis turns with the swinging leg, drops a little on the swing side, shifts over the
    # stance foot, and leans into turns (centripetal balance).
    yaw = -(0.05 + 0.03 * min(v, 4.0) / 1.4) * np.cos(2 * np.pi * c)
    lean_in = -np.arctan(v * p["turn"] / 9.81)
    roll = 0.04 * np.cos(2 * np.pi * (c - 0.2)) + lean_in
    lat = (0.015 if run else 0.025) * np.cos(2 * np.pi * (c - 0.25))

    feet, hips = [], []
    for sign, *_ in _SIDES:
        ax, az, pitch = _foot_path((c + (0.0 if sign > 0 else 0.5)) % 1.0, v, f, g, b)
        hx, hy, hz = b["hip"] * np.array([1, sign, 1])
        # hip joint relative to the pelvis, after the pelvis roll then yaw
        hip_z = hy * np.sin(roll) + hz * np.cos(roll)
        hip_x = hx * np.cos(yaw) - (hy * np.cos(roll) - hz * np.sin(roll)) * np.sin(yaw)
        feet.append((ax, az, pitch))
        hips.append((hip_x, hip_z))

    # Pelvis height: as high as both legs reach (walking: the stance leg vaults over the foot; the
    # swing foot rises fast enough never to bind); running also caps it with a bounce that is
    # lowest at mid-stance.
    reach = g["reach"] * (b["l1"] + b["l2"])
    caps = [az - hz + np.sqrt(np.maximum(reach**2 - (ax - hx) ** 2, 1e-4)) for (ax, az, _), (hx, hz) in zip(feet, hips)]
    if g["crouch"] is not None:
        low = b["h"] - b["hip"][2] + g["crouch"] * (b["l1"] + b["l2"])
        caps.append(low + g["bounce"] * (0.5 - 0.5 * np.cos(4 * np.pi * (c - g["duty"] / 2))))
    height = _softmin(np.stack(caps, -1), axis=-1)  # (n,) pelvis above the ground
    soles = []
    for (sign, hip, kn, an, _col, sh, el), (ax, az, pitch), (hx, hz) in zip(_SIDES, feet, hips):
        flex, knee = _leg_ik(ax - hx, az - hz - height, b)
        e[:, hip, 1] = -flex
        e[:, kn, 1] = knee
        e[:, an, 1] = -(pitch - (flex - knee))  # foot pitch less the shank's
        e[:, hip, 2] = -yaw  # feet keep pointing where the body goes
        e[:, hip, 0] = -roll - lat / b["leg"]  # legs vertical under a rolled, shifted pelvis
        e[:, an, 0] = lat / b["leg"]
        cos, sin = np.cos(pitch), np.sin(pitch)
        soles += [az - b["hb"] * sin - b["h"] * cos, az + b["fx"] * sin - b["h"] * cos]  # heel, toe heights
        # Arms swing against the legs: the left arm is back when the left leg is forward.
        cl = 2 * np.pi * (c + (0.0 if sign > 0 else 0.5))
        arm = p["arm_amp"] * style["arm"]
        e[:, sh, 1] = -((0.0 if run else 0.03) - arm * np.cos(cl))
        e[:, sh, 0] = sign * (style["abd"] + (0.1 if run else 0.0))
        e[:, el, 1] = -((1.4 if run else style["elbow"]) + (0.25 if run else 0.3 * arm) * (0.5 - 0.5 * np.cos(cl)))
    e[:, PELVIS, 2] = yaw
    e[:, PELVIS, 0] = roll
    e[:, SPINE1, 0] = -0.6 * (roll - lean_in)
    e[:, SPINE3, 0] = -0.4 * (roll - lean_in)
    e[:, SPINE3, 2] = -1.3 * yaw  # chest counter-rotates
    e[:, NECK, 2] = 0.3 * yaw
    lean = style["lean"] + (0.15 if run else 0.04)
    e[:, SPINE1, 1] = lean / 2
    e[:, SPINE2, 1] = lean / 2 + 0.015 * np.cos(4 * np.pi * c)  # trunk nods at step frequency
    e[:, HEAD, 1] = -lean / 2
    e[:, HEAD, 2] = 0.25 * np.tanh(p["turn"])  # look into the turn
    # The FK pass puts the lowest sole on the ground; lift it by the designed clearance, and in
    # running by the ballistic float between toe-off and the other foot's landing (both feet
    # rise with the body, so the legs need not reach further).
    lift = _softmin(np.stack(soles, -1), axis=-1)
    if run:
        float_ = (0.5 - g["duty"]) / f  # seconds in the air
        lift = (
            lift
            + 9.81 * float_**2 / 8 * np.sin(np.pi * np.clip(((c % 0.5) - g["duty"]) / (0.5 - g["duty"]), 0.0, 1.0)) ** 2
        )
    return {"euler": e, "speed": v, "turn": p["turn"], "lift": lift, "lateral": lat}


def _walk(tl, phase, p, style, b):
    return _gait(tl, phase, p, style, b, run=False)


def _run(tl, phase, p, style, b):
    return _gait(tl, phase, p, style, b, run=True)


def _jump(tl, phase, p, style, b):
    n = len(tl)
    u = np.clip((tl - p["pad"]) / p["period"], 0.0, p["count"])
    frac = u % 1.0  # (n,) position in the current jump
    crouch = PchipInterpolator(_JUMP_U, _JUMP_CROUCH)(frac)
    plantar = PchipInterpolator(_JUMP_U, _JUMP_PLANTAR)(frac)
    shoulder = PchipInterpolator(_JUMP_U, _JUMP_SHOULDER)(frac) * style["arm"] ** 0.5
    elbow = PchipInterpolator(_JUMP_U, _JUMP_ELBOW)(frac)
    e = np.zeros((n, 22, 3))
    _squat(e, knee=0.05 + p["knee"] * crouch, pelvis_pitch=0.25 * crouch)
    for sign, _hip, _kn, an, _col, sh, el in _SIDES:
        e[:, an, 1] += plantar
        e[:, sh, 1] = -shoulder
        e[:, sh, 0] = sign * style["abd"]
        e[:, el, 1] = -elbow
    e[:, SPINE1, 1] += 0.2 * crouch + style["lean"]
    e[:, SPINE2, 1] += 0.2 * crouch
    e[:, NECK, 1] += -0.2 * crouch  # eyes stay on the horizon
    t0, t1 = _JUMP_FLIGHT
    s = np.clip((frac - t0) / (t1 - t0), 0.0, 1.0)
    lift = p["height"] * np.sin(np.pi * s) ** 2
    # Forward travel happens in the air: the speed that covers p["forward"] over the flight, smoothly.
    speed = p["forward"] * 30 * s**2 * (1 - s) ** 2 / ((t1 - t0) * p["period"])
    return {"euler": e, "lift": lift, "speed": speed}


def _arm_swing(tl, phase, p, style, b):
    n = len(tl)
    e = _stand(n, style, knee=0.0)
    ang = 2 * np.pi * p["freq"] * tl + p["phase"]
    for i, (sign, _hip, _kn, _an, col, sh, el) in enumerate(_SIDES):
        a = ang + np.pi * p["anti"] * i
        raise_ = p["lateral"] * (0.5 - 0.5 * np.cos(a))
        e[:, sh, 1] = -(0.1 + p["sagittal"] * np.sin(a))
        e[:, sh, 0] = sign * (style["abd"] + raise_)
        e[:, col, 0] = sign * 0.1 * raise_  # shrug as the arm goes up
        e[:, el, 1] = -p["elbow"]
    _squat(e, knee=0.05 + p["bounce"] * (0.5 - 0.5 * np.cos(2 * ang)), pelvis_pitch=np.zeros(n))  # knees give
    e[:, SPINE2, 1] += 0.05 * np.sin(ang)
    return {"euler": e}


def _wave(tl, phase, p, style, b):
    n = len(tl)
    e = _stand(n, style)
    k = 0 if p["side"] > 0 else 1
    sign, hip, kn, an, col, sh, el = _SIDES[k]
    osc = p["amp"] * np.sin(2 * np.pi * p["freq"] * tl + p["phase"])
    # Upper arm out to the side and up; the forearm turned up about the forward axis swings side
    # to side in the frontal plane.
    e[:, sh, 0] = sign * p["raise"]
    e[:, sh, 1] = -p["forward"]
    e[:, col, 0] = sign * 0.15
    e[:, el, 1] = 0.0
    e[:, el, 0] = sign * (p["elbow"] + osc)
    e[:, SPINE3, 0] += -sign * 0.04 + 0.01 * osc  # lean away from the raised arm
    e[:, HEAD, 2] += sign * 0.15
    e[:, _SIDES[1 - k][5], 1] += -0.05 * np.sin(2 * np.pi * 0.3 * tl)
    return {"euler": e}


def _idle(tl, phase, p, style, b):
    n = len(tl)
    e = _stand(n, style)
    ang = 2 * np.pi * p["freq"] * tl + p["phase"]
    lat = p["shift"] * np.sin(ang)  # weight shift from foot to foot
    for _sign, hip, _kn, an, _col, sh, _el in _SIDES:
        e[:, hip, 0] += -lat / b["leg"]
        e[:, an, 0] += lat / b["leg"]
        e[:, sh, 1] += -0.05 * np.sin(ang + 0.5)
    e[:, SPINE1, 0] += 0.5 * lat / b["leg"]
    e[:, SPINE3, 0] += 0.5 * lat / b["leg"]
    e[:, HEAD, 2] += p["look"] * np.sin(0.37 * ang + 1.0)
    e[:, HEAD, 1] += 0.05 * np.sin(0.61 * ang)
    return {"euler": e, "lateral": lat}


_ACTIVITY_FN = {
    "walk": _walk,
    "run": _run,
    "turn": _walk,
    "jump": _jump,
    "arm_swing": _arm_swing,
    "wave": _wave,
    "idle": _idle,
}


# --- small helpers ---


def _softmin(x: np.ndarray, axis: int) -> np.ndarray:
    """Smooth minimum (at most _TAU * log(count) below the true one)."""
    m = x.min(axis=axis, keepdims=True)
    return (m - _TAU * np.log(np.exp(-(x - m) / _TAU).sum(axis=axis, keepdims=True))).squeeze(axis)


def _smoothstep(x: np.ndarray) -> np.ndarray:
    x = np.clip(x, 0.0, 1.0)
    return x * x * (3 - 2 * x)


def _smootherstep(x: np.ndarray) -> np.ndarray:
    x = np.clip(x, 0.0, 1.0)
    return x * x * x * (x * (6 * x - 15) + 10)


def _hermite(s: np.ndarray, p0: float, m0: float, p1: float, m1: float) -> np.ndarray:
    """Cubic Hermite on s in [0, 1] from p0 (slope m0) to p1 (slope m1)."""
    s2, s3 = s * s, s * s * s
    return (2 * s3 - 3 * s2 + 1) * p0 + (s3 - 2 * s2 + s) * m0 + (-2 * s3 + 3 * s2) * p1 + (s3 - s2) * m1


def _integrate(rate: np.ndarray, fps: float) -> np.ndarray:
    """Trapezoidal running integral, starting at 0."""
    return np.concatenate([[0.0], np.cumsum((rate[1:] + rate[:-1]) / 2)]) / fps
