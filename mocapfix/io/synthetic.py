"""Procedural human motion on the smpl22 skeleton: the default dataset, no files needed.

Each clip is a seeded sequence of activities (walk, run, turn, jump, arm_swing, wave, idle)
cross-faded over 0.3-0.5 s. Poses are built as per-joint Euler angles from periodic gait
profiles and keyframed gestures, blended linearly between activities (so the motion stays
smooth), then turned into local axis-angle and run through mocapfix.kinematics FK, so the
positions equal fk_axis_angle(rotations, root_translation, offsets, parents) by construction.

Frame: metres, z up, the character faces +x at heading 0, its left side is +y.
Rest pose (all rotations zero): standing straight, arms hanging down, soles on z = 0.
"""
from __future__ import annotations

import numpy as np
import roma
import torch
from scipy.interpolate import PchipInterpolator
from scipy.spatial.transform import Rotation

from mocapfix.clip import Clip
from mocapfix.kinematics import fk_axis_angle, forward_kinematics
from mocapfix.skeleton import preset

ACTIVITIES = ("walk", "run", "turn", "jump", "arm_swing", "wave", "idle")
_ACTIVITY_P = np.array([0.18, 0.12, 0.16, 0.12, 0.14, 0.12, 0.16])

(PELVIS, L_HIP, R_HIP, SPINE1, L_KNEE, R_KNEE, SPINE2, L_ANKLE, R_ANKLE, SPINE3, L_FOOT, R_FOOT, NECK,
 L_COLLAR, R_COLLAR, HEAD, L_SHOULDER, R_SHOULDER, L_ELBOW, R_ELBOW, L_WRIST, R_WRIST) = range(22)

# (sign, hip, knee, ankle, collar, shoulder, elbow): sign mirrors abduction/yaw about the sagittal plane.
_SIDES = ((+1, L_HIP, L_KNEE, L_ANKLE, L_COLLAR, L_SHOULDER, L_ELBOW),
          (-1, R_HIP, R_KNEE, R_ANKLE, R_COLLAR, R_SHOULDER, R_ELBOW))

# Rest offsets of an average adult (scale 1: 1.7 m tall, pelvis at 0.95 m), each in the parent's
# frame. Right-side joints mirror the left ones (y negated).
_REST = {
    "pelvis": (0.0, 0.0, 0.0),
    "left_hip": (-0.005, 0.085, -0.085), "spine1": (-0.015, 0.0, 0.11), "left_knee": (0.005, 0.01, -0.385),
    "spine2": (0.01, 0.0, 0.135), "left_ankle": (-0.02, 0.0, -0.40), "spine3": (0.0, 0.0, 0.055),
    "left_foot": (0.125, 0.015, -0.06), "neck": (-0.015, 0.0, 0.215), "left_collar": (-0.01, 0.075, 0.14),
    "head": (0.04, 0.0, 0.09), "left_shoulder": (-0.01, 0.11, 0.015), "left_elbow": (-0.01, 0.005, -0.265),
    "left_wrist": (0.01, 0.0, -0.25),
}
_TOE_DROP = 0.02         # sole below the foot (toe) joint, metres at scale 1
_HEEL_BACK = 0.05        # heel behind the ankle joint
_SOFTMIN_TAU = 0.01      # metres: smooths the switch of the supporting contact point
_RUN_GAIN = 1.0
_HIP_TRI = 0.0
_HIP_WARP = 0.0
_STRIDE_GAIN = 1.4       # hip amplitude per unit of (speed / 2 pi cadence leg), tuned to minimise foot skate
_UPPER_BODY = (SPINE1, SPINE2, SPINE3, NECK, HEAD, L_COLLAR, R_COLLAR, L_SHOULDER, R_SHOULDER, L_ELBOW, R_ELBOW)

