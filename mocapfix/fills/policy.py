"""The fill policy: which method fills each hole, and which observed tokens a model may replace,
decided on held-out data so that mocapfix never outputs worse than the best classical fill.

A small model can lose to a cubic spline on short holes and win on long ones; a large one can
lose at 0.1 s and win everywhere else. So the model's error and each classical fill's error are
measured per hole length and body part on the validation split (Calibration, from a training
module's validation) and stored in the checkpoint (FillPolicy.to_dict). `fix` and the test
tables then fill each hole with the method that was best for holes of its length and part, and
replace an observed token only where the model disagrees with it by more than the model ever
does with clean data (replace_threshold_m).

A candidate is a single method ("spline") or the mean of two ("limb+spline"): two fills that err
in different directions average to a smaller error than either (a spline overshoots where the
limb fill bends), and which pair that is differs by hole length and part, so it is measured too.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import torch

from mocapfix.core.skeleton import Skeleton

PARTS = ("full", "arm", "leg")
CLEAN_QUANTILE = 0.995  # of the model's disagreement with clean observed tokens: above it, a token is suspect
LEARNED = ("xmae",)  # the methods that are models; every other is a classical fill
MODEL_MARGIN = 0.98  # a model fills a hole only where its val error is 2 % below the best classical fill's
BLEND = "+"  # "a+b": the mean of fills a and b
BLEND_MARGIN = 0.99  # a blend of classical fills only where 1 % below the best single one (in doubt, the simpler)


def components(method: str) -> list[str]:
    """The single methods a candidate averages: "limb+spline" -> ["limb", "spline"]."""
    return method.split(BLEND)


def is_learned(method: str) -> bool:
    """A candidate with a model in it (a model alone, or a model averaged with a classical fill)."""
    return any(m in LEARNED for m in components(method))


def blends(fills: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
    """fills: method -> (..., 3) -> the same plus the mean of every pair, named "a+b" (sorted)."""
    names = sorted(fills)
    out = dict(fills)
    for i, a in enumerate(names):
        for b in names[i + 1 :]:
            out[a + BLEND + b] = 0.5 * (fills[a] + fills[b])
    return out


@dataclass
class FillPolicy:
    gaps_s: list[float]  # the hole lengths measured, ascending
    error_mm: dict[str, dict[str, list[float]]]  # part -> method -> MPJPE per gap (val split)
    replace_threshold_m: float | None = None  # None: never replace an observed token
    windows: int = 0  # val windows it was measured on
    notes: list[str] = field(default_factory=list)
    # (method, margin): this classical fill unless another classical candidate's error is below
    # margin x its error (near-ties rank differently on other holes); None: the lowest error
    preferred: tuple[str, float] | None = None

    def best(self, part: str, gap_s: float) -> str:
        """The method with the lowest error for holes of this part, at the measured length nearest
        gap_s; a blend of classical fills only where it beats the best single one by BLEND_MARGIN,
        the model (or a blend with it) only where it beats the best classical fill by MODEL_MARGIN
        (in doubt, the fill whose behaviour a user knows); the preferred classical fill, where one
        is set, unless another classical candidate beats it by its margin."""
        table = self.error_mm.get(part) or self.error_mm["full"]
        i = min(range(len(self.gaps_s)), key=lambda k: abs(self.gaps_s[k] - gap_s))
        singles = [m for m in table if not is_learned(m) and BLEND not in m]
        mixed = [m for m in table if not is_learned(m) and BLEND in m]
        best = min(singles, key=lambda m: table[m][i]) if singles else None
        blend = min(mixed, key=lambda m: table[m][i]) if mixed else None
        if best is None or (blend is not None and table[blend][i] < BLEND_MARGIN * table[best][i]):
            best = blend
        if self.preferred is not None and self.preferred[0] in table:
            keep, margin = self.preferred
            if best is None or table[best][i] >= margin * table[keep][i]:
                best = keep
        model = min((m for m in table if is_learned(m)), key=lambda m: table[m][i], default=None)
        if best is None or (model is not None and table[model][i] < MODEL_MARGIN * table[best][i]):
            return model
        return best

    def methods(self) -> list[str]:
        """The single methods its candidates are made of (the fills a caller computes)."""
        return sorted({c for table in self.error_mm.values() for m in table for c in components(m)})

    def describe(self) -> list[str]:
        """One line per part: the method chosen at each measured gap, with its error and the best
        classical fill's."""
        lines = []
        for part, table in self.error_mm.items():
            cells = []
            for i, g in enumerate(self.gaps_s):
                m = self.best(part, g)
                classical = min(v[i] for k, v in table.items() if not is_learned(k))
                cells.append(f"{g:g}s {m} {table[m][i]:.1f} (classical {classical:.1f})")
            lines.append(f"{part}: " + ", ".join(cells))
        if self.replace_threshold_m is not None:
            lines.append(
                f"observed tokens replaced where the model disagrees by more than "
                f"{1000 * self.replace_threshold_m:.0f} mm"
            )
        return lines

    def to_dict(self) -> dict:
        """Plain values (a checkpoint loaded with weights_only=True holds nothing else)."""
        return {
            "gaps_s": list(self.gaps_s),
            "error_mm": self.error_mm,
            "replace_threshold_m": self.replace_threshold_m,
            "windows": self.windows,
            "notes": list(self.notes),
            "preferred": list(self.preferred) if self.preferred else None,
        }

    @classmethod
    def from_dict(cls, d: dict) -> FillPolicy:
        return cls(
            [float(g) for g in d["gaps_s"]],
            d["error_mm"],
            d.get("replace_threshold_m"),
            int(d.get("windows", 0)),
            list(d.get("notes", [])),
            (str(d["preferred"][0]), float(d["preferred"][1])) if d.get("preferred") else None,
        )


