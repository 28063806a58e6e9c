"""Cleaning motion of any length with a trained checkpoint: the library behind `mocapfix fix`.

One file's clips (its people) -> the model's joints, by name -> the model's fps -> sliding
windows of the model's length (every window of every person in one batched pass) -> the
model's estimate of every token -> windows blended with smooth weights -> the input's frame
times (windowing.py: blend_windows) -> merged with the input by mode:

    infill   missing tokens (NaN) get the estimate; observed tokens stay bit-identical.
    denoise  observed tokens get the estimate; missing tokens stay missing.
    both     every token gets the estimate (denoised and filled).

A Fixer (mocapfix.fix.fixers) turns a batch of windows into estimates; there is one per checkpoint
kind. Nothing here imports training code.

What a window holds is the part that differs by fixer, behind windowing.WindowSource:
PositionWindows (XMAE; Motion-DVAE on its positions state: joint positions, Lerp as the fallback,
then the fill policy, the anchoring of fills on the data, and the other joints' holes) and
RotationWindows (Motion-DVAE on its rotations state: joint rotations of BVH or AMASS input,
blended as quaternions; a BVH input gets a BVH output). The jitter remover reads whole takes,
not windows: jitter_clips.py.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import roma
import torch

from mocapfix.core.clip import Clip, MotionFileError, check_human_scale
from mocapfix.core.kinematics import fk_axis_angle
from mocapfix.core.resample import hold_last_frame, model_frames, resample_frames, resample_motion
from mocapfix.core.skeleton import Skeleton
from mocapfix.evaluation.metrics import LimbSigma
from mocapfix.fills.classical import CLASSICAL, hermite_infill, lerp_infill, limb_infill
from mocapfix.fills.motion_matching import FILLS as MATCH_FILLS
from mocapfix.fills.motion_matching import MotionLibrary, Searchable, match_fills, mirror_of
from mocapfix.fills.policy import FillPolicy, apply_fill_policy, excursions, policy_names, recording_step_floor
from mocapfix.fills.recording_policy import measure_policy
from mocapfix.fix.fixers import Fixer, RotationFixer
from mocapfix.fix.windowing import blend_windows, window_layout
from mocapfix.io import read_motion
from mocapfix.rig.mapping import match_joints

MODES = ("infill", "denoise", "both")


# --- joints ---


def map_joints(
    skeleton: Skeleton,
    model: Skeleton,
    source="",
    joint_map: dict[str, str] | None = None,
    allow_missing: bool = False,
) -> np.ndarray:
    """(J_model,) index of each model joint in `skeleton`: by `joint_map` (input name -> model
    name), the same name (any case, namespace prefixes aside), else the same body part under
    another convention's name (rig/mapping.py: Mixamo, CMU, SMPL, Human3.6M, ...). A model
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


# --- fixing the clips of one file ---

NOT_JUDGED = "observed tokens kept, not judged"
# --mode both / denoise replace the observed tokens of a joint that jumped away from the model's
# estimate by more than JUMP_STEP x the checkpoint's replace threshold (0.15 m for the shipped
# XMAE), and by more than the recording's own residual steps allow (recording_step_floor), and
# back within MAX_REPLACED_S (fills/policy.py: excursions). Every other observed token is
# kept as recorded: a model that disagrees with an unusual motion does not move it.
JUMP_STEP = 2 / 3
MAX_REPLACED_S = 2.0


def too_short(clip: Clip, fixer) -> bool:
    """A clip shorter than the model's window gives the model too little motion to judge an
    observed token against (mostly padding in view): denoise and both keep its observed tokens
    and only fill its holes. (A 1-frame take once had its feet moved 0.8 m.)"""
    return model_frames(clip.num_frames, clip.fps, fixer.fps) < fixer.window


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


def _who(clips: list[Clip]) -> Callable[[int], str]:
    """Clip i's name in a message: "" for a file of one clip."""

    def who(i: int) -> str:
        c = clips[i]
        if len(clips) == 1:
            return ""
        return f"sequence {c.name}: " if c.meta.get("format") == "h36m" else f"person {c.meta.get('person_id', i)}: "

    return who