# Countermovement jump, keyframes over one jump cycle u in [0, 1): crouch depth (fraction of the
# deepest knee bend), ankle plantarflexion (rad), shoulder flexion (rad), elbow flexion (rad).
_JUMP_U = np.array([0.0, 0.08, 0.28, 0.44, 0.58, 0.72, 0.80, 0.92, 1.0])
_JUMP_CROUCH = np.array([0.0, 0.05, 1.0, 0.0, 0.25, 0.05, 0.55, 0.1, 0.0])
_JUMP_PLANTAR = np.array([0.0, 0.0, 0.0, 0.55, 0.35, 0.2, 0.0, 0.0, 0.0])
_JUMP_SHOULDER = np.array([0.0, -0.1, -0.6, 1.1, 1.0, 0.5, 0.1, 0.0, 0.0])
_JUMP_ELBOW = np.array([0.15, 0.2, 0.3, 0.4, 0.5, 0.4, 0.4, 0.2, 0.15])
_JUMP_FLIGHT = (0.45, 0.71)  # take-off and landing, fraction of the cycle


def generate_clips(num_clips: int = 64, seconds: float = 10.0, fps: float = 30.0, seed: int = 0) -> list[Clip]:
    """num_clips procedural clips of `seconds` at `fps`; clip i depends only on (seed, i)."""
    if int(num_clips) != num_clips or num_clips < 0:
        raise ValueError(f"num_clips must be a non-negative integer, got {num_clips!r}")
    if int(seed) != seed or seed < 0:
        raise ValueError(f"seed must be a non-negative integer, got {seed!r}")
    if not (np.isfinite(fps) and fps > 0 and np.isfinite(seconds) and seconds > 0):
        raise ValueError(f"seconds and fps must be positive, got seconds={seconds!r} fps={fps!r}")
    T = int(round(seconds * fps))
    if T < 2:
        raise ValueError(f"{seconds} s at {fps} fps is fewer than 2 frames")
    num_clips, seed = int(num_clips), int(seed)
    skeleton = preset("smpl22")
    if num_clips == 0:
        return []
    t = np.arange(T) / fps  # (T,) seconds

    plans = [_plan_clip(np.random.default_rng([seed, i]), t, fps) for i in range(num_clips)]
    euler = np.stack([p["euler"] for p in plans])        # (N, T, J, 3) x, y, z angles, R = Rz Ry Rx
    offsets = np.stack([p["offsets"] for p in plans])    # (N, J, 3)
    rotvec = Rotation.from_euler("ZYX", euler[..., ::-1].reshape(-1, 3)).as_rotvec()
    rotvec = rotvec.reshape(euler.shape).astype(np.float32)
    offsets = offsets.astype(np.float32)

    # Height: FK with the root on the origin, then lift the body so that its lowest sole point
    # (soft minimum over both heels and toes) rests on z = 0, plus any flight height.
    parents = skeleton.parents
    rv = torch.from_numpy(rotvec).double()
    off = torch.from_numpy(offsets).double()[:, None]    # (N, 1, J, 3)
    pos0, glob = forward_kinematics(roma.rotvec_to_rotmat(rv), torch.zeros(*rv.shape[:2], 3, dtype=torch.float64),
                                    off, parents)        # (N, T, J, 3), (N, T, J, 3, 3)
    soles = torch.from_numpy(np.stack([p["soles"] for p in plans]))[:, None]   # (N, 1, 2, 3) heel, toe
    contacts = torch.cat([_sole_points(pos0, glob, soles, side) for side in ("left", "right")], dim=-2)  # (N, T, 4, 3)
    cz = contacts[..., 2]
    lowest = -_SOFTMIN_TAU * torch.logsumexp(-cz / _SOFTMIN_TAU, dim=-1)  # (N, T)
    root = np.stack([p["root_xy"] for p in plans])       # (N, T, 3) with z = extra height
    root[..., 2] += -lowest.numpy()
    root = root.astype(np.float32)

    positions = fk_axis_angle(rv, torch.from_numpy(root).double(), off, parents).numpy().astype(np.float32)
    clips = []
    for i, p in enumerate(plans):
        clips.append(Clip(positions=positions[i], fps=float(fps), skeleton=skeleton, name=f"synthetic_{i:04d}",
                          source=f"synthetic://{seed}/{i}", rotations=rotvec[i], root_translation=root[i],
                          offsets=offsets[i],
                          meta={"format": "synthetic", "seed": seed, "activity": [s[0] for s in p["segments"]],
                                "segments": p["segments"], "body_scale": p["scale"]}))
    return clips