def hole_frames(observed: torch.Tensor) -> torch.Tensor:
    """observed: (B, T, J) bool -> (B, T, J) long: for a missing token, the length in frames of the
    run of missing frames of its joint that it is in; 0 for observed tokens."""
    B, T, J = observed.shape
    t = torch.arange(T, device=observed.device).view(1, T, 1).expand(B, T, J)
    prev = torch.where(observed, t, -1).cummax(dim=1).values  # last observed at or before t
    nxt = torch.where(observed, t, T).flip(1).cummin(dim=1).values.flip(1)  # first observed at or after t
    return torch.where(observed, 0, nxt - prev - 1)


def token_parts(observed: torch.Tensor, skeleton: Skeleton) -> torch.Tensor:
    """observed: (B, T, J) -> (B, T, J) index into PARTS of the table a missing token is filled by:
    "full" in frames that miss at least half the joints (a body-wide hole), else the limb the joint
    belongs to (arm, leg), else "full"."""
    B, T, J = observed.shape
    limb = torch.zeros(J, dtype=torch.long, device=observed.device)
    for group, members in skeleton.groups.items():
        limb[list(members)] = PARTS.index(group.split("_")[-1])
    body_wide = (~observed).float().mean(dim=-1, keepdim=True) >= 0.5  # (B, T, 1)
    return torch.where(body_wide, 0, limb.view(1, 1, J).expand(B, T, J))