def _frames_and_people(clips: list[Clip]) -> tuple[int, int]:
    """Frames per person and people, as a report gives them (Human3.6M's clips are sequences of one
    subject, laid end to end, not people)."""
    total = sum(c.num_frames for c in clips)
    return (total if clips[0].meta.get("format") == "h36m" else total // len(clips)), len(clips)


def fix_clips(
    clips: list[Clip],
    fixer: Fixer,
    mode: str = "infill",
    overlap: float = 0.5,
    batch_size: int = 64,
    progress: Callable[[int, int], None] | None = None,
    joint_map: dict[str, str] | None = None,
    measured: tuple[FillPolicy | None, str | None] | None = None,
    library: MotionLibrary | None = None,
) -> tuple[list[Clip], FixReport]:
    """Fix the clips of one file; each keeps its skeleton, frames and fps (positions only: no
    rotations; a rotation model's clips go to _fix_rotations and keep their rotations).
    progress(done, total) is called after each batch of windows. measured: (policy, note) from
    measure_recordings over several files (a folder's takes) instead of this file's own;
    library: other takes the motion-matching fills search besides this file's (motion_library:
    the run's files, fix --library).

    With the fixer's fill policy (calibrated on its val split, fills/policy.py, and measured
    again on the recording, recording_policy.py) each hole is filled by the method that was best
    for holes of its length and part, and in denoise / both an observed token is replaced only
    where its joint jumped away from the model's estimate and back (excursions, JUMP_STEP): such
    tokens are taken out and filled like holes (the model's estimate with the wrong value in view
    is pulled towards it). Without a policy the model's estimate is used everywhere the mode says."""
    if mode not in MODES:
        raise ValueError(f"mode must be one of {MODES}, got {mode!r}")
    if not 0.0 <= overlap < 1.0:
        raise ValueError(f"overlap must be in [0, 1), got {overlap}")
    if not clips:
        raise ValueError("fix_clips needs at least one clip")
    check_human_scale(clips, clips[0].source or clips[0].name)
    if getattr(fixer, "state", "positions") == "rotations":
        return _fix_rotations(clips, fixer, mode, overlap, batch_size, progress, joint_map)
    if fixer.kind == "jitter":  # whole takes, no windows: its own module (it uses this one's helpers)
        from mocapfix.fix.jitter_clips import denoise_clips

        return denoise_clips(clips, fixer, mode, progress, joint_map)
    if any(c.duration_s > PIECE_S + 2 * PIECE_MARGIN_S for c in clips):
        return _fix_in_pieces(clips, fixer, mode, overlap, batch_size, progress, joint_map, measured, library)
    policy: FillPolicy | None = getattr(fixer, "policy", None)
    policy_note, view = None, None
    # A calibrated model's holes are filled as the recording's own evidence says (a checkpoint
    # without a policy keeps its documented behaviour: the model everywhere the mode says).
    # In denoise and both the holes are known after the first pass (the input's and the jumps
    # taken out): the policy is measured then, for those kinds of hole only.
    if fixer.kind == "xmae" and policy is not None:
        view = _model_view(clips, fixer, joint_map)
        if measured is not None and measured[1] and mode != "denoise":  # the run's (it measured something)
            policy, policy_note = measured
        elif mode == "infill" and any(not np.isfinite(x).all() for x in view[1]):  # else nothing to fill
            policy, policy_note = _measure(fixer, [view], [clips], mode, overlap, batch_size, library=library)
    if policy is None or mode == "infill":
        out, report = _fix_positions(
            clips, fixer, mode, overlap, batch_size, progress, policy, joint_map, view=view, library=library
        )
        if policy_note:
            report.notes.insert(0, policy_note)
        return out, report

    # Pass 1: the model's estimate of every token; the observed tokens it disagrees with are suspect.
    # (only the model's joints of it are used: the other joints are left as they are)
    estimates, first = _fix_positions(
        clips, fixer, "both", overlap, batch_size, progress, None, joint_map, fill_other_joints=False, view=view
    )
    masked, suspects, seen, replaced, min_step = [], 0, [], [], 0.0
    for c, e in zip(clips, estimates):
        idx = map_joints(c.skeleton, fixer.skeleton, c.source, joint_map, allow_missing=True)
        seen.append(np.isfinite(c.positions[:, np.maximum(idx, 0)]).all(-1) & (idx >= 0))  # (T, Jm)
        idx = idx[idx >= 0]  # the model joints the recording has
        x = torch.from_numpy(c.positions[:, idx])
        obs = ~torch.isnan(x).any(-1)
        if policy.replace_threshold_m is None:
            bad = np.zeros(obs.shape, dtype=bool)
        else:  # (T, Jm) the tokens that jumped away from the estimate and back
            residual = torch.nan_to_num(x - torch.from_numpy(e.positions[:, idx]))
            step = max(JUMP_STEP * policy.replace_threshold_m, recording_step_floor(residual, obs))
            min_step = max(min_step, step)
            bad = excursions(residual, obs, step, round(MAX_REPLACED_S * c.fps)).numpy()
        if too_short(c, fixer):  # no evidence to judge a token against: kept (pass 1 said so)
            bad[:] = False
        suspects += int(bad.sum())
        positions = c.positions.copy()
        positions[:, idx] = np.where(bad[..., None], np.nan, positions[:, idx])
        masked.append(c.replace(positions=positions))
        replaced.append((idx, bad))
    if fixer.kind == "xmae" and policy_note is None:
        masked_view = _model_view(masked, fixer, joint_map)
        if any(not np.isfinite(x).all() for x in masked_view[1]):  # holes or jumps to fill
            policy, policy_note = _measure(
                fixer, [masked_view], [masked], "infill", overlap, batch_size, library=library
            )
    # Pass 2: the holes and the suspect tokens filled by the policy; the rest stays bit-identical.
    out, report = _fix_positions(
        masked,
        fixer,
        "infill",
        overlap,
        batch_size,
        progress,
        policy,
        joint_map,
        fill_other_joints=mode != "denoise",
        seen=seen,
        library=library,
    )
    report.filled, report.replaced = report.filled - suspects, suspects
    out = [_carry_passengers(o, c, idx, bad) for o, c, (idx, bad) in zip(out, clips, replaced)]
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
        f"replaced where a joint jumped more than {1000 * min_step:.0f} mm away from "
        f"the model's estimate and back within {MAX_REPLACED_S:g} s"
        if policy.replace_threshold_m is not None
        else "no replace threshold: observed tokens kept",
    )
    report.notes[:0] = [n for n in first.notes if n.endswith(NOT_JUDGED)] + ([policy_note] if policy_note else [])
    return out, report