def _sole_points(pos: torch.Tensor, glob: torch.Tensor, soles: torch.Tensor, side: str) -> torch.Tensor:
    """Heel and toe sole points of one foot, (N, T, 2, 3).
    pos (N, T, J, 3), glob (N, T, J, 3, 3), soles (N, 1, 2, 3): heel in the ankle's frame, toe in the foot's."""
    ankle, foot = (L_ANKLE, L_FOOT) if side == "left" else (R_ANKLE, R_FOOT)
    heel = pos[..., ankle, :] + (glob[..., ankle, :, :] @ soles[..., 0, :, None])[..., 0]
    toe = pos[..., foot, :] + (glob[..., foot, :, :] @ soles[..., 1, :, None])[..., 0]
    return torch.stack([heel, toe], dim=-2)


# --- one clip ---

def _body(rng: np.random.Generator) -> tuple[np.ndarray, float]:
    """Offsets (J, 3) of a random body and its scale. Per-bone variation is left/right symmetric."""
    names = preset("smpl22").joint_names
    scale = rng.uniform(0.85, 1.15)
    factor = {n: rng.uniform(0.95, 1.05) for n in _REST}
    offsets = np.zeros((len(names), 3))
    for j, n in enumerate(names):
        left = n.replace("right_", "left_")
        offsets[j] = _REST[left]
        if n.startswith("right_"):
            offsets[j, 1] *= -1
        offsets[j] *= scale * factor[left]
    return offsets, scale


def _plan_clip(rng: np.random.Generator, t: np.ndarray, fps: float) -> dict:
    """Everything of one clip but FK: Euler angles (T, J, 3), root xy (T, 3), offsets, segments."""
    T = len(t)
    offsets, scale = _body(rng)
    leg = -(offsets[L_HIP, 2] + offsets[L_KNEE, 2] + offsets[L_ANKLE, 2] + offsets[L_FOOT, 2]) + _TOE_DROP * scale
    style = {"arm": rng.uniform(0.6, 1.4), "lean": rng.uniform(-0.03, 0.08), "abd": rng.uniform(0.07, 0.18),
             "elbow": rng.uniform(0.1, 0.35)}

    # Segments: activity, start, end (s) and per-segment constants.
    segs, start, prev = [], -rng.uniform(0.0, 1.0), None
    while start < t[-1]:
        # No activity twice in a row (but walk, which varies by speed): a repeat would look like one long segment.
        prob = np.array([0.0 if a == prev and a != "walk" else q for a, q in zip(ACTIVITIES, _ACTIVITY_P)])
        act = ACTIVITIES[rng.choice(len(ACTIVITIES), p=prob / prob.sum())]
        p = _segment_params(act, rng, scale, leg, prev_cadence=segs[-1][3]["cadence"] if segs else None)
        segs.append([act, start, start + p["duration"], p])
        start, prev = start + p["duration"], act

    # Blend weights (T, K): a quintic ease across each boundary, 0.3-0.5 s wide; partition of unity.
    K = len(segs)
    s = np.zeros((T, K + 1))
    s[:, 0] = 1.0
    for k in range(1, K):
        width = segs[k][3]["blend"]
        s[:, k] = _smootherstep((t - segs[k][1] + width / 2) / width)
    w = s[:, :K] - s[:, 1:]                                     # (T, K)

    # Shared gait phase (cycles): integrated from the blended cadence, so walk/run/turn stay in step.
    cadence = w @ np.array([sg[3]["cadence"] for sg in segs])   # (T,) gait cycles per second
    phase = rng.uniform() + np.concatenate([[0.0], np.cumsum((cadence[1:] + cadence[:-1]) / 2) / fps])

    euler = np.zeros((T, 22, 3))
    speed, turn, lift, lateral = np.zeros(T), np.zeros(T), np.zeros(T), np.zeros(T)
    for k, (act, t0, t1, p) in enumerate(segs):
        live = w[:, k] > 0
        if not live.any():
            continue
        out = _ACTIVITY_FN[act](t[live], t[live] - t0, phase[live], p, style, leg)
        wk = w[live, k]
        euler[live] += wk[:, None, None] * out["euler"]
        speed[live] += wk * out.get("speed", 0.0)
        turn[live] += wk * out.get("turn", 0.0)
        lift[live] += wk * out.get("lift", 0.0)
        lateral[live] += wk * out.get("lateral", 0.0)

    # Small smooth per-clip wobble of the upper body, so that no two clips share a posture exactly.
    for j in _UPPER_BODY:
        for a in range(3):
            f, ph, amp = rng.uniform(0.1, 0.6, 3), rng.uniform(0, 2 * np.pi, 3), rng.uniform(0.005, 0.015, 3)
            euler[:, j, a] += (amp * np.sin(2 * np.pi * f * t[:, None] + ph)).sum(-1)

    heading = rng.uniform(0, 2 * np.pi) + _integrate(turn, fps)            # (T,)
    euler[:, PELVIS, 2] += heading
    fwd = np.stack([np.cos(heading), np.sin(heading)], -1)                  # (T, 2)
    left = np.stack([-np.sin(heading), np.cos(heading)], -1)
    xy = np.stack([_integrate(speed * fwd[:, 0], fps), _integrate(speed * fwd[:, 1], fps)], -1)
    xy = xy + rng.uniform(-0.5, 0.5, 2) + lateral[:, None] * left
    root = np.concatenate([xy, lift[:, None]], -1)                          # (T, 3)

    last = len(t)
    segments = []
    for act, t0, t1, _ in segs:
        f0, f1 = max(0, int(round(t0 * fps))), min(last, int(round(t1 * fps)))
        if f1 > f0:
            segments.append([act, f0, f1])
    # Sole points: toe just under the foot joint, heel behind the ankle at the same height.
    soles = np.array([[-_HEEL_BACK * scale, 0.0, offsets[L_FOOT, 2] - _TOE_DROP * scale],
                      [0.0, 0.0, -_TOE_DROP * scale]])
    return {"euler": euler, "offsets": offsets, "root_xy": root, "segments": segments, "scale": float(scale),
            "soles": soles}