def apply_fill_policy(
    policy: FillPolicy,
    positions: torch.Tensor,
    observed: torch.Tensor,
    fills: dict[str, torch.Tensor],
    fps: float,
    skeleton: Skeleton,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Each missing token from the fill the policy names for its hole; observed tokens as given.

    positions: (B, T, J, 3); observed: (B, T, J) bool; fills: method -> (B, T, J, 3), holding
    every single method of policy.methods() -> (B, T, J, 3), and (B, T, J) the index into
    policy_names(policy, fills) of the candidate each token took (-1 for observed tokens)."""
    names = policy_names(policy, fills)
    stacked = torch.stack([_candidate(fills, m) for m in names])  # (M, B, T, J, 3)
    seconds = hole_frames(observed).float() / fps
    parts = token_parts(observed, skeleton)
    # the choice depends only on (part, nearest measured gap): a lookup table, not a per-token loop
    edges = torch.tensor([(a + b) / 2 for a, b in zip(policy.gaps_s, policy.gaps_s[1:])], device=observed.device)
    gap_index = torch.bucketize(seconds.contiguous(), edges)  # (B, T, J) into gaps_s
    table = torch.tensor(
        [[names.index(policy.best(p, g)) for g in policy.gaps_s] for p in PARTS], device=observed.device
    )  # (parts, gaps)
    choice = table[parts, gap_index]  # (B, T, J)
    out = stacked.gather(0, choice[None, ..., None].expand(1, *choice.shape, 3))[0]
    return torch.where(observed[..., None], positions, out), torch.where(observed, -1, choice)


def policy_names(policy: FillPolicy, fills: dict[str, torch.Tensor]) -> list[str]:
    """The candidates apply_fill_policy may take: the single fills given, then the blends the
    policy names (the index its `chosen` refers to)."""
    chosen = {policy.best(p, g) for p in PARTS for g in policy.gaps_s}
    return list(fills) + sorted(m for m in chosen if m not in fills)


def _candidate(fills: dict[str, torch.Tensor], method: str) -> torch.Tensor:
    parts = components(method)
    return fills[method] if method in fills else sum(fills[m] for m in parts) / len(parts)


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


class Calibration:
    """Accumulates, over validation batches, each method's error per (part, gap) on infill tasks
    and the model's disagreement with clean observed tokens -> FillPolicy."""

    def __init__(self, gaps_s):
        self.gaps_s = sorted(float(g) for g in gaps_s)
        self.sums: dict[tuple[str, float, str], list[float]] = {}  # (part, gap, method) -> [error sum m, count]
        self.clean: list[torch.Tensor] = []
        self.windows = 0

    def add_infill(
        self, part: str, gap_s: float, method: str, pred: torch.Tensor, target: torch.Tensor, scored: torch.Tensor
    ) -> None:
        """pred, target: (B, T, J, 3) metres; scored: (B, T, J) bool (the filled tokens with truth).
        Pass blends(fills) through add_fills to measure the pairs too."""
        err = (pred.float() - torch.nan_to_num(target.float())).norm(dim=-1)[scored]
        s = self.sums.setdefault((part, float(gap_s), method), [0.0, 0])
        s[0] += float(err.sum())
        s[1] += int(err.numel())

    def add_fills(
        self, part: str, gap_s: float, fills: dict[str, torch.Tensor], target: torch.Tensor, scored: torch.Tensor
    ) -> None:
        """Every single fill and the mean of every pair of them (see the module's docstring)."""
        for method, pred in blends(fills).items():
            self.add_infill(part, gap_s, method, pred, target, scored)

    def add_clean(self, estimate: torch.Tensor, positions: torch.Tensor, observed: torch.Tensor) -> None:
        """The model's estimate of windows it saw whole: how far it strays from clean data."""
        self.clean.append((estimate.float() - torch.nan_to_num(positions.float())).norm(dim=-1)[observed].cpu())
        self.windows += len(positions)

    def compute(self) -> FillPolicy | None:
        if not self.sums:
            return None
        error: dict[str, dict[str, list[float]]] = {}
        for part in PARTS:
            methods = sorted({m for (p, _, m) in self.sums if p == part})
            rows = {
                m: [
                    1000.0 * self.sums[(part, g, m)][0] / max(self.sums[(part, g, m)][1], 1)
                    if (part, g, m) in self.sums
                    else float("inf")
                    for g in self.gaps_s
                ]
                for m in methods
            }
            if rows:
                error[part] = rows
        threshold = None
        if self.clean:
            d = torch.cat(self.clean)
            if d.numel():
                # a sample is enough for the quantile (torch.quantile refuses very large inputs)
                d = d[torch.randperm(d.numel(), generator=torch.Generator().manual_seed(0))[:1_000_000]]
                threshold = float(torch.quantile(d.double(), CLEAN_QUANTILE))
        return FillPolicy(self.gaps_s, error, threshold, self.windows)