# A take longer than PIECE_S is fixed in pieces of PIECE_S, each with PIECE_MARGIN_S of the take
# on both sides as context (more than a window, a jump's MAX_REPLACED_S and most holes): the
# memory a run needs is a piece's, whatever the take's length (a 30-minute take was 2.5x a
# minute's), and each piece's fill policy is measured on that piece of the recording.
PIECE_S = 120.0
PIECE_MARGIN_S = 10.0


def _fix_in_pieces(clips, fixer, mode, overlap, batch_size, progress, joint_map, measured, library):
    """fix_clips for clips of which some are long: each clip alone, a long one piece by piece."""
    out, reports, pieces = [], [], 0
    for c in clips:
        T, piece, margin = c.num_frames, round(PIECE_S * c.fps), round(PIECE_MARGIN_S * c.fps)
        starts = range(0, T, piece) if c.duration_s > PIECE_S + 2 * PIECE_MARGIN_S else [0]
        pieces += len(starts) if len(starts) > 1 else 0
        positions = np.empty_like(c.positions)
        for a in starts:
            b = T if len(starts) == 1 else min(T, a + piece)
            lo, hi = max(0, a - margin), min(T, b + margin)
            part = c.replace(positions=c.positions[lo:hi], rotations=None, root_translation=None, offsets=None)
            (fixed,), report = fix_clips(
                [part], fixer, mode, overlap, batch_size, progress, joint_map, measured, library
            )
            positions[a:b] = fixed.positions[a - lo : b - lo]
            # the piece's counts are over its margins too: its own frames' share of them
            was, now = np.isfinite(c.positions[a:b]).all(-1), np.isfinite(positions[a:b]).all(-1)
            filled, replaced = int((~was & now).sum()), int((was & (positions[a:b] != c.positions[a:b]).any(-1)).sum())
            share = filled / report.filled if report.filled else 0.0
            by = {m: round(n * share) for m, n in report.filled_by.items()}
            reports.append((dataclasses.replace(report, filled=filled, replaced=replaced, filled_by=by), b - a))
        out.append(c.replace(positions=positions, rotations=None, root_translation=None, offsets=None))
    frames, people = _frames_and_people(clips)
    notes, filled_by = [], {}
    for report, _ in reports:
        notes += [n for n in report.notes if n not in notes]
        for method, n in report.filled_by.items():
            filled_by[method] = filled_by.get(method, 0) + n
    notes.append(f"fixed in {pieces} pieces of {PIECE_S:g} s (each with {PIECE_MARGIN_S:g} s of context)")

    def mean(field: str) -> float:  # frame-weighted over the pieces
        return sum(getattr(r, field) * n for r, n in reports) / max(1, sum(n for _, n in reports))

    report = FixReport(
        frames,
        people,
        sum(r.filled for r, _ in reports),
        sum(r.replaced for r, _ in reports),
        mean("limb_sigma_before_mm"),
        mean("limb_sigma_after_mm"),
        sum(r.windows for r, _ in reports),
        notes,
        filled_by,
    )
    return out, report