def _segment_params(act: str, rng: np.random.Generator, scale: float, leg: float, prev_cadence: float | None) -> dict:
    """Constants of one activity segment: duration (s), blend width (s), gait cadence (cycles/s), ..."""
    p = {"blend": rng.uniform(0.3, 0.5), "duration": rng.uniform(1.8, 4.0)}
    # Taller people step slower; one gait cycle is two steps.
    if act in ("walk", "turn"):
        p["speed"] = rng.uniform(0.8, 1.6) if act == "walk" else rng.uniform(0.8, 1.3)
        p["cadence"] = (1.0 + 0.6 * p["speed"]) * rng.uniform(0.95, 1.05) / np.sqrt(scale) / 2
        p["turn"] = rng.uniform(-0.08, 0.08) if act == "walk" else rng.choice([-1, 1]) * rng.uniform(0.5, 1.4)
    elif act == "run":
        p["speed"] = rng.uniform(2.5, 4.0)
        p["cadence"] = (2.3 + 0.15 * p["speed"]) * rng.uniform(0.95, 1.05) / np.sqrt(scale) / 2
        p["turn"] = rng.uniform(-0.1, 0.1)
    else:
        p["cadence"] = prev_cadence if prev_cadence is not None else 0.9
    if act in ("walk", "turn", "run"):
        # Hip amplitude from speed: the stance foot, swept back by the hip at the body's speed,
        # stays roughly planted (peak sweep speed 2 pi f L A ~ forward speed).
        gain = _RUN_GAIN if act == "run" else _STRIDE_GAIN
        p["hip_amp"] = min(0.7, gain * p["speed"] / (2 * np.pi * p["cadence"] * leg))
        p["arm_amp"] = rng.uniform(0.15, 0.3) * p["speed"] / 1.2 if act != "run" else rng.uniform(0.45, 0.7)
    if act == "jump":
        p["period"] = rng.uniform(1.2, 1.6)
        p["count"] = int(rng.integers(1, 3))
        p["pad"] = 0.35
        p["duration"] = 2 * p["pad"] + p["count"] * p["period"]
        p["knee"] = rng.uniform(0.9, 1.2)
        flight = (_JUMP_FLIGHT[1] - _JUMP_FLIGHT[0]) * p["period"]
        p["height"] = 9.81 * flight ** 2 / 8 * rng.uniform(0.8, 1.1)   # ballistic apex for that flight time
        p["forward"] = rng.uniform(0.0, 0.4)
    elif act == "arm_swing":
        p["freq"] = rng.uniform(0.5, 1.0)
        p["sagittal"] = rng.uniform(0.3, 1.2)
        p["lateral"] = rng.uniform(0.0, 1.2) * rng.integers(0, 2)
        p["anti"] = float(rng.integers(0, 2))      # 1: arms in counter-phase
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


