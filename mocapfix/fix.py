"""Cleaning motion of any length with a trained checkpoint: the library behind `mocapfix fix`.

One file's clips (its people) -> the model's joints, by name -> the model's fps -> sliding
windows of the model's length (every window of every person in one batched pass) -> the
model's estimate of every token -> windows blended with smooth weights -> the input's frame
times -> merged with the input by mode:

    infill   missing tokens (NaN) get the estimate; observed tokens stay bit-identical.
    denoise  observed tokens get the estimate; missing tokens stay missing.
    both     every token gets the estimate (denoised and filled).

A Fixer (mocapfix.fixers) turns a batch of windows into estimates; there is one per checkpoint
kind. Nothing here imports training code.

Fixers on positions (XMAE; Motion-DVAE on its positions state) take windows of joint positions.
Motion-DVAE on its rotations state takes windows of joint rotations (BVH, AMASS input) and gives
rotations back: those clips go through fix_rotation_clips, and a BVH input gets a BVH output.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import roma
import torch

from mocapfix.clip import Clip, MotionFileError, check_human_scale
from mocapfix.evaluation.baselines import CLASSICAL, lerp_infill, limb_infill
from mocapfix.evaluation.metrics import LimbSigma
from mocapfix.evaluation.policy import FillPolicy, apply_fill_policy, policy_names, suspect_tokens
from mocapfix.fixers import Fixer, RotationFixer
from mocapfix.io import read_motion
from mocapfix.io.joint_names import match_joints
from mocapfix.kinematics import fk_axis_angle
from mocapfix.skeleton import Skeleton

MODES = ("infill", "denoise", "both")


# --- joints and frame times ---


def map_joints(
    skeleton: Skeleton,
    model: Skeleton,
    source="",
    joint_map: dict[str, str] | None = None,
    allow_missing: bool = False,
) -> np.ndarray:
    """(J_model,) index of each model joint in `skeleton`: by `joint_map` (input name -> model
    name), the same name (any case, namespace prefixes aside), else the same body part under
    another convention's name (io/joint_names.py: Mixamo, CMU, SMPL, Human3.6M, ...). A model
    joint the input lacks is an error naming them all, unless allow_missing: then its index is -1
    (a positions model estimates it like any missing token) as long as at least half of the
    model's joints are found. Input joints the model does not know are not in the map (the model
    never sees them; _fill_other_joints fills their holes)."""
    found = match_joints(skeleton, model, joint_map)
    missing = [n for n in model.joint_names if n not in found]
    if missing and allow_missing and 2 * len(found) >= model.num_joints:
        return np.array([found.get(n, -1) for n in model.joint_names], dtype=np.int64)
    if missing:
        raise MotionFileError(
            source,
            f"skeleton does not match the model's ({model.name}, {model.num_joints} "
            f"joints): missing {', '.join(missing)} (`mocapfix inspect FILE --ckpt CKPT` shows the "
            "mapping; --joint-map FILE names joints, one `input name: model name` per line)",
        )
    return np.array([found[n] for n in model.joint_names], dtype=np.int64)


def resample_frames(x: np.ndarray, src_fps: float, dst_fps: float, num: int) -> np.ndarray:
    """x: (T, ...) sampled at t = k / src_fps -> (num, ...) at t = k / dst_fps, linear.
    A sample takes NaN from a neighbour it uses; shared instants are copied exactly; times past
    the last frame are NaN (the caller decides what they mean)."""
    T = x.shape[0]
    f = np.arange(num) * (src_fps / dst_fps)
    f = np.where(np.abs(f - np.round(f)) < 1e-6, np.round(f), f)
    past = f > T - 1
    f = np.minimum(f, T - 1)
    i0 = np.floor(f).astype(np.int64)
    i1 = np.minimum(i0 + 1, T - 1)
    w = (f - i0).reshape(-1, *([1] * (x.ndim - 1)))
    out = x[i0] * (1 - w) + x[i1] * w
    exact = (w == 0).reshape(-1)
    out[exact] = x[i0[exact]]  # bit-identical, and no NaN from an unused neighbour
    out[past] = np.nan
    return out.astype(x.dtype, copy=False)


def model_frames(num_frames: int, fps: float, model_fps: float) -> int:
    """Frames at the model's fps that cover the input's time span (the last one may be past it)."""
    return int(math.ceil((num_frames - 1) * model_fps / fps - 1e-6)) + 1


# --- windows ---


def window_layout(num_frames: int, window: int, overlap: float) -> tuple[np.ndarray, int]:
    """Starts of the windows over a clip of num_frames (model fps) and the stride.
    Stride window * (1 - overlap); one more window ends at the clip's end when the stride does
    not land there. A clip shorter than a window gets one window, centred: start < 0."""
    stride = max(1, int(round(window * (1.0 - overlap))))
    if num_frames <= window:
        return np.array([-((window - num_frames) // 2)], dtype=np.int64), stride
    starts = np.arange(0, num_frames - window + 1, stride, dtype=np.int64)
    if starts[-1] != num_frames - window:
        starts = np.append(starts, num_frames - window)
    return starts, stride


def windows_for(need: np.ndarray, window: int, overlap: float) -> tuple[np.ndarray, int]:
    """Starts of the windows that cover the needed frames need (K,) bool, and the stride.

    A run of needed frames no longer than three quarters of a window gets one window centred on
    it: the paper evaluates with the gap in the middle of the window, where the model has
    context on both sides. A longer run gets the regular grid of window_layout over the run and a quarter
    window of context on each side. When that takes more windows than the plain grid (short runs
    close together: scattered missing tokens), the grid's windows that hold a needed frame are
    used instead. With every frame needed it is window_layout's grid."""
    K = len(need)
    stride = max(1, int(round(window * (1.0 - overlap))))
    if K <= window:
        return window_layout(K, window, overlap)
    edges = np.diff(np.concatenate([[0], need.astype(np.int8), [0]]))
    starts = []
    for s, e in zip(np.nonzero(edges == 1)[0], np.nonzero(edges == -1)[0]):  # runs [s, e)
        if e - s <= 3 * window // 4:
            starts.append([min(max((s + e - window) // 2, 0), K - window)])
        else:
            lo, hi = max(0, s - window // 4), min(K, e + window // 4)
            grid, _ = window_layout(hi - lo, window, overlap)
            starts.append(np.clip(grid + lo, 0, K - window))
    if not starts:
        return np.zeros(0, dtype=np.int64), stride
    starts = np.unique(np.concatenate(starts)).astype(np.int64)
    # Many short runs close together (scattered missing tokens): the plain grid is cheaper.
    grid, _ = window_layout(K, window, overlap)
    grid = grid[[need[g : g + window].any() for g in grid]]
    return (grid if len(grid) < len(starts) else starts), stride


def blend_weights(window: int, stride: int) -> np.ndarray:
    """(W,) weights that rise over the overlap, stay 1 between, and fall over the overlap:
    sin^2 ramps, so two windows one stride apart sum to exactly 1 where they overlap (Hann for
    overlap W/2). Never 0, so a frame that only one window covers (clip ends) keeps it."""
    overlap = window - stride
    w = np.ones(window)
    if overlap > 0:
        ramp = np.sin(0.5 * np.pi * (np.arange(overlap) + 0.5) / overlap) ** 2
        w[:overlap] = ramp
        w[window - overlap :] = np.minimum(w[window - overlap :], ramp[::-1])
    return w


# --- fixing the clips of one file ---


@dataclass
class FixReport:
    frames: int  # per person, at the input's fps
    people: int  # clips of the file (people; sequences for Human3.6M)
    filled: int  # missing tokens given a value
    replaced: int  # observed tokens replaced by the estimate
    limb_sigma_before_mm: float  # the model's limbs, over the input's tokens
    limb_sigma_after_mm: float
    windows: int  # windows the model ran on
    notes: list[str] = field(default_factory=list)
    filled_by: dict[str, int] = field(default_factory=dict)  # method -> missing tokens it filled (fill policy)


def fix_clips(
    clips: list[Clip],
    fixer: Fixer,
    mode: str = "infill",
    overlap: float = 0.5,
    batch_size: int = 64,
    progress: Callable[[int, int], None] | None = None,
    joint_map: dict[str, str] | None = None,
) -> tuple[list[Clip], FixReport]:
    """Fix the clips of one file; each keeps its skeleton, frames and fps (positions only: no
    rotations; a rotation model's clips go to fix_rotation_clips and keep their rotations).
    progress(done, total) is called after each batch of windows.

    With the fixer's fill policy (a checkpoint calibrated on its val split, evaluation/policy.py)
    each hole is filled by the method that was best for holes of its length and part, and in
    denoise / both an observed token is replaced only where the model disagrees with it by more
    than it does with clean data: such tokens are taken out and filled like holes (the model's
    estimate with the wrong value in view is pulled towards it). Without a policy the model's
    estimate is used everywhere the mode says."""
    if mode not in MODES:
        raise ValueError(f"mode must be one of {MODES}, got {mode!r}")
    if not 0.0 <= overlap < 1.0:
        raise ValueError(f"overlap must be in [0, 1), got {overlap}")
    if not clips:
        raise ValueError("fix_clips needs at least one clip")
    check_human_scale(clips, clips[0].source or clips[0].name)
    if getattr(fixer, "state", "positions") == "rotations":
        return fix_rotation_clips(clips, fixer, mode, overlap, batch_size, progress, joint_map)
    policy: FillPolicy | None = getattr(fixer, "policy", None)
    if policy is None or mode == "infill":
        return _fix_positions(clips, fixer, mode, overlap, batch_size, progress, policy, joint_map)

    # Pass 1: the model's estimate of every token; the observed tokens it disagrees with are suspect.
    # (only the model's joints of it are used: the other joints are left as they are)
    estimates, first = _fix_positions(
        clips, fixer, "both", overlap, batch_size, progress, None, joint_map, fill_other_joints=False
    )
    masked, suspects = [], 0
    for c, e in zip(clips, estimates):
        idx = map_joints(c.skeleton, fixer.skeleton, c.source, joint_map, allow_missing=True)
        idx = idx[idx >= 0]  # the model joints the recording has
        x = torch.from_numpy(c.positions[:, idx])
        obs = ~torch.isnan(x).any(-1)
        bad = suspect_tokens(policy, torch.from_numpy(e.positions[:, idx]), x, obs).numpy()  # (T, Jm)
        suspects += int(bad.sum())
        positions = c.positions.copy()
        positions[:, idx] = np.where(bad[..., None], np.nan, positions[:, idx])
        masked.append(c.replace(positions=positions))
    # Pass 2: the holes and the suspect tokens filled by the policy; the rest stays bit-identical.
    out, report = _fix_positions(
        masked, fixer, "infill", overlap, batch_size, progress, policy, joint_map, fill_other_joints=mode != "denoise"
    )
    report.filled, report.replaced = report.filled - suspects, suspects
    if mode == "denoise":  # holes of the input stay holes
        out = [
            o.replace(positions=np.where(np.isnan(c.positions), np.nan, o.positions).astype(np.float32))
            for o, c in zip(out, clips)
        ]
        report.filled = 0
    report.windows += first.windows
    report.limb_sigma_before_mm = first.limb_sigma_before_mm
    report.notes.insert(
        0,
        f"replaced where the model disagreed by more than {1000 * policy.replace_threshold_m:.0f} mm"
        if policy.replace_threshold_m is not None
        else "no replace threshold: observed tokens kept",
    )
    return out, report


def _fix_positions(
    clips: list[Clip],
    fixer: Fixer,
    mode: str,
    overlap: float,
    batch_size: int,
    progress: Callable[[int, int], None] | None,
    policy: FillPolicy | None,
    joint_map: dict[str, str] | None = None,
    fill_other_joints: bool = True,
) -> tuple[list[Clip], FixReport]:
    """fix_clips for a positions model, one pass: the model's estimate merged by mode (infill with
    the fill policy where there is one); the holes of joints the model does not use filled too
    (fill_other_joints, unless denoise)."""
    model, W, fps_m = fixer.skeleton, fixer.window, fixer.fps
    source = clips[0].source or clips[0].name
    many = len(clips) > 1

    def who(i: int) -> str:
        c = clips[i]
        return (
            ""
            if not many
            else f"sequence {c.name}: "
            if c.meta.get("format") == "h36m"
            else f"person {c.meta.get('person_id', i)}: "
        )

    # Each clip at the model's joints and fps. Frames past the input's end are unobserved.
    index, x_in, x_m = [], [], []
    for i, c in enumerate(clips):
        idx = map_joints(c.skeleton, model, source, joint_map, allow_missing=True)
        # (T, Jm, 3); a model joint the recording lacks (-1) is missing in every frame
        x = np.where((idx >= 0)[None, :, None], c.positions[:, np.maximum(idx, 0)], np.nan).astype(np.float32)
        if not np.isfinite(x).all(-1).any():
            raise MotionFileError(source, f"{who(i)}no data for any of the model's joints in any frame")
        index.append(idx)
        x_in.append(x)
        x_m.append(resample_frames(x, c.fps, fps_m, model_frames(c.num_frames, c.fps, fps_m)))

    # Which model frames need an estimate: infill only uses it at missing tokens and at the
    # observed frames next to them (anchors); the other modes use it wherever there is data.
    need_m = []
    for c, x, xm in zip(clips, x_in, x_m):
        obs = np.isfinite(x).all(-1)  # (T, Jm)
        if mode == "infill":
            gap = ~obs.all(-1)
            need = gap.copy()
            need[1:] |= gap[:-1]
            need[:-1] |= gap[1:]
        elif mode == "denoise":
            need = obs.any(-1)
        else:
            need = np.ones(len(obs), dtype=bool)
        # the model frames each needed input frame interpolates from
        f = np.nonzero(need)[0] * (fps_m / c.fps)
        nm = np.zeros(len(xm), dtype=bool)
        nm[np.minimum(np.floor(f + 1e-6).astype(np.int64), len(xm) - 1)] = True
        nm[np.minimum(np.ceil(f - 1e-6).astype(np.int64), len(xm) - 1)] = True
        need_m.append(nm)

    # Every window of every clip, as rows of frame indices into the clips laid end to end;
    # padding (short clips) points at a NaN row past the end. Windows with data go to the model;
    # windows without any (a hole longer than a window) get Lerp instead, blended the same way,
    # so there is no seam where the model's estimate meets the fallback.
    offsets = np.cumsum([0] + [len(xm) for xm in x_m])
    pad_row = int(offsets[-1])
    padded = np.concatenate(x_m + [np.full((1,) + x_m[0].shape[1:], np.nan, dtype=np.float32)])
    model_rows, lerp_rows, stride = [], [], W
    for k, xm in enumerate(x_m):
        starts, stride = windows_for(need_m[k], W, overlap)
        f = starts[:, None] + np.arange(W)[None]  # (n, W) clip frames
        valid = (f >= 0) & (f < len(xm))
        fc = np.clip(f, 0, len(xm) - 1)
        needed = (valid & need_m[k][fc]).any(1)
        data = (valid & np.isfinite(xm).all(-1).any(-1)[fc]).any(1)
        r = np.where(valid, fc + offsets[k], pad_row)
        model_rows.append(r[needed & data])
        lerp_rows.append(r[needed & ~data])
    rows = np.concatenate(model_rows)  # (N, W)
    weights = torch.from_numpy(blend_weights(W, stride))  # (W,)
    Jm = model.num_joints
    acc = torch.zeros(pad_row + 1, Jm, 3, dtype=torch.float64)
    wsum = torch.zeros(pad_row + 1, dtype=torch.float64)

    def add(r: torch.Tensor, est: torch.Tensor) -> None:
        # r: (B, W) rows, est: (B, W, Jm, 3); padding rows weigh nothing
        w = weights[None].expand(len(r), -1) * (r != pad_row)  # (B, W)
        acc.index_add_(0, r.reshape(-1), (est * w[..., None, None]).reshape(-1, Jm, 3))
        wsum.index_add_(0, r.reshape(-1), w.reshape(-1))

    bad = []
    for b0 in range(0, len(rows), batch_size):
        r = torch.from_numpy(rows[b0 : b0 + batch_size])  # (B, W)
        pos = torch.from_numpy(padded)[r]  # (B, W, Jm, 3)
        est = fixer.estimate(pos, ~torch.isnan(pos).any(-1)).to(torch.float64)  # (B, W, Jm, 3)
        ok = torch.isfinite(est).flatten(1).all(1)  # (B,)
        add(r[ok], est[ok])
        bad.append(rows[b0 : b0 + batch_size][~ok.numpy()])
        if progress is not None:
            progress(min(b0 + batch_size, len(rows)), len(rows))
    model_wsum = wsum.clone()
    fallback = np.concatenate(lerp_rows + bad)
    if len(fallback):
        lerp = [
            lerp_infill(torch.from_numpy(xm).double()[None], torch.from_numpy(np.isfinite(xm).all(-1))[None])[0]
            for xm in x_m
        ]
        lerp = torch.cat(lerp + [torch.zeros(1, Jm, 3, dtype=torch.float64)])  # (frames + 1, Jm, 3)
        r = torch.from_numpy(fallback)
        add(r, lerp[r])
    bad_windows = sum(len(b) for b in bad)

    out_clips, notes = [], []
    filled = replaced = lerped = other_filled = 0
    filled_by: dict[str, int] = {}
    never, absent_joints = {}, {}
    sigma_before, sigma_after = LimbSigma(list(model.limbs)), LimbSigma(list(model.limbs))
    for k, c in enumerate(clips):
        a, b = offsets[k], offsets[k + 1]
        est_m = (acc[a:b] / wsum[a:b].clamp_min(1e-12)[:, None, None]).numpy()  # (K, Jm, 3)
        lerped += int(((model_wsum[a:b] <= 0).numpy() & need_m[k]).sum())
        est = resample_frames(est_m, fps_m, c.fps, c.num_frames)  # (T, Jm, 3)

        x = x_in[k].astype(np.float64)
        obs = np.isfinite(x).all(-1)  # (T, Jm)
        if mode == "infill":
            # Anchor the estimate on the data: the residual at observed tokens, interpolated
            # over each gap, is added to the fill, so the fill meets the data at both gap ends.
            resid = torch.from_numpy(np.where(obs[..., None], x - est, np.nan))
            resid = lerp_infill(resid[None], torch.from_numpy(obs)[None])[0].numpy()
            new = np.where(obs[..., None], x, est + resid)
            if policy is not None:
                absent = index[k] < 0
                model_fill = new[:, absent]
                new = _policy_fill(policy, x, obs, new, c.fps, model, filled_by)
                new[:, absent] = model_fill  # no classical fill has anything to go on there
        elif mode == "denoise":
            new = np.where(obs[..., None], est, np.nan)
        else:
            new = est
        new = new.astype(np.float32)
        if mode == "infill":
            new[obs] = x_in[k][obs]  # bit-identical, whatever float64 did
        must = obs if mode == "denoise" else np.ones_like(obs)
        if not np.isfinite(new[must]).all():  # a bug, never data: do not write it
            raise MotionFileError(source, f"{who(k)}the estimate is not finite; nothing written")
        filled += int((~obs).sum()) if mode != "denoise" else 0
        replaced += int(obs.sum()) if mode != "infill" else 0
        present = index[k] >= 0
        lost = [model.joint_names[j] for j in np.nonzero(~obs.any(0) & present)[0]]
        if lost:
            never[who(k) or ""] = lost
        if not present.all():
            absent_joints[who(k) or ""] = [model.joint_names[j] for j in np.nonzero(~present)[0]]
            filled -= int((~obs[:, ~present]).sum()) if mode != "denoise" else 0  # estimated, not written

        positions = c.positions.copy()
        positions[:, index[k][present]] = new[:, present]
        if fill_other_joints and mode != "denoise":
            positions, n = _fill_other_joints(positions, index[k], c.skeleton)
            other_filled += n
        sigma_before.update(torch.from_numpy(x_in[k])[None])
        sigma_after.update(torch.from_numpy(new)[None])
        out_clips.append(c.replace(positions=positions, rotations=None, root_translation=None, offsets=None))

    if other_filled:
        notes.append(f"{other_filled} missing tokens of joints the model does not use filled along the skeleton")
        filled += other_filled
    if lerped:
        notes.append(f"{lerped} frames at {fps_m:g} fps had no data within a window: linear interpolation")
    if bad_windows:
        notes.append(f"{bad_windows} windows gave non-finite estimates: linear interpolation there")
    fate = "left missing" if mode == "denoise" else "estimated from the rest of the body"
    for person, joints in never.items():
        notes.append(f"{person}joints never observed: {', '.join(joints)} ({fate})")
    for person, joints in absent_joints.items():
        notes.append(f"{person}model joints not in the recording: {', '.join(joints)} (estimated, not written)")
    whole = _joints_missing_for_a_window(x_m, W, overlap)
    if whole:
        notes.append(f"{whole} windows had a joint missing throughout ({fate})")
    people = len(clips)
    frames = (
        sum(c.num_frames for c in clips) // people
        if clips[0].meta.get("format") != "h36m"
        else sum(c.num_frames for c in clips)
    )
    report = FixReport(
        frames,
        people,
        filled,
        replaced,
        float(sigma_before.compute()),
        float(sigma_after.compute()),
        len(rows),
        notes,
        filled_by,
    )
    return out_clips, report


def _fill_other_joints(positions: np.ndarray, model_joints: np.ndarray, skeleton: Skeleton) -> tuple[np.ndarray, int]:
    """positions: (T, J, 3) a clip with the model's joints fixed -> the holes of its other joints
    (fingers, extra spine joints) filled by the limb fill (each from its parent, bone length kept,
    evaluation/baselines.py), and how many tokens that filled. Observed tokens stay as they are;
    a joint never seen in the clip stays missing."""
    other = np.setdiff1d(np.arange(skeleton.num_joints), model_joints)
    holes = ~np.isfinite(positions[:, other]).all(-1)  # (T, E)
    if not holes.any():
        return positions, 0
    x = torch.from_numpy(positions.astype(np.float64))[None]
    filled = limb_infill(x, ~torch.isnan(x).any(-1), skeleton.parents)[0].numpy()  # (T, J, 3)
    out = positions.copy()
    out[:, other] = np.where(holes[..., None], filled[:, other], positions[:, other])
    return out, int(np.isfinite(out[:, other]).all(-1)[holes].sum())


def _policy_fill(
    policy: FillPolicy,
    x: np.ndarray,
    obs: np.ndarray,
    model_fill: np.ndarray,
    fps: float,
    skeleton: Skeleton,
    counts: dict[str, int],
) -> np.ndarray:
    """x: (T, J, 3) one clip's data, obs: (T, J), model_fill: (T, J, 3) the model's fill -> each
    hole filled by the method the policy names for its length and part; counts[method] += tokens."""
    xt, ot = torch.from_numpy(x)[None], torch.from_numpy(obs)[None]
    fills = {"xmae": torch.from_numpy(model_fill)[None]}
    fills.update({m: CLASSICAL[m](xt, ot, skeleton.parents) for m in policy.methods() if m in CLASSICAL})
    out, chosen = apply_fill_policy(policy, xt, ot, fills, fps, skeleton)
    names = policy_names(policy, fills)
    for i, n in enumerate(torch.bincount(chosen[chosen >= 0], minlength=len(names)).tolist()):
        if n:
            counts[names[i]] = counts.get(names[i], 0) + n
    return out[0].numpy()


def _joints_missing_for_a_window(x_m: list[np.ndarray], W: int, overlap: float) -> int:
    """Windows (with data) in which some model joint is missing in every frame, joints that are
    missing in the whole clip aside (reported on their own)."""
    count = 0
    for xm in x_m:
        obs = np.isfinite(xm).all(-1)  # (K, Jm)
        starts, _ = window_layout(len(xm), W, overlap)
        sometimes = obs.any(0)
        for s in starts:
            o = obs[max(s, 0) : s + W]
            if o.any() and (~o.any(0) & sometimes).any():
                count += 1
    return count


# --- rotation models: rotations in, rotations out ---


def rotation_clips(
    path,
    clips: list[Clip],
    model: Skeleton,
    source: str = "auto",
    joint_map: dict[str, str] | None = None,
    **read_options,
) -> list[Clip]:
    """The clips of a file as a rotation model needs them. A BVH file is read again with only
    the model's joints (read_bvh keep_joints), as the model was trained (without a helper root
    such as Bandai Namco's joint_Root): with a joint whose translation moves below the root, the
    whole tree has no exact rotations, the model's joints do. Other formats come as they are."""
    first = clips[0]
    if first.meta.get("format") != "bvh":
        return clips
    index = map_joints(first.skeleton, model, path, joint_map)
    if first.has_rotations and len(index) == first.skeleton.num_joints:
        return clips
    keep = [first.skeleton.joint_names[i] for i in index]
    return read_motion(path, "bvh" if source == "auto" else source, **read_options, keep_joints=keep)


def resample_motion(
    rotations: np.ndarray, root: np.ndarray, src_fps: float, dst_fps: float, num: int
) -> tuple[np.ndarray, np.ndarray]:
    """rotations (T, J, 3) axis-angle and root translation (T, 3) sampled at t = k / src_fps ->
    (num, J, 3), (num, 3) at t = k / dst_fps: rotations by slerp, the root linearly. Shared
    instants are copied exactly; times past the last frame hold it."""
    T = rotations.shape[0]
    f = np.arange(num) * (src_fps / dst_fps)
    f = np.minimum(np.where(np.abs(f - np.round(f)) < 1e-6, np.round(f), f), T - 1)
    i0 = np.floor(f).astype(np.int64)
    i1 = np.minimum(i0 + 1, T - 1)
    w = f - i0  # (num,)
    r0, r1 = (roma.rotvec_to_rotmat(torch.from_numpy(rotations[i]).double()) for i in (i0, i1))  # (num, J, 3, 3)
    step = roma.rotmat_to_rotvec(r0.transpose(-1, -2) @ r1) * torch.from_numpy(w)[:, None, None]
    rot = roma.rotmat_to_rotvec(r0 @ roma.rotvec_to_rotmat(step)).numpy()  # slerp: R0 exp(w log(R0^T R1))
    out_root = root[i0] * (1 - w[:, None]) + root[i1] * w[:, None]
    exact = w == 0
    rot[exact], out_root[exact] = rotations[i0[exact]], root[i0[exact]]
    return rot.astype(rotations.dtype), out_root.astype(root.dtype)


def fix_rotation_clips(
    clips: list[Clip],
    fixer: RotationFixer,
    mode: str = "denoise",
    overlap: float = 0.5,
    batch_size: int = 64,
    progress: Callable[[int, int], None] | None = None,
    joint_map: dict[str, str] | None = None,
) -> tuple[list[Clip], FixReport]:
    """Fix clips with rotations through a rotation model (a RotationFixer); each keeps its
    skeleton, frames and fps, and comes back with rotations, root translation and the positions
    their forward kinematics gives.

    Rotation data has no missing tokens, so `infill` leaves the clips as they are; `denoise` and
    `both` replace every frame. The model's joints must hang as in the model (the input may have
    more joints: they keep their rotations and move with their parents). Windows as for
    positions (resampled to the model's fps by slerp, windows of the model's length, stride
    window * (1 - overlap)); a clip shorter than a window is one window of its own length (the
    model's networks are recurrent). Overlapping windows are blended with the same sin^2
    weights: rotations as the normalised weighted sum of their quaternions (each turned to the
    hemisphere of the input's, so q and -q agree), the root translation linearly."""
    model, W, fps_m = fixer.skeleton, fixer.window, fixer.fps
    source = clips[0].source or clips[0].name
    many = len(clips) > 1
    notes = list(getattr(fixer, "notes", []))

    def who(i: int) -> str:
        return f"person {clips[i].meta.get('person_id', i)}: " if many else ""

    index = []
    for i, c in enumerate(clips):
        idx = map_joints(c.skeleton, model, source, joint_map)
        if not c.has_rotations:
            why = c.meta.get("no_rotations")
            raise MotionFileError(
                source,
                f"{who(i)}the model ({fixer.kind}, rotations state) needs joint rotations; "
                f"this input has none{f' ({why})' if why else ''}",
            )
        hangs = [c.skeleton.parents[idx[m]] == (idx[p] if p >= 0 else -1) for m, p in enumerate(model.parents)]
        if not all(hangs):
            bad = model.joint_names[hangs.index(False)]
            raise MotionFileError(
                source,
                f"{who(i)}skeleton hierarchy differs from the model's ({model.name}): joint {bad} has another parent",
            )
        if not (np.isfinite(c.rotations).all() and np.isfinite(c.root_translation).all()):
            raise MotionFileError(source, f"{who(i)}rotations are not finite")
        index.append(idx)
    sigma_before, sigma_after = LimbSigma(list(model.limbs)), LimbSigma(list(model.limbs))
    for c, idx in zip(clips, index):
        sigma_before.update(torch.from_numpy(c.positions[:, idx])[None])
    people = len(clips)
    frames = sum(c.num_frames for c in clips) // people
    if mode == "infill":
        notes.append("rotation input has no missing tokens: nothing to fill (--mode denoise replaces them)")
        before = float(sigma_before.compute())
        return list(clips), FixReport(frames, people, 0, 0, before, before, 0, notes)

    # Each clip at the model's fps; every window of every clip as (clip, start, length).
    rot_m, root_m, windows = [], [], []
    for k, (c, idx) in enumerate(zip(clips, index)):
        K = model_frames(c.num_frames, c.fps, fps_m)
        if K < 2:
            raise MotionFileError(source, f"{who(k)}too short for the model: it needs 2 frames at {fps_m:g} fps")
        r, t = resample_motion(c.rotations[:, idx], c.root_translation, c.fps, fps_m, K)
        rot_m.append(r)
        root_m.append(t)
        length = min(W, K)
        starts, _ = window_layout(K, length, overlap)
        windows += [(k, int(s), length) for s in starts]
    # Windows of one length run together (short clips make their own batches).
    windows.sort(key=lambda w: w[2])
    q_ref = [roma.rotvec_to_unitquat(torch.from_numpy(r).double()) for r in rot_m]  # (K, Jm, 4) the input's
    q_acc = [torch.zeros_like(q) for q in q_ref]
    t_acc = [torch.zeros(len(r), 3, dtype=torch.float64) for r in root_m]
    w_acc = [torch.zeros(len(r), dtype=torch.float64) for r in root_m]
    batches = [windows[i : i + batch_size] for i in range(0, len(windows), batch_size)]
    batches = [[w for w in b if w[2] == length] for b in batches for length in sorted({w[2] for w in b})]
    done = bad = 0
    for batch in batches:
        length = batch[0][2]
        frames_of = [torch.arange(s, s + length) for _, s, _ in batch]
        rot = torch.stack([torch.from_numpy(rot_m[k][s : s + length]) for k, s, _ in batch])  # (B, L, Jm, 3)
        root = torch.stack([torch.from_numpy(root_m[k][s : s + length]) for k, s, _ in batch])  # (B, L, 3)
        offs = torch.stack([torch.from_numpy(clips[k].offsets[index[k]]) for k, _, _ in batch])  # (B, Jm, 3)
        est_rot, est_root = fixer.estimate_rotations(rot, root, offs)
        ok = (torch.isfinite(est_rot).flatten(1).all(1) & torch.isfinite(est_root).flatten(1).all(1)).tolist()
        stride = max(1, int(round(length * (1.0 - overlap))))
        weights = torch.from_numpy(blend_weights(length, stride))  # (L,)
        for b, (k, _s, _) in enumerate(batch):
            if not ok[b]:  # those frames keep the input unless another window covers them
                bad += 1
                continue
            f = frames_of[b]
            q = roma.rotvec_to_unitquat(est_rot[b].double())  # (L, Jm, 4)
            q = torch.where((q * q_ref[k][f]).sum(-1, keepdim=True) < 0, -q, q)
            q_acc[k].index_add_(0, f, q * weights[:, None, None])
            t_acc[k].index_add_(0, f, est_root[b].double() * weights[:, None])
            w_acc[k].index_add_(0, f, weights)
        done += len(batch)
        if progress is not None:
            progress(done, len(windows))

    out_clips, replaced = [], 0
    for k, (c, idx) in enumerate(zip(clips, index)):
        have = (w_acc[k] > 0)[:, None]
        q = torch.where(have[..., None], q_acc[k], q_ref[k])
        rot = roma.unitquat_to_rotvec(q / q.norm(dim=-1, keepdim=True)).numpy()  # (K, Jm, 3)
        root = torch.where(
            have, t_acc[k] / w_acc[k].clamp_min(1e-12)[:, None], torch.from_numpy(root_m[k]).double()
        ).numpy()  # (K, 3)
        rot, root = resample_motion(rot, root, fps_m, c.fps, c.num_frames)
        rotations = c.rotations.astype(np.float64)
        rotations[:, idx] = rot
        positions = fk_axis_angle(
            torch.from_numpy(rotations),
            torch.from_numpy(root),
            torch.from_numpy(c.offsets.astype(np.float64)),
            c.skeleton.parents,
        ).numpy()
        if not (np.isfinite(positions).all() and np.isfinite(rotations).all()):  # a bug, never data
            raise MotionFileError(source, f"{who(k)}the estimate is not finite; nothing written")
        replaced += c.num_frames * len(idx)
        sigma_after.update(torch.from_numpy(positions[:, idx])[None])
        out_clips.append(
            c.replace(
                positions=positions.astype(np.float32),
                rotations=rotations.astype(np.float32),
                root_translation=root.astype(np.float32),
            )
        )
    if bad:
        notes.append(f"{bad} windows gave non-finite estimates: the input kept where no other window covers")
    report = FixReport(
        frames, people, 0, replaced, float(sigma_before.compute()), float(sigma_after.compute()), len(windows), notes
    )
    return out_clips, report