def measure_recordings(
    recordings: list[list[Clip]],
    fixer: Fixer,
    mode: str = "infill",
    overlap: float = 0.5,
    batch_size: int = 64,
    joint_map: dict[str, str] | None = None,
    map_takes=None,
    library: MotionLibrary | None = None,
) -> tuple[FillPolicy | None, str | None]:
    """The fill policy of several recordings measured together (the takes of one folder: one
    performer or session, whose holes alone are too few to rank the fills by; recording_policy.py)
    -> (policy, a line for the report); pass it to fix_clips(measured=...). (None, None) for a
    checkpoint without a policy, a rotations model or denoise. A recording the model's joints
    cannot be found in is left out (fixing it says why). map_takes: measure_on_takes' (workers);
    library: other takes the motion-matching fills search besides these (fix --library)."""
    if fixer.kind != "xmae" or mode == "denoise" or getattr(fixer, "policy", None) is None:
        return None, None
    views, mapped = [], []
    for clips in recordings:
        try:
            views.append(_model_view(clips, fixer, joint_map))
            mapped.append(clips)
        except MotionFileError:
            continue
    if not views:
        return None, None
    return _measure(fixer, views, mapped, mode, overlap, batch_size, map_takes, library)


def _measure(fixer, views, recordings, mode, overlap, batch_size, map_takes=None, library=None):
    """measure_policy over recordings and their _model_view()s (index, x_in, x_m) -> (policy, note)."""
    tracks = [x for v in views for x in v[2]]  # (K, Jm, 3) per clip, the model's fps
    takes = [(x, c.fps) for v, clips in zip(views, recordings) for x, c in zip(v[1], clips)]  # the input's fps
    keys = [key for clips in recordings for key in take_keys(clips)]
    fill = model_fill(fixer, overlap, batch_size)
    return measure_policy(fixer, tracks, takes, fixer.policy, fill, mode == "both", map_takes, keys, library)


def take_keys(clips: list[Clip]) -> list[tuple[str, int]]:
    """What names each clip of a file in a MotionLibrary: (its file, its place in the file)."""
    return [(c.source or c.name, i) for i, c in enumerate(clips)]