# --- poses: each returns Euler angles (n, J, 3) and root motion for n frames ---
# Sign conventions (all rotations in the parent's frame, R = Rz Ry Rx):
#   hip/shoulder flexion (limb forward):  y = -angle     knee flexion (shank back): y = +angle
#   ankle dorsiflexion (toes up):         y = -angle     elbow flexion (forearm up): y = -angle
#   trunk forward lean / head nod down:   y = +angle     abduction of a left limb:  x = +angle (right: -)
#   turning left (counter-clockwise):     z = +angle

def _stand(n: int, style: dict, knee: float = 0.05) -> np.ndarray:
    """Relaxed standing: soft knees with flat feet, arms hanging slightly away from the body."""
    e = np.zeros((n, 22, 3))
    _legs(e, knee=np.full(n, knee), pelvis_pitch=np.zeros(n))
    for sign, _, _, _, _, sh, el in _SIDES:
        e[:, sh, 0] = sign * style["abd"]
        e[:, el, 1] = -style["elbow"]
    e[:, SPINE2, 1] = style["lean"]
    return e


def _legs(e: np.ndarray, knee: np.ndarray, pelvis_pitch: np.ndarray, sides=(0, 1)) -> None:
    """Bend the knees keeping the feet flat and under the pelvis: hip = pitch + knee / 2, ankle = knee / 2."""
    e[:, PELVIS, 1] += pelvis_pitch
    for i in sides:
        _, hip, kn, an, _, _, _ = _SIDES[i]
        e[:, hip, 1] += -(pelvis_pitch + knee / 2)
        e[:, kn, 1] += knee
        e[:, an, 1] += -(knee / 2)


def _vm(c: np.ndarray, mu: float, width: float) -> np.ndarray:
    """Periodic bump (von Mises) at cycle fraction mu, peak 1, about `width` cycles wide."""
    return np.exp((np.cos(2 * np.pi * (c - mu)) - 1) / (2 * np.pi * width) ** 2)


