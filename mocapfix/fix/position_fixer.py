"""What a positions model (XMAE; Motion-DVAE on its positions state) does with the clips of one
file: a long take in pieces (pieces.py); the fill policy measured on the recording where the
fixer measures its policy (measure.py); then one pass (positions.py), or, in denoise and both
with a policy, two: the jumps found and replaced, the holes filled (replace.py)."""

from __future__ import annotations

import numpy as np

from mocapfix.core.clip import Clip
from mocapfix.fix.fixer import Fixer, FixOptions
from mocapfix.fix.joints import ModelView, model_view
from mocapfix.fix.measure import measure_views
from mocapfix.fix.pieces import fix_in_pieces, is_long
from mocapfix.fix.positions import Estimates, model_estimates, positions_pass
from mocapfix.fix.replace import replace_jumps
from mocapfix.fix.report import FixReport


class PositionFixer(Fixer):
    """A fixer whose estimate is every token's position: estimate(positions (B, W, J, 3),
    observed (B, W, J)) -> (B, W, J, 3). With the fill policy (calibrated on its val split,
    fills/policy.py, and measured again on the recording where measures_policy) each hole is
    filled by the method that was best for holes of its length and part, and in denoise / both
    an observed token is replaced only where its joint jumped away from the model's estimate and
    back (replace.py). Without a policy the model's estimate is used everywhere the mode says."""

    candidate = "xmae"  # its fill's name among a fill policy's candidates (fills/policy.py LEARNED)

    def estimates(self, clips: list[Clip], view: ModelView, need_m: list[np.ndarray], options: FixOptions) -> Estimates:
        """The model's estimate of each clip at the frames need_m ((K,) bool per clip at the
        model's frames) asks for: windows of the model's length, blended (positions.model_estimates)."""
        return model_estimates(clips, self, view, need_m, options)

    def fix_clips(self, clips: list[Clip], options: FixOptions) -> tuple[list[Clip], FixReport]:
        if any(is_long(c) for c in clips):
            return fix_in_pieces(clips, self, options)
        policy, note, view = self._policy_for(clips, options)
        if policy is None or options.mode == "infill":
            out, report = positions_pass(clips, self, options, policy, view=view)
            if note:
                report.notes.insert(0, note)
            return out, report
        return replace_jumps(clips, self, options, policy, note, view)

    def _policy_for(self, clips: list[Clip], options: FixOptions) -> tuple:
        """(the policy the holes are filled by, a line for the report or None, the clips'
        model_view or None). A calibrated model's holes are filled as the recording's own evidence
        says (a checkpoint without a policy keeps its documented behaviour: the model everywhere
        the mode says). In denoise and both the holes are known after the first pass (the input's
        and the jumps taken out): the policy is measured then (replace.py), for those kinds only."""
        policy, note, view = self.policy, None, None
        if self.measures_policy and policy is not None:
            view = model_view(clips, self.skeleton, self.fps, options.joint_map)
            if options.measured is not None and options.measured[1] and options.mode != "denoise":  # the run's
                policy, note = options.measured
            elif options.mode == "infill" and view.has_holes():  # else nothing to fill
                policy, note = measure_views(
                    self, [view], [clips], options.mode, options.overlap, options.batch_size, library=options.library
                )
        return policy, note, view

    def whole_take_fills(self, clips: list[Clip], view: ModelView) -> list[np.ndarray] | None:
        """Each take's fill over the whole take at the model's frames (K, Jm, 3), the fill its
        network corrects; None: the network corrects its window's own fill, as it was trained."""
        return None