def motion_library(
    recordings: list[list[Clip]], fixer: Fixer, joint_map: dict[str, str] | None = None
) -> MotionLibrary | None:
    """The takes of several files (a run's) at the model's joints and their own fps, for the
    motion-matching fills of every file of the run (fills/motion_matching.py); None where none maps."""
    takes, keys = [], []
    for clips in recordings:
        try:
            _, x_in, _ = _model_view(clips, fixer, joint_map)
        except MotionFileError:
            continue
        takes += [(x, c.fps) for x, c in zip(x_in, clips)]
        keys += take_keys(clips)
    return MotionLibrary(takes, keys, mirror_of(fixer.skeleton)) if takes else None


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
    seen: list[np.ndarray] | None = None,
    view: tuple | None = None,
    library: MotionLibrary | None = None,
) -> tuple[list[Clip], FixReport]:
    """fix_clips for a positions model, one pass: the model's estimate merged by mode (infill with
    the fill policy where there is one); the holes of joints the model does not use filled too
    (fill_other_joints, unless denoise). A clip shorter than the model's window keeps its
    observed tokens in every mode (too_short). seen: (T, Jm) per clip, the tokens the recording
    observed, when `clips` has some taken out (the policy's second pass): the report's "never
    observed" is about the recording. view: _model_view(clips, ...) when the caller has it.
    library: what the policy's motion-matching fills search besides these clips."""
    model, W, fps_m = fixer.skeleton, fixer.window, fixer.fps
    source = clips[0].source or clips[0].name
    who = _who(clips)

    index, x_in, x_m = view if view is not None else _model_view(clips, fixer, joint_map)
    keys = take_keys(clips)
    if policy is not None and any(m in MATCH_FILLS for m in policy.methods()):
        own = [(x, c.fps) for x, c in zip(x_in, clips)]
        library = MotionLibrary(own, keys, mirror_of(model)) if library is None else library.including(own, keys)

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

    # Windows with data go to the model; windows without any (a hole longer than a window) get
    # Lerp instead, blended the same way, so there is no seam where the estimate meets the fallback.
    has_data = [np.isfinite(xm).all(-1).any(-1) for xm in x_m]  # (K,) per clip
    windows = PositionWindows(fixer, x_m, _whole_take_fills(fixer, clips, x_in, x_m))
    blended = blend_windows(windows, need_m, has_data, overlap, batch_size, progress)
    Jm = model.num_joints

    out_clips, notes = [], []
    filled = replaced = lerped = other_filled = 0
    filled_by: dict[str, int] = {}
    never, absent_joints = {}, {}
    sigma_before, sigma_after = LimbSigma(list(model.limbs)), LimbSigma(list(model.limbs))
    for k, c in enumerate(clips):
        est_m = blended.tracks[k].reshape(-1, Jm, 3)  # (K, Jm, 3); NaN at frames no window needed
        lerped += int((~blended.by_model[k] & need_m[k]).sum())
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
                searched = None if library is None else library.without(keys[k], c.fps)
                new = _policy_fill(policy, x, obs, new, c.fps, model, filled_by, searched)
                new[:, absent] = model_fill  # no classical fill has anything to go on there
        elif mode == "denoise":
            new = np.where(obs[..., None], est, np.nan)
        else:
            new = est
        new = new.astype(np.float32)
        keep = mode == "infill" or too_short(c, fixer)
        if keep:
            new[obs] = x_in[k][obs]  # bit-identical, whatever float64 did
        if keep and mode != "infill":
            notes.append(
                f"{who(k)}{c.num_frames} frames, shorter than the model's window ({W} frames at {fps_m:g} fps): "
                + NOT_JUDGED
            )
        must = obs if mode == "denoise" else np.ones_like(obs)
        if not np.isfinite(new[must]).all():  # a bug, never data: do not write it
            raise MotionFileError(source, f"{who(k)}the estimate is not finite; nothing written")
        filled += int((~obs).sum()) if mode != "denoise" else 0
        replaced += int(obs.sum()) if not keep else 0
        present = index[k] >= 0
        observed = obs if seen is None else seen[k]
        lost = [model.joint_names[j] for j in np.nonzero(~observed.any(0) & present)[0]]
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
    if blended.failed:
        notes.append(f"{blended.failed} windows gave non-finite estimates: linear interpolation there")
    fate = "left missing" if mode == "denoise" else "estimated from the rest of the body"
    for person, joints in never.items():
        notes.append(f"{person}joints never observed: {', '.join(joints)} ({fate})")
    for person, joints in absent_joints.items():
        notes.append(f"{person}model joints not in the recording: {', '.join(joints)} (estimated, not written)")
    whole = _joints_missing_for_a_window(x_m, W, overlap)
    if whole:
        notes.append(f"{whole} windows had a joint missing throughout ({fate})")
    frames, people = _frames_and_people(clips)
    report = FixReport(
        frames,
        people,
        filled,
        replaced,
        float(sigma_before.compute()),
        float(sigma_after.compute()),
        blended.windows,
        notes,
        filled_by,
    )
    return out_clips, report


def model_fill(fixer: Fixer, overlap: float, batch_size: int):
    """The model's fill of a take as fix makes it (windows, blending, anchoring on the data; no
    policy): x (T, J, 3) at the model's joints and the take's fps, NaN = missing -> (T, J, 3)."""

    def fill(x: np.ndarray, fps: float) -> np.ndarray:
        take = Clip(x.astype(np.float32), fps, fixer.skeleton)
        out, _ = _fix_positions([take], fixer, "infill", overlap, batch_size, None, None, fill_other_joints=False)
        return out[0].positions

    return fill