def _gait(t, tl, phase, p, style, leg, run: bool) -> dict:
    """Walk or run. Cycle fraction c = 0 at left heel strike (left hip most flexed); right leg half a cycle later."""
    n = len(t)
    e = np.zeros((n, 22, 3))
    A, arm = p["hip_amp"], p["arm_amp"] * style["arm"]
    lean = style["lean"] + (0.15 if run else 0.04)
    for sign, hip, kn, an, col, sh, el in _SIDES:
        c = phase if sign > 0 else phase + 0.5
        ang = 2 * np.pi * c
        hang = ang - _HIP_WARP * np.sin(ang - 2 * np.pi * 0.3)
        hip_wave = (np.cos(hang) + _HIP_TRI * np.cos(3 * hang)) / (1 + _HIP_TRI)
        if run:
            hip_flex = 0.2 + A * hip_wave
            knee = 0.15 + 0.55 * _vm(c, 0.18, 0.07) + (0.8 + 0.2 * p["speed"]) * _vm(c, 0.68, 0.13)
            dorsi = 0.25 * _vm(c, 0.2, 0.08) - 0.45 * _vm(c, 0.42, 0.06) + 0.1 * _vm(c, 0.8, 0.1)
            shoulder = 0.0 - arm * np.cos(ang)
            elbow = 1.4 + 0.25 * (0.5 - 0.5 * np.cos(ang))
        else:
            hip_flex = 0.08 + A * hip_wave
            knee = 0.06 + 0.28 * _vm(c, 0.14, 0.06) + 1.0 * _vm(c, 0.72, 0.1)
            dorsi = 0.12 * _vm(c, 0.4, 0.1) - 0.35 * _vm(c, 0.62, 0.05) + 0.05 * _vm(c, 0.85, 0.1) \
                - 0.05 * _vm(c, 0.03, 0.04)
            shoulder = 0.03 - arm * np.cos(ang)
            elbow = style["elbow"] + 0.3 * arm * (0.5 - 0.5 * np.cos(ang))
        e[:, hip, 1] = -hip_flex
        e[:, kn, 1] = knee
        e[:, an, 1] = -dorsi
        e[:, sh, 1] = -shoulder
        e[:, sh, 0] = sign * (style["abd"] + (0.1 if run else 0.0))
        e[:, el, 1] = -elbow
    # Pelvis turns with the swinging leg, the chest counter-rotates, the head keeps looking ahead.
    c = phase
    yaw = -(0.06 + 0.03 * A / 0.3) * np.cos(2 * np.pi * c)
    roll = 0.04 * np.cos(2 * np.pi * (c - 0.2))   # swing side of the pelvis drops a little
    lat = (0.015 if run else 0.025) * np.cos(2 * np.pi * (c - 0.25))  # body over the stance foot
    e[:, PELVIS, 2] += yaw
    e[:, SPINE3, 2] += -1.3 * yaw
    e[:, NECK, 2] += 0.3 * yaw
    e[:, PELVIS, 0] += roll
    e[:, SPINE1, 0] += -0.6 * roll
    e[:, SPINE3, 0] += -0.4 * roll
    for sign, hip, kn, an, *_ in _SIDES:
        e[:, hip, 0] += -roll - lat / leg           # keep the legs vertical under a rolled, shifted pelvis
        e[:, an, 0] += lat / leg
    e[:, SPINE1, 1] += lean / 2
    e[:, SPINE2, 1] += lean / 2
    e[:, HEAD, 1] += -lean / 2
    e[:, SPINE2, 1] += 0.015 * np.cos(4 * np.pi * c)  # trunk nods at step frequency
    # Lean into the turn (centripetal balance) and look where you go.
    lean_in = -np.arctan(p["speed"] * p["turn"] / 9.81)
    e[:, PELVIS, 0] += lean_in
    e[:, HEAD, 2] += 0.25 * np.tanh(p["turn"])
    lift = (0.04 * (_vm(c, 0.45, 0.06) + _vm(c, 0.95, 0.06))) if run else 0.0  # flight phase
    return {"euler": e, "speed": p["speed"], "turn": p["turn"], "lift": lift, "lateral": lat}


def _walk(t, tl, phase, p, style, leg):
    return _gait(t, tl, phase, p, style, leg, run=False)


def _run(t, tl, phase, p, style, leg):
    return _gait(t, tl, phase, p, style, leg, run=True)


def _jump(t, tl, phase, p, style, leg):
    n = len(t)
    u = np.clip((tl - p["pad"]) / p["period"], 0.0, p["count"])
    frac = u % 1.0                                             # (n,) position in the current jump
    crouch = PchipInterpolator(_JUMP_U, _JUMP_CROUCH)(frac)
    plantar = PchipInterpolator(_JUMP_U, _JUMP_PLANTAR)(frac)
    shoulder = PchipInterpolator(_JUMP_U, _JUMP_SHOULDER)(frac)
    elbow = PchipInterpolator(_JUMP_U, _JUMP_ELBOW)(frac)
    e = np.zeros((n, 22, 3))
    knee = 0.05 + p["knee"] * crouch
    _legs(e, knee=knee, pelvis_pitch=0.25 * crouch)
    for sign, hip, kn, an, col, sh, el in _SIDES:
        e[:, an, 1] += plantar
        e[:, sh, 1] = -shoulder * style["arm"] ** 0.5
        e[:, sh, 0] = sign * style["abd"]
        e[:, el, 1] = -elbow
    e[:, SPINE1, 1] += 0.2 * crouch + style["lean"]
    e[:, SPINE2, 1] += 0.2 * crouch
    e[:, NECK, 1] += -0.2 * crouch                              # eyes stay on the horizon
    t0, t1 = _JUMP_FLIGHT
    s = np.clip((frac - t0) / (t1 - t0), 0.0, 1.0)
    lift = p["height"] * np.sin(np.pi * s) ** 2
    # Forward travel happens in the air: a smoothstep of distance over the flight, as a speed.
    speed = p["forward"] * 30 * s ** 2 * (1 - s) ** 2 / ((t1 - t0) * p["period"])
    return {"euler": e, "lift": lift, "speed": speed}


