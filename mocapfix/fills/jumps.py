"""Which observed tokens a model may replace: those it disagrees with beyond the fill policy's
replace threshold (a test window's displaced tokens), and on whole recordings the excursions, a
jump away from the model's estimate and back (fix/replace.py)."""

from __future__ import annotations

import torch

from mocapfix.fills.policy import FillPolicy


def suspect_tokens(
    policy: FillPolicy, estimate: torch.Tensor, positions: torch.Tensor, observed: torch.Tensor
) -> torch.Tensor:
    """(B, T, J) bool: observed tokens the model disagrees with by more than it does with clean data
    (displaced or glitched joints); none without a calibrated threshold.
    estimate: the model's estimate with every available token observed."""
    if policy.replace_threshold_m is None:
        return torch.zeros_like(observed)
    far = (estimate.float() - torch.nan_to_num(positions.float())).norm(dim=-1) > policy.replace_threshold_m
    return observed & far


# An excursion's first step must also stand out from the recording's own residual steps: this
# many times their STEP_QUANTILE. (A tenth of the steps' 1 % tail would have to be jumps to raise it.)
STEP_QUANTILE, STEP_FACTOR = 0.99, 3.0


def recording_step_floor(residual: torch.Tensor, observed: torch.Tensor) -> float:
    """The smallest jump (metres) that can start an excursion on this recording, measured on it:
    STEP_FACTOR x the STEP_QUANTILE of the residual's frame-to-frame steps over observed tokens.

    The checkpoint's replace threshold was calibrated on its val split; a model fine-tuned on a few
    takes agrees with those far more closely than with a stranger's take (`mocapfix demo`: after 300
    steps on 40 Bandai takes the threshold fell from 228 to 48 mm, while a held-out take's residual
    steps reach 39 mm at the 99th percentile, and 774 of its 9,021 clean tokens were replaced).
    residual: (T, J, 3), observed: (T, J) bool."""
    both = observed[1:] & observed[:-1]
    steps = (residual[1:] - residual[:-1]).norm(dim=-1)[both]  # (n,)
    if steps.numel() == 0:
        return 0.0
    every = -(-steps.numel() // 1_000_000)  # a sample over the whole take: torch.quantile refuses very large inputs
    return STEP_FACTOR * float(torch.quantile(steps[::every].double(), STEP_QUANTILE))


def excursions(residual: torch.Tensor, observed: torch.Tensor, min_step_m: float, max_frames: int) -> torch.Tensor:
    """The tokens of one take that jumped away and came back: (T, J) bool.

    residual: (T, J, 3) the data minus the model's estimate; observed: (T, J) bool. The estimate
    moves as the body does, so a frame-to-frame step of the residual is the data's own jump; an
    excursion is a step of more than min_step_m answered, within max_frames, by a step back of
    about the same vector (the two sum to less than half of the first): the frames between are
    where the joint was away. A model that disagrees with a stranger's motion does so smoothly,
    and a jumped joint in a plausible pose (its arm rotated with it) fools the model's
    disagreement mid-jump but not its edges: on the 70 CMU takes with the shipped Bandai model,
    0.06 % of the clean tokens are in excursions (2.7 % are beyond the replace threshold) and
    99.6 % of the tokens of arms displaced 0.5-1 m for 0.5 s; on Bandai's test takes 0.2 % and
    98.9 %. A run at the take's first or last frame has one edge: nothing shows it came back
    (CMU's takes start with a bind pose a metre from the next frame: the take's, kept)."""
    step = residual[1:] - residual[:-1]  # (T-1, J, 3): into frame t+1
    size = torch.where(observed[1:] & observed[:-1], step.norm(dim=-1), 0.0)  # (T-1, J)
    out = torch.zeros_like(observed)
    for j in torch.nonzero((size > min_step_m).any(0)).flatten().tolist():
        jumps = torch.nonzero(size[:, j] > min_step_m).flatten().tolist()
        done = -1
        for a in jumps:
            if a <= done:
                continue
            for b in (b for b in jumps if a < b <= a + max_frames):
                if float((step[a, j] + step[b, j]).norm()) < 0.5 * float(size[a, j]):
                    out[a + 1 : b + 1, j] = True
                    done = b
                    break
    return out
