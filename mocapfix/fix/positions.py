"""One pass of a positions model over the clips of one file: each clip at the model's joints and
fps -> windows of the model's length (every window of every person in one batched pass,
windowing.blend_windows) -> the blended estimate back at the clip's frames -> merged with the
input by mode:

    infill   missing tokens (NaN) get the estimate, anchored on the data at both ends of each
             hole (and, with a fill policy, the fill it names for the hole); observed tokens stay
             bit-identical.
    denoise  observed tokens get the estimate; missing tokens stay missing.
    both     every token gets the estimate (denoised and filled).

The joints the model does not use (fingers, extra spine joints) get their holes filled along the
skeleton. position_fixer.py decides which passes a fix makes (the fill policy, jumps replaced).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import numpy as np
import torch

from mocapfix.core.clip import Clip, MotionFileError
from mocapfix.core.resample import hold_last_frame, resample_frames
from mocapfix.core.skeleton import Skeleton
from mocapfix.fills.classical import classical_fills, hermite_infill, lerp_infill, limb_infill
from mocapfix.fills.fill import Made
from mocapfix.fills.motion_matching import MotionMatching, library_of
from mocapfix.fills.policy import FillPolicy
from mocapfix.fix.fixer import Fixer, FixOptions
from mocapfix.fix.joints import ModelView, model_view
from mocapfix.fix.report import NOT_JUDGED, FixReport, LimbSpread, frames_and_people, who
from mocapfix.fix.windowing import blend_windows, window_layout


class PositionWindows:
    """Windows of joint positions for a positions fixer (windowing.WindowSource): x_m[k] (K, Jm, 3)
    each clip at the model's joints and fps, NaN at missing tokens; padding is missing too.
    fills: each clip's whole-take fill at the model's frames, the fill the network corrects
    (hermite_take_fills), or None. Estimates are blended as positions; the fallback is Lerp over the clip."""

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


def hermite_take_fills(fps_m: float, clips: list[Clip], view: ModelView) -> list[np.ndarray]:
    """For an XMAE that corrects the cubic Hermite fill (fill_kind hermite): each take's Hermite
    fill over the whole take at the recording's own frame rate, brought to the model's (K, Jm, 3).
    A window of the model sees at most a second; the fill from the whole take at, say, 120 fps is
    a better start (on the CMU strangers it beats a cubic spline, docs/results.md)."""
    fills = []
    for c, x, xm in zip(clips, view.x_in, view.x_m):
        xt = torch.from_numpy(x.astype(np.float64))[None]  # (1, T, Jm, 3)
        filled = hermite_infill(xt, ~torch.isnan(xt).any(-1))[0].numpy()
        # NaN past the take's last frame in the model's frames: those hold the last frame
        fills.append(hold_last_frame(resample_frames(filled, c.fps, fps_m, len(xm))).astype(np.float32))
    return fills


def take_keys(clips: list[Clip]) -> list[tuple[str, int]]:
    """What names each clip of a file in a MotionLibrary: (its file, its place in the file)."""
    return [(c.source or c.name, i) for i, c in enumerate(clips)]


def needed_frames(clips: list[Clip], view: ModelView, mode: str, fps_m: float) -> list[np.ndarray]:
    """(K,) bool per clip: the model frames that need an estimate. Infill only uses it at missing
    tokens and at the observed frames next to them (anchors); the other modes use it wherever
    there is data."""
    need_m = []
    for c, x, xm in zip(clips, view.x_in, view.x_m):
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
    return need_m


@dataclass
class _Tally:
    """What one pass counts over the clips of a file, for its report."""

    model: Skeleton
    filled: int = 0
    replaced: int = 0
    lerped: int = 0
    other_filled: int = 0
    filled_by: dict[str, int] = field(default_factory=dict)
    never: dict[str, list[str]] = field(default_factory=dict)  # person -> model joints never observed
    absent: dict[str, list[str]] = field(default_factory=dict)  # person -> model joints the recording lacks
    notes: list[str] = field(default_factory=list)

    def __post_init__(self):
        self.limbs = LimbSpread(self.model)


def positions_pass(
    clips: list[Clip],
    fixer: Fixer,
    options: FixOptions,
    policy: FillPolicy | None,
    fill_other_joints: bool = True,
    seen: list[np.ndarray] | None = None,
    view: ModelView | None = None,
) -> tuple[list[Clip], FixReport]:
    """The clips of one file fixed by one pass of a positions model in options.mode (infill with
    the fill policy where there is one); the holes of joints the model does not use filled too
    (fill_other_joints, unless denoise). A clip shorter than the model's window keeps its
    observed tokens in every mode (Fixer.too_short). seen: (T, Jm) per clip, the tokens the
    recording observed, when `clips` has some taken out (the policy's second pass): the report's
    "never observed" is about the recording. view: model_view(clips, ...) when the caller has it.
    options.library: what the policy's motion-matching fills search besides these clips."""
    model, fps_m, mode = fixer.skeleton, fixer.fps, options.mode
    source = clips[0].source or clips[0].name
    view = view if view is not None else model_view(clips, model, fps_m, options.joint_map)
    keys, library = take_keys(clips), options.library
    if policy is not None:  # what the policy's motion matching searches (if it chooses it): these takes too
        library = library_of([(x, c.fps) for x, c in zip(view.x_in, clips)], keys, model, library)

    # Windows with data go to the model; windows without any (a hole longer than a window) get
    # Lerp instead, blended the same way, so there is no seam where the estimate meets the fallback.
    need_m = needed_frames(clips, view, mode, fps_m)
    has_data = [np.isfinite(xm).all(-1).any(-1) for xm in view.x_m]  # (K,) per clip
    windows = PositionWindows(fixer, view.x_m, fixer.whole_take_fills(clips, view))
    blended = blend_windows(windows, need_m, has_data, options.overlap, options.batch_size, options.progress)

    tally, out_clips = _Tally(model), []
    for k, c in enumerate(clips):
        est_m = blended.tracks[k].reshape(-1, model.num_joints, 3)  # (K, Jm, 3); NaN at frames no window needed
        tally.lerped += int((~blended.by_model[k] & need_m[k]).sum())
        est = resample_frames(est_m, fps_m, c.fps, c.num_frames)  # (T, Jm, 3)
        match = MotionMatching(library, keys[k])  # this take's own data searched as it is, holes and all
        new = _merge(est, view.x_in[k], view.index[k], mode, policy, c.fps, model, tally.filled_by, match)
        keep = mode == "infill" or fixer.too_short(c)  # its observed tokens kept
        out_clips.append(
            _clip_fixed(c, k, new, view, fixer, mode, keep, seen, fill_other_joints, tally, who(clips), source)
        )
    return out_clips, _pass_report(clips, view, fixer, options, blended, tally)


def _merge(
    est: np.ndarray,
    x_in: np.ndarray,
    index: np.ndarray,
    mode: str,
    policy: FillPolicy | None,
    fps: float,
    model: Skeleton,
    filled_by: dict[str, int],
    match: MotionMatching,
) -> np.ndarray:
    """est: (T, Jm, 3) the model's estimate at a clip's frames, x_in (T, Jm, 3) the clip at the
    model's joints -> (T, Jm, 3) float64, the two merged as the mode says."""
    x = x_in.astype(np.float64)
    obs = np.isfinite(x).all(-1)  # (T, Jm)
    if mode == "denoise":
        return np.where(obs[..., None], est, np.nan)
    if mode == "both":
        return est
    # Anchor the estimate on the data: the residual at observed tokens, interpolated over each
    # gap, is added to the fill, so the fill meets the data at both gap ends.
    resid = torch.from_numpy(np.where(obs[..., None], x - est, np.nan))
    resid = lerp_infill(resid[None], torch.from_numpy(obs)[None])[0].numpy()
    new = np.where(obs[..., None], x, est + resid)
    if policy is not None:
        absent = index < 0
        model_fill = new[:, absent]
        fills = [Made("xmae", torch.from_numpy(new)[None]), *classical_fills(), match]
        # counted: the joints the recording has (the fill of one it lacks is not written)
        xt, ot, counted = torch.from_numpy(x)[None], torch.from_numpy(obs)[None], torch.from_numpy(~absent)
        out, counts = policy.transform(xt, ot, fps, model, fills, counted)
        for method, n in counts.items():
            filled_by[method] = filled_by.get(method, 0) + n
        new = out[0].numpy()
        new[:, absent] = model_fill  # no classical fill has anything to go on there
    return new


def _clip_fixed(c, k, new, view, fixer, mode, keep, seen, fill_other_joints, tally: _Tally, name, source) -> Clip:
    """Clip k with the merged estimate `new` (T, Jm, 3) written into its model joints; counted."""
    model, x_in, index = fixer.skeleton, view.x_in[k], view.index[k]
    obs = np.isfinite(x_in).all(-1)  # (T, Jm)
    new = new.astype(np.float32)
    if keep:
        new[obs] = x_in[obs]  # bit-identical, whatever float64 did
    if keep and mode != "infill":
        tally.notes.append(
            f"{name(k)}{c.num_frames} frames, shorter than the model's window ({fixer.window} frames at "
            f"{fixer.fps:g} fps): " + NOT_JUDGED
        )
    must = obs if mode == "denoise" else np.ones_like(obs)
    if not np.isfinite(new[must]).all():  # a bug, never data: do not write it
        raise MotionFileError(source, f"{name(k)}the estimate is not finite; nothing written")
    tally.filled += int((~obs).sum()) if mode != "denoise" else 0
    tally.replaced += int(obs.sum()) if not keep else 0
    present = index >= 0
    observed = obs if seen is None else seen[k]
    lost = [model.joint_names[j] for j in np.nonzero(~observed.any(0) & present)[0]]
    if lost:
        tally.never[name(k) or ""] = lost
    if not present.all():
        tally.absent[name(k) or ""] = [model.joint_names[j] for j in np.nonzero(~present)[0]]
        tally.filled -= int((~obs[:, ~present]).sum()) if mode != "denoise" else 0  # estimated, not written

    positions = c.positions.copy()
    positions[:, index[present]] = new[:, present]
    if fill_other_joints and mode != "denoise":
        positions, n = fill_other_joints_of(positions, index, c.skeleton)
        tally.other_filled += n
    tally.limbs.add(x_in, new, index)  # the limbs of the joints the clip has
    return c.replace(positions=positions, rotations=None, root_translation=None, offsets=None)


def _pass_report(clips, view: ModelView, fixer: Fixer, options: FixOptions, blended, tally: _Tally) -> FixReport:
    notes, fps_m = tally.notes, fixer.fps
    if tally.other_filled:
        notes.append(f"{tally.other_filled} missing tokens of joints the model does not use filled along the skeleton")
        tally.filled += tally.other_filled
    if tally.lerped:
        notes.append(f"{tally.lerped} frames at {fps_m:g} fps had no data within a window: linear interpolation")
    if blended.failed:
        notes.append(f"{blended.failed} windows gave non-finite estimates: linear interpolation there")
    fate = "left missing" if options.mode == "denoise" else "estimated from the rest of the body"
    for person, joints in tally.never.items():
        notes.append(f"{person}joints never observed: {', '.join(joints)} ({fate})")
    for person, joints in tally.absent.items():
        notes.append(f"{person}model joints not in the recording: {', '.join(joints)} (estimated, not written)")
    whole = _joints_missing_for_a_window(view.x_m, fixer.window, options.overlap)
    if whole:
        notes.append(f"{whole} windows had a joint missing throughout ({fate})")
    frames, people = frames_and_people(clips)
    before, after = tally.limbs.values()
    return FixReport(
        frames, people, tally.filled, tally.replaced, before, after, blended.windows, notes, tally.filled_by
    )


def with_mode(options: FixOptions, mode: str) -> FixOptions:
    return dataclasses.replace(options, mode=mode)


def fill_other_joints_of(positions: np.ndarray, model_joints: np.ndarray, skeleton: Skeleton) -> tuple[np.ndarray, int]:
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
