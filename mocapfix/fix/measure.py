"""The fill policy fitted on recordings as `fix` fills them (FillPolicy.fit): the model enters
as a Fill, its fill of a take made by the positions pass itself (windows, blending, anchoring on
the data); and the takes a run's motion-matching fills search."""

from __future__ import annotations

import numpy as np
import torch

from mocapfix.core.clip import Clip, MotionFileError
from mocapfix.fills.classical import lerp_infill
from mocapfix.fills.fill import Fill
from mocapfix.fills.motion_matching import MotionLibrary, MotionMatching, library_of
from mocapfix.fills.policy import FillPolicy
from mocapfix.fix.fixer import Fixer, FixOptions
from mocapfix.fix.joints import ModelView, model_view
from mocapfix.fix.merge import merge
from mocapfix.fix.position_windows import needed_frames
from mocapfix.fix.positions import take_keys
from mocapfix.fix.threads import on_one_blas_thread


class TakeFill(Fill):
    """A positions model's fill of whole takes as fix makes it (its estimates: windows blended,
    or a learned correction's holes; anchored on the data; no policy), named as the fixer's
    candidate: fill(x (T, J, 3) at the model's joints, the take's fps; NaN =
    missing) -> (T, J, 3), and the same over a batch of takes as a Fill. Asked for some holes
    (the ones a policy is measured on), it runs the windows those need and no others: a hole of
    the take's own keeps the Lerp fill there."""

    def __init__(self, fixer: Fixer, overlap: float, batch_size: int):
        self.fixer, self.options = fixer, FixOptions("infill", overlap, batch_size)
        self.names = (fixer.candidate,)

    def __call__(self, x: np.ndarray, fps: float, asked: np.ndarray | None = None) -> np.ndarray:
        """x: (T, J, 3); asked: (T,) bool, the frames whose holes are wanted (None: all)."""
        return self.takes([x], fps, None if asked is None else [asked])[0]

    def takes(self, xs: list[np.ndarray], fps: float, asked: list[np.ndarray] | None = None) -> list[np.ndarray]:
        """__call__ of several takes at once, their windows run in the same batches: a policy's
        measurement asks for a few holes of each kind, and on a CPU a call of a few windows costs
        the model nearly three times a window what a full batch does (5 against 1.8 ms)."""
        skeleton = self.fixer.skeleton
        takes = [Clip(x.astype(np.float32), fps, skeleton) for x in xs]
        view = model_view(takes, skeleton, self.fixer.fps, None)
        need_m = needed_frames(takes, view, "infill", self.fixer.fps, asked)
        estimates = self.fixer.estimates(takes, view, need_m, self.options).clips
        out = []
        for k, (x, est) in enumerate(zip(xs, estimates)):
            new = merge(est, view.x_in[k], view.index[k], "infill", None, fps, skeleton, {}, MotionMatching(None))
            if asked is not None:  # the holes not asked for: no window ran there (est NaN); Lerp keeps it finite
                xt = torch.from_numpy(x.astype(np.float64))[None]
                new = np.where(np.isfinite(new), new, lerp_infill(xt, ~torch.isnan(xt).any(-1))[0].numpy())
            out.append(new)
        return out

    def fill(self, positions, observed, fps, skeleton, asked=None, shared=None) -> dict[str, torch.Tensor]:
        frames = None if asked is None else list(asked.any(-1).numpy())  # (T,) per take
        out = self.takes([x.numpy() for x in positions], fps, frames)
        return {self.names[0]: torch.stack([torch.from_numpy(o).double() for o in out])}


def model_fill(fixer: Fixer, overlap: float, batch_size: int) -> TakeFill:
    """The model's fill of takes as fix makes it, the Fill a policy is fitted with."""
    return TakeFill(fixer, overlap, batch_size)


@on_one_blas_thread  # fix/threads.py
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
    performer or session, whose holes alone are too few to rank the fills by; FillPolicy.fit)
    -> (policy, a line for the report); pass it to fix_clips(measured=...). (None, None) for a
    fixer that does not measure its policy (Fixer.measures_policy), one without a policy, or
    denoise. A recording the model's joints cannot be found in is left out (fixing it says why).
    map_takes: measure_on_takes' (workers); library: other takes the motion-matching fills
    search besides these (fix --library)."""
    if not fixer.measures_policy or mode == "denoise" or fixer.policy is None:
        return None, None
    views, mapped = [], []
    for clips in recordings:
        try:
            views.append(model_view(clips, fixer.skeleton, fixer.fps, joint_map))
            mapped.append(clips)
        except MotionFileError:
            continue
    if not views:
        return None, None
    return measure_views(fixer, views, mapped, mode, overlap, batch_size, map_takes, library)


def measure_views(
    fixer: Fixer,
    views: list[ModelView],
    recordings: list[list[Clip]],
    mode: str,
    overlap: float,
    batch_size: int,
    map_takes=None,
    library: MotionLibrary | None = None,
) -> tuple[FillPolicy | None, str | None]:
    """The fixer's policy fitted on recordings seen at the model's joints (model_view) -> (policy,
    note); in --mode both every kind of hole (its jumps make holes of any kind)."""
    tracks = [x for v in views for x in v.x_m]  # (K, Jm, 3) per clip, the model's fps
    takes = [(x, c.fps) for v, clips in zip(views, recordings) for x, c in zip(v.x_in, clips)]  # the input's fps
    keys = [key for clips in recordings for key in take_keys(clips)]
    holes_of = None if mode == "both" else (tracks, fixer.fps)
    fill = model_fill(fixer, overlap, batch_size)
    return fixer.policy.fit(takes, fixer.skeleton, fill, holes_of, map_takes, keys, library)


def motion_library(
    recordings: list[list[Clip]],
    fixer: Fixer,
    joint_map: dict[str, str] | None = None,
    library: MotionLibrary | None = None,
) -> MotionLibrary | None:
    """The takes of several files (a run's) at the model's joints and their own fps, then
    `library`'s (fix --library's), for the motion-matching fills of every file of the run
    (fills/motion_matching.py); None where none maps."""
    takes, keys = [], []
    for clips in recordings:
        try:
            view = model_view(clips, fixer.skeleton, fixer.fps, joint_map)
        except MotionFileError:
            continue
        takes += [(x, c.fps) for x, c in zip(view.x_in, clips)]
        keys += take_keys(clips)
    return library_of(takes, keys, fixer.skeleton, library) if takes else None