def _model_view(
    clips: list[Clip], fixer: Fixer, joint_map: dict[str, str] | None
) -> tuple[list[np.ndarray], list[np.ndarray], list[np.ndarray]]:
    """Each clip at the model's joints (index (Jm,) into the clip's, -1 where it lacks one), on the
    clip's frames (T, Jm, 3) and at the model's fps (K, Jm, 3); a model joint the recording lacks
    is missing in every frame, as are frames past the input's end."""
    model, fps_m = fixer.skeleton, fixer.fps
    source, who = clips[0].source or clips[0].name, _who(clips)
    index, x_in, x_m = [], [], []
    for i, c in enumerate(clips):
        idx = map_joints(c.skeleton, model, source, joint_map, allow_missing=True)
        x = np.where((idx >= 0)[None, :, None], c.positions[:, np.maximum(idx, 0)], np.nan).astype(np.float32)
        if not np.isfinite(x).all(-1).any():
            raise MotionFileError(source, f"{who(i)}no data for any of the model's joints in any frame")
        index.append(idx)
        x_in.append(x)
        x_m.append(resample_frames(x, c.fps, fps_m, model_frames(c.num_frames, c.fps, fps_m)))
    return index, x_in, x_m


def _whole_take_fills(fixer: Fixer, clips: list[Clip], x_in, x_m) -> list[np.ndarray] | None:
    """For an XMAE that corrects the cubic Hermite fill (fill_kind hermite): each take's Hermite
    fill over the whole take at the recording's own frame rate, brought to the model's (K, Jm, 3).
    A window of the model sees at most a second; the fill from the whole take at, say, 120 fps is
    a better start (on the CMU strangers it beats a cubic spline, docs/results.md). None for
    every other model: they correct their window's own fill, as they were trained."""
    net = getattr(fixer, "net", None)
    if fixer.kind != "xmae" or not getattr(net, "fill_input", False) or getattr(net, "fill_kind", "") != "hermite":
        return None
    fills = []
    for c, x, xm in zip(clips, x_in, x_m):
        xt = torch.from_numpy(x.astype(np.float64))[None]  # (1, T, Jm, 3)
        filled = hermite_infill(xt, ~torch.isnan(xt).any(-1))[0].numpy()
        # NaN past the take's last frame in the model's frames: those hold the last frame
        fills.append(hold_last_frame(resample_frames(filled, c.fps, fixer.fps, len(xm))).astype(np.float32))
    return fills


class PositionWindows:
    """Windows of joint positions for a positions fixer (windowing.WindowSource): x_m[k] (K, Jm, 3)
    each clip at the model's joints and fps, NaN at missing tokens; padding is missing too.
    fills: each clip's whole-take fill at the model's frames, the fill the network corrects
    (_whole_take_fills), or None. Estimates are blended as positions; the fallback is Lerp over the clip."""

    fixed_length = True  # XMAE's positional embedding has one length

    def __init__(self, fixer: Fixer, x_m: list[np.ndarray], fills: list[np.ndarray] | None = None):
        self.fixer, self.x_m, self.fills = fixer, x_m, fills
        self.window, self.dim = fixer.window, 3 * x_m[0].shape[1]
        self._lerp: dict[int, np.ndarray] = {}

    def estimate(self, windows: list[tuple[int, np.ndarray]]) -> torch.Tensor:
        pos = np.stack([np.where((f >= 0)[:, None, None], self.x_m[k][np.maximum(f, 0)], np.nan) for k, f in windows])
        pos = torch.from_numpy(pos.astype(np.float32))  # (B, W, Jm, 3)
        if self.fills is None:
            return self.fixer.estimate(pos, ~torch.isnan(pos).any(-1)).double().flatten(2)  # (B, W, 3 Jm)
        # past the take's ends (padding; NaN in the resampled fill too) the fill holds the nearest frame
        fill = np.stack([self.fills[k][np.clip(f, 0, len(self.fills[k]) - 1)] for k, f in windows])
        fill = torch.from_numpy(np.nan_to_num(fill))  # (B, W, Jm, 3)
        return self.fixer.estimate(pos, ~torch.isnan(pos).any(-1), fill).double().flatten(2)

    def fallback(self, k: int) -> np.ndarray:
        if k not in self._lerp:
            x = torch.from_numpy(self.x_m[k]).double()[None]  # (1, K, Jm, 3)
            self._lerp[k] = lerp_infill(x, ~torch.isnan(x).any(-1))[0].flatten(1).numpy()
        return self._lerp[k]