def _arm_swing(t, tl, phase, p, style, leg):
    n = len(t)
    e = _stand(n, style)
    ang = 2 * np.pi * p["freq"] * tl + p["phase"]
    for i, (sign, hip, kn, an, col, sh, el) in enumerate(_SIDES):
        a = ang + np.pi * p["anti"] * i
        e[:, sh, 1] = -(0.1 + p["sagittal"] * np.sin(a))
        e[:, sh, 0] = sign * (style["abd"] + p["lateral"] * (0.5 - 0.5 * np.cos(a)))
        e[:, col, 0] = sign * 0.1 * p["lateral"] * (0.5 - 0.5 * np.cos(a))   # shrug as the arm goes up
        e[:, el, 1] = -p["elbow"]
    # Knees give a little with every swing.
    bend = p["bounce"] * (0.5 - 0.5 * np.cos(2 * ang))
    _legs(e, knee=bend, pelvis_pitch=np.zeros(n))
    e[:, SPINE2, 1] += 0.05 * np.sin(ang)
    return {"euler": e}


def _wave(t, tl, phase, p, style, leg):
    n = len(t)
    e = _stand(n, style)
    k = 0 if p["side"] > 0 else 1
    sign, hip, kn, an, col, sh, el = _SIDES[k]
    osc = p["amp"] * np.sin(2 * np.pi * p["freq"] * tl + p["phase"])
    # Upper arm out to the side and up, forearm pointing up (rotation about the forward axis),
    # swinging side to side in the frontal plane.
    e[:, sh, 0] = sign * p["raise"]
    e[:, sh, 1] = -p["forward"]
    e[:, col, 0] = sign * 0.15
    e[:, el, 1] = 0.0
    e[:, el, 0] = sign * (p["elbow"] + osc)
    e[:, SPINE3, 0] += -sign * 0.04 + 0.01 * osc           # lean away from the raised arm
    e[:, HEAD, 2] += sign * 0.15
    other = _SIDES[1 - k]
    e[:, other[5], 1] += -0.05 * np.sin(2 * np.pi * 0.3 * tl)
    return {"euler": e}


def _idle(t, tl, phase, p, style, leg):
    n = len(t)
    e = _stand(n, style)
    ang = 2 * np.pi * p["freq"] * tl + p["phase"]
    lat = p["shift"] * np.sin(ang)                         # weight shift from foot to foot
    for sign, hip, kn, an, col, sh, el in _SIDES:
        e[:, hip, 0] += -lat / leg
        e[:, an, 0] += lat / leg
        e[:, sh, 1] += -0.05 * np.sin(ang + 0.5)
    e[:, SPINE1, 0] += 0.5 * lat / leg
    e[:, SPINE3, 0] += 0.5 * lat / leg
    e[:, HEAD, 2] += p["look"] * np.sin(0.37 * ang + 1.0)
    e[:, HEAD, 1] += 0.05 * np.sin(0.61 * ang)
    return {"euler": e, "lateral": lat}


_ACTIVITY_FN = {"walk": _walk, "run": _run, "turn": _walk, "jump": _jump, "arm_swing": _arm_swing, "wave": _wave,
                "idle": _idle}


def _smootherstep(x: np.ndarray) -> np.ndarray:
    x = np.clip(x, 0.0, 1.0)
    return x * x * x * (x * (6 * x - 15) + 10)


def _integrate(rate: np.ndarray, fps: float) -> np.ndarray:
    """Trapezoidal running integral, starting at 0."""
    return np.concatenate([[0.0], np.cumsum((rate[1:] + rate[:-1]) / 2)]) / fps