def _carry_passengers(fixed: Clip, clip: Clip, model_joints: np.ndarray, replaced: np.ndarray) -> Clip:
    """The joints the model does not use (fingers, toes, twist bones) move with the nearest model
    joint above them where that one was replaced: a hand that jumped and was put back brings its
    fingers. model_joints: (Jm,) the clip's index of each model joint; replaced: (T, Jm)."""
    if not replaced.any():
        return fixed
    parents, positions = clip.skeleton.parents, fixed.positions.copy()
    column = {int(j): k for k, j in enumerate(model_joints)}
    for j in range(clip.skeleton.num_joints):
        if j in column:
            continue
        a = parents[j]
        while a >= 0 and a not in column:
            a = parents[a]
        if a < 0:
            continue
        moved = replaced[:, column[a]] & np.isfinite(clip.positions[:, j]).all(-1)  # (T,)
        positions[moved, j] = clip.positions[moved, j] + fixed.positions[moved, a] - clip.positions[moved, a]
    return fixed.replace(positions=positions)


def _fill_other_joints(positions: np.ndarray, model_joints: np.ndarray, skeleton: Skeleton) -> tuple[np.ndarray, int]:
    """positions: (T, J, 3) a clip with the model's joints fixed -> the holes of its other joints
    (fingers, extra spine joints) filled by the limb fill (each from its parent, bone length kept,
    fills/classical.py), and how many tokens that filled. Observed tokens stay as they are;
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
    library: Searchable | None = None,
) -> np.ndarray:
    """x: (T, J, 3) one clip's data, obs: (T, J), model_fill: (T, J, 3) the model's fill -> each
    hole filled by the method the policy names for its length and part; counts[method] += tokens.
    library: the other takes the motion-matching fills search (MotionLibrary.without)."""
    xt, ot = torch.from_numpy(x)[None], torch.from_numpy(obs)[None]
    fills = {"xmae": torch.from_numpy(model_fill)[None]}
    methods = set(policy.methods())
    fills.update({m: CLASSICAL[m](xt, ot, skeleton.parents) for m in methods if m in CLASSICAL})
    if methods & set(MATCH_FILLS):
        hermite = fills["hermite"] if "hermite" in fills else CLASSICAL["hermite"](xt, ot, skeleton.parents)
        found = match_fills(x, obs, hermite[0].numpy(), library, fps)
        fills.update({m: torch.from_numpy(f)[None] for m, f in found.items()})
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


class RotationWindows:
    """Windows of joint rotations for a rotations fixer (windowing.WindowSource): per clip the
    local axis-angle rotations (K, Jm, 3) and root translation (K, 3) at the model's fps, and the
    bone offsets (Jm, 3). The estimate is blended as unit quaternions, each turned to the
    hemisphere of the input's (q and -q are one rotation), and renormalised after (the weighted
    sum); the root translation linearly. The fallback is the input itself."""

    fixed_length = False  # recurrent networks: a short clip is a short window

    def __init__(self, fixer: RotationFixer, rotations: list, roots: list, offsets: list):
        self.fixer, self.rotations, self.roots, self.offsets = fixer, rotations, roots, offsets
        self.window, self.dim = fixer.window, 4 * rotations[0].shape[1] + 3
        self.q_ref = [roma.rotvec_to_unitquat(torch.from_numpy(r).double()) for r in rotations]  # (K, Jm, 4)

    def estimate(self, windows: list[tuple[int, np.ndarray]]) -> torch.Tensor:
        rot = torch.stack([torch.from_numpy(self.rotations[k][f]) for k, f in windows])  # (B, L, Jm, 3)
        root = torch.stack([torch.from_numpy(self.roots[k][f]) for k, f in windows])  # (B, L, 3)
        offs = torch.stack([torch.from_numpy(self.offsets[k]) for k, _ in windows])  # (B, Jm, 3)
        est_rot, est_root = self.fixer.estimate_rotations(rot, root, offs)
        q = roma.rotvec_to_unitquat(est_rot.double())  # (B, L, Jm, 4)
        ref = torch.stack([self.q_ref[k][f] for k, f in windows])
        q = torch.where((q * ref).sum(-1, keepdim=True) < 0, -q, q)
        return torch.cat([q.flatten(2), est_root.double()], -1)  # (B, L, 4 Jm + 3)

    def fallback(self, k: int) -> np.ndarray:
        return torch.cat([self.q_ref[k].flatten(1), torch.from_numpy(self.roots[k]).double()], -1).numpy()


def _fix_rotations(
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
    window * (1 - overlap)); a clip shorter than a window is kept as it is (too_short: too little
    motion to judge it by). Overlapping windows are blended as RotationWindows says."""
    model, fps_m = fixer.skeleton, fixer.fps
    source = clips[0].source or clips[0].name
    who = _who(clips)
    notes = list(getattr(fixer, "notes", []))

    index = []
    for i, c in enumerate(clips):
        idx = map_joints(c.skeleton, model, source, joint_map)
        if not c.has_rotations:
            why = c.meta.get("no_rotations")
            if why == "the kept joints have no constant bone offsets":  # the rig's own rotations do not fit
                problem = (
                    f"this rig's rotations do not fit its {model.num_joints}-joint hierarchy ({model.name}): "
                    "joints of the rig between the model's turn too"
                )
            else:
                problem = f"this input has none{f' ({why})' if why else ''}"
            raise MotionFileError(
                source,
                f"{who(i)}the model ({fixer.kind}, rotations state) needs joint rotations; {problem} "
                "(jitter on any rig: --model jitter-many)",
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
    frames, people = _frames_and_people(clips)
    if mode == "infill":
        notes.append("rotation input has no missing tokens: nothing to fill (--mode denoise replaces them)")
        before = float(sigma_before.compute())
        return list(clips), FixReport(frames, people, 0, 0, before, before, 0, notes)

    # Each clip long enough to judge (too_short) at the model's fps; every frame needs the estimate.
    judged = [k for k, c in enumerate(clips) if not too_short(c, fixer)]
    for k in sorted(set(range(len(clips))) - set(judged)):
        notes.append(
            f"{who(k)}{clips[k].num_frames} frames, shorter than the model's window "
            f"({fixer.window} frames at {fps_m:g} fps): {NOT_JUDGED}"
        )
    rot_m, root_m = [], []
    for k in judged:
        c, idx = clips[k], index[k]
        r, t = resample_motion(
            c.rotations[:, idx], c.root_translation, c.fps, fps_m, model_frames(c.num_frames, c.fps, fps_m)
        )
        rot_m.append(r)
        root_m.append(t)
    if not judged:
        before = float(sigma_before.compute())
        return list(clips), FixReport(frames, people, 0, 0, before, before, 0, notes)
    windows = RotationWindows(fixer, rot_m, root_m, [clips[k].offsets[index[k]] for k in judged])
    need = [np.ones(len(r), dtype=bool) for r in rot_m]
    blended = blend_windows(windows, need, need, overlap, batch_size, progress)
    tracks = dict(zip(judged, blended.tracks))

    out_clips, replaced = [], 0
    Jm = model.num_joints
    for k, (c, idx) in enumerate(zip(clips, index)):
        if k not in tracks:
            sigma_after.update(torch.from_numpy(c.positions[:, idx])[None])
            out_clips.append(c)
            continue
        track = torch.from_numpy(tracks[k])  # (K, 4 Jm + 3)
        q = track[:, : 4 * Jm].reshape(-1, Jm, 4)
        rot = roma.unitquat_to_rotvec(q / q.norm(dim=-1, keepdim=True)).numpy()  # (K, Jm, 3)
        root = track[:, 4 * Jm :].numpy()  # (K, 3)
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
    if blended.failed:
        notes.append(f"{blended.failed} windows gave non-finite estimates: the input blended in there")
    report = FixReport(
        frames, people, 0, replaced, float(sigma_before.compute()), float(sigma_after.compute()), blended.windows, notes
    )
    return out_clips, report
